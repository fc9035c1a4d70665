/* The per-frame passes in C: the depth pass's DDA against a brute-force
 * slab test over every block, and the ERT pre-pass's generator, bin choice
 * and closed-form cases. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "passes.h"
#include "raypace_backend.h"
#include "test_util.h"

static uint64_t lcg(uint64_t *s) {
  *s = *s * 6364136223846793005ull + 1442695040888963407ull;
  return *s >> 11;
}

static double unit(uint64_t *s) {
  return (double)lcg(s) / 9007199254740992.0;
}

/* Ray-box overlap by slabs, written separately from the DDA. */
static int slab(const rp__ray *ray, const double lo[3], const double hi[3],
                double *t0, double *t1) {
  double a = ray->s, b = ray->t1;
  int k;
  for (k = 0; k < 3; k++) {
    if (ray->dp[k] == 0.0) {
      if (ray->p0[k] < lo[k] || ray->p0[k] > hi[k])
        return 0;
      continue;
    }
    {
      double ta = (lo[k] - ray->p0[k]) / ray->dp[k];
      double tb = (hi[k] - ray->p0[k]) / ray->dp[k];
      if (ta > tb) {
        double t = ta;
        ta = tb, tb = t;
      }
      a = ta > a ? ta : a;
      b = tb < b ? tb : b;
    }
  }
  *t0 = a, *t1 = b;
  return a <= b;
}

/* Brute force: the union of the ray's overlaps with every occupied block's
 * region [16b - 0.5, 16b + 15.5) (the last one ends at dims - 0.5). */
static void brute_depth(const rp__ray *ray, const uint32_t dims[3],
                        const uint8_t *grid, const uint32_t blocks[3],
                        double *front, double *back) {
  uint32_t bx, by, bz;
  *front = INFINITY, *back = -INFINITY;
  if (!ray->hit)
    return;
  for (bz = 0; bz < blocks[2]; bz++)
    for (by = 0; by < blocks[1]; by++)
      for (bx = 0; bx < blocks[0]; bx++) {
        uint32_t b[3] = {bx, by, bz}, k;
        double lo[3], hi[3], t0, t1;
        if (!grid[(bz * blocks[1] + by) * blocks[0] + bx])
          continue;
        for (k = 0; k < 3; k++) {
          lo[k] = 16.0 * b[k] - 0.5;
          hi[k] = fmin(16.0 * b[k] + 15.5, dims[k] - 0.5);
        }
        if (slab(ray, lo, hi, &t0, &t1)) {
          *front = fmin(*front, t0);
          *back = fmax(*back, t1);
        }
      }
}

static void dda_matches_brute_force(void **state) {
  rp_context *ctx = rp_test_context();
  static const uint32_t sizes[][3] = {{48, 48, 48}, {37, 70, 19}, {1, 1, 1},
                                      {100, 3, 77}};
  uint64_t s = 99;
  size_t v;
  int checked = 0, touching = 0;
  (void)state;
  for (v = 0; v < sizeof sizes / sizeof sizes[0]; v++) {
    rp_generate_desc g = {0};
    rp_volume *vol = NULL;
    rp_volume_info in;
    uint8_t *grid;
    uint32_t nb, i;
    int density, cam;
    g.kind = RP_GEN_NOISE;
    memcpy(g.dims, sizes[v], sizeof g.dims);
    assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
    rp_volume_get_info(vol, &in);
    nb = in.blocks[0] * in.blocks[1] * in.blocks[2];
    grid = malloc(nb);
    for (density = 0; density < 3; density++) {
      /* Sparse, half and nearly full occupancy patterns. */
      for (i = 0; i < nb; i++)
        grid[i] = unit(&s) < (density == 0 ? 0.1 : density == 1 ? 0.5 : 0.95);
      for (cam = 0; cam < 20; cam++) {
        rp_camera c = {0};
        rp__raygen rg;
        uint32_t x, y;
        c.projection = cam % 4 == 3 ? RP_ORTHOGRAPHIC : RP_PERSPECTIVE;
        rp_camera_orbit(&c, vol, (float)(360 * unit(&s)),
                        (float)(180 * unit(&s) - 90),
                        (float)(0.3 + 2.5 * unit(&s)));
        assert_int_equal(rp__raygen_init(ctx, &c, vol, 13, 11, &rg), 0);
        for (y = 0; y < 11; y++)
          for (x = 0; x < 13; x++) {
            rp__ray ray;
            double f, b, bf, bb;
            rp__raygen_ray(&rg, x, y, &ray);
            rp__depth_ray(&ray, rg.dims, grid, in.blocks, &f, &b);
            brute_depth(&ray, in.dims, grid, in.blocks, &bf, &bb);
            checked++;
            if (isinf(bf)) {
              /* A ray touching an occupied block in a single point may
               * count as entering it in one and not the other. */
              if (!isinf(f)) {
                assert_true(b - f < 1e-9);
                touching++;
              }
              continue;
            }
            assert_false(isinf(f));
            assert_float_equal(f, bf, 1e-9 * fmax(1.0, fabs(bf)));
            assert_float_equal(b, bb, 1e-9 * fmax(1.0, fabs(bb)));
          }
      }
    }
    free(grid);
    rp_volume_destroy(vol);
  }
  print_message("DDA: %d rays against brute force, %d touching\n", checked,
                touching);
  assert_true(touching * 1000 < checked);
  rp_context_destroy(ctx);
}

/* Known answers from an independent transcription of the formulas
 * (Python, integers masked to 32 bits) of backends/README.md. */
static void generator_known_answers(void **state) {
  static const struct {
    uint32_t seed, frame, ray, draws[4];
  } kat[] = {
      {0, 0, 0, {0x1f6b42ecu, 0x4de87003u, 0x039a2657u, 0x5445c0ebu}},
      {1234, 7, 0, {0x7d6c39beu, 0x94e6ba48u, 0xdcea8223u, 0x7b775529u}},
      {1234, 7, 1, {0xddfa38bau, 0xeb2fdd61u, 0xc5bac1d3u, 0xc41079a8u}},
      {0xffffffffu, 0xffffffffu, 12345,
       {0x6482db9fu, 0xc6d7a2a5u, 0xad2bdbafu, 0x49505cc1u}},
  };
  size_t i;
  int k;
  (void)state;
  assert_int_equal(rp__ert_mix(0), 0);
  assert_int_equal(rp__ert_mix(1), 0x688990c0u);
  assert_int_equal(rp__ert_mix(0xdeadbeefu), 0xe628c683u);
  for (i = 0; i < sizeof kat / sizeof kat[0]; i++) {
    rp__taus t;
    rp__taus_seed(&t, kat[i].seed, kat[i].frame, kat[i].ray);
    for (k = 0; k < 4; k++)
      assert_int_equal(rp__taus_next(&t), kat[i].draws[k]);
  }
}

/* The bin choice is exact: over every tau that is a multiple of 2^16 the
 * share of each bin is its byte over the total, to one part in 2^16. */
static void bin_choice_follows_the_histogram(void **state) {
  static const uint8_t h[16] = {200, 0, 3, 0, 0, 17, 1, 0,
                                0,   0, 0, 0, 9, 0, 0, 25};
  uint32_t count[16] = {0}, total = 0, k;
  uint64_t tau;
  (void)state;
  for (k = 0; k < 16; k++)
    total += h[k];
  for (tau = 0; tau < (1ull << 32); tau += 1u << 16)
    count[rp__ert_pick_bin(h, (uint32_t)tau)]++;
  for (k = 0; k < 16; k++) {
    double want = 65536.0 * h[k] / total;
    assert_true(fabs(count[k] - want) <= 1.0);
  }
  /* An empty bin is never picked, even at the ends of the range. */
  assert_int_equal(rp__ert_pick_bin(h, 0), 0);
  assert_int_equal(rp__ert_pick_bin(h, 0xffffffffu), 15);
  assert_float_equal(rp__ert_bin_alpha(0), 0.0, 0);
  assert_float_equal(rp__ert_bin_alpha(1), 0.5 / 15, 1e-15);
  assert_float_equal(rp__ert_bin_alpha(15), 14.5 / 15, 1e-15);
}

/* Closed forms: an opaque TF terminates every hit ray at its first coarse
 * sample (one bin-15 draw at step 8 brings A to 1 - (1/30)^8), so d_ert is
 * the entry depth s; a transparent TF never terminates. */
static void ert_closed_forms(void **state) {
  rp_context *ctx = rp_test_context();
  rp_generate_desc g = {0};
  rp_volume *vol = NULL;
  rp_histograms *h = NULL;
  rp_tf *opaque = NULL, *clear = NULL;
  rp_occupancy *occ = NULL;
  rp_camera cam = {0};
  rp__raygen rg;
  float d[9 * 7];
  uint32_t gw, gh, cx, cy;
  (void)state;
  g.kind = RP_GEN_NOISE;
  g.dims[0] = 40, g.dims[1] = 30, g.dims[2] = 20;
  assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
  assert_int_equal(rp_histograms_build(ctx, vol, &h), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "opaque", &opaque), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "transparent", &clear), 0);
  assert_int_equal(rp_occupancy_build(ctx, h, opaque, &occ), 0);
  rp_camera_orbit(&cam, vol, 20, 10, 2.0f);
  assert_int_equal(rp__raygen_init(ctx, &cam, vol, 33, 27, &rg), 0);
  rp__ert_grid(33, 27, &gw, &gh);
  assert_int_equal(gw, 9);
  assert_int_equal(gh, 7);
  rp__ert_prepass(&rg, occ->grid, occ->alpha_hist, h->blocks, 1.0f, 0.99f,
                  5, 0, d);
  for (cy = 0; cy < gh; cy++)
    for (cx = 0; cx < gw; cx++) {
      rp__ray ray;
      rp__raygen_ray_at(&rg, 4.0 * cx + 2, 4.0 * cy + 2, &ray);
      if (ray.hit)
        assert_float_equal(d[cy * gw + cx], ray.s, 1e-4);
      else
        assert_true(isinf(d[cy * gw + cx]));
    }
  assert_int_equal(rp_occupancy_update(occ, clear), 0);
  rp__ert_prepass(&rg, occ->grid, occ->alpha_hist, h->blocks, 1.0f, 0.99f,
                  5, 0, d);
  for (cx = 0; cx < gw * gh; cx++)
    assert_true(isinf(d[cx]));
  rp_occupancy_destroy(occ);
  rp_tf_destroy(opaque);
  rp_tf_destroy(clear);
  rp_histograms_destroy(h);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* Same seed and frame: the same estimate; another frame: another draw. */
static void ert_is_deterministic_per_seed(void **state) {
  rp_context *ctx = rp_test_context();
  rp_generate_desc g = {0};
  rp_volume *vol = NULL;
  rp_histograms *h = NULL;
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  rp_camera cam = {0};
  rp__raygen rg;
  float a[16 * 16], b[16 * 16], c[16 * 16];
  (void)state;
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = 64;
  assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
  assert_int_equal(rp_histograms_build(ctx, vol, &h), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, h, tf, &occ), 0);
  rp_camera_orbit(&cam, vol, 10, 10, 1.8f);
  assert_int_equal(rp__raygen_init(ctx, &cam, vol, 64, 64, &rg), 0);
  rp__ert_prepass(&rg, occ->grid, occ->alpha_hist, h->blocks, 1.0f, 0.6f, 9,
                  1, a);
  rp__ert_prepass(&rg, occ->grid, occ->alpha_hist, h->blocks, 1.0f, 0.6f, 9,
                  1, b);
  rp__ert_prepass(&rg, occ->grid, occ->alpha_hist, h->blocks, 1.0f, 0.6f, 9,
                  2, c);
  assert_memory_equal(a, b, sizeof a);
  assert_memory_not_equal(a, c, sizeof a);
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
  rp_histograms_destroy(h);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(dda_matches_brute_force),
      cmocka_unit_test(generator_known_answers),
      cmocka_unit_test(bin_choice_follows_the_histogram),
      cmocka_unit_test(ert_closed_forms),
      cmocka_unit_test(ert_is_deterministic_per_seed),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
