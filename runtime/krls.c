/* Kernel recursive least squares. krls.h states the model, the
 * replacement policy and the drift rule; this file follows it. Matrices
 * are row-major with stride n = max_dict, dictionary in insertion order.
 * Every rank-one change to a symmetric matrix is written as X += s u u^T
 * with one scaled vector u, so that X stays exactly symmetric: u_i * u_j
 * and u_j * u_i round alike, (g * u_i) * u_j and (g * u_j) * u_i do not. */
#include <math.h>
#include <string.h>

#include "internal.h"
#include "krls.h"

#define CLIP_WARMUP 8
#define CLIP_RATE (1.0 / 16.0)
/* A sample the dictionary explains is clamped to c * (s + this * ybar):
 * the floor lets a fit that was exact (s = 0) still move. */
#define CLIP_FLOOR 1e-3
/* Drift checks after each change of Ki. */
#define DRIFT_CHECKS 1

struct rp__krls {
  rp_context *ctx;
  rp__krls_desc d;
  int n;          /* capacity: d.max_dict, the stride of the matrices */
  int m;          /* dictionary size */
  double *dict;   /* n * dim */
  double *K;      /* kernel matrix of the dictionary, exact values */
  double *Ki;     /* its recursive inverse */
  double *P;      /* inverse of the weighted sum of a_i a_i^T */
  double *theta;  /* least-squares values on the dictionary */
  double *alpha;  /* Ki theta */
  uint64_t *used; /* update count at each element's last use */
  double *k, *a, *v, *w; /* scratch vectors */
  double *L;      /* scratch matrix for the rebuild */
  uint64_t t;
  int checks_left; /* drift checks still due since Ki last changed */
  uint64_t probe_rng;
  double drift_floor; /* probe right after the last rebuild */
  int seen;           /* samples seen by the clamp's warm-up */
  double rscale, yscale;
  rp__krls_stats st;
};

void rp__krls_desc_defaults(const rp__krls_desc *in, rp__krls_desc *out) {
  rp__krls_desc d;
  if (in)
    d = *in;
  else
    memset(&d, 0, sizeof d);
  if (d.gamma == 0)
    d.gamma = 1.0;
  if (d.nu == 0)
    d.nu = 1e-3;
  if (d.max_dict == 0)
    d.max_dict = 32;
  if (d.forget == 0)
    d.forget = 1.0;
  *out = d;
}

static int check_desc(rp_context *ctx, const rp__krls_desc *d) {
  const struct {
    const char *name;
    double v, lo, hi;
  } f[] = {{"gamma", d->gamma, 1e-300, 1e300},
           {"nu", d->nu, 1e-12, 1e300},
           {"bias", d->bias, 0, 1e300},
           {"forget", d->forget, 1e-300, 1},
           {"clip", d->clip, 0, 1e300},
           {"noise_ratio", d->noise_ratio, 0, 1e300}};
  size_t i;
  if (d->dim < 1 || d->dim > RP__KRLS_MAX_DIM)
    return rp__fail(ctx, RP_EINVAL, "krls: field 'dim' = %d is not in "
                    "1..%d", d->dim, RP__KRLS_MAX_DIM);
  if (d->max_dict < 1 || d->max_dict > RP__KRLS_MAX_DICT)
    return rp__fail(ctx, RP_EINVAL, "krls: field 'max_dict' = %d is not "
                    "in 1..%d", d->max_dict, RP__KRLS_MAX_DICT);
  for (i = 0; i < sizeof f / sizeof f[0]; i++) {
    if (!isfinite(f[i].v))
      return rp__fail(ctx, RP_ENOTFINITE, "krls: field '%s' is %g",
                      f[i].name, f[i].v);
    if (f[i].v < f[i].lo || f[i].v > f[i].hi)
      return rp__fail(ctx, RP_EINVAL, "krls: field '%s' = %g is not in "
                      "[%g, %g]", f[i].name, f[i].v, f[i].lo, f[i].hi);
  }
  if (d->evict != RP__KRLS_EVICT_LRU && d->evict != RP__KRLS_EVICT_OLDEST)
    return rp__fail(ctx, RP_EINVAL, "krls: field 'evict' = %d is not a "
                    "policy", d->evict);
  if (d->clip != 0 && d->clip < 1)
    return rp__fail(ctx, RP_EINVAL, "krls: field 'clip' = %g: 0 (off) "
                    "or >= 1", d->clip);
  /* delta / r must stay finite: delta <= 1 + bias. */
  if (d->noise_ratio != 0 && d->noise_ratio < 1e-12)
    return rp__fail(ctx, RP_EINVAL, "krls: field 'noise_ratio' = %g: 0 "
                    "(off) or >= 1e-12", d->noise_ratio);
  return 0;
}

int rp__krls_create(rp_context *ctx, const rp__krls_desc *desc,
                    rp__krls **out) {
  rp__krls_desc d;
  rp__krls *m;
  size_t n, nn, bytes;
  char *p;
  int err;
  *out = NULL;
  rp__krls_desc_defaults(desc, &d);
  if ((err = check_desc(ctx, &d)) != 0)
    return err;
  n = (size_t)d.max_dict;
  nn = n * n;
  /* One block: the struct, then doubles, then the use times (same size
   * and alignment as a double). */
  bytes = sizeof *m + sizeof(double) * (n * (size_t)d.dim + 4 * nn + 6 * n)
          + sizeof(uint64_t) * n;
  p = rp__malloc(ctx, bytes);
  if (!p)
    return rp__fail(ctx, RP_ENOMEM, "krls: %zu bytes", bytes);
  m = (rp__krls *)(void *)p;
  memset(m, 0, sizeof *m);
  m->ctx = ctx;
  m->d = d;
  m->n = d.max_dict;
  m->dict = (double *)(void *)(p + sizeof *m);
  m->K = m->dict + n * (size_t)d.dim;
  m->Ki = m->K + nn;
  m->P = m->Ki + nn;
  m->L = m->P + nn;
  m->theta = m->L + nn;
  m->alpha = m->theta + n;
  m->k = m->alpha + n;
  m->a = m->k + n;
  m->v = m->a + n;
  m->w = m->v + n;
  m->used = (uint64_t *)(void *)(m->w + n);
  rp__krls_reset(m);
  *out = m;
  return 0;
}

void rp__krls_destroy(rp__krls *m) {
  if (m)
    rp__free(m->ctx, m);
}

void rp__krls_reset(rp__krls *m) {
  m->m = 0;
  m->t = 0;
  m->checks_left = 0;
  m->probe_rng = 0x9E3779B97F4A7C15ULL;
  m->drift_floor = 0;
  m->seen = 0;
  m->rscale = m->yscale = 0;
  memset(&m->st, 0, sizeof m->st);
}

/* out_j = k(d_j, x) for every element. The dictionary is stored feature
 * by feature (dict[f * n + j]): four elements at a time, each distance
 * sums over the features in its own register, and gcc packs the four
 * into two-wide vectors; one element at a time is a chain of dim
 * dependent adds. */
static void kernel_row(const rp__krls *m, const double *x,
                       double *restrict out) {
  const int mm = m->m, dim = m->d.dim, n = m->n;
  const double g = m->d.gamma, bias = m->d.bias;
  int f, j;
  for (j = 0; j + 4 <= mm; j += 4) {
    double s0 = 0, s1 = 0, s2 = 0, s3 = 0;
    for (f = 0; f < dim; f++) {
      const double *row = m->dict + (size_t)f * n + j;
      double t0 = row[0] - x[f], t1 = row[1] - x[f];
      double t2 = row[2] - x[f], t3 = row[3] - x[f];
      s0 += t0 * t0;
      s1 += t1 * t1;
      s2 += t2 * t2;
      s3 += t3 * t3;
    }
    out[j] = s0;
    out[j + 1] = s1;
    out[j + 2] = s2;
    out[j + 3] = s3;
  }
  for (; j < mm; j++) {
    double s = 0;
    for (f = 0; f < dim; f++) {
      double t = m->dict[(size_t)f * n + j] - x[f];
      s += t * t;
    }
    out[j] = s;
  }
  for (j = 0; j < mm; j++)
    out[j] = exp(-g * out[j]) + bias;
}

/* Eight partial sums, which gcc packs into four two-wide vector chains:
 * one sum would wait on each add's latency. */
static double dot(const double *restrict u, const double *restrict v,
                  int len) {
  double s0 = 0, s1 = 0, s2 = 0, s3 = 0, s4 = 0, s5 = 0, s6 = 0, s7 = 0;
  int i = 0;
  for (; i + 8 <= len; i += 8) {
    s0 += u[i] * v[i];
    s1 += u[i + 1] * v[i + 1];
    s2 += u[i + 2] * v[i + 2];
    s3 += u[i + 3] * v[i + 3];
    s4 += u[i + 4] * v[i + 4];
    s5 += u[i + 5] * v[i + 5];
    s6 += u[i + 6] * v[i + 6];
    s7 += u[i + 7] * v[i + 7];
  }
  for (; i < len; i++)
    s0 += u[i] * v[i];
  return ((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7));
}

/* y += a x, unrolled so that gcc's -O2 vectorizer packs it. */
static void axpy(double *restrict y, double a, const double *restrict x,
                 int len) {
  int i = 0;
  for (; i + 4 <= len; i += 4) {
    y[i] += a * x[i];
    y[i + 1] += a * x[i + 1];
    y[i + 2] += a * x[i + 2];
    y[i + 3] += a * x[i + 3];
  }
  for (; i < len; i++)
    y[i] += a * x[i];
}

/* out = A x for the leading m x m block of A (stride n). */
static void matvec(const double *A, int n, int m, const double *x,
                   double *restrict out) {
  int i;
  for (i = 0; i < m; i++)
    out[i] = dot(A + (size_t)i * n, x, m);
}

static double trace(const double *A, int n, int m) {
  double s = 0;
  int i;
  for (i = 0; i < m; i++)
    s += A[(size_t)i * n + i];
  return s;
}

/* lambda for this update: 1 while trace(P) >= m (see krls.h). */
static double lambda_now(const rp__krls *m) {
  if (m->d.forget >= 1 || trace(m->P, m->n, m->m) >= m->m)
    return 1.0;
  return m->d.forget;
}

/* Removes row and column j of the leading m x m block, in place: rows
 * above j shift their tail left by one, rows below also move up one. */
static void drop_rc(double *A, int n, int m, int j) {
  const size_t tail = sizeof(double) * (size_t)(m - 1 - j);
  int r;
  for (r = 0; r < m - 1; r++) {
    const double *src = A + (size_t)(r + (r >= j)) * n;
    double *dst = A + (size_t)r * n;
    if (r >= j)
      memcpy(dst, src, sizeof(double) * (size_t)j); /* other rows */
    memmove(dst + j, src + j + 1, tail);
  }
}

/* Evicts element j by marginalising it out (krls.h): theta and P lose
 * entry j and nothing else changes; Ki becomes the inverse of K without j
 * by the block-inverse identity run backwards,
 *   Ki' = Ki_-j - Ki_-j,j Ki_j,-j / Ki_jj. */
static void evict(rp__krls *m, int j) {
  const int n = m->n, mm = m->m, dim = m->d.dim;
  double *u = m->v, kjj = m->Ki[(size_t)j * n + j];
  int i, f;
  /* Ki_jj = 1 / (d_j's ALD residual on the others) > 0 in exact
   * arithmetic; a non-positive one is left to the drift check. */
  if (kjj > 0 && isfinite(kjj)) {
    const double s = 1.0 / sqrt(kjj);
    for (i = 0; i < mm; i++)
      u[i] = m->Ki[(size_t)i * n + j] * s;
    for (i = 0; i < mm; i++)
      axpy(m->Ki + (size_t)i * n, -u[i], u, mm);
  }
  drop_rc(m->K, n, mm, j);
  drop_rc(m->Ki, n, mm, j);
  drop_rc(m->P, n, mm, j);
  for (i = j; i < mm - 1; i++) {
    m->theta[i] = m->theta[i + 1];
    m->used[i] = m->used[i + 1];
  }
  for (f = 0; f < dim; f++) {
    double *row = m->dict + (size_t)f * n;
    memmove(row + j, row + j + 1, sizeof(double) * (size_t)(mm - 1 - j));
  }
  m->m = mm - 1;
  m->st.evicted++;
  m->checks_left = DRIFT_CHECKS;
}

/* a = Ki k re-expressed, before element j is evicted, as the projection
 * on the other elements, in O(m) rather than a new O(m^2) product. With
 * c = Ki_-j,j and d = Ki_jj, the evicted inverse is Ki_-j - c c^T / d and
 * a_-j = Ki_-j k_-j + c k_j, so
 *   a' = a_-j - c (k_j + c^T k_-j / d).
 * Entry j is left for the caller to drop. Where d is not positive the
 * eviction skips its downdate too (see evict), and so does this. */
static void downdate_a(rp__krls *m, int j) {
  const double *c = m->Ki + (size_t)j * m->n; /* column j, by symmetry */
  const double d = c[j];
  double ck = 0, coef;
  int i;
  if (!(d > 0 && isfinite(d)))
    return;
  for (i = 0; i < m->m; i++)
    if (i != j)
      ck += c[i] * m->k[i];
  coef = m->k[j] + ck / d;
  for (i = 0; i < m->m; i++)
    m->a[i] -= c[i] * coef;
}

/* pa = P a and returns a^T P a, at least 0 (P is positive definite: a
 * negative value is round-off). */
static double p_of_a(const rp__krls *m, double *pa) {
  double apa;
  matvec(m->P, m->n, m->m, m->a, pa);
  apa = dot(m->a, pa, m->m);
  return apa > 0 ? apa : 0;
}

/* Appends x with kernel column k (m->k), projection a (m->a), ALD residual
 * delta > 0 and target value yv: the paper's block-inverse step. */
static void grow(rp__krls *m, const double *x, double yv, double delta,
                 double kxx) {
  const int n = m->n, mm = m->m;
  const double lam = lambda_now(m), s = 1.0 / sqrt(delta);
  double *u = m->v, pnn = 1.0;
  int i, l;
  for (i = 0; i < mm; i++)
    u[i] = m->a[i] * s;
  for (i = 0; i < mm; i++)
    axpy(m->Ki + (size_t)i * n, u[i], u, mm);
  if (lam < 1)
    for (i = 0; i < mm; i++)
      for (l = 0; l < mm; l++)
        m->P[(size_t)i * n + l] /= lam;
  for (i = 0; i < mm; i++) {
    double c = -m->a[i] / delta;
    m->Ki[(size_t)i * n + mm] = m->Ki[(size_t)mm * n + i] = c;
    m->K[(size_t)i * n + mm] = m->K[(size_t)mm * n + i] = m->k[i];
    m->P[(size_t)i * n + mm] = m->P[(size_t)mm * n + i] = 0;
  }
  if (m->d.noise_ratio > 0) {
    /* The prior of krls.h: theta_new = a^T theta + eps, eps of variance
     * delta / r, observed once with unit noise. A Kalman step on the
     * grown state; every division is by v + 1 >= 1. */
    double *c = m->w, *uc = m->v, fp, e, v, den, sd;
    v = p_of_a(m, c) + delta / m->d.noise_ratio;
    fp = dot(m->a, m->theta, mm);
    den = v + 1.0;
    sd = 1.0 / sqrt(den);
    e = yv - fp;
    /* The downdate as u u^T with u = c / sqrt(den), so that P stays
     * symmetric bit for bit, as rls_step keeps it (u is m->v, free
     * again: the Ki update above is done). */
    for (i = 0; i < mm; i++)
      uc[i] = c[i] * sd;
    for (i = 0; i < mm; i++) {
      m->theta[i] += c[i] * (e / den);
      axpy(m->P + (size_t)i * n, -uc[i], uc, mm);
      m->P[(size_t)i * n + mm] = m->P[(size_t)mm * n + i] = c[i] / den;
    }
    pnn = v / den;
    yv = fp + pnn * e;
  }
  m->Ki[(size_t)mm * n + mm] = 1.0 / delta;
  m->K[(size_t)mm * n + mm] = kxx;
  m->P[(size_t)mm * n + mm] = pnn;
  m->theta[mm] = yv;
  m->used[mm] = m->t;
  for (i = 0; i < m->d.dim; i++)
    m->dict[(size_t)i * n + mm] = x[i];
  m->m = mm + 1;
  m->st.grown++;
  m->checks_left = DRIFT_CHECKS;
}

/* The RLS step for an ALD sample with residual e: gain q = P a / (lambda +
 * a^T P a), theta += q e, P = (P - q a^T P) / lambda. */
static void rls_step(rp__krls *m, double e) {
  const int n = m->n, mm = m->m;
  const double lam = lambda_now(m);
  double *pa = m->v, *u = m->w, apa, g, s;
  int i, l;
  apa = p_of_a(m, pa);
  g = 1.0 / (lam + apa);
  s = sqrt(g);
  for (i = 0; i < mm; i++) {
    m->theta[i] += pa[i] * (g * e);
    u[i] = pa[i] * s;
  }
  for (i = 0; i < mm; i++) {
    double *pi = m->P + (size_t)i * n;
    axpy(pi, -u[i], u, mm);
    if (lam < 1)
      for (l = 0; l < mm; l++)
        pi[l] /= lam;
  }
}

/* Cholesky of K, then Ki column by column from L y = e_c, L^T x = y; the
 * lower entries of column c are written to both halves, so Ki comes out
 * symmetric. Returns -1, or the index whose pivot was not positive. */
static int chol_inverse(rp__krls *m) {
  const int n = m->n, mm = m->m;
  double *L = m->L, *y = m->v;
  int i, j, c;
  for (j = 0; j < mm; j++) {
    double *lj = L + (size_t)j * n;
    double s = m->K[(size_t)j * n + j] - dot(lj, lj, j);
    if (!(s > 0) || !isfinite(s))
      return j;
    lj[j] = sqrt(s);
    for (i = j + 1; i < mm; i++) {
      double *li = L + (size_t)i * n;
      li[j] = (m->K[(size_t)i * n + j] - dot(li, lj, j)) / lj[j];
    }
  }
  for (c = 0; c < mm; c++) {
    for (i = 0; i < mm; i++) {
      const double *li = L + (size_t)i * n;
      double s = i == c ? 1.0 : 0.0;
      if (i < c) {
        y[i] = 0;
        continue;
      }
      for (j = c; j < i; j++)
        s -= li[j] * y[j];
      y[i] = s / li[i];
    }
    for (i = mm - 1; i >= c; i--) {
      double s = y[i];
      for (j = i + 1; j < mm; j++)
        s -= L[(size_t)j * n + i] * y[j];
      y[i] = s / L[(size_t)i * n + i];
      m->Ki[(size_t)i * n + c] = m->Ki[(size_t)c * n + i] = y[i];
    }
  }
  return -1;
}

/* The larger of two residuals; NaN, once seen, stays. */
static double worse(double r, double e) {
  return r != r || e <= r ? r : e;
}

static double col_drift(const rp__krls *m, int c) {
  const double *kc = m->Ki + (size_t)c * m->n; /* column c, by symmetry */
  double r = 0;
  int i;
  for (i = 0; i < m->m; i++)
    r = worse(r, fabs(dot(m->K + (size_t)i * m->n, kc, m->m) - (i == c)));
  return r;
}

/* v_i uniform in [-sqrt 3, sqrt 3] (unit variance), 16 bits each, four
 * per step of the generator (xorshift64). Not random signs: the nearly
 * singular direction of an ill-conditioned K~ is often the difference of
 * two close elements, q = e_a - e_b, and signs give q^T v = 0 half the
 * time (a probe missed a residual 170 times its size that way). */
static void random_probe(rp__krls *m, double *v, int len) {
  uint64_t bits = 0;
  int i;
  for (i = 0; i < len; i++) {
    if (i % 4 == 0) {
      m->probe_rng ^= m->probe_rng << 13;
      m->probe_rng ^= m->probe_rng >> 7;
      m->probe_rng ^= m->probe_rng << 17;
      bits = m->probe_rng;
    }
    v[i] = ((double)((bits >> (16 * (i % 4))) & 0xFFFF) + 0.5) *
               (2 * 1.7320508075688772 / 65536) - 1.7320508075688772;
  }
}

/* max_i |(R v)_i| for a random vector v, R = K Ki - I: row i's expected
 * square is the sum of squares of R's row i, so a large entry in any
 * column shows, where checking one column at a time can miss the one an
 * eviction spoiled. O(m^2); uses v and w as scratch. */
static double probe(rp__krls *m) {
  const int n = m->n, mm = m->m;
  double *v = m->v, *t = m->w, r = 0;
  int i;
  random_probe(m, v, mm);
  matvec(m->Ki, n, mm, v, t);
  for (i = 0; i < mm; i++)
    r = worse(r, fabs(dot(m->K + (size_t)i * n, t, mm) - v[i]));
  return r;
}

/* The drift check (krls.h): the column of the newest element, exactly,
 * and one random probe. A growth step with delta near nu multiplies the
 * error of a by 1 / delta into the new row and column; an eviction leaves
 * a residual close to rank one, R ~ p q^T, which the probe sees unless
 * q^T v happens to be small. Two random probes (and, before that, random
 * signs) let through residuals 20 to 200 times the probe on ill
 * conditioned streams; this pair stayed within 6 times. O(m^2). */
static double probe_drift(rp__krls *m) {
  double r = col_drift(m, m->m - 1);
  return worse(r, probe(m));
}

double rp__krls_drift(const rp__krls *m) {
  double r = 0;
  int c;
  for (c = 0; c < m->m; c++)
    r = worse(r, col_drift(m, c));
  return r;
}

static void rebuild(rp__krls *m) {
  int j, tries;
  /* A failing pivot cannot happen in exact arithmetic (krls.h); should
   * round-off make one, that element is the one K~ cannot tell from the
   * earlier ones, and it goes. */
  for (tries = 0; tries < m->n && (j = chol_inverse(m)) >= 0; tries++)
    evict(m, j);
  matvec(m->Ki, m->n, m->m, m->theta, m->alpha);
  /* What a fresh inverse itself leaves, O(m^2). */
  m->drift_floor = probe_drift(m);
  m->st.floor_max = fmax(m->st.floor_max, m->drift_floor);
  m->checks_left = 0;
  m->st.rebuilds++;
}

static void check_drift(rp__krls *m) {
  double r, bound;
  if (m->checks_left <= 0 || m->m == 0)
    return;
  m->checks_left--;
  r = probe_drift(m);
  m->st.checks++;
  m->st.drift = r;
  if (!(r <= m->st.drift_max))
    m->st.drift_max = r;
  bound = fmax(RP__KRLS_DRIFT_REBUILD, 8.0 * m->drift_floor);
  if (!(r <= bound))
    rebuild(m);
}

/* The optional Huber clamp of krls.h; f is the prediction at x. */
static double clamp_residual(rp__krls *m, double e, double f, int novel) {
  double lim;
  if (m->seen < CLIP_WARMUP) {
    m->seen++;
    m->rscale += (fabs(e) - m->rscale) / m->seen;
    m->yscale += (fabs(f + e) - m->yscale) / m->seen;
    return e;
  }
  lim = m->d.clip * (m->rscale + (novel ? 1.0 : CLIP_FLOOR) * m->yscale);
  if (lim > 0 && fabs(e) > lim) {
    e = copysign(lim, e);
    m->st.clipped++;
  }
  m->rscale += CLIP_RATE * (fabs(e) - m->rscale);
  m->yscale += CLIP_RATE * (fabs(f + e) - m->yscale);
  return e;
}

int rp__krls_update(rp__krls *m, const double *x, double y) {
  const double kxx = 1.0 + m->d.bias;
  /* No element is "used" by a sample whose kernel values all underflowed
   * to the bias: it is near none of them. */
  double f, e, delta = kxx, best = m->d.bias;
  int i, near = -1, novel;
  for (i = 0; i < m->d.dim; i++)
    if (!isfinite(x[i]))
      return rp__fail(m->ctx, RP_ENOTFINITE, "krls: feature x[%d] is %g",
                      i, x[i]);
  if (!isfinite(y))
    return rp__fail(m->ctx, RP_ENOTFINITE, "krls: target y is %g", y);
  if (y < 0 && !m->d.signed_y)
    return rp__fail(m->ctx, RP_ERANGE, "krls: target y = %g is negative "
                    "(timings and costs are >= 0)", y);
  m->t++;
  kernel_row(m, x, m->k);
  for (i = 0; i < m->m; i++) {
    if (m->k[i] > best) {
      best = m->k[i];
      near = i;
    }
  }
  f = dot(m->k, m->alpha, m->m);
  if (m->m > 0) {
    matvec(m->Ki, m->n, m->m, m->k, m->a);
    delta = kxx - dot(m->k, m->a, m->m);
  }
  /* NaN delta (never, with finite inputs) counts as ALD: no division. */
  novel = m->m == 0 || delta > m->d.nu;
  e = y - f;
  if (m->d.clip > 0)
    e = clamp_residual(m, e, f, novel);
  if (near >= 0)
    m->used[near] = m->t;
  if (!novel) {
    rls_step(m, e);
  } else {
    if (m->m == m->n) {
      int lru = 0;
      /* Oldest: index 0, insertion order. */
      for (i = 1; m->d.evict == RP__KRLS_EVICT_LRU && i < m->m; i++)
        if (m->used[i] < m->used[lru])
          lru = i;
      downdate_a(m, lru);
      evict(m, lru);
      for (i = lru; i < m->m; i++) {
        m->k[i] = m->k[i + 1];
        m->a[i] = m->a[i + 1];
      }
      delta = kxx - dot(m->k, m->a, m->m);
      /* Fewer elements only raise delta; keep round-off from lowering
       * it under the tolerance that admitted the sample. */
      if (!(delta > m->d.nu))
        delta = m->d.nu;
    }
    grow(m, x, f + e, delta, kxx);
  }
  matvec(m->Ki, m->n, m->m, m->theta, m->alpha);
  m->st.updates++;
  check_drift(m);
  return 0;
}

double rp__krls_predict(const rp__krls *m, const double *x) {
  double k[RP__KRLS_MAX_DICT];
  kernel_row(m, x, k);
  return dot(k, m->alpha, m->m);
}

double rp__krls_novelty(const rp__krls *m, const double *x) {
  double k[RP__KRLS_MAX_DICT], a[RP__KRLS_MAX_DICT];
  const double kxx = 1.0 + m->d.bias;
  double u;
  if (m->m == 0)
    return 1.0;
  kernel_row(m, x, k);
  matvec(m->Ki, m->n, m->m, k, a);
  u = (kxx - dot(k, a, m->m)) / kxx;
  return u > 0.0 ? (u < 1.0 ? u : 1.0) : 0.0; /* NaN: 0 */
}

void rp__krls_get_stats(const rp__krls *m, rp__krls_stats *out) {
  *out = m->st;
  out->size = m->m;
}

void rp__krls_point(const rp__krls *m, int i, double *out) {
  int f;
  for (f = 0; f < m->d.dim; f++)
    out[f] = m->dict[(size_t)f * m->n + i];
}

double rp__krls_alpha(const rp__krls *m, int i) { return m->alpha[i]; }

double rp__krls_kinv(const rp__krls *m, int i, int j) {
  return m->Ki[(size_t)i * m->n + j];
}
