/* Block histograms H, opacity histograms H-alpha and occupancy against
 * brute force computed here from the voxels with the rules of DESIGN
 * section 2, written out independently of runtime/histogram.c. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "test_util.h"

/* DESIGN section 2, verbatim: integer data bin = (v - min)*64/(max-min+1);
 * float data: 64 equal parts of [min, max], max in the last bin. */
static int brute_bin(const rp_volume_info *in, double v) {
  if (in->type != RP_F32) {
    long long lo = (long long)in->min, r = (long long)in->max - lo + 1;
    return (int)(((long long)v - lo) * 64 / r);
  }
  if (in->max == in->min)
    return 0;
  {
    int b = (int)floor((v - in->min) / (in->max - in->min) * 64);
    return b > 63 ? 63 : b;
  }
}

static double voxel_at(const rp_volume *vol, const rp_volume_info *in,
                       size_t idx) {
  const void *d = rp_volume_data(vol);
  switch (in->type) {
  case RP_U8: return ((const uint8_t *)d)[idx];
  case RP_U16: return ((const uint16_t *)d)[idx];
  default: return ((const float *)d)[idx];
  }
}

/* Brute-force H: one pass over voxels, block index from coordinates. */
static uint32_t *brute_h(const rp_volume *vol) {
  rp_volume_info in;
  uint32_t *c, x, y, z, nb;
  size_t idx = 0;
  rp_volume_get_info(vol, &in);
  nb = in.blocks[0] * in.blocks[1] * in.blocks[2];
  c = calloc((size_t)nb * 64, sizeof *c);
  assert_non_null(c);
  for (z = 0; z < in.dims[2]; z++)
    for (y = 0; y < in.dims[1]; y++)
      for (x = 0; x < in.dims[0]; x++, idx++) {
        uint32_t b = ((z / 16) * in.blocks[1] + y / 16) * in.blocks[0] +
                     x / 16;
        c[(size_t)b * 64 + brute_bin(&in, voxel_at(vol, &in, idx))]++;
      }
  return c;
}

static void check_h_equals_brute(rp_context *ctx, const rp_volume *vol,
                                 const char *what) {
  rp_histograms *h = NULL;
  uint32_t *expect = brute_h(vol), b, n;
  assert_int_equal(rp_histograms_build(ctx, vol, &h), 0);
  n = rp_histograms_block_count(h);
  for (b = 0; b < n; b++) {
    if (memcmp(rp_histograms_block(h, b), expect + (size_t)b * 64,
               64 * sizeof(uint32_t)) != 0)
      fail_msg("%s: block %u differs from brute force", what, b);
  }
  free(expect);
  rp_histograms_destroy(h);
}

static rp_volume *gen(rp_context *ctx, rp_generator kind, uint32_t x,
                      uint32_t y, uint32_t z, rp_voxel_type type) {
  rp_generate_desc d = {0};
  rp_volume *v = NULL;
  d.kind = kind, d.dims[0] = x, d.dims[1] = y, d.dims[2] = z;
  d.type = type, d.seed = 7;
  assert_int_equal(rp_volume_generate(ctx, &d, &v), 0);
  return v;
}

static void h_matches_brute_force_on_odd_sizes(void **state) {
  static const uint32_t sizes[][3] = {
      {1, 1, 1}, {17, 33, 5}, {100, 3, 77}, {16, 16, 16}, {33, 1, 48}};
  static const rp_generator kinds[] = {RP_GEN_NOISE, RP_GEN_PHANTOM,
                                       RP_GEN_MARSCHNER_LOBB};
  rp_context *ctx = rp_test_context();
  size_t s, k, t;
  (void)state;
  for (s = 0; s < sizeof sizes / sizeof sizes[0]; s++)
    for (k = 0; k < 3; k++)
      for (t = 0; t < 2; t++) {
        char what[64];
        rp_volume *v = gen(ctx, kinds[k], sizes[s][0], sizes[s][1],
                           sizes[s][2], t ? RP_U16 : RP_U8);
        snprintf(what, sizeof what, "%ux%ux%u kind %d type %d", sizes[s][0],
                 sizes[s][1], sizes[s][2], (int)kinds[k], t ? 16 : 8);
        check_h_equals_brute(ctx, v, what);
        rp_volume_destroy(v);
      }
  rp_context_destroy(ctx);
}

/* 16-bit full range and values on bin edges: with min 0 and max 65535 each
 * bin is 1024 values wide, so v = 1024k - 1 and 1024k straddle an edge. */
static void h_bin_edges_16bit_full_range(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume_desc d = {0};
  rp_volume *v = NULL;
  rp_histograms *h = NULL;
  uint16_t vox[20 * 3 * 2];
  uint32_t i, k;
  (void)state;
  for (i = 0; i < 120; i++) {
    k = i % 65;
    vox[i] = (uint16_t)(i % 2 ? (k * 1024 > 65535 ? 65535 : k * 1024)
                              : (k == 0 ? 0 : k * 1024 - 1));
  }
  vox[0] = 0, vox[1] = 65535;
  d.dims[0] = 20, d.dims[1] = 3, d.dims[2] = 2, d.type = RP_U16;
  d.data = vox;
  assert_int_equal(rp_volume_create(ctx, &d, &v), 0);
  check_h_equals_brute(ctx, v, "u16 edges");
  assert_int_equal(rp_histograms_build(ctx, v, &h), 0);
  assert_int_equal(rp_histograms_bin_of(h, 1023), 0);
  assert_int_equal(rp_histograms_bin_of(h, 1024), 1);
  assert_int_equal(rp_histograms_bin_of(h, 65535), 63);
  rp_histograms_destroy(h);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

/* Float data: values exactly on edges min + k*(max-min)/64, and max. */
static void h_bin_edges_float(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume_desc d = {0};
  rp_volume *v = NULL;
  float vox[65 * 2];
  int i;
  (void)state;
  for (i = 0; i <= 64; i++) {
    vox[i] = -8.0f + 16.0f * (float)i / 64.0f; /* exact in binary */
    vox[65 + i] = nextafterf(vox[i], -INFINITY);
  }
  vox[65] = -8.0f;
  d.dims[0] = 65, d.dims[1] = 2, d.dims[2] = 1, d.type = RP_F32;
  d.data = vox;
  assert_int_equal(rp_volume_create(ctx, &d, &v), 0);
  check_h_equals_brute(ctx, v, "float edges");
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

/* The value interval of each bin is exactly the set of values that fall
 * in it: checked for every value of several integer ranges. */
static void bin_value_ranges_are_exact(void **state) {
  static const double ranges[][2] = {
      {0, 255}, {3, 200}, {7, 7}, {10, 40}, {0, 65535}, {100, 3371}};
  size_t r;
  (void)state;
  for (r = 0; r < sizeof ranges / sizeof ranges[0]; r++) {
    rp__value_range vr;
    int b;
    double v;
    vr.type = ranges[r][1] > 255 ? RP_U16 : RP_U8;
    vr.min = ranges[r][0], vr.max = ranges[r][1];
    for (v = vr.min; v <= vr.max; v++) {
      double lo, hi;
      b = rp__bin_of(&vr, v);
      rp__bin_value_range(&vr, b, &lo, &hi);
      assert_true(lo <= v && v <= hi);
    }
    for (b = 0; b < 64; b++) {
      double lo, hi;
      rp__bin_value_range(&vr, b, &lo, &hi);
      if (lo <= hi) {
        assert_int_equal(rp__bin_of(&vr, lo), b);
        assert_int_equal(rp__bin_of(&vr, hi), b);
      }
    }
  }
}

/* Values outside [min, max], and NaN, never reach an integer cast: below
 * is bin 0, above is the bin of max, for every voxel type. */
static void bin_of_outside_the_range(void **state) {
  rp__value_range u8 = {RP_U8, 3, 200, 0, {0}}, f32 = {RP_F32, -2, 6, 0, {0}};
  (void)state;
  assert_int_equal(rp__bin_of(&u8, -5), 0);
  assert_int_equal(rp__bin_of(&u8, 1e30), rp__bin_of(&u8, 200));
  assert_int_equal(rp__bin_of(&u8, -1e30), 0);
  assert_int_equal(rp__bin_of(&u8, NAN), 0);
  assert_int_equal(rp__bin_of(&u8, 200), 63);
  assert_int_equal(rp__bin_of(&f32, 1e30), 63);
  assert_int_equal(rp__bin_of(&f32, NAN), 0);
  assert_int_equal(rp__bin_of(&f32, -1e30), 0);
}

/* Block counts for axes near 2^32 must not wrap to 0. */
static void block_counts_do_not_wrap(void **state) {
  (void)state;
  assert_int_equal(rp__blocks_along(1), 1);
  assert_int_equal(rp__blocks_along(16), 1);
  assert_int_equal(rp__blocks_along(17), 2);
  assert_int_equal(rp__blocks_along(UINT32_MAX), 268435456u);
  assert_int_equal(rp__blocks_along(UINT32_MAX - 14), 268435456u);
}

static void threads_do_not_change_h(void **state) {
  rp_context_desc cd = {0};
  rp_context *one = NULL, *many = NULL;
  rp_histograms *h1 = NULL, *h2 = NULL;
  rp_volume *v;
  (void)state;
  cd.threads = 1;
  assert_int_equal(rp_context_create(&cd, &one), 0);
  cd.threads = 300; /* more than the pool holds: capped, not overrun */
  assert_int_equal(rp_context_create(&cd, &many), 0);
  v = gen(one, RP_GEN_NOISE, 20, 330, 250, RP_U16); /* 336 rows */
  assert_int_equal(rp_histograms_build(one, v, &h1), 0);
  assert_int_equal(rp_histograms_build(many, v, &h2), 0);
  assert_memory_equal(rp_histograms_block(h1, 0), rp_histograms_block(h2, 0),
                      rp_histograms_block_count(h1) * 64 * sizeof(uint32_t));
  rp_histograms_destroy(h1);
  rp_histograms_destroy(h2);
  rp_volume_destroy(v);
  rp_context_destroy(one);
  rp_context_destroy(many);
}

/* ---- H-alpha and occupancy ---------------------------------------------- */

/* Control points on the knots of a 129-entry LUT (k/128, exact in binary),
 * so the function the LUT defines is exactly this one and the test
 * evaluates it in closed form. */
static const rp_tf_point tf_points[] = {{0.0f, 0, 0, 0, 0},
                                        {0.25f, 0, 0, 0, 0},
                                        {0.3125f, 1, 1, 1, .6f},
                                        {0.375f, 1, 1, 1, 0},
                                        {0.6875f, 1, 1, 1, 0},
                                        {0.8125f, 1, 1, 1, 1},
                                        {1.0f, 1, 1, 1, 1}};
#define NPTS ((int)(sizeof tf_points / sizeof tf_points[0]))

static double pts_alpha(double x) {
  int i;
  if (x <= 0)
    return tf_points[0].a;
  if (x >= 1)
    return tf_points[NPTS - 1].a;
  for (i = 0; tf_points[i + 1].x < x; i++) {
  }
  return tf_points[i].a + (x - tf_points[i].x) /
                              (tf_points[i + 1].x - tf_points[i].x) *
                              (tf_points[i + 1].a - tf_points[i].a);
}

static double pts_max(double x0, double x1) {
  double m = fmax(pts_alpha(x0), pts_alpha(x1));
  int i;
  for (i = 0; i < NPTS; i++)
    if (tf_points[i].x > x0 && tf_points[i].x < x1)
      m = fmax(m, tf_points[i].a);
  return m;
}

static double pts_mean(double x0, double x1) {
  double sum = 0, xa = x0;
  int i;
  if (x1 <= x0)
    return pts_alpha(x0);
  for (i = 0; i < NPTS; i++) {
    double xb = tf_points[i].x;
    if (xb <= xa)
      continue;
    if (xb >= x1)
      break;
    sum += 0.5 * (pts_alpha(xa) + pts_alpha(xb)) * (xb - xa);
    xa = xb;
  }
  sum += 0.5 * (pts_alpha(xa) + pts_alpha(x1)) * (x1 - xa);
  return sum / (x1 - x0);
}

static rp_tf *pts_tf(rp_context *ctx) {
  rp_tf_desc d = {0};
  rp_tf *tf = NULL;
  d.points = tf_points, d.count = NPTS, d.lut_size = 129;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), 0);
  return tf;
}

/* Integer bins [lo, hi] per the rule (v - min)*64/R written out. */
static void brute_bin_range(const rp_volume_info *in, int b, double *lo,
                            double *hi) {
  double v, first = -1, last = -2;
  if (in->type == RP_F32) { /* 64 equal parts of [min, max] */
    double w = (in->max - in->min) / 64;
    *lo = in->min + b * w;
    *hi = b == 63 ? in->max : in->min + (b + 1) * w;
    return;
  }
  for (v = in->min; v <= in->max; v++) {
    if (brute_bin(in, v) == b) {
      if (first < 0)
        first = v;
      last = v;
    }
  }
  *lo = first, *hi = last;
}

static double to_x(const rp_volume_info *in, double v) {
  return in->max > in->min ? (v - in->min) / (in->max - in->min) : 0;
}

static void check_alpha_and_occupancy(rp_context *ctx, const rp_volume *vol,
                                      const char *what) {
  rp_volume_info in;
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  rp_tf *tf = pts_tf(ctx);
  double bin_lo[64], bin_hi[64];
  int bin_op[64], b;
  uint32_t bx, by, bz, nb, empty = 0;
  rp_volume_get_info(vol, &in);
  nb = in.blocks[0] * in.blocks[1] * in.blocks[2];
  for (b = 0; b < 64; b++) {
    double a;
    brute_bin_range(&in, b, &bin_lo[b], &bin_hi[b]);
    a = bin_lo[b] <= bin_hi[b]
            ? pts_mean(to_x(&in, bin_lo[b]), to_x(&in, bin_hi[b]))
            : 0;
    bin_op[b] = a == 0 ? 0 : (int)ceil(a * 15 - 1e-12);
    if (a > 0 && bin_op[b] < 1)
      bin_op[b] = 1;
  }
  assert_int_equal(rp_histograms_build(ctx, vol, &h), 0);
  assert_int_equal(rp_occupancy_build(ctx, h, tf, &occ), 0);
  for (bz = 0; bz < in.blocks[2]; bz++)
    for (by = 0; by < in.blocks[1]; by++)
      for (bx = 0; bx < in.blocks[0]; bx++) {
        uint32_t blk = (bz * in.blocks[1] + by) * in.blocks[0] + bx;
        uint64_t acc[16] = {0}, total = 0;
        double vmin = 1e300, vmax = -1e300;
        int lo_bin = 64, hi_bin = -1, j, expect_grid, expect_exact_grid;
        uint32_t x, y, z;
        const uint8_t *ah = rp_occupancy_alpha_hist(occ) + blk * 16;
        /* H-alpha from the block's own voxels. */
        for (z = bz * 16; z < bz * 16 + 16 && z < in.dims[2]; z++)
          for (y = by * 16; y < by * 16 + 16 && y < in.dims[1]; y++)
            for (x = bx * 16; x < bx * 16 + 16 && x < in.dims[0]; x++) {
              size_t idx = ((size_t)z * in.dims[1] + y) * in.dims[0] + x;
              acc[bin_op[brute_bin(&in, voxel_at(vol, &in, idx))]]++;
              total++;
            }
        for (j = 0; j < 16; j++) {
          uint64_t q = (uint64_t)floor(acc[j] * 255.0 / total + 0.5);
          if (acc[j] > 0 && q == 0)
            q = 1;
          if (ah[j] != q)
            fail_msg("%s: block %u H-alpha bin %d: %u, brute %u", what, blk,
                     j, ah[j], (unsigned)q);
        }
        /* Occupancy from the voxels of the block and its 26 neighbours. */
        for (z = bz ? bz * 16 - 16 : 0; z < bz * 16 + 32 && z < in.dims[2];
             z++)
          for (y = by ? by * 16 - 16 : 0;
               y < by * 16 + 32 && y < in.dims[1]; y++)
            for (x = bx ? bx * 16 - 16 : 0;
                 x < bx * 16 + 32 && x < in.dims[0]; x++) {
              size_t idx = ((size_t)z * in.dims[1] + y) * in.dims[0] + x;
              double v = voxel_at(vol, &in, idx);
              int bb = brute_bin(&in, v);
              vmin = fmin(vmin, v), vmax = fmax(vmax, v);
              lo_bin = bb < lo_bin ? bb : lo_bin;
              hi_bin = bb > hi_bin ? bb : hi_bin;
            }
        /* Exact at bin granularity, and conservative at voxel level: any
         * interpolated value lies in [vmin, vmax]. */
        expect_grid = pts_max(to_x(&in, bin_lo[lo_bin]),
                              to_x(&in, bin_hi[hi_bin])) > 0;
        expect_exact_grid = pts_max(to_x(&in, vmin), to_x(&in, vmax)) > 0;
        if (rp_occupancy_grid(occ)[blk] != expect_grid)
          fail_msg("%s: block %u occupancy %d, brute %d", what, blk,
                   rp_occupancy_grid(occ)[blk], expect_grid);
        if (expect_exact_grid)
          assert_int_equal(rp_occupancy_grid(occ)[blk], 1);
        empty += !expect_grid;
      }
  assert_int_equal(rp_occupancy_empty_blocks(occ), empty);
  /* An update for the same TF reproduces the grid (no stale state). */
  {
    uint8_t *copy = malloc(nb);
    rp_tf *opaque = NULL;
    memcpy(copy, rp_occupancy_grid(occ), nb);
    assert_int_equal(rp_tf_create_preset(ctx, "opaque", &opaque), 0);
    assert_int_equal(rp_occupancy_update(occ, opaque), 0);
    assert_int_equal(rp_occupancy_empty_blocks(occ), 0);
    assert_int_equal(rp_occupancy_update(occ, tf), 0);
    assert_memory_equal(copy, rp_occupancy_grid(occ), nb);
    free(copy);
    rp_tf_destroy(opaque);
  }
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
}

static void alpha_hist_and_occupancy_match_brute_force(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *v;
  (void)state;
  v = gen(ctx, RP_GEN_PHANTOM, 70, 61, 45, RP_U8);
  check_alpha_and_occupancy(ctx, v, "phantom u8");
  rp_volume_destroy(v);
  v = gen(ctx, RP_GEN_PHANTOM, 40, 33, 50, RP_U16);
  check_alpha_and_occupancy(ctx, v, "phantom u16");
  rp_volume_destroy(v);
  v = gen(ctx, RP_GEN_MARSCHNER_LOBB, 17, 33, 5, RP_U8);
  check_alpha_and_occupancy(ctx, v, "ML 17x33x5");
  rp_volume_destroy(v);
  v = gen(ctx, RP_GEN_NOISE, 1, 1, 1, RP_U8);
  check_alpha_and_occupancy(ctx, v, "1x1x1");
  rp_volume_destroy(v);
  {
    /* Float voxels: the phantom rescaled to [-1, 3]. */
    rp_volume_desc d = {0};
    rp_volume *ph = gen(ctx, RP_GEN_PHANTOM, 37, 40, 33, RP_U8);
    const uint8_t *src = rp_volume_data(ph);
    size_t i, n = (size_t)37 * 40 * 33;
    float *vox = malloc(n * sizeof *vox);
    assert_non_null(vox);
    for (i = 0; i < n; i++)
      vox[i] = -1.0f + 4.0f * src[i] / 255.0f;
    d.dims[0] = 37, d.dims[1] = 40, d.dims[2] = 33, d.type = RP_F32;
    d.data = vox;
    assert_int_equal(rp_volume_create(ctx, &d, &v), 0);
    check_alpha_and_occupancy(ctx, v, "phantom float");
    rp_volume_destroy(v);
    rp_volume_destroy(ph);
    free(vox);
  }
  rp_context_destroy(ctx);
}

/* The interpolation case the occupancy rule exists for: one block of air
 * (0) next to one of bone (255); the TF is zero near both values and
 * non-zero only in between. No voxel maps to non-zero opacity, yet the
 * samples between the blocks do, so both blocks must be occupied. */
static void interpolation_crossing_a_peak_keeps_blocks(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume_desc d = {0};
  /* Zero over the whole first and last density bins (values 0..3 and
   * 252..255), one at the middle. */
  rp_tf_point p[5] = {{0, 1, 1, 1, 0}, {.02f, 1, 1, 1, 0}, {.5f, 1, 1, 1, 1},
                      {.98f, 1, 1, 1, 0}, {1, 1, 1, 1, 0}};
  rp_tf_desc td = {0};
  rp_tf *tf = NULL;
  rp_volume *v = NULL;
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  static uint8_t vox[32 * 16 * 16];
  size_t i;
  (void)state;
  for (i = 0; i < sizeof vox; i++)
    vox[i] = (i % 32) < 16 ? 0 : 255;
  d.dims[0] = 32, d.dims[1] = 16, d.dims[2] = 16, d.type = RP_U8;
  d.data = vox;
  td.points = p, td.count = 5;
  assert_int_equal(rp_volume_create(ctx, &d, &v), 0);
  assert_int_equal(rp_tf_create(ctx, &td, &tf), 0);
  assert_int_equal(rp_histograms_build(ctx, v, &h), 0);
  assert_int_equal(rp_occupancy_build(ctx, h, tf, &occ), 0);
  assert_int_equal(rp_occupancy_grid(occ)[0], 1);
  assert_int_equal(rp_occupancy_grid(occ)[1], 1);
  /* ...while H-alpha, which describes voxels, puts them all in bin 0. */
  assert_int_equal(rp_occupancy_alpha_hist(occ)[0], 255);
  assert_int_equal(rp_occupancy_alpha_hist(occ)[16], 255);
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

/* Every real volume in the shared folder, when it is there. */
static void real_volumes_match_brute_force(void **state) {
  const char *const *names = rp_test_data_names();
  rp_context *ctx;
  int n;
  (void)state;
  if (names[0] == NULL)
    skip();
  ctx = rp_test_context();
  for (n = 0; names[n] != NULL; n++) {
    char path[1024];
    rp_volume *v = NULL;
    rp_test_data_volume(names[n], path, sizeof path);
    if (rp_volume_load(ctx, path, &v) != 0)
      fail_msg("%s: %s", names[n], rp_last_error(ctx));
    check_h_equals_brute(ctx, v, names[n]);
    rp_volume_destroy(v);
  }
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(h_matches_brute_force_on_odd_sizes),
      cmocka_unit_test(h_bin_edges_16bit_full_range),
      cmocka_unit_test(h_bin_edges_float),
      cmocka_unit_test(bin_value_ranges_are_exact),
      cmocka_unit_test(threads_do_not_change_h),
      cmocka_unit_test(bin_of_outside_the_range),
      cmocka_unit_test(block_counts_do_not_wrap),
      cmocka_unit_test(alpha_hist_and_occupancy_match_brute_force),
      cmocka_unit_test(interpolation_crossing_a_peak_keeps_blocks),
      cmocka_unit_test(real_volumes_match_brute_force),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
