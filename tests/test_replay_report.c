/* What replay reports per event class (cli/replay_report.c), worked out
 * again here the slow way on made-up frames:
 * - a quantile is the nearest rank's: the smallest value with at least
 *   p n of the values at or under it, found by counting, not sorting;
 * - a frame's classes are those of the events on it and on the two
 *   frames before it, found here by marking forward from each event;
 * - each class's frames, miss rate, share over 1.2x, p95, p99 and mean
 *   density, and the TF-switch overshoot, from those marks;
 * - the whole run's miss rate, by counting the late frames. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "replay.h"
#include "test_util.h"

/* A small LCG, so that the made-up frames are the same on every run. */
static uint32_t next(uint32_t *s) {
  *s = *s * 1664525u + 1013904223u;
  return *s >> 8;
}

/* Nearest rank by counting: the smallest v[i] with at least pct % of the
 * n values <= it; exact in integers. */
static double brute_quantile(const double *v, int n, int pct) {
  double best = INFINITY;
  int i, j;
  for (i = 0; i < n; i++) {
    int at_or_under = 0;
    for (j = 0; j < n; j++)
      at_or_under += v[j] <= v[i];
    if (100 * at_or_under >= pct * n && v[i] < best)
      best = v[i];
  }
  return best;
}

static void quantile_is_nearest_rank(void **state) {
  static const int pcts[] = {1, 50, 90, 95, 99, 100};
  uint32_t seed = 7;
  double v[64], w[64];
  int n, k, i;
  (void)state;
  for (n = 1; n <= 64; n++) {
    for (i = 0; i < n; i++)
      /* Few distinct values, so that ties are common. */
      v[i] = (double)(next(&seed) % 17) * 0.25;
    for (k = 0; k < (int)(sizeof pcts / sizeof pcts[0]); k++) {
      double got;
      memcpy(w, v, (size_t)n * sizeof *v);
      got = cli_quantile(w, n, pcts[k] / 100.0);
      if (got != brute_quantile(v, n, pcts[k]))
        fail_msg("n %d, p%d: %g, counting says %g", n, pcts[k], got,
                 brute_quantile(v, n, pcts[k]));
    }
  }
  /* Twenty values 1..20: p95 is the 19th, p99 the 20th. */
  for (i = 0; i < 20; i++)
    w[i] = 20 - i;
  assert_true(cli_quantile(w, 20, 0.95) == 19.0);
  assert_true(cli_quantile(w, 20, 0.99) == 20.0);
  assert_true(isnan(cli_quantile(w, 0, 0.5)));
}

static void events_come_from_the_state(void **state) {
  rp_sequence_state st;
  (void)state;
  memset(&st, 0, sizeof st);
  st.frame = 7;
  assert_int_equal(replay_frame_events(&st), 0);
  st.tf_changed = st.camera_cut = 1;
  st.camera_changed = 1; /* motion alone is no event */
  assert_int_equal(replay_frame_events(&st), REPLAY_EV_TF | REPLAY_EV_CUT);
  st.effects_changed = st.target_changed = 1;
  assert_int_equal(replay_frame_events(&st),
                   REPLAY_EV_TF | REPLAY_EV_CUT | REPLAY_EV_EFFECTS |
                       REPLAY_EV_TARGET);
  /* Frame 0's flags are all set, but the settle frames played it. */
  st.frame = 0;
  assert_int_equal(replay_frame_events(&st), 0);
  assert_string_equal(replay_class_name(0), "smooth");
  assert_string_equal(replay_class_name(1), "tf_switch");
  assert_string_equal(replay_class_name(2), "camera_cut");
  assert_string_equal(replay_class_name(3), "effect_toggle");
  assert_string_equal(replay_class_name(4), "target_change");
}

#define N 400

static void classes_add_up(void **state) {
  static frame_row rows[N];
  static int in[N][REPLAY_CLASSES];
  static double ratios[N];
  uint32_t seed = 11, i, j;
  summary s;
  double switch_over = 0.0;
  int c;
  (void)state;
  memset(rows, 0, sizeof rows);
  memset(in, 0, sizeof in);
  for (i = 0; i < N; i++) {
    frame_row *w = &rows[i];
    uint32_t r = next(&seed) % 100;
    w->frame = i;
    /* Events now and then, some together, some two frames apart. */
    w->events = i == 0 ? 0
                : r < 4 ? REPLAY_EV_TF
                : r < 7 ? REPLAY_EV_TF | REPLAY_EV_CUT
                : r < 10 ? REPLAY_EV_EFFECTS
                : r < 13 ? REPLAY_EV_TARGET
                : 0;
    w->target_ms = 10.0 + (double)(next(&seed) % 5);
    w->measured_ms = w->target_ms * (0.6 + (next(&seed) % 1000) * 0.0008);
    w->rho = 0.01 * (1 + next(&seed) % 100);
  }
  /* Each event marks its frame and the two after it. */
  for (i = 0; i < N; i++)
    for (c = 1; c < REPLAY_CLASSES; c++)
      if (rows[i].events & (1u << (c - 1)))
        for (j = i; j <= i + 2 && j < N; j++)
          in[j][c] = 1;
  for (i = 0; i < N; i++) {
    in[i][0] = !(in[i][1] || in[i][2] || in[i][3] || in[i][4]);
    if (in[i][1])
      switch_over = fmax(switch_over, rows[i].measured_ms /
                                          rows[i].target_ms - 1.0);
  }
  assert_int_equal(replay_summarise(RP_CONTROL_PREDICTED, rows, N, 1.0, &s),
                   0);
  assert_true(fabs(s.switch_over - switch_over) < 1e-12);
  /* The slowest frame of a TF switch or cut itself. */
  {
    double ev = -1.0;
    for (i = 0; i < N; i++)
      if (rows[i].events & (REPLAY_EV_TF | REPLAY_EV_CUT))
        ev = fmax(ev, rows[i].measured_ms / rows[i].target_ms);
    assert_true(ev > 0.0 && s.event_frame_max == ev);
  }
  /* The whole run's miss rate: every frame over its target, counted. */
  for (i = 0, j = 0; i < N; i++)
    j += rows[i].measured_ms > rows[i].target_ms;
  assert_true(j > 0 && j < N);
  assert_true(fabs(s.miss_rate - (double)j / N) < 1e-12);
  for (c = 0; c < REPLAY_CLASSES; c++) {
    const class_stats *cs = &s.classes[c];
    uint32_t frames = 0, miss = 0, over = 0;
    double dens = 0.0;
    for (i = 0; i < N; i++) {
      const frame_row *w = &rows[i];
      if (!in[i][c])
        continue;
      ratios[frames++] = w->measured_ms / w->target_ms;
      miss += w->measured_ms > w->target_ms;
      over += w->measured_ms > 1.2 * w->target_ms;
      dens += w->rho;
    }
    if (frames <= 20) /* every class is exercised */
      fail_msg("class %d: %u frames", c, frames);
    assert_int_equal(cs->frames, frames);
    assert_true(fabs(cs->miss_rate - (double)miss / frames) < 1e-12);
    assert_true(fabs(cs->share_over_1_2 - (double)over / frames) < 1e-12);
    assert_true(fabs(cs->mean_density - dens / frames) < 1e-12);
    assert_true(cs->p95 == brute_quantile(ratios, (int)frames, 95));
    assert_true(cs->p99 == brute_quantile(ratios, (int)frames, 99));
  }
  /* A class no frame is in has no figures. */
  for (i = 0; i < N; i++)
    rows[i].events &= ~REPLAY_EV_TARGET;
  assert_int_equal(replay_summarise(RP_CONTROL_PREDICTED, rows, N, 1.0, &s),
                   0);
  assert_int_equal(s.classes[4].frames, 0);
  assert_true(isnan(s.classes[4].miss_rate) && isnan(s.classes[4].p95) &&
              isnan(s.classes[4].mean_density));
}

/* The median of n values by insertion sort (in place): the middle one,
 * or the mean of the two middle ones. */
static double insertion_median(double *v, uint32_t n) {
  uint32_t i, j;
  for (i = 1; i < n; i++)
    for (j = i; j > 0 && v[j - 1] > v[j]; j--) {
      double t = v[j];
      v[j] = v[j - 1];
      v[j - 1] = t;
    }
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* --split's summary: each term's rms and mean worked out again here over
 * the frames that have a split; the means add up to the pass error's,
 * as the terms do frame by frame. */
static void split_terms_add_up(void **state) {
  static frame_row rows[N];
  uint32_t seed = 5, i, m = 0;
  static double av[5][N];
  double q[6] = {0}, mean[4] = {0};
  error_split e;
  (void)state;
  memset(rows, 0, sizeof rows);
  for (i = 0; i < N; i++) {
    frame_row *w = &rows[i];
    double x[5];
    int k;
    for (k = 0; k < 5; k++)
      x[k] = 5.0 + (next(&seed) % 1000) * 0.01;
    w->target_ms = x[0];
    w->render_ms = x[1];
    w->split_first_ms = x[2];
    w->split_ms = x[3];
    w->pass_predicted_ms = x[4];
    w->split_sd_ms = 0.001 * (next(&seed) % 100);
    w->measured_ms = w->render_ms + 0.5;
    w->predicted_ms = w->pass_predicted_ms + 0.25;
    if (i % 7 == 3) /* no split on these */
      w->split_ms = NAN;
  }
  for (i = 0; i < N; i++) {
    const frame_row *w = &rows[i];
    double t = w->target_ms, v[6];
    int k;
    if (isnan(w->split_ms))
      continue;
    v[0] = (w->render_ms - w->pass_predicted_ms) / t;
    v[1] = (w->render_ms - w->split_first_ms) / t;
    v[2] = (w->split_first_ms - w->split_ms) / t;
    v[3] = (w->split_ms - w->pass_predicted_ms) / t;
    v[4] = w->split_sd_ms / t;
    v[5] = 0.25 / t; /* outside: 0.5 measured, 0.25 predicted */
    for (k = 0; k < 6; k++)
      q[k] += v[k] * v[k];
    for (k = 0; k < 4; k++)
      mean[k] += v[k];
    for (k = 0; k < 5; k++)
      av[k][m] = fabs(v[k]);
    m++;
  }
  replay_split_summarise(rows, N, 4, &e);
  assert_int_equal(e.frames, m);
  assert_int_equal(e.repeats, 4);
  assert_true(fabs(e.pass_rms - sqrt(q[0] / m)) < 1e-12);
  assert_true(fabs(e.context_rms - sqrt(q[1] / m)) < 1e-12);
  assert_true(fabs(e.switch_rms - sqrt(q[2] / m)) < 1e-12);
  assert_true(fabs(e.model_rms - sqrt(q[3] / m)) < 1e-12);
  assert_true(fabs(e.noise_rms - sqrt(q[4] / m)) < 1e-12);
  assert_true(fabs(e.outside_rms - sqrt(q[5] / m)) < 1e-12);
  assert_true(fabs(e.pass_mean - mean[0] / m) < 1e-12);
  assert_true(e.pass_med == insertion_median(av[0], m));
  assert_true(e.context_med == insertion_median(av[1], m));
  assert_true(e.switch_med == insertion_median(av[2], m));
  assert_true(e.model_med == insertion_median(av[3], m));
  assert_true(e.noise_med == insertion_median(av[4], m));
  assert_true(fabs(e.pass_mean - (e.context_mean + e.switch_mean +
                                   e.model_mean)) < 1e-12);
  /* Beyond the noise: the noise's variance off each mean square, by
   * how many renders each term differences (2 singles; a single less a
   * median of 4, whose variance is pi / 8 of one; a median of 4). */
  {
    const double v = q[4] / m, med = 3.14159265358979 / 8.0;
    assert_true(fabs(e.context_excess -
                     sqrt(fmax(0.0, q[1] / m - 2.0 * v))) < 1e-12);
    assert_true(fabs(e.switch_excess -
                     sqrt(fmax(0.0, q[2] / m - (1.0 + med) * v))) < 1e-12);
    assert_true(fabs(e.model_excess -
                     sqrt(fmax(0.0, q[3] / m - med * v))) < 1e-12);
  }
  /* No frame with a split: no figures. */
  for (i = 0; i < N; i++)
    rows[i].split_ms = NAN;
  replay_split_summarise(rows, N, 4, &e);
  assert_int_equal(e.frames, 0);
  assert_true(isnan(e.pass_rms) && isnan(e.model_mean) &&
              isnan(e.model_med));
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(quantile_is_nearest_rank),
      cmocka_unit_test(events_come_from_the_state),
      cmocka_unit_test(classes_add_up),
      cmocka_unit_test(split_terms_add_up),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
