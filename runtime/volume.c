/* Volumes in memory: creation, validation, range, info. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bounds.h"
#include "internal.h"

size_t rp__voxel_size(rp_voxel_type type) {
  switch (type) {
  case RP_U8: return 1;
  case RP_U16: return 2;
  case RP_F32: return 4;
  case RP_S8: return 1;
  case RP_S16: return 2;
  case RP_U32: return 4;
  case RP_S32: return 4;
  default: return 0;
  }
}

const char *rp_voxel_type_name(rp_voxel_type type) {
  switch (type) {
  case RP_U8: return "uint8";
  case RP_U16: return "uint16";
  case RP_F32: return "float32";
  case RP_S8: return "int8";
  case RP_S16: return "int16";
  case RP_U32: return "uint32";
  case RP_S32: return "int32";
  default: return "unknown";
  }
}

/* rp__volume_size's checks; `memory` adds the check against the memory
 * the machine has, which only a caller that has not yet allocated the
 * voxels can make. */
static int volume_size(rp_context *ctx, const char *what, const char *field,
                       const uint64_t dims[3], rp_voxel_type type,
                       int memory, size_t *voxels, size_t *bytes) {
  uint64_t n = 1, b;
  size_t vs = rp__voxel_size(type);
  char ask[200];
  int a;
  if (vs == 0)
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: field 'type': value %d is "
                    "not a voxel type", what, (int)type);
  for (a = 0; a < 3; a++) {
    if (dims[a] == 0)
      return rp__fail(ctx, RP_ERANGE, "%s: %s: axis %d is 0 "
                      "(every axis needs at least one voxel)", what, field, a);
    if (__builtin_mul_overflow(n, dims[a], &n))
      return rp__fail(ctx, RP_ERANGE, "%s: %s: %llu x %llu x "
                      "%llu voxels overflow 64 bits", what, field,
                      (unsigned long long)dims[0],
                      (unsigned long long)dims[1],
                      (unsigned long long)dims[2]);
  }
  for (a = 0; a < 3; a++)
    if (dims[a] > RP_VOLUME_MAX_DIM)
      return rp__fail(ctx, RP_ERANGE, "%s: %s: axis %d is %llu voxels; "
                      "must be in [1, %u] (RP_VOLUME_MAX_DIM)", what, field,
                      a, (unsigned long long)dims[a], RP_VOLUME_MAX_DIM);
  if (__builtin_mul_overflow(n, (uint64_t)vs, &b) || b > SIZE_MAX ||
      b > ctx->desc.max_volume_bytes)
    return rp__fail(ctx, RP_ERANGE, "%s: %s: %llu x %llu x %llu "
                    "%s voxels exceed the limit of %llu bytes "
                    "(rp_context_desc.max_volume_bytes)", what, field,
                    (unsigned long long)dims[0], (unsigned long long)dims[1],
                    (unsigned long long)dims[2], rp_voxel_type_name(type),
                    (unsigned long long)ctx->desc.max_volume_bytes);
  snprintf(ask, sizeof ask, "%s: %llu x %llu x %llu %s voxels", what,
           (unsigned long long)dims[0], (unsigned long long)dims[1],
           (unsigned long long)dims[2], rp_voxel_type_name(type));
  if (memory && rp__check_memory(ctx, ask, b) != 0)
    return RP_ENOMEM;
  *voxels = (size_t)n;
  *bytes = (size_t)b;
  return 0;
}

int rp__volume_size(rp_context *ctx, const char *what, const char *field,
                    const uint64_t dims[3], rp_voxel_type type,
                    size_t *voxels, size_t *bytes) {
  return volume_size(ctx, what, field, dims, type, 1, voxels, bytes);
}

int rp__spacing_check(rp_context *ctx, const char *where, const char *field,
                      int axis, double v) {
  char name[96];
  snprintf(name, sizeof name, axis >= 0 ? "%s[%d]" : "%s", field, axis);
  if (v >= RP_SPACING_MIN && v <= RP_SPACING_MAX)
    return 0;
  /* A float the caller gave reads as that float ("1e-09"), a double
   * from a file as itself. */
  rp__check_range(ctx, where, name, v, (double)(float)v == v,
                  RP_SPACING_MIN, RP_SPACING_MAX,
                  "(a length: mm for CT and MRI)", NULL);
  return isfinite(v) ? RP_ERANGE : RP_ENOTFINITE;
}

/* `where` and `field` name the spacing as its caller took it. */
static int check_spacing(rp_context *ctx, const char *where,
                         const char *field, const float in[3], float out[3]) {
  int a, err;
  for (a = 0; a < 3; a++) {
    float s = in != NULL ? in[a] : 0.0f;
    if (s == 0.0f)
      s = 1.0f;
    if ((err = rp__spacing_check(ctx, where, field, a, s)) != 0)
      return err;
    out[a] = s;
  }
  return 0;
}

/* min/max in one pass; float data is checked for NaN/inf on the way, since
 * every later stage (histogram bins, TF position) assumes finite values. */
static int compute_range(rp_context *ctx, rp_volume *v) {
  size_t i, n = v->voxel_count;
  if (v->type == RP_U8) {
    const uint8_t *p = v->data;
    uint8_t lo = 255, hi = 0;
    for (i = 0; i < n; i++) {
      lo = p[i] < lo ? p[i] : lo;
      hi = p[i] > hi ? p[i] : hi;
    }
    v->min = lo, v->max = hi;
  } else if (v->type == RP_U16) {
    const uint16_t *p = v->data;
    uint16_t lo = 65535, hi = 0;
    for (i = 0; i < n; i++) {
      lo = p[i] < lo ? p[i] : lo;
      hi = p[i] > hi ? p[i] : hi;
    }
    v->min = lo, v->max = hi;
  } else {
    const float *p = v->data;
    float lo = INFINITY, hi = -INFINITY;
    for (i = 0; i < n; i++) {
      if (!isfinite(p[i])) {
        size_t x = i % v->dims[0], y = (i / v->dims[0]) % v->dims[1];
        size_t z = i / ((size_t)v->dims[0] * v->dims[1]);
        return rp__fail(ctx, RP_ENOTFINITE, "voxel (%zu, %zu, %zu): value "
                        "%g is not finite", x, y, z, (double)p[i]);
      }
      lo = p[i] < lo ? p[i] : lo;
      hi = p[i] > hi ? p[i] : hi;
    }
    v->min = lo, v->max = hi;
  }
  return 0;
}

static int cmp_float(const void *a, const void *b) {
  float x = *(const float *)a, y = *(const float *)b;
  return (x > y) - (x < y);
}

/* The per-mille quantiles of the stored values. Integer types are counted
 * exactly; float volumes are sorted on an even subsample of at most 2^20
 * voxels (a percentile off by about 1/1000 of the voxels at worst: the
 * table's own resolution). */
static int compute_quantiles(rp_context *ctx, rp_volume *v) {
  size_t i, n = v->voxel_count;
  int q;
  if (v->type == RP_F32) {
    size_t stride = n > ((size_t)1 << 20) ? n / ((size_t)1 << 20) : 1;
    size_t m = (n + stride - 1) / stride, k = 0;
    float *s = rp__malloc(ctx, m * sizeof *s);
    const float *p = v->data;
    if (s == NULL)
      return rp__fail(ctx, RP_ENOMEM, "volume: out of memory");
    for (i = 0; i < n && k < m; i += stride)
      s[k++] = p[i];
    qsort(s, k, sizeof *s, cmp_float);
    for (q = 0; q < RP__QUANTILES; q++)
      v->quantile[q] = s[(size_t)((double)q / (RP__QUANTILES - 1) *
                                  (double)(k - 1) + 0.5)];
    rp__free(ctx, s);
    return 0;
  }
  {
    size_t bins = v->type == RP_U8 ? 256 : 65536, b = 0;
    uint64_t *count = rp__calloc(ctx, bins, sizeof *count), seen = 0;
    if (count == NULL)
      return rp__fail(ctx, RP_ENOMEM, "volume: out of memory");
    if (v->type == RP_U8)
      for (i = 0; i < n; i++)
        count[((const uint8_t *)v->data)[i]]++;
    else
      for (i = 0; i < n; i++)
        count[((const uint16_t *)v->data)[i]]++;
    /* quantile q: the smallest value whose cumulative count reaches the
     * rank round(q / 1000 * (n - 1)) + 1, as for the sorted sample. */
    for (q = 0; q < RP__QUANTILES; q++) {
      uint64_t rank = (uint64_t)((double)q / (RP__QUANTILES - 1) *
                                 (double)(n - 1) + 0.5) + 1;
      while (seen + count[b] < rank)
        seen += count[b++];
      v->quantile[q] = (float)b;
    }
    rp__free(ctx, count);
  }
  return 0;
}

void rp__volume_values(const rp_volume *v, rp__value_range *out) {
  out->type = v->type;
  out->min = v->min, out->max = v->max;
  out->offset = v->data_offset;
  memcpy(out->quantile, v->quantile, sizeof out->quantile);
}

/* Devices read three voxel types. The others are converted in place, each
 * to a type of the same size, so that a loader's buffer is adopted without
 * a second copy: int8 and int16 flip their sign bit (stored = value + 128
 * or + 32768, exact, order kept), 32-bit integers become float32 (exact up
 * to 2^24 in magnitude, within half a float ulp above). */
static void store_for_devices(rp_volume *v) {
  size_t i, n = v->voxel_count;
  switch (v->data_type) {
  case RP_S8: {
    uint8_t *p = v->data;
    for (i = 0; i < n; i++)
      p[i] ^= 0x80u;
    v->type = RP_U8, v->data_offset = -128.0;
    break;
  }
  case RP_S16: {
    uint16_t *p = v->data;
    for (i = 0; i < n; i++)
      p[i] ^= 0x8000u;
    v->type = RP_U16, v->data_offset = -32768.0;
    break;
  }
  case RP_U32: {
    uint32_t *p = v->data;
    float *f = v->data;
    for (i = 0; i < n; i++) {
      uint32_t u = p[i];
      f[i] = (float)u;
    }
    v->type = RP_F32;
    break;
  }
  case RP_S32: {
    int32_t *p = v->data;
    float *f = v->data;
    for (i = 0; i < n; i++) {
      int32_t u = p[i];
      f[i] = (float)u;
    }
    v->type = RP_F32;
    break;
  }
  default:
    v->type = v->data_type;
    break;
  }
}

int rp__volume_adopt(rp_context *ctx, const uint32_t dims[3],
                     rp_voxel_type type, const float spacing[3], void *data,
                     rp_volume **out) {
  rp_volume *v;
  uint64_t d64[3] = {dims[0], dims[1], dims[2]};
  size_t voxels = 0, bytes = 0;
  /* The voxels are allocated already: no memory check. */
  int err = volume_size(ctx, "volume", "field 'dims'", d64, type, 0,
                        &voxels, &bytes);
  if (err != 0) {
    rp__free(ctx, data);
    return err;
  }
  v = rp__calloc(ctx, 1, sizeof *v);
  if (v == NULL) {
    rp__free(ctx, data);
    return rp__fail(ctx, RP_ENOMEM, "volume: out of memory");
  }
  v->ctx = ctx;
  v->id = rp__next_id();
  memcpy(v->dims, dims, sizeof v->dims);
  v->data_type = type;
  v->orientation.direction[0] = 1.0; /* not known: the identity */
  v->orientation.direction[4] = 1.0;
  v->orientation.direction[8] = 1.0;
  v->voxel_count = voxels;
  v->data = data;
  store_for_devices(v);
  err = check_spacing(ctx, "volume", "spacing", spacing, v->spacing);
  if (err == 0)
    err = compute_range(ctx, v);
  if (err == 0)
    err = compute_quantiles(ctx, v);
  if (err != 0) {
    rp_volume_destroy(v); /* frees data too: the volume owns it now */
    return err;
  }
  *out = v;
  return 0;
}

int rp_volume_create(rp_context *ctx, const rp_volume_desc *desc,
                     rp_volume **out) {
  uint64_t d64[3];
  size_t voxels = 0, bytes = 0;
  rp_orientation orient;
  float spacing[3];
  void *copy;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (desc == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_volume_create: desc and out are "
                    "required");
  if (desc->data == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_volume_create: field 'data' is "
                    "NULL");
  err = rp__orientation_check(ctx, "rp_volume_create", &desc->orientation,
                              &orient);
  if (err != 0)
    return err;
  err = check_spacing(ctx, "rp_volume_create", "rp_volume_desc.spacing",
                      desc->spacing, spacing);
  if (err != 0)
    return err;
  d64[0] = desc->dims[0], d64[1] = desc->dims[1], d64[2] = desc->dims[2];
  err = rp__volume_size(ctx, "rp_volume_create", "field 'dims'", d64,
                        desc->type, &voxels,
                        &bytes);
  if (err != 0)
    return err;
  copy = rp__malloc(ctx, bytes);
  if (copy == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_volume_create: cannot allocate %zu "
                    "bytes", bytes);
  memcpy(copy, desc->data, bytes);
  err = rp__volume_adopt(ctx, desc->dims, desc->type, desc->spacing, copy,
                         out);
  if (err == 0)
    (*out)->orientation = orient;
  return err;
}

int rp__orientation_check(rp_context *ctx, const char *what,
                          const rp_orientation *in, rp_orientation *out) {
  int i, j;
  rp_orientation o;
  memset(&o, 0, sizeof o);
  o.direction[0] = o.direction[4] = o.direction[8] = 1.0;
  if (in == NULL || !in->known) {
    *out = o;
    return 0;
  }
  for (i = 0; i < 9; i++)
    if (!isfinite(in->direction[i]))
      return rp__fail(ctx, RP_ENOTFINITE, "%s: field 'orientation."
                      "direction[%d]': value %g is not finite", what, i,
                      in->direction[i]);
  for (i = 0; i < 3; i++)
    if (!isfinite(in->origin[i]))
      return rp__fail(ctx, RP_ENOTFINITE, "%s: field 'orientation."
                      "origin[%d]': value %g is not finite", what, i,
                      in->origin[i]);
  /* Files round directions to a few digits; 1e-3 accepts that and still
   * refuses a sheared or scaled grid, which this renderer cannot show. */
  for (j = 0; j < 3; j++) {
    const double *a = &in->direction[3 * j];
    double len = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    if (!(fabs(len - 1.0) < 1e-3))
      return rp__fail(ctx, RP_ERANGE, "%s: field 'orientation.direction': "
                      "column %d has length %g (each column is a unit "
                      "vector)", what, j, len);
    for (i = 0; i < j; i++) {
      const double *b = &in->direction[3 * i];
      double dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
      if (!(fabs(dot) < 1e-3))
        return rp__fail(ctx, RP_ERANGE, "%s: field 'orientation."
                        "direction': columns %d and %d are not orthogonal "
                        "(dot product %g): a sheared grid is not supported",
                        what, i, j, dot);
    }
    for (i = 0; i < 3; i++)
      o.direction[3 * j + i] = a[i] / len;
  }
  memcpy(o.origin, in->origin, sizeof o.origin);
  o.known = 1;
  *out = o;
  return 0;
}

void rp_volume_destroy(rp_volume *vol) {
  rp_context *ctx;
  if (vol == NULL)
    return;
  ctx = vol->ctx;
  rp__free(ctx, vol->data);
  rp__free(ctx, vol);
}

void rp_volume_get_info(const rp_volume *vol, rp_volume_info *info) {
  int a;
  if (vol == NULL || info == NULL)
    return;
  memset(info, 0, sizeof *info);
  for (a = 0; a < 3; a++) {
    info->dims[a] = vol->dims[a];
    info->spacing[a] = vol->spacing[a];
    info->blocks[a] = rp__blocks_along(vol->dims[a]);
  }
  info->type = vol->data_type;
  info->min = vol->min + vol->data_offset;
  info->max = vol->max + vol->data_offset;
  info->orientation = vol->orientation;
  info->stored_type = vol->type;
  info->stored_offset = vol->data_offset;
}

const void *rp_volume_data(const rp_volume *vol) {
  return vol != NULL ? vol->data : NULL;
}
