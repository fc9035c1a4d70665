/* The cost model (runtime/predict.c) and the tuning spaces
 * (runtime/space.c): probes against closed forms and the reference
 * raycaster's sample counts, the learned model against a synthetic plant
 * whose cost is known, and the hard cases (outliers, duplicates, bad
 * timings, unseen views). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "passes.h"
#include "raypace_pace.h"
#include "test_util.h"

/* ---- Tuning spaces ------------------------------------------------------- */

static void expect_map(rp_space space, double rho, double step,
                       double scale) {
  rp_space_desc d = {0};
  float st, sc;
  d.space = space;
  rp_space_map(&d, rho, &st, &sc);
  assert_float_equal(st, step, 1e-5 * step);
  assert_float_equal(sc, scale, 1e-6);
}

static void test_space_closed_forms(void **state) {
  rp_space_desc d = {0};
  rp_space sp;
  float st, sc;
  int i;
  (void)state;
  expect_map(RP_SPACE_RAY, 0.25, 4.0, 1.0);
  expect_map(RP_SPACE_IMAGE, 0.25, 1.0, 0.5);
  expect_map(RP_SPACE_HYBRID, 0.25, 2.0, sqrt(0.5));
  expect_map(RP_SPACE_RAY, 1.0, 1.0, 1.0);
  /* Above 1, NaN: the finest; at or below 0 and past the bound: the
   * coarsest, never a NaN or an out-of-bounds step. */
  expect_map(RP_SPACE_HYBRID, 7.0, 1.0, 1.0);
  expect_map(RP_SPACE_HYBRID, NAN, 1.0, 1.0);
  expect_map(RP_SPACE_RAY, 0.0, 16.0, 1.0);
  expect_map(RP_SPACE_IMAGE, -1.0, 1.0, 0.125);
  expect_map(RP_SPACE_HYBRID, 1e-9, 16.0, 0.125);
  d.space = RP_SPACE_RAY;
  assert_float_equal(rp_space_min_density(&d), 1.0 / 16, 1e-12);
  d.space = RP_SPACE_IMAGE;
  assert_float_equal(rp_space_min_density(&d), 1.0 / 64, 1e-12);
  d.space = RP_SPACE_HYBRID;
  assert_float_equal(rp_space_min_density(&d), 1.0 / 1024, 1e-12);
  /* Hybrid with the ray factor saturating at max_step 2: the image
   * factor takes the rest of -ln(1/32), 32 / 2 = 16 = 1 / scale^2. */
  d.base_step = 1.0f;
  d.max_step = 2.0f;
  rp_space_map(&d, 1.0 / 32, &st, &sc);
  assert_float_equal(st, 2.0, 1e-6);
  assert_float_equal(sc, 0.25, 1e-6);
  /* Above 1, a min_step under the base step: the step alone refines,
   * to min_step and no further; pure image space stops at 1. A
   * min_step over the base step, or none, is the base step. */
  memset(&d, 0, sizeof(d));
  d.min_step = 0.25f;
  for (i = 0; i < 3; i++) {
    d.space = (rp_space)i;
    rp_space_map(&d, 2.0, &st, &sc);
    assert_float_equal(st, i == RP_SPACE_IMAGE ? 1.0 : 0.5, 1e-7);
    assert_float_equal(sc, 1.0, 0.0);
    rp_space_map(&d, 7.0, &st, &sc);
    assert_float_equal(st, i == RP_SPACE_IMAGE ? 1.0 : 0.25, 0.0);
    rp_space_map(&d, NAN, &st, &sc);
    assert_float_equal(st, 1.0, 0.0);
    rp_space_map(&d, INFINITY, &st, &sc);
    assert_float_equal(st, i == RP_SPACE_IMAGE ? 1.0 : 0.25, 0.0);
    assert_float_equal(sc, 1.0, 0.0);
    assert_float_equal(rp_space_max_density(&d),
                       i == RP_SPACE_IMAGE ? 1.0 : 4.0, 0.0);
  }
  d.min_step = 3.0f;
  assert_float_equal(rp_space_max_density(&d), 1.0, 0.0);
  rp_space_map(&d, 2.0, &st, &sc);
  assert_float_equal(st, 1.0, 0.0);
  assert_float_equal(sc, 1.0, 0.0);
  d.min_step = NAN;
  assert_float_equal(rp_space_max_density(&d), 1.0, 0.0);
  /* The identity rho = scale^2 * base / step, in every space, for
   * densities inside the bounds; base step 0.5, min_step 0.0625. */
  for (i = 0; i < 3; i++) {
    int k;
    memset(&d, 0, sizeof(d));
    d.space = (rp_space)i;
    d.base_step = 0.5f;
    d.min_step = 0.0625f;
    for (k = 0; k < 50; k++) {
      double lo = rp_space_min_density(&d), hi = rp_space_max_density(&d);
      double rho = lo * pow(hi / lo, k / 49.0);
      rp_space_map(&d, rho, &st, &sc);
      assert_float_equal((double)sc * sc * 0.5 / st, rho, 1e-5 * rho);
      assert_true(st >= (i == RP_SPACE_IMAGE ? 0.5f : 0.0625f) &&
                  st <= 8.0f);
      assert_true(sc >= 0.125f && sc <= 1.0f);
      assert_true(rho <= 1.0 || sc == 1.0f);
    }
  }
  /* A min_scale above 1 means no image scaling: clamped, not replaced. */
  memset(&d, 0, sizeof(d));
  d.space = RP_SPACE_HYBRID;
  d.min_scale = 1.5f;
  assert_float_equal(rp_space_min_density(&d), 1.0 / 16, 1e-12);
  assert_int_equal(rp_space_from_name("hybrid", &sp), 0);
  assert_int_equal(sp, RP_SPACE_HYBRID);
  assert_string_equal(rp_space_name(RP_SPACE_IMAGE), "image");
  assert_int_equal(rp_space_from_name("rays", &sp), RP_EINVAL);
}

/* ---- Probe --------------------------------------------------------------- */

typedef struct scene {
  rp_context *ctx;
  rp_volume *vol;
  rp_histograms *h;
  rp_tf *tf;
  rp_occupancy *occ;
  rp_camera cam;
} scene;

/* A 32x24x40 box of constant 200 (range made [0, 255] by two corner
 * voxels), seen orthographically along -z through a 64-unit-high view: one
 * output pixel per world unit, so which probe rays hit and how long they
 * are is a matter of counting. */
static void box_scene(scene *s, const char *tf) {
  enum { X = 32, Y = 24, Z = 40 };
  uint8_t *v = malloc((size_t)X * Y * Z);
  rp_volume_desc vd = {{X, Y, Z}, RP_U8, {0, 0, 0}, NULL, {0}};
  assert_non_null(v);
  memset(v, 200, (size_t)X * Y * Z);
  v[0] = 0;
  v[(size_t)X * Y * Z - 1] = 255;
  vd.data = v;
  s->ctx = rp_test_context();
  assert_int_equal(rp_volume_create(s->ctx, &vd, &s->vol), 0);
  free(v);
  assert_int_equal(rp_histograms_build(s->ctx, s->vol, &s->h), 0);
  assert_int_equal(rp_tf_create_preset(s->ctx, tf, &s->tf), 0);
  assert_int_equal(rp_occupancy_build(s->ctx, s->h, s->tf, &s->occ), 0);
  memset(&s->cam, 0, sizeof(s->cam));
  s->cam.projection = RP_ORTHOGRAPHIC;
  s->cam.eye[2] = 100.0f;
  s->cam.up[1] = 1.0f;
  s->cam.ortho_height = 64.0f;
}

static void scene_free(scene *s) {
  rp_occupancy_destroy(s->occ);
  rp_tf_destroy(s->tf);
  rp_histograms_destroy(s->h);
  rp_volume_destroy(s->vol);
  rp_context_destroy(s->ctx);
}

/* A generated 64^3 phantom with its histograms; no TF yet. */
static void phantom_scene(scene *s) {
  rp_generate_desc g = {0};
  s->ctx = rp_test_context();
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = 64;
  g.type = RP_U8;
  g.seed = 5;
  assert_int_equal(rp_volume_generate(s->ctx, &g, &s->vol), 0);
  assert_int_equal(rp_histograms_build(s->ctx, s->vol, &s->h), 0);
}

static uint64_t reference_samples(scene *s, const rp_render_desc *d) {
  uint32_t w, h, tx, ty, i;
  uint64_t n = 0;
  uint8_t *rgba;
  rp_tile_stats *tiles;
  rp_scaled_size(d, &w, &h);
  rp_tile_grid(w, h, &tx, &ty);
  rgba = malloc((size_t)w * h * 4);
  tiles = calloc((size_t)tx * ty, sizeof(*tiles));
  assert_non_null(rgba);
  assert_non_null(tiles);
  assert_int_equal(rp_render_reference(s->ctx, s->vol, s->tf, s->occ, NULL,
                                       &s->cam, d, rgba, tiles), 0);
  for (i = 0; i < tx * ty; i++)
    n += tiles[i].samples;
  free(rgba);
  free(tiles);
  return n;
}

static void test_probe_box_closed_form(void **state) {
  scene s;
  rp_render_desc d = {0};
  rp_frame_probe p;
  rp_cost_model *m;
  rp_cost_estimate e;
  double expect;
  uint64_t measured;
  (void)state;
  box_scene(&s, "ramp");
  d.width = d.height = 64;
  d.effects = 0;
  /* Jitter off: the lattice starts at each ray's box entry, the closed
   * form below. The jittered lattice's count follows at the end. */
  d.jitter = RP_JITTER_OFF;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 1, 0, &p), 0);
  /* Probe ray (cx, cy) passes through x = 4 cx + 2 - 32: inside the box
   * (|x| < 16) for cx = 4..11, and |y| < 12 for cy = 5..10: 8 x 6 rays,
   * each through the full 40-voxel depth. */
  assert_int_equal(p.rays, 256);
  assert_int_equal(p.rays_hit, 48);
  assert_int_equal(p.rays_ended, 0);
  assert_float_equal(p.depth_sum, 48 * 40.0, 1e-9);
  assert_float_equal(p.depth_max, 40.0, 1e-12);
  assert_float_equal(p.ert_cut, 0.0, 0.0);
  assert_float_equal(p.pixels_per_voxel, 1.0, 1e-12);
  assert_float_equal(p.diagonal, sqrt(32.0 * 32 + 24 * 24 + 40 * 40),
                     1e-9);
  assert_float_equal(p.view[2], -1.0, 1e-12);
  /* S' at step 1: 16 pixels per probe ray x (1920 + 48 / 2). The
   * reference takes 41 lattice samples on each of the 32 x 24 rays that
   * hit: the estimate is within 1/82 of it. */
  assert_int_equal(rp_cost_model_create(s.ctx, NULL, &m), 0);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  expect = 16.0 * (1920.0 + 24.0);
  assert_float_equal(e.samples, expect, 1e-9);
  assert_float_equal(e.fetches, 1.0, 0.0);
  d.step = 1.0f;
  measured = reference_samples(&s, &d);
  assert_int_equal(measured, 32 * 24 * 41);
  assert_true(fabs(e.samples - (double)measured) <= measured / 60.0);
  /* Scale 1/2: a quarter of the rays over the same frustum. */
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 0.5f, &e), 0);
  assert_float_equal(e.samples, expect / 4.0, 1e-9);
  d.image_scale = 0.5f;
  measured = reference_samples(&s, &d);
  assert_true(fabs(e.samples - (double)measured) <= measured / 20.0);
  /* Jittered, the 40 voxels of depth take 40 samples on every ray (41
   * only where a pixel's offset is exactly 0), and S' drops the half
   * sample per ray: 16 x 1920, the count itself. */
  d.jitter = RP_JITTER_DEFAULT;
  d.image_scale = 0.0f;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 1, 0, &p), 0);
  assert_int_equal(p.jitter, 1);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.samples, 16.0 * 1920.0, 1e-9);
  assert_int_equal(reference_samples(&s, &d), 32 * 24 * 40);
  rp_cost_model_destroy(m);
  scene_free(&s);
}

/* The same box at 512 x 512: a 128 x 128 pre-pass grid, more than the
 * probe's 1024 rays, so it traces every fourth ray per axis. Ray cx sits
 * at x = (4 cx + 2) / 8 - 32 voxels: inside |x| < 16 for cx = 32..95, 16
 * of them multiples of 4; |y| < 12 for cy = 40..87, 12 of them. S' keeps
 * the full grid's estimate and stays within 1/60 of the reference's
 * count. */
static void test_probe_subgrid(void **state) {
  scene s;
  rp_render_desc d = {0};
  rp_frame_probe p;
  rp_cost_model *m;
  rp_cost_estimate e;
  uint64_t measured;
  (void)state;
  box_scene(&s, "ramp");
  d.width = d.height = 512;
  d.jitter = RP_JITTER_OFF; /* the closed form's lattice */
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 1, 0, &p), 0);
  assert_int_equal(p.rays, 32 * 32);
  assert_int_equal(p.rays_hit, 16 * 12);
  assert_float_equal(p.depth_sum, 16 * 12 * 40.0, 1e-9);
  assert_int_equal(rp_cost_model_create(s.ctx, NULL, &m), 0);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.samples, 256.0 * (16 * 12 * 40.0 + 16 * 12 / 2.0),
                     1e-6);
  d.step = 1.0f;
  measured = reference_samples(&s, &d);
  assert_int_equal(measured, 256 * 192 * 41);
  assert_true(fabs(e.samples - (double)measured) <= measured / 60.0);
  rp_cost_model_destroy(m);
  scene_free(&s);
}

/* An opaque TF with ERT: the pre-pass ends every ray at its first coarse
 * step, the raycast after its first sample: S' = 16 x 48 x 1 exactly. */
static void test_probe_ert_opaque(void **state) {
  scene s;
  rp_render_desc d = {0};
  rp_frame_probe p;
  rp_cost_model *m;
  rp_cost_estimate e;
  (void)state;
  box_scene(&s, "opaque");
  d.width = d.height = 64;
  d.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 7, 3, &p), 0);
  assert_int_equal(p.rays_hit, 48);
  assert_int_equal(p.rays_ended, 48);
  assert_float_equal(p.depth_sum, 0.0, 1e-9);
  assert_float_equal(p.ert_cut, 1.0, 1e-12);
  assert_int_equal(rp_cost_model_create(s.ctx, NULL, &m), 0);
  assert_int_equal(rp_cost_predict(m, &p, 0.5f, 1.0f, &e), 0);
  assert_float_equal(e.samples, 16.0 * 48, 1e-9);
  d.step = 0.5f;
  assert_int_equal(reference_samples(&s, &d), 32 * 24);
  rp_cost_model_destroy(m);
  scene_free(&s);
}

/* A nearly transparent TF: alpha 0.0165 a voxel in the box, so 40
 * voxels of depth reach an opacity of 0.49 and an ERT threshold of 0.6
 * ends no ray. The box's voxels all fall in the first opacity bin,
 * (0, 1/15]: drawn at the bin's centre (1/30) the pre-pass would end
 * every ray after about 27 voxels and S' would be a third short. Drawn
 * at the mean opacity of the voxels in the bin, S' matches the reference
 * raycaster's count to the lattice's half sample. */
static void test_probe_nearly_transparent(void **state) {
  scene s;
  rp_render_desc d = {0};
  rp_frame_probe p;
  rp_cost_model *m;
  rp_cost_estimate e;
  uint64_t measured;
  (void)state;
  box_scene(&s, "nearly-transparent");
  d.width = d.height = 64;
  d.jitter = RP_JITTER_OFF; /* the closed form's lattice */
  d.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP;
  d.ert_threshold = 0.6f;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 1, 0, &p), 0);
  assert_int_equal(p.rays_hit, 48);
  assert_int_equal(p.rays_ended, 0);
  assert_int_equal(rp_cost_model_create(s.ctx, NULL, &m), 0);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  d.step = 1.0f;
  measured = reference_samples(&s, &d);
  assert_int_equal(measured, 32 * 24 * 41);
  assert_true(fabs(e.samples - (double)measured) <= measured / 60.0);
  rp_cost_model_destroy(m);
  scene_free(&s);
}

/* All transparent: nothing is occupied, no ray samples anything. */
static void test_probe_transparent(void **state) {
  scene s;
  rp_render_desc d = {0};
  rp_frame_probe p;
  (void)state;
  box_scene(&s, "transparent");
  d.width = 7;
  d.height = 513;
  d.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 1, 0, &p), 0);
  assert_int_equal(p.rays, 2 * 129);
  assert_int_equal(p.rays_hit, 0);
  assert_float_equal(p.depth_sum, 0.0, 0.0);
  scene_free(&s);
}

/* The shaded share: only samples with opacity above 0 are shaded, and
 * the probe estimates their share from the blocks' counts of voxels that
 * show. Closed forms on the box first: an opaque box ends every ray on
 * its first sample, which shows (k = 7); a nearly transparent one shows
 * everywhere but the two corner voxels of value 0 and 255 (k = 7 to
 * within their share of a block). Then held to the reference raycaster's
 * own count of shaded samples on a generated phantom, over views, TFs,
 * and ERT on and off: within 0.03 of it (k within 0.18 fetches). */
static void test_probe_shaded_share(void **state) {
  static const char *const tfs[] = {"minmax-soft", "minmax-bone", "mri"};
  scene s;
  rp_render_desc d = {0};
  rp_frame_probe p;
  rp_cost_model *m;
  rp_cost_estimate e;
  double worst = 0.0;
  int t, v, ert;
  (void)state;
  box_scene(&s, "opaque");
  d.width = d.height = 64;
  d.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_SHADING;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 7, 3, &p), 0);
  assert_int_equal(rp_cost_model_create(s.ctx, NULL, &m), 0);
  assert_int_equal(rp_cost_predict(m, &p, 0.5f, 1.0f, &e), 0);
  assert_float_equal(e.fetches, 7.0, 1e-12);
  rp_cost_model_destroy(m);
  scene_free(&s);
  box_scene(&s, "nearly-transparent");
  d.effects = RP_EFFECT_SKIP | RP_EFFECT_SHADING;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 7, 3, &p), 0);
  assert_int_equal(rp_cost_model_create(s.ctx, NULL, &m), 0);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_true(e.fetches <= 7.0 && e.fetches > 7.0 - 6.0 * 2.0 / 4096.0);
  /* Without shading nothing is estimated and nothing costs. */
  d.effects = RP_EFFECT_SKIP;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 7, 3, &p), 0);
  assert_float_equal(p.lit_span, 0.0, 0.0);
  assert_float_equal(p.lit_ends, 0.0, 0.0);
  rp_cost_model_destroy(m);
  scene_free(&s);

  phantom_scene(&s);
  assert_int_equal(rp_cost_model_create(s.ctx, NULL, &m), 0);
  for (t = 0; t < 3; t++) {
    assert_int_equal(rp_tf_create_preset(s.ctx, tfs[t], &s.tf), 0);
    assert_int_equal(rp_occupancy_build(s.ctx, s.h, s.tf, &s.occ), 0);
    for (v = 0; v < 3; v++) {
      for (ert = 0; ert < 2; ert++) {
        rp__raygen rg;
        rp_region all = {0, 0, 96, 96};
        uint8_t *rgba = malloc(96 * 96 * 4);
        rp_tile_stats tiles[12 * 12];
        uint64_t fetches[12 * 12], n = 0, f = 0;
        double truth, est;
        int k;
        memset(&s.cam, 0, sizeof s.cam);
        rp_camera_orbit(&s.cam, s.vol, 30.0f + 110.0f * (float)v,
                        20.0f - 25.0f * (float)v, 2.2f);
        memset(&d, 0, sizeof d);
        d.width = d.height = 96;
        d.effects = RP_EFFECT_SKIP | RP_EFFECT_SHADING |
                    (ert ? RP_EFFECT_ERT : 0u);
        assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ,
                                                &s.cam, &d, 7, 3, &p), 0);
        assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
        d = rp__render_desc_defaults(&d);
        assert_non_null(rgba);
        assert_int_equal(rp__raygen_init(s.ctx, &s.cam, s.vol, 96, 96, &rg),
                         0);
        rp__reference_render(s.vol, s.tf, s.occ->grid, s.h->blocks, NULL, &rg, &d,
                             &all, rgba, tiles, fetches);
        for (k = 0; k < 12 * 12; k++)
          n += tiles[k].samples, f += fetches[k];
        free(rgba);
        assert_true(n > 0);
        truth = (double)(f - n) / 6.0 / (double)n;
        est = (e.fetches - 1.0) / 6.0;
        print_message("shaded share %s view %d ert %d: reference %.4f, "
                      "probe %.4f\n", tfs[t], v, ert, truth, est);
        /* Measured: at most 0.017 apart (minmax-bone with ERT: 0.031 for
         * 0.015, interpolation across its bone edge). */
        assert_true(fabs(est - truth) <= 0.03);
        worst = fmax(worst, fabs(est - truth));
      }
    }
    rp_occupancy_destroy(s.occ);
    rp_tf_destroy(s.tf);
  }
  print_message("shaded share: worst difference %.4f\n", worst);
  rp_cost_model_destroy(m);
  rp_histograms_destroy(s.h);
  rp_volume_destroy(s.vol);
  rp_context_destroy(s.ctx);
}

/* The probe's own cost (docs/pacing.md, "Prediction's own cost"): the
 * runtime asks for as many rays as its budget pays for at the probe's
 * measured cost per ray, never under RP__PROBE_MIN_RAYS, never over
 * RP_PROBE_MAX_RAYS, and all of them while no cost is known. */
static void test_probe_ray_budget(void **state) {
  (void)state;
  assert_int_equal(rp__probe_ray_budget(0.5, 1e-3), 500);
  assert_int_equal(rp__probe_ray_budget(0.5, 2e-3), 250);
  assert_int_equal(rp__probe_ray_budget(0.05, 1e-3), RP__PROBE_MIN_RAYS);
  assert_int_equal(rp__probe_ray_budget(0.0, 1e-3), RP__PROBE_MIN_RAYS);
  assert_int_equal(rp__probe_ray_budget(20.0, 1e-3), RP_PROBE_MAX_RAYS);
  assert_int_equal(rp__probe_ray_budget(1e300, 1e-300), RP_PROBE_MAX_RAYS);
  assert_int_equal(rp__probe_ray_budget(0.1, 0.0), RP_PROBE_MAX_RAYS);
  assert_int_equal(rp__probe_ray_budget(0.1, -1.0), RP_PROBE_MAX_RAYS);
  assert_int_equal(rp__probe_ray_budget(0.1, NAN), RP_PROBE_MAX_RAYS);
  assert_int_equal(rp__probe_ray_budget(NAN, 1e-3), RP_PROBE_MAX_RAYS);
}

/* A probe asked for fewer rays traces the regular subgrid of every sub-th
 * pre-pass ray, sub the smallest that fits (counted here from the grid,
 * 64 x 64 rays at 256 x 256), and its per-ray sums estimate the full
 * probe's: on a generated phantom over three views and two TFs, the
 * samples per ray at step 1 (S' / rays), the share of rays that hit and
 * the shaded share are within the bounds below of the 1024-ray probe's. The traced rays are the full probe's own
 * (same ray ids, same ERT draws), so the sums at 1024 rays are also the
 * same whether the ERT pre-pass walks the whole box or only the span
 * the depth pass found occupied. */
static double probe_samples_per_ray(const rp_frame_probe *p) {
  return (p->depth_sum + 0.5 * p->rays_hit + 0.5 * p->rays_ended) / p->rays;
}

static double probe_lit_share(const rp_frame_probe *p) {
  double all = p->depth_sum + 0.5 * p->rays_hit + 0.5 * p->rays_ended;
  return all > 0.0 ? (p->lit_span + p->lit_ends) / all : 0.0;
}

static void test_probe_fewer_rays(void **state) {
  static const char *const tfs[] = {"minmax-soft", "minmax-bone"};
  static const uint32_t caps[] = {576, 256, RP__PROBE_MIN_RAYS};
  scene s;
  rp_render_desc d = {0};
  rp_frame_probe *full = malloc(sizeof *full), *p = malloc(sizeof *p);
  double worst_s = 0.0, worst_hit = 0.0, worst_lit = 0.0;
  int t, v, c;
  (void)state;
  assert_non_null(full);
  assert_non_null(p);
  phantom_scene(&s);
  d.width = d.height = 256;
  d.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_SHADING;
  for (t = 0; t < 2; t++) {
    assert_int_equal(rp_tf_create_preset(s.ctx, tfs[t], &s.tf), 0);
    assert_int_equal(rp_occupancy_build(s.ctx, s.h, s.tf, &s.occ), 0);
    for (v = 0; v < 3; v++) {
      memset(&s.cam, 0, sizeof s.cam);
      rp_camera_orbit(&s.cam, s.vol, 30.0f + 110.0f * (float)v,
                      20.0f - 25.0f * (float)v, 1.6f);
      assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ,
                                              &s.cam, &d, 7, 3, full), 0);
      assert_int_equal(full->rays, 1024); /* every 2nd of 64 x 64 */
      /* 0 and past the most: the full probe, the same sums. */
      assert_int_equal(rp__frame_probe_compute(s.ctx, s.vol, s.tf, s.occ,
                                               &s.cam, &d, 7, 3, 0, p), 0);
      assert_int_equal(p->rays, full->rays);
      assert_float_equal(p->depth_sum, full->depth_sum, 0.0);
      for (c = 0; c < 3; c++) {
        uint32_t sub = 1, side;
        while (((64 + sub - 1) / sub) * ((64 + sub - 1) / sub) > caps[c])
          sub++;
        side = (64 + sub - 1) / sub;
        assert_int_equal(rp__frame_probe_compute(s.ctx, s.vol, s.tf, s.occ,
                                                 &s.cam, &d, 7, 3, caps[c],
                                                 p), 0);
        assert_int_equal(p->rays, side * side);
        assert_true(p->rays <= caps[c]);
        assert_int_equal(p->map_width, side);
        assert_int_equal(p->map_stride, 4 * sub);
        worst_s = fmax(worst_s, fabs(probe_samples_per_ray(p) /
                                     probe_samples_per_ray(full) - 1.0));
        worst_hit = fmax(worst_hit,
                         fabs((double)p->rays_hit / p->rays -
                              (double)full->rays_hit / full->rays));
        worst_lit = fmax(worst_lit,
                         fabs(probe_lit_share(p) - probe_lit_share(full)));
      }
    }
    rp_occupancy_destroy(s.occ);
    rp_tf_destroy(s.tf);
  }
  print_message("fewer rays: worst S'/ray %.4f, hit share %.4f, shaded "
                "share %.4f\n", worst_s, worst_hit, worst_lit);
  /* Measured: S' per ray 0.052 (the subgrids of every 3rd and 6th ray
   * start at the image's corner, not its centre: 2-5 % short here,
   * which kappa learns), hit share 0.002, shaded share 0.025. */
  assert_true(worst_s <= 0.06);
  assert_true(worst_hit <= 0.05);
  assert_true(worst_lit <= 0.03);
  free(full);
  free(p);
  rp_histograms_destroy(s.h);
  rp_volume_destroy(s.vol);
  rp_context_destroy(s.ctx);
}

static void test_probe_errors(void **state) {
  scene s;
  rp_render_desc d = {0};
  rp_frame_probe p;
  rp_tf *other;
  (void)state;
  box_scene(&s, "ramp");
  d.width = d.height = 16;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, NULL, &s.cam,
                                          &d, 1, 0, &p), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(s.ctx), "occ is NULL"));
  assert_int_equal(rp_tf_create_preset(s.ctx, "opaque", &other), 0);
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, other, s.occ,
                                          &s.cam, &d, 1, 0, &p), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(s.ctx), "another transfer"));
  d.width = 0;
  assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ, &s.cam,
                                          &d, 1, 0, &p), RP_EINVAL);
  rp_tf_destroy(other);
  scene_free(&s);
}

/* ---- Model --------------------------------------------------------------- */

/* A probe as rp_frame_probe_compute would fill it, for a view direction
 * (x, y, z): S'(1, 1) = 16 * (depth_sum + rays_hit / 2). */
static rp_frame_probe synthetic_probe(double x, double y, double z) {
  rp_frame_probe p;
  double n = sqrt(x * x + y * y + z * z);
  memset(&p, 0, sizeof(p));
  p.width = p.height = 256;
  p.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP;
  p.rays = 64 * 64;
  p.rays_hit = 2000;
  p.depth_sum = 2000 * 100.0;
  p.depth_max = 180.0;
  p.ert_cut = 0.3;
  p.view[0] = x / n;
  p.view[1] = y / n;
  p.view[2] = z / n;
  p.pixels_per_voxel = 1.5;
  p.diagonal = 220.0;
  return p;
}

/* Trains one frame of a plant whose fetch costs sigma_ns and whose frame
 * has c0_ms on top, rendering exactly the estimated samples. */
static void train_plant(rp_cost_model *m, const rp_frame_probe *p,
                        double sigma_ns, double c0_ms) {
  rp_cost_estimate e;
  double ray_ms;
  assert_int_equal(rp_cost_predict(m, p, 1.0f, 1.0f, &e), 0);
  ray_ms = sigma_ns * 1e-6 * e.fetches * floor(e.samples);
  assert_int_equal(rp_cost_train(m, p, 1.0f, 1.0f, (uint64_t)e.samples,
                                 ray_ms, ray_ms + c0_ms), 0);
}

static double predicted_sigma(const rp_cost_model *m,
                              const rp_frame_probe *p) {
  rp_cost_estimate e;
  assert_int_equal(rp_cost_predict(m, p, 1.0f, 1.0f, &e), 0);
  return e.sigma_ns;
}

/* Pre-integration's fetches against the reference raycaster's count on
 * the phantom: k = 1 + (rays that sample) / samples, the probe's estimate
 * of it within 0.01 of the reference's f / n at steps 1 and 3, ERT on and
 * off (measured: 0.004 at most), and its samples within 5 % (measured:
 * 2.7 %, the plain classification's own error). */
static void test_probe_preint(void **state) {
  static const float steps[] = {1.0f, 3.0f};
  scene s;
  rp_cost_model *m;
  int st, ert;
  (void)state;
  phantom_scene(&s);
  assert_int_equal(rp_tf_create_preset(s.ctx, "minmax-soft", &s.tf), 0);
  assert_int_equal(rp_occupancy_build(s.ctx, s.h, s.tf, &s.occ), 0);
  assert_int_equal(rp_cost_model_create(s.ctx, NULL, &m), 0);
  rp_camera_orbit(&s.cam, s.vol, 30.0f, 20.0f, 2.2f);
  for (st = 0; st < 2; st++)
    for (ert = 0; ert < 2; ert++) {
      rp_render_desc d = {0};
      rp_frame_probe p;
      rp_cost_estimate e;
      rp__raygen rg;
      rp_region all = {0, 0, 96, 96};
      uint8_t *rgba = malloc(96 * 96 * 4);
      rp_tile_stats tiles[12 * 12];
      uint64_t fetches[12 * 12], n = 0, f = 0;
      double truth;
      int k;
      d.width = d.height = 96;
      d.step = steps[st];
      d.effects = RP_EFFECT_SKIP | RP_EFFECT_PREINT |
                  (ert ? RP_EFFECT_ERT : 0u);
      assert_int_equal(rp_frame_probe_compute(s.ctx, s.vol, s.tf, s.occ,
                                              &s.cam, &d, 7, 3, &p), 0);
      assert_int_equal(rp_cost_predict(m, &p, d.step, 1.0f, &e), 0);
      d = rp__render_desc_defaults(&d);
      assert_non_null(rgba);
      assert_int_equal(rp__raygen_init(s.ctx, &s.cam, s.vol, 96, 96, &rg),
                       0);
      rp__reference_render(s.vol, s.tf, s.occ->grid, s.h->blocks, NULL, &rg,
                           &d, &all, rgba, tiles, fetches);
      for (k = 0; k < 12 * 12; k++)
        n += tiles[k].samples, f += fetches[k];
      free(rgba);
      assert_true(n > 0);
      truth = (double)f / (double)n;
      print_message("preint k step %g ert %d: reference %.4f, model %.4f; "
                    "samples %llu, model %.0f\n", (double)d.step, ert, truth,
                    e.fetches, (unsigned long long)n, e.samples);
      assert_true(truth > 1.0);
      assert_true(fabs(e.fetches - truth) <= 0.01);
      assert_true(fabs(e.samples - (double)n) <= 0.05 * (double)n);
    }
  rp_cost_model_destroy(m);
  scene_free(&s);
}

static void test_model_learns_plant(void **state) {
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_cost_estimate e;
  rp_frame_probe p = synthetic_probe(0, 0, -1);
  int i;
  (void)state;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  /* Before training: the prior sigma0 (5 ns) and no fixed cost. */
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.sigma_ns, 5.0, 1e-12);
  assert_float_equal(e.c0_ms, 0.0, 0.0);
  for (i = 0; i < 20; i++)
    train_plant(m, &p, 3.0, 1.5);
  /* k = 1 (no shading), S' = 16 (200000 + 1000). */
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.samples, 16.0 * 201000, 1e-6);
  assert_float_equal(e.sigma_ns, 3.0, 3e-9);
  assert_float_equal(e.c0_ms, 1.5, 1e-9);
  assert_float_equal(e.ms, 3e-6 * 16.0 * 201000 + 1.5, 1e-6);
  /* Shading: six more fetches per sample that shows. A quarter of every
   * span and of the extra samples shows: k = 1 + 6 / 4 at any step. */
  p.effects |= RP_EFFECT_SHADING;
  p.lit_span = 0.25 * p.depth_sum;
  p.lit_ends = 0.25 * 1000;
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.fetches, 2.5, 1e-12);
  assert_int_equal(rp_cost_predict(m, &p, 3.0f, 1.0f, &e), 0);
  assert_float_equal(e.fetches, 2.5, 1e-12);
  /* Every extra sample shows (ERT ended the rays on them): the share
   * grows with the step, (L_lit / h + 1000) / (L / h + 1000). */
  p.lit_ends = 1000;
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.fetches, 1.0 + 6.0 * 51000.0 / 201000.0, 1e-12);
  assert_int_equal(rp_cost_predict(m, &p, 4.0f, 1.0f, &e), 0);
  assert_float_equal(e.fetches, 1.0 + 6.0 * 13500.0 / 51000.0, 1e-12);
  /* Everything shows: the most, seven. */
  p.lit_span = p.depth_sum;
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.fetches, 7.0, 1e-12);
  assert_int_equal(rp_fetches_per_sample(p.effects), 7);
  /* Pre-integration: one more fetch per ray that samples, 2000 over
   * S' = 200000 / h + 2000 / 2 (at h = 2), skipping or not. */
  p.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_PREINT;
  p.lit_span = p.lit_ends = 0.0;
  assert_int_equal(rp_cost_predict(m, &p, 2.0f, 1.0f, &e), 0);
  assert_float_equal(e.samples, 16.0 * 101000.0, 1e-6);
  assert_float_equal(e.fetches, 1.0 + 2000.0 / 101000.0, 1e-12);
  p.effects = RP_EFFECT_ERT | RP_EFFECT_PREINT;
  assert_int_equal(rp_cost_predict(m, &p, 2.0f, 1.0f, &e), 0);
  assert_float_equal(e.samples, 16.0 * 101000.0, 1e-6);
  assert_float_equal(e.fetches, 1.0 + 2000.0 / 101000.0, 1e-12);
  assert_int_equal(rp_fetches_per_sample(p.effects), 1);
  p.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_SHADING;
  p.lit_span = p.depth_sum;
  p.lit_ends = 1000;
  /* A probe whose shaded span exceeds its span was not computed. */
  p.lit_span = 1.5 * p.depth_sum;
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), RP_EINVAL);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

/* Trains one frame at (step, scale) of a plant whose raycast costs
 * launch_ms at scale 1, a cost per ray (scale^2 of it at `scale`), plus
 * sigma_ns a fetch, times `stall` (1 for an honest frame). */
static void train_affine_at(rp_cost_model *m, const rp_frame_probe *p,
                            float step, float scale, double launch_ms,
                            double sigma_ns, double stall) {
  rp_cost_estimate e;
  double ray_ms;
  assert_int_equal(rp_cost_predict(m, p, step, scale, &e), 0);
  ray_ms = stall * (launch_ms * scale * scale +
                    sigma_ns * 1e-6 * e.fetches * floor(e.samples));
  assert_int_equal(rp_cost_train(m, p, step, scale, (uint64_t)e.samples,
                                 ray_ms, ray_ms + 0.5), 0);
}

/* Trains one frame at `step` and image scale 1 of a plant whose raycast
 * costs launch_ms plus sigma_ns a fetch, times `stall` (1 for an honest
 * frame). */
static void train_affine(rp_cost_model *m, const rp_frame_probe *p,
                         float step, double launch_ms, double sigma_ns,
                         double stall) {
  train_affine_at(m, p, step, 1.0f, launch_ms, sigma_ns, stall);
}

/* A raycast of 1.2 ms plus 4 ns a fetch, seen at six steps (S' from
 * 3.2 M at step 1 to 0.54 M at step 6): the launch cost and sigma are
 * told apart, and a step never trained is priced by the line; seen at
 * two scales too, the launch cost is priced per ray. As a cost
 * per fetch alone this plant would read 4.4 ns at step 1 and 6.2 ns at
 * step 6. A fifth of the frames stalled tenfold moves the launch cost
 * by under 2 %. */
static void test_model_launch_cost(void **state) {
  static const float steps[] = {1.0f, 1.5f, 2.0f, 3.0f, 4.0f, 6.0f};
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe p = synthetic_probe(0, 0, -1);
  rp_cost_estimate e;
  int i;
  (void)state;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  for (i = 0; i < 48; i++)
    train_affine(m, &p, steps[i % 6], 1.2, 4.0, 1.0);
  assert_int_equal(rp_cost_predict(m, &p, 2.5f, 1.0f, &e), 0);
  printf("launch %.6f ms, sigma %.6f ns\n", e.launch_ms, e.sigma_ns);
  assert_float_equal(e.launch_ms, 1.2, 1e-3);
  assert_float_equal(e.sigma_ns, 4.0, 4e-3);
  assert_float_equal(e.ms, 1.2 + 4e-6 * e.samples + 0.5, 2e-3);
  rp_cost_model_reset(m);
  for (i = 0; i < 48; i++)
    train_affine(m, &p, steps[i % 6], 1.2, 4.0, i % 5 == 4 ? 10.0 : 1.0);
  assert_int_equal(rp_cost_predict(m, &p, 2.5f, 1.0f, &e), 0);
  printf("with stalls: launch %.6f ms\n", e.launch_ms);
  assert_float_equal(e.launch_ms, 1.2, 0.024);
  /* One steady setting: a and sigma cannot be told apart, a stays 0. */
  rp_cost_model_reset(m);
  for (i = 0; i < 48; i++)
    train_affine(m, &p, 2.0f, 1.2, 4.0, 1.0);
  assert_int_equal(rp_cost_predict(m, &p, 2.0f, 1.0f, &e), 0);
  assert_float_equal(e.launch_ms, 0.0, 0.0);
  /* The fixed cost is a cost per ray: 20 ns a ray (1.31 ms at 256^2)
   * seen at scales 1 and 0.5 prices a frame at scale 0.25 with 20 ns
   * times its 4096 rays. A cost per launch would carry the 1.31 ms to
   * every scale: at scale 0.25 and step 6, more than the whole raycast. */
  rp_cost_model_reset(m);
  for (i = 0; i < 48; i++)
    train_affine_at(m, &p, steps[i % 6], i % 12 < 6 ? 1.0f : 0.5f,
                    20e-6 * 65536, 4.0, 1.0);
  assert_int_equal(rp_cost_predict(m, &p, 6.0f, 0.25f, &e), 0);
  printf("scale 0.25: launch %.6f ms (20 ns x 4096 rays = %.6f)\n",
         e.launch_ms, 20e-6 * 4096);
  assert_float_equal(e.launch_ms, 20e-6 * 4096, 1e-3 * 20e-6 * 4096);
  assert_float_equal(e.sigma_ns, 4.0, 4e-3);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

/* The launch fit across scenes. A window of one steady setting keeps
 * the a an earlier fit found (no pair to fit with); a frame of a new
 * scene whose whole raycast is cheaper than that a lowers it at once to
 * LAUNCH_SHARE (0.9) of that raycast, fit or no fit. And pairs are made
 * within one set of effects only: a plant of 1.2 ms plus 4 ns a fetch
 * without shading and 1.2 ms plus 2 ns a fetch with it (the gradient's
 * fetches hit the cache), each seen at two steps, gives a = 1.2 ms; the
 * pairs across the two would put a line through both costs per fetch. */
static void test_model_launch_new_scene(void **state) {
  static const float steps[] = {1.0f, 1.5f, 2.0f, 3.0f, 4.0f, 6.0f};
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe p = synthetic_probe(0, 0, -1), q;
  rp_cost_estimate e;
  int i;
  (void)state;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  for (i = 0; i < 48; i++)
    train_affine(m, &p, steps[i % 6], 1.2, 4.0, 1.0);
  for (i = 0; i < 24; i++)
    train_affine(m, &p, 2.0f, 1.2, 4.0, 1.0);
  assert_int_equal(rp_cost_predict(m, &p, 2.0f, 1.0f, &e), 0);
  assert_float_equal(e.launch_ms, 1.2, 1e-3);
  assert_int_equal(rp_cost_train(m, &p, 2.0f, 1.0f, (uint64_t)e.samples,
                                 0.5, 1.0), 0);
  assert_int_equal(rp_cost_predict(m, &p, 2.0f, 1.0f, &e), 0);
  assert_float_equal(e.launch_ms, 0.9 * 0.5, 1e-12);

  rp_cost_model_reset(m);
  q = p;
  q.effects |= RP_EFFECT_SHADING;
  q.lit_span = q.depth_sum;
  q.lit_ends = 1000;
  for (i = 0; i < 48; i++)
    train_affine(m, i % 2 ? &q : &p, i % 4 < 2 ? 1.0f : 6.0f, 1.2,
                 i % 2 ? 2.0 : 4.0, 1.0);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  printf("launch cost with and without shading: %.6f ms\n", e.launch_ms);
  assert_float_equal(e.launch_ms, 1.2, 1e-3);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

/* The short-term correction across a change of scene. Three frames of
 * one scene at half the cost the model had learned make q about 1/2
 * there; a frame of another scene (other view, spans, ERT share) is
 * priced without it, since it lowers the prediction, also after a frame
 * of that scene that taught sigma nothing. Three frames at
 * twice the cost make q about 2, and that one is carried over: it can
 * only cost image quality, never an overshoot. */
static void test_model_correction_new_scene(void **state) {
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe a = synthetic_probe(1, 1, 0), b = synthetic_probe(0, 0, 1);
  double base, on_a, on_b;
  int i, k;
  (void)state;
  b.ert_cut = 0.8;
  b.depth_sum /= 3;
  b.depth_max /= 3;
  for (k = 0; k < 2; k++) {
    const double f = k ? 2.0 : 0.5;
    assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
    for (i = 0; i < 40; i++)
      train_plant(m, &a, 4.0, 0.5);
    base = predicted_sigma(m, &b);
    for (i = 0; i < 3; i++)
      train_plant(m, &a, 4.0 * f, 0.5);
    on_a = predicted_sigma(m, &a);
    on_b = predicted_sigma(m, &b);
    printf("cost x%.1f on scene a: sigma' %.3f there, %.3f on scene b "
           "(%.3f before)\n", f, on_a, on_b, base);
    assert_float_equal(on_a, 4.0 * f, 0.1 * 4.0 * f);
    if (k == 0) {
      assert_true(on_b > 1.4 * on_a && on_b <= base);
      /* A frame of scene b that teaches sigma nothing (no sample) leaves
       * q as scene a made it: still not carried to b. */
      assert_int_equal(rp_cost_train(m, &b, 1.0f, 1.0f, 0, 0.1, 0.6), 0);
      assert_float_equal(predicted_sigma(m, &b), on_b, 1e-12);
    } else {
      assert_true(on_b > 1.4 * base);
    }
    rp_cost_model_destroy(m);
  }
  rp_context_destroy(ctx);
}

/* A machine slowed by half for a while (another process on the cores):
 * the model follows from the burst's third frame, within 10 %, where the
 * running mean alone would take tens of frames; one stalled frame moves
 * the prediction by nothing; when the burst ends the model is back
 * within 10 % after three frames. */
static void test_model_short_term(void **state) {
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe p = synthetic_probe(1, 1, 0);
  double before;
  int i;
  (void)state;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  for (i = 0; i < 40; i++)
    train_plant(m, &p, 4.0, 0.5);
  before = predicted_sigma(m, &p);
  assert_float_equal(before, 4.0, 0.04);
  train_plant(m, &p, 4000.0, 0.5);
  assert_float_equal(predicted_sigma(m, &p), before, 0.04 * before);
  train_plant(m, &p, 4.0, 0.5);
  for (i = 0; i < 2; i++) {
    train_plant(m, &p, 6.0, 0.5);
    assert_true(predicted_sigma(m, &p) < 5.0);
  }
  train_plant(m, &p, 6.0, 0.5);
  printf("burst: sigma' %.3f after 3 frames at 6\n", predicted_sigma(m, &p));
  assert_float_equal(predicted_sigma(m, &p), 6.0, 0.6);
  for (i = 0; i < 3; i++)
    train_plant(m, &p, 4.0, 0.5);
  printf("after: sigma' %.3f after 3 frames at 4\n", predicted_sigma(m, &p));
  assert_float_equal(predicted_sigma(m, &p), 4.0, 0.4);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

/* Frames the fetch model hardly sees: at step 64 a raycast is mostly its
 * launch cost (0.2 ms of fetches in 1.4 ms), so it does not teach sigma
 * and q never hears of it. When such frames all come in dearer than t'
 * (here the time outside the raycast jumps from 0.5 to 3 ms, which c0's
 * robust mean follows only over tens of frames), Q follows from the third
 * frame, within 10 %; before that t' is left alone; the next frame that
 * teaches sigma sets Q back to 1. */
static void test_model_frame_correction(void **state) {
  static const float steps[] = {1.0f, 1.5f, 2.0f, 3.0f, 4.0f, 6.0f};
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe p = synthetic_probe(0, 0, -1);
  rp_cost_estimate e;
  double ray_ms, frame_ms = 0.0, first = 0.0;
  int i;
  (void)state;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  for (i = 0; i < 48; i++)
    train_affine(m, &p, steps[i % 6], 1.2, 4.0, 1.0);
  for (i = 0; i < 6; i++) {
    assert_int_equal(rp_cost_predict(m, &p, 64.0f, 1.0f, &e), 0);
    if (i == 0)
      first = e.ms;
    else if (i < 3) /* two frames agree: not yet a bias */
      assert_float_equal(e.frame_factor, 1.0, 0.0);
    else
      assert_float_equal(e.ms, frame_ms, 0.1 * frame_ms);
    ray_ms = 1.2 + 4e-6 * e.fetches * floor(e.samples);
    frame_ms = ray_ms + 3.0;
    assert_true(ray_ms - 1.2 < 0.5 * ray_ms); /* does not teach sigma */
    assert_int_equal(rp_cost_train(m, &p, 64.0f, 1.0f, (uint64_t)e.samples,
                                   ray_ms, frame_ms), 0);
  }
  printf("step 64: t' %.3f ms at first, %.3f ms (Q %.3f) after 6 frames "
         "of %.3f ms\n", first, e.ms, e.frame_factor, frame_ms);
  assert_true(first < 0.6 * frame_ms); /* what Q had to correct */
  train_affine(m, &p, 1.0f, 1.2, 4.0, 1.0);
  assert_int_equal(rp_cost_predict(m, &p, 64.0f, 1.0f, &e), 0);
  assert_float_equal(e.frame_factor, 1.0, 0.0);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

/* Two views of different cost learned apart; a view far from both falls
 * back between them, never towards a free frame. */
static void test_model_views_and_unseen(void **state) {
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe a = synthetic_probe(1, 0, 0), b = synthetic_probe(-1, 0, 0);
  rp_frame_probe c = synthetic_probe(0, 1, 0);
  double sc;
  int i;
  (void)state;
  c.ert_cut = 0.9;
  c.pixels_per_voxel = 8.0;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  for (i = 0; i < 60; i++) {
    train_plant(m, &a, 2.0, 0.0);
    train_plant(m, &b, 8.0, 0.0);
  }
  assert_float_equal(predicted_sigma(m, &a), 2.0, 0.2);
  assert_float_equal(predicted_sigma(m, &b), 8.0, 0.8);
  sc = predicted_sigma(m, &c);
  assert_true(sc > 2.0 && sc < 8.0);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

/* One timing 1000x off (a stalled frame) moves the model by under 10 %;
 * 2000 identical frames keep it exact. */
static void test_model_outlier_and_duplicates(void **state) {
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe p = synthetic_probe(0, 1, 1);
  rp_cost_estimate e;
  int i;
  (void)state;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  for (i = 0; i < 2000; i++)
    train_plant(m, &p, 4.0, 0.5);
  assert_float_equal(predicted_sigma(m, &p), 4.0, 4e-9);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  train_plant(m, &p, 4000.0, 500.0);
  assert_true(fabs(predicted_sigma(m, &p) - 4.0) < 0.4);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_true(fabs(e.c0_ms - 0.5) < 0.05);
  /* And it comes back. */
  for (i = 0; i < 50; i++)
    train_plant(m, &p, 4.0, 0.5);
  assert_float_equal(predicted_sigma(m, &p), 4.0, 0.04);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

/* A true, lasting step in the cost is followed, not clamped away. */
static void test_model_follows_step(void **state) {
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe p = synthetic_probe(1, 1, 0);
  int i;
  (void)state;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  for (i = 0; i < 100; i++)
    train_plant(m, &p, 2.0, 0.0);
  for (i = 0; i < 60; i++)
    train_plant(m, &p, 6.0, 0.0);
  assert_float_equal(predicted_sigma(m, &p), 6.0, 0.3);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

/* A probe whose estimate is 38 % short for one kind of frame and exact
 * for another: the ratio is learned for each, sigma stays the real cost
 * of a fetch. */
static void test_model_sample_ratio(void **state) {
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe a = synthetic_probe(0, 0, 1), b = a;
  rp_cost_estimate e;
  int i;
  (void)state;
  a.ert_cut = 0.9;
  b.ert_cut = 0.0;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  for (i = 0; i < 60; i++) {
    double s;
    assert_int_equal(rp_cost_predict(m, &a, 1.0f, 1.0f, &e), 0);
    s = floor(e.samples * 1.6);
    assert_int_equal(rp_cost_train(m, &a, 1.0f, 1.0f, (uint64_t)s,
                                   3e-6 * s, 3e-6 * s), 0);
    assert_int_equal(rp_cost_predict(m, &b, 1.0f, 1.0f, &e), 0);
    s = e.samples;
    assert_int_equal(rp_cost_train(m, &b, 1.0f, 1.0f, (uint64_t)s,
                                   3e-6 * s, 3e-6 * s), 0);
  }
  assert_int_equal(rp_cost_predict(m, &a, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.sigma_ns, 3.0, 0.03);
  assert_float_equal(e.sample_ratio, 1.6, 0.08);
  assert_float_equal(e.ms, 3e-6 * 1.6 * e.samples, 0.05 * e.ms);
  assert_int_equal(rp_cost_predict(m, &b, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.sample_ratio, 1.0, 0.05);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

/* The fixed cost is learned apart for full-scale and upscaled frames; one
 * kind stands in for the other until it has frames of its own. */
static void test_model_c0_by_scale(void **state) {
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_frame_probe p = synthetic_probe(1, 0, 1);
  rp_cost_estimate e;
  int i;
  (void)state;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  for (i = 0; i < 10; i++)
    assert_int_equal(rp_cost_train(m, &p, 1.0f, 1.0f, 1000, 2.0, 3.0), 0);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 0.5f, &e), 0);
  assert_float_equal(e.c0_ms, 1.0, 1e-12);
  for (i = 0; i < 10; i++)
    assert_int_equal(rp_cost_train(m, &p, 1.0f, 0.5f, 250, 0.5, 4.0), 0);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 0.5f, &e), 0);
  assert_float_equal(e.c0_ms, 3.5, 1e-12);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &e), 0);
  assert_float_equal(e.c0_ms, 1.0, 1e-12);
  rp_cost_model_destroy(m);
  rp_context_destroy(ctx);
}

static void test_model_bad_input(void **state) {
  rp_context *ctx = rp_test_context();
  rp_cost_model *m;
  rp_cost_model_desc d = {0};
  rp_frame_probe p = synthetic_probe(0, 0, 1), bad = p;
  rp_cost_estimate before, after;
  (void)state;
  assert_int_equal(rp_cost_model_create(ctx, NULL, &m), 0);
  train_plant(m, &p, 3.0, 1.0);
  train_plant(m, &p, 3.5, 1.0);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &before), 0);
  assert_int_equal(rp_cost_train(m, &p, 1.0f, 1.0f, 1000, NAN, 2.0),
                   RP_ENOTFINITE);
  assert_int_equal(rp_cost_train(m, &p, 1.0f, 1.0f, 1000, 1.0, INFINITY),
                   RP_ENOTFINITE);
  assert_int_equal(rp_cost_train(m, &p, 1.0f, 1.0f, 1000, -1.0, 2.0),
                   RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "negative"));
  assert_int_equal(rp_cost_train(m, &p, 0.0f, 1.0f, 1000, 1.0, 2.0),
                   RP_EINVAL);
  assert_int_equal(rp_cost_train(m, &p, 1.0f, 1.5f, 1000, 1.0, 2.0),
                   RP_EINVAL);
  assert_int_equal(rp_cost_train(m, &p, NAN, 1.0f, 1000, 1.0, 2.0),
                   RP_ENOTFINITE);
  /* Finite, but its cost per fetch overflows: refused whole. */
  assert_int_equal(rp_cost_train(m, &p, 1.0f, 1.0f, 1, 1e303, 1e303),
                   RP_ERANGE);
  bad.rays_hit = bad.rays + 1;
  assert_int_equal(rp_cost_train(m, &bad, 1.0f, 1.0f, 1000, 1.0, 2.0),
                   RP_EINVAL);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &after), 0);
  assert_memory_equal(&before, &after, sizeof(before));
  /* A frame with no samples teaches c0 only. */
  assert_int_equal(rp_cost_train(m, &p, 1.0f, 1.0f, 0, 0.0, 1.0), 0);
  assert_int_equal(rp_cost_predict(m, &p, 1.0f, 1.0f, &after), 0);
  assert_float_equal(after.sigma_ns, before.sigma_ns, 0.0);
  rp_cost_model_destroy(m);
  d.sigma0_ns = -1.0;
  assert_int_equal(rp_cost_model_create(ctx, &d, &m), RP_EINVAL);
  d.sigma0_ns = NAN;
  assert_int_equal(rp_cost_model_create(ctx, &d, &m), RP_ENOTFINITE);
  assert_non_null(strstr(rp_last_error(ctx), "sigma0_ns"));
  d.sigma0_ns = 0.0;
  d.gamma = -1.0;
  assert_int_equal(rp_cost_model_create(ctx, &d, &m), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "gamma"));
  rp_cost_model_destroy(NULL);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_space_closed_forms),
      cmocka_unit_test(test_probe_box_closed_form),
      cmocka_unit_test(test_probe_subgrid),
      cmocka_unit_test(test_probe_ert_opaque),
      cmocka_unit_test(test_probe_nearly_transparent),
      cmocka_unit_test(test_probe_transparent),
      cmocka_unit_test(test_probe_shaded_share),
      cmocka_unit_test(test_probe_preint),
      cmocka_unit_test(test_probe_ray_budget),
      cmocka_unit_test(test_probe_fewer_rays),
      cmocka_unit_test(test_probe_errors),
      cmocka_unit_test(test_model_learns_plant),
      cmocka_unit_test(test_model_launch_cost),
      cmocka_unit_test(test_model_launch_new_scene),
      cmocka_unit_test(test_model_short_term),
      cmocka_unit_test(test_model_correction_new_scene),
      cmocka_unit_test(test_model_frame_correction),
      cmocka_unit_test(test_model_views_and_unseen),
      cmocka_unit_test(test_model_outlier_and_duplicates),
      cmocka_unit_test(test_model_follows_step),
      cmocka_unit_test(test_model_sample_ratio),
      cmocka_unit_test(test_model_c0_by_scale),
      cmocka_unit_test(test_model_bad_input),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
