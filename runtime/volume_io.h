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

/* ---- volume_io.c ---------------------------------------------------------- */

/* Opens a regular file for reading (never blocking on a FIFO, never
 * opening a device); NULL with *rc set and the error recorded on failure.
 * `owner`, when not NULL, is the header that named it, for the message.
 * *size is the file's size. Also used by tf_file.c. */
FILE *rp__open_regular(rp_context *ctx, const char *path, const char *owner,
                       uint64_t *size, int *rc);

/* ---- volume_header.c: text helpers the header parsers share -------------- */

/* Case-insensitive ASCII comparison, whatever the locale. */
int rp__text_eq_nocase(const char *a, const char *b);
/* Strips spaces at both ends, in place. */
char *rp__text_trim(char *s);
/* Splits off the next space-separated token, in place; NULL when none. */
char *rp__text_token(char **cursor);
/* A short, printable copy of `s` for an error message. */
const char *rp__text_shown(char buf[64], const char *s);
/* Numbers filling the whole token: unsigned, signed, floating point (with
 * '.' whatever the locale; NaN and infinities accepted, callers refuse
 * them). Each returns 1 on success, 0 otherwise. */
int rp__text_u64(const char *s, uint64_t *v);
int rp__text_i64(const char *s, int64_t *v);
int rp__text_double(const char *s, double *v);

/* Lines of a header in memory. */
typedef struct rp__line_reader {
  const uint8_t *buf;
  size_t len, pos;
  unsigned number; /* of the last line returned, from 1 */
} rp__line_reader;

/* Longest header line accepted. */
#define RP__MAX_LINE 4096

/* The next line, without "\n" or "\r\n", as a C string. Returns 1 with a
 * line, 0 at the end, or an error (too long, or holding a NUL byte). */
int rp__text_line(rp_context *ctx, const char *name, rp__line_reader *lr,
                  char out[RP__MAX_LINE + 1]);
/* A voxel spacing `v` read as `text` for `axis` of `field`: positive,
 * finite and representable as a float; written to *out. */
int rp__header_spacing(rp_context *ctx, const char *name, const char *field,
                       int axis, const char *text, double v, float *out);
/* Exactly three sizes, each at least 1, from `value` (modified). */
int rp__header_sizes(rp_context *ctx, const char *name, const char *field,
                     char *value, uint64_t dims[3]);
/* Records a data file name (not empty, not too long). */
int rp__header_data_file(rp_context *ctx, const char *name,
                         const char *field, const char *value,
                         rp__volume_header *hdr);

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

/* ---- volume_mhd.c ------------------------------------------------------- */

extern const rp__header_fields rp__mhd_fields_named;
/* A MetaImage header (.mhd/.mha) in memory into hdr. *header_len receives
 * the offset just past the ElementDataFile line, where LOCAL data starts. */
int rp__mhd_parse(rp_context *ctx, const char *name, const uint8_t *buf,
                  size_t len, rp__volume_header *hdr, size_t *header_len);
/* Whether a file is MetaImage: its name ends in .mhd or .mha, or its first
 * key is ObjectType or NDims. */
int rp__looks_like_mhd(const char *path, const uint8_t *buf, size_t len);

/* ---- volume_nifti.c ----------------------------------------------------- */

/* Whether a file is NIfTI-1/2 (or an Analyze pair): its name ends in .nii,
 * .nii.gz, .hdr or .img, or its first bytes hold a NIfTI magic. */
int rp__looks_like_nifti(const char *path, const uint8_t *buf, size_t len);
/* Loads a NIfTI file through nifticlib: header first, checked against the
 * context's limits, then the voxels. RP_EUNSUPPORTED when raypace was
 * built without nifticlib. */
int rp__nifti_load(rp_context *ctx, const char *path, rp_volume **out);

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
