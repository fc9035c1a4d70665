/* Ambient occlusion: the AO volume a device computes (compute_ao)
 * against the reference's (rp_ao_compute_reference), renders that read
 * an AO volume (RP_EFFECT_AO) against the reference's, and the backend's
 * refusal to read an AO volume it does not hold. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "conformance.h"

/* ---- the AO volume ------------------------------------------------------- */

typedef struct ao_case {
  const char *what;
  rp_ao_desc desc;     /* `unbricked` is set per run */
  int ways;            /* runs (bits): 1, unbricked; 2, bricked */
  int dark;            /* clearly occluded voxels the reference must have
                          (bits): 1, over 1 % below 192; 2, over 2 %
                          below 224, and bricks to skip when bricked */
  int skips;           /* bricked: some voxels, not all, are skipped */
  size_t boxes;        /* how many of ao_boxes to compute */
} ao_case;

/* Boxes of the whole volume, clamped to it: unaligned, one voxel thick,
 * a single voxel; then for the first scene only (a 40x37x33 one), the far
 * corner and nearly the whole. (A box computed in slabs is Vulkan's own:
 * test_vk_backend.c.) */
static const uint32_t ao_boxes[][6] = {
    {5, 3, 7, 29, 30, 26},   {13, 0, 1, 14, 37, 2}, {0, 0, 0, 1, 1, 1},
    {5, 3, 7, 31, 30, 20},   {39, 36, 32, 40, 37, 33},
    {13, 0, 2, 14, 37, 3},   {1, 2, 3, 40, 37, 33}};
#define AO_BOXES_ALL 3

/* The device's AO of box [lo, end) into a new buffer, checking that it
 * writes no byte past the box. */
static uint8_t *device_ao(const rp_ao_plan *plan, const uint32_t lo[3],
                          const uint32_t end[3], const char *what) {
  size_t n = (size_t)(end[0] - lo[0]) * (end[1] - lo[1]) * (end[2] - lo[2]);
  uint8_t *out = malloc(n + 1);
  assert_non_null(out);
  memset(out, 0xcd, n + 1);
  if (rp_device_compute_ao(dev, plan, lo, end, out) != 0)
    fail_msg("%s: compute_ao: %s", what, rp_last_error(ctx));
  assert_int_equal(out[n], 0xcd);
  assert_true(rp_device_last_time_ns(dev) > 0);
  return out;
}

/* Whole-volume AO against the reference by the tolerance, the voxels of
 * empty bricks 255 on both sides, then every box equal to the same
 * voxels of the whole, bit for bit. */
static void ao_run(const lit_scene *l, const ao_case *k,
                   const rp_ao_desc *desc, const char *what) {
  const uint32_t zero[3] = {0, 0, 0}, *dims = l->s.vol->dims;
  size_t n = l->s.vol->voxel_count, i, over2 = 0, dark192 = 0, dark224 = 0;
  size_t skipped = 0, b;
  rp_ao *ref = NULL;
  rp_ao_plan *plan = NULL;
  uint64_t full, total;
  const uint8_t *want;
  uint8_t *got;
  int worst = 0;
  if (rp_ao_compute_reference(ctx, l->s.vol, l->tf, desc, NULL, NULL,
                              &ref) != 0 ||
      rp_ao_plan_create(ctx, l->s.vol, l->tf, desc, &plan) != 0)
    fail_msg("%s: %s", what, rp_last_error(ctx));
  assert_int_equal(!desc->unbricked, plan->bricks != NULL);
  rp_ao_bricks(ref, &full, &total);
  /* Unbricked computes every brick; bricked has some to skip in the
   * scenes with air. */
  if (desc->unbricked)
    assert_true(full == total);
  else if (k->dark & 2)
    assert_true(full < total);
  want = rp_ao_data(ref, NULL);
  got = device_ao(plan, zero, dims, what);
  for (i = 0; i < n; i++) {
    int d = abs((int)got[i] - (int)want[i]);
    over2 += d > 2;
    worst = d > worst ? d : worst;
    dark192 += want[i] < 192;
    dark224 += want[i] < 224;
  }
  if (plan->bricks != NULL) {
    const uint32_t *g = plan->brick_grid;
    uint32_t x, y, z;
    for (z = 0; z < dims[2]; z++)
      for (y = 0; y < dims[1]; y++)
        for (x = 0; x < dims[0]; x++) {
          size_t v = ((size_t)z * dims[1] + y) * dims[0] + x;
          if (plan->bricks[((size_t)(z / 4) * g[1] + y / 4) * g[0] +
                           x / 4])
            continue;
          /* A voxel of an empty brick is 255 exactly, never sampled. */
          assert_int_equal(got[v], 255);
          assert_int_equal(want[v], 255);
          skipped++;
        }
    if (k->skips)
      assert_true(skipped > 0 && skipped < n);
  }
  print_message("%s: %zu voxels, %zu below 192, %zu skipped, worst %d/255, "
                "%zu over 2/255\n", what, n, dark192, skipped, worst, over2);
  if (worst > 8 || over2 * 1000 > n)
    fail_msg("%s: worst %d/255, %zu of %zu voxels over 2/255", what, worst,
             over2, n);
  /* Occlusion there is, or the tolerance passed a volume of 255s. */
  if (k->dark & 1)
    assert_true(dark192 * 100 > n);
  if (k->dark & 2)
    assert_true(dark224 * 50 > n);
  for (b = 0; b < k->boxes; b++) {
    uint32_t lo[3], end[3], x, y, z, a;
    uint8_t *part;
    for (a = 0; a < 3; a++) {
      lo[a] = ao_boxes[b][a] < dims[a] ? ao_boxes[b][a] : dims[a] - 1;
      end[a] = ao_boxes[b][3 + a] < dims[a] ? ao_boxes[b][3 + a] : dims[a];
      if (end[a] <= lo[a])
        end[a] = lo[a] + 1;
    }
    part = device_ao(plan, lo, end, what);
    for (z = lo[2]; z < end[2]; z++)
      for (y = lo[1]; y < end[1]; y++)
        for (x = lo[0]; x < end[0]; x++) {
          uint8_t pv = part[((size_t)(z - lo[2]) * (end[1] - lo[1]) +
                             (y - lo[1])) * (end[0] - lo[0]) + (x - lo[0])];
          uint8_t wv = got[((size_t)z * dims[1] + y) * dims[0] + x];
          if (pv != wv)
            fail_msg("%s box %zu: voxel (%u, %u, %u) is %u, %u in the "
                     "whole volume", what, b, x, y, z, pv, wv);
        }
    free(part);
  }
  free(got);
  rp_ao_plan_destroy(plan);
  rp_ao_destroy(ref);
}

static void ao_scene(lit_scene l, const ao_case *k) {
  int bricked;
  char what[160];
  device_scene(dev, &l.s, l.tf, l.occ);
  for (bricked = 0; bricked < 2; bricked++) {
    rp_ao_desc desc = k->desc;
    if (!(k->ways & (1 << bricked)))
      continue;
    desc.unbricked = !bricked;
    snprintf(what, sizeof what, "%s AO %s", k->what,
             bricked ? "bricked" : "unbricked");
    ao_run(&l, k, &desc, what);
  }
  unlit(&l);
}

/* compute_ao against the reference, bricked and unbricked, on odd sizes,
 * every voxel type (each computed both ways), a desc off the defaults
 * (every input of the job reaches the kernel), an alpha corrected from a
 * reference step of 2, and volumes thinner than a brick. */
void ao_volume(void **state) {
  static const uint32_t thin[2][3] = {{19, 1, 2}, {1, 7, 3}};
  const rp_ao_desc odd = {7, 5, 6.0f, 0.5f, 0};
  ao_case k;
  int v;
  (void)state;
  memset(&k, 0, sizeof k);
  k.what = "phantom u8 40x37x33", k.ways = 3, k.dark = 3, k.skips = 1;
  k.boxes = sizeof ao_boxes / sizeof ao_boxes[0];
  ao_scene(lit(make_scene(k.what, RP_GEN_PHANTOM, 40, 37, 33, RP_U8),
               rp_test_preset(ctx, "minmax-bone")),
           &k);
  k.what = "phantom u16 39x34x37", k.ways = 2, k.dark = 2;
  k.boxes = AO_BOXES_ALL;
  ao_scene(lit(make_scene(k.what, RP_GEN_PHANTOM, 39, 34, 37, RP_U16),
               rp_test_preset(ctx, "minmax-soft")),
           &k);
  k.what = "Marschner-Lobb u16 23x30x19", k.desc = odd, k.ways = 1;
  k.dark = 1, k.skips = 0;
  ao_scene(lit(make_scene(k.what, RP_GEN_MARSCHNER_LOBB, 23, 30, 19,
                          RP_U16),
               rp_test_preset(ctx, "mri")),
           &k);
  k.what = "float blob", k.ways = 2, k.skips = 1;
  ao_scene(lit(scene_of(k.what, rp_test_float_blob(ctx)),
               rp_test_preset(ctx, "minmax-soft")),
           &k);
  memset(&k, 0, sizeof k);
  k.what = "float32 ramp", k.ways = 1, k.boxes = AO_BOXES_ALL;
  ao_scene(lit(scene_of(k.what, rp_test_float_field(ctx)),
               rp_test_ramp_tf(ctx, 2.0f)),
           &k);
  for (v = 0; v < 2; v++) {
    k.what = "thin volume", k.ways = 3;
    ao_scene(lit(scene_of(k.what, thin_volume(thin[v])), solid_tf()), &k);
  }
}

/* ---- renders reading it -------------------------------------------------- */

/* Pixels more than 8/255 apart in any channel, and pixels with alpha
 * over 8/255. */
static uint32_t pixels_apart(const uint8_t *a, const uint8_t *b, size_t px) {
  uint32_t n = 0;
  size_t i;
  int c;
  for (i = 0; i < px; i++)
    for (c = 0; c < 4; c++)
      if (abs((int)a[4 * i + c] - (int)b[4 * i + c]) > 8) {
        n++;
        break;
      }
  return n;
}

static uint32_t pixels_seen(const uint8_t *a, size_t px) {
  uint32_t n = 0;
  size_t i;
  for (i = 0; i < px; i++)
    n += a[4 * i + 3] > 8;
  return n;
}

/* Share of lit pixels whose colour differs by more than 8/255. */
static double changed_share(const uint8_t *a, const uint8_t *b, size_t px) {
  size_t i, lit_px = 0, changed = 0;
  for (i = 0; i < px; i++) {
    int c, m = 0;
    if (a[4 * i + 3] == 0 && b[4 * i + 3] == 0)
      continue;
    lit_px++;
    for (c = 0; c < 3; c++) {
      int dd = abs((int)a[4 * i + c] - (int)b[4 * i + c]);
      m = dd > m ? dd : m;
    }
    changed += m > 8;
  }
  return lit_px > 0 ? (double)changed / (double)lit_px : 0.0;
}

/* One frame with AO and the same without, each held to the reference
 * (images, tiles, fetches: one more per visible sample with AO); then
 * AO must show, and only darken: alpha, samples and every tile as they
 * are without it, no colour channel brighter. */
static void ao_frame(const lit_scene *l, const rp_ao *ao, int cam_kind,
                     uint32_t w, uint32_t h, float step, uint32_t effects,
                     tally *t) {
  rp_camera cam = camera(l->s.vol, cam_kind);
  rp_render_desc d = {0};
  size_t px = (size_t)w * h, i;
  uint32_t tx, ty, apart, seen;
  uint8_t *with = malloc(px * 4), *without = malloc(px * 4);
  rp_tile_stats *tw, *to;
  char what[160];
  double share;
  rp_tile_grid(w, h, &tx, &ty);
  tw = malloc((size_t)tx * ty * sizeof *tw);
  to = malloc((size_t)tx * ty * sizeof *to);
  assert_true(with && without && tw && to);
  d.width = w, d.height = h, d.step = step, d.effects = effects;
  snprintf(what, sizeof what, "%s AO effects 0x%x camera %s", l->s.name,
           effects, camera_name(cam_kind));
  check_render_out(t, &l->s, l->tf, l->occ, ao, &cam, &d, what, 1, with, tw,
                   NULL);
  d.effects &= ~(uint32_t)RP_EFFECT_AO;
  check_render_out(t, &l->s, l->tf, l->occ, NULL, &cam, &d, what, 1,
                   without, to, NULL);
  apart = pixels_apart(with, without, px);
  seen = pixels_seen(without, px);
  share = changed_share(with, without, px);
  print_message("%s: %u of %u visible pixels darkened, %.1f %% of lit "
                "pixels changed\n", what, apart, seen, 100.0 * share);
  /* An AO ignored would leave the image as it is without. */
  if ((seen > 0 && apart * 10 < seen) || share < 0.2)
    fail_msg("%s: AO changed only %u of %u visible pixels (%.1f %% of lit "
             "ones)", what, apart, seen, 100.0 * share);
  for (i = 0; i < px * 4; i++)
    if (i % 4 == 3 ? with[i] != without[i] : with[i] > without[i] + 1)
      fail_msg("%s: byte %zu is %u, %u without AO", what, i, with[i],
               without[i]);
  assert_memory_equal(tw, to, (size_t)tx * ty * sizeof *tw);
  free(with), free(without), free(tw), free(to);
}

/* RP_EFFECT_AO renders with the reference's AO volume on both sides, so
 * that differences are the raycast's: AO alone, with shading, with every
 * effect, with skipping; three scenes, from outside, inside and
 * obliquely (at a step of its own). Released, the device holds no AO
 * memory and refuses an AO render. */
void ao_render(void **state) {
  static const uint32_t sets[] = {
      RP_EFFECT_AO, RP_EFFECT_AO | RP_EFFECT_SHADING,
      RP_EFFECT_AO | RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP,
      RP_EFFECT_AO | RP_EFFECT_SKIP};
  static const struct {
    int cam;
    uint32_t w, h;
    float step;
  } views[] = {{CAM_OUTSIDE, 61, 45, 0.0f}, {CAM_INSIDE, 61, 45, 0.0f},
               {CAM_ORTHO, 61, 45, 0.6f},   {CAM_OUTSIDE, 64, 56, 0.0f},
               {CAM_INSIDE2, 64, 56, 0.0f}};
  tally t = {0};
  int g;
  size_t e, v;
  (void)state;
  for (g = 0; g < 3; g++) {
    lit_scene l =
        g == 0 ? lit(make_scene("phantom u8 minmax-soft", RP_GEN_PHANTOM, 40, 37,
                                33, RP_U8),
                     rp_test_preset(ctx, "minmax-soft"))
        : g == 1 ? lit(make_scene("phantom u8 minmax-bone", RP_GEN_PHANTOM, 40,
                                  37, 33, RP_U8),
                       rp_test_preset(ctx, "minmax-bone"))
                 : lit(make_scene("phantom u16 minmax-soft", RP_GEN_PHANTOM, 39,
                                  34, 37, RP_U16),
                       rp_test_preset(ctx, "minmax-soft"));
    rp_ao *ao = NULL;
    assert_int_equal(rp_ao_compute_reference(ctx, l.s.vol, l.tf, NULL, NULL,
                                             NULL, &ao),
                     0);
    device_scene(dev, &l.s, l.tf, l.occ);
    assert_int_equal(rp_device_set_ao(dev, ao), 0);
    assert_true(rp_device_ao_bytes(dev) >= l.s.vol->voxel_count);
    for (v = 0; v < sizeof views / sizeof views[0]; v++) {
      /* The first scene from the first three views, the others from the
       * last two. */
      if ((g == 0) != (v < 3))
        continue;
      for (e = 0; e < sizeof sets / sizeof sets[0]; e++)
        ao_frame(&l, ao, views[v].cam, views[v].w, views[v].h,
                 views[v].step, sets[e], &t);
    }
    if (g == 2) {
      rp_camera cam = camera(l.s.vol, CAM_OUTSIDE);
      rp_render_desc d = {0};
      uint8_t img[16 * 16 * 4];
      assert_int_equal(rp_device_set_ao(dev, NULL), 0);
      assert_int_equal(rp_device_ao_bytes(dev), 0);
      d.width = 16, d.height = 16, d.effects = RP_EFFECT_AO;
      assert_int_equal(rp_device_render(dev, &cam, &d, NULL, img, NULL),
                       RP_ESTATE);
    }
    assert_int_equal(rp_device_set_ao(dev, NULL), 0);
    rp_ao_destroy(ao);
    unlit(&l);
  }
  finish(&t, "AO renders", 0);
}

/* ---- the backend's own guard --------------------------------------------- */

/* The backend itself refuses to read an AO volume it does not hold (the
 * front end checks first, but a slip must not read a missing buffer):
 * none before a volume; a raycast with RP_EFFECT_AO before one is
 * uploaded, after it is released, and after a volume of another shape
 * replaced the one it was for; one of the same shape keeps it. Without
 * AO the same frames need none, and render right. */
void ao_state(void **state) {
  bare b;
  lit_scene l, other;
  rp_render_desc d = {0};
  rp__raygen rg;
  rp_frame_params p;
  rp_region all;
  rp_camera cam;
  uint8_t *ao, *rgba, *want;
  rp_tile_stats *tiles, *wt;
  uint32_t tx, ty;
  tally t = {0};
  uint8_t one = 128;
  (void)state;
  if (bare_open(ctx, &b) == RP_EUNSUPPORTED) {
    print_message("%s: %s: skipped (the front end's own AO checks are in "
                  "ao_render)\n", backend_name(), rp_last_error(ctx));
    skip();
  }
  assert_int_equal(b.ops->upload_ao(b.impl, &one), RP_ESTATE);
  assert_int_equal(b.ops->upload_ao(b.impl, NULL), 0);
  l = lit(make_scene("phantom 24x20x18", RP_GEN_PHANTOM, 24, 20, 18, RP_U8),
          rp_test_preset(ctx, "minmax-bone"));
  bare_upload(&b, &l.s, l.tf, l.occ);
  cam = camera(l.s.vol, CAM_OUTSIDE);
  d.width = d.height = 24;
  d.effects = RP_EFFECT_AO | RP_EFFECT_SHADING;
  bare_frame(&l.s, l.tf, l.occ, &cam, &d, &rg, &p);
  all.x0 = all.y0 = 0, all.x1 = p.width, all.y1 = p.height;
  rp_tile_grid(p.width, p.height, &tx, &ty);
  ao = malloc(l.s.vol->voxel_count);
  rgba = malloc((size_t)p.width * p.height * 4);
  want = malloc((size_t)p.width * p.height * 4);
  tiles = malloc((size_t)tx * ty * sizeof *tiles);
  wt = malloc((size_t)tx * ty * sizeof *wt);
  assert_true(ao && rgba && want && tiles && wt);
  memset(ao, 200, l.s.vol->voxel_count);
  assert_int_equal(b.ops->depth_pass(b.impl, &p, NULL), 0);
  assert_int_equal(b.ops->raycast(b.impl, &p, &all, rgba, tiles, NULL),
                   RP_ESTATE);
  assert_non_null(strstr(rp_last_error(ctx), "AO"));
  assert_int_equal(b.ops->upload_ao(b.impl, ao), 0);
  assert_int_equal(b.ops->raycast(b.impl, &p, &all, rgba, tiles, NULL), 0);
  /* Uploaded again, over the one it holds. */
  assert_int_equal(b.ops->upload_ao(b.impl, ao), 0);
  assert_int_equal(b.ops->raycast(b.impl, &p, &all, rgba, tiles, NULL), 0);
  assert_int_equal(b.ops->upload_ao(b.impl, NULL), 0);
  assert_int_equal(b.ops->raycast(b.impl, &p, &all, rgba, tiles, NULL),
                   RP_ESTATE);
  /* Without AO the same frame needs none, and is right. */
  p.effects &= ~(uint32_t)RP_EFFECT_AO;
  d.effects = p.effects;
  assert_int_equal(b.ops->raycast(b.impl, &p, &all, rgba, tiles, NULL), 0);
  rp__reference_render(l.s.vol, l.tf, NULL, l.s.h->blocks, NULL, &rg, &d,
                       &all, want, wt, NULL);
  compare(&t, "after AO released", rgba, want, tiles, wt, p.width, p.height,
          p.step);
  finish(&t, "after AO released", 1);
  /* A volume of the same shape keeps the AO volume; another drops it. */
  p.effects |= RP_EFFECT_AO;
  assert_int_equal(b.ops->upload_ao(b.impl, ao), 0);
  assert_int_equal(b.ops->upload_volume(b.impl, l.s.vol), 0);
  assert_int_equal(b.ops->raycast(b.impl, &p, &all, rgba, tiles, NULL), 0);
  other = lit(make_scene("phantom 25x20x18", RP_GEN_PHANTOM, 25, 20, 18,
                         RP_U8),
              rp_test_preset(ctx, "minmax-bone"));
  bare_upload(&b, &other.s, other.tf, other.occ);
  d.effects = RP_EFFECT_AO | RP_EFFECT_SHADING;
  bare_frame(&other.s, other.tf, other.occ, &cam, &d, &rg, &p);
  assert_int_equal(b.ops->depth_pass(b.impl, &p, NULL), 0);
  assert_int_equal(b.ops->raycast(b.impl, &p, &all, rgba, tiles, NULL),
                   RP_ESTATE);
  free(ao), free(rgba), free(want), free(tiles), free(wt);
  unlit(&other);
  unlit(&l);
  bare_close(&b);
}
