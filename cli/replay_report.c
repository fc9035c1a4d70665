/* raypace replay's report (replay.h): what the recorded frames say,
 * per controller (DESIGN section 10), the goals of M4 as ratios within
 * the run, and the outputs: a table and goal line or JSON, per-frame CSV,
 * the still frame's CSV and gnuplot plots. */
#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "replay.h"

/* The smoothing factors of the EWMA predictors tried on the still
 * frame's times. */
#define NOISE_EWMAS 4
static const double NOISE_ALPHAS[NOISE_EWMAS] = {0.1, 0.2, 0.3, 0.5};

/* The spread of n frame times `ms` of the still frame, in segments
 * `seg` (noise_floor; its rho is kept). Within a segment, every
 * predictor is scored on its frames after the first, each from the
 * frames before it; the EWMAs start at the segment's first frame.
 * `work` holds n doubles. */
void replay_noise_stats(const double *ms, const uint32_t *seg, uint32_t n,
                        double *work, noise_floor *out) {
  double se = 0.0, se_last = 0.0, se_ew[NOISE_EWMAS] = {0};
  double ew[NOISE_EWMAS], best;
  uint32_t i, j, a, scored = 0;
  double rho = out->rho;
  memset(out, 0, sizeof *out);
  out->rho = rho;
  for (i = 0; i < n; i = j) {
    double lmed;
    for (j = i; j < n && seg[j] == seg[i]; j++)
      work[j - i] = ms[j];
    lmed = log(cli_median(work, (int)(j - i)));
    out->max_over = fmax(out->max_over, work[j - i - 1] / exp(lmed) - 1);
    out->segments++;
    for (a = 0; a < NOISE_EWMAS; a++)
      ew[a] = log(ms[i]);
    for (; i + 1 < j; i++) {
      double l = log(ms[i + 1]), e;
      se += (l - lmed) * (l - lmed);
      e = l - log(ms[i]);
      se_last += e * e;
      for (a = 0; a < NOISE_EWMAS; a++) {
        e = l - ew[a];
        se_ew[a] += e * e;
        ew[a] += NOISE_ALPHAS[a] * e;
      }
      scored++;
    }
  }
  memcpy(work, ms, n * sizeof *work);
  out->median_ms = n > 0 ? cli_median(work, (int)n) : 0.0;
  if (scored == 0)
    return;
  out->frames = n;
  out->sd = sqrt(se / scored);
  out->sd_last = sqrt(se_last / scored);
  best = fmin(se, se_last);
  for (a = 0; a < NOISE_EWMAS; a++)
    best = fmin(best, se_ew[a]);
  out->sd_best = sqrt(best / scored);
}

/* Writes --noise-csv. */
static int write_noise_csv(const replay_result *r) {
  FILE *f = fopen(r->o->noise_csv, "w");
  uint32_t i;
  int bad;
  if (f == NULL) {
    fprintf(stderr, "raypace replay: --noise-csv %s: cannot open for "
                    "writing\n", r->o->noise_csv);
    return 1;
  }
  fprintf(f, "frame,segment,density,measured_ms\n");
  for (i = 0; i < r->frames; i++)
    fprintf(f, "%u,%u,%.5f,%.6f\n", i, r->still_seg[i], r->noise.rho,
            r->still_ms[i]);
  bad = ferror(f);
  if (fclose(f) != 0 || bad) {
    fprintf(stderr, "raypace replay: --noise-csv %s: write failed\n",
            r->o->noise_csv);
    return 1;
  }
  return 0;
}

/* ---- Event classes ------------------------------------------------------ */

static const char *const CLASS_NAMES[REPLAY_CLASSES] = {
    "smooth", "tf_switch", "camera_cut", "effect_toggle", "target_change"};

const char *replay_class_name(int c) {
  return c >= 0 && c < REPLAY_CLASSES ? CLASS_NAMES[c] : "?";
}

uint32_t replay_frame_events(const rp_sequence_state *st) {
  if (st->frame == 0)
    return 0;
  return (st->tf_changed ? REPLAY_EV_TF : 0u) |
         (st->camera_cut ? REPLAY_EV_CUT : 0u) |
         (st->effects_changed ? REPLAY_EV_EFFECTS : 0u) |
         (st->target_changed ? REPLAY_EV_TARGET : 0u);
}

uint32_t replay_frame_classes(const frame_row *rows, uint32_t i) {
  uint32_t ev = 0, j = i > REPLAY_CLASS_AFTER ? i - REPLAY_CLASS_AFTER : 0;
  for (; j <= i; j++)
    ev |= rows[j].events;
  return ev;
}

/* A mask of events as a CSV field: their classes' names joined by '+',
 * or `none`. */
static void class_field(FILE *f, uint32_t mask, const char *none) {
  int c, any = 0;
  if (mask == 0) {
    fputs(none, f);
    return;
  }
  for (c = 1; c < REPLAY_CLASSES; c++)
    if (mask & (1u << (c - 1))) {
      fprintf(f, "%s%s", any ? "+" : "", CLASS_NAMES[c]);
      any = 1;
    }
}

/* Every class's figures over n rows; `work` holds n doubles. */
static void summarise_classes(const frame_row *rows, uint32_t n,
                              double *work, class_stats *out) {
  int c;
  for (c = 0; c < REPLAY_CLASSES; c++) {
    class_stats *cs = &out[c];
    uint32_t i, miss = 0, over = 0;
    double dens = 0.0;
    memset(cs, 0, sizeof *cs);
    for (i = 0; i < n; i++) {
      const frame_row *w = &rows[i];
      uint32_t m = replay_frame_classes(rows, i);
      if (c == 0 ? m != 0 : (m & (1u << (c - 1))) == 0)
        continue;
      work[cs->frames++] = w->measured_ms / w->target_ms;
      miss += w->measured_ms > w->target_ms;
      over += w->measured_ms > 1.2 * w->target_ms;
      dens += w->rho;
    }
    if (cs->frames == 0) {
      cs->miss_rate = cs->share_over_1_2 = cs->mean_density = NAN;
      cs->p95 = cs->p99 = NAN;
      continue;
    }
    cs->miss_rate = (double)miss / cs->frames;
    cs->share_over_1_2 = (double)over / cs->frames;
    cs->mean_density = dens / cs->frames;
    cs->p95 = cli_quantile(work, (int)cs->frames, 0.95);
    cs->p99 = cli_quantile(work, (int)cs->frames, 0.99);
  }
}

int replay_summarise(rp_controller_kind kind, const frame_row *rows,
                     uint32_t n, double rho_max, summary *s) {
  uint32_t i, over = 0, late = 0, sig_n = 0, open_n = 0;
  double se_open = 0;
  double se = 0, se_rel = 0, pe = 0, sig = 0, dens = 0, ov = 0, oh = 0;
  double mt = 0, mm = 0, imb = 0, *work;
  memset(s, 0, sizeof(*s));
  s->kind = kind;
  s->frames = n;
  s->event_frame_max = NAN;
  for (i = 0; i < n; i++) {
    const frame_row *w = &rows[i];
    double d = w->measured_ms - w->target_ms, rel = d / w->target_ms;
    if ((w->events & (REPLAY_EV_TF | REPLAY_EV_CUT)) &&
        !(w->measured_ms / w->target_ms <= s->event_frame_max))
      s->event_frame_max = w->measured_ms / w->target_ms;
    se += d * d;
    se_rel += rel * rel;
    /* A frame at the top density that is still under the target had no
     * better choice: it is left out of rmse_open. */
    if (!(w->rho >= rho_max && d < 0.0)) {
      se_open += d * d;
      open_n++;
    }
    if (rel > ov)
      ov = rel;
    /* A switch's overshoot: on the frames of the tf_switch class. */
    if ((replay_frame_classes(rows, i) & REPLAY_EV_TF) &&
        rel > s->switch_over)
      s->switch_over = rel;
    over += w->measured_ms > 1.2 * w->target_ms;
    late += w->measured_ms > w->target_ms;
    dens += w->rho;
    /* The frame's prediction (what it had spent when the controller
     * decided, and the model's time for its last pass) against its
     * time. */
    d = w->predicted_ms - w->measured_ms;
    pe += d * d;
    if (i >= 30 && isfinite(w->sigma_ns) && w->sigma_ns > 0) {
      sig += fabs(w->sigma_pred_ns - w->sigma_ns) / w->sigma_ns;
      sig_n++;
    }
    oh += w->probe_ms;
    mt += w->target_ms;
    mm += w->measured_ms;
    imb += w->imbalance;
  }
  if (n == 0)
    return 0;
  s->rmse_ms = sqrt(se / n);
  s->rmse_rel = sqrt(se_rel / n);
  s->rmse_open_ms = open_n > 0 ? sqrt(se_open / open_n) : 0.0;
  s->max_over = ov;
  s->share_over_20 = (double)over / n;
  s->miss_rate = (double)late / n;
  s->mean_density = dens / n;
  s->pred_rmse_ms = sqrt(pe / n);
  s->sigma_err_30 = sig_n > 0 ? sig / sig_n : NAN;
  s->overhead_ms = oh / n;
  s->mean_target = mt / n;
  s->mean_ms = mm / n;
  s->mean_imbalance = imb / n;
  if ((work = malloc(n * sizeof *work)) == NULL)
    return RP_ENOMEM;
  summarise_classes(rows, n, work, s->classes);
  free(work);
  return 0;
}

/* ---- Output -------------------------------------------------------------- */

/* With `ndev` > 0 (--devices) each row ends in dev<i>_share,
 * dev<i>_busy_ms, dev<i>_raycast_ms, dev<i>_samples for every device and
 * the frame's imbalance, all of its last pass, and, after the AO and
 * upload columns, dev<i>_tail_share: the predicted cost of the tail
 * strips each device took. Then the render passes' time, the predicted
 * controller's margin, the model's novelty of the frame and --split's
 * three figures (NaN without). The
 * last two columns name the frame's own
 * events ("none" without) and the classes it counts in ("smooth"
 * without), joined by '+'. `what` names the option that asked for the
 * file in an error. */
static int write_csv(const char *path, const char *what,
                     const summary *sums, frame_row *const *rows, int nctl,
                     uint32_t n, uint32_t ndev) {
  FILE *f = fopen(path, "w");
  int k;
  uint32_t i, j;
  if (f == NULL) {
    fprintf(stderr, "raypace replay: %s: cannot write '%s': %s\n", what,
            path, strerror(errno));
    return 1;
  }
  fprintf(f, "controller,frame,target_ms,measured_ms,predicted_ms,"
             "delta_ms,passes,density,step,scale,samples_est,samples,"
             "sigma_pred_ns,sigma_ns,probe_ms,tf_switch");
  for (j = 0; j < ndev; j++)
    fprintf(f, ",dev%u_share,dev%u_busy_ms,dev%u_raycast_ms,dev%u_samples",
            j, j, j, j);
  /* Appended, so that the earlier columns keep their places. */
  fprintf(f, "%s,ao_ms,ao,upload_ms,upload_predicted_ms",
          ndev > 0 ? ",imbalance" : "");
  for (j = 0; j < ndev; j++)
    fprintf(f, ",dev%u_tail_share", j);
  fprintf(f, ",pass_predicted_ms,render_ms,margin,novelty,split_first_ms,"
             "split_ms,split_sd_ms,events,classes\n");
  for (k = 0; k < nctl; k++) {
    for (i = 0; i < n; i++) {
      const frame_row *w = &rows[k][i];
      fprintf(f, "%s,%u,%.4f,%.4f,%.4f,%.4f,%d,%.9g,%.9g,%.9g,%.0f,%llu,"
                 "%.4f,%.4f,%.4f,%d",
              rp_controller_name(sums[k].kind), w->frame, w->target_ms,
              w->measured_ms, w->predicted_ms,
              w->measured_ms - w->target_ms, w->passes, w->rho,
              (double)w->step, (double)w->scale, w->samples_est,
              (unsigned long long)w->samples, w->sigma_pred_ns, w->sigma_ns,
              w->probe_ms, (w->events & REPLAY_EV_TF) != 0);
      for (j = 0; j < ndev; j++)
        fprintf(f, ",%.9g,%.4f,%.4f,%llu", w->dev[j].share,
                w->dev[j].busy_ms, w->dev[j].raycast_ms,
                (unsigned long long)w->dev[j].samples);
      if (ndev > 0)
        fprintf(f, ",%.4f", w->imbalance);
      fprintf(f, ",%.4f,%d,%.4f,%.4f", w->ao_ms, w->ao, w->upload_ms,
              w->upload_pred_ms);
      for (j = 0; j < ndev; j++)
        fprintf(f, ",%.5f", w->dev[j].strip_share);
      fprintf(f, ",%.6f,%.6f,%.5f,%.4f,%.6f,%.6f,%.6f,",
              w->pass_predicted_ms, w->render_ms, w->margin, w->novelty,
              w->split_first_ms, w->split_ms, w->split_sd_ms);
      class_field(f, w->events, "none");
      fputc(',', f);
      class_field(f, replay_frame_classes(rows[k], i), CLASS_NAMES[0]);
      fputc('\n', f);
    }
  }
  return fclose(f) == 0 ? 0 : 1;
}

/* Frame times of every controller against the target (top) and their
 * densities (bottom), like seed 000 Fig. 5, drawn by gnuplot from the
 * CSV. */
static int write_plot(const char *png, const char *csv, const summary *sums,
                      int nctl, const char *title) {
  cli_plot plot;
  FILE *g;
  int k;
  if (cli_plot_open(&plot, "raypace replay") != 0)
    return 1;
  g = plot.g;
  fprintf(g, "set terminal pngcairo size 1200,900 noenhanced\n"
             "set output ");
  cli_gnuplot_string(g, png);
  fprintf(g, "\nset datafile separator ','\n"
             "set key outside right top\n"
             "set multiplot layout 2,1 title ");
  cli_gnuplot_string(g, title);
  fprintf(g, "\nset ylabel 'frame time (ms)'\nset grid\nplot ");
  cli_gnuplot_string(g, csv);
  fprintf(g, " skip 1 using 2:(strcol(1) eq '%s' ? $3 : 1/0) "
             "with lines lw 3 lc rgb 'black' title 'target'",
          rp_controller_name(sums[0].kind));
  for (k = 0; k < nctl; k++)
    fprintf(g, ", '' skip 1 using 2:(strcol(1) eq '%s' ? $4 : 1/0) "
               "with lines lw 1.5 lc rgb '%s' title '%s'",
            rp_controller_name(sums[k].kind),
            cli_controller_colour(sums[k].kind),
            rp_controller_name(sums[k].kind));
  fprintf(g, "\nset xlabel 'frame'\n"
             "set ylabel 'density (1 = base step, full size)'\n"
             "set logscale y\nplot ");
  for (k = 0; k < nctl; k++) {
    fprintf(g, "%s", k ? ", " : "");
    cli_gnuplot_string(g, csv);
    fprintf(g, " skip 1 using 2:(strcol(1) eq '%s' ? $8 : 1/0) "
               "with lines lw 1.5 lc rgb '%s' title '%s'",
            rp_controller_name(sums[k].kind),
            cli_controller_colour(sums[k].kind),
            rp_controller_name(sums[k].kind));
  }
  fprintf(g, "\nunset multiplot\n");
  return cli_plot_close(&plot, "raypace replay");
}

/* Device i's label: its spec, as --devices gave it. */
static void device_label(const rp_device_desc *d, const rp_fault_desc *f,
                         uint32_t i, char *buf, size_t size) {
  int n = snprintf(buf, size, "dev%u %s:%u", i, d->backend, d->index);
  if (n > 0 && (size_t)n < size && d->compute_units > 0)
    n += snprintf(buf + n, size - (size_t)n, ":cu=%u", d->compute_units);
  if (n > 0 && (size_t)n < size && f->slowdown > 0)
    n += snprintf(buf + n, size - (size_t)n, ":slow=%g", f->slowdown);
  if (n > 0 && (size_t)n < size && f->fail_at_render > 0)
    snprintf(buf + n, size - (size_t)n, ":fail=%u", f->fail_at_render);
}

/* Per-device busy times (left) and stacked shares (right) per frame, one
 * row of panels per controller, like seed 000 Fig. 8: --devices with
 * two or more devices. The CSV's device columns start at 17 (write_csv).
 */
static int write_device_plot(const char *png, const char *csv,
                             const summary *sums, int nctl,
                             const replay_result *r) {
  uint32_t n = r->o->ndevices, i;
  cli_plot plot;
  FILE *g;
  int k;
  if (cli_plot_open(&plot, "raypace replay") != 0)
    return 1;
  g = plot.g;
  fprintf(g, "set terminal pngcairo size 1400,%d noenhanced\n"
             "set output ", 120 + 260 * nctl);
  cli_gnuplot_string(g, png);
  fprintf(g, "\nset datafile separator ','\nset grid\n"
             "set key outside right top\n"
             "set multiplot layout %d,2 title ", nctl);
  cli_gnuplot_string(g, "per-device busy time and share per frame");
  fprintf(g, "\n");
  for (k = 0; k < nctl; k++) {
    const char *name = rp_controller_name(sums[k].kind);
    /* The lines are devices; the controller's colour is its titles'. */
    fprintf(g, "set title '%s: busy' textcolor rgb '%s'\nset ylabel 'ms'\n"
               "set yrange [*:*]\nplot ", name,
            cli_controller_colour(sums[k].kind));
    /* A frame the device had no region in is a gap, not a 0. */
    for (i = 0; i < n; i++) {
      char label[96];
      device_label(&r->o->devices[i], &r->o->device_ext[i].faults, i, label,
                   sizeof(label));
      fprintf(g, "%s", i ? ", " : "");
      cli_gnuplot_string(g, csv);
      fprintf(g, " skip 1 using 2:(strcol(1) eq '%s' && $%u > 0 ? $%u : "
                 "1/0) with linespoints pt 7 ps 0.4 lc %u title ",
              name, 20 + 4 * i, 18 + 4 * i, i + 1);
      cli_gnuplot_string(g, label);
    }
    fprintf(g, "\nset title '%s: shares' textcolor rgb '%s'\n"
               "set ylabel 'share'\nset yrange [0:1]\nplot ", name,
            cli_controller_colour(sums[k].kind));
    for (i = 0; i < n; i++) {
      uint32_t j;
      fprintf(g, "%s", i ? ", " : "");
      cli_gnuplot_string(g, csv);
      fprintf(g, " skip 1 using 2:(strcol(1) eq '%s' ? 0", name);
      for (j = 0; j < i; j++)
        fprintf(g, " + $%u", 17 + 4 * j);
      fprintf(g, " : 1/0):(0");
      for (j = 0; j <= i; j++)
        fprintf(g, " + $%u", 17 + 4 * j);
      fprintf(g, ") with filledcurves lc %u fs solid 0.6 title 'dev%u'",
              i + 1, i);
    }
    fprintf(g, "\n");
  }
  fprintf(g, "unset multiplot\n");
  return cli_plot_close(&plot, "raypace replay");
}

/* "classes": {"smooth": {...}, "tf_switch": {...}, ...}, every class,
 * with null figures where it has no frames. */
static void add_classes(cJSON *o, const summary *s) {
  cJSON *cl = cJSON_AddObjectToObject(o, "classes");
  int c;
  for (c = 0; c < REPLAY_CLASSES; c++) {
    const class_stats *cs = &s->classes[c];
    cJSON *e = cJSON_AddObjectToObject(cl, CLASS_NAMES[c]);
    cJSON_AddNumberToObject(e, "frames", cs->frames);
    cli_json_figure(e, "miss_rate", cs->miss_rate);
    cli_json_figure(e, "share_over_1_2", cs->share_over_1_2);
    cli_json_figure(e, "p95", cs->p95);
    cli_json_figure(e, "p99", cs->p99);
    cli_json_figure(e, "mean_density", cs->mean_density);
  }
}

/* "error_split": --split's figures (replay.h, error_split). */
static void add_split(cJSON *o, const error_split *e) {
  cJSON *x = cJSON_AddObjectToObject(o, "error_split");
  cJSON_AddNumberToObject(x, "frames", e->frames);
  cJSON_AddNumberToObject(x, "repeats", e->repeats);
  cli_json_figure(x, "pass_rms", e->pass_rms);
  cli_json_figure(x, "context_rms", e->context_rms);
  cli_json_figure(x, "switch_rms", e->switch_rms);
  cli_json_figure(x, "model_rms", e->model_rms);
  cli_json_figure(x, "noise_rms", e->noise_rms);
  cli_json_figure(x, "pass_mean", e->pass_mean);
  cli_json_figure(x, "context_mean", e->context_mean);
  cli_json_figure(x, "switch_mean", e->switch_mean);
  cli_json_figure(x, "model_mean", e->model_mean);
  cli_json_figure(x, "frame_rms", e->frame_rms);
  cli_json_figure(x, "outside_rms", e->outside_rms);
  cli_json_figure(x, "context_excess", e->context_excess);
  cli_json_figure(x, "switch_excess", e->switch_excess);
  cli_json_figure(x, "model_excess", e->model_excess);
  cli_json_figure(x, "pass_median", e->pass_med);
  cli_json_figure(x, "context_median", e->context_med);
  cli_json_figure(x, "switch_median", e->switch_med);
  cli_json_figure(x, "model_median", e->model_med);
  cli_json_figure(x, "noise_median", e->noise_med);
}

static void print_json(const replay_result *r, const summary *s) {
  cJSON *o = cJSON_CreateObject();
  char *text;
  cJSON_AddStringToObject(o, "controller", rp_controller_name(s->kind));
  cJSON_AddStringToObject(o, "sequence", rp_sequence_name(r->seq));
  cJSON_AddStringToObject(o, "space", rp_space_name(r->space.space));
  cJSON_AddNumberToObject(o, "frames", s->frames);
  cJSON_AddNumberToObject(o, "full_ms", r->full_ms);
  cJSON_AddNumberToObject(o, "mean_target_ms", s->mean_target);
  cJSON_AddNumberToObject(o, "mean_ms", s->mean_ms);
  cJSON_AddNumberToObject(o, "target_rmse_ms", s->rmse_ms);
  cJSON_AddNumberToObject(o, "target_rmse_rel", s->rmse_rel);
  cJSON_AddNumberToObject(o, "target_rmse_open_ms", s->rmse_open_ms);
  cJSON_AddNumberToObject(o, "max_overshoot", s->max_over);
  cJSON_AddNumberToObject(o, "switch_overshoot", s->switch_over);
  cli_json_figure(o, "event_frame_max", s->event_frame_max);
  cJSON_AddNumberToObject(o, "miss_rate", s->miss_rate);
  cJSON_AddNumberToObject(o, "share_over_1_2", s->share_over_20);
  cJSON_AddNumberToObject(o, "mean_density", s->mean_density);
  cJSON_AddNumberToObject(o, "prediction_rmse_ms", s->pred_rmse_ms);
  cli_json_figure(o, "sigma_error_after_30", s->sigma_err_30);
  cJSON_AddNumberToObject(o, "overhead_ms", s->overhead_ms);
  add_classes(o, s);
  if (s->split.frames > 0)
    add_split(o, &s->split);
  if (r->noise.frames > 0) {
    cJSON *n = cJSON_AddObjectToObject(o, "noise");
    cJSON_AddNumberToObject(n, "frames", r->noise.frames);
    cJSON_AddNumberToObject(n, "segments", r->noise.segments);
    cJSON_AddNumberToObject(n, "density", r->noise.rho);
    cJSON_AddNumberToObject(n, "median_ms", r->noise.median_ms);
    cJSON_AddNumberToObject(n, "sd", r->noise.sd);
    cJSON_AddNumberToObject(n, "sd_last", r->noise.sd_last);
    cJSON_AddNumberToObject(n, "sd_best", r->noise.sd_best);
    cJSON_AddNumberToObject(n, "max_overshoot", r->noise.max_over);
  }
  if (r->o->ndevices > 0) {
    cJSON *a = cJSON_AddArrayToObject(o, "devices");
    uint32_t i;
    for (i = 0; i < r->o->ndevices; i++) {
      cJSON_AddItemToArray(a, cJSON_CreateString(r->device_names[i]));
    }
    cJSON_AddNumberToObject(o, "devices_alive", s->devices_alive);
    cJSON_AddNumberToObject(o, "mean_imbalance", s->mean_imbalance);
  }
  text = cJSON_PrintUnformatted(o);
  if (text != NULL)
    printf("%s\n", text);
  free(text);
  cJSON_Delete(o);
}

static void print_table(const replay_result *r, const summary *sums, int nctl) {
  int k;
  printf("sequence %s, %u frames, %ux%u, space %s; no-adaptation frame "
         "%.1f ms\n", rp_sequence_name(r->seq), r->frames, r->o->width,
         r->o->height, rp_space_name(r->space.space), r->full_ms);
  if (r->o->ndevices > 0)
    printf("devices %s (a group of %u)\n", r->o->devices_spec,
           r->o->ndevices);
  if (r->noise.frames > 0)
    printf("timing noise, a still frame after each round (%u frames, %u "
           "segment%s, density %.3f, median %.2f ms): sd %.1f%% about "
           "the median, %.1f%% frame to frame, %.1f%% the best "
           "predictor; slowest +%.1f%%\n",
           r->noise.frames, r->noise.segments,
           r->noise.segments == 1 ? "" : "s", r->noise.rho,
           r->noise.median_ms,
           100 * r->noise.sd, 100 * r->noise.sd_last,
           100 * r->noise.sd_best, 100 * r->noise.max_over);
  printf("%-11s %8s %8s %8s %8s %8s %7s %7s %8s %9s %8s %8s%s\n",
         "controller", "mean_ms", "target", "rmse_ms", "rmse_open",
         "rmse_rel", "max_ovr", "sw_ovr", ">1.2T", "density", "pred_rmse",
         "sigma_e30", r->o->ndevices > 0 ? "   imbal  alive" : "");
  for (k = 0; k < nctl; k++) {
    const summary *s = &sums[k];
    printf("%-11s %8.2f %8.2f %8.2f %8.2f %8.3f %6.1f%% %6.1f%% %7.1f%% "
           "%9.4f %8.2f ", rp_controller_name(s->kind), s->mean_ms,
           s->mean_target, s->rmse_ms, s->rmse_open_ms, s->rmse_rel,
           100 * s->max_over, 100 * s->switch_over,
           100 * s->share_over_20, s->mean_density, s->pred_rmse_ms);
    /* NaN when the run had no 30 frames to measure it after. */
    if (isfinite(s->sigma_err_30))
      printf("%8.3f", s->sigma_err_30);
    else
      printf("%8s", "-");
    if (r->o->ndevices > 0)
      printf(" %7.3f %6u", s->mean_imbalance, s->devices_alive);
    printf("\n");
  }
}

/* --split's section: each term's rms and mean as a share of the
 * target, and its mean square as a share of the pass error's. */
static void print_split(const summary *sums, int nctl) {
  const error_split *e = NULL;
  int k;
  for (k = 0; k < nctl; k++)
    if (sums[k].split.frames > 0)
      e = &sums[k].split;
  if (e == NULL)
    return;
  printf("\nwhere predicted's error comes from (--split: %u frames, %u "
         "repeats each; share of the target):\n"
         "%-10s %8s %8s %8s %8s %8s\n", e->frames, e->repeats, "term",
         "rms", "mean", "ms_share", ">noise", "median");
  {
    const char *names[] = {"pass", "context", "switching", "model"};
    const double rms[] = {e->pass_rms, e->context_rms, e->switch_rms,
                          e->model_rms};
    const double mean[] = {e->pass_mean, e->context_mean, e->switch_mean,
                           e->model_mean};
    const double beyond[] = {NAN, e->context_excess, e->switch_excess,
                             e->model_excess};
    const double med[] = {e->pass_med, e->context_med, e->switch_med,
                          e->model_med};
    int i;
    for (i = 0; i < 4; i++)
      printf("%-10s %8.4f %+8.4f %8.3f %8.4f %8.4f\n", names[i], rms[i],
             mean[i], rms[i] * rms[i] / (e->pass_rms * e->pass_rms),
             beyond[i], med[i]);
  }
  printf("%-10s %8.4f %35.4f\n%-10s %8.4f\n%-10s %8.4f\n", "noise",
         e->noise_rms, e->noise_med, "frame", e->frame_rms, "outside",
         e->outside_rms);
}

/* The per-class section after the table: a row per class with frames
 * and controller played. */
static void print_classes(const summary *sums, int nctl) {
  int c, k;
  printf("per event class (an event's frame and the %d after it; a frame "
         "near several events counts in each; smooth: near none):\n",
         REPLAY_CLASS_AFTER);
  printf("%-14s %6s  %-11s %6s %7s %7s %7s %9s\n", "class", "frames",
         "controller", "miss", ">1.2T", "p95 t/T", "p99 t/T", "density");
  for (c = 0; c < REPLAY_CLASSES; c++) {
    for (k = 0; k < nctl; k++) {
      const class_stats *cs = &sums[k].classes[c];
      if (cs->frames == 0)
        continue;
      printf("%-14s %6u  %-11s %5.1f%% %6.1f%% %7.3f %7.3f %9.4f\n",
             CLASS_NAMES[c], cs->frames, rp_controller_name(sums[k].kind),
             100 * cs->miss_rate, 100 * cs->share_over_1_2, cs->p95,
             cs->p99, cs->mean_density);
    }
  }
}

/* The reactive rules the predicted controller's RMSE is held against. */
static int is_reactive(rp_controller_kind k) {
  return k == RP_CONTROL_LAST_FRAME || k == RP_CONTROL_VTK ||
         k == RP_CONTROL_UE5 || k == RP_CONTROL_VALVE;
}

/* Every figure unknown: what a run that ends early reports. */
void replay_goals_clear(cli_pacing_goals *g) {
  g->ratio = g->ratio_open = g->ratio_noise = NAN;
  g->max_over = g->switch_over = NAN;
  g->density_two_pass = g->density_last_frame = NAN;
  g->noise_sd_best = g->noise_max_over = NAN;
  g->full_ms = NAN;
  g->late = g->over_1_2 = g->event_frame_max = NAN;
}

/* The goals as ratios within this run (cli_pacing_goals): NaN
 * where the controllers a figure compares were not played. */
void replay_goals(const replay_result *r, const summary *sums, int nctl,
                          cli_pacing_goals *g) {
  const summary *by[RP_CONTROL_COUNT] = {0};
  const summary *p;
  double best = INFINITY, best_open = INFINITY;
  int k;
  replay_goals_clear(g);
  g->full_ms = r->full_ms;
  for (k = 0; k < nctl; k++)
    by[sums[k].kind] = &sums[k];
  if (r->noise.frames > 0) {
    g->noise_sd_best = r->noise.sd_best;
    g->noise_max_over = r->noise.max_over;
  }
  if ((p = by[RP_CONTROL_PREDICTED]) == NULL)
    return;
  for (k = 0; k < RP_CONTROL_COUNT; k++) {
    if (!is_reactive((rp_controller_kind)k))
      continue;
    if (by[k] != NULL && by[k]->rmse_ms < best)
      best = by[k]->rmse_ms;
    if (by[k] != NULL && by[k]->rmse_open_ms < best_open)
      best_open = by[k]->rmse_open_ms;
  }
  if (isfinite(best) && best > 0)
    g->ratio = p->rmse_ms / best;
  if (isfinite(best_open) && best_open > 0) {
    g->ratio_open = p->rmse_open_ms / best_open;
    /* A model with no error but the machine's own would miss each
     * target by about noise.sd_best of it: about where the ratio lands
     * from the noise alone (an estimate from another frame, not a
     * bound). */
    if (r->noise.frames > 0)
      g->ratio_noise = r->noise.sd_best * p->mean_target / best_open;
  }
  g->max_over = p->max_over;
  g->switch_over = p->switch_over;
  g->late = p->miss_rate;
  g->over_1_2 = p->share_over_20;
  g->event_frame_max = p->event_frame_max;
  if (by[RP_CONTROL_TWO_PASS] != NULL)
    g->density_two_pass =
        p->mean_density / by[RP_CONTROL_TWO_PASS]->mean_density;
  if (by[RP_CONTROL_LAST_FRAME] != NULL)
    g->density_last_frame =
        p->mean_density / by[RP_CONTROL_LAST_FRAME]->mean_density;
}

/* The goals' line, when the predicted controller was played. */
static void print_goals(const replay_result *r, const summary *sums, int nctl) {
  cli_pacing_goals g;
  int k, played = 0, reactive = 0;
  for (k = 0; k < nctl; k++) {
    played |= sums[k].kind == RP_CONTROL_PREDICTED;
    reactive |= is_reactive(sums[k].kind);
  }
  if (!played)
    return;
  replay_goals(r, sums, nctl, &g);
  /* With no reactive rule played (one controller) there is nothing to
   * hold the RMSE against: say so rather than print a NaN. */
  if (!reactive)
    printf("goals: predicted rmse / best reactive: no reactive "
           "controller played (--controller all)");
  else {
    printf("goals: predicted rmse / best reactive = ");
    if (isfinite(g.ratio))
      printf("%.3f", g.ratio);
    else
      printf("-");
    printf(" (<= %g), reachable frames only ", CLI_GOAL_RATIO);
    if (isfinite(g.ratio_open))
      printf("%.3f", g.ratio_open);
    else
      printf("- (none)");
    if (isfinite(g.ratio_noise))
      printf(" (%.3f from timing noise alone)", g.ratio_noise);
  }
  printf("; max overshoot %.1f%% (<= %g%%), on TF switches %.1f%%",
         100 * g.max_over, 100 * CLI_GOAL_OVERSHOOT, 100 * g.switch_over);
  if (isfinite(g.density_two_pass))
    printf("; density / two-pass = %.2f (>= %g)", g.density_two_pass,
           CLI_GOAL_TWO_PASS);
  if (isfinite(g.density_last_frame))
    printf("; density / last-frame = %.2f (>= %g)", g.density_last_frame,
           CLI_GOAL_LAST_FRAME);
  printf("\n");
}


int replay_report(const replay_result *r, const summary *sums,
                  frame_row *const *rows, int nctl) {
  const replay_opts *o = r->o;
  char csv_tmp[4096] = "";
  const char *csv;
  int k;
  if (o->noise_csv != NULL && r->still_ms == NULL)
    fprintf(stderr, "raypace replay: --noise-csv %s not written: no "
                    "still frame with one controller, or when the "
                    "controllers play one after another (--devices, "
                    "--budget-mb, a backend with one device)\n",
            o->noise_csv);
  else if (o->noise_csv != NULL && write_noise_csv(r) != 0)
    return 1;
  if (o->json) {
    for (k = 0; k < nctl; k++)
      print_json(r, &sums[k]);
  } else {
    print_table(r, sums, nctl);
    print_goals(r, sums, nctl);
    print_split(sums, nctl);
    print_classes(sums, nctl);
  }
  /* Without --csv the plot's data goes to PLOT.csv, removed after. */
  if (o->plot != NULL && o->csv == NULL &&
      (size_t)snprintf(csv_tmp, sizeof(csv_tmp), "%s.csv", o->plot) >=
          sizeof(csv_tmp)) {
    fprintf(stderr, "raypace replay: --plot path too long\n");
    return 1;
  }
  csv = o->csv != NULL ? o->csv : o->plot != NULL ? csv_tmp : NULL;
  if (csv != NULL &&
      write_csv(csv, csv == csv_tmp ? "--plot (its data, removed after)"
                                    : "--csv",
                sums, rows, nctl, r->frames, o->ndevices) != 0)
    return 1;
  if (o->plot != NULL) {
    char title[256];
    snprintf(title, sizeof(title), "%s: %s, space %s",
             rp_sequence_name(r->seq), o->volume,
             rp_space_name(r->space.space));
    if (write_plot(o->plot, csv, sums, nctl, title) != 0)
      return 1;
    if (o->ndevices >= 2) {
      char dplot[4096];
      size_t len = strlen(o->plot);
      if (len >= 4 && strcmp(o->plot + len - 4, ".png") == 0)
        len -= 4;
      if ((size_t)snprintf(dplot, sizeof(dplot), "%.*s-devices.png",
                           (int)len, o->plot) >= sizeof(dplot)) {
        fprintf(stderr, "raypace replay: --plot path too long\n");
        return 1;
      }
      if (write_device_plot(dplot, csv, sums, nctl, r) != 0)
        return 1;
    }
    if (csv == csv_tmp)
      remove(csv_tmp);
  }
  return 0;
}
