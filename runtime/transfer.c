/* Transfer functions: control points -> lookup table, presets, opacity
 * correction.
 *
 * The LUT read with linear interpolation IS the transfer function: the
 * renderer, the opacity histograms and the occupancy grid all read the same
 * piecewise-linear function through rp__tf_sample, rp__tf_alpha_mean and
 * rp__tf_alpha_max. Had the histograms integrated the control points while
 * the renderer read the table, a point of zero opacity between two table
 * entries could make the grid call a block empty that the renderer sees. */
#include <math.h>
#include <string.h>

#include "internal.h"

#define RP__LUT_DEFAULT 1024
#define RP__LUT_MAX 65536

float rp_opacity_correct(float alpha, float step, float ref_step) {
  double r, a;
  /* Exact at both ends and independent of the step: a transparent sample
   * stays transparent and an opaque one opaque. log1p(-1) would be -inf. */
  if (!(alpha > 0.0f))
    return 0.0f;
  if (alpha >= 1.0f)
    return 1.0f;
  r = (double)step / (double)ref_step;
  if (!(r > 0.0) || !isfinite(r))
    return NAN; /* callers validate steps; make a bad one visible */
  /* 1 - (1-a)^r loses everything to cancellation when a or r is small;
   * the log1p/expm1 form keeps full relative precision, and double keeps
   * the float result within one ulp. */
  a = -expm1(r * log1p(-(double)alpha));
  return (float)a;
}

static int check_unit(rp_context *ctx, int i, const char *field, float v) {
  if (!isfinite(v))
    return rp__fail(ctx, RP_ENOTFINITE, "transfer function: point %d field "
                    "'%s': value %g is not finite", i, field, (double)v);
  if (v < 0.0f || v > 1.0f)
    return rp__fail(ctx, RP_ERANGE, "transfer function: point %d field "
                    "'%s': value %g is outside [0, 1]", i, field, (double)v);
  return 0;
}

static int validate(rp_context *ctx, const rp_tf_desc *d) {
  int i, err;
  if (d->points == NULL || d->count < 1)
    return rp__fail(ctx, RP_EINVAL, "transfer function: field 'count': "
                    "value %d (at least one point is needed)", d->count);
  if (!isfinite(d->reference_step))
    return rp__fail(ctx, RP_ENOTFINITE, "transfer function: field "
                    "'reference_step': value %g is not finite",
                    (double)d->reference_step);
  if (d->reference_step < 0.0f)
    return rp__fail(ctx, RP_ERANGE, "transfer function: field "
                    "'reference_step': value %g must be > 0",
                    (double)d->reference_step);
  if (d->lut_size != 0 && (d->lut_size < 2 || d->lut_size > RP__LUT_MAX))
    return rp__fail(ctx, RP_ERANGE, "transfer function: field 'lut_size': "
                    "value %d is outside [2, %d]", d->lut_size, RP__LUT_MAX);
  for (i = 0; i < d->count; i++) {
    const rp_tf_point *p = &d->points[i];
    if ((err = check_unit(ctx, i, "x", p->x)) != 0 ||
        (err = check_unit(ctx, i, "r", p->r)) != 0 ||
        (err = check_unit(ctx, i, "g", p->g)) != 0 ||
        (err = check_unit(ctx, i, "b", p->b)) != 0 ||
        (err = check_unit(ctx, i, "a", p->a)) != 0)
      return err;
    if (i > 0 && !(p->x > d->points[i - 1].x))
      return rp__fail(ctx, RP_EINVAL, "transfer function: point %d field "
                      "'x': value %g does not exceed point %d's %g (points "
                      "must be strictly increasing)", i, (double)p->x, i - 1,
                      (double)d->points[i - 1].x);
  }
  return 0;
}

/* The control-point function at x, in double. */
static void eval_points(const rp_tf_desc *d, double x, double out[4]) {
  const rp_tf_point *p = d->points;
  int i = 0, c;
  double w;
  if (x <= p[0].x) {
    out[0] = p[0].r, out[1] = p[0].g, out[2] = p[0].b, out[3] = p[0].a;
    return;
  }
  if (x >= p[d->count - 1].x) {
    p += d->count - 1;
    out[0] = p->r, out[1] = p->g, out[2] = p->b, out[3] = p->a;
    return;
  }
  while (p[i + 1].x < x)
    i++;
  w = (x - p[i].x) / ((double)p[i + 1].x - p[i].x);
  for (c = 0; c < 4; c++) {
    const float *a = &p[i].r, *b = &p[i + 1].r;
    out[c] = a[c] + w * ((double)b[c] - a[c]);
  }
}

int rp_tf_create(rp_context *ctx, const rp_tf_desc *desc, rp_tf **out) {
  rp_tf *tf;
  int i, c, n, err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (desc == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_tf_create: desc and out are "
                    "required");
  if ((err = validate(ctx, desc)) != 0)
    return err;
  n = desc->lut_size != 0 ? desc->lut_size : RP__LUT_DEFAULT;
  tf = rp__calloc(ctx, 1, sizeof *tf);
  if (tf != NULL)
    tf->lut = rp__malloc(ctx, (size_t)n * 4 * sizeof(float));
  if (tf == NULL || tf->lut == NULL) {
    rp__free(ctx, tf);
    return rp__fail(ctx, RP_ENOMEM, "transfer function: out of memory");
  }
  tf->ctx = ctx;
  tf->id = rp__next_id();
  tf->lut_size = n;
  tf->reference_step =
      desc->reference_step != 0.0f ? desc->reference_step : 1.0f;
  for (i = 0; i < n; i++) {
    double v[4];
    eval_points(desc, (double)i / (n - 1), v);
    for (c = 0; c < 4; c++)
      tf->lut[4 * i + c] = (float)v[c];
  }
  *out = tf;
  return 0;
}

#define P(x, r, g, b, a) {(x), (r), (g), (b), (a)}

static const rp_tf_point preset_transparent[] = {P(0, 1, 1, 1, 0)};
static const rp_tf_point preset_opaque[] = {P(0, .85f, .85f, .85f, 1),
                                            P(1, 1, 1, 1, 1)};
static const rp_tf_point preset_ct_bone[] = {
    P(0, 0, 0, 0, 0), P(.30f, .80f, .60f, .45f, 0),
    P(.45f, .95f, .85f, .70f, .25f), P(.70f, 1, .97f, .90f, .70f),
    P(1, 1, 1, 1, .90f)};
static const rp_tf_point preset_ct_soft[] = {
    P(0, 0, 0, 0, 0), P(.08f, .70f, .30f, .25f, 0),
    P(.15f, .85f, .45f, .35f, .03f), P(.30f, .90f, .60f, .50f, .04f),
    P(.45f, .95f, .90f, .80f, .40f), P(1, 1, 1, 1, .90f)};
static const rp_tf_point preset_mri[] = {
    P(0, 0, 0, 0, 0), P(.10f, .50f, .40f, .35f, 0),
    P(.35f, .85f, .70f, .60f, .08f), P(.70f, 1, .92f, .85f, .50f),
    P(1, 1, 1, 1, .80f)};
static const rp_tf_point preset_ramp[] = {P(0, 0, 0, 0, 0),
                                          P(1, 1, 1, 1, 1)};
/* Costly on purpose: rays almost never terminate early, the opposite of
 * "opaque"; switching between the two is the abrupt change a frame-time
 * controller must survive. */
static const rp_tf_point preset_nearly_transparent[] = {
    P(0, 0, 0, 0, 0), P(.02f, .60f, .70f, 1, .004f), P(1, 1, 1, 1, .02f)};

#undef P

typedef struct preset {
  const char *name;
  const rp_tf_point *points;
  int count;
} preset;

#define PRESET(name, arr) {name, arr, (int)(sizeof arr / sizeof arr[0])}
static const preset presets[] = {
    PRESET("transparent", preset_transparent),
    PRESET("opaque", preset_opaque),
    PRESET("ct-bone", preset_ct_bone),
    PRESET("ct-soft", preset_ct_soft),
    PRESET("mri", preset_mri),
    PRESET("ramp", preset_ramp),
    PRESET("nearly-transparent", preset_nearly_transparent),
};
#undef PRESET

const char *const *rp_tf_preset_names(void) {
  static const char *const names[] = {
      "transparent", "opaque", "ct-bone", "ct-soft", "mri", "ramp",
      "nearly-transparent", NULL};
  return names;
}

int rp_tf_create_preset(rp_context *ctx, const char *name, rp_tf **out) {
  size_t i;
  if (ctx == NULL)
    return RP_EINVAL;
  if (name == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_tf_create_preset: name and out are "
                    "required");
  for (i = 0; i < sizeof presets / sizeof presets[0]; i++) {
    if (strcmp(presets[i].name, name) == 0) {
      rp_tf_desc d = {0};
      d.points = presets[i].points;
      d.count = presets[i].count;
      return rp_tf_create(ctx, &d, out);
    }
  }
  return rp__fail(ctx, RP_EINVAL, "transfer function preset '%s' is "
                  "unknown; known: transparent, opaque, ct-bone, ct-soft, "
                  "mri, ramp, nearly-transparent", name);
}

int rp__tf_clone(rp_context *ctx, const rp_tf *src, rp_tf **out) {
  size_t bytes = (size_t)src->lut_size * 4 * sizeof(float);
  rp_tf *tf = rp__calloc(ctx, 1, sizeof *tf);
  if (tf != NULL)
    tf->lut = rp__malloc(ctx, bytes);
  if (tf == NULL || tf->lut == NULL) {
    rp__free(ctx, tf);
    return rp__fail(ctx, RP_ENOMEM, "transfer function: out of memory");
  }
  tf->ctx = ctx;
  tf->id = rp__next_id();
  tf->lut_size = src->lut_size;
  tf->reference_step = src->reference_step;
  memcpy(tf->lut, src->lut, bytes);
  *out = tf;
  return 0;
}

int rp__tf_same(const rp_tf *a, const rp_tf *b) {
  return a->lut_size == b->lut_size &&
         a->reference_step == b->reference_step &&
         memcmp(a->lut, b->lut, (size_t)a->lut_size * 4 * sizeof(float)) ==
             0;
}

void rp_tf_destroy(rp_tf *tf) {
  if (tf == NULL)
    return;
  rp__free(tf->ctx, tf->lut);
  rp__free(tf->ctx, tf);
}

float rp_tf_reference_step(const rp_tf *tf) {
  return tf != NULL ? tf->reference_step : 0.0f;
}

const float *rp_tf_lut(const rp_tf *tf, int *lut_size) {
  if (tf == NULL)
    return NULL;
  if (lut_size != NULL)
    *lut_size = tf->lut_size;
  return tf->lut;
}

static double clamp01(double x) { return x < 0.0 ? 0.0 : x > 1.0 ? 1.0 : x; }

/* LUT entry index and weight for x in [0, 1]. */
static int lut_pos(const rp_tf *tf, double x, double *w) {
  double f = clamp01(x) * (tf->lut_size - 1);
  int i = (int)f;
  if (i >= tf->lut_size - 1)
    i = tf->lut_size - 2;
  *w = f - i;
  return i;
}

void rp__tf_sample(const rp_tf *tf, double x, float rgba[4]) {
  double w;
  int i = lut_pos(tf, x, &w), c;
  const float *a = &tf->lut[4 * i], *b = a + 4;
  for (c = 0; c < 4; c++)
    rgba[c] = (float)(a[c] + w * ((double)b[c] - a[c]));
}

static double alpha_at(const rp_tf *tf, double x) {
  double w;
  int i = lut_pos(tf, x, &w);
  const float *a = &tf->lut[4 * i];
  return a[3] + w * ((double)a[7] - a[3]);
}

float rp__tf_alpha_max(const rp_tf *tf, double x0, double x1) {
  double m, f0, f1;
  int i, last;
  if (x1 < x0) {
    double t = x0;
    x0 = x1, x1 = t;
  }
  x0 = clamp01(x0), x1 = clamp01(x1);
  m = fmax(alpha_at(tf, x0), alpha_at(tf, x1));
  /* Between the ends the maximum of a piecewise-linear function sits on a
   * table entry strictly inside the interval. */
  f0 = x0 * (tf->lut_size - 1);
  f1 = x1 * (tf->lut_size - 1);
  last = (int)ceil(f1) - 1;
  for (i = (int)floor(f0) + 1; i <= last; i++)
    m = fmax(m, tf->lut[4 * i + 3]);
  return (float)m;
}

void rp__tf_alpha_prefix(const rp_tf *tf, uint32_t *prefix) {
  int i;
  prefix[0] = 0;
  for (i = 0; i < tf->lut_size; i++)
    prefix[i + 1] = prefix[i] + (tf->lut[4 * i + 3] > 0.0f);
}

int rp__tf_alpha_any(const rp_tf *tf, const uint32_t *prefix, double x0,
                     double x1) {
  double f0, f1;
  int first, last;
  if (x1 < x0) {
    double t = x0;
    x0 = x1, x1 = t;
  }
  x0 = clamp01(x0), x1 = clamp01(x1);
  /* rp__tf_alpha_max's ends and entries, its float result above 0 read
   * as either: a float entry above 0 keeps the maximum above 0. */
  if ((float)fmax(alpha_at(tf, x0), alpha_at(tf, x1)) > 0.0f)
    return 1;
  f0 = x0 * (tf->lut_size - 1);
  f1 = x1 * (tf->lut_size - 1);
  first = (int)floor(f0) + 1;
  last = (int)ceil(f1) - 1;
  return first <= last && prefix[last + 1] > prefix[first];
}

/* Integral of alpha over [x0, x1] inside [0, 1]: trapezoids between the
 * table entries, exact for the piecewise-linear function. Every term is a
 * non-negative product, so the sum is zero only if alpha is zero on the
 * whole interval: "empty" stays exact. */
static double alpha_integral01(const rp_tf *tf, double x0, double x1) {
  double sum = 0.0, xa = x0, aa = alpha_at(tf, x0);
  double scale = tf->lut_size - 1;
  int i = (int)floor(x0 * scale) + 1;
  for (; i <= (int)ceil(x1 * scale) - 1; i++) {
    double xb = i / scale, ab = tf->lut[4 * i + 3];
    if (xb <= xa)
      continue;
    sum += 0.5 * (aa + ab) * (xb - xa);
    xa = xb, aa = ab;
  }
  if (x1 > xa)
    sum += 0.5 * (aa + alpha_at(tf, x1)) * (x1 - xa);
  return sum;
}

double rp__tf_alpha_mean(const rp_tf *tf, double x0, double x1) {
  double sum = 0.0, lo, hi;
  if (x1 < x0) {
    double t = x0;
    x0 = x1, x1 = t;
  }
  if (!(x1 > x0))
    return alpha_at(tf, x0);
  /* Outside [0, 1] the function is constant (the LUT is clamped). */
  if (x0 < 0.0)
    sum += alpha_at(tf, 0.0) * (fmin(x1, 0.0) - x0);
  if (x1 > 1.0)
    sum += alpha_at(tf, 1.0) * (x1 - fmax(x0, 1.0));
  lo = clamp01(x0), hi = clamp01(x1);
  if (hi > lo)
    sum += alpha_integral01(tf, lo, hi);
  return sum / (x1 - x0);
}
