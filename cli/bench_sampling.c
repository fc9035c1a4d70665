/* raypace bench quality --sampling: what jittered ray starts cost and buy
 * (DESIGN section 14, docs/sampling.md).
 *
 * At each step, full image scale, three ways to sample: plain (every ray
 * on the lattice from its box entry, RP_JITTER_OFF), jittered (one frame,
 * a per-pixel offset of the lattice), and the mean of N jittered frames
 * with the seeds a runtime gives consecutive frames (what a still view
 * accumulates to; its time is N frames'). Each against the unjittered
 * fine reference: MSE, PSNR and SSIM, and the median frame time over the
 * runs. The settings alternate inside each step, so that a drift of the
 * machine shifts plain and jittered alike. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_quality.h"

#define KINDS 3
#define MAX_STEPS 4

static const float all_steps[MAX_STEPS] = {2.0f, 1.0f, 0.5f, 0.25f};
static const char *const kind_names[KINDS] = {"plain", "jittered",
                                              "jittered-mean"};

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

static int measure_step(bench *b, rp_device *dev, const quality_opts *o,
                        float step, const uint8_t *ref, float *acc,
                        sample_point p[KINDS]) {
  uint32_t sw, sh;
  int k, err;
  for (k = 0; k < KINDS; k++) {
    p[k].step = step;
    p[k].kind = k;
    if (k < 2) {
      b->rd.jitter = k == 0 ? RP_JITTER_OFF : RP_JITTER_ON;
      b->rd.jitter_seed = 0; /* RP_JITTER_SEED */
      if (bench_measure(b, dev, step, 1.0f, o->runs, &sw, &sh, &p[k].ms) !=
          0)
        return 1;
    } else {
      if (jittered_mean(b, dev, step, o->frames, acc) != 0)
        return 1;
      p[k].ms = p[1].ms * o->frames;
    }
    if ((err = rp_image_compare(b->ctx, b->out, ref, o->width, o->height,
                                &p[k].m)) != 0)
      return cli_error(b->ctx, "compare", err);
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
  printf("%6s %-14s %10s %10s %7s %7s\n", "step", "sampling", "ms", "MSE",
         "PSNR", "SSIM");
  for (i = 0; i < n; i++)
    printf("%6g %-14s %10.2f %10.3f %7.2f %7.4f\n", p[i].step,
           kind_names[p[i].kind], p[i].ms, p[i].m.mse, p[i].m.psnr,
           p[i].m.ssim);
}

static int print_json(const quality_opts *o, const rp_caps *caps,
                      const char *ref_backend, double ref_ms,
                      const sample_point *p, int n) {
  cJSON *root = cJSON_CreateObject(), *rows;
  char *text;
  int i, ok;
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
  text = cJSON_Print(root);
  ok = text != NULL;
  if (ok)
    printf("%s\n", text);
  free(text);
  cJSON_Delete(root);
  return ok ? 0 : 1;
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
           "steps 2 to 0.25",
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
  int steps = o->quick ? 2 : MAX_STEPS, s, n = steps * KINDS, rc = 0;
  float *acc = malloc((size_t)o->width * o->height * 4 * sizeof *acc);
  if (acc == NULL) {
    fprintf(stderr, "raypace bench: out of memory\n");
    return 1;
  }
  for (s = 0; s < steps; s++)
    if (measure_step(b, dev, o, all_steps[s], ref, acc,
                     &pts[s * KINDS]) != 0) {
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
