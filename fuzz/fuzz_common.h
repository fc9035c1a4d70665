/* What both libFuzzer targets share: the context they run in, and the
 * contract every loader promises, checked after decoding a parsed header:
 * a failure is a negative code with a message and leaves *out untouched;
 * a success matches the header. Any breach aborts, which libFuzzer reports
 * as a crash. */
#ifndef RP_FUZZ_COMMON_H
#define RP_FUZZ_COMMON_H

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

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

/* A parse result: 0, or a failure that must carry a message. Returns
 * whether to go on to decoding. */
static int fuzz_parsed(rp_context *ctx, int rc) {
  if (rc != 0 && (rc > 0 || rp_last_error(ctx)[0] == '\0'))
    abort();
  return rc == 0;
}

static inline void fuzz_decode_checked(rp_context *ctx, const char *name,
                                       const rp__volume_header *hdr,
                                       const uint8_t *payload, size_t len) {
  static int sentinel;
  rp_volume *vol = (rp_volume *)&sentinel;
  rp_volume_info info;
  int rc;
  rp__clear_error(ctx);
  rc = rp__volume_decode(ctx, name, hdr, payload, len, &vol);
  if (rc != 0) {
    if (rc > 0 || vol != (rp_volume *)&sentinel ||
        rp_last_error(ctx)[0] == '\0')
      abort();
    return;
  }
  rp_volume_get_info(vol, &info);
  if (info.dims[0] != hdr->dims[0] || info.dims[1] != hdr->dims[1] ||
      info.dims[2] != hdr->dims[2] || info.type != hdr->type ||
      !(info.min <= info.max))
    abort();
  rp_volume_destroy(vol);
}

#endif /* RP_FUZZ_COMMON_H */
