/* The per-frame passes and what a raycast reports besides its pixels:
 * the depth pass against the C walk (rp__depth_ray), ray by ray; the ERT
 * pre-pass against the C generator (rp__ert_prepass); regions rendered
 * apart against the whole image; fetch counts against the reference's.
 *
 * Depth pass, per ray: a miss (+inf, -inf) on either side must be one on
 * both, exactly, or the ray is counted off (a ray grazing the box may
 * flip); without skipping, every other ray's box clip is within 1e-3
 * voxels, or the test fails at once; with skipping, values more than
 * 1e-3 apart are counted off (a ray grazing a block corner may see one
 * block more or less). Off values stay under 0.2 % of the rays of each
 * camera and skip setting, and off rays under 0.1 % of all.
 *
 * ERT pre-pass, per pre-pass ray: equal within 1e-3, or both finite and
 * one coarse step apart (float rounding may move a termination by one
 * step) on at most 0.1 % of the rays of each camera and frame; anything
 * else fails at once. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "conformance.h"

/* Zeros with one blob of values 100..200 off the centre, on no block
 * boundary: the occupied blocks' box (the blob's blocks and their
 * neighbours) is inside the grid on every side, so kernels that clip to
 * it (backends/README.md) are held to the reference's walk of the whole
 * grid, rays that miss the box included. */
static scene blob_scene(void) {
  enum { X = 96, Y = 80, Z = 80 };
  rp_volume_desc vd = {{X, Y, Z}, RP_U8, {1.0f, 1.0f, 1.0f}, NULL, {0}};
  uint8_t *v = calloc((size_t)X * Y * Z, 1);
  rp_volume *vol = NULL;
  uint32_t x, y, z;
  assert_non_null(v);
  for (z = 37; z < 45; z++)
    for (y = 36; y < 44; y++)
      for (x = 50; x < 62; x++)
        v[((size_t)z * Y + y) * X + x] = (uint8_t)(100 + (x + y + z) % 101);
  vd.data = v;
  assert_int_equal(rp_volume_create(ctx, &vd, &vol), 0);
  free(v);
  return scene_of("blob 96x80x80", vol);
}

/* The blob's occupied box lies inside the grid along every axis. */
static void check_blob_box(const lit_scene *l) {
  int a;
  for (a = 0; a < 3; a++)
    assert_true(l->occ->box_lo[a] > 0 &&
                l->occ->box_lo[a] < l->occ->box_end[a] &&
                l->occ->box_end[a] < l->s.h->blocks[a]);
}

/* The rays of a frame at its scaled size, as the reference casts them. */
static void raygen(const scene *s, const rp_camera *cam,
                   const rp_render_desc *desc, rp__raygen *rg) {
  rp_render_desc d = rp__render_desc_defaults(desc);
  assert_int_equal(rp__raygen_init(ctx, cam, s->vol, d.width, d.height, rg),
                   0);
  rp_scaled_size(&d, &rg->width, &rg->height);
}

/* ---- depth pass ---------------------------------------------------------- */

typedef struct depth_tally {
  uint64_t rays, off_rays;
} depth_tally;

/* Nothing in view: every ray (+inf, -inf), and a render writes an empty
 * image with no samples. */
static void check_nothing_seen(const float *fb, const rp_camera *cam,
                               const rp_render_desc *d, uint32_t w,
                               uint32_t h) {
  uint32_t i, tx, ty;
  uint8_t *img = malloc((size_t)w * h * 4);
  rp_tile_stats *tiles;
  rp_tile_grid(w, h, &tx, &ty);
  tiles = calloc((size_t)tx * ty, sizeof *tiles);
  assert_true(img != NULL && tiles != NULL);
  for (i = 0; i < w * h; i++)
    assert_true(isinf(fb[2 * i]) && fb[2 * i] > 0 &&
                isinf(fb[2 * i + 1]) && fb[2 * i + 1] < 0);
  memset(img, 0xab, (size_t)w * h * 4);
  assert_int_equal(rp_device_render(dev, cam, d, NULL, img, tiles), 0);
  for (i = 0; i < w * h * 4; i++)
    assert_int_equal(img[i], 0);
  for (i = 0; i < tx * ty; i++)
    assert_int_equal(tiles[i].samples, 0);
  free(img);
  free(tiles);
}

/* One camera and skip setting of a scene: the device's depth pass
 * against rp__depth_ray, ray by ray (the rules atop this file). */
static void depth_frame(const lit_scene *l, int cam_kind, int skip,
                        uint32_t w, uint32_t h, depth_tally *t) {
  rp_camera cam = camera(l->s.vol, cam_kind);
  rp_render_desc d = {0};
  rp__raygen rg;
  uint32_t x, y, off_values = 0;
  float *fb;
  d.width = w, d.height = h;
  d.effects = skip ? RP_EFFECT_SKIP : 0u;
  raygen(&l->s, &cam, &d, &rg);
  fb = malloc((size_t)rg.width * rg.height * 2 * sizeof *fb);
  assert_non_null(fb);
  if (rp_device_depth_pass(dev, &cam, &d, fb) != 0)
    fail_msg("%s: depth pass: %s", l->s.name, rp_last_error(ctx));
  assert_true(rp_device_last_time_ns(dev) > 0);
  for (y = 0; y < rg.height; y++)
    for (x = 0; x < rg.width; x++) {
      const float *got = fb + 2 * ((size_t)y * rg.width + x);
      double want[2];
      rp__ray ray;
      int k, off = 0;
      rp__raygen_ray(&rg, x, y, &ray);
      rp__depth_ray(&ray, rg.dims, skip ? rp_occupancy_grid(l->occ) : NULL,
                    l->s.h->blocks, &want[0], &want[1]);
      t->rays++;
      if (isinf(want[0]) || isinf(got[0])) {
        for (k = 0; k < 2; k++)
          off += got[k] != (float)want[k];
      } else {
        for (k = 0; k < 2; k++) {
          if (fabs(got[k] - want[k]) <= 1e-3)
            continue;
          if (!skip)
            fail_msg("%s camera %s ray (%u, %u): (%.6f, %.6f), box clip "
                     "(%.6f, %.6f)", l->s.name, camera_name(cam_kind), x, y,
                     (double)got[0], (double)got[1], want[0], want[1]);
          off++;
        }
      }
      off_values += (uint32_t)off;
      t->off_rays += off > 0;
    }
  if ((uint64_t)off_values * 1000 > 2 * (uint64_t)rg.width * rg.height)
    fail_msg("%s camera %s skip %d: %u depth values off", l->s.name,
             camera_name(cam_kind), skip, off_values);
  if (cam_kind == CAM_AWAY)
    check_nothing_seen(fb, &cam, &d, rg.width, rg.height);
  free(fb);
}

static void depth_scene(lit_scene l, const int *cams, int ncams, uint32_t w,
                        uint32_t h, depth_tally *t) {
  int c, skip;
  device_scene(dev, &l.s, l.tf, l.occ);
  for (c = 0; c < ncams; c++)
    for (skip = 0; skip < 2; skip++)
      depth_frame(&l, cams[c], skip, w, h, t);
  unlit(&l);
}

/* Scenes: a phantom and the blob (whose occupied box is inside the grid)
 * from every matrix camera; two more phantoms from outside, inside,
 * obliquely and along an axis, and from a camera that sees nothing. */
void depth_pass(void **state) {
  static const int five[] = {CAM_OUTSIDE, CAM_GRAZING, CAM_ZOOMED,
                             CAM_INSIDE, CAM_ORTHO};
  static const int four[] = {CAM_OUTSIDE, CAM_INSIDE, CAM_ORTHO, CAM_AWAY};
  static const int three[] = {CAM_OUTSIDE, CAM_INSIDE2, CAM_AXIS};
  depth_tally t = {0, 0};
  lit_scene blob = lit(blob_scene(), rp_test_preset(ctx, "minmax-soft"));
  (void)state;
  check_blob_box(&blob);
  depth_scene(lit(make_scene("phantom 64x50x40", RP_GEN_PHANTOM, 64, 50, 40,
                             RP_U8),
                  rp_test_preset(ctx, "minmax-soft")),
              five, 5, 61, 45, &t);
  depth_scene(blob, five, 5, 61, 45, &t);
  depth_scene(lit(make_scene("phantom 48x40x56", RP_GEN_PHANTOM, 48, 40, 56,
                             RP_U8),
                  rp_test_preset(ctx, "minmax-bone")),
              four, 4, 45, 38, &t);
  depth_scene(lit(make_scene("phantom 48^3", RP_GEN_PHANTOM, 48, 48, 48,
                             RP_U8),
                  rp_test_preset(ctx, "minmax-bone")),
              three, 3, 80, 64, &t);
  print_message("%s: depth pass: %llu of %llu rays off (rounding at block "
                "faces)\n", backend_name(), (unsigned long long)t.off_rays,
                (unsigned long long)t.rays);
  assert_true(t.off_rays * 1000 <= t.rays);
}

/* ---- ERT pre-pass -------------------------------------------------------- */

typedef struct ert_case {
  uint32_t w, h, effects;
  uint32_t frames;       /* frames 0 .. frames - 1 per camera */
  int thresholds;        /* 2: each camera at the default and at 0.5 */
  double finite_each;    /* share of rays that must terminate, per pass */
} ert_case;

typedef struct ert_tally {
  uint64_t rays, off, finite;
} ert_tally;

/* One pass of the device against rp__ert_prepass. */
static void ert_frame(const lit_scene *l, const rp_camera *cam,
                      const ert_case *k, float threshold, uint32_t seed,
                      uint32_t frame, ert_tally *t) {
  rp_render_desc d = {0};
  rp__raygen rg;
  uint32_t gw, gh, i, off = 0, finite = 0;
  float *got, *want;
  d.width = k->w, d.height = k->h, d.effects = k->effects;
  d.ert_threshold = threshold;
  raygen(&l->s, cam, &d, &rg);
  rp__ert_grid(rg.width, rg.height, &gw, &gh);
  got = malloc(sizeof(float) * gw * gh);
  want = malloc(sizeof(float) * gw * gh);
  assert_true(got != NULL && want != NULL);
  if (rp_device_ert_prepass(dev, cam, &d, seed, frame, got) != 0)
    fail_msg("%s: ERT pre-pass: %s", l->s.name, rp_last_error(ctx));
  rp__ert_prepass(&rg, rp_occupancy_grid(l->occ),
                  rp_occupancy_alpha_hist(l->occ), l->s.h->blocks,
                  rp_tf_reference_step(l->tf),
                  rp__render_desc_defaults(&d).ert_threshold, seed, frame,
                  want);
  for (i = 0; i < gw * gh; i++) {
    finite += isfinite(want[i]) != 0;
    if (got[i] == want[i] || fabsf(got[i] - want[i]) <= 1e-3f)
      continue;
    if (isinf(got[i]) || isinf(want[i]) ||
        fabsf(fabsf(got[i] - want[i]) - RP_ERT_COARSE_STEP) > 1e-2f)
      fail_msg("%s: ERT ray %u (seed %u frame %u): %g, reference %g",
               l->s.name, i, seed, frame, (double)got[i], (double)want[i]);
    off++;
  }
  if ((uint64_t)off * 1000 > (uint64_t)gw * gh)
    fail_msg("%s seed %u frame %u: %u of %u pre-pass rays one step off",
             l->s.name, seed, frame, off, gw * gh);
  /* The scene must terminate rays, or nothing was tested. */
  if ((double)finite < k->finite_each * gw * gh)
    fail_msg("%s seed %u frame %u: only %u of %u rays terminate",
             l->s.name, seed, frame, finite, gw * gh);
  t->rays += (uint64_t)gw * gh;
  t->off += off;
  t->finite += finite;
  free(got);
  free(want);
}

static void ert_scene(lit_scene l, const rp_camera *cams, int ncams,
                      const ert_case *k, ert_tally *t) {
  int c, th;
  uint32_t f;
  device_scene(dev, &l.s, l.tf, l.occ);
  for (c = 0; c < ncams; c++)
    for (f = 0; f < k->frames; f++)
      for (th = 0; th < k->thresholds; th++)
        ert_frame(&l, &cams[c], k, th ? 0.5f : 0.0f, 1234u + (uint32_t)c,
                  k->thresholds == 2 ? 7u : f, t);
  unlit(&l);
}

/* The balls of sparse_volume from outside, orthographically and from
 * between them, aimed so that most pre-pass rays terminate. */
static void ball_cameras(rp_camera cams[3]) {
  memset(cams, 0, 3 * sizeof cams[0]);
  cams[0].eye[0] = 20.0f, cams[0].eye[1] = 10.0f, cams[0].eye[2] = 160.0f;
  cams[0].center[0] = -33.5f, cams[0].center[1] = -21.5f;
  cams[0].center[2] = -17.5f;
  cams[0].fov_y_deg = 7.0f;
  cams[1] = cams[0];
  cams[1].projection = RP_ORTHOGRAPHIC;
  cams[1].center[0] = 28.5f, cams[1].center[1] = 20.5f;
  cams[1].center[2] = 18.5f;
  cams[1].ortho_height = 20.0f;
  cams[2].center[0] = 28.5f, cams[2].center[1] = 20.5f;
  cams[2].center[2] = 18.5f;
  cams[2].fov_y_deg = 20.0f;
}

/* A phantom and the blob from every matrix camera at both thresholds; a
 * phantom from outside, inside (threshold 0.5) and obliquely; the two
 * balls over three frames each, with most rays terminating. */
void ert_prepass(void **state) {
  static const ert_case matrix = {61, 45, RP_EFFECT_SKIP | RP_EFFECT_ERT,
                                  1, 2, 0.0};
  static const ert_case balls = {256, 192, RP_EFFECT_SKIP | RP_EFFECT_ERT,
                                 3, 1, 1.0 / 8};
  static const int kinds[] = {CAM_OUTSIDE, CAM_INSIDE, CAM_ORTHO};
  ert_tally t = {0, 0, 0}, phantom = {0, 0, 0};
  rp_camera cams[CAMERAS];
  lit_scene l;
  int c;
  (void)state;
  l = lit(make_scene("phantom 64x50x40", RP_GEN_PHANTOM, 64, 50, 40, RP_U8),
          rp_test_preset(ctx, "minmax-soft"));
  for (c = 0; c < CAMERAS; c++)
    cams[c] = camera(l.s.vol, c);
  ert_scene(l, cams, CAMERAS, &matrix, &t);
  l = lit(blob_scene(), rp_test_preset(ctx, "minmax-soft"));
  for (c = 0; c < CAMERAS; c++)
    cams[c] = camera(l.s.vol, c);
  ert_scene(l, cams, CAMERAS, &matrix, &t);
  /* Each camera a seed and frame of its own; inside, a threshold of
   * 0.5. */
  l = lit(make_scene("phantom 48^3", RP_GEN_PHANTOM, 48, 48, 48, RP_U8),
          rp_test_preset(ctx, "minmax-soft"));
  device_scene(dev, &l.s, l.tf, l.occ);
  for (c = 0; c < 3; c++) {
    static const ert_case one = {150, 97, RP_EFFECT_ERT, 1, 1, 0.0};
    rp_camera cam = camera(l.s.vol, kinds[c]);
    ert_frame(&l, &cam, &one, kinds[c] == CAM_INSIDE ? 0.5f : 0.0f,
              1234u + (uint32_t)c, 7u * (uint32_t)c, &phantom);
  }
  unlit(&l);
  assert_true(phantom.finite * 10 > phantom.rays);
  t.rays += phantom.rays, t.off += phantom.off;
  l = lit(scene_of("sparse u8", sparse_volume()), rp_test_ramp_tf(ctx, 1.0f));
  ball_cameras(cams);
  ert_scene(l, cams, 3, &balls, &t);
  print_message("%s: ERT pre-pass: %llu of %llu rays one step off\n",
                backend_name(), (unsigned long long)t.off,
                (unsigned long long)t.rays);
  assert_true(t.off * 1000 <= t.rays);
}

/* ---- regions ------------------------------------------------------------- */

/* Four tile-aligned quadrants split at (qx, qy), rendered apart into the
 * same buffers, equal one render of the whole image bit for bit (pixels,
 * tiles, fetches), and each call writes nothing outside its region:
 * what the quadrants not yet rendered hold is the fill. */
static void quadrants(const lit_scene *l, int cam_kind, uint32_t w,
                      uint32_t h, uint32_t qx, uint32_t qy) {
  rp_camera cam = camera(l->s.vol, cam_kind);
  rp_render_desc d = {0};
  uint32_t tx, ty, nt, q, x, y, k;
  uint8_t *whole = malloc((size_t)w * h * 4);
  uint8_t *parts = malloc((size_t)w * h * 4);
  rp_tile_stats *tw, *tp;
  uint64_t *fw, *fp;
  rp_tile_grid(w, h, &tx, &ty);
  nt = tx * ty;
  tw = malloc(nt * sizeof *tw), tp = malloc(nt * sizeof *tp);
  fw = malloc(nt * sizeof *fw), fp = malloc(nt * sizeof *fp);
  assert_true(whole && parts && tw && tp && fw && fp);
  d.width = w, d.height = h;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  device_scene(dev, &l->s, l->tf, l->occ);
  assert_int_equal(rp__device_render(dev, &cam, &d, NULL, whole, tw, fw), 0);
  memset(parts, 0xcd, (size_t)w * h * 4);
  memset(tp, 0xcd, nt * sizeof *tp);
  memset(fp, 0xcd, nt * sizeof *fp);
  for (q = 0; q < 4; q++) {
    rp_region r;
    r.x0 = (q & 1) ? qx : 0, r.x1 = (q & 1) ? w : qx;
    r.y0 = (q & 2) ? qy : 0, r.y1 = (q & 2) ? h : qy;
    if (rp__device_render(dev, &cam, &d, &r, parts, tp, fp) != 0)
      fail_msg("%s region %u: %s", l->s.name, q, rp_last_error(ctx));
    for (y = 0; y < h; y++)
      for (x = 0; x < w; x++) {
        uint32_t done = (uint32_t)((y >= qy) << 1 | (x >= qx)) <= q;
        const uint8_t *px = parts + 4 * ((size_t)y * w + x);
        if (!done && (px[0] != 0xcd || px[1] != 0xcd || px[2] != 0xcd ||
                      px[3] != 0xcd))
          fail_msg("%s: region %u wrote pixel (%u, %u) outside it",
                   l->s.name, q, x, y);
      }
    for (k = 0; k < nt; k++) {
      uint32_t x0 = (k % tx) * RP_TILE_SIZE, y0 = (k / tx) * RP_TILE_SIZE;
      uint32_t done = (uint32_t)((y0 >= qy) << 1 | (x0 >= qx)) <= q;
      const uint8_t *b = (const uint8_t *)&tp[k];
      if (!done && (b[0] != 0xcd || ((const uint8_t *)&fp[k])[0] != 0xcd))
        fail_msg("%s: region %u wrote tile %u outside it", l->s.name, q, k);
    }
  }
  assert_memory_equal(whole, parts, (size_t)w * h * 4);
  assert_memory_equal(tw, tp, nt * sizeof *tw);
  assert_memory_equal(fw, fp, nt * sizeof *fw);
  for (k = 0; k < nt; k++)
    assert_true(tw[k].rays_hit <= RP_TILE_SIZE * RP_TILE_SIZE);
  free(whole), free(parts), free(tw), free(tp), free(fw), free(fp);
}

/* Three scenes and cuts; then a region off the tile grid is refused. */
void regions_compose(void **state) {
  lit_scene l;
  rp_camera cam;
  rp_render_desc d = {0};
  rp_region bad = {3, 0, 16, 8};
  uint8_t px[37 * 29 * 4];
  (void)state;
  l = lit(make_scene("ML 41x37x29 u16", RP_GEN_MARSCHNER_LOBB, 41, 37, 29,
                     RP_U16),
          rp_test_preset(ctx, "minmax-bone"));
  quadrants(&l, CAM_ORTHO, 53, 37, 24, 16);
  unlit(&l);
  l = lit(make_scene("phantom 48^3", RP_GEN_PHANTOM, 48, 48, 48, RP_U8),
          rp_test_preset(ctx, "minmax-bone"));
  quadrants(&l, CAM_INSIDE2, 61, 45, 32, 24);
  unlit(&l);
  l = lit(make_scene("phantom 40^3", RP_GEN_PHANTOM, 40, 40, 40, RP_U8),
          rp_test_preset(ctx, "minmax-bone"));
  quadrants(&l, CAM_OUTSIDE, 37, 29, 16, 16);
  cam = camera(l.s.vol, CAM_OUTSIDE);
  d.width = 37, d.height = 29;
  assert_int_equal(rp_device_render(dev, &cam, &d, &bad, px, NULL),
                   RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "tile grid"));
  unlit(&l);
}

/* ---- fetch counts -------------------------------------------------------- */

/* Renders `effects` and the same with shading on, counting: both held to
 * the reference's fetches; shading changes colour, never opacity, so
 * the same samples are taken in every tile; unshaded, one fetch a
 * sample; shaded, more but under seven a sample: this view shows tissue
 * through transparent air inside occupied blocks, so some samples are
 * shaded and some not. What the extra fetches cost in time is
 * bench_backends' figure (medians), not a test's: on a shared machine
 * the order of two renders' times can flip (it did once, in CI). */
static void shading_pair(const lit_scene *l, uint32_t size, uint32_t effects,
                         tally *t) {
  rp_camera cam = camera(l->s.vol, CAM_OUTSIDE);
  rp_render_desc d = {0};
  uint32_t tx, ty, k;
  rp_tile_stats *tiles[2];
  uint64_t *fetches[2], f[2] = {0, 0}, samples = 0;
  int r;
  rp_tile_grid(size, size, &tx, &ty);
  for (r = 0; r < 2; r++) {
    tiles[r] = calloc((size_t)tx * ty, sizeof *tiles[r]);
    fetches[r] = calloc((size_t)tx * ty, sizeof *fetches[r]);
    assert_true(tiles[r] != NULL && fetches[r] != NULL);
    d.width = d.height = size;
    d.effects = effects | (r ? RP_EFFECT_SHADING : 0u);
    check_render_out(t, &l->s, l->tf, l->occ, NULL, &cam, &d,
                     r ? "shaded" : "unshaded", 1, NULL, tiles[r],
                     fetches[r]);
    for (k = 0; k < tx * ty; k++)
      f[r] += fetches[r][k];
  }
  for (k = 0; k < tx * ty; k++)
    samples += tiles[0][k].samples;
  assert_memory_equal(tiles[0], tiles[1], (size_t)tx * ty * sizeof *tiles[0]);
  assert_true(f[0] > 0 && f[0] == samples);
  assert_true(f[1] > f[0] && f[1] < 7 * f[0]);
  print_message("%s: %ux%u effects 0x%x: fetches %llu unshaded, %llu "
                "shaded\n", backend_name(), size, size, effects,
                (unsigned long long)f[0], (unsigned long long)f[1]);
  for (r = 0; r < 2; r++) {
    free(tiles[r]);
    free(fetches[r]);
  }
}

/* The counting variant's fetches are the reference's (one per sample,
 * six more per shaded sample with opacity above 0), for every effect set
 * but AO (occlusion.c counts AO's), and shading's pairs on two phantoms. */
void fetch_counts(void **state) {
  static const uint32_t sets[] = {
      0, RP_EFFECT_SHADING, RP_EFFECT_ERT, RP_EFFECT_SKIP,
      RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP};
  tally t = {0};
  rp_camera cam;
  lit_scene l;
  size_t e;
  (void)state;
  l = lit(make_scene("phantom 48^3", RP_GEN_PHANTOM, 48, 48, 48, RP_U8),
          rp_test_preset(ctx, "minmax-soft"));
  device_scene(dev, &l.s, l.tf, l.occ);
  cam = camera(l.s.vol, CAM_OUTSIDE);
  for (e = 0; e < sizeof sets / sizeof sets[0]; e++) {
    rp_render_desc d = {0};
    char what[64];
    d.width = d.height = 64;
    d.effects = sets[e];
    snprintf(what, sizeof what, "phantom 48^3 effects 0x%x", sets[e]);
    check_render(&t, &l.s, l.tf, l.occ, NULL, &cam, &d, what, 1);
  }
  shading_pair(&l, 160, 0, &t);
  unlit(&l);
  l = lit(make_scene("phantom 64^3", RP_GEN_PHANTOM, 64, 64, 64, RP_U8),
          rp_test_preset(ctx, "minmax-soft"));
  device_scene(dev, &l.s, l.tf, l.occ);
  shading_pair(&l, 96, RP_EFFECT_SKIP, &t);
  unlit(&l);
  finish(&t, "fetch counts", 0);
}
