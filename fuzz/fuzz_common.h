/* What both libFuzzer targets share: the context they run in, and the
 * contract every loader promises, checked after decoding a parsed header:
 * a failure is a negative code with a message and leaves *out untouched;
 * a success matches the header. Any breach aborts, which libFuzzer reports
 * as a crash. */
#ifndef RP_FUZZ_COMMON_H
#define RP_FUZZ_COMMON_H

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"

static inline rp_context *fuzz_context(void) {
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

/* A small CT-like volume (4^3 floats, -1000 .. 1000) for what takes one:
 * a TF's data range (percentile and window ranges read its values), a
 * sequence's cameras. */
static inline rp_volume *fuzz_volume(void) {
  static rp_volume *vol;
  if (vol == NULL) {
    static float v[4 * 4 * 4];
    rp_volume_desc d;
    size_t i;
    for (i = 0; i < sizeof v / sizeof v[0]; i++)
      v[i] = -1000.0f + 2000.0f * (float)i / 63.0f;
    memset(&d, 0, sizeof d);
    d.dims[0] = d.dims[1] = d.dims[2] = 4;
    d.type = RP_F32;
    d.data = v;
    if (rp_volume_create(fuzz_context(), &d, &vol) != 0)
      abort();
  }
  return vol;
}

/* A parse result: 0, or a failure that must carry a message. Returns
 * whether to go on to decoding. */
static inline int fuzz_parsed(rp_context *ctx, int rc) {
  if (rc != 0 && (rc > 0 || rp_last_error(ctx)[0] == '\0'))
    abort();
  return rc == 0;
}

/* A load's result against the contract: a failure is negative, leaves
 * *out (`obj`, a volume or a TF, first set to `untouched`) alone and
 * carries a message. Returns whether the load succeeded. */
static inline int fuzz_loaded(rp_context *ctx, int rc, const void *obj,
                              const void *untouched) {
  if (rc != 0 && (rc > 0 || obj != untouched ||
                  rp_last_error(ctx)[0] == '\0'))
    abort();
  return rc == 0;
}

/* Whether a volume's orientation breaks its promise: unit, orthogonal
 * columns and a finite origin when known, the identity when not. */
static inline int fuzz_orientation_bad(const rp_orientation *o) {
  int i, j;
  for (i = 0; i < 3; i++) {
    const double *a = &o->direction[3 * i];
    if (!isfinite(o->origin[i]) ||
        fabs(a[0] * a[0] + a[1] * a[1] + a[2] * a[2] - 1.0) > 1e-6)
      return 1;
    for (j = 0; j < i; j++) {
      const double *b = &o->direction[3 * j];
      if (fabs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) > 1e-3)
        return 1;
    }
  }
  return !o->known && (o->direction[0] != 1.0 || o->direction[4] != 1.0 ||
                       o->direction[8] != 1.0);
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
  if (!fuzz_loaded(ctx, rc, vol, &sentinel))
    return;
  rp_volume_get_info(vol, &info);
  if (info.dims[0] != hdr->dims[0] || info.dims[1] != hdr->dims[1] ||
      info.dims[2] != hdr->dims[2] || info.type != hdr->type ||
      !(info.min <= info.max) ||
      info.orientation.known != hdr->orientation.known ||
      fuzz_orientation_bad(&info.orientation))
    abort();
  rp_volume_destroy(vol);
}

/* A header parser that also says where an attached payload starts
 * (rp__nrrd_parse, rp__mhd_parse). */
typedef int (*fuzz_header_parser)(rp_context *ctx, const char *name,
                                  const uint8_t *buf, size_t len,
                                  rp__volume_header *hdr, size_t *header_len);

/* One input of such a format: the header through `parse`, whatever
 * follows it through the decoder, both held to the contract. */
static inline void fuzz_header_then_payload(fuzz_header_parser parse,
                                            const char *name,
                                            const uint8_t *data,
                                            size_t size) {
  rp_context *ctx = fuzz_context();
  rp__volume_header hdr;
  size_t header_len = 0;
  rp__clear_error(ctx);
  if (!fuzz_parsed(ctx, parse(ctx, name, data, size, &hdr, &header_len)))
    return;
  if (header_len > size)
    abort();
  fuzz_decode_checked(ctx, name, &hdr, data + header_len,
                      size - header_len);
}

#endif /* RP_FUZZ_COMMON_H */
