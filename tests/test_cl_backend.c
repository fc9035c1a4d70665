/* The OpenCL backend, driven directly through rp_cl_bootstrap and its ops
 * (no front end): only what is OpenCL's own. What every backend shares
 * (images, depth and ERT passes, regions, fetch counts, AO, kernels built
 * ahead, the kernel-variant cache) is held to the contract in
 * tests/conformance, run per backend. Here: the bootstrap's probe and
 * device list, device time of uploads from profiling events, build
 * errors with the compiler's log, the kernel's hand-written opacity
 * correction, sub-devices and partitions, and the AO buffer's life.
 *
 * Exits 77 (skipped) when no OpenCL device is present. Kernels compile
 * once per option set; with POCL_CACHE_DIR kept between runs (ctest sets
 * it under the build tree) later runs take a few seconds. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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

/* From outside, in perspective. */
static rp_camera camera(const rp_volume *vol) {
  rp_camera c = {0};
  rp_camera_orbit(&c, vol, 30, 20, 2.2f);
  return c;
}

/* A frame as the front end builds it: the camera resolved for the output
 * size, rays for the scaled size, everything in float. `d` comes back
 * with its defaults resolved and `rg` at the scaled size, ready for
 * the C reference. */
static void frame_params(const scene *s, const rp_camera *cam,
                         rp_render_desc *d, rp__raygen *rg,
                         rp_frame_params *p) {
  double span[2];
  *d = rp__render_desc_defaults(d);
  rp__tf_volume_range(s->tf, s->vol, span);
  assert_int_equal(rp__frame_params(ctx, s->vol, s->occ, cam, d,
                                    rp_tf_reference_step(s->tf),
                                    (uint32_t)s->tf->lut_size, span, rg, p),
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

static uint64_t total_samples(const image *im) {
  uint64_t n = 0;
  uint32_t k;
  for (k = 0; k < im->tx * im->ty; k++)
    n += im->tiles[k].samples;
  return n;
}

/* ---- tests --------------------------------------------------------------- */

/* The bootstrap: its probe counts the device list (each root device and
 * its one-unit sub-devices), its name, and a device past the list's end
 * is RP_ENODEV with a message, not a crash (the front end's own checks,
 * caps included, are the conformance suite's). Uploads are timed by
 * profiling events like every other operation. */
static void probe_and_caps(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 24, 20, 18, RP_U8, "minmax-bone");
  device d;
  uint32_t n = 0;
  (void)state;
  assert_int_equal(rp_cl_bootstrap.probe(ctx, &n), 0);
  assert_int_equal(n, device_count);
  assert_string_equal(rp_cl_bootstrap.name, "opencl");
  open_device(0, &d);
  assert_string_equal(d.caps.backend, "opencl");
  assert_int_equal(d.ops->upload_volume(d.impl, s.vol), 0);
  assert_true(d.ops->last_time_ns(d.impl) > 0);
  close_device(&d);
  assert_int_equal(
      rp_cl_bootstrap.create(ctx, n, 0, &d.ops, &d.impl, &d.caps),
      RP_ENODEV);
  assert_non_null(strstr(rp_last_error(ctx), "does not exist"));
  drop_scene(&s);
}

/* A program that does not compile: RP_EBUILD, naming what was built
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

/* Sub-devices: one compute unit each, and the same image. */
static void sub_devices(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 48, 48, 48, RP_U8, "minmax-bone");
  rp_camera cam = camera(s.vol);
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

/* Partitions asked for by size (rp_device_desc's compute_units):
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

/* The AO volume's buffer lives only while one is uploaded: upload_ao
 * makes it, upload_ao(NULL) releases it (conformance's ao_state holds
 * every backend to refusing what it does not hold). */
static void ao_buffer(void **state) {
  scene s = make_scene(RP_GEN_PHANTOM, 24, 20, 18, RP_U8, "minmax-bone");
  uint8_t *ao = malloc(s.vol->voxel_count);
  const rp_cl_impl *impl;
  device dev;
  (void)state;
  assert_non_null(ao);
  memset(ao, 200, s.vol->voxel_count);
  open_device(0, &dev);
  impl = dev.impl;
  upload(&dev, &s);
  assert_null(impl->ao.mem);
  assert_int_equal(dev.ops->upload_ao(dev.impl, ao), 0);
  assert_non_null(impl->ao.mem);
  assert_true(impl->ao.size >= s.vol->voxel_count);
  assert_int_equal(dev.ops->upload_ao(dev.impl, NULL), 0);
  assert_null(impl->ao.mem);
  free(ao);
  close_device(&dev);
  drop_scene(&s);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(probe_and_caps),
      cmocka_unit_test(build_failure),
      cmocka_unit_test(opacity_correction),
      cmocka_unit_test(sub_devices),
      cmocka_unit_test(partitions),
      cmocka_unit_test(ao_buffer),
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
