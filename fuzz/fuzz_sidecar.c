/* libFuzzer target: a sidecar and its raw payload in one input, split at
 * the first NUL byte (a sidecar is text and may not hold one): the text
 * goes through rp__sidecar_parse, the bytes after the NUL through
 * rp__volume_decode. Without a NUL the whole input serves as both, which
 * keeps plain-text seeds useful. */
#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  rp_context *ctx = fuzz_context();
  rp__volume_header hdr;
  const uint8_t *nul = size > 0 ? memchr(data, '\0', size) : NULL;
  size_t text_len = nul != NULL ? (size_t)(nul - data) : size;
  const uint8_t *payload = nul != NULL ? nul + 1 : data;
  size_t payload_len = nul != NULL ? size - text_len - 1 : size;

  rp__clear_error(ctx);
  if (!fuzz_parsed(ctx, rp__sidecar_parse(ctx, "fuzz.txt", data, text_len,
                                          &hdr)))
    return 0;
  if (hdr.gzip || hdr.skip_to_end || hdr.byte_skip != 0 ||
      hdr.line_skip != 0 || hdr.data_file[0] == '\0')
    abort(); /* a sidecar names a raw file and nothing else */
  fuzz_decode_checked(ctx, "fuzz.txt", &hdr, payload, payload_len);
  return 0;
}
