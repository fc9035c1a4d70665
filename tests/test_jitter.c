/* Ray-start jitter (rp_jitter, DESIGN section 14): the per-pixel offset
 * against its documented formula, its spread, the per-frame seeds, the
 * reference's jittered lattice against counts worked out here, and what
 * jitter is for: averaged over seeds, a slab's opacity converges on the
 * analytic value where the unjittered lattice stays biased. The device
 * backends are held to the same offsets in tests/conformance/jitter.c. */
#include "test_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The integer mix of backends/README.md, written out from the text. */
static uint32_t mix(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}

/* rp_jitter_offset as its doc comment states it. */
static double offset_of(uint32_t x, uint32_t y, uint32_t seed) {
  uint32_t h = mix(seed ^ mix(x ^ mix(y + 0x632be5abu)));
  return ldexp((double)(h >> 8), -24);
}

static void test_offset_formula(void **state) {
  static const uint32_t seeds[] = {0u, 1u, RP_JITTER_SEED, 0xffffffffu};
  uint32_t x, y, k;
  (void)state;
  for (k = 0; k < 4; k++)
    for (y = 0; y < 70; y++)
      for (x = 0; x < 70; x++) {
        float j = rp_jitter_offset(x * 977u, y * 131u, seeds[k]);
        double want = offset_of(x * 977u, y * 131u, seeds[k]);
        if ((double)j != want)
          fail_msg("offset (%u, %u) seed 0x%x: %.9g, want %.9g", x * 977u,
                   y * 131u, seeds[k], (double)j, want);
        assert_true(j >= 0.0f && j < 1.0f);
      }
  /* The largest value is 1 - 2^-24, still below 1 in float. */
  assert_true((float)ldexp(16777215.0, -24) < 1.0f);
}

/* Uniform over [0, 1), and neighbours unrelated: a hash linear in x
 * would put its ring pattern back. */
static void test_offset_spread(void **state) {
  enum { N = 256, BINS = 16 };
  uint32_t bins[BINS] = {0}, x, y, b;
  double corr_x = 0.0, corr_y = 0.0;
  (void)state;
  for (y = 0; y < N; y++)
    for (x = 0; x < N; x++) {
      double j = rp_jitter_offset(x, y, 7u);
      bins[(int)(j * BINS)]++;
      corr_x += (j - 0.5) * (rp_jitter_offset(x + 1, y, 7u) - 0.5);
      corr_y += (j - 0.5) * (rp_jitter_offset(x, y + 1, 7u) - 0.5);
    }
  /* 4096 expected per bin; its standard deviation is 62. */
  for (b = 0; b < BINS; b++)
    if (fabs((double)bins[b] - N * N / BINS) > 320.0)
      fail_msg("bin %u holds %u of %u offsets", b, bins[b], N * N);
  /* Independent offsets: a mean product of 0 +- 0.0003 (1/12 / N). */
  assert_true(fabs(corr_x / (N * N)) < 0.003);
  assert_true(fabs(corr_y / (N * N)) < 0.003);
}

static int cmp_u32(const void *a, const void *b) {
  uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
  return x < y ? -1 : x > y;
}

static void test_frame_seeds(void **state) {
  enum { N = 4096 };
  uint32_t *s = malloc(N * sizeof *s), i;
  (void)state;
  assert_non_null(s);
  for (i = 0; i < N; i++) {
    s[i] = rp_jitter_frame_seed(0u, i);
    assert_int_equal(s[i], rp_jitter_frame_seed(RP_JITTER_SEED, i));
    assert_true(s[i] != 0u);
  }
  assert_true(rp_jitter_frame_seed(1u, 5) != rp_jitter_frame_seed(2u, 5));
  assert_true(rp_jitter_frame_seed(1u, 5) !=
              rp_jitter_frame_seed(1u, 5 + (1ull << 32)));
  qsort(s, N, sizeof *s, cmp_u32);
  for (i = 1; i < N; i++)
    assert_true(s[i] != s[i - 1]);
  free(s);
}

/* A box of one value, 11 voxels along x, under one colour and an
 * opacity of `alpha` per voxel. */
typedef struct slab {
  rp_context *ctx;
  rp_volume *vol;
  rp_tf *tf;
  rp_camera cam;
} slab;

static slab slab_open(float alpha) {
  rp_volume_desc vd = {{11, 16, 16}, RP_U8, {1, 1, 1}, NULL, {0}};
  rp_tf_point p = {0.5f, 1.0f, 1.0f, 1.0f, alpha};
  rp_tf_desc td = {&p, 1, 1.0f, 0, 0, 0, 0, 0};
  uint8_t data[11 * 16 * 16];
  slab s;
  memset(&s, 0, sizeof s);
  s.ctx = rp_test_context();
  memset(data, 120, sizeof data);
  vd.data = data;
  assert_int_equal(rp_volume_create(s.ctx, &vd, &s.vol), 0);
  assert_int_equal(rp_tf_create(s.ctx, &td, &s.tf), 0);
  /* Straight along -x, every ray through the box's full 11 voxels: from
   * depth 54.5 to 65.5. */
  s.cam.projection = RP_ORTHOGRAPHIC;
  s.cam.eye[0] = 60.0f;
  s.cam.ortho_height = 12.0f;
  return s;
}

static void slab_close(slab *s) {
  rp_tf_destroy(s->tf);
  rp_volume_destroy(s->vol);
  rp_context_destroy(s->ctx);
}

#define SLAB_PX 16

static void slab_render(const slab *s, float step, rp_jitter jitter,
                        uint32_t seed, uint8_t *rgba,
                        rp_tile_stats *tiles) {
  rp_render_desc d = {0};
  d.width = d.height = SLAB_PX;
  d.step = step;
  d.jitter = jitter;
  d.jitter_seed = seed;
  if (rp_render_reference(s->ctx, s->vol, s->tf, NULL, NULL, &s->cam, &d,
                          rgba, tiles) != 0)
    fail_msg("render: %s", rp_last_error(s->ctx));
}

/* Each ray's samples s + (j + i) * step <= t1 over the slab's 11 voxels:
 * floor((11 - j step) / step) + 1 of them, the last at depth 54.5 +
 * (j + n - 1) step; the tiles' sums and means of those. */
static void test_jittered_lattice(void **state) {
  static const float steps[] = {2.0f, 0.7f, 3.3f};
  slab s = slab_open(0.05f);
  uint8_t rgba[SLAB_PX * SLAB_PX * 4];
  rp_tile_stats tiles[4];
  int k;
  (void)state;
  for (k = 0; k < 3; k++) {
    double step = steps[k];
    uint32_t seed = 1000u + (uint32_t)k, tx, ty, x, y;
    slab_render(&s, steps[k], RP_JITTER_ON, seed, rgba, tiles);
    for (ty = 0; ty < 2; ty++)
      for (tx = 0; tx < 2; tx++) {
        uint64_t n_sum = 0;
        double depth = 0.0;
        const rp_tile_stats *t = &tiles[ty * 2 + tx];
        for (y = 8 * ty; y < 8 * ty + 8; y++)
          for (x = 8 * tx; x < 8 * tx + 8; x++) {
            double j = offset_of(x, y, seed);
            double n = floor((11.0 - j * step) / step) + 1.0;
            n_sum += (uint64_t)n;
            depth += 54.5 + (j + n - 1.0) * step;
          }
        assert_int_equal(t->samples, n_sum);
        assert_int_equal(t->rays_hit, 64);
        assert_true(fabs(t->mean_depth - depth / 64.0) < 1e-3);
      }
  }
  slab_close(&s);
}

/* The slab's opacity: 1 - (1 - alpha)^11 in the limit of a fine step (the
 * opacity correction makes each sample's share (1 - alpha)^step). At a
 * step of 2 the unjittered lattice takes 6 samples on 11 voxels, as if
 * they were 12; jittered, 6 or 5 by the pixel's offset, 11 on average.
 * Averaged over 16 seeds of 16 x 16 pixels, the jittered opacity lies
 * within half a byte of the analytic one (what remains is that the mean
 * of (1 - alpha)^n is not (1 - alpha)^mean n); the lattice's is 8 bytes
 * off. */
static void test_slab_mean(void **state) {
  slab s = slab_open(0.1f);
  uint8_t rgba[SLAB_PX * SLAB_PX * 4];
  double exact = 1.0 - pow(0.9, 11.0), plain = 0.0, jittered = 0.0;
  uint32_t seed, i;
  (void)state;
  slab_render(&s, 2.0f, RP_JITTER_OFF, 0, rgba, NULL);
  for (i = 0; i < SLAB_PX * SLAB_PX; i++)
    plain += rgba[4 * i + 3] / 255.0;
  plain /= SLAB_PX * SLAB_PX;
  assert_true(fabs(plain - (1.0 - pow(0.9, 12.0))) < 0.5 / 255.0);
  for (seed = 1; seed <= 16; seed++) {
    slab_render(&s, 2.0f, RP_JITTER_ON, seed * 0x9e3779b9u, rgba, NULL);
    for (i = 0; i < SLAB_PX * SLAB_PX; i++)
      jittered += rgba[4 * i + 3] / 255.0;
  }
  jittered /= 16.0 * SLAB_PX * SLAB_PX;
  print_message("slab opacity: analytic %.5f, unjittered %.5f (%+.2f/255),"
                " jittered mean %.5f (%+.2f/255)\n", exact, plain,
                (plain - exact) * 255.0, jittered,
                (jittered - exact) * 255.0);
  assert_true(fabs(plain - exact) > 7.0 / 255.0);
  assert_true(fabs(jittered - exact) < 1.0 / 255.0);
  assert_true(fabs(jittered - exact) < fabs(plain - exact) / 8.0);
  slab_close(&s);
}

/* Jitter off, the lattice starts at the box entry whatever the seed; an
 * unknown mode is refused, naming the field and value. */
static void test_off_and_errors(void **state) {
  slab s = slab_open(0.1f);
  uint8_t a[SLAB_PX * SLAB_PX * 4], b[SLAB_PX * SLAB_PX * 4];
  rp_render_desc d = {0};
  (void)state;
  slab_render(&s, 2.0f, RP_JITTER_OFF, 5u, a, NULL);
  slab_render(&s, 2.0f, RP_JITTER_OFF, 6u, b, NULL);
  assert_memory_equal(a, b, sizeof a);
  /* Zero means on, with RP_JITTER_SEED. */
  slab_render(&s, 2.0f, RP_JITTER_DEFAULT, 0u, a, NULL);
  slab_render(&s, 2.0f, RP_JITTER_ON, RP_JITTER_SEED, b, NULL);
  assert_memory_equal(a, b, sizeof a);
  d.width = d.height = 4;
  d.jitter = (rp_jitter)7;
  assert_int_equal(rp_render_reference(s.ctx, s.vol, s.tf, NULL, NULL,
                                       &s.cam, &d, a, NULL),
                   RP_EINVAL);
  assert_non_null(strstr(rp_last_error(s.ctx), "rp_render_desc.jitter is 7"));
  slab_close(&s);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_offset_formula),
      cmocka_unit_test(test_offset_spread),
      cmocka_unit_test(test_frame_seeds),
      cmocka_unit_test(test_jittered_lattice),
      cmocka_unit_test(test_slab_mean),
      cmocka_unit_test(test_off_and_errors),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
