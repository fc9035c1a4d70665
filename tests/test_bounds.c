/* The limits of raypace.h (RP_STEP_*, RP_SPACING_*, RP_FOV_*, ...), each
 * on both sides: the last value accepted renders or loads, the first one
 * past it is refused with a message that names the public field, the
 * value and the range. The cases of issue 31 that ran without end or
 * returned a wrong image (step 1e-9, a sidecar spacing of 1e-30) now fail
 * at once, and an allocation the machine cannot hold is refused with
 * RP_ENOMEM saying how much was asked.
 *
 * The oracles are worked out here: the box diagonal of a volume whose
 * sides form a Pythagorean quadruple (3, 4, 12: diagonal 13), lattice
 * counts from floor(length / step) + 1, and a render that must not change
 * when every length (spacings and eye) is scaled by the same factor. */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bounds.h"
#include "raygen.h"
#include "raypace_runtime.h"
#include "test_util.h"

/* The message names `field` and states `value` (as the float it was),
 * and every one of the NULL-ended strings after it. */
static void expect_msg(rp_context *ctx, const char *field, double value,
                       ...) {
  const char *msg = rp_last_error(ctx), *at = strstr(msg, field), *s;
  char want[128];
  va_list ap;
  if (at == NULL)
    fail_msg("message '%s' does not name '%s'", msg, field);
  snprintf(want, sizeof want, "%s is ", field);
  at = strstr(msg, want);
  if (at == NULL)
    fail_msg("message '%s' does not say '%s'", msg, want);
  if ((float)strtod(at + strlen(want), NULL) != (float)value)
    fail_msg("message '%s' does not state the value %.9g", msg, value);
  va_start(ap, value);
  while ((s = va_arg(ap, const char *)) != NULL)
    if (strstr(msg, s) == NULL)
      fail_msg("message '%s' does not name '%s'", msg, s);
  va_end(ap);
}

/* A uint8 volume of constant 200 with the given dims and spacing. */
static rp_volume *const_volume(rp_context *ctx, uint32_t x, uint32_t y,
                               uint32_t z, const float spacing[3]) {
  rp_volume_desc d = {0};
  rp_volume *v = NULL;
  size_t n = (size_t)x * y * z;
  uint8_t *data = malloc(n);
  assert_non_null(data);
  memset(data, 200, n);
  d.dims[0] = x, d.dims[1] = y, d.dims[2] = z;
  d.type = RP_U8;
  d.data = data;
  if (spacing != NULL)
    memcpy(d.spacing, spacing, sizeof d.spacing);
  assert_int_equal(rp_volume_create(ctx, &d, &v), 0);
  free(data);
  return v;
}

/* A half-transparent grey TF (alpha 0.5 per voxel at every value). */
static rp_tf *grey_tf(rp_context *ctx) {
  rp_tf_point p[2] = {{0, 0.8f, 0.8f, 0.8f, 0.5f}, {1, 0.8f, 0.8f, 0.8f, 0.5f}};
  rp_tf_desc d = {0};
  rp_tf *tf = NULL;
  d.points = p;
  d.count = 2;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), 0);
  return tf;
}

/* Orthographic along -z through the box's middle, rays 1/4 voxel apart. */
static rp_camera ortho_z(const rp_volume *vol) {
  rp_volume_info in;
  rp_camera c = {0};
  rp_volume_get_info(vol, &in);
  c.projection = RP_ORTHOGRAPHIC;
  c.eye[2] = in.dims[2] * in.spacing[2];
  c.ortho_height = 0.5f * in.spacing[1];
  return c;
}

typedef struct render_out {
  int err;
  uint32_t w, h;
  uint64_t samples, hits;
  uint8_t *rgba;
} render_out;

/* Renders with the reference; frees nothing but sets out->rgba (NULL on
 * failure). */
static render_out render(rp_context *ctx, const rp_volume *vol,
                         const rp_tf *tf, const rp_camera *cam,
                         const rp_render_desc *d) {
  render_out o = {0};
  uint32_t tx, ty, t;
  rp_tile_stats *tiles;
  rp_scaled_size(d, &o.w, &o.h);
  rp_tile_grid(o.w, o.h, &tx, &ty);
  o.rgba = calloc((size_t)o.w * o.h, 4);
  tiles = calloc((size_t)tx * ty, sizeof *tiles);
  assert_true(o.rgba != NULL && tiles != NULL);
  o.err = rp_render_reference(ctx, vol, tf, NULL, NULL, cam, d, o.rgba,
                              tiles);
  for (t = 0; t < tx * ty; t++) {
    o.samples += tiles[t].samples;
    o.hits += tiles[t].rays_hit;
  }
  free(tiles);
  if (o.err != 0) {
    free(o.rgba);
    o.rgba = NULL;
  }
  return o;
}

/* A constant volume of the given shape with the grey TF. */
typedef struct scene {
  rp_context *ctx;
  rp_volume *vol;
  rp_tf *tf;
} scene;

static scene scene_open(uint32_t x, uint32_t y, uint32_t z,
                        const float spacing[3]) {
  scene s;
  s.ctx = rp_test_context();
  s.vol = const_volume(s.ctx, x, y, z, spacing);
  s.tf = grey_tf(s.ctx);
  return s;
}

static void scene_close(scene *s) {
  rp_tf_destroy(s->tf);
  rp_volume_destroy(s->vol);
  rp_context_destroy(s->ctx);
}

/* The render succeeds: its counts (the image is dropped). */
static render_out render_ok(const scene *s, const rp_camera *cam,
                            const rp_render_desc *d) {
  render_out o = render(s->ctx, s->vol, s->tf, cam, d);
  if (o.err != 0)
    fail_msg("render refused: %s", rp_last_error(s->ctx));
  free(o.rgba);
  o.rgba = NULL;
  return o;
}

/* The render is refused with RP_EINVAL. */
static void refused(const scene *s, const rp_camera *cam,
                    const rp_render_desc *d) {
  assert_int_equal(render(s->ctx, s->vol, s->tf, cam, d).err, RP_EINVAL);
}

/* ---- render desc ------------------------------------------------------- */

static void step_bounds(void **state) {
  scene s = scene_open(4, 4, 4, NULL);
  rp_camera cam = ortho_z(s.vol);
  rp_render_desc d = {0};
  render_out o;
  double want;
  (void)state;
  d.width = d.height = 4;
  d.jitter = RP_JITTER_OFF;
  /* Every ray crosses the 4 voxels of the box along z: the lattice from
   * its entry holds floor(4 / step) + 1 samples (give or take the last,
   * where rounding decides). */
  d.step = RP_STEP_MIN;
  o = render_ok(&s, &cam, &d);
  want = 16.0 * (floor(4.0 / (double)RP_STEP_MIN) + 1.0);
  assert_true(fabs((double)o.samples - want) <= 16.0);
  d.step = RP_STEP_MAX; /* one sample per ray, at the entry */
  o = render_ok(&s, &cam, &d);
  assert_int_equal(o.samples, 16);

  d.step = nextafterf(RP_STEP_MIN, 0.0f);
  o = render(s.ctx, s.vol, s.tf, &cam, &d);
  assert_int_equal(o.err, RP_EINVAL);
  expect_msg(s.ctx, "rp_render_desc.step", d.step, "[0.001, 10000]", "voxels",
             NULL);
  d.step = nextafterf(RP_STEP_MAX, INFINITY);
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_render_desc.step", d.step, NULL);
  /* Issue 31: step 1e-9 ran with no end. */
  d.step = 1e-9f;
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_render_desc.step", 1e-9, NULL);
  scene_close(&s);
}

static void ert_and_scale_bounds(void **state) {
  scene s = scene_open(4, 4, 4, NULL);
  rp_camera cam = ortho_z(s.vol);
  rp_render_desc d = {0};
  render_out o;
  (void)state;
  d.width = d.height = 4;
  d.jitter = RP_JITTER_OFF;
  d.effects = RP_EFFECT_ERT;
  /* Alpha 0.5 per voxel: at threshold 0.01 a ray stops after its first
   * sample, at 1.0 it takes all five of the 4-voxel box. */
  d.ert_threshold = RP_ERT_THRESHOLD_MIN;
  o = render_ok(&s, &cam, &d);
  assert_int_equal(o.samples, 16);
  d.ert_threshold = RP_ERT_THRESHOLD_MAX;
  o = render_ok(&s, &cam, &d);
  assert_int_equal(o.samples, 16 * 5);
  d.ert_threshold = nextafterf(RP_ERT_THRESHOLD_MIN, 0.0f);
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_render_desc.ert_threshold", d.ert_threshold,
             "[0.01, 1]", NULL);
  d.ert_threshold = nextafterf(RP_ERT_THRESHOLD_MAX, INFINITY);
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_render_desc.ert_threshold", d.ert_threshold, NULL);
  d.ert_threshold = 0.0f;

  /* 100 x 100 at scale 0.01 is raycast at 1 x 1. */
  d.width = d.height = 100;
  d.image_scale = RP_SCALE_MIN;
  o = render_ok(&s, &cam, &d);
  assert_true(o.w == 1 && o.h == 1 && o.hits == 1);
  d.image_scale = nextafterf(RP_SCALE_MIN, 0.0f);
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_render_desc.image_scale", d.image_scale, "[0.01, 1]",
             NULL);
  d.image_scale = 1e-9f; /* issue 31: a black image, exit 0 */
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_render_desc.image_scale", 1e-9, NULL);
  d.image_scale = nextafterf(RP_SCALE_MAX, INFINITY);
  refused(&s, &cam, &d);
  scene_close(&s);
}

static void image_bounds(void **state) {
  scene s = scene_open(4, 4, 4, NULL);
  rp_camera cam = ortho_z(s.vol);
  rp_render_desc d = {0};
  rp_device_desc dd = {0};
  rp_device *dev = NULL;
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  rp_upload_estimate est;
  (void)state;
  /* The widest image renders (one row). */
  d.width = RP_IMAGE_MAX_DIM, d.height = 1;
  render_ok(&s, &cam, &d);
  d.width = RP_IMAGE_MAX_DIM + 1;
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_render_desc.width x height", RP_IMAGE_MAX_DIM + 1.0,
             "[1, 16384] pixels", NULL);

  /* The pixel bound, through a call that checks a whole frame without
   * rendering it: the reference device's upload estimate. */
  dd.backend = "reference";
  assert_int_equal(rp_device_create(s.ctx, &dd, &dev), 0);
  assert_int_equal(rp_histograms_build(s.ctx, s.vol, &h), 0);
  assert_int_equal(rp_occupancy_build(s.ctx, h, s.tf, &occ), 0);
  assert_int_equal(rp_device_set_volume(dev, s.vol), 0);
  assert_int_equal(rp_device_set_tf(dev, s.tf, occ), 0);
  d.width = RP_IMAGE_MAX_DIM;
  d.height = RP_IMAGE_MAX_PIXELS / RP_IMAGE_MAX_DIM;
  assert_int_equal(rp_device_upload_estimate(dev, &cam, &d, NULL, &est), 0);
  d.height++;
  assert_int_equal(rp_device_upload_estimate(dev, &cam, &d, NULL, &est),
                   RP_EINVAL);
  /* Issue 31: 16384 x 16384 took 6.2 GB without a word. */
  d.height = RP_IMAGE_MAX_DIM;
  assert_int_equal(rp_device_upload_estimate(dev, &cam, &d, NULL, &est),
                   RP_EINVAL);
  expect_msg(s.ctx, "rp_render_desc.width x height", 16384.0,
             "268435456 pixels", "at most 67108864", NULL);
  rp_device_destroy(dev);
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  scene_close(&s);
}

/* ---- camera ------------------------------------------------------------ */

static void fov_bounds(void **state) {
  scene s = scene_open(4, 4, 4, NULL);
  rp_camera cam = {0};
  rp_render_desc d = {0};
  render_out o;
  (void)state;
  d.width = d.height = 3;
  cam.eye[2] = 3.0f; /* inside the bounding sphere, outside the box */
  /* The middle ray goes straight down the axis through the box at any
   * fov: at least it hits. */
  cam.fov_y_deg = RP_FOV_MAX_DEG;
  o = render_ok(&s, &cam, &d);
  assert_true(o.hits >= 1);
  cam.fov_y_deg = RP_FOV_MIN_DEG;
  o = render_ok(&s, &cam, &d);
  assert_int_equal(o.hits, 9); /* a narrow view holds only the box */
  cam.fov_y_deg = nextafterf(RP_FOV_MIN_DEG, 0.0f);
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_camera.fov_y_deg", cam.fov_y_deg, "[0.01, 170]",
             "degrees", NULL);
  cam.fov_y_deg = nextafterf(RP_FOV_MAX_DEG, INFINITY);
  refused(&s, &cam, &d);
  cam.fov_y_deg = 179.9f; /* issue 31: a black image, exit 0 */
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_camera.fov_y_deg", 179.9, "must be in [0.01, 170]",
             NULL);
  assert_null(strstr(rp_last_error(s.ctx), "cam->"));
  scene_close(&s);
}

/* A 3 x 4 x 12 box: diagonal 13 exactly. */
static void distance_and_ortho_bounds(void **state) {
  scene s = scene_open(3, 4, 12, NULL);
  rp_camera cam = {0};
  rp_render_desc d = {0};
  const double diam = 13.0;
  float h;
  render_out o;
  (void)state;
  d.width = d.height = 2;
  cam.fov_y_deg = 1.0f;
  cam.eye[2] = (float)(RP_CAMERA_DISTANCE_MAX * diam); /* exact: 130000 */
  assert_true((double)cam.eye[2] == RP_CAMERA_DISTANCE_MAX * diam);
  o = render_ok(&s, &cam, &d);
  cam.eye[2] = nextafterf(cam.eye[2], INFINITY);
  refused(&s, &cam, &d);
  assert_non_null(strstr(rp_last_error(s.ctx),
                         "rp_camera.eye is (0, 0, 130000)"));
  assert_non_null(strstr(rp_last_error(s.ctx), "RP_CAMERA_DISTANCE_MAX"));

  /* ortho_height in bounding diameters: the smallest float at or above
   * 1e-6 diameters renders, the float below it is refused. */
  cam.projection = RP_ORTHOGRAPHIC;
  cam.eye[2] = 20.0f;
  h = (float)(RP_ORTHO_HEIGHT_MIN * diam);
  while ((double)h / diam < RP_ORTHO_HEIGHT_MIN)
    h = nextafterf(h, INFINITY);
  cam.ortho_height = h;
  o = render_ok(&s, &cam, &d);
  assert_int_equal(o.hits, 4);
  cam.ortho_height = nextafterf(h, 0.0f);
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_camera.ortho_height", cam.ortho_height, NULL);
  cam.ortho_height = (float)(RP_ORTHO_HEIGHT_MAX * diam); /* 130000 */
  o = render_ok(&s, &cam, &d);
  cam.ortho_height = nextafterf(cam.ortho_height, INFINITY);
  refused(&s, &cam, &d);
  expect_msg(s.ctx, "rp_camera.ortho_height", cam.ortho_height, NULL);
  scene_close(&s);
}

/* ---- volumes and files ------------------------------------------------- */

/* The same scene with every length times k (spacings and eye) is the
 * same image: a volume at either spacing limit renders what it does at
 * spacing 1, not black. */
static void spacing_bounds_render_alike(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *ph = rp_test_generate(ctx, RP_GEN_PHANTOM, 16, 16, 16, RP_U8,
                                   1);
  rp_tf *tf = rp_test_preset(ctx, "minmax-soft");
  const float ks[2] = {RP_SPACING_MIN, RP_SPACING_MAX};
  rp_render_desc d = {0};
  rp_volume_desc vd = {0};
  rp_camera cam = {0};
  render_out base, o;
  int i;
  size_t p, off = 0;
  (void)state;
  d.width = d.height = 16;
  d.jitter = RP_JITTER_OFF;
  cam.eye[0] = 20.0f, cam.eye[1] = 9.0f, cam.eye[2] = 25.0f;
  base = render(ctx, ph, tf, &cam, &d);
  assert_int_equal(base.err, 0);
  assert_true(base.hits > 100);
  vd.dims[0] = vd.dims[1] = vd.dims[2] = 16;
  vd.type = RP_U8;
  vd.data = rp_volume_data(ph);
  for (i = 0; i < 2; i++) {
    rp_volume *v = NULL;
    rp_camera c = cam;
    int a;
    for (a = 0; a < 3; a++) {
      vd.spacing[a] = ks[i];
      c.eye[a] = cam.eye[a] * ks[i];
    }
    assert_int_equal(rp_volume_create(ctx, &vd, &v), 0);
    o = render(ctx, v, tf, &c, &d);
    assert_int_equal(o.err, 0);
    assert_int_equal(o.hits, base.hits);
    for (p = 0; p < 16 * 16 * 4; p++)
      off += abs((int)o.rgba[p] - (int)base.rgba[p]) > 2;
    free(o.rgba);
    rp_volume_destroy(v);
    v = NULL;
    /* One step past the limit is refused, naming the field. */
    vd.spacing[1] = i == 0 ? nextafterf(ks[i], 0.0f)
                           : nextafterf(ks[i], INFINITY);
    assert_int_equal(rp_volume_create(ctx, &vd, &v), RP_ERANGE);
    expect_msg(ctx, "rp_volume_desc.spacing[1]", vd.spacing[1],
               "[1e-09, 1e+09]", NULL);
    assert_null(v);
  }
  /* Rounding of eye positions scaled by 1e-9 or 1e9 moves a few
   * channels by a level or two at most. */
  assert_true(off <= 16);
  free(base.rgba);
  rp_tf_destroy(tf);
  rp_volume_destroy(ph);
  rp_context_destroy(ctx);
}

static void sidecar_spacing(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t raw[8 * 8 * 8];
  rp_volume *v;
  rp_volume_info in;
  char text[256];
  const char *path;
  (void)state;
  memset(raw, 7, sizeof raw);
  rp_test_write_file("bounds.raw", raw, sizeof raw);
  /* Issue 31: 1e-30 looped in rp__lattice_count at 8x8; 1e30 rendered
   * black. Both are refused at load, naming the file and the field. */
  snprintf(text, sizeof text, "file: bounds.raw\ndims: 8 8 8\n"
           "type: uint8\nspacing: 1 1e-30 1\n");
  path = rp_test_write_file("bounds_tiny.txt", text, strlen(text));
  rp_test_load_fails(ctx, path, RP_ERANGE, "bounds_tiny.txt", "'spacing'",
                     "axis 1", "1e-30", "[1e-09, 1e+09]", NULL);
  snprintf(text, sizeof text, "file: bounds.raw\ndims: 8 8 8\n"
           "type: uint8\nspacing: 1e30 1 1\n");
  path = rp_test_write_file("bounds_huge.txt", text, strlen(text));
  rp_test_load_fails(ctx, path, RP_ERANGE, "bounds_huge.txt", "axis 0",
                     "1e30", NULL);
  /* The limits themselves load. */
  snprintf(text, sizeof text, "file: bounds.raw\ndims: 8 8 8\n"
           "type: uint8\nspacing: 1e-9 1e9 1\n");
  path = rp_test_write_file("bounds_edge.txt", text, strlen(text));
  v = rp_test_load_ok(ctx, path);
  rp_volume_get_info(v, &in);
  assert_true(in.spacing[0] == RP_SPACING_MIN &&
              in.spacing[1] == RP_SPACING_MAX);
  rp_volume_destroy(v);
  /* NRRD and MetaImage go through the same check. */
  snprintf(text, sizeof text, "NRRD0004\ntype: uint8\ndimension: 3\n"
           "sizes: 8 8 8\nspacings: 1 1 2e9\nencoding: raw\n"
           "data file: bounds.raw\n\n");
  path = rp_test_write_file("bounds.nhdr", text, strlen(text));
  rp_test_load_fails(ctx, path, RP_ERANGE, "bounds.nhdr", "spacings",
                     "axis 2", "2e9", NULL);
  snprintf(text, sizeof text, "ObjectType = Image\nNDims = 3\n"
           "DimSize = 8 8 8\nElementSpacing = 1 5e-10 1\n"
           "ElementType = MET_UCHAR\nElementDataFile = bounds.raw\n");
  path = rp_test_write_file("bounds.mhd", text, strlen(text));
  rp_test_load_fails(ctx, path, RP_ERANGE, "bounds.mhd", "ElementSpacing",
                     "5e-10", NULL);
  rp_context_destroy(ctx);
}

static void volume_dims_bound(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume_desc d = {0};
  rp_volume *v = NULL;
  uint8_t *data = calloc(RP_VOLUME_MAX_DIM + 1, 1);
  (void)state;
  assert_non_null(data);
  d.dims[0] = RP_VOLUME_MAX_DIM, d.dims[1] = d.dims[2] = 1;
  d.type = RP_U8;
  d.data = data;
  assert_int_equal(rp_volume_create(ctx, &d, &v), 0);
  rp_volume_destroy(v);
  v = NULL;
  d.dims[0] = 1, d.dims[2] = RP_VOLUME_MAX_DIM + 1;
  assert_int_equal(rp_volume_create(ctx, &d, &v), RP_ERANGE);
  assert_null(v);
  assert_non_null(strstr(rp_last_error(ctx), "axis 2 is 65537 voxels"));
  assert_non_null(strstr(rp_last_error(ctx), "[1, 65536]"));
  free(data);
  rp_context_destroy(ctx);
}

/* ---- work and memory --------------------------------------------------- */

/* The box of 2 x 1 x 1 voxels with x spacing 1e4 and the others 1: its
 * diagonal is sqrt(2e4^2 + 2) voxels of the finest spacing. Rays that
 * miss (the camera looks away) cost nothing, so each bound is checked at
 * its edge without taking 2^24 samples. */
static void work_bounds(void **state) {
  const float sp[3] = {1e4f, 1.0f, 1.0f};
  scene s = scene_open(2, 1, 1, sp);
  rp_camera cam = {0};
  rp_render_desc d = {0};
  const double diag = sqrt(2e4 * 2e4 + 2.0);
  double per_ray;
  uint32_t h;
  float step;
  render_out o;
  (void)state;
  cam.eye[2] = 3.0f;
  cam.center[2] = 6.0f; /* looking away from the box */
  d.width = d.height = 1;
  /* The finest step whose lattice fits: floor(diag / step) + 1 at most
   * 2^24. */
  step = (float)(diag / (RP_MAX_SAMPLES_PER_RAY - 1.0));
  while (floor(diag / step) + 1.0 > RP_MAX_SAMPLES_PER_RAY)
    step = nextafterf(step, INFINITY);
  while (floor(diag / nextafterf(step, 0.0f)) + 1.0 <=
         RP_MAX_SAMPLES_PER_RAY)
    step = nextafterf(step, 0.0f);
  d.step = step;
  o = render_ok(&s, &cam, &d);
  assert_int_equal(o.hits, 0);
  d.step = nextafterf(step, 0.0f);
  refused(&s, &cam, &d);
  assert_non_null(strstr(rp_last_error(s.ctx), "RP_MAX_SAMPLES_PER_RAY"));
  assert_non_null(strstr(rp_last_error(s.ctx), "16777216"));

  /* The frame: rays times per_ray at most 2^38. */
  d.step = 2.0f;
  per_ray = floor(diag / 2.0) + 1.0;
  d.width = 16384;
  h = (uint32_t)floor((double)RP_MAX_SAMPLES_PER_FRAME / (per_ray * 16384));
  d.height = h;
  assert_true(h >= 1 && (uint64_t)d.width * h <= RP_IMAGE_MAX_PIXELS);
  {
    rp__raygen rg;
    /* The check itself on the geometry (rendering 16384 x h rays that
     * miss would take seconds): the edge passes, one row more fails. */
    assert_int_equal(rp__raygen_init(s.ctx, &cam, s.vol, d.width, h, &rg), 0);
    assert_int_equal(rp__check_work(s.ctx, "test", &rg, d.step), 0);
    rg.height = h + 1;
    assert_int_equal(rp__check_work(s.ctx, "test", &rg, d.step), RP_EINVAL);
    assert_non_null(strstr(rp_last_error(s.ctx), "RP_MAX_SAMPLES_PER_FRAME"));
  }
  scene_close(&s);
}

/* Whatever it is given, a ray's lattice ends within the work bound: here
 * positions so large that s + step == s, which walked to 2^53. */
static void lattice_capped(void **state) {
  (void)state;
  assert_int_equal(rp__lattice_count(0.0, 1e9, 1e-3), RP_MAX_SAMPLES_PER_RAY);
  assert_true(rp__lattice_count(1e20, 1e20, 1.0) <= RP_MAX_SAMPLES_PER_RAY);
  assert_int_equal(rp__lattice_count(0.0, 10.0, 1.0), 11);
}

static void allocation_refused(void **state) {
  rp_context_desc cd = {0};
  rp_context *ctx = NULL;
  rp_volume_desc d = {0};
  rp_volume *v = NULL;
  uint8_t byte = 0;
  uint64_t avail = rp__memory_available();
  (void)state;
  /* 65536^3 uint8 voxels are 2^48 bytes, 256 TiB: within every other
   * bound once max_volume_bytes allows it, beyond any machine here. */
  if (avail == 0 || avail >= (1ull << 48))
    skip();
  cd.max_volume_bytes = UINT64_MAX;
  assert_int_equal(rp_context_create(&cd, &ctx), 0);
  d.dims[0] = d.dims[1] = d.dims[2] = RP_VOLUME_MAX_DIM;
  d.type = RP_U8;
  d.data = &byte; /* never read: refused first */
  assert_int_equal(rp_volume_create(ctx, &d, &v), RP_ENOMEM);
  assert_null(v);
  assert_non_null(strstr(rp_last_error(ctx), "256.0 TiB"));
  assert_non_null(strstr(rp_last_error(ctx), "281474976710656 bytes"));
  assert_non_null(strstr(rp_last_error(ctx), "available"));
  rp_context_destroy(ctx);
}

static void on_frame(rp_runtime *rt, const rp_frame *frame, void *user) {
  (void)rt, (void)frame, (void)user;
}

/* The runtime refuses, before it opens anything, a space or viewport the
 * render desc would refuse in every frame. */
static void runtime_desc_bounds(void **state) {
  rp_context *ctx = rp_test_context();
  rp_runtime_desc d = {0}, bad;
  rp_runtime *rt = NULL;
  (void)state;
  d.on_frame = on_frame;
  d.pacing = RP_PACE_MANUAL;
  bad = d;
  bad.space.min_step = nextafterf(RP_STEP_MIN, 0.0f);
  assert_int_equal(rp_runtime_create(ctx, &bad, &rt), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx),
                         "rp_runtime_desc.space.min_step is 0.000999"));
  bad = d;
  bad.space.max_step = 2e4f;
  assert_int_equal(rp_runtime_create(ctx, &bad, &rt), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "space.max_step is 20000"));
  bad = d;
  bad.space.min_scale = 1e-3f;
  assert_int_equal(rp_runtime_create(ctx, &bad, &rt), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "space.min_scale is 0.001"));
  bad = d;
  bad.width = RP_IMAGE_MAX_DIM;
  bad.height = RP_IMAGE_MAX_PIXELS / RP_IMAGE_MAX_DIM + 1;
  assert_int_equal(rp_runtime_create(ctx, &bad, &rt), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx),
                         "rp_runtime_desc.width x height is 16384x4097"));
  assert_null(rt);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(step_bounds),
      cmocka_unit_test(ert_and_scale_bounds),
      cmocka_unit_test(image_bounds),
      cmocka_unit_test(fov_bounds),
      cmocka_unit_test(distance_and_ortho_bounds),
      cmocka_unit_test(spacing_bounds_render_alike),
      cmocka_unit_test(sidecar_spacing),
      cmocka_unit_test(volume_dims_bound),
      cmocka_unit_test(work_bounds),
      cmocka_unit_test(lattice_capped),
      cmocka_unit_test(allocation_refused),
      cmocka_unit_test(runtime_desc_bounds),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
