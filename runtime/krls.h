/* Kernel recursive least squares (Engel, Mannor and Meir, "The kernel
 * recursive least-squares algorithm", IEEE TSP 52(8), 2004): the learner
 * behind the cost model's sigma (DESIGN section 5). Internal API.
 *
 * Model. Kernel k(x, x') = exp(-gamma * |x - x'|^2) + bias. A dictionary
 * D = {d_1..d_m} holds the samples that were not approximately linearly
 * dependent (ALD) on the dictionary when they arrived: a new x is ALD when
 * delta = k(x, x) - k_D(x)^T K~^-1 k_D(x) <= nu, K~ the dictionary's kernel
 * matrix. Every sample i is represented by its projection coefficients a_i
 * (a_i = K~^-1 k_D(x_i) on the dictionary of its time, padded with zeros
 * for elements added later; a dictionary element's own row is a unit
 * vector). The model is the least-squares fit
 *   theta = argmin sum_i lambda^(n-i) (y_i - a_i^T theta)^2,
 *   alpha = K~^-1 theta,  f(x) = sum_j alpha_j k(d_j, x),
 * kept by the recursions of the paper: an ALD sample updates theta and
 * P = (sum lambda^(n-i) a_i a_i^T)^-1 by a rank-one RLS step; a novel one
 * grows K~^-1 by the block-inverse formula, P by a unit diagonal entry and
 * theta by its own target. Both are O(m^2); nothing is allocated after
 * create. theta (values on the dictionary) is the state and alpha is
 * recomputed from it, so an exact rebuild of K~^-1 also restores alpha.
 *
 * Bounded dictionary: the replacement policy. When a novel sample arrives
 * and the dictionary holds max_dict elements, the least recently used
 * element is evicted first. An element is "used" when it is the nearest
 * element (largest kernel value) to an incoming sample, ALD or not, and
 * when it is added. Why: the cost model is fed the frame's features during
 * camera moves and transfer-function changes, so the region of feature
 * space being visited drifts. Elements in regions that are no longer
 * visited stop being used and go first, and the dictionary follows the
 * stream. Unlike dropping the oldest element (dlib's policy), a view that
 * is returned to all the time (the home view, a slow orbit) keeps its
 * elements, which would otherwise be evicted and re-added in a cycle.
 * What the evicted element knew is marginalised: theta holds the fitted
 * function's values at the dictionary points and P their covariance (up
 * to the noise variance), and eviction drops entry j of both and changes
 * nothing else (O(m^2), for the downdate of K~^-1). That is exactly the
 * least-squares problem above in which theta_j stays a free parameter
 * that no later sample touches, and in function terms f becomes its best
 * approximation (in the kernel's norm) on the remaining elements; dlib's
 * krls does the same when it drops its oldest element (a re-fit through
 * d_j's projection on the others inflates theta: docs/pacing.md, "KRLS").
 * The dictionary keeps insertion order, which makes each Cholesky pivot
 * of K~ at least the delta > nu its element had when it arrived: the
 * rebuild below cannot meet a zero pivot.
 *
 * Drift of the recursive inverse. K~^-1 changes only when the dictionary
 * does, and the update that changes it checks R = K~ K~^-1 - I twice,
 * O(m^2) each: on the column of the newest element, max_i |R_i,new|, and
 * on a random vector v, max_i |(R v)_i| (each row's expected square is
 * that row's sum of squares, so a large entry anywhere shows). The two
 * cover the two ways R grows: a growth step with delta near nu multiplies
 * the error of a by 1 / delta into the new row and column, and an
 * eviction exposes the forward error of K~^-1, about eps * cond(K~)^2, as
 * a residual close to rank one (other checks let far more through:
 * docs/pacing.md, "KRLS"). When the check is over
 * RP__KRLS_DRIFT_REBUILD = 1e-6, or over 8 times what it found right
 * after the last rebuild should K~ be so ill conditioned that Cholesky
 * cannot do better, K~^-1 is rebuilt from the dictionary's kernel matrix
 * by Cholesky (O(m^3)) and alpha is recomputed from theta.
 * An ALD update changes no K~^-1 and checks nothing. Why 1e-6: the
 * model's values at its own dictionary points are K~ alpha =
 * theta + R theta, so R bounds the model's own error there relative to
 * theta, and 1e-6 (times m) is far below any timing noise; the ALD test's
 * k^T K~^-1 k moves by a^T R k, small against nu. A stream whose
 * evictions nearly all rebuild has a dictionary too ill conditioned for
 * the recursion, and nu should be raised (docs/pacing.md, "KRLS", has
 * the measurements). stats.drift_max is the largest check, before
 * rebuild.
 *
 * Divisions. delta <= nu is the ALD branch (duplicates give delta = 0), so
 * the growth branch divides by delta > nu >= 1e-12 only; the RLS gain
 * divides by lambda + a^T P a >= lambda. gamma -> 0 makes every kernel
 * value 1 + bias: every sample after the first is ALD and the model is a
 * constant least-squares fit. Huge gamma makes K~ = I (plus bias): every
 * distinct sample is novel and the dictionary turns over by the policy
 * above.
 *
 * Optional extras, both off by default so that the model is the exact
 * least-squares solution above (the oracle tests rely on it):
 * - forget = lambda < 1 weighs sample i by lambda^(n-i), so the model keeps
 *   tracking a target that changes at fixed features (a transfer function
 *   changes what a fetch costs). Forgetting is suspended while trace(P) >=
 *   m, the trace a dictionary of m once-seen elements has, so a long still
 *   camera cannot wind P up without bound.
 * - clip = c >= 1 clamps the residual e = y - f(x) before it is learned,
 *   a Huber-style guard against a single timing that is far off (a frame
 *   stalled by the OS, a shader compile): to c * (s + 1e-3 ybar) for an
 *   ALD sample, s the running mean of clamped |e| (rate 1/16) and ybar
 *   that of |y| (the floor lets a fit that was exact move at all), and to
 *   c * (s + ybar) for a novel one, since the model has no support there.
 *   The first 8 samples are not clamped. s can grow by the factor
 *   1 + (c - 1) / 16 per update, so a true step in the target is followed
 *   after a few tens of updates rather than ignored (tests/test_krls.c
 *   holds a timing 1000x off to under 1% of the target with c = 4).
 * - noise_ratio = r > 0 puts a prior on each new element. Without it a
 *   novel sample sets its element's value to its own target, noise and
 *   all, and the next sample beside it is predicted by that one noisy
 *   value: on a camera orbit, where nearly every frame is novel, the
 *   model chases each frame's timing noise (docs/pacing.md, "The cost
 *   model", the bullet on the prior). With r, the element's value before
 *   its sample is the
 *   model's prediction a^T theta plus a deviation of variance delta / r
 *   (in units of the noise variance): delta is the share of k(x, x) the
 *   dictionary cannot express, the posterior variance of a Gaussian
 *   process with this kernel, so a sample beside known ones moves the
 *   model little and one far from them nearly as far as its target; r is
 *   the noise variance over the variance of the learned function. The
 *   sample is then learned by a Kalman step on the grown state, with e
 *   its residual and v = a^T P a + delta / r the prior variance of the
 *   new value: the old values move by P a e / (v + 1), the new one is
 *   a^T theta + v e / (v + 1), and P loses (P a)(P a)^T / (v + 1), its
 *   new row being P a / (v + 1) and its new diagonal entry v / (v + 1).
 *   v >= 0, so every division is by at least 1. r -> 0 gives the exact
 *   least-squares model above. The model is then the maximum a
 *   posteriori fit of the least-squares problem plus, for each element
 *   j, the term
 *   (theta_j - b_j^T theta)^2 r / delta_j with b_j its projection on the
 *   elements before it (tests/test_krls.c solves that directly).
 * For the cost model: forget = 0.995, clip = 4 and noise_ratio = 0.05
 * (docs/pacing.md, "The cost model", says why).
 *
 * Threading: a model belongs to one thread; predict is const and may run
 * concurrently with other predicts on the same model. */
#ifndef RP_KRLS_H
#define RP_KRLS_H

#include <stdint.h>

#include "raypace.h"

#ifdef __cplusplus
extern "C" {
#endif

#define RP__KRLS_MAX_DIM 8
#define RP__KRLS_MAX_DICT 256
/* Rebuild threshold for the drift check (see above). */
#define RP__KRLS_DRIFT_REBUILD 1e-6

typedef struct rp__krls rp__krls;

typedef enum rp__krls_evict {
  RP__KRLS_EVICT_LRU = 0,   /* the policy above */
  RP__KRLS_EVICT_OLDEST = 1 /* dlib's: for comparing with it */
} rp__krls_evict;

/* Zero means default for every field but dim. */
typedef struct rp__krls_desc {
  int dim;       /* features per sample, 1..RP__KRLS_MAX_DIM (required);
                    features are expected scaled to [0, 1] */
  double gamma;  /* RBF width, > 0; default 1 (features in [0, 1]) */
  double nu;     /* ALD tolerance on delta, >= 1e-12; default 1e-3 */
  int max_dict;  /* dictionary bound, 1..RP__KRLS_MAX_DICT; default 32 */
  double bias;   /* constant added to the kernel, >= 0; default 0. dlib's
                    krls adds 0.01 (an implicit intercept) */
  double forget; /* lambda in (0, 1]; default 1: no forgetting */
  double clip;   /* residual clamp factor c >= 1; default 0: off */
  int evict;     /* rp__krls_evict; default least recently used */
  double noise_ratio; /* r >= 0: the prior on a new element (above);
                    default 0: none */
  int signed_y;  /* 1: any finite target is learned; 0 (default): a
                    negative one is refused, since a timing or a cost
                    cannot be. A caller that learns a residual around a
                    mean (the cost model) sets it. */
} rp__krls_desc;

typedef struct rp__krls_stats {
  int size;          /* dictionary elements m */
  uint64_t updates;  /* samples learned */
  uint64_t grown;    /* samples that entered the dictionary */
  uint64_t evicted;  /* elements replaced */
  uint64_t clipped;  /* residuals clamped (clip > 0) */
  uint64_t checks;   /* drift checks */
  uint64_t rebuilds; /* exact rebuilds of K~^-1 */
  double drift;      /* last drift check */
  double drift_max;  /* largest drift check, before any rebuild */
  double floor_max;  /* largest check right after a rebuild */
} rp__krls_stats;

/* `in` with defaults filled in (in may be NULL: all defaults). */
void rp__krls_desc_defaults(const rp__krls_desc *in, rp__krls_desc *out);

/* Validates d (RP_EINVAL naming the field, RP_ENOTFINITE for NaN/inf) and
 * allocates every array for max_dict at once (RP_ENOMEM). */
int rp__krls_create(rp_context *ctx, const rp__krls_desc *d,
                    rp__krls **out);
void rp__krls_destroy(rp__krls *m); /* NULL: no-op */
/* Forgets every sample; keeps the desc and the memory. */
void rp__krls_reset(rp__krls *m);

/* Learns (x, y), x of dim features. Returns 0, RP_ENOTFINITE (NaN or inf
 * in x[i] or y; the message names it) or RP_ERANGE (y < 0 unless
 * signed_y: timings and costs are >= 0). On error the model is
 * unchanged. O(m^2) and no allocation; O(m^3) when the inverse is
 * rebuilt. */
int rp__krls_update(rp__krls *m, const double *x, double y);
/* f(x); 0 before the first sample. x is not checked: NaN in, NaN out.
 * O(m * dim). */
double rp__krls_predict(const rp__krls *m, const double *x);
/* How far x is from what the model learned: delta(x) / k(x, x), the
 * share of k(x, x) that the dictionary's span does not explain (a
 * Gaussian process's posterior variance over its prior, noise aside),
 * in [0, 1]: about 0 at a point it learned, 1 far from all of them and
 * with no dictionary. */
double rp__krls_novelty(const rp__krls *m, const double *x);

void rp__krls_get_stats(const rp__krls *m, rp__krls_stats *out);

/* For tests: dictionary element i (dim values into out, insertion
 * order), alpha_i, (K~^-1)_ij, and the full drift
 * max_ij |(K~ K~^-1 - I)_ij| (O(m^3), no side effect). */
void rp__krls_point(const rp__krls *m, int i, double *out);
double rp__krls_alpha(const rp__krls *m, int i);
double rp__krls_kinv(const rp__krls *m, int i, int j);
double rp__krls_drift(const rp__krls *m);

#ifdef __cplusplus
}
#endif

#endif /* RP_KRLS_H */
