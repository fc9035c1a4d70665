/* Generated volumes: the demo and the tests must not need real data.
 *
 * Every generator maps voxel centres to [-1, 1]^3 and produces a value in
 * [0, 1] that is quantised to the full range of the voxel type, so 16-bit
 * volumes exercise the whole 0..65535 range. */
#include <math.h>
#include <string.h>

#include "internal.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

/* Marschner and Lobb (1994), "An evaluation of reconstruction filters for
 * volume rendering": f_M = 6, alpha = 0.25. */
static double marschner_lobb(double x, double y, double z) {
  const double fm = 6.0, alpha = 0.25;
  double r = sqrt(x * x + y * y);
  double rho_r = cos(2.0 * M_PI * fm * cos(M_PI * r / 2.0));
  return (1.0 - sin(M_PI * z / 2.0) + alpha * (1.0 + rho_r)) /
         (2.0 * (1.0 + alpha));
}

/* 1 inside (e < 0), 0 outside, linear across a band of width w: edges
 * blur over a voxel or two as in a real scan (partial volume), instead of
 * the staircase a hard threshold leaves under shading. */
static double inside(double e, double w) {
  double t = 0.5 - e / w;
  return t < 0.0 ? 0.0 : t > 1.0 ? 1.0 : t;
}

/* A CT-like phantom: air (exactly 0) around an ellipsoidal body of soft
 * tissue, a thin bony shell, a dense core and two small dense inclusions.
 * Most of the box is air, so empty-space skipping has real work to do, and
 * the core is opaque under bone presets, so early termination does too. */
static double phantom(double x, double y, double z) {
  double body = sqrt((x * x) / (0.80 * 0.80) + (y * y) / (0.65 * 0.65) +
                     (z * z) / (0.85 * 0.85));
  double core = sqrt(x * x + y * y + z * z) / 0.30;
  double i1 = sqrt((x - 0.45) * (x - 0.45) + y * y +
                   (z - 0.2) * (z - 0.2)) / 0.08;
  double i2 = sqrt((x + 0.4) * (x + 0.4) + (y - 0.25) * (y - 0.25) + z * z) /
              0.06;
  double tissue = 0.20 + 0.05 * sin(6.0 * x) * cos(5.0 * y);
  double v = tissue * inside(body - 1.0, 0.04);
  v = fmax(v, 0.45 * (inside(body - 1.0, 0.04) - inside(body - 0.96, 0.04)));
  v = fmax(v, (0.85 + 0.15 * fmax(0.0, 1.0 - core)) * inside(core - 1.0, 0.1));
  v = fmax(v, 0.95 * fmax(inside(i1 - 1.0, 0.3), inside(i2 - 1.0, 0.3)));
  return v;
}

/* splitmix64 (Steele, Lea, Flood 2014): tiny, seedable, good enough to
 * make noise that defeats every kind of skipping. */
static uint64_t splitmix64(uint64_t *s) {
  uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

int rp_volume_generate(rp_context *ctx, const rp_generate_desc *desc,
                       rp_volume **out) {
  uint64_t d64[3], state;
  size_t voxels = 0, bytes = 0, idx = 0;
  rp_voxel_type type;
  double qmax;
  void *data;
  uint32_t i, j, k;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (desc == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_volume_generate: desc and out are "
                    "required");
  type = desc->type != 0 ? desc->type : RP_U8;
  if (type != RP_U8 && type != RP_U16)
    return rp__fail(ctx, RP_EUNSUPPORTED, "rp_volume_generate: field "
                    "'type': value %d (generators make uint8 or uint16)",
                    (int)desc->type);
  if (desc->kind < RP_GEN_MARSCHNER_LOBB || desc->kind > RP_GEN_NOISE)
    return rp__fail(ctx, RP_EINVAL, "rp_volume_generate: field 'kind': "
                    "value %d is not a generator", (int)desc->kind);
  d64[0] = desc->dims[0], d64[1] = desc->dims[1], d64[2] = desc->dims[2];
  err = rp__volume_size(ctx, "rp_volume_generate", "field 'dims'", d64,
                        type, &voxels,
                        &bytes);
  if (err != 0)
    return err;
  data = rp__malloc(ctx, bytes);
  if (data == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_volume_generate: cannot allocate "
                    "%zu bytes", bytes);
  qmax = type == RP_U8 ? 255.0 : 65535.0;
  state = desc->seed;
  for (k = 0; k < desc->dims[2]; k++) {
    double z = 2.0 * (k + 0.5) / desc->dims[2] - 1.0;
    for (j = 0; j < desc->dims[1]; j++) {
      double y = 2.0 * (j + 0.5) / desc->dims[1] - 1.0;
      for (i = 0; i < desc->dims[0]; i++, idx++) {
        double x = 2.0 * (i + 0.5) / desc->dims[0] - 1.0, v;
        if (desc->kind == RP_GEN_MARSCHNER_LOBB)
          v = marschner_lobb(x, y, z);
        else if (desc->kind == RP_GEN_PHANTOM)
          v = phantom(x, y, z);
        else
          v = (double)(splitmix64(&state) >> 11) / 9007199254740992.0;
        v = floor(v * qmax + 0.5);
        v = v < 0 ? 0 : v > qmax ? qmax : v;
        if (type == RP_U8)
          ((uint8_t *)data)[idx] = (uint8_t)v;
        else
          ((uint16_t *)data)[idx] = (uint16_t)v;
      }
    }
  }
  return rp__volume_adopt(ctx, desc->dims, type, NULL, data, out);
}
