/* What the conformance files share: scenes, cameras, the image and tile
 * comparison against the reference, and the backend driven without its
 * front end (conformance.h). */
#include "conformance.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const char *backend_name(void) {
  const char *b = getenv("RP_BACKEND");
  return b != NULL && b[0] != '\0' ? b : "reference";
}

/* ---- scenes -------------------------------------------------------------- */

scene scene_of(const char *name, rp_volume *vol) {
  scene s = {name, vol, NULL};
  assert_int_equal(rp_histograms_build(ctx, s.vol, &s.h), 0);
  return s;
}

scene make_scene(const char *name, rp_generator kind, uint32_t x,
                 uint32_t y, uint32_t z, rp_voxel_type type) {
  return scene_of(name, rp_test_generate(ctx, kind, x, y, z, type, 3));
}

void drop_scene(scene *s) {
  rp_histograms_destroy(s->h);
  rp_volume_destroy(s->vol);
  s->h = NULL;
  s->vol = NULL;
}

static rp_volume *volume_from(const uint32_t dims[3], rp_voxel_type type,
                              const float spacing[3], const void *data) {
  rp_volume_desc d = {{dims[0], dims[1], dims[2]}, type,
                      {spacing[0], spacing[1], spacing[2]}, data, {0}};
  rp_volume *vol = NULL;
  assert_int_equal(rp_volume_create(ctx, &d, &vol), 0);
  return vol;
}

rp_volume *sparse_volume(void) {
  static const uint32_t n[3] = {128, 112, 96};
  static const float sp[3] = {1.0f, 1.0f, 1.0f};
  uint8_t *data = calloc((size_t)n[0] * n[1] * n[2], 1);
  rp_volume *vol;
  uint32_t x, y, z;
  assert_non_null(data);
  for (z = 0; z < n[2]; z++)
    for (y = 0; y < n[1]; y++)
      for (x = 0; x < n[0]; x++) {
        double a = sqrt((x - 30.0) * (x - 30.0) + (y - 34.0) * (y - 34.0) +
                        (z - 30.0) * (z - 30.0)) - 11.0;
        double b = sqrt((x - 92.0) * (x - 92.0) + (y - 76.0) * (y - 76.0) +
                        (z - 66.0) * (z - 66.0)) - 9.0;
        double e = fmin(a, b), v = e < 0.0 ? 1.0 : 1.0 - e / 2.0;
        if (v > 0.0)
          data[((size_t)z * n[1] + y) * n[0] + x] =
              (uint8_t)(v * (200.0 + 55.0 * sin(0.3 * x + 0.2 * y)));
      }
  vol = volume_from(n, RP_U8, sp, data);
  free(data);
  return vol;
}

rp_volume *thin_volume(const uint32_t dims[3]) {
  static const float sp[3] = {1.0f, 0.5f, 2.0f};
  uint16_t data[19 * 7 * 3];
  size_t i, n = (size_t)dims[0] * dims[1] * dims[2];
  assert_true(n <= sizeof data / sizeof data[0]);
  for (i = 0; i < n; i++)
    data[i] = (uint16_t)(1000 + 7919 * i % 50000);
  return volume_from(dims, RP_U16, sp, data);
}

rp_tf *solid_tf(void) {
  rp_tf_point pts[2] = {{0.0f, 0.2f, 0.4f, 0.9f, 0.3f},
                        {1.0f, 0.9f, 0.5f, 0.1f, 0.5f}};
  rp_tf_desc d = {pts, 2, 2.0f, 0, 0, 0, 0, 0};
  rp_tf *tf = NULL;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), 0);
  return tf;
}

lit_scene lit(scene s, rp_tf *tf) {
  lit_scene l = {s, tf, NULL};
  assert_int_equal(rp_occupancy_build(ctx, s.h, tf, &l.occ), 0);
  return l;
}

void unlit(lit_scene *l) {
  rp_occupancy_destroy(l->occ);
  rp_tf_destroy(l->tf);
  drop_scene(&l->s);
  l->occ = NULL;
  l->tf = NULL;
}

void device_scene(rp_device *d, const scene *s, const rp_tf *tf,
                  const rp_occupancy *occ) {
  if (rp_device_set_volume(d, s->vol) != 0 ||
      rp_device_set_tf(d, tf, occ) != 0)
    fail_msg("%s: upload: %s", s->name, rp_last_error(ctx));
}

/* ---- cameras ------------------------------------------------------------- */

rp_camera camera(const rp_volume *vol, int kind) {
  rp_camera c = {0};
  switch (kind) {
  case CAM_OUTSIDE:
    rp_camera_orbit(&c, vol, 30, 20, 2.2f);
    break;
  case CAM_GRAZING:
    rp_camera_orbit(&c, vol, 90, 0, 1.6f);
    c.center[1] = c.eye[1] = 0.49f * (float)vol->dims[1] * vol->spacing[1];
    break;
  case CAM_ZOOMED:
    rp_camera_orbit(&c, vol, -40, 35, 2.0f);
    c.fov_y_deg = 9.0f;
    break;
  case CAM_INSIDE:
    rp_camera_orbit(&c, vol, 200, -15, 0.35f);
    c.fov_y_deg = 70.0f;
    break;
  case CAM_ORTHO:
    c.projection = RP_ORTHOGRAPHIC;
    rp_camera_orbit(&c, vol, 45, 35, 3.0f);
    break;
  case CAM_AXIS:
    c.projection = RP_ORTHOGRAPHIC;
    rp_camera_orbit(&c, vol, 90, 0, 3.0f);
    break;
  case CAM_INSIDE2:
    rp_camera_orbit(&c, vol, -40, 10, 0.35f);
    break;
  default: /* CAM_AWAY */
    rp_camera_orbit(&c, vol, 10, 5, 3.0f);
    c.center[0] = 2.0f * c.eye[0];
    c.center[1] = 2.0f * c.eye[1];
    c.center[2] = 2.0f * c.eye[2];
    break;
  }
  return c;
}

const char *camera_name(int kind) {
  static const char *const n[CAM_KINDS] = {
      "outside", "grazing", "zoomed", "inside", "ortho", "axis ortho",
      "inside 2", "away"};
  return n[kind];
}

/* ---- images -------------------------------------------------------------- */

/* A tile's rays: 8x8 but at the image's right and bottom edges. */
static uint32_t tile_rays(uint32_t k, uint32_t tx, uint32_t w, uint32_t h) {
  uint32_t x0 = (k % tx) * RP_TILE_SIZE, y0 = (k / tx) * RP_TILE_SIZE;
  return ((w - x0) < RP_TILE_SIZE ? w - x0 : RP_TILE_SIZE) *
         ((h - y0) < RP_TILE_SIZE ? h - y0 : RP_TILE_SIZE);
}

void compare(tally *t, const char *what, const uint8_t *got,
             const uint8_t *want, const rp_tile_stats *gt,
             const rp_tile_stats *wt, uint32_t w, uint32_t h, float step) {
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
    const rp_tile_stats *g = &gt[k], *r = &wt[k];
    int64_t d = (int64_t)g->samples - (int64_t)r->samples;
    if (llabs(d) > (int64_t)tile_rays(k, tx, w, h))
      fail_msg("%s: tile %u takes %u samples, reference %u (more than one "
               "per ray apart)", what, k, g->samples, r->samples);
    /* A ray grazing the box or a block corner may take a sample in one
     * and none in the other: a few per tile at most. */
    if (abs((int)g->rays_hit - (int)r->rays_hit) > 2)
      fail_msg("%s: tile %u has %u rays hit, reference %u", what, k,
               g->rays_hit, r->rays_hit);
    if (g->rays_hit == r->rays_hit && r->rays_hit > 0 &&
        fabs(g->mean_depth - r->mean_depth) >
            1e-3 * (1.0 + fabs(r->mean_depth)) + step)
      fail_msg("%s: tile %u mean depth %g, reference %g", what, k,
               (double)g->mean_depth, (double)r->mean_depth);
    t->compared_tiles++;
  }
}

void finish(const tally *t, const char *name, int quiet) {
  if (!quiet)
    print_message("%s on %s: %llu pixels, %llu over 2/255 (%.4f %%), "
                  "worst %d/255 at %s\n", backend_name(), name,
                  (unsigned long long)t->pixels,
                  (unsigned long long)t->over2,
                  100.0 * (double)t->over2 / (double)t->pixels, t->worst,
                  t->worst ? t->worst_at : "-");
  if (!quiet && t->fetches > 0)
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
  uint32_t w, h, tiles;
  uint8_t *got, *want;
  rp_tile_stats *gt, *wt;
  uint64_t *fetches, *want_fetches;
} frame;

static void frame_alloc(frame *f, uint32_t w, uint32_t h) {
  uint32_t tx, ty;
  rp_tile_grid(w, h, &tx, &ty);
  f->w = w, f->h = h, f->tiles = tx * ty;
  f->got = calloc((size_t)w * h, 4);
  f->want = calloc((size_t)w * h, 4);
  f->gt = calloc(f->tiles, sizeof *f->gt);
  f->wt = calloc(f->tiles, sizeof *f->wt);
  f->fetches = calloc(f->tiles, sizeof *f->fetches);
  f->want_fetches = calloc(f->tiles, sizeof *f->want_fetches);
  assert_true(f->got && f->want && f->gt && f->wt && f->fetches &&
              f->want_fetches);
}

static void frame_free(frame *f) {
  free(f->got), free(f->want), free(f->gt), free(f->wt), free(f->fetches);
  free(f->want_fetches);
}

/* The reference's image, tiles and fetches per tile: what
 * rp_render_reference does, through the internal entry that also
 * counts. */
static void reference(const scene *s, const rp_tf *tf,
                      const rp_occupancy *occ, const rp_ao *ao,
                      const rp_camera *cam, const rp_render_desc *desc,
                      frame *f) {
  rp_render_desc d = rp__render_desc_defaults(desc);
  rp__raygen rg;
  rp_region all = {0, 0, 0, 0};
  rp_volume ao_view;
  assert_int_equal(rp__raygen_init(ctx, cam, s->vol, d.width, d.height, &rg),
                   0);
  rp_scaled_size(&d, &rg.width, &rg.height);
  all.x1 = rg.width;
  all.y1 = rg.height;
  if (ao != NULL)
    rp__ao_view(ao, &ao_view);
  rp__reference_render(s->vol, tf,
                       (d.effects & RP_EFFECT_SKIP) ? occ->grid : NULL,
                       s->h->blocks, ao != NULL ? &ao_view : NULL, &rg, &d,
                       &all, f->want, f->wt, f->want_fetches);
}

void check_render(tally *t, const scene *s, const rp_tf *tf,
                  const rp_occupancy *occ, const rp_ao *ao,
                  const rp_camera *cam, const rp_render_desc *d,
                  const char *what, int count_fetches) {
  check_render_out(t, s, tf, occ, ao, cam, d, what, count_fetches, NULL,
                   NULL, NULL);
}

void check_render_out(tally *t, const scene *s, const rp_tf *tf,
                      const rp_occupancy *occ, const rp_ao *ao,
                      const rp_camera *cam, const rp_render_desc *d,
                      const char *what, int count_fetches, uint8_t *rgba,
                      rp_tile_stats *tiles, uint64_t *fetches) {
  frame f;
  uint32_t sw, sh;
  rp_scaled_size(d, &sw, &sh);
  frame_alloc(&f, sw, sh);
  reference(s, tf, occ, ao, cam, d, &f);
  if (rp__device_render(dev, cam, d, NULL, f.got, f.gt,
                        count_fetches ? f.fetches : NULL) != 0)
    fail_msg("%s: %s: %s", what, backend_name(), rp_last_error(ctx));
  compare(t, what, f.got, f.want, f.gt, f.wt, sw, sh,
          rp__render_desc_defaults(d).step);
  if (count_fetches)
    rp_test_check_fetches(what, f.gt, f.fetches, f.wt, f.want_fetches,
                          f.tiles, d->effects,
                          &t->fetches, &t->fetches_off);
  if (rgba != NULL)
    memcpy(rgba, f.got, (size_t)sw * sh * 4);
  if (tiles != NULL)
    memcpy(tiles, f.gt, f.tiles * sizeof *tiles);
  if (fetches != NULL)
    memcpy(fetches, f.fetches, f.tiles * sizeof *fetches);
  frame_free(&f);
}

void check_image(const scene *s, const rp_tf *tf, const rp_occupancy *occ,
                 const rp_camera *cam, const rp_render_desc *d,
                 const char *what) {
  tally t = {0};
  check_render(&t, s, tf, occ, NULL, cam, d, what, 0);
  finish(&t, what, 1);
}

/* ---- the backend without its front end ----------------------------------- */

int bare_open(rp_context *c, bare *b) {
  int err = rp__backend_open(c, backend_name(), 0, &b->ops, &b->impl,
                             &b->caps);
  if (err != 0 && err != RP_EUNSUPPORTED)
    fail_msg("opening %s bare: %s", backend_name(), rp_last_error(c));
  return err;
}

void bare_close(bare *b) {
  b->ops->destroy(b->impl);
  b->impl = NULL;
}

void bare_upload(const bare *b, const scene *s, const rp_tf *tf,
                 const rp_occupancy *occ) {
  int n = 0;
  const float *lut = rp_tf_lut(tf, &n);
  if (b->ops->upload_volume(b->impl, s->vol) != 0 ||
      b->ops->upload_tf(b->impl, lut, (uint32_t)n) != 0 ||
      b->ops->upload_occupancy(b->impl, rp_occupancy_grid(occ),
                               rp_occupancy_alpha_hist(occ),
                               s->h->blocks) != 0)
    fail_msg("%s: bare upload: %s", s->name, rp_last_error(ctx));
}

void bare_frame(const scene *s, const rp_tf *tf, const rp_occupancy *occ,
                const rp_camera *cam, rp_render_desc *d, rp__raygen *rg,
                rp_frame_params *p) {
  int n = 0;
  double span[2];
  rp_tf_lut(tf, &n);
  rp__tf_volume_range(tf, s->vol, span);
  *d = rp__render_desc_defaults(d);
  assert_int_equal(rp__frame_params(ctx, s->vol, occ, cam, d,
                                    rp_tf_reference_step(tf), (uint32_t)n,
                                    span, rg, p),
                   0);
}

void bare_render(const bare *b, const rp_frame_params *p, uint8_t *rgba,
                 rp_tile_stats *tiles, uint64_t *fetches) {
  rp_region all = {0, 0, p->width, p->height};
  if (b->ops->depth_pass(b->impl, p, NULL) != 0 ||
      b->ops->raycast(b->impl, p, &all, rgba, tiles, fetches) != 0)
    fail_msg("bare render: %s", rp_last_error(ctx));
}

int variant_stats(const bare *b, rp_variant_stats *st) {
  memset(st, 0, sizeof *st);
#ifdef RP_WITH_OPENCL
  if (strcmp(b->caps.backend, "opencl") == 0) {
    rp_cl__variant_stats(b->impl, st);
    return 1;
  }
#endif
#ifdef RP_WITH_VULKAN
  if (strcmp(b->caps.backend, "vulkan") == 0) {
    rp_vk__variant_stats(b->impl, st);
    return 1;
  }
#endif
  (void)b;
  return 0;
}
