/* NIfTI-1 and NIfTI-2 volumes (.nii, .nii.gz, .hdr/.img pairs, Analyze
 * 7.5 pairs too) through nifticlib (volume_io.h says how the loader's
 * parts fit together).
 *
 * nifticlib reads the header: both versions, the qform and sform with
 * their codes, the pairing of .hdr and .img, extensions. The voxels are
 * read here, with zlib (plain or gzip alike): nifticlib would allocate
 * with malloc behind the context's allocator and quietly replace NaN and
 * infinities with 0, and its messages go to stderr. Before nifticlib sees
 * a file, its first bytes are checked here (version, sizes, type, data
 * offset) against the context's limits, so that a malformed header can
 * neither make it allocate absurd sizes nor make it print.
 *
 * Policy decisions (tests/test_volume_formats.c holds us to them):
 * - Types: uint8, int8, int16, uint16, int32, uint32, float32; float64 is
 *   converted to float32 when every value is finite and fits.
 * - scl_slope/scl_inter apply when the slope is finite, non-zero and not
 *   (1, 0): integer data with an integer slope and intercept stays int16
 *   when every result fits it, anything else becomes float32.
 * - Orientation from the sform (sform_code > 0), else the qform
 *   (qform_code > 0), else unknown; NIfTI's RAS+ is turned into LPS.
 *   Spacing is the length of the transform's columns, or pixdim when no
 *   transform is known. A sheared sform falls back to the qform.
 * - Up to 7 dimensions, all past the third of size 1 (a 4D file with one
 *   volume); more is refused naming the sizes. */
#define ZLIB_CONST
#include <errno.h>
#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <zlib.h>

#include "volume_io.h"

/* Whether `path` ends in `ext`, ignoring case. */
static int ends_with(const char *path, const char *ext) {
  size_t n = strlen(path), e = strlen(ext);
  return n >= e && rp__text_eq_nocase(path + n - e, ext);
}

int rp__looks_like_nifti(const char *path, const uint8_t *buf, size_t len) {
  static const char *const exts[] = {".nii", ".nii.gz", ".hdr", ".hdr.gz",
                                     ".img", ".img.gz"};
  size_t i;
  for (i = 0; i < sizeof exts / sizeof exts[0]; i++)
    if (ends_with(path, exts[i]))
      return 1;
  if (len >= 348 && (memcmp(buf + 344, "n+1", 4) == 0 ||
                     memcmp(buf + 344, "ni1", 4) == 0))
    return 1;
  return len >= 540 && memcmp(buf + 4, "n+2\0", 4) == 0;
}

#ifndef RP_WITH_NIFTI

int rp__nifti_load(rp_context *ctx, const char *path, rp_volume **out) {
  (void)out;
  return rp__fail(ctx, RP_EUNSUPPORTED,
                  "%s: NIfTI files need nifticlib, and this raypace was "
                  "built without it (install libnifti2-dev and rebuild)",
                  path);
}

#else

#include <nifti2_io.h>

/* NIfTI's datatype codes (nifti1.h), by the voxel type each becomes. */
static const struct {
  int code;
  rp_voxel_type type;
  int bytes;
} nifti_types[] = {{DT_UINT8, RP_U8, 1},    {DT_INT8, RP_S8, 1},
                   {DT_INT16, RP_S16, 2},   {DT_UINT16, RP_U16, 2},
                   {DT_INT32, RP_S32, 4},   {DT_UINT32, RP_U32, 4},
                   {DT_FLOAT32, RP_F32, 4}, {DT_FLOAT64, RP_F32, 8}};

/* The voxel type a datatype code gives, and its size in the file; 0 when
 * it is not one we read. */
static int nifti_type(int code, rp_voxel_type *type, int *bytes) {
  size_t i;
  for (i = 0; i < sizeof nifti_types / sizeof nifti_types[0]; i++) {
    if (nifti_types[i].code == code) {
      *type = nifti_types[i].type;
      *bytes = nifti_types[i].bytes;
      return 1;
    }
  }
  return 0;
}

static int refuse_type(rp_context *ctx, const char *path, int code) {
  return rp__fail(ctx, RP_EUNSUPPORTED,
                  "%s: datatype %d (%s) is not supported (accepted: uint8, "
                  "int8, int16, uint16, int32, uint32, float32, float64)",
                  path, code, nifti_datatype_string(code));
}

/* The sizes of dim[] (dim[0] of them): x, y, z, and every further axis of
 * size 1. */
static int check_dims(rp_context *ctx, const char *path,
                      const int64_t dim[8], uint64_t dims[3]) {
  char text[200];
  size_t used = 0;
  int64_t n = dim[0];
  int i, extra = 0;
  if (n < 1 || n > 7)
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: dim[0] %lld is not a number of dimensions (1 to 7)",
                    path, (long long)n);
  for (i = 1; i <= n; i++) {
    used += (size_t)snprintf(text + used, sizeof text - used, "%s%lld",
                             i > 1 ? " x " : "", (long long)dim[i]);
    if (dim[i] < 1)
      return rp__fail(ctx, RP_ERANGE,
                      "%s: dim[%d] %lld: every size must be at least 1",
                      path, i, (long long)dim[i]);
    if (i > 3 && dim[i] > 1)
      extra = 1;
  }
  if (extra)
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: dims %s: only one 3D volume is supported (a 4D file "
                    "with more than one volume, or vector data)",
                    path, text);
  for (i = 0; i < 3; i++)
    dims[i] = i < n ? (uint64_t)dim[i + 1] : 1;
  return 0;
}

/* Sizes, type and bytes of a header against the context's limit: the
 * voxel type it becomes, its size in the file, the voxel count. float64
 * is read whole before it becomes float32, so its 8 bytes count. */
static int check_size(rp_context *ctx, const char *path, const int64_t dim[8],
                      int code, uint64_t dims[3], rp_voxel_type *type,
                      int *file_bytes, size_t *voxels) {
  size_t bytes = 0;
  int rc;
  if ((rc = check_dims(ctx, path, dim, dims)) != 0)
    return rc;
  if (!nifti_type(code, type, file_bytes))
    return refuse_type(ctx, path, code);
  if ((rc = rp__volume_size(ctx, path, "field 'dim'", dims, *type, voxels,
                            &bytes)) != 0)
    return rc;
  if (*file_bytes == 8 && *voxels > ctx->desc.max_volume_bytes / 8)
    return rp__fail(ctx, RP_ERANGE,
                    "%s: field 'dim': %zu float64 voxels exceed the limit of "
                    "%llu bytes (rp_context_desc.max_volume_bytes)",
                    path, *voxels,
                    (unsigned long long)ctx->desc.max_volume_bytes);
  return 0;
}

/* ---- The header's first bytes, before nifticlib sees them --------------- */

typedef struct nifti_peek {
  int version; /* 1 (or Analyze), 2 */
  int swap;    /* the header is in the other byte order */
  int onefile; /* voxels in the header's file ("n+1", "n+2") */
  int datatype;
  int64_t dim[8];
  double vox_offset;
} nifti_peek;

static void swap_n(uint8_t *p, size_t n) {
  size_t i;
  for (i = 0; i < n / 2; i++) {
    uint8_t t = p[i];
    p[i] = p[n - 1 - i];
    p[n - 1 - i] = t;
  }
}

/* A field of the header, in native order. */
static void get_field(const uint8_t *h, size_t at, void *out, size_t n,
                      int swap) {
  uint8_t tmp[8];
  memcpy(tmp, h + at, n);
  if (swap)
    swap_n(tmp, n);
  memcpy(out, tmp, n);
}

/* Reads the first bytes of the header file `hname` (gzip or not) and
 * tells the version, byte order, sizes, type and data offset. */
static int peek_header(rp_context *ctx, const char *path, const char *hname,
                       nifti_peek *pk) {
  uint8_t h[540];
  int32_t size, swapped;
  int16_t s16;
  int got, i;
  float f;
  struct stat st;
  gzFile g;
  memset(pk, 0, sizeof *pk);
  /* A FIFO would block the open: regular files only, as volume_io.c. */
  if (stat(hname, &st) != 0)
    return rp__fail(ctx, RP_ENOENT, "%s: header %s: no such file", path,
                    hname);
  if (!S_ISREG(st.st_mode))
    return rp__fail(ctx, RP_EIO, "%s: header %s: not a regular file", path,
                    hname);
  g = gzopen(hname, "rb");
  if (g == NULL)
    return rp__fail(ctx, errno == ENOENT ? RP_ENOENT : RP_EIO,
                    "%s: cannot open header %s", path, hname);
  got = gzread(g, h, sizeof h);
  gzclose(g);
  if (got < 0)
    return rp__fail(ctx, RP_EIO, "%s: cannot read header %s (corrupt "
                    "gzip?)", path, hname);
  if (got < 4)
    return rp__fail(ctx, RP_ETRUNC, "%s: header truncated: %d bytes", path,
                    got);
  memcpy(&size, h, 4);
  swapped = size;
  swap_n((uint8_t *)&swapped, 4);
  if ((size == 348 || swapped == 348) && got < 348)
    return rp__fail(ctx, RP_ETRUNC,
                    "%s: header truncated: %d bytes, a NIfTI-1 header takes "
                    "348",
                    path, got);
  if (size == 348 || swapped == 348) {
    pk->version = 1;
    pk->swap = size != 348;
    get_field(h, 70, &s16, 2, pk->swap);
    pk->datatype = s16;
    for (i = 0; i < 8; i++) {
      get_field(h, 40 + 2 * (size_t)i, &s16, 2, pk->swap);
      pk->dim[i] = s16;
    }
    get_field(h, 108, &f, 4, pk->swap);
    pk->vox_offset = f;
    pk->onefile = memcmp(h + 344, "n+1", 4) == 0;
  } else if (size == 540 || swapped == 540) {
    if (got < 540)
      return rp__fail(ctx, RP_ETRUNC,
                      "%s: header truncated: %d bytes, a NIfTI-2 header "
                      "takes 540",
                      path, got);
    pk->version = 2;
    pk->swap = size != 540;
    get_field(h, 12, &s16, 2, pk->swap);
    pk->datatype = s16;
    for (i = 0; i < 8; i++)
      get_field(h, 16 + 8 * (size_t)i, &pk->dim[i], 8, pk->swap);
    {
      int64_t off;
      get_field(h, 168, &off, 8, pk->swap);
      pk->vox_offset = (double)off;
    }
    pk->onefile = memcmp(h + 4, "n+2", 4) == 0;
  } else {
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: sizeof_hdr %d is neither 348 (NIfTI-1, Analyze) nor "
                    "540 (NIfTI-2)",
                    path, (int)size);
  }
  if (!isfinite(pk->vox_offset) || pk->vox_offset < 0)
    return rp__fail(ctx, RP_EFORMAT, "%s: vox_offset %g is not a byte "
                    "offset", path, pk->vox_offset);
  return 0;
}

/* The checks nifticlib's reading must not come before: sizes, type and a
 * data offset that the file can hold. */
static int precheck(rp_context *ctx, const char *path, const char *hname,
                    nifti_peek *pk) {
  struct stat st;
  rp_voxel_type type;
  uint64_t dims[3] = {0, 0, 0};
  size_t voxels = 0;
  int rc, file_bytes;
  if ((rc = peek_header(ctx, path, hname, pk)) != 0)
    return rc;
  if ((rc = check_size(ctx, path, pk->dim, pk->datatype, dims, &type,
                       &file_bytes, &voxels)) != 0)
    return rc;
  /* Extensions lie between the header and vox_offset, and nifticlib
   * allocates what they claim up to there: the offset must be one the
   * file can hold (a gzip stream inflates at most about 1032 times). */
  if (pk->onefile && stat(hname, &st) == 0) {
    double cap = (double)st.st_size * (ends_with(hname, ".gz") ? 1032 : 1);
    if (pk->vox_offset > cap)
      return rp__fail(ctx, RP_ETRUNC,
                      "%s: vox_offset %.0f lies past the end of the file "
                      "(%lld bytes)",
                      path, pk->vox_offset, (long long)st.st_size);
  }
  return 0;
}

/* ---- Voxels ------------------------------------------------------------- */

/* Reads `bytes` bytes at `offset` of the data file into memory from
 * rp__malloc. */
static int read_voxels(rp_context *ctx, const char *path, const char *iname,
                       int64_t offset, size_t bytes, uint8_t **out) {
  struct stat st;
  uint8_t *data;
  size_t done = 0;
  gzFile g;
  if (stat(iname, &st) != 0)
    return rp__fail(ctx, RP_ENOENT, "%s: data file %s: no such file", path,
                    iname);
  if (!S_ISREG(st.st_mode))
    return rp__fail(ctx, RP_EIO, "%s: data file %s: not a regular file",
                    path, iname);
  if ((g = gzopen(iname, "rb")) == NULL)
    return rp__fail(ctx, RP_EIO, "%s: data file %s: cannot open", path,
                    iname);
  data = rp__malloc(ctx, bytes > 0 ? bytes : 1);
  if (data == NULL) {
    gzclose(g);
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory for %zu bytes", path,
                    bytes);
  }
  if (gzseek(g, (z_off_t)offset, SEEK_SET) != (z_off_t)offset) {
    rp__free(ctx, data);
    gzclose(g);
    return rp__fail(ctx, RP_ETRUNC, "%s: data file %s ends before "
                    "vox_offset %lld", path, iname, (long long)offset);
  }
  while (done < bytes) {
    unsigned want = bytes - done > (1u << 30) ? 1u << 30
                                              : (unsigned)(bytes - done);
    int got = gzread(g, data + done, want);
    if (got <= 0)
      break;
    done += (size_t)got;
  }
  gzclose(g);
  if (done < bytes) {
    rp__free(ctx, data);
    return rp__fail(ctx, RP_ETRUNC,
                    "%s: data truncated: %zu of %zu bytes after vox_offset "
                    "%lld in %s",
                    path, done, bytes, (long long)offset, iname);
  }
  *out = data;
  return 0;
}

static void swap_voxels(uint8_t *p, size_t count, int size) {
  size_t i;
  if (size > 1)
    for (i = 0; i < count; i++)
      swap_n(p + i * (size_t)size, (size_t)size);
}

/* Voxel i of a buffer of the given NIfTI datatype, as a double. */
static double value_at(const uint8_t *p, int code, size_t i) {
  switch (code) {
  case DT_UINT8: return p[i];
  case DT_INT8: return (int8_t)p[i];
  case DT_INT16: { int16_t v; memcpy(&v, p + 2 * i, 2); return v; }
  case DT_UINT16: { uint16_t v; memcpy(&v, p + 2 * i, 2); return v; }
  case DT_INT32: { int32_t v; memcpy(&v, p + 4 * i, 4); return v; }
  case DT_UINT32: { uint32_t v; memcpy(&v, p + 4 * i, 4); return v; }
  case DT_FLOAT32: { float v; memcpy(&v, p + 4 * i, 4); return v; }
  default: { double v; memcpy(&v, p + 8 * i, 8); return v; }
  }
}

/* Rewrites the voxels as `slope * v + inter` (slope 1, inter 0 for a
 * plain conversion) in the type the policy says: int16 for integer data
 * with integer scaling whose results fit, float32 otherwise. *data is
 * replaced. */
static int convert(rp_context *ctx, const char *path, int code,
                   size_t voxels, double slope, double inter,
                   uint8_t **data, rp_voxel_type *type) {
  int integer = code != DT_FLOAT32 && code != DT_FLOAT64;
  int to_s16 = integer && slope == floor(slope) && inter == floor(inter);
  uint8_t *out;
  size_t i;
  for (i = 0; to_s16 && i < voxels; i++) {
    double v = slope * value_at(*data, code, i) + inter;
    to_s16 = v >= INT16_MIN && v <= INT16_MAX;
  }
  out = rp__malloc(ctx, voxels * (to_s16 ? 2 : 4) + 1);
  if (out == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory", path);
  for (i = 0; i < voxels; i++) {
    double v = slope * value_at(*data, code, i) + inter;
    if (to_s16) {
      int16_t s = (int16_t)v;
      memcpy(out + 2 * i, &s, 2);
      continue;
    }
    if (!isfinite(v) || fabs(v) > FLT_MAX) {
      rp__free(ctx, out);
      return rp__fail(ctx, RP_ENOTFINITE,
                      "%s: voxel %zu: value %g (stored %g, scl_slope %g, "
                      "scl_inter %g) is not a finite float32",
                      path, i, v, value_at(*data, code, i), slope, inter);
    }
    {
      float f = (float)v;
      memcpy(out + 4 * i, &f, 4);
    }
  }
  rp__free(ctx, *data);
  *data = out;
  *type = to_s16 ? RP_S16 : RP_F32;
  return 0;
}

/* ---- Geometry ------------------------------------------------------------ */

/* Orientation (LPS) and spacing from a RAS+ transform; 0, or an error when
 * the transform is not a rotation times spacings. */
static int from_matrix(rp_context *ctx, const char *what,
                       const nifti_dmat44 *m, rp_orientation *o,
                       float spacing[3]) {
  static const double lps[3] = {-1.0, -1.0, 1.0};
  rp_orientation raw;
  int i, j;
  memset(&raw, 0, sizeof raw);
  raw.known = 1;
  for (j = 0; j < 3; j++) {
    double len = 0.0;
    for (i = 0; i < 3; i++)
      len += m->m[i][j] * m->m[i][j];
    len = sqrt(len);
    if (!(len >= RP_SPACING_MIN && len <= RP_SPACING_MAX))
      return rp__fail(ctx, RP_ERANGE, "%s: column %d has length %g; a "
                      "voxel size must be in [%g, %g] (RP_SPACING_MIN/MAX)",
                      what, j, len, RP_SPACING_MIN, RP_SPACING_MAX);
    spacing[j] = (float)len;
    for (i = 0; i < 3; i++)
      raw.direction[3 * j + i] = lps[i] * m->m[i][j] / len;
  }
  for (i = 0; i < 3; i++)
    raw.origin[i] = lps[i] * m->m[i][3];
  return rp__orientation_check(ctx, what, &raw, o);
}

static int geometry(rp_context *ctx, const char *path, const nifti_image *nim,
                    rp_orientation *o, float spacing[3]) {
  char what[1100];
  int i, rc = 1;
  rp__orientation_check(ctx, path, NULL, o); /* not known: the identity */
  if (nim->sform_code > 0) {
    snprintf(what, sizeof what, "%s: sform (srow_x/y/z)", path);
    rc = from_matrix(ctx, what, &nim->sto_xyz, o, spacing);
    if (rc == 0 || nim->qform_code <= 0)
      return rc;
  }
  if (nim->qform_code > 0) {
    snprintf(what, sizeof what, "%s: qform (quatern_*, qoffset_*, pixdim)",
             path);
    return from_matrix(ctx, what, &nim->qto_xyz, o, spacing);
  }
  for (i = 0; i < 3; i++) {
    double d = fabs(nim->pixdim[i + 1]);
    char num[32];
    snprintf(num, sizeof num, "%g", nim->pixdim[i + 1]);
    if ((rc = rp__header_spacing(ctx, path, "pixdim", i + 1, num, d,
                                 &spacing[i])) != 0)
      return rc;
  }
  return 0;
}

/* ---- Loading ------------------------------------------------------------ */

/* Header read and checked: the voxels, their conversion, the volume. */
static int load_image(rp_context *ctx, const char *path,
                      const nifti_image *nim, rp_volume **out) {
  rp_orientation orient;
  rp_voxel_type type;
  uint64_t d64[3] = {0, 0, 0};
  uint32_t dims[3];
  float spacing[3];
  size_t voxels = 0;
  uint8_t *data = NULL;
  double slope = nim->scl_slope, inter = nim->scl_inter;
  int rc, file_bytes, scaled, i;
  /* Again on what nifticlib made of the header: the voxels follow it. */
  if ((rc = check_size(ctx, path, nim->dim, nim->datatype, d64, &type,
                       &file_bytes, &voxels)) != 0)
    return rc;
  if ((rc = geometry(ctx, path, nim, &orient, spacing)) != 0)
    return rc;
  scaled = slope != 0.0 && !(slope == 1.0 && inter == 0.0);
  if (scaled && (!isfinite(slope) || !isfinite(inter)))
    return rp__fail(ctx, RP_ENOTFINITE,
                    "%s: scl_slope %g, scl_inter %g: not finite", path, slope,
                    inter);
  rc = read_voxels(ctx, path, nim->iname, nim->iname_offset,
                   voxels * (size_t)file_bytes, &data);
  if (rc != 0 || data == NULL) /* data is set exactly when rc is 0 */
    return rc != 0 ? rc : RP_ENOMEM;
  if (nim->byteorder != nifti_short_order())
    swap_voxels(data, voxels, file_bytes);
  if (scaled || file_bytes == 8)
    rc = convert(ctx, path, nim->datatype, voxels, scaled ? slope : 1.0,
                 scaled ? inter : 0.0, &data, &type);
  if (rc != 0) {
    rp__free(ctx, data);
    return rc;
  }
  for (i = 0; i < 3; i++)
    dims[i] = (uint32_t)d64[i];
  rc = rp__volume_adopt(ctx, dims, type, spacing, data, out);
  if (rc != 0) {
    char msg[RP__ERRMSG_MAX];
    snprintf(msg, sizeof msg, "%s", rp_last_error(ctx));
    return rp__fail(ctx, rc, "%s: %s", path, msg);
  }
  (*out)->orientation = orient;
  return 0;
}

static pthread_once_t quiet_once = PTHREAD_ONCE_INIT;

static void quiet_nifticlib(void) { nifti_set_debug_level(0); }

int rp__nifti_load(rp_context *ctx, const char *path, rp_volume **out) {
  nifti_peek pk;
  nifti_image *nim;
  char *hname;
  int rc;
  /* nifticlib reports through stderr; every failure here says why
   * itself. The level is a process-wide setting of the library's, set
   * once so that loads on several threads do not race on it. */
  pthread_once(&quiet_once, quiet_nifticlib);
  hname = nifti_findhdrname(path);
  if (hname == NULL)
    return rp__fail(ctx, RP_ENOENT,
                    "%s: no NIfTI header found for it (.nii, or .hdr beside "
                    ".img)",
                    path);
  rc = precheck(ctx, path, hname, &pk);
  free(hname);
  if (rc != 0)
    return rc;
  nim = nifti_image_read(path, 0);
  if (nim == NULL)
    return rp__fail(ctx, RP_EFORMAT, "%s: not a readable NIfTI header",
                    path);
  rc = load_image(ctx, path, nim, out);
  nifti_image_free(nim);
  return rc;
}

#endif /* RP_WITH_NIFTI */
