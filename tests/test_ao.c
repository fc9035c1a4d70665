/* Ambient occlusion: the scalar reference against closed forms, bricking
 * against the unbricked computation (values and rendered images), the
 * plan's brick counts against brute force, and the device front end's
 * checks. Nothing expected is computed by calling the code under test. */
#include "test_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "raypace_ao.h"

/* ---- helpers ----------------------------------------------------------- */

static rp_volume *generated(rp_context *ctx, rp_generator kind, uint32_t nx,
                            uint32_t ny, uint32_t nz) {
  rp_generate_desc g = {kind, {nx, ny, nz}, RP_U8, 7};
  rp_volume *vol = NULL;
  assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
  return vol;
}

/* A TF of the same colour and opacity at every value. */
static rp_tf *constant_tf(rp_context *ctx, float alpha, float ref_step) {
  rp_tf_point pts[2] = {{0.0f, 1.0f, 1.0f, 1.0f, alpha},
                        {1.0f, 1.0f, 1.0f, 1.0f, alpha}};
  rp_tf_desc d = {pts, 2, ref_step, 0, 0, 0, 0, 0};
  rp_tf *tf = NULL;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), 0);
  return tf;
}

/* Depth along unit-ish direction d from voxel centre v at which the ray
 * leaves the box [-0.5, dims - 0.5]: the slab test's exit. */
static double box_exit(const uint32_t dims[3], const double v[3],
                       const float d[3]) {
  double t = INFINITY;
  int a;
  for (a = 0; a < 3; a++) {
    double e;
    if (d[a] > 0.0f)
      e = ((double)dims[a] - 0.5 - v[a]) / (double)d[a];
    else if (d[a] < 0.0f)
      e = (-0.5 - v[a]) / (double)d[a];
    else
      continue;
    t = e < t ? e : t;
  }
  return t;
}

/* ---- tests ------------------------------------------------------------- */

/* The directions are unit vectors spread evenly: their centroid is near
 * the origin and no two are closer than a Fibonacci spiral allows. */
static void test_directions(void **state) {
  static const uint32_t counts[] = {1, 2, 7, 16, 64, 256};
  size_t c;
  (void)state;
  for (c = 0; c < sizeof counts / sizeof counts[0]; c++) {
    uint32_t n = counts[c], l, m;
    double sum[3] = {0, 0, 0}, closest = 4.0;
    for (l = 0; l < n; l++) {
      float d[3], e[3];
      rp_ao_direction(l, n, d);
      assert_true(fabs(sqrt((double)d[0] * d[0] + (double)d[1] * d[1] +
                            (double)d[2] * d[2]) -
                       1.0) < 1e-6);
      sum[0] += d[0], sum[1] += d[1], sum[2] += d[2];
      for (m = l + 1; m < n; m++) {
        double dd;
        rp_ao_direction(m, n, e);
        dd = sqrt(((double)d[0] - e[0]) * ((double)d[0] - e[0]) +
                  ((double)d[1] - e[1]) * ((double)d[1] - e[1]) +
                  ((double)d[2] - e[2]) * ((double)d[2] - e[2]));
        closest = dd < closest ? dd : closest;
      }
    }
    /* z is symmetric by construction; x and y sum to little. */
    assert_true(fabs(sum[2]) < 1e-5);
    if (n >= 7) {
      assert_true(hypot(sum[0], sum[1]) / n < 0.1);
      /* Points of area 4 pi / n each: neighbours at least half the
       * spacing sqrt(4 pi / n) apart. */
      assert_true(closest > 0.5 * sqrt(4.0 * 3.14159265358979 / n));
    }
  }
}

/* A constant opacity c everywhere inside the box: along direction l the
 * first K samples lie inside (the box is convex and contains the voxel
 * centre), so after sample m the transmittance is (1 - c')^min(m, K) with
 * c' corrected to the AO step. I_l and AO follow in closed form; the
 * stored byte is within 1 of its rounding. */
static void check_constant(rp_context *ctx, const uint32_t dims[3],
                           float alpha, const char *what) {
  rp_volume *vol = generated(ctx, RP_GEN_NOISE, dims[0], dims[1], dims[2]);
  rp_tf *tf = constant_tf(ctx, alpha, 0.5f);
  rp_ao_desc desc = {12, 5, 6.0f, 1.5f, 1};
  rp_ao *ao = NULL;
  const uint8_t *got;
  double step = (6.0 - 1.5) / 5.0;
  double corr = 1.0 - pow(1.0 - alpha, step / 0.5);
  uint32_t i, j, k, l, m, worst = 0;
  assert_int_equal(rp_ao_compute_reference(ctx, vol, tf, &desc, NULL, NULL,
                                           &ao),
                   0);
  got = rp_ao_data(ao, NULL);
  for (k = 0; k < dims[2]; k++)
    for (j = 0; j < dims[1]; j++)
      for (i = 0; i < dims[0]; i++) {
        double v[3] = {i, j, k}, acc = 0.0, want;
        uint32_t diff;
        uint8_t g = got[((size_t)k * dims[1] + j) * dims[0] + i];
        for (l = 0; l < 12; l++) {
          float d[3];
          double exit_t, I = 0.0;
          uint32_t K = 0;
          rp_ao_direction(l, 12, d);
          exit_t = box_exit(dims, v, d);
          while (K < 5 && 1.5 + K * step <= exit_t)
            K++;
          for (m = 1; m <= 5; m++)
            I += pow(1.0 - corr, m < K ? m : K);
          acc += I / 5.0;
        }
        want = floor(acc / 12.0 * 255.0 + 0.5);
        diff = (uint32_t)fabs((double)g - want);
        worst = diff > worst ? diff : worst;
      }
  if (worst > 1)
    fail_msg("%s: AO off the closed form by %u", what, worst);
  rp_ao_destroy(ao);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
}

static void test_closed_forms(void **state) {
  rp_context *ctx = *state;
  static const uint32_t odd[3] = {13, 9, 11}, one[3] = {1, 1, 1};
  static const uint32_t flat[3] = {2, 3, 1}, thin[3] = {1, 17, 2};
  check_constant(ctx, odd, 0.0f, "transparent");
  check_constant(ctx, odd, 0.3f, "alpha 0.3");
  check_constant(ctx, odd, 1.0f, "opaque");
  check_constant(ctx, odd, 1e-6f, "nearly transparent");
  check_constant(ctx, one, 1.0f, "1x1x1 opaque");
  check_constant(ctx, flat, 0.6f, "2x3x1");
  check_constant(ctx, thin, 0.9f, "1x17x2");
}

/* Transparent everywhere: every brick is empty, every voxel 255, and
 * bricking computed none of them. */
static void test_transparent(void **state) {
  rp_context *ctx = *state;
  rp_volume *vol = generated(ctx, RP_GEN_PHANTOM, 21, 18, 17);
  rp_tf *tf = rp_test_preset(ctx, "transparent");
  rp_ao *ao = NULL;
  uint64_t computed, total;
  uint32_t dims[3];
  const uint8_t *v;
  size_t n, i;
  assert_int_equal(rp_ao_compute_reference(ctx, vol, tf, NULL, NULL, NULL,
                                           &ao),
                   0);
  v = rp_ao_data(ao, dims);
  n = (size_t)dims[0] * dims[1] * dims[2];
  for (i = 0; i < n; i++)
    assert_int_equal(v[i], 255);
  rp_ao_bricks(ao, &computed, &total);
  assert_int_equal(computed, 0);
  assert_int_equal(total, 6 * 5 * 5);
  rp_ao_destroy(ao);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
}

static void record_progress(double f, void *user) {
  double *last = user;
  assert_true(f >= last[0] && f <= 1.0);
  last[0] = f;
  last[1] += 1.0;
}

/* Bricked AO equals unbricked AO on every voxel of a full brick, is 255
 * elsewhere, and the images rendered with either are identical: the
 * overlap keeps every voxel a visible sample interpolates. The phantom
 * under minmax-bone has empty bricks next to full ones all along its core. */
static void test_bricking_is_seamless(void **state) {
  rp_context *ctx = *state;
  rp_volume *vol = generated(ctx, RP_GEN_PHANTOM, 38, 35, 33);
  rp_tf *tf = rp_test_preset(ctx, "minmax-bone");
  rp_ao_desc bricked = {8, 6, 5.0f, 1.0f, 0}, full = bricked;
  rp_ao *a = NULL, *b = NULL;
  uint64_t computed, total;
  uint32_t dims[3], i, j, k;
  const uint8_t *va, *vb;
  double progress[2] = {0.0, 0.0};
  rp_camera cam = {0};
  rp_render_desc d = {96, 96, 0.5f, RP_EFFECT_AO | RP_EFFECT_SHADING, 0, 0,
                      RP_JITTER_DEFAULT, 0};
  uint8_t *ia = malloc(96 * 96 * 4), *ib = malloc(96 * 96 * 4);
  uint8_t *plain = malloc(96 * 96 * 4);
  size_t p, darker = 0;
  full.unbricked = 1;
  assert_true(ia && ib && plain);
  assert_int_equal(rp_ao_compute_reference(ctx, vol, tf, &bricked,
                                           record_progress, progress, &a),
                   0);
  assert_true(progress[0] == 1.0 && progress[1] >= 2.0);
  assert_int_equal(rp_ao_compute_reference(ctx, vol, tf, &full, NULL, NULL,
                                           &b),
                   0);
  rp_ao_bricks(a, &computed, &total);
  /* Some bricks skipped, some computed: the case is seam-prone. */
  assert_true(computed > 0 && computed < total);
  va = rp_ao_data(a, dims);
  vb = rp_ao_data(b, NULL);
  for (k = 0; k < dims[2]; k++)
    for (j = 0; j < dims[1]; j++)
      for (i = 0; i < dims[0]; i++) {
        size_t o = ((size_t)k * dims[1] + j) * dims[0] + i;
        assert_true(va[o] == vb[o] || va[o] == 255);
      }
  rp_camera_orbit(&cam, vol, 30.0f, 20.0f, 1.6f);
  assert_int_equal(rp_render_reference(ctx, vol, tf, NULL, a, &cam, &d, ia,
                                       NULL),
                   0);
  assert_int_equal(rp_render_reference(ctx, vol, tf, NULL, b, &cam, &d, ib,
                                       NULL),
                   0);
  assert_memory_equal(ia, ib, 96 * 96 * 4);
  /* AO only darkens: same alpha, colour never brighter, and visibly
   * darker somewhere. */
  d.effects = RP_EFFECT_SHADING;
  assert_int_equal(rp_render_reference(ctx, vol, tf, NULL, NULL, &cam, &d,
                                       plain, NULL),
                   0);
  for (p = 0; p < 96 * 96; p++) {
    int c;
    assert_int_equal(ia[4 * p + 3], plain[4 * p + 3]);
    for (c = 0; c < 3; c++)
      assert_true(ia[4 * p + c] <= plain[4 * p + c]);
    darker += ia[4 * p] + 8 < plain[4 * p];
  }
  assert_true(darker > 100);
  free(ia);
  free(ib);
  free(plain);
  rp_ao_destroy(a);
  rp_ao_destroy(b);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
}

/* Whether the LUT (linear between entries) has opacity above 0 anywhere
 * on [x0, x1]: at an end, or at an entry strictly between. */
static int lut_nonzero(const rp_tf *tf, double x0, double x1) {
  int n, i;
  const float *lut = rp_tf_lut(tf, &n);
  double f0 = fmin(fmax(x0, 0.0), 1.0) * (n - 1);
  double f1 = fmin(fmax(x1, 0.0), 1.0) * (n - 1);
  for (i = (int)floor(f0); i <= (int)ceil(f1) && i < n; i++) {
    double w;
    int e = i < n - 1 ? i : n - 2;
    if (i > f0 && i < f1 && lut[4 * i + 3] > 0.0f)
      return 1;
    /* The two ends, interpolated. */
    w = f0 - e;
    if (f0 >= e && f0 <= e + 1 &&
        (1.0 - w) * lut[4 * e + 3] + w * lut[4 * (e + 1) + 3] > 0.0)
      return 1;
    w = f1 - e;
    if (f1 >= e && f1 <= e + 1 &&
        (1.0 - w) * lut[4 * e + 3] + w * lut[4 * (e + 1) + 3] > 0.0)
      return 1;
  }
  return 0;
}

/* Full bricks in a box, O(1) from the plan, against a brute-force count:
 * each brick's voxels and a one-voxel overlap scanned for their value
 * range, the LUT checked over it, then the bricks the box overlaps
 * counted one by one. */
static void test_plan_counts(void **state) {
  rp_context *ctx = *state;
  uint32_t dims[3] = {30, 27, 25}, g[3] = {8, 7, 7};
  rp_volume *vol = generated(ctx, RP_GEN_PHANTOM, dims[0], dims[1], dims[2]);
  rp_tf *tf = rp_test_preset(ctx, "minmax-bone");
  const uint8_t *vox = rp_volume_data(vol);
  rp_volume_info info;
  rp_ao_plan *plan = NULL, *all = NULL;
  uint8_t full[8 * 7 * 7];
  uint32_t trial, b[3], n_full = 0;
  unsigned seed = 12345;
  rp_ao_desc desc = {4, 2, 3.0f, 1.0f, 0}, unbricked = desc;
  uint32_t lo0[3] = {0, 0, 0};
  unbricked.unbricked = 1;
  rp_volume_get_info(vol, &info);
  for (b[2] = 0; b[2] < g[2]; b[2]++)
    for (b[1] = 0; b[1] < g[1]; b[1]++)
      for (b[0] = 0; b[0] < g[0]; b[0]++) {
        uint32_t lo[3], hi[3], x, y, z, a;
        double mn = 1e30, mx = -1e30;
        for (a = 0; a < 3; a++) {
          lo[a] = b[a] * 4 > 0 ? b[a] * 4 - 1 : 0;
          hi[a] = b[a] * 4 + 5 < dims[a] ? b[a] * 4 + 5 : dims[a];
        }
        for (z = lo[2]; z < hi[2]; z++)
          for (y = lo[1]; y < hi[1]; y++)
            for (x = lo[0]; x < hi[0]; x++) {
              double v = vox[((size_t)z * dims[1] + y) * dims[0] + x];
              mn = v < mn ? v : mn;
              mx = v > mx ? v : mx;
            }
        full[(b[2] * g[1] + b[1]) * g[0] + b[0]] =
            (uint8_t)lut_nonzero(tf, (mn - info.min) / (info.max - info.min),
                                 (mx - info.min) / (info.max - info.min));
        n_full += full[(b[2] * g[1] + b[1]) * g[0] + b[0]];
      }
  /* Neither none nor all: the count has something to get wrong. */
  assert_true(n_full > 0 && n_full < 8 * 7 * 7);
  assert_int_equal(rp_ao_plan_create(ctx, vol, tf, &desc, &plan), 0);
  assert_int_equal(rp_ao_plan_create(ctx, vol, tf, &unbricked, &all), 0);
  assert_int_equal(rp_ao_plan_full_bricks(plan, lo0, dims), n_full);
  assert_int_equal(rp_ao_plan_full_bricks(all, lo0, dims), 8 * 7 * 7);
  for (trial = 0; trial < 300; trial++) {
    uint32_t lo[3], end[3], a, x, y, z;
    uint64_t want = 0, boxes = 1;
    for (a = 0; a < 3; a++) {
      seed = seed * 1103515245u + 12345u;
      lo[a] = (seed >> 8) % dims[a];
      seed = seed * 1103515245u + 12345u;
      end[a] = lo[a] + 1 + (seed >> 8) % (dims[a] - lo[a]);
      boxes *= (end[a] - 1) / 4 - lo[a] / 4 + 1;
    }
    for (z = lo[2] / 4; z <= (end[2] - 1) / 4; z++)
      for (y = lo[1] / 4; y <= (end[1] - 1) / 4; y++)
        for (x = lo[0] / 4; x <= (end[0] - 1) / 4; x++)
          want += full[(z * g[1] + y) * g[0] + x];
    assert_int_equal(rp_ao_plan_full_bricks(plan, lo, end), want);
    assert_int_equal(rp_ao_plan_full_bricks(all, lo, end), boxes);
  }
  rp_ao_plan_destroy(plan);
  rp_ao_plan_destroy(all);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
}

/* The reference device computes any box of the volume exactly as the
 * reference computation of the whole, and renders with the AO it holds
 * exactly as rp_render_reference does with it. */
static void test_reference_device(void **state) {
  rp_context *ctx = *state;
  rp_volume *vol = generated(ctx, RP_GEN_PHANTOM, 27, 22, 19);
  rp_tf *tf = rp_test_preset(ctx, "minmax-soft"),
        *other = rp_test_preset(ctx, "minmax-bone");
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL, *occ2 = NULL;
  rp_device_desc dd = {0};
  rp_device *dev = NULL;
  rp_ao_desc desc = {6, 4, 4.0f, 1.0f, 0};
  rp_ao_plan *plan = NULL;
  rp_ao *ao = NULL;
  const uint8_t *whole;
  uint32_t dims[3], boxes[3][6] = {{0, 0, 0, 27, 22, 19},
                                    {3, 5, 7, 4, 6, 8},
                                    {10, 0, 11, 27, 9, 19}};
  rp_camera cam = {0};
  rp_render_desc d = {64, 48, 0.75f, RP_EFFECT_AO | RP_EFFECT_SKIP, 0, 0,
                      RP_JITTER_DEFAULT, 0};
  uint8_t *got = malloc(64 * 48 * 4), *want = malloc(64 * 48 * 4);
  int b;
  assert_true(got && want);
  dd.backend = "reference";
  assert_int_equal(rp_device_create(ctx, &dd, &dev), 0);
  assert_int_equal(rp_histograms_build(ctx, vol, &h), 0);
  assert_int_equal(rp_occupancy_build(ctx, h, tf, &occ), 0);
  assert_int_equal(rp_occupancy_build(ctx, h, other, &occ2), 0);
  assert_int_equal(rp_device_set_volume(dev, vol), 0);
  assert_int_equal(rp_ao_plan_create(ctx, vol, tf, &desc, &plan), 0);
  /* The plan is for minmax-soft; the device holds no TF, then another. */
  assert_int_equal(rp_device_compute_ao(dev, plan, boxes[0], boxes[0] + 3,
                                        got),
                   RP_ESTATE);
  assert_int_equal(rp_device_set_tf(dev, other, occ2), 0);
  assert_int_equal(rp_device_compute_ao(dev, plan, boxes[0], boxes[0] + 3,
                                        got),
                   RP_ESTATE);
  assert_int_equal(rp_device_set_tf(dev, tf, occ), 0);
  assert_int_equal(rp_ao_compute_reference(ctx, vol, tf, &desc, NULL, NULL,
                                           &ao),
                   0);
  whole = rp_ao_data(ao, dims);
  for (b = 0; b < 3; b++) {
    const uint32_t *lo = boxes[b], *end = boxes[b] + 3;
    uint32_t nx = end[0] - lo[0], ny = end[1] - lo[1], i, j, k;
    uint8_t *part = malloc((size_t)nx * ny * (end[2] - lo[2]));
    assert_non_null(part);
    assert_int_equal(rp_device_compute_ao(dev, plan, lo, end, part), 0);
    for (k = lo[2]; k < end[2]; k++)
      for (j = lo[1]; j < end[1]; j++)
        for (i = lo[0]; i < end[0]; i++)
          assert_int_equal(
              part[((size_t)(k - lo[2]) * ny + (j - lo[1])) * nx +
                   (i - lo[0])],
              whole[((size_t)k * dims[1] + j) * dims[0] + i]);
    free(part);
  }
  {
    /* Boxes outside the volume or empty are refused. */
    uint32_t lo[3] = {0, 0, 0}, end[3] = {28, 22, 19};
    assert_int_equal(rp_device_compute_ao(dev, plan, lo, end, got),
                     RP_EINVAL);
    end[0] = 0;
    assert_int_equal(rp_device_compute_ao(dev, plan, lo, end, got),
                     RP_EINVAL);
  }
  rp_camera_orbit(&cam, vol, -40.0f, 10.0f, 1.5f);
  /* No AO set: the render is refused, and no AO memory exists. */
  assert_int_equal(rp_device_ao_bytes(dev), 0);
  assert_int_equal(rp_device_render(dev, &cam, &d, NULL, got, NULL),
                   RP_ESTATE);
  assert_int_equal(rp_device_set_ao(dev, ao), 0);
  assert_int_equal(rp_device_ao_bytes(dev), 27 * 22 * 19);
  assert_int_equal(rp_device_render(dev, &cam, &d, NULL, got, NULL), 0);
  assert_int_equal(rp_render_reference(ctx, vol, tf, occ, ao, &cam, &d, want,
                                       NULL),
                   0);
  assert_memory_equal(got, want, 64 * 48 * 4);
  /* AO for minmax-soft does not render under minmax-bone. */
  assert_int_equal(rp_device_set_tf(dev, other, occ2), 0);
  assert_int_equal(rp_device_render(dev, &cam, &d, NULL, got, NULL),
                   RP_ESTATE);
  assert_int_equal(rp_render_reference(ctx, vol, other, occ2, ao, &cam, &d,
                                       want, NULL),
                   RP_EINVAL);
  assert_int_equal(rp_device_set_ao(dev, NULL), 0);
  assert_int_equal(rp_device_ao_bytes(dev), 0);
  free(got);
  free(want);
  rp_ao_destroy(ao);
  rp_ao_plan_destroy(plan);
  rp_device_destroy(dev);
  rp_occupancy_destroy(occ);
  rp_occupancy_destroy(occ2);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
  rp_tf_destroy(other);
  rp_volume_destroy(vol);
}

/* Every out-of-range desc field is refused with its own code and a
 * message naming it; nothing is allocated for the caller. */
static void test_bad_desc(void **state) {
  rp_context *ctx = *state;
  rp_volume *vol = generated(ctx, RP_GEN_PHANTOM, 8, 8, 8);
  rp_tf *tf = rp_test_preset(ctx, "minmax-soft");
  struct {
    rp_ao_desc d;
    int err;
    const char *word;
  } cases[] = {
      {{257, 0, 0, 0, 0}, RP_ERANGE, "directions"},
      {{0, 257, 0, 0, 0}, RP_ERANGE, "samples"},
      {{0, 0, NAN, 0, 0}, RP_ENOTFINITE, "radius"},
      {{0, 0, 0, INFINITY, 0}, RP_ENOTFINITE, "offset"},
      {{0, 0, -1.0f, 0, 0}, RP_ERANGE, "radius"},
      {{0, 0, 300.0f, 0, 0}, RP_ERANGE, "radius"},
      {{0, 0, 4.0f, 4.0f, 0}, RP_ERANGE, "offset"},
      {{0, 0, 4.0f, -1.0f, 0}, RP_ERANGE, "offset"},
      {{0, 0, 0, 0, 2}, RP_EINVAL, "unbricked"},
  };
  size_t i;
  for (i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    rp_ao *ao = (rp_ao *)&cases; /* must stay untouched */
    rp_ao_plan *plan = (rp_ao_plan *)&cases;
    assert_int_equal(rp_ao_compute_reference(ctx, vol, tf, &cases[i].d, NULL,
                                             NULL, &ao),
                     cases[i].err);
    assert_non_null(strstr(rp_last_error(ctx), cases[i].word));
    assert_ptr_equal(ao, (rp_ao *)&cases);
    assert_int_equal(rp_ao_plan_create(ctx, vol, tf, &cases[i].d, &plan),
                     cases[i].err);
    assert_ptr_equal(plan, (rp_ao_plan *)&cases);
  }
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
}

/* A volume with a dense ball near its -x end and nothing elsewhere: the
 * full bricks all sit on one side of an even split. */
static rp_volume *lopsided(rp_context *ctx) {
  uint32_t dims[3] = {44, 24, 21}, x, y, z;
  rp_volume_desc d = {{44, 24, 21}, RP_U8, {0, 0, 0}, NULL, {0}};
  uint8_t *v = malloc((size_t)dims[0] * dims[1] * dims[2]);
  rp_volume *vol = NULL;
  assert_non_null(v);
  for (z = 0; z < dims[2]; z++)
    for (y = 0; y < dims[1]; y++)
      for (x = 0; x < dims[0]; x++) {
        double dx = x - 9.0, dy = y - 11.5, dz = z - 10.0;
        v[((size_t)z * dims[1] + y) * dims[0] + x] =
            dx * dx + dy * dy + dz * dz < 49.0 ? 200 : (x == 43 ? 100 : 0);
      }
  d.data = v;
  assert_int_equal(rp_volume_create(ctx, &d, &vol), 0);
  free(v);
  return vol;
}

/* The lopsided volume under minmax-bone with its occupancy, a plan for
 * `desc` and (want_reference) the reference's AO of it. */
typedef struct lopsided_scene {
  rp_volume *vol;
  rp_tf *tf;
  rp_histograms *h;
  rp_occupancy *occ;
  rp_ao_plan *plan;
  rp_ao *want;
} lopsided_scene;

static void scene_open(rp_context *ctx, lopsided_scene *sc,
                       const rp_ao_desc *desc, int want_reference) {
  memset(sc, 0, sizeof *sc);
  sc->vol = lopsided(ctx);
  sc->tf = rp_test_preset(ctx, "minmax-bone");
  assert_int_equal(rp_histograms_build(ctx, sc->vol, &sc->h), 0);
  assert_int_equal(rp_occupancy_build(ctx, sc->h, sc->tf, &sc->occ), 0);
  assert_int_equal(rp_ao_plan_create(ctx, sc->vol, sc->tf, desc, &sc->plan),
                   0);
  if (want_reference)
    assert_int_equal(rp_ao_compute_reference(ctx, sc->vol, sc->tf, desc,
                                             NULL, NULL, &sc->want),
                     0);
}

static void scene_close(lopsided_scene *sc) {
  rp_ao_destroy(sc->want);
  rp_ao_plan_destroy(sc->plan);
  rp_occupancy_destroy(sc->occ);
  rp_histograms_destroy(sc->h);
  rp_tf_destroy(sc->tf);
  rp_volume_destroy(sc->vol);
}

typedef struct device_set {
  rp_context *ctx[5];
  rp_device *dev[5];
} device_set;

/* Every device of the set fails (open_devices' fail_device). */
#define ALL_DEVICES 1000u

/* n reference devices, each on a context of its own, holding the scene's
 * volume and TF; device fail_device (ALL_DEVICES: each) fails from its
 * fail_at-th AO job. */
static void open_devices(device_set *ds, uint32_t n, const lopsided_scene *sn,
                         uint32_t fail_device, uint32_t fail_at) {
  uint32_t i;
  memset(ds, 0, sizeof *ds);
  for (i = 0; i < n; i++) {
    rp_device_desc dd = {0};
    rp_fault_desc fd = {{RP_EXT_FAULTS, NULL}, 0.0, 0, 0, 0, 0.0};
    dd.backend = "reference";
    if (i == fail_device || fail_device == ALL_DEVICES) {
      fd.fail_at_ao = fail_at;
      rp_test_faults(&dd, &fd);
    }
    ds->ctx[i] = rp_test_context();
    assert_int_equal(rp_device_create(ds->ctx[i], &dd, &ds->dev[i]), 0);
    assert_int_equal(rp_device_set_volume(ds->dev[i], sn->vol), 0);
    assert_int_equal(rp_device_set_tf(ds->dev[i], sn->tf, sn->occ), 0);
  }
}

static void close_devices(device_set *ds) {
  uint32_t i;
  for (i = 0; i < 5; i++) {
    rp_device_destroy(ds->dev[i]);
    rp_context_destroy(ds->ctx[i]);
  }
}

/* Every scheme over 1, 2, 3 and 5 devices assembles exactly the volume
 * the reference computes whole (the reference devices run the same
 * double code per voxel); progress rises to 1; static blocks tile the
 * grid. */
static void test_schemes_assemble(void **state) {
  rp_context *ctx = *state;
  rp_ao_desc desc = {6, 4, 5.0f, 1.0f, 0};
  lopsided_scene sn;
  static const uint32_t counts[] = {1, 2, 3, 5};
  static const rp_ao_scheme schemes[] = {RP_AO_DYNAMIC, RP_AO_STATIC,
                                         RP_AO_STATIC_NAIVE};
  size_t c, k, n = 44 * 24 * 21;
  uint8_t *cover = malloc(n);
  assert_non_null(cover);
  scene_open(ctx, &sn, &desc, 1);
  for (c = 0; c < sizeof counts / sizeof counts[0]; c++)
    for (k = 0; k < 3; k++) {
      device_set ds;
      rp_ao_schedule sc = {0};
      rp_ao_report rep;
      rp_ao *got = NULL;
      double progress[2] = {0.0, 0.0};
      uint32_t i;
      open_devices(&ds, counts[c], &sn, 99, 0);
      sc.scheme = schemes[k];
      sc.block = 12;
      sc.progress = record_progress;
      sc.user = progress;
      assert_int_equal(rp_ao_compute(ctx, ds.dev, counts[c], sn.plan, &sc,
                                     &got, &rep),
                       0);
      assert_memory_equal(rp_ao_data(got, NULL), rp_ao_data(sn.want, NULL),
                          n);
      assert_true(progress[0] == 1.0);
      assert_int_equal(rep.device_count, counts[c]);
      assert_true(rep.total_ms >= rep.max_ms && rep.max_ms >= rep.min_ms);
      if (schemes[k] != RP_AO_DYNAMIC) {
        size_t covered = 0;
        memset(cover, 0, n);
        for (i = 0; i < counts[c]; i++) {
          const uint32_t *lo = rep.devices[i].block_lo;
          const uint32_t *end = rep.devices[i].block_end;
          uint32_t x, y, z;
          for (z = lo[2]; z < end[2]; z++)
            for (y = lo[1]; y < end[1]; y++)
              for (x = lo[0]; x < end[0]; x++)
                cover[((size_t)z * 24 + y) * 44 + x]++;
        }
        for (i = 0; i < n; i++) {
          assert_true(cover[i] <= 1);
          covered += cover[i];
        }
        assert_int_equal(covered, n);
      }
      rp_ao_destroy(got);
      close_devices(&ds);
    }
  free(cover);
  scene_close(&sn);
}

/* On the lopsided volume an even split leaves one device nearly all the
 * full bricks; moving the planes brings every device's share within a
 * brick layer of even. */
static void test_static_balances(void **state) {
  rp_context *ctx = *state;
  rp_ao_desc desc = {2, 1, 2.0f, 1.0f, 0};
  lopsided_scene sn;
  uint32_t n, lo0[3] = {0, 0, 0}, dims[3] = {44, 24, 21};
  uint64_t total;
  scene_open(ctx, &sn, &desc, 0);
  total = rp_ao_plan_full_bricks(sn.plan, lo0, dims);
  for (n = 2; n <= 3; n++) {
    double spread[2];
    int k;
    for (k = 0; k < 2; k++) {
      device_set ds;
      rp_ao_schedule sc = {0};
      rp_ao_report rep;
      rp_ao *got = NULL;
      uint64_t mx = 0, mn = UINT64_MAX, sum = 0;
      uint32_t i;
      open_devices(&ds, n, &sn, 99, 0);
      sc.scheme = k == 0 ? RP_AO_STATIC_NAIVE : RP_AO_STATIC;
      sc.balance_ms = 10000.0; /* the bound, not the clock, ends it */
      assert_int_equal(
          rp_ao_compute(ctx, ds.dev, n, sn.plan, &sc, &got, &rep), 0);
      for (i = 0; i < n; i++) {
        uint64_t f = rp_ao_plan_full_bricks(sn.plan, rep.devices[i].block_lo,
                                            rep.devices[i].block_end);
        mx = f > mx ? f : mx;
        mn = f < mn ? f : mn;
        sum += f;
      }
      assert_int_equal(sum, total);
      spread[k] = (double)(mx - mn) / ((double)total / n);
      rp_ao_destroy(got);
      close_devices(&ds);
    }
    /* Naive: the ball's side has far more than its share (the far face
     * holds a layer of full bricks, so the other side is not empty).
     * Balanced: within the full bricks of one 4-voxel layer (at most 6 x
     * 6 bricks) of even. */
    assert_true(spread[0] > 0.5);
    assert_true(spread[1] * ((double)total / n) <= 36.0);
    assert_true(spread[1] < 0.5 * spread[0]);
  }
  scene_close(&sn);
}

/* With device speeds given, static splits hand out full bricks in their
 * ratio: a device three times as fast gets three times the bricks, to
 * within a brick layer (at most 36 bricks here); naive splits the volume
 * in that ratio. */
static void test_static_follows_speed(void **state) {
  rp_context *ctx = *state;
  rp_ao_desc desc = {2, 1, 2.0f, 1.0f, 0};
  lopsided_scene sn;
  int k;
  scene_open(ctx, &sn, &desc, 0);
  /* Naive; balanced with the fast device on the ball's side; balanced
   * with it on the far side, where the proportional step from the naive
   * plane crosses the sparse middle of the volume in one move. */
  for (k = 0; k < 3; k++) {
    device_set ds;
    rp_ao_schedule sc = {0};
    rp_ao_report rep;
    rp_ao *got = NULL;
    uint64_t f[2];
    uint32_t i, fast = k == 2 ? 0 : 1;
    open_devices(&ds, 2, &sn, 99, 0);
    sc.scheme = k == 0 ? RP_AO_STATIC_NAIVE : RP_AO_STATIC;
    sc.balance_ms = 10000.0;
    sc.speed[fast] = 3.0;
    sc.speed[1 - fast] = 1.0;
    assert_int_equal(rp_ao_compute(ctx, ds.dev, 2, sn.plan, &sc, &got, &rep),
                     0);
    for (i = 0; i < 2; i++)
      f[i] = rp_ao_plan_full_bricks(sn.plan, rep.devices[i].block_lo,
                                    rep.devices[i].block_end);
    if (k == 0) {
      /* x is the longest axis: device 0 gets the first quarter of it,
       * to the nearest brick face. */
      assert_int_equal(rep.devices[0].block_end[0], 12);
    } else {
      double d = 3.0 * (double)f[1 - fast] - (double)f[fast];
      assert_true(fabs(d) <= 4.0 * 36.0);
      assert_true(f[fast] > 2 * f[1 - fast]);
    }
    rp_ao_destroy(got);
    close_devices(&ds);
  }
  scene_close(&sn);
}

/* Per-speed imbalance D of a split of `vol`'s x axis at `plane`, from the
 * plan's counts (tested against brute force above). */
static double split_d(const rp_ao_plan *plan, const uint32_t dims[3],
                      uint32_t plane, const double speed[2],
                      double *smaller) {
  uint32_t lo[3] = {0, 0, 0}, end[3], lo2[3] = {0, 0, 0};
  double l, r;
  memcpy(end, dims, sizeof end);
  end[0] = plane;
  lo2[0] = plane;
  l = (double)rp_ao_plan_full_bricks(plan, lo, end) / speed[0];
  r = (double)rp_ao_plan_full_bricks(plan, lo2, dims) / speed[1];
  *smaller = l < r ? l : r;
  return l - r;
}

/* Random sparse volumes (dense x-slabs here and there, empty between):
 * the balanced plane is as good as the best brick-aligned plane found
 * by trying them all, or within the tolerance. Sparse layers at the
 * plane make the proportional step overshoot; the plane must still end
 * at the balance point, not where the overshoot was noticed. */
static void test_static_finds_balance(void **state) {
  rp_context *ctx = *state;
  uint32_t dims[3] = {96, 32, 32}, trial;
  unsigned seed = 99;
  rp_ao_desc desc = {2, 1, 2.0f, 1.0f, 0};
  rp_tf *tf = rp_test_preset(ctx, "minmax-bone");
  uint8_t *v = malloc(96 * 32 * 32);
  assert_non_null(v);
  for (trial = 0; trial < 24; trial++) {
    rp_volume_desc vd = {{96, 32, 32}, RP_U8, {0, 0, 0}, NULL, {0}};
    rp_volume *vol = NULL;
    rp_histograms *h = NULL;
    rp_occupancy *occ = NULL;
    rp_ao_plan *plan = NULL;
    lopsided_scene sn;
    device_set ds;
    rp_ao_schedule sc = {0};
    rp_ao_report rep;
    rp_ao *got = NULL;
    double speed[2], best = INFINITY, got_d, smaller, s2;
    uint32_t x, p, any = 0;
    /* Per x-slab: dense across the whole section (12 %), dense in one
     * 2x2-voxel spot (a layer of one or two full bricks, 20 %), or
     * empty. */
    for (x = 0; x < 96; x++) {
      unsigned r;
      seed = seed * 1103515245u + 12345u;
      r = (seed >> 16) % 100;
      for (p = 0; p < 32 * 32; p++) {
        uint32_t y = p % 32, z = p / 32;
        int spot = y >= 15 && y < 17 && z >= 15 && z < 17;
        v[(size_t)p * 96 + x] = r < 12 || (r < 32 && spot) ? 200 : 0;
      }
      any |= r < 32;
    }
    if (!any)
      continue;
    vd.data = v;
    assert_int_equal(rp_volume_create(ctx, &vd, &vol), 0);
    assert_int_equal(rp_histograms_build(ctx, vol, &h), 0);
    assert_int_equal(rp_occupancy_build(ctx, h, tf, &occ), 0);
    assert_int_equal(rp_ao_plan_create(ctx, vol, tf, &desc, &plan), 0);
    speed[0] = trial % 2 ? 3.0 : 1.0;
    speed[1] = trial % 2 ? 1.0 : 3.0;
    memset(&sn, 0, sizeof sn);
    sn.vol = vol;
    sn.tf = tf;
    sn.occ = occ;
    open_devices(&ds, 2, &sn, 99, 0);
    sc.scheme = RP_AO_STATIC;
    sc.balance_ms = 10000.0;
    sc.speed[0] = speed[0];
    sc.speed[1] = speed[1];
    assert_int_equal(rp_ao_compute(ctx, ds.dev, 2, plan, &sc, &got, &rep),
                     0);
    for (p = 4; p < 96; p += 4) {
      double d = fabs(split_d(plan, dims, p, speed, &s2));
      best = d < best ? d : best;
    }
    got_d = fabs(split_d(plan, dims, rep.devices[0].block_end[0], speed,
                         &smaller));
    if (!(got_d <= best + 1e-9 ||
          got_d <= 0.02 * (smaller > 1.0 ? smaller : 1.0)))
      fail_msg("trial %u: plane %u has |D| %.2f, the best %.2f", trial,
               rep.devices[0].block_end[0], got_d, best);
    rp_ao_destroy(got);
    close_devices(&ds);
    rp_ao_plan_destroy(plan);
    rp_occupancy_destroy(occ);
    rp_histograms_destroy(h);
    rp_volume_destroy(vol);
  }
  free(v);
  rp_tf_destroy(tf);
}

/* Steps: a step with a budget far below one job's time still takes one
 * job per device (progress every step) and no more; finishing early is
 * refused and loses nothing; a non-positive or NaN budget is refused;
 * once every job is done a step does nothing, and the assembled volume
 * is exactly the reference's. */
static void test_run_in_steps(void **state) {
  rp_context *ctx = *state;
  rp_ao_desc desc = {4, 3, 4.0f, 1.0f, 0};
  lopsided_scene sn;
  device_set ds;
  rp_ao_schedule sc = {0};
  rp_ao_run *run = NULL;
  rp_ao *got = (rp_ao *)&sn;
  rp_ao_report rep;
  double fraction = -1.0, last = 0.0;
  int steps = 0;
  scene_open(ctx, &sn, &desc, 1);
  open_devices(&ds, 2, &sn, 99, 0);
  sc.block = 8; /* 6 x 3 x 3 blocks, those with full bricks queued */
  assert_int_equal(rp_ao_run_create(ctx, ds.dev, 2, sn.plan, &sc, &run), 0);
  assert_int_equal(rp_ao_run_step(run, 0.0, &fraction), RP_ERANGE);
  assert_int_equal(rp_ao_run_step(run, NAN, &fraction), RP_ENOTFINITE);
  assert_int_equal(rp_ao_run_finish(run, &got, &rep), RP_ESTATE);
  assert_ptr_equal(got, (rp_ao *)&sn);
  do {
    uint32_t before = 0, after = 0, i;
    rp_ao_run_report(run, &rep);
    for (i = 0; i < 2; i++)
      before += rep.devices[i].jobs;
    assert_int_equal(rp_ao_run_step(run, 1e-6, &fraction), 0);
    rp_ao_run_report(run, &rep);
    for (i = 0; i < 2; i++)
      after += rep.devices[i].jobs;
    /* One job per device at most, at least one in all. */
    assert_true(after > before && after - before <= 2);
    assert_true(fraction > last);
    last = fraction;
    steps++;
  } while (fraction < 1.0);
  assert_true(steps >= 3);
  assert_int_equal(rp_ao_run_step(run, 1e-6, &fraction), 0);
  assert_true(fraction == 1.0);
  assert_int_equal(rp_ao_run_finish(run, &got, &rep), 0);
  assert_memory_equal(rp_ao_data(got, NULL), rp_ao_data(sn.want, NULL),
                      44 * 24 * 21);
  /* The volume went to the caller: a second finish has none. */
  {
    rp_ao *again = NULL;
    assert_int_equal(rp_ao_run_finish(run, &again, NULL), RP_ESTATE);
    assert_null(again);
  }
  rp_ao_destroy(got);
  rp_ao_run_destroy(run);
  close_devices(&ds);
  scene_close(&sn);
}

/* A device lost mid-computation hands its work to the others and the
 * result is still exact; with every device lost the call fails and
 * leaves *out alone. */
static void test_device_lost(void **state) {
  rp_context *ctx = *state;
  rp_ao_desc desc = {4, 3, 4.0f, 1.0f, 0};
  lopsided_scene sn;
  int k;
  scene_open(ctx, &sn, &desc, 1);
  for (k = 0; k < 2; k++) {
    device_set ds;
    rp_ao_schedule sc = {0};
    rp_ao_report rep;
    rp_ao *got = NULL;
    /* Device 1 fails at its first job. Static: it owns jobs, so it
     * fails. Dynamic: a device whose thread starts late may find the
     * queue empty (seen under CI load), so it fails or took nothing. */
    open_devices(&ds, 3, &sn, 1, 1);
    sc.scheme = k == 0 ? RP_AO_DYNAMIC : RP_AO_STATIC;
    sc.block = 8;
    assert_int_equal(rp_ao_compute(ctx, ds.dev, 3, sn.plan, &sc, &got, &rep),
                     0);
    assert_memory_equal(rp_ao_data(got, NULL), rp_ao_data(sn.want, NULL),
                        44 * 24 * 21);
    if (k == 1 || rep.devices[1].status != 0)
      assert_int_equal(rep.devices[1].status, RP_EDEVICE);
    else
      assert_int_equal(rep.devices[1].jobs, 0);
    assert_int_equal(rep.devices[1].jobs, 0); /* its job went elsewhere */
    assert_int_equal(rep.devices[0].status, 0);
    rp_ao_destroy(got);
    close_devices(&ds);
  }
  {
    /* Both devices fail from their first job. */
    device_set ds;
    rp_ao *got = (rp_ao *)&ds;
    open_devices(&ds, 2, &sn, ALL_DEVICES, 1);
    assert_int_equal(rp_ao_compute(ctx, ds.dev, 2, sn.plan, NULL, &got,
                                   NULL),
                     RP_EDEVICE);
    assert_ptr_equal(got, (rp_ao *)&ds);
    assert_non_null(strstr(rp_last_error(ctx), "every device failed"));
    close_devices(&ds);
  }
  scene_close(&sn);
}

/* Bad schedules and device lists are refused before any work. */
static void test_bad_schedule(void **state) {
  rp_context *ctx = *state;
  lopsided_scene sn;
  rp_tf *other = rp_test_preset(ctx, "minmax-soft");
  rp_ao_plan *stale = NULL;
  rp_ao *got = NULL;
  device_set ds;
  rp_device *twice[2];
  rp_ao_schedule sc = {0};
  scene_open(ctx, &sn, NULL, 0);
  assert_int_equal(rp_ao_plan_create(ctx, sn.vol, other, NULL, &stale), 0);
  open_devices(&ds, 2, &sn, 99, 0);
  assert_int_equal(rp_ao_compute(ctx, ds.dev, 0, sn.plan, NULL, &got, NULL),
                   RP_ERANGE);
  assert_int_equal(rp_ao_compute(ctx, ds.dev, 2, stale, NULL, &got, NULL),
                   RP_ESTATE);
  twice[0] = twice[1] = ds.dev[0];
  assert_int_equal(rp_ao_compute(ctx, twice, 2, sn.plan, NULL, &got, NULL),
                   RP_EINVAL);
  sc.block = 10;
  assert_int_equal(rp_ao_compute(ctx, ds.dev, 2, sn.plan, &sc, &got, NULL),
                   RP_EINVAL);
  sc.block = 0;
  sc.balance_ms = NAN;
  assert_int_equal(rp_ao_compute(ctx, ds.dev, 2, sn.plan, &sc, &got, NULL),
                   RP_ENOTFINITE);
  sc.balance_ms = 0.0;
  sc.speed[1] = -1.0;
  assert_int_equal(rp_ao_compute(ctx, ds.dev, 2, sn.plan, &sc, &got, NULL),
                   RP_ERANGE);
  sc.speed[1] = INFINITY;
  assert_int_equal(rp_ao_compute(ctx, ds.dev, 2, sn.plan, &sc, &got, NULL),
                   RP_ENOTFINITE);
  sc.speed[1] = 0.0;
  sc.scheme = (rp_ao_scheme)7;
  assert_int_equal(rp_ao_compute(ctx, ds.dev, 2, sn.plan, &sc, &got, NULL),
                   RP_EINVAL);
  assert_null(got);
  close_devices(&ds);
  rp_ao_plan_destroy(stale);
  rp_tf_destroy(other);
  scene_close(&sn);
}

static int setup(void **state) {
  *state = rp_test_context();
  return 0;
}

static int teardown(void **state) {
  rp_context_destroy(*state);
  return 0;
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_directions),
      cmocka_unit_test(test_closed_forms),
      cmocka_unit_test(test_transparent),
      cmocka_unit_test(test_bricking_is_seamless),
      cmocka_unit_test(test_plan_counts),
      cmocka_unit_test(test_reference_device),
      cmocka_unit_test(test_bad_desc),
      cmocka_unit_test(test_schemes_assemble),
      cmocka_unit_test(test_static_balances),
      cmocka_unit_test(test_static_follows_speed),
      cmocka_unit_test(test_static_finds_balance),
      cmocka_unit_test(test_run_in_steps),
      cmocka_unit_test(test_device_lost),
      cmocka_unit_test(test_bad_schedule),
  };
  return cmocka_run_group_tests(tests, setup, teardown);
}
