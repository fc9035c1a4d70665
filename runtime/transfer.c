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
/* Data values a TF may place (points in data units, a data range, a
 * window's ends): kernels take the span as floats and subtract its ends,
 * which stays finite within +-1e30 (beyond, a window of 4e41 became an
 * infinite span and a TF that sampled nothing). */
#define RP__TF_DATA_MAX 1e30

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

static int check_range(rp_context *ctx, const rp_tf_desc *d) {
  if (d->units != RP_TF_NORMALISED && d->units != RP_TF_DATA)
    return rp__fail(ctx, RP_EINVAL, "transfer function: field 'units': "
                    "value %d is not an rp_tf_units", (int)d->units);
  if (d->range == RP_TF_RANGE_MINMAX)
    return 0;
  if (d->range != RP_TF_RANGE_PERCENTILES && d->range != RP_TF_RANGE_DATA)
    return rp__fail(ctx, RP_EINVAL, "transfer function: field 'range': "
                    "value %d is not an rp_tf_range", (int)d->range);
  if (d->units == RP_TF_DATA)
    return rp__fail(ctx, RP_EINVAL, "transfer function: field 'range': "
                    "points in data units carry their own range (leave "
                    "'range' at RP_TF_RANGE_MINMAX)");
  if (!isfinite(d->range_lo) || !isfinite(d->range_hi))
    return rp__fail(ctx, RP_ENOTFINITE, "transfer function: fields "
                    "'range_lo', 'range_hi': values %g, %g must be finite",
                    d->range_lo, d->range_hi);
  if (!(d->range_lo < d->range_hi))
    return rp__fail(ctx, RP_ERANGE, "transfer function: fields "
                    "'range_lo', 'range_hi': %g is not below %g",
                    d->range_lo, d->range_hi);
  if (d->range == RP_TF_RANGE_DATA &&
      (d->range_lo < -RP__TF_DATA_MAX || d->range_hi > RP__TF_DATA_MAX))
    return rp__fail(ctx, RP_ERANGE, "transfer function: fields "
                    "'range_lo', 'range_hi': data values %g, %g are "
                    "outside [-1e30, 1e30]", d->range_lo, d->range_hi);
  if (d->range == RP_TF_RANGE_PERCENTILES &&
      (d->range_lo < 0.0 || d->range_hi > 100.0))
    return rp__fail(ctx, RP_ERANGE, "transfer function: fields "
                    "'range_lo', 'range_hi': percentiles %g, %g are "
                    "outside [0, 100]", d->range_lo, d->range_hi);
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
  if (d->reference_step != 0.0f &&
      !(d->reference_step >= RP_STEP_MIN && d->reference_step <= RP_STEP_MAX))
    return rp__fail(ctx, RP_ERANGE, "transfer function: field "
                    "'reference_step' (rp_tf_desc.reference_step): value "
                    "%g must be in [%g, %g] voxels (0: 1)",
                    (double)d->reference_step, RP_STEP_MIN, RP_STEP_MAX);
  if (d->lut_size != 0 && (d->lut_size < 2 || d->lut_size > RP__LUT_MAX))
    return rp__fail(ctx, RP_ERANGE, "transfer function: field 'lut_size': "
                    "value %d is outside [2, %d]", d->lut_size, RP__LUT_MAX);
  if ((err = check_range(ctx, d)) != 0)
    return err;
  for (i = 0; i < d->count; i++) {
    const rp_tf_point *p = &d->points[i];
    if (d->units == RP_TF_DATA && !isfinite(p->x))
      return rp__fail(ctx, RP_ENOTFINITE, "transfer function: point %d "
                      "field 'x': value %g is not finite", i, (double)p->x);
    if (d->units == RP_TF_DATA && fabsf(p->x) > RP__TF_DATA_MAX)
      return rp__fail(ctx, RP_ERANGE, "transfer function: point %d field "
                      "'x': data value %g is outside [-1e30, 1e30]", i,
                      (double)p->x);
    if ((d->units != RP_TF_DATA && (err = check_unit(ctx, i, "x", p->x)) !=
                                       0) ||
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
  tf->range = desc->range;
  tf->range_lo = desc->range_lo, tf->range_hi = desc->range_hi;
  if (desc->units == RP_TF_DATA) {
    /* The table spans the points; outside them the TF is constant, as the
     * clamped table read is. */
    tf->range = RP_TF_RANGE_DATA;
    tf->range_lo = desc->points[0].x;
    tf->range_hi = desc->points[desc->count - 1].x;
  }
  for (i = 0; i < n; i++) {
    double v[4], x = (double)i / (n - 1);
    if (desc->units == RP_TF_DATA)
      x = tf->range_lo + x * (tf->range_hi - tf->range_lo);
    eval_points(desc, x, v);
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
/* The CT presets lie on their clinical windows in HU (a point's x is its
 * place in the window): bone 2000/500 ([-500, 1500]: bone from about
 * 150 HU, dense cortex by 700), soft tissue 400/40 ([-160, 240]: fat
 * faint, muscle and organs red, contrast and bone white), lung 1500/-600
 * ([-1350, 150]: air clear, parenchyma a faint haze, vessels and walls
 * solid) and angio 700/250 ([-100, 600]: soft tissue clear, contrast
 * 200-500 HU red, bone white). No end alpha is 0.9: two such samples at
 * the reference step reach exactly 0.99, the default ERT threshold, where
 * a float and a double sum may stop on different samples. */
static const rp_tf_point preset_ct_bone[] = {
    P(0, 0, 0, 0, 0), P(.32f, .80f, .60f, .45f, 0),
    P(.40f, .95f, .85f, .70f, .20f), P(.60f, 1, .97f, .90f, .70f),
    P(1, 1, 1, 1, .95f)};
static const rp_tf_point preset_ct_soft_hu[] = {
    P(0, 0, 0, 0, 0), P(.10f, .90f, .80f, .40f, 0),
    P(.15f, .90f, .80f, .45f, .015f), P(.40f, .75f, .25f, .20f, .03f),
    P(.55f, .85f, .35f, .30f, .20f), P(.80f, .95f, .80f, .75f, .60f),
    P(1, 1, 1, 1, .92f)};
static const rp_tf_point preset_ct_lung[] = {
    P(0, 0, 0, 0, 0), P(.26f, .60f, .70f, .90f, 0),
    P(.35f, .70f, .75f, .90f, .015f), P(.60f, .85f, .60f, .60f, .04f),
    P(.75f, .85f, .35f, .30f, .50f), P(1, 1, .90f, .85f, .85f)};
static const rp_tf_point preset_ct_angio[] = {
    P(0, 0, 0, 0, 0), P(.35f, .70f, .10f, .10f, 0),
    P(.50f, .90f, .20f, .15f, .50f), P(.80f, 1, .60f, .50f, .80f),
    P(1, 1, 1, 1, .95f)};
/* The ct-bone and ct-soft of 0.10, over [min, max], unchanged: for CT not
 * in HU. */
static const rp_tf_point preset_minmax_bone[] = {
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
  rp_tf_range range;
  double lo, hi; /* PERCENTILES: percentiles; DATA: the window in HU */
} preset;

#define PRESET(name, arr, range, lo, hi)                                     \
  {name, arr, (int)(sizeof arr / sizeof arr[0]), range, lo, hi}
#define WINDOWED(name, arr, w, l)                                            \
  PRESET(name, arr, RP_TF_RANGE_DATA, (l) - (w) / 2.0, (l) + (w) / 2.0)
static const preset presets[] = {
    PRESET("transparent", preset_transparent, RP_TF_RANGE_MINMAX, 0, 0),
    PRESET("opaque", preset_opaque, RP_TF_RANGE_MINMAX, 0, 0),
    WINDOWED("ct-bone", preset_ct_bone, 2000.0, 500.0),
    WINDOWED("ct-soft", preset_ct_soft_hu, 400.0, 40.0),
    WINDOWED("ct-lung", preset_ct_lung, 1500.0, -600.0),
    WINDOWED("ct-angio", preset_ct_angio, 700.0, 250.0),
    /* MRI has no units: the 1st to 99.5th percentile is the tissue range
     * whatever the scanner's scale, and a few hot voxels cannot move it */
    PRESET("mri", preset_mri, RP_TF_RANGE_PERCENTILES, 1.0, 99.5),
    PRESET("minmax-bone", preset_minmax_bone, RP_TF_RANGE_MINMAX, 0, 0),
    PRESET("minmax-soft", preset_ct_soft, RP_TF_RANGE_MINMAX, 0, 0),
    PRESET("ramp", preset_ramp, RP_TF_RANGE_MINMAX, 0, 0),
    PRESET("nearly-transparent", preset_nearly_transparent,
           RP_TF_RANGE_MINMAX, 0, 0),
};
#undef WINDOWED
#undef PRESET
#define N_PRESETS (sizeof presets / sizeof presets[0])

const char *const *rp_tf_preset_names(void) {
  static const char *names[N_PRESETS + 1];
  size_t i;
  if (names[0] == NULL) /* the same values on every call: a benign race */
    for (i = 0; i < N_PRESETS; i++)
      names[i] = presets[i].name;
  return names;
}

int rp_tf_create_preset(rp_context *ctx, const char *name, rp_tf **out) {
  char known[256] = "";
  size_t i;
  if (ctx == NULL)
    return RP_EINVAL;
  if (name == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_tf_create_preset: name and out are "
                    "required");
  for (i = 0; i < N_PRESETS; i++) {
    if (strcmp(presets[i].name, name) == 0) {
      rp_tf_desc d = {0};
      d.points = presets[i].points;
      d.count = presets[i].count;
      d.range = presets[i].range;
      d.range_lo = presets[i].lo;
      d.range_hi = presets[i].hi;
      return rp_tf_create(ctx, &d, out);
    }
    strcat(known, i > 0 ? ", " : "");
    strcat(known, presets[i].name);
  }
  return rp__fail(ctx, RP_EINVAL, "transfer function preset '%s' is "
                  "unknown; known: %s", name, known);
}

int rp_tf_window(rp_context *ctx, const rp_tf *src, double width,
                 double level, rp_tf **out) {
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (src == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_tf_window: src and out are "
                    "required");
  if (!isfinite(width) || !isfinite(level))
    return rp__fail(ctx, RP_ENOTFINITE, "window/level: width %g, level %g: "
                    "both must be finite", width, level);
  if (!(width > 0.0))
    return rp__fail(ctx, RP_ERANGE, "window/level: width %g must be > 0",
                    width);
  if (!(fabs(level) + width / 2.0 <= RP__TF_DATA_MAX))
    return rp__fail(ctx, RP_ERANGE, "window/level: width %g, level %g: "
                    "the window's ends must lie within [-1e30, 1e30]",
                    width, level);
  if ((err = rp__tf_clone(ctx, src, out)) != 0)
    return err;
  (*out)->range = RP_TF_RANGE_DATA;
  (*out)->range_lo = level - width / 2.0;
  (*out)->range_hi = level + width / 2.0;
  return 0;
}

/* Quantile at percentile pc of the table (linear between per-mille
 * entries). */
static double quantile_at(const rp__value_range *r, double pc) {
  double f = pc * 10.0;
  int i = (int)floor(f);
  if (i < 0)
    return r->quantile[0];
  if (i >= RP__QUANTILES - 1)
    return r->quantile[RP__QUANTILES - 1];
  return r->quantile[i] + (f - i) * ((double)r->quantile[i + 1] -
                                     r->quantile[i]);
}

void rp__tf_stored_range(const rp_tf *tf, const rp__value_range *r,
                         double out[2]) {
  out[0] = r->min, out[1] = r->max;
  if (tf->range == RP_TF_RANGE_DATA) {
    out[0] = tf->range_lo - r->offset;
    out[1] = tf->range_hi - r->offset;
  } else if (tf->range == RP_TF_RANGE_PERCENTILES) {
    double lo = quantile_at(r, tf->range_lo);
    double hi = quantile_at(r, tf->range_hi);
    /* A volume with few distinct values can put both percentiles on one:
     * fall back to the whole range rather than a step function. */
    if (hi > lo)
      out[0] = lo, out[1] = hi;
  }
  /* Kernels receive the span as floats (rp_frame_params.value_min/max):
   * rounded here, the host passes place every value exactly as they do. */
  out[0] = (float)out[0], out[1] = (float)out[1];
}

void rp__tf_volume_range(const rp_tf *tf, const rp_volume *v,
                         double out[2]) {
  rp__value_range r;
  rp__volume_values(v, &r);
  rp__tf_stored_range(tf, &r, out);
}

void rp_tf_data_range(const rp_tf *tf, const rp_volume *vol, double *lo,
                      double *hi) {
  double r[2] = {0.0, 0.0};
  if (tf != NULL && vol != NULL) {
    rp__tf_volume_range(tf, vol, r);
    r[0] += vol->data_offset, r[1] += vol->data_offset;
  }
  if (lo != NULL)
    *lo = r[0];
  if (hi != NULL)
    *hi = r[1];
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
  tf->range = src->range;
  tf->range_lo = src->range_lo, tf->range_hi = src->range_hi;
  memcpy(tf->lut, src->lut, bytes);
  *out = tf;
  return 0;
}

int rp__tf_same(const rp_tf *a, const rp_tf *b) {
  return a->lut_size == b->lut_size &&
         a->reference_step == b->reference_step && a->range == b->range &&
         a->range_lo == b->range_lo && a->range_hi == b->range_hi &&
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
