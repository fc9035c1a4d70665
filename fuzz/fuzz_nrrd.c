/* libFuzzer target: an NRRD file in memory. The header goes through
 * rp__nrrd_parse; whatever follows it (the attached payload, or nothing for
 * a detached header) goes through rp__volume_decode. Besides the
 * sanitizers, it checks the contract every loader promises: a failure
 * leaves *out untouched and says why, a success matches the header. */
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  fuzz_header_then_payload(rp__nrrd_parse, "fuzz.nrrd", data, size);
  return 0;
}
