/* libFuzzer target: an NRRD file in memory. The header goes through
 * rp__nrrd_parse; whatever follows it (the attached payload, or nothing for
 * a detached header) goes through rp__volume_decode. Besides the
 * sanitizers, it checks the contract every loader promises: a failure
 * leaves *out untouched and says why, a success matches the header. */
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
    /* Small enough that no accepted header makes a run slow or the
     * process exceed libFuzzer's memory limit. */
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
  rp_volume_info info;
  size_t header_len = 0;
  int rc;

  rp__clear_error(ctx);
  rc = rp__nrrd_parse(ctx, "fuzz.nrrd", data, size, &hdr, &header_len);
  if (rc != 0) {
    if (rc > 0 || rp_last_error(ctx)[0] == '\0')
      abort();
    return 0;
  }
  if (header_len > size)
    abort();
  rp__clear_error(ctx);
  rc = rp__volume_decode(ctx, "fuzz.nrrd", &hdr, data + header_len,
                         size - header_len, &vol);
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
