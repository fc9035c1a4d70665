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

/* ---- CT head in HU --------------------------------------------------------- */

/* Normalised ellipsoid radius of (x, y, z): < 1 inside. */
static double ell(double x, double y, double z, double cx, double cy,
                  double cz, double rx, double ry, double rz) {
  double a = (x - cx) / rx, b = (y - cy) / ry, c = (z - cz) / rz;
  return sqrt(a * a + b * b + c * c);
}

/* Paints `hu` over `v` with coverage m in [0, 1] (partial volume). */
static double paint(double v, double hu, double m) {
  return v + m * (hu - v);
}

/* A CT head in HU, in patient coordinates: x towards the patient's left,
 * y posterior, z superior (LPS), all in [-1, 1]. Each tissue is painted
 * over the one outside it, edges blurred over about a voxel of a 160^3
 * grid, with the values of the usual tables (air -1000, fat about -90,
 * soft tissue and skin 30-60, brain 30-40, CSF 5, cancellous bone about
 * 700, cortical 1500, iodinated contrast 300). The nose points anterior
 * and the spine runs inferior, so a wrong view shows at once. */
static double ct_head(double x, double y, double z) {
  const double w = 0.045;
  double cran = ell(x, y, z, 0, 0.05, 0.18, 0.62, 0.74, 0.70);
  double face = ell(x, y, z, 0, -0.25, -0.22, 0.50, 0.52, 0.45);
  double nose = ell(x, y, z, 0, -0.74, -0.08, 0.08, 0.14, 0.18);
  double neck = sqrt(x * x / (0.34 * 0.34) +
                     (y - 0.12) * (y - 0.12) / (0.36 * 0.36));
  double spine = sqrt(x * x + (y - 0.25) * (y - 0.25)) / 0.10;
  double body, v = -1000.0, m;
  int i;
  /* The neck ends below the skull base: its top blends into the face. */
  body = fmin(fmin(cran, face), nose);
  if (z < -0.3)
    body = fmin(body, neck);
  v = paint(v, 40.0, inside(body - 1.0, w));      /* skin */
  v = paint(v, -90.0, inside(body - 0.96, w));    /* subcutaneous fat */
  v = paint(v, 50.0, inside(body - 0.92, w) * (z < -0.3 ? 1.0 : 0.0));
  v = paint(v, 45.0, inside(face - 0.92, w));     /* facial muscle */
  /* Skull: cortical tables with cancellous bone between. */
  v = paint(v, 1500.0, inside(cran - 0.93, w));
  v = paint(v, 700.0, inside(cran - 0.91, w));
  v = paint(v, 1300.0, inside(cran - 0.88, w));
  v = paint(v, 8.0, inside(cran - 0.865, w));     /* CSF around the brain */
  m = inside(cran - 0.85, w);
  v = paint(v, 33.0 + 5.0 * sin(14.0 * x) * sin(11.0 * y) * sin(9.0 * z),
            m);                                    /* grey and white */
  for (i = -1; i <= 1; i += 2) {
    double vent = ell(x, y, z, 0.10 * i, 0.08, 0.25, 0.06, 0.22, 0.10);
    double eye = ell(x, y, z, 0.23 * i, -0.56, 0.0, 0.10, 0.10, 0.10);
    double orbit = ell(x, y, z, 0.23 * i, -0.53, 0.0, 0.14, 0.14, 0.14);
    double carotid = sqrt((x - 0.2 * i) * (x - 0.2 * i) +
                          (y + 0.02) * (y + 0.02)) / 0.035;
    v = paint(v, 5.0, inside(vent - 1.0, w));
    v = paint(v, 1200.0, inside(orbit - 1.0, w) -
                             inside(orbit - 0.85, w)); /* orbital rim */
    v = paint(v, -90.0, inside(orbit - 0.85, w));
    v = paint(v, 12.0, inside(eye - 1.0, w));
    if (z < 0.05) /* up the neck into the skull base */
      v = paint(v, 300.0, inside(carotid - 1.0, 0.3));
  }
  if (z < -0.25) { /* vertebral bodies and the discs between them */
    double disc = fabs(fmod(z + 2.0, 0.14) - 0.07) < 0.015 ? 1.0 : 0.0;
    v = paint(v, disc > 0.0 ? 80.0 : 750.0, inside(spine - 1.0, 0.2));
    v = paint(v, 1400.0, inside(spine - 1.0, 0.2) - inside(spine - 0.8, 0.2));
  }
  return v;
}

static int ct_head_volume(rp_context *ctx, const rp_generate_desc *desc,
                          rp_volume **out) {
  uint64_t d64[3] = {desc->dims[0], desc->dims[1], desc->dims[2]};
  size_t voxels = 0, bytes = 0, idx = 0;
  int16_t *data;
  uint32_t i, j, k;
  int err;
  if (desc->type != 0 && desc->type != RP_S16)
    return rp__fail(ctx, RP_EUNSUPPORTED, "rp_volume_generate: field "
                    "'type': value %d (the CT head is int16 HU)",
                    (int)desc->type);
  err = rp__volume_size(ctx, "rp_volume_generate", "field 'dims'", d64,
                        RP_S16, &voxels, &bytes);
  if (err != 0)
    return err;
  if ((data = rp__malloc(ctx, bytes)) == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_volume_generate: cannot allocate "
                    "%zu bytes", bytes);
  for (k = 0; k < desc->dims[2]; k++) {
    double z = 2.0 * (k + 0.5) / desc->dims[2] - 1.0;
    for (j = 0; j < desc->dims[1]; j++) {
      double y = 2.0 * (j + 0.5) / desc->dims[1] - 1.0;
      for (i = 0; i < desc->dims[0]; i++, idx++) {
        double x = 2.0 * (i + 0.5) / desc->dims[0] - 1.0;
        data[idx] = (int16_t)floor(ct_head(x, y, z) + 0.5);
      }
    }
  }
  err = rp__volume_adopt(ctx, desc->dims, RP_S16, NULL, data, out);
  if (err == 0) { /* voxel axes along LPS, centred on the origin */
    rp_volume *v = *out;
    int a;
    v->orientation.known = 1;
    for (a = 0; a < 3; a++)
      v->orientation.origin[a] = -0.5 * (v->dims[a] - 1) * v->spacing[a];
  }
  return err;
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
  if (desc->kind == RP_GEN_CT_HEAD)
    return ct_head_volume(ctx, desc, out);
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
