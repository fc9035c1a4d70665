/* Bilinear upscaling of a frame rendered at image scale < 1. */
#include <math.h>
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

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(ramp_is_linear),
      cmocka_unit_test(same_size_copies_and_one_pixel_fills),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
