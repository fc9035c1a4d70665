/* Swapping backends under one context mid-sequence: the app must not
 * notice. A camera orbits through a sequence of frames; every few frames
 * the device is destroyed and the next backend that has a device here is
 * opened, the same scene uploaded, and the sequence goes on. Every frame
 * is held to the reference with the conformance tolerance, and the frame
 * just before and just after a swap are rendered with the same camera, so
 * a swap that changed the picture shows as a jump. Skips (77) when fewer
 * than two backends have a device. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "test_util.h"

#define W 48
#define H 36
#define FRAMES 12

static rp_context *ctx;
static const char *usable[8];
static int n_usable;

/* Pixels more than 2/255 apart in any channel; the largest difference. */
static int diff(const uint8_t *a, const uint8_t *b, int *over2) {
  int i, worst = 0;
  *over2 = 0;
  for (i = 0; i < W * H; i++) {
    int c, w = 0;
    for (c = 0; c < 4; c++) {
      int d = abs((int)a[4 * i + c] - (int)b[4 * i + c]);
      w = d > w ? d : w;
    }
    *over2 += w > 2;
    worst = w > worst ? w : worst;
  }
  return worst;
}

static rp_device *open_scene(const char *backend, const rp_volume *vol,
                             const rp_tf *tf, const rp_occupancy *occ) {
  rp_device_desc d = {0};
  rp_device *dev = NULL;
  d.backend = backend;
  assert_int_equal(rp_device_create(ctx, &d, &dev), 0);
  assert_int_equal(rp_device_set_volume(dev, vol), 0);
  assert_int_equal(rp_device_set_tf(dev, tf, occ), 0);
  return dev;
}

static void swap_mid_sequence(void **state) {
  rp_generate_desc g = {0};
  rp_volume *vol = NULL;
  rp_histograms *h = NULL;
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  rp_device *dev;
  rp_render_desc rd = {0};
  static uint8_t got[W * H * 4], want[W * H * 4], before[W * H * 4];
  int f, current = 0, total_over2 = 0, worst = 0, swaps = 0;
  (void)state;
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = 56, g.dims[1] = 48, g.dims[2] = 40;
  assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
  assert_int_equal(rp_histograms_build(ctx, vol, &h), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, h, tf, &occ), 0);
  rd.width = W, rd.height = H;
  rd.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  dev = open_scene(usable[0], vol, tf, occ);
  for (f = 0; f < FRAMES; f++) {
    rp_camera cam = {0};
    int over2, w;
    /* Frames 4k and 4k+1 share a camera: the swap happens between them. */
    rp_camera_orbit(&cam, vol, 15.0f * (f / 2), 20, 2.2f);
    if (f > 0 && f % 4 == 1) {
      memcpy(before, got, sizeof got);
      rp_device_destroy(dev);
      current = (current + 1) % n_usable;
      dev = open_scene(usable[current], vol, tf, occ);
      swaps++;
    }
    assert_int_equal(rp_device_render(dev, &cam, &rd, NULL, got, NULL), 0);
    assert_int_equal(
        rp_render_reference(ctx, vol, tf, occ, NULL, &cam, &rd, want, NULL), 0);
    w = diff(got, want, &over2);
    total_over2 += over2;
    worst = w > worst ? w : worst;
    if (w > 8)
      fail_msg("frame %d on %s: a pixel %d/255 off the reference", f,
               usable[current], w);
    if (f % 4 == 1) {
      w = diff(got, before, &over2);
      if (w > 8 || over2 > W * H / 1000)
        fail_msg("frame %d: the swap to %s changed the picture (%d pixels "
                 "over 2/255, worst %d)", f, usable[current], over2, w);
    }
  }
  print_message("swap: %d swaps over %d backends, %d of %d pixels over "
                "2/255, worst %d/255\n", swaps, n_usable, total_over2,
                FRAMES * W * H, worst);
  assert_true(total_over2 <= FRAMES * W * H / 1000);
  rp_device_destroy(dev);
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
  rp_histograms_destroy(h);
  rp_volume_destroy(vol);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(swap_mid_sequence),
  };
  const char *const *names;
  int rc;
  assert_int_equal(rp_context_create(NULL, &ctx), 0);
  for (names = rp_backend_names(); *names != NULL && n_usable < 8; names++) {
    uint32_t count = 0;
    if (rp_device_count(ctx, *names, &count) == 0 && count > 0)
      usable[n_usable++] = *names;
  }
  if (n_usable < 2) {
    printf("swap: fewer than two backends with a device here\n");
    rp_context_destroy(ctx);
    return 77;
  }
  rc = cmocka_run_group_tests(tests, NULL, NULL);
  rp_context_destroy(ctx);
  return rc;
}
