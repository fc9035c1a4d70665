/* The smallest embedding of raypace: make a context, load (or generate) a
 * volume, pick a transfer function, open the best device, set a camera and
 * render one frame to PNG.
 *
 *   sample_render [VOLUME_FILE|-] [OUT.png]
 *
 * Without a file (or with "-") it renders a generated CT-like phantom. The
 * device is the first backend with one (RP_BACKEND=opencl|vulkan|reference
 * picks); without any GPU or CPU driver it falls back to the reference. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "raypace.h"

static int check(rp_context *ctx, int err, const char *what) {
  if (err != 0)
    fprintf(stderr, "%s: %s: %s\n", what, rp_strerror(err),
            rp_last_error(ctx));
  return err;
}

int main(int argc, char **argv) {
  const char *out = argc > 2 ? argv[2] : "sample.png";
  rp_context *ctx = NULL;
  rp_volume *vol = NULL;
  rp_tf *tf = NULL;
  rp_histograms *hist = NULL;
  rp_occupancy *occ = NULL;
  rp_device *dev = NULL;
  rp_device_desc dd = {0};
  rp_caps caps;
  rp_camera cam = {0};
  rp_render_desc rd = {0};
  uint8_t *rgba = NULL;
  int err;

  if ((err = rp_context_create(NULL, &ctx)) != 0)
    return 1;
  if (argc > 1 && strcmp(argv[1], "-") != 0) {
    err = check(ctx, rp_volume_load(ctx, argv[1], &vol), argv[1]);
  } else {
    rp_generate_desc g = {0};
    g.kind = RP_GEN_PHANTOM;
    g.dims[0] = g.dims[1] = g.dims[2] = 128;
    err = check(ctx, rp_volume_generate(ctx, &g, &vol), "generate");
  }
  if (err == 0)
    err = check(ctx, rp_tf_create_preset(ctx, "minmax-bone", &tf), "tf");
  /* Histograms once per volume, occupancy once per transfer function: they
   * let the renderer skip empty space. The occupancy reads the histograms,
   * so they live as long as it does. */
  if (err == 0)
    err = check(ctx, rp_histograms_build(ctx, vol, &hist), "histograms");
  if (err == 0)
    err = check(ctx, rp_occupancy_build(ctx, hist, tf, &occ), "occupancy");
  if (err == 0) {
    err = rp_device_create(ctx, &dd, &dev);
    if (err == RP_ENODEV) { /* no driver: the scalar reference still works */
      dd.backend = "reference";
      err = rp_device_create(ctx, &dd, &dev);
    }
    check(ctx, err, "device");
  }
  /* The device keeps its own copies: vol and tf could be freed now. */
  if (err == 0)
    err = check(ctx, rp_device_set_volume(dev, vol), "upload volume");
  if (err == 0)
    err = check(ctx, rp_device_set_tf(dev, tf, occ), "upload tf");
  if (err == 0) {
    rp_camera_orbit(&cam, vol, 30.0f, 20.0f, 2.5f);
    rd.width = rd.height = 256;
    rd.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
    rgba = malloc((size_t)rd.width * rd.height * 4);
    err = rgba == NULL ? RP_ENOMEM : 0;
  }
  if (err == 0)
    err = check(ctx, rp_device_render(dev, &cam, &rd, NULL, rgba, NULL),
                "render");
  if (err == 0)
    err = check(ctx, rp_write_png(ctx, out, rgba, rd.width, rd.height,
                                  NULL), out);
  if (err == 0) {
    rp_device_get_caps(dev, &caps);
    printf("wrote %s on %s (%s), %.2f ms device time\n", out, caps.backend,
           caps.device, rp_device_last_time_ns(dev) * 1e-6);
  }
  free(rgba);
  rp_device_destroy(dev);
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(hist);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
  return err == 0 ? 0 : 1;
}
