/* Fault injection (runtime/faults.c, rp_fault_desc): a wrapper around any
 * backend.
 *
 * - Renders are counted as the front end sees them: an out-of-core
 *   render, which reaches the backend as three or more raycasts (parts,
 *   slabs) and brick uploads, counts once, so a device set to stall at its
 *   second render and fail from its third renders twice (the second
 *   stalled) and fails the third. Counting raycasts would fail the first.
 * - AO jobs are counted per rp_device_compute_ao, apart from renders.
 * - The wrapper forwards faithfully: for every backend present, a wrapped
 *   device with nothing to inject renders the plain device's image, and
 *   keeps its optional abilities (building ahead, its own clock). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "passes.h"
#include "raypace_ao.h"
#include "raypace_testing.h"
#include "test_util.h"

static rp_context *ctx;

typedef rp_test_scene scene;

static scene make_scene(uint32_t n) {
  return rp_test_scene_make(ctx, RP_GEN_PHANTOM, n, 5, "minmax-soft");
}

static rp_device *open_dev(rp_device_desc *dd, const scene *s) {
  rp_device *dev = NULL;
  if (rp_device_create(ctx, dd, &dev) != 0)
    fail_msg("%s: %s", dd->backend, rp_last_error(ctx));
  assert_int_equal(rp_device_set_volume(dev, s->vol), 0);
  assert_int_equal(rp_device_set_tf(dev, s->tf, s->occ), 0);
  return dev;
}

static double now_ms(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e3 + 1e-6 * (double)ts.tv_nsec;
}

/* ---- out of core --------------------------------------------------------- */

static void test_out_of_core_counts_renders(void **state) {
  const char *backend = rp_test_has_device("opencl")   ? "opencl"
                        : rp_test_has_device("vulkan") ? "vulkan"
                                                       : NULL;
  scene s;
  rp_device_desc dd = {0};
  rp_fault_desc fd = {{RP_EXT_FAULTS, NULL}, 0.0, 3, 0, 2, 300.0};
  rp_device *plain, *faulty;
  rp_camera c = {0};
  rp_render_desc d = {0};
  rp_brick_stats st;
  uint8_t *want, *got;
  uint32_t i;
  double t0;
  (void)state;
  if (backend == NULL)
    skip(); /* out of core needs a backend with a brick pool */
  s = make_scene(96);
  want = malloc(128 * 96 * 4);
  got = malloc(128 * 96 * 4);
  assert_true(want != NULL && got != NULL);
  rp_camera_orbit(&c, s.vol, 30.0f, 20.0f, 2.2f);
  d.width = 128, d.height = 96;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  dd.backend = backend;
  dd.budget_bytes = 96 * 96 * 96 / 8;
  dd.brick_size = 8;
  plain = open_dev(&dd, &s);
  rp_test_faults(&dd, &fd);
  faulty = open_dev(&dd, &s);
  assert_int_equal(rp_device_render(plain, &c, &d, NULL, want, NULL), 0);
  assert_int_equal(rp_device_get_brick_stats(plain, &st), 0);
  assert_int_equal(st.out_of_core, 1);
  print_message("%s: a render in %u parts (%u slabs)\n", backend,
                st.last_pieces, st.last_slabs);
  assert_true(st.last_pieces >= 3);
  /* Render 1 takes as many raycasts, and is one render. */
  assert_int_equal(rp_device_render(faulty, &c, &d, NULL, got, NULL), 0);
  assert_int_equal(rp_device_get_brick_stats(faulty, &st), 0);
  assert_true(st.last_pieces >= 3);
  assert_memory_equal(got, want, 128 * 96 * 4);
  /* Render 2 stalls 300 ms, once. */
  memset(got, 0, 128 * 96 * 4);
  t0 = now_ms();
  assert_int_equal(rp_device_render(faulty, &c, &d, NULL, got, NULL), 0);
  assert_true(now_ms() - t0 >= 300.0);
  assert_true(rp_device_last_time_ns(faulty) >= 300000000u);
  assert_memory_equal(got, want, 128 * 96 * 4);
  /* Render 3 and every later one fail, leaving the image alone. */
  for (i = 0; i < 2; i++) {
    memset(got, 0x5a, 128 * 96 * 4);
    assert_int_equal(rp_device_render(faulty, &c, &d, NULL, got, NULL),
                     RP_EDEVICE);
    assert_non_null(strstr(rp_last_error(ctx), "injected at render 3"));
    assert_int_equal(got[0], 0x5a);
    assert_int_equal(got[128 * 96 * 4 - 1], 0x5a);
  }
  rp_device_destroy(faulty);
  rp_device_destroy(plain);
  free(want);
  free(got);
  rp_test_scene_drop(&s);
}

/* ---- AO jobs ------------------------------------------------------------- */

static void test_ao_jobs_fail_apart(void **state) {
  scene s = make_scene(16);
  rp_device_desc dd = {0};
  rp_fault_desc fd = {{RP_EXT_FAULTS, NULL}, 0.0, 0, 2, 0, 0.0};
  rp_ao_desc ad = {4, 3, 3.0f, 1.0f, 1};
  rp_ao_plan *plan = NULL;
  rp_device *dev;
  rp_camera c = {0};
  rp_render_desc d = {0};
  uint32_t lo[3] = {0, 0, 0}, end[3] = {4, 4, 4};
  uint8_t box[64], img[8 * 8 * 4];
  int i;
  (void)state;
  dd.backend = "reference";
  rp_test_faults(&dd, &fd);
  dev = open_dev(&dd, &s);
  assert_int_equal(rp_ao_plan_create(ctx, s.vol, s.tf, &ad, &plan), 0);
  rp_camera_orbit(&c, s.vol, 30.0f, 20.0f, 2.2f);
  d.width = d.height = 8;
  assert_int_equal(rp_device_compute_ao(dev, plan, lo, end, box), 0);
  for (i = 0; i < 3; i++) {
    assert_int_equal(rp_device_compute_ao(dev, plan, lo, end, box),
                     RP_EDEVICE);
    assert_non_null(strstr(rp_last_error(ctx), "injected at AO job 2"));
    /* Renders are counted apart: none was set to fail. */
    assert_int_equal(rp_device_render(dev, &c, &d, NULL, img, NULL), 0);
  }
  rp_ao_plan_destroy(plan);
  rp_device_destroy(dev);
  rp_test_scene_drop(&s);
}

/* ---- forwarding ---------------------------------------------------------- */

static void test_wrapper_forwards(void **state) {
  static const char *const backends[] = {"reference", "test", "opencl",
                                         "vulkan"};
  scene s = make_scene(32);
  rp_camera c = {0};
  rp_render_desc d = {0};
  uint8_t a[40 * 24 * 4], b[40 * 24 * 4];
  size_t k;
  int ran = 0;
  (void)state;
  rp_camera_orbit(&c, s.vol, 60.0f, 10.0f, 2.0f);
  d.width = 40, d.height = 24;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_SKIP;
  for (k = 0; k < sizeof backends / sizeof backends[0]; k++) {
    rp_device_desc dd = {0};
    rp_fault_desc fd = {{RP_EXT_FAULTS, NULL}, 0.0, 0, 0, 0, 0.0};
    rp_device *plain, *wrapped;
    uint64_t ns;
    if (!rp_test_has_device(backends[k]))
      continue;
    ran++;
    dd.backend = backends[k];
    plain = open_dev(&dd, &s);
    rp_test_faults(&dd, &fd);
    wrapped = open_dev(&dd, &s);
    memset(a, 1, sizeof a);
    memset(b, 2, sizeof b);
    assert_int_equal(rp_device_render(plain, &c, &d, NULL, a, NULL), 0);
    assert_int_equal(rp_device_render(wrapped, &c, &d, NULL, b, NULL), 0);
    assert_memory_equal(a, b, sizeof a);
    assert_int_equal(rp__device_builds_ahead(wrapped),
                     rp__device_builds_ahead(plain));
    assert_int_equal(rp__device_clock_ns(wrapped, &ns),
                     rp__device_clock_ns(plain, &ns));
    assert_int_equal(rp_device_prepare(wrapped, ctx, d.effects), 0);
    rp_device_destroy(wrapped);
    rp_device_destroy(plain);
  }
  assert_true(ran >= 2); /* the host backends are always there */
  rp_test_scene_drop(&s);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_out_of_core_counts_renders),
      cmocka_unit_test(test_ao_jobs_fail_apart),
      cmocka_unit_test(test_wrapper_forwards),
  };
  int rc;
  ctx = rp_test_context();
  rc = cmocka_run_group_tests(tests, NULL, NULL);
  rp_context_destroy(ctx);
  return rc;
}
