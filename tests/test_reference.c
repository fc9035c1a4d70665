/* The scalar reference raycaster, camera and sampling.
 *
 * The reference is the oracle every backend is tested against, so its own
 * tests compare it with values worked out here from the geometry: closed
 * forms on constant and linear volumes, brute-force counts of lattice
 * samples, and invariants (skipping changes no pixel, early termination
 * changes none by more than the opacity left). Nothing expected is
 * computed by calling the code under test. */
#include "test_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "raygen.h"

#define PI 3.14159265358979323846

/* ---- helpers ----------------------------------------------------------- */

static rp_volume *const_volume(rp_context *ctx, uint32_t nx, uint32_t ny,
                               uint32_t nz, const float spacing[3]) {
  rp_volume_desc d = {{nx, ny, nz}, RP_U8, {0, 0, 0}, NULL, {0}};
  size_t n = (size_t)nx * ny * nz;
  uint8_t *data = malloc(n);
  rp_volume *vol = NULL;
  assert_non_null(data);
  memset(data, 100, n);
  if (spacing != NULL)
    memcpy(d.spacing, spacing, sizeof d.spacing);
  d.data = data;
  assert_int_equal(rp_volume_create(ctx, &d, &vol), 0);
  free(data);
  return vol;
}

/* A float volume holding fn(i, j, k). */
static rp_volume *func_volume(rp_context *ctx, const uint32_t dims[3],
                              const float spacing[3],
                              double (*fn)(double, double, double)) {
  rp_volume_desc d = {{dims[0], dims[1], dims[2]}, RP_F32, {1, 1, 1}, NULL, {0}};
  size_t n = (size_t)dims[0] * dims[1] * dims[2], i, j, k;
  float *data = malloc(n * sizeof *data);
  rp_volume *vol = NULL;
  assert_non_null(data);
  for (k = 0; k < dims[2]; k++)
    for (j = 0; j < dims[1]; j++)
      for (i = 0; i < dims[0]; i++)
        data[(k * dims[1] + j) * dims[0] + i] =
            (float)fn((double)i, (double)j, (double)k);
  if (spacing != NULL)
    memcpy(d.spacing, spacing, sizeof d.spacing);
  d.data = data;
  assert_int_equal(rp_volume_create(ctx, &d, &vol), 0);
  free(data);
  return vol;
}

static rp_volume *generated(rp_context *ctx, rp_generator kind, uint32_t nx,
                            uint32_t ny, uint32_t nz) {
  rp_generate_desc d = {kind, {nx, ny, nz}, RP_U8, 7};
  rp_volume *vol = NULL;
  assert_int_equal(rp_volume_generate(ctx, &d, &vol), 0);
  return vol;
}

/* The same colour and alpha at every data value. */
static rp_tf *const_tf(rp_context *ctx, float r, float g, float b, float a) {
  rp_tf_point p = {0.5f, r, g, b, a};
  rp_tf_desc d = {&p, 1, 0.0f, 0, 0, 0, 0, 0};
  rp_tf *tf = NULL;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), 0);
  return tf;
}

typedef struct occ_pair {
  rp_histograms *h;
  rp_occupancy *occ;
} occ_pair;

static occ_pair make_occ(rp_context *ctx, const rp_volume *vol,
                         const rp_tf *tf) {
  occ_pair o = {NULL, NULL};
  assert_int_equal(rp_histograms_build(ctx, vol, &o.h), 0);
  assert_int_equal(rp_occupancy_build(ctx, o.h, tf, &o.occ), 0);
  return o;
}

static void free_occ(occ_pair o) {
  rp_occupancy_destroy(o.occ);
  rp_histograms_destroy(o.h);
}

/* An image with its tile stats. */
typedef struct image {
  uint32_t w, h, tx, ty;
  uint8_t *rgba;
  rp_tile_stats *tiles;
} image;

static image image_new(uint32_t w, uint32_t h) {
  image im;
  im.w = w;
  im.h = h;
  rp_tile_grid(w, h, &im.tx, &im.ty);
  im.rgba = malloc((size_t)w * h * 4);
  im.tiles = malloc((size_t)im.tx * im.ty * sizeof *im.tiles);
  assert_non_null(im.rgba);
  assert_non_null(im.tiles);
  /* Garbage the renderer must overwrite. */
  memset(im.rgba, 0xA5, (size_t)w * h * 4);
  memset(im.tiles, 0xA5, (size_t)im.tx * im.ty * sizeof *im.tiles);
  return im;
}

static void image_free(image *im) {
  free(im->rgba);
  free(im->tiles);
}

/* Jitter off: the closed forms below count the samples of the lattice
 * that starts where each ray enters the box (test_jitter.c holds the
 * jittered lattice to its own). */
static void render(rp_context *ctx, const rp_volume *vol, const rp_tf *tf,
                   const rp_occupancy *occ, const rp_camera *cam,
                   float step, uint32_t effects, image *im) {
  rp_render_desc d = {im->w, im->h, step, effects, 0.0f, 0.0f,
                      RP_JITTER_OFF, 0};
  int err = rp_render_reference(ctx, vol, tf, occ, NULL, cam, &d, im->rgba,
                                im->tiles);
  if (err != 0)
    fail_msg("render failed: %s: %s", rp_err_name(err), rp_last_error(ctx));
}

static uint64_t total_samples(const image *im) {
  uint64_t s = 0;
  size_t t;
  for (t = 0; t < (size_t)im->tx * im->ty; t++)
    s += im->tiles[t].samples;
  return s;
}

static uint64_t total_hits(const image *im) {
  uint64_t s = 0;
  size_t t;
  for (t = 0; t < (size_t)im->tx * im->ty; t++)
    s += im->tiles[t].rays_hit;
  return s;
}

/* Mean depth over all rays that took a sample. */
static double mean_depth(const image *im) {
  double sum = 0.0;
  uint64_t hits = 0;
  size_t t;
  for (t = 0; t < (size_t)im->tx * im->ty; t++) {
    sum += (double)im->tiles[t].mean_depth * im->tiles[t].rays_hit;
    hits += im->tiles[t].rays_hit;
  }
  return hits > 0 ? sum / (double)hits : 0.0;
}

static rp_camera ortho_down_z(float eye_z, float height) {
  rp_camera cam;
  memset(&cam, 0, sizeof cam);
  cam.projection = RP_ORTHOGRAPHIC;
  cam.eye[2] = eye_z;
  cam.up[1] = 1.0f;
  cam.ortho_height = height;
  return cam;
}

static rp_camera orbit(const rp_volume *vol, rp_projection proj, float az,
                       float el, float dist) {
  rp_camera cam;
  memset(&cam, 0, sizeof cam);
  cam.projection = proj;
  rp_camera_orbit(&cam, vol, az, el, dist);
  return cam;
}

static int byte_close(int got, double want01, int tol) {
  double want = want01 * 255.0;
  return fabs(got - want) <= tol + 0.5;
}

/* ---- 1 and 8: constant volume, closed form, tile stats ---------------- */

/* Renders a constant volume (dims, spacing) with an orthographic camera at
 * z = eye_z looking down -z, and checks every pixel and tile against the
 * closed form: a ray through the box samples n = floor((t1 - s)/step) + 1
 * times, each with opacity a' = 1 - (1 - a)^step, so A = 1 - (1 - a')^n
 * and C = c A. Rays outside the box's x/y extent take nothing. */
static void check_const_ortho(const uint32_t dims[3], const float sp[3],
                              uint32_t w, uint32_t h, float height,
                              float eye_z, float step, uint32_t effects) {
  rp_context *ctx = rp_test_context();
  rp_volume *vol = const_volume(ctx, dims[0], dims[1], dims[2], sp);
  const float col[4] = {0.8f, 0.5f, 0.25f, 0.06f};
  rp_tf *tf = const_tf(ctx, col[0], col[1], col[2], col[3]);
  occ_pair o = make_occ(ctx, vol, tf);
  rp_camera cam = ortho_down_z(eye_z, height);
  image im = image_new(w, h);
  double half[3], minsp = sp[0], d = step, a1, hh = 0.5 * height;
  double hw = hh * w / h;
  uint32_t x, y, t;
  uint64_t *want_samples, *want_hits;
  double *want_depth;
  int c;
  for (c = 0; c < 3; c++) {
    half[c] = 0.5 * dims[c] * sp[c];
    if (sp[c] < minsp)
      minsp = sp[c];
  }
  a1 = 1.0 - pow(1.0 - (double)col[3], d);
  want_samples = calloc((size_t)im.tx * im.ty, sizeof *want_samples);
  want_hits = calloc((size_t)im.tx * im.ty, sizeof *want_hits);
  want_depth = calloc((size_t)im.tx * im.ty, sizeof *want_depth);
  render(ctx, vol, tf, o.occ, &cam, step, effects, &im);
  for (y = 0; y < h; y++) {
    for (x = 0; x < w; x++) {
      double ox = (2.0 * (x + 0.5) / w - 1.0) * hw;
      double oy = (1.0 - 2.0 * (y + 0.5) / h) * hh;
      const uint8_t *px = &im.rgba[((size_t)y * w + x) * 4];
      double A = 0.0, s, t1, len;
      uint64_t n = 0;
      /* Rays exactly on a face would make the count depend on rounding;
       * the parameters are chosen so that none is. */
      assert_true(fabs(fabs(ox) - half[0]) > 1e-6);
      assert_true(fabs(fabs(oy) - half[1]) > 1e-6);
      t = (y / 8) * im.tx + x / 8;
      if (fabs(ox) < half[0] && fabs(oy) < half[1] &&
          eye_z >= -half[2]) {
        s = eye_z > half[2] ? (eye_z - half[2]) / minsp : 0.0;
        t1 = (eye_z + half[2]) / minsp;
        len = t1 - s;
        n = (uint64_t)floor(len / d) + 1;
        A = 1.0 - pow(1.0 - a1, (double)n);
        want_samples[t] += n;
        want_hits[t]++;
        want_depth[t] += s + (double)(n - 1) * d;
      }
      for (c = 0; c < 3; c++)
        if (!byte_close(px[c], col[c] * A, 1))
          fail_msg("pixel (%u,%u) channel %d: got %d want %.3f", x, y, c,
                   px[c], col[c] * A * 255.0);
      if (!byte_close(px[3], A, 1))
        fail_msg("pixel (%u,%u) alpha: got %d want %.3f (n %llu)", x, y,
                 px[3], A * 255.0, (unsigned long long)n);
    }
  }
  for (t = 0; t < im.tx * im.ty; t++) {
    assert_int_equal(im.tiles[t].samples, want_samples[t]);
    assert_int_equal(im.tiles[t].rays_hit, want_hits[t]);
    if (want_hits[t] == 0) {
      assert_true(im.tiles[t].mean_depth == 0.0f);
    } else {
      double md = want_depth[t] / (double)want_hits[t];
      assert_true(fabs(im.tiles[t].mean_depth - md) <= 1e-5 * md + 1e-6);
    }
  }
  free(want_samples);
  free(want_hits);
  free(want_depth);
  image_free(&im);
  free_occ(o);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

static void test_const_volume_closed_form(void **state) {
  const uint32_t dims[3] = {20, 13, 16};
  const float iso[3] = {1, 1, 1}, aniso[3] = {0.5f, 1.0f, 2.0f};
  const float steps[] = {1.0f, 0.75f, 0.5f, 2.5f, 0.3f};
  size_t i;
  (void)state;
  for (i = 0; i < sizeof steps / sizeof steps[0]; i++) {
    check_const_ortho(dims, iso, 24, 20, 16.0f, 100.0f, steps[i], 0);
    /* Depth is in units of the finest spacing: 32 world units of z at
     * min spacing 0.5 are 64 voxel units. Some rays miss in x. */
    check_const_ortho(dims, aniso, 24, 20, 16.0f, 100.0f, steps[i], 0);
  }
  /* Skipping over an all-occupied grid changes nothing. */
  check_const_ortho(dims, aniso, 24, 20, 16.0f, 100.0f, 1.0f,
                    RP_EFFECT_SKIP);
}

/* ---- 2: transparent and opaque ---------------------------------------- */

static void test_transparent_and_opaque(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *ph = generated(ctx, RP_GEN_PHANTOM, 32, 32, 32);
  rp_volume *cv = const_volume(ctx, 12, 12, 12, NULL);
  rp_tf *clear = rp_test_preset(ctx, "transparent"),
        *opaque = rp_test_preset(ctx, "opaque");
  occ_pair o = make_occ(ctx, ph, clear), oc = make_occ(ctx, cv, opaque);
  rp_camera cam = orbit(ph, RP_PERSPECTIVE, 30.0f, 20.0f, 2.0f);
  image im = image_new(33, 17);
  const float *lut;
  int lut_size;
  size_t i, n = (size_t)im.w * im.h;
  uint64_t opaque_px = 0;
  (void)state;

  render(ctx, ph, clear, NULL, &cam, 1.0f, 0, &im);
  for (i = 0; i < n * 4; i++)
    assert_int_equal(im.rgba[i], 0);
  assert_true(total_samples(&im) > 0);
  /* Every block is empty for this TF, so no ray takes a sample. */
  assert_int_equal(rp_occupancy_empty_blocks(o.occ),
                   rp_histograms_block_count(o.h));
  render(ctx, ph, clear, o.occ, &cam, 1.0f, RP_EFFECT_SKIP, &im);
  for (i = 0; i < n * 4; i++)
    assert_int_equal(im.rgba[i], 0);
  assert_int_equal(total_samples(&im), 0);
  assert_int_equal(total_hits(&im), 0);
  for (i = 0; i < (size_t)im.tx * im.ty; i++)
    assert_true(im.tiles[i].mean_depth == 0.0f);

  /* Opaque with ERT: the first sample ends every ray, and the pixel is
   * the TF's colour at that value (a constant volume sits at x = 0). */
  lut = rp_tf_lut(opaque, &lut_size);
  cam = orbit(cv, RP_PERSPECTIVE, 30.0f, 20.0f, 2.0f);
  render(ctx, cv, opaque, oc.occ, &cam, 1.0f,
         RP_EFFECT_ERT | RP_EFFECT_SKIP, &im);
  for (i = 0; i < n; i++) {
    const uint8_t *px = &im.rgba[i * 4];
    if (px[3] == 0) {
      assert_true(px[0] == 0 && px[1] == 0 && px[2] == 0);
      continue;
    }
    opaque_px++;
    assert_int_equal(px[3], 255);
    assert_int_equal(px[0], (int)floor(lut[0] * 255.0 + 0.5));
    assert_int_equal(px[1], (int)floor(lut[1] * 255.0 + 0.5));
    assert_int_equal(px[2], (int)floor(lut[2] * 255.0 + 0.5));
  }
  assert_true(opaque_px > n / 4);
  assert_int_equal(total_samples(&im), opaque_px);
  assert_int_equal(total_hits(&im), opaque_px);
  for (i = 0; i < (size_t)im.tx * im.ty; i++)
    assert_int_equal(im.tiles[i].samples, im.tiles[i].rays_hit);

  image_free(&im);
  free_occ(o);
  free_occ(oc);
  rp_tf_destroy(clear);
  rp_tf_destroy(opaque);
  rp_volume_destroy(ph);
  rp_volume_destroy(cv);
  rp_context_destroy(ctx);
}

/* ---- 3: trilinear sampling -------------------------------------------- */

static double lin_fn(double i, double j, double k) {
  return 3.0 * i - 2.0 * j + 5.0 * k + 1.5;
}

/* Multilinear, so trilinear interpolation reproduces it exactly too. */
static double prod_fn(double i, double j, double k) {
  return (i + 1.0) * (j + 2.0) * (k + 3.0);
}

static double clampd(double v, double lo, double hi) {
  return v < lo ? lo : v > hi ? hi : v;
}

/* Deterministic uniform numbers in [0, 1). */
static double rnd(uint64_t *state) {
  *state = *state * 6364136223846793005ull + 1442695040888963407ull;
  return (double)(*state >> 11) / 9007199254740992.0;
}

static void test_trilinear(void **state) {
  rp_context *ctx = rp_test_context();
  const uint32_t dims[3] = {7, 5, 4}, thin[3] = {1, 6, 3};
  rp_volume *lin = func_volume(ctx, dims, NULL, lin_fn);
  rp_volume *prod = func_volume(ctx, dims, NULL, prod_fn);
  rp_volume *flat = func_volume(ctx, thin, NULL, prod_fn);
  uint64_t seed = 12345;
  int n, a;
  (void)state;
  for (n = 0; n < 20000; n++) {
    double p[3], q[3], qf[3], want, got;
    for (a = 0; a < 3; a++) {
      /* Reach two voxels past each side so clamping is exercised. */
      p[a] = -2.0 + rnd(&seed) * (dims[a] + 3.0);
      q[a] = clampd(p[a], 0.0, dims[a] - 1.0);
      qf[a] = clampd(p[a], 0.0, thin[a] - 1.0);
    }
    want = lin_fn(q[0], q[1], q[2]);
    got = rp__sample_trilinear(lin, p);
    assert_true(fabs(got - want) <= 1e-9 * (fabs(want) + 1.0));
    want = prod_fn(q[0], q[1], q[2]);
    got = rp__sample_trilinear(prod, p);
    assert_true(fabs(got - want) <= 1e-9 * (fabs(want) + 1.0));
    want = prod_fn(qf[0], qf[1], qf[2]);
    got = rp__sample_trilinear(flat, p);
    assert_true(fabs(got - want) <= 1e-9 * (fabs(want) + 1.0));
  }
  /* At voxel centres the stored value comes back exactly. */
  for (a = 0; a < (int)(dims[0] * dims[1] * dims[2]); a++) {
    double p[3];
    p[0] = a % dims[0];
    p[1] = (a / dims[0]) % dims[1];
    p[2] = a / (dims[0] * dims[1]);
    assert_true(rp__sample_trilinear(prod, p) == prod_fn(p[0], p[1], p[2]));
  }
  rp_volume_destroy(lin);
  rp_volume_destroy(prod);
  rp_volume_destroy(flat);
  rp_context_destroy(ctx);
}

/* ---- camera and ray generation ---------------------------------------- */

static void normalize(double v[3]) {
  double l = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  v[0] /= l;
  v[1] /= l;
  v[2] /= l;
}

static void test_camera_rays(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *vol = const_volume(ctx, 10, 20, 30, NULL);
  rp_camera cam;
  rp__raygen rg;
  rp__ray ray;
  double r = 0.5 * sqrt(10.0 * 10 + 20.0 * 20 + 30.0 * 30), want[3], t;
  uint32_t x, y;
  int a;
  (void)state;

  /* Orbit: azimuth 0 is +z, 90 is +x; elevation 90 is +y. */
  cam = orbit(vol, RP_PERSPECTIVE, 0.0f, 0.0f, 2.0f);
  assert_true(fabs(cam.eye[2] - 2.0 * r) < 1e-4 && fabs(cam.eye[0]) < 1e-4);
  cam = orbit(vol, RP_PERSPECTIVE, 90.0f, 0.0f, 3.0f);
  assert_true(fabs(cam.eye[0] - 3.0 * r) < 1e-4 && fabs(cam.eye[2]) < 1e-3);
  cam = orbit(vol, RP_ORTHOGRAPHIC, 10.0f, 90.0f, 1.5f);
  assert_int_equal(cam.projection, RP_ORTHOGRAPHIC);
  assert_true(fabs(cam.eye[1] - 1.5 * r) < 1e-4);
  /* Looking straight down y: a valid camera whose up is the limit of
   * the views beside the pole (elevation 89.9 at the same azimuth), not
   * that view rolled (the default up's switch to +z at the pole). */
  assert_int_equal(rp__raygen_init(ctx, &cam, vol, 4, 4, &rg), 0);
  {
    rp__raygen near;
    rp_camera c2 = orbit(vol, RP_ORTHOGRAPHIC, 10.0f, 89.9f, 1.5f);
    assert_int_equal(rp__raygen_init(ctx, &c2, vol, 4, 4, &near), 0);
    assert_true(rg.u[0] * near.u[0] + rg.u[1] * near.u[1] +
                    rg.u[2] * near.u[2] > 0.999);
    c2 = orbit(vol, RP_ORTHOGRAPHIC, 10.0f, -90.0f, 1.5f);
    assert_int_equal(rp__raygen_init(ctx, &c2, vol, 4, 4, &near), 0);
    c2 = orbit(vol, RP_ORTHOGRAPHIC, 10.0f, -89.9f, 1.5f);
    assert_int_equal(rp__raygen_init(ctx, &c2, vol, 4, 4, &rg), 0);
    assert_true(rg.u[0] * near.u[0] + rg.u[1] * near.u[1] +
                    rg.u[2] * near.u[2] > 0.999);
  }

  /* An orthographic camera's default height is the box diagonal. */
  assert_true(fabs(rg.half_h - r) < 1e-9);
  assert_true(fabs(rg.half_w - r) < 1e-9);

  /* Perspective from +z: f = -z, r = +x, u = +y. A 1x1 viewport's ray
   * is the view direction; the corners of a 3x2 one follow the NDC
   * formula with tan(20 deg) and aspect 3/2. */
  memset(&cam, 0, sizeof cam);
  cam.eye[2] = 100.0f;
  assert_int_equal(rp__raygen_init(ctx, &cam, vol, 1, 1, &rg), 0);
  rp__raygen_ray(&rg, 0, 0, &ray);
  assert_true(fabs(ray.dir[2] + 1.0) < 1e-12 && ray.hit);
  /* The box is 30 deep at spacing 1: enters at 85, leaves at 115. */
  assert_true(fabs(ray.t0 - 85.0) < 1e-9 && fabs(ray.t1 - 115.0) < 1e-9);
  assert_true(ray.s == ray.t0);
  assert_int_equal(rp__raygen_init(ctx, &cam, vol, 3, 2, &rg), 0);
  t = tan(20.0 * PI / 180.0);
  for (y = 0; y < 2; y++) {
    for (x = 0; x < 3; x++) {
      double nu = (2.0 * x + 1.0) / 3.0 - 1.0, nv = 1.0 - (2.0 * y + 1.0) / 2;
      want[0] = nu * t * 1.5;
      want[1] = nv * t;
      want[2] = -1.0;
      normalize(want);
      rp__raygen_ray(&rg, x, y, &ray);
      for (a = 0; a < 3; a++) {
        assert_true(fabs(ray.dir[a] - want[a]) < 1e-12);
        assert_true(ray.org[a] == cam.eye[a]);
      }
    }
  }

  /* A ray that misses, one behind the eye, and one parallel to a face
   * outside the box. */
  cam.eye[0] = 50.0f;
  cam.center[0] = 50.0f;
  assert_int_equal(rp__raygen_init(ctx, &cam, vol, 1, 1, &rg), 0);
  rp__raygen_ray(&rg, 0, 0, &ray);
  assert_false(ray.hit);
  memset(&cam, 0, sizeof cam);
  cam.eye[2] = -100.0f;
  cam.center[2] = -200.0f;
  assert_int_equal(rp__raygen_init(ctx, &cam, vol, 1, 1, &rg), 0);
  rp__raygen_ray(&rg, 0, 0, &ray);
  assert_false(ray.hit);

  /* Eye inside: sampling starts at the eye (s = 0, t0 < 0). */
  memset(&cam, 0, sizeof cam);
  cam.eye[2] = 5.0f;
  assert_int_equal(rp__raygen_init(ctx, &cam, vol, 1, 1, &rg), 0);
  rp__raygen_ray(&rg, 0, 0, &ray);
  assert_true(ray.hit && ray.s == 0.0 && ray.t0 < 0.0);
  assert_true(fabs(ray.t1 - 20.0) < 1e-9);

  /* Lattice counts against the definition, by brute force. */
  {
    const double ss[] = {0.0, 85.0, 3.25, 1e-9};
    const double lens[] = {0.0, 1.0, 30.0, 7.3, 0.999};
    const double steps[] = {1.0, 0.5, 0.3, 0.7, 2.0, 1e-3, 1e3};
    size_t i, j, k;
    for (i = 0; i < 4; i++)
      for (j = 0; j < 5; j++)
        for (k = 0; k < 7; k++) {
          double s0 = ss[i], t1 = ss[i] + lens[j];
          uint64_t m = 0;
          while (s0 + (double)m * steps[k] <= t1)
            m++;
          assert_int_equal(rp__lattice_count(s0, t1, steps[k]), m);
        }
  }
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* ---- shading closed forms --------------------------------------------- */

static double zramp(double i, double j, double k) {
  (void)i;
  (void)j;
  return 4.0 * k;
}

static double xzramp(double i, double j, double k) {
  (void)j;
  return 2.0 * i + 4.0 * k;
}

/* xzramp with voxel (0, 0, 0) at -400: a range of 586. */
static double xzramp_outlier(double i, double j, double k) {
  return i + j + k == 0.0 ? -400.0 : xzramp(i, j, k);
}

/* A volume that rises along z, a TF of constant colour and alpha: the
 * gradient is +z everywhere, so for view direction d the headlight gives
 * ndotl = |d_z| and each sample's colour c (0.3 + 0.7 ndotl) +
 * 0.2 ndotl^20, the same along the ray. C = shaded * A per pixel. A
 * constant volume has no gradient: ndotl = 1. Eight voxels along z, so
 * that even at the z faces, where clamping quarters the central
 * difference, the gradient (1/28 of the range per voxel) is above the 2 %
 * below which normals blend towards the light (tested at the end). */
static void test_shading_closed_form(void **state) {
  rp_context *ctx = rp_test_context();
  const uint32_t dims[3] = {16, 16, 8};
  const float sp[3] = {1.0f, 1.0f, 0.5f};
  rp_volume *ramp = func_volume(ctx, dims, sp, zramp);
  rp_volume *flat = const_volume(ctx, 16, 16, 16, NULL);
  const float col[3] = {0.6f, 0.4f, 0.9f};
  rp_tf *tf = const_tf(ctx, col[0], col[1], col[2], 0.1f);
  const float angles[] = {0.0f, 90.0f, 60.0f, 135.0f};
  image im = image_new(16, 16), ref = image_new(16, 16);
  size_t a, i;
  int c, checked = 0;
  (void)state;
  for (a = 0; a < 4; a++) {
    double th = angles[a] * PI / 180.0, ndotl = fabs(cos(th));
    rp_camera cam = orbit(ramp, RP_ORTHOGRAPHIC, angles[a], 0.0f, 3.0f);
    cam.ortho_height = 12.0f;
    render(ctx, ramp, tf, NULL, &cam, 1.0f, RP_EFFECT_SHADING, &im);
    render(ctx, ramp, tf, NULL, &cam, 1.0f, 0, &ref);
    for (i = 0; i < (size_t)im.w * im.h; i++) {
      double A = im.rgba[i * 4 + 3] / 255.0;
      /* Alpha does not depend on shading. */
      assert_int_equal(im.rgba[i * 4 + 3], ref.rgba[i * 4 + 3]);
      if (A < 0.3)
        continue;
      checked++;
      for (c = 0; c < 3; c++) {
        double want = col[c] * (0.3 + 0.7 * ndotl) + 0.2 * pow(ndotl, 20);
        want = want > 1.0 ? 1.0 : want;
        assert_true(byte_close(im.rgba[i * 4 + c], want * A, 1));
      }
    }
    assert_int_equal(total_samples(&im), total_samples(&ref));
  }
  {
    rp_camera cam = orbit(flat, RP_PERSPECTIVE, 20.0f, 30.0f, 2.5f);
    render(ctx, flat, tf, NULL, &cam, 1.0f, RP_EFFECT_SHADING, &im);
    for (i = 0; i < (size_t)im.w * im.h; i++) {
      double A = im.rgba[i * 4 + 3] / 255.0;
      if (A < 0.3)
        continue;
      checked++;
      for (c = 0; c < 3; c++) {
        double want = col[c] + 0.2 > 1.0 ? 1.0 : col[c] + 0.2;
        assert_true(byte_close(im.rgba[i * 4 + c], want * A, 1));
      }
    }
  }
  assert_true(checked > 200);

  /* The gradient is taken per world unit: on 2i + 4k with z spacing 0.5
   * it is (2, 0, 8). An orthographic eye inside the volume with an
   * opaque TF and ERT takes exactly one sample per ray, at its origin,
   * far from any face, so each pixel is the lit colour itself. */
  {
    const uint32_t d2[3] = {32, 32, 32};
    rp_volume *xz = func_volume(ctx, d2, sp, xzramp);
    rp_tf *op = const_tf(ctx, col[0], col[1], col[2], 1.0f);
    const double dirs[][3] = {{0, 0, -1}, {-1, 0, 0}, {0.6, 0, -0.8},
                              {-0.28, 0.96, 0}, {0.48, -0.6, 0.64}};
    for (a = 0; a < sizeof dirs / sizeof dirs[0]; a++) {
      rp_camera cam;
      const double g[3] = {2.0, 0.0, 8.0};
      double ndotl = fabs(g[0] * dirs[a][0] + g[2] * dirs[a][2]) /
                     sqrt(68.0);
      memset(&cam, 0, sizeof cam);
      cam.projection = RP_ORTHOGRAPHIC;
      cam.ortho_height = 6.0f;
      for (c = 0; c < 3; c++)
        cam.center[c] = (float)dirs[a][c];
      render(ctx, xz, op, NULL, &cam, 1.0f,
             RP_EFFECT_SHADING | RP_EFFECT_ERT, &im);
      assert_int_equal(total_samples(&im), (uint64_t)im.w * im.h);
      for (i = 0; i < (size_t)im.w * im.h; i++) {
        assert_int_equal(im.rgba[i * 4 + 3], 255);
        for (c = 0; c < 3; c++) {
          double want =
              col[c] * (0.3 + 0.7 * ndotl) + 0.2 * pow(ndotl, 20);
          assert_true(byte_close(im.rgba[i * 4 + c], want > 1 ? 1 : want,
                                 1));
        }
      }
    }
    rp_tf_destroy(op);
    rp_volume_destroy(xz);
  }
  /* The same gradient, (2, 0, 8) per world unit, 4.12 per voxel of the
   * finest spacing (0.5), in a volume whose range one corner voxel
   * stretches to 586: 0.70 % of it per voxel, below the 2 % of a
   * surface, so the light blends towards facing it by m = 0.70 / 2:
   * ndotl' = 1 - m (1 - ndotl). The sample sits at the centre, far from
   * the corner. */
  {
    const uint32_t d2[3] = {32, 32, 32};
    rp_volume *xz = func_volume(ctx, d2, sp, xzramp_outlier);
    rp_tf *op = const_tf(ctx, col[0], col[1], col[2], 1.0f);
    const double dir[3] = {0.6, 0, -0.8}, g[3] = {2.0, 0.0, 8.0};
    double ndotl = fabs(g[0] * dir[0] + g[2] * dir[2]) / sqrt(68.0);
    double m = sqrt(68.0) * 0.5 / 586.0 / 0.02;
    rp_camera cam;
    ndotl = 1.0 - m * (1.0 - ndotl);
    memset(&cam, 0, sizeof cam);
    cam.projection = RP_ORTHOGRAPHIC;
    cam.ortho_height = 6.0f;
    for (c = 0; c < 3; c++)
      cam.center[c] = (float)dir[c];
    render(ctx, xz, op, NULL, &cam, 1.0f, RP_EFFECT_SHADING | RP_EFFECT_ERT,
           &im);
    for (i = 0; i < (size_t)im.w * im.h; i++)
      for (c = 0; c < 3; c++) {
        double want = col[c] * (0.3 + 0.7 * ndotl) + 0.2 * pow(ndotl, 20);
        assert_true(byte_close(im.rgba[i * 4 + c], want > 1 ? 1 : want, 1));
      }
    rp_tf_destroy(op);
    rp_volume_destroy(xz);
  }
  image_free(&im);
  image_free(&ref);
  rp_tf_destroy(tf);
  rp_volume_destroy(ramp);
  rp_volume_destroy(flat);
  rp_context_destroy(ctx);
}

/* ---- 4: skipping changes no pixel ------------------------------------- */

typedef struct cam_case {
  const char *name;
  rp_camera cam;
} cam_case;

/* Cameras that stress different parts of the skip logic. */
static int camera_cases(const rp_volume *vol, cam_case out[6]) {
  rp_volume_info info;
  float hy, hz;
  int n = 0;
  rp_volume_get_info(vol, &info);
  hy = 0.5f * info.dims[1] * info.spacing[1];
  hz = 0.5f * info.dims[2] * info.spacing[2];
  out[n].name = "outside";
  out[n++].cam = orbit(vol, RP_PERSPECTIVE, 30.0f, 20.0f, 2.5f);
  /* The middle row (odd height) runs inside the plane of the top face. */
  out[n].name = "grazing face";
  memset(&out[n].cam, 0, sizeof out[n].cam);
  out[n].cam.eye[1] = hy;
  out[n].cam.eye[2] = 4.0f * hz;
  out[n].cam.center[1] = hy;
  n++;
  out[n].name = "grazing corner";
  out[n++].cam = orbit(vol, RP_PERSPECTIVE, 45.0f, 35.26439f, 1.0f);
  out[n].name = "inside";
  out[n++].cam = orbit(vol, RP_PERSPECTIVE, 200.0f, -10.0f, 0.3f);
  out[n].name = "orthographic";
  out[n++].cam = orbit(vol, RP_ORTHOGRAPHIC, 100.0f, -30.0f, 2.0f);
  out[n].name = "orthographic inside";
  out[n++].cam = orbit(vol, RP_ORTHOGRAPHIC, 0.0f, 89.0f, 0.2f);
  return n;
}

static void check_skip_identity(rp_context *ctx, const rp_volume *vol,
                                const char *vname, uint64_t *saved) {
  const char *presets[] = {"minmax-bone", "minmax-soft", "mri"};
  const uint32_t effect_sets[] = {0, RP_EFFECT_SHADING | RP_EFFECT_ERT};
  const float steps[] = {1.0f, 0.7f};
  cam_case cams[6];
  int ncam = camera_cases(vol, cams), p, c, e;
  image off = image_new(24, 19), on = image_new(24, 19);
  for (p = 0; p < 3; p++) {
    rp_tf *tf = rp_test_preset(ctx, presets[p]);
    occ_pair o = make_occ(ctx, vol, tf);
    for (c = 0; c < ncam; c++) {
      for (e = 0; e < 2; e++) {
        float step = steps[(c + e) % 2];
        size_t t;
        render(ctx, vol, tf, NULL, &cams[c].cam, step, effect_sets[e], &off);
        render(ctx, vol, tf, o.occ, &cams[c].cam, step,
               effect_sets[e] | RP_EFFECT_SKIP, &on);
        if (memcmp(off.rgba, on.rgba, (size_t)off.w * off.h * 4) != 0)
          fail_msg("%s, %s, camera %s, effects %u: skipping changed the "
                   "image", vname, presets[p], cams[c].name,
                   (unsigned)effect_sets[e]);
        for (t = 0; t < (size_t)on.tx * on.ty; t++)
          assert_true(on.tiles[t].samples <= off.tiles[t].samples);
        *saved += total_samples(&off) - total_samples(&on);
      }
    }
    free_occ(o);
    rp_tf_destroy(tf);
  }
  image_free(&off);
  image_free(&on);
}

static void test_skip_identical(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *ph = generated(ctx, RP_GEN_PHANTOM, 64, 64, 64);
  rp_volume *big = generated(ctx, RP_GEN_PHANTOM, 128, 128, 128);
  rp_volume *ml = generated(ctx, RP_GEN_MARSCHNER_LOBB, 41, 37, 29);
  rp_volume *nz = generated(ctx, RP_GEN_NOISE, 23, 20, 18);
  uint64_t saved = 0;
  (void)state;
  check_skip_identity(ctx, ph, "phantom 64", &saved);
  check_skip_identity(ctx, ml, "marschner-lobb", &saved);
  check_skip_identity(ctx, nz, "noise", &saved);
  /* At 64^3 the body reaches a neighbour of every 16^3 block, so only
   * the finer grid of a 128^3 phantom has empty blocks to skip: there
   * skipping must save samples, not just keep the image. */
  saved = 0;
  check_skip_identity(ctx, big, "phantom 128", &saved);
  assert_true(saved > 0);
  rp_volume_destroy(ph);
  rp_volume_destroy(big);
  rp_volume_destroy(ml);
  rp_volume_destroy(nz);
  rp_context_destroy(ctx);
}

/* The skip range itself, against a grid set by hand (the real grid is
 * conservative, which hides where block boundaries fall). A constant
 * 40x4x4 volume seen along -x from x = 100: the ray enters at depth 80
 * and the lattice sample i sits at voxel x = 39.5 - i*step, in block
 * floor((39.5 - i*step + 0.5) / 16) clamped to 0..2. Only samples from
 * the first to the last in an occupied block are taken, the empty ones
 * between them included. */
static void test_skip_lattice(void **state) {
  static const uint8_t grids[][3] = {
      {0, 1, 0}, {1, 0, 1}, {0, 0, 0}, {1, 0, 0}, {0, 0, 1}, {1, 1, 1}};
  const float steps[] = {1.0f, 0.75f, 2.5f, 7.0f};
  rp_context *ctx = rp_test_context();
  rp_volume *vol = const_volume(ctx, 40, 4, 4, NULL);
  rp_tf *tf = const_tf(ctx, 1.0f, 1.0f, 1.0f, 0.04f);
  occ_pair o = make_occ(ctx, vol, tf);
  rp_camera cam;
  image im = image_new(4, 4);
  size_t g, k, p;
  (void)state;
  memset(&cam, 0, sizeof cam);
  cam.projection = RP_ORTHOGRAPHIC;
  cam.eye[0] = 100.0f;
  cam.ortho_height = 2.0f; /* all 16 rays inside the 4x4 cross-section */
  assert_int_equal(rp_histograms_block_count(o.h), 3);
  for (g = 0; g < sizeof grids / sizeof grids[0]; g++) {
    memcpy(o.occ->grid, grids[g], 3);
    for (k = 0; k < sizeof steps / sizeof steps[0]; k++) {
      double d = steps[k], a1 = 1.0 - pow(1.0 - 0.04, d), A;
      long first = -1, last = -1, i;
      uint64_t n;
      for (i = 0; 80.0 + i * d <= 120.0; i++) {
        double q = floor((39.5 - i * d + 0.5) / 16.0);
        int b = q < 0.0 ? 0 : q > 2.0 ? 2 : (int)q;
        if (grids[g][b]) {
          if (first < 0)
            first = i;
          last = i;
        }
      }
      n = first < 0 ? 0 : (uint64_t)(last - first + 1);
      A = 1.0 - pow(1.0 - a1, (double)n);
      render(ctx, vol, tf, o.occ, &cam, steps[k], RP_EFFECT_SKIP, &im);
      if (im.tiles[0].samples != 16 * n)
        fail_msg("grid %zu step %g: %u samples, want 16 x %llu", g, d,
                 (unsigned)im.tiles[0].samples, (unsigned long long)n);
      assert_int_equal(im.tiles[0].rays_hit, n > 0 ? 16 : 0);
      if (n > 0)
        assert_true(fabs(im.tiles[0].mean_depth - (80.0 + last * d)) <
                    1e-4);
      for (p = 0; p < 16 * 4; p++)
        assert_true(byte_close(im.rgba[p], A, 1));
    }
  }
  image_free(&im);
  free_occ(o);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* ---- 5: early ray termination ------------------------------------------ */

/* Once A >= threshold, every later sample adds (1 - A) a' c <= (1 - A) per
 * channel in total, so a terminated pixel is below the full one by at most
 * (1 - threshold), plus one for the two roundings. */
static void test_ert_bound(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *ph = generated(ctx, RP_GEN_PHANTOM, 48, 48, 48);
  const char *names[] = {"minmax-soft", "opaque", "mri"};
  const float thresholds[] = {0.0f, 0.9f, 0.5f};
  rp_camera cam = orbit(ph, RP_PERSPECTIVE, 40.0f, 25.0f, 2.2f);
  image full = image_new(32, 24), cut = image_new(32, 24);
  int p, k;
  (void)state;
  for (p = 0; p < 3; p++) {
    rp_tf *tf = rp_test_preset(ctx, names[p]);
    render(ctx, ph, tf, NULL, &cam, 1.0f, RP_EFFECT_SHADING, &full);
    for (k = 0; k < 3; k++) {
      rp_render_desc d = {cut.w, cut.h, 1.0f,
                          RP_EFFECT_SHADING | RP_EFFECT_ERT, thresholds[k],
                          0.0f, RP_JITTER_OFF, 0}; /* as render() */
      double thr = thresholds[k] != 0.0f ? thresholds[k] : 0.99f;
      double bound = (1.0 - thr) * 255.0 + 1.0;
      size_t i;
      assert_int_equal(rp_render_reference(ctx, ph, tf, NULL, NULL, &cam, &d,
                                           cut.rgba, cut.tiles),
                       0);
      for (i = 0; i < (size_t)cut.w * cut.h * 4; i++)
        if (fabs((double)full.rgba[i] - cut.rgba[i]) > bound)
          fail_msg("%s threshold %g: byte %zu differs %d vs %d", names[p],
                   thr, i, full.rgba[i], cut.rgba[i]);
      for (i = 0; i < (size_t)cut.tx * cut.ty; i++)
        assert_true(cut.tiles[i].samples <= full.tiles[i].samples);
      if (k == 2 || p == 1)
        assert_true(total_samples(&cut) < total_samples(&full));
    }
    rp_tf_destroy(tf);
  }
  image_free(&full);
  image_free(&cut);
  rp_volume_destroy(ph);
  rp_context_destroy(ctx);
}

/* ---- 6: odd sizes and extreme steps ------------------------------------ */

static void test_odd_sizes(void **state) {
  const uint32_t one[3] = {1, 1, 1}, odd[3] = {17, 33, 5}, tiny[3] = {3, 3,
                                                                     3};
  const float unit[3] = {1, 1, 1}, sp[3] = {1.0f, 0.5f, 1.5f};
  rp_context *ctx = rp_test_context();
  rp_volume *ph = generated(ctx, RP_GEN_PHANTOM, 24, 24, 24);
  rp_volume *cv = const_volume(ctx, 20, 20, 20, NULL);
  rp_tf *tf = rp_test_preset(ctx, "minmax-soft"),
        *ctf = const_tf(ctx, 1, 1, 1, 0.5f);
  rp_camera cam;
  image im;
  size_t t;
  (void)state;

  /* 1x1x1 volume: a box one voxel wide; the ray meets it over depth 1,
   * so two samples at step 1, one at step 1.5. */
  check_const_ortho(one, unit, 1, 1, 0.5f, 10.0f, 1.0f, 0);
  check_const_ortho(one, unit, 3, 3, 2.0f, 10.0f, 1.5f, RP_EFFECT_SKIP);
  check_const_ortho(one, unit, 1, 1, 0.5f, 10.0f, 1e-3f, 0);
  /* 17x33x5, anisotropic, odd viewport, eye inside the box. */
  check_const_ortho(odd, sp, 13, 9, 20.0f, 2.0f, 1.0f, 0);
  check_const_ortho(odd, sp, 13, 9, 20.0f, 30.0f, 0.9f, RP_EFFECT_SKIP);
  /* Tiny step on a tiny volume: thousands of samples per ray. */
  check_const_ortho(tiny, unit, 4, 4, 2.5f, 5.0f, 1e-3f, 0);
  /* A huge step: exactly one sample per ray that meets the box. */
  check_const_ortho(odd, sp, 13, 9, 20.0f, 30.0f, 1e3f, 0);

  /* 1x1 viewport: one tile. */
  im = image_new(1, 1);
  assert_int_equal(im.tx * im.ty, 1);
  cam = orbit(ph, RP_PERSPECTIVE, 10.0f, 10.0f, 2.0f);
  render(ctx, ph, tf, NULL, &cam, 1.0f, RP_EFFECT_SHADING, &im);
  assert_int_equal(im.tiles[0].rays_hit, 1);
  assert_true(im.tiles[0].samples > 10);
  image_free(&im);

  /* 7x513: one tile column, a last tile row of one pixel. */
  im = image_new(7, 513);
  assert_int_equal(im.tx, 1);
  assert_int_equal(im.ty, 65);
  cam = orbit(ph, RP_PERSPECTIVE, 10.0f, 10.0f, 2.0f);
  render(ctx, ph, tf, NULL, &cam, 1.0f, 0, &im);
  for (t = 0; t < 65; t++)
    assert_true(im.tiles[t].rays_hit <= (t == 64 ? 7u : 56u));
  assert_true(total_hits(&im) > 0);
  image_free(&im);

  /* Step 1e3 from an orbit: one sample per hit ray, at the entry. */
  im = image_new(20, 20);
  cam = orbit(cv, RP_PERSPECTIVE, 33.0f, -21.0f, 2.0f);
  render(ctx, cv, ctf, NULL, &cam, 1e3f, 0, &im);
  for (t = 0; t < (size_t)im.tx * im.ty; t++)
    assert_int_equal(im.tiles[t].samples, im.tiles[t].rays_hit);
  assert_true(total_hits(&im) > 100);
  /* Each hit pixel holds a' = 1 - 0.5^1000, i.e. opaque white. */
  for (t = 0; t < (size_t)im.w * im.h; t++)
    assert_true(im.rgba[t * 4 + 3] == 0 || im.rgba[t * 4 + 3] == 255);
  image_free(&im);

  rp_tf_destroy(tf);
  rp_tf_destroy(ctf);
  rp_volume_destroy(ph);
  rp_volume_destroy(cv);
  rp_context_destroy(ctx);
}

/* ---- 7: camera inside the volume -------------------------------------- */

static void test_camera_inside(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *ph = generated(ctx, RP_GEN_PHANTOM, 40, 40, 40);
  rp_tf *tf = rp_test_preset(ctx, "minmax-soft");
  rp_camera out = orbit(ph, RP_PERSPECTIVE, 70.0f, 15.0f, 2.5f);
  rp_camera in = orbit(ph, RP_PERSPECTIVE, 70.0f, 15.0f, 0.25f);
  image a = image_new(24, 24), b = image_new(24, 24);
  (void)state;
  render(ctx, ph, tf, NULL, &out, 1.0f, 0, &a);
  render(ctx, ph, tf, NULL, &in, 1.0f, 0, &b);
  /* Inside the box every ray samples at least at the eye. */
  assert_int_equal(total_hits(&b), 24 * 24);
  assert_true(total_samples(&b) > 0);
  assert_true(mean_depth(&b) < mean_depth(&a));
  /* The far face is at most the box diagonal (in voxels) away. */
  assert_true(mean_depth(&b) <= sqrt(3.0) * 40.0);
  image_free(&a);
  image_free(&b);
  rp_tf_destroy(tf);
  rp_volume_destroy(ph);
  rp_context_destroy(ctx);
}

/* ---- 10: bad arguments -------------------------------------------------- */

typedef struct bad_case {
  const char *what;
  int want;
  const char *needle; /* must appear in rp_last_error */
} bad_case;

static void expect_fail(rp_context *ctx, const rp_volume *vol,
                        const rp_tf *tf, const rp_occupancy *occ,
                        const rp_camera *cam, const rp_render_desc *desc,
                        uint8_t *rgba, const bad_case *bc) {
  rp_tile_stats tiles[4];
  uint8_t before[4 * 4 * 4];
  int err;
  if (rgba != NULL)
    memcpy(before, rgba, sizeof before);
  memset(tiles, 0x5A, sizeof tiles);
  err = rp_render_reference(ctx, vol, tf, occ, NULL, cam, desc, rgba, tiles);
  if (err != bc->want)
    fail_msg("%s: got %s, want %s (%s)", bc->what, rp_err_name(err),
             rp_err_name(bc->want), rp_last_error(ctx));
  if (strstr(rp_last_error(ctx), bc->needle) == NULL)
    fail_msg("%s: message '%s' does not name '%s'", bc->what,
             rp_last_error(ctx), bc->needle);
  /* A failed call leaves its outputs alone. */
  if (rgba != NULL)
    assert_memory_equal(before, rgba, sizeof before);
  assert_true(tiles[0].samples == 0x5A5A5A5Au);
}

/* Cameras the reference refuses, each naming the field. */
static void test_bad_cameras(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *vol = const_volume(ctx, 8, 8, 8, NULL);
  rp_tf *tf = const_tf(ctx, 1, 1, 1, 0.5f);
  rp_camera good = orbit(vol, RP_PERSPECTIVE, 10, 10, 2), cam;
  rp_render_desc ok = {4, 4, 0.0f, 0, 0.0f, 0.0f, RP_JITTER_DEFAULT, 0};
  uint8_t rgba[4 * 4 * 4];
  (void)state;
  memset(rgba, 0x33, sizeof rgba);
#define CAM_CASE(stmt, needle)                                                \
  do {                                                                        \
    bad_case bc = {#stmt, RP_EINVAL, needle};                                 \
    cam = good;                                                               \
    stmt;                                                                     \
    expect_fail(ctx, vol, tf, NULL, &cam, &ok, rgba, &bc);                    \
  } while (0)
  CAM_CASE(memcpy(cam.center, cam.eye, sizeof cam.eye), "center");
  CAM_CASE(cam.eye[1] = NAN, "eye[1]");
  CAM_CASE(cam.center[2] = INFINITY, "center[2]");
  CAM_CASE(cam.up[0] = NAN, "up[0]");
  CAM_CASE(cam.fov_y_deg = 180.0f, "fov_y_deg");
  CAM_CASE(cam.fov_y_deg = -5.0f, "fov_y_deg");
  CAM_CASE(cam.fov_y_deg = NAN, "fov_y_deg");
  CAM_CASE(cam.ortho_height = -1.0f, "ortho_height");
  CAM_CASE(cam.projection = (rp_projection)7, "projection");
  CAM_CASE((cam.up[0] = cam.center[0] - cam.eye[0],
            cam.up[1] = cam.center[1] - cam.eye[1],
            cam.up[2] = cam.center[2] - cam.eye[2]),
           "up");
#undef CAM_CASE
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* Tiles of 8x8 pixels: ceil(w / 8) x ceil(h / 8), NULL outputs allowed. */
static void test_tile_grid(void **state) {
  uint32_t tx, ty;
  (void)state;
  rp_tile_grid(0, 0, &tx, &ty);
  assert_true(tx == 0 && ty == 0);
  rp_tile_grid(1, 8, &tx, &ty);
  assert_true(tx == 1 && ty == 1);
  rp_tile_grid(9, 17, &tx, &ty);
  assert_true(tx == 2 && ty == 3);
  rp_tile_grid(UINT32_MAX, 16, &tx, &ty);
  assert_true(tx == 536870912u && ty == 2);
  rp_tile_grid(5, 5, NULL, NULL);
}

static void test_bad_arguments(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *vol = const_volume(ctx, 8, 8, 8, NULL);
  rp_volume *other = const_volume(ctx, 8, 8, 9, NULL);
  rp_tf *tf = const_tf(ctx, 1, 1, 1, 0.5f), *tf2 = const_tf(ctx, 1, 0, 0, 1);
  occ_pair o = make_occ(ctx, vol, tf), o2 = make_occ(ctx, vol, tf2);
  occ_pair o3 = make_occ(ctx, other, tf);
  rp_camera good = orbit(vol, RP_PERSPECTIVE, 10, 10, 2);
  rp_render_desc ok = {4, 4, 0.0f, 0, 0.0f, 0.0f, RP_JITTER_DEFAULT, 0}, d;
  uint8_t rgba[4 * 4 * 4];
  (void)state;
  memset(rgba, 0x33, sizeof rgba);
  assert_int_equal(rp_render_reference(NULL, vol, tf, NULL, NULL, &good, &ok, rgba,
                                       NULL),
                   RP_EINVAL);
  {
    bad_case bc = {"NULL vol", RP_EINVAL, "vol"};
    expect_fail(ctx, NULL, tf, NULL, &good, &ok, rgba, &bc);
  }
  {
    bad_case bc = {"NULL tf", RP_EINVAL, "tf"};
    expect_fail(ctx, vol, NULL, NULL, &good, &ok, rgba, &bc);
  }
  {
    bad_case bc = {"NULL cam", RP_EINVAL, "cam"};
    expect_fail(ctx, vol, tf, NULL, NULL, &ok, rgba, &bc);
  }
  {
    bad_case bc = {"NULL desc", RP_EINVAL, "desc"};
    expect_fail(ctx, vol, tf, NULL, &good, NULL, rgba, &bc);
  }
  {
    bad_case bc = {"NULL rgba", RP_EINVAL, "rgba"};
    expect_fail(ctx, vol, tf, NULL, &good, &ok, NULL, &bc);
  }
#define DESC_CASE(field, value, code, needle)                                 \
  do {                                                                        \
    bad_case bc = {#field " = " #value, code, needle};                        \
    d = ok;                                                                   \
    d.field = value;                                                          \
    expect_fail(ctx, vol, tf, o.occ, &good, &d, rgba, &bc);                   \
  } while (0)
  DESC_CASE(width, 0, RP_EINVAL, "width");
  DESC_CASE(height, 0, RP_EINVAL, "height");
  DESC_CASE(step, -1.0f, RP_EINVAL, "step");
  DESC_CASE(step, NAN, RP_EINVAL, "step");
  DESC_CASE(step, INFINITY, RP_EINVAL, "step");
  DESC_CASE(ert_threshold, -0.5f, RP_EINVAL, "ert_threshold");
  DESC_CASE(ert_threshold, 1.5f, RP_EINVAL, "ert_threshold");
  DESC_CASE(ert_threshold, NAN, RP_EINVAL, "ert_threshold");
  DESC_CASE(effects, 1u << 9, RP_EINVAL, "effects");
  DESC_CASE(effects, RP_EFFECT_AO, RP_EINVAL, "ao is NULL");
#undef DESC_CASE
  {
    /* Refused by RP_IMAGE_MAX_DIM long before the bytes could wrap. */
    bad_case bc = {"width*height*4 overflow", RP_EINVAL,
                   "4294967295x4294967295; each must be in [1, 16384]"};
    d = ok;
    d.width = UINT32_MAX;
    d.height = UINT32_MAX;
    expect_fail(ctx, vol, tf, NULL, &good, &d, rgba, &bc);
  }
  {
    bad_case bc = {"SKIP without occ", RP_EINVAL, "occ"};
    d = ok;
    d.effects = RP_EFFECT_SKIP;
    expect_fail(ctx, vol, tf, NULL, &good, &d, rgba, &bc);
  }
  {
    bad_case bc = {"occ of another tf", RP_EINVAL, "transfer function"};
    d = ok;
    d.effects = RP_EFFECT_SKIP;
    expect_fail(ctx, vol, tf, o2.occ, &good, &d, rgba, &bc);
  }
  {
    bad_case bc = {"occ of another volume", RP_EINVAL, "another volume"};
    d = ok;
    d.effects = RP_EFFECT_SKIP;
    expect_fail(ctx, vol, tf, o3.occ, &good, &d, rgba, &bc);
  }
  {
    /* Same dims, other voxels: dims alone cannot tell them apart. */
    rp_volume *twin = const_volume(ctx, 8, 8, 8, NULL);
    occ_pair ot = make_occ(ctx, twin, tf);
    bad_case bc = {"occ of a same-size volume", RP_EINVAL,
                   "another volume"};
    d = ok;
    d.effects = RP_EFFECT_SKIP;
    expect_fail(ctx, vol, tf, ot.occ, &good, &d, rgba, &bc);
    free_occ(ot);
    rp_volume_destroy(twin);
  }
  /* An invalid argument is reported before the unsupported effect. */
  {
    bad_case bc = {"AO and bad step", RP_EINVAL, "step"};
    d = ok;
    d.effects = RP_EFFECT_AO;
    d.step = -2.0f;
    expect_fail(ctx, vol, tf, NULL, &good, &d, rgba, &bc);
  }
  /* The valid call still works, and tiles may be NULL. */
  assert_int_equal(rp_render_reference(ctx, vol, tf, NULL, NULL, &good, &ok, rgba,
                                       NULL),
                   0);


  free_occ(o);
  free_occ(o2);
  free_occ(o3);
  rp_tf_destroy(tf);
  rp_tf_destroy(tf2);
  rp_volume_destroy(vol);
  rp_volume_destroy(other);
  rp_context_destroy(ctx);
}

/* ---- 11: real data ------------------------------------------------------ */

static void test_bonsai_skip(void **state) {
  char path[1024];
  rp_context *ctx;
  rp_volume *vol = NULL;
  rp_tf *tf;
  occ_pair o;
  rp_camera cam;
  image off, on;
  int err;
  (void)state;
  if (rp_test_data_volume("bonsai", path, sizeof path) == NULL) {
    skip();
    return;
  }
  ctx = rp_test_context();
  err = rp_volume_load(ctx, path, &vol);
  if (err != 0)
    fail_msg("loading %s: %s", path, rp_last_error(ctx));
  tf = rp_test_preset(ctx, "minmax-bone");
  o = make_occ(ctx, vol, tf);
  cam = orbit(vol, RP_PERSPECTIVE, 30.0f, 15.0f, 1.8f);
  off = image_new(64, 64);
  on = image_new(64, 64);
  render(ctx, vol, tf, NULL, &cam, 1.0f, RP_EFFECT_SHADING | RP_EFFECT_ERT,
         &off);
  render(ctx, vol, tf, o.occ, &cam, 1.0f,
         RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP, &on);
  assert_memory_equal(off.rgba, on.rgba, (size_t)64 * 64 * 4);
  assert_true(total_samples(&on) < total_samples(&off));
  image_free(&off);
  image_free(&on);
  free_occ(o);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_const_volume_closed_form),
      cmocka_unit_test(test_transparent_and_opaque),
      cmocka_unit_test(test_trilinear),
      cmocka_unit_test(test_camera_rays),
      cmocka_unit_test(test_shading_closed_form),
      cmocka_unit_test(test_skip_identical),
      cmocka_unit_test(test_skip_lattice),
      cmocka_unit_test(test_ert_bound),
      cmocka_unit_test(test_odd_sizes),
      cmocka_unit_test(test_camera_inside),
      cmocka_unit_test(test_bad_arguments),
      cmocka_unit_test(test_bad_cameras),
      cmocka_unit_test(test_tile_grid),
      cmocka_unit_test(test_bonsai_skip),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
