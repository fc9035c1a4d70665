/* The Vulkan backend, driven directly through rp_vk_bootstrap and its ops
 * (no front end): only what is Vulkan's own. What every backend shares
 * (images, depth and ERT passes, regions, fetch counts, AO, kernels built
 * ahead, the kernel-variant cache) is held to the contract in
 * tests/conformance, run per backend. Here: the volume's two layouts and
 * upload paths, AO in the plain layout and in slabs with its buffers'
 * life, the opacity correction as a specialization constant, the
 * pipeline cache file, SPIR-V checks, device limits, a missing driver,
 * and no sub-devices.
 *
 * Exits 77 (skipped) when no Vulkan device is present. */
#include "test_util.h"

#include <math.h>
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
  return rp_test_generate(g_ctx, kind, nx, ny, nz, type, 11);
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
  double span[2];
  d.width = fd->width;
  d.height = fd->height;
  d.step = fd->step;
  d.effects = fd->effects;
  d.image_scale = fd->scale;
  f->d = rp__render_desc_defaults(&d);
  rp_tf_lut(s->tf, &lut_size);
  rp__tf_volume_range(s->tf, s->vol, span);
  assert_int_equal(rp__frame_params(g_ctx, s->vol, s->occ, cam, &f->d,
                                    rp_tf_reference_step(s->tf),
                                    (uint32_t)lut_size, span, &f->rg, &f->p),
                   0);
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

/* The three cameras: outside in perspective, inside the volume, and an
 * axis-aligned orthographic view (rays with exactly zero components). */
static void cameras(const rp_volume *vol, rp_camera cams[3]) {
  memset(cams, 0, 3 * sizeof cams[0]);
  rp_camera_orbit(&cams[0], vol, 30.0f, 20.0f, 2.2f);
  rp_camera_orbit(&cams[1], vol, -40.0f, 10.0f, 0.35f);
  cams[2].projection = RP_ORTHOGRAPHIC;
  rp_camera_orbit(&cams[2], vol, 90.0f, 0.0f, 3.0f);
}

/* ---- tests: layouts ------------------------------------------------------ */

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
                          : rp_test_float_field(g_ctx),
               rp_test_ramp_tf(g_ctx, 1.0f));
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

/* AO in both layouts, against the reference (the plain layout reads the
 * same voxels as the quad one), and a box computed in slabs of one brick
 * layer equal to the same voxels of the whole, bit for bit; compute_ao's
 * buffers live only during each call (vk_ao_box). */
static void test_ao_layouts(void **state) {
  const uint32_t lo[3] = {3, 6, 2}, end[3] = {38, 35, 31};
  const uint32_t zero[3] = {0, 0, 0};
  rp_ao_desc d = {0};
  scene s;
  int plain;
  (void)state;
  scene_init(&s, generate(RP_GEN_PHANTOM, 40, 37, 33, RP_U8),
             rp_test_preset(g_ctx, "minmax-soft"));
  for (plain = 0; plain < 2; plain++) {
    rp_ao_plan *plan = NULL;
    rp_ao *ref = NULL;
    rp_vk_stats st;
    uint8_t *got, *part;
    uint32_t x, y, z;
    rp_vk_hooks.force_plain = plain;
    scene_upload(&s, NULL);
    rp_vk_hooks.force_plain = 0;
    rp_vk_get_stats(g_impl, &st);
    assert_int_equal(st.quad_layout, !plain);
    assert_int_equal(rp_ao_compute_reference(g_ctx, s.vol, s.tf, &d, NULL,
                                             NULL, &ref),
                     0);
    assert_int_equal(rp_ao_plan_create(g_ctx, s.vol, s.tf, &d, &plan), 0);
    got = vk_ao_box(&s, plan, zero, s.vol->dims);
    check_ao(got, rp_ao_data(ref, NULL), s.vol->voxel_count, 1,
             plain ? "AO plain layout" : "AO quad layout");
    rp_vk_hooks.ao_chunk_bytes = 1;
    part = vk_ao_box(&s, plan, lo, end);
    rp_vk_hooks.ao_chunk_bytes = 0;
    for (z = lo[2]; z < end[2]; z++)
      for (y = lo[1]; y < end[1]; y++)
        for (x = lo[0]; x < end[0]; x++) {
          uint8_t pv = part[((size_t)(z - lo[2]) * (end[1] - lo[1]) +
                             (y - lo[1])) * (end[0] - lo[0]) + (x - lo[0])];
          uint8_t wv = got[((size_t)z * 37 + y) * 40 + x];
          if (pv != wv)
            fail_msg("slabs (plain %d): voxel (%u,%u,%u) is %u, %u in the "
                     "whole volume", plain, x, y, z, pv, wv);
        }
    free(part);
    free(got);
    rp_ao_plan_destroy(plan);
    rp_ao_destroy(ref);
  }
  scene_free(&s);
}

/* AO memory exists only while an AO volume is uploaded: upload_ao makes
 * the R8 texel buffer and its view, uploading again reuses them,
 * upload_ao(NULL) frees both; a volume of the same shape keeps it, one of
 * another shape drops it (conformance's ao_state holds every backend to
 * refusing what it does not hold). */
static void test_ao_memory(void **state) {
  rp_vk_impl *impl = g_impl;
  rp_camera cams[3];
  rp_vk_stats st;
  scene s;
  frame f;
  frame_desc fd = {16, 16, 1.0f, 1.0f, RP_EFFECT_AO | RP_EFFECT_SHADING};
  uint8_t rgba[16 * 16 * 4];
  uint8_t *ao;
  (void)state;
  scene_init(&s, generate(RP_GEN_PHANTOM, 24, 20, 18, RP_U8),
             rp_test_preset(g_ctx, "minmax-soft"));
  scene_upload(&s, NULL);
  cameras(s.vol, cams);
  frame_init(&s, &cams[0], &fd, &f);
  assert_int_equal(g_ops->upload_ao(g_impl, NULL), 0);
  assert_int_equal(impl->ao.buf, VK_NULL_HANDLE);
  ao = malloc(s.vol->voxel_count);
  assert_non_null(ao);
  memset(ao, 128, s.vol->voxel_count);
  assert_int_equal(g_ops->upload_ao(g_impl, ao), 0);
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.ao_bytes, s.vol->voxel_count);
  assert_true(impl->ao_view != VK_NULL_HANDLE);
  vk_render(NULL, &f, NULL, rgba, NULL, NULL);
  assert_int_equal(g_ops->upload_ao(g_impl, ao), 0);
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.ao_bytes, s.vol->voxel_count);
  assert_int_equal(g_ops->upload_ao(g_impl, NULL), 0);
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.ao_bytes, 0);
  assert_int_equal(impl->ao.buf, VK_NULL_HANDLE);
  assert_int_equal(impl->ao_view, VK_NULL_HANDLE);
  /* Same shape kept, another shape dropped. */
  assert_int_equal(g_ops->upload_ao(g_impl, ao), 0);
  assert_int_equal(g_ops->upload_volume(g_impl, s.vol), 0);
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.ao_bytes, s.vol->voxel_count);
  free(ao);
  scene_free(&s);
  scene_init(&s, generate(RP_GEN_PHANTOM, 20, 20, 18, RP_U8),
             rp_test_preset(g_ctx, "minmax-soft"));
  scene_upload(&s, NULL);
  rp_vk_get_stats(g_impl, &st);
  assert_int_equal(st.ao_bytes, 0);
  assert_int_equal(impl->ao.buf, VK_NULL_HANDLE);
  scene_free(&s);
}

/* The opacity correction is a specialization constant: a frame at a step
 * other than the TF's reference step needs a raycast pipeline of its
 * own, one more than a frame at the reference step, and prepare builds
 * the raycast both ways (and the depth pass), so that neither frame
 * builds. */
static void test_step_kind(void **state) {
  const uint32_t effects = RP_EFFECT_SHADING | RP_EFFECT_ERT |
                           RP_EFFECT_SKIP;
  const rp_backend_ops *ops = NULL;
  rp_context *ctx2 = rp_test_context();
  void *plain = NULL, *prep = NULL;
  rp_variant_stats a, b;
  rp_camera cams[3];
  uint8_t *img = malloc(64 * 64 * 4);
  rp_caps caps;
  scene s;
  frame f;
  int i;
  (void)state;
  assert_non_null(img);
  assert_int_equal(rp_vk_bootstrap.create(g_ctx, 0, 0, &ops, &plain, &caps),
                   0);
  assert_int_equal(rp_vk_bootstrap.create(g_ctx, 0, 0, &ops, &prep, &caps),
                   0);
  scene_init(&s, generate(RP_GEN_PHANTOM, 32, 32, 32, RP_U8),
             rp_test_ramp_tf(g_ctx, 1.0f));
  cameras(s.vol, cams);
  scene_upload(&s, plain);
  scene_upload(&s, prep);
  assert_int_equal(ops->prepare(prep, ctx2, effects), 0);
  rp_vk__variant_stats(prep, &a);
  assert_int_equal(a.builds, 3);
  for (i = 0; i < 2; i++) {
    frame_desc fd = {64, 64, 1.0f, i ? 0.6f : 1.0f, effects};
    frame_init(&s, &cams[0], &fd, &f);
    rp_vk__variant_stats(plain, &a);
    vk_render(plain, &f, NULL, img, NULL, NULL);
    rp_vk__variant_stats(plain, &b);
    /* The first: depth pass and raycast; the second: another raycast. */
    assert_int_equal(b.builds, a.builds + (i ? 1u : 2u));
    vk_render(prep, &f, NULL, img, NULL, NULL);
    rp_vk__variant_stats(prep, &b);
    assert_int_equal(b.builds, 3);
  }
  ops->destroy(plain);
  ops->destroy(prep);
  rp_context_destroy(ctx2);
  scene_free(&s);
  free(img);
}

/* ---- tests: device, cache, failures -------------------------------------- */

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
             rp_test_preset(g_ctx, "minmax-soft"));

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
      cmocka_unit_test(test_no_partition),
      cmocka_unit_test(test_layouts_agree),
      cmocka_unit_test(test_ao_layouts),
      cmocka_unit_test(test_ao_memory),
      cmocka_unit_test(test_step_kind),
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
