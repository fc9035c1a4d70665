/* The Vulkan backend, driven directly through rp_vk_bootstrap and its ops
 * (no front end), against the scalar C reference: runtime/reference.c for
 * images and tiles, depth.c for the depth pass, ert.c for the ERT
 * pre-pass. Frame parameters are built from a camera with the reference's
 * own raygen, the way runtime/backend.c builds them.
 *
 * Tolerances are the contract's (backends/README.md): images within 2/255
 * on >= 99.9 % of pixels and none over 8/255, tile samples within one per
 * ray, ERT terminations equal except one coarse step on <= 0.1 % of rays.
 *
 * Exits 77 (skipped) when no Vulkan device is present. */
#include "test_util.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "ao.h"
#include "passes.h"
#include "raypace_ao.h"
#include "vk_internal.h"

static rp_context *g_ctx;
static const rp_backend_ops *g_ops;
static void *g_impl;
static rp_caps g_caps;

/* ---- scenes and frames --------------------------------------------------- */

typedef struct scene {
  rp_volume *vol;
  rp_tf *tf;
  rp_histograms *h;
  rp_occupancy *occ;
} scene;

static rp_volume *generate(rp_generator kind, uint32_t nx, uint32_t ny,
                           uint32_t nz, rp_voxel_type type) {
  rp_generate_desc d = {kind, {nx, ny, nz}, type, 11};
  rp_volume *vol = NULL;
  assert_int_equal(rp_volume_generate(g_ctx, &d, &vol), 0);
  return vol;
}

/* A smooth float field with negative values and anisotropic spacing: two
 * blobs of opposite sign over a gentle slope. */
static rp_volume *float_volume(void) {
  const uint32_t nx = 37, ny = 30, nz = 26;
  rp_volume_desc d = {{nx, ny, nz}, RP_F32, {1.0f, 1.5f, 0.8f}, NULL};
  float *data = malloc(sizeof(float) * nx * ny * nz);
  rp_volume *vol = NULL;
  uint32_t x, y, z;
  assert_non_null(data);
  for (z = 0; z < nz; z++)
    for (y = 0; y < ny; y++)
      for (x = 0; x < nx; x++) {
        double a = (x - 12.0) * (x - 12.0) + (y - 14.0) * (y - 14.0) +
                   (z - 12.0) * (z - 12.0);
        double b = (x - 25.0) * (x - 25.0) + (y - 16.0) * (y - 16.0) +
                   (z - 14.0) * (z - 14.0);
        data[((size_t)z * ny + y) * nx + x] =
            (float)(3.0 * exp(-a / 40.0) - 2.0 * exp(-b / 25.0) +
                    0.01 * x - 0.5);
      }
  d.data = data;
  assert_int_equal(rp_volume_create(g_ctx, &d, &vol), 0);
  free(data);
  return vol;
}

/* Two dense balls in air, far apart in a volume of 8x7x6 blocks: most
 * blocks are empty (even after the occupancy's one-block dilation), and
 * there is an empty run between the balls. */
static rp_volume *sparse_volume(void) {
  const uint32_t nx = 128, ny = 112, nz = 96;
  rp_volume_desc d = {{nx, ny, nz}, RP_U8, {1.0f, 1.0f, 1.0f}, NULL};
  uint8_t *data = calloc((size_t)nx * ny * nz, 1);
  rp_volume *vol = NULL;
  uint32_t x, y, z;
  assert_non_null(data);
  for (z = 0; z < nz; z++)
    for (y = 0; y < ny; y++)
      for (x = 0; x < nx; x++) {
        double a = sqrt((x - 30.0) * (x - 30.0) + (y - 34.0) * (y - 34.0) +
                        (z - 30.0) * (z - 30.0)) - 11.0;
        double b = sqrt((x - 92.0) * (x - 92.0) + (y - 76.0) * (y - 76.0) +
                        (z - 66.0) * (z - 66.0)) - 9.0;
        double e = fmin(a, b), v = e < 0.0 ? 1.0 : 1.0 - e / 2.0;
        if (v > 0.0)
          data[((size_t)z * ny + y) * nx + x] =
              (uint8_t)(v * (200.0 + 55.0 * sin(0.3 * x + 0.2 * y)));
      }
  d.data = data;
  assert_int_equal(rp_volume_create(g_ctx, &d, &vol), 0);
  free(data);
  return vol;
}

/* Half-transparent ramp whose alpha is given per `ref_step` voxels, so a
 * step other than ref_step exercises the opacity correction. */
static rp_tf *ramp_tf(float ref_step) {
  rp_tf_point pts[4] = {{0.0f, 0.1f, 0.2f, 0.9f, 0.0f},
                        {0.35f, 0.9f, 0.6f, 0.1f, 0.0f},
                        {0.6f, 1.0f, 0.9f, 0.3f, 0.25f},
                        {1.0f, 0.9f, 0.1f, 0.1f, 0.6f}};
  rp_tf_desc d = {pts, 4, ref_step, 256};
  rp_tf *tf = NULL;
  assert_int_equal(rp_tf_create(g_ctx, &d, &tf), 0);
  return tf;
}

/* Partly opaque everywhere, reference step 2. */
static rp_tf *solid_tf(void) {
  rp_tf_point pts[2] = {{0.0f, 0.2f, 0.4f, 0.9f, 0.3f},
                        {1.0f, 0.9f, 0.5f, 0.1f, 0.5f}};
  rp_tf_desc d = {pts, 2, 2.0f, 0};
  rp_tf *tf = NULL;
  assert_int_equal(rp_tf_create(g_ctx, &d, &tf), 0);
  return tf;
}

/* A uint16 volume of at most 19 x 7 x 3 voxels with anisotropic spacing
 * and values spread over the range: the thin and tiny cases. */
static rp_volume *thin_volume(const uint32_t dims[3]) {
  uint16_t data[19 * 7 * 3];
  rp_volume_desc d = {
      {dims[0], dims[1], dims[2]}, RP_U16, {1.0f, 0.5f, 2.0f}, data};
  rp_volume *vol = NULL;
  size_t i, n = (size_t)dims[0] * dims[1] * dims[2];
  assert_true(n <= sizeof data / sizeof data[0]);
  for (i = 0; i < n; i++)
    data[i] = (uint16_t)(1000 + 7919 * i % 50000);
  assert_int_equal(rp_volume_create(g_ctx, &d, &vol), 0);
  return vol;
}

static void scene_init(scene *s, rp_volume *vol, rp_tf *tf) {
  s->vol = vol;
  s->tf = tf;
  assert_int_equal(rp_histograms_build(g_ctx, vol, &s->h), 0);
  assert_int_equal(rp_occupancy_build(g_ctx, s->h, tf, &s->occ), 0);
}

/* Uploads the scene to `impl` (g_impl when NULL). */
static void scene_upload(const scene *s, void *impl) {
  int lut_size = 0;
  const float *lut = rp_tf_lut(s->tf, &lut_size);
  if (impl == NULL)
    impl = g_impl;
  assert_int_equal(g_ops->upload_volume(impl, s->vol), 0);
  assert_int_equal(g_ops->upload_tf(impl, lut, (uint32_t)lut_size), 0);
  assert_int_equal(g_ops->upload_occupancy(impl, s->occ->grid,
                                           s->occ->alpha_hist,
                                           s->h->blocks),
                   0);
}

static void scene_free(scene *s) {
  rp_occupancy_destroy(s->occ);
  rp_histograms_destroy(s->h);
  rp_tf_destroy(s->tf);
  rp_volume_destroy(s->vol);
  memset(s, 0, sizeof *s);
}

typedef struct frame {
  rp__raygen rg;     /* resolved for the output, sized to the scaled image */
  rp_render_desc d;  /* defaults resolved */
  rp_frame_params p;
} frame;

typedef struct frame_desc {
  uint32_t width, height;
  float scale, step;
  uint32_t effects;
} frame_desc;

/* The frame parameters of runtime/backend.c, from the reference's raygen:
 * the double basis rounded to float, the frustum of the output image, the
 * rays of the scaled one. */
static void frame_init(const scene *s, const rp_camera *cam,
                       const frame_desc *fd, frame *f) {
  rp_render_desc d = {0};
  int lut_size = 0;
  d.width = fd->width;
  d.height = fd->height;
  d.step = fd->step;
  d.effects = fd->effects;
  d.image_scale = fd->scale;
  f->d = rp__render_desc_defaults(&d);
  rp_tf_lut(s->tf, &lut_size);
  assert_int_equal(rp__frame_params(g_ctx, s->vol, s->occ, cam, &f->d,
                                    rp_tf_reference_step(s->tf),
                                    (uint32_t)lut_size, &f->rg, &f->p),
                   0);
}

static size_t tile_count(const frame *f) {
  uint32_t tx, ty;
  rp_tile_grid(f->p.width, f->p.height, &tx, &ty);
  return (size_t)tx * ty;
}

/* The front end's order: the depth pass, then the raycast. */
static void vk_render(void *impl, const frame *f, const rp_region *r,
                      uint8_t *rgba, rp_tile_stats *tiles,
                      uint64_t *fetches) {
  rp_region all = {0, 0, f->p.width, f->p.height};
  if (impl == NULL)
    impl = g_impl;
  assert_int_equal(g_ops->depth_pass(impl, &f->p, NULL), 0);
  assert_int_equal(g_ops->raycast(impl, &f->p, r != NULL ? r : &all, rgba,
                                  tiles, fetches),
                   0);
}

static void ref_render(const scene *s, const frame *f, uint8_t *rgba,
                       rp_tile_stats *tiles, uint64_t *fetches) {
  rp_region all = {0, 0, f->p.width, f->p.height};
  rp__reference_render(s->vol, s->tf, s->occ->grid, s->h->blocks, NULL,
                       &f->rg, &f->d, &all, rgba, tiles, fetches);
}

/* ---- comparisons --------------------------------------------------------- */

static void check_image(const uint8_t *got, const uint8_t *want, size_t px,
                        const char *what) {
  size_t i, over2 = 0, over8 = 0;
  int worst = 0;
  for (i = 0; i < px; i++) {
    int c, m = 0;
    for (c = 0; c < 4; c++) {
      int d = abs((int)got[4 * i + c] - (int)want[4 * i + c]);
      m = d > m ? d : m;
    }
    over2 += m > 2;
    over8 += m > 8;
    worst = m > worst ? m : worst;
  }
  if (over8 > 0 || over2 * 1000 > px)
    fail_msg("%s: %zu of %zu pixels over 2/255, %zu over 8/255 (worst %d)",
             what, over2, px, over8, worst);
}

static void check_tiles(const rp_tile_stats *got, const rp_tile_stats *want,
                        const frame *f, const char *what) {
  uint32_t tx, ty, x, y;
  rp_tile_grid(f->p.width, f->p.height, &tx, &ty);
  for (y = 0; y < ty; y++)
    for (x = 0; x < tx; x++) {
      const rp_tile_stats *g = &got[(size_t)y * tx + x];
      const rp_tile_stats *w = &want[(size_t)y * tx + x];
      uint32_t rw = f->p.width - 8 * x < 8 ? f->p.width - 8 * x : 8;
      uint32_t rh = f->p.height - 8 * y < 8 ? f->p.height - 8 * y : 8;
      int64_t ds = (int64_t)g->samples - (int64_t)w->samples;
      if (llabs(ds) > (int64_t)(rw * rh))
        fail_msg("%s: tile (%u,%u) has %u samples, reference %u (more "
                 "than one per ray apart)", what, x, y, g->samples,
                 w->samples);
      /* A ray grazing the box or a block corner may take a sample in one
       * and none in the other: a few per tile at most. */
      if (abs((int)g->rays_hit - (int)w->rays_hit) > 2)
        fail_msg("%s: tile (%u,%u) has %u rays hit, reference %u", what, x,
                 y, g->rays_hit, w->rays_hit);
      if (g->rays_hit == w->rays_hit && w->rays_hit > 0 &&
          fabs(g->mean_depth - w->mean_depth) >
              1e-3 * (1.0 + fabs(w->mean_depth)) + f->p.step)
        fail_msg("%s: tile (%u,%u) mean depth %g, reference %g", what, x, y,
                 (double)g->mean_depth, (double)w->mean_depth);
    }
}

/* Renders one frame on both sides and holds them to the contract. */
static void check_frame(const scene *s, const rp_camera *cam,
                        const frame_desc *fd, const char *what) {
  frame f;
  size_t px, nt;
  uint8_t *got, *want;
  rp_tile_stats *tg, *tw;
  char label[160];
  frame_init(s, cam, fd, &f);
  px = (size_t)f.p.width * f.p.height;
  nt = tile_count(&f);
  got = calloc(px, 4);
  want = calloc(px, 4);
  tg = calloc(nt, sizeof *tg);
  tw = calloc(nt, sizeof *tw);
  assert_true(got && want && tg && tw);
  vk_render(NULL, &f, NULL, got, tg, NULL);
  ref_render(s, &f, want, tw, NULL);
  snprintf(label, sizeof label, "%s %ux%u effects 0x%x step %g", what,
           f.p.width, f.p.height, (unsigned)fd->effects, (double)f.p.step);
  check_image(got, want, px, label);
  if (getenv("RP_VK_TEST_VERBOSE")) {
    size_t i, lit = 0, sum = 0, diff = 0;
    for (i = 0; i < px; i++) {
      lit += got[4 * i + 3] > 0;
      diff += memcmp(got + 4 * i, want + 4 * i, 4) != 0;
    }
    for (i = 0; i < nt; i++)
      sum += tw[i].samples;
    print_message("%s: %zu/%zu lit, %zu differ, %zu samples\n", label, lit,
                  px, diff, sum);
  }
  check_tiles(tg, tw, &f, label);
  free(got);
  free(want);
  free(tg);
  free(tw);
}

/* The three cameras: outside in perspective, inside the volume, and an
 * axis-aligned orthographic view (rays with exactly zero components). */
static void cameras(const rp_volume *vol, rp_camera cams[3]) {
  memset(cams, 0, 3 * sizeof cams[0]);
  rp_camera_orbit(&cams[0], vol, 30.0f, 20.0f, 2.2f);
  rp_camera_orbit(&cams[1], vol, -40.0f, 10.0f, 0.35f);
  cams[2].projection = RP_ORTHOGRAPHIC;
  rp_camera_orbit(&cams[2], vol, 90.0f, 0.0f, 3.0f);
}

static const uint32_t effect_sets[] = {
    0,
    RP_EFFECT_SHADING,
    RP_EFFECT_ERT,
    RP_EFFECT_SKIP,
    RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP,
};

static void check_scene(const scene *s, const char *what, float step) {
  rp_camera cams[3];
  size_t e;
  int c;
  char label[96];
  cameras(s->vol, cams);
  scene_upload(s, NULL);
  for (c = 0; c < 3; c++)
    for (e = 0; e < sizeof effect_sets / sizeof effect_sets[0]; e++) {
      frame_desc fd = {48, 40, 1.0f, step, effect_sets[e]};
      snprintf(label, sizeof label, "%s camera %d", what, c);
      check_frame(s, &cams[c], &fd, label);
    }
}

/* ---- tests: images ------------------------------------------------------- */

static void test_phantom_u8(void **state) {
  scene s;
  (void)state;
  scene_init(&s, generate(RP_GEN_PHANTOM, 48, 48, 48, RP_U8),
             rp_test_preset(g_ctx, "ct-soft"));
  check_scene(&s, "phantom u8", 1.0f);
  scene_free(&s);
  /* Mostly empty blocks: skipping has work to do. */
  scene_init(&s, sparse_volume(), ramp_tf(1.0f));
  assert_true(rp_occupancy_empty_blocks(s.occ) > 100);
  check_scene(&s, "sparse u8", 1.0f);
  scene_free(&s);
}

static void test_marschner_lobb_u16(void **state) {
  scene s;
  (void)state;
  scene_init(&s, generate(RP_GEN_MARSCHNER_LOBB, 41, 37, 29, RP_U16),
             ramp_tf(1.0f));
  check_scene(&s, "Marschner-Lobb u16", 1.0f);
  scene_free(&s);
}

static void test_float32(void **state) {
  scene s;
  (void)state;
  /* Step 0.7 against a reference step of 2: the correction is live. */
  scene_init(&s, float_volume(), ramp_tf(2.0f));
  check_scene(&s, "float32", 0.7f);
  scene_free(&s);
}

static void test_noise(void **state) {
  scene s;
  (void)state;
  scene_init(&s, generate(RP_GEN_NOISE, 40, 40, 40, RP_U8),
             rp_test_preset(g_ctx, "mri"));
  check_scene(&s, "noise u8", 1.0f);
  scene_free(&s);
}

/* Viewports of one pixel and of one odd column, and a half-scale image
 * whose rays cover the output frustum. */
static void test_odd_viewports(void **state) {
  static const frame_desc fds[] = {
      {1, 1, 1.0f, 1.0f, RP_EFFECT_SHADING | RP_EFFECT_SKIP},
      {7, 513, 1.0f, 1.0f, RP_EFFECT_SHADING | RP_EFFECT_ERT |
                               RP_EFFECT_SKIP},
      {7, 513, 1.0f, 0.5f, 0},
      {96, 64, 0.5f, 1.0f, RP_EFFECT_ERT | RP_EFFECT_SKIP},
      {90, 61, 0.5f, 1.0f, RP_EFFECT_SHADING},
  };
  rp_camera cams[3];
  scene s;
  size_t i;
  (void)state;
  scene_init(&s, generate(RP_GEN_PHANTOM, 48, 48, 48, RP_U8),
             rp_test_preset(g_ctx, "ct-soft"));
  scene_upload(&s, NULL);
  cameras(s.vol, cams);
  for (i = 0; i < sizeof fds / sizeof fds[0]; i++)
    check_frame(&s, &cams[i % 2], &fds[i], "odd viewport");
  scene_free(&s);
}

/* Volumes one voxel thick along some axes: every neighbour the quad
 * layout stores is clamped, and the block grid is a single block. */
static void test_thin_volumes(void **state) {
  static const uint32_t dims[3][3] = {{1, 1, 1}, {1, 7, 3}, {19, 1, 2}};
  rp_camera cams[3];
  scene s;
  int v, c;
  (void)state;
  for (v = 0; v < 3; v++) {
    rp_volume *vol = thin_volume(dims[v]);
    /* Opaque at every value: a single-valued volume sits at x = 0. */
    scene_init(&s, vol, solid_tf());
    scene_upload(&s, NULL);
    cameras(s.vol, cams);
    for (c = 0; c < 3; c++) {
      frame_desc fd = {24, 20, 1.0f, 0.25f,
                       RP_EFFECT_SHADING | RP_EFFECT_SKIP | RP_EFFECT_ERT};
      check_frame(&s, &cams[c], &fd, "thin volume");
    }
    scene_free(&s);
  }
}

/* Both volume layouts and both upload paths give the same bits. */
static void test_layouts_agree(void **state) {
  rp_camera cams[3];
  scene s;
  frame f;
  frame_desc fd = {64, 48, 1.0f, 1.0f,
                   RP_EFFECT_SHADING | RP_EFFECT_SKIP | RP_EFFECT_ERT};
  uint8_t *a = calloc(64 * 48, 4), *b = calloc(64 * 48, 4);
  rp_vk_stats st;
  int t;
  (void)state;
  assert_true(a && b);
  for (t = 0; t < 2; t++) {
    scene_init(&s, t == 0 ? generate(RP_GEN_MARSCHNER_LOBB, 41, 37, 29,
                                     RP_U16)
                          : float_volume(),
               ramp_tf(1.0f));
    cameras(s.vol, cams);
    scene_upload(&s, NULL);
    frame_init(&s, &cams[0], &fd, &f);
    rp_vk_get_stats(g_impl, &st);
    assert_int_equal(st.quad_layout, 1);
    vk_render(NULL, &f, NULL, a, NULL, NULL);
    rp_vk_hooks.force_plain = 1;
    rp_vk_hooks.force_staging = 1;
    scene_upload(&s, NULL);
    rp_vk_hooks.force_plain = 0;
    rp_vk_hooks.force_staging = 0;
    rp_vk_get_stats(g_impl, &st);
    assert_int_equal(st.quad_layout, 0);
    vk_render(NULL, &f, NULL, b, NULL, NULL);
    assert_memory_equal(a, b, 64 * 48 * 4);
    scene_free(&s);
  }
  free(a);
  free(b);
}

/* ---- tests: ambient occlusion -------------------------------------------- */

/* The job runtime/backend.c hands a backend for box [lo, end) of `plan`
 * on the uploaded scene. */
static void ao_job_init(const scene *s, const rp_ao_plan *plan,
                        const uint32_t lo[3], const uint32_t end[3],
                        rp_ao_job *job) {
  int lut_size = 0;
  rp_tf_lut(s->tf, &lut_size);
  rp__ao_job(plan, lo, end, rp_tf_reference_step(s->tf), s->vol->min,
             s->vol->max, (uint32_t)lut_size, job);
}

/* AO of box [lo, end) on the device, into a new buffer. */
static uint8_t *vk_ao_box(const scene *s, const rp_ao_plan *plan,
                          const uint32_t lo[3], const uint32_t end[3]) {
  size_t n = (size_t)(end[0] - lo[0]) * (end[1] - lo[1]) * (end[2] - lo[2]);
  uint8_t *out = malloc(n);
  rp_ao_job job;
  assert_non_null(out);
  memset(out, 0xcd, n);
  ao_job_init(s, plan, lo, end, &job);
  assert_int_equal(g_ops->compute_ao(g_impl, &job, out), 0);
  /* Its buffers live only during the call. */
  assert_int_equal(((rp_vk_impl *)g_impl)->ao_out.buf, VK_NULL_HANDLE);
  assert_int_equal(((rp_vk_impl *)g_impl)->ao_dirs.buf, VK_NULL_HANDLE);
  return out;
}

/* The contract's AO tolerance: within 2/255 on >= 99.9 % of voxels, none
 * over 8/255. With `need_dark`, at least 2 % of the reference's voxels
 * must be clearly occluded (below 224). */
static void check_ao(const uint8_t *got, const uint8_t *want, size_t n,
                     int need_dark, const char *what) {
  size_t i, over2 = 0, over8 = 0, dark = 0;
  int worst = 0;
  for (i = 0; i < n; i++) {
    int d = abs((int)got[i] - (int)want[i]);
    over2 += d > 2;
    over8 += d > 8;
    worst = d > worst ? d : worst;
    dark += want[i] < 224;
  }
  if (getenv("RP_VK_TEST_VERBOSE"))
    print_message("%s: %zu voxels, %zu over 2/255, worst %d, %zu below "
                  "224\n", what, n, over2, worst, dark);
  if (over8 > 0 || over2 * 1000 > n)
    fail_msg("%s: %zu of %zu voxels over 2/255, %zu over 8/255 (worst %d)",
             what, over2, n, over8, worst);
  /* Occlusion there is, or nothing was tested. */
  if (need_dark)
    assert_true(dark * 50 > n);
}

/* Whole-volume AO, bricked and unbricked, against the reference (with
 * `need_dark`, also: the voxels of empty bricks are 255 on both sides);
 * boxes of it (unaligned, one voxel thick, computed in slabs of one brick
 * layer) equal to the same voxels of the whole, bit for bit. */
static void check_ao_scene(const scene *s, int need_dark,
                           const char *what) {
  static const uint32_t boxes[4][2][3] = {
      {{5, 3, 7}, {29, 30, 26}},
      {{13, 0, 1}, {14, 37, 2}},
      {{0, 0, 0}, {1, 1, 1}},
      {{3, 6, 2}, {38, 35, 31}},
  };
  int bricked, b;
  char label[128];
  scene_upload(s, NULL);
  for (bricked = 0; bricked < 2; bricked++) {
    rp_ao_desc d = {0};
    rp_ao_plan *plan = NULL;
    rp_ao *ref = NULL;
    uint32_t dims[3], zero[3] = {0, 0, 0};
    const uint8_t *want;
    uint8_t *got;
    uint64_t full, total;
    d.unbricked = !bricked;
    assert_int_equal(rp_ao_compute_reference(g_ctx, s->vol, s->tf, &d, NULL,
                                             NULL, &ref),
                     0);
    assert_int_equal(rp_ao_plan_create(g_ctx, s->vol, s->tf, &d, &plan), 0);
    want = rp_ao_data(ref, dims);
    rp_ao_bricks(ref, &full, &total);
    /* Unbricked computes every brick; bricked has some to skip in the
     * scenes with air. */
    if (!bricked)
      assert_true(full == total);
    else if (need_dark)
      assert_true(full < total);
    assert_int_equal(bricked, plan->bricks != NULL);
    got = vk_ao_box(s, plan, zero, dims);
    snprintf(label, sizeof label, "%s AO %s", what,
             bricked ? "bricked" : "unbricked");
    check_ao(got, want, s->vol->voxel_count, need_dark, label);
    if (bricked && need_dark) {
      size_t i, skipped = 0;
      for (i = 0; i < s->vol->voxel_count; i++) {
        uint32_t x = (uint32_t)(i % dims[0]);
        uint32_t y = (uint32_t)(i / dims[0] % dims[1]);
        uint32_t z = (uint32_t)(i / dims[0] / dims[1]);
        size_t bi = ((size_t)(z / 4) * plan->brick_grid[1] + y / 4) *
                        plan->brick_grid[0] + x / 4;
        if (plan->bricks[bi] == 0) {
          assert_int_equal(got[i], 255);
          assert_int_equal(want[i], 255);
          skipped++;
        }
      }
      assert_true(skipped > 0);
    }
    for (b = 0; b < 4; b++) {
      uint32_t lo[3], end[3], x, y, z;
      uint8_t *part;
      int a, empty = 0;
      for (a = 0; a < 3; a++) {
        lo[a] = boxes[b][0][a] < dims[a] ? boxes[b][0][a] : dims[a] - 1;
        end[a] = boxes[b][1][a] < dims[a] ? boxes[b][1][a] : dims[a];
        empty |= lo[a] >= end[a];
      }
      if (empty)
        continue;
      /* The last box in slabs of one brick layer. */
      rp_vk_hooks.ao_chunk_bytes = b == 3 ? 1 : 0;
      part = vk_ao_box(s, plan, lo, end);
      rp_vk_hooks.ao_chunk_bytes = 0;
      for (z = lo[2]; z < end[2]; z++)
        for (y = lo[1]; y < end[1]; y++)
          for (x = lo[0]; x < end[0]; x++) {
            uint8_t pv = part[((size_t)(z - lo[2]) * (end[1] - lo[1]) +
                               (y - lo[1])) * (end[0] - lo[0]) +
                              (x - lo[0])];
            uint8_t wv = got[((size_t)z * dims[1] + y) * dims[0] + x];
            if (pv != wv)
              fail_msg("%s box %d: voxel (%u,%u,%u) is %u, %u in the "
                       "whole volume", label, b, x, y, z, pv, wv);
          }
      free(part);
    }
    free(got);
    rp_ao_plan_destroy(plan);
    rp_ao_destroy(ref);
  }
}

static void test_ao_volume(void **state) {
  scene s;
  (void)state;
  scene_init(&s, generate(RP_GEN_PHANTOM, 40, 37, 33, RP_U8),
             rp_test_preset(g_ctx, "ct-bone"));
  check_ao_scene(&s, 1, "phantom u8 40x37x33");
  scene_free(&s);
  scene_init(&s, generate(RP_GEN_PHANTOM, 39, 34, 37, RP_U16),
             rp_test_preset(g_ctx, "ct-soft"));
  check_ao_scene(&s, 1, "phantom u16 39x34x37");
  scene_free(&s);
  /* The plain layout reads the same voxels. */
  scene_init(&s, generate(RP_GEN_PHANTOM, 40, 37, 33, RP_U8),
             rp_test_preset(g_ctx, "ct-soft"));
  rp_vk_hooks.force_plain = 1;
  check_ao_scene(&s, 1, "phantom u8 plain layout");
  rp_vk_hooks.force_plain = 0;
  scene_free(&s);
  /* Float voxels, and an alpha corrected from a reference step of 2. */
  scene_init(&s, float_volume(), ramp_tf(2.0f));
  check_ao_scene(&s, 0, "float32");
  scene_free(&s);
  /* Volumes thinner than a brick. */
  {
    static const uint32_t dims[2][3] = {{19, 1, 2}, {1, 7, 3}};
    int v;
    for (v = 0; v < 2; v++) {
      rp_volume *vol = thin_volume(dims[v]);
      scene_init(&s, vol, solid_tf());
      check_ao_scene(&s, 0, "thin volume");
      scene_free(&s);
    }
  }
}

/* Renders `effects` on both devices and holds them to the contract
 * (images, tiles' fetches); returns the Vulkan image (malloc). */
static uint8_t *ao_render_pair(rp_device *vk, rp_device *ref,
                               const rp_camera *cam, uint32_t effects,
                               const char *what) {
  const uint32_t w = 64, h = 56;
  rp_render_desc d = {0};
  uint32_t tx, ty;
  size_t nt;
  uint8_t *got = calloc((size_t)w * h, 4), *want = calloc((size_t)w * h, 4);
  rp_tile_stats *tg, *tw;
  uint64_t *fg, *fw, total = 0, off = 0;
  char label[128];
  rp_tile_grid(w, h, &tx, &ty);
  nt = (size_t)tx * ty;
  tg = calloc(nt, sizeof *tg);
  tw = calloc(nt, sizeof *tw);
  fg = calloc(nt, sizeof *fg);
  fw = calloc(nt, sizeof *fw);
  assert_true(got && want && tg && tw && fg && fw);
  d.width = w;
  d.height = h;
  d.effects = effects;
  assert_int_equal(rp__device_render(vk, cam, &d, NULL, got, tg, fg), 0);
  assert_int_equal(rp__device_render(ref, cam, &d, NULL, want, tw, fw), 0);
  snprintf(label, sizeof label, "%s effects 0x%x", what, (unsigned)effects);
  check_image(got, want, (size_t)w * h, label);
  rp_test_check_fetches(label, tg, fg, tw, fw, nt,
                        rp_test_visible_fetches(effects), &total, &off);
  free(want);
  free(tg);
  free(tw);
  free(fg);
  free(fw);
  return got;
}

/* Share of lit pixels whose colour differs by more than 8/255. */
static double changed_share(const uint8_t *a, const uint8_t *b, size_t px) {
  size_t i, lit = 0, changed = 0;
  for (i = 0; i < px; i++) {
    int c, m = 0;
    if (a[4 * i + 3] == 0 && b[4 * i + 3] == 0)
      continue;
    lit++;
    for (c = 0; c < 3; c++) {
      int dd = abs((int)a[4 * i + c] - (int)b[4 * i + c]);
      m = dd > m ? dd : m;
    }
    changed += m > 8;
  }
  return lit > 0 ? (double)changed / (double)lit : 0.0;
}

/* RP_EFFECT_AO renders against the reference device holding the same AO
 * volume, with and without shading; and AO visibly darkens the image. */
static void test_ao_render(void **state) {
  static const uint32_t sets[] = {
      RP_EFFECT_AO,
      RP_EFFECT_AO | RP_EFFECT_SHADING,
      RP_EFFECT_AO | RP_EFFECT_SHADING | RP_EFFECT_SKIP | RP_EFFECT_ERT,
      RP_EFFECT_AO | RP_EFFECT_SKIP,
  };
  rp_device_desc dv = {0}, dr = {0};
  rp_device *vk = NULL, *ref = NULL;
  rp_camera cams[3];
  rp_ao *ao = NULL;
  scene s;
  size_t e;
  int c, g;
  (void)state;
  dv.backend = "vulkan";
  dr.backend = "reference";
  assert_int_equal(rp_device_create(g_ctx, &dv, &vk), 0);
  assert_int_equal(rp_device_create(g_ctx, &dr, &ref), 0);
  for (g = 0; g < 2; g++) {
    scene_init(&s,
               g == 0 ? generate(RP_GEN_PHANTOM, 40, 37, 33, RP_U8)
                      : generate(RP_GEN_PHANTOM, 39, 34, 37, RP_U16),
               rp_test_preset(g_ctx, g == 0 ? "ct-bone" : "ct-soft"));
    assert_int_equal(rp_ao_compute_reference(g_ctx, s.vol, s.tf, NULL, NULL,
                                             NULL, &ao),
                     0);
    assert_int_equal(rp_device_set_volume(vk, s.vol), 0);
    assert_int_equal(rp_device_set_tf(vk, s.tf, s.occ), 0);
    assert_int_equal(rp_device_set_volume(ref, s.vol), 0);
    assert_int_equal(rp_device_set_tf(ref, s.tf, s.occ), 0);
    assert_int_equal(rp_device_set_ao(vk, ao), 0);
    assert_int_equal(rp_device_set_ao(ref, ao), 0);
    cameras(s.vol, cams);
    for (c = 0; c < 2; c++)
      for (e = 0; e < sizeof sets / sizeof sets[0]; e++) {
        uint8_t *with, *without;
        double share;
        with = ao_render_pair(vk, ref, &cams[c], sets[e], "AO render");
        without = ao_render_pair(vk, ref, &cams[c],
                                 sets[e] & ~(uint32_t)RP_EFFECT_AO,
                                 "AO render (off)");
        share = changed_share(with, without, 64 * 56);
        if (getenv("RP_VK_TEST_VERBOSE"))
          print_message("AO scene %d camera %d effects 0x%x: %.1f %% of "
                        "lit pixels changed by AO\n", g, c,
                        (unsigned)sets[e], 100.0 * share);
        /* An AO ignored would leave the image as it is without. */
        if (share < 0.2)
          fail_msg("AO changed only %.1f %% of lit pixels (scene %d camera "
                   "%d effects 0x%x)", 100.0 * share, g, c,
                   (unsigned)sets[e]);
        free(with);
        free(without);
      }
    assert_int_equal(rp_device_set_ao(vk, NULL), 0);
    assert_int_equal(rp_device_set_ao(ref, NULL), 0);
    rp_ao_destroy(ao);
    ao = NULL;
    scene_free(&s);
  }
  rp_device_destroy(vk);
  rp_device_destroy(ref);
}

/* AO memory exists only while an AO volume is uploaded; a raycast with
 * RP_EFFECT_AO without one is refused, and so is an AO volume before a
 * volume; a volume of another shape drops the AO volume. */
static void test_ao_state(void **state) {
  rp_vk_impl *impl = g_impl;
  rp_camera cams[3];
  rp_region all;
  rp_vk_stats st;
  scene s;
  frame f;
  frame_desc fd = {16, 16, 1.0f, 1.0f, RP_EFFECT_AO | RP_EFFECT_SHADING};
  uint8_t rgba[16 * 16 * 4];
  uint8_t *ao;
  const rp_backend_ops *ops = NULL;
  void *fresh = NULL;
  rp_caps caps;
  (void)state;
  /* A device with nothing uploaded. */
  assert_int_equal(rp_vk_bootstrap.create(g_ctx, 0, 0, &ops, &fresh, &caps),
                   0);
  ao = calloc(1, 1);
  assert_non_null(ao);
  assert_int_equal(ops->upload_ao(fresh, ao), RP_ESTATE);
  assert_int_equal(ops->upload_ao(fresh, NULL), 0);
  free(ao);
  ops->destroy(fresh);

  scene_init(&s, generate(RP_GEN_PHANTOM, 24, 20, 18, RP_U8),
             rp_test_preset(g_ctx, "ct-soft"));
  scene_upload(&s, NULL);
  cameras(s.vol, cams);
  frame_init(&s, &cams[0], &fd, &f);
  all.x0 = all.y0 = 0;
  all.x1 = f.p.width;
  all.y1 = f.p.height;
  assert_int_equal(g_ops->upload_ao(g_impl, NULL), 0);
  assert_int_equal(impl->ao.buf, VK_NULL_HANDLE);
  assert_int_equal(g_ops->raycast(g_impl, &f.p, &all, rgba, NULL, NULL),
                   RP_ESTATE);
  assert_non_null(strstr(rp_last_error(g_ctx), "RP_EFFECT_AO"));

  ao = malloc(s.vol->voxel_count);
  assert_non_null(ao);
  memset(ao, 128, s.vol->voxel_count);
  assert_int_equal(g_ops->upload_ao(g_impl, ao), 0);
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.ao_bytes, s.vol->voxel_count);
  vk_render(NULL, &f, NULL, rgba, NULL, NULL);
  /* Uploaded again, into the same buffer. */
  assert_int_equal(g_ops->upload_ao(g_impl, ao), 0);
  vk_render(NULL, &f, NULL, rgba, NULL, NULL);
  assert_int_equal(g_ops->upload_ao(g_impl, NULL), 0);
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.ao_bytes, 0);
  assert_int_equal(impl->ao.buf, VK_NULL_HANDLE);
  assert_int_equal(impl->ao_view, VK_NULL_HANDLE);
  /* Renders without AO are unaffected by its absence. */
  fd.effects = RP_EFFECT_SHADING;
  check_frame(&s, &cams[0], &fd, "after AO released");

  /* Same shape kept, another shape dropped. */
  assert_int_equal(g_ops->upload_ao(g_impl, ao), 0);
  assert_int_equal(g_ops->upload_volume(g_impl, s.vol), 0);
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.ao_bytes, s.vol->voxel_count);
  free(ao);
  scene_free(&s);
  scene_init(&s, generate(RP_GEN_PHANTOM, 20, 20, 18, RP_U8),
             rp_test_preset(g_ctx, "ct-soft"));
  scene_upload(&s, NULL);
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.ao_bytes, 0);
  assert_int_equal(impl->ao.buf, VK_NULL_HANDLE);
  scene_free(&s);
}

/* ---- tests: counting, regions, passes ------------------------------------ */

/* Renders `f` with the counting variant and holds every tile's fetches
 * to the reference's (rp_test_check_fetches); returns the total fetches
 * and, in *samples, the total samples. */
static uint64_t counted(const scene *s, const frame *f, uint64_t *samples) {
  size_t nt = tile_count(f), i;
  size_t px = (size_t)f->p.width * f->p.height;
  uint8_t *rgba = calloc(px, 4);
  rp_tile_stats *tiles = calloc(nt, sizeof *tiles);
  rp_tile_stats *want = calloc(nt, sizeof *want);
  uint64_t *fetches = calloc(nt, sizeof *fetches);
  uint64_t *want_fetches = calloc(nt, sizeof *want_fetches);
  uint64_t total = 0, ref_total = 0, off = 0;
  assert_true(rgba && tiles && want && fetches && want_fetches);
  vk_render(NULL, f, NULL, rgba, tiles, fetches);
  ref_render(s, f, rgba, want, want_fetches);
  rp_test_check_fetches("counted", tiles, fetches, want, want_fetches, nt,
                        rp_test_visible_fetches(f->d.effects), &ref_total,
                        &off);
  *samples = 0;
  for (i = 0; i < nt; i++) {
    total += fetches[i];
    *samples += tiles[i].samples;
  }
  free(rgba);
  free(tiles);
  free(want);
  free(fetches);
  free(want_fetches);
  return total;
}

static void test_fetch_counts(void **state) {
  rp_camera cams[3];
  scene s;
  frame f, fs;
  uint64_t shaded, plain, n_shaded, n_plain;
  frame_desc fd = {64, 64, 1.0f, 1.0f, 0};
  size_t e;
  (void)state;
  scene_init(&s, generate(RP_GEN_PHANTOM, 48, 48, 48, RP_U8),
             rp_test_preset(g_ctx, "ct-soft"));
  scene_upload(&s, NULL);
  cameras(s.vol, cams);
  for (e = 0; e < sizeof effect_sets / sizeof effect_sets[0]; e++) {
    fd.effects = effect_sets[e];
    frame_init(&s, &cams[0], &fd, &f);
    counted(&s, &f, &n_plain);
  }
  /* What the extra fetches cost in time is bench_backends' figure (medians,
   * ert+skip against shade+ert+skip), not a unit test's: on a shared
   * machine the order of two renders' times can flip (the OpenCL twin of
   * this check did, in CI, at its best of nine). */
  fd.width = fd.height = 160;
  fd.effects = RP_EFFECT_SHADING;
  frame_init(&s, &cams[0], &fd, &fs);
  shaded = counted(&s, &fs, &n_shaded);
  fd.effects = 0;
  frame_init(&s, &cams[0], &fd, &f);
  plain = counted(&s, &f, &n_plain);
  /* Shading changes colour, never opacity: the same samples; of them,
   * the ones that show are shaded, and this view has both kinds. */
  assert_true(plain > 0 && plain == n_plain && n_shaded == n_plain);
  assert_true(plain < shaded && shaded < 7 * plain);
  print_message("fetches %llu vs %llu (no shading vs shading)\n",
                (unsigned long long)plain, (unsigned long long)shaded);
  scene_free(&s);
}

/* Four tile-aligned quadrants give the full render bit for bit, and a
 * region render writes nothing outside its region. */
static void test_regions(void **state) {
  rp_camera cams[3];
  scene s;
  frame f;
  frame_desc fd = {61, 45, 1.0f, 1.0f,
                   RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP};
  const rp_region quads[4] = {
      {0, 0, 32, 24}, {32, 0, 61, 24}, {0, 24, 32, 45}, {32, 24, 61, 45}};
  size_t px = 61 * 45, nt;
  uint8_t *full, *parts;
  rp_tile_stats *tfull, *tparts;
  uint64_t *ffull, *fparts;
  uint32_t x, y, created;
  rp_vk_stats st;
  int q;
  (void)state;
  scene_init(&s, generate(RP_GEN_PHANTOM, 48, 48, 48, RP_U8),
             rp_test_preset(g_ctx, "ct-bone"));
  scene_upload(&s, NULL);
  cameras(s.vol, cams);
  frame_init(&s, &cams[1], &fd, &f);
  nt = tile_count(&f);
  full = calloc(px, 4);
  parts = malloc(px * 4);
  tfull = calloc(nt, sizeof *tfull);
  tparts = calloc(nt, sizeof *tparts);
  ffull = calloc(nt, sizeof *ffull);
  fparts = calloc(nt, sizeof *fparts);
  assert_true(full && parts && tfull && tparts && ffull && fparts);
  memset(parts, 0xab, px * 4);
  vk_render(NULL, &f, NULL, full, tfull, ffull);
  rp_vk_get_stats(g_impl, &st);
  created = st.pipelines_created;
  vk_render(NULL, &f, &quads[0], parts, tparts, fparts);
  for (y = 0; y < 45; y++)
    for (x = 0; x < 61; x++)
      if (x >= 32 || y >= 24)
        assert_int_equal(parts[(y * 61 + x) * 4], 0xab);
  for (q = 1; q < 4; q++)
    vk_render(NULL, &f, &quads[q], parts, tparts, fparts);
  assert_memory_equal(full, parts, px * 4);
  assert_memory_equal(tfull, tparts, nt * sizeof *tfull);
  assert_memory_equal(ffull, fparts, nt * sizeof *ffull);
  /* The same effect set reuses its pipelines. */
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.pipelines_created, created);
  free(full);
  free(parts);
  free(tfull);
  free(tparts);
  free(ffull);
  free(fparts);
  scene_free(&s);
}

/* ---- tests: prepare ------------------------------------------------------ */

/* A device of its own on `ctx` (g_ctx when NULL), so that its pipeline
 * table starts empty. */
static void *fresh_device(rp_context *ctx) {
  const rp_backend_ops *ops = NULL;
  void *impl = NULL;
  rp_caps caps;
  assert_int_equal(rp_vk_bootstrap.create(ctx != NULL ? ctx : g_ctx, 0, 0,
                                          &ops, &impl, &caps),
                   0);
  assert_ptr_equal(ops, g_ops);
  return impl;
}

static uint32_t pipelines_created(void *impl) {
  rp_vk_stats st;
  rp_vk_get_stats(impl, &st);
  return st.pipelines_created;
}

/* A 32^3 scene and its cameras: with 64x64 frames, the tests below take
 * a second or two. */
static void prepare_scene(scene *s, rp_camera cams[3]) {
  scene_init(s, generate(RP_GEN_PHANTOM, 32, 32, 32, RP_U8),
             ramp_tf(1.0f));
  cameras(s->vol, cams);
}

/* prepare, with errors on a context of its own, builds what the frames
 * of its effect set bind, at either step kind (opacity corrected or not):
 * they build nothing, and render what a device without prepare does. */
static void test_prepare(void **state) {
  const uint32_t effects = RP_EFFECT_SHADING | RP_EFFECT_ERT |
                           RP_EFFECT_SKIP;
  /* ramp_tf(1): step 1 is the reference step, 0.6 needs correcting. */
  const float steps[2] = {1.0f, 0.6f};
  rp_context *ctx2 = rp_test_context();
  void *prep = fresh_device(NULL), *plain = fresh_device(NULL);
  uint8_t *a = malloc(64 * 64 * 4), *b = malloc(64 * 64 * 4);
  rp_camera cams[3];
  scene s;
  frame f;
  uint32_t built, plain_built;
  int i;
  (void)state;
  assert_true(a && b);
  prepare_scene(&s, cams);
  scene_upload(&s, prep);
  scene_upload(&s, plain);
  assert_int_equal(g_ops->prepare(prep, ctx2, effects), 0);
  built = pipelines_created(prep);
  assert_true(built > 0);
  /* What is in the table is not built again. */
  assert_int_equal(g_ops->prepare(prep, ctx2, effects), 0);
  assert_int_equal(pipelines_created(prep), built);
  for (i = 0; i < 2; i++) {
    frame_desc fd = {64, 64, 1.0f, steps[i], effects};
    frame_init(&s, &cams[i], &fd, &f);
    plain_built = pipelines_created(plain);
    vk_render(prep, &f, NULL, a, NULL, NULL);
    vk_render(plain, &f, NULL, b, NULL, NULL);
    assert_int_equal(pipelines_created(prep), built);
    /* The frame did need a pipeline of its own: the first needs the
     * depth pass and a raycast, the second another raycast. */
    assert_true(pipelines_created(plain) > plain_built);
    assert_memory_equal(a, b, 64 * 64 * 4);
  }
  g_ops->destroy(prep);
  g_ops->destroy(plain);
  rp_context_destroy(ctx2);
  scene_free(&s);
  free(a);
  free(b);
}

/* With AO, prepare also builds compute_ao's pipeline: the AO volume's
 * computation and the frames that read it, at either step kind, build
 * nothing. */
static void test_prepare_ao(void **state) {
  const uint32_t effects = RP_EFFECT_SHADING | RP_EFFECT_ERT |
                           RP_EFFECT_SKIP | RP_EFFECT_AO;
  const float steps[2] = {1.0f, 0.6f};
  rp_context *ctx2 = rp_test_context();
  void *prep = fresh_device(NULL);
  uint8_t *a = malloc(64 * 64 * 4), *ao;
  uint32_t lo[3] = {0, 0, 0}, built;
  rp_ao_desc ad = {0};
  rp_ao_plan *plan = NULL;
  rp_ao_job job;
  rp_camera cams[3];
  scene s;
  frame f;
  int i;
  (void)state;
  prepare_scene(&s, cams);
  scene_upload(&s, prep);
  ao = malloc(s.vol->voxel_count);
  assert_true(a && ao);
  assert_int_equal(g_ops->prepare(prep, ctx2, effects), 0);
  built = pipelines_created(prep);
  assert_int_equal(rp_ao_plan_create(g_ctx, s.vol, s.tf, &ad, &plan), 0);
  ao_job_init(&s, plan, lo, s.vol->dims, &job);
  assert_int_equal(g_ops->compute_ao(prep, &job, ao), 0);
  assert_int_equal(g_ops->upload_ao(prep, ao), 0);
  for (i = 0; i < 2; i++) {
    frame_desc fd = {64, 64, 1.0f, steps[i], effects};
    frame_init(&s, &cams[i], &fd, &f);
    vk_render(prep, &f, NULL, a, NULL, NULL);
  }
  assert_int_equal(pipelines_created(prep), built);
  rp_ao_plan_destroy(plan);
  g_ops->destroy(prep);
  rp_context_destroy(ctx2);
  scene_free(&s);
  free(a);
  free(ao);
}

/* Before any volume: RP_ESTATE, said in the caller's context, not in the
 * device's; through the ops and through rp_device_prepare. */
static void test_prepare_no_volume(void **state) {
  rp_context *dctx = rp_test_context(), *ctx2 = rp_test_context();
  rp_context *ctx3 = rp_test_context();
  rp_device_desc dd;
  rp_device *dev = NULL;
  rp_volume *vol;
  char before[512];
  void *impl;
  (void)state;
  impl = fresh_device(dctx);
  snprintf(before, sizeof before, "%s", rp_last_error(dctx));
  assert_int_equal(g_ops->prepare(impl, ctx2, RP_EFFECT_SKIP), RP_ESTATE);
  assert_non_null(strstr(rp_last_error(ctx2), "volume"));
  assert_string_equal(rp_last_error(dctx), before);
  assert_int_equal(pipelines_created(impl), 0);
  g_ops->destroy(impl);

  /* The front end passes the call on, context and all; once a volume is
   * there, prepare succeeds. */
  memset(&dd, 0, sizeof dd);
  dd.backend = "vulkan";
  assert_int_equal(rp_device_create(dctx, &dd, &dev), 0);
  snprintf(before, sizeof before, "%s", rp_last_error(dctx));
  assert_int_equal(rp_device_prepare(dev, ctx3, RP_EFFECT_SKIP), RP_ESTATE);
  assert_non_null(strstr(rp_last_error(ctx3), "volume"));
  assert_string_equal(rp_last_error(dctx), before);
  vol = generate(RP_GEN_PHANTOM, 32, 32, 32, RP_U8);
  assert_int_equal(rp_device_set_volume(dev, vol), 0);
  assert_int_equal(rp_device_prepare(dev, ctx3, RP_EFFECT_SKIP), 0);
  rp_volume_destroy(vol);
  rp_device_destroy(dev);
  rp_context_destroy(dctx);
  rp_context_destroy(ctx2);
  rp_context_destroy(ctx3);
}

typedef struct prepare_job {
  void *impl;
  rp_context *ctx;
  uint32_t effects;
  int rc;
  atomic_int done;
} prepare_job;

static void *prepare_main(void *arg) {
  prepare_job *j = arg;
  j->rc = g_ops->prepare(j->impl, j->ctx, j->effects);
  atomic_store(&j->done, 1);
  return NULL;
}

/* prepare on a second thread while this one renders another effect set
 * on the same device (both building pipelines into one table): the
 * prepared set's frame then builds nothing and gives a fresh device's
 * image bit for bit. */
static void test_prepare_concurrent(void **state) {
  const uint32_t effects = RP_EFFECT_SHADING | RP_EFFECT_ERT |
                           RP_EFFECT_SKIP;
  rp_context *ctx2 = rp_test_context();
  void *impl = fresh_device(NULL), *fresh;
  uint8_t *a = malloc(64 * 64 * 4), *b = malloc(64 * 64 * 4);
  frame_desc other = {64, 64, 1.0f, 1.0f, RP_EFFECT_ERT};
  frame_desc fd = {64, 64, 1.0f, 0.6f, effects};
  prepare_job job;
  pthread_t thread;
  rp_camera cams[3];
  scene s;
  frame f;
  uint32_t built;
  int renders;
  (void)state;
  assert_true(a && b);
  prepare_scene(&s, cams);
  scene_upload(&s, impl);
  job.impl = impl;
  job.ctx = ctx2;
  job.effects = effects;
  job.rc = -1;
  atomic_init(&job.done, 0);
  assert_int_equal(pthread_create(&thread, NULL, prepare_main, &job), 0);
  /* A few frames at least, and on for as long as prepare builds; each
   * camera change runs a depth pass too. */
  for (renders = 0; renders < 4 || (!atomic_load(&job.done) &&
                                    renders < 200);
       renders++) {
    other.step = renders % 2 ? 0.6f : 1.0f;
    frame_init(&s, &cams[renders % 3], &other, &f);
    vk_render(impl, &f, NULL, a, NULL, NULL);
  }
  assert_int_equal(pthread_join(thread, NULL), 0);
  assert_int_equal(job.rc, 0);
  built = pipelines_created(impl);
  frame_init(&s, &cams[0], &fd, &f);
  vk_render(impl, &f, NULL, a, NULL, NULL);
  assert_int_equal(pipelines_created(impl), built);
  fresh = fresh_device(NULL);
  scene_upload(&s, fresh);
  vk_render(fresh, &f, NULL, b, NULL, NULL);
  assert_memory_equal(a, b, 64 * 64 * 4);
  g_ops->destroy(fresh);
  g_ops->destroy(impl);
  rp_context_destroy(ctx2);
  scene_free(&s);
  free(a);
  free(b);
}

/* The depth pass against runtime/depth.c, ray by ray. */
static void test_depth_pass(void **state) {
  rp_camera cams[3];
  scene s;
  frame f;
  frame_desc fd = {80, 64, 1.0f, 1.0f, 0};
  float *fb = malloc(80 * 64 * 2 * sizeof(float));
  int c, skip;
  (void)state;
  assert_non_null(fb);
  scene_init(&s, generate(RP_GEN_PHANTOM, 48, 48, 48, RP_U8),
             rp_test_preset(g_ctx, "ct-bone"));
  scene_upload(&s, NULL);
  cameras(s.vol, cams);
  for (c = 0; c < 3; c++)
    for (skip = 0; skip < 2; skip++) {
      uint32_t x, y, bad = 0;
      fd.effects = skip ? RP_EFFECT_SKIP : 0;
      frame_init(&s, &cams[c], &fd, &f);
      assert_int_equal(g_ops->depth_pass(g_impl, &f.p, fb), 0);
      for (y = 0; y < f.p.height; y++)
        for (x = 0; x < f.p.width; x++) {
          rp__ray ray;
          double want[2];
          const float *got = &fb[((size_t)y * f.p.width + x) * 2];
          int k;
          rp__raygen_ray(&f.rg, x, y, &ray);
          rp__depth_ray(&ray, f.rg.dims, skip ? s.occ->grid : NULL,
                        s.h->blocks, &want[0], &want[1]);
          for (k = 0; k < 2; k++) {
            int ok = isinf(want[k])
                         ? got[k] == (float)want[k]
                         : fabs(got[k] - want[k]) <=
                               1e-3 * (1.0 + fabs(want[k]));
            bad += !ok;
          }
        }
      /* Rays grazing a block corner may see one block more or less. */
      if (bad * 1000 > 2 * (uint32_t)(f.p.width * f.p.height))
        fail_msg("camera %d skip %d: %u depth values differ", c, skip, bad);
    }
  free(fb);
  scene_free(&s);
}

/* The ERT pre-pass against runtime/ert.c: the same random draws, so the
 * same terminations, but for float compositing on rare rays. */
static void test_ert_prepass(void **state) {
  rp_camera cams[3];
  scene s;
  frame f;
  frame_desc fd = {256, 192, 1.0f, 1.0f, RP_EFFECT_ERT | RP_EFFECT_SKIP};
  uint32_t gw, gh, frame_no;
  float *got, *want;
  int c;
  (void)state;
  scene_init(&s, sparse_volume(), ramp_tf(1.0f));
  scene_upload(&s, NULL);
  /* Aimed at the balls, so that most pre-pass rays terminate: from
   * outside at ball A, orthographic at ball B, and from between them. */
  memset(cams, 0, sizeof cams);
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
  rp__ert_grid(256, 192, &gw, &gh);
  got = malloc(sizeof(float) * gw * gh);
  want = malloc(sizeof(float) * gw * gh);
  assert_true(got && want);
  for (c = 0; c < 3; c++)
    for (frame_no = 0; frame_no < 3; frame_no++) {
      uint32_t i, same = 0, step_off = 0, finite = 0;
      frame_init(&s, &cams[c], &fd, &f);
      f.p.ert_seed = 1234u + (uint32_t)c;
      f.p.frame = frame_no;
      assert_int_equal(g_ops->ert_prepass(g_impl, &f.p, got), 0);
      rp__ert_prepass(&f.rg, s.occ->grid, s.occ->alpha_hist, s.h->blocks,
                      f.p.ref_step, f.p.ert_threshold, f.p.ert_seed,
                      frame_no, want);
      for (i = 0; i < gw * gh; i++) {
        double d = fabs((double)got[i] - want[i]);
        finite += isfinite(want[i]) != 0;
        if (got[i] == want[i] || d <= 1e-3 * (1.0 + fabs(want[i])))
          same++;
        else if (fabs(d - RP_ERT_COARSE_STEP) <= 1e-2)
          step_off++;
      }
      if (same + step_off != gw * gh || step_off * 1000 > gw * gh)
        fail_msg("camera %d frame %u: %u of %u rays equal, %u one step "
                 "off", c, frame_no, same, gw * gh, step_off);
      if (getenv("RP_VK_TEST_VERBOSE"))
        print_message("ert camera %d frame %u: %u same, %u off, %u finite "
                      "of %u\n", c, frame_no, same, step_off, finite,
                      gw * gh);
      /* The scene must actually terminate rays, or nothing was tested. */
      assert_true(finite > gw * gh / 8);
    }
  free(got);
  free(want);
  scene_free(&s);
}

/* ---- tests: device, cache, failures -------------------------------------- */

static void test_caps(void **state) {
  (void)state;
  assert_string_equal(g_caps.backend, "vulkan");
  assert_true(g_caps.device[0] != '\0');
  assert_int_equal(g_caps.effects, RP_EFFECT_SHADING | RP_EFFECT_ERT |
                                       RP_EFFECT_SKIP | RP_EFFECT_AO);
  assert_int_equal(g_caps.voxel_types,
                   (1u << RP_U8) | (1u << RP_U16) | (1u << RP_F32));
  assert_true(g_caps.max_alloc_bytes > 0);
  assert_true(g_caps.global_mem_bytes > 0);
  assert_true(g_caps.compute_units >= 1);
  assert_int_equal(g_caps.sub_device, 0);
}

/* Vulkan has no sub-devices: no partition_units op, and create refuses a
 * partition without creating anything. */
static void test_no_partition(void **state) {
  const rp_backend_ops *ops = NULL;
  void *impl = NULL;
  rp_caps caps;
  (void)state;
  assert_null(rp_vk_bootstrap.partition_units);
  assert_int_equal(rp_vk_bootstrap.create(g_ctx, 0, 1, &ops, &impl, &caps),
                   RP_EUNSUPPORTED);
  assert_null(impl);
  assert_non_null(strstr(rp_last_error(g_ctx), "partition"));
}

static const char *cache_dir(void) {
  static char dir[512];
  snprintf(dir, sizeof dir, "%s/vk-cache-test-%ld", rp_test_tmp_dir(),
           (long)getpid());
  return dir;
}

/* Creates a device, renders one shaded frame on it, returns its stats
 * after destroy has saved the cache (stats are read before). */
static void cached_device_run(const scene *s, rp_vk_stats *st) {
  const rp_backend_ops *ops = NULL;
  void *impl = NULL;
  rp_caps caps;
  rp_camera cams[3];
  frame f;
  frame_desc fd = {16, 16, 1.0f, 1.0f, RP_EFFECT_SHADING | RP_EFFECT_SKIP};
  uint8_t rgba[16 * 16 * 4];
  assert_int_equal(rp_vk_bootstrap.create(g_ctx, 0, 0, &ops, &impl, &caps),
                   0);
  scene_upload(s, impl);
  cameras(s->vol, cams);
  frame_init(s, &cams[0], &fd, &f);
  vk_render(impl, &f, NULL, rgba, NULL, NULL);
  rp_vk_get_stats(impl, st);
  ops->destroy(impl);
}

static void write_bytes(const char *path, const void *data, size_t n) {
  FILE *fp = fopen(path, "wb");
  assert_non_null(fp);
  assert_int_equal(fwrite(data, 1, n, fp), n);
  assert_int_equal(fclose(fp), 0);
}

static void test_pipeline_cache(void **state) {
  scene s;
  rp_vk_stats cold, warm, bad;
  char path[600];
  FILE *fp;
  long size;
  unsigned char *bytes;
  char *saved_env = getenv("RP_VK_PIPELINE_CACHE") != NULL
                        ? strdup(getenv("RP_VK_PIPELINE_CACHE"))
                        : NULL;
  (void)state;
  setenv("RP_VK_PIPELINE_CACHE", cache_dir(), 1);
  scene_init(&s, generate(RP_GEN_PHANTOM, 24, 24, 24, RP_U8),
             rp_test_preset(g_ctx, "ct-soft"));

  cached_device_run(&s, &cold);
  snprintf(path, sizeof path, "%s", cold.cache_path);
  remove(path); /* a leftover from an earlier run would make it warm */
  cached_device_run(&s, &cold);
  assert_int_equal(cold.cache_loaded, 0);
  assert_true(cold.pipelines_created >= 2);
  fp = fopen(path, "rb");
  assert_non_null(fp); /* destroy saved it */
  fclose(fp);

  cached_device_run(&s, &warm);
  assert_int_equal(warm.cache_loaded, 1);
  assert_true(warm.cache_bytes > 0);
  print_message("pipeline creation: %u pipelines, cold %.1f ms, with cache "
                "file %.1f ms (%zu bytes of driver data, %u driver-reported "
                "hits)\n", warm.pipelines_created,
                cold.pipeline_create_ns / 1e6, warm.pipeline_create_ns / 1e6,
                warm.cache_bytes, warm.pipeline_cache_hits);

  /* Corrupt: one byte flipped in the driver data. */
  fp = fopen(path, "rb");
  assert_non_null(fp);
  assert_int_equal(fseek(fp, 0, SEEK_END), 0);
  size = ftell(fp);
  rewind(fp);
  bytes = malloc((size_t)size);
  assert_non_null(bytes);
  assert_int_equal(fread(bytes, 1, (size_t)size, fp), (size_t)size);
  fclose(fp);
  bytes[size - 1] ^= 0x5a;
  write_bytes(path, bytes, (size_t)size);
  cached_device_run(&s, &bad);
  assert_int_equal(bad.cache_loaded, 0);
  assert_non_null(strstr(bad.cache_reject, "checksum"));

  /* Garbage, and a file cut short. */
  write_bytes(path, "not a pipeline cache at all", 27);
  cached_device_run(&s, &bad);
  assert_int_equal(bad.cache_loaded, 0);
  write_bytes(path, bytes, 10);
  cached_device_run(&s, &bad);
  assert_int_equal(bad.cache_loaded, 0);
  free(bytes);

  /* Whole and well-formed, but another driver's: its header names a
   * vendor no device here has. */
  {
    unsigned char foreign[sizeof(rp_vk_cache_header) +
                          sizeof(VkPipelineCacheHeaderVersionOne)];
    rp_vk_cache_header h;
    VkPipelineCacheHeaderVersionOne d;
    memset(&d, 0, sizeof d);
    d.headerSize = sizeof d;
    d.headerVersion = VK_PIPELINE_CACHE_HEADER_VERSION_ONE;
    d.vendorID = 0xfeed;
    memcpy(h.magic, RP_VK_CACHE_MAGIC, sizeof h.magic);
    h.size = sizeof d;
    h.checksum = rp_vk__fnv1a((const uint8_t *)&d, sizeof d);
    memcpy(foreign, &h, sizeof h);
    memcpy(foreign + sizeof h, &d, sizeof d);
    write_bytes(path, foreign, sizeof foreign);
    cached_device_run(&s, &bad);
    assert_int_equal(bad.cache_loaded, 0);
    assert_non_null(strstr(bad.cache_reject, "another device"));
  }

  /* The run above saved a good file again. */
  cached_device_run(&s, &warm);
  assert_int_equal(warm.cache_loaded, 1);
  remove(path);
  rmdir(cache_dir());
  if (saved_env != NULL)
    setenv("RP_VK_PIPELINE_CACHE", saved_env, 1);
  else
    unsetenv("RP_VK_PIPELINE_CACHE");
  free(saved_env);
  scene_free(&s);
}

static void test_bad_kernel(void **state) {
  const rp_backend_ops *ops = NULL;
  void *impl = NULL;
  rp_caps caps;
  int k;
  (void)state;
  for (k = 0; k < RP_VK_KERNEL_COUNT; k++) {
    rp_vk_hooks.corrupt_kernel = k + 1;
    assert_int_equal(rp_vk_bootstrap.create(g_ctx, 0, 0, &ops, &impl, &caps),
                     RP_EBUILD);
    rp_vk_hooks.corrupt_kernel = 0;
    assert_non_null(strstr(rp_last_error(g_ctx), "SPIR-V"));
  }
  assert_non_null(strstr(rp_last_error(g_ctx), "'ao'"));
}

static void test_too_big(void **state) {
  struct rp_volume big;
  rp_vk_buffer b;
  char want[64];
  (void)state;
  /* Never read: the limits are checked before any voxel is. */
  memset(&big, 0, sizeof big);
  big.ctx = g_ctx;
  big.dims[0] = big.dims[1] = big.dims[2] = 2048;
  big.type = RP_U16;
  big.voxel_count = (size_t)2048 * 2048 * 2048;
  assert_int_equal(g_ops->upload_volume(g_impl, &big), RP_EUNSUPPORTED);
  assert_non_null(strstr(rp_last_error(g_ctx), "maxTexelBufferElements"));
  /* An allocation over the device's limit names its size. */
  assert_int_equal(rp_vk__buffer((rp_vk_impl *)g_impl, "test buffer",
                                 g_caps.max_alloc_bytes + 1,
                                 VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 0, &b),
                   RP_ENOMEM);
  snprintf(want, sizeof want, "%llu",
           (unsigned long long)(g_caps.max_alloc_bytes + 1));
  assert_non_null(strstr(rp_last_error(g_ctx), want));
  /* An image whose depth buffer a kernel could not address: refused
   * before anything is allocated or dispatched. */
  {
    uint64_t range =
        ((rp_vk_impl *)g_impl)->props.limits.maxStorageBufferRange;
    rp_frame_params p;
    memset(&p, 0, sizeof p);
    p.width = 4096;
    p.height = (uint32_t)(range / (8u * 4096u) + 1);
    assert_int_equal(g_ops->depth_pass(g_impl, &p, NULL), RP_EUNSUPPORTED);
    /* (A device with a huge range may hit its dispatch limit first.) */
    assert_true(strstr(rp_last_error(g_ctx), "maxStorageBufferRange") ||
                strstr(rp_last_error(g_ctx), "workgroups"));
  }
}

/* With the loader pointed at no driver, probe finds nothing (no error)
 * and create says so. */
static void test_no_driver(void **state) {
  const char *vars[2] = {"VK_ICD_FILENAMES", "VK_DRIVER_FILES"};
  char *saved[2];
  const rp_backend_ops *ops = NULL;
  void *impl = NULL;
  rp_caps caps;
  uint32_t count = 99;
  int i;
  (void)state;
  for (i = 0; i < 2; i++) {
    const char *v = getenv(vars[i]);
    saved[i] = v != NULL ? strdup(v) : NULL;
    setenv(vars[i], "/nonexistent/raypace-no-icd.json", 1);
  }
  assert_int_equal(rp_vk_bootstrap.probe(g_ctx, &count), 0);
  assert_int_equal(count, 0);
  assert_int_equal(rp_vk_bootstrap.create(g_ctx, 0, 0, &ops, &impl, &caps),
                   RP_ENODEV);
  for (i = 0; i < 2; i++) {
    if (saved[i] != NULL)
      setenv(vars[i], saved[i], 1);
    else
      unsetenv(vars[i]);
    free(saved[i]);
  }
  assert_int_equal(rp_vk_bootstrap.probe(g_ctx, &count), 0);
  assert_true(count >= 1);
}

static int group_setup(void **state) {
  (void)state;
  g_ctx = rp_test_context();
  return rp_vk_bootstrap.create(g_ctx, 0, 0, &g_ops, &g_impl, &g_caps);
}

static int group_teardown(void **state) {
  (void)state;
  g_ops->destroy(g_impl);
  rp_context_destroy(g_ctx);
  return 0;
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_caps),
      cmocka_unit_test(test_no_partition),
      cmocka_unit_test(test_phantom_u8),
      cmocka_unit_test(test_marschner_lobb_u16),
      cmocka_unit_test(test_float32),
      cmocka_unit_test(test_noise),
      cmocka_unit_test(test_odd_viewports),
      cmocka_unit_test(test_thin_volumes),
      cmocka_unit_test(test_layouts_agree),
      cmocka_unit_test(test_ao_volume),
      cmocka_unit_test(test_ao_render),
      cmocka_unit_test(test_ao_state),
      cmocka_unit_test(test_fetch_counts),
      cmocka_unit_test(test_regions),
      cmocka_unit_test(test_prepare),
      cmocka_unit_test(test_prepare_ao),
      cmocka_unit_test(test_prepare_no_volume),
      cmocka_unit_test(test_prepare_concurrent),
      cmocka_unit_test(test_depth_pass),
      cmocka_unit_test(test_ert_prepass),
      cmocka_unit_test(test_pipeline_cache),
      cmocka_unit_test(test_bad_kernel),
      cmocka_unit_test(test_too_big),
      cmocka_unit_test(test_no_driver),
  };
  rp_context *ctx = rp_test_context();
  uint32_t count = 0;
  rp_vk_bootstrap.probe(ctx, &count);
  rp_context_destroy(ctx);
  if (count == 0) {
    printf("no Vulkan device: skipped\n");
    return 77;
  }
  return cmocka_run_group_tests(tests, group_setup, group_teardown);
}
