/* bench_bricks: what rendering out of core costs (DESIGN section 9, M8).
 *
 * Per volume, one device renders 512^2 frames (shading, ERT, skipping)
 * holding the whole volume, then with a memory budget of 0.999 (bricked,
 * all visible bricks resident), 1/2, 1/4 and 1/8 of the volume (bricks
 * of --brick-size voxels, default 16). Two camera
 * paths:
 *   still   the same camera every frame: after the first, what stays
 *           resident decides whether anything is uploaded
 *   orbit   the camera turns 6 degrees per frame around the volume
 * Per budget and path: the median frame time over --frames frames (after
 * one warm-up frame), its ratio to the in-core median of the same run,
 * the share of the frame's device time spent uploading bricks, the
 * megabytes uploaded per frame, the parts a frame was cut into so that
 * each part's bricks fit the pool, and the pool's hit rate.
 *
 * usage: bench_bricks [--backend NAME] [--frames N] [--brick-size N]
 *                     [--size N] [--no-shading] [VOLUME ...]
 *        (default volumes: bonsai and engine from $RP_SHARED_DATA, else
 *        a generated 256^3 phantom) */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_util.h"
#include "raypace.h"

#define MAX_FRAMES 64

/* The frames' effects: shading, ERT and skipping (--no-shading: the last
 * two). */
static uint32_t effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;

typedef struct path_result {
  double median_ms, upload_share, mb_per_frame, parts, hit_rate;
} path_result;

/* Renders `frames` frames (plus one warm-up) of the path on dev. */
static int run_path(rp_device *dev, const rp_volume *vol, int orbit,
                    uint32_t frames, uint32_t size, path_result *out) {
  rp_render_desc d = {0};
  rp_brick_stats s0, s1;
  double ms[MAX_FRAMES], up_ns = 0, dev_ns = 0, bytes = 0, parts = 0;
  uint8_t *img = malloc((size_t)size * size * 4);
  uint32_t f;
  int err = 0;
  if (img == NULL)
    return RP_ENOMEM;
  d.width = d.height = size;
  d.effects = effects;
  for (f = 0; f <= frames && err == 0; f++) {
    rp_camera cam = {0};
    rp_brick_stats st;
    double t0;
    rp_camera_orbit(&cam, vol, orbit ? 30.0f + 6.0f * (float)f : 30.0f,
                    20.0f, 2.0f);
    if (f == 1)
      rp_device_get_brick_stats(dev, &s0);
    t0 = bench_seconds(CLOCK_MONOTONIC);
    err = rp_device_render(dev, &cam, &d, NULL, img, NULL);
    if (f == 0)
      continue; /* kernels built, pool filled: not measured */
    ms[f - 1] = (bench_seconds(CLOCK_MONOTONIC) - t0) * 1e3;
    rp_device_get_brick_stats(dev, &st);
    dev_ns += (double)rp_device_last_time_ns(dev);
    up_ns += (double)st.last_upload_ns;
    bytes += (double)st.last_upload_bytes;
    parts += st.out_of_core ? st.last_pieces : 1;
  }
  free(img);
  if (err != 0)
    return err;
  rp_device_get_brick_stats(dev, &s1);
  out->median_ms = bench_median(ms, (int)frames);
  out->upload_share = dev_ns > 0 ? up_ns / dev_ns : 0;
  out->mb_per_frame = bytes / frames / 1048576.0;
  out->parts = parts / frames;
  out->hit_rate = s1.hits + s1.misses > s0.hits + s0.misses
                      ? (double)(s1.hits - s0.hits) /
                            (double)(s1.hits + s1.misses - s0.hits -
                                     s0.misses)
                      : 1.0;
  return 0;
}

static int bench_volume(rp_context *ctx, const char *backend,
                        const char *name, rp_volume *vol, uint32_t frames,
                        uint32_t brick, uint32_t size) {
  /* 0.999: bricked, yet every visible brick fits at once (one part, no
   * uploads after the first frame): what sampling through the table
   * costs by itself. */
  static const double fractions[] = {0.0, 0.999, 0.5, 0.25, 0.125};
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  rp_tf *tf = NULL;
  rp_volume_info info;
  double in_core[2] = {0, 0}, bytes;
  size_t i;
  int err, path;
  rp_volume_get_info(vol, &info);
  bytes = (double)info.dims[0] * info.dims[1] * info.dims[2] *
          (info.type == RP_U8 ? 1 : info.type == RP_U16 ? 2 : 4);
  if ((err = rp_tf_create_preset(ctx, "minmax-bone", &tf)) != 0 ||
      (err = rp_histograms_build(ctx, vol, &h)) != 0 ||
      (err = rp_occupancy_build(ctx, h, tf, &occ)) != 0)
    goto out;
  printf("\n%s (%ux%ux%u, %.1f MB), %ux%u, bricks of %u^3, %s%s\n", name,
         info.dims[0], info.dims[1], info.dims[2],
         bytes / 1048576.0, size, size, brick, backend,
         (effects & RP_EFFECT_SHADING) ? "" : ", no shading");
  printf("%-8s %-6s %10s %8s %9s %9s %7s %8s\n", "budget", "path",
         "frame ms", "x core", "upload %", "MB/frame", "parts", "hits %");
  for (i = 0; i < sizeof fractions / sizeof fractions[0]; i++) {
    rp_device_desc dd = {0};
    rp_device *dev = NULL;
    dd.backend = backend;
    dd.brick_size = brick;
    dd.budget_bytes = (uint64_t)(fractions[i] * bytes);
    if ((err = rp_device_create(ctx, &dd, &dev)) != 0 ||
        (err = rp_device_set_volume(dev, vol)) != 0 ||
        (err = rp_device_set_tf(dev, tf, occ)) != 0) {
      rp_device_destroy(dev);
      goto out;
    }
    for (path = 0; path < 2; path++) {
      path_result r;
      char label[16];
      if (fractions[i] == 0.0)
        snprintf(label, sizeof label, "in core");
      else if (fractions[i] > 0.5)
        snprintf(label, sizeof label, "%.3f", fractions[i]);
      else
        snprintf(label, sizeof label, "1/%.0f", 1.0 / fractions[i]);
      if ((err = run_path(dev, vol, path, frames, size, &r)) != 0) {
        printf("%-8s %-6s failed: %s\n", label, path ? "orbit" : "still",
               rp_last_error(ctx));
        continue;
      }
      if (fractions[i] == 0.0)
        in_core[path] = r.median_ms;
      printf("%-8s %-6s %10.1f %8.2f %9.1f %9.2f %7.1f %8.1f\n", label,
             path ? "orbit" : "still", r.median_ms,
             in_core[path] > 0 ? r.median_ms / in_core[path] : 0.0,
             100.0 * r.upload_share, r.mb_per_frame, r.parts,
             100.0 * r.hit_rate);
    }
    rp_device_destroy(dev);
  }
  err = 0;
out:
  if (err != 0)
    fprintf(stderr, "bench_bricks: %s: %s\n", name, rp_last_error(ctx));
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
  return err;
}

int main(int argc, char **argv) {
  const char *backend = "opencl";
  uint32_t frames = 15, brick = 16, size = 512;
  const char *names[16];
  int nnames = 0, i, rc = 0;
  rp_context *ctx = NULL;
  for (i = 1; i < argc; i++) {
    if (strcmp(argv[i], "--backend") == 0 && i + 1 < argc)
      backend = argv[++i];
    else if (strcmp(argv[i], "--frames") == 0 && i + 1 < argc)
      frames = (uint32_t)atoi(argv[++i]);
    else if (strcmp(argv[i], "--brick-size") == 0 && i + 1 < argc)
      brick = (uint32_t)atoi(argv[++i]);
    else if (strcmp(argv[i], "--size") == 0 && i + 1 < argc)
      size = (uint32_t)atoi(argv[++i]);
    else if (strcmp(argv[i], "--no-shading") == 0)
      effects &= ~(uint32_t)RP_EFFECT_SHADING;
    else if (argv[i][0] != '-' && nnames < 16)
      names[nnames++] = argv[i];
    else {
      fprintf(stderr, "usage: bench_bricks [--backend NAME] [--frames N] "
                      "[--brick-size N] [--size N] [--no-shading] "
                      "[VOLUME ...]\n");
      return 2;
    }
  }
  if (frames < 1 || frames > MAX_FRAMES || size < 8 || size > 4096) {
    fprintf(stderr, "bench_bricks: --frames 1..%d, --size 8..4096\n",
            MAX_FRAMES);
    return 2;
  }
  if (rp_context_create(NULL, &ctx) != 0)
    return 1;
  if (nnames == 0) {
    const char *dir = getenv("RP_SHARED_DATA");
    static char paths[2][512];
    static const char *const sets[] = {"bonsai", "engine"};
    int k;
    for (k = 0; k < 2 && dir != NULL; k++) {
      FILE *f;
      snprintf(paths[k], sizeof paths[k], "%s/%s/%s.txt", dir, sets[k],
               sets[k]);
      if ((f = fopen(paths[k], "r")) != NULL) {
        fclose(f);
        names[nnames++] = paths[k];
      }
    }
  }
  if (nnames == 0) {
    rp_generate_desc g = {0};
    rp_volume *vol = NULL;
    g.kind = RP_GEN_PHANTOM;
    g.dims[0] = g.dims[1] = g.dims[2] = 256;
    if (rp_volume_generate(ctx, &g, &vol) != 0)
      rc = 1;
    else
      rc = bench_volume(ctx, backend, "phantom", vol, frames, brick, size)
               ? 1
               : 0;
    rp_volume_destroy(vol);
  }
  for (i = 0; i < nnames; i++) {
    rp_volume *vol = NULL;
    const char *base = strrchr(names[i], '/');
    if (rp_volume_load(ctx, names[i], &vol) != 0) {
      fprintf(stderr, "bench_bricks: %s: %s\n", names[i], rp_last_error(ctx));
      rc = 1;
      continue;
    }
    if (bench_volume(ctx, backend, base ? base + 1 : names[i], vol, frames,
                     brick, size) != 0)
      rc = 1;
    rp_volume_destroy(vol);
  }
  rp_context_destroy(ctx);
  return rc;
}
