/* Image resampling for image-space tuning: a frame rendered at a scale
 * below one is stretched to the output bilinearly. Premultiplied colour
 * interpolates correctly as it is (no fringes at transparent edges). */
#include <math.h>
#include <string.h>

#include "internal.h"

/* Source coordinate of a destination pixel centre, clamped to the valid
 * interpolation range, split into a base index and a weight. */
static void source_pos(uint32_t i, uint32_t dst, uint32_t src, uint32_t *i0,
                       uint32_t *i1, float *w) {
  double s = ((double)i + 0.5) * src / dst - 0.5, f;
  if (s < 0.0)
    s = 0.0;
  if (s > src - 1.0)
    s = src - 1.0;
  f = floor(s);
  *i0 = (uint32_t)f;
  *i1 = *i0 + 1 < src ? *i0 + 1 : *i0;
  *w = (float)(s - f);
}

void rp_image_upscale(const uint8_t *src, uint32_t src_w, uint32_t src_h,
                      uint8_t *dst, uint32_t dst_w, uint32_t dst_h) {
  uint32_t x, y;
  if (src == NULL || dst == NULL || src_w == 0 || src_h == 0)
    return;
  if (src_w == dst_w && src_h == dst_h) {
    memmove(dst, src, (size_t)src_w * src_h * 4);
    return;
  }
  for (y = 0; y < dst_h; y++) {
    uint32_t y0, y1;
    float wy;
    source_pos(y, dst_h, src_h, &y0, &y1, &wy);
    for (x = 0; x < dst_w; x++) {
      uint32_t x0, x1, c;
      float wx;
      const uint8_t *r0, *r1;
      source_pos(x, dst_w, src_w, &x0, &x1, &wx);
      r0 = src + (size_t)y0 * src_w * 4;
      r1 = src + (size_t)y1 * src_w * 4;
      for (c = 0; c < 4; c++) {
        float top = r0[4 * x0 + c] + wx * (r0[4 * x1 + c] - r0[4 * x0 + c]);
        float bot = r1[4 * x0 + c] + wx * (r1[4 * x1 + c] - r1[4 * x0 + c]);
        dst[((size_t)y * dst_w + x) * 4 + c] =
            (uint8_t)(top + wy * (bot - top) + 0.5f);
      }
    }
  }
}
