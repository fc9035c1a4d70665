/* MetaImage headers (ITK's .mhd with a detached data file, .mha with the
 * data attached) into an rp__volume_header (volume_io.h says how the
 * loader's parts fit together).
 *
 * A header is "Key = Value" lines, and ElementDataFile comes last: with
 * LOCAL, the data starts right after its line. Policy decisions
 * (tests/test_volume_formats.c holds us to them):
 * - Only what a scalar 3D image needs: ObjectType Image, NDims 3, one
 *   channel, binary data; anything else is refused naming the key.
 * - Keys are matched without regard to case; unknown keys are ignored, as
 *   MetaIO itself does with keys it does not know.
 * - Orientation: TransformMatrix (also spelt Rotation or Orientation)
 *   holds the axes' unit vectors in LPS, axis 0's three components first;
 *   Offset (Position, Origin) the centre of voxel 0. Without a matrix,
 *   AnatomicalOrientation (ITK's convention: each letter is where an axis
 *   comes from, "RAI" is LPS) gives the axes. A matrix that is all zero is
 *   no matrix.
 * - HeaderSize skips bytes of a detached data file (-1: the data is the
 *   file's tail); with compressed data it must be 0. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "volume_io.h"

/* Keys whose repetition is an error, one bit each. */
enum {
  K_OBJECT = 1 << 0,
  K_NDIMS = 1 << 1,
  K_DIMSIZE = 1 << 2,
  K_TYPE = 1 << 3,
  K_SPACING = 1 << 4,
  K_MSB = 1 << 5,
  K_HEADERSIZE = 1 << 6,
  K_COMPRESSED = 1 << 7,
  K_COMPSIZE = 1 << 8,
  K_DATAFILE = 1 << 9,
  K_MATRIX = 1 << 10,
  K_OFFSET = 1 << 11,
  K_ANATOMY = 1 << 12,
  K_CHANNELS = 1 << 13,
  K_BINARY = 1 << 14,
  K_IGNORED = 1 << 15 /* known and of no use here (ElementSize) */
};

static const struct {
  const char *name;
  unsigned bit;
} mhd_keys[] = {
    {"ObjectType", K_OBJECT},
    {"NDims", K_NDIMS},
    {"DimSize", K_DIMSIZE},
    {"ElementType", K_TYPE},
    {"ElementSpacing", K_SPACING},
    {"ElementByteOrderMSB", K_MSB},
    {"BinaryDataByteOrderMSB", K_MSB},
    {"HeaderSize", K_HEADERSIZE},
    {"CompressedData", K_COMPRESSED},
    {"CompressedDataSize", K_COMPSIZE},
    {"ElementDataFile", K_DATAFILE},
    {"TransformMatrix", K_MATRIX},
    {"Rotation", K_MATRIX},
    {"Orientation", K_MATRIX},
    {"Offset", K_OFFSET},
    {"Position", K_OFFSET},
    {"Origin", K_OFFSET},
    {"AnatomicalOrientation", K_ANATOMY},
    {"ElementNumberOfChannels", K_CHANNELS},
    {"BinaryData", K_BINARY},
    {"ElementSize", K_IGNORED},
};

static const struct {
  const char *name;
  rp_voxel_type type;
} mhd_types[] = {{"MET_UCHAR", RP_U8},  {"MET_CHAR", RP_S8},
                 {"MET_USHORT", RP_U16}, {"MET_SHORT", RP_S16},
                 {"MET_UINT", RP_U32},   {"MET_INT", RP_S32},
                 {"MET_FLOAT", RP_F32}};

/* What the header says beyond rp__volume_header, until all is read. */
typedef struct mhd_state {
  unsigned seen;
  int compressed;
  int64_t header_size;
  double matrix[9];
  double offset[3];
  char anatomy[4];
} mhd_state;

/* "True" or "False" (MetaIO also writes 1 and 0). */
static int parse_bool(rp_context *ctx, const char *name, const char *key,
                      const char *value, int *out) {
  char sv[64];
  if (rp__text_eq_nocase(value, "True") || strcmp(value, "1") == 0)
    *out = 1;
  else if (rp__text_eq_nocase(value, "False") || strcmp(value, "0") == 0)
    *out = 0;
  else
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: %s '%s' is neither True nor False", name, key,
                    rp__text_shown(sv, value));
  return 0;
}

/* Exactly n numbers, finite. */
static int parse_numbers(rp_context *ctx, const char *name, const char *key,
                         char *value, double *out, int n) {
  char sv[64], copy[RP__MAX_LINE + 1];
  char *cursor = value, *tok;
  int i = 0;
  snprintf(copy, sizeof copy, "%s", value);
  while ((tok = rp__text_token(&cursor)) != NULL) {
    if (i == n || !rp__text_double(tok, &out[i]))
      return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s' is not %d numbers",
                      name, key, rp__text_shown(sv, copy), n);
    if (!isfinite(out[i]))
      return rp__fail(ctx, RP_ENOTFINITE, "%s: %s '%s': value %d is not "
                      "finite", name, key, rp__text_shown(sv, copy), i);
    i++;
  }
  if (i != n)
    return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s' is not %d numbers", name,
                    key, rp__text_shown(sv, copy), n);
  return 0;
}

static int parse_element_type(rp_context *ctx, const char *name,
                              const char *value, rp_voxel_type *type) {
  char sv[64];
  size_t i;
  for (i = 0; i < sizeof mhd_types / sizeof mhd_types[0]; i++) {
    if (rp__text_eq_nocase(value, mhd_types[i].name)) {
      *type = mhd_types[i].type;
      return 0;
    }
  }
  return rp__fail(ctx, RP_EUNSUPPORTED,
                  "%s: ElementType '%s' is not supported (accepted: "
                  "MET_UCHAR, MET_CHAR, MET_USHORT, MET_SHORT, MET_UINT, "
                  "MET_INT, MET_FLOAT)",
                  name, rp__text_shown(sv, value));
}

/* ElementDataFile: LOCAL, or one file; several files are refused. */
static int parse_data_file(rp_context *ctx, const char *name, char *value,
                           rp__volume_header *hdr) {
  char sv[64];
  if (strcmp(value, "LOCAL") == 0)
    return 0;
  if (strncmp(value, "LIST", 4) == 0 &&
      (value[4] == '\0' || value[4] == ' ' || value[4] == '\t'))
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: ElementDataFile 'LIST' (one file per slice) is not "
                    "supported",
                    name);
  if (strchr(value, '%') != NULL)
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: ElementDataFile '%s' (a pattern for several files) "
                    "is not supported",
                    name, rp__text_shown(sv, value));
  return rp__header_data_file(ctx, name, "ElementDataFile", value, hdr);
}

/* One key this loader uses. `value` is modified. */
static int mhd_key(rp_context *ctx, const char *name, unsigned bit,
                   const char *key, char *value, rp__volume_header *hdr,
                   mhd_state *st) {
  char sv[64];
  char num[32];
  double v[3] = {0, 0, 0};
  int64_t n;
  int flag = 0, rc, a;
  switch (bit) {
  case K_OBJECT:
    if (!rp__text_eq_nocase(value, "Image"))
      return rp__fail(ctx, RP_EUNSUPPORTED,
                      "%s: ObjectType '%s' is not supported (only Image)",
                      name, rp__text_shown(sv, value));
    return 0;
  case K_NDIMS:
  case K_CHANNELS:
    if (!rp__text_i64(value, &n) || n < 1)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: %s '%s' is not a positive integer", name, key,
                      rp__text_shown(sv, value));
    if (n != (bit == K_NDIMS ? 3 : 1))
      return rp__fail(ctx, RP_EUNSUPPORTED,
                      "%s: %s %lld is not supported (only %d)", name, key,
                      (long long)n, bit == K_NDIMS ? 3 : 1);
    return 0;
  case K_DIMSIZE:
    return rp__header_sizes(ctx, name, key, value, hdr->dims);
  case K_TYPE:
    return parse_element_type(ctx, name, value, &hdr->type);
  case K_SPACING:
    if ((rc = parse_numbers(ctx, name, key, value, v, 3)) != 0)
      return rc;
    for (a = 0; a < 3; a++) {
      snprintf(num, sizeof num, "%g", v[a]);
      if ((rc = rp__header_spacing(ctx, name, key, a, num, v[a],
                                   &hdr->spacing[a])) != 0)
        return rc;
    }
    return 0;
  case K_MSB:
    return parse_bool(ctx, name, key, value, &hdr->big_endian);
  case K_BINARY:
    if ((rc = parse_bool(ctx, name, key, value, &flag)) != 0)
      return rc;
    return flag ? 0
                : rp__fail(ctx, RP_EUNSUPPORTED,
                           "%s: BinaryData False (voxels as text) is not "
                           "supported",
                           name);
  case K_HEADERSIZE:
    if (!rp__text_i64(value, &n) || n < -1)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: HeaderSize '%s' is not -1 or a whole number",
                      name, rp__text_shown(sv, value));
    st->header_size = n;
    return 0;
  case K_COMPRESSED:
    return parse_bool(ctx, name, key, value, &st->compressed);
  case K_COMPSIZE:
    if (!rp__text_u64(value, &hdr->payload_bytes) || hdr->payload_bytes == 0)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: CompressedDataSize '%s' is not a positive whole "
                      "number",
                      name, rp__text_shown(sv, value));
    return 0;
  case K_DATAFILE:
    return parse_data_file(ctx, name, value, hdr);
  case K_MATRIX:
    return parse_numbers(ctx, name, key, value, st->matrix, 9);
  case K_OFFSET:
    return parse_numbers(ctx, name, key, value, st->offset, 3);
  case K_ANATOMY:
    if (strlen(value) != 3)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: AnatomicalOrientation '%s' is not three letters",
                      name, rp__text_shown(sv, value));
    memcpy(st->anatomy, value, 4);
    return 0;
  default: /* K_IGNORED */
    return 0;
  }
}

/* The unit vector, in LPS, of an axis that AnatomicalOrientation says
 * comes from `letter`: it points the other way. 0 for '?' (not known),
 * -1 for a letter that is not a direction. */
static int anatomy_axis(char letter, double v[3]) {
  static const char from[6] = {'R', 'L', 'A', 'P', 'I', 'S'};
  int k;
  v[0] = v[1] = v[2] = 0.0;
  if (letter == '?')
    return 0;
  for (k = 0; k < 6; k++) {
    if ((letter & ~0x20) == from[k]) {
      v[k / 2] = k % 2 == 0 ? 1.0 : -1.0;
      return 1;
    }
  }
  return -1;
}

/* The orientation, once all keys are read. */
static int mhd_orientation(rp_context *ctx, const char *name,
                           const mhd_state *st, rp__volume_header *hdr) {
  char what[1100], sv[64];
  rp_orientation o;
  int a, nonzero = 0, known = 0, r;
  memset(&o, 0, sizeof o);
  for (a = 0; a < 9; a++)
    nonzero |= st->matrix[a] != 0.0;
  if (nonzero) {
    memcpy(o.direction, st->matrix, sizeof o.direction);
    snprintf(what, sizeof what, "%s: TransformMatrix", name);
  } else if (st->seen & K_ANATOMY) {
    for (a = 0; a < 3; a++) {
      r = anatomy_axis(st->anatomy[a], &o.direction[3 * a]);
      if (r < 0)
        return rp__fail(ctx, RP_EFORMAT,
                        "%s: AnatomicalOrientation '%s': '%c' is not one of "
                        "R, L, A, P, I, S",
                        name, rp__text_shown(sv, st->anatomy),
                        st->anatomy[a]);
      known += r;
    }
    if (known > 0 && known < 3)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: AnatomicalOrientation '%s' names some axes only",
                      name, rp__text_shown(sv, st->anatomy));
    if (known == 0)
      return 0;
    snprintf(what, sizeof what, "%s: AnatomicalOrientation", name);
  } else {
    return 0;
  }
  o.known = 1;
  memcpy(o.origin, st->offset, sizeof o.origin);
  return rp__orientation_check(ctx, what, &o, &hdr->orientation);
}

static unsigned mhd_key_bit(const char *key) {
  size_t i;
  for (i = 0; i < sizeof mhd_keys / sizeof mhd_keys[0]; i++)
    if (rp__text_eq_nocase(key, mhd_keys[i].name))
      return mhd_keys[i].bit;
  return 0;
}

/* What follows ElementDataFile, and the checks that need all keys. */
static int mhd_finish(rp_context *ctx, const char *name, mhd_state *st,
                      rp__volume_header *h) {
  static const struct {
    unsigned bit;
    const char *name;
  } required[] = {{K_NDIMS, "NDims"},
                  {K_DIMSIZE, "DimSize"},
                  {K_TYPE, "ElementType"},
                  {K_DATAFILE, "ElementDataFile"}};
  size_t i, bytes = 0;
  int rc;
  for (i = 0; i < sizeof required / sizeof required[0]; i++)
    if (!(st->seen & required[i].bit))
      return rp__fail(ctx, RP_EFORMAT, "%s: missing key '%s'", name,
                      required[i].name);
  h->gzip = st->compressed;
  if (st->compressed && st->header_size != 0)
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: HeaderSize %lld with CompressedData True is not "
                    "supported",
                    name, (long long)st->header_size);
  if ((st->seen & K_COMPSIZE) && !st->compressed)
    h->payload_bytes = 0; /* MetaIO ignores it for raw data too */
  /* HeaderSize is about a detached file; MetaIO reads LOCAL data right
   * after the header whatever it says. */
  if (h->data_file[0] != '\0') {
    h->skip_to_end = st->header_size == -1;
    h->byte_skip = st->header_size > 0 ? (uint64_t)st->header_size : 0;
  }
  if ((rc = mhd_orientation(ctx, name, st, h)) != 0)
    return rc;
  return rp__volume_header_check(ctx, name, &rp__mhd_fields_named, h,
                                 &bytes);
}

const rp__header_fields rp__mhd_fields_named = {"DimSize",
                                                "ElementSpacing"};

int rp__mhd_parse(rp_context *ctx, const char *name, const uint8_t *buf,
                  size_t len, rp__volume_header *hdr, size_t *header_len) {
  char line[RP__MAX_LINE + 1], sv[64];
  rp__line_reader lr;
  rp__volume_header h;
  mhd_state st;
  int rc = 0;

  if (ctx == NULL)
    return RP_EINVAL;
  if (name == NULL)
    name = "(memory)";
  if ((buf == NULL && len > 0) || hdr == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: rp__mhd_parse: NULL argument",
                    name);
  memset(&lr, 0, sizeof lr);
  lr.buf = buf;
  lr.len = len;
  memset(&st, 0, sizeof st);
  rp__volume_header_init(&h);
  while (!(st.seen & K_DATAFILE) &&
         (rc = rp__text_line(ctx, name, &lr, line)) > 0) {
    char *eq, *key, *value = rp__text_trim(line);
    unsigned bit;
    if (value[0] == '\0')
      continue;
    eq = strchr(line, '=');
    if (eq == NULL)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: line %u '%s' is not 'Key = Value'", name,
                      lr.number, rp__text_shown(sv, value));
    *eq = '\0';
    key = rp__text_trim(line);
    value = rp__text_trim(eq + 1);
    bit = mhd_key_bit(key);
    if (bit == 0)
      continue;
    if ((st.seen & bit) && bit != K_IGNORED)
      return rp__fail(ctx, RP_EFORMAT, "%s: key '%s' appears twice", name,
                      rp__text_shown(sv, key));
    st.seen |= bit;
    if ((rc = mhd_key(ctx, name, bit, key, value, &h, &st)) != 0)
      return rc;
  }
  if (rc < 0)
    return rc;
  if ((rc = mhd_finish(ctx, name, &st, &h)) != 0)
    return rc;
  *hdr = h;
  if (header_len != NULL)
    *header_len = lr.pos;
  return 0;
}

int rp__looks_like_mhd(const char *path, const uint8_t *buf, size_t len) {
  static const char *const keys[] = {"ObjectType", "NDims"};
  size_t n = strlen(path), k, pos = 0;
  if (n >= 4 && (rp__text_eq_nocase(path + n - 4, ".mhd") ||
                 rp__text_eq_nocase(path + n - 4, ".mha")))
    return 1;
  /* Otherwise by its first key, as ITK tells MetaImage apart. */
  while (pos < len && (buf[pos] == ' ' || buf[pos] == '\t' ||
                       buf[pos] == '\r' || buf[pos] == '\n'))
    pos++;
  for (k = 0; k < sizeof keys / sizeof keys[0]; k++) {
    size_t kl = strlen(keys[k]), q = pos + kl;
    if (len - pos < kl || memcmp(buf + pos, keys[k], kl) != 0)
      continue;
    while (q < len && (buf[q] == ' ' || buf[q] == '\t'))
      q++;
    if (q < len && buf[q] == '=')
      return 1;
  }
  return 0;
}
