/* Volume headers: NRRD, the raypace sidecar and the dims and type in a
 * NAME_XxYxZ_TYPE.raw file name, each read into an rp__volume_header
 * (volume_io.h says how the loader's parts fit together).
 *
 * Policy decisions (tests/test_volume_io.c holds us to them):
 * - A size of 0 is RP_ERANGE, like a product too large for size_t or for
 *   the context's max_volume_bytes.
 * - Lines are at most MAX_LINE bytes; a longer one is RP_EFORMAT. */
#include <float.h>
#include <locale.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "volume_io.h"

#define MAX_LINE RP__MAX_LINE

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
  F_BYTES = 1 << 10,
  F_SPACE = 1 << 11,
  F_SPACE_DIM = 1 << 12,
  F_ORIGIN = 1 << 13
};

typedef struct field_name {
  const char *name;
  unsigned bit;
} field_name;

typedef struct type_name {
  const char *name;
  rp_voxel_type type;
} type_name;

const rp__header_fields rp__nrrd_fields_named = {"field 'sizes'",
                                                 "field 'spacings'"};
const rp__header_fields rp__sidecar_fields_named = {"field 'dims'",
                                                    "field 'spacing'"};
const rp__header_fields rp__raw_fields_named = {"the dims in the file name",
                                                "field 'spacing'"};

/* ---- Text helpers ------------------------------------------------------ */

/* Character classes by hand: <ctype.h> depends on the locale and is
 * undefined for negative chars. */
static int is_space(int c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

static int is_digit(int c) { return c >= '0' && c <= '9'; }

static int to_lower(int c) { return c >= 'A' && c <= 'Z' ? c - 'A' + 'a' : c; }

int rp__text_eq_nocase(const char *a, const char *b) {
  while (*a != '\0' && to_lower((unsigned char)*a) ==
                           to_lower((unsigned char)*b)) {
    a++;
    b++;
  }
  return *a == '\0' && *b == '\0';
}

/* Strips spaces at both ends, in place. */
char *rp__text_trim(char *s) {
  size_t n;
  while (is_space((unsigned char)*s))
    s++;
  n = strlen(s);
  while (n > 0 && is_space((unsigned char)s[n - 1]))
    s[--n] = '\0';
  return s;
}

/* Splits off the next space-separated token, in place; NULL when none. */
char *rp__text_token(char **cursor) {
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
const char *rp__text_shown(char buf[64], const char *s) {
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
int rp__text_u64(const char *s, uint64_t *v) {
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
int rp__text_i64(const char *s, int64_t *v) {
  uint64_t mag;
  int neg = *s == '-';
  if (*s == '-' || *s == '+')
    s++;
  if (!rp__text_u64(s, &mag) || mag > (uint64_t)INT64_MAX)
    return 0;
  *v = neg ? -(int64_t)mag : (int64_t)mag;
  return 1;
}

/* A floating-point number filling the whole token. strtod reads the
 * decimal point of the current locale, which a host application may have
 * changed, so the token's '.' is translated first; NaN and infinities are
 * accepted here and rejected by the callers with RP_ENOTFINITE. */
int rp__text_double(const char *s, double *v) {
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
  return rp__voxel_size(type) != 0 ? rp_voxel_type_name(type) : "?";
}

const char *rp__volume_dims_text(char buf[96],
                                 const rp__volume_header *hdr) {
  snprintf(buf, 96, "%llux%llux%llu %s", (unsigned long long)hdr->dims[0],
           (unsigned long long)hdr->dims[1], (unsigned long long)hdr->dims[2],
           type_label(hdr->type));
  return buf;
}

/* ---- Lines of a memory buffer ------------------------------------------ */

/* Copies the next line into `out` as a C string, without its "\n" or
 * "\r\n". Returns 1 with a line, 0 at the end of the buffer, or an error:
 * lines longer than MAX_LINE and lines holding a NUL byte are malformed. */
int rp__text_line(rp_context *ctx, const char *name, rp__line_reader *lr,
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
    if (rp__text_eq_nocase(value, names->name)) {
      *type = names->type;
      return 0;
    }
  }
  return rp__fail(ctx, RP_EUNSUPPORTED,
                  "%s: %s '%s' is not supported (accepted: %s)", name, field,
                  rp__text_shown(sv, value), accepted);
}

static int parse_endian(rp_context *ctx, const char *name, const char *field,
                        const char *value, int *big) {
  char sv[64];
  if (rp__text_eq_nocase(value, "little"))
    *big = 0;
  else if (rp__text_eq_nocase(value, "big"))
    *big = 1;
  else
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: %s '%s' is neither 'little' nor 'big'", name, field,
                    rp__text_shown(sv, value));
  return 0;
}

/* Exactly three sizes, each at least 1. */
int rp__header_sizes(rp_context *ctx, const char *name, const char *field,
                     char *value, uint64_t dims[3]) {
  char sv[64], copy[MAX_LINE + 1];
  char *cursor = value, *tok;
  int n = 0;
  snprintf(copy, sizeof copy, "%s", value);
  while ((tok = rp__text_token(&cursor)) != NULL) {
    if (n == 3 || !rp__text_u64(tok, &dims[n]))
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: %s '%s' is not three whole numbers", name, field,
                      rp__text_shown(sv, copy));
    if (dims[n] == 0)
      return rp__fail(ctx, RP_ERANGE,
                      "%s: %s '%s': every size must be at least 1", name,
                      field, rp__text_shown(sv, copy));
    n++;
  }
  if (n != 3)
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: %s '%s' is not three whole numbers", name, field,
                    rp__text_shown(sv, copy));
  return 0;
}

/* A voxel spacing must be a positive, finite float. `text` is what the
 * file says for `axis`: a number, or a vector whose length is v. */
int rp__header_spacing(rp_context *ctx, const char *name, const char *field,
                         int axis, const char *text, double v, float *out) {
  char sv[64];
  float f;
  if (!isfinite(v))
    return rp__fail(ctx, RP_ENOTFINITE,
                    "%s: field '%s': axis %d value '%s' is not finite", name,
                    field, axis, rp__text_shown(sv, text));
  if (!(v > 0.0) || v > FLT_MAX)
    return rp__fail(ctx, RP_ERANGE,
                    "%s: field '%s': axis %d value '%s' is not a positive "
                    "float",
                    name, field, axis, rp__text_shown(sv, text));
  if (v < RP_SPACING_MIN || v > RP_SPACING_MAX)
    return rp__fail(ctx, RP_ERANGE,
                    "%s: field '%s': axis %d value '%s' is out of range; a "
                    "voxel spacing must be in [%g, %g] (RP_SPACING_MIN/MAX)",
                    name, field, axis, rp__text_shown(sv, text),
                    RP_SPACING_MIN, RP_SPACING_MAX);
  f = (float)v;
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
  while ((tok = rp__text_token(&cursor)) != NULL) {
    if (n == 3 || !rp__text_double(tok, &v))
      return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s' is not three numbers",
                      name, field, rp__text_shown(sv, copy));
    if ((rc = rp__header_spacing(ctx, name, field, n, tok, v, &spacing[n])) !=
        0)
      return rc;
    n++;
  }
  if (n != 3)
    return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s' is not three numbers",
                    name, field, rp__text_shown(sv, copy));
  return 0;
}

/* One NRRD vector "(a,b,c)" at *p, up to 16 components, into v[]; *p
 * moves past it. `what` says which vector, for messages ("axis 1"). */
static int parse_vector(rp_context *ctx, const char *name, const char *field,
                        const char *value, const char **p, const char *what,
                        double v[16], int *ncomp) {
  char sv[64], comp[64];
  const char *q = *p, *close;
  int n = 0;
  while (is_space((unsigned char)*q))
    q++;
  if (*q != '(')
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: %s '%s': %s is not a vector '(x,y,z)'", name, field,
                    rp__text_shown(sv, value), what);
  close = strchr(q, ')');
  if (close == NULL)
    return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s': missing ')'", name,
                    field, rp__text_shown(sv, value));
  q++;
  while (q <= close) {
    const char *end = q;
    size_t len;
    while (end < close && *end != ',')
      end++;
    len = (size_t)(end - q);
    if (len >= sizeof comp)
      len = sizeof comp - 1; /* a cut number fails to parse below */
    memcpy(comp, q, len);
    comp[len] = '\0';
    if (n == 16 || !rp__text_double(rp__text_trim(comp), &v[n]))
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: %s '%s': %s is not a vector of numbers", name,
                      field, rp__text_shown(sv, value), what);
    if (!isfinite(v[n]))
      return rp__fail(ctx, RP_ENOTFINITE, "%s: %s '%s': %s is not finite",
                      name, field, rp__text_shown(sv, value), what);
    n++;
    q = end + 1;
  }
  *p = close + 1;
  *ncomp = n;
  return 0;
}

/* What an NRRD header says about space, gathered over its fields and
 * turned into an orientation once all are read (their order is free). */
typedef struct nrrd_space {
  int named;         /* "space" or "space dimension" given */
  int patient;       /* "space" names an anatomical frame */
  double sign[3];    /* its axes in LPS: -1 where it points the other way */
  int ncomp;         /* components of each "space directions" vector */
  double dir[3][3];  /* those vectors, when they have three components */
  int has_origin;
  double origin[3];
} nrrd_space;

/* NRRD "space directions: (a,b,c) (d,e,f) (g,h,i)": one vector per axis in
 * world space, whose length is that axis's spacing. "none" marks a
 * non-spatial axis, which a 3D volume cannot have. */
static int parse_directions(rp_context *ctx, const char *name,
                            const char *field, const char *value,
                            float spacing[3], nrrd_space *sp) {
  char sv[64], vec[64], what[16];
  const char *p = value;
  int axis, ncomp = 0, rc, i;
  for (axis = 0; axis < 3; axis++) {
    const char *start = p;
    double v[16] = {0}, sum = 0.0;
    size_t vn;
    snprintf(what, sizeof what, "axis %d", axis);
    if ((rc = parse_vector(ctx, name, field, value, &p, what, v, &ncomp)) !=
        0)
      return rc;
    if (axis > 0 && ncomp != sp->ncomp)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: %s '%s': vectors differ in length", name, field,
                      rp__text_shown(sv, value));
    sp->ncomp = ncomp;
    for (i = 0; i < ncomp; i++) {
      sum += v[i] * v[i];
      if (ncomp == 3)
        sp->dir[axis][i] = v[i];
    }
    /* This axis's vector, for a message about its length. */
    while (is_space((unsigned char)*start))
      start++;
    vn = (size_t)(p - start);
    if (vn >= sizeof vec)
      vn = sizeof vec - 1;
    memcpy(vec, start, vn);
    vec[vn] = '\0';
    if ((rc = rp__header_spacing(ctx, name, field, axis, vec, sqrt(sum),
                                 &spacing[axis])) != 0)
      return rc;
  }
  while (is_space((unsigned char)*p))
    p++;
  if (*p != '\0')
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: %s '%s' has more than three vectors", name, field,
                    rp__text_shown(sv, value));
  return 0;
}

/* NRRD "space": the anatomical frames map onto LPS by flipping axes;
 * scanner and generic 3D frames are spatial but say nothing of the
 * patient, so the volume keeps its spacing and no orientation. Frames
 * with time are 4D. */
static int parse_space(rp_context *ctx, const char *name, const char *value,
                       nrrd_space *sp) {
  static const struct {
    const char *name, *abbrev;
    double sx, sy;
  } frames[] = {{"left-posterior-superior", "LPS", 1, 1},
                {"right-anterior-superior", "RAS", -1, -1},
                {"left-anterior-superior", "LAS", 1, -1}};
  static const char *const plain[] = {"scanner-xyz", "3D-right-handed",
                                      "3D-left-handed"};
  char sv[64];
  size_t i, n = strlen(value);
  sp->named = 1;
  for (i = 0; i < sizeof frames / sizeof frames[0]; i++) {
    if (rp__text_eq_nocase(value, frames[i].name) ||
        rp__text_eq_nocase(value, frames[i].abbrev)) {
      sp->patient = 1;
      sp->sign[0] = frames[i].sx;
      sp->sign[1] = frames[i].sy;
      sp->sign[2] = 1;
      return 0;
    }
  }
  for (i = 0; i < sizeof plain / sizeof plain[0]; i++)
    if (rp__text_eq_nocase(value, plain[i]))
      return 0;
  if ((n > 5 && rp__text_eq_nocase(value + n - 5, "-time")) ||
      rp__text_eq_nocase(value, "RAST") || rp__text_eq_nocase(value, "LAST") ||
      rp__text_eq_nocase(value, "LPST"))
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: space '%s' has a time axis: only 3D spaces are "
                    "supported",
                    name, rp__text_shown(sv, value));
  return rp__fail(ctx, RP_EFORMAT,
                  "%s: space '%s' is not an NRRD space (accepted: "
                  "right-anterior-superior (RAS), left-anterior-superior "
                  "(LAS), left-posterior-superior (LPS), scanner-xyz, "
                  "3D-right-handed, 3D-left-handed)",
                  name, rp__text_shown(sv, value));
}

static int parse_origin(rp_context *ctx, const char *name, const char *value,
                        nrrd_space *sp) {
  char sv[64];
  const char *p = value;
  double v[16];
  int n = 0, rc;
  if ((rc = parse_vector(ctx, name, "space origin", value, &p, "the origin",
                         v, &n)) != 0)
    return rc;
  while (is_space((unsigned char)*p))
    p++;
  if (n != 3 || *p != '\0')
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: space origin '%s' is not one vector (x,y,z)", name,
                    rp__text_shown(sv, value));
  memcpy(sp->origin, v, sizeof sp->origin);
  sp->has_origin = 1;
  return 0;
}

/* The orientation in LPS, once the whole header is read: known when the
 * space is anatomical and the directions are 3-vectors. The origin
 * defaults to zero, as NRRD readers take it. */
static int nrrd_orientation(rp_context *ctx, const char *name,
                            unsigned seen, const nrrd_space *sp,
                            rp__volume_header *h) {
  char what[1100];
  rp_orientation o;
  int a, i;
  if (sp->named && (seen & F_DIRECTIONS) && sp->ncomp != 3)
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: space directions: vectors of %d components in a 3D "
                    "space",
                    name, sp->ncomp);
  if (!sp->patient || !(seen & F_DIRECTIONS))
    return 0;
  memset(&o, 0, sizeof o);
  o.known = 1;
  for (a = 0; a < 3; a++) {
    const double *d = sp->dir[a];
    double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (i = 0; i < 3; i++) {
      o.direction[3 * a + i] = sp->sign[i] * d[i] / len;
      o.origin[i] = sp->has_origin ? sp->sign[i] * sp->origin[i] : 0.0;
    }
  }
  snprintf(what, sizeof what, "%s: space directions", name);
  return rp__orientation_check(ctx, what, &o, &h->orientation);
}

int rp__header_data_file(rp_context *ctx, const char *name, const char *field,
                         const char *value, rp__volume_header *hdr) {
  char sv[64];
  size_t n = strlen(value);
  if (n == 0)
    return rp__fail(ctx, RP_EFORMAT, "%s: %s is empty", name, field);
  if (n >= sizeof hdr->data_file)
    return rp__fail(ctx, RP_EFORMAT, "%s: %s '%s' is too long", name, field,
                    rp__text_shown(sv, value));
  memcpy(hdr->data_file, value, n + 1);
  return 0;
}

int rp__volume_header_check(rp_context *ctx, const char *name,
                            const rp__header_fields *fields,
                            const rp__volume_header *hdr, size_t *bytes) {
  size_t voxels;
  int i;
  for (i = 0; i < 3; i++)
    if (!(hdr->spacing[i] >= RP_SPACING_MIN &&
          hdr->spacing[i] <= RP_SPACING_MAX))
      return rp__fail(ctx, RP_ERANGE,
                      "%s: %s: axis %d value %g must be in [%g, %g]",
                      name, fields->spacing, i, (double)hdr->spacing[i],
                      RP_SPACING_MIN, RP_SPACING_MAX);
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

void rp__volume_header_init(rp__volume_header *hdr) {
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
    {"signed char", RP_S8},     {"int8", RP_S8},
    {"int8_t", RP_S8},          {"short", RP_S16},
    {"short int", RP_S16},      {"signed short", RP_S16},
    {"signed short int", RP_S16}, {"int16", RP_S16},
    {"int16_t", RP_S16},        {"int", RP_S32},
    {"signed int", RP_S32},     {"int32", RP_S32},
    {"int32_t", RP_S32},        {"uint", RP_U32},
    {"unsigned int", RP_U32},   {"uint32", RP_U32},
    {"uint32_t", RP_U32},
    {NULL, RP_U8}};

static const field_name nrrd_fields[] = {
    {"type", F_TYPE},           {"dimension", F_DIMENSION},
    {"sizes", F_SIZES},         {"endian", F_ENDIAN},
    {"encoding", F_ENCODING},   {"spacings", F_SPACINGS},
    {"space directions", F_DIRECTIONS},
    {"data file", F_DATA_FILE}, {"datafile", F_DATA_FILE},
    {"byte skip", F_BYTE_SKIP}, {"byteskip", F_BYTE_SKIP},
    {"line skip", F_LINE_SKIP}, {"lineskip", F_LINE_SKIP},
    {"space", F_SPACE},         {"space dimension", F_SPACE_DIM},
    {"space origin", F_ORIGIN}, {NULL, 0}};

static unsigned field_bit(const field_name *fields, const char *field) {
  for (; fields->name != NULL; fields++)
    if (rp__text_eq_nocase(field, fields->name))
      return fields->bit;
  return 0;
}

/* One NRRD field this loader uses. `value` is modified. */
static int nrrd_field(rp_context *ctx, const char *name, unsigned bit,
                      const char *field, char *value, rp__volume_header *hdr,
                      nrrd_space *sp) {
  char sv[64];
  int64_t n;
  switch (bit) {
  case F_TYPE:
    return parse_type(ctx, name, "type", value, nrrd_types,
                      "uchar, ushort, float, signed char, short, int, uint and "
                      "their aliases", &hdr->type);
  case F_DIMENSION:
    if (!rp__text_i64(value, &n) || n < 1)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: dimension '%s' is not a positive integer", name,
                      rp__text_shown(sv, value));
    if (n != 3)
      return rp__fail(ctx, RP_EUNSUPPORTED,
                      "%s: dimension %lld is not supported (only 3)", name,
                      (long long)n);
    return 0;
  case F_SIZES:
    return rp__header_sizes(ctx, name, "sizes", value, hdr->dims);
  case F_ENDIAN:
    return parse_endian(ctx, name, "endian", value, &hdr->big_endian);
  case F_ENCODING:
    if (rp__text_eq_nocase(value, "raw"))
      hdr->gzip = 0;
    else if (rp__text_eq_nocase(value, "gzip") || rp__text_eq_nocase(value, "gz"))
      hdr->gzip = 1;
    else
      return rp__fail(ctx, RP_EUNSUPPORTED,
                      "%s: encoding '%s' is not supported (raw, gzip)", name,
                      rp__text_shown(sv, value));
    return 0;
  case F_SPACINGS:
    return parse_spacings(ctx, name, "spacings", value, hdr->spacing);
  case F_DIRECTIONS:
    return parse_directions(ctx, name, "space directions", value,
                            hdr->spacing, sp);
  case F_SPACE:
    return parse_space(ctx, name, value, sp);
  case F_SPACE_DIM:
    if (!rp__text_i64(value, &n) || n < 1)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: space dimension '%s' is not a positive integer",
                      name, rp__text_shown(sv, value));
    if (n != 3)
      return rp__fail(ctx, RP_EUNSUPPORTED,
                      "%s: space dimension %lld is not supported (only 3)",
                      name, (long long)n);
    sp->named = 1;
    return 0;
  case F_ORIGIN:
    return parse_origin(ctx, name, value, sp);
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
                      name, field, rp__text_shown(sv, value));
    return rp__header_data_file(ctx, name, field, value, hdr);
  case F_BYTE_SKIP:
    if (!rp__text_i64(value, &n))
      return rp__fail(ctx, RP_EFORMAT, "%s: byte skip '%s' is not an integer",
                      name, rp__text_shown(sv, value));
    if (n < -1)
      return rp__fail(ctx, RP_ERANGE,
                      "%s: byte skip %lld must be -1 or more", name,
                      (long long)n);
    hdr->skip_to_end = n == -1;
    hdr->byte_skip = n == -1 ? 0 : (uint64_t)n;
    return 0;
  case F_LINE_SKIP:
    if (!rp__text_i64(value, &n))
      return rp__fail(ctx, RP_EFORMAT, "%s: line skip '%s' is not an integer",
                      name, rp__text_shown(sv, value));
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
                    name, rp__text_shown(sv, line));
  }
  return rp__fail(ctx, RP_EFORMAT,
                  "%s: magic '%s' is not NRRD000N (N from 1 to 5)", name,
                  rp__text_shown(sv, line));
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
  rp__line_reader lr;
  rp__volume_header h;
  nrrd_space sp;
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
  if ((rc = rp__text_line(ctx, name, &lr, line)) <= 0)
    return rc < 0 ? rc : rp__fail(ctx, RP_EFORMAT, "%s: no magic", name);
  if ((rc = nrrd_magic(ctx, name, line)) != 0)
    return rc;
  rp__volume_header_init(&h);
  memset(&sp, 0, sizeof sp);
  for (;;) {
    char *colon, *field, *value;
    unsigned bit;
    rc = rp__text_line(ctx, name, &lr, line);
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
                      lr.number, rp__text_shown(sv, line));
    if (colon[1] == '=')
      continue; /* "key:=value" pairs carry nothing we use */
    *colon = '\0';
    field = rp__text_trim(line);
    value = rp__text_trim(colon + 1);
    bit = field_bit(nrrd_fields, field);
    if (bit == 0)
      continue; /* NRRD allows fields we do not need */
    if (seen & bit)
      return rp__fail(ctx, RP_EFORMAT, "%s: field '%s' appears twice", name,
                      rp__text_shown(sv, field));
    seen |= bit;
    if ((rc = nrrd_field(ctx, name, bit, field, value, &h, &sp)) != 0)
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
  if ((seen & F_SPACE) && (seen & F_SPACE_DIM))
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: fields 'space' and 'space dimension' exclude each "
                    "other",
                    name);
  if (h.skip_to_end && h.gzip)
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: byte skip -1 needs raw encoding, not gzip", name);
  if ((rc = nrrd_orientation(ctx, name, seen, &sp, &h)) != 0)
    return rc;
  if ((rc = rp__volume_header_check(ctx, name, &rp__nrrd_fields_named, &h,
                                    &bytes)) != 0)
    return rc;
  *hdr = h;
  if (header_len != NULL)
    *header_len = end;
  return 0;
}

/* ---- Sidecar ------------------------------------------------------------- */

static const type_name plain_types[] = {
    {"uint8", RP_U8},   {"uint16", RP_U16}, {"float32", RP_F32},
    {"int8", RP_S8},    {"int16", RP_S16},  {"int32", RP_S32},
    {"uint32", RP_U32}, {NULL, RP_U8}};

#define RP__PLAIN_TYPE_LIST \
  "uint8, int8, uint16, int16, uint32, int32, float32"

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
  rp__line_reader lr;
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
  rp__volume_header_init(&h);
  while ((rc = rp__text_line(ctx, name, &lr, line)) > 0) {
    char *colon, *key, *value = rp__text_trim(line);
    unsigned bit;
    if (value[0] == '\0' || value[0] == '#')
      continue;
    colon = strchr(line, ':');
    if (colon == NULL)
      return rp__fail(ctx, RP_EFORMAT, "%s: line %u '%s' is not 'key: value'",
                      name, lr.number, rp__text_shown(sv, value));
    *colon = '\0';
    key = rp__text_trim(line);
    value = rp__text_trim(colon + 1);
    bit = field_bit(sidecar_keys, key);
    if (bit == 0)
      continue; /* descriptive keys: min, max, mean, source, ... */
    if (seen & bit)
      return rp__fail(ctx, RP_EFORMAT, "%s: key '%s' appears twice", name,
                      rp__text_shown(sv, key));
    seen |= bit;
    switch (bit) {
    case F_DATA_FILE:
      rc = rp__header_data_file(ctx, name, "file", value, &h);
      break;
    case F_SIZES:
      rc = rp__header_sizes(ctx, name, "dims", value, h.dims);
      break;
    case F_TYPE:
      rc = parse_type(ctx, name, "type", value, plain_types,
                      RP__PLAIN_TYPE_LIST, &h.type);
      break;
    case F_ENDIAN:
      rc = parse_endian(ctx, name, "endian", value, &h.big_endian);
      break;
    case F_SPACINGS:
      rc = parse_spacings(ctx, name, "spacing", value, h.spacing);
      break;
    default: /* F_BYTES */
      rc = rp__text_u64(value, &declared)
               ? 0
               : rp__fail(ctx, RP_EFORMAT,
                          "%s: bytes '%s' is not a whole number", name,
                          rp__text_shown(sv, value));
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
  if ((rc = rp__volume_header_check(ctx, name, &rp__sidecar_fields_named,
                                    &h, &bytes)) != 0)
    return rc;
  if ((seen & F_BYTES) && declared != (uint64_t)bytes)
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: bytes %llu disagrees with dims %s (%zu bytes)", name,
                    (unsigned long long)declared,
                    rp__volume_dims_text(dt, &h), bytes);
  *hdr = h;
  return 0;
}

int rp__looks_like_sidecar(const uint8_t *buf, size_t len) {
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
    if (!rp__text_u64(tok, &dims[axis]))
      return 0;
    if (axis < 2) {
      if (i == n || (s[i] != 'x' && s[i] != 'X'))
        return 0;
      i++;
    }
  }
  return i == n;
}

int rp__raw_name_parse(rp_context *ctx, const char *path,
                       rp__volume_header *hdr) {
  const char *base = strrchr(path, '/');
  const char *type_sep, *dims_sep, *p;
  char type[32];
  size_t n, stem, bytes;
  rp__volume_header h;
  int rc;
  base = base != NULL ? base + 1 : path;
  n = strlen(base);
  if (n < 4 || !rp__text_eq_nocase(base + n - 4, ".raw"))
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
  rp__volume_header_init(&h);
  if (!parse_dims_token(dims_sep + 1, (size_t)(type_sep - dims_sep - 1),
                        h.dims))
    return 1;
  n = (size_t)(base + stem - type_sep - 1);
  if (n >= sizeof type)
    n = sizeof type - 1;
  memcpy(type, type_sep + 1, n);
  type[n] = '\0';
  if ((rc = parse_type(ctx, path, "type in the file name", type, plain_types,
                       RP__PLAIN_TYPE_LIST, &h.type)) != 0)
    return rc;
  if (h.dims[0] == 0 || h.dims[1] == 0 || h.dims[2] == 0)
    return rp__fail(ctx, RP_ERANGE,
                    "%s: sizes in the file name must be at least 1", path);
  if ((rc = rp__volume_header_check(ctx, path, &rp__raw_fields_named, &h,
                                    &bytes)) != 0)
    return rc;
  *hdr = h;
  return 0;
}
