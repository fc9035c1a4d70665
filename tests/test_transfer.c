/* Transfer functions: validation, LUT, the exact integral and maximum the
 * histograms rely on, and opacity correction against long double. */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "test_util.h"

/* ---- opacity correction ------------------------------------------------ */

/* Bound: the float result is within one float ulp of the exact value
 * (computed here in 80-bit long double), for every step ratio in
 * [1e-3, 1e3] and alpha from 1e-7 to 1 - 1e-7. */
static void opacity_correction_matches_long_double(void **state) {
  static const double alphas[] = {1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 0.01, 0.1,
                                  0.25, 0.5, 0.75, 0.9, 0.99, 0.999,
                                  1 - 1e-4, 1 - 1e-5, 1 - 1e-6, 1 - 1e-7};
  size_t i;
  int k, checked = 0;
  double worst_ulps = 0;
  (void)state;
  for (i = 0; i < sizeof alphas / sizeof alphas[0]; i++) {
    float a = (float)alphas[i];
    for (k = -60; k <= 60; k++) {
      float ratio = powf(10.0f, k / 20.0f); /* 1e-3 .. 1e3 */
      float got = rp_opacity_correct(a, ratio, 1.0f);
      long double exact =
          -expm1l((long double)ratio * log1pl(-(long double)a));
      float fexact = (float)exact;
      double ulp = nextafterf(fexact, INFINITY) - fexact;
      double err = fabs((double)((long double)got - exact));
      if (ulp == 0 || fexact >= 1.0f)
        ulp = FLT_EPSILON / 2;
      assert_true(got >= 0.0f && got <= 1.0f);
      if (err / ulp > worst_ulps)
        worst_ulps = err / ulp;
      assert_true(err <= ulp);
      checked++;
    }
  }
  assert_int_equal(checked, 17 * 121);
  print_message("opacity correction: worst error %.3f ulp over %d cases\n",
                worst_ulps, checked);
}

static void opacity_correction_closed_forms(void **state) {
  static const float alphas[] = {1e-6f, 0.01f, 0.3f, 0.5f, 0.9f, 0.999f};
  size_t i;
  (void)state;
  for (i = 0; i < sizeof alphas / sizeof alphas[0]; i++) {
    double a = alphas[i];
    /* ratio 1 is the identity; 2 and 1/2 have closed forms. */
    assert_float_equal(rp_opacity_correct(alphas[i], 1, 1), a, 1e-7 * a);
    assert_float_equal(rp_opacity_correct(alphas[i], 2, 1), 2 * a - a * a,
                       1e-6 * a);
    assert_float_equal(rp_opacity_correct(alphas[i], .5f, 1),
                       a / (1 + sqrt(1 - a)), 1e-6 * a);
    /* Only the ratio matters. */
    assert_float_equal(rp_opacity_correct(alphas[i], 0.75f, 0.25f),
                       rp_opacity_correct(alphas[i], 3, 1), 0);
  }
  /* The ends are exact at any step. */
  assert_true(rp_opacity_correct(0, 1e-3f, 1) == 0.0f);
  assert_true(rp_opacity_correct(0, 1e3f, 1) == 0.0f);
  assert_true(rp_opacity_correct(1, 1e-3f, 1) == 1.0f);
  assert_true(rp_opacity_correct(1, 1e3f, 1) == 1.0f);
  assert_true(rp_opacity_correct(-0.5f, 1, 1) == 0.0f);
  assert_true(isnan(rp_opacity_correct(0.5f, 0, 1)));
  assert_true(isnan(rp_opacity_correct(0.5f, NAN, 1)));
}

/* Why the expm1/log1p form: the naive float formula loses a tiny alpha at a
 * tiny step entirely. */
static void naive_form_fails_where_ours_holds(void **state) {
  float a = 1e-7f, r = 1e-3f;
  float naive = 1.0f - powf(1.0f - a, r);
  float ours = rp_opacity_correct(a, r, 1.0f);
  double exact = -expm1((double)r * log1p(-(double)a));
  (void)state;
  assert_true(fabs(naive - exact) / exact > 0.5);
  assert_true(fabs(ours - exact) / exact < 1e-6);
}

/* ---- validation ---------------------------------------------------------- */

static int make(rp_context *ctx, const rp_tf_point *p, int n, rp_tf **tf) {
  rp_tf_desc d = {0};
  d.points = p;
  d.count = n;
  return rp_tf_create(ctx, &d, tf);
}

static void rejects_bad_points(void **state) {
  rp_context *ctx = rp_test_context();
  rp_tf *tf = NULL;
  rp_tf_point ok[2] = {{0, 0, 0, 0, 0}, {1, 1, 1, 1, 1}};
  rp_tf_point p[2];
  rp_tf_desc d = {0};
  (void)state;

  memcpy(p, ok, sizeof p);
  p[1].a = NAN;
  assert_int_equal(make(ctx, p, 2, &tf), RP_ENOTFINITE);
  assert_non_null(strstr(rp_last_error(ctx), "point 1 field 'a'"));
  memcpy(p, ok, sizeof p);
  p[0].x = INFINITY;
  assert_int_equal(make(ctx, p, 2, &tf), RP_ENOTFINITE);
  assert_non_null(strstr(rp_last_error(ctx), "point 0 field 'x'"));
  memcpy(p, ok, sizeof p);
  p[1].g = 1.5f;
  assert_int_equal(make(ctx, p, 2, &tf), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "'g': value 1.5"));
  memcpy(p, ok, sizeof p);
  p[0].x = -0.1f;
  assert_int_equal(make(ctx, p, 2, &tf), RP_ERANGE);
  memcpy(p, ok, sizeof p);
  p[0].x = 0.7f, p[1].x = 0.3f;
  assert_int_equal(make(ctx, p, 2, &tf), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "strictly increasing"));
  memcpy(p, ok, sizeof p);
  p[0].x = 0.5f, p[1].x = 0.5f;
  assert_int_equal(make(ctx, p, 2, &tf), RP_EINVAL);
  assert_int_equal(make(ctx, ok, 0, &tf), RP_EINVAL);
  assert_int_equal(make(ctx, NULL, 2, &tf), RP_EINVAL);
  d.points = ok, d.count = 2, d.lut_size = 1;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "lut_size"));
  d.lut_size = 0, d.reference_step = -1;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), RP_ERANGE);
  d.reference_step = NAN;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), RP_ENOTFINITE);
  assert_null(tf); /* failed calls leave the output alone */
  assert_int_equal(rp_tf_create_preset(ctx, "no-such", &tf), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "minmax-bone"));
  assert_int_equal(rp_tf_create(NULL, &d, &tf), RP_EINVAL);
  rp_tf_destroy(NULL);
  rp_context_destroy(ctx);
}

static void presets_build(void **state) {
  rp_context *ctx = rp_test_context();
  const char *const *names = rp_tf_preset_names();
  int n = 0, i, size;
  (void)state;
  for (; names[n] != NULL; n++) {
    rp_tf *tf = NULL;
    const float *lut;
    assert_int_equal(rp_tf_create_preset(ctx, names[n], &tf), 0);
    lut = rp_tf_lut(tf, &size);
    assert_int_equal(size, 1024);
    assert_float_equal(rp_tf_reference_step(tf), 1.0f, 0);
    for (i = 0; i < size; i++) {
      if (strcmp(names[n], "transparent") == 0)
        assert_true(lut[4 * i + 3] == 0.0f);
      if (strcmp(names[n], "opaque") == 0)
        assert_true(lut[4 * i + 3] == 1.0f);
    }
    rp_tf_destroy(tf);
  }
  assert_true(n >= 6);
  rp_context_destroy(ctx);
}

/* ---- the function the LUT defines --------------------------------------- */

/* Control points on LUT knots (lut_size 129: knots at k/128, exact in
 * binary), so the interpolated LUT equals the control-point function
 * exactly and the test can evaluate it in closed form. */
#define K_ZERO_END 0.296875 /* 38/128 */
#define K_PEAK 0.40625      /* 52/128 */
static const rp_tf_point knots[] = {{0.0f, 0, 0, 0, 0},
                                    {(float)K_ZERO_END, .2f, .3f, .4f, 0},
                                    {(float)K_PEAK, .5f, .5f, .5f, .8f},
                                    {0.546875f, .6f, .6f, .6f, .1f},
                                    {0.796875f, .9f, .9f, .9f, .1f},
                                    {1.0f, 1, 1, 1, .5f}};

static double knot_alpha(double x) {
  int i;
  int n = (int)(sizeof knots / sizeof knots[0]);
  if (x <= 0)
    return knots[0].a;
  if (x >= 1)
    return knots[n - 1].a;
  for (i = 0; knots[i + 1].x < x; i++) {
  }
  return knots[i].a + (x - knots[i].x) / (knots[i + 1].x - knots[i].x) *
                          (knots[i + 1].a - knots[i].a);
}

/* Closed-form integral of the piecewise-linear control-point alpha. */
static double knot_integral(double x0, double x1) {
  double sum = 0, xa = x0;
  int i, n = (int)(sizeof knots / sizeof knots[0]);
  for (i = 0; i < n; i++) {
    double xb = knots[i].x;
    if (xb <= xa)
      continue;
    if (xb >= x1)
      break;
    sum += 0.5 * (knot_alpha(xa) + knot_alpha(xb)) * (xb - xa);
    xa = xb;
  }
  return sum + 0.5 * (knot_alpha(xa) + knot_alpha(x1)) * (x1 - xa);
}

static rp_tf *knot_tf(rp_context *ctx) {
  rp_tf_desc d = {0};
  rp_tf *tf = NULL;
  d.points = knots;
  d.count = (int)(sizeof knots / sizeof knots[0]);
  d.lut_size = 129;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), 0);
  return tf;
}

static void lut_sampling_is_the_control_point_function(void **state) {
  rp_context *ctx = rp_test_context();
  rp_tf *tf = knot_tf(ctx);
  int i;
  (void)state;
  for (i = 0; i <= 2000; i++) {
    double x = i / 2000.0;
    float rgba[4];
    rp__tf_sample(tf, x, rgba);
    assert_float_equal(rgba[3], knot_alpha(x), 2e-6);
  }
  rp_tf_destroy(tf);
  rp_context_destroy(ctx);
}

static void alpha_mean_and_max_match_closed_form(void **state) {
  rp_context *ctx = rp_test_context();
  rp_tf *tf = knot_tf(ctx);
  uint64_t s = 12345;
  int i;
  (void)state;
  for (i = 0; i < 5000; i++) {
    double x0, x1, m, brute_max = 0;
    int k;
    s = s * 6364136223846793005ull + 1442695040888963407ull;
    x0 = (double)(s >> 11) / 9007199254740992.0;
    s = s * 6364136223846793005ull + 1442695040888963407ull;
    x1 = x0 + (1 - x0) * (double)(s >> 11) / 9007199254740992.0;
    if (x1 > x0)
      assert_float_equal(rp__tf_alpha_mean(tf, x0, x1),
                         knot_integral(x0, x1) / (x1 - x0), 1e-6);
    /* The maximum of a piecewise-linear function: ends and knots. */
    brute_max = fmax(knot_alpha(x0), knot_alpha(x1));
    for (k = 0; k < 6; k++)
      if (knots[k].x > x0 && knots[k].x < x1)
        brute_max = fmax(brute_max, knots[k].a);
    m = rp__tf_alpha_max(tf, x0, x1);
    assert_float_equal(m, brute_max, 2e-6);
  }
  /* Degenerate interval: the point value. */
  assert_float_equal(rp__tf_alpha_mean(tf, K_PEAK, K_PEAK), 0.8, 1e-6);
  rp_tf_destroy(tf);
  rp_context_destroy(ctx);
}

/* "Empty" must be exact: zero up to K_ZERO_END exactly, positive past. */
static void zero_is_exact(void **state) {
  rp_context *ctx = rp_test_context();
  rp_tf *tf = knot_tf(ctx);
  (void)state;
  assert_true(rp__tf_alpha_mean(tf, 0.0, K_ZERO_END) == 0.0);
  assert_true(rp__tf_alpha_max(tf, 0.0, K_ZERO_END) == 0.0f);
  assert_true(rp__tf_alpha_mean(tf, 0.1, K_ZERO_END + 1e-9) > 0.0);
  assert_true(rp__tf_alpha_max(tf, 0.1, K_ZERO_END + 1e-6) > 0.0f);
  /* Outside [0, 1] the function is constant. */
  assert_float_equal(rp__tf_alpha_mean(tf, 1.0, 3.0), 0.5, 1e-7);
  assert_true(rp__tf_alpha_mean(tf, -2.0, 0.0) == 0.0);
  rp_tf_destroy(tf);
  rp_context_destroy(ctx);
}

/* rp__tf_alpha_any, the constant-time test an AO brick mask asks per
 * brick, against rp__tf_alpha_max > 0, the scan it replaces: equal on
 * every interval of 1.2 million random and edge ones (ends on table
 * entries among them), over TFs with runs of zero alpha (a narrow window,
 * a step, a single non-zero entry), the transparent and opaque
 * presets. */
static void alpha_any_is_alpha_max_above_zero(void **state) {
  static const rp_tf_point window[4] = {{0.0f, 0, 0, 0, 0.0f},
                                        {0.40f, 1, 1, 1, 0.0f},
                                        {0.41f, 1, 1, 1, 0.7f},
                                        {0.42f, 1, 1, 1, 0.0f}};
  static const rp_tf_point step[3] = {{0.0f, 0, 0, 0, 0.0f},
                                      {0.5f, 1, 1, 1, 0.0f},
                                      {0.5001f, 1, 1, 1, 1e-6f}};
  /* One table entry (512 of 1025) above 0, its neighbours 0: an
   * interval from entry 511 or before to entry 513 exactly sees it only
   * inside. */
  static const rp_tf_point spike[3] = {{511.0f / 1024, 1, 1, 1, 0.0f},
                                       {512.0f / 1024, 1, 1, 1, 0.5f},
                                       {513.0f / 1024, 1, 1, 1, 0.0f}};
  const char *presets[4] = {"transparent", "opaque", "minmax-bone",
                            "nearly-transparent"};
  rp_context *ctx = rp_test_context();
  uint64_t seed = 12345, tried = 0, on = 0;
  int k, i;
  (void)state;
  for (k = 0; k < 8; k++) {
    rp_tf *tf = NULL;
    uint32_t *prefix;
    if (k < 4) {
      tf = rp_test_preset(ctx, presets[k]);
    } else {
      rp_tf_desc d = {0};
      d.points = k == 4 ? window : k == 7 ? spike : step;
      d.count = k == 4 ? 4 : 3;
      /* 2^n + 1 entries: an interval can end exactly on an entry, where
       * the interpolation gives its neighbour no weight. */
      d.lut_size = k == 6 ? 9 : 1025;
      assert_int_equal(rp_tf_create(ctx, &d, &tf), 0);
    }
    prefix = malloc(((size_t)tf->lut_size + 1) * sizeof *prefix);
    assert_non_null(prefix);
    rp__tf_alpha_prefix(tf, prefix);
    for (i = 0; i < 150000; i++) {
      double x0, x1;
      int any, max;
      seed = seed * 6364136223846793005ull + 1442695040888963407ull;
      x0 = (double)(seed >> 11) / 9007199254740992.0 * 1.2 - 0.1;
      seed = seed * 6364136223846793005ull + 1442695040888963407ull;
      x1 = i % 4 == 0 ? x0 + (double)(seed >> 40) * 1e-9
           : i % 4 == 2 ? (double)(seed >> 11) / 9007199254740992.0
                        : (double)(seed % (uint64_t)tf->lut_size) /
                              (tf->lut_size - 1);
      if (i % 4 == 3)
        x0 = (double)((seed >> 20) % (uint64_t)tf->lut_size) /
             (tf->lut_size - 1);
      any = rp__tf_alpha_any(tf, prefix, x0, x1);
      max = rp__tf_alpha_max(tf, x0, x1) > 0.0f;
      if (any != max)
        fail_msg("TF %d: [%.17g, %.17g]: any %d, max %d", k, x0, x1, any,
                 max);
      tried++;
      on += any;
    }
    free(prefix);
    rp_tf_destroy(tf);
  }
  /* Both answers were asked often. */
  assert_true(on > tried / 10 && on < tried - tried / 10);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(opacity_correction_matches_long_double),
      cmocka_unit_test(opacity_correction_closed_forms),
      cmocka_unit_test(naive_form_fails_where_ours_holds),
      cmocka_unit_test(rejects_bad_points),
      cmocka_unit_test(presets_build),
      cmocka_unit_test(lut_sampling_is_the_control_point_function),
      cmocka_unit_test(alpha_mean_and_max_match_closed_form),
      cmocka_unit_test(zero_is_exact),
      cmocka_unit_test(alpha_any_is_alpha_max_above_zero),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
