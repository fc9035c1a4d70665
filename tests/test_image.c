/* Bilinear upscaling of a frame rendered at image scale < 1, and the
 * image metrics (MSE, PSNR, SSIM) quality is measured with. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "test_util.h"

/* A ramp along x is reproduced exactly (to rounding): destination pixel x
 * samples the source at s = (x + 0.5) * sw / dw - 0.5, clamped. */
static void ramp_is_linear(void **state) {
  uint8_t src[4 * 2 * 4], dst[11 * 3 * 4];
  uint32_t x, y, c;
  (void)state;
  for (y = 0; y < 2; y++)
    for (x = 0; x < 4; x++)
      for (c = 0; c < 4; c++)
        src[(y * 4 + x) * 4 + c] = (uint8_t)(60 * x + c);
  rp_image_upscale(src, 4, 2, dst, 11, 3);
  for (y = 0; y < 3; y++)
    for (x = 0; x < 11; x++)
      for (c = 0; c < 4; c++) {
        double s = (x + 0.5) * 4.0 / 11.0 - 0.5;
        double want = 60.0 * fmin(fmax(s, 0.0), 3.0) + c;
        assert_true(fabs(dst[(y * 11 + x) * 4 + c] - want) <= 0.5 + 1e-3);
      }
}

static void same_size_copies_and_one_pixel_fills(void **state) {
  uint8_t src[3 * 2 * 4], dst[3 * 2 * 4], big[5 * 7 * 4];
  uint8_t one[4] = {10, 20, 30, 40};
  size_t i;
  (void)state;
  for (i = 0; i < sizeof src; i++)
    src[i] = (uint8_t)(i * 7);
  rp_image_upscale(src, 3, 2, dst, 3, 2);
  assert_memory_equal(src, dst, sizeof src);
  rp_image_upscale(one, 1, 1, big, 5, 7);
  for (i = 0; i < 5 * 7; i++)
    assert_memory_equal(big + 4 * i, one, 4);
}

/* ---- rp_image_compare --------------------------------------------------- */

#define C1 ((0.01 * 255.0) * (0.01 * 255.0))
#define C2 ((0.03 * 255.0) * (0.03 * 255.0))

static uint32_t lcg_next(uint32_t *s) {
  *s = *s * 1664525u + 1013904223u;
  return *s >> 8;
}

/* A random image and a noisy copy of it (noise of +-amp per channel). */
static void random_pair(uint8_t *a, uint8_t *b, size_t pixels, int amp,
                        uint32_t seed) {
  size_t i;
  for (i = 0; i < pixels * 4; i++) {
    int v = (int)(lcg_next(&seed) % 256);
    int n = (int)(lcg_next(&seed) % (2u * amp + 1)) - amp;
    a[i] = (uint8_t)v;
    b[i] = (uint8_t)(v + n < 0 ? 0 : v + n > 255 ? 255 : v + n);
  }
}

static double luma(const uint8_t *p) {
  return 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2];
}

/* SSIM straight from its definition, written apart from the library's
 * separable version: per window position, the 2-D Gaussian weights
 * normalised over the window, two-pass moments, then the mean. */
static double brute_ssim(const uint8_t *a, const uint8_t *b, uint32_t w,
                         uint32_t h) {
  uint32_t kw = w < 11 ? w : 11, kh = h < 11 ? h : 11, x0, y0, i, j;
  double cx = 0.5 * (kw - 1.0), cy = 0.5 * (kh - 1.0), total = 0;
  for (y0 = 0; y0 + kh <= h; y0++)
    for (x0 = 0; x0 + kw <= w; x0++) {
      double ws = 0, ma = 0, mb = 0, va = 0, vb = 0, cv = 0;
      for (j = 0; j < kh; j++)
        for (i = 0; i < kw; i++)
          ws += exp(-((i - cx) * (i - cx) + (j - cy) * (j - cy)) / 4.5);
      for (j = 0; j < kh; j++)
        for (i = 0; i < kw; i++) {
          size_t p = ((size_t)(y0 + j) * w + x0 + i) * 4;
          double g =
              exp(-((i - cx) * (i - cx) + (j - cy) * (j - cy)) / 4.5) / ws;
          ma += g * luma(a + p);
          mb += g * luma(b + p);
        }
      for (j = 0; j < kh; j++)
        for (i = 0; i < kw; i++) {
          size_t p = ((size_t)(y0 + j) * w + x0 + i) * 4;
          double g =
              exp(-((i - cx) * (i - cx) + (j - cy) * (j - cy)) / 4.5) / ws;
          double da = luma(a + p) - ma, db = luma(b + p) - mb;
          va += g * da * da;
          vb += g * db * db;
          cv += g * da * db;
        }
      total += (2 * ma * mb + C1) * (2 * cv + C2) /
               ((ma * ma + mb * mb + C1) * (va + vb + C2));
    }
  return total / ((double)(w - kw + 1) * (h - kh + 1));
}

static double brute_mse(const uint8_t *a, const uint8_t *b, size_t pixels) {
  double s = 0;
  size_t i;
  int c;
  for (i = 0; i < pixels; i++)
    for (c = 0; c < 3; c++) {
      double d = (double)a[4 * i + c] - b[4 * i + c];
      s += d * d;
    }
  return s / (3.0 * pixels);
}

static void identical_images(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t a[37 * 21 * 4], b[37 * 21 * 4];
  rp_image_metrics m;
  size_t i;
  (void)state;
  random_pair(a, b, 37 * 21, 0, 5);
  /* Alpha is not compared: the image is judged as seen over black. */
  for (i = 3; i < sizeof b; i += 4)
    b[i] = (uint8_t)(255 - b[i]);
  assert_int_equal(rp_image_compare(ctx, a, b, 37, 21, &m), 0);
  assert_true(m.mse == 0.0);
  assert_true(isinf(m.psnr) && m.psnr > 0);
  assert_true(fabs(m.ssim - 1.0) < 1e-12);
  rp_context_destroy(ctx);
}

/* Constant images c and c + d: every pixel differs by d in each channel,
 * so MSE = d^2; the windows have no variance, so SSIM is its luminance
 * term (2 c (c + d) + C1) / (c^2 + (c + d)^2 + C1) (luma of grey c is c).
 */
static void constant_offset(void **state) {
  rp_context *ctx = rp_test_context();
  static const int cs[] = {0, 40, 128, 200};
  static const int ds[] = {0, 1, 7, 55};
  uint8_t a[19 * 14 * 4], b[19 * 14 * 4];
  rp_image_metrics m;
  size_t ci, di, i;
  (void)state;
  for (ci = 0; ci < 4; ci++)
    for (di = 0; di < 4; di++) {
      double c = cs[ci], d = ds[di], want;
      for (i = 0; i < sizeof a; i++) {
        a[i] = (uint8_t)(i % 4 == 3 ? 255 : c);
        b[i] = (uint8_t)(i % 4 == 3 ? 255 : c + d);
      }
      assert_int_equal(rp_image_compare(ctx, a, b, 19, 14, &m), 0);
      assert_true(fabs(m.mse - d * d) < 1e-12);
      if (d == 0)
        assert_true(isinf(m.psnr));
      else
        assert_true(fabs(m.psnr - 10 * log10(255.0 * 255.0 / (d * d))) <
                    1e-9);
      want = (2 * c * (c + d) + C1) / (c * c + (c + d) * (c + d) + C1);
      assert_true(fabs(m.ssim - want) < 1e-9);
    }
  rp_context_destroy(ctx);
}

/* Random pairs against the brute-force definition, over sizes larger and
 * smaller than the window along each axis, 1x1 and odd sizes included. */
static void matches_brute_force(void **state) {
  static const uint32_t sizes[][2] = {{1, 1},  {1, 30}, {30, 1}, {5, 3},
                                      {11, 11}, {12, 11}, {23, 17},
                                      {4, 40}, {64, 9}};
  rp_context *ctx = rp_test_context();
  uint8_t a[64 * 40 * 4], b[64 * 40 * 4];
  size_t k;
  (void)state;
  for (k = 0; k < sizeof sizes / sizeof sizes[0]; k++) {
    uint32_t w = sizes[k][0], h = sizes[k][1];
    int amp;
    for (amp = 3; amp <= 90; amp *= 5) {
      rp_image_metrics m;
      double mse, ssim;
      random_pair(a, b, (size_t)w * h, amp, (uint32_t)(k * 31 + amp));
      mse = brute_mse(a, b, (size_t)w * h);
      ssim = brute_ssim(a, b, w, h);
      assert_int_equal(rp_image_compare(ctx, a, b, w, h, &m), 0);
      assert_true(fabs(m.mse - mse) < 1e-9 * (1 + mse));
      assert_true(fabs(m.psnr - 10 * log10(255.0 * 255.0 / mse)) < 1e-9);
      assert_true(fabs(m.ssim - ssim) < 1e-9);
      assert_true(m.ssim < 1.0 && m.ssim > -1.0);
    }
  }
  rp_context_destroy(ctx);
}

/* A 1x1 image is one window of one pixel: SSIM is the luminance term. */
static void one_pixel(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t a[4] = {10, 20, 30, 255}, b[4] = {13, 20, 30, 255};
  rp_image_metrics m;
  double la = luma(a), lb = luma(b);
  (void)state;
  assert_int_equal(rp_image_compare(ctx, a, b, 1, 1, &m), 0);
  assert_true(fabs(m.mse - 3.0) < 1e-12);
  assert_true(fabs(m.ssim - (2 * la * lb + C1) / (la * la + lb * lb + C1)) <
              1e-12);
  rp_context_destroy(ctx);
}

static void bad_arguments(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t a[16] = {0}, b[16] = {0};
  rp_image_metrics m = {1, 2, 3};
  (void)state;
  assert_int_equal(rp_image_compare(NULL, a, b, 2, 2, &m), RP_EINVAL);
  assert_int_equal(rp_image_compare(ctx, NULL, b, 2, 2, &m), RP_EINVAL);
  assert_int_equal(rp_image_compare(ctx, a, NULL, 2, 2, &m), RP_EINVAL);
  assert_int_equal(rp_image_compare(ctx, a, b, 2, 2, NULL), RP_EINVAL);
  assert_int_equal(rp_image_compare(ctx, a, b, 0, 2, &m), RP_EINVAL);
  assert_int_equal(rp_image_compare(ctx, a, b, 2, 0, &m), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "rp_image_compare"));
  /* A failed call leaves its output untouched. */
  assert_true(m.mse == 1 && m.psnr == 2 && m.ssim == 3);
  rp_context_destroy(ctx);
}

/* An allocator that refuses once armed: the comparison's scratch. */
static int refuse_alloc;

static void *failing_alloc(size_t size, void *user) {
  (void)user;
  return refuse_alloc ? NULL : malloc(size);
}

static void failing_free(void *ptr, void *user) {
  (void)user;
  free(ptr);
}

static void out_of_memory(void **state) {
  rp_context_desc d = {0};
  rp_context *ctx = NULL;
  uint8_t a[16 * 16 * 4] = {0}, b[16 * 16 * 4] = {0};
  rp_image_metrics m = {1, 2, 3};
  (void)state;
  d.allocator.alloc = failing_alloc;
  d.allocator.free = failing_free;
  refuse_alloc = 0;
  assert_int_equal(rp_context_create(&d, &ctx), 0);
  refuse_alloc = 1;
  assert_int_equal(rp_image_compare(ctx, a, b, 16, 16, &m), RP_ENOMEM);
  assert_true(m.mse == 1 && m.psnr == 2 && m.ssim == 3);
  refuse_alloc = 0;
  assert_int_equal(rp_image_compare(ctx, a, b, 16, 16, &m), 0);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(ramp_is_linear),
      cmocka_unit_test(same_size_copies_and_one_pixel_fills),
      cmocka_unit_test(identical_images),
      cmocka_unit_test(constant_offset),
      cmocka_unit_test(matches_brute_force),
      cmocka_unit_test(one_pixel),
      cmocka_unit_test(bad_arguments),
      cmocka_unit_test(out_of_memory),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
