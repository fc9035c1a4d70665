/* Generated volumes: determinism, the analytic signal, the phantom's empty
 * space and dense core, 16-bit range, invalid descriptors. */
#include <math.h>
#include <string.h>

#include "test_util.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

static rp_volume *gen(rp_context *ctx, rp_generator kind, uint32_t n,
                      rp_voxel_type type, uint64_t seed) {
  rp_generate_desc d = {0};
  rp_volume *v = NULL;
  d.kind = kind, d.dims[0] = d.dims[1] = d.dims[2] = n;
  d.type = type, d.seed = seed;
  assert_int_equal(rp_volume_generate(ctx, &d, &v), 0);
  return v;
}

static void deterministic_and_seeded(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *a = gen(ctx, RP_GEN_NOISE, 20, RP_U8, 1);
  rp_volume *b = gen(ctx, RP_GEN_NOISE, 20, RP_U8, 1);
  rp_volume *c = gen(ctx, RP_GEN_NOISE, 20, RP_U8, 2);
  (void)state;
  assert_memory_equal(rp_volume_data(a), rp_volume_data(b), 8000);
  assert_memory_not_equal(rp_volume_data(a), rp_volume_data(c), 8000);
  rp_volume_destroy(a);
  rp_volume_destroy(b);
  rp_volume_destroy(c);
  rp_context_destroy(ctx);
}

/* Marschner-Lobb written out from the 1994 paper at a few voxel centres. */
static void marschner_lobb_matches_formula(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *v = gen(ctx, RP_GEN_MARSCHNER_LOBB, 41, RP_U16, 0);
  const uint16_t *d = rp_volume_data(v);
  uint32_t i, j, k;
  (void)state;
  for (k = 0; k < 41; k += 5)
    for (j = 0; j < 41; j += 7)
      for (i = 0; i < 41; i += 3) {
        double x = 2.0 * (i + 0.5) / 41 - 1, y = 2.0 * (j + 0.5) / 41 - 1;
        double z = 2.0 * (k + 0.5) / 41 - 1, r = sqrt(x * x + y * y);
        double rho = (1 - sin(M_PI * z / 2) +
                      0.25 * (1 + cos(2 * M_PI * 6 * cos(M_PI * r / 2)))) /
                     2.5;
        assert_int_equal(d[((size_t)k * 41 + j) * 41 + i],
                         (int)floor(rho * 65535 + 0.5));
      }
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

static void phantom_has_air_and_a_dense_core(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *v = gen(ctx, RP_GEN_PHANTOM, 64, RP_U8, 0);
  rp_volume_info in;
  const uint8_t *d = rp_volume_data(v);
  size_t i, zeros = 0;
  (void)state;
  for (i = 0; i < 64 * 64 * 64; i++)
    zeros += d[i] == 0;
  rp_volume_get_info(v, &in);
  assert_true(zeros > 64 * 64 * 64 * 0.5); /* large empty regions */
  assert_true(in.max >= 250);              /* dense core */
  assert_true(d[(32 * 64 + 32) * 64 + 32] >= 240);
  assert_int_equal(d[0], 0);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

static void noise_16bit_uses_full_range(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *v = gen(ctx, RP_GEN_NOISE, 40, RP_U16, 9);
  rp_volume_info in;
  (void)state;
  rp_volume_get_info(v, &in);
  assert_int_equal(in.type, RP_U16);
  assert_true(in.min < 100);
  assert_true(in.max > 65435);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

static void invalid_descriptors(void **state) {
  rp_context *ctx = rp_test_context();
  rp_generate_desc d = {0};
  rp_volume *v = NULL;
  (void)state;
  d.kind = RP_GEN_PHANTOM;
  d.dims[0] = 4, d.dims[1] = 0, d.dims[2] = 4;
  assert_int_equal(rp_volume_generate(ctx, &d, &v), RP_ERANGE);
  d.dims[1] = 4;
  d.type = RP_F32;
  assert_int_equal(rp_volume_generate(ctx, &d, &v), RP_EUNSUPPORTED);
  d.type = RP_U8;
  d.kind = (rp_generator)0;
  assert_int_equal(rp_volume_generate(ctx, &d, &v), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "kind"));
  assert_int_equal(rp_volume_generate(ctx, NULL, &v), RP_EINVAL);
  assert_null(v);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(deterministic_and_seeded),
      cmocka_unit_test(marschner_lobb_matches_formula),
      cmocka_unit_test(phantom_has_air_and_a_dense_core),
      cmocka_unit_test(noise_16bit_uses_full_range),
      cmocka_unit_test(invalid_descriptors),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
