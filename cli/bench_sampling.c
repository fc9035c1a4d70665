/* raypace bench quality --sampling: what jittered ray starts and
 * pre-integrated classification cost and buy (DESIGN section 14,
 * docs/sampling.md).
 *
 * At each step, full image scale, five ways to sample: plain (every ray
 * on the lattice from its box entry, RP_JITTER_OFF), jittered (one frame,
 * a per-pixel offset of the lattice), pre-integrated (RP_EFFECT_PREINT,
 * unjittered), both, and the mean of N jittered frames with the seeds a
 * runtime gives consecutive frames (what a still view accumulates to; its
 * time is N frames'). Each against the unjittered, plainly classified
 * fine reference: MSE, PSNR and SSIM, and the median frame time over the
 * runs, so that equal times can be compared across rows (the plot's x
 * axis). The settings alternate inside each step, so that a drift of the
 * machine shifts them alike. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_quality.h"

#define KINDS 5
#define MAX_STEPS 5
#define MEAN_KIND 4 /* the jittered mean: its frames' time */

static const float all_steps[MAX_STEPS] = {4.0f, 2.0f, 1.0f, 0.5f, 0.25f};
static const char *const kind_names[KINDS] = {
    "plain", "jittered", "preint", "jittered-preint", "jittered-mean"};

typedef struct sample_point {
  float step;
  int kind;       /* index into kind_names */
  double ms;      /* median frame time; the mean: N frames' */
  rp_image_metrics m;
} sample_point;

/* The mean of `frames` jittered frames at `step` into b->out, as the
 * runtime's consecutive frames would jitter them. */
static int jittered_mean(bench *b, rp_device *dev, float step,
                         uint32_t frames, float *acc) {
  size_t n = (size_t)b->rd.width * b->rd.height * 4, i;
  uint32_t f, sw, sh;
  double ms;
  memset(acc, 0, n * sizeof *acc);
  for (f = 0; f < frames; f++) {
    b->rd.jitter = RP_JITTER_ON;
    b->rd.jitter_seed = rp_jitter_frame_seed(0u, f);
    if (bench_measure(b, dev, step, 1.0f, 0, &sw, &sh, &ms) != 0)
      return 1;
    for (i = 0; i < n; i++)
      acc[i] += b->out[i];
  }
  for (i = 0; i < n; i++)
    b->out[i] = (uint8_t)floorf(acc[i] / (float)frames + 0.5f);
  return 0;
}

/* The kinds at one step; *n points appended to p. Pre-integration only
 * where the device has it (`preint`). */
static int measure_step(bench *b, rp_device *dev, const quality_opts *o,
                        float step, const uint8_t *ref, float *acc,
                        int preint, sample_point *p, int *n) {
  uint32_t sw, sh, effects = b->rd.effects;
  double jittered_ms = 0.0;
  int k, err;
  for (k = 0; k < KINDS; k++) {
    sample_point *q = &p[*n];
    int pre = k == 2 || k == 3;
    if (pre && !preint)
      continue;
    q->step = step;
    q->kind = k;
    if (k != MEAN_KIND) {
      b->rd.jitter = (k & 1) ? RP_JITTER_ON : RP_JITTER_OFF;
      b->rd.jitter_seed = 0; /* RP_JITTER_SEED */
      b->rd.effects = effects | (pre ? RP_EFFECT_PREINT : 0u);
      err = bench_measure(b, dev, step, 1.0f, o->runs, &sw, &sh, &q->ms);
      b->rd.effects = effects;
      if (err != 0)
        return 1;
      if (k == 1)
        jittered_ms = q->ms;
    } else {
      if (jittered_mean(b, dev, step, o->frames, acc) != 0)
        return 1;
      q->ms = jittered_ms * o->frames;
    }
    if ((err = rp_image_compare(b->ctx, b->out, ref, o->width, o->height,
                                &q->m)) != 0)
      return cli_error(b->ctx, "compare", err);
    (*n)++;
  }
  return 0;
}

static void print_table(const quality_opts *o, const rp_caps *caps,
                        const char *ref_backend, double ref_ms,
                        const sample_point *p, int n) {
  int i;
  printf("%s, %ux%u, tf %s%s, on %s '%s', median of %d\n", o->volume,
         o->width, o->height, o->tf, o->shading ? ", shading" : "",
         caps->backend, caps->device, o->runs);
  printf("reference: step %g, no jitter, on %s: %.2f ms (one cold frame)"
         "\njittered-mean: the mean of %u jittered frames (its time: "
         "theirs)\n\n",
         o->ref_step, ref_backend, ref_ms, o->frames);
  printf("%6s %-16s %10s %10s %7s %7s\n", "step", "sampling", "ms", "MSE",
         "PSNR", "SSIM");
  for (i = 0; i < n; i++)
    printf("%6g %-16s %10.2f %10.3f %7.2f %7.4f\n", p[i].step,
           kind_names[p[i].kind], p[i].ms, p[i].m.mse, p[i].m.psnr,
           p[i].m.ssim);
}

static int print_json(const quality_opts *o, const rp_caps *caps,
                      const char *ref_backend, double ref_ms,
                      const sample_point *p, int n) {
  cJSON *root = cJSON_CreateObject(), *rows;
  int i;
  cJSON_AddStringToObject(root, "volume", o->volume);
  cJSON_AddStringToObject(root, "backend", caps->backend);
  cJSON_AddStringToObject(root, "device", caps->device);
  cJSON_AddNumberToObject(root, "width", o->width);
  cJSON_AddNumberToObject(root, "height", o->height);
  cJSON_AddStringToObject(root, "tf", o->tf);
  cJSON_AddBoolToObject(root, "shading", o->shading);
  cJSON_AddNumberToObject(root, "runs", o->runs);
  cJSON_AddNumberToObject(root, "frames", o->frames);
  cJSON_AddNumberToObject(root, "ref_step", o->ref_step);
  cJSON_AddStringToObject(root, "ref_backend", ref_backend);
  cJSON_AddNumberToObject(root, "ref_ms", ref_ms);
  rows = cJSON_AddArrayToObject(root, "sampling");
  for (i = 0; i < n; i++) {
    cJSON *e = cJSON_CreateObject();
    cJSON_AddNumberToObject(e, "step", p[i].step);
    cJSON_AddStringToObject(e, "sampling", kind_names[p[i].kind]);
    cJSON_AddNumberToObject(e, "ms", p[i].ms);
    bench_json_metrics(e, &p[i].m);
    cJSON_AddItemToArray(rows, e);
  }
  return cli_print_json(root);
}

static int write_csv(const char *path, const sample_point *p, int n) {
  FILE *f = fopen(path, "w");
  int i;
  if (f == NULL) {
    fprintf(stderr, "raypace bench: --csv: cannot write %s\n", path);
    return 1;
  }
  fprintf(f, "sampling,step,ms,mse,psnr,ssim\n");
  for (i = 0; i < n; i++)
    fprintf(f, "%s,%g,%.6f,%.6f,%.6f,%.6f\n", kind_names[p[i].kind],
            p[i].step, p[i].ms, p[i].m.mse, p[i].m.psnr, p[i].m.ssim);
  if (fclose(f) != 0) {
    fprintf(stderr, "raypace bench: %s: write failed\n", path);
    return 1;
  }
  return 0;
}

/* PSNR over time, one line per way of sampling. */
static int write_plot(const quality_opts *o, const char *device,
                      const sample_point *p, int n) {
  cli_plot plot;
  FILE *g;
  char title[512];
  int k, i;
  snprintf(title, sizeof title,
           "%s, %ux%u, %s: PSNR against an unjittered step %g reference, "
           "steps 4 to 0.25",
           o->volume, o->width, o->height, device, o->ref_step);
  if (bench_plot_open(&plot, o->plot, title) != 0)
    return 1;
  g = plot.g;
  fprintf(g, "set logscale x\n");
  for (k = 0; k < KINDS; k++) {
    fprintf(g, "$k%d << EOD\n", k);
    for (i = 0; i < n; i++)
      if (p[i].kind == k && isfinite(p[i].m.psnr))
        fprintf(g, "%.6f %.6f\n", p[i].ms, p[i].m.psnr);
    fprintf(g, "EOD\n");
  }
  fprintf(g, "plot ");
  for (k = 0; k < KINDS; k++)
    fprintf(g, "%s$k%d using 1:2 with linespoints pt 7 title '%s'",
            k ? ", " : "", k, kind_names[k]);
  fprintf(g, "\n");
  return cli_plot_close(&plot, "raypace bench");
}

int bench_sampling(bench *b, rp_device *dev, const quality_opts *o,
                   const rp_caps *caps, const char *ref_backend,
                   double ref_ms, const uint8_t *ref) {
  sample_point pts[MAX_STEPS * KINDS];
  int steps = o->quick ? 2 : MAX_STEPS, s, n = 0, rc = 0;
  int preint = (caps->effects & RP_EFFECT_PREINT) != 0;
  float *acc = malloc((size_t)o->width * o->height * 4 * sizeof *acc);
  if (acc == NULL) {
    fprintf(stderr, "raypace bench: out of memory\n");
    return 1;
  }
  if (!preint && !o->json)
    printf("(%s has no RP_EFFECT_PREINT: its rows are left out)\n",
           caps->backend);
  for (s = 0; s < steps; s++)
    if (measure_step(b, dev, o, all_steps[s], ref, acc, preint, pts,
                     &n) != 0) {
      free(acc);
      return 1;
    }
  free(acc);
  if (o->json)
    rc = print_json(o, caps, ref_backend, ref_ms, pts, n);
  else
    print_table(o, caps, ref_backend, ref_ms, pts, n);
  if (o->csv != NULL) {
    if (write_csv(o->csv, pts, n) != 0)
      rc = 1;
    else if (!o->json)
      printf("\nwrote %s\n", o->csv);
  }
  if (o->plot != NULL) {
    if (write_plot(o, caps->backend, pts, n) != 0)
      rc = 1;
    else if (!o->json)
      printf("wrote %s\n", o->plot);
  }
  return rc;
}
