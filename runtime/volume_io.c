/* Volume files: NRRD (attached or detached header, raw or gzip encoding),
 * the raypace sidecar ("key: value" lines naming a raw file) and raw files
 * whose name carries dims and type (NAME_XxYxZ_TYPE.raw).
 *
 * The parsers and the decoder work on memory with an explicit length, never
 * on NUL-terminated text, so that fuzz targets reach them without files;
 * only rp_volume_load touches the file system. Every failure goes through
 * rp__fail with the file, the field and the value, and leaves *out alone.
 *
 * rp_volume_load tells the formats apart in this order: a .raw file by its
 * name (its bytes can be anything, "NRRD" included); NRRD by its magic
 * "NRRD" at byte 0; a sidecar by at least two of the lines "file:", "dims:"
 * and "type:". Only regular files are opened: a FIFO would block.
 *
 * Policy decisions (tests/test_volume_io.c holds us to them):
 * - A size of 0 is RP_ERANGE, like a product too large for size_t or for
 *   the context's max_volume_bytes.
 * - Data must fill the file exactly: fewer bytes than the sizes need is
 *   RP_ETRUNC, more is RP_EFORMAT. The only way to ignore leading bytes is
 *   NRRD's "byte skip" (-1: the payload is the file's last bytes) and
 *   "line skip". For gzip the stream must end with the data, and nothing
 *   may follow it; "line skip" counts lines of the file before the
 *   stream, "byte skip" bytes of the inflated data (as teem reads them),
 *   and -1 is for raw data only.
 * - Lines are at most MAX_LINE bytes; a longer one is RP_EFORMAT. */
#define ZLIB_CONST
#include <errno.h>
#include <fcntl.h>
#include <float.h>
#include <limits.h>
#include <locale.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>
#include <zlib.h>

#include "internal.h"

#define MAX_LINE 4096
/* Bytes read from the start of a file to recognise it; an NRRD header or a
 * sidecar must fit in them. */
#define HEAD_MAX ((size_t)1 << 20)
/* Read and inflate granularity. */
#define CHUNK ((size_t)64 << 10)

/* Calls to inflate() made by this thread, which only tests read: they hold
 * the decoder to a bounded number of calls per inflated byte. Thread-local,
 * so that concurrent loads do not race on it. */
extern _Thread_local unsigned long rp__inflate_calls;
_Thread_local unsigned long rp__inflate_calls;

/* Fields whose repetition is an error, one bit each. */
enum {
  F_TYPE = 1 << 0,
  F_DIMENSION = 1 << 1,
  F_SIZES = 1 << 2,
  F_ENDIAN = 1 << 3,
  F_ENCODING = 1 << 4,
  F_SPACINGS = 1 << 5,
  F_DIRECTIONS = 1 << 6,
  F_DATA_FILE = 1 << 7,
  F_BYTE_SKIP = 1 << 8,
  F_LINE_SKIP = 1 << 9,
  F_BYTES = 1 << 10
};

typedef struct field_name {
  const char *name;
  unsigned bit;
} field_name;

typedef struct type_name {
  const char *name;
  rp_voxel_type type;
} type_name;

/* How each format names a header's sizes and spacing, so that a message
 * about them points at the text the user wrote. */
typedef struct header_fields {
  const char *dims;
  const char *spacing;
} header_fields;

static const header_fields nrrd_fields_named = {"field 'sizes'",
                                                "field 'spacings'"};
static const header_fields sidecar_fields_named = {"field 'dims'",
                                                   "field 'spacing'"};
static const header_fields raw_fields_named = {"the dims in the file name",
                                               "field 'spacing'"};
/* A header handed to rp__volume_decode: its struct's own field names. */
static const header_fields memory_fields_named = {"field 'dims'",
                                                  "field 'spacing'"};

/* ---- Text helpers ------------------------------------------------------ */

/* Character classes by hand: <ctype.h> depends on the locale and is
 * undefined for negative chars. */
static int is_space(int c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

static int is_digit(int c) { return c >= '0' && c <= '9'; }

static int to_lower(int c) { return c >= 'A' && c <= 'Z' ? c - 'A' + 'a' : c; }

static int eq_nocase(const char *a, const char *b) {
  while (*a != '\0' && to_lower((unsigned char)*a) ==
                           to_lower((unsigned char)*b)) {
    a++;
    b++;
  }
  return *a == '\0' && *b == '\0';
}

/* Strips spaces at both ends, in place. */
static char *trim(char *s) {
  size_t n;
  while (is_space((unsigned char)*s))
    s++;
  n = strlen(s);
  while (n > 0 && is_space((unsigned char)s[n - 1]))
    s[--n] = '\0';
  return s;
}

/* Splits off the next space-separated token, in place; NULL when none. */
static char *next_token(char **cursor) {
  char *s = *cursor, *tok;
  while (is_space((unsigned char)*s))
    s++;
  if (*s == '\0') {
    *cursor = s;
    return NULL;
  }
  tok = s;
  while (*s != '\0' && !is_space((unsigned char)*s))
    s++;
  if (*s != '\0')
    *s++ = '\0';
  *cursor = s;
  return tok;
}

/* A short, printable copy of `s` for an error message, so that a binary
 * file cannot fill the message or the user's terminal with garbage. */
static const char *shown(char buf[64], const char *s) {
  size_t i;
  for (i = 0; s[i] != '\0' && i < 48; i++) {
    unsigned char c = (unsigned char)s[i];
    buf[i] = c >= 0x20 && c < 0x7f ? (char)c : '?';
  }
  if (s[i] != '\0') {
    memcpy(buf + i, "...", 3);
    i += 3;
  }
  buf[i] = '\0';
  return buf;
}

/* A decimal integer filling the whole token, without sign. */
static int parse_u64(const char *s, uint64_t *v) {
  uint64_t x = 0;
  if (*s == '\0')
    return 0;
  for (; *s != '\0'; s++) {
    unsigned d;
    if (!is_digit((unsigned char)*s))
      return 0;
    d = (unsigned)(*s - '0');
    if (x > (UINT64_MAX - d) / 10)
      return 0;
    x = x * 10 + d;
  }
  *v = x;
  return 1;
}

/* A decimal integer with an optional sign, filling the whole token. */
static int parse_i64(const char *s, int64_t *v) {
  uint64_t mag;
  int neg = *s == '-';
  if (*s == '-' || *s == '+')
    s++;
  if (!parse_u64(s, &mag) || mag > (uint64_t)INT64_MAX)
    return 0;
  *v = neg ? -(int64_t)mag : (int64_t)mag;
  return 1;
}

/* A floating-point number filling the whole token. strtod reads the
 * decimal point of the current locale, which a host application may have
 * changed, so the token's '.' is translated first; NaN and infinities are
 * accepted here and rejected by the callers with RP_ENOTFINITE. */
static int parse_double(const char *s, double *v) {
  char tmp[64];
  const char *dp = localeconv()->decimal_point;
  size_t n = strlen(s);
  char *end;
  if (n == 0 || n >= sizeof tmp)
    return 0;
  memcpy(tmp, s, n + 1);
  if (dp != NULL && dp[0] != '\0' && dp[0] != '.' && dp[1] == '\0') {
    char *p;
    if (strchr(tmp, dp[0]) != NULL)
      return 0;
    for (p = tmp; *p != '\0'; p++)
      if (*p == '.')
        *p = dp[0];
  }
  *v = strtod(tmp, &end);
  return end != tmp && *end == '\0';
}

static const char *type_label(rp_voxel_type type) {
  switch (type) {
  case RP_U8: return "uint8";
  case RP_U16: return "uint16";
  case RP_F32: return "float32";
  default: return "?";
  }
}

/* "AxBxC type" of a header, for messages. */
static const char *dims_text(char buf[96], const rp__volume_header *hdr) {
  snprintf(buf, 96, "%llux%llux%llu %s", (unsigned long long)hdr->dims[0],
           (unsigned long long)hdr->dims[1], (unsigned long long)hdr->dims[2],
           type_label(hdr->type));
  return buf;
}

/* ---- Lines of a memory buffer ------------------------------------------ */

typedef struct line_reader {
  const uint8_t *buf;
  size_t len, pos;
  unsigned number; /* of the last line returned, from 1 */
} line_reader;

/* Copies the next line into `out` as a C string, without its "\n" or
 * "\r\n". Returns 1 with a line, 0 at the end of the buffer, or an error:
 * lines longer than MAX_LINE and lines holding a NUL byte are malformed. */
static int next_line(rp_context *ctx, const char *name, line_reader *lr,
                     char out[MAX_LINE + 1]) {
  const uint8_t *start = lr->buf + lr->pos;
  const uint8_t *nl;
  size_t n, rest;
  out[0] = '\0';
  if (lr->pos >= lr->len)
    return 0;
  rest = lr->len - lr->pos;
  nl = memchr(start, '\n', rest);
  n = nl != NULL ? (size_t)(nl - start) : rest;
  lr->pos += nl != NULL ? n + 1 : n;
  lr->number++;
  if (n > 0 && start[n - 1] == '\r')
    n--;
  if (n > MAX_LINE)
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: line %u is longer than %d bytes", name, lr->number,
                    MAX_LINE);
  if (memchr(start, '\0', n) != NULL)
    return rp__fail(ctx, RP_EFORMAT, "%s: line %u holds a NUL byte", name,
                    lr->number);
  memcpy(out, start, n);
  out[n] = '\0';
  return 1;
}

/* ---- Field values -------------------------------------------------------- */

static int parse_type(rp_context *ctx, const char *name, const char *field,
                      const char *value, const type_name *names,
                      const char *accepted, rp_voxel_type *type) {
  char sv[64];
  for (; names->name != NULL; names++) {
    if (eq_nocase(value, names->name)) {
      *type = names->type;
      return 0;
    }
  }
  return rp__fail(ctx, RP_EUNSUPPORTED,
                  "%s: %s '%s' is not supported (accepted: %s)", name, field,
                  shown(sv, value), accepted);
}

static int parse_endian(rp_context *ctx, const char *name, const char *field,
                        const char *value, int *big) {
  char sv[64];
  if (eq_nocase(value, "little"))
    *big = 0;
  else if (eq_nocase(value, "big"))
    *big = 1;
  else
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: %s '%s' is neither 'little' nor 'big'", name, field,
                    shown(sv, value));
  return 0;
}

/* Exactly three sizes, each at least 1. */
static int parse_sizes(rp_context *ctx, const char *name, const char *field,
                       char *value, uint64_t dims[3]) {
  char sv[64], copy[MAX_LINE + 1];
  char *cursor = value, *tok;
  int n = 0;
  snprintf(copy, sizeof copy, "%s", value);
  while ((tok = next_token(&cursor)) != NULL) {
    if (n == 3 || !parse_u64(tok, &dims[n]))
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: %s '%s' is not three whole numbers", name, field,
                      shown(sv, copy));
    if (dims[n] == 0)
      return rp__fail(ctx, RP_ERANGE,
                      "%s: %s '%s': every size must be at least 1", name,
                      field, shown(sv, copy));
    n++;
  }
  if (n != 3)
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: %s '%s' is not three whole numbers", name, field,
                    shown(sv, copy));
  return 0;
}

/* A voxel spacing must be a positive, finite float. `text` is what the
 * file says for `axis`: a number, or a vector whose length is v. */
static int check_spacing(rp_context *ctx, const char *name, const char *field,
                         int axis, const char *text, double v, float *out) {
  char sv[64];
  float f;
  if (!isfinite(v))
    return rp__fail(ctx, RP_ENOTFINITE,
                    "%s: field '%s': axis %d value '%s' is not finite", name,
                    field, axis, shown(sv, text));
  if (!(v > 0.0) || v > FLT_MAX)
    return rp__fail(ctx, RP_ERANGE,
                    "%s: field '%s': axis %d value '%s' is not a positive "
                    "float",
                    name, field, axis, shown(sv, text));
  f = (float)v;
  if (!(f > 0.0f))
    return rp__fail(ctx, RP_ERANGE,
                    "%s: field '%s': axis %d value '%s' is too small", name,
                    field, axis, shown(sv, text));
  *out = f;
  return 0;
}

static int parse_spacings(rp_context *ctx, const char *name,
                          const char *field, char *value, float spacing[3]) {
  char sv[64], copy[MAX_LINE + 1];
  char *cursor = value, *tok;
  int n = 0, rc;
  double v;
  snprintf(copy, sizeof copy, "%s", value);
  while ((tok = next_token(&cursor)) != NULL) {
    if (n == 3 || !parse_double(tok, &v))
      return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s' is not three numbers",
                      name, field, shown(sv, copy));
    if ((rc = check_spacing(ctx, name, field, n, tok, v, &spacing[n])) !=
        0)
      return rc;
    n++;
  }
  if (n != 3)
    return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s' is not three numbers",
                    name, field, shown(sv, copy));
  return 0;
}

/* NRRD "space directions: (a,b,c) (d,e,f) (g,h,i)": one vector per axis in
 * world space, whose length is that axis's spacing. "none" marks a
 * non-spatial axis, which a 3D volume cannot have. */
static int parse_directions(rp_context *ctx, const char *name,
                            const char *field, const char *value,
                            float spacing[3]) {
  char sv[64], comp[64], vec[64];
  const char *p = value;
  int axis, ncomp_first = 0, rc;
  for (axis = 0; axis < 3; axis++) {
    const char *close;
    double sum = 0.0;
    int ncomp = 0;
    size_t vn;
    while (is_space((unsigned char)*p))
      p++;
    if (*p != '(')
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: %s '%s': axis %d is not a vector '(x,y,z)'", name,
                      field, shown(sv, value), axis);
    close = strchr(p, ')');
    if (close == NULL)
      return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s': missing ')'", name,
                      field, shown(sv, value));
    /* This axis's vector, for a message about its length. */
    vn = (size_t)(close - p) + 1;
    if (vn >= sizeof vec)
      vn = sizeof vec - 1;
    memcpy(vec, p, vn);
    vec[vn] = '\0';
    p++;
    while (p <= close) {
      const char *end = p;
      size_t n;
      double v;
      while (end < close && *end != ',')
        end++;
      n = (size_t)(end - p);
      if (n >= sizeof comp)
        n = sizeof comp - 1; /* a cut number fails to parse below */
      memcpy(comp, p, n);
      comp[n] = '\0';
      if (!parse_double(trim(comp), &v) || ncomp == 16)
        return rp__fail(ctx, RP_EFORMAT,
                        "%s: %s '%s': axis %d is not a vector of numbers",
                        name, field, shown(sv, value), axis);
      if (!isfinite(v))
        return rp__fail(ctx, RP_ENOTFINITE,
                        "%s: %s '%s': axis %d is not finite", name, field,
                        shown(sv, value), axis);
      sum += v * v;
      ncomp++;
      p = end + 1;
    }
    if (axis == 0)
      ncomp_first = ncomp;
    else if (ncomp != ncomp_first)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: %s '%s': vectors differ in length", name, field,
                      shown(sv, value));
    if ((rc = check_spacing(ctx, name, field, axis, vec, sqrt(sum),
                            &spacing[axis])) != 0)
      return rc;
  }
  while (is_space((unsigned char)*p))
    p++;
  if (*p != '\0')
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: %s '%s' has more than three vectors", name, field,
                    shown(sv, value));
  return 0;
}

static int set_data_file(rp_context *ctx, const char *name, const char *field,
                         const char *value, rp__volume_header *hdr) {
  char sv[64];
  size_t n = strlen(value);
  if (n == 0)
    return rp__fail(ctx, RP_EFORMAT, "%s: %s is empty", name, field);
  if (n >= sizeof hdr->data_file)
    return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s' is too long", name, field,
                    shown(sv, value));
  memcpy(hdr->data_file, value, n + 1);
  return 0;
}

/* Sizes, type and spacing of a header, then the byte size against the
 * context's limit. Shared by the parsers and the decoder, which may be
 * handed a header that no parser produced. Messages name the field as
 * `fields` says the format calls it. */
static int check_header(rp_context *ctx, const char *name,
                        const header_fields *fields,
                        const rp__volume_header *hdr, size_t *bytes) {
  size_t voxels;
  int i;
  for (i = 0; i < 3; i++)
    if (!isfinite(hdr->spacing[i]) || !(hdr->spacing[i] > 0.0f))
      return rp__fail(ctx, RP_ERANGE,
                      "%s: %s: axis %d value %g must be positive and finite",
                      name, fields->spacing, i, (double)hdr->spacing[i]);
  if (memchr(hdr->data_file, '\0', sizeof hdr->data_file) == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: data file name is not terminated",
                    name);
  /* The type first, so that rp__volume_size's messages are about sizes
   * only and `what` can name the sizes' field. */
  if (rp__voxel_size(hdr->type) == 0)
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: field 'type': value %d is not a voxel type", name,
                    (int)hdr->type);
  /* Sizes of at least 1 and below 2^32, and the byte limit. */
  return rp__volume_size(ctx, name, fields->dims, hdr->dims, hdr->type,
                         &voxels, bytes);
}

static void header_init(rp__volume_header *hdr) {
  memset(hdr, 0, sizeof *hdr);
  hdr->spacing[0] = hdr->spacing[1] = hdr->spacing[2] = 1.0f;
}

/* ---- NRRD ---------------------------------------------------------------- */

static const type_name nrrd_types[] = {
    {"uchar", RP_U8},           {"unsigned char", RP_U8},
    {"uint8", RP_U8},           {"uint8_t", RP_U8},
    {"ushort", RP_U16},         {"unsigned short", RP_U16},
    {"unsigned short int", RP_U16}, {"uint16", RP_U16},
    {"uint16_t", RP_U16},       {"float", RP_F32},
    {NULL, RP_U8}};

static const field_name nrrd_fields[] = {
    {"type", F_TYPE},           {"dimension", F_DIMENSION},
    {"sizes", F_SIZES},         {"endian", F_ENDIAN},
    {"encoding", F_ENCODING},   {"spacings", F_SPACINGS},
    {"space directions", F_DIRECTIONS},
    {"data file", F_DATA_FILE}, {"datafile", F_DATA_FILE},
    {"byte skip", F_BYTE_SKIP}, {"byteskip", F_BYTE_SKIP},
    {"line skip", F_LINE_SKIP}, {"lineskip", F_LINE_SKIP},
    {NULL, 0}};

static unsigned field_bit(const field_name *fields, const char *field) {
  for (; fields->name != NULL; fields++)
    if (eq_nocase(field, fields->name))
      return fields->bit;
  return 0;
}

/* One NRRD field this loader uses. `value` is modified. */
static int nrrd_field(rp_context *ctx, const char *name, unsigned bit,
                      const char *field, char *value, rp__volume_header *hdr) {
  char sv[64];
  int64_t n;
  switch (bit) {
  case F_TYPE:
    return parse_type(ctx, name, "type", value, nrrd_types,
                      "uchar, ushort, float and their aliases", &hdr->type);
  case F_DIMENSION:
    if (!parse_i64(value, &n) || n < 1)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: dimension '%s' is not a positive integer", name,
                      shown(sv, value));
    if (n != 3)
      return rp__fail(ctx, RP_EUNSUPPORTED,
                      "%s: dimension %lld is not supported (only 3)", name,
                      (long long)n);
    return 0;
  case F_SIZES:
    return parse_sizes(ctx, name, "sizes", value, hdr->dims);
  case F_ENDIAN:
    return parse_endian(ctx, name, "endian", value, &hdr->big_endian);
  case F_ENCODING:
    if (eq_nocase(value, "raw"))
      hdr->gzip = 0;
    else if (eq_nocase(value, "gzip") || eq_nocase(value, "gz"))
      hdr->gzip = 1;
    else
      return rp__fail(ctx, RP_EUNSUPPORTED,
                      "%s: encoding '%s' is not supported (raw, gzip)", name,
                      shown(sv, value));
    return 0;
  case F_SPACINGS:
    return parse_spacings(ctx, name, "spacings", value, hdr->spacing);
  case F_DIRECTIONS:
    return parse_directions(ctx, name, "space directions", value,
                            hdr->spacing);
  case F_DATA_FILE:
    /* "LIST" and "<format> <min> <max> <step>" name several files, one
     * slice each: this loader reads a single file. */
    if (strncmp(value, "LIST", 4) == 0 &&
        (value[4] == '\0' || is_space((unsigned char)value[4])))
      return rp__fail(ctx, RP_EUNSUPPORTED,
                      "%s: %s 'LIST' (several files) is not supported", name,
                      field);
    if (strchr(value, '%') != NULL)
      return rp__fail(ctx, RP_EUNSUPPORTED,
                      "%s: %s '%s' (a format for several files) is not "
                      "supported",
                      name, field, shown(sv, value));
    return set_data_file(ctx, name, field, value, hdr);
  case F_BYTE_SKIP:
    if (!parse_i64(value, &n))
      return rp__fail(ctx, RP_EFORMAT, "%s: byte skip '%s' is not an integer",
                      name, shown(sv, value));
    if (n < -1)
      return rp__fail(ctx, RP_ERANGE,
                      "%s: byte skip %lld must be -1 or more", name,
                      (long long)n);
    hdr->skip_to_end = n == -1;
    hdr->byte_skip = n == -1 ? 0 : (uint64_t)n;
    return 0;
  case F_LINE_SKIP:
    if (!parse_i64(value, &n))
      return rp__fail(ctx, RP_EFORMAT, "%s: line skip '%s' is not an integer",
                      name, shown(sv, value));
    if (n < 0)
      return rp__fail(ctx, RP_ERANGE, "%s: line skip %lld must be 0 or more",
                      name, (long long)n);
    hdr->line_skip = (uint64_t)n;
    return 0;
  default:
    return 0;
  }
}

/* The magic line: "NRRD000N" with N from 1 to 5. */
static int nrrd_magic(rp_context *ctx, const char *name, const char *line) {
  char sv[64];
  if (strlen(line) == 8 && memcmp(line, "NRRD000", 7) == 0 &&
      is_digit((unsigned char)line[7])) {
    if (line[7] >= '1' && line[7] <= '5')
      return 0;
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: NRRD version '%s' is not supported (NRRD0001 to "
                    "NRRD0005)",
                    name, shown(sv, line));
  }
  return rp__fail(ctx, RP_EFORMAT,
                  "%s: magic '%s' is not NRRD000N (N from 1 to 5)", name,
                  shown(sv, line));
}

int rp__nrrd_parse(rp_context *ctx, const char *name, const uint8_t *buf,
                   size_t len, rp__volume_header *hdr, size_t *header_len) {
  static const struct {
    unsigned bit;
    const char *name;
  } required[] = {{F_TYPE, "type"},
                  {F_DIMENSION, "dimension"},
                  {F_SIZES, "sizes"},
                  {F_ENCODING, "encoding"}};
  char line[MAX_LINE + 1] = "", sv[64];
  line_reader lr;
  rp__volume_header h;
  unsigned seen = 0;
  size_t end = len, bytes = 0, i;
  int rc;

  if (ctx == NULL)
    return RP_EINVAL;
  if (name == NULL)
    name = "(memory)";
  if ((buf == NULL && len > 0) || hdr == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: rp__nrrd_parse: NULL argument",
                    name);
  if (len < 4 || memcmp(buf, "NRRD", 4) != 0)
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: not an NRRD file (it does not start with 'NRRD')",
                    name);
  lr.buf = buf;
  lr.len = len;
  lr.pos = 0;
  lr.number = 0;
  if ((rc = next_line(ctx, name, &lr, line)) <= 0)
    return rc < 0 ? rc : rp__fail(ctx, RP_EFORMAT, "%s: no magic", name);
  if ((rc = nrrd_magic(ctx, name, line)) != 0)
    return rc;
  header_init(&h);
  for (;;) {
    char *colon, *field, *value;
    unsigned bit;
    rc = next_line(ctx, name, &lr, line);
    if (rc < 0)
      return rc;
    if (rc == 0)
      break; /* header without data: detached, or data missing */
    if (line[0] == '\0') {
      end = lr.pos; /* an attached payload starts after the empty line */
      break;
    }
    if (line[0] == '#')
      continue;
    colon = strchr(line, ':');
    if (colon == NULL)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: line %u '%s' is not 'field: value'", name,
                      lr.number, shown(sv, line));
    if (colon[1] == '=')
      continue; /* "key:=value" pairs carry nothing we use */
    *colon = '\0';
    field = trim(line);
    value = trim(colon + 1);
    bit = field_bit(nrrd_fields, field);
    if (bit == 0)
      continue; /* NRRD allows fields we do not need */
    if (seen & bit)
      return rp__fail(ctx, RP_EFORMAT, "%s: field '%s' appears twice", name,
                      shown(sv, field));
    seen |= bit;
    if ((rc = nrrd_field(ctx, name, bit, field, value, &h)) != 0)
      return rc;
  }
  for (i = 0; i < sizeof required / sizeof required[0]; i++)
    if (!(seen & required[i].bit))
      return rp__fail(ctx, RP_EFORMAT, "%s: missing field '%s'", name,
                      required[i].name);
  if (h.type != RP_U8 && !(seen & F_ENDIAN))
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: missing field 'endian' (needed for type %s)", name,
                    type_label(h.type));
  if ((seen & F_SPACINGS) && (seen & F_DIRECTIONS))
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: fields 'spacings' and 'space directions' exclude "
                    "each other",
                    name);
  if (h.skip_to_end && h.gzip)
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: byte skip -1 needs raw encoding, not gzip", name);
  if ((rc = check_header(ctx, name, &nrrd_fields_named, &h, &bytes)) != 0)
    return rc;
  *hdr = h;
  if (header_len != NULL)
    *header_len = end;
  return 0;
}

/* ---- Sidecar ------------------------------------------------------------- */

static const type_name plain_types[] = {
    {"uint8", RP_U8}, {"uint16", RP_U16}, {"float32", RP_F32}, {NULL, RP_U8}};

static const field_name sidecar_keys[] = {
    {"file", F_DATA_FILE}, {"dims", F_SIZES},     {"type", F_TYPE},
    {"endian", F_ENDIAN},  {"spacing", F_SPACINGS}, {"bytes", F_BYTES},
    {NULL, 0}};

int rp__sidecar_parse(rp_context *ctx, const char *name, const uint8_t *buf,
                      size_t len, rp__volume_header *hdr) {
  static const struct {
    unsigned bit;
    const char *name;
  } required[] = {{F_DATA_FILE, "file"}, {F_SIZES, "dims"}, {F_TYPE, "type"}};
  char line[MAX_LINE + 1], sv[64], dt[96];
  line_reader lr;
  rp__volume_header h;
  unsigned seen = 0;
  uint64_t declared = 0;
  size_t bytes = 0, i;
  int rc;

  if (ctx == NULL)
    return RP_EINVAL;
  if (name == NULL)
    name = "(memory)";
  if ((buf == NULL && len > 0) || hdr == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: rp__sidecar_parse: NULL argument",
                    name);
  lr.buf = buf;
  lr.len = len;
  lr.pos = 0;
  lr.number = 0;
  header_init(&h);
  while ((rc = next_line(ctx, name, &lr, line)) > 0) {
    char *colon, *key, *value = trim(line);
    unsigned bit;
    if (value[0] == '\0' || value[0] == '#')
      continue;
    colon = strchr(line, ':');
    if (colon == NULL)
      return rp__fail(ctx, RP_EFORMAT, "%s: line %u '%s' is not 'key: value'",
                      name, lr.number, shown(sv, value));
    *colon = '\0';
    key = trim(line);
    value = trim(colon + 1);
    bit = field_bit(sidecar_keys, key);
    if (bit == 0)
      continue; /* descriptive keys: min, max, mean, source, ... */
    if (seen & bit)
      return rp__fail(ctx, RP_EFORMAT, "%s: key '%s' appears twice", name,
                      shown(sv, key));
    seen |= bit;
    switch (bit) {
    case F_DATA_FILE:
      rc = set_data_file(ctx, name, "file", value, &h);
      break;
    case F_SIZES:
      rc = parse_sizes(ctx, name, "dims", value, h.dims);
      break;
    case F_TYPE:
      rc = parse_type(ctx, name, "type", value, plain_types,
                      "uint8, uint16, float32", &h.type);
      break;
    case F_ENDIAN:
      rc = parse_endian(ctx, name, "endian", value, &h.big_endian);
      break;
    case F_SPACINGS:
      rc = parse_spacings(ctx, name, "spacing", value, h.spacing);
      break;
    default: /* F_BYTES */
      rc = parse_u64(value, &declared)
               ? 0
               : rp__fail(ctx, RP_EFORMAT,
                          "%s: bytes '%s' is not a whole number", name,
                          shown(sv, value));
      break;
    }
    if (rc != 0)
      return rc;
  }
  if (rc < 0)
    return rc;
  for (i = 0; i < sizeof required / sizeof required[0]; i++)
    if (!(seen & required[i].bit))
      return rp__fail(ctx, RP_EFORMAT, "%s: missing key '%s'", name,
                      required[i].name);
  if ((rc = check_header(ctx, name, &sidecar_fields_named, &h, &bytes)) !=
      0)
    return rc;
  if ((seen & F_BYTES) && declared != (uint64_t)bytes)
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: bytes %llu disagrees with dims %s (%zu bytes)", name,
                    (unsigned long long)declared, dims_text(dt, &h), bytes);
  *hdr = h;
  return 0;
}

/* Whether a file's first bytes look like a sidecar: at least two of the
 * lines "file:", "dims:" and "type:", so that a sidecar missing one of them
 * still reaches the parser and gets a message naming the missing key. */
static int looks_like_sidecar(const uint8_t *buf, size_t len) {
  static const char keys[3][6] = {"file:", "dims:", "type:"};
  int found[3] = {0, 0, 0}, k;
  size_t pos = 0;
  while (pos < len) {
    const uint8_t *nl = memchr(buf + pos, '\n', len - pos);
    size_t end = nl != NULL ? (size_t)(nl - buf) : len;
    while (pos < end && is_space(buf[pos]))
      pos++;
    for (k = 0; k < 3; k++)
      if (end - pos >= 5 && memcmp(buf + pos, keys[k], 5) == 0)
        found[k] = 1;
    pos = end + 1;
  }
  return found[0] + found[1] + found[2] >= 2;
}

/* ---- NAME_XxYxZ_TYPE.raw ----------------------------------------------- */

/* "AxBxC" into dims; 0 when the text is not of that form. */
static int parse_dims_token(const char *s, size_t n, uint64_t dims[3]) {
  char tok[32];
  size_t i = 0;
  int axis;
  for (axis = 0; axis < 3; axis++) {
    size_t start = i;
    while (i < n && is_digit((unsigned char)s[i]))
      i++;
    if (i == start || i - start >= sizeof tok)
      return 0;
    memcpy(tok, s + start, i - start);
    tok[i - start] = '\0';
    if (!parse_u64(tok, &dims[axis]))
      return 0;
    if (axis < 2) {
      if (i == n || (s[i] != 'x' && s[i] != 'X'))
        return 0;
      i++;
    }
  }
  return i == n;
}

/* Fills hdr from a path whose file name is NAME_XxYxZ_TYPE.raw. Returns 0,
 * 1 when the name is not of that form (nothing recorded), or an error when
 * it is but its type or sizes are not acceptable. */
static int raw_name_parse(rp_context *ctx, const char *path,
                          rp__volume_header *hdr) {
  const char *base = strrchr(path, '/');
  const char *type_sep, *dims_sep, *p;
  char type[32];
  size_t n, stem, bytes;
  rp__volume_header h;
  int rc;
  base = base != NULL ? base + 1 : path;
  n = strlen(base);
  if (n < 4 || !eq_nocase(base + n - 4, ".raw"))
    return 1;
  stem = n - 4;
  type_sep = dims_sep = NULL;
  for (p = base; p < base + stem; p++) {
    if (*p == '_') {
      dims_sep = type_sep;
      type_sep = p;
    }
  }
  if (type_sep == NULL || dims_sep == NULL || dims_sep == base)
    return 1;
  header_init(&h);
  if (!parse_dims_token(dims_sep + 1, (size_t)(type_sep - dims_sep - 1),
                        h.dims))
    return 1;
  n = (size_t)(base + stem - type_sep - 1);
  if (n >= sizeof type)
    n = sizeof type - 1;
  memcpy(type, type_sep + 1, n);
  type[n] = '\0';
  if ((rc = parse_type(ctx, path, "type in the file name", type, plain_types,
                       "uint8, uint16, float32", &h.type)) != 0)
    return rc;
  if (h.dims[0] == 0 || h.dims[1] == 0 || h.dims[2] == 0)
    return rp__fail(ctx, RP_ERANGE,
                    "%s: sizes in the file name must be at least 1", path);
  if ((rc = check_header(ctx, path, &raw_fields_named, &h, &bytes)) != 0)
    return rc;
  *hdr = h;
  return 0;
}

/* ---- Decoding ------------------------------------------------------------ */

/* Where payload bytes come from: a memory buffer, or an open file whose
 * remaining size is known (from fstat) so that sizes are checked before
 * anything is allocated. */
typedef struct source {
  FILE *fp; /* NULL: memory */
  const uint8_t *mem;
  uint64_t left; /* bytes not consumed yet */
} source;

/* Reads up to n bytes; *got < n only at the end of the data. */
static int src_read(rp_context *ctx, const char *name, source *s, void *dst,
                    size_t n, size_t *got) {
  if (n > s->left)
    n = (size_t)s->left;
  if (s->fp == NULL) {
    memcpy(dst, s->mem, n);
    s->mem += n;
    *got = n;
  } else {
    *got = fread(dst, 1, n, s->fp);
    if (*got < n && ferror(s->fp))
      return rp__fail(ctx, RP_EIO, "%s: read error: %s", name,
                      strerror(errno));
    if (*got < n) {
      s->left = 0; /* shrank since fstat: report as truncated */
      return 0;
    }
  }
  s->left -= *got;
  return 0;
}

static int src_skip(rp_context *ctx, const char *name, source *s,
                    uint64_t n) {
  if (s->fp == NULL) {
    s->mem += n;
  } else if (n > 0) {
    /* n <= left <= the file size, which fits off_t. */
    if (fseeko(s->fp, (off_t)n, SEEK_CUR) != 0)
      return rp__fail(ctx, RP_EIO, "%s: seek error: %s", name,
                      strerror(errno));
  }
  s->left -= n;
  return 0;
}

/* Consumes `lines` lines, each up to and including its '\n'. */
static int src_skip_lines(rp_context *ctx, const char *name, source *s,
                          uint64_t lines) {
  uint64_t done;
  for (done = 0; done < lines; done++) {
    if (s->fp == NULL) {
      const uint8_t *nl = NULL;
      if (s->left > 0)
        nl = memchr(s->mem, '\n', s->left > SIZE_MAX ? SIZE_MAX
                                                     : (size_t)s->left);
      if (nl == NULL)
        break;
      src_skip(ctx, name, s, (uint64_t)(nl - s->mem) + 1);
    } else {
      int c = 0;
      while (s->left > 0 && (c = getc(s->fp)) != EOF) {
        s->left--;
        if (c == '\n')
          break;
      }
      if (c == EOF && ferror(s->fp))
        return rp__fail(ctx, RP_EIO, "%s: read error: %s", name,
                        strerror(errno));
      if (c != '\n')
        break;
    }
  }
  if (done < lines)
    return rp__fail(ctx, RP_ETRUNC,
                    "%s: line skip %llu goes past the end of the data (%llu "
                    "lines)",
                    name, (unsigned long long)lines,
                    (unsigned long long)done);
  return 0;
}

static int decode_raw(rp_context *ctx, const char *name,
                      const rp__volume_header *hdr, source *src,
                      size_t bytes, uint8_t **out) {
  char dt[96];
  uint8_t *data;
  size_t got;
  int rc;
  if (hdr->skip_to_end) {
    if (src->left < bytes)
      return rp__fail(ctx, RP_ETRUNC,
                      "%s: data truncated: %s needs %zu bytes, %llu present",
                      name, dims_text(dt, hdr), bytes,
                      (unsigned long long)src->left);
    if ((rc = src_skip(ctx, name, src, src->left - bytes)) != 0)
      return rc;
  } else {
    if (hdr->byte_skip > src->left)
      return rp__fail(ctx, RP_ETRUNC,
                      "%s: byte skip %llu goes past the end of the data (%llu "
                      "bytes)",
                      name, (unsigned long long)hdr->byte_skip,
                      (unsigned long long)src->left);
    if ((rc = src_skip(ctx, name, src, hdr->byte_skip)) != 0)
      return rc;
    if (src->left < bytes)
      return rp__fail(ctx, RP_ETRUNC,
                      "%s: data truncated: %s needs %zu bytes, %llu present",
                      name, dims_text(dt, hdr), bytes,
                      (unsigned long long)src->left);
    if (src->left > bytes)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: %llu bytes of data, but %s needs %zu: the sizes "
                      "do not match the data",
                      name, (unsigned long long)src->left,
                      dims_text(dt, hdr), bytes);
  }
  data = rp__malloc(ctx, bytes);
  if (data == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory for %zu bytes", name,
                    bytes);
  if ((rc = src_read(ctx, name, src, data, bytes, &got)) != 0 ||
      got < bytes) {
    rp__free(ctx, data);
    return rc != 0 ? rc
                   : rp__fail(ctx, RP_ETRUNC,
                              "%s: data truncated: read %zu of %zu bytes",
                              name, got, bytes);
  }
  *out = data;
  return 0;
}

/* zlib allocates through the context's allocator too. */
static voidpf z_alloc(voidpf opaque, uInt items, uInt size) {
  if (size != 0 && items > SIZE_MAX / size)
    return Z_NULL;
  return rp__malloc((rp_context *)opaque, (size_t)items * size);
}

static void z_free(voidpf opaque, voidpf ptr) {
  rp__free((rp_context *)opaque, ptr);
}

/* Inflates a gzip or zlib stream into exactly `bytes` bytes. The output
 * grows as data arrives (doubling, capped at `bytes`): a small file that
 * claims huge sizes runs out of input and fails with RP_ETRUNC long before
 * it could make us allocate what it claims. The byte skip is inflated into
 * a window of up to CHUNK bytes of its own: the output buffer of a tiny
 * volume would take one inflate call per skipped byte. */
static int decode_gzip(rp_context *ctx, const char *name,
                       const rp__volume_header *hdr, source *src,
                       size_t bytes, uint8_t **out) {
  enum { SKIP, FILL, SPILL };
  uint8_t spill[64];
  uint8_t *in = NULL, *data = NULL, *window = NULL;
  uint64_t skip = hdr->byte_skip;
  size_t cap, wcap, have = 0;
  int rc = 0, zrc, in_end = 0, inited = 0;
  z_stream zs;

  memset(&zs, 0, sizeof zs);
  zs.zalloc = z_alloc;
  zs.zfree = z_free;
  zs.opaque = ctx;
  cap = bytes < CHUNK ? bytes : CHUNK;
  data = rp__malloc(ctx, cap);
  if (src->fp != NULL)
    in = rp__malloc(ctx, CHUNK);
  /* The output buffer serves as the window when it is as large. */
  wcap = skip < CHUNK ? (size_t)skip : CHUNK;
  if (wcap > cap)
    window = rp__malloc(ctx, wcap);
  else
    wcap = cap;
  if (data == NULL || (src->fp != NULL && in == NULL) ||
      (wcap > cap && window == NULL)) {
    rc = rp__fail(ctx, RP_ENOMEM, "%s: out of memory", name);
    goto done;
  }
  /* 15 + 32: largest window, and accept either a gzip or a zlib header. */
  zrc = inflateInit2(&zs, 15 + 32);
  if (zrc != Z_OK) {
    rc = rp__fail(ctx, zrc == Z_MEM_ERROR ? RP_ENOMEM : RP_EIO,
                  "%s: cannot start zlib (%d)", name, zrc);
    goto done;
  }
  inited = 1;
  for (;;) {
    int mode;
    uInt before;
    if (zs.avail_in == 0 && !in_end) {
      if (src->fp == NULL) {
        size_t n = src->left > UINT_MAX ? UINT_MAX : (size_t)src->left;
        zs.next_in = src->mem;
        zs.avail_in = (uInt)n;
        src_skip(ctx, name, src, n);
      } else {
        size_t got;
        if ((rc = src_read(ctx, name, src, in, CHUNK, &got)) != 0)
          goto done;
        zs.next_in = in;
        zs.avail_in = (uInt)got;
      }
      in_end = src->left == 0;
    }
    if (skip > 0) {
      mode = SKIP; /* inflated bytes before the payload: discard */
      zs.next_out = window != NULL ? window : data;
      zs.avail_out = (uInt)(skip < wcap ? skip : wcap);
    } else if (have < cap) {
      mode = FILL;
      zs.next_out = data + have;
      zs.avail_out = (uInt)(cap - have > UINT_MAX ? UINT_MAX : cap - have);
    } else if (cap < bytes) {
      size_t ncap = cap > bytes / 2 ? bytes : cap * 2;
      uint8_t *grown = rp__malloc(ctx, ncap);
      if (grown == NULL) {
        rc = rp__fail(ctx, RP_ENOMEM, "%s: out of memory for %zu bytes",
                      name, ncap);
        goto done;
      }
      memcpy(grown, data, have);
      rp__free(ctx, data);
      data = grown;
      cap = ncap;
      continue;
    } else {
      mode = SPILL; /* all data is in: anything more is too much */
      zs.next_out = spill;
      zs.avail_out = sizeof spill;
    }
    before = zs.avail_out;
    zrc = inflate(&zs, Z_NO_FLUSH);
    rp__inflate_calls++;
    if (mode == SKIP)
      skip -= before - zs.avail_out;
    else if (mode == FILL)
      have += before - zs.avail_out;
    else if (zs.avail_out != before) {
      rc = rp__fail(ctx, RP_EFORMAT,
                    "%s: gzip data holds more than the %zu bytes the sizes "
                    "need",
                    name, bytes);
      goto done;
    }
    if (zrc == Z_STREAM_END)
      break;
    if (zrc == Z_OK)
      continue;
    if (zrc == Z_BUF_ERROR && zs.avail_in == 0) {
      /* No progress possible: the output always has room, so the input
       * ran out; refill, or the stream was cut short. */
      if (!in_end)
        continue;
      rc = rp__fail(ctx, RP_ETRUNC,
                    "%s: gzip data truncated after %zu of %zu bytes", name,
                    have, bytes);
      goto done;
    }
    rc = zrc == Z_MEM_ERROR
             ? rp__fail(ctx, RP_ENOMEM, "%s: out of memory in zlib", name)
             : rp__fail(ctx, RP_EFORMAT, "%s: corrupt gzip data (%s)", name,
                        zs.msg != NULL ? zs.msg : "unknown zlib error");
    goto done;
  }
  if (skip > 0 || have < bytes) {
    rc = rp__fail(ctx, RP_ETRUNC,
                  "%s: gzip data ends after %zu of %zu bytes", name, have,
                  bytes);
    goto done;
  }
  if (zs.avail_in > 0 || src->left > 0) {
    rc = rp__fail(ctx, RP_EFORMAT,
                  "%s: %llu bytes follow the end of the gzip stream", name,
                  (unsigned long long)(zs.avail_in + src->left));
    goto done;
  }
done:
  if (inited)
    inflateEnd(&zs);
  rp__free(ctx, window);
  rp__free(ctx, in);
  if (rc != 0) {
    rp__free(ctx, data);
    return rc;
  }
  *out = data;
  return 0;
}

static int host_is_big_endian(void) {
  const uint16_t one = 1;
  uint8_t first;
  memcpy(&first, &one, 1);
  return first == 0;
}

static void swap_bytes(uint8_t *p, size_t count, size_t size) {
  size_t i;
  uint8_t t;
  for (i = 0; i < count; i++, p += size) {
    if (size == 2) {
      t = p[0], p[0] = p[1], p[1] = t;
    } else if (size == 4) {
      t = p[0], p[0] = p[3], p[3] = t;
      t = p[1], p[1] = p[2], p[2] = t;
    }
  }
}

/* Skips, decodes, byte-swaps and hands the voxels to a new volume. The
 * header has passed check_header and needs `bytes` bytes. */
static int decode_source(rp_context *ctx, const char *name,
                         const rp__volume_header *hdr, source *src,
                         size_t bytes, rp_volume **out) {
  uint8_t *data = NULL;
  uint32_t dims[3];
  rp_volume *vol = NULL;
  size_t vs = rp__voxel_size(hdr->type);
  int rc;

  if ((rc = src_skip_lines(ctx, name, src, hdr->line_skip)) != 0)
    return rc;
  rc = hdr->gzip ? decode_gzip(ctx, name, hdr, src, bytes, &data)
                 : decode_raw(ctx, name, hdr, src, bytes, &data);
  if (rc != 0 || data == NULL) /* data is set exactly when rc is 0 */
    return rc != 0 ? rc : RP_ENOMEM;
  if (vs > 1 && (hdr->big_endian != 0) != host_is_big_endian())
    swap_bytes(data, bytes / vs, vs);
  dims[0] = (uint32_t)hdr->dims[0];
  dims[1] = (uint32_t)hdr->dims[1];
  dims[2] = (uint32_t)hdr->dims[2];
  rc = rp__volume_adopt(ctx, dims, hdr->type, hdr->spacing, data, &vol);
  if (rc != 0) {
    /* The message is about the voxels; say which file they came from. */
    char msg[RP__ERRMSG_MAX];
    snprintf(msg, sizeof msg, "%s", rp_last_error(ctx));
    return rp__fail(ctx, rc, "%s: %s", name, msg);
  }
  *out = vol;
  return 0;
}

int rp__volume_decode(rp_context *ctx, const char *name,
                      const rp__volume_header *hdr, const uint8_t *payload,
                      size_t len, rp_volume **out) {
  source src;
  size_t bytes = 0;
  int rc;
  if (ctx == NULL)
    return RP_EINVAL;
  if (name == NULL)
    name = "(memory)";
  if (hdr == NULL || out == NULL || (payload == NULL && len > 0))
    return rp__fail(ctx, RP_EINVAL, "%s: rp__volume_decode: NULL argument",
                    name);
  if ((rc = check_header(ctx, name, &memory_fields_named, hdr, &bytes)) != 0)
    return rc;
  if (hdr->skip_to_end && hdr->gzip)
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: byte skip -1 needs raw encoding, not gzip", name);
  src.fp = NULL;
  src.mem = payload;
  src.left = len;
  return decode_source(ctx, name, hdr, &src, bytes, out);
}

/* ---- Files --------------------------------------------------------------- */

static int no_such_file(rp_context *ctx, const char *path,
                        const char *owner) {
  return owner != NULL
             ? rp__fail(ctx, RP_ENOENT, "%s: data file %s: no such file",
                        owner, path)
             : rp__fail(ctx, RP_ENOENT, "%s: no such file", path);
}

static int not_regular(rp_context *ctx, const char *path,
                       const char *owner) {
  return owner != NULL
             ? rp__fail(ctx, RP_EIO, "%s: data file %s: not a regular file",
                        owner, path)
             : rp__fail(ctx, RP_EIO, "%s: not a regular file", path);
}

/* Opens a regular file for reading; NULL with *rc set on failure. `owner`,
 * when not NULL, is the header that named it, for the message. A FIFO
 * blocks in open() until a writer comes, and opening a device may act on
 * it, so the path's type is checked before it is opened; the open itself
 * does not block either, and the type is checked again on the descriptor,
 * in case the path changed in between. */
static FILE *open_file(rp_context *ctx, const char *path, const char *owner,
                       uint64_t *size, int *rc) {
  struct stat st;
  FILE *f = NULL;
  int fd, flags, err;
  if (stat(path, &st) != 0) {
    err = errno;
    *rc = err == ENOENT || err == ENOTDIR
              ? no_such_file(ctx, path, owner)
              : rp__fail(ctx, RP_EIO, "%s: cannot stat: %s", path,
                         strerror(err));
    return NULL;
  }
  if (!S_ISREG(st.st_mode)) {
    *rc = not_regular(ctx, path, owner);
    return NULL;
  }
  fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    err = errno;
    *rc = err == ENOENT || err == ENOTDIR
              ? no_such_file(ctx, path, owner)
              : rp__fail(ctx, RP_EIO, "%s: cannot open: %s", path,
                         strerror(err));
    return NULL;
  }
  if (fstat(fd, &st) != 0) {
    err = errno;
    close(fd);
    *rc = rp__fail(ctx, RP_EIO, "%s: cannot stat: %s", path, strerror(err));
    return NULL;
  }
  if (!S_ISREG(st.st_mode)) {
    close(fd);
    *rc = not_regular(ctx, path, owner);
    return NULL;
  }
  /* Reads block as usual from here on. */
  flags = fcntl(fd, F_GETFL);
  if (flags != -1 && fcntl(fd, F_SETFL, flags & ~O_NONBLOCK) != -1)
    f = fdopen(fd, "rb");
  if (f == NULL) {
    err = errno;
    close(fd);
    *rc = rp__fail(ctx, err == ENOMEM ? RP_ENOMEM : RP_EIO,
                   "%s: cannot open: %s", path, strerror(err));
    return NULL;
  }
  *size = (uint64_t)st.st_size;
  return f;
}

/* The file `file` names relative to the directory of `header`, in memory
 * from rp__malloc; NULL when out of memory (recorded). Absolute names are
 * kept as they are. */
static char *resolve(rp_context *ctx, const char *header, const char *file) {
  const char *slash = strrchr(header, '/');
  size_t dir = file[0] == '/' || slash == NULL
                   ? 0
                   : (size_t)(slash - header) + 1;
  size_t n = strlen(file);
  char *p = rp__malloc(ctx, dir + n + 1);
  if (p == NULL) {
    rp__fail(ctx, RP_ENOMEM, "%s: out of memory", header);
    return NULL;
  }
  memcpy(p, header, dir);
  memcpy(p + dir, file, n + 1);
  return p;
}

/* Decodes the payload of `fp`, from byte `offset` to its end. */
static int decode_file(rp_context *ctx, const char *name,
                       const header_fields *fields,
                       const rp__volume_header *hdr, FILE *fp, uint64_t size,
                       uint64_t offset, rp_volume **out) {
  source src;
  size_t bytes = 0;
  int rc;
  if ((rc = check_header(ctx, name, fields, hdr, &bytes)) != 0)
    return rc;
  if (offset > size || fseeko(fp, (off_t)offset, SEEK_SET) != 0)
    return rp__fail(ctx, RP_EIO, "%s: seek error", name);
  src.fp = fp;
  src.mem = NULL;
  src.left = size - offset;
  return decode_source(ctx, name, hdr, &src, bytes, out);
}

/* The payload of a header that names a data file. */
static int decode_data_file(rp_context *ctx, const char *path,
                            const header_fields *fields,
                            const rp__volume_header *hdr, rp_volume **out) {
  char *data_path = resolve(ctx, path, hdr->data_file);
  FILE *fp;
  uint64_t size = 0;
  int rc = RP_ENOMEM;
  if (data_path == NULL)
    return rc;
  fp = open_file(ctx, data_path, path, &size, &rc);
  if (fp != NULL) {
    rc = decode_file(ctx, data_path, fields, hdr, fp, size, 0, out);
    fclose(fp);
  }
  rp__free(ctx, data_path);
  return rc;
}

/* An NRRD header must end within the bytes read: at an empty line, or at
 * the end of a file that fits in them. */
static int has_blank_line(const uint8_t *buf, size_t len) {
  size_t pos = 0;
  while (pos < len) {
    const uint8_t *nl = memchr(buf + pos, '\n', len - pos);
    size_t end;
    if (nl == NULL)
      return 0;
    end = (size_t)(nl - buf);
    if (end == pos || (end == pos + 1 && buf[pos] == '\r'))
      return 1;
    pos = end + 1;
  }
  return 0;
}

static int load_nrrd(rp_context *ctx, const char *path, FILE *fp,
                     uint64_t size, const uint8_t *head, size_t head_len,
                     rp_volume **out) {
  rp__volume_header hdr;
  size_t header_len = 0;
  int rc;
  header_init(&hdr);
  if (head_len < size && !has_blank_line(head, head_len))
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: NRRD header does not end (empty line) within its "
                    "first %zu bytes",
                    path, HEAD_MAX);
  rc = rp__nrrd_parse(ctx, path, head, head_len, &hdr, &header_len);
  if (rc != 0)
    return rc;
  if (hdr.data_file[0] != '\0')
    return decode_data_file(ctx, path, &nrrd_fields_named, &hdr, out);
  return decode_file(ctx, path, &nrrd_fields_named, &hdr, fp, size,
                     header_len, out);
}

int rp_volume_load(rp_context *ctx, const char *path, rp_volume **out) {
  rp__volume_header hdr;
  uint8_t *head = NULL;
  size_t head_len, got;
  uint64_t size = 0;
  FILE *fp = NULL;
  int rc;

  if (ctx == NULL)
    return RP_EINVAL;
  if (path == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL,
                    "rp_volume_load: path and out must not be NULL");
  header_init(&hdr);
  if ((fp = open_file(ctx, path, NULL, &size, &rc)) == NULL)
    return rc;
  /* A .raw file by its name first: its content is voxels only, and voxels
   * may begin with any bytes, "NRRD" included. Then the first bytes
   * decide: NRRD by its magic, a sidecar by its keys. */
  rc = raw_name_parse(ctx, path, &hdr);
  if (rc <= 0) {
    if (rc == 0)
      rc = decode_file(ctx, path, &raw_fields_named, &hdr, fp, size, 0,
                       out);
    goto done;
  }
  head_len = size < HEAD_MAX ? (size_t)size : HEAD_MAX;
  head = rp__malloc(ctx, head_len > 0 ? head_len : 1);
  if (head == NULL) {
    rc = rp__fail(ctx, RP_ENOMEM, "%s: out of memory", path);
    goto done;
  }
  got = fread(head, 1, head_len, fp);
  if (got < head_len) {
    rc = rp__fail(ctx, RP_EIO, "%s: read error: %s", path,
                  ferror(fp) ? strerror(errno) : "file shrank");
    goto done;
  }
  if (head_len >= 4 && memcmp(head, "NRRD", 4) == 0) {
    rc = load_nrrd(ctx, path, fp, size, head, head_len, out);
  } else if (looks_like_sidecar(head, head_len)) {
    if (size > HEAD_MAX)
      rc = rp__fail(ctx, RP_EFORMAT,
                    "%s: too large for a sidecar (%llu bytes)", path,
                    (unsigned long long)size);
    else if ((rc = rp__sidecar_parse(ctx, path, head, head_len, &hdr)) == 0)
      rc = decode_data_file(ctx, path, &sidecar_fields_named, &hdr, out);
  } else {
    rc = rp__fail(ctx, RP_EFORMAT,
                  "%s: not a volume file; accepted: NRRD (starts with "
                  "NRRD000N), a sidecar (lines 'file:', 'dims:', 'type:') "
                  "or NAME_XxYxZ_TYPE.raw (TYPE uint8, uint16, float32)",
                  path);
  }
done:
  rp__free(ctx, head);
  fclose(fp);
  return rc;
}
