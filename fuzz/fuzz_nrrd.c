/* libFuzzer target: an NRRD file in memory. The header goes through
 * rp__nrrd_parse; whatever follows it (the attached payload, or nothing for
 * a detached header) goes through rp__volume_decode. Besides the
 * sanitizers, it checks the contract every loader promises: a failure
 * leaves *out untouched and says why, a success matches the header. */
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  rp_context *ctx = fuzz_context();
  rp__volume_header hdr;
  size_t header_len = 0;

  rp__clear_error(ctx);
  if (!fuzz_parsed(ctx, rp__nrrd_parse(ctx, "fuzz.nrrd", data, size, &hdr,
                                       &header_len)))
    return 0;
  if (header_len > size)
    abort();
  fuzz_decode_checked(ctx, "fuzz.nrrd", &hdr, data + header_len,
                      size - header_len);
  return 0;
}
