/* Context, errors, version, allocator hooks, out-of-memory paths, and the
 * promise that a failed call never touches the caller's data. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "test_util.h"

static void every_error_has_a_name_and_message(void **state) {
  int seen = 0;
  (void)state;
#define CHECK(name, val, msg)                                                 \
  assert_string_equal(rp_err_name(val), #name);                               \
  assert_string_equal(rp_strerror(val), msg);                                 \
  assert_true((val) < 0);                                                     \
  seen++;
  RP_ERRNO_MAP(CHECK)
#undef CHECK
  assert_true(seen >= 15);
  assert_string_equal(rp_strerror(0), "success");
  assert_string_equal(rp_strerror(-9999), "unknown error");
  assert_string_equal(rp_err_name(12345), "UNKNOWN");
}

/* The header, the library and the build system (CMake project version,
 * which also goes into raypace.pc and the package config) must agree. */
static void version_matches_header(void **state) {
  char expect[32];
  (void)state;
  assert_int_equal(rp_version(), RP_VERSION_HEX);
  snprintf(expect, sizeof expect, "%d.%d.%d", RP_VERSION_MAJOR,
           RP_VERSION_MINOR, RP_VERSION_PATCH);
  assert_string_equal(rp_version_string(), expect);
  assert_string_equal(rp_version_string(), RP_PROJECT_VERSION);
}

/* An allocator that counts and can fail the n-th allocation. */
typedef struct counting {
  long allocs, frees, fail_at;
} counting;

static void *count_alloc(size_t size, void *user) {
  counting *c = user;
  if (c->fail_at >= 0 && c->allocs == c->fail_at) {
    c->fail_at = -2; /* fail once */
    return NULL;
  }
  c->allocs++;
  return malloc(size);
}

static void count_free(void *p, void *user) {
  counting *c = user;
  c->frees++;
  free(p);
}

/* One representative sequence of everything M1 allocates. */
static int workload(rp_context *ctx) {
  rp_generate_desc g = {0};
  rp_volume *v = NULL;
  rp_tf *tf = NULL;
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  int err;
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = 40, g.dims[1] = 20, g.dims[2] = 33;
  if ((err = rp_volume_generate(ctx, &g, &v)) != 0)
    goto out;
  if ((err = rp_tf_create_preset(ctx, "minmax-bone", &tf)) != 0)
    goto out;
  if ((err = rp_histograms_build(ctx, v, &h)) != 0)
    goto out;
  err = rp_occupancy_build(ctx, h, tf, &occ);
out:
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
  rp_volume_destroy(v);
  return err;
}

static void allocator_hooks_balance(void **state) {
  counting c = {0, 0, -1};
  rp_context_desc d = {0};
  rp_context *ctx = NULL;
  (void)state;
  d.allocator.alloc = count_alloc;
  d.allocator.free = count_free;
  d.allocator.user = &c;
  assert_int_equal(rp_context_create(&d, &ctx), 0);
  assert_int_equal(workload(ctx), 0);
  rp_context_destroy(ctx);
  assert_true(c.allocs > 5);
  assert_int_equal(c.allocs, c.frees);
}

/* Fail the n-th allocation for every n: each failure is RP_ENOMEM and
 * nothing leaks (allocation count equals free count every time). */
static void every_allocation_failure_is_clean(void **state) {
  long n;
  int failures = 0;
  (void)state;
  for (n = 1;; n++) {
    counting c = {0, 0, n};
    rp_context_desc d = {0};
    rp_context *ctx = NULL;
    int err;
    d.allocator.alloc = count_alloc;
    d.allocator.free = count_free;
    d.allocator.user = &c;
    d.threads = 1;
    assert_int_equal(rp_context_create(&d, &ctx), 0);
    err = workload(ctx);
    rp_context_destroy(ctx);
    assert_int_equal(c.allocs, c.frees);
    if (err == 0)
      break;
    assert_int_equal(err, RP_ENOMEM);
    failures++;
  }
  assert_true(failures >= 5);
}

static void half_an_allocator_is_rejected(void **state) {
  rp_context_desc d = {0};
  rp_context *ctx = NULL;
  (void)state;
  d.allocator.alloc = count_alloc;
  assert_int_equal(rp_context_create(&d, &ctx), RP_EINVAL);
  assert_null(ctx);
  assert_int_equal(rp_context_create(NULL, NULL), RP_EINVAL);
}

static void destroy_accepts_null(void **state) {
  (void)state;
  rp_context_destroy(NULL);
  rp_volume_destroy(NULL);
  rp_tf_destroy(NULL);
  rp_histograms_destroy(NULL);
  rp_occupancy_destroy(NULL);
}

static void volume_create_copies_and_validates(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume_desc d = {0};
  rp_volume *v = NULL;
  rp_volume_info in;
  float vox[2 * 3 * 4];
  float keep[24];
  int i;
  (void)state;
  for (i = 0; i < 24; i++)
    vox[i] = (float)i - 5.0f;
  d.dims[0] = 2, d.dims[1] = 3, d.dims[2] = 4, d.type = RP_F32;
  d.data = vox;
  d.spacing[0] = 0.5f, d.spacing[2] = 2.0f;
  assert_int_equal(rp_volume_create(ctx, &d, &v), 0);
  vox[0] = 1000; /* the volume holds its own copy */
  assert_float_equal(((const float *)rp_volume_data(v))[0], -5.0f, 0);
  rp_volume_get_info(v, &in);
  assert_float_equal(in.min, -5, 0);
  assert_float_equal(in.max, 18, 0);
  assert_float_equal(in.spacing[0], 0.5f, 0);
  assert_float_equal(in.spacing[1], 1.0f, 0); /* zero means default */
  assert_int_equal(in.blocks[0], 1);
  rp_volume_destroy(v);
  v = NULL;

  /* NaN: a clear error naming the voxel, and the caller's data intact. */
  vox[0] = -5.0f;
  vox[13] = NAN;
  memcpy(keep, vox, sizeof keep);
  assert_int_equal(rp_volume_create(ctx, &d, &v), RP_ENOTFINITE);
  assert_null(v);
  assert_non_null(strstr(rp_last_error(ctx), "voxel (1, 0, 2)"));
  assert_memory_equal(keep, vox, sizeof keep);
  vox[13] = 1;

  d.spacing[1] = -1;
  assert_int_equal(rp_volume_create(ctx, &d, &v), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "spacing[1]"));
  d.spacing[1] = INFINITY;
  assert_int_equal(rp_volume_create(ctx, &d, &v), RP_ENOTFINITE);
  d.spacing[1] = 0;
  d.dims[1] = 0;
  assert_int_equal(rp_volume_create(ctx, &d, &v), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "axis 1 is 0"));
  d.dims[1] = 3;
  d.type = (rp_voxel_type)9;
  assert_int_equal(rp_volume_create(ctx, &d, &v), RP_EUNSUPPORTED);
  d.type = RP_F32;
  d.data = NULL;
  assert_int_equal(rp_volume_create(ctx, &d, &v), RP_EINVAL);
  assert_int_equal(rp_volume_create(NULL, &d, &v), RP_EINVAL);
  assert_null(v);
  rp_context_destroy(ctx);
}

static void volume_limit_and_overflow(void **state) {
  rp_context_desc cd = {0};
  rp_context *ctx = NULL;
  rp_volume_desc d = {0};
  rp_generate_desc g = {0};
  rp_volume *v = NULL;
  uint8_t byte = 0;
  (void)state;
  cd.max_volume_bytes = 1000;
  assert_int_equal(rp_context_create(&cd, &ctx), 0);
  g.kind = RP_GEN_NOISE;
  g.dims[0] = 10, g.dims[1] = 10, g.dims[2] = 11;
  assert_int_equal(rp_volume_generate(ctx, &g, &v), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "max_volume_bytes"));
  g.dims[2] = 10;
  assert_int_equal(rp_volume_generate(ctx, &g, &v), 0);
  rp_volume_destroy(v);
  v = NULL;
  /* 2^32-1 cubed overflows 64 bits: refused before any allocation. */
  d.dims[0] = d.dims[1] = d.dims[2] = UINT32_MAX;
  d.type = RP_U16;
  d.data = &byte;
  assert_int_equal(rp_volume_create(ctx, &d, &v), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "overflow"));
  assert_null(v);
  rp_context_destroy(ctx);
}

typedef struct log_seen {
  int count, last_item;
  char msg[256];
} log_seen;

static void logger(const char *tag, int level, int item, const char *msg,
                   int line, void *user) {
  log_seen *s = user;
  (void)tag, (void)line;
  assert_int_equal(level, RP_LOG_ERROR);
  s->count++;
  s->last_item = item;
  snprintf(s->msg, sizeof s->msg, "%s", msg);
}

static void errors_reach_the_logger(void **state) {
  log_seen seen = {0};
  rp_context_desc d = {0};
  rp_context *ctx = NULL;
  rp_tf *tf = NULL;
  (void)state;
  d.logger = logger;
  d.logger_user = &seen;
  assert_int_equal(rp_context_create(&d, &ctx), 0);
  assert_string_equal(rp_last_error(ctx), "");
  assert_int_equal(rp_tf_create_preset(ctx, "bogus", &tf), RP_EINVAL);
  assert_int_equal(seen.count, 1);
  assert_int_equal(seen.last_item, RP_EINVAL);
  assert_string_equal(seen.msg, rp_last_error(ctx));
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(every_error_has_a_name_and_message),
      cmocka_unit_test(version_matches_header),
      cmocka_unit_test(allocator_hooks_balance),
      cmocka_unit_test(every_allocation_failure_is_clean),
      cmocka_unit_test(half_an_allocator_is_rejected),
      cmocka_unit_test(destroy_accepts_null),
      cmocka_unit_test(volume_create_copies_and_validates),
      cmocka_unit_test(volume_limit_and_overflow),
      cmocka_unit_test(errors_reach_the_logger),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
