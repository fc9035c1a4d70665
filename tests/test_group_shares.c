/* The split's arithmetic (runtime/shares.c), against values worked out
 * by hand: no devices, no threads. Shares come quantised to multiples of
 * 2^-53 (raypace_balance.h), so they are compared to 1e-12. */
#include <math.h>
#include <string.h>

#include "shares.h"
#include "test_util.h"

#define EPS 1e-12

/* A split model of this rate, depth-pass frequency and depth-pass time
 * (rp__split_model), nothing else known. */
#define MODEL(r, freq, est)                                                 \
  { .rate = (r), .depth_freq = (freq), .depth_est = (est) }

static rp_group_desc dynamic_desc(rp_damping damping, double rate) {
  rp_group_desc d;
  memset(&d, 0, sizeof d);
  d.share_mode = RP_SHARES_DYNAMIC;
  d.damping = damping;
  d.damp_rate = rate;
  return d;
}

/* Device 0: 2 ms per unit of cost and a 4 ms depth pass every frame;
 * device 1: 6 ms per unit, no depth pass; the frame costs 10 units. So
 * var = 20 and 60 ms, fixed = 4 and 0 ms, and finishing together means
 * 4 + 20 w = 60 (1 - w): w = 56 / 80 = 0.7, both at 18 ms. */
static void test_finish_together(void **state) {
  rp__split_model m0 = MODEL(2.0, 1.0, 4.0), m1 = MODEL(6.0, 1.0, 0.0);
  const rp__split_model *dev[2] = {&m0, &m1};
  rp_group_desc d = dynamic_desc(RP_DAMP_SMOOTH, 1.0);
  double w[2];
  (void)state;
  assert_int_equal(rp__frame_shares(&d, dev, 2, NULL, 10.0, w), 0);
  assert_true(fabs(w[0] - 0.7) < EPS && fabs(w[1] - 0.3) < EPS);
  assert_true(fabs((4.0 + w[0] * 20.0) - w[1] * 60.0) < 1e-9);
  /* The depth pass only every other frame: fixed 2, 2 + 20 w = 60 - 60 w,
   * w = 58 / 80. */
  m0.depth_freq = 0.5;
  assert_int_equal(rp__frame_shares(&d, dev, 2, NULL, 10.0, w), 0);
  assert_true(fabs(w[0] - 58.0 / 80.0) < EPS);
}

/* Smooth damping mixes with last frame's shares: (1 - lambda) prev +
 * lambda target; without a last frame, with the even split. The
 * paper's form mixes with the even split always: (1 - zeta) / n + zeta
 * target. Target 0.7 / 0.3 as above. */
static void test_damping(void **state) {
  rp__split_model m0 = MODEL(2.0, 1.0, 4.0), m1 = MODEL(6.0, 1.0, 0.0);
  const rp__split_model *dev[2] = {&m0, &m1};
  rp_group_desc smooth = dynamic_desc(RP_DAMP_SMOOTH, 0.5);
  rp_group_desc even = dynamic_desc(RP_DAMP_EVEN, 0.25);
  const double prev[2] = {0.2, 0.8}, none[2] = {0.0, 0.0};
  double w[2];
  (void)state;
  assert_int_equal(rp__frame_shares(&smooth, dev, 2, prev, 10.0, w), 0);
  assert_true(fabs(w[0] - (0.5 * 0.2 + 0.5 * 0.7)) < EPS);
  assert_true(fabs(w[1] - (0.5 * 0.8 + 0.5 * 0.3)) < EPS);
  assert_int_equal(rp__frame_shares(&smooth, dev, 2, NULL, 10.0, w), 0);
  assert_true(fabs(w[0] - (0.5 * 0.5 + 0.5 * 0.7)) < EPS);
  /* Last shares summing to 0 over the live devices count as none. */
  assert_int_equal(rp__frame_shares(&smooth, dev, 2, none, 10.0, w), 0);
  assert_true(fabs(w[0] - 0.6) < EPS);
  assert_int_equal(rp__frame_shares(&even, dev, 2, prev, 10.0, w), 0);
  assert_true(fabs(w[0] - (0.75 / 2.0 + 0.25 * 0.7)) < EPS);
  assert_true(fabs(w[1] - (0.75 / 2.0 + 0.25 * 0.3)) < EPS);
}

/* A device whose fixed cost alone is past the common finish leaves the
 * race: rates 1 and 1 on 10 units, fixed 0 and 20: T = (1 + 20 / 10) /
 * (2 / 10) = 15 < 20, so device 1 gets 0 and device 0 all of it. An
 * unmeasured device (rate 0) counts as the measured ones' mean speed;
 * with the frame's cost unknown, every device does. */
static void test_out_of_race_and_unknown(void **state) {
  rp__split_model a = MODEL(1.0, 1.0, 0.0), b = MODEL(1.0, 1.0, 20.0);
  rp__split_model fast = MODEL(2.0, 0.0, 0.0);
  rp__split_model fresh = MODEL(0.0, 0.0, 0.0);
  rp__split_model slow = MODEL(8.0, 0.0, 0.0);
  const rp__split_model *race[2] = {&a, &b}, *mixed[3] = {&fast, &fresh,
                                                          &slow};
  rp_group_desc d = dynamic_desc(RP_DAMP_SMOOTH, 1.0);
  double w[3];
  (void)state;
  assert_int_equal(rp__frame_shares(&d, race, 2, NULL, 10.0, w), 0);
  assert_true(fabs(w[0] - 1.0) < EPS && w[1] == 0.0);
  /* Speeds 1/2 and 1/8 per unit: mean 5/16, so the fresh device has rate
   * 16/5; shares in proportion to speed: 1/2 : 5/16 : 1/8 = 8 : 5 : 2. */
  assert_int_equal(rp__frame_shares(&d, mixed, 3, NULL, 10.0, w), 0);
  assert_true(fabs(w[0] - 8.0 / 15.0) < EPS);
  assert_true(fabs(w[1] - 5.0 / 15.0) < EPS);
  assert_true(fabs(w[2] - 2.0 / 15.0) < EPS);
  assert_int_equal(rp__frame_shares(&d, mixed, 3, NULL, 0.0, w), 0);
  assert_true(fabs(w[0] - 1.0 / 3.0) < EPS && fabs(w[2] - 1.0 / 3.0) < EPS);
}

/* Dropped devices (NULL) get 0 and the others share the frame; fixed
 * shares are the live devices' renormalised, even when all of them are
 * 0; no live device is RP_ENODEV. */
static void test_dropped_and_fixed(void **state) {
  rp__split_model m = MODEL(2.0, 0.0, 0.0);
  const rp__split_model *one[3] = {NULL, &m, NULL}, *none[2] = {NULL, NULL};
  const rp__split_model *first_two[3] = {&m, &m, NULL};
  const double fixed[3] = {1.0, 3.0, 4.0}, zero[3] = {0.0, 0.0, 5.0};
  rp_group_desc d = dynamic_desc(RP_DAMP_SMOOTH, 0.5);
  double w[3], prev[3] = {0.5, 0.1, 0.4};
  (void)state;
  assert_int_equal(rp__frame_shares(&d, one, 3, prev, 10.0, w), 0);
  assert_true(w[0] == 0.0 && w[1] == 1.0 && w[2] == 0.0);
  assert_int_equal(rp__frame_shares(&d, none, 2, NULL, 10.0, w),
                   RP_ENODEV);
  d.share_mode = RP_SHARES_FIXED;
  d.fixed_shares = fixed;
  assert_int_equal(rp__frame_shares(&d, first_two, 3, prev, 10.0, w), 0);
  assert_true(fabs(w[0] - 0.25) < EPS && fabs(w[1] - 0.75) < EPS &&
              w[2] == 0.0);
  d.fixed_shares = zero;
  assert_int_equal(rp__frame_shares(&d, first_two, 3, prev, 10.0, w), 0);
  assert_true(fabs(w[0] - 0.5) < EPS && fabs(w[1] - 0.5) < EPS);
}

/* The rate is the median of the last three measured: a stall moves
 * nothing (of two, the lower counts), a real slow-down is followed from
 * its second frame. */
static void test_rate_median(void **state) {
  static const struct {
    double add, rate;
  } steps[] = {
      {1.0, 1.0},  /* one: itself */
      {10.0, 1.0}, /* the stall; of two, the lower */
      {1.2, 1.2},  /* {1, 10, 1.2} */
      {1.1, 1.2},  /* {1.1, 10, 1.2}: the ring dropped the 1 */
      {1.3, 1.2},  /* {1.1, 1.3, 1.2}: the stall is gone */
      {5.0, 1.3},  /* {1.1, 1.3, 5}: one slow frame is not followed */
      {5.0, 5.0},  /* {5, 1.3, 5}: two are */
  };
  rp__split_model m;
  size_t i;
  (void)state;
  memset(&m, 0, sizeof m);
  for (i = 0; i < sizeof steps / sizeof *steps; i++) {
    rp__rate_add(&m, steps[i].add);
    if (m.rate != steps[i].rate)
      fail_msg("step %zu: rate %g, expected %g", i, m.rate, steps[i].rate);
  }
}

/* What a frame teaches: the rate outside the depth pass per unit of
 * cost, the depth pass's time and how often frames need it (a running
 * mean closing a quarter of the gap); a sliver's time counts only when
 * it lowers the rate. Step by step from nothing, on a frame of total
 * cost 100. */
static void test_learn(void **state) {
  static const struct {
    rp__split_sample s;
    int frame_depth;
    double rate, depth_freq; /* expected after the step */
    uint32_t n_rates;
  } steps[] = {
      /* (30 - 10) / 4 = 5; the first frame sets the frequency outright */
      {{1, 4.0, 1, 10.0, 30.0}, 1, 5.0, 1.0, 1},
      /* idle while frames need no depth pass: 1 + 0.25 (0 - 1) */
      {{0, 0.0, 0, 0.0, 0.0}, 0, 5.0, 0.75, 1},
      /* 4 % of the frame at 100 / 4 = 25 per unit (above 5): left out;
       * no depth pass: 0.75 + 0.25 (0 - 0.75) */
      {{1, 4.0, 0, 0.0, 100.0}, 0, 5.0, 0.5625, 1},
      /* the same sliver at 8 / 4 = 2 lowers it: of {5, 2}, 2 */
      {{1, 4.0, 0, 0.0, 8.0}, 0, 2.0, 0.421875, 2},
      /* 5 % or more counts whatever it says: {5, 2, 25}: 5 */
      {{1, 5.0, 0, 0.0, 125.0}, 0, 5.0, 0.31640625, 3},
  };
  rp__split_model m;
  size_t i;
  (void)state;
  memset(&m, 0, sizeof m);
  for (i = 0; i < sizeof steps / sizeof *steps; i++) {
    rp__split_learn(&m, &steps[i].s, 100.0, steps[i].frame_depth);
    if (m.rate != steps[i].rate || m.depth_freq != steps[i].depth_freq ||
        m.n_rates != steps[i].n_rates)
      fail_msg("step %zu: rate %g, depth_freq %g, %u rates", i, m.rate,
               m.depth_freq, m.n_rates);
  }
  assert_true(m.depth_est == 10.0); /* the one depth pass measured */
}

/* The frame's predicted time: c0 = 2 ms, Q = 1.5 and t' = 10 ms give
 * fixed 3 and var 7; with a second device of fixed 1, var 20 at shares
 * 0.6 / 0.4, the devices take 3 + 4.2 and 1 + 8 ms: the frame 9 ms, the
 * fastest (least var) device 0. A share under half a tile pays nothing:
 * 0.004 of 100 tiles. */
static void test_predict(void **state) {
  rp__device_cost c[2];
  double shares[2] = {0.6, 0.4}, sliver[2] = {0.996, 0.004};
  int fastest;
  (void)state;
  memset(c, 0, sizeof c);
  c[0].e.c0_ms = 2.0;
  c[0].e.frame_factor = 1.5;
  c[0].e.ms = 10.0;
  rp__device_cost_split(&c[0]);
  assert_true(c[0].ok && c[0].fixed == 3.0 && c[0].var == 7.0);
  c[1].e.c0_ms = 1.0;
  c[1].e.frame_factor = 1.0;
  c[1].e.ms = 21.0;
  rp__device_cost_split(&c[1]);
  assert_true(c[1].ok && c[1].fixed == 1.0 && c[1].var == 20.0);
  assert_true(fabs(rp__predict_frame(c, shares, 2, 100.0, &fastest) - 9.0) <
              1e-12);
  assert_int_equal(fastest, 0);
  assert_true(fabs(rp__predict_frame(c, sliver, 2, 100.0, &fastest) -
                   (3.0 + 0.996 * 7.0)) < 1e-12);
  /* A model predicting no raycast (t' at or under its fixed part) is
   * left out; none left: NaN. */
  c[0].e.ms = 3.0;
  rp__device_cost_split(&c[0]);
  assert_false(c[0].ok);
  assert_true(fabs(rp__predict_frame(c, shares, 2, 100.0, &fastest) - 9.0) <
              1e-12);
  assert_int_equal(fastest, 1);
  c[1].e.ms = NAN;
  rp__device_cost_split(&c[1]);
  assert_true(isnan(rp__predict_frame(c, shares, 2, 100.0, &fastest)));
  assert_int_equal(fastest, -1);
}

/* Region sums and the tail: a 4 x 4 grid whose tile (x, y) costs
 * 1 + x + 4 y sums to 136 (16 + 120). A tail of a quarter needs 34: the
 * bottom row (1 + 12) * 4 + 6 = 58 reaches it. Two strips of 29 each:
 * columns 13 + 14 = 27 < 29, + 15 = 42, so the first closes after x = 2,
 * leaving the last column. */
static void test_regions_and_tail(void **state) {
  float cost[16];
  rp_region all = {0, 0, 4, 4}, box = {1, 1, 3, 3}, strips[8];
  uint32_t i, n;
  (void)state;
  for (i = 0; i < 16; i++)
    cost[i] = (float)(1 + (i % 4) + 4 * (i / 4));
  assert_true(rp__region_cost(cost, 4, &all) == 136.0);
  /* Tiles (1,1) (2,1) (1,2) (2,2): 6 + 7 + 10 + 11. */
  assert_true(rp__region_cost(cost, 4, &box) == 34.0);
  n = rp__tail_cut(cost, 4, 4, 0.25, 2, 136.0, strips);
  assert_int_equal(n, 2);
  assert_true(strips[0].x0 == 0 && strips[0].x1 == 3 &&
              strips[0].y0 == 3 && strips[0].y1 == 4);
  assert_true(strips[1].x0 == 3 && strips[1].x1 == 4 &&
              strips[1].y0 == 3 && strips[1].y1 == 4);
  /* Half the frame: two rows (58 + 42 = 100 >= 68); eight strips are
   * capped at the grid's 4 columns, one column each. */
  n = rp__tail_cut(cost, 4, 4, 0.5, 8, 136.0, strips);
  assert_int_equal(n, 4);
  for (i = 0; i < 4; i++)
    assert_true(strips[i].x0 == i && strips[i].x1 == i + 1 &&
                strips[i].y0 == 2 && strips[i].y1 == 4);
  /* No tail on one row, on a frame of no cost, or when every row but
   * the top costs nothing. */
  assert_int_equal(rp__tail_cut(cost, 16, 1, 0.25, 2, 136.0, strips), 0);
  assert_int_equal(rp__tail_cut(cost, 4, 4, 0.25, 2, 0.0, strips), 0);
  for (i = 4; i < 16; i++)
    cost[i] = 0.0f;
  assert_int_equal(rp__tail_cut(cost, 4, 4, 0.25, 2, 10.0, strips), 0);
  assert_true(rp__region_empty(&(rp_region){2, 0, 2, 4}));
  assert_false(rp__region_empty(&box));
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_finish_together),
      cmocka_unit_test(test_damping),
      cmocka_unit_test(test_out_of_race_and_unknown),
      cmocka_unit_test(test_dropped_and_fixed),
      cmocka_unit_test(test_rate_median),
      cmocka_unit_test(test_learn),
      cmocka_unit_test(test_predict),
      cmocka_unit_test(test_regions_and_tail),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
