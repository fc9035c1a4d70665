/* The Eq. 2 tuner (runtime/tune.c) and the controllers (runtime/control.c).
 * Expected values are worked out here by hand from each rule's statement
 * (closed forms, fractions, or the rule's formula written out term by
 * term), never by calling into the code under test. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "raypace_pace.h"
#include "test_util.h"

#define assert_close(x, y, rel)                                              \
  do {                                                                       \
    double x_ = (x), y_ = (y);                                               \
    if (!(fabs(x_ - y_) <= (rel) * fmax(fabs(x_), fabs(y_))))                \
      fail_msg("%s = %.17g, expected %.17g", #x, x_, y_);                    \
  } while (0)

/* ---- models for the tuner ---------------------------------------------- */

typedef struct model {
  double a, b;      /* linear: a rho + b */
  double c, p;      /* power: c rho^p */
  double edge;      /* step: lo_t under edge, hi_t from it on */
  double lo_t, hi_t;
  double value;     /* constant */
  double nan_lo, nan_hi; /* linear, NaN inside [nan_lo, nan_hi] */
  int nan_calls;         /* calls that returned NaN */
  long sleep_ns;    /* step: each call from sleep_from on sleeps this */
  int sleep_from;
  int calls;
} model;

static double m_linear(void *u, double rho) {
  model *m = u;
  m->calls++;
  return m->a * rho + m->b;
}

static double m_power(void *u, double rho) {
  model *m = u;
  m->calls++;
  return m->c * pow(rho, m->p);
}

static double m_step(void *u, double rho) {
  model *m = u;
  m->calls++;
  if (m->sleep_ns > 0 && m->calls >= m->sleep_from) {
    struct timespec ts = {0, m->sleep_ns};
    nanosleep(&ts, NULL);
  }
  return rho < m->edge ? m->lo_t : m->hi_t;
}

/* Linear under the edge, a flat hi_t from it on: a model that stops
 * being monotone, as a cost model's sigma learned at one density can
 * make it. */
static double m_cliff(void *u, double rho) {
  model *m = u;
  m->calls++;
  return rho < m->edge ? m->a * rho : m->hi_t;
}

static double m_const(void *u, double rho) {
  model *m = u;
  (void)rho;
  m->calls++;
  return m->value;
}

static double m_nan_band(void *u, double rho) {
  model *m = u;
  m->calls++;
  if (rho >= m->nan_lo && rho <= m->nan_hi) {
    m->nan_calls++;
    return NAN;
  }
  return m->a * rho + m->b;
}

/* The tuner's wall-clock budget (200 us by default) is for frames; a
 * test of what the search finds must not depend on how busy the machine
 * is (CI once stopped tune_power_law after one prediction), so these
 * searches are bounded by max_iters alone. tune_time_limit tests the
 * budget itself. */
#define NO_TIME_LIMIT_US 1e9

/* rp_tune with rp_tune_desc.lift = lift (0: the default). */
static rp_tune_result tune_lifted(double target, double rho_prev,
                                  double lift, rp_predict_fn fn, model *m) {
  rp_tune_desc d;
  rp_tune_result r;
  memset(&d, 0, sizeof d);
  d.target_ms = target;
  d.max_time_us = NO_TIME_LIMIT_US;
  d.rho_prev = rho_prev;
  d.lift = lift;
  memset(&r, 0, sizeof r);
  assert_int_equal(rp_tune(&d, fn, m, &r), 0);
  assert_int_equal(r.iters, m->calls);
  assert_true(isfinite(r.rho));
  return r;
}

static rp_tune_result tune(double target, double rho_prev, rp_predict_fn fn,
                           model *m) {
  return tune_lifted(target, rho_prev, 0, fn, m);
}

/* ---- tuner ------------------------------------------------------------- */

/* t' = a rho + b: rho* = (T - b) / a. The default tolerance accepts
 * t' in [0.99 T, T], which is rho in [rho* - 0.01 T / a, rho*]. The
 * secant through two points is exact on a line, so: one prediction at
 * the start, one extrapolation, one secant step. */
static void tune_linear_closed_form(void **state) {
  const struct {
    double a, b, T, prev, star;
  } cs[] = {{10, 2, 6, 0, 0.4},        /* from rho_max, above */
            {10, 2, 6, 0.35, 0.4},     /* from below, within damping */
            {8, 0, 4, 0, 0.5},         /* proportional: exact at once */
            {100, 5, 30, 0.3, 0.25},   /* from above */
            {1, 0.05, 0.3, 0.9, 0.25}};
  size_t i;
  (void)state;
  for (i = 0; i < sizeof cs / sizeof cs[0]; i++) {
    model m = {0};
    rp_tune_result r;
    double t;
    m.a = cs[i].a;
    m.b = cs[i].b;
    r = tune(cs[i].T, cs[i].prev, m_linear, &m);
    t = cs[i].a * r.rho + cs[i].b;
    assert_true(r.iters <= 3);
    assert_true(t <= cs[i].T);
    assert_true(t >= 0.99 * cs[i].T);
    assert_true(r.rho <= cs[i].star * (1 + 1e-12));
    assert_true(r.rho >= cs[i].star - 0.01 * cs[i].T / cs[i].a);
    assert_close(r.predicted_ms, t, 1e-12);
    assert_int_equal(r.limited, 0);
  }
}

/* t' = c rho^p, monotone, not linear: rho* = (T / c)^(1/p). With c = 40,
 * T = 10: 0.25^(1/p). */
static void tune_power_law(void **state) {
  const struct {
    double p, star;
  } cs[] = {{0.5, 0.0625},
            {1.5, 0.3968502629920499},
            {2, 0.5},
            {3, 0.6299605249474366}};
  size_t i;
  (void)state;
  for (i = 0; i < sizeof cs / sizeof cs[0]; i++) {
    model m = {0};
    rp_tune_desc d = {0};
    rp_tune_result r;
    double t;
    m.c = 40;
    m.p = cs[i].p;
    d.target_ms = 10;
    d.max_time_us = NO_TIME_LIMIT_US;
    d.max_iters = 30;
    assert_int_equal(rp_tune(&d, m_power, &m, &r), 0);
    t = 40 * pow(r.rho, cs[i].p);
    printf("power %.1f: %d predictions\n", cs[i].p, r.iters);
    assert_true(t <= 10 && t >= 9.9);
    assert_true(r.rho <= cs[i].star * (1 + 1e-12));
    assert_true(r.rho >= pow(9.9 / 40, 1 / cs[i].p) * (1 - 1e-12));
    /* Within the default budget of 8 as well. */
    memset(&m, 0, sizeof m);
    m.c = 40;
    m.p = cs[i].p;
    r = tune(10, 0, m_power, &m);
    t = 40 * pow(r.rho, cs[i].p);
    assert_true(t <= 10 && t >= 9.9);
  }
}

/* A step: 5 ms under rho = 0.37, 20 ms from it on, target 10. No
 * prediction ever lands in the band; the bracket closes on the edge and
 * the result is the largest rho under it that was tried. */
static void tune_step_model(void **state) {
  model m = {0};
  rp_tune_desc d = {0};
  rp_tune_result r;
  (void)state;
  m.edge = 0.37;
  m.lo_t = 5;
  m.hi_t = 20;
  d.target_ms = 10;
  d.max_time_us = NO_TIME_LIMIT_US;
  d.max_iters = 80;
  assert_int_equal(rp_tune(&d, m_step, &m, &r), 0);
  assert_true(r.rho < 0.37);
  assert_true(r.rho > 0.37 - 1e-6);
  assert_true(r.predicted_ms == 5);
  assert_int_equal(r.limited, 0);
  /* The default budget: still on the feasible side. */
  memset(&m, 0, sizeof m);
  m.edge = 0.37;
  m.lo_t = 5;
  m.hi_t = 20;
  r = tune(10, 0, m_step, &m);
  assert_true(r.rho < 0.37);
  assert_true(r.predicted_ms == 5);
  assert_int_equal(r.iters, 8);
}

/* t' = 600 rho under 0.04, 30 from there on, target 24 from rho_prev
 * 0.25 (the largest feasible rho is 0.04 - 0.24 / 600 = 0.0396): the
 * flat secant sends the search to rho_min (0.6 ms), which leaves a
 * bracket [0.001, 0.2] two hundred times wide. Split by straight-line
 * interpolation (Illinois), the 8 predictions end at rho 0.0137, a
 * third of what the frame could have had (worked by hand: 0.158,
 * 0.125, 0.082, 0.041 over, then 0.0137 under); split geometrically
 * while wider than 4x (0.014, 0.053, then interpolation), at 0.0358. */
static void tune_wide_bracket(void **state) {
  model m = {0};
  rp_tune_result r;
  (void)state;
  m.a = 600;
  m.edge = 0.04;
  m.hi_t = 30;
  r = tune(24, 0.25, m_cliff, &m);
  printf("wide bracket: rho %.4f after %d predictions\n", r.rho, r.iters);
  assert_true(r.rho >= 0.03 && r.rho < 0.04);
  assert_true(r.predicted_ms <= 24);
}

static void tune_constant_models(void **state) {
  const double bad[] = {0.0, -1.0, NAN, INFINITY, -INFINITY};
  model m = {0};
  rp_tune_result r;
  size_t i;
  (void)state;
  /* Exactly the target everywhere: the start is in the band. */
  m.value = 10;
  r = tune(10, 0.5, m_const, &m);
  assert_int_equal(r.iters, 1);
  assert_true(r.rho == 0.5);
  assert_true(r.predicted_ms == 10);
  assert_int_equal(r.limited, 0);
  /* Half the target everywhere: up to the damped clamp 0.5 / 0.8 after
   * one extrapolation (0.5 * 9.95 / 5 = 0.995, cut to 0.625); its 5 ms
   * is over a quarter of the target, so the damping stays and no lift
   * is tried (two predictions). */
  memset(&m, 0, sizeof m);
  m.value = 5;
  r = tune(10, 0.5, m_const, &m);
  assert_int_equal(r.iters, 2);
  assert_true(r.rho == 0.5 * (1.0 / 0.8));
  assert_true(r.predicted_ms == 5);
  assert_int_equal(r.limited, 1);
  /* Twice the target everywhere: 0.5, then 0.5 * 9.95 / 20, then the
   * flat secant sends it to rho_min, which is over too. No density
   * meets the target, and every one costs rho_min's time: the upper
   * clamp 0.625, asked once more (TUNE_FLOOR_SLACK). */
  memset(&m, 0, sizeof m);
  m.value = 20;
  r = tune(10, 0.5, m_const, &m);
  assert_int_equal(r.iters, 4);
  assert_true(r.rho == 0.5 * (1.0 / 0.8));
  assert_true(r.predicted_ms == 20);
  assert_int_equal(r.limited, 1);
  /* Nothing valid: the start and both clamps are tried, then rho_prev
   * stays (rho_max on a first frame, where start and clamp coincide). */
  for (i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    memset(&m, 0, sizeof m);
    m.value = bad[i];
    r = tune(10, 0.5, m_const, &m);
    assert_int_equal(r.iters, 3);
    assert_true(r.rho == 0.5);
    assert_true(isnan(r.predicted_ms));
    assert_int_equal(r.limited, 0);
    memset(&m, 0, sizeof m);
    m.value = bad[i];
    r = tune(10, 0, m_const, &m);
    assert_int_equal(r.iters, 2);
    assert_true(r.rho == 1);
  }
}

/* NaN in places: t' = 10 rho + 2, target 6 (rho* = 0.4). */
static void tune_nan_in_places(void **state) {
  model m = {0};
  rp_tune_result r;
  double t;
  (void)state;
  /* NaN at the start (rho_max): rho_min, then up to the solution. */
  m.a = 10;
  m.b = 2;
  m.nan_lo = 0.9;
  m.nan_hi = 1;
  r = tune(6, 0, m_nan_band, &m);
  t = 10 * r.rho + 2;
  assert_true(t <= 6 && t >= 5.94);
  /* NaN over the solution: whatever is returned was priced, under the
   * target, so below the NaN band (t'(0.45) = 6.5 is over). */
  memset(&m, 0, sizeof m);
  m.a = 10;
  m.b = 2;
  m.nan_lo = 0.3;
  m.nan_hi = 0.45;
  r = tune(6, 0, m_nan_band, &m);
  assert_true(r.rho < 0.3);
  assert_true(r.predicted_ms <= 6);
  assert_close(r.predicted_ms, 10 * r.rho + 2, 1e-12);
  /* NaN under 0.2 only: from above, never touched. */
  memset(&m, 0, sizeof m);
  m.a = 10;
  m.b = 2;
  m.nan_lo = 0;
  m.nan_hi = 0.2;
  r = tune(6, 0, m_nan_band, &m);
  t = 10 * r.rho + 2;
  assert_true(t <= 6 && t >= 5.94);
  /* Everything the damping allows is NaN: rho_prev stays. */
  memset(&m, 0, sizeof m);
  m.a = 10;
  m.b = 2;
  m.nan_lo = 0;
  m.nan_hi = 0.2;
  r = tune(6, 0.1, m_nan_band, &m);
  assert_true(r.rho == 0.1);
  assert_true(isnan(r.predicted_ms));
}

/* Rises are capped at rho_prev * raise_limit exactly; falls are not. */
static void tune_damping(void **state) {
  model m = {0};
  rp_tune_desc d = {0};
  rp_tune_result r;
  (void)state;
  m.a = 10; /* t' = 10 rho, target 10: rho* = 1 */
  r = tune(10, 0.5, m_linear, &m);
  assert_true(r.rho == 0.5 * (1.0 / 0.8));
  assert_true(r.predicted_ms == 10 * r.rho);
  assert_int_equal(r.limited, 1);
  d.target_ms = 10;
  d.max_time_us = NO_TIME_LIMIT_US;
  d.rho_prev = 0.5;
  d.raise_limit = 1.1;
  m.calls = 0;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), 0);
  assert_true(r.rho == 0.5 * 1.1);
  d.raise_limit = 1;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), 0);
  assert_true(r.rho == 0.5);
  assert_int_equal(r.limited, 1);
  /* A fall by a factor of 9 in one call: t' = 100 rho, rho* = 0.1. */
  memset(&m, 0, sizeof m);
  m.a = 100;
  r = tune(10, 0.9, m_linear, &m);
  assert_true(r.rho <= 0.1 && r.rho >= 0.099);
  assert_int_equal(r.limited, 0);
}

static void tune_clamps(void **state) {
  model m = {0};
  rp_tune_desc d = {0};
  rp_tune_result r;
  (void)state;
  /* rho_max under the solution (t' = 10 rho, target 10). */
  m.a = 10;
  d.target_ms = 10;
  d.max_time_us = NO_TIME_LIMIT_US;
  d.rho_max = 0.3;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), 0);
  assert_true(r.rho == 0.3);
  assert_int_equal(r.limited, 1);
  /* rho_min over it (t' = 100 rho: rho* = 0.1). Within 10 % of
   * t'(0.2) = 20 ms lies only rho 0.22, under twice rho_min: rho_min. */
  m.a = 100;
  d.rho_max = 0;
  d.rho_min = 0.2;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), 0);
  assert_true(r.rho == 0.2);
  assert_true(r.predicted_ms == 20);
  assert_int_equal(r.limited, 1);
  /* rho_prev * raise_limit under rho_min: rho_min wins over the
   * damping. Its 0.005 ms is under a quarter of the target, so the lift
   * then takes rho to where t' = 5 rho is a quarter of it, in the
   * band [0.99, 1] of 2.5 ms. */
  d.rho_min = 0;
  d.rho_prev = 1e-4;
  m.a = 5;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), 0);
  assert_true(r.rho >= 0.99 * 0.5 && r.rho <= 0.5);
  assert_int_equal(r.limited, 1);
  /* With a lower target the damped rho_min is over a quarter of it: no
   * lift, rho_min. */
  d.target_ms = 0.015;
  memset(&m, 0, sizeof m);
  m.a = 5;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), 0);
  assert_true(r.rho == 1e-3);
}

/* The damping is lifted when the damped density is predicted at a
 * quarter of the target or less, and only then, to the largest density
 * predicted at a quarter: rho_max at the boundary itself, just under
 * rho_max when it is priced just over, a model that cannot price
 * rho_max, a damped density over a quarter, and a lift that the budget
 * of predictions leaves no room for. */
static void tune_damping_lift(void **state) {
  model m = {0};
  rp_tune_desc d = {0};
  rp_tune_result r;
  (void)state;
  /* t' = 2.5 rho, target 10: rho_max at exactly a quarter. */
  m.a = 2.5;
  r = tune(10, 0.3, m_linear, &m);
  assert_true(r.rho == 1.0);
  assert_true(r.predicted_ms == 2.5);
  assert_int_equal(r.limited, 1);
  assert_int_equal(r.iters, m.calls);
  /* The same with rho_max 8 (a step an eighth of the base), first
   * frame: past 1 to the band [0.99, 1] of the target, rho in [3.96, 4]. */
  memset(&m, 0, sizeof m);
  memset(&d, 0, sizeof d);
  m.a = 2.5;
  d.target_ms = 10;
  d.rho_max = 8;
  d.max_time_us = NO_TIME_LIMIT_US;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), 0);
  assert_true(r.rho <= 4.0 && r.rho >= 0.99 * 4.0);
  assert_int_equal(r.limited, 0);
  /* Just over a quarter: not rho_max, but the density whose t' is in
   * the band [0.99, 1] of a quarter of the target. */
  memset(&m, 0, sizeof m);
  m.a = 2.5000001;
  r = tune(10, 0.3, m_linear, &m);
  assert_true(r.rho < 1.0 && r.rho >= 0.99 * 2.5 / 2.5000001);
  assert_true(r.predicted_ms <= 2.5 && r.predicted_ms >= 0.99 * 2.5);
  assert_int_equal(r.limited, 1);
  assert_int_equal(r.iters, m.calls);
  /* A steeper model, t' = 10 rho from 0.05: damped to 0.0625 (0.625
   * ms), lifted to t' = 2.5 ms, rho in [0.2475, 0.25]. */
  memset(&m, 0, sizeof m);
  m.a = 10;
  r = tune(10, 0.05, m_linear, &m);
  assert_true(r.rho >= 0.2475 && r.rho <= 0.25);
  /* The damped density itself over a quarter (t' = 10 rho from 0.3:
   * 3.75 ms at 0.375): damped, no lift. */
  memset(&m, 0, sizeof m);
  m.a = 10;
  r = tune(10, 0.3, m_linear, &m);
  assert_true(r.rho == 0.3 * (1.0 / 0.8));
  /* rho_max not priced (NaN above 0.9): lifted toward the gap, never
   * into it, and priced under a quarter. */
  memset(&m, 0, sizeof m);
  m.a = 1;
  m.nan_lo = 0.9;
  m.nan_hi = 2;
  r = tune(10, 0.3, m_nan_band, &m);
  assert_true(r.rho > 0.3 * (1.0 / 0.8) && r.rho < 0.9);
  assert_true(r.predicted_ms <= 2.5);
  /* The search used every prediction: no lift is tried. */
  memset(&m, 0, sizeof m);
  m.a = 1;
  d.target_ms = 10;
  d.rho_prev = 0.3;
  d.max_iters = 1;
  d.max_time_us = NO_TIME_LIMIT_US;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), 0);
  assert_true(r.rho == 0.3);
  assert_int_equal(m.calls, 1);
  /* A fall is never affected: t' = 100 rho from 0.9 goes to 0.1. */
  memset(&m, 0, sizeof m);
  m.a = 100;
  r = tune(10, 0.9, m_linear, &m);
  assert_true(r.rho <= 0.1 && r.rho >= 0.099);
}

/* rp_tune_desc.lift moves the lift's threshold and its aim together:
 * t' = 10 rho from 0.05, target 10, lift 0.5: damped to 0.0625 (0.625
 * ms, under half the target), lifted to where t' = 5, rho in [0.495,
 * 0.5]; from 0.45 the damped 0.5625 is priced over half: no lift. Out
 * of (0, 1), or not finite, it is refused. */
static void tune_lift_share(void **state) {
  model m = {0};
  rp_tune_desc d;
  rp_tune_result r;
  static const double bad[] = {1.0, 1.5, -0.25, NAN};
  size_t i;
  (void)state;
  m.a = 10;
  r = tune_lifted(10, 0.05, 0.5, m_linear, &m);
  assert_true(r.rho >= 0.495 && r.rho <= 0.5);
  assert_true(r.predicted_ms >= 4.95 && r.predicted_ms <= 5);
  memset(&m, 0, sizeof m);
  m.a = 10;
  r = tune_lifted(10, 0.45, 0.5, m_linear, &m);
  assert_true(r.rho == 0.45 * (1.0 / 0.8));
  memset(&d, 0, sizeof d);
  d.target_ms = 10;
  for (i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    d.lift = bad[i];
    assert_int_equal(rp_tune(&d, m_linear, &m, &r),
                     isnan(bad[i]) ? RP_ENOTFINITE : RP_EINVAL);
  }
}

static void tune_extreme_targets(void **state) {
  model m = {0};
  rp_tune_result r;
  (void)state;
  /* t' = 10 rho + 1 at a target of 1 ns: 1.01 ms at rho_min, so rho
   * where t' is in [0.99, 1] x 1.111 ms: [0.009989, 0.0111]. */
  m.a = 10;
  m.b = 1;
  r = tune(1e-9, 0, m_linear, &m);
  assert_true(r.rho >= 0.009989 && r.rho <= 0.0111);
  assert_true(r.predicted_ms >= 0.99 * 1.111 && r.predicted_ms <= 1.111);
  assert_int_equal(r.limited, 1);
  memset(&m, 0, sizeof m);
  m.a = 10;
  m.b = 1;
  r = tune(1e9, 0, m_linear, &m);
  assert_true(r.rho == 1);
  assert_int_equal(r.iters, 1);
  assert_int_equal(r.limited, 1);
}

/* The plant of tune_unreachable_target: t' = 10 + 10 rho. */
static model fixed_cost(void) {
  model m = {0};
  m.a = 10;
  m.b = 10;
  return m;
}

/* rp_tune at target 5 on fixed_cost, with rho_prev and tolerance set. */
static rp_tune_result tune_fixed_cost(double rho_prev, double tolerance,
                                      model *m) {
  rp_tune_desc d = {0};
  rp_tune_result r;
  *m = fixed_cost();
  d.target_ms = 5;
  d.rho_prev = rho_prev;
  d.tolerance = tolerance;
  d.max_time_us = NO_TIME_LIMIT_US;
  assert_int_equal(rp_tune(&d, m_linear, m, &r), 0);
  assert_int_equal(r.iters, m->calls);
  return r;
}

/* A target under rho_min's time: t' = 10 + 10 rho (a fixed cost that
 * dominates), target 5. rho_min's 10.01 ms is the fastest frame; the
 * tuner takes the largest density predicted within 10 % of it
 * (TUNE_FLOOR_SLACK), 11.011 ms: rho in [(0.99 x 11.011 - 10) / 10,
 * 0.1011] = [0.0901, 0.1011], not rho_min. On the next frame, from
 * that answer, the main search predicts it again (then 0.0434 and
 * rho_min) and the floor search ends on it: 3 predictions, the same
 * rho. The damping still holds a rise: from rho_prev 0.01 the clamp
 * 0.0125 (10.125 ms) is the answer; with the clamp at rho_min itself,
 * rho_min, after its one prediction. Where the time is all samples
 * (t' = 100 rho, target 0.05), 10 % more time buys 10 % more density,
 * under TUNE_FLOOR_GAIN's 2x: rho_min. */
static void tune_unreachable_target(void **state) {
  model m;
  rp_tune_result r;
  double rho;
  (void)state;
  r = tune_fixed_cost(0, 0, &m);
  printf("unreachable: rho %.4f, %.3f ms after %d predictions\n", r.rho,
         r.predicted_ms, r.iters);
  assert_true(r.rho >= 0.0901 && r.rho <= 0.1011);
  assert_true(r.predicted_ms >= 0.99 * 11.011 &&
              r.predicted_ms <= 11.011);
  assert_int_equal(r.limited, 1);
  rho = r.rho;
  r = tune_fixed_cost(rho, 0, &m);
  assert_true(r.rho == rho);
  assert_int_equal(r.iters, 3);
  r = tune_fixed_cost(0.01, 0, &m);
  assert_true(r.rho == 0.01 * (1.0 / 0.8));
  assert_close(r.predicted_ms, 10.125, 1e-12);
  assert_int_equal(r.limited, 1);
  /* rho_prev * raise_limit under rho_min: the clamp is rho_min. */
  r = tune_fixed_cost(1e-4, 0, &m);
  assert_true(r.rho == 1e-3);
  assert_close(r.predicted_ms, 10.01, 1e-12);
  assert_int_equal(r.iters, 1);
  /* A caller's tolerance of 0.5: the floor search's band stays in the
   * upper half of the slack, t' in [1.05, 1.1] x 10.01 ms, rho in
   * [0.0511, 0.1011]. */
  r = tune_fixed_cost(0, 0.5, &m);
  assert_true(r.rho >= 0.0511 && r.rho <= 0.1011);
  memset(&m, 0, sizeof m);
  m.a = 100;
  r = tune(0.05, 0, m_linear, &m);
  assert_true(r.rho == 1e-3);
  assert_close(r.predicted_ms, 0.1, 1e-12);
  /* Unpriced from 0.5 up: the first frame's start (rho_max) is asked
   * once, not again by the floor search, which still finds the band. */
  memset(&m, 0, sizeof m);
  m.a = 10;
  m.b = 10;
  m.nan_lo = 0.5;
  m.nan_hi = 1;
  r = tune(5, 0, m_nan_band, &m);
  assert_true(r.rho >= 0.0901 && r.rho <= 0.1011);
  assert_int_equal(m.nan_calls, 1);
  /* A time that does not depend on rho, on a first frame: rho_max. */
  memset(&m, 0, sizeof m);
  m.value = 30;
  r = tune(10, 0, m_const, &m);
  assert_true(r.rho == 1);
  assert_true(r.predicted_ms == 30);
}

static double wall_ms(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

/* The first two predictions return at once, the third sleeps 8 ms; the
 * limit is 5 ms, so the check after the third stops the search. Only a
 * stall of over 5 ms before the third call can change that, and it can
 * only stop the search sooner: the count is then under three and the
 * answer is the tuner's best after fewer predictions. */
static void tune_time_limit(void **state) {
  model m = {0};
  rp_tune_desc d = {0};
  rp_tune_result r;
  double t0, took;
  (void)state;
  m.edge = 0.37;
  m.lo_t = 5;
  m.hi_t = 20;
  m.sleep_ns = 8000000;
  m.sleep_from = 3;
  d.target_ms = 10;
  d.max_iters = 1000;
  d.max_time_us = 5000;
  t0 = wall_ms();
  assert_int_equal(rp_tune(&d, m_step, &m, &r), 0);
  took = wall_ms() - t0;
  printf("time limit: %d predictions in %.2f ms\n", r.iters, took);
  /* Without the limit: 1000 predictions, 8 s. */
  assert_int_equal(r.iters, m.calls);
  assert_true(r.iters >= 1 && r.iters <= 3);
  assert_true(took < 1000);
  if (r.iters == 3)
    assert_true(r.rho < 0.37);
}

static void tune_bad_desc(void **state) {
  model m = {0};
  rp_tune_desc d = {0};
  rp_tune_result r, before;
  (void)state;
  m.a = 1;
  memset(&before, 0x5a, sizeof before);
  r = before;
  assert_int_equal(rp_tune(NULL, m_linear, &m, &r), RP_EINVAL);
  d.target_ms = 10;
  assert_int_equal(rp_tune(&d, NULL, &m, &r), RP_EINVAL);
  assert_int_equal(rp_tune(&d, m_linear, &m, NULL), RP_EINVAL);
  d.target_ms = 0;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_EINVAL);
  d.target_ms = -1;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_EINVAL);
  d.target_ms = NAN;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_ENOTFINITE);
  d.target_ms = INFINITY;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_ENOTFINITE);
  d.target_ms = 10;
  d.rho_prev = -0.5;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_EINVAL);
  d.rho_prev = INFINITY;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_ENOTFINITE);
  d.rho_prev = 0;
  d.rho_min = 0.5;
  d.rho_max = 0.4;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_EINVAL);
  d.rho_min = -1;
  d.rho_max = 0;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_EINVAL);
  d.rho_min = 0;
  d.rho_max = 0;
  d.raise_limit = 0.5;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_EINVAL);
  d.raise_limit = 0;
  d.tolerance = 1.5;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_EINVAL);
  d.tolerance = 0;
  d.max_iters = -1;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_EINVAL);
  d.max_iters = 0;
  d.max_time_us = -1;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_EINVAL);
  d.max_time_us = NAN;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), RP_ENOTFINITE);
  assert_memory_equal(&r, &before, sizeof r);
  assert_int_equal(m.calls, 0);
  /* A density above 1 is a step under the base step: allowed. */
  d.max_time_us = 0;
  d.rho_max = 2;
  assert_int_equal(rp_tune(&d, m_linear, &m, &r), 0);
  assert_true(r.rho == 2.0); /* t' = rho: 2 ms of 10 at most */
}

/* ---- controllers ------------------------------------------------------- */

/* The synthetic plant: a pass at rho costs a rho + b ms. */
typedef struct plant {
  double a, b;
} plant;

static double plant_time(const plant *p, double rho) {
  return p->a * rho + p->b;
}

static double plant_predict(void *u, double rho) {
  return plant_time(u, rho);
}

static rp_controller *make(rp_context *ctx, rp_controller_kind kind,
                           double rho_start) {
  rp_controller_desc d = {0};
  rp_controller *c = NULL;
  d.kind = kind;
  d.rho_start = rho_start;
  d.tune_time_us = NO_TIME_LIMIT_US;
  /* The closed forms here are of each rule aiming at the target itself;
   * predicted's deadline contract has tests of its own. */
  d.miss_rate = -1.0;
  assert_int_equal(rp_controller_create(ctx, &d, &c), 0);
  assert_non_null(c);
  return c;
}

/* One frame on the plant: returns its first pass's density; *t gets the
 * frame's time, *final its final density, *passes the pass count. */
static double frame(rp_controller *c, double target, plant *p, double *t,
                    double *final, int *passes) {
  double rho, first, sum = 0;
  int again = 1, n = 0;
  assert_int_equal(
      rp_controller_begin_frame(c, target, plant_predict, p, &rho), 0);
  first = rho;
  while (again) {
    double pt = plant_time(p, rho);
    sum += pt;
    assert_int_equal(rp_controller_end_pass(c, pt, &again, &rho), 0);
    assert_true(++n <= 2);
  }
  if (t != NULL)
    *t = sum;
  if (final != NULL)
    *final = rho;
  if (passes != NULL)
    *passes = n;
  return first;
}

/* One frame with a scripted time, whatever the density. */
static double frame_scripted(rp_controller *c, double target, double t) {
  double rho, r2;
  int again;
  assert_int_equal(rp_controller_begin_frame(c, target, NULL, NULL, &rho),
                   0);
  assert_int_equal(rp_controller_end_pass(c, t, &again, &r2), 0);
  assert_int_equal(again, 0);
  return rho;
}

static void controller_names(void **state) {
  rp_controller_kind k;
  int i;
  (void)state;
  for (i = 0; i < RP_CONTROL_COUNT; i++) {
    assert_int_equal(
        rp_controller_from_name(rp_controller_name((rp_controller_kind)i),
                                &k),
        0);
    assert_int_equal((int)k, i);
  }
  assert_string_equal(rp_controller_name(RP_CONTROL_UE5), "ue5");
  assert_string_equal(rp_controller_name(RP_CONTROL_LAST_FRAME),
                      "last-frame");
  assert_string_equal(rp_controller_name(RP_CONTROL_COUNT), "unknown");
  assert_int_equal(rp_controller_from_name("vtk5", &k), RP_EINVAL);
  assert_int_equal(rp_controller_from_name(NULL, &k), RP_EINVAL);
}

static void controller_none(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller *c = make(ctx, RP_CONTROL_NONE, 0.3);
  plant p = {100, 5};
  int f;
  (void)state;
  for (f = 0; f < 10; f++)
    assert_true(frame(c, 10, &p, NULL, NULL, NULL) == 0.3);
  rp_controller_destroy(c);
  rp_controller_destroy(NULL);
  rp_context_destroy(ctx);
}

/* Densities above 1 (a step under the base step): rho_max 4 is taken.
 * The start defaults to 1 clamped to the bounds; LAST_FRAME on a plant of
 * 2 rho ms against 10 ms wants 5, rises by 1.25x a frame from 1 and stops
 * at rho_max. */
static void controller_above_one(void **state) {
  static const double want[] = {1,           1.25,          1.5625,
                                1.953125,    2.44140625,    3.0517578125,
                                3.814697265625, 4,          4};
  rp_context *ctx = rp_test_context();
  rp_controller_desc d = {0};
  rp_controller *c = NULL;
  plant cheap = {2, 0};
  size_t f;
  (void)state;
  d.kind = RP_CONTROL_NONE;
  d.rho_max = 4;
  assert_int_equal(rp_controller_create(ctx, &d, &c), 0);
  assert_true(frame(c, 10, &cheap, NULL, NULL, NULL) == 1.0);
  rp_controller_destroy(c);
  d.rho_min = 2;
  assert_int_equal(rp_controller_create(ctx, &d, &c), 0);
  assert_true(frame(c, 10, &cheap, NULL, NULL, NULL) == 2.0);
  rp_controller_destroy(c);
  d.kind = RP_CONTROL_LAST_FRAME;
  d.rho_min = 0;
  assert_int_equal(rp_controller_create(ctx, &d, &c), 0);
  for (f = 0; f < sizeof want / sizeof want[0]; f++)
    assert_float_equal(frame(c, 10, &cheap, NULL, NULL, NULL), want[f],
                       1e-12 * want[f]);
  rp_controller_destroy(c);
  rp_context_destroy(ctx);
}

/* rho <- rho * target / t_last, a rise capped at 1 / 0.8. Target 10,
 * plant 20 rho + 1 from rho 1: 10/21, 100/221, 1000/2221,
 * 10000/22221; then the plant turns cheap (2 rho + 1) and each rise is
 * the cap, 1.25 times: 12500/22221, 15625/22221, 19531.25/22221, then
 * 24414.0625/22221 > 1 is clamped to rho_max. */
static void controller_last_frame(void **state) {
  const double want[] = {1,
                         10.0 / 21,
                         100.0 / 221,
                         1000.0 / 2221,
                         10000.0 / 22221,
                         12500.0 / 22221,
                         15625.0 / 22221,
                         19531.25 / 22221,
                         1,
                         1};
  rp_context *ctx = rp_test_context();
  rp_controller *c = make(ctx, RP_CONTROL_LAST_FRAME, 0);
  plant p = {20, 1};
  int f;
  (void)state;
  for (f = 0; f < 10; f++) {
    if (f == 4)
      p.a = 2;
    assert_close(frame(c, 10, &p, NULL, NULL, NULL), want[f], 1e-13);
  }
  /* Reset: the history is gone, the next frame is rho_start again. */
  rp_controller_reset(c);
  p.a = 1000;
  assert_true(frame(c, 10, &p, NULL, NULL, NULL) == 1);
  rp_controller_destroy(c);
  rp_context_destroy(ctx);
}

/* Seed 000 §7 "Two pass", target 10, plant 20 rho + 1, rho_start 1:
 * frame 1: pass at 1/4 costs 6 >= 5: no second pass, final 1/4;
 * frame 2: pass at 1/16 costs 2.25 < 5: second pass at
 *   (1/16) (10 - 2.25) / 2.25 = 31/144, final 31/144, time 2.25 + 5.30..;
 * frame 3: pass at 31/576 costs 299/144: second at
 *   (31/576) (1141/144) / (299/144) = 35371/172224. */
static void controller_two_pass(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller *c = make(ctx, RP_CONTROL_TWO_PASS, 0);
  plant p = {20, 1};
  double first, t, final, rho;
  int passes, again;
  (void)state;
  first = frame(c, 10, &p, &t, &final, &passes);
  assert_true(first == 0.25 && final == 0.25 && passes == 1 && t == 6);
  first = frame(c, 10, &p, &t, &final, &passes);
  assert_true(first == 0.0625);
  assert_int_equal(passes, 2);
  assert_close(final, 31.0 / 144, 1e-14);
  assert_close(t, 2.25 + 20 * 31.0 / 144 + 1, 1e-14);
  first = frame(c, 10, &p, &t, &final, &passes);
  assert_close(first, 31.0 / 576, 1e-14);
  assert_int_equal(passes, 2);
  assert_close(final, 35371.0 / 172224, 1e-13);
  rp_controller_destroy(c);

  /* Exactly half the target is not under it: one pass. */
  c = make(ctx, RP_CONTROL_TWO_PASS, 0);
  p.a = 20;
  p.b = 0;
  frame(c, 10, &p, &t, &final, &passes);
  assert_int_equal(passes, 1);
  /* A free first pass extrapolates to rho_max (not infinity). */
  assert_int_equal(rp_controller_begin_frame(c, 10, NULL, NULL, &rho), 0);
  assert_int_equal(rp_controller_end_pass(c, 0, &again, &rho), 0);
  assert_int_equal(again, 1);
  assert_true(rho == 1);
  assert_int_equal(rp_controller_end_pass(c, 3, &again, &rho), 0);
  assert_int_equal(again, 0);
  /* A third end_pass: the frame is over. */
  assert_int_equal(rp_controller_end_pass(c, 3, &again, &rho), RP_EINVAL);
  rp_controller_destroy(c);
  rp_context_destroy(ctx);
}

/* An abrupt transfer function change: the plant's slope goes from 10 to
 * 40 on frame 10. With a perfect model, predicted meets the target on
 * that very frame; last-frame renders it at the old density. */
static void controller_predicted_vs_last_frame(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller *pc = make(ctx, RP_CONTROL_PREDICTED, 0);
  rp_controller *lc = make(ctx, RP_CONTROL_LAST_FRAME, 0);
  plant pp = {10, 1}, lp = {10, 1};
  int f;
  (void)state;
  for (f = 1; f <= 14; f++) {
    double tp, tl;
    if (f == 10)
      pp.a = lp.a = 40;
    frame(pc, 10, &pp, &tp, NULL, NULL);
    frame(lc, 10, &lp, &tl, NULL, NULL);
    assert_true(tp <= 10 && tp >= 9.9);
    if (f == 10)
      assert_true(tl > 30); /* 40 * (9 / 10) + 1 = 37 */
  }
  rp_controller_destroy(pc);
  rp_controller_destroy(lc);
  rp_context_destroy(ctx);
}

/* predicted, with a model three times too cheap (t' = 10 rho + 1, the
 * frames 30 rho + 1): the first frame rises, damped, from 0.4 to 0.5
 * and takes 16 ms against a t' of 6; that is over 1.5 times t', so the
 * next frame holds 0.5 rather than rising to 0.625. Once a frame comes
 * within 1.5 times its t' the rise resumes, and a fall is never held. */
static void controller_predicted_holds_on_a_miss(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller *c = make(ctx, RP_CONTROL_PREDICTED, 0.4);
  plant cheap = {10, 1};
  double rho, r2, t;
  int again;
  (void)state;
  assert_int_equal(
      rp_controller_begin_frame(c, 10, plant_predict, &cheap, &rho), 0);
  assert_close(rho, 0.5, 1e-12);
  t = 30 * rho + 1;
  assert_int_equal(rp_controller_end_pass(c, t, &again, &r2), 0);
  assert_int_equal(
      rp_controller_begin_frame(c, 10, plant_predict, &cheap, &rho), 0);
  assert_close(rho, 0.5, 1e-12); /* held */
  /* This one came in at its t' (6 ms): the rise resumes. */
  assert_int_equal(rp_controller_end_pass(c, 6, &again, &r2), 0);
  assert_int_equal(
      rp_controller_begin_frame(c, 10, plant_predict, &cheap, &rho), 0);
  assert_close(rho, 0.625, 1e-12);
  /* A miss, then a lower target: the fall happens at once. */
  assert_int_equal(rp_controller_end_pass(c, 30 * rho + 1, &again, &r2),
                   0);
  assert_int_equal(
      rp_controller_begin_frame(c, 4, plant_predict, &cheap, &rho), 0);
  assert_true(rho < 0.4 && rho >= 0.99 * 0.3 - 1e-12);
  assert_int_equal(rp_controller_end_pass(c, 4, &again, &r2), 0);
  rp_controller_destroy(c);
  rp_context_destroy(ctx);
}

/* predicted, with an exact model (t' = 10 rho, target 10) from 0.05: the
 * first frame lifts its damped rise at a quarter of the target (rho
 * 0.25); a frame that came in at its t' lets the next lift at half
 * (0.5), and past half the rise is damped again (0.625). A frame 30 %
 * over its t' lifts at a quarter only: the damped 0.3125, priced at
 * 3.125 ms, stays. So does a frame right about a scene that then
 * changed: after 0.25 at its t', the model prices the new scene at half
 * the cost (t' = 5 rho, 1.25 ms at 0.25 against the 2.5 ms taken), and
 * the lift aims at a quarter, t' = 2.5 at 0.5, not at half (1.0). */
/* One frame of target 10 on plant p, taking `over` times p's own t' for
 * the density chosen; returns that density. */
static double frame_over(rp_controller *c, plant *p, double over) {
  double rho, next;
  int again;
  assert_int_equal(
      rp_controller_begin_frame(c, 10, plant_predict, p, &rho), 0);
  assert_int_equal(
      rp_controller_end_pass(c, over * plant_time(p, rho), &again, &next),
      0);
  assert_int_equal(again, 0);
  return rho;
}

static void controller_predicted_lifts_when_right(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller *c = make(ctx, RP_CONTROL_PREDICTED, 0.05);
  plant exact = {10, 0};
  double rho;
  (void)state;
  rho = frame_over(c, &exact, 1.0);
  assert_true(rho >= 0.2475 && rho <= 0.25);
  rho = frame_over(c, &exact, 1.0);
  assert_true(rho >= 0.495 && rho <= 0.5);
  assert_close(frame_over(c, &exact, 1.0), 1.25 * rho, 1e-12);
  rp_controller_destroy(c);

  c = make(ctx, RP_CONTROL_PREDICTED, 0.05);
  rho = frame_over(c, &exact, 1.3);
  assert_close(frame_over(c, &exact, 1.0), 1.25 * rho, 1e-12);
  rp_controller_destroy(c);

  c = make(ctx, RP_CONTROL_PREDICTED, 0.05);
  (void)frame_over(c, &exact, 1.0);
  exact.a = 5;
  rho = frame_over(c, &exact, 1.0);
  assert_true(rho >= 0.495 && rho <= 0.5);
  rp_controller_destroy(c);
  rp_context_destroy(ctx);
}

/* A target no density meets, through the controllers: plant 10 rho +
 * 10, target 5, from rho_start 1. predicted goes at once to the largest
 * density within 10 % of rho_min's 10.01 ms (rp_tune: [0.0901, 0.1011])
 * and stays there, every frame within 10 % of the fastest; last-frame
 * halves the density a frame (rho 5 / (10 rho + 10) < rho / 2) down to
 * rho_min, whose frames are under 1 % faster. */
static void controller_unreachable_target(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller *pc = make(ctx, RP_CONTROL_PREDICTED, 0);
  rp_controller *lc = make(ctx, RP_CONTROL_LAST_FRAME, 0);
  plant pp = {10, 10}, lp = {10, 10};
  double rho = 0, t = 0;
  int f;
  (void)state;
  for (f = 0; f < 20; f++) {
    rho = frame(pc, 5, &pp, &t, NULL, NULL);
    assert_true(rho >= 0.0901 && rho <= 0.1011);
    assert_true(t <= 11.011);
  }
  for (f = 0; f < 20; f++)
    rho = frame(lc, 5, &lp, &t, NULL, NULL);
  assert_true(rho == 1e-3);
  rp_controller_destroy(pc);
  rp_controller_destroy(lc);
  rp_context_destroy(ctx);
}

/* VTK: isd' = isd sqrt(t f / budget), isd in [1, 10], rho = 1 / isd^2,
 * so rho' = rho budget / (f t) while isd stays inside. f = 1.66 for a
 * budget under a second (vtkFixedPointVolumeRayCastMapper), 1 above. */
static void controller_vtk(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller_desc d = {0};
  rp_controller *c = make(ctx, RP_CONTROL_VTK, 0);
  plant p = {100, 2};
  double rho, t, want;
  int f;
  (void)state;
  rho = frame(c, 50, &p, &t, NULL, NULL);
  assert_true(rho == 1 && t == 102);
  rho = frame(c, 50, &p, &t, NULL, NULL);
  assert_close(rho, 50 / (1.66 * 102), 1e-14);
  for (f = 0; f < 5; f++) {
    want = rho * 50 / (1.66 * t);
    rho = frame(c, 50, &p, &t, NULL, NULL);
    assert_close(rho, want, 1e-13);
  }
  rp_controller_destroy(c);

  /* No damping: from isd 5 to the clamp isd 1 in one frame. */
  c = make(ctx, RP_CONTROL_VTK, 0.04);
  p.a = 1;
  p.b = 0.1;
  assert_true(frame(c, 50, &p, NULL, NULL, NULL) == 0.04);
  assert_true(frame(c, 50, &p, NULL, NULL, NULL) == 1);
  rp_controller_destroy(c);

  /* The clamp isd 10: rho 0.01 (and rho_min above it wins). */
  c = make(ctx, RP_CONTROL_VTK, 0);
  p.a = 1e4;
  p.b = 0.1;
  frame(c, 50, &p, NULL, NULL, NULL);
  assert_close(frame(c, 50, &p, NULL, NULL, NULL), 0.01, 1e-14);
  rp_controller_destroy(c);
  d.kind = RP_CONTROL_VTK;
  d.rho_min = 0.05;
  assert_int_equal(rp_controller_create(ctx, &d, &c), 0);
  frame(c, 50, &p, NULL, NULL, NULL);
  assert_true(frame(c, 50, &p, NULL, NULL, NULL) == 0.05);
  rp_controller_destroy(c);

  /* f given (vtkVolumeRayCastMapper's 1), and a budget of 2 s (f = 1). */
  d.rho_min = 0;
  d.vtk_f = 1;
  assert_int_equal(rp_controller_create(ctx, &d, &c), 0);
  p.a = 100;
  p.b = 2;
  frame(c, 50, &p, NULL, NULL, NULL);
  assert_close(frame(c, 50, &p, NULL, NULL, NULL), 50.0 / 102, 1e-14);
  rp_controller_destroy(c);
  c = make(ctx, RP_CONTROL_VTK, 0);
  p.a = 4000;
  p.b = 0;
  frame(c, 2000, &p, NULL, NULL, NULL);
  assert_close(frame(c, 2000, &p, NULL, NULL, NULL), 0.5, 1e-14);
  rp_controller_destroy(c);
  rp_context_destroy(ctx);
}

/* The UE5 weighted suggestion over the last n frames (newest first). */
static double ue_mean(const double *s, const double *t, int n, double T) {
  double num = 0, den = 0, w = 1;
  int k;
  for (k = 0; k < n; k++) {
    num += w * s[k] * sqrt(T / t[k]);
    den += w;
    w *= 0.9;
  }
  return num / den;
}

/* UE5, budget 10 (targeted 9), plant 8 rho + 0.5, s = 0.5 at start:
 * - frames 1..3: under 3 frames known, no decision;
 * - decisions from frame 4 on, none taken until 8 have passed: frames
 *   4..11 stay; frame 12 takes the amortised suggestion
 *   s1 = 0.5 + 0.9 (0.5 sqrt(9 / 2.5) - 0.5);
 * - frames 13..20 wait again; frame 21 weighs 9 frames at s1 against 7
 *   at 0.5.
 * Then the same start with a jump (slope 40) on frame 14: frame 15 is
 * still at s1 (one frame over), frame 16 drops at once (two frames over
 * budget: panic) to s1 sqrt(9 / t15), and frame 17 again (two over the
 * targeted time) using only the last two frames. */
static void controller_ue5(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller *c = make(ctx, RP_CONTROL_UE5, 0.25);
  plant p = {8, 0.5};
  double s1, t1, s21, rho, hs[16], ht[16], s16, t15, t16, s17;
  int f, k;
  (void)state;
  s1 = 0.5 + 0.9 * (0.5 * sqrt(9 / 2.5) - 0.5);
  t1 = 8 * s1 * s1 + 0.5;
  for (f = 1; f <= 11; f++)
    assert_close(frame(c, 10, &p, NULL, NULL, NULL), 0.25, 1e-15);
  for (f = 12; f <= 20; f++)
    assert_close(frame(c, 10, &p, NULL, NULL, NULL), s1 * s1, 1e-14);
  for (k = 0; k < 16; k++) {
    hs[k] = k < 9 ? s1 : 0.5;
    ht[k] = k < 9 ? t1 : 2.5;
  }
  s21 = s1 + 0.9 * (ue_mean(hs, ht, 16, 9) - s1);
  s21 = fmin(s21, 1);
  rho = frame(c, 10, &p, NULL, NULL, NULL);
  assert_close(rho, s21 * s21, 1e-13);
  assert_true(rho > s1 * s1 * 1.04);
  rp_controller_destroy(c);

  c = make(ctx, RP_CONTROL_UE5, 0.25);
  p.a = 8;
  for (f = 1; f <= 13; f++)
    frame(c, 10, &p, NULL, NULL, NULL);
  p.a = 40;
  assert_close(frame(c, 10, &p, NULL, NULL, NULL), s1 * s1, 1e-14); /* 14 */
  assert_close(frame(c, 10, &p, &t15, NULL, NULL), s1 * s1, 1e-14);
  assert_close(t15, 40 * s1 * s1 + 0.5, 1e-14);
  s16 = s1 * sqrt(9 / t15);
  assert_close(frame(c, 10, &p, &t16, NULL, NULL), s16 * s16, 1e-13);
  assert_true(t16 > 9 && t16 < 10);
  hs[0] = s16;
  ht[0] = t16;
  hs[1] = s1;
  ht[1] = t15;
  s17 = ue_mean(hs, ht, 2, 9);
  assert_close(frame(c, 10, &p, NULL, NULL, NULL), s17 * s17, 1e-13);
  assert_true(s17 < s16);
  rp_controller_destroy(c);
  rp_context_destroy(ctx);
}

/* Valve's ladder with the defaults: rho_max 1.15^(level - 50), level 50
 * at rho 1 (1.15^50 > 1000 >= 1.15^49, so level 0 is rho_min). */
static double ladder(int level) { return pow(1.15, level - 50); }

static void controller_valve(void **state) {
  const double drop3[] = {9.9, 9.9, 9.8, 9.35, 9.1};
  const double extra[] = {8.0, 8.0, 8.0, 8.0, 8.7, 8.0, 8.0, 8.9, 9.0};
  rp_context *ctx = rp_test_context();
  rp_controller *c = make(ctx, RP_CONTROL_VALVE, pow(1.15, -10));
  plant p = {5, 1}; /* always under 70 % of 10 */
  double rho;
  int f, level;
  (void)state;
  /* Raises: one level per 5 frames (2 ignored + 3 under 70 %), from
   * level 40 to the top, 50, then no further. */
  for (f = 1; f <= 60; f++) {
    level = 40 + (f - 1) / 5;
    if (level > 50)
      level = 50;
    assert_close(frame(c, 10, &p, NULL, NULL, NULL), ladder(level), 1e-12);
  }
  rp_controller_destroy(c);

  /* Three frames over 90 %, each too close to the last for the
   * extrapolation rule (9.35 + (9.35 - 9.8) = 8.9): dropped 2 levels on
   * frame 6; then under 70 %: up one level on frame 11. */
  c = make(ctx, RP_CONTROL_VALVE, 0);
  for (f = 1; f <= 5; f++)
    assert_true(frame_scripted(c, 10, drop3[f - 1]) == 1);
  for (f = 6; f <= 10; f++)
    assert_close(frame_scripted(c, 10, 6.0), ladder(48), 1e-12);
  assert_close(frame_scripted(c, 10, 6.0), ladder(49), 1e-12);
  rp_controller_destroy(c);

  /* Extrapolation: frame 5 at 8.7 > 8.5 and 8.7 + 0.7 > 9: frame 6 drops
   * 2 levels. After it, frames 6 and 7 are ignored: frame 8's 8.9 would
   * fire the rule at frame 9 but is only the 3rd frame at the level; at
   * frame 10, 9.0 + 0.1 > 9 fires it. */
  c = make(ctx, RP_CONTROL_VALVE, 0);
  for (f = 1; f <= 9; f++) {
    rho = frame_scripted(c, 10, extra[f - 1]);
    assert_close(rho, ladder(f <= 5 ? 50 : 48), 1e-12);
  }
  assert_close(frame_scripted(c, 10, 8.0), ladder(46), 1e-12);
  rp_controller_destroy(c);

  /* Flat at 8.7: over 85 % but the extrapolation stays at 8.7: no drop;
   * not under 70 %: no raise. Constant 9.5 at the bottom: stays. */
  c = make(ctx, RP_CONTROL_VALVE, 0);
  for (f = 1; f <= 20; f++)
    assert_true(frame_scripted(c, 10, 8.7) == 1);
  rp_controller_destroy(c);
  c = make(ctx, RP_CONTROL_VALVE, 1e-3);
  for (f = 1; f <= 20; f++)
    assert_true(frame_scripted(c, 10, 9.5) == 1e-3);
  rp_controller_destroy(c);
  rp_context_destroy(ctx);
}

static void controller_misuse(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller *c = make(ctx, RP_CONTROL_LAST_FRAME, 0.5);
  rp_controller *twin = make(ctx, RP_CONTROL_LAST_FRAME, 0.5);
  rp_controller *pc = make(ctx, RP_CONTROL_PREDICTED, 0);
  double rho = -1, r2;
  int again = -1;
  (void)state;
  assert_int_equal(rp_controller_end_pass(c, 5, &again, &rho), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "without begin_frame"));
  assert_true(rho == -1 && again == -1);
  assert_int_equal(rp_controller_begin_frame(c, NAN, NULL, NULL, &rho),
                   RP_ENOTFINITE);
  assert_non_null(strstr(rp_last_error(ctx), "target_ms"));
  assert_int_equal(rp_controller_begin_frame(c, INFINITY, NULL, NULL, &rho),
                   RP_ENOTFINITE);
  assert_int_equal(rp_controller_begin_frame(c, 0, NULL, NULL, &rho),
                   RP_EINVAL);
  assert_int_equal(rp_controller_begin_frame(c, -3, NULL, NULL, &rho),
                   RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "not positive"));
  assert_true(rho == -1);
  assert_int_equal(rp_controller_begin_frame(pc, 10, NULL, NULL, &rho),
                   RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "predict function"));

  assert_int_equal(rp_controller_begin_frame(c, 10, NULL, NULL, &rho), 0);
  assert_int_equal(rp_controller_begin_frame(c, 10, NULL, NULL, &r2),
                   RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "while a frame is open"));
  assert_int_equal(rp_controller_end_pass(c, NAN, &again, &r2),
                   RP_ENOTFINITE);
  assert_int_equal(rp_controller_end_pass(c, INFINITY, &again, &r2),
                   RP_ENOTFINITE);
  assert_int_equal(rp_controller_end_pass(c, -1, &again, &r2), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "negative"));
  assert_int_equal(rp_controller_end_pass(c, 20, &again, &r2), 0);
  assert_int_equal(again, 0);
  /* The twin saw only the good calls: the two agree from here on. */
  assert_int_equal(rp_controller_begin_frame(twin, 10, NULL, NULL, &r2), 0);
  assert_int_equal(rp_controller_end_pass(twin, 20, &again, &r2), 0);
  assert_int_equal(rp_controller_begin_frame(c, 10, NULL, NULL, &rho), 0);
  assert_int_equal(rp_controller_begin_frame(twin, 10, NULL, NULL, &r2), 0);
  assert_true(rho == r2 && rho == 0.25);
  /* Reset closes an open frame. */
  rp_controller_reset(c);
  assert_int_equal(rp_controller_begin_frame(c, 10, NULL, NULL, &rho), 0);
  assert_true(rho == 0.5);
  rp_controller_destroy(c);
  rp_controller_destroy(twin);
  rp_controller_destroy(pc);
  rp_context_destroy(ctx);
}

static void controller_bad_desc(void **state) {
  rp_context *ctx = rp_test_context();
  rp_controller_desc d = {0};
  rp_controller *c = (rp_controller *)&d; /* must stay untouched */
  (void)state;
  assert_int_equal(rp_controller_create(NULL, &d, &c), RP_EINVAL);
  assert_int_equal(rp_controller_create(ctx, &d, NULL), RP_EINVAL);
  d.kind = RP_CONTROL_COUNT;
  assert_int_equal(rp_controller_create(ctx, &d, &c), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "kind"));
  d.kind = RP_CONTROL_VALVE;
  d.rho_min = 0.5;
  d.rho_max = 0.4;
  assert_int_equal(rp_controller_create(ctx, &d, &c), RP_EINVAL);
  d.rho_min = 0;
  d.rho_max = -1;
  assert_int_equal(rp_controller_create(ctx, &d, &c), RP_EINVAL);
  d.rho_max = 0.5;
  d.rho_start = 0.7;
  assert_int_equal(rp_controller_create(ctx, &d, &c), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "rho_start"));
  d.rho_start = 0;
  d.raise_limit = 0.9;
  assert_int_equal(rp_controller_create(ctx, &d, &c), RP_EINVAL);
  d.raise_limit = NAN;
  assert_int_equal(rp_controller_create(ctx, &d, &c), RP_ENOTFINITE);
  assert_non_null(strstr(rp_last_error(ctx), "raise_limit"));
  d.raise_limit = 0;
  d.vtk_f = -1;
  assert_int_equal(rp_controller_create(ctx, &d, &c), RP_EINVAL);
  d.vtk_f = 0;
  d.tune_time_us = -1;
  assert_int_equal(rp_controller_create(ctx, &d, &c), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "tune_time_us"));
  d.tune_time_us = INFINITY;
  assert_int_equal(rp_controller_create(ctx, &d, &c), RP_ENOTFINITE);
  assert_true(c == (rp_controller *)&d);
  /* A NULL desc is all defaults. */
  assert_int_equal(rp_controller_create(ctx, NULL, &c), 0);
  rp_controller_destroy(c);
  rp_context_destroy(ctx);
}

static int fail_after;
static void *counting_alloc(size_t size, void *user) {
  (void)user;
  return fail_after-- > 0 ? malloc(size) : NULL;
}
static void counting_free(void *ptr, void *user) {
  (void)user;
  free(ptr);
}

static void controller_out_of_memory(void **state) {
  rp_context_desc cd = {0};
  rp_context *ctx = NULL;
  rp_controller *c = NULL;
  (void)state;
  cd.allocator.alloc = counting_alloc;
  cd.allocator.free = counting_free;
  fail_after = 1; /* the context, then nothing */
  assert_int_equal(rp_context_create(&cd, &ctx), 0);
  assert_int_equal(rp_controller_create(ctx, NULL, &c), RP_ENOMEM);
  assert_null(c);
  rp_context_destroy(ctx);
}

static uint64_t rng = 88172645463325252ULL;
static double urand(void) {
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return (double)(rng >> 11) * 0x1p-53;
}

/* Anything a model can say, sane or not. */
static double wild(void) {
  double u = urand();
  if (u < 0.1)
    return 0;
  if (u < 0.15)
    return 1e300;
  if (u < 0.2)
    return 1e-300;
  return pow(10, urand() * 8 - 4);
}

static double wild_predict(void *u, double rho) {
  double v = urand();
  (void)u;
  (void)rho;
  return v < 0.1 ? NAN : v < 0.2 ? -1 : v < 0.25 ? INFINITY : wild();
}

/* No rule may ever emit NaN or leave [rho_min, rho_max], whatever the
 * times and targets. */
static void controller_never_out_of_range(void **state) {
  rp_context *ctx = rp_test_context();
  int k, f;
  (void)state;
  for (k = 0; k < RP_CONTROL_COUNT; k++) {
    rp_controller_desc d = {0};
    rp_controller *c;
    d.kind = (rp_controller_kind)k;
    d.rho_min = 0.01;
    d.rho_max = 0.9;
    assert_int_equal(rp_controller_create(ctx, &d, &c), 0);
    for (f = 0; f < 2000; f++) {
      double target = f % 50 == 49 ? 1e-9 : pow(10, urand() * 4 - 1);
      double rho;
      int again = 1, passes = 0;
      assert_int_equal(rp_controller_begin_frame(c, target, wild_predict,
                                                 NULL, &rho),
                       0);
      while (again) {
        assert_true(rho >= 0.01 && rho <= 0.9);
        assert_int_equal(rp_controller_end_pass(c, wild(), &again, &rho),
                         0);
        assert_true(++passes <= 2);
      }
      assert_true(rho >= 0.01 && rho <= 0.9);
    }
    rp_controller_destroy(c);
  }
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(tune_linear_closed_form),
      cmocka_unit_test(tune_power_law),
      cmocka_unit_test(tune_step_model),
      cmocka_unit_test(tune_constant_models),
      cmocka_unit_test(tune_wide_bracket),
      cmocka_unit_test(tune_nan_in_places),
      cmocka_unit_test(tune_damping),
      cmocka_unit_test(tune_damping_lift),
      cmocka_unit_test(tune_lift_share),
      cmocka_unit_test(tune_clamps),
      cmocka_unit_test(tune_extreme_targets),
      cmocka_unit_test(tune_unreachable_target),
      cmocka_unit_test(tune_time_limit),
      cmocka_unit_test(tune_bad_desc),
      cmocka_unit_test(controller_names),
      cmocka_unit_test(controller_none),
      cmocka_unit_test(controller_above_one),
      cmocka_unit_test(controller_last_frame),
      cmocka_unit_test(controller_two_pass),
      cmocka_unit_test(controller_predicted_vs_last_frame),
      cmocka_unit_test(controller_predicted_holds_on_a_miss),
      cmocka_unit_test(controller_predicted_lifts_when_right),
      cmocka_unit_test(controller_unreachable_target),
      cmocka_unit_test(controller_vtk),
      cmocka_unit_test(controller_ue5),
      cmocka_unit_test(controller_valve),
      cmocka_unit_test(controller_misuse),
      cmocka_unit_test(controller_bad_desc),
      cmocka_unit_test(controller_out_of_memory),
      cmocka_unit_test(controller_never_out_of_range),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
