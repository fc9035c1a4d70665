/* raypace replay --split R: where the predicted controller's error comes
 * from (M10; docs/pacing.md, "Where the error comes from").
 *
 * One more runtime (controller none) follows the predicted controller's
 * runtime frame by frame: right after that runtime renders a frame, this
 * one renders the same frame (the same events, at the density the
 * controller chose): once, as the controller's own frame was, right
 * after the frame before; then, for a recorded frame, R times more with
 * nothing changed but the camera posted again (see split_frame). All of
 * it within milliseconds of the controller's frame, so that the
 * machine's slower drifts (seconds) fall on every term alike. The
 * repeats measure the machine's own timing noise at fixed settings, and
 * their median is what the frame costs once settled. The controller's
 * frame, its first render here and the settled cost then split the
 * pass's error (replay.h, error_split). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "replay.h"

/* Sample standard deviation of n > 1 values. */
static double sd_of(const double *v, uint32_t n) {
  double m = 0.0, q = 0.0;
  uint32_t i;
  for (i = 0; i < n; i++)
    m += v[i];
  m /= n;
  for (i = 0; i < n; i++)
    q += (v[i] - m) * (v[i] - m);
  return sqrt(q / (n - 1));
}

int replay_split_open(replay *r) {
  memset(&r->split, 0, sizeof r->split);
  r->split.kind = RP_CONTROL_NONE;
  if ((r->split_t = malloc(r->o.split * sizeof *r->split_t)) == NULL)
    return cli_error(r->ctx, "--split", RP_ENOMEM);
  if (!r->o.quiet)
    fprintf(stderr, "replay: --split: each of predicted's frames again "
                    "on a runtime of its own, then %u times more\n",
            r->o.split);
  return replay_player_open(r, &r->split, 0);
}

void replay_split_close(replay *r) {
  replay_player_close(&r->split);
  free(r->split_t);
  r->split_t = NULL;
}

int replay_split_frame(replay *r, const player *p, uint32_t f,
                       frame_row *row) {
  player *s = &r->split;
  double *t = r->split_t;
  rp_sequence_state st;
  rp_camera cam;
  uint32_t j;
  int err, moved;
  if (row != NULL)
    row->split_first_ms = row->split_ms = row->split_sd_ms = NAN;
  if (!(p->st.rho > 0)) /* no density to render at */
    return 0;
  if (replay_sequence_frame(r, f, &st, &cam) != 0 ||
      replay_post_state(r, s, &st, &cam, replay_frame_target(r, &st)) != 0)
    return 1;
  if ((err = rp_runtime_set_density(s->rt, p->st.rho)) != 0) {
    fprintf(stderr, "raypace: replay: --split: density %g of frame %u: "
                    "%s\n", p->st.rho, f, rp_strerror(err));
    return 1;
  }
  if (replay_step(s, "--split") != 0)
    return 1;
  /* A settle frame only keeps the runtimes in step. A frame that
   * rendered other effects (an AO computation that ended on another
   * frame here) or in several passes is not the same work. */
  if (row == NULL || s->st.effects != row->effects || s->st.passes != 1 ||
      row->passes != 1)
    return 0;
  row->split_first_ms = s->st.render_ms;
  /* The frame after the settle frames held its camera. */
  moved = f > 0 && st.camera_changed;
  for (j = 0; j < r->o.split; j++) {
    /* On a frame whose camera moved, the camera posted anew, one ulp
     * apart every other repeat (the same image), so that the work a new
     * camera sets off (the probe, each device's depth pass) is in every
     * repeat as it was in the frame: in a moving sequence it is part of
     * every frame's cost. */
    rp_camera again = cam;
    if (moved && j % 2 == 0)
      again.eye[0] = nextafterf(cam.eye[0], INFINITY);
    if (replay_post_state(r, s, &st, &again, 0.0) != 0 ||
        replay_step(s, "--split") != 0)
      return 1;
    t[j] = s->st.render_ms;
  }
  row->split_sd_ms = sd_of(t, r->o.split);
  row->split_ms = cli_median(t, (int)r->o.split);
  return 0;
}
/* The median of |x| over n values; sorts a copy in `work`. */
static double median_abs(const double *x, uint32_t n, double *work) {
  uint32_t i;
  if (n == 0)
    return NAN;
  for (i = 0; i < n; i++)
    work[i] = fabs(x[i]);
  return cli_median(work, (int)n);
}

/* Root mean square and mean of n values x. */
static void rms_mean(const double *x, uint32_t n, double *rms, double *mean) {
  double s = 0.0, q = 0.0;
  uint32_t i;
  for (i = 0; i < n; i++) {
    s += x[i];
    q += x[i] * x[i];
  }
  *rms = n > 0 ? sqrt(q / n) : NAN;
  if (mean != NULL)
    *mean = n > 0 ? s / n : NAN;
}

/* What of a term's rms the noise does not explain: the noise's variance
 * v taken off its mean square. NaN stays NaN. */
static double excess(double rms, double v) {
  double q = rms * rms - v;
  return q > 0.0 ? sqrt(q) : isnan(q) ? NAN : 0.0;
}

enum { T_PASS, T_CONTEXT, T_SWITCH, T_MODEL, T_NOISE, T_FRAME, T_OUTSIDE,
       T_COUNT };

void replay_split_summarise(const frame_row *rows, uint32_t n,
                            uint32_t repeats, error_split *out) {
  /* The terms, T_COUNT rows of n, and a row to sort in. */
  double *x = malloc((size_t)(T_COUNT + 1) * (n > 0 ? n : 1) * sizeof *x);
  double *work;
  uint32_t i, m = 0;
  memset(out, 0, sizeof *out);
  out->repeats = repeats;
  if (x == NULL)
    return; /* frames 0: no split to report */
  work = x + (size_t)T_COUNT * n;
  for (i = 0; i < n; i++) {
    const frame_row *w = &rows[i];
    double tgt = w->target_ms;
    if (!isfinite(w->split_ms) || !isfinite(w->pass_predicted_ms) ||
        !(tgt > 0))
      continue;
    x[T_PASS * n + m] = (w->render_ms - w->pass_predicted_ms) / tgt;
    x[T_CONTEXT * n + m] = (w->render_ms - w->split_first_ms) / tgt;
    x[T_SWITCH * n + m] = (w->split_first_ms - w->split_ms) / tgt;
    x[T_MODEL * n + m] = (w->split_ms - w->pass_predicted_ms) / tgt;
    x[T_NOISE * n + m] = w->split_sd_ms / tgt;
    x[T_FRAME * n + m] = (w->measured_ms - w->predicted_ms) / tgt;
    x[T_OUTSIDE * n + m] = x[T_FRAME * n + m] - x[T_PASS * n + m];
    m++;
  }
  out->frames = m;
  rms_mean(x + T_PASS * n, m, &out->pass_rms, &out->pass_mean);
  rms_mean(x + T_CONTEXT * n, m, &out->context_rms, &out->context_mean);
  rms_mean(x + T_SWITCH * n, m, &out->switch_rms, &out->switch_mean);
  rms_mean(x + T_MODEL * n, m, &out->model_rms, &out->model_mean);
  rms_mean(x + T_NOISE * n, m, &out->noise_rms, NULL);
  rms_mean(x + T_FRAME * n, m, &out->frame_rms, NULL);
  rms_mean(x + T_OUTSIDE * n, m, &out->outside_rms, NULL);
  out->pass_med = median_abs(x + T_PASS * n, m, work);
  out->context_med = median_abs(x + T_CONTEXT * n, m, work);
  out->switch_med = median_abs(x + T_SWITCH * n, m, work);
  out->model_med = median_abs(x + T_MODEL * n, m, work);
  out->noise_med = median_abs(x + T_NOISE * n, m, work);
  free(x);
  {
    const double v = out->noise_rms * out->noise_rms;
    const double med = repeats > 0 ? 3.14159265358979 / (2.0 * repeats) : 0.0;
    out->context_excess = excess(out->context_rms, 2.0 * v);
    out->switch_excess = excess(out->switch_rms, (1.0 + med) * v);
    out->model_excess = excess(out->model_rms, med * v);
  }
}
