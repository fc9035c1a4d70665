/* Cost-model variants on recorded frames. `raypace replay --trace FILE`
 * writes what each controller's cost model learned from, one row per
 * pass; this program feeds each controller's rows, in order, to fresh
 * models built with other settings and scores every one-step-ahead
 * prediction (the frame predicted before it is learned, as in the
 * replay) against the frame time recorded. The frames are the same for
 * every variant, so the comparison carries none of the machine's noise
 * between runs; what it cannot show is how a controller would have
 * chosen differently under another model.
 *
 *   bench_costmodel --trace FILE [--ratios LIST] [--skip N]
 *
 * --ratios: noise_ratio values to compare (rp_cost_model_desc), "none"
 * for no prior; default none,0.01,0.05,0.2. --skip: rows per controller
 * not scored while the model warms up (default 30). --rows: every
 * prediction's parts (a, c0, sigma, Q) as CSV, for a closer look.
 *
 * Per controller and variant it prints the rms and the 95th percentile
 * of |ln(frame / t')|, and the stream's timing noise: over consecutive
 * rows rendered at the same step, scale and effects, the (robust)
 * standard deviation of the change in ln frame time over sqrt 2. A model that
 * knew each frame's cost exactly would still miss by about that much. */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_util.h"
#include "raypace.h"
#include "raypace_pace.h"

#define MAX_VARIANTS 8
#define MAX_STREAMS 16
#define LINE_MAX_LEN 4096
#define MAX_FIELDS 64

enum {
  C_CONTROLLER, C_WIDTH, C_HEIGHT, C_EFFECTS, C_JITTER, C_RAYS, C_RAYS_HIT,
  C_RAYS_ENDED, C_DEPTH_SUM, C_DEPTH_MAX, C_ERT_CUT, C_LIT_SPAN, C_LIT_ENDS,
  C_VIEW_X, C_VIEW_Y, C_VIEW_Z, C_PPV, C_DIAGONAL, C_STEP, C_SCALE,
  C_SAMPLES, C_RAYCAST_MS, C_FRAME_MS, C_COUNT
};

static const char *const columns[C_COUNT] = {
    "controller", "width", "height", "effects", "jitter", "rays", "rays_hit",
    "rays_ended", "depth_sum", "depth_max", "ert_cut", "lit_span",
    "lit_ends", "view_x", "view_y", "view_z", "pixels_per_voxel",
    "diagonal", "step", "scale", "samples", "raycast_ms", "frame_ms"};

typedef struct row {
  rp_frame_probe probe; /* the summary fields; no span map */
  float step, scale;
  uint64_t samples;
  double raycast_ms, frame_ms;
} row;

typedef struct stream {
  char name[32];
  row *rows;
  int n, cap;
} stream;

static void usage(FILE *f) {
  fprintf(f, "usage: bench_costmodel --trace FILE [--ratios LIST] "
             "[--skip N] [--rows OUT.csv]\n");
}

/* Splits `line` at commas in place; returns the field count, or max + 1
 * when there are more than max. */
static int split(char *line, char **field, int max) {
  int n = 0;
  char *p = line;
  line[strcspn(line, "\r\n")] = '\0';
  for (;;) {
    if (n == max)
      return max + 1;
    field[n++] = p;
    if ((p = strchr(p, ',')) == NULL)
      return n;
    *p++ = '\0';
  }
}

static int number(const char *s, double *out) {
  char *end;
  *out = strtod(s, &end);
  return end != s && *end == '\0' && isfinite(*out);
}

/* One line into buf: 1, 0 at the end of the file, -1 for a line that
 * does not fit. */
static int read_line(FILE *f, char *buf, int size) {
  size_t len;
  if (fgets(buf, size, f) == NULL)
    return 0;
  len = strlen(buf);
  if (len > 0 && buf[len - 1] != '\n' && !feof(f))
    return -1;
  return 1;
}

static stream *stream_of(stream *s, int *ns, const char *name) {
  int i;
  for (i = 0; i < *ns; i++)
    if (strcmp(s[i].name, name) == 0)
      return &s[i];
  if (*ns == MAX_STREAMS || strlen(name) >= sizeof s[0].name)
    return NULL;
  strcpy(s[*ns].name, name);
  return &s[(*ns)++];
}

/* Whether column c's value v is what the trace can hold there: counts
 * whole and in range, times and sizes >= 0 (frame time > 0: it is what
 * the predictions are scored against), the view any finite value. */
static int fits(int c, double v) {
  switch (c) {
  case C_WIDTH: case C_HEIGHT: case C_EFFECTS: case C_RAYS:
  case C_RAYS_HIT: case C_RAYS_ENDED:
    return v >= 0 && v <= 4294967295.0 && v == floor(v);
  case C_JITTER: return v == 0 || v == 1;
  case C_SAMPLES: return v >= 0 && v <= 9007199254740992.0 && v == floor(v);
  case C_VIEW_X: case C_VIEW_Y: case C_VIEW_Z: return 1;
  case C_FRAME_MS: return v > 0;
  default: return v >= 0;
  }
}

/* Reads the trace into one stream per controller, in file order. */
static int read_trace(const char *path, stream *s, int *ns) {
  FILE *f = fopen(path, "r");
  char line[LINE_MAX_LEN], *field[MAX_FIELDS];
  int col[C_COUNT], nf, n, i, c, got, lineno = 1;
  if (f == NULL) {
    fprintf(stderr, "bench_costmodel: cannot open '%s'\n", path);
    return -1;
  }
  if ((got = read_line(f, line, sizeof line)) <= 0) {
    fprintf(stderr, "bench_costmodel: '%s' is %s\n", path,
            got == 0 ? "empty" : "not a trace (first line too long)");
    goto fail;
  }
  if ((nf = split(line, field, MAX_FIELDS)) > MAX_FIELDS) {
    fprintf(stderr, "bench_costmodel: '%s': over %d columns\n", path,
            MAX_FIELDS);
    goto fail;
  }
  for (c = 0; c < C_COUNT; c++) {
    col[c] = -1;
    for (i = 0; i < nf; i++)
      if (strcmp(field[i], columns[c]) == 0)
        col[c] = i;
    if (col[c] < 0) {
      fprintf(stderr, "bench_costmodel: '%s' has no column '%s' (not a "
                      "raypace replay --trace file?)\n", path, columns[c]);
      goto fail;
    }
  }
  while ((got = read_line(f, line, sizeof line)) != 0) {
    double v[C_COUNT];
    stream *st;
    row *r;
    lineno++;
    if (got < 0) {
      fprintf(stderr, "bench_costmodel: %s:%d: line over %d characters\n",
              path, lineno, LINE_MAX_LEN - 2);
      goto fail;
    }
    if (line[strspn(line, " \t\r\n")] == '\0')
      continue; /* a blank line */
    if ((n = split(line, field, MAX_FIELDS)) != nf) {
      fprintf(stderr, "bench_costmodel: %s:%d: %s%d fields, the header has "
                      "%d\n", path, lineno, n > MAX_FIELDS ? "over " : "",
              n > MAX_FIELDS ? MAX_FIELDS : n, nf);
      goto fail;
    }
    for (c = 1; c < C_COUNT; c++)
      if (!number(field[col[c]], &v[c]) || !fits(c, v[c])) {
        fprintf(stderr, "bench_costmodel: %s:%d: '%s' = '%s' is out of "
                        "range\n", path, lineno, columns[c], field[col[c]]);
        goto fail;
      }
    if ((st = stream_of(s, ns, field[col[C_CONTROLLER]])) == NULL) {
      fprintf(stderr, "bench_costmodel: %s:%d: too many controllers or "
                      "a name too long\n", path, lineno);
      goto fail;
    }
    if (st->n == st->cap) {
      int cap = st->cap ? 2 * st->cap : 256;
      row *g = realloc(st->rows, sizeof(row) * (size_t)cap);
      if (g == NULL) {
        fprintf(stderr, "bench_costmodel: out of memory\n");
        goto fail;
      }
      st->rows = g;
      st->cap = cap;
    }
    r = &st->rows[st->n++];
    memset(r, 0, sizeof *r);
    r->probe.width = (uint32_t)v[C_WIDTH];
    r->probe.height = (uint32_t)v[C_HEIGHT];
    r->probe.effects = (uint32_t)v[C_EFFECTS];
    r->probe.jitter = (uint32_t)v[C_JITTER];
    r->probe.rays = (uint32_t)v[C_RAYS];
    r->probe.rays_hit = (uint32_t)v[C_RAYS_HIT];
    r->probe.rays_ended = (uint32_t)v[C_RAYS_ENDED];
    r->probe.depth_sum = v[C_DEPTH_SUM];
    r->probe.depth_max = v[C_DEPTH_MAX];
    r->probe.ert_cut = v[C_ERT_CUT];
    r->probe.lit_span = v[C_LIT_SPAN];
    r->probe.lit_ends = v[C_LIT_ENDS];
    r->probe.view[0] = v[C_VIEW_X];
    r->probe.view[1] = v[C_VIEW_Y];
    r->probe.view[2] = v[C_VIEW_Z];
    r->probe.pixels_per_voxel = v[C_PPV];
    r->probe.diagonal = v[C_DIAGONAL];
    r->step = (float)v[C_STEP];
    r->scale = (float)v[C_SCALE];
    r->samples = (uint64_t)v[C_SAMPLES];
    r->raycast_ms = v[C_RAYCAST_MS];
    r->frame_ms = v[C_FRAME_MS];
  }
  fclose(f);
  if (*ns == 0) {
    fprintf(stderr, "bench_costmodel: '%s' has no rows\n", path);
    return -1;
  }
  return 0;
fail:
  fclose(f);
  return -1;
}

/* Timing noise of a stream (above); NAN with under 10 pairs. The
 * deviation is 1.4826 times the median absolute one (equal for a normal
 * distribution), so that the jumps at a TF switch, at the same step and
 * scale, do not count as noise. */
static double noise_of(const stream *s) {
  double *d = malloc(sizeof(double) * (size_t)s->n), med, sd;
  int i, n = 0;
  if (d == NULL)
    return NAN;
  for (i = 1; i < s->n; i++) {
    const row *a = &s->rows[i - 1], *b = &s->rows[i];
    if (a->step == b->step && a->scale == b->scale &&
        a->probe.effects == b->probe.effects)
      d[n++] = log(b->frame_ms / a->frame_ms);
  }
  if (n < 10) {
    free(d);
    return NAN;
  }
  med = bench_median(d, n);
  for (i = 0; i < n; i++)
    d[i] = fabs(d[i] - med);
  sd = 1.4826 * bench_median(d, n) / sqrt(2.0);
  free(d);
  return sd;
}

/* Feeds the stream to a model with noise_ratio r; rms and 95th
 * percentile of |ln(frame / t')| over the rows past `skip`. */
static int score(rp_context *ctx, const stream *s, double r, int skip,
                 FILE *rows, double *rms, double *p95) {
  rp_cost_model_desc d;
  rp_cost_model *m = NULL;
  double *e = malloc(sizeof(double) * (size_t)s->n), sq = 0;
  int i, n = 0, err;
  if (e == NULL)
    return RP_ENOMEM;
  memset(&d, 0, sizeof d);
  d.noise_ratio = r;
  if ((err = rp_cost_model_create(ctx, &d, &m)) != 0) {
    free(e);
    return err;
  }
  for (i = 0; i < s->n; i++) {
    const row *w = &s->rows[i];
    rp_cost_estimate est;
    if ((err = rp_cost_predict(m, &w->probe, w->step, w->scale, &est)) !=
        0)
      break;
    if (rows != NULL)
      fprintf(rows, "%s,%g,%d,%g,%g,%llu,%.17g,%.17g,%.17g,%.17g,%.17g,"
              "%.17g,%.17g\n", s->name, r, i, (double)w->step,
              (double)w->scale, (unsigned long long)w->samples,
              w->raycast_ms, w->frame_ms, est.ms, est.launch_ms,
              est.c0_ms, est.sigma_ns, est.frame_factor);
    if (i >= skip && est.ms > 0 && w->frame_ms > 0) {
      e[n] = fabs(log(w->frame_ms / est.ms));
      sq += e[n] * e[n];
      n++;
    }
    if ((err = rp_cost_train(m, &w->probe, w->step, w->scale, w->samples,
                             w->raycast_ms, w->frame_ms)) != 0)
      break;
  }
  rp_cost_model_destroy(m);
  if (err == 0 && n > 0) {
    *rms = sqrt(sq / n);
    qsort(e, (size_t)n, sizeof *e, bench_cmp_double);
    *p95 = e[(int)(0.95 * (n - 1))];
  } else {
    *rms = *p95 = NAN;
  }
  free(e);
  return err;
}

static int parse_ratios(const char *list, double *r, int *nr) {
  char buf[256], *tok, *save = NULL;
  if (strlen(list) >= sizeof buf)
    return -1;
  strcpy(buf, list);
  *nr = 0;
  for (tok = strtok_r(buf, ",", &save); tok != NULL;
       tok = strtok_r(NULL, ",", &save)) {
    double v;
    if (*nr == MAX_VARIANTS)
      return -1;
    if (strcmp(tok, "none") == 0)
      v = -1;
    else if (!number(tok, &v) || !(v > 0))
      return -1;
    r[(*nr)++] = v;
  }
  return *nr > 0 ? 0 : -1;
}

int main(int argc, char **argv) {
  static const struct option opts[] = {
      {"trace", required_argument, 0, 't'},
      {"ratios", required_argument, 0, 'r'},
      {"skip", required_argument, 0, 's'},
      {"rows", required_argument, 0, 'o'},
      {"help", no_argument, 0, 'h'},
      {0, 0, 0, 0}};
  const char *trace = NULL, *rows_path = NULL;
  FILE *rows = NULL;
  double ratios[MAX_VARIANTS] = {-1, 0.01, 0.05, 0.2};
  int nr = 4, skip = 30, c, i, k, ns = 0, rc = 1;
  stream s[MAX_STREAMS];
  rp_context *ctx = NULL;
  memset(s, 0, sizeof s);
  while ((c = getopt_long(argc, argv, "h", opts, NULL)) != -1) {
    switch (c) {
    case 't': trace = optarg; break;
    case 'r':
      if (parse_ratios(optarg, ratios, &nr) != 0) {
        fprintf(stderr, "bench_costmodel: --ratios '%s': a list of "
                        "'none' and numbers > 0, at most %d\n", optarg,
                MAX_VARIANTS);
        return 2;
      }
      break;
    case 's': {
      double v;
      if (!number(optarg, &v) || v < 0 || v > 1e6) {
        fprintf(stderr, "bench_costmodel: bad --skip '%s'\n", optarg);
        return 2;
      }
      skip = (int)v;
      break;
    }
    case 'o': rows_path = optarg; break;
    case 'h': usage(stdout); return 0;
    default: usage(stderr); return 2;
    }
  }
  if (trace == NULL || optind != argc) {
    usage(stderr);
    return 2;
  }
  if (read_trace(trace, s, &ns) != 0)
    goto out;
  if (rows_path != NULL) {
    if ((rows = fopen(rows_path, "w")) == NULL) {
      fprintf(stderr, "bench_costmodel: cannot open '%s'\n", rows_path);
      goto out;
    }
    fputs("controller,ratio,row,step,scale,samples,raycast_ms,frame_ms,"
          "predicted_ms,launch_ms,c0_ms,sigma_ns,frame_factor\n", rows);
  }
  if (rp_context_create(NULL, &ctx) != 0) {
    fprintf(stderr, "bench_costmodel: no context\n");
    goto out;
  }
  printf("%-11s %5s %6s", "controller", "rows", "noise");
  for (k = 0; k < nr; k++) {
    char h[32];
    if (ratios[k] < 0)
      snprintf(h, sizeof h, "none");
    else
      snprintf(h, sizeof h, "r=%g", ratios[k]);
    printf(" %14s", h);
  }
  printf("\n%-11s %5s %6s", "", "", "");
  for (k = 0; k < nr; k++)
    printf(" %14s", "rms / p95");
  printf("\n");
  for (i = 0; i < ns; i++) {
    printf("%-11s %5d %6.3f", s[i].name, s[i].n, noise_of(&s[i]));
    for (k = 0; k < nr; k++) {
      double rms, p95;
      int err = score(ctx, &s[i], ratios[k], skip, rows, &rms, &p95);
      if (err != 0) {
        fprintf(stderr, "\nbench_costmodel: %s: %s\n", s[i].name,
                rp_last_error(ctx));
        goto out;
      }
      printf("    %.3f/%.3f", rms, p95);
    }
    printf("\n");
  }
  rc = 0;
out:
  for (i = 0; i < ns; i++)
    free(s[i].rows);
  rp_context_destroy(ctx);
  if (rows != NULL && fclose(rows) != 0) {
    fprintf(stderr, "bench_costmodel: writing '%s' failed\n", rows_path);
    rc = 1;
  }
  return rc;
}
