/* bench pacing --pareto's comparison (cli/bench_pareto.c): a rule's
 * density at a miss rate, along the upper envelope of its measured
 * points, against values worked out by hand and by brute force:
 * - hand-worked curves: a dominated point left out, a tie, a NaN point,
 *   one point, none; a rate under, on, between, past the frontier and
 *   over the measured range;
 * - on random curves, at any m between two measured miss rates the
 *   density is the envelope worked out from its definition
 *   (brute_envelope: the most any point reached at a miss rate <= m,
 *   found by scanning every point, joined by a line to the next point
 *   that betters it), never under that most;
 * - the comparison: the best rule where it is known, its ratio, a floor
 *   taken, an unknown rule left out, vtk as shipped. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "bench_pacing.h"
#include "test_util.h"

#define TOL 1e-12

static double at(const double *miss, const double *dens, int n, double m,
                 int want_where) {
  int where = -1;
  double d = cli_pareto_density_at(miss, dens, n, m, &where);
  assert_int_equal(where, want_where);
  return d;
}

/* The density at m is `want` (NaN: unknown), and m lies `where`. */
static void at_is(const double *miss, const double *dens, int n, double m,
                  int where, double want) {
  double d = at(miss, dens, n, m, where);
  if (isnan(want) ? !isnan(d) : !(fabs(d - want) < TOL))
    fail_msg("at %g: %.17g, not %.17g", m, d, want);
}

/* (0.01, 0.20), (0.05, 0.15), (0.10, 0.30), (0.30, 0.25), given out of
 * order: the frontier is (0.01, 0.20) and (0.10, 0.30); the points at
 * 0.05 and 0.30 are dominated (more misses, less density). */
static void envelope_by_hand(void **state) {
  const double miss[] = {0.10, 0.01, 0.30, 0.05};
  const double dens[] = {0.30, 0.20, 0.25, 0.15};
  (void)state;
  /* 0.20 + (0.30 - 0.20) (0.05 - 0.01) / (0.10 - 0.01) = 0.2444... */
  at_is(miss, dens, 4, 0.05, CLI_PARETO_INSIDE, 0.20 + 0.10 * 0.04 / 0.09);
  at_is(miss, dens, 4, 0.01, CLI_PARETO_INSIDE, 0.20);
  at_is(miss, dens, 4, 0.10, CLI_PARETO_INSIDE, 0.30);
  /* Past the frontier's top, within the measured range: its density. */
  at_is(miss, dens, 4, 0.20, CLI_PARETO_INSIDE, 0.30);
  at_is(miss, dens, 4, 0.30, CLI_PARETO_INSIDE, 0.30);
  /* Over the measured range: the top density, a floor. */
  at_is(miss, dens, 4, 0.50, CLI_PARETO_ABOVE, 0.30);
  /* Under it: unknown. */
  at_is(miss, dens, 4, 0.005, CLI_PARETO_BELOW, NAN);
}

static void ties_nan_and_few_points(void **state) {
  const double tie_m[] = {0.0, 0.2, 0.0}, tie_d[] = {0.10, 0.30, 0.15};
  const double nan_m[] = {NAN, 0.1}, nan_d[] = {0.5, 0.2};
  const double one_m[] = {0.05}, one_d[] = {0.2};
  (void)state;
  /* Of two points at the same miss rate the denser counts. */
  at_is(tie_m, tie_d, 3, 0.0, CLI_PARETO_INSIDE, 0.15);
  at_is(tie_m, tie_d, 3, 0.1, CLI_PARETO_INSIDE, 0.225);
  /* A point without a figure is no point. */
  at_is(nan_m, nan_d, 2, 0.1, CLI_PARETO_INSIDE, 0.2);
  at_is(nan_m, nan_d, 2, 0.05, CLI_PARETO_BELOW, NAN);
  at_is(one_m, one_d, 1, 0.05, CLI_PARETO_INSIDE, 0.2);
  at_is(one_m, one_d, 1, 0.06, CLI_PARETO_ABOVE, 0.2);
  at_is(one_m, one_d, 0, 0.05, CLI_PARETO_EMPTY, NAN);
  at_is(one_m, one_d, 1, NAN, CLI_PARETO_EMPTY, NAN);
  /* where may be NULL. */
  assert_true(fabs(cli_pareto_density_at(one_m, one_d, 1, 0.05, NULL) -
                   0.2) < TOL);
}

static uint32_t next(uint32_t *s) {
  *s = *s * 1664525u + 1013904223u;
  return *s >> 8;
}

/* The most density any point reached at a miss rate <= m. */
static double brute_best(const double *miss, const double *dens, int n,
                         double m) {
  double best = -INFINITY;
  int i;
  for (i = 0; i < n; i++)
    if (miss[i] <= m && dens[i] > best)
      best = dens[i];
  return best;
}

/* The envelope at m, from its definition: the step (the most density at
 * a miss rate <= m, first reached at m_lo) and the next point that
 * betters it (the least miss rate over m with more density, the most
 * density at that rate), joined by a line; the step alone if none. */
static double brute_envelope(const double *miss, const double *dens, int n,
                             double m) {
  double d_lo = brute_best(miss, dens, n, m), m_lo = INFINITY;
  double m_hi = INFINITY, d_hi = -INFINITY;
  int i;
  for (i = 0; i < n; i++) {
    if (miss[i] <= m && dens[i] == d_lo && miss[i] < m_lo)
      m_lo = miss[i];
    if (miss[i] > m && dens[i] > d_lo && miss[i] <= m_hi) {
      d_hi = miss[i] < m_hi ? dens[i] : fmax(d_hi, dens[i]);
      m_hi = miss[i];
    }
  }
  if (m_hi == INFINITY)
    return d_lo;
  return d_lo + (d_hi - d_lo) * (m - m_lo) / (m_hi - m_lo);
}

static void envelope_by_brute_force(void **state) {
  double miss[CLI_PARETO_MAX_SETTINGS], dens[CLI_PARETO_MAX_SETTINGS];
  uint32_t seed = 5;
  int trial, i, j;
  (void)state;
  for (trial = 0; trial < 500; trial++) {
    int n = 1 + (int)(next(&seed) % CLI_PARETO_MAX_SETTINGS);
    for (i = 0; i < n; i++) {
      /* Coarse values, so that ties happen. */
      miss[i] = 0.01 * (double)(next(&seed) % 20);
      dens[i] = 0.05 * (double)(1 + next(&seed) % 10);
    }
    for (i = 0; i < n; i++) {
      double d = at(miss, dens, n, miss[i], CLI_PARETO_INSIDE);
      /* At least what the rule reached there, more where a dominated
       * point lies under the line between two that dominate it. */
      assert_true(d >= brute_best(miss, dens, n, miss[i]) - TOL);
      assert_true(fabs(d - brute_envelope(miss, dens, n, miss[i])) < TOL);
      for (j = 0; j < n; j++) {
        double lo = fmin(miss[i], miss[j]), hi = fmax(miss[i], miss[j]);
        double m = lo + (hi - lo) * (double)(next(&seed) % 1000) / 1000.0;
        double dm = at(miss, dens, n, m, CLI_PARETO_INSIDE);
        assert_true(fabs(dm - brute_envelope(miss, dens, n, m)) < TOL);
        /* Along the envelope, more misses never cost density. */
        assert_true(dm >= brute_best(miss, dens, n, lo) - TOL);
      }
    }
  }
}

static void comparison(void **state) {
  double miss[CLI_PARETO_RULES][CLI_PARETO_MAX_SETTINGS];
  double dens[CLI_PARETO_RULES][CLI_PARETO_MAX_SETTINGS];
  int n[CLI_PARETO_RULES] = {4, 1, 1, 0};
  const double lf_m[] = {0.10, 0.01, 0.30, 0.05};
  const double lf_d[] = {0.30, 0.20, 0.25, 0.15};
  cli_pareto_cmp x;
  (void)state;
  assert_int_equal(cli_pareto_rules[0], RP_CONTROL_LAST_FRAME);
  assert_int_equal(cli_pareto_rules[1], RP_CONTROL_VTK);
  assert_int_equal(cli_pareto_rules[2], RP_CONTROL_UE5);
  assert_int_equal(cli_pareto_rules[3], RP_CONTROL_VALVE);
  memcpy(miss[0], lf_m, sizeof lf_m);
  memcpy(dens[0], lf_d, sizeof lf_d);
  miss[1][0] = 0.01; /* vtk: never missed 5 %: a floor of 0.1 */
  dens[1][0] = 0.10;
  miss[2][0] = 0.08; /* ue5: never under 8 %: unknown at 5 % */
  dens[2][0] = 0.90;
  cli_pareto_compare(0.05, 0.33, miss, dens, n, 0.11, &x);
  assert_int_equal(x.where[0], CLI_PARETO_INSIDE);
  assert_int_equal(x.where[1], CLI_PARETO_ABOVE);
  assert_int_equal(x.where[2], CLI_PARETO_BELOW);
  assert_int_equal(x.where[3], CLI_PARETO_EMPTY);
  assert_true(fabs(x.at[1] - 0.10) < TOL);
  assert_true(isnan(x.at[2]) && isnan(x.at[3]));
  assert_int_equal(x.best, 0);
  assert_true(fabs(x.ratio_best - 0.33 / (0.20 + 0.10 * 0.04 / 0.09)) <
              TOL);
  assert_true(fabs(x.ratio_vtk - 3.0) < TOL);
  /* A floor can be the best; a tie goes to the earlier rule. */
  dens[1][0] = 0.30;
  cli_pareto_compare(0.20, 0.6, miss, dens, n, NAN, &x);
  assert_int_equal(x.where[0], CLI_PARETO_INSIDE);
  assert_int_equal(x.where[2], CLI_PARETO_ABOVE);
  assert_true(fabs(x.at[2] - 0.90) < TOL);
  assert_int_equal(x.best, 2);
  assert_true(fabs(x.ratio_best - 0.6 / 0.9) < TOL);
  assert_true(isnan(x.ratio_vtk));
  n[2] = 0;
  cli_pareto_compare(0.20, 0.6, miss, dens, n, NAN, &x);
  assert_true(fabs(x.at[0] - 0.30) < TOL && fabs(x.at[1] - 0.30) < TOL);
  assert_int_equal(x.best, 0);
  /* No rule known there: no best, no ratio. */
  n[0] = n[1] = 0;
  cli_pareto_compare(0.20, 0.6, miss, dens, n, NAN, &x);
  assert_int_equal(x.best, -1);
  assert_true(isnan(x.ratio_best));
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(envelope_by_hand),
      cmocka_unit_test(ties_nan_and_few_points),
      cmocka_unit_test(envelope_by_brute_force),
      cmocka_unit_test(comparison),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
