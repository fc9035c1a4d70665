/* Pre-integrated classification (RP_EFFECT_PREINT, docs/sampling.md).
 *
 * The model. Entry i of the LUT (alpha a_i per reference step, straight
 * colour c_i) gives the extinction per reference step
 * tau_i = -ln(1 - min(a_i, RP_PREINT_ALPHA_MAX)) and the emission
 * q_i = tau_i c_i; between entries tau and q are linear in the LUT
 * position f = x (lut_size - 1). (The plain classification interpolates
 * a instead; at the entries the two agree.) A segment of length d over
 * which f runs linearly from f_a to f_b has the mean M = (1 / (f_b - f_a))
 * times the integral of (tau, q) over [f_a, f_b] (M = (tau, q)(f_a) when
 * f_a = f_b), opacity 1 - exp(-(d / ref_step) M_tau) and straight colour
 * M_q / M_tau: the emission weighted by extinction, Engel, Kraus and
 * Ertl's approximation that neglects the attenuation inside the segment.
 *
 * The clamp: an opaque entry (a = 1) has infinite tau; at 1 - 1e-6 a
 * segment of one reference step still reaches 1 - 1e-6, which an 8-bit
 * channel cannot tell from 1, while every table value stays finite. */
#include <math.h>

#include "internal.h"
#include "raypace_backend.h"

/* tau and q = tau * rgb of LUT entry i. */
static void node(const float *lut, uint32_t i, double out[4]) {
  double a = lut[4 * (size_t)i + 3], tau;
  int c;
  if (!(a > 0.0))
    a = 0.0;
  if (a > RP_PREINT_ALPHA_MAX)
    a = RP_PREINT_ALPHA_MAX;
  tau = -log1p(-a);
  out[0] = tau;
  for (c = 0; c < 3; c++)
    out[c + 1] = tau * lut[4 * (size_t)i + c];
}

void rp__preint_table(const float *lut, uint32_t lut_size, float *out) {
  double sum[4] = {0.0, 0.0, 0.0, 0.0}, prev[4], cur[4];
  uint32_t i;
  int c;
  for (i = 0; i < lut_size; i++) {
    node(lut, i, cur);
    /* The integral up to entry i: trapezoids, exact for linear pieces. */
    if (i > 0)
      for (c = 0; c < 4; c++)
        sum[c] += 0.5 * (prev[c] + cur[c]);
    for (c = 0; c < 4; c++) {
      out[8 * (size_t)i + c] = (float)cur[c];
      out[8 * (size_t)i + 4 + c] = (float)sum[c];
      prev[c] = cur[c];
    }
  }
}

/* Cell and weight of LUT position f (already in [0, lut_size - 1]), as
 * the LUT's own lookup takes them. */
static uint32_t cell(double f, uint32_t lut_size, double *w) {
  uint32_t e = (uint32_t)f;
  if (e > lut_size - 2)
    e = lut_size - 2;
  *w = f - e;
  return e;
}

/* (tau, q) at position f inside cell e with weight w. */
static void at(const float *lut, uint32_t e, double w, double out[4]) {
  double lo[4], hi[4];
  int c;
  node(lut, e, lo);
  node(lut, e + 1, hi);
  for (c = 0; c < 4; c++)
    out[c] = lo[c] + w * (hi[c] - lo[c]);
}

void rp__preint_mean(const rp_tf *tf, double xa, double xb, double out[4]) {
  uint32_t n = (uint32_t)tf->lut_size, ea, eb, e;
  double top = n - 1.0, fa, fb, wa, wb, pa[4], pb[4], lo[4], hi[4];
  int c;
  fa = (xa < 0.0 ? 0.0 : xa > 1.0 ? 1.0 : xa) * top;
  fb = (xb < 0.0 ? 0.0 : xb > 1.0 ? 1.0 : xb) * top;
  if (fb < fa) {
    double t = fa;
    fa = fb, fb = t;
  }
  ea = cell(fa, n, &wa);
  eb = cell(fb, n, &wb);
  at(tf->lut, ea, wa, pa);
  at(tf->lut, eb, wb, pb);
  if (ea == eb) {
    /* One linear piece: the mean is the mean of the ends, exact. */
    for (c = 0; c < 4; c++)
      out[c] = 0.5 * (pa[c] + pb[c]);
    return;
  }
  /* The rest of fa's cell, the whole cells between, the start of fb's. */
  node(tf->lut, ea + 1, hi);
  for (c = 0; c < 4; c++)
    out[c] = 0.5 * (1.0 - wa) * (pa[c] + hi[c]);
  for (e = ea + 1; e < eb; e++) {
    node(tf->lut, e, lo);
    node(tf->lut, e + 1, hi);
    for (c = 0; c < 4; c++)
      out[c] += 0.5 * (lo[c] + hi[c]);
  }
  node(tf->lut, eb, lo);
  for (c = 0; c < 4; c++) {
    out[c] += 0.5 * wb * (lo[c] + pb[c]);
    out[c] /= fb - fa;
  }
}

void rp__preint_classify(const double mean[4], double ratio,
                         double rgba[4]) {
  int c;
  rgba[3] = -expm1(-ratio * mean[0]);
  for (c = 0; c < 3; c++) {
    double v = mean[0] > 0.0 ? mean[c + 1] / mean[0] : 0.0;
    rgba[c] = v < 0.0 ? 0.0 : v > 1.0 ? 1.0 : v;
  }
}
