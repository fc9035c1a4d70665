/* Image resampling for image-space tuning: a frame rendered at a scale
 * below one is stretched to the output bilinearly. Premultiplied colour
 * interpolates correctly as it is (no fringes at transparent edges). */
#include <math.h>
#include <string.h>

#include "internal.h"

/* Interpolation weights are fixed point with this many fraction bits:
 * fine enough that quantising them moves no channel by more than
 * 255 / 2^25, and two of them times a channel fit in 64 bits. */
#define WEIGHT_BITS 24
#define WEIGHT_ONE ((uint64_t)1 << WEIGHT_BITS)

/* Source coordinate of a destination pixel centre, clamped to the valid
 * interpolation range, split into a base index and a weight. */
static void source_pos(uint32_t i, uint32_t dst, uint32_t src, uint32_t *i0,
                       uint32_t *i1, uint64_t *w) {
  double s = ((double)i + 0.5) * src / dst - 0.5, f;
  if (s < 0.0)
    s = 0.0;
  if (s > src - 1.0)
    s = src - 1.0;
  f = floor(s);
  *i0 = (uint32_t)f;
  *i1 = *i0 + 1 < src ? *i0 + 1 : *i0;
  *w = (uint64_t)((s - f) * (double)WEIGHT_ONE + 0.5);
}

/* Columns whose taps are worked out once and reused for every row: the
 * per-pixel floor and division were most of the upscale's cost
 * (docs/runtime.md, "Overhead"). */
#define UPSCALE_COLUMNS 256

void rp_image_upscale(const uint8_t *src, uint32_t src_w, uint32_t src_h,
                      uint8_t *dst, uint32_t dst_w, uint32_t dst_h) {
  uint32_t x_lo, x0s[UPSCALE_COLUMNS], x1s[UPSCALE_COLUMNS];
  uint64_t wxs[UPSCALE_COLUMNS];
  if (src == NULL || dst == NULL || src_w == 0 || src_h == 0)
    return;
  if (src_w == dst_w && src_h == dst_h) {
    memmove(dst, src, (size_t)src_w * src_h * 4);
    return;
  }
  for (x_lo = 0; x_lo < dst_w; x_lo += UPSCALE_COLUMNS) {
    uint32_t n = dst_w - x_lo < UPSCALE_COLUMNS ? dst_w - x_lo
                                                 : UPSCALE_COLUMNS;
    uint32_t x, y;
    for (x = 0; x < n; x++)
      source_pos(x_lo + x, dst_w, src_w, &x0s[x], &x1s[x], &wxs[x]);
    for (y = 0; y < dst_h; y++) {
      uint32_t y0, y1;
      uint64_t wy;
      const uint8_t *r0, *r1;
      uint8_t *out = dst + ((size_t)y * dst_w + x_lo) * 4;
      source_pos(y, dst_h, src_h, &y0, &y1, &wy);
      r0 = src + (size_t)y0 * src_w * 4;
      r1 = src + (size_t)y1 * src_w * 4;
      for (x = 0; x < n; x++) {
        const uint8_t *a0 = r0 + 4 * x0s[x], *a1 = r0 + 4 * x1s[x];
        const uint8_t *b0 = r1 + 4 * x0s[x], *b1 = r1 + 4 * x1s[x];
        uint64_t wx = wxs[x];
        uint32_t c;
        for (c = 0; c < 4; c++) {
          uint64_t top = a0[c] * (WEIGHT_ONE - wx) + a1[c] * wx;
          uint64_t bot = b0[c] * (WEIGHT_ONE - wx) + b1[c] * wx;
          out[4 * x + c] = (uint8_t)((top * (WEIGHT_ONE - wy) + bot * wy +
                                      (WEIGHT_ONE * WEIGHT_ONE >> 1)) >>
                                     (2 * WEIGHT_BITS));
        }
      }
    }
  }
}

/* ---- Image metrics (seed 000 Table 4) ----------------------------------- */

/* SSIM as Wang et al. 2004 define it: an 11x11 Gaussian window, sigma 1.5,
 * K1 = 0.01, K2 = 0.03, dynamic range L = 255. */
#define SSIM_WINDOW 11
#define SSIM_SIGMA 1.5
#define SSIM_C1 ((0.01 * 255.0) * (0.01 * 255.0))
#define SSIM_C2 ((0.03 * 255.0) * (0.03 * 255.0))

/* Window sums per valid column: weighted a, b, a^2, b^2 and a*b. */
enum { M_A, M_B, M_AA, M_BB, M_AB, M_COUNT };

/* n taps of the Gaussian at offsets from the window's middle, summing to
 * one. The 2-D window is the outer product of two of these, which is the
 * normalised 2-D Gaussian itself: that is what makes it separable. */
static void gauss_taps(uint32_t n, double *g) {
  double mid = 0.5 * (n - 1.0), sum = 0.0;
  uint32_t i;
  for (i = 0; i < n; i++) {
    double d = i - mid;
    g[i] = exp(-d * d / (2.0 * SSIM_SIGMA * SSIM_SIGMA));
    sum += g[i];
  }
  for (i = 0; i < n; i++)
    g[i] /= sum;
}

/* Luma of one row of premultiplied pixels, i.e. of the row seen over
 * black; also adds the row's squared R, G, B differences to *sq. */
static void luma_rows(const uint8_t *a, const uint8_t *b, uint32_t w,
                      double *la, double *lb, uint64_t *sq) {
  uint32_t x;
  for (x = 0; x < w; x++, a += 4, b += 4) {
    int dr = a[0] - b[0], dg = a[1] - b[1], db = a[2] - b[2];
    *sq += (uint64_t)(dr * dr + dg * dg + db * db);
    la[x] = 0.299 * a[0] + 0.587 * a[1] + 0.114 * a[2];
    lb[x] = 0.299 * b[0] + 0.587 * b[1] + 0.114 * b[2];
  }
}

/* The horizontal pass over one row: the five weighted sums of each valid
 * window position, into `row` (M_COUNT arrays of ow). */
static void window_row(const double *la, const double *lb, uint32_t ow,
                       const double *g, uint32_t kw, double *row) {
  uint32_t x, i;
  for (x = 0; x < ow; x++) {
    double s[M_COUNT] = {0};
    for (i = 0; i < kw; i++) {
      double va = la[x + i], vb = lb[x + i];
      s[M_A] += g[i] * va;
      s[M_B] += g[i] * vb;
      s[M_AA] += g[i] * va * va;
      s[M_BB] += g[i] * vb * vb;
      s[M_AB] += g[i] * va * vb;
    }
    for (i = 0; i < M_COUNT; i++)
      row[(size_t)i * ow + x] = s[i];
  }
}

static double ssim_of(const double m[M_COUNT]) {
  double va = m[M_AA] - m[M_A] * m[M_A], vb = m[M_BB] - m[M_B] * m[M_B];
  double cov = m[M_AB] - m[M_A] * m[M_B];
  return (2.0 * m[M_A] * m[M_B] + SSIM_C1) * (2.0 * cov + SSIM_C2) /
         ((m[M_A] * m[M_A] + m[M_B] * m[M_B] + SSIM_C1) *
          (va + vb + SSIM_C2));
}

int rp_image_compare(rp_context *ctx, const uint8_t *a, const uint8_t *b,
                     uint32_t width, uint32_t height,
                     rp_image_metrics *out) {
  uint32_t kw, kh, ow, oh, x, y;
  double gx[SSIM_WINDOW], gy[SSIM_WINDOW], *la, *lb, *ring, ssim_sum = 0;
  size_t row_sums, scratch;
  /* Exact: each pixel adds at most 3 * 255^2 < 2^18, so 2^46 pixels
   * (far more than fit in memory) would be needed to overflow. */
  uint64_t sq = 0;
  if (ctx == NULL)
    return RP_EINVAL;
  if (a == NULL || b == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_image_compare: NULL %s",
                    a == NULL ? "a" : b == NULL ? "b" : "out");
  if (width == 0 || height == 0)
    return rp__fail(ctx, RP_EINVAL, "rp_image_compare: size %ux%u",
                    width, height);
  if ((size_t)width > SIZE_MAX / 4 / height)
    return rp__fail(ctx, RP_ERANGE, "rp_image_compare: %ux%u overflows",
                    width, height);
  kw = width < SSIM_WINDOW ? width : SSIM_WINDOW;
  kh = height < SSIM_WINDOW ? height : SSIM_WINDOW;
  ow = width - kw + 1;
  oh = height - kh + 1;
  gauss_taps(kw, gx);
  gauss_taps(kh, gy);
  /* The vertical pass needs the horizontal sums of the last kh rows only:
   * a ring of kh rows, row r in slot r % kh. */
  row_sums = (size_t)M_COUNT * ow;
  scratch = 2 * (size_t)width + row_sums * kh;
  if (scratch > SIZE_MAX / sizeof(double))
    return rp__fail(ctx, RP_ERANGE, "rp_image_compare: %ux%u overflows",
                    width, height);
  la = rp__malloc(ctx, scratch * sizeof(double));
  if (la == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_image_compare: %zu bytes",
                    scratch * sizeof(double));
  lb = la + width;
  ring = lb + width;
  for (y = 0; y < height; y++) {
    size_t off = (size_t)y * width * 4;
    luma_rows(a + off, b + off, width, la, lb, &sq);
    window_row(la, lb, ow, gx, kw, ring + (size_t)(y % kh) * row_sums);
    if (y + 1 < kh)
      continue;
    for (x = 0; x < ow; x++) {
      double m[M_COUNT] = {0};
      uint32_t j, k;
      for (j = 0; j < kh; j++) {
        const double *r = ring + (size_t)((y + 1 - kh + j) % kh) * row_sums;
        for (k = 0; k < M_COUNT; k++)
          m[k] += gy[j] * r[(size_t)k * ow + x];
      }
      ssim_sum += ssim_of(m);
    }
  }
  rp__free(ctx, la);
  out->mse = (double)sq / (3.0 * width * height);
  out->psnr = sq == 0 ? INFINITY : 10.0 * log10(255.0 * 255.0 / out->mse);
  out->ssim = ssim_sum / ((double)ow * oh);
  return 0;
}
