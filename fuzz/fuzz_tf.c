/* libFuzzer target: a transfer function file (rp_tf_load's format) in
 * memory, through rp__tf_parse, the parser rp_tf_load runs on the file's
 * bytes. Besides the sanitizers it holds a TF to what rp_tf_create
 * promises: a LUT of finite entries in [0, 1], a positive reference step,
 * and a finite, ordered data range on a volume. */
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  rp_context *ctx = fuzz_context();
  static int sentinel;
  rp_tf *tf = (rp_tf *)&sentinel;
  const float *lut;
  double lo = 0.0, hi = 0.0;
  int n = 0, i;
  float step;

  rp__clear_error(ctx);
  if (!fuzz_loaded(ctx, rp__tf_parse(ctx, "fuzz.tf", (const char *)data,
                                     size, &tf),
                   tf, &sentinel))
    return 0;
  lut = rp_tf_lut(tf, &n);
  if (lut == NULL || n < 2 || n > 65536)
    abort();
  for (i = 0; i < 4 * n; i++)
    if (!(lut[i] >= 0.0f && lut[i] <= 1.0f))
      abort();
  step = rp_tf_reference_step(tf);
  if (!(step > 0.0f) || !isfinite(step))
    abort();
  rp_tf_data_range(tf, fuzz_volume(), &lo, &hi);
  if (!isfinite(lo) || !isfinite(hi) || !(lo <= hi))
    abort();
  rp_tf_destroy(tf);
  return 0;
}
