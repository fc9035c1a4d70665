/* Transfer functions placed in data units: windows, percentiles, signed
 * voxels, and the outlier voxel that used to blank a CT. Each expected
 * value is worked out here (a closed form, or the same data stored in
 * another voxel type), never read back from the code under test. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "test_util.h"

#define N 32 /* the CT head's grid: N^3 */
#define W 64 /* image size */

static rp_volume *ct_head(rp_context *ctx, uint32_t n) {
  rp_generate_desc g = {0};
  rp_volume *v = NULL;
  g.kind = RP_GEN_CT_HEAD;
  g.dims[0] = g.dims[1] = g.dims[2] = n;
  assert_int_equal(rp_volume_generate(ctx, &g, &v), 0);
  return v;
}

/* A volume of the same voxel values as `src` (data units), stored as
 * `type` after adding `shift` to each value. */
static rp_volume *restored(rp_context *ctx, const rp_volume *src,
                           rp_voxel_type type, double shift) {
  rp_volume_info info;
  rp_volume_desc d = {{0}, 0, {0}, NULL, {0}};
  rp_volume *v = NULL;
  const void *data = rp_volume_data(src);
  size_t i, n;
  void *buf;
  rp_volume_get_info(src, &info);
  n = (size_t)info.dims[0] * info.dims[1] * info.dims[2];
  buf = malloc(n * 4);
  assert_non_null(buf);
  for (i = 0; i < n; i++) {
    double x = (info.stored_type == RP_U16 ? ((const uint16_t *)data)[i]
                                            : ((const uint8_t *)data)[i]) +
               info.stored_offset + shift;
    if (type == RP_F32)
      ((float *)buf)[i] = (float)x;
    else if (type == RP_U16)
      ((uint16_t *)buf)[i] = (uint16_t)x;
    else
      ((int16_t *)buf)[i] = (int16_t)x;
  }
  memcpy(d.dims, info.dims, sizeof d.dims);
  d.type = type;
  d.data = buf;
  assert_int_equal(rp_volume_create(ctx, &d, &v), 0);
  free(buf);
  return v;
}

/* The reference render of `vol` under `tf` from the front, shaded. */
static void render(rp_context *ctx, const rp_volume *vol, const rp_tf *tf,
                   uint8_t *rgba) {
  rp_camera cam = {0};
  rp_render_desc d = {0};
  assert_int_equal(rp_camera_view(&cam, vol, RP_VIEW_ANTERIOR, 2.0f), 0);
  d.width = d.height = W;
  d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT;
  if (rp_render_reference(ctx, vol, tf, NULL, NULL, &cam, &d, rgba, NULL))
    fail_msg("render: %s", rp_last_error(ctx));
}

static double psnr(rp_context *ctx, const uint8_t *a, const uint8_t *b) {
  rp_image_metrics m;
  assert_int_equal(rp_image_compare(ctx, a, b, W, W, &m), 0);
  return m.psnr;
}

static size_t lit_pixels(const uint8_t *rgba) {
  size_t i, n = 0;
  for (i = 0; i < (size_t)W * W; i++)
    n += rgba[4 * i + 3] > 8;
  return n;
}

static rp_tf *preset(rp_context *ctx, const char *name) {
  rp_tf *tf = NULL;
  assert_int_equal(rp_tf_create_preset(ctx, name, &tf), 0);
  return tf;
}

/* Window/level and the presets' windows: [level - w/2, level + w/2] in
 * data units on any volume; bad widths are refused naming the value. */
static void window_level_places_the_tf(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *v = ct_head(ctx, 8);
  rp_tf *bone = preset(ctx, "ct-bone"), *w = NULL;
  double lo, hi;
  (void)state;
  rp_tf_data_range(bone, v, &lo, &hi);
  assert_float_equal(lo, 500.0 - 1000.0, 0);
  assert_float_equal(hi, 500.0 + 1000.0, 0);
  assert_int_equal(rp_tf_window(ctx, bone, 80.0, 40.0, &w), 0);
  rp_tf_data_range(w, v, &lo, &hi);
  assert_float_equal(lo, 0.0, 0);
  assert_float_equal(hi, 80.0, 0);
  rp_tf_destroy(w);
  assert_int_equal(rp_tf_window(ctx, bone, 0.0, 40.0, &w), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "width 0"));
  assert_int_equal(rp_tf_window(ctx, bone, NAN, 40.0, &w), RP_ENOTFINITE);
  /* Ends beyond +-1e30 (a float span would overflow), either way. */
  assert_int_equal(rp_tf_window(ctx, bone, 4e41, 40.0, &w), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "width 4e+41"));
  assert_int_equal(rp_tf_window(ctx, bone, 1.0, -2e30, &w), RP_ERANGE);
  rp_tf_destroy(bone);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

/* The same data values render the same, whatever type stores them: int16
 * (stored offset), float32 (stored as is), and uint16 holding HU + 1024
 * under the window shifted by 1024. Exact: every value maps to the same
 * TF position in float. */
static void storage_does_not_change_the_image(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *s16 = ct_head(ctx, N);
  rp_volume *f32 = restored(ctx, s16, RP_F32, 0.0);
  rp_volume *u16 = restored(ctx, s16, RP_U16, 1024.0);
  rp_volume_info info;
  rp_tf *bone = preset(ctx, "ct-bone"), *shifted = NULL;
  uint8_t *a = malloc(W * W * 4), *b = malloc(W * W * 4),
          *c = malloc(W * W * 4);
  (void)state;
  rp_volume_get_info(s16, &info);
  assert_int_equal(info.type, RP_S16);
  assert_float_equal(info.min, -1000.0, 0);
  assert_true(info.max > 700.0 && info.max <= 1500.0); /* bone */
  assert_int_equal(rp_tf_window(ctx, bone, 2000.0, 500.0 + 1024.0,
                                &shifted), 0);
  render(ctx, s16, bone, a);
  render(ctx, f32, bone, b);
  render(ctx, u16, shifted, c);
  print_message("ct head %d^3, ct-bone: %zu lit pixels of %d\n", N,
                lit_pixels(a), W * W);
  assert_true(lit_pixels(a) > W * W / 10); /* the skull is there */
  assert_memory_equal(a, b, W * W * 4);
  assert_memory_equal(a, c, W * W * 4);
  free(a), free(b), free(c);
  rp_tf_destroy(bone), rp_tf_destroy(shifted);
  rp_volume_destroy(s16), rp_volume_destroy(f32), rp_volume_destroy(u16);
  rp_context_destroy(ctx);
}

/* Percentile ranges against the closed form: 1000 voxels holding 0..999
 * once each (shuffled), so the p-th percentile is the value of rank
 * round(p / 100 * 999), for the counted integer path and the sorted float
 * path alike. */
static void percentiles_match_closed_form(void **state) {
  rp_context *ctx = rp_test_context();
  static const rp_tf_point pts[] = {{0, 0, 0, 0, 0}, {1, 1, 1, 1, 1}};
  static const double pc[][2] = {{10, 90}, {1, 99.5}, {0, 100}, {25, 75}};
  uint16_t u[1000];
  float f[1000];
  rp_volume_desc d = {{10, 10, 10}, RP_U16, {0}, u, {0}};
  rp_volume *vu = NULL, *vf = NULL;
  size_t i, k;
  (void)state;
  for (i = 0; i < 1000; i++) {
    u[i] = (uint16_t)((i * 337) % 1000); /* 337 is prime to 1000 */
    f[i] = (float)u[i] - 500.0f;
  }
  assert_int_equal(rp_volume_create(ctx, &d, &vu), 0);
  d.type = RP_F32, d.data = f;
  assert_int_equal(rp_volume_create(ctx, &d, &vf), 0);
  for (k = 0; k < sizeof pc / sizeof pc[0]; k++) {
    rp_tf_desc td = {pts, 2, 0, 0, 0, RP_TF_RANGE_PERCENTILES, 0, 0};
    rp_tf *tf = NULL;
    double lo, hi, want_lo = floor(pc[k][0] / 100 * 999 + 0.5);
    double want_hi = floor(pc[k][1] / 100 * 999 + 0.5);
    td.range_lo = pc[k][0], td.range_hi = pc[k][1];
    assert_int_equal(rp_tf_create(ctx, &td, &tf), 0);
    rp_tf_data_range(tf, vu, &lo, &hi);
    assert_float_equal(lo, want_lo, 0);
    assert_float_equal(hi, want_hi, 0);
    rp_tf_data_range(tf, vf, &lo, &hi);
    assert_float_equal(lo, want_lo - 500.0, 0);
    assert_float_equal(hi, want_hi - 500.0, 0);
    rp_tf_destroy(tf);
  }
  rp_volume_destroy(vu), rp_volume_destroy(vf);
  rp_context_destroy(ctx);
}

/* One voxel set to the type's largest value (a metal filling, a hot
 * pixel) deep inside the head. Bound: the render under a preset placed
 * in data units (CT) or on percentiles (MRI) stays within 40 dB PSNR of
 * the clean one; the same test of a [min, max] preset fails it, which is
 * what the bound guards against. */
static void one_outlier_voxel_changes_little(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *clean = ct_head(ctx, N), *u16 = restored(ctx, clean, RP_U16,
                                                      1024.0);
  rp_volume *dirty, *u16_dirty;
  rp_volume_info info;
  static const char *const names[] = {"ct-bone", "ct-soft", "mri",
                                      "minmax-bone"};
  size_t n, k, at;
  uint8_t *a = malloc(W * W * 4), *b = malloc(W * W * 4);
  int16_t *s;
  uint16_t *t;
  (void)state;
  rp_volume_get_info(clean, &info);
  n = (size_t)N * N * N;
  at = (size_t)N / 2 * N * N + (size_t)N / 2 * N + N / 2;
  s = malloc(n * 2), t = malloc(n * 2);
  for (k = 0; k < n; k++) {
    s[k] = (int16_t)(((const uint16_t *)rp_volume_data(clean))[k] +
                     info.stored_offset);
    t[k] = ((const uint16_t *)rp_volume_data(u16))[k];
  }
  s[at] = 32767, t[at] = 65535;
  {
    rp_volume_desc d = {{N, N, N}, RP_S16, {0}, s, {0}};
    assert_int_equal(rp_volume_create(ctx, &d, &dirty), 0);
    d.type = RP_U16, d.data = t;
    assert_int_equal(rp_volume_create(ctx, &d, &u16_dirty), 0);
  }
  for (k = 0; k < sizeof names / sizeof names[0]; k++) {
    rp_tf *tf = preset(ctx, names[k]);
    /* The MRI preset and [min, max] are tried on the unsigned copy,
     * where the outlier sits at 65535 as in the report. */
    int unsigned_copy = k >= 2;
    double p;
    render(ctx, unsigned_copy ? u16 : clean, tf, a);
    render(ctx, unsigned_copy ? u16_dirty : dirty, tf, b);
    p = psnr(ctx, a, b);
    print_message("%s: PSNR %.1f dB with one outlier voxel (%zu lit "
                  "pixels)\n", names[k], p, lit_pixels(a));
    assert_true(lit_pixels(a) > 0);
    if (strcmp(names[k], "minmax-bone") == 0)
      assert_true(p < 40.0);
    else
      assert_true(p >= 40.0);
    rp_tf_destroy(tf);
  }
  free(a), free(b), free(s), free(t);
  rp_volume_destroy(clean), rp_volume_destroy(dirty);
  rp_volume_destroy(u16), rp_volume_destroy(u16_dirty);
  rp_context_destroy(ctx);
}

static const char *put(const char *name, const char *text) {
  return rp_test_write_file(name, text, strlen(text));
}

/* TF files: points in data units, a window, comments; errors name the
 * file and the line. */
static void tf_files_in_data_units(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *v = ct_head(ctx, 8);
  const char *path;
  rp_tf *tf = NULL;
  double lo, hi;
  const float *lut;
  int n;
  (void)state;
  path = put("bone.tf", "# bone in HU\nunits: data\n"
                            "-200 0 0 0 0\n300, 1, 1, 1, 0.5\n"
                            "1300 1 1 1 1  # cortex\n");
  assert_int_equal(rp_tf_load(ctx, path, &tf), 0);
  rp_tf_data_range(tf, v, &lo, &hi);
  assert_float_equal(lo, -200.0, 0);
  assert_float_equal(hi, 1300.0, 0);
  lut = rp_tf_lut(tf, &n);
  /* 300 HU lies a third of the way: alpha 0.5 there, by the points. */
  assert_float_equal(lut[4 * ((n - 1) / 3) + 3], 0.5f, 2e-3f);
  rp_tf_destroy(tf);
  path = put("win.tf", "range: window 400 40\n0 0 0 0 0\n"
                            "1 1 1 1 1\n");
  assert_int_equal(rp_tf_load(ctx, path, &tf), 0);
  rp_tf_data_range(tf, v, &lo, &hi);
  assert_float_equal(lo, -160.0, 0);
  assert_float_equal(hi, 240.0, 0);
  rp_tf_destroy(tf);
  path = put("bad.tf", "0 0 0 0 0\n1 1 1 oops 1\n");
  assert_int_equal(rp_tf_load(ctx, path, &tf), RP_EFORMAT);
  assert_non_null(strstr(rp_last_error(ctx), "bad.tf: line 2"));
  path = put("unord.tf", "units: data\n5 0 0 0 0\n"
                            "-5 1 1 1 1\n");
  assert_int_equal(rp_tf_load(ctx, path, &tf), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "unord.tf"));
  assert_int_equal(rp_tf_load(ctx, "/nonexistent.tf", &tf), RP_ENOENT);
  /* fuzz_tf: a window of 4e41 was taken and spanned [-inf, inf]. */
  path = put("wide.tf", "range: window 401e39 40\n0 0 0 0 0\n");
  assert_int_equal(rp_tf_load(ctx, path, &tf), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "wide.tf: line 1"));
  path = put("far.tf", "units: data\n0 0 0 0 0\n2e30 1 1 1 1\n");
  assert_int_equal(rp_tf_load(ctx, path, &tf), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "point 1 field 'x'"));
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

/* Anatomical views follow the volume's orientation: the CT head stored
 * with its axes permuted and one reversed (voxel axis 0 superior, 1 left,
 * 2 anterior), with the direction matrix that says so, looks the same
 * from the front as the original. Bound: PSNR >= 50 dB (the same world
 * samples, interpolated in another axis order). Then the camera of each
 * view against D^T applied by hand, and a sheared orientation refused. */
static void views_follow_the_orientation(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *v = ct_head(ctx, N), *p = NULL;
  rp_volume_info info;
  rp_volume_desc d = {{N, N, N}, RP_S16, {0}, NULL, {0}};
  rp_tf *bone = preset(ctx, "ct-bone");
  uint8_t *a = malloc(W * W * 4), *b = malloc(W * W * 4);
  int16_t *buf = malloc((size_t)N * N * N * 2);
  const uint16_t *src = rp_volume_data(v);
  rp_camera cam = {0};
  uint32_t i, j, k;
  double m;
  (void)state;
  rp_volume_get_info(v, &info);
  assert_true(info.orientation.known);
  for (k = 0; k < N; k++) /* p(i, j, k) = v(x = j, y = N-1-k, z = i) */
    for (j = 0; j < N; j++)
      for (i = 0; i < N; i++)
        buf[((size_t)k * N + j) * N + i] = (int16_t)(
            src[((size_t)i * N + (N - 1 - k)) * N + j] + info.stored_offset);
  d.data = buf;
  d.orientation.known = 1;
  d.orientation.direction[2] = 1;  /* column 0: superior */
  d.orientation.direction[3] = 1;  /* column 1: left */
  d.orientation.direction[7] = -1; /* column 2: anterior */
  assert_int_equal(rp_volume_create(ctx, &d, &p), 0);
  render(ctx, v, bone, a);
  render(ctx, p, bone, b);
  m = psnr(ctx, a, b);
  print_message("anterior view of the permuted head: PSNR %.1f dB\n", m);
  assert_true(m >= 50.0);
  /* From the front: eye along D^T (0, -1, 0) = (0, 0, 1), up D^T (0, 0,
   * 1) = (1, 0, 0); from the left: D^T (1, 0, 0) = (0, 1, 0). */
  assert_int_equal(rp_camera_view(&cam, p, RP_VIEW_ANTERIOR, 1.0f), 0);
  assert_true(cam.eye[0] == 0 && cam.eye[1] == 0 && cam.eye[2] > 0);
  assert_true(cam.up[0] == 1 && cam.up[1] == 0 && cam.up[2] == 0);
  assert_int_equal(rp_camera_view(&cam, p, RP_VIEW_LEFT, 1.0f), 0);
  assert_true(cam.eye[0] == 0 && cam.eye[1] > 0 && cam.eye[2] == 0);
  assert_int_equal(rp_camera_view(&cam, p, (rp_view)99, 1.0f), RP_EINVAL);
  assert_int_equal(rp_view_from_name("superior"), RP_VIEW_SUPERIOR);
  assert_int_equal(rp_view_from_name("up"), 0);
  rp_volume_destroy(p);
  d.orientation.direction[3] = 0.5; /* columns 0 and 1 no longer unit */
  assert_int_equal(rp_volume_create(ctx, &d, &p), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "orientation.direction"));
  free(a), free(b), free(buf);
  rp_tf_destroy(bone);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

/* Block histograms of signed data against brute force on the data values:
 * bin = (v - min) * 64 / (max - min + 1) per voxel of each 16^3 block, in
 * HU, on an odd grid of the CT head (-1000 .. about 1400 HU). */
static void signed_histograms_match_brute_force(void **state) {
  rp_context *ctx = rp_test_context();
  rp_generate_desc g = {0};
  rp_volume *v = NULL;
  rp_histograms *h = NULL;
  rp_volume_info info;
  const uint16_t *d;
  uint32_t bx, by, bz, x, y, z, nb[3];
  long long lo, hi;
  (void)state;
  g.kind = RP_GEN_CT_HEAD;
  g.dims[0] = 37, g.dims[1] = 29, g.dims[2] = 33;
  assert_int_equal(rp_volume_generate(ctx, &g, &v), 0);
  assert_int_equal(rp_histograms_build(ctx, v, &h), 0);
  rp_volume_get_info(v, &info);
  assert_true(info.min < 0.0);
  d = rp_volume_data(v);
  lo = (long long)info.min, hi = (long long)info.max;
  for (x = 0; x < 3; x++)
    nb[x] = (info.dims[x] + 15) / 16;
  for (bz = 0; bz < nb[2]; bz++)
    for (by = 0; by < nb[1]; by++)
      for (bx = 0; bx < nb[0]; bx++) {
        uint32_t want[RP_DENSITY_BINS] = {0};
        const uint32_t *got = rp_histograms_block(
            h, (bz * nb[1] + by) * nb[0] + bx);
        for (z = bz * 16; z < bz * 16 + 16 && z < info.dims[2]; z++)
          for (y = by * 16; y < by * 16 + 16 && y < info.dims[1]; y++)
            for (x = bx * 16; x < bx * 16 + 16 && x < info.dims[0]; x++) {
              long long hu = (long long)d[((size_t)z * info.dims[1] + y) *
                                              info.dims[0] + x] +
                             (long long)info.stored_offset;
              want[(hu - lo) * RP_DENSITY_BINS / (hi - lo + 1)]++;
            }
        assert_memory_equal(got, want, sizeof want);
      }
  rp_histograms_destroy(h);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(window_level_places_the_tf),
      cmocka_unit_test(storage_does_not_change_the_image),
      cmocka_unit_test(percentiles_match_closed_form),
      cmocka_unit_test(one_outlier_voxel_changes_little),
      cmocka_unit_test(tf_files_in_data_units),
      cmocka_unit_test(views_follow_the_orientation),
      cmocka_unit_test(signed_histograms_match_brute_force),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
