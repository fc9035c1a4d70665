/* Backend "test" (runtime/test_backend.c, raypace_testing.h): the
 * deterministic test device.
 *
 * - Its images and tile stats are the reference device's, byte for byte,
 *   over effect sets (AO included), cameras and regions.
 * - Without noise, every time it reports is the formula of
 *   raypace_testing.h evaluated here from the work counted independently:
 *   rays from the region, fetches from the reference device's counting
 *   path, voxels and bytes from the scene. Its clock is the sum of those
 *   times, an implicit depth pass included.
 * - With noise, one seed gives the same time sequence on two devices and
 *   another seed a different one; over 4000 operations of one base time
 *   the log-times' standard deviation is within 10 % of noise_sd (the
 *   estimate's own standard error is 1.1 %) and their mean within four
 *   standard errors of 0.
 * - Fault injection around it waits on its clock, not in wall time.
 * - Bad parameters and extension chains are refused naming the field. */
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
  return rp_test_scene_make(ctx, RP_GEN_PHANTOM, n, 3, "minmax-bone");
}

/* A device of `backend` holding the scene; `test` (may be NULL) chained
 * onto its desc. */
static rp_device *open_on(const char *backend, const scene *s,
                          rp_test_backend_desc *test) {
  rp_device_desc dd = {0};
  rp_device *dev = NULL;
  dd.backend = backend;
  if (test != NULL) {
    test->header.type = RP_EXT_TEST_BACKEND;
    dd.next = test;
  }
  if (rp_device_create(ctx, &dd, &dev) != 0)
    fail_msg("%s: %s", backend, rp_last_error(ctx));
  assert_int_equal(rp_device_set_volume(dev, s->vol), 0);
  assert_int_equal(rp_device_set_tf(dev, s->tf, s->occ), 0);
  return dev;
}

static uint64_t clock_of(const rp_device *dev) {
  uint64_t ns = 0;
  assert_int_equal(rp__device_clock_ns(dev, &ns), 1);
  return ns;
}

/* ---- the image ----------------------------------------------------------- */

static void test_images_are_the_references(void **state) {
  static const uint32_t effects[] = {
      0, RP_EFFECT_SHADING, RP_EFFECT_ERT | RP_EFFECT_SKIP,
      RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_AO};
  scene s = make_scene(24);
  rp_ao_desc ad = {6, 4, 4.0f, 1.0f, 0};
  rp_ao *ao = NULL;
  rp_device *t = open_on("test", &s, NULL), *r = open_on("reference", &s,
                                                           NULL);
  uint8_t a[40 * 30 * 4], b[40 * 30 * 4];
  rp_tile_stats ta[5 * 4], tb[5 * 4];
  size_t e;
  int cam;
  (void)state;
  assert_int_equal(rp_ao_compute_reference(ctx, s.vol, s.tf, &ad, NULL,
                                           NULL, &ao),
                   0);
  assert_int_equal(rp_device_set_ao(t, ao), 0);
  assert_int_equal(rp_device_set_ao(r, ao), 0);
  for (cam = 0; cam < 3; cam++)
    for (e = 0; e < sizeof effects / sizeof effects[0]; e++) {
      rp_camera c = {0};
      rp_render_desc d = {0};
      rp_region half = {8, 0, 40, 16};
      rp_camera_orbit(&c, s.vol, 30.0f + 100.0f * (float)cam, 20.0f,
                      cam == 2 ? 0.4f : 2.2f);
      d.width = 40, d.height = 30, d.effects = effects[e];
      d.step = cam == 1 ? 0.7f : 1.0f;
      memset(a, 1, sizeof a), memset(b, 2, sizeof b);
      memset(ta, 3, sizeof ta), memset(tb, 4, sizeof tb);
      assert_int_equal(rp_device_render(t, &c, &d, NULL, a, ta), 0);
      assert_int_equal(rp_render_reference(ctx, s.vol, s.tf, s.occ, ao, &c,
                                           &d, b, tb),
                       0);
      assert_memory_equal(a, b, sizeof a);
      assert_memory_equal(ta, tb, sizeof ta);
      /* A region, against the reference device's same region. */
      assert_int_equal(rp_device_render(t, &c, &d, &half, a, ta), 0);
      assert_int_equal(rp_device_render(r, &c, &d, &half, b, tb), 0);
      assert_memory_equal(a, b, sizeof a);
    }
  assert_int_equal(rp__device_clock_ns(r, &(uint64_t){0}), 0);
  rp_ao_destroy(ao);
  rp_device_destroy(t);
  rp_device_destroy(r);
  rp_test_scene_drop(&s);
}

/* ---- the formula --------------------------------------------------------- */

/* Integer costs, so that every formula is exact in double. */
static rp_test_backend_desc exact_costs(void) {
  rp_test_backend_desc d = {{RP_EXT_TEST_BACKEND, NULL}, 0, -1.0, 1000.0,
                            7.0, 3.0, 2.0, 2.0, 5.0};
  return d;
}

/* The reference device's fetches over the tiles of region r of a w-wide
 * image, counted by its counting path. */
static uint64_t reference_fetches(rp_device *ref, const rp_camera *c,
                                  const rp_render_desc *d,
                                  const rp_region *r) {
  uint32_t sw, sh, tx, ty, x, y;
  uint64_t *f, sum = 0;
  uint8_t *img;
  rp_scaled_size(d, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  f = calloc((size_t)tx * ty, sizeof *f);
  img = calloc((size_t)sw * sh, 4);
  assert_true(f != NULL && img != NULL);
  assert_int_equal(rp__device_render(ref, c, d, r, img, NULL, f), 0);
  for (y = r->y0 / 8; y * 8 < r->y1; y++)
    for (x = r->x0 / 8; x * 8 < r->x1; x++)
      sum += f[(size_t)y * tx + x];
  free(f);
  free(img);
  return sum;
}

static void test_times_follow_the_formula(void **state) {
  scene s = make_scene(32);
  rp_test_backend_desc p = exact_costs();
  rp_device *t, *r = open_on("reference", &s, NULL);
  rp_camera c = {0}, c2 = {0};
  rp_render_desc d = {0};
  rp_region all = {0, 0, 48, 40}, part = {8, 16, 32, 40};
  uint8_t img[48 * 40 * 4];
  float fb[48 * 40 * 2], ert[12 * 10];
  uint64_t want, sum = 0, fetches, nb = (uint64_t)s.occ->h->block_count;
  rp_ao_plan *plan = NULL;
  rp_ao_desc ad = {4, 3, 3.0f, 1.0f, 1};
  rp_ao *ao = NULL;
  uint32_t lo[3] = {2, 3, 4}, end[3] = {12, 9, 20};
  uint8_t *box = malloc(10 * 6 * 16);
  (void)state;
  t = open_on("test", &s, &p);
  /* The scene's uploads: volume, LUT (16 bytes an entry), occupancy (a
   * byte and 16 H-alpha bytes a block); the last is what is reported. */
  sum = 2 * 32 * 32 * 32 + 2 * 16 * (uint64_t)s.tf->lut_size +
        2 * 17 * nb;
  assert_int_equal(rp_device_last_time_ns(t), 2 * 17 * nb);
  assert_int_equal(clock_of(t), sum);
  rp_camera_orbit(&c, s.vol, 30.0f, 20.0f, 2.2f);
  rp_camera_orbit(&c2, s.vol, 140.0f, -30.0f, 2.0f);
  d.width = 48, d.height = 40;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  assert_int_equal(rp_device_depth_pass(t, &c, &d, fb), 0);
  want = 1000 + 2 * 48 * 40;
  assert_int_equal(rp_device_last_time_ns(t), want);
  sum += want;
  assert_int_equal(rp_device_ert_prepass(t, &c, &d, 1, 2, ert), 0);
  want = 1000 + 2 * 12 * 10;
  assert_int_equal(rp_device_last_time_ns(t), want);
  sum += want;
  /* The depth pass is held: the renders below run none. */
  fetches = reference_fetches(r, &c, &d, &all);
  assert_true(fetches > 48 * 40);
  assert_int_equal(rp_device_render(t, &c, &d, NULL, img, NULL), 0);
  want = 1000 + 7 * 48 * 40 + 3 * fetches;
  assert_int_equal(rp_device_last_time_ns(t), want);
  sum += want;
  fetches = reference_fetches(r, &c, &d, &part);
  assert_int_equal(rp_device_render(t, &c, &d, &part, img, NULL), 0);
  want = 1000 + 7 * 24 * 24 + 3 * fetches;
  assert_int_equal(rp_device_last_time_ns(t), want);
  sum += want;
  assert_int_equal(clock_of(t), sum);
  /* Another camera: the render runs its own depth pass first, which the
   * clock counts and the reported time does not. */
  fetches = reference_fetches(r, &c2, &d, &all);
  assert_int_equal(rp_device_render(t, &c2, &d, NULL, img, NULL), 0);
  want = 1000 + 7 * 48 * 40 + 3 * fetches;
  assert_int_equal(rp_device_last_time_ns(t), want);
  sum += 1000 + 2 * 48 * 40 + want;
  assert_int_equal(clock_of(t), sum);
  /* AO: a box of voxels, then an AO volume uploaded (a byte a voxel). */
  assert_int_equal(rp_ao_plan_create(ctx, s.vol, s.tf, &ad, &plan), 0);
  assert_int_equal(rp_device_compute_ao(t, plan, lo, end, box), 0);
  want = 1000 + 5 * 10 * 6 * 16;
  assert_int_equal(rp_device_last_time_ns(t), want);
  sum += want;
  assert_int_equal(rp_ao_compute_reference(ctx, s.vol, s.tf, &ad, NULL,
                                           NULL, &ao),
                   0);
  assert_int_equal(rp_device_set_ao(t, ao), 0);
  sum += 2 * 32 * 32 * 32;
  assert_int_equal(clock_of(t), sum);
  assert_int_equal(rp_device_set_ao(t, NULL), 0); /* free */
  assert_int_equal(clock_of(t), sum);
  free(box);
  rp_ao_destroy(ao);
  rp_ao_plan_destroy(plan);
  rp_device_destroy(t);
  rp_device_destroy(r);
  rp_test_scene_drop(&s);
}

/* ---- the noise ----------------------------------------------------------- */

/* n depth passes of an 8x8 image on a fresh device; their times. */
static void depth_times(const scene *s, rp_test_backend_desc *p, uint32_t n,
                        uint64_t *out) {
  rp_device *t = open_on("test", s, p);
  rp_camera c = {0};
  rp_render_desc d = {0};
  uint32_t i;
  rp_camera_orbit(&c, s->vol, 30.0f, 20.0f, 2.2f);
  d.width = d.height = 8;
  for (i = 0; i < n; i++) {
    assert_int_equal(rp_device_depth_pass(t, &c, &d, NULL), 0);
    out[i] = rp_device_last_time_ns(t);
  }
  rp_device_destroy(t);
}

/* Mean and standard deviation of log(t / base) over n times. */
static void log_spread(const uint64_t *t, uint32_t n, double base,
                       double *mean, double *sd) {
  double m = 0.0, v = 0.0;
  uint32_t i;
  for (i = 0; i < n; i++)
    m += log((double)t[i] / base);
  m /= n;
  for (i = 0; i < n; i++) {
    double x = log((double)t[i] / base) - m;
    v += x * x;
  }
  *mean = m;
  *sd = sqrt(v / (n - 1));
}

#define DRAWS 4000

static void test_noise_is_seeded(void **state) {
  scene s = make_scene(16);
  rp_test_backend_desc p = exact_costs();
  uint64_t *a = malloc(DRAWS * sizeof *a), *b = malloc(DRAWS * sizeof *b);
  uint64_t *c = malloc(DRAWS * sizeof *c);
  /* The base is large next to the rounding to whole ns (1e-6). */
  double base = 1e6 + 2.0 * 64, mean, sd, sds[2] = {0.05, 0.0};
  uint32_t i, same = 0, k;
  (void)state;
  assert_true(a != NULL && b != NULL && c != NULL);
  p.launch_ns = 1e6;
  for (k = 0; k < 2; k++) {
    double want = sds[k] > 0.0 ? sds[k] : 0.02; /* 0: the default */
    p.noise_sd = sds[k];
    p.seed = 42;
    depth_times(&s, &p, DRAWS, a);
    depth_times(&s, &p, DRAWS, b);
    assert_memory_equal(a, b, DRAWS * sizeof *a);
    p.seed = 43;
    depth_times(&s, &p, DRAWS, c);
    for (i = 0, same = 0; i < DRAWS; i++)
      same += a[i] == c[i];
    /* Two streams agree on a time only by chance (a few in a thousand
     * at this sd and base). */
    if (same > DRAWS / 50)
      fail_msg("seeds 42 and 43 agree on %u of %u times", same, DRAWS);
    log_spread(a, DRAWS, base, &mean, &sd);
    print_message("noise_sd %g: log-times mean %.5f, sd %.5f over %u\n",
                  want, mean, sd, DRAWS);
    assert_true(fabs(sd - want) <= 0.1 * want);
    assert_true(fabs(mean) <= 4.0 * want / sqrt(DRAWS));
  }
  free(a), free(b), free(c);
  rp_test_scene_drop(&s);
}

/* ---- faults around it ---------------------------------------------------- */

static double wall_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* A test device slowed 1000x whose operations cost a second each, and
 * stalled a minute at its second render: the reported times and the
 * clock say so exactly, and the test takes no such time. */
static void test_faults_wait_on_its_clock(void **state) {
  scene s = make_scene(16);
  rp_test_backend_desc p = exact_costs();
  rp_fault_desc fd = {{RP_EXT_FAULTS, NULL}, 1000.0, 0, 0, 2, 60000.0};
  rp_device_desc dd = {0};
  rp_device *t = NULL;
  rp_camera c = {0};
  rp_render_desc d = {0};
  uint8_t img[8 * 8 * 4];
  uint64_t before, ray;
  double t0 = wall_s();
  (void)state;
  p.launch_ns = 1e9;
  p.ray_ns = p.fetch_ns = p.depth_ray_ns = p.ns_per_byte = -1.0;
  dd.backend = "test";
  dd.next = &p;
  p.header.next = &fd;
  assert_int_equal(rp_device_create(ctx, &dd, &t), 0);
  assert_int_equal(rp_device_set_volume(t, s.vol), 0);
  assert_int_equal(rp_device_set_tf(t, s.tf, s.occ), 0);
  assert_int_equal(clock_of(t), 0); /* free uploads, slowed or not */
  rp_camera_orbit(&c, s.vol, 30.0f, 20.0f, 2.2f);
  d.width = d.height = 8;
  assert_int_equal(rp_device_render(t, &c, &d, NULL, img, NULL), 0);
  ray = 1000ull * 1000000000ull;
  assert_int_equal(rp_device_last_time_ns(t), ray);
  assert_int_equal(clock_of(t), 2 * ray); /* its depth pass, and it */
  before = clock_of(t);
  assert_int_equal(rp_device_render(t, &c, &d, NULL, img, NULL), 0);
  assert_int_equal(rp_device_last_time_ns(t), ray + 60000000000ull);
  assert_int_equal(clock_of(t) - before, ray + 60000000000ull);
  assert_true(wall_s() - t0 < 30.0);
  rp_device_destroy(t);
  rp_test_scene_drop(&s);
}

/* ---- refusals ------------------------------------------------------------ */

static void expect_refused(rp_device_desc *dd, int err, const char *says) {
  rp_device *dev = NULL;
  assert_int_equal(rp_device_create(ctx, dd, &dev), err);
  assert_null(dev);
  if (strstr(rp_last_error(ctx), says) == NULL)
    fail_msg("'%s' does not say '%s'", rp_last_error(ctx), says);
}

static void test_bad_parameters(void **state) {
  rp_test_backend_desc p = exact_costs(), q = exact_costs();
  rp_fault_desc fd = {{RP_EXT_FAULTS, NULL}, 0.0, 0, 0, 0, 0.0};
  rp_ext_header odd = {(rp_ext_type)99, NULL};
  rp_device_desc dd = {0};
  const char *const *n;
  uint32_t count = 0;
  int listed = 0;
  (void)state;
  dd.backend = "test";
  dd.next = &p;
  p.noise_sd = NAN;
  expect_refused(&dd, RP_ENOTFINITE, "rp_test_backend_desc.noise_sd");
  p.noise_sd = 1.5;
  expect_refused(&dd, RP_ERANGE, "noise_sd 1.5");
  p = exact_costs();
  p.ray_ns = 2e6;
  expect_refused(&dd, RP_ERANGE, "rp_test_backend_desc.ray_ns");
  p = exact_costs();
  p.launch_ns = INFINITY;
  expect_refused(&dd, RP_ENOTFINITE, "launch_ns");
  p = exact_costs();
  p.ao_voxel_ns = -INFINITY;
  expect_refused(&dd, RP_ENOTFINITE, "ao_voxel_ns");
  p = exact_costs();
  /* The chain: a second test desc, an unknown type, a loop (it repeats
   * a struct), and the test backend's parameters on another backend. */
  p.header.next = &q;
  expect_refused(&dd, RP_EINVAL, "two rp_test_backend_desc");
  p.header.next = &odd;
  expect_refused(&dd, RP_EINVAL, "struct 2 of desc->next has type 99");
  p.header.next = &fd;
  fd.header.next = &p;
  expect_refused(&dd, RP_EINVAL, "two rp_test_backend_desc");
  fd.header.next = NULL;
  dd.backend = "reference";
  expect_refused(&dd, RP_EINVAL, "for backend 'test'");
  /* The reference's refusals, under the test backend's name. */
  dd.backend = "test";
  p.header.next = NULL;
  dd.budget_bytes = 1024;
  expect_refused(&dd, RP_EUNSUPPORTED, "backend 'test' holds the whole");
  dd.budget_bytes = 0;
  dd.index = 1;
  expect_refused(&dd, RP_ENODEV, "backend 'test' has one device");
  dd.index = 0;
  dd.compute_units = 2;
  expect_refused(&dd, RP_EUNSUPPORTED, "cannot partition its device");
  /* Named only: listed and counted, never the default. */
  for (n = rp_backend_names(); *n != NULL; n++)
    listed += strcmp(*n, "test") == 0;
  assert_int_equal(listed, 1);
  assert_int_equal(rp_device_count(ctx, "test", &count), 0);
  assert_int_equal(count, 1);
  {
    rp_device_desc any = {0};
    rp_device *dev = NULL;
    rp_caps caps;
    int err = rp_device_create(ctx, &any, &dev);
    if (err == 0) {
      rp_device_get_caps(dev, &caps);
      assert_string_not_equal(caps.backend, "test");
      assert_string_not_equal(caps.backend, "reference");
      rp_device_destroy(dev);
    } else {
      assert_int_equal(err, RP_ENODEV);
    }
  }
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_images_are_the_references),
      cmocka_unit_test(test_times_follow_the_formula),
      cmocka_unit_test(test_noise_is_seeded),
      cmocka_unit_test(test_faults_wait_on_its_clock),
      cmocka_unit_test(test_bad_parameters),
  };
  int rc;
  /* Selection by default must not see a backend named here. */
  unsetenv("RP_BACKEND");
  ctx = rp_test_context();
  rc = cmocka_run_group_tests(tests, NULL, NULL);
  rp_context_destroy(ctx);
  return rc;
}
