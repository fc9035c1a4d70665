/* Out-of-core volumes (DESIGN section 9, runtime/bricks.h): the bricks'
 * layout against the volume, the bricks a region needs against the
 * samples its rays take, the pool's LRU against a brute-force model, and
 * images rendered through a pool of an eighth of the volume against the
 * same device holding the whole volume: equal byte for byte, tile stats
 * and fetch counts included, for every effect set, camera and backend
 * present. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bricks.h"
#include "raypace_ao.h"
#include "passes.h"
#include "raygen.h"
#include "test_util.h"

static rp_context *ctx;

typedef struct scene {
  rp_volume *vol;
  rp_histograms *h;
  rp_tf *tf;
  rp_occupancy *occ;
} scene;

static scene make_scene(rp_generator kind, uint32_t x, uint32_t y,
                        uint32_t z, rp_voxel_type type, const char *tf) {
  scene s = {0};
  rp_generate_desc g = {0};
  g.kind = kind, g.dims[0] = x, g.dims[1] = y, g.dims[2] = z;
  g.type = type, g.seed = 5;
  assert_int_equal(rp_volume_generate(ctx, &g, &s.vol), 0);
  assert_int_equal(rp_histograms_build(ctx, s.vol, &s.h), 0);
  s.tf = rp_test_preset(ctx, tf);
  assert_int_equal(rp_occupancy_build(ctx, s.h, s.tf, &s.occ), 0);
  return s;
}

static void set_tf(scene *s, const char *tf) {
  rp_occupancy_destroy(s->occ);
  rp_tf_destroy(s->tf);
  s->tf = rp_test_preset(ctx, tf);
  assert_int_equal(rp_occupancy_build(ctx, s->h, s->tf, &s->occ), 0);
}

static void drop_scene(scene *s) {
  rp_occupancy_destroy(s->occ);
  rp_tf_destroy(s->tf);
  rp_histograms_destroy(s->h);
  rp_volume_destroy(s->vol);
}

static size_t volume_bytes(const rp_volume *v) {
  return (size_t)v->dims[0] * v->dims[1] * v->dims[2] *
         rp__voxel_size(v->type);
}

/* Cameras: outside (perspective), inside the volume, orthographic, and
 * a close one that sees a corner. */
static rp_camera camera(const rp_volume *vol, int kind) {
  rp_camera c = {0};
  if (kind == 0) {
    rp_camera_orbit(&c, vol, 30, 20, 2.2f);
  } else if (kind == 1) {
    rp_camera_orbit(&c, vol, 200, -15, 0.35f);
    c.fov_y_deg = 70.0f;
  } else if (kind == 2) {
    /* Zoomed in enough that a tile's beam fits an eighth of the volume
     * (test_errors has one that does not fit). */
    double dx = vol->dims[0] * vol->spacing[0];
    double dy = vol->dims[1] * vol->spacing[1];
    double dz = vol->dims[2] * vol->spacing[2];
    c.projection = RP_ORTHOGRAPHIC;
    c.ortho_height = (float)(0.4 * sqrt(dx * dx + dy * dy + dz * dz));
    rp_camera_orbit(&c, vol, 45, 35, 3.0f);
  } else {
    rp_camera_orbit(&c, vol, 120, 40, 0.9f);
    c.fov_y_deg = 30.0f;
  }
  return c;
}

/* ---- layout ---------------------------------------------------------------- */

static double stored_voxel(const rp__bricks *b, uint32_t id, size_t i,
                           rp_voxel_type type) {
  const void *v = rp__bricks_voxels(b, id);
  return type == RP_U8    ? ((const uint8_t *)v)[i]
         : type == RP_U16 ? ((const uint16_t *)v)[i]
                          : ((const float *)v)[i];
}

/* Every stored voxel is the volume's voxel at its position clamped to the
 * volume (the border past the end replicates the edge). */
static void check_layout(rp_voxel_type type, uint32_t x, uint32_t y,
                         uint32_t z, uint32_t size) {
  scene s = make_scene(RP_GEN_PHANTOM, x, y, z, type, "minmax-soft");
  rp__bricks *b = NULL;
  rp__bricks_info info;
  uint32_t bx, by, bz, i, j, k, st = size + 1;
  assert_int_equal(rp__bricks_create(ctx, s.vol, size, 4, &b), 0);
  rp__bricks_get_info(b, &info);
  assert_int_equal(info.grid[0], (x + size - 1) / size);
  assert_int_equal(info.grid[1], (y + size - 1) / size);
  assert_int_equal(info.grid[2], (z + size - 1) / size);
  for (bz = 0; bz < info.grid[2]; bz++)
    for (by = 0; by < info.grid[1]; by++)
      for (bx = 0; bx < info.grid[0]; bx++) {
        uint32_t id = (bz * info.grid[1] + by) * info.grid[0] + bx;
        for (k = 0; k < st; k++)
          for (j = 0; j < st; j++)
            for (i = 0; i < st; i++) {
              uint32_t vx = bx * size + i, vy = by * size + j;
              uint32_t vz = bz * size + k;
              vx = vx < x ? vx : x - 1;
              vy = vy < y ? vy : y - 1;
              vz = vz < z ? vz : z - 1;
              if (stored_voxel(b, id, ((size_t)k * st + j) * st + i, type) !=
                  rp__voxel(s.vol, vx, vy, vz))
                fail_msg("brick (%u,%u,%u) voxel (%u,%u,%u) differs", bx, by,
                         bz, i, j, k);
            }
      }
  rp__bricks_destroy(b);
  drop_scene(&s);
}

static void test_layout(void **state) {
  (void)state;
  check_layout(RP_U8, 37, 21, 19, 8);
  check_layout(RP_U16, 16, 17, 1, 8);
  check_layout(RP_U8, 1, 1, 9, 8);
}

/* ---- needed bricks against the samples -------------------------------------- */

/* The brick of the cell a sample at voxel-space p reads, as the kernels
 * find it: clamp to [0, dims - 1], floor, low corner at most dims - 2. */
static uint32_t brick_of(const rp_volume *vol, const rp__bricks_info *info,
                         const double p[3]) {
  uint32_t c[3];
  int a;
  for (a = 0; a < 3; a++) {
    double d = vol->dims[a], q = p[a] < 0.0 ? 0.0 : p[a];
    uint32_t lom = vol->dims[a] > 1 ? vol->dims[a] - 2 : 0, i;
    q = q > d - 1.0 ? d - 1.0 : q;
    i = (uint32_t)q;
    i = i < lom ? i : lom;
    c[a] = i / info->brick_size;
  }
  return (c[2] * info->grid[1] + c[1]) * info->grid[0] + c[0];
}

static int in_list(const uint32_t *list, uint32_t n, uint32_t id) {
  uint32_t i;
  for (i = 0; i < n; i++)
    if (list[i] == id)
      return 1;
  return 0;
}

/* Marches every ray of `r` in double at step 0.5 and checks that each
 * sample in a visible brick found its brick (and, with shading, the
 * bricks of its six gradient reads) in the needed list. Returns the
 * visible samples seen. */
static uint64_t check_cover(const scene *s, rp__bricks *b, const rp_camera *c,
                            uint32_t w, uint32_t h, const rp_region *r,
                            int shading) {
  rp__raygen rg;
  rp__bricks_info info;
  uint32_t x, y, n;
  uint64_t seen = 0;
  const uint32_t *need;
  assert_int_equal(rp__raygen_init(ctx, c, s->vol, w, h, &rg), 0);
  rp__bricks_get_info(b, &info);
  rp__bricks_frame(b, &rg, shading);
  n = rp__bricks_needed(b, r);
  need = rp__bricks_need_list(b);
  for (y = r->y0; y < r->y1; y++)
    for (x = r->x0; x < r->x1; x++) {
      rp__ray ray;
      double t;
      rp__raygen_ray(&rg, x, y, &ray);
      if (!ray.hit)
        continue;
      for (t = ray.s; t <= ray.t1; t += 0.5) {
        double p[3];
        uint32_t id;
        int a;
        for (a = 0; a < 3; a++)
          p[a] = ray.p0[a] + t * ray.dp[a];
        id = brick_of(s->vol, &info, p);
        if (!rp__bricks_visible(b, id))
          continue;
        seen++;
        if (!in_list(need, n, id))
          fail_msg("pixel (%u,%u): sample at (%g,%g,%g) reads brick %u, "
                   "which the region does not list", x, y, p[0], p[1], p[2],
                   id);
        for (a = 0; a < 3 && shading; a++) {
          double q[3] = {p[0], p[1], p[2]};
          int sgn;
          for (sgn = -1; sgn <= 1; sgn += 2) {
            q[a] = p[a] + sgn;
            if (!in_list(need, n, brick_of(s->vol, &info, q)))
              fail_msg("pixel (%u,%u): gradient read at (%g,%g,%g) misses "
                       "its brick", x, y, q[0], q[1], q[2]);
          }
        }
      }
    }
  return seen;
}

static void test_needed_covers_samples(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 45, 38, 29, RP_U8, "minmax-soft");
  rp__bricks *b = NULL;
  rp_region whole = {0, 0, 48, 40}, quarter = {24, 0, 48, 24};
  rp_region strip = {8, 16, 16, 40};
  int kind, shading;
  uint32_t all_need, quarter_need;
  (void)state;
  assert_int_equal(rp__bricks_create(ctx, s.vol, 8, 8, &b), 0);
  rp__bricks_set_tf(b, s.tf);
  for (kind = 0; kind < 4; kind++)
    for (shading = 0; shading <= 1; shading++) {
      rp_camera c = camera(s.vol, kind);
      uint64_t seen = check_cover(&s, b, &c, 48, 40, &whole, shading);
      all_need = rp__bricks_needed(b, &whole);
      check_cover(&s, b, &c, 48, 40, &quarter, shading);
      quarter_need = rp__bricks_needed(b, &quarter);
      check_cover(&s, b, &c, 48, 40, &strip, shading);
      /* The footprints cull: a quarter of the image from outside needs
       * fewer bricks than the whole (inside, every brick straddling the
       * eye plane is needed everywhere). */
      if (kind == 0 || kind == 2)
        assert_true(quarter_need < all_need);
      assert_true(seen > 0 || kind == 3);
    }
  rp__bricks_destroy(b);
  drop_scene(&s);
}

/* ---- the pool's LRU against a brute-force model ------------------------------ */

/* The model: per brick its slot (0: not resident) and the request it was
 * last used in. A miss takes the lowest free slot, else evicts the
 * resident brick last used longest ago (ties: the lowest slot) among
 * those the request does not use. */
typedef struct lru_model {
  uint32_t slot[64];
  uint64_t used[64];
  uint32_t slots;
  uint64_t hits, misses, evictions;
} lru_model;

static void model_request(lru_model *m, const uint32_t *ids, uint32_t n,
                          uint64_t now) {
  uint32_t i, id;
  for (i = 0; i < n; i++)
    if (m->slot[ids[i]] != 0) {
      m->used[ids[i]] = now;
      m->hits++;
    }
  for (i = 0; i < n; i++) {
    uint32_t s, best = 64, free_slot = 0;
    if (m->slot[ids[i]] != 0) /* a hit, counted above */
      continue;
    /* Lowest slot no brick holds. */
    for (s = 1; s < m->slots && free_slot == 0; s++) {
      int taken = 0;
      for (id = 0; id < 64; id++)
        taken |= m->slot[id] == s;
      if (!taken)
        free_slot = s;
    }
    if (free_slot == 0) {
      for (id = 0; id < 64; id++) {
        if (m->slot[id] == 0 || m->used[id] == now)
          continue;
        if (best == 64 || m->used[id] < m->used[best] ||
            (m->used[id] == m->used[best] && m->slot[id] < m->slot[best]))
          best = id;
      }
      assert_true(best < 64);
      free_slot = m->slot[best];
      m->slot[best] = 0;
      m->evictions++;
    }
    m->slot[ids[i]] = free_slot;
    m->used[ids[i]] = now;
    m->misses++;
  }
}

static void test_lru_matches_model(void **state) {
  /* 4 x 4 x 4 bricks of 8 voxels: 64 bricks, 9 slots (8 for bricks). */
  scene s = make_scene(RP_GEN_PHANTOM, 32, 32, 32, RP_U8, "opaque");
  rp__bricks *b = NULL;
  rp__bricks_info info;
  lru_model m;
  uint64_t rng = 12345;
  int step;
  (void)state;
  memset(&m, 0, sizeof m);
  m.slots = 9;
  assert_int_equal(rp__bricks_create(ctx, s.vol, 8, 9, &b), 0);
  rp__bricks_set_tf(b, s.tf);
  for (step = 1; step <= 400; step++) {
    uint32_t ids[8], n, i, j;
    /* Requests of 1..8 distinct bricks, drawn from a window that drifts
     * so that some repeat (hits) and some are new (misses, evictions). */
    rng = rng * 6364136223846793005ull + 1442695040888963407ull;
    n = 1 + (uint32_t)(rng >> 61);
    for (i = 0; i < n; i++) {
      uint32_t id;
      int dup;
      do {
        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
        id = ((uint32_t)(rng >> 40) % 12 + (uint32_t)step / 10) % 64;
        dup = 0;
        for (j = 0; j < i; j++)
          dup |= ids[j] == id;
      } while (dup);
      ids[i] = id;
    }
    rp__bricks_set_needed(b, ids, n);
    rp__bricks_admit(b);
    model_request(&m, ids, n, (uint64_t)step);
    rp__bricks_get_info(b, &info);
    assert_int_equal(info.hits, m.hits);
    assert_int_equal(info.misses, m.misses);
    assert_int_equal(info.evictions, m.evictions);
    /* Every brick of the request is where the model put it, and what is
     * to upload is exactly the misses. */
    for (i = 0; i < n; i++)
      assert_int_equal(rp__bricks_table(b)[ids[i]], m.slot[ids[i]]);
  }
  assert_true(m.hits > 100 && m.evictions > 100);
  rp__bricks_destroy(b);
  drop_scene(&s);
}

/* ---- images: out of core equals in core -------------------------------------- */

typedef struct pair {
  rp_device *whole, *bricked;
} pair;

/* Two devices of one backend: one holding the whole volume, one with a
 * budget of `fraction` of it in bricks of `size`. 0 when the backend has
 * no device here. */
static int open_pair(const char *backend, const scene *s, double fraction,
                     uint32_t size, pair *p) {
  rp_device_desc d = {0};
  rp_brick_stats st;
  if (!rp_test_has_device(backend))
    return 0;
  d.backend = backend;
  assert_int_equal(rp_device_create(ctx, &d, &p->whole), 0);
  d.budget_bytes = (uint64_t)(fraction * (double)volume_bytes(s->vol));
  d.brick_size = size;
  assert_int_equal(rp_device_create(ctx, &d, &p->bricked), 0);
  if (rp_device_set_volume(p->whole, s->vol) != 0 ||
      rp_device_set_volume(p->bricked, s->vol) != 0 ||
      rp_device_set_tf(p->whole, s->tf, s->occ) != 0 ||
      rp_device_set_tf(p->bricked, s->tf, s->occ) != 0)
    fail_msg("%s: %s", backend, rp_last_error(ctx));
  assert_int_equal(rp_device_get_brick_stats(p->bricked, &st), 0);
  assert_int_equal(st.out_of_core, 1);
  assert_int_equal(rp_device_get_brick_stats(p->whole, &st), 0);
  assert_int_equal(st.out_of_core, 0);
  return 1;
}

static void close_pair(pair *p) {
  rp_device_destroy(p->whole);
  rp_device_destroy(p->bricked);
}

/* Renders with both and holds the images, tiles and fetch counts equal.
 * Returns the pieces the bricked render was cut into. */
static uint32_t check_same(const char *what, pair *p, const rp_camera *c,
                           const rp_render_desc *d) {
  uint32_t w, h, tw, th, i;
  uint8_t *a, *b;
  rp_tile_stats *ta, *tb;
  uint64_t *fa, *fb;
  rp_brick_stats st;
  rp_upload_estimate est;
  rp_scaled_size(d, &w, &h);
  tw = (w + 7) / 8, th = (h + 7) / 8;
  a = calloc((size_t)w * h, 4), b = calloc((size_t)w * h, 4);
  ta = calloc((size_t)tw * th, sizeof *ta);
  tb = calloc((size_t)tw * th, sizeof *tb);
  fa = calloc((size_t)tw * th, sizeof *fa);
  fb = calloc((size_t)tw * th, sizeof *fb);
  assert_true(a && b && ta && tb && fa && fb);
  if (rp_device_upload_estimate(p->bricked, c, d, NULL, &est) != 0 ||
      rp__device_render(p->whole, c, d, NULL, a, ta, fa) != 0 ||
      rp__device_render(p->bricked, c, d, NULL, b, tb, fb) != 0)
    fail_msg("%s: %s", what, rp_last_error(ctx));
  /* The estimate follows the render's plan: the bytes it said. */
  assert_int_equal(rp_device_get_brick_stats(p->bricked, &st), 0);
  if (est.bytes != st.last_upload_bytes)
    fail_msg("%s: estimated %llu bytes to upload, the render uploaded %llu",
             what, (unsigned long long)est.bytes,
             (unsigned long long)st.last_upload_bytes);
  for (i = 0; i < w * h * 4; i++)
    if (a[i] != b[i])
      fail_msg("%s: pixel (%u,%u) channel %u: %u in core, %u out of core",
               what, i / 4 % w, i / 4 / w, i % 4, a[i], b[i]);
  for (i = 0; i < tw * th; i++) {
    assert_int_equal(ta[i].samples, tb[i].samples);
    assert_int_equal(ta[i].rays_hit, tb[i].rays_hit);
    assert_true(ta[i].mean_depth == tb[i].mean_depth);
    if (fa[i] != fb[i])
      fail_msg("%s: tile %u: %llu fetches in core, %llu out of core", what,
               i, (unsigned long long)fa[i], (unsigned long long)fb[i]);
  }
  assert_int_equal(rp_device_get_brick_stats(p->bricked, &st), 0);
  free(a), free(b), free(ta), free(tb), free(fa), free(fb);
  return st.last_pieces;
}

static const uint32_t effect_sets[] = {
    0, RP_EFFECT_SHADING, RP_EFFECT_ERT | RP_EFFECT_SKIP,
    RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP};

static void check_backend_images(const char *backend) {
  static const struct {
    rp_generator kind;
    uint32_t x, y, z;
    rp_voxel_type type;
    uint32_t brick;
  } vols[] = {{RP_GEN_PHANTOM, 128, 128, 128, RP_U8, 8},
              {RP_GEN_PHANTOM, 101, 90, 77, RP_U16, 8},
              {RP_GEN_MARSCHNER_LOBB, 96, 96, 96, RP_U8, 8}};
  size_t v;
  int ran = 0;
  for (v = 0; v < sizeof vols / sizeof vols[0]; v++) {
    scene s = make_scene(vols[v].kind, vols[v].x, vols[v].y, vols[v].z,
                         vols[v].type, "minmax-soft");
    pair p;
    uint32_t most = 0;
    size_t e;
    int kind;
    if (!open_pair(backend, &s, 0.125, vols[v].brick, &p)) {
      drop_scene(&s);
      break;
    }
    ran = 1;
    for (kind = 0; kind < 4; kind++)
      for (e = 0; e < sizeof effect_sets / sizeof effect_sets[0]; e++) {
        rp_render_desc d = {0};
        rp_camera c = camera(s.vol, kind);
        char what[128];
        uint32_t pieces;
        d.width = 170, d.height = 130, d.effects = effect_sets[e];
        d.step = kind == 3 ? 0.37f : 1.0f;
        snprintf(what, sizeof what, "%s volume %zu camera %d effects 0x%x",
                 backend, v, kind, (unsigned)d.effects);
        pieces = check_same(what, &p, &c, &d);
        most = pieces > most ? pieces : most;
      }
    /* An eighth of the volume cannot hold what the outside view needs:
     * the cut into parts was exercised. */
    assert_true(most > 1);
    /* A new TF: other bricks are visible, slot 0 holds another value. */
    set_tf(&s, "minmax-bone");
    if (rp_device_set_tf(p.whole, s.tf, s.occ) != 0 ||
        rp_device_set_tf(p.bricked, s.tf, s.occ) != 0)
      fail_msg("%s: %s", backend, rp_last_error(ctx));
    for (e = 0; e < sizeof effect_sets / sizeof effect_sets[0]; e++) {
      rp_render_desc d = {0};
      rp_camera c = camera(s.vol, 0);
      d.width = 190, d.height = 150, d.effects = effect_sets[e];
      d.image_scale = 0.9f;
      check_same("after a TF change", &p, &c, &d);
    }
    close_pair(&p);
    drop_scene(&s);
  }
  if (!ran)
    printf("# %s: no device here; skipped\n", backend);
}

/* Small images of a small volume: one tile's rays need more bricks than
 * an eighth of the volume holds, so tiles are cast in depth slabs. */
static void check_backend_slabs(const char *backend) {
  scene s = make_scene(RP_GEN_PHANTOM, 64, 64, 64, RP_U8, "minmax-soft");
  pair p;
  uint32_t slabs = 0;
  size_t e;
  int kind;
  if (!open_pair(backend, &s, 0.125, 8, &p)) {
    drop_scene(&s);
    return;
  }
  for (kind = 0; kind < 4; kind++)
    for (e = 0; e < sizeof effect_sets / sizeof effect_sets[0]; e++) {
      rp_render_desc d = {0};
      rp_camera c = camera(s.vol, kind);
      rp_brick_stats st;
      char what[128];
      d.width = 61, d.height = 47, d.effects = effect_sets[e];
      snprintf(what, sizeof what, "%s slabs camera %d effects 0x%x",
               backend, kind, (unsigned)d.effects);
      check_same(what, &p, &c, &d);
      assert_int_equal(rp_device_get_brick_stats(p.bricked, &st), 0);
      slabs += st.last_slabs;
    }
  assert_true(slabs > 0);
  /* Extreme steps on an axis-aligned view, in slabs: a ray finished in
   * one slab still computes an (unused) sample position in the next, and
   * where a direction component is exactly 0 (the middle row and column
   * of an odd-sized image) that position must stay finite at any step. */
  {
    static const float steps[] = {0.05f, 4.0f, 16.0f};
    uint32_t axis_slabs = 0;
    size_t k;
    for (k = 0; k < sizeof steps / sizeof steps[0]; k++)
      for (e = 0; e < sizeof effect_sets / sizeof effect_sets[0]; e++) {
        rp_render_desc d = {0};
        rp_camera c = {0};
        rp_brick_stats st;
        char what[128];
        rp_camera_orbit(&c, s.vol, 0, 0, 0.9f);
        c.fov_y_deg = 30.0f;
        d.width = 61, d.height = 47, d.effects = effect_sets[e];
        d.step = steps[k];
        snprintf(what, sizeof what, "%s axis-aligned step %g effects 0x%x",
                 backend, (double)steps[k], (unsigned)d.effects);
        check_same(what, &p, &c, &d);
        assert_int_equal(rp_device_get_brick_stats(p.bricked, &st), 0);
        axis_slabs += st.last_slabs;
      }
    assert_true(axis_slabs > 0);
  }
  close_pair(&p);
  drop_scene(&s);
}

static void test_images_opencl(void **state) {
  (void)state;
  check_backend_images("opencl");
  check_backend_slabs("opencl");
}

static void test_images_vulkan(void **state) {
  (void)state;
  check_backend_images("vulkan");
  check_backend_slabs("vulkan");
}

/* The second frame of a camera that fits the pool in one part uploads
 * nothing; a camera elsewhere misses and evicts; the counters add up. */
static void test_camera_path_counts(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 64, 64, 64, RP_U8, "minmax-soft");
  pair p;
  rp_brick_stats st0, st1, st2, st3;
  rp_render_desc d = {0};
  rp_camera near = camera(s.vol, 3), away;
  uint8_t *img;
  (void)state;
  if (!open_pair("opencl", &s, 0.5, 8, &p)) {
    drop_scene(&s);
    skip();
  }
  d.width = 32, d.height = 32;
  img = calloc(32 * 32, 4);
  assert_non_null(img);
  away = near;
  rp_camera_orbit(&away, s.vol, 300, -40, 0.9f);
  away.fov_y_deg = 30.0f;
  if (rp_device_render(p.bricked, &near, &d, NULL, img, NULL) != 0)
    fail_msg("%s", rp_last_error(ctx));
  assert_int_equal(rp_device_get_brick_stats(p.bricked, &st0), 0);
  assert_int_equal(st0.last_pieces, 1);
  assert_int_equal(st0.hits, 0);
  assert_true(st0.misses > 0);
  assert_int_equal(st0.evictions, 0);
  assert_int_equal(st0.uploaded_bytes,
                   st0.misses * rp__bricks_stored_bytes(8, RP_U8));
  assert_int_equal(rp_device_render(p.bricked, &near, &d, NULL, img, NULL), 0);
  assert_int_equal(rp_device_get_brick_stats(p.bricked, &st1), 0);
  assert_int_equal(st1.misses, st0.misses);
  assert_int_equal(st1.hits, st0.misses);
  assert_int_equal(st1.last_upload_bytes, 0);
  assert_int_equal(rp_device_render(p.bricked, &away, &d, NULL, img, NULL), 0);
  assert_int_equal(rp_device_get_brick_stats(p.bricked, &st2), 0);
  assert_true(st2.misses > st1.misses);
  assert_int_equal(st2.resident, st2.misses - st2.evictions);
  assert_true(st2.resident <= st2.slots - 1);
  /* Back: what the other view evicted comes back, nothing else. */
  assert_int_equal(rp_device_render(p.bricked, &near, &d, NULL, img, NULL), 0);
  assert_int_equal(rp_device_get_brick_stats(p.bricked, &st3), 0);
  assert_int_equal(st3.hits + st3.misses - st2.hits - st2.misses,
                   st0.misses);
  assert_int_equal(st3.misses - st2.misses, st3.evictions - st2.evictions +
                   (st3.resident - st2.resident));
  free(img);
  close_pair(&p);
  drop_scene(&s);
}

/* ---- errors ------------------------------------------------------------------ */

static void test_errors(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 64, 64, 64, RP_U8, "opaque");
  rp_device_desc d = {0};
  rp_device *dev = NULL;
  rp_render_desc rd = {0};
  rp_camera c = camera(s.vol, 0);
  uint8_t img[16 * 16 * 4];
  (void)state;
  d.backend = "reference";
  d.budget_bytes = 1000;
  assert_int_equal(rp_device_create(ctx, &d, &dev), RP_EUNSUPPORTED);
  assert_non_null(strstr(rp_last_error(ctx), "budget"));
  d.budget_bytes = 0;
  d.brick_size = 12;
  assert_int_equal(rp_device_create(ctx, &d, &dev), RP_ERANGE);
  d.brick_size = 512;
  assert_int_equal(rp_device_create(ctx, &d, &dev), RP_ERANGE);
  if (!rp_test_has_device("opencl")) {
    drop_scene(&s);
    skip();
  }
  d.backend = "opencl";
  d.brick_size = 16;
  /* Less than two bricks: refused at the volume, nothing changed. */
  d.budget_bytes = rp__bricks_stored_bytes(16, RP_U8) + 1;
  assert_int_equal(rp_device_create(ctx, &d, &dev), 0);
  assert_int_equal(rp_device_set_volume(dev, s.vol), RP_ENOMEM);
  assert_non_null(strstr(rp_last_error(ctx), "at least 2"));
  rp_device_destroy(dev);
  /* Two slots: an opaque volume needs more than one brick behind any
   * tile, so the render fails with the pixels it could not fit, and the
   * device still works for a view that fits. */
  d.budget_bytes = 2 * rp__bricks_stored_bytes(16, RP_U8);
  assert_int_equal(rp_device_create(ctx, &d, &dev), 0);
  assert_int_equal(rp_device_set_volume(dev, s.vol), 0);
  assert_int_equal(rp_device_set_tf(dev, s.tf, s.occ), 0);
  rd.width = 16, rd.height = 16;
  assert_int_equal(rp_device_render(dev, &c, &rd, NULL, img, NULL),
                   RP_ENOMEM);
  assert_non_null(strstr(rp_last_error(ctx), "need"));
  /* AO needs the whole volume. */
  rd.effects = RP_EFFECT_AO;
  assert_int_equal(rp_device_render(dev, &c, &rd, NULL, img, NULL),
                   RP_EUNSUPPORTED);
  assert_non_null(strstr(rp_last_error(ctx), "out of core"));
  assert_int_equal(rp_device_set_ao(dev, NULL), 0);
  rp_device_destroy(dev);
  drop_scene(&s);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_layout),
      cmocka_unit_test(test_needed_covers_samples),
      cmocka_unit_test(test_lru_matches_model),
      cmocka_unit_test(test_images_opencl),
      cmocka_unit_test(test_images_vulkan),
      cmocka_unit_test(test_camera_path_counts),
      cmocka_unit_test(test_errors),
  };
  int rc;
  ctx = rp_test_context();
  rc = cmocka_run_group_tests(tests, NULL, NULL);
  rp_context_destroy(ctx);
  return rc;
}
