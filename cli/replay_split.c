/* raypace replay --split R: where the predicted controller's error comes
 * from (M10; docs/pacing.md, "Where the error comes from").
 *
 * After the replay, one more runtime (controller none) plays the
 * sequence again, and renders each recorded frame of the predicted
 * controller at the density that controller chose for it: once right
 * after the frame before (the first render at the frame's settings, as
 * the controller's own frame was), then R times more with nothing
 * changed but the camera posted again (see split_frame). Nothing else runs on the machine meanwhile: the repeats
 * measure the machine's own timing noise at fixed settings, not
 * interleaved with other work, and their median is what the frame costs
 * once settled. The controller's frame, its first render here and the
 * settled cost then split the pass's error (replay.h, error_split). */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "replay.h"

/* Mean and sample standard deviation of n > 1 values. */
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

/* Frame f on the split runtime: its state and the predicted
 * controller's density, a first render and `repeats` more. */
static int split_frame(replay *r, player *p, frame_row *row, double *t) {
  rp_sequence_state st;
  rp_camera cam;
  uint32_t j;
  int err, moved;
  if (replay_sequence_frame(r, row->frame, &st, &cam) != 0 ||
      replay_post_state(r, p, &st, &cam, replay_frame_target(r, &st)) != 0)
    return 1;
  if ((err = rp_runtime_set_density(p->rt, row->rho)) != 0) {
    fprintf(stderr, "raypace: replay: --split: density %g of frame %u: "
                    "%s\n", row->rho, row->frame, rp_strerror(err));
    return 1;
  }
  if (replay_step(p, "--split") != 0)
    return 1;
  /* The same effects, or the frames are not the same work (an AO
   * computation that ended on another frame here). */
  if (p->st.effects != row->effects || p->st.passes != 1)
    return 0;
  row->split_first_ms = p->st.render_ms;
  /* Frame 0 follows the settle frames, which held its camera. */
  moved = row->frame > 0 && st.camera_changed;
  for (j = 0; j < r->o.split; j++) {
    /* On a frame whose camera moved, the camera posted anew, one ulp
     * apart every other repeat (the same image), so that the work a new
     * camera sets off (the probe, each device's depth pass) is in every
     * repeat as it was in the frame: in a moving sequence it is part of
     * every frame's cost. */
    rp_camera again = cam;
    if (moved && j % 2 == 0)
      again.eye[0] = nextafterf(cam.eye[0], INFINITY);
    if (replay_post_state(r, p, &st, &again, 0.0) != 0 ||
        replay_step(p, "--split") != 0)
      return 1;
    t[j] = p->st.render_ms;
  }
  row->split_sd_ms = sd_of(t, r->o.split);
  row->split_ms = cli_median(t, (int)r->o.split);
  return 0;
}

int replay_split(replay *r, frame_row *rows) {
  player p;
  double *t;
  uint32_t f;
  int rc = 1;
  for (f = 0; f < r->frames; f++)
    rows[f].split_first_ms = rows[f].split_ms = rows[f].split_sd_ms = NAN;
  if ((t = malloc(r->o.split * sizeof *t)) == NULL)
    return cli_error(r->ctx, "--split", RP_ENOMEM);
  memset(&p, 0, sizeof p);
  p.kind = RP_CONTROL_NONE;
  if (!r->o.quiet)
    fprintf(stderr, "replay: --split: predicted's %u frames again, %u "
                    "repeats each, on a runtime of their own\n",
            r->frames, r->o.split);
  if (replay_player_open(r, &p, 0) != 0)
    goto out;
  /* The warm-up left the runtime in the first frame's state; the settle
   * frames then play it at frame 0's density, as they did before the
   * controller's frame 0. */
  for (f = 0; f < r->o.settle && rows[0].rho > 0; f++)
    if (rp_runtime_set_density(p.rt, rows[0].rho) != 0 ||
        replay_step(&p, "--split") != 0)
      goto out;
  for (f = 0; f < r->frames; f++) {
    frame_row *row = &rows[f];
    if (!(row->rho > 0)) /* a failed frame has no density to render */
      continue;
    if (split_frame(r, &p, row, t) != 0)
      goto out;
  }
  rc = 0;
out:
  replay_player_close(&p);
  free(t);
  return rc;
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
  double *x = malloc((size_t)T_COUNT * (n > 0 ? n : 1) * sizeof *x);
  uint32_t i, m = 0;
  memset(out, 0, sizeof *out);
  out->repeats = repeats;
  if (x == NULL)
    return; /* frames 0: no split to report */
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
  free(x);
  {
    const double v = out->noise_rms * out->noise_rms;
    const double med = repeats > 0 ? 3.14159265358979 / (2.0 * repeats) : 0.0;
    out->context_excess = excess(out->context_rms, 2.0 * v);
    out->switch_excess = excess(out->switch_rms, (1.0 + med) * v);
    out->model_excess = excess(out->model_rms, med * v);
  }
}
