/* libFuzzer target: a MetaImage file in memory. The header goes through
 * rp__mhd_parse; whatever follows its ElementDataFile line (the LOCAL
 * payload, or stray bytes after a header that names a file) goes through
 * rp__volume_decode. fuzz_common.h checks the contract every loader
 * promises. */
#include "fuzz_common.h"
#include "volume_io.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  fuzz_header_then_payload(rp__mhd_parse, "fuzz.mha", data, size);
  return 0;
}
