/* Load balancing (runtime/balance.c): shares, damping, the tile split and
 * the balance metric. Expected values are worked out here by hand
 * (fractions, closed forms of the damping recursions) or by brute force
 * over the tiles (region costs and coverage), never through the SAT or
 * any other code under test. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "raypace_balance.h"
#include "test_util.h"

#define assert_close(x, y, tol)                                              \
  do {                                                                       \
    double x_ = (x), y_ = (y);                                               \
    if (!(fabs(x_ - y_) <= (tol)))                                           \
      fail_msg("%s = %.17g, expected %.17g (tol %g)", #x, x_, y_,            \
               (double)(tol));                                               \
  } while (0)

#define assert_region(r, a, b, c, d)                                         \
  do {                                                                       \
    rp_region r_ = (r);                                                      \
    if (r_.x0 != (a) || r_.y0 != (b) || r_.x1 != (c) || r_.y1 != (d))       \
      fail_msg("%s = (%u, %u, %u, %u), expected (%u, %u, %u, %u)", #r,      \
               r_.x0, r_.y0, r_.x1, r_.y1, (unsigned)(a), (unsigned)(b),    \
               (unsigned)(c), (unsigned)(d));                                \
  } while (0)

static uint64_t rng = 0x9E3779B97F4A7C15ULL;
static double urand(void) {
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return (double)(rng >> 11) * 0x1p-53;
}
static uint32_t irand(uint32_t lo, uint32_t hi) { /* [lo, hi] */
  return lo + (uint32_t)(urand() * (hi - lo + 1));
}

/* Sums in index order and in reverse. */
static double sum_fwd(const double *w, uint32_t n) {
  double s = 0;
  uint32_t i;
  for (i = 0; i < n; i++)
    s += w[i];
  return s;
}
static double sum_rev(const double *w, uint32_t n) {
  double s = 0;
  uint32_t i;
  for (i = n; i-- > 0;)
    s += w[i];
  return s;
}

static int empty(rp_region r) { return r.x0 == r.x1 || r.y0 == r.y1; }

static rp_balancer *make(rp_context *ctx) {
  rp_balancer *b = NULL;
  assert_int_equal(rp_balancer_create(ctx, NULL, &b), 0);
  assert_non_null(b);
  return b;
}

/* ---- shares ------------------------------------------------------------- */

static void shares_closed_form(void **state) {
  const double s3[3] = {1, 2, 4};
  double w[3], e[3];
  uint32_t k;
  (void)state;
  /* 1/sigma = 1, 1/2, 1/4, sum 7/4: shares 4/7, 2/7, 1/7. */
  assert_int_equal(rp_balance_shares(s3, 3, w), 0);
  assert_close(w[0], 4.0 / 7, 1e-15);
  assert_close(w[1], 2.0 / 7, 1e-15);
  assert_close(w[2], 1.0 / 7, 1e-15);
  assert_true(sum_fwd(w, 3) == 1.0);
  assert_true(sum_rev(w, 3) == 1.0);
  assert_true(w[1] + (w[2] + w[0]) == 1.0);
  /* Eq. 3: prod_{j != i} = 8, 4, 2 over sum 7: they sum to 2, not 1. */
  assert_int_equal(rp_balance_shares_eq3(s3, 3, e), 0);
  assert_close(e[0], 8.0 / 7, 1e-15);
  assert_close(e[1], 4.0 / 7, 1e-15);
  assert_close(e[2], 2.0 / 7, 1e-15);
  assert_close(sum_fwd(e, 3), 2.0, 1e-15);
  /* Two devices: both are sigma_other / (sigma_0 + sigma_1). */
  for (k = 0; k < 200; k++) {
    double s2[2], a[2], b[2];
    s2[0] = pow(10, urand() * 12 - 6);
    s2[1] = pow(10, urand() * 12 - 6);
    assert_int_equal(rp_balance_shares(s2, 2, a), 0);
    assert_int_equal(rp_balance_shares_eq3(s2, 2, b), 0);
    assert_close(a[0], s2[1] / (s2[0] + s2[1]), 4e-16);
    assert_close(a[0], b[0], 4e-16);
    assert_close(a[1], b[1], 4e-16);
    assert_true(a[0] + a[1] == 1.0);
  }
  /* Only ratios matter, at any magnitude (no overflow of 1/sigma). */
  {
    /* 1 / 1e-310 overflows to infinity; subnormals carry about 13
     * digits. */
    const double tiny[3] = {1e-310, 2e-310, 4e-310};
    const double huge[3] = {1e300, 2e300, 4e300};
    double t[3], h[3];
    assert_int_equal(rp_balance_shares(tiny, 3, t), 0);
    assert_int_equal(rp_balance_shares(huge, 3, h), 0);
    for (k = 0; k < 3; k++) {
      assert_close(t[k], w[k], 1e-12);
      assert_true(h[k] == w[k]);
    }
  }
  /* One device: everything. */
  assert_int_equal(rp_balance_shares(s3 + 2, 1, w), 0);
  assert_true(w[0] == 1.0);
}

static void shares_unknown(void **state) {
  const double nan3[3] = {1, NAN, 4}, zero3[3] = {1, 0, 4};
  const double none[3] = {NAN, 0, NAN}, one[3] = {NAN, 2, 0};
  double w[3];
  int i;
  (void)state;
  /* Known 1/sigma: 1 and 1/4, mean 5/8; speeds 1, 5/8, 1/4 (sum 15/8):
   * 8/15, 5/15, 2/15. NaN and 0 both mean unknown. */
  assert_int_equal(rp_balance_shares(nan3, 3, w), 0);
  assert_close(w[0], 8.0 / 15, 1e-15);
  assert_close(w[1], 5.0 / 15, 1e-15);
  assert_close(w[2], 2.0 / 15, 1e-15);
  assert_true(sum_fwd(w, 3) == 1.0);
  assert_int_equal(rp_balance_shares(zero3, 3, w), 0);
  assert_close(w[1], 5.0 / 15, 1e-15);
  /* None known, or a single known device: the even split. */
  assert_int_equal(rp_balance_shares(none, 3, w), 0);
  for (i = 0; i < 3; i++)
    assert_close(w[i], 1.0 / 3, 0x1p-52);
  assert_true(sum_fwd(w, 3) == 1.0 && sum_rev(w, 3) == 1.0);
  assert_int_equal(rp_balance_shares(one, 3, w), 0);
  for (i = 0; i < 3; i++)
    assert_close(w[i], 1.0 / 3, 0x1p-52);
}

/* Random sigma over 24 decades, n up to 64: each share is the closed form
 * (in long double) and they add to exactly 1 in both orders. */
static void shares_random_exact_sum(void **state) {
  double sigma[64], w[64];
  int k;
  (void)state;
  for (k = 0; k < 500; k++) {
    uint32_t n = irand(1, 64), i;
    long double inv = 0;
    for (i = 0; i < n; i++) {
      sigma[i] = pow(10, urand() * 24 - 12);
      inv += 1.0L / sigma[i];
    }
    assert_int_equal(rp_balance_shares(sigma, n, w), 0);
    assert_true(sum_fwd(w, n) == 1.0);
    assert_true(sum_rev(w, n) == 1.0);
    for (i = 0; i < n; i++) {
      assert_true(w[i] >= 0);
      assert_close(w[i], (double)(1.0L / sigma[i] / inv), 1e-14);
    }
  }
}

static void shares_errors(void **state) {
  const double inf3[3] = {1, INFINITY, 2}, neg3[3] = {1, -2, 2};
  const double zero3[3] = {1, 0, 2}, ok3[3] = {1, 2, 3};
  double w[3] = {-7, -7, -7};
  (void)state;
  assert_int_equal(rp_balance_shares(inf3, 3, w), RP_ENOTFINITE);
  assert_int_equal(rp_balance_shares(neg3, 3, w), RP_ERANGE);
  assert_int_equal(rp_balance_shares(ok3, 0, w), RP_EINVAL);
  assert_int_equal(rp_balance_shares(ok3, RP_BALANCE_MAX_DEVICES + 1, w),
                   RP_ERANGE);
  assert_int_equal(rp_balance_shares(NULL, 3, w), RP_EINVAL);
  assert_int_equal(rp_balance_shares(ok3, 3, NULL), RP_EINVAL);
  /* Eq. 3 has no "unknown": every sigma must be positive. */
  assert_int_equal(rp_balance_shares_eq3(zero3, 3, w), RP_ERANGE);
  assert_int_equal(rp_balance_shares_eq3(inf3, 3, w), RP_ENOTFINITE);
  {
    double big[40];
    int i;
    for (i = 0; i < 40; i++)
      big[i] = 1e300;
    assert_int_equal(rp_balance_shares_eq3(big, 40, w), RP_ERANGE);
  }
  assert_true(w[0] == -7 && w[1] == -7 && w[2] == -7);
}

/* ---- damping ------------------------------------------------------------ */

/* Ours, from the even start toward sigma (1, 2, 4)'s shares w* = (4, 2,
 * 1) / 7 held still: w_t = w* + (1 - lambda)^t (1/3 - w*), exactly the
 * recursion's closed form. The device times sigma_i w_i, frame cost 1,
 * deviate from 4/7 by (1 - lambda)^t sigma_i (1/3 - w*_i) = (-5, 2, 16) /
 * 21 (1 - lambda)^t: max - min = (1 - lambda)^t, mean = 4/7 + 13/63 (1 -
 * lambda)^t. Stated convergence: with lambda = 1/2 every share is within
 * 1e-3 of w* by frame 8 (0.5^8 * 5/21 < 1e-3) and the metric under 0.01
 * (0.5^8 / (4/7) < 0.007). */
static void damp_smooth_converges(void **state) {
  const double sigma[3] = {1, 2, 4}, ws[3] = {4.0 / 7, 2.0 / 7, 1.0 / 7};
  const double lambdas[3] = {0.5, 0.25, 1.0};
  int li, t, i;
  (void)state;
  for (li = 0; li < 3; li++) {
    double lambda = lambdas[li], w[3];
    for (t = 1; t <= 40; t++) {
      double target[3], times[3], m, g = pow(1 - lambda, t);
      /* The first frame has no previous shares: the even start. */
      assert_int_equal(rp_balance_shares(sigma, 3, target), 0);
      assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, lambda,
                                       t == 1 ? NULL : w, target, 3, w),
                       0);
      assert_true(sum_fwd(w, 3) == 1.0 && sum_rev(w, 3) == 1.0);
      for (i = 0; i < 3; i++) {
        assert_close(w[i], ws[i] + g * (1.0 / 3 - ws[i]), 1e-14);
        times[i] = sigma[i] * w[i];
      }
      assert_int_equal(rp_balance_metric(times, NULL, 3, &m), 0);
      assert_close(m, g / (4.0 / 7 + 13.0 / 63 * g), 1e-13);
      if (lambda == 0.5 && t >= 8) {
        for (i = 0; i < 3; i++)
          assert_true(fabs(w[i] - ws[i]) < 1e-3);
        assert_true(m < 0.01);
      }
    }
  }
}

/* The paper's: w = (1 - zeta)/3 + zeta w*, the same from the first frame
 * on (no history), never w*. With zeta = 1/2: 1/6 + (2, 1, 1/2)/7 = (19,
 * 13, 10)/42; times sigma w = (19, 26, 40)/42, so the metric is (40 - 19)
 * / (85 / 3) = 63/85 every frame. */
static void damp_paper_fixed_point(void **state) {
  const double sigma[3] = {1, 2, 4};
  double w[3] = {1, 1, 1};
  int t, i;
  (void)state;
  for (t = 1; t <= 10; t++) {
    double target[3], times[3], m;
    assert_int_equal(rp_balance_shares(sigma, 3, target), 0);
    /* Rate 0: zeta = 1/2. prev is ignored (here last frame's shares). */
    assert_int_equal(rp_balance_damp(RP_DAMP_EVEN, 0, w, target, 3, w), 0);
    assert_close(w[0], 19.0 / 42, 1e-15);
    assert_close(w[1], 13.0 / 42, 1e-15);
    assert_close(w[2], 10.0 / 42, 1e-15);
    assert_true(sum_fwd(w, 3) == 1.0);
    for (i = 0; i < 3; i++)
      times[i] = sigma[i] * w[i];
    assert_int_equal(rp_balance_metric(times, NULL, 3, &m), 0);
    assert_close(m, 63.0 / 85, 1e-14);
  }
}

/* The cap: a device far faster than the rest gets at most (1 - zeta)/n +
 * zeta under the paper's rule, while ours gives it what it earns. */
static void damp_paper_cap(void **state) {
  const double zetas[3] = {0.5, 0.8, 0.1};
  double sigma[4] = {1, 1e9, 1e9, 1e9}, w[4], target[4];
  int zi, i;
  (void)state;
  for (zi = 0; zi < 3; zi++) {
    double z = zetas[zi];
    uint32_t n;
    for (n = 2; n <= 4; n++) {
      double fast = 1.0 / (1.0 + (n - 1) * 1e-9); /* w*_0 */
      assert_int_equal(rp_balance_shares(sigma, n, target), 0);
      assert_int_equal(rp_balance_damp(RP_DAMP_EVEN, z, NULL, target, n, w),
                       0);
      assert_close(w[0], (1 - z) / n + z * fast, 1e-15);
      assert_true(w[0] <= (1 - z) / n + z);
      for (i = 1; i < (int)n; i++)
        assert_true(w[i] >= (1 - z) / n);
      assert_true(sum_fwd(w, n) == 1.0);
      /* Ours from the even split converges past the cap: the error
       * shrinks by 1 - zeta a frame, 0.9^400 < 1e-18. */
      {
        double s[4];
        int t;
        for (t = 0; t < 400; t++)
          assert_int_equal(
              rp_balance_damp(RP_DAMP_SMOOTH, z, t ? s : NULL, target, n, s),
              0);
        assert_close(s[0], fast, 1e-6);
      }
    }
  }
}

static void damp_args(void **state) {
  const double target[3] = {4, 2, 1}, prev[3] = {1, 1, 1};
  const double zeros[3] = {0, 0, 0}, neg[3] = {1, -1, 1};
  const double nan3[3] = {1, NAN, 1};
  double out[3] = {-7, -7, -7}, a[3], b[3];
  rp_context *ctx = rp_test_context();
  rp_balancer *bal = NULL;
  rp_balancer_desc d = {0};
  (void)state;
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 1.5, prev, target, 3, out),
                   RP_ERANGE);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, -0.1, prev, target, 3,
                                   out),
                   RP_ERANGE);
  assert_int_equal(rp_balance_damp(RP_DAMP_EVEN, NAN, prev, target, 3, out),
                   RP_ENOTFINITE);
  assert_int_equal(rp_balance_damp((rp_damping)7, 0.5, prev, target, 3, out),
                   RP_EINVAL);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0.5, prev, zeros, 3, out),
                   RP_EINVAL);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0.5, neg, target, 3, out),
                   RP_ERANGE);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0.5, prev, nan3, 3, out),
                   RP_ENOTFINITE);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0.5, prev, target, 0, out),
                   RP_EINVAL);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0.5, prev, NULL, 3, out),
                   RP_EINVAL);
  assert_true(out[0] == -7 && out[1] == -7 && out[2] == -7);
  /* Rate 0 is the default, 1/2; unnormalised inputs are normalised:
   * (1/3 + 4/7) / 2 = 19/42. */
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0, prev, target, 3, a), 0);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0.5, prev, target, 3, b),
                   0);
  assert_true(a[0] == b[0] && a[1] == b[1] && a[2] == b[2]);
  assert_close(a[0], 19.0 / 42, 1e-15);
  /* In place. */
  memcpy(b, prev, sizeof b);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0.5, b, target, 3, b), 0);
  assert_true(a[0] == b[0] && a[1] == b[1] && a[2] == b[2]);
  /* prev NULL is the even split: the same as passing it. */
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0.3, NULL, target, 3, a),
                   0);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0.3, prev, target, 3, b),
                   0);
  assert_true(a[0] == b[0] && a[1] == b[1] && a[2] == b[2]);
  /* Two devices: even start 1/2, target (3/4, 1/4): (5/8, 3/8). */
  {
    const double t2[2] = {0.75, 0.25};
    assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0, NULL, t2, 2, a), 0);
    assert_close(a[0], 5.0 / 8, 1e-16);
    assert_close(a[1], 3.0 / 8, 1e-16);
  }
  /* Bad balancer descs. */
  d.max_devices = RP_BALANCE_MAX_DEVICES + 1;
  assert_int_equal(rp_balancer_create(ctx, &d, &bal), RP_ERANGE);
  d.max_devices = 0;
  d.max_tiles = RP_BALANCE_MAX_TILES + 1;
  assert_int_equal(rp_balancer_create(ctx, &d, &bal), RP_ERANGE);
  assert_null(bal);
  assert_int_equal(rp_balancer_create(ctx, NULL, NULL), RP_EINVAL);
  assert_int_equal(rp_balancer_create(NULL, NULL, &bal), RP_EINVAL);
  rp_balancer_destroy(NULL);
  rp_context_destroy(ctx);
}

/* ---- the split ---------------------------------------------------------- */

/* Every rectangle inside the grid and each tile covered exactly once. */
static void check_cover(const rp_region *r, uint32_t n, uint32_t tx,
                        uint32_t ty) {
  unsigned char *seen = calloc((size_t)tx * ty, 1);
  uint32_t i, x, y;
  assert_non_null(seen);
  for (i = 0; i < n; i++) {
    assert_true(r[i].x0 <= r[i].x1 && r[i].x1 <= tx);
    assert_true(r[i].y0 <= r[i].y1 && r[i].y1 <= ty);
    /* The explicit bounds, though asserted above, keep GCC's -O3
     * stringop-overflow check from seeing a write past `seen`: cmocka's
     * assert_true is not noreturn to it. */
    for (y = r[i].y0; y < r[i].y1 && y < ty; y++)
      for (x = r[i].x0; x < r[i].x1 && x < tx; x++)
        seen[(size_t)y * tx + x]++;
  }
  for (i = 0; i < tx * ty; i++)
    if (seen[i] != 1)
      fail_msg("tile (%u, %u) covered %d times", i % tx, i / tx, seen[i]);
  free(seen);
}

/* A rectangle's cost summed tile by tile. */
static double region_cost(const double *c, uint32_t tx, rp_region r) {
  double s = 0;
  uint32_t x, y;
  for (y = r.y0; y < r.y1; y++)
    for (x = r.x0; x < r.x1; x++)
      s += c[(size_t)y * tx + x];
  return s;
}

/* The depth of each device in the kd-tree: the number of cuts above it,
 * from the documented group rule (closest share sums; ties within 1e-12
 * of the sum: nearest the middle, then the larger m). */
static void depths(const double *w, uint32_t d0, uint32_t d1, int depth,
                   int *out) {
  double total = 0, left = 0, best = INFINITY;
  uint32_t m, bm = d0 + 1;
  if (d1 - d0 == 1) {
    out[d0] = depth;
    return;
  }
  for (m = d0; m < d1; m++)
    total += w[m];
  for (m = d0 + 1; m < d1; m++) {
    double diff;
    left += w[m - 1];
    diff = fabs(total - 2 * left);
    if (diff < best - 1e-12 * total ||
        (diff <= best + 1e-12 * total &&
         labs(2 * (long)m - (long)(d0 + d1)) <=
             labs(2 * (long)bm - (long)(d0 + d1)))) {
      best = fmin(best, diff);
      bm = m;
    }
  }
  depths(w, d0, bm, depth + 1, out);
  depths(w, bm, d1, depth + 1, out);
}

/* Random grids and shares. The bound: each cut lands within half the cost
 * of the row or column of tiles it crosses of its target, and a device's
 * error is at most the sum over the cuts above it, so
 * |cost_i - w_i C| <= depth_i * M / 2, with M the largest cost of any
 * whole row or column of the grid (a crossed slice is part of one). */
static void split_random(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer *b = make(ctx);
  double *c = malloc(40 * 40 * sizeof *c);
  float *cf = malloc(40 * 40 * sizeof *cf);
  double sigma[8], w[8];
  rp_region r[8];
  int k, dep[8];
  (void)state;
  assert_non_null(c);
  assert_non_null(cf);
  for (k = 0; k < 600; k++) {
    uint32_t tx = irand(1, 40), ty = irand(1, 40), n = irand(1, 8);
    uint32_t i, x, y, kind = k % 4, use_float = (k / 4) % 2;
    double total = 0, m = 0;
    for (i = 0; i < tx * ty; i++) {
      double u = urand();
      c[i] = kind == 0   ? 1.0 + u
             : kind == 1 ? (u < 0.8 ? 0 : urand() * 100)
             : kind == 2 ? pow(10, 6 * u)
                         : floor(u * 4);
      if (use_float) {
        cf[i] = (float)c[i];
        c[i] = cf[i];
      }
      total += c[i];
    }
    if (total == 0) /* documented: zero total splits by tile count */
      for (i = 0; i < tx * ty; i++)
        c[i] = 1, total += 1;
    for (y = 0; y < ty; y++) {
      double s = 0;
      for (x = 0; x < tx; x++)
        s += c[(size_t)y * tx + x];
      m = fmax(m, s);
    }
    for (x = 0; x < tx; x++) {
      double s = 0;
      for (y = 0; y < ty; y++)
        s += c[(size_t)y * tx + x];
      m = fmax(m, s);
    }
    for (i = 0; i < n; i++)
      sigma[i] = pow(10, urand() * 2);
    assert_int_equal(rp_balance_shares(sigma, n, w), 0);
    if (use_float)
      assert_int_equal(rp_balancer_split_f(b, cf, tx, ty, w, n, r), 0);
    else
      assert_int_equal(rp_balancer_split(b, c, tx, ty, w, n, r), 0);
    check_cover(r, n, tx, ty);
    depths(w, 0, n, 0, dep);
    for (i = 0; i < n; i++) {
      double got = region_cost(c, tx, r[i]);
      assert_true(dep[i] <= (int)n - 1);
      if (!(fabs(got - w[i] * total) <= dep[i] * m / 2 + 1e-9 * total))
        fail_msg("case %d (%ux%u, n %u, kind %u): device %u cost %.17g, "
                 "ideal %.17g, bound %g",
                 k, tx, ty, n, kind, i, got, w[i] * total, dep[i] * m / 2);
    }
  }
  free(c);
  free(cf);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

static double *fill(uint32_t count, double v) {
  double *c = malloc(count * sizeof *c);
  uint32_t i;
  assert_non_null(c);
  for (i = 0; i < count; i++)
    c[i] = v;
  return c;
}

/* 64 x 64 uniform tiles, three equal shares. By hand: groups {0, 1} and
 * {2} (a tie, the larger m); the square is cut across x where 64 p is
 * nearest 4096 * 2/3 = 2730.7: p = 43 (2752; 42 gives 2688); the left
 * 43 x 64 is cut across y at 32. So 1376, 1376 and 1344 tiles, each
 * within one column (64 tiles) of 4096/3. */
static void split_uniform_thirds(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer *b = make(ctx);
  double *c = fill(64 * 64, 1.0);
  const double ones[3] = {1, 1, 1}, unknown[3] = {NAN, NAN, NAN};
  double w[3];
  rp_region r[3];
  int i, pass;
  (void)state;
  for (pass = 0; pass < 2; pass++) {
    if (pass == 0)
      memcpy(w, ones, sizeof w);
    else /* first frames: no sigma known yet, an even split */
      assert_int_equal(rp_balance_shares(unknown, 3, w), 0);
    assert_int_equal(rp_balancer_split(b, c, 64, 64, w, 3, r), 0);
    check_cover(r, 3, 64, 64);
    assert_region(r[0], 0, 0, 43, 32);
    assert_region(r[1], 0, 32, 43, 64);
    assert_region(r[2], 43, 0, 64, 64);
    for (i = 0; i < 3; i++)
      assert_true(fabs(region_cost(c, 64, r[i]) - 4096.0 / 3) <= 64);
  }
  free(c);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

/* One device 1000x slower: share 1/1001. On 64 x 64 uniform tiles its
 * ideal is 4.1 tiles, under one 64-tile column: it gets an empty region
 * and the other the whole grid. On a 2000 x 1 strip its ideal is 1.998
 * tiles: it gets the last 2. */
static void split_slow_device(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer *b = make(ctx);
  const double sigma[2] = {1, 1000};
  double w[2], times[2], m, *c = fill(64 * 64, 1.0), *strip = fill(2000, 2.5);
  rp_region r[2], px[2];
  (void)state;
  assert_int_equal(rp_balance_shares(sigma, 2, w), 0);
  assert_close(w[1], 1.0 / 1001, 0x1p-52); /* shares are k / 2^53 */
  assert_int_equal(rp_balancer_split(b, c, 64, 64, w, 2, r), 0);
  assert_region(r[0], 0, 0, 64, 64);
  assert_true(empty(r[1]));
  check_cover(r, 2, 64, 64);
  assert_int_equal(rp_balance_to_pixels(r, 2, 512, 512, px), 0);
  assert_region(px[0], 0, 0, 512, 512);
  assert_true(empty(px[1]));
  /* The idle device is left out of the metric. */
  times[0] = 5;
  times[1] = 0;
  assert_int_equal(rp_balance_metric(times, r, 2, &m), 0);
  assert_true(m == 0);
  assert_int_equal(rp_balancer_split(b, strip, 2000, 1, w, 2, r), 0);
  assert_region(r[0], 0, 0, 1998, 1);
  assert_region(r[1], 1998, 0, 2000, 1);
  free(c);
  free(strip);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

/* All the cost in tile (5, 9) of 16 x 16. Two equal shares: cutting
 * before or after column 5 misses by 50 either way; every cut in [0, 5]
 * or [6, 16] costs the same, and the count position 8 decides. Four
 * devices: everyone still gets 64 tiles, one of them the hot tile. */
static void split_one_hot_tile(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer *b = make(ctx);
  double *c = fill(16 * 16, 0.0);
  const double w2[2] = {0.5, 0.5}, w4[4] = {1, 1, 1, 1};
  rp_region r[4];
  int i, hot = 0;
  (void)state;
  c[9 * 16 + 5] = 100;
  assert_int_equal(rp_balancer_split(b, c, 16, 16, w2, 2, r), 0);
  assert_region(r[0], 0, 0, 8, 16);
  assert_region(r[1], 8, 0, 16, 16);
  assert_int_equal(rp_balancer_split(b, c, 16, 16, w4, 4, r), 0);
  check_cover(r, 4, 16, 16);
  for (i = 0; i < 4; i++) {
    double rc = region_cost(c, 16, r[i]);
    assert_int_equal((r[i].x1 - r[i].x0) * (r[i].y1 - r[i].y0), 64);
    assert_true(rc == 0 || rc == 100);
    hot += rc == 100;
  }
  assert_int_equal(hot, 1);
  free(c);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

/* A 1 x 1 grid, three devices: one gets the tile, two are empty; with
 * cost 0 too (the count fallback). */
static void split_single_tile(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer *b = make(ctx);
  const double costs[2] = {3.5, 0}, w[3] = {1, 1, 1};
  rp_region r[3];
  int k, i, got;
  (void)state;
  for (k = 0; k < 2; k++) {
    assert_int_equal(rp_balancer_split(b, &costs[k], 1, 1, w, 3, r), 0);
    check_cover(r, 3, 1, 1);
    for (got = 0, i = 0; i < 3; i++)
      if (!empty(r[i])) {
        assert_region(r[i], 0, 0, 1, 1);
        got++;
      }
    assert_int_equal(got, 1);
  }
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

/* More devices than tiles. 2 x 2 uniform with 7 equal shares: four
 * devices get one tile each, three get nothing. Random shares on 3 x 1
 * with 16 devices: at most 3 non-empty regions, all disjoint. */
static void split_more_devices_than_tiles(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer_desc d = {0};
  rp_balancer *b = NULL;
  const double c4[4] = {1, 1, 1, 1}, c3[3] = {2, 0, 7};
  double w[16];
  rp_region r[16];
  int i, k, busy;
  (void)state;
  d.max_devices = 16;
  d.max_tiles = 4;
  assert_int_equal(rp_balancer_create(ctx, &d, &b), 0);
  for (i = 0; i < 7; i++)
    w[i] = 1;
  assert_int_equal(rp_balancer_split(b, c4, 2, 2, w, 7, r), 0);
  check_cover(r, 7, 2, 2);
  for (busy = 0, i = 0; i < 7; i++)
    if (!empty(r[i])) {
      assert_int_equal((r[i].x1 - r[i].x0) * (r[i].y1 - r[i].y0), 1);
      busy++;
    }
  assert_int_equal(busy, 4);
  for (k = 0; k < 50; k++) {
    for (i = 0; i < 16; i++)
      w[i] = urand() < 0.2 ? 0 : urand();
    w[k % 16] = 1; /* a positive sum */
    assert_int_equal(rp_balancer_split(b, c3, 3, 1, w, 16, r), 0);
    check_cover(r, 16, 3, 1);
    for (busy = 0, i = 0; i < 16; i++) {
      busy += !empty(r[i]);
      if (w[i] == 0) /* a zero share never gets tiles */
        assert_true(empty(r[i]));
    }
    assert_true(busy <= 3);
  }
  /* 16 devices on a grid of 4 tiles: over max_tiles is refused. */
  assert_int_equal(rp_balancer_split(b, c4, 4, 2, w, 16, r), RP_ERANGE);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

/* No cost anywhere: split by tile count. 10 x 10, shares 2:1:1: device 0
 * alone against {1, 2} (equal sums), cut across x at 5; the right 5 x 10
 * across y at 5: exactly 50, 25 and 25 tiles. */
static void split_zero_cost(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer *b = make(ctx);
  double *c = fill(100, 0.0);
  float cf[100];
  const double w[3] = {0.5, 0.25, 0.25};
  rp_region r[3];
  int k;
  (void)state;
  memset(cf, 0, sizeof cf);
  for (k = 0; k < 2; k++) {
    if (k == 0)
      assert_int_equal(rp_balancer_split(b, c, 10, 10, w, 3, r), 0);
    else
      assert_int_equal(rp_balancer_split_f(b, cf, 10, 10, w, 3, r), 0);
    assert_region(r[0], 0, 0, 5, 10);
    assert_region(r[1], 5, 0, 10, 5);
    assert_region(r[2], 5, 5, 10, 10);
  }
  free(c);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

/* The group rule on 8 x 8 uniform tiles, shares (1, 1, 1, 1, 6): the
 * closest share sums are {0..3} (4) against {4} (6), not the middle
 * split {0, 1, 2} (3) against {3, 4} (7). Across x at 40 % of 64 = 25.6
 * tiles: 3 columns (24; 4 give 32). The left 3 x 8 for four equal shares:
 * across y at 4, then each 3 x 4 across y at 2. By count the middle
 * split would have cut at 2 columns instead. */
static void split_group_rule(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer *b = make(ctx);
  double *c = fill(64, 1.0);
  const double w[5] = {1, 1, 1, 1, 6};
  rp_region r[5];
  (void)state;
  assert_int_equal(rp_balancer_split(b, c, 8, 8, w, 5, r), 0);
  assert_region(r[0], 0, 0, 3, 2);
  assert_region(r[1], 0, 2, 3, 4);
  assert_region(r[2], 0, 4, 3, 6);
  assert_region(r[3], 0, 6, 3, 8);
  assert_region(r[4], 3, 0, 8, 8);
  free(c);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

/* Tiles of 1e12 and 1: integer prefix sums keep the small tiles (a
 * double SAT would lose them to cancellation). 1 x 8 strip: 1e12 at x =
 * 0, then seven 1s; two devices with shares 1e12 and 7 put the cut
 * exactly after the hot tile. */
static void split_dynamic_range(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer *b = make(ctx);
  const double c[8] = {1e12, 1, 1, 1, 1, 1, 1, 1};
  const double w[2] = {1e12, 7}, w3[3] = {1e12, 3, 4};
  rp_region r[3];
  (void)state;
  assert_int_equal(rp_balancer_split(b, c, 8, 1, w, 2, r), 0);
  assert_region(r[0], 0, 0, 1, 1);
  assert_region(r[1], 1, 0, 8, 1);
  /* The three-way version: {0} against {1, 2}, then 3:4 of 7 ones. */
  assert_int_equal(rp_balancer_split(b, c, 8, 1, w3, 3, r), 0);
  assert_region(r[0], 0, 0, 1, 1);
  assert_region(r[1], 1, 0, 4, 1);
  assert_region(r[2], 4, 0, 8, 1);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

static void split_errors(void **state) {
  rp_context *ctx = rp_test_context();
  rp_balancer *b = make(ctx);
  double c[20], w[2] = {1, 1};
  float cf[20];
  rp_region r[2], before[2];
  int i;
  (void)state;
  for (i = 0; i < 20; i++)
    c[i] = 1, cf[i] = 1;
  memset(r, 0xAB, sizeof r);
  memcpy(before, r, sizeof r);
  c[2 * 5 + 3] = NAN; /* tile (3, 2) of 5 x 4 */
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 2, r), RP_ENOTFINITE);
  assert_non_null(strstr(rp_last_error(ctx), "(3, 2)"));
  c[2 * 5 + 3] = INFINITY;
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 2, r), RP_ENOTFINITE);
  c[2 * 5 + 3] = -1;
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 2, r), RP_ERANGE);
  c[2 * 5 + 3] = 1;
  cf[19] = NAN;
  assert_int_equal(rp_balancer_split_f(b, cf, 5, 4, w, 2, r), RP_ENOTFINITE);
  assert_non_null(strstr(rp_last_error(ctx), "(4, 3)"));
  cf[19] = -INFINITY;
  assert_int_equal(rp_balancer_split_f(b, cf, 5, 4, w, 2, r), RP_ENOTFINITE);
  w[1] = NAN;
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 2, r), RP_ENOTFINITE);
  w[1] = -1;
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 2, r), RP_ERANGE);
  w[0] = w[1] = 0;
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 2, r), RP_EINVAL);
  w[0] = w[1] = 1;
  assert_int_equal(rp_balancer_split(b, c, 0, 4, w, 2, r), RP_EINVAL);
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 0, r), RP_EINVAL);
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 9, r), RP_ERANGE);
  assert_int_equal(rp_balancer_split(b, c, 513, 512, w, 2, r), RP_ERANGE);
  assert_int_equal(rp_balancer_split(b, NULL, 5, 4, w, 2, r), RP_EINVAL);
  assert_int_equal(rp_balancer_split(b, c, 5, 4, NULL, 2, r), RP_EINVAL);
  assert_int_equal(rp_balancer_split(NULL, c, 5, 4, w, 2, r), RP_EINVAL);
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 2, NULL), RP_EINVAL);
  assert_true(memcmp(r, before, sizeof r) == 0);
  /* Still works afterwards. */
  assert_int_equal(rp_balancer_split(b, c, 5, 4, w, 2, r), 0);
  check_cover(r, 2, 5, 4);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
}

static void to_pixels(void **state) {
  /* 20 x 13 pixels: 3 x 2 tiles, the last column 4 wide, the last row 5
   * high. */
  rp_region t[3] = {{0, 0, 2, 1}, {2, 0, 3, 2}, {0, 1, 2, 2}};
  rp_region e[1] = {{3, 0, 3, 2}}, bad[1] = {{0, 0, 4, 1}};
  rp_region p[3], keep = {9, 9, 9, 9};
  (void)state;
  assert_int_equal(rp_balance_to_pixels(t, 3, 20, 13, p), 0);
  assert_region(p[0], 0, 0, 16, 8);
  assert_region(p[1], 16, 0, 20, 13);
  assert_region(p[2], 0, 8, 16, 13);
  assert_int_equal(rp_balance_to_pixels(t, 3, 20, 13, t), 0); /* in place */
  assert_true(memcmp(t, p, sizeof p) == 0);
  assert_int_equal(rp_balance_to_pixels(e, 1, 20, 13, e), 0);
  assert_region(e[0], 20, 0, 20, 13);
  p[0] = keep;
  assert_int_equal(rp_balance_to_pixels(bad, 1, 20, 13, p), RP_ERANGE);
  assert_int_equal(rp_balance_to_pixels(t, 1, 0, 13, p), RP_EINVAL);
  assert_int_equal(rp_balance_to_pixels(NULL, 1, 20, 13, p), RP_EINVAL);
  assert_region(p[0], 9, 9, 9, 9);
  /* The widest image: 8 x 536870912 passes 2^32, clamped. */
  {
    rp_region w[1] = {{0, 0, 536870912, 1}};
    assert_int_equal(rp_balance_to_pixels(w, 1, UINT32_MAX, 8, w), 0);
    assert_region(w[0], 0, 0, UINT32_MAX, 8);
  }
}

static void metric(void **state) {
  const double t3[3] = {1, 2, 3}, z[3] = {0, 0, 0};
  const double nan3[3] = {1, NAN, 2}, neg3[3] = {1, -1, 2};
  rp_region r[3] = {{0, 0, 1, 1}, {1, 0, 1, 1}, {1, 0, 2, 1}};
  double m = -1;
  (void)state;
  /* (3 - 1) / 2 = 1; without device 1 (empty): (3 - 1) / 2 = 1 again;
   * and for times 1, 2 only (device 2 empty): (2 - 1) / 1.5. */
  assert_int_equal(rp_balance_metric(t3, NULL, 3, &m), 0);
  assert_close(m, 1.0, 1e-15);
  assert_int_equal(rp_balance_metric(t3, r, 3, &m), 0);
  assert_close(m, 1.0, 1e-15);
  r[1].x1 = 2;
  r[2].x1 = 1;
  assert_int_equal(rp_balance_metric(t3, r, 3, &m), 0);
  assert_close(m, 1.0 / 1.5, 1e-15);
  assert_int_equal(rp_balance_metric(z, NULL, 3, &m), 0);
  assert_true(m == 0);
  m = -1;
  assert_int_equal(rp_balance_metric(nan3, NULL, 3, &m), RP_ENOTFINITE);
  assert_int_equal(rp_balance_metric(neg3, NULL, 3, &m), RP_ERANGE);
  assert_int_equal(rp_balance_metric(t3, NULL, 0, &m), RP_EINVAL);
  assert_true(m == -1);
}

/* ---- memory ------------------------------------------------------------- */

static int allocs, fail_after = -1;
static void *counting_alloc(size_t size, void *user) {
  (void)user;
  if (fail_after >= 0 && allocs >= fail_after)
    return NULL;
  allocs++;
  return malloc(size);
}
static void counting_free(void *p, void *user) {
  (void)user;
  free(p);
}

/* Create fails cleanly without memory; a frame's shares, damping and
 * split allocate nothing (the hot path). */
static void memory(void **state) {
  rp_context_desc cd = {0};
  rp_context *ctx = NULL;
  rp_balancer *b = NULL;
  const double sigma[3] = {1, 2, NAN};
  double w[3], *c = fill(64 * 64, 1.0);
  rp_region r[3];
  int before;
  (void)state;
  cd.allocator.alloc = counting_alloc;
  cd.allocator.free = counting_free;
  allocs = 0;
  fail_after = 1; /* the context, then nothing */
  assert_int_equal(rp_context_create(&cd, &ctx), 0);
  assert_int_equal(rp_balancer_create(ctx, NULL, &b), RP_ENOMEM);
  assert_null(b);
  fail_after = -1;
  assert_int_equal(rp_balancer_create(ctx, NULL, &b), 0);
  before = allocs;
  assert_int_equal(rp_balance_shares(sigma, 3, w), 0);
  assert_int_equal(rp_balance_damp(RP_DAMP_SMOOTH, 0, NULL, w, 3, w), 0);
  assert_int_equal(rp_balancer_split(b, c, 64, 64, w, 3, r), 0);
  assert_int_equal(allocs, before);
  rp_balancer_destroy(b);
  rp_context_destroy(ctx);
  free(c);
}

/* Shares with fixed costs, in closed form: device i takes f_i + w_i v_i.
 * - no fixed costs: 1/v ratios, {2/3, 1/3} for v = {1, 2};
 * - f = {0.5, 0}, v = {1, 1}: T = (1 + 0.5) / 2 = 0.75, w = {0.25, 0.75};
 * - f = {2, 0}, v = {1, 1}: T = 1.5 < 2 drops device 0, then T = 1,
 *   w = {0, 1};
 * - an unknown v counts as the mean speed: v = {NaN, 2} -> {0.5, 0.5}. */
static void test_shares_fixed(void **state) {
  double w[2], v[2] = {1.0, 2.0}, f[2] = {0.0, 0.0};
  (void)state;
  assert_int_equal(rp_balance_shares_fixed(v, f, 2, w), 0);
  assert_true(fabs(w[0] - 2.0 / 3.0) < 1e-15 && w[0] + w[1] == 1.0);
  v[1] = 1.0;
  f[0] = 0.5;
  assert_int_equal(rp_balance_shares_fixed(v, f, 2, w), 0);
  assert_true(w[0] == 0.25 && w[1] == 0.75);
  f[0] = 2.0;
  assert_int_equal(rp_balance_shares_fixed(v, f, 2, w), 0);
  assert_true(w[0] == 0.0 && w[1] == 1.0);
  v[0] = NAN;
  v[1] = 2.0;
  f[0] = 0.0;
  assert_int_equal(rp_balance_shares_fixed(v, f, 2, w), 0);
  assert_true(w[0] == 0.5 && w[1] == 0.5);
  /* Refused input leaves w alone. */
  f[1] = NAN;
  assert_int_equal(rp_balance_shares_fixed(v, f, 2, w), RP_ENOTFINITE);
  f[1] = -1.0;
  assert_int_equal(rp_balance_shares_fixed(v, f, 2, w), RP_ERANGE);
  assert_int_equal(rp_balance_shares_fixed(NULL, f, 2, w), RP_EINVAL);
  assert_true(w[0] == 0.5 && w[1] == 0.5);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_shares_fixed),
      cmocka_unit_test(shares_closed_form),
      cmocka_unit_test(shares_unknown),
      cmocka_unit_test(shares_random_exact_sum),
      cmocka_unit_test(shares_errors),
      cmocka_unit_test(damp_smooth_converges),
      cmocka_unit_test(damp_paper_fixed_point),
      cmocka_unit_test(damp_paper_cap),
      cmocka_unit_test(damp_args),
      cmocka_unit_test(split_random),
      cmocka_unit_test(split_uniform_thirds),
      cmocka_unit_test(split_slow_device),
      cmocka_unit_test(split_one_hot_tile),
      cmocka_unit_test(split_single_tile),
      cmocka_unit_test(split_more_devices_than_tiles),
      cmocka_unit_test(split_zero_cost),
      cmocka_unit_test(split_group_rule),
      cmocka_unit_test(split_dynamic_range),
      cmocka_unit_test(split_errors),
      cmocka_unit_test(to_pixels),
      cmocka_unit_test(metric),
      cmocka_unit_test(memory),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
