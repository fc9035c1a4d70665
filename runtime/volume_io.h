/* The volume loader's three parts and what they share. NRRD (attached or
 * detached header, raw or gzip encoding), the raypace sidecar ("key: value"
 * lines naming a raw file) and raw files whose name carries dims and type
 * (NAME_XxYxZ_TYPE.raw) are read in three steps, one file each:
 * - volume_header.c reads a header into an rp__volume_header;
 * - volume_decode.c turns a payload (raw or gzip, either endianness) into
 *   a volume;
 * - volume_io.c opens files and tells the formats apart (rp_volume_load).
 *
 * The parsers and the decoder work on memory with an explicit length (or
 * on a FILE already open), never on paths or NUL-terminated text, so that
 * fuzz targets reach them without files; only volume_io.c touches the file
 * system. Every failure goes through rp__fail with the file, the field and
 * the value, and leaves *out alone. rp__volume_header, rp__nrrd_parse,
 * rp__sidecar_parse and rp__volume_decode, which the fuzz targets call,
 * are declared in internal.h. */
#ifndef RP_VOLUME_IO_H
#define RP_VOLUME_IO_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "internal.h"

/* ---- volume_header.c ---------------------------------------------------- */

/* How each format names a header's sizes and spacing, so that a message
 * about them points at the text the user wrote. */
typedef struct rp__header_fields {
  const char *dims;
  const char *spacing;
} rp__header_fields;

extern const rp__header_fields rp__nrrd_fields_named;
extern const rp__header_fields rp__sidecar_fields_named;
extern const rp__header_fields rp__raw_fields_named;

/* An empty header: no file, unit spacing, little-endian raw data. */
void rp__volume_header_init(rp__volume_header *hdr);
/* Sizes, type and spacing of a header, then its byte size (*bytes)
 * against the context's limit. The decoder calls it too: it may be handed
 * a header that no parser produced. Messages name the field as `fields`
 * says the format calls it. */
int rp__volume_header_check(rp_context *ctx, const char *name,
                            const rp__header_fields *fields,
                            const rp__volume_header *hdr, size_t *bytes);
/* "AxBxC type" of a header, for messages. */
const char *rp__volume_dims_text(char buf[96], const rp__volume_header *hdr);
/* Fills hdr from a path whose file name is NAME_XxYxZ_TYPE.raw. Returns 0,
 * 1 when the name is not of that form (nothing recorded), or an error when
 * it is but its type or sizes are not acceptable. */
int rp__raw_name_parse(rp_context *ctx, const char *path,
                       rp__volume_header *hdr);
/* Whether a file's first bytes look like a sidecar: at least two of the
 * lines "file:", "dims:" and "type:", so that a sidecar missing one of them
 * still reaches the parser and gets a message naming the missing key. */
int rp__looks_like_sidecar(const uint8_t *buf, size_t len);

/* ---- volume_decode.c ---------------------------------------------------- */

/* Where payload bytes come from: a memory buffer, or an open file whose
 * remaining size is known (from fstat) so that sizes are checked before
 * anything is allocated. */
typedef struct rp__volume_source {
  FILE *fp; /* NULL: memory */
  const uint8_t *mem;
  uint64_t left; /* bytes not consumed yet */
} rp__volume_source;

/* Skips, decodes, byte-swaps and hands the voxels to a new volume. The
 * header has passed rp__volume_header_check and needs `bytes` bytes. */
int rp__volume_decode_source(rp_context *ctx, const char *name,
                             const rp__volume_header *hdr,
                             rp__volume_source *src, size_t bytes,
                             rp_volume **out);

#endif
