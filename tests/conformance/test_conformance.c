/* Backend conformance, written once and run per backend (ctest registers
 * it with RP_BACKEND=reference|test|opencl|vulkan; exit code 77 when that
 * backend has no device here). conformance.h states the tolerances; the
 * areas are in files of their own: images.c (the image matrices against
 * rp_render_reference), passes.c (depth pass, ERT pre-pass, regions,
 * fetch counts), occlusion.c (the AO volume and renders reading it),
 * kernels.c (kernels built ahead, the kernel-variant cache). This file:
 * the device itself (caps, time, the front end's checks, the testing
 * knobs, partitions) and main. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "conformance.h"

rp_context *ctx;
rp_device *dev;

/* What every backend's device says of itself: all effects and voxel
 * types, at least one compute unit, an allocation limit within its
 * memory, not a sub-device; and a device index past the backend's last
 * is RP_ENODEV, saying which was asked for. */
static void device_caps(void **state) {
  rp_caps caps;
  rp_device_desc dd = {0};
  rp_device *none = NULL;
  uint32_t n = 0;
  (void)state;
  rp_device_get_caps(dev, &caps);
  assert_string_equal(caps.backend, backend_name());
  assert_true(caps.device[0] != '\0');
  assert_int_equal(caps.sub_device, 0);
  assert_int_equal(caps.effects, RP_EFFECT_SHADING | RP_EFFECT_ERT |
                                     RP_EFFECT_SKIP | RP_EFFECT_AO |
                                     RP_EFFECT_PREINT);
  assert_int_equal(caps.voxel_types,
                   (1u << RP_U8) | (1u << RP_U16) | (1u << RP_F32));
  assert_true(caps.compute_units >= 1);
  assert_true(caps.global_mem_bytes > 0);
  assert_true(caps.max_alloc_bytes > 0 &&
              caps.max_alloc_bytes <= caps.global_mem_bytes);
  assert_int_equal(rp_device_count(ctx, backend_name(), &n), 0);
  assert_true(n >= 1);
  dd.backend = backend_name();
  dd.index = n;
  assert_int_equal(rp_device_create(ctx, &dd, &none), RP_ENODEV);
  assert_null(none);
  assert_non_null(strstr(rp_last_error(ctx), "requested"));
}

static double now_ns(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e9 + (double)ts.tv_nsec;
}

/* The time a device reports (rp_device_last_time_ns): non-zero after a
 * depth pass and a render, and a render's never more than the
 * wall time of the blocking call that ran it (with 1 % and 10 us for a
 * device clock's rate and granularity), at two image sizes. The first
 * render of a size is not timed: it may build kernels and runs the
 * depth pass. Whether the time grows with the work is a timing order,
 * which a shared machine can flip: bench_backends shows that as
 * medians. */
static void device_time(void **state) {
  scene s = make_scene("phantom 48^3", RP_GEN_PHANTOM, 48, 48, 48, RP_U8);
  rp_camera cam = camera(s.vol, CAM_OUTSIDE);
  rp_tf *tf = rp_test_preset(ctx, "minmax-bone");
  rp_occupancy *occ = NULL;
  int r;
  (void)state;
  assert_int_equal(rp_occupancy_build(ctx, s.h, tf, &occ), 0);
  assert_int_equal(rp_device_set_volume(dev, s.vol), 0);
  assert_int_equal(rp_device_set_tf(dev, tf, occ), 0);
  for (r = 0; r < 2; r++) {
    rp_render_desc d = {0};
    uint32_t n = r ? 128 : 16;
    uint8_t *img = malloc((size_t)n * n * 4);
    float *fb = malloc((size_t)n * n * 2 * sizeof *fb);
    double t0, wall_ns, dev_ns;
    assert_true(img != NULL && fb != NULL);
    d.width = d.height = n;
    assert_int_equal(rp_device_depth_pass(dev, &cam, &d, fb), 0);
    assert_true(rp_device_last_time_ns(dev) > 0);
    assert_int_equal(rp_device_render(dev, &cam, &d, NULL, img, NULL), 0);
    assert_true(rp_device_last_time_ns(dev) > 0);
    t0 = now_ns();
    assert_int_equal(rp_device_render(dev, &cam, &d, NULL, img, NULL), 0);
    wall_ns = now_ns() - t0;
    dev_ns = (double)rp_device_last_time_ns(dev);
    print_message("%s %ux%u render: device %.3f ms, call %.3f ms\n",
                  backend_name(), n, n, dev_ns * 1e-6, wall_ns * 1e-6);
    assert_true(dev_ns > 0 && dev_ns <= 1.01 * wall_ns + 1e4);
    free(img);
    free(fb);
  }
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
  drop_scene(&s);
}

/* Calls in the wrong state or with bad arguments never reach the backend
 * and say what is wrong. */
static void front_end_validates(void **state) {
  rp_device *fresh = NULL;
  rp_device_desc dd = {0};
  rp_camera cam = {0};
  rp_render_desc d = {0};
  uint8_t px[4];
  (void)state;
  dd.backend = backend_name();
  assert_int_equal(rp_device_create(ctx, &dd, &fresh), 0);
  cam.eye[2] = 5;
  d.width = d.height = 1;
  assert_int_equal(rp_device_render(fresh, &cam, &d, NULL, px, NULL),
                   RP_ESTATE);
  assert_non_null(strstr(rp_last_error(ctx), "volume"));
  assert_int_equal(rp_device_set_tf(fresh, NULL, NULL), RP_EINVAL);
  dd.backend = "no-such-backend";
  assert_int_equal(rp_device_create(ctx, &dd, &fresh), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "available"));
  rp_device_destroy(fresh);
  rp_device_destroy(NULL);
}

/* One render of the whole 8x8 image, the time that passed for the
 * device meanwhile (wall time, or its own clock when it keeps one: the
 * test backend) and the time it reports, in ns. */
static void timed_render(rp_device *on, const rp_camera *cam,
                         const rp_render_desc *d, uint8_t *img,
                         double *wall_ns, double *reported_ns) {
  struct timespec a, b;
  uint64_t c0 = 0, c1 = 0;
  int own = rp__device_clock_ns(on, &c0);
  clock_gettime(CLOCK_MONOTONIC, &a);
  assert_int_equal(rp_device_render(on, cam, d, NULL, img, NULL), 0);
  clock_gettime(CLOCK_MONOTONIC, &b);
  *wall_ns = (double)(b.tv_sec - a.tv_sec) * 1e9 +
             (double)(b.tv_nsec - a.tv_nsec);
  if (own && rp__device_clock_ns(on, &c1))
    *wall_ns = (double)(c1 - c0);
  *reported_ns = (double)rp_device_last_time_ns(on);
}
/* Fault injection (rp_fault_desc) around this backend. A device slowed
 * 1000x (once warm: rp__device_set_slowdown after a first render) waits
 * 999x its device time after each operation and reports 1000x it: its renders report at least 10x the median of the same
 * renders on the plain device (a margin of 100 against noise), and the
 * time that passes for each (wall time, or the device's own clock) is
 * at least 999/1000 of what it reports (less 1 ns for the rounding to
 * whole ns), however fast or loaded the machine is. Either bound fails
 * if its half of the slowdown is missing. A device set to fail at its
 * second render renders once, the same image as the plain device, then
 * fails every render with RP_EDEVICE and leaves the caller's image as it
 * was. */
static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

static void slowed_and_failing_devices(void **state) {
  scene s = make_scene("phantom 24^3", RP_GEN_PHANTOM, 24, 24, 24, RP_U8);
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  rp_camera cam = camera(s.vol, 0);
  rp_render_desc d = {0};
  rp_device_desc dd = {0};
  rp_fault_desc fd = {{RP_EXT_FAULTS, NULL}, 0.0, 0, 0, 0, 0.0};
  rp_device *slow = NULL, *lost = NULL, *plain = NULL;
  uint8_t first[8 * 8 * 4], img[8 * 8 * 4], keep[8 * 8 * 4];
  double wall_ns, reported_ns, plain_ns[3];
  int i;
  (void)state;
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, s.h, tf, &occ), 0);
  d.width = d.height = 8;
  d.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP;
  dd.backend = backend_name();
  assert_int_equal(rp_device_create(ctx, &dd, &plain), 0);
  dd.next = &fd;
  fd.slowdown = 0.5;
  assert_int_equal(rp_device_create(ctx, &dd, &slow), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "slowdown"));
  fd.slowdown = NAN;
  assert_int_equal(rp_device_create(ctx, &dd, &slow), RP_ENOTFINITE);
  fd.slowdown = 20001.0;
  assert_int_equal(rp_device_create(ctx, &dd, &slow), RP_ERANGE);
  assert_null(slow);
  fd.slowdown = 0.0;
  fd.stall_ms = -1.0;
  assert_int_equal(rp_device_create(ctx, &dd, &slow), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "stall_ms"));
  fd.stall_ms = INFINITY;
  assert_int_equal(rp_device_create(ctx, &dd, &slow), RP_ENOTFINITE);
  assert_null(slow);
  fd.stall_ms = 0.0;
  assert_int_equal(rp_device_set_volume(plain, s.vol), 0);
  assert_int_equal(rp_device_set_tf(plain, tf, occ), 0);
  for (i = 0; i < 3; i++) {
    assert_int_equal(rp_device_render(plain, &cam, &d, NULL, img, NULL), 0);
    plain_ns[i] = (double)rp_device_last_time_ns(plain);
  }
  qsort(plain_ns, 3, sizeof plain_ns[0], cmp_double);
  /* Slowed once warm: its first render builds its kernels, which lavapipe
   * counts as device time (107 ms on a fresh machine, 107 s slowed). */
  assert_int_equal(rp_device_create(ctx, &dd, &slow), 0);
  assert_int_equal(rp_device_set_volume(slow, s.vol), 0);
  assert_int_equal(rp_device_set_tf(slow, tf, occ), 0);
  assert_int_equal(rp_device_render(slow, &cam, &d, NULL, first, NULL), 0);
  assert_int_equal(rp__device_set_slowdown(plain, 1000.0), RP_EINVAL);
  assert_int_equal(rp__device_set_slowdown(slow, 0.5), RP_ERANGE);
  assert_int_equal(rp__device_set_slowdown(slow, 1000.0), 0);
  for (i = 0; i < 2; i++) {
    timed_render(slow, &cam, &d, first, &wall_ns, &reported_ns);
    assert_true(reported_ns >= 10.0 * plain_ns[1]);
    assert_true(wall_ns + 1.0 >= reported_ns * 999.0 / 1000.0);
  }
  assert_memory_equal(first, img, sizeof img);
  rp_device_destroy(slow);
  slow = NULL;
  /* A stall of 200 ms on the third render only: that render's wall and
   * reported times grow by it, the second and fourth do not (a warm 8x8
   * render takes well under a millisecond). The first is not timed: a
   * new device may compile its kernels then, and lavapipe's first
   * dispatch counts its compile as device time (440 ms here cold). */
  fd.slowdown = 0.0;
  fd.stall_at_render = 3;
  fd.stall_ms = 200.0;
  assert_int_equal(rp_device_create(ctx, &dd, &slow), 0);
  assert_int_equal(rp_device_set_volume(slow, s.vol), 0);
  assert_int_equal(rp_device_set_tf(slow, tf, occ), 0);
  assert_int_equal(rp_device_render(slow, &cam, &d, NULL, first, NULL), 0);
  for (i = 0; i < 3; i++) {
    timed_render(slow, &cam, &d, first, &wall_ns, &reported_ns);
    if (i == 1) {
      assert_true(wall_ns >= 200e6 && reported_ns >= 200e6);
    } else {
      assert_true(reported_ns < 200e6);
    }
    assert_memory_equal(first, img, sizeof img);
  }
  fd.stall_at_render = 0;
  fd.stall_ms = 0.0;
  fd.fail_at_render = 2;
  assert_int_equal(rp_device_create(ctx, &dd, &lost), 0);
  assert_int_equal(rp_device_set_volume(lost, s.vol), 0);
  assert_int_equal(rp_device_set_tf(lost, tf, occ), 0);
  assert_int_equal(rp_device_render(lost, &cam, &d, NULL, first, NULL), 0);
  assert_memory_equal(first, img, sizeof img);
  for (i = 0; i < 2; i++) {
    memset(keep, 0x5a, sizeof keep);
    assert_int_equal(rp_device_render(lost, &cam, &d, NULL, keep, NULL),
                     RP_EDEVICE);
    assert_non_null(strstr(rp_last_error(ctx), "injected"));
    for (size_t j = 0; j < sizeof keep; j++)
      assert_int_equal(keep[j], 0x5a);
  }
  rp_device_destroy(lost);
  rp_device_destroy(slow);
  rp_device_destroy(plain);
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
  drop_scene(&s);
}

/* rp_device_desc's compute_units. A backend that cannot partition a
 * device (the reference, Vulkan) refuses it with RP_EUNSUPPORTED. OpenCL,
 * where the device splits equally: a sub-device of all its compute units
 * and one of one compute unit open and say so in their caps, the latter
 * renders the whole device's image byte for byte (the same kernels on the
 * same hardware), and more compute units than the device has are
 * RP_ERANGE. A refused device is not created, and every device leaves
 * the allocation count as it found it (a context of its own counts). */
typedef struct counting {
  long allocs, frees;
} counting;

static void *count_alloc(size_t size, void *user) {
  ((counting *)user)->allocs++;
  return malloc(size);
}

static void count_free(void *p, void *user) {
  if (p != NULL)
    ((counting *)user)->frees++;
  free(p);
}

/* A context whose allocator counts into `c`. */
static rp_context *counting_context(counting *c) {
  rp_context_desc cd = {0};
  rp_context *cc = NULL;
  cd.allocator.alloc = count_alloc;
  cd.allocator.free = count_free;
  cd.allocator.user = c;
  assert_int_equal(rp_context_create(&cd, &cc), 0);
  return cc;
}

/* rp_device_create on the counting context: returns its result and
 * checks that a refused device is NULL and freed everything it took. */
static int counted_create(rp_context *cc, const counting *c,
                          const rp_device_desc *dd, rp_device **out) {
  long live = c->allocs - c->frees;
  int err;
  *out = NULL;
  err = rp_device_create(cc, dd, out);
  if (err != 0) {
    assert_null(*out);
    assert_int_equal(c->allocs - c->frees, live);
  }
  return err;
}

static void partitioned_devices(void **state) {
  scene s = make_scene("phantom 40^3", RP_GEN_PHANTOM, 40, 40, 40, RP_U8);
  counting c = {0, 0};
  rp_context *cc = counting_context(&c);
  rp_device_desc dd = {0};
  rp_device *part = NULL;
  rp_caps whole, caps;
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  rp_camera cam = camera(s.vol, 0);
  rp_render_desc d = {0};
  uint8_t a[40 * 32 * 4], b[40 * 32 * 4];
  rp_tile_stats ta[5 * 4], tb[5 * 4];
  long live;
  int err;
  (void)state;
  rp_device_get_caps(dev, &whole);
  dd.backend = backend_name();
  dd.compute_units = 1;
  err = counted_create(cc, &c, &dd, &part);
  if (strcmp(backend_name(), "opencl") != 0 || err == RP_EUNSUPPORTED) {
    /* Refused: the message says why, and so is every other count. */
    assert_int_equal(err, RP_EUNSUPPORTED);
    assert_non_null(strstr(rp_last_error(cc), "partition"));
    dd.compute_units = whole.compute_units + 1;
    assert_int_equal(counted_create(cc, &c, &dd, &part), RP_EUNSUPPORTED);
    print_message("%s: %s\n", backend_name(), rp_last_error(cc));
    rp_context_destroy(cc);
    assert_int_equal(c.allocs, c.frees);
    drop_scene(&s);
    if (strcmp(backend_name(), "opencl") == 0)
      skip(); /* an OpenCL device that cannot be split equally */
    return;
  }
  assert_int_equal(err, 0);
  rp_device_get_caps(part, &caps);
  assert_string_equal(caps.backend, "opencl");
  assert_int_equal(caps.sub_device, 1);
  assert_int_equal(caps.compute_units, 1);
  rp_device_destroy(part);
  /* All of the device's compute units: one part, the size of the whole. */
  live = c.allocs - c.frees;
  dd.compute_units = whole.compute_units;
  assert_int_equal(counted_create(cc, &c, &dd, &part), 0);
  rp_device_get_caps(part, &caps);
  assert_int_equal(caps.sub_device, 1);
  assert_int_equal(caps.compute_units, whole.compute_units);
  rp_device_destroy(part);
  assert_int_equal(c.allocs - c.frees, live);
  /* One more is out of range, and says so. */
  dd.compute_units = whole.compute_units + 1;
  assert_int_equal(counted_create(cc, &c, &dd, &part), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(cc), "exceeds"));
  rp_context_destroy(cc);
  assert_int_equal(c.allocs, c.frees);
  /* One compute unit renders what the whole device renders. */
  dd.compute_units = 1;
  assert_int_equal(rp_device_create(ctx, &dd, &part), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, s.h, tf, &occ), 0);
  d.width = 40, d.height = 32;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  memset(a, 0x11, sizeof a);
  memset(b, 0x22, sizeof b);
  assert_int_equal(rp_device_set_volume(dev, s.vol), 0);
  assert_int_equal(rp_device_set_tf(dev, tf, occ), 0);
  assert_int_equal(rp_device_render(dev, &cam, &d, NULL, a, ta), 0);
  assert_int_equal(rp_device_set_volume(part, s.vol), 0);
  assert_int_equal(rp_device_set_tf(part, tf, occ), 0);
  assert_int_equal(rp_device_render(part, &cam, &d, NULL, b, tb), 0);
  assert_memory_equal(a, b, sizeof a);
  assert_memory_equal(ta, tb, sizeof ta);
  assert_true(ta[2 * 5 + 2].samples > 0); /* the middle is not empty */
  rp_device_destroy(part);
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
  drop_scene(&s);
}

/* Everything a device takes from its context's allocator goes back to it,
 * through a volume, a TF with its occupancy (the backends stage the LUT
 * and its pre-integration table in the context's memory) and a frame:
 * counted through a user allocator. OpenCL and Vulkan gave the staging
 * copy to free() instead (a foreign pointer for a user allocator). */
static void allocations_return(void **state) {
  scene s = make_scene("phantom 24^3", RP_GEN_PHANTOM, 24, 24, 24, RP_U8);
  counting c = {0, 0};
  rp_context *cc = counting_context(&c);
  rp_device_desc dd = {0};
  rp_device *own = NULL;
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  rp_camera cam = camera(s.vol, 0);
  rp_render_desc d = {0};
  uint8_t img[24 * 16 * 4];
  (void)state;
  dd.backend = backend_name();
  assert_int_equal(rp_device_create(cc, &dd, &own), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, s.h, tf, &occ), 0);
  assert_int_equal(rp_device_set_volume(own, s.vol), 0);
  assert_int_equal(rp_device_set_tf(own, tf, occ), 0);
  d.width = 24, d.height = 16;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  assert_int_equal(rp_device_render(own, &cam, &d, NULL, img, NULL), 0);
  rp_device_destroy(own);
  rp_context_destroy(cc);
  /* The context and the device at least. */
  assert_true(c.allocs >= 2);
  assert_int_equal(c.allocs, c.frees);
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
  drop_scene(&s);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(device_caps),
      cmocka_unit_test(front_end_validates),
      cmocka_unit_test(device_time),
      cmocka_unit_test(slowed_and_failing_devices),
      cmocka_unit_test(partitioned_devices),
      cmocka_unit_test(allocations_return),
      cmocka_unit_test(regions_compose),
      cmocka_unit_test(depth_pass),
      cmocka_unit_test(ert_prepass),
      cmocka_unit_test(fetch_counts),
      cmocka_unit_test(odd_viewports_and_scales),
      cmocka_unit_test(views_and_steps),
      cmocka_unit_test(scenes_from_three_cameras),
      cmocka_unit_test(thin_volumes),
      cmocka_unit_test(jitter_seeds),
      cmocka_unit_test(matrix_phantom_u8),
      cmocka_unit_test(matrix_marschner_lobb_u16),
      cmocka_unit_test(matrix_noise),
      cmocka_unit_test(matrix_float),
      cmocka_unit_test(matrix_ct_head_s16),
      cmocka_unit_test(matrix_thin_shell_u16),
      cmocka_unit_test(matrix_real_volumes),
      cmocka_unit_test(ao_volume),
      cmocka_unit_test(ao_render),
      cmocka_unit_test(ao_state),
      cmocka_unit_test(prepare_no_volume),
      cmocka_unit_test(prepare_builds_ahead),
      cmocka_unit_test(prepare_ao),
      cmocka_unit_test(prepare_concurrent),
      /* Last: the variants it renders are the ones the matrices above
       * built, which a driver's own disk cache (PoCL's) then holds. */
      cmocka_unit_test(variant_cache),
  };
  rp_device_desc dd = {0};
  rp_caps caps;
  int rc, err;
  assert_int_equal(rp_context_create(NULL, &ctx), 0);
  dd.backend = backend_name();
  err = rp_device_create(ctx, &dd, &dev);
  if (err != 0) {
    printf("conformance: backend '%s' unavailable here: %s\n",
           backend_name(), rp_last_error(ctx));
    rp_context_destroy(ctx);
    return 77;
  }
  rp_device_get_caps(dev, &caps);
  printf("conformance: %s device '%s'\n", caps.backend, caps.device);
  rc = cmocka_run_group_tests(tests, NULL, NULL);
  rp_device_destroy(dev);
  rp_context_destroy(ctx);
  return rc;
}
