/* The OpenCL backend, driven directly through rp_cl_bootstrap and its ops
 * (no front end): what is specific to it. The cross-backend image matrix
 * lives in tests/conformance; here a smoke-level comparison suffices,
 * plus what only this backend has: compiled-out effects and the fetch
 * counting variant, the program cache, build errors with their log,
 * sub-devices, regions written in place, its depth and ERT passes, its
 * own (hand-written) opacity correction, and its AO volume kernel and
 * AO raycast variant.
 *
 * Exits 77 (skipped) when no OpenCL device is present. Kernels compile
 * once per option set; with POCL_CACHE_DIR kept between runs (ctest sets
 * it under the build tree) later runs take a few seconds. */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "ao.h"
#include "cl_internal.h"
#include "passes.h"
#include "test_util.h"

static rp_context *ctx;
static uint32_t device_count;

/* ---- fixtures ------------------------------------------------------------ */

typedef struct scene {
  rp_volume *vol;
  rp_histograms *h;
  rp_tf *tf;
  rp_occupancy *occ;
} scene;

typedef struct device {
  const rp_backend_ops *ops;
  void *impl;
  rp_caps caps;
} device;

static void open_device(uint32_t index, device *d) {
  int err =
      rp_cl_bootstrap.create(ctx, index, 0, &d->ops, &d->impl, &d->caps);
  if (err != 0)
    fail_msg("create(%u): %s", (unsigned)index, rp_last_error(ctx));
}

static void close_device(device *d) { d->ops->destroy(d->impl); }

static scene make_scene(rp_generator kind, uint32_t x, uint32_t y,
                        uint32_t z, rp_voxel_type type, const char *tf) {
  scene s = {0};
  rp_generate_desc g = {0};
  g.kind = kind, g.dims[0] = x, g.dims[1] = y, g.dims[2] = z;
  g.type = type, g.seed = 11;
  assert_int_equal(rp_volume_generate(ctx, &g, &s.vol), 0);
  assert_int_equal(rp_histograms_build(ctx, s.vol, &s.h), 0);
  assert_int_equal(rp_tf_create_preset(ctx, tf, &s.tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, s.h, s.tf, &s.occ), 0);
  return s;
}

/* A float volume: a smooth blob, so that gradients and lighting vary. */
static scene float_scene(const char *tf) {
  scene s = {0};
  rp_volume_desc d = {{21, 18, 25}, RP_F32, {1.0f, 1.3f, 0.8f}, NULL};
  float *v = malloc(21 * 18 * 25 * sizeof *v);
  uint32_t i, j, k;
  assert_non_null(v);
  for (k = 0; k < 25; k++)
    for (j = 0; j < 18; j++)
      for (i = 0; i < 21; i++) {
        double dx = i - 10.0, dy = (j - 9.0) * 1.3, dz = (k - 12.0) * 0.8;
        v[(k * 18 + j) * 21 + i] =
            (float)(-3.5 + 100.0 * exp(-(dx * dx + dy * dy + dz * dz) / 40.0));
      }
  d.data = v;
  assert_int_equal(rp_volume_create(ctx, &d, &s.vol), 0);
  free(v);
  assert_int_equal(rp_histograms_build(ctx, s.vol, &s.h), 0);
  assert_int_equal(rp_tf_create_preset(ctx, tf, &s.tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, s.h, s.tf, &s.occ), 0);
  return s;
}

static void drop_scene(scene *s) {
  rp_occupancy_destroy(s->occ);
  rp_tf_destroy(s->tf);
  rp_histograms_destroy(s->h);
  rp_volume_destroy(s->vol);
}

static void upload(const device *d, const scene *s) {
  int n = 0;
  const float *lut = rp_tf_lut(s->tf, &n);
  if (d->ops->upload_volume(d->impl, s->vol) != 0 ||
      d->ops->upload_tf(d->impl, lut, (uint32_t)n) != 0 ||
      d->ops->upload_occupancy(d->impl, rp_occupancy_grid(s->occ),
                               rp_occupancy_alpha_hist(s->occ),
                               s->h->blocks) != 0)
    fail_msg("upload: %s", rp_last_error(ctx));
}

static rp_camera camera(const rp_volume *vol, int kind) {
  rp_camera c = {0};
  if (kind == 0) { /* outside, perspective */
    rp_camera_orbit(&c, vol, 30, 20, 2.2f);
  } else if (kind == 1) { /* inside the volume */
    rp_camera_orbit(&c, vol, 200, -15, 0.35f);
    c.fov_y_deg = 70.0f;
  } else if (kind == 2) { /* orthographic */
    c.projection = RP_ORTHOGRAPHIC;
    rp_camera_orbit(&c, vol, 45, 35, 3.0f);
  } else { /* looking away: every ray misses */
    rp_camera_orbit(&c, vol, 10, 5, 3.0f);
    c.center[0] = 2.0f * c.eye[0];
    c.center[1] = 2.0f * c.eye[1];
    c.center[2] = 2.0f * c.eye[2];
  }
  return c;
}

/* A frame as the front end builds it: the camera resolved for the output
 * size, rays for the scaled size, everything in float. `d` comes back
 * with its defaults resolved and `rg` at the scaled size, ready for
 * the C reference. */
static void frame_params(const scene *s, const rp_camera *cam,
                         rp_render_desc *d, rp__raygen *rg,
                         rp_frame_params *p) {
  *d = rp__render_desc_defaults(d);
  assert_int_equal(rp__frame_params(ctx, s->vol, s->occ, cam, d,
                                    rp_tf_reference_step(s->tf),
                                    (uint32_t)s->tf->lut_size, rg, p),
                   0);
}

/* Output of one raycast (or of the reference) at the scaled size. */
typedef struct image {
  uint32_t w, h, tx, ty;
  uint8_t *rgba;
  rp_tile_stats *tiles;
  uint64_t *fetches;
} image;

static void image_alloc(image *im, uint32_t w, uint32_t h) {
  im->w = w, im->h = h;
  rp_tile_grid(w, h, &im->tx, &im->ty);
  im->rgba = calloc((size_t)w * h, 4);
  im->tiles = calloc((size_t)im->tx * im->ty, sizeof *im->tiles);
  im->fetches = calloc((size_t)im->tx * im->ty, sizeof *im->fetches);
  assert_true(im->rgba != NULL && im->tiles != NULL && im->fetches != NULL);
}

static void image_free(image *im) {
  free(im->rgba), free(im->tiles), free(im->fetches);
}

/* Depth pass, then a raycast of the whole scaled image. */
static void render(const device *dev, const rp_frame_params *p, image *im,
                   int count_fetches) {
  rp_region all = {0, 0, p->width, p->height};
  if (dev->ops->depth_pass(dev->impl, p, NULL) != 0 ||
      dev->ops->raycast(dev->impl, p, &all, im->rgba, im->tiles,
                        count_fetches ? im->fetches : NULL) != 0)
    fail_msg("render: %s", rp_last_error(ctx));
}

/* The reference's image and tiles, and its fetches when `fetches`. */
static void reference(const scene *s, const rp__raygen *rg,
                      const rp_render_desc *d, image *im, int fetches) {
  rp_region all = {0, 0, rg->width, rg->height};
  const uint8_t *grid =
      (d->effects & RP_EFFECT_SKIP) ? rp_occupancy_grid(s->occ) : NULL;
  rp__reference_render(s->vol, s->tf, grid, s->h->blocks, NULL, rg, d,
                       &all, im->rgba, im->tiles,
                       fetches ? im->fetches : NULL);
}

/* The contract's tolerance: at most 0.1 % of pixels more than 2/255 off
 * in a channel, none more than 8/255; tile sample counts within one per
 * ray. Returns the worst channel difference. */
static int compare(const char *what, const image *got, const image *want) {
  uint32_t i, k, over = 0;
  int worst = 0;
  for (i = 0; i < got->w * got->h; i++) {
    int c, m = 0;
    for (c = 0; c < 4; c++) {
      int dd = abs((int)got->rgba[4 * i + c] - (int)want->rgba[4 * i + c]);
      m = dd > m ? dd : m;
    }
    over += m > 2;
    if (m > worst)
      worst = m;
  }
  if (worst > 8 || over > 0.001 * got->w * got->h)
    fail_msg("%s: worst %d/255, %u of %u pixels over 2/255", what, worst,
             (unsigned)over, (unsigned)(got->w * got->h));
  for (k = 0; k < got->tx * got->ty; k++) {
    int64_t dd = (int64_t)got->tiles[k].samples - want->tiles[k].samples;
    if (llabs(dd) > RP_TILE_SIZE * RP_TILE_SIZE)
      fail_msg("%s: tile %u takes %u samples, the reference %u", what,
               (unsigned)k, got->tiles[k].samples, want->tiles[k].samples);
  }
  return worst;
}

static uint64_t total_samples(const image *im) {
  uint64_t n = 0;
  uint32_t k;
  for (k = 0; k < im->tx * im->ty; k++)
    n += im->tiles[k].samples;
  return n;
}

/* The program cache's builds and hits (variant_cache.h's figures). */
static void cache_stats(void *impl, uint32_t *builds, uint32_t *hits) {
  rp_variant_stats st;
  rp_cl__variant_stats(impl, &st);
  *builds = st.builds;
  *hits = st.hits;
}

static double now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* ---- tests --------------------------------------------------------------- */

static void probe_and_caps(void **state) {
  device d;
  uint32_t n = 0;
  (void)state;
  assert_int_equal(rp_cl_bootstrap.probe(ctx, &n), 0);
  assert_int_equal(n, device_count);
  assert_string_equal(rp_cl_bootstrap.name, "opencl");
  open_device(0, &d);
  assert_string_equal(d.caps.backend, "opencl");
  assert_true(d.caps.device[0] != '\0');
  assert_int_equal(d.caps.sub_device, 0);
  assert_int_equal(d.caps.effects, RP_EFFECT_SHADING | RP_EFFECT_ERT |
                                       RP_EFFECT_SKIP | RP_EFFECT_AO);
  assert_int_equal(d.caps.voxel_types,
                   (1u << RP_U8) | (1u << RP_U16) | (1u << RP_F32));
  assert_true(d.caps.compute_units >= 1);
  assert_true(d.caps.max_alloc_bytes > 0 &&
              d.caps.max_alloc_bytes <= d.caps.global_mem_bytes);
  close_device(&d);
  /* Past the end is RP_ENODEV with a message, not a crash. */
  assert_int_equal(
      rp_cl_bootstrap.create(ctx, n, 0, &d.ops, &d.impl, &d.caps),
      RP_ENODEV);
  assert_non_null(strstr(rp_last_error(ctx), "does not exist"));
}

/* (1) Shading compiled out costs nothing: fewer fetches, the same samples; and
 * the counting variant's fetches are the reference's: one per sample,
 * six more per sample with opacity above 0 (the others are not shaded). */
static void shading_fetch_counts(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 64, 64, 64, RP_U8, "ct-soft");
  rp_camera cam = camera(s.vol, 0);
  device dev;
  image plain, lit, want;
  uint64_t f_plain = 0, f_lit = 0, total = 0, off = 0, samples = 0;
  uint32_t k;
  int r;
  (void)state;
  open_device(0, &dev);
  upload(&dev, &s);
  for (r = 0; r < 2; r++) {
    rp_render_desc d = {0};
    rp__raygen rg;
    rp_frame_params p;
    image *im = r ? &lit : &plain;
    d.width = d.height = 96;
    d.effects = RP_EFFECT_SKIP | (r ? RP_EFFECT_SHADING : 0u);
    frame_params(&s, &cam, &d, &rg, &p);
    image_alloc(im, p.width, p.height);
    image_alloc(&want, p.width, p.height);
    render(&dev, &p, im, 1);
    reference(&s, &rg, &d, &want, 1);
    rp_test_check_fetches(r ? "shaded" : "plain", im->tiles, im->fetches,
                          want.tiles, want.fetches, im->tx * im->ty,
                          rp_test_visible_fetches(d.effects), &total, &off);
    for (k = 0; k < im->tx * im->ty; k++) {
      if (r)
        f_lit += im->fetches[k];
      else
        f_plain += im->fetches[k], samples += im->tiles[k].samples;
    }
    image_free(&want);
  }
  /* Shading changes colour, never opacity: the same samples are taken. */
  assert_memory_equal(plain.tiles, lit.tiles,
                      plain.tx * plain.ty * sizeof *plain.tiles);
  /* Unshaded: one fetch a sample. Shaded: this view shows soft tissue
   * through transparent air inside occupied blocks, so some samples are
   * shaded and some not. */
  assert_true(f_plain > 0 && f_plain == samples);
  assert_true(f_lit > f_plain && f_lit < 7 * f_plain);
  /* What the extra fetches cost in time is a benchmark's figure, not a
   * unit test's (bench_backends: ert+skip against shade+ert+skip): on a
   * shared machine a timing order between two renders can flip (it did
   * once, in CI, at 160^2, best of nine each). */
  print_message("fetches %llu vs %llu (no shading vs shading)\n",
                (unsigned long long)f_plain, (unsigned long long)f_lit);
  image_free(&plain);
  image_free(&lit);
  close_device(&dev);
  drop_scene(&s);
}

/* (2) A program is built once per option set and device. */
static void build_cache(void **state) {
  device dev;
  uint32_t b0, h0, b1, h1;
  (void)state;
  open_device(0, &dev);
  cache_stats(dev.impl, &b0, &h0);
  assert_int_equal(b0, 0);
  assert_int_equal(rp_cl__prepare_raycast(dev.impl, RP_EFFECT_ERT, 0), 0);
  cache_stats(dev.impl, &b1, &h1);
  assert_int_equal(b1, 1);
  assert_int_equal(h1, h0);
  assert_int_equal(rp_cl__prepare_raycast(dev.impl, RP_EFFECT_ERT, 0), 0);
  cache_stats(dev.impl, &b1, &h1);
  assert_int_equal(b1, 1);
  assert_int_equal(h1, h0 + 1);
  /* Another effect set, or the counting variant, is another program. */
  assert_int_equal(rp_cl__prepare_raycast(dev.impl, RP_EFFECT_SKIP, 0), 0);
  assert_int_equal(rp_cl__prepare_raycast(dev.impl, RP_EFFECT_ERT, 1), 0);
  cache_stats(dev.impl, &b1, &h1);
  assert_int_equal(b1, 3);
  /* AO is compiled in or out like the others. */
  assert_int_equal(rp_cl__prepare_raycast(dev.impl,
                                          RP_EFFECT_ERT | RP_EFFECT_AO, 0),
                   0);
  cache_stats(dev.impl, &b1, &h1);
  assert_int_equal(b1, 4);
  close_device(&dev);
}

/* (2b) prepare builds a frame's kernels on another thread while this
 * one renders other frames on the same device: afterwards that frame
 * builds nothing and renders what a fresh device renders. */
typedef struct prepare_job {
  device *dev;
  rp_context *ctx;
  uint32_t effects;
  int rc;
} prepare_job;

static void *prepare_thread(void *arg) {
  prepare_job *j = arg;
  j->rc = j->dev->ops->prepare(j->dev->impl, j->ctx, j->effects);
  return NULL;
}

static void prepare_ahead(void **state) {
  const uint32_t want = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  scene s = make_scene(RP_GEN_PHANTOM, 24, 20, 22, RP_U16, "ct-bone");
  rp_camera cam = camera(s.vol, 0);
  rp_render_desc d = {0};
  rp__raygen rg;
  rp_frame_params p;
  device dev, fresh;
  image im, again;
  prepare_job job;
  pthread_t th;
  uint32_t b0, h0, b1, h1;
  int i;
  rp_context *ctx2 = rp_test_context();
  (void)state;
  open_device(0, &dev);
  /* No volume yet: nothing to build for, and the error is the caller's,
   * not the device's context's. */
  rp__clear_error(ctx);
  assert_int_equal(dev.ops->prepare(dev.impl, ctx2, want), RP_ESTATE);
  assert_non_null(strstr(rp_last_error(ctx2), "volume"));
  assert_string_equal(rp_last_error(ctx), "");
  upload(&dev, &s);
  d.width = 64, d.height = 48, d.effects = RP_EFFECT_ERT;
  frame_params(&s, &cam, &d, &rg, &p);
  image_alloc(&im, p.width, p.height);
  image_alloc(&again, p.width, p.height);
  job.dev = &dev, job.ctx = ctx2, job.effects = want, job.rc = -1;
  assert_int_equal(pthread_create(&th, NULL, prepare_thread, &job), 0);
  for (i = 0; i < 4; i++)
    render(&dev, &p, &im, 0);
  assert_int_equal(pthread_join(th, NULL), 0);
  assert_int_equal(job.rc, 0);
  /* Both kernels of the prepared set are there: the frame builds none,
   * and a second prepare finds them. */
  d.effects = want;
  frame_params(&s, &cam, &d, &rg, &p);
  cache_stats(dev.impl, &b0, &h0);
  render(&dev, &p, &im, 0);
  cache_stats(dev.impl, &b1, &h1);
  assert_int_equal(b1, b0);
  assert_int_equal(h1, h0 + 2);
  assert_int_equal(dev.ops->prepare(dev.impl, ctx2, want), 0);
  cache_stats(dev.impl, &b1, &h1);
  assert_int_equal(b1, b0);
  /* The same kernel a frame builds for itself. */
  open_device(0, &fresh);
  upload(&fresh, &s);
  render(&fresh, &p, &again, 0);
  assert_memory_equal(im.rgba, again.rgba, (size_t)p.width * p.height * 4);
  assert_memory_equal(im.tiles, again.tiles,
                      (size_t)im.tx * im.ty * sizeof *im.tiles);
  image_free(&im);
  image_free(&again);
  close_device(&fresh);
  close_device(&dev);
  rp_context_destroy(ctx2);
  drop_scene(&s);
}

/* (3) A program that does not compile: RP_EBUILD, naming what was built
 * and quoting the compiler. */
static void build_failure(void **state) {
  static const char bad[] =
      "__kernel void broken(__global float *out) {\n"
      "  out[0] = no_such_identifier_here * 2.0f;\n"
      "}\n";
  device dev;
  const char *msg;
  (void)state;
  open_device(0, &dev);
  assert_int_equal(rp_cl__build_program_for_test(dev.impl, bad, ""),
                   RP_EBUILD);
  msg = rp_last_error(ctx);
  print_message("build error: %s\n", msg);
  assert_non_null(strstr(msg, "test kernel"));
  assert_non_null(strstr(msg, "no_such_identifier_here"));
  assert_non_null(strstr(msg, "error"));
  /* Bad options are a build error too. */
  assert_int_equal(rp_cl__build_program_for_test(dev.impl,
                                                 "__kernel void k(void){}",
                                                 "-cl-no-such-option"),
                   RP_EBUILD);
  /* And a good one builds. */
  assert_int_equal(rp_cl__build_program_for_test(
                       dev.impl, "__kernel void k(void) {}", ""), 0);
  /* Other failures name the OpenCL error and say what was done. */
  assert_int_equal(rp_cl__fail(ctx, CL_MEM_OBJECT_ALLOCATION_FAILURE,
                               "clCreateBuffer"), RP_ENOMEM);
  assert_non_null(strstr(rp_last_error(ctx),
                         "CL_MEM_OBJECT_ALLOCATION_FAILURE (-4)"));
  assert_int_equal(rp_cl__fail(ctx, CL_INVALID_BUFFER_SIZE, "alloc"),
                   RP_ENOMEM);
  assert_int_equal(rp_cl__fail(ctx, CL_INVALID_KERNEL_ARGS, "running x"),
                   RP_EDEVICE);
  assert_non_null(strstr(rp_last_error(ctx), "running x"));
  close_device(&dev);
}

/* (4) Sub-devices: one compute unit each, and the same image. */
static void sub_devices(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 48, 48, 48, RP_U8, "ct-bone");
  rp_camera cam = camera(s.vol, 0);
  rp_render_desc d = {0};
  rp__raygen rg;
  rp_frame_params p;
  device whole, part;
  image a, b;
  (void)state;
  if (device_count < 2) {
    drop_scene(&s);
    skip();
  }
  d.width = 61, d.height = 40;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  frame_params(&s, &cam, &d, &rg, &p);
  open_device(0, &whole);
  open_device(1, &part);
  assert_int_equal(part.caps.sub_device, 1);
  assert_int_equal(part.caps.compute_units, 1);
  assert_non_null(strstr(part.caps.device, "sub-device"));
  upload(&whole, &s);
  upload(&part, &s);
  image_alloc(&a, p.width, p.height);
  image_alloc(&b, p.width, p.height);
  render(&whole, &p, &a, 0);
  render(&part, &p, &b, 0);
  /* The same kernels on the same CPU: identical, not just close. */
  assert_memory_equal(a.rgba, b.rgba, (size_t)p.width * p.height * 4);
  assert_memory_equal(a.tiles, b.tiles, a.tx * a.ty * sizeof *a.tiles);
  assert_true(total_samples(&a) > 0);
  image_free(&a);
  image_free(&b);
  close_device(&part);
  close_device(&whole);
  drop_scene(&s);
}

/* (4b) Partitions asked for by size (rp_device_desc's compute_units):
 * device 0 reports the compute units it can be split into, a listed
 * sub-device will not split again, and a partition the driver refuses is
 * RP_EUNSUPPORTED naming the OpenCL error (the front end's range check
 * is skipped here on purpose). */
static void partitions(void **state) {
  device d;
  uint32_t units = 0;
  (void)state;
  assert_non_null(rp_cl_bootstrap.partition_units);
  if (rp_cl_bootstrap.partition_units(ctx, 0, &units) == RP_EUNSUPPORTED)
    skip();
  open_device(0, &d);
  assert_int_equal(units, d.caps.compute_units);
  close_device(&d);
  assert_int_equal(rp_cl_bootstrap.partition_units(ctx, device_count,
                                                   &units),
                   RP_ENODEV);
  if (device_count >= 2) {
    assert_int_equal(rp_cl_bootstrap.partition_units(ctx, 1, &units),
                     RP_EUNSUPPORTED);
    assert_non_null(strstr(rp_last_error(ctx), "already a sub-device"));
  }
  d.impl = NULL;
  assert_int_equal(rp_cl_bootstrap.create(ctx, 0, units + 1, &d.ops,
                                          &d.impl, &d.caps),
                   RP_EUNSUPPORTED);
  assert_null(d.impl);
  assert_non_null(strstr(rp_last_error(ctx), "clCreateSubDevices"));
  assert_non_null(strstr(rp_last_error(ctx), "CL_"));
  assert_int_equal(rp_cl_bootstrap.create(ctx, 0, units, &d.ops, &d.impl,
                                          &d.caps),
                   0);
  assert_int_equal(d.caps.sub_device, 1);
  assert_int_equal(d.caps.compute_units, units);
  close_device(&d);
}

/* (5) Images against the C reference: a smoke-level matrix over voxel
 * types, effects, cameras, odd viewports, image scale and steps (steps
 * other than the TF's own exercise the opacity correction). */
static void images_vs_reference(void **state) {
  static const uint32_t effects[] = {
      0, RP_EFFECT_SHADING, RP_EFFECT_ERT | RP_EFFECT_SKIP,
      RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP};
  static const struct {
    uint32_t w, h;
    float scale, step;
  } views[] = {{40, 30, 0, 0},   {1, 1, 0, 0},      {7, 513, 0, 0.5f},
               {64, 48, 0.5f, 0}, {33, 17, 0, 0.3f}, {24, 24, 0, 2.7f}};
  scene scenes[4];
  device dev;
  int si, e, c, v, worst = 0, renders = 0;
  (void)state;
  scenes[0] = make_scene(RP_GEN_PHANTOM, 48, 48, 48, RP_U8, "ct-bone");
  scenes[1] = make_scene(RP_GEN_MARSCHNER_LOBB, 41, 37, 29, RP_U16, "mri");
  scenes[2] = make_scene(RP_GEN_NOISE, 23, 17, 30, RP_U8,
                         "nearly-transparent");
  scenes[3] = float_scene("ct-soft");
  open_device(0, &dev);
  for (si = 0; si < 4; si++) {
    upload(&dev, &scenes[si]);
    for (e = 0; e < 4; e++)
      for (c = 0; c < 3; c++)
        for (v = 0; v < 6; v++) {
          rp_camera cam = camera(scenes[si].vol, c);
          rp_render_desc d = {0};
          rp__raygen rg;
          rp_frame_params p;
          image got, want;
          char what[128];
          int w;
          /* Every view on the first camera; one more per other camera. */
          if (c > 0 && v != (c + e + si) % 6)
            continue;
          d.width = views[v].w, d.height = views[v].h;
          d.image_scale = views[v].scale;
          d.step = views[v].step;
          d.effects = effects[e];
          frame_params(&scenes[si], &cam, &d, &rg, &p);
          image_alloc(&got, p.width, p.height);
          image_alloc(&want, p.width, p.height);
          render(&dev, &p, &got, 0);
          reference(&scenes[si], &rg, &d, &want, 0);
          snprintf(what, sizeof what, "scene %d effects 0x%x camera %d "
                   "view %ux%u scale %g step %g", si, (unsigned)effects[e],
                   c, views[v].w, views[v].h, (double)views[v].scale,
                   (double)d.step);
          w = compare(what, &got, &want);
          worst = w > worst ? w : worst;
          renders++;
          image_free(&got);
          image_free(&want);
        }
  }
  print_message("%d renders, worst channel difference %d/255\n", renders,
                worst);
  close_device(&dev);
  for (si = 0; si < 4; si++)
    drop_scene(&scenes[si]);
}

/* The kernel's hand-written log1p/expm1 against the double reference. */
static void opacity_correction(void **state) {
  static const float ratios[] = {1e-3f, 0.05f, 0.3f, 0.5f,  0.999f,
                                 1.001f, 2.7f, 8.0f, 100.0f, 1e4f};
  enum { N = 4096 };
  float *a = malloc(N * sizeof *a), *out = malloc(N * sizeof *out);
  device dev;
  double worst_rel = 0.0, worst_abs = 0.0;
  int i, r;
  (void)state;
  assert_true(a != NULL && out != NULL);
  /* Tiny to nearly 1, both ends exactly, and a few below and above. */
  for (i = 0; i < N; i++) {
    double f = (double)i / (N - 1);
    a[i] = (float)(i < N / 2 ? pow(10.0, -9.0 + 9.0 * 2.0 * f)
                             : 1.0 - pow(10.0, -7.0 * (2.0 * f - 1.0)));
  }
  a[0] = 0.0f, a[1] = 1.0f, a[2] = -0.25f, a[3] = 1.5f, a[4] = 1e-30f;
  a[5] = 0.25f, a[6] = nextafterf(0.25f, 0.0f), a[7] = 0.5f;
  a[8] = nextafterf(1.0f, 0.0f);
  open_device(0, &dev);
  for (r = 0; r < (int)(sizeof ratios / sizeof ratios[0]); r++) {
    if (rp_cl__correct_for_test(dev.impl, a, N, ratios[r], out) != 0)
      fail_msg("%s", rp_last_error(ctx));
    for (i = 0; i < N; i++) {
      float want = rp_opacity_correct(a[i], ratios[r], 1.0f);
      double err = fabs((double)out[i] - want);
      if (a[i] <= 0.0f || a[i] >= 1.0f) {
        /* Exact at both ends, at any step. */
        if (out[i] != (a[i] <= 0.0f ? 0.0f : 1.0f))
          fail_msg("a = %g ratio %g: %g, not exact", (double)a[i],
                   (double)ratios[r], (double)out[i]);
        continue;
      }
      if (err > worst_abs)
        worst_abs = err;
      if (want > 0.0f && err / want > worst_rel)
        worst_rel = err / want;
      /* Relative precision for small results, absolute near 1. */
      if (err > 1e-6 * want + 2e-7)
        fail_msg("a = %.9g ratio %g: %.9g, reference %.9g", (double)a[i],
                 (double)ratios[r], (double)out[i], (double)want);
    }
  }
  print_message("opacity correction: worst relative error %.3g, absolute "
                "%.3g\n", worst_rel, worst_abs);
  close_device(&dev);
  free(a);
  free(out);
}

/* (6) Depth pass: without SKIP the box clip; with SKIP the C pass. And
 * a camera that sees nothing: (+inf, -inf) everywhere, nothing drawn. */
static void depth_pass(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 48, 40, 56, RP_U8, "ct-bone");
  device dev;
  int c, skip_on;
  uint32_t mism = 0, rays = 0;
  (void)state;
  open_device(0, &dev);
  upload(&dev, &s);
  for (c = 0; c < 4; c++)
    for (skip_on = 0; skip_on < 2; skip_on++) {
      rp_camera cam = camera(s.vol, c);
      rp_render_desc d = {0};
      rp__raygen rg;
      rp_frame_params p;
      float *fb;
      uint32_t x, y;
      d.width = 45, d.height = 38;
      d.effects = skip_on ? RP_EFFECT_SKIP : 0u;
      frame_params(&s, &cam, &d, &rg, &p);
      fb = malloc((size_t)p.width * p.height * 2 * sizeof *fb);
      assert_non_null(fb);
      assert_int_equal(dev.ops->depth_pass(dev.impl, &p, fb), 0);
      assert_true(dev.ops->last_time_ns(dev.impl) > 0);
      for (y = 0; y < p.height; y++)
        for (x = 0; x < p.width; x++) {
          rp__ray ray;
          double f, b;
          const float *got = fb + 2 * ((size_t)y * p.width + x);
          rp__raygen_ray(&rg, x, y, &ray);
          rp__depth_ray(&ray, rg.dims, skip_on ? rp_occupancy_grid(s.occ)
                                               : NULL,
                        s.h->blocks, &f, &b);
          rays++;
          if (isinf(f) || isinf(got[0])) {
            /* Misses agree exactly (a grazing ray may flip: counted). */
            if (!(got[0] == (float)f && got[1] == (float)b))
              mism++;
            continue;
          }
          if (!skip_on) {
            if (fabs(got[0] - f) > 1e-3 || fabs(got[1] - b) > 1e-3)
              fail_msg("camera %d ray (%u, %u): (%.6f, %.6f), box clip "
                       "(%.6f, %.6f)", c, x, y, (double)got[0],
                       (double)got[1], f, b);
          } else if (fabs(got[0] - f) > 1e-3 || fabs(got[1] - b) > 1e-3) {
            mism++;
          }
        }
      if (c == 3) {
        /* Nothing in view: every ray (+inf, -inf) and an empty image. */
        image im;
        rp_region all = {0, 0, p.width, p.height};
        uint32_t i;
        for (i = 0; i < p.width * p.height; i++)
          assert_true(isinf(fb[2 * i]) && fb[2 * i] > 0 &&
                      isinf(fb[2 * i + 1]) && fb[2 * i + 1] < 0);
        image_alloc(&im, p.width, p.height);
        memset(im.rgba, 0xab, (size_t)p.width * p.height * 4);
        assert_int_equal(dev.ops->raycast(dev.impl, &p, &all, im.rgba,
                                          im.tiles, NULL), 0);
        for (i = 0; i < p.width * p.height * 4; i++)
          assert_int_equal(im.rgba[i], 0);
        assert_int_equal(total_samples(&im), 0);
        image_free(&im);
      }
      free(fb);
    }
  print_message("depth pass: %u of %u values off (rounding at block "
                "faces)\n", (unsigned)mism, (unsigned)rays);
  assert_true(mism <= rays / 1000);
  close_device(&dev);
  drop_scene(&s);
}

/* The ERT pre-pass against the C pass with the same generator and seed. */
static void ert_prepass(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 48, 48, 48, RP_U8, "ct-soft");
  device dev;
  uint32_t c, off = 0, total = 0, finite = 0;
  (void)state;
  open_device(0, &dev);
  upload(&dev, &s);
  for (c = 0; c < 3; c++) {
    rp_camera cam = camera(s.vol, (int)c);
    rp_render_desc d = {0};
    rp__raygen rg;
    rp_frame_params p;
    uint32_t gw, gh, i;
    float *got, *want;
    d.width = 150, d.height = 97;
    d.effects = RP_EFFECT_ERT;
    d.ert_threshold = c == 1 ? 0.5f : 0.0f;
    frame_params(&s, &cam, &d, &rg, &p);
    p.ert_seed = 1234u + c;
    p.frame = 7u * c;
    rp__ert_grid(p.width, p.height, &gw, &gh);
    got = malloc((size_t)gw * gh * sizeof *got);
    want = malloc((size_t)gw * gh * sizeof *want);
    assert_true(got != NULL && want != NULL);
    assert_int_equal(dev.ops->ert_prepass(dev.impl, &p, got), 0);
    rp__ert_prepass(&rg, rp_occupancy_grid(s.occ),
                    rp_occupancy_alpha_hist(s.occ), s.h->blocks,
                    rp_tf_reference_step(s.tf), d.ert_threshold, p.ert_seed,
                    p.frame, want);
    for (i = 0; i < gw * gh; i++) {
      total++;
      finite += isfinite(want[i]) != 0;
      if (got[i] == want[i] || fabsf(got[i] - want[i]) <= 1e-3f)
        continue;
      /* Float rounding may move a termination by one coarse step. */
      if (isfinite(got[i]) && isfinite(want[i]) &&
          fabsf(got[i] - want[i]) <= RP_ERT_COARSE_STEP + 1e-3f)
        off++;
      else
        fail_msg("camera %u ray %u: %g, reference %g", (unsigned)c,
                 (unsigned)i, (double)got[i], (double)want[i]);
    }
    free(got);
    free(want);
  }
  print_message("ERT pre-pass: %u rays, %u terminate, %u one step off\n",
                (unsigned)total, (unsigned)finite, (unsigned)off);
  assert_true(finite > total / 10);
  assert_true(off <= total / 1000);
  close_device(&dev);
  drop_scene(&s);
}

/* (7) Four tile-aligned quadrants, rendered separately into the same
 * buffers, equal one full render bit for bit; nothing outside a region
 * is written. */
static void regions(void **state) {
  scene s = make_scene(RP_GEN_MARSCHNER_LOBB, 41, 37, 29, RP_U16, "ct-bone");
  rp_camera cam = camera(s.vol, 2);
  rp_render_desc d = {0};
  rp__raygen rg;
  rp_frame_params p;
  device dev;
  image full, parts;
  uint32_t q, i;
  (void)state;
  d.width = 53, d.height = 37;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP;
  frame_params(&s, &cam, &d, &rg, &p);
  open_device(0, &dev);
  upload(&dev, &s);
  image_alloc(&full, p.width, p.height);
  image_alloc(&parts, p.width, p.height);
  render(&dev, &p, &full, 1);
  memset(parts.rgba, 0xcd, (size_t)p.width * p.height * 4);
  memset(parts.tiles, 0xcd, parts.tx * parts.ty * sizeof *parts.tiles);
  memset(parts.fetches, 0xcd, parts.tx * parts.ty * sizeof *parts.fetches);
  for (q = 0; q < 4; q++) {
    rp_region r;
    uint32_t x, y;
    r.x0 = (q & 1) ? 24 : 0;
    r.x1 = (q & 1) ? p.width : 24;
    r.y0 = (q & 2) ? 16 : 0;
    r.y1 = (q & 2) ? p.height : 16;
    if (dev.ops->raycast(dev.impl, &p, &r, parts.rgba, parts.tiles,
                         parts.fetches) != 0)
      fail_msg("region %u: %s", (unsigned)q, rp_last_error(ctx));
    /* Pixels of quadrants not yet rendered still hold the fill. */
    for (y = 0; y < p.height; y++)
      for (x = 0; x < p.width; x++) {
        uint32_t done = (uint32_t)((y >= 16) << 1 | (x >= 24)) <= q;
        const uint8_t *px = parts.rgba + 4 * ((size_t)y * p.width + x);
        if (!done && px[0] != 0xcd)
          fail_msg("region %u wrote pixel (%u, %u) outside it",
                   (unsigned)q, (unsigned)x, (unsigned)y);
      }
  }
  assert_memory_equal(full.rgba, parts.rgba, (size_t)p.width * p.height * 4);
  assert_memory_equal(full.tiles, parts.tiles,
                      full.tx * full.ty * sizeof *full.tiles);
  assert_memory_equal(full.fetches, parts.fetches,
                      full.tx * full.ty * sizeof *full.fetches);
  for (i = 0; i < full.tx * full.ty; i++)
    assert_true(full.tiles[i].rays_hit <= RP_TILE_SIZE * RP_TILE_SIZE);
  image_free(&full);
  image_free(&parts);
  close_device(&dev);
  drop_scene(&s);
}

/* Device time comes from OpenCL profiling events: non-zero for every op,
 * and never more than the wall time of the blocking call that ran the
 * raycast (with 1 % and 10 us for the device clock's rate and
 * granularity). Whether it grows with the work is a timing order, which
 * a shared machine can flip: bench_backends shows that as medians. */
static void device_timing(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 48, 48, 48, RP_U8, "ct-bone");
  rp_camera cam = camera(s.vol, 0);
  device dev;
  int r;
  (void)state;
  open_device(0, &dev);
  upload(&dev, &s);
  assert_true(dev.ops->last_time_ns(dev.impl) > 0);
  for (r = 0; r < 2; r++) {
    rp_render_desc d = {0};
    rp__raygen rg;
    rp_frame_params p;
    rp_region all;
    image im;
    double t0, wall_ns, dev_ns;
    d.width = d.height = r ? 128 : 16;
    frame_params(&s, &cam, &d, &rg, &p);
    image_alloc(&im, p.width, p.height);
    render(&dev, &p, &im, 0);
    assert_true(dev.ops->last_time_ns(dev.impl) > 0);
    all.x0 = all.y0 = 0;
    all.x1 = p.width;
    all.y1 = p.height;
    t0 = now();
    assert_int_equal(dev.ops->raycast(dev.impl, &p, &all, im.rgba, im.tiles,
                                      NULL),
                     0);
    wall_ns = (now() - t0) * 1e9;
    dev_ns = (double)dev.ops->last_time_ns(dev.impl);
    print_message("%ux%u raycast: device %.3f ms, call %.3f ms\n",
                  (unsigned)p.width, (unsigned)p.height, dev_ns * 1e-6,
                  wall_ns * 1e-6);
    assert_true(dev_ns > 0 && dev_ns <= 1.01 * wall_ns + 1e4);
    image_free(&im);
  }
  close_device(&dev);
  drop_scene(&s);
}

/* ---- ambient occlusion --------------------------------------------------- */

/* The job the front end hands a backend for voxels [lo, end) under
 * `plan` (runtime/backend.c, rp_device_compute_ao). */
static rp_ao_job ao_job(const scene *s, const rp_ao_plan *plan,
                        const uint32_t lo[3], const uint32_t end[3]) {
  rp_ao_job job;
  rp__ao_job(plan, lo, end, rp_tf_reference_step(s->tf), s->vol->min,
             s->vol->max, (uint32_t)s->tf->lut_size, &job);
  return job;
}

/* The device's AO volume of scene `s` under `desc` against the C
 * reference's: within 2/255 on >= 99.9 % of voxels, none over 8/255.
 * Returns the device's values (whole volume) for further checks. */
static uint8_t *ao_vs_reference(const device *dev, const scene *s,
                                const rp_ao_desc *desc, const char *what,
                                rp_ao_plan **plan_out) {
  rp_ao *want = NULL;
  rp_ao_plan *plan = NULL;
  const uint32_t *dims = s->vol->dims;
  const uint32_t lo[3] = {0, 0, 0};
  size_t n = s->vol->voxel_count, i, over = 0, occluded = 0, skipped = 0;
  uint8_t *got = malloc(n);
  const uint8_t *ref;
  rp_ao_job job;
  int worst = 0;
  assert_non_null(got);
  if (rp_ao_compute_reference(ctx, s->vol, s->tf, desc, NULL, NULL,
                              &want) != 0 ||
      rp_ao_plan_create(ctx, s->vol, s->tf, desc, &plan) != 0)
    fail_msg("%s: %s", what, rp_last_error(ctx));
  job = ao_job(s, plan, lo, dims);
  memset(got, 0xcd, n);
  if (dev->ops->compute_ao(dev->impl, &job, got) != 0)
    fail_msg("%s: compute_ao: %s", what, rp_last_error(ctx));
  assert_true(dev->ops->last_time_ns(dev->impl) > 0);
  ref = rp_ao_data(want, NULL);
  for (i = 0; i < n; i++) {
    int d = abs((int)got[i] - (int)ref[i]);
    over += d > 2;
    worst = d > worst ? d : worst;
    occluded += ref[i] < 192;
  }
  if (plan->bricks != NULL) {
    /* A voxel of an empty brick is 255 exactly, never sampled. */
    uint32_t x, y, z;
    const uint32_t *g = plan->brick_grid;
    for (z = 0; z < dims[2]; z++)
      for (y = 0; y < dims[1]; y++)
        for (x = 0; x < dims[0]; x++)
          if (!plan->bricks[((size_t)(z / 4) * g[1] + y / 4) * g[0] +
                            x / 4]) {
            assert_int_equal(got[((size_t)z * dims[1] + y) * dims[0] + x],
                             255);
            skipped++;
          }
    assert_true(skipped > 0 && skipped < n);
  }
  print_message("%s: %zu voxels, %zu occluded below 192, %zu skipped, "
                "worst %d/255, %zu over 2/255; %.2f ms\n", what, n,
                occluded, skipped, worst, over,
                dev->ops->last_time_ns(dev->impl) * 1e-6);
  if (worst > 8 || over * 1000 > n)
    fail_msg("%s: worst %d/255, %zu of %zu voxels over 2/255", what, worst,
             over, n);
  /* Not a volume of 255s that would pass any tolerance. */
  assert_true(occluded > n / 100);
  rp_ao_destroy(want);
  if (plan_out != NULL)
    *plan_out = plan;
  else
    rp_ao_plan_destroy(plan);
  return got;
}

/* (8) compute_ao against the C reference, bricked and unbricked, on odd
 * sizes and each voxel type; a sub-box equals the same voxels of the
 * whole volume exactly. */
static void ao_volume(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 40, 37, 33, RP_U8, "ct-bone");
  scene s16 = make_scene(RP_GEN_MARSCHNER_LOBB, 23, 30, 19, RP_U16, "mri");
  scene sf = float_scene("ct-soft");
  static const uint32_t boxes[][6] = {
      {5, 3, 7, 31, 30, 20}, {0, 0, 0, 1, 1, 1}, {39, 36, 32, 40, 37, 33},
      {13, 0, 2, 14, 37, 3}, {1, 2, 3, 40, 37, 33}};
  device dev;
  int bricked, b;
  (void)state;
  open_device(0, &dev);
  upload(&dev, &s);
  for (bricked = 0; bricked < 2; bricked++) {
    rp_ao_desc desc = {0};
    rp_ao_plan *plan = NULL;
    uint8_t *whole;
    desc.unbricked = !bricked;
    whole = ao_vs_reference(&dev, &s, &desc,
                            bricked ? "phantom u8, bricked"
                                    : "phantom u8, unbricked",
                            &plan);
    for (b = 0; b < (int)(sizeof boxes / sizeof boxes[0]); b++) {
      const uint32_t *lo = boxes[b], *end = boxes[b] + 3;
      uint32_t nx = end[0] - lo[0], ny = end[1] - lo[1], x, y, z;
      size_t n = (size_t)nx * ny * (end[2] - lo[2]);
      uint8_t *part = malloc(n + 1);
      rp_ao_job job = ao_job(&s, plan, lo, end);
      assert_non_null(part);
      part[n] = 0xcd;
      if (dev.ops->compute_ao(dev.impl, &job, part) != 0)
        fail_msg("box %d: %s", b, rp_last_error(ctx));
      assert_int_equal(part[n], 0xcd);
      for (z = lo[2]; z < end[2]; z++)
        for (y = lo[1]; y < end[1]; y++)
          for (x = lo[0]; x < end[0]; x++) {
            uint8_t want = whole[((size_t)z * 37 + y) * 40 + x];
            uint8_t got = part[((size_t)(z - lo[2]) * ny + (y - lo[1])) *
                                   nx + (x - lo[0])];
            if (got != want)
              fail_msg("box %d (bricked %d): voxel (%u, %u, %u) is %u, "
                       "%u in the whole volume", b, bricked, x, y, z, got,
                       want);
          }
      free(part);
    }
    rp_ao_plan_destroy(plan);
    free(whole);
  }
  {
    /* Other voxel types, and a desc off the defaults: every input of
     * the job reaches the kernel. */
    rp_ao_desc desc = {0};
    desc.directions = 7, desc.samples = 5, desc.radius = 6.0f;
    desc.offset = 0.5f, desc.unbricked = 1;
    upload(&dev, &s16);
    free(ao_vs_reference(&dev, &s16, &desc, "Marschner-Lobb u16", NULL));
    upload(&dev, &sf);
    desc.unbricked = 0;
    free(ao_vs_reference(&dev, &sf, &desc, "float blob", NULL));
  }
  close_device(&dev);
  drop_scene(&s);
  drop_scene(&s16);
  drop_scene(&sf);
}

/* Per-channel difference of two images: pixels more than 8/255 apart. */
static uint32_t pixels_apart(const image *a, const image *b) {
  uint32_t i, n = 0;
  int c;
  for (i = 0; i < a->w * a->h; i++)
    for (c = 0; c < 4; c++)
      if (abs((int)a->rgba[4 * i + c] - (int)b->rgba[4 * i + c]) > 8) {
        n++;
        break;
      }
  return n;
}

static uint32_t pixels_seen(const image *a) {
  uint32_t i, n = 0;
  for (i = 0; i < a->w * a->h; i++)
    n += a->rgba[4 * i + 3] > 8;
  return n;
}

/* (9) RP_EFFECT_AO renders: this device against the reference device
 * with the same AO volume, with and without shading, images and fetch
 * counts (one more per visible sample); the AO visibly darkens the
 * image; an AO render without an AO volume is RP_ESTATE. */
static void ao_render(void **state) {
  static const uint32_t effects[] = {
      RP_EFFECT_AO, RP_EFFECT_AO | RP_EFFECT_SHADING,
      RP_EFFECT_AO | RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP,
      RP_EFFECT_AO | RP_EFFECT_SKIP};
  scene s = make_scene(RP_GEN_PHANTOM, 40, 37, 33, RP_U8, "ct-soft");
  rp_device *cl = NULL, *ref = NULL;
  rp_device_desc dd = {0};
  rp_ao *ao = NULL;
  uint64_t total = 0, off = 0;
  int e, c, worst = 0;
  (void)state;
  assert_int_equal(rp_ao_compute_reference(ctx, s.vol, s.tf, NULL, NULL,
                                           NULL, &ao), 0);
  dd.backend = "opencl";
  assert_int_equal(rp_device_create(ctx, &dd, &cl), 0);
  dd.backend = "reference";
  assert_int_equal(rp_device_create(ctx, &dd, &ref), 0);
  assert_int_equal(rp_device_set_volume(cl, s.vol), 0);
  assert_int_equal(rp_device_set_tf(cl, s.tf, s.occ), 0);
  assert_int_equal(rp_device_set_volume(ref, s.vol), 0);
  assert_int_equal(rp_device_set_tf(ref, s.tf, s.occ), 0);
  assert_int_equal(rp_device_set_ao(cl, ao), 0);
  assert_int_equal(rp_device_set_ao(ref, ao), 0);
  assert_true(rp_device_ao_bytes(cl) >= s.vol->voxel_count);
  for (e = 0; e < 4; e++)
    for (c = 0; c < 3; c++) {
      rp_camera cam = camera(s.vol, c);
      rp_render_desc d = {0};
      image got, want, plain;
      char what[96];
      uint32_t apart, seen;
      d.width = 61, d.height = 45;
      d.step = c == 2 ? 0.6f : 0.0f;
      d.effects = effects[e];
      image_alloc(&got, 61, 45);
      image_alloc(&want, 61, 45);
      image_alloc(&plain, 61, 45);
      if (rp__device_render(cl, &cam, &d, NULL, got.rgba, got.tiles,
                            got.fetches) != 0 ||
          rp__device_render(ref, &cam, &d, NULL, want.rgba, want.tiles,
                            want.fetches) != 0)
        fail_msg("effects 0x%x camera %d: %s", (unsigned)d.effects, c,
                 rp_last_error(ctx));
      snprintf(what, sizeof what, "AO effects 0x%x camera %d",
               (unsigned)d.effects, c);
      {
        int w = compare(what, &got, &want);
        worst = w > worst ? w : worst;
      }
      rp_test_check_fetches(what, got.tiles, got.fetches, want.tiles,
                            want.fetches, got.tx * got.ty,
                            rp_test_visible_fetches(d.effects), &total,
                            &off);
      /* The same frame without AO: AO must show. */
      d.effects &= ~(uint32_t)RP_EFFECT_AO;
      assert_int_equal(rp__device_render(cl, &cam, &d, NULL, plain.rgba,
                                         plain.tiles, plain.fetches), 0);
      apart = pixels_apart(&got, &plain);
      seen = pixels_seen(&plain);
      print_message("%s: %u of %u visible pixels darkened by AO\n", what,
                    apart, seen);
      if (seen > 0 && apart * 10 < seen)
        fail_msg("%s: AO changed only %u of %u visible pixels", what, apart,
                 seen);
      /* AO only darkens, and never changes opacity or samples. */
      {
        uint32_t i;
        for (i = 0; i < got.w * got.h * 4; i++)
          if (i % 4 == 3 ? got.rgba[i] != plain.rgba[i]
                         : got.rgba[i] > plain.rgba[i] + 1)
            fail_msg("%s: byte %u is %u, %u without AO", what, i,
                     got.rgba[i], plain.rgba[i]);
      }
      assert_memory_equal(got.tiles, plain.tiles,
                          got.tx * got.ty * sizeof *got.tiles);
      image_free(&got);
      image_free(&want);
      image_free(&plain);
    }
  print_message("AO renders: worst channel difference %d/255; fetches %llu, "
                "%llu off\n", worst, (unsigned long long)total,
                (unsigned long long)off);
  /* Released: no AO memory, and an AO render is refused. */
  assert_int_equal(rp_device_set_ao(cl, NULL), 0);
  assert_int_equal(rp_device_ao_bytes(cl), 0);
  {
    rp_camera cam = camera(s.vol, 0);
    rp_render_desc d = {0};
    image im;
    d.width = 16, d.height = 16, d.effects = RP_EFFECT_AO;
    image_alloc(&im, 16, 16);
    assert_int_equal(rp_device_render(cl, &cam, &d, NULL, im.rgba, NULL),
                     RP_ESTATE);
    image_free(&im);
  }
  rp_device_destroy(cl);
  rp_device_destroy(ref);
  rp_ao_destroy(ao);
  drop_scene(&s);
}

/* The backend itself refuses an AO raycast without an AO volume (the
 * front end checks first, but a slip must not read a missing buffer),
 * and upload_ao(NULL) leaves no AO memory. */
static void ao_state(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 24, 20, 18, RP_U8, "ct-bone");
  rp_camera cam = camera(s.vol, 0);
  rp_render_desc d = {0};
  rp__raygen rg;
  rp_frame_params p;
  rp_region all;
  device dev;
  image im;
  uint8_t *ao = malloc(s.vol->voxel_count);
  const rp_cl_impl *impl;
  (void)state;
  assert_non_null(ao);
  memset(ao, 200, s.vol->voxel_count);
  open_device(0, &dev);
  impl = dev.impl;
  /* Nothing to attach it to yet. */
  assert_int_equal(dev.ops->upload_ao(dev.impl, ao), RP_ESTATE);
  upload(&dev, &s);
  d.width = d.height = 24;
  d.effects = RP_EFFECT_AO | RP_EFFECT_SHADING;
  frame_params(&s, &cam, &d, &rg, &p);
  all.x0 = all.y0 = 0, all.x1 = p.width, all.y1 = p.height;
  image_alloc(&im, p.width, p.height);
  assert_int_equal(dev.ops->depth_pass(dev.impl, &p, NULL), 0);
  assert_int_equal(dev.ops->raycast(dev.impl, &p, &all, im.rgba, im.tiles,
                                    NULL), RP_ESTATE);
  assert_non_null(strstr(rp_last_error(ctx), "AO"));
  assert_int_equal(dev.ops->upload_ao(dev.impl, ao), 0);
  assert_non_null(impl->ao.mem);
  assert_int_equal(dev.ops->raycast(dev.impl, &p, &all, im.rgba, im.tiles,
                                    NULL), 0);
  assert_int_equal(dev.ops->upload_ao(dev.impl, NULL), 0);
  assert_null(impl->ao.mem);
  assert_int_equal(dev.ops->raycast(dev.impl, &p, &all, im.rgba, im.tiles,
                                    NULL), RP_ESTATE);
  /* Without AO the same frame needs none. */
  p.effects &= ~(uint32_t)RP_EFFECT_AO;
  assert_int_equal(dev.ops->raycast(dev.impl, &p, &all, im.rgba, im.tiles,
                                    NULL), 0);
  /* An AO volume of another volume's size is not read either. */
  assert_int_equal(dev.ops->upload_ao(dev.impl, ao), 0);
  {
    scene big = make_scene(RP_GEN_PHANTOM, 25, 20, 18, RP_U8, "ct-bone");
    upload(&dev, &big);
    p.effects |= RP_EFFECT_AO;
    assert_int_equal(dev.ops->raycast(dev.impl, &p, &all, im.rgba,
                                      im.tiles, NULL), RP_ESTATE);
    drop_scene(&big);
  }
  image_free(&im);
  free(ao);
  close_device(&dev);
  drop_scene(&s);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(probe_and_caps),
      cmocka_unit_test(build_cache),
      cmocka_unit_test(prepare_ahead),
      cmocka_unit_test(build_failure),
      cmocka_unit_test(shading_fetch_counts),
      cmocka_unit_test(opacity_correction),
      cmocka_unit_test(depth_pass),
      cmocka_unit_test(ert_prepass),
      cmocka_unit_test(regions),
      cmocka_unit_test(sub_devices),
      cmocka_unit_test(partitions),
      cmocka_unit_test(device_timing),
      cmocka_unit_test(images_vs_reference),
      cmocka_unit_test(ao_volume),
      cmocka_unit_test(ao_render),
      cmocka_unit_test(ao_state),
  };
  int rc;
  ctx = rp_test_context();
  if (rp_cl_bootstrap.probe(ctx, &device_count) != 0 || device_count == 0) {
    printf("no OpenCL device: skipped\n");
    rp_context_destroy(ctx);
    return 77;
  }
  rc = cmocka_run_group_tests(tests, NULL, NULL);
  rp_context_destroy(ctx);
  return rc;
}
