/* libFuzzer target: a sidecar and its raw payload in one input, split at
 * the first NUL byte (a sidecar is text and may not hold one): the text
 * goes through rp__sidecar_parse, the bytes after the NUL through
 * rp__volume_decode. Without a NUL the whole input serves as both, which
 * keeps plain-text seeds useful. */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static rp_context *fuzz_context(void) {
  static rp_context *ctx;
  if (ctx == NULL) {
    rp_context_desc desc;
    memset(&desc, 0, sizeof desc);
    desc.threads = 1;
    desc.max_volume_bytes = (uint64_t)64 << 20;
    if (rp_context_create(&desc, &ctx) != 0)
      abort();
  }
  return ctx;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static int sentinel;
  rp_context *ctx = fuzz_context();
  rp__volume_header hdr;
  rp_volume *vol = (rp_volume *)&sentinel;
  const uint8_t *nul = size > 0 ? memchr(data, '\0', size) : NULL;
  size_t text_len = nul != NULL ? (size_t)(nul - data) : size;
  const uint8_t *payload = nul != NULL ? nul + 1 : data;
  size_t payload_len = nul != NULL ? size - text_len - 1 : size;
  rp_volume_info info;
  int rc;

  rp__clear_error(ctx);
  rc = rp__sidecar_parse(ctx, "fuzz.txt", data, text_len, &hdr);
  if (rc != 0) {
    if (rc > 0 || rp_last_error(ctx)[0] == '\0')
      abort();
    return 0;
  }
  if (hdr.gzip || hdr.skip_to_end || hdr.byte_skip != 0 ||
      hdr.line_skip != 0 || hdr.data_file[0] == '\0')
    abort(); /* a sidecar names a raw file and nothing else */
  rp__clear_error(ctx);
  rc = rp__volume_decode(ctx, "fuzz.txt", &hdr, payload, payload_len, &vol);
  if (rc != 0) {
    if (rc > 0 || vol != (rp_volume *)&sentinel ||
        rp_last_error(ctx)[0] == '\0')
      abort();
    return 0;
  }
  rp_volume_get_info(vol, &info);
  if (info.dims[0] != hdr.dims[0] || info.dims[1] != hdr.dims[1] ||
      info.dims[2] != hdr.dims[2] || info.type != hdr.type ||
      !(info.min <= info.max))
    abort();
  rp_volume_destroy(vol);
  return 0;
}
