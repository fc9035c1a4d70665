/* Backend conformance, written once and run per backend (ctest registers it
 * with RP_BACKEND=reference|test|opencl|vulkan; exit code 77 when that
 * backend has no device here).
 *
 * Every image is compared with rp_render_reference, the scalar oracle, over
 * a matrix of volumes, transfer functions, effects, cameras, viewports and
 * image scales. The tolerance (backends/README.md): per volume, at most
 * 0.1 % of pixels more than 2/255 off in any channel and none more than
 * 8/255; tile sample counts within one per ray; volume fetches (one
 * per sample, six more per shaded sample and one more with AO: only
 * samples with opacity above 0 take them) held to the reference's count as
 * rp_test_check_fetches states; the ERT pre-pass
 * equal to the C evaluation of the same generator and seed, a ray's
 * termination differing by one coarse step on at most 0.1 % of rays; the
 * AO volume the device computes within 2/255 of the reference's on
 * >= 99.9 % of voxels and none over 8/255. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "ao.h"
#include "passes.h"
#include "raypace_backend.h"
#include "raypace_testing.h"
#include "test_util.h"

static const char *backend_name(void) {
  const char *b = getenv("RP_BACKEND");
  return b != NULL && b[0] != '\0' ? b : "reference";
}

/* Accumulated over one volume's matrix. */
typedef struct tally {
  uint64_t fetches, fetches_off; /* reference's; off beyond samples */
  uint64_t pixels, over2, compared_tiles;
  int worst;
  char worst_at[160];
} tally;

typedef struct scene {
  const char *name;
  rp_volume *vol;
  rp_histograms *h;
} scene;

static rp_context *ctx;
static rp_device *dev;
static int device_counts_fetches = 1;

static rp_camera camera(const rp_volume *vol, int kind) {
  rp_camera c = {0};
  switch (kind) {
  case 0: /* outside, perspective */
    rp_camera_orbit(&c, vol, 30, 20, 2.2f);
    break;
  case 1: /* grazing: looking along a face, rays skim the box */
    rp_camera_orbit(&c, vol, 90, 0, 1.6f);
    c.center[1] = c.eye[1] = 0.49f * (float)vol->dims[1] * vol->spacing[1];
    break;
  case 2: /* zoomed in: a narrow field of view */
    rp_camera_orbit(&c, vol, -40, 35, 2.0f);
    c.fov_y_deg = 9.0f;
    break;
  case 3: /* inside the volume */
    rp_camera_orbit(&c, vol, 200, -15, 0.35f);
    c.fov_y_deg = 70.0f;
    break;
  default: /* orthographic */
    c.projection = RP_ORTHOGRAPHIC;
    rp_camera_orbit(&c, vol, 45, 35, 3.0f);
    break;
  }
  return c;
}
#define CAMERAS 5

static const char *camera_name(int kind) {
  static const char *const n[] = {"outside", "grazing", "zoomed", "inside",
                                  "ortho"};
  return n[kind];
}

static void compare(tally *t, const char *what, const uint8_t *got,
                    const uint8_t *want, const rp_tile_stats *gt,
                    const rp_tile_stats *wt, uint32_t w, uint32_t h) {
  uint32_t i, tx, ty, k;
  rp_tile_grid(w, h, &tx, &ty);
  for (i = 0; i < w * h; i++) {
    int worst = 0, c;
    for (c = 0; c < 4; c++) {
      int d = abs((int)got[4 * i + c] - (int)want[4 * i + c]);
      worst = d > worst ? d : worst;
    }
    t->pixels++;
    t->over2 += worst > 2;
    if (worst > t->worst) {
      t->worst = worst;
      snprintf(t->worst_at, sizeof t->worst_at, "%s pixel (%u, %u)", what,
               i % w, i / w);
    }
  }
  for (k = 0; k < tx * ty; k++) {
    uint32_t x0 = (k % tx) * RP_TILE_SIZE, y0 = (k / tx) * RP_TILE_SIZE;
    uint32_t rays = ((w - x0) < RP_TILE_SIZE ? w - x0 : RP_TILE_SIZE) *
                    ((h - y0) < RP_TILE_SIZE ? h - y0 : RP_TILE_SIZE);
    int64_t d = (int64_t)gt[k].samples - (int64_t)wt[k].samples;
    if (llabs(d) > (int64_t)rays)
      fail_msg("%s: tile %u takes %u samples, reference %u (more than one "
               "per ray apart)", what, k, gt[k].samples, wt[k].samples);
    t->compared_tiles++;
  }
}

static void finish(const tally *t, const char *name) {
  print_message("%s on %s: %llu pixels, %llu over 2/255 (%.4f %%), worst "
                "%d/255 at %s\n", backend_name(), name,
                (unsigned long long)t->pixels,
                (unsigned long long)t->over2,
                100.0 * (double)t->over2 / (double)t->pixels, t->worst,
                t->worst ? t->worst_at : "-");
  if (t->fetches > 0)
    print_message("%s on %s: fetches %llu, %llu off beyond the sample "
                  "differences\n", backend_name(), name,
                  (unsigned long long)t->fetches,
                  (unsigned long long)t->fetches_off);
  if (t->worst > 8)
    fail_msg("%s: a pixel is %d/255 off (%s); the bound is 8", name,
             t->worst, t->worst_at);
  if ((double)t->over2 > 0.001 * (double)t->pixels)
    fail_msg("%s: %llu of %llu pixels over 2/255; the bound is 0.1 %%",
             name, (unsigned long long)t->over2,
             (unsigned long long)t->pixels);
}

typedef struct frame {
  uint32_t w, h;
  uint8_t *got, *want;
  rp_tile_stats *gt, *wt;
  uint64_t *fetches;
} frame;

static void frame_alloc(frame *f, uint32_t w, uint32_t h) {
  uint32_t tx, ty;
  rp_tile_grid(w, h, &tx, &ty);
  f->w = w, f->h = h;
  f->got = calloc((size_t)w * h, 4);
  f->want = calloc((size_t)w * h, 4);
  f->gt = calloc((size_t)tx * ty, sizeof *f->gt);
  f->wt = calloc((size_t)tx * ty, sizeof *f->wt);
  f->fetches = calloc((size_t)tx * ty, sizeof *f->fetches);
  assert_true(f->got && f->want && f->gt && f->wt && f->fetches);
}

static void frame_free(frame *f) {
  free(f->got), free(f->want), free(f->gt), free(f->wt), free(f->fetches);
}

/* The reference's image, tiles and, when `fetches` is not NULL, fetches
 * per tile: then what rp_render_reference does, through the internal
 * entry that also counts. */
static void reference(const scene *s, const rp_tf *tf,
                      const rp_occupancy *occ, const rp_ao *ao,
                      const rp_camera *cam, const rp_render_desc *desc,
                      frame *f, uint64_t *fetches, const char *what) {
  rp_render_desc d = rp__render_desc_defaults(desc);
  rp__raygen rg;
  rp_region all = {0, 0, 0, 0};
  rp_volume ao_view;
  if (fetches == NULL) {
    if (rp_render_reference(ctx, s->vol, tf, occ, ao, cam, desc, f->want,
                            f->wt) != 0)
      fail_msg("%s: reference: %s", what, rp_last_error(ctx));
    return;
  }
  assert_int_equal(rp__raygen_init(ctx, cam, s->vol, d.width, d.height, &rg),
                   0);
  rp_scaled_size(&d, &rg.width, &rg.height);
  all.x1 = rg.width;
  all.y1 = rg.height;
  if (ao != NULL)
    rp__ao_view(ao, &ao_view);
  rp__reference_render(s->vol, tf,
                       (d.effects & RP_EFFECT_SKIP) ? occ->grid : NULL,
                       occ != NULL ? occ->h->blocks : NULL,
                       ao != NULL ? &ao_view : NULL, &rg, &d, &all, f->want,
                       f->wt, fetches);
}

/* One render on the device and on the reference, compared. */
static void check_render(tally *t, const scene *s, const rp_tf *tf,
                         const rp_occupancy *occ, const rp_ao *ao,
                         const rp_camera *cam,
                         const rp_render_desc *d, const char *what,
                         int count_fetches) {
  frame f;
  uint32_t sw, sh, tx = 0, ty = 0;
  uint64_t *want_fetches = NULL;
  int err;
  rp_scaled_size(d, &sw, &sh);
  frame_alloc(&f, sw, sh);
  if (count_fetches) {
    rp_tile_grid(sw, sh, &tx, &ty);
    want_fetches = calloc((size_t)tx * ty, sizeof *want_fetches);
    assert_non_null(want_fetches);
  }
  reference(s, tf, occ, ao, cam, d, &f, want_fetches, what);
  err = rp__device_render(dev, cam, d, NULL, f.got, f.gt,
                          count_fetches ? f.fetches : NULL);
  if (err == RP_EUNSUPPORTED && count_fetches) {
    device_counts_fetches = 0;
    count_fetches = 0;
    err = rp__device_render(dev, cam, d, NULL, f.got, f.gt, NULL);
  }
  if (err != 0)
    fail_msg("%s: %s: %s", what, backend_name(), rp_last_error(ctx));
  compare(t, what, f.got, f.want, f.gt, f.wt, sw, sh);
  if (count_fetches)
    rp_test_check_fetches(what, f.gt, f.fetches, f.wt, want_fetches,
                          (size_t)tx * ty,
                          rp_test_visible_fetches(d->effects), &t->fetches,
                          &t->fetches_off);
  free(want_fetches);
  frame_free(&f);
}

static const char *const tfs[] = {"ct-bone", "transparent", "opaque",
                                  "nearly-transparent", "mri"};
#define TFS 5
/* AO appears once, with every other effect: each set is a kernel
 * variant to build per voxel type, and AO alone (without shading) is
 * held to the reference in each backend's own test. */
static const uint32_t effect_sets[] = {
    0, RP_EFFECT_SHADING, RP_EFFECT_ERT, RP_EFFECT_SKIP,
    RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP,
    RP_EFFECT_AO | RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP};
#define EFFECT_SETS 6
#define EFFECT_SETS_NO_AO 5 /* the first five */

/* AO settings small enough for the reference to compute per TF. */
static const rp_ao_desc conformance_ao = {6, 4, 4.0f, 1.0f, 0};

/* The device's AO of the scene under `tf` against the reference's, by
 * the contract's tolerance (backends/README.md): within 2/255 on at
 * least 99.9 % of voxels, none over 8/255. Returns the reference's, the
 * one both sides then render with, so that image differences are the
 * raycast's alone. */
static rp_ao *check_ao(const scene *s, const rp_tf *tf) {
  rp_ao_plan *plan = NULL;
  rp_ao *want = NULL, *got = NULL;
  const uint8_t *a, *b;
  size_t n = s->vol->voxel_count, i, over2 = 0;
  int worst = 0;
  assert_int_equal(rp_ao_compute_reference(ctx, s->vol, tf, &conformance_ao,
                                           NULL, NULL, &want),
                   0);
  assert_int_equal(rp_ao_plan_create(ctx, s->vol, tf, &conformance_ao,
                                     &plan),
                   0);
  if (rp_ao_compute(ctx, &dev, 1, plan, NULL, &got, NULL) != 0)
    fail_msg("%s: AO on %s: %s", s->name, backend_name(),
             rp_last_error(ctx));
  a = rp_ao_data(got, NULL);
  b = rp_ao_data(want, NULL);
  for (i = 0; i < n; i++) {
    int d = abs((int)a[i] - (int)b[i]);
    over2 += d > 2;
    worst = d > worst ? d : worst;
  }
  if (worst > 8 || over2 * 1000 > n)
    fail_msg("%s: AO: worst %d/255, %zu of %zu voxels over 2/255", s->name,
             worst, over2, n);
  rp_ao_destroy(got);
  rp_ao_plan_destroy(plan);
  if (rp_device_set_ao(dev, want) != 0)
    fail_msg("%s: set_ao: %s", s->name, rp_last_error(ctx));
  return want;
}

/* The device's AO of the box [lo, end) against the reference's voxels,
 * for volumes too large for the reference to compute whole per TF. */
static void check_ao_box(const scene *s, const rp_tf *tf) {
  rp_ao_plan *plan = NULL;
  uint32_t lo[3], end[3], a;
  size_t n, i, over2 = 0;
  uint8_t *got, *want;
  int worst = 0;
  for (a = 0; a < 3; a++) {
    uint32_t d = s->vol->dims[a], len = d < 24 ? d : 24;
    lo[a] = (d - len) / 2;
    end[a] = lo[a] + len;
  }
  n = (size_t)(end[0] - lo[0]) * (end[1] - lo[1]) * (end[2] - lo[2]);
  got = malloc(n);
  want = malloc(n);
  assert_true(got && want);
  assert_int_equal(rp_ao_plan_create(ctx, s->vol, tf, &conformance_ao,
                                     &plan),
                   0);
  if (rp_device_compute_ao(dev, plan, lo, end, got) != 0)
    fail_msg("%s: AO on %s: %s", s->name, backend_name(),
             rp_last_error(ctx));
  rp__ao_reference_box(s->vol, tf, plan, lo, end, lo[2], end[2], want);
  for (i = 0; i < n; i++) {
    int d = abs((int)got[i] - (int)want[i]);
    over2 += d > 2;
    worst = d > worst ? d : worst;
  }
  if (worst > 8 || over2 * 1000 > n)
    fail_msg("%s: AO box: worst %d/255, %zu of %zu voxels over 2/255",
             s->name, worst, over2, n);
  free(got);
  free(want);
  rp_ao_plan_destroy(plan);
}

/* with_ao: 1 the AO volume compared and the AO effect sets rendered; 0
 * only a central box of AO compared (large volumes). */
static void run_matrix(scene *s, uint32_t w, uint32_t h, int full,
                       int with_ao) {
  tally t = {0};
  int ti, e, c;
  rp_ao *ao = NULL;
  assert_int_equal(rp_device_set_volume(dev, s->vol), 0);
  for (ti = 0; ti < TFS; ti++) {
    rp_tf *tf = NULL;
    rp_occupancy *occ = NULL;
    assert_int_equal(rp_tf_create_preset(ctx, tfs[ti], &tf), 0);
    assert_int_equal(rp_occupancy_build(ctx, s->h, tf, &occ), 0);
    if (rp_device_set_tf(dev, tf, occ) != 0)
      fail_msg("set_tf: %s", rp_last_error(ctx));
    if (with_ao)
      ao = check_ao(s, tf);
    else
      check_ao_box(s, tf);
    for (e = 0; e < (with_ao ? EFFECT_SETS : EFFECT_SETS_NO_AO); e++) {
      for (c = 0; c < CAMERAS; c++) {
        rp_camera cam = camera(s->vol, c);
        rp_render_desc d = {0};
        char what[160];
        /* The full cross product on the first TF; the others with every
         * effect set from two cameras, which is where they differ. */
        if (!full && c > 1)
          continue;
        if (ti > 0 && c != 0 && c != 3)
          continue;
        d.width = w, d.height = h, d.effects = effect_sets[e];
        snprintf(what, sizeof what, "%s tf %s effects 0x%x camera %s",
                 s->name, tfs[ti], effect_sets[e], camera_name(c));
        check_render(&t, s, tf, occ, ao, &cam, &d, what, c == 0);
      }
    }
    rp_ao_destroy(ao);
    ao = NULL;
    rp_occupancy_destroy(occ);
    rp_tf_destroy(tf);
  }
  assert_int_equal(rp_device_set_ao(dev, NULL), 0);
  finish(&t, s->name);
}

static scene make_scene(const char *name, rp_generator kind, uint32_t x,
                        uint32_t y, uint32_t z, rp_voxel_type type) {
  scene s = {name, NULL, NULL};
  rp_generate_desc g = {0};
  g.kind = kind, g.dims[0] = x, g.dims[1] = y, g.dims[2] = z;
  g.type = type, g.seed = 3;
  assert_int_equal(rp_volume_generate(ctx, &g, &s.vol), 0);
  assert_int_equal(rp_histograms_build(ctx, s.vol, &s.h), 0);
  return s;
}

static void drop_scene(scene *s) {
  rp_histograms_destroy(s->h);
  rp_volume_destroy(s->vol);
}

static void matrix_phantom_u8(void **state) {
  scene s = make_scene("phantom 48^3 u8", RP_GEN_PHANTOM, 48, 48, 48, RP_U8);
  (void)state;
  run_matrix(&s, 32, 24, 1, 1);
  drop_scene(&s);
}

static void matrix_marschner_lobb_u16(void **state) {
  scene s = make_scene("Marschner-Lobb 41x37x29 u16", RP_GEN_MARSCHNER_LOBB,
                       41, 37, 29, RP_U16);
  (void)state;
  run_matrix(&s, 24, 20, 1, 1);
  drop_scene(&s);
}

static void matrix_noise(void **state) {
  scene s = make_scene("noise 23x17x30 u8", RP_GEN_NOISE, 23, 17, 30, RP_U8);
  (void)state;
  run_matrix(&s, 20, 16, 0, 1);
  drop_scene(&s);
}

/* Float voxels: Marschner-Lobb rescaled to [-3, 5]. */
static void matrix_float(void **state) {
  scene s = make_scene("ML 33x20x26 float", RP_GEN_MARSCHNER_LOBB, 33, 20,
                       26, RP_U16);
  rp_volume_desc d = {0};
  rp_volume *fv = NULL;
  size_t i, n = (size_t)33 * 20 * 26;
  float *vox = malloc(n * sizeof *vox);
  const uint16_t *src = rp_volume_data(s.vol);
  (void)state;
  assert_non_null(vox);
  for (i = 0; i < n; i++)
    vox[i] = -3.0f + 8.0f * src[i] / 65535.0f;
  d.dims[0] = 33, d.dims[1] = 20, d.dims[2] = 26, d.type = RP_F32;
  d.data = vox;
  d.spacing[0] = 1.0f, d.spacing[1] = 1.5f, d.spacing[2] = 0.75f;
  assert_int_equal(rp_volume_create(ctx, &d, &fv), 0);
  free(vox);
  drop_scene(&s);
  s.vol = fv;
  assert_int_equal(rp_histograms_build(ctx, fv, &s.h), 0);
  run_matrix(&s, 24, 18, 0, 1);
  drop_scene(&s);
}

/* 1x1, 7x513 and a 0.5 image scale, every effect set, three steps. */
static void odd_viewports_and_scales(void **state) {
  static const uint32_t sizes[][2] = {{1, 1}, {7, 513}, {40, 30}, {9, 2}};
  static const float scales[] = {1.0f, 1.0f, 0.5f, 1.0f};
  static const float steps[] = {0.0f, 0.37f, 2.6f};
  scene s = make_scene("phantom 40x33x21", RP_GEN_PHANTOM, 40, 33, 21, RP_U8);
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  tally t = {0};
  size_t v;
  int e, c;
  (void)state;
  assert_int_equal(rp_device_set_volume(dev, s.vol), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "ct-soft", &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, s.h, tf, &occ), 0);
  assert_int_equal(rp_device_set_tf(dev, tf, occ), 0);
  for (v = 0; v < sizeof sizes / sizeof sizes[0]; v++)
    for (e = 0; e < EFFECT_SETS_NO_AO; e++)
      for (c = 0; c < CAMERAS; c += 2) {
        rp_camera cam = camera(s.vol, c);
        rp_render_desc d = {0};
        char what[160];
        d.width = sizes[v][0], d.height = sizes[v][1];
        d.image_scale = scales[v];
        d.effects = effect_sets[e];
        /* Steps other than the TF's reference step exercise opacity
         * correction; 0 is the default (1). */
        d.step = steps[(v + (uint32_t)e) % 3];
        snprintf(what, sizeof what, "%ux%u scale %g step %g effects 0x%x "
                 "camera %s", d.width, d.height, (double)d.image_scale,
                 (double)d.step, d.effects, camera_name(c));
        check_render(&t, &s, tf, occ, NULL, &cam, &d, what, 1);
      }
  finish(&t, "odd viewports");
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
  drop_scene(&s);
}

/* Real volumes when ../shared/data is there: 8 and 16 bit, anisotropic. */
static void matrix_real_volumes(void **state) {
  static const char *const names[] = {"bonsai", "headsq_ct",
                                      "vx_smallhead_ct"};
  size_t i;
  int any = 0;
  (void)state;
  for (i = 0; i < sizeof names / sizeof names[0]; i++) {
    char path[1024];
    scene s = {names[i], NULL, NULL};
    if (rp_test_data_volume(names[i], path, sizeof path) == NULL)
      continue;
    any = 1;
    if (rp_volume_load(ctx, path, &s.vol) != 0)
      fail_msg("%s: %s", path, rp_last_error(ctx));
    assert_int_equal(rp_histograms_build(ctx, s.vol, &s.h), 0);
    run_matrix(&s, 24, 24, 0, 0);
    drop_scene(&s);
  }
  if (!any)
    skip();
}

/* Depth pass against the C DDA; ERT pre-pass against the C generator. */
typedef struct pass_tally {
  uint64_t rays, differ, depth_rays, depth_differ;
} pass_tally;

/* The device's depth pass and ERT pre-pass against the reference
 * device's over every camera, for one volume and TF. */
static void compare_passes(const rp_volume *vol, const rp_histograms *h,
                           const char *tf_name, pass_tally *t) {
  rp_device *ref = NULL;
  rp_device_desc rd = {0};
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  int c, e;
  rd.backend = "reference";
  assert_int_equal(rp_device_create(ctx, &rd, &ref), 0);
  assert_int_equal(rp_tf_create_preset(ctx, tf_name, &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, h, tf, &occ), 0);
  assert_int_equal(rp_device_set_volume(dev, vol), 0);
  assert_int_equal(rp_device_set_tf(dev, tf, occ), 0);
  assert_int_equal(rp_device_set_volume(ref, vol), 0);
  assert_int_equal(rp_device_set_tf(ref, tf, occ), 0);
  for (c = 0; c < CAMERAS; c++) {
    for (e = 0; e < 2; e++) {
      rp_camera cam = camera(vol, c);
      rp_render_desc d = {0};
      uint32_t gw, gh, i;
      float *a, *b;
      d.width = 61, d.height = 45;
      d.effects = e ? RP_EFFECT_SKIP : 0;
      a = malloc(sizeof(float) * 2 * 61 * 45);
      b = malloc(sizeof(float) * 2 * 61 * 45);
      assert_true(a != NULL && b != NULL);
      assert_int_equal(rp_device_depth_pass(dev, &cam, &d, a), 0);
      assert_int_equal(rp_device_depth_pass(ref, &cam, &d, b), 0);
      for (i = 0; i < 2 * 61 * 45; i++) {
        float tol = 1e-3f * fmaxf(1.0f, fabsf(b[i]));
        t->depth_rays++;
        if (!(a[i] == b[i] || fabsf(a[i] - b[i]) <= tol))
          t->depth_differ++;
      }
      rp__ert_grid(61, 45, &gw, &gh);
      d.effects = RP_EFFECT_SKIP | RP_EFFECT_ERT;
      d.ert_threshold = e ? 0.5f : 0.0f;
      assert_int_equal(rp_device_ert_prepass(dev, &cam, &d, 1234, 7, a), 0);
      assert_int_equal(rp_device_ert_prepass(ref, &cam, &d, 1234, 7, b), 0);
      for (i = 0; i < gw * gh; i++) {
        t->rays++;
        if (a[i] == b[i] || fabsf(a[i] - b[i]) <= 1e-3f * fabsf(b[i]))
          continue;
        /* Float rounding may move a termination by one coarse step. */
        if (isinf(a[i]) || isinf(b[i]) ||
            fabsf(fabsf(a[i] - b[i]) - RP_ERT_COARSE_STEP) > 1e-2f)
          fail_msg("ERT ray %u (camera %s): %g vs reference %g", i,
                   camera_name(c), (double)a[i], (double)b[i]);
        t->differ++;
      }
      free(a);
      free(b);
    }
  }
  rp_device_destroy(ref);
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
}

/* Zeros with one blob of values 100..200 off the centre, on no block
 * boundary: the occupied blocks' box (the blob's blocks and their
 * neighbours) is inside the grid on every side, so kernels that clip to
 * it (backends/README.md) are held to the reference's walk of the whole
 * grid, rays that miss the box included. */
static scene blob_scene(void) {
  enum { X = 96, Y = 80, Z = 80 };
  scene s = {"blob 96x80x80", NULL, NULL};
  rp_volume_desc vd = {{X, Y, Z}, RP_U8, {1.0f, 1.0f, 1.0f}, NULL};
  uint8_t *v = calloc((size_t)X * Y * Z, 1);
  uint32_t x, y, z;
  assert_non_null(v);
  for (z = 37; z < 45; z++)
    for (y = 36; y < 44; y++)
      for (x = 50; x < 62; x++)
        v[((size_t)z * Y + y) * X + x] = (uint8_t)(100 + (x + y + z) % 101);
  vd.data = v;
  assert_int_equal(rp_volume_create(ctx, &vd, &s.vol), 0);
  free(v);
  assert_int_equal(rp_histograms_build(ctx, s.vol, &s.h), 0);
  return s;
}

static void depth_and_ert_passes(void **state) {
  scene s = make_scene("phantom 64x50x40", RP_GEN_PHANTOM, 64, 50, 40, RP_U8);
  scene blob = blob_scene();
  pass_tally t = {0, 0, 0, 0};
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  int a;
  (void)state;
  compare_passes(s.vol, s.h, "ct-soft", &t);
  /* The blob's box: inside the grid along every axis. */
  assert_int_equal(rp_tf_create_preset(ctx, "ct-soft", &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, blob.h, tf, &occ), 0);
  for (a = 0; a < 3; a++)
    assert_true(occ->box_lo[a] > 0 && occ->box_lo[a] < occ->box_end[a] &&
                occ->box_end[a] < blob.h->blocks[a]);
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
  compare_passes(blob.vol, blob.h, "ct-soft", &t);
  print_message("%s: ERT pre-pass: %llu of %llu rays one step off; depth "
                "pass: %llu of %llu values off\n", backend_name(),
                (unsigned long long)t.differ, (unsigned long long)t.rays,
                (unsigned long long)t.depth_differ,
                (unsigned long long)t.depth_rays);
  assert_true((double)t.differ <= 0.001 * (double)t.rays);
  assert_true((double)t.depth_differ <= 0.001 * (double)t.depth_rays);
  drop_scene(&blob);
  drop_scene(&s);
}

/* Regions: four tile-aligned quadrants rendered apart equal one render of
 * the whole image, and each call writes only its own region. */
static void regions_compose(void **state) {
  scene s = make_scene("phantom 40^3", RP_GEN_PHANTOM, 40, 40, 40, RP_U8);
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  rp_camera cam = camera(s.vol, 0);
  rp_render_desc d = {0};
  uint8_t whole[37 * 29 * 4], parts[37 * 29 * 4];
  rp_tile_stats tw[5 * 4], tp[5 * 4];
  rp_region q[4] = {{0, 0, 16, 16}, {16, 0, 37, 16}, {0, 16, 16, 29},
                    {16, 16, 37, 29}};
  rp_region bad = {3, 0, 16, 8};
  int i;
  (void)state;
  assert_int_equal(rp_tf_create_preset(ctx, "ct-bone", &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, s.h, tf, &occ), 0);
  assert_int_equal(rp_device_set_volume(dev, s.vol), 0);
  assert_int_equal(rp_device_set_tf(dev, tf, occ), 0);
  d.width = 37, d.height = 29;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  assert_int_equal(rp_device_render(dev, &cam, &d, NULL, whole, tw), 0);
  memset(parts, 0xab, sizeof parts);
  memset(tp, 0xab, sizeof tp);
  for (i = 0; i < 4; i++)
    assert_int_equal(rp_device_render(dev, &cam, &d, &q[i], parts, tp), 0);
  assert_memory_equal(whole, parts, sizeof whole);
  assert_memory_equal(tw, tp, sizeof tw);
  assert_int_equal(rp_device_render(dev, &cam, &d, &bad, parts, tp),
                   RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "tile grid"));
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
 * 1000x waits 999x its device time after each operation and reports
 * 1000x it: its renders report at least 10x the median of the same
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
  assert_int_equal(rp_tf_create_preset(ctx, "ct-bone", &tf), 0);
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
  fd.slowdown = 1000.0;
  assert_int_equal(rp_device_create(ctx, &dd, &slow), 0);
  assert_int_equal(rp_device_set_volume(slow, s.vol), 0);
  assert_int_equal(rp_device_set_tf(slow, tf, occ), 0);
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
  rp_context_desc cd = {0};
  rp_context *cc = NULL;
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
  cd.allocator.alloc = count_alloc;
  cd.allocator.free = count_free;
  cd.allocator.user = &c;
  assert_int_equal(rp_context_create(&cd, &cc), 0);
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
  assert_int_equal(rp_tf_create_preset(ctx, "ct-bone", &tf), 0);
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

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(front_end_validates),
      cmocka_unit_test(slowed_and_failing_devices),
      cmocka_unit_test(partitioned_devices),
      cmocka_unit_test(regions_compose),
      cmocka_unit_test(depth_and_ert_passes),
      cmocka_unit_test(odd_viewports_and_scales),
      cmocka_unit_test(matrix_phantom_u8),
      cmocka_unit_test(matrix_marschner_lobb_u16),
      cmocka_unit_test(matrix_noise),
      cmocka_unit_test(matrix_float),
      cmocka_unit_test(matrix_real_volumes),
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
  if (!device_counts_fetches)
    printf("conformance: this device does not count fetches\n");
  rp_device_destroy(dev);
  rp_context_destroy(ctx);
  return rc;
}
