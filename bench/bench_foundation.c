/* M1 benchmark: block histogram build throughput, H-alpha + occupancy
 * update per transfer-function change, and reference raycaster samples/s.
 *
 *   bench_foundation [--quick] [--runs N] [--data DIR]
 *
 * Prints medians over N runs (default 7) and ratios measured in the same
 * run, since the machine is shared and noisy. --quick shrinks everything
 * so that the test suite can check the program still works. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bench_util.h"
#include "raypace.h"

static double now(void) { return bench_seconds(CLOCK_MONOTONIC); }

static void die(rp_context *ctx, const char *what, int err) {
  fprintf(stderr, "bench: %s: %s: %s\n", what, rp_strerror(err),
          rp_last_error(ctx));
  exit(1);
}

/* Median seconds of rp_histograms_build on a context with `threads`. */
static double time_h(const rp_volume *vol, int threads, int runs) {
  rp_context_desc cd = {0};
  rp_context *ctx = NULL;
  double t[64];
  int r, err;
  cd.threads = threads;
  if ((err = rp_context_create(&cd, &ctx)) != 0)
    die(ctx, "context", err);
  for (r = 0; r < runs; r++) {
    rp_histograms *h = NULL;
    double t0 = now();
    if ((err = rp_histograms_build(ctx, vol, &h)) != 0)
      die(ctx, "histograms", err);
    t[r] = now() - t0;
    rp_histograms_destroy(h);
  }
  rp_context_destroy(ctx);
  return bench_median(t, runs);
}

static void bench_volume(rp_context *ctx, const char *name, rp_volume *vol,
                         int runs, uint32_t image) {
  static const char *const tfs[] = {"minmax-bone", "minmax-soft", "mri", "opaque",
                                    "nearly-transparent", "transparent"};
  rp_volume_info in;
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  rp_tf *tf[6] = {0};
  double t[64], voxels, h_all, h_one;
  int r, i, err;
  rp_volume_get_info(vol, &in);
  voxels = (double)in.dims[0] * in.dims[1] * in.dims[2];
  h_all = time_h(vol, 0, runs);
  h_one = time_h(vol, 1, runs);
  printf("%-22s H build: %8.1f ms  %7.1f M voxels/s (all cores)  "
         "%7.1f M voxels/s (1 thread)  speed-up %.2fx\n",
         name, h_all * 1e3, voxels / h_all / 1e6, voxels / h_one / 1e6,
         h_one / h_all);

  if ((err = rp_histograms_build(ctx, vol, &h)) != 0)
    die(ctx, "histograms", err);
  for (i = 0; i < 6; i++)
    if ((err = rp_tf_create_preset(ctx, tfs[i], &tf[i])) != 0)
      die(ctx, "tf", err);
  if ((err = rp_occupancy_build(ctx, h, tf[0], &occ)) != 0)
    die(ctx, "occupancy", err);
  for (r = 0; r < runs; r++) {
    double t0 = now();
    for (i = 0; i < 6; i++)
      rp_occupancy_update(occ, tf[(i + 1) % 6]);
    t[r] = (now() - t0) / 6;
  }
  printf("%-22s H-alpha + occupancy per TF change: %.3f ms (%u blocks)\n",
         name, bench_median(t, runs) * 1e3, rp_histograms_block_count(h));

  if (image > 0) {
    rp_camera cam = {0};
    rp_render_desc rd = {0};
    uint32_t tx, ty, k;
    uint8_t *rgba = malloc((size_t)image * image * 4);
    rp_tile_stats *tiles;
    double samples = 0;
    rp_tile_grid(image, image, &tx, &ty);
    tiles = malloc((size_t)tx * ty * sizeof *tiles);
    if (rgba == NULL || tiles == NULL)
      die(ctx, "malloc", RP_ENOMEM);
    rp_occupancy_update(occ, tf[0]);
    rp_camera_orbit(&cam, vol, 30, 20, 2.0f);
    rd.width = rd.height = image;
    rd.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP;
    /* The reference is slow by design; three runs give a median. */
    for (r = 0; r < 3; r++) {
      double t0 = now();
      if ((err = rp_render_reference(ctx, vol, tf[0], occ, NULL, &cam, &rd, rgba,
                                     tiles)) != 0)
        die(ctx, "render", err);
      t[r] = now() - t0;
    }
    for (k = 0; k < tx * ty; k++)
      samples += tiles[k].samples;
    printf("%-22s reference raycast %ux%u minmax-bone ERT+skip: %.0f ms, "
           "%.2f M samples/s (1 thread)\n",
           name, image, image, bench_median(t, 3) * 1e3,
           samples / bench_median(t, 3) / 1e6);
    free(rgba);
    free(tiles);
  }
  rp_occupancy_destroy(occ);
  for (i = 0; i < 6; i++)
    rp_tf_destroy(tf[i]);
  rp_histograms_destroy(h);
}

static void print_machine(void) {
  char line[256], model[256] = "unknown";
  FILE *f = fopen("/proc/cpuinfo", "r");
  while (f != NULL && fgets(line, sizeof line, f) != NULL) {
    if (strncmp(line, "model name", 10) == 0) {
      char *p = strchr(line, ':');
      if (p != NULL) {
        snprintf(model, sizeof model, "%s", p + 2);
        model[strcspn(model, "\n")] = '\0';
      }
      break;
    }
  }
  if (f != NULL)
    fclose(f);
  printf("machine: %s, %ld cores online; raypace %s\n", model,
         sysconf(_SC_NPROCESSORS_ONLN), rp_version_string());
}

int main(int argc, char **argv) {
  const char *data = getenv("RP_SHARED_DATA");
  int runs = 7, quick = 0, i, err;
  rp_context *ctx = NULL;
  rp_generate_desc g = {0};
  rp_volume *vol = NULL;
  char path[1024];
  for (i = 1; i < argc; i++) {
    if (strcmp(argv[i], "--quick") == 0)
      quick = 1;
    else if (strcmp(argv[i], "--runs") == 0 && i + 1 < argc)
      runs = atoi(argv[++i]);
    else if (strcmp(argv[i], "--data") == 0 && i + 1 < argc)
      data = argv[++i];
    else {
      fprintf(stderr, "usage: bench_foundation [--quick] [--runs N] "
                      "[--data DIR]\n");
      return 2;
    }
  }
  if (runs < 1 || runs > 64)
    runs = 7;
  if (quick)
    runs = 1;
  print_machine();
  if ((err = rp_context_create(NULL, &ctx)) != 0)
    return 1;

  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = quick ? 40 : 512;
  if ((err = rp_volume_generate(ctx, &g, &vol)) != 0)
    die(ctx, "generate", err);
  bench_volume(ctx, quick ? "phantom 40^3" : "phantom 512^3", vol, runs, 0);
  rp_volume_destroy(vol);
  vol = NULL;

  if (data != NULL && !quick) {
    snprintf(path, sizeof path, "%s/bonsai/bonsai.txt", data);
    if (rp_volume_load(ctx, path, &vol) == 0) {
      bench_volume(ctx, "bonsai 256^3", vol, runs, 512);
      rp_volume_destroy(vol);
      vol = NULL;
    } else {
      printf("bonsai not loaded (%s): skipped\n", rp_last_error(ctx));
    }
  }
  g.dims[0] = g.dims[1] = g.dims[2] = quick ? 24 : 256;
  if ((err = rp_volume_generate(ctx, &g, &vol)) != 0)
    die(ctx, "generate", err);
  bench_volume(ctx, quick ? "phantom 24^3" : "phantom 256^3", vol, runs,
               quick ? 16 : 512);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
  return 0;
}
