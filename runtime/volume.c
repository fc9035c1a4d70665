/* Volumes in memory: creation, validation, range, info. */
#include <math.h>
#include <string.h>

#include "internal.h"

size_t rp__voxel_size(rp_voxel_type type) {
  switch (type) {
  case RP_U8: return 1;
  case RP_U16: return 2;
  case RP_F32: return 4;
  default: return 0;
  }
}

const char *rp_voxel_type_name(rp_voxel_type type) {
  switch (type) {
  case RP_U8: return "uint8";
  case RP_U16: return "uint16";
  case RP_F32: return "float32";
  default: return "unknown";
  }
}

int rp__volume_size(rp_context *ctx, const char *what, const char *field,
                    const uint64_t dims[3], rp_voxel_type type,
                    size_t *voxels, size_t *bytes) {
  uint64_t n = 1, b;
  size_t vs = rp__voxel_size(type);
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
  if (__builtin_mul_overflow(n, (uint64_t)vs, &b) || b > SIZE_MAX ||
      b > ctx->desc.max_volume_bytes)
    return rp__fail(ctx, RP_ERANGE, "%s: %s: %llu x %llu x %llu "
                    "%s voxels exceed the limit of %llu bytes "
                    "(rp_context_desc.max_volume_bytes)", what, field,
                    (unsigned long long)dims[0], (unsigned long long)dims[1],
                    (unsigned long long)dims[2], rp_voxel_type_name(type),
                    (unsigned long long)ctx->desc.max_volume_bytes);
  if (dims[0] > UINT32_MAX || dims[1] > UINT32_MAX || dims[2] > UINT32_MAX)
    return rp__fail(ctx, RP_ERANGE, "%s: %s: an axis exceeds "
                    "2^32 - 1 voxels", what, field);
  *voxels = (size_t)n;
  *bytes = (size_t)b;
  return 0;
}

static int check_spacing(rp_context *ctx, const float in[3], float out[3]) {
  int a;
  for (a = 0; a < 3; a++) {
    float s = in != NULL ? in[a] : 0.0f;
    if (s == 0.0f)
      s = 1.0f;
    if (!isfinite(s))
      return rp__fail(ctx, RP_ENOTFINITE, "field 'spacing[%d]': value %g is "
                      "not finite", a, (double)s);
    if (s < 0.0f)
      return rp__fail(ctx, RP_ERANGE, "field 'spacing[%d]': value %g must "
                      "be > 0", a, (double)s);
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

int rp__volume_adopt(rp_context *ctx, const uint32_t dims[3],
                     rp_voxel_type type, const float spacing[3], void *data,
                     rp_volume **out) {
  rp_volume *v;
  uint64_t d64[3] = {dims[0], dims[1], dims[2]};
  size_t voxels = 0, bytes = 0;
  int err = rp__volume_size(ctx, "volume", "field 'dims'", d64, type,
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
  v->type = type;
  v->data_type = type;
  v->voxel_count = voxels;
  v->data = data;
  err = check_spacing(ctx, spacing, v->spacing);
  if (err == 0)
    err = compute_range(ctx, v);
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
  return rp__volume_adopt(ctx, desc->dims, desc->type, desc->spacing, copy,
                          out);
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
}

const void *rp_volume_data(const rp_volume *vol) {
  return vol != NULL ? vol->data : NULL;
}
