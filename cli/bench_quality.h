/* raypace bench quality's shared parts: its options, its scene on a
 * device, and the timed render (bench.c), which the sampling comparison
 * (bench_sampling.c) uses too. */
#ifndef RP_CLI_BENCH_QUALITY_H
#define RP_CLI_BENCH_QUALITY_H

#include <cjson/cJSON.h>
#include <stdint.h>

#include "cli_util.h"
#include "raypace.h"

typedef struct quality_opts {
  const char *volume, *tf, *backend, *ref_backend, *csv, *plot;
  float orbit[3], ref_step, base_step;
  uint32_t width, height, device;
  int runs, shading, json, quick, sampling;
  uint32_t frames; /* --sampling: jittered frames averaged */
} quality_opts;

typedef struct bench {
  rp_context *ctx;
  rp_volume *vol;
  rp_tf *tf;
  rp_occupancy *occ;
  rp_camera cam;
  rp_render_desc rd; /* output size, effects and jitter; step and scale
                        vary */
  uint8_t *scaled, *out;
  double *times;
} bench;

/* Renders `runs` + 1 frames of b->rd at (step, scale), the first
 * untimed, each upscaled into b->out; *ms is the median time of the timed
 * ones (runs 0: the one frame's time, cold). */
int bench_measure(bench *b, rp_device *dev, float step, float scale,
                  int runs, uint32_t *sw, uint32_t *sh, double *ms);

/* Adds m's mse, psnr (null when +inf: JSON has no infinity) and ssim to
 * the object o. */
void bench_json_metrics(cJSON *o, const rp_image_metrics *m);

/* Opens gnuplot on a 960x640 PNG at `path` (pngcairo where it is built
 * in), titled, with PSNR over the median frame time as the axes; 0, or 1
 * with the error on stderr. */
int bench_plot_open(cli_plot *plot, const char *path, const char *title);

/* --sampling: plain against jittered sampling at several steps, against
 * the reference `ref`; the table (or JSON), --csv and --plot. */
int bench_sampling(bench *b, rp_device *dev, const quality_opts *o,
                   const rp_caps *caps, const char *ref_backend,
                   double ref_ms, const uint8_t *ref);

#endif
