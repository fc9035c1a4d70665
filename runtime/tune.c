/* The Eq. 2 tuner (DESIGN section 6, seed 000 section 6.1): the largest
 * sampling density rho whose predicted frame time t'(rho) meets the
 * target. Frame time is close to linear in rho, so the search is a
 * bracketed root find on g(rho) = t'(rho) - aim:
 * - one side known (every prediction so far under the aim, or every one
 *   over it): extrapolate. From one point, Eq. 2's rho * aim / t', which
 *   assumes t' proportional to rho; from two points on the same side,
 *   the secant through them, which is exact for t' = a rho + b (the
 *   proportional step alone only creeps up on a model with b != 0);
 * - both sides known: Eq. 2's third case, linear interpolation between
 *   the bracket ends (regula falsi). Plain regula falsi stalls when one
 *   end is never replaced (a convex t' keeps the far end forever); the
 *   Illinois rule (Dowell and Jarratt, BIT 11 (1971) 168-174) halves the
 *   stored g of an end that survives two steps in a row, which moves the
 *   interpolant toward it; an interpolant outside the bracket (rounding)
 *   falls back to bisection. A bracket wider than TUNE_WIDE in rho is
 *   split at its geometric middle instead (tests/test_tune.c shows one
 *   where interpolation ends at a third of the answer).
 * The aim is the middle of the accepted band [T (1 - tol), T], so that a
 * prediction landing on it (exactly, for a linear model) is feasible even
 * after rounding; a prediction inside the band ends the search. */
#include <math.h>
#include <string.h>

#include "internal.h"
#include "raypace_pace.h"

#define TUNE_ITERS 8
#define TUNE_TOL 0.01
#define TUNE_TIME_US 200.0
/* A bracket narrower than this, relative to its upper end, has nothing
 * left to find. */
#define TUNE_COLLAPSE 1e-12
/* Densities where the model predicted nothing usable, kept so that later
 * candidates step around them. More than this are not remembered. */
#define TUNE_MAX_BAD 16
/* Bracket ends further apart than this factor are split geometrically. */
#define TUNE_WIDE 4.0
/* The damping guards against a rise the model priced too low. A rise to
 * a density predicted at this share of the target or less would
 * overshoot only if the model were off by 4x; its log residual has a
 * standard deviation of about 0.17 here (docs/pacing.md), so 4x (ln 4 =
 * 1.39) is eight of them. Such a rise is taken at once: after a switch
 * to a cheap TF the finest image comes in one frame, not after five
 * damped ones, and after a frame that came in far under its prediction
 * (a fixed cost priced for the scene before) the density climbs back to
 * a quarter of the target in one frame, then damped the rest of the
 * way. */
#define TUNE_LIFT 0.25
/* When even rho_min is predicted over the target, no density meets it,
 * and the fastest frame is all rho_min buys. Where the fixed costs
 * dominate (launch, readback, a small image), that frame is hardly
 * faster than one at many times the density (docs/pacing.md, "Tuner and
 * controllers"). So the density goes to the largest predicted within
 * TUNE_FLOOR_SLACK of rho_min's time instead, for the best image that
 * time allows; but only if that is at least TUNE_FLOOR_GAIN times
 * rho_min: where the time is all samples (t' proportional to rho), 10 %
 * more time buys 10 % more density, not worth a frame that already
 * misses its target. */
#define TUNE_FLOOR_SLACK 0.1
#define TUNE_FLOOR_GAIN 2.0
/* Valid predictions a search keeps, for the floor search to start from
 * (more than TUNE_ITERS: a caller may allow more). */
#define TUNE_MAX_SEEN 16

/* The desc with its defaults filled in: the one place that knows them
 * (STYLE rule 3). */
static rp_tune_desc tune_defaults(const rp_tune_desc *in) {
  rp_tune_desc d = *in;
  if (d.rho_min == 0)
    d.rho_min = RP__RHO_MIN;
  if (d.rho_max == 0)
    d.rho_max = RP__RHO_MAX;
  if (d.raise_limit == 0)
    d.raise_limit = RP__RAISE_LIMIT;
  if (d.max_iters == 0)
    d.max_iters = TUNE_ITERS;
  if (d.tolerance == 0)
    d.tolerance = TUNE_TOL;
  if (d.max_time_us == 0)
    d.max_time_us = TUNE_TIME_US;
  if (d.lift == 0)
    d.lift = TUNE_LIFT;
  return d;
}

static int check_desc(const rp_tune_desc *d) {
  const struct {
    const char *name;
    double v;
  } f[] = {{"target_ms", d->target_ms},   {"rho_prev", d->rho_prev},
           {"rho_min", d->rho_min},       {"rho_max", d->rho_max},
           {"raise_limit", d->raise_limit}, {"tolerance", d->tolerance},
           {"max_time_us", d->max_time_us}, {"lift", d->lift}};
  size_t i;
  /* rp_tune has no context: the messages are dropped (rp__fail with a
   * NULL ctx), the codes say which class of fault it was. */
  for (i = 0; i < sizeof f / sizeof f[0]; i++)
    if (!isfinite(f[i].v))
      return rp__fail(NULL, RP_ENOTFINITE, "tune: field '%s' is %g",
                      f[i].name, f[i].v);
  if (!(d->target_ms > 0) || d->rho_prev < 0 || !(d->rho_min > 0) ||
      d->rho_min > d->rho_max || d->raise_limit < 1 ||
      d->max_iters < 1 || !(d->tolerance > 0 && d->tolerance < 1) ||
      !(d->max_time_us > 0) || !(d->lift > 0 && d->lift < 1))
    return rp__fail(NULL, RP_EINVAL, "tune: a field is out of range");
  return 0;
}

typedef struct point {
  double r, t;
} point;

typedef struct search {
  double target, aim, band_lo; /* T, T (1 - tol / 2), T (1 - tol) */
  double lb, ub;               /* rho_min and the damped upper clamp */
  int have_lo, have_lo2, have_hi, have_hi2;
  point lo, lo2; /* largest rho with t' <= aim, and the one before */
  point hi, hi2; /* smallest rho with t' > aim, and the one before */
  double glo, ghi; /* g at lo and hi, Illinois-scaled */
  int last_side;   /* -1: lo replaced last, +1: hi, 0: neither yet */
  int have_best;
  point best; /* largest rho with a valid t' <= T */
  int have_lb, tried_lb;
  double t_lb; /* t'(rho_min) when predicted validly */
  double bad[TUNE_MAX_BAD];
  int nbad;
  int probe; /* next fallback probe while nothing valid is known */
  point seen[TUNE_MAX_SEEN]; /* valid predictions, in the order made */
  int nseen;
} search;

/* The smallest known-bad density above r (+inf if none), and the
 * largest below it (0 if none). */
static double bad_above(const search *s, double r) {
  double b = INFINITY;
  int i;
  for (i = 0; i < s->nbad; i++)
    if (s->bad[i] > r && s->bad[i] < b)
      b = s->bad[i];
  return b;
}

static double bad_below(const search *s, double r) {
  double b = 0;
  int i;
  for (i = 0; i < s->nbad; i++)
    if (s->bad[i] < r && s->bad[i] > b)
      b = s->bad[i];
  return b;
}

/* Eq. 2's one-sided step from p toward the aim. With a second point q on
 * the same side, the secant through both; a secant that is flat or
 * falls (rho does not drive the time there) sends the search to the
 * clamp `bound`, where the model has to answer whether any density
 * helps. With p alone, rho * aim / t' (t' > 0 for every valid point). */
static double extrapolate(const search *s, point p, const point *q,
                          double bound) {
  if (q != NULL) {
    double slope = (p.t - q->t) / (p.r - q->r);
    if (!(slope > 0) || !isfinite(slope))
      return bound;
    return p.r + (s->aim - p.t) / slope;
  }
  return p.r * (s->aim / p.t);
}

/* The next density to predict, or -1 when the search can make no more
 * progress. */
static double next_candidate(search *s, double r0) {
  double r, bar;
  if (s->have_lo && s->have_hi) {
    double w = s->hi.r - s->lo.r;
    if (!(w > TUNE_COLLAPSE * s->hi.r))
      return -1;
    /* glo <= 0 < ghi, so the denominator is positive. */
    r = s->lo.r + w * (-s->glo / (s->ghi - s->glo));
    /* A bracket over a factor of TUNE_WIDE in rho: a straight line from
     * one end to the other is a poor model of t' there (a time that is
     * proportional to rho plus a constant bends on that scale), and the
     * interpolant creeps along the lower end. The geometric middle
     * halves the bracket's span in log rho at each step instead. */
    if (s->hi.r > TUNE_WIDE * s->lo.r)
      r = sqrt(s->lo.r * s->hi.r);
    if (!(r > s->lo.r && r < s->hi.r))
      r = s->lo.r + 0.5 * w;
    return r;
  }
  if (s->have_lo) {
    if (s->lo.r >= s->ub)
      return -1; /* the upper clamp is under the aim: done */
    r = extrapolate(s, s->lo, s->have_lo2 ? &s->lo2 : NULL, s->ub);
    if (!(r <= s->ub)) /* also catches NaN */
      r = s->ub;
    bar = bad_above(s, s->lo.r);
    if (r >= bar)
      r = 0.5 * (s->lo.r + bar);
    return r > s->lo.r ? r : -1;
  }
  if (s->have_hi) {
    if (s->hi.r <= s->lb)
      return -1; /* rho_min itself is over the aim */
    r = extrapolate(s, s->hi, s->have_hi2 ? &s->hi2 : NULL, s->lb);
    if (!(r >= s->lb))
      r = s->lb;
    bar = bad_below(s, s->hi.r);
    if (r <= bar) {
      /* The model cannot price the way down. Nothing feasible is known
       * yet, so first ask at rho_min, past the gap: a feasible point
       * there makes a bracket, and the search continues from below. */
      if (!s->tried_lb)
        return s->lb;
      r = 0.5 * (bar + s->hi.r);
    }
    return r < s->hi.r ? r : -1;
  }
  /* Nothing usable yet: the start, then each clamp. */
  while (s->probe < 3) {
    int i, seen = 0;
    r = s->probe == 0 ? r0 : s->probe == 1 ? s->ub : s->lb;
    s->probe++;
    for (i = 0; i < s->nbad; i++)
      seen |= s->bad[i] == r;
    if (!seen)
      return r;
  }
  return -1;
}

/* Files a valid prediction t at r. Returns 1 when it lands in the
 * accepted band. */
static int record(search *s, double r, double t) {
  s->tried_lb |= r == s->lb;
  if (s->nseen < TUNE_MAX_SEEN) {
    s->seen[s->nseen].r = r;
    s->seen[s->nseen].t = t;
    s->nseen++;
  }
  if (t <= s->target && (!s->have_best || r > s->best.r)) {
    s->best.r = r;
    s->best.t = t;
    s->have_best = 1;
  }
  if (r == s->lb) {
    s->have_lb = 1;
    s->t_lb = t;
  }
  if (t <= s->aim) {
    if (!s->have_lo || r > s->lo.r) {
      s->lo2 = s->lo;
      s->have_lo2 = s->have_lo;
      s->lo.r = r;
      s->lo.t = t;
      s->glo = t - s->aim;
      s->have_lo = 1;
      /* A point under the aim above a point over it: the model is not
       * monotone there. Keep the newer point; the old end is void. */
      if (s->have_hi && s->hi.r <= r)
        s->have_hi = s->have_hi2 = 0;
      if (s->have_hi && s->last_side == -1)
        s->ghi *= 0.5; /* Illinois: hi survived twice */
      s->last_side = -1;
    }
  } else if ((!s->have_hi || r < s->hi.r) && !(s->have_lo && r <= s->lo.r)) {
    s->hi2 = s->hi;
    s->have_hi2 = s->have_hi;
    s->hi.r = r;
    s->hi.t = t;
    s->ghi = t - s->aim;
    s->have_hi = 1;
    if (s->have_lo && s->last_side == 1)
      s->glo *= 0.5; /* Illinois: lo survived twice */
    s->last_side = 1;
  }
  return t >= s->band_lo && t <= s->target;
}

/* Whether the time budget that began at start_us (microseconds) is
 * spent. */
static int spent(double start_us, double max_us) {
  return rp__now_ms() * 1e3 - start_us >= max_us;
}

/* Whether t is a prediction at all: NaN, infinite or <= 0 is unknown. */
static int priced(double t) { return isfinite(t) && t > 0; }

/* Whether the best density found was cut by the upper clamp: at ub while
 * still under the band (it would have gone higher). */
static int held_at_ub(const search *s) {
  return s->have_best && s->best.r >= s->ub && s->best.t < s->band_lo;
}

/* Files a prediction that was NaN, infinite or <= 0 at r. */
static void record_bad(search *s, double r) {
  s->tried_lb |= r == s->lb;
  if (s->nbad < TUNE_MAX_BAD)
    s->bad[s->nbad++] = r;
  /* An interpolant between the bracket ends that the model cannot price:
   * drop the upper end, so the search continues upward from lo with this
   * point as a barrier, never past it. */
  if (s->have_lo && s->have_hi && r > s->lo.r && r < s->hi.r)
    s->have_hi = s->have_hi2 = 0;
}

/* Files the prediction t at r, priced or not. Returns 1 when it lands in
 * the accepted band. */
static int file_prediction(search *s, double r, double t) {
  if (priced(t))
    return record(s, r, t);
  record_bad(s, r);
  return 0;
}

static void search_init(search *s, double target, double tol, double lb,
                        double ub) {
  memset(s, 0, sizeof *s);
  s->target = target;
  s->aim = target * (1.0 - 0.5 * tol);
  s->band_lo = target * (1.0 - tol);
  s->lb = lb;
  s->ub = ub;
}

/* The search from r0 until a prediction lands in the band, the bracket
 * closes, or the call's iterations or time run out (iters counts every
 * prediction of the call). */
static void run_search(search *s, double r0, const rp_tune_desc *d,
                       rp_predict_fn predict, void *user, double start,
                       int *iters) {
  while (*iters < d->max_iters) {
    double r, t;
    /* Checked before each prediction but the first: the call overruns
     * max_time_us by at most one prediction. */
    if (*iters > 0 && spent(start, d->max_time_us))
      break;
    r = next_candidate(s, r0);
    if (r < 0)
      break;
    t = predict(user, r);
    (*iters)++;
    if (file_prediction(s, r, t))
      break;
  }
}

/* The lift: held back by the damping alone, with the density it allows
 * predicted far under the target (at d->lift of it or less), the density
 * rises to the largest predicted at d->lift of the target, searched the
 * same way between that density and rho_max (first asking at rho_max,
 * which is the answer after a switch to a cheap TF). */
static void lift(search *s, const rp_tune_desc *d, rp_predict_fn predict,
                 void *user, double start, int *iters) {
  search l;
  double t;
  if (!(held_at_ub(s) && s->ub < d->rho_max &&
        s->best.t <= d->lift * s->target && *iters < d->max_iters &&
        !spent(start, d->max_time_us)))
    return;
  t = predict(user, d->rho_max);
  (*iters)++;
  search_init(&l, d->lift * s->target, d->tolerance, s->best.r, d->rho_max);
  (void)file_prediction(&l, d->rho_max, t);
  if (!(l.have_best && l.best.r >= d->rho_max) &&
      !record(&l, s->best.r, s->best.t))
    run_search(&l, d->rho_max, d, predict, user, start, iters);
  if (l.have_best && l.best.r > s->best.r) {
    s->best = l.best;
    s->ub = l.best.r; /* still held by the damping, or at rho_max */
  }
}

/* What a target under rho_min's time gets: rho_min, or, when even rho_min
 * is over the target (TUNE_FLOOR_SLACK), the largest density predicted
 * within the slack of rho_min's time if that is at least
 * TUNE_FLOOR_GAIN times rho_min. The search starts from what this call
 * has predicted already (on a steady scene, last frame's answer is among
 * it and ends it), then asks the upper clamp (a time that does not
 * depend on rho ends there), then searches between. Its band is kept in
 * the upper half of the slack (a caller's wide tolerance would reach
 * down to rho_min's own time and end the search there). */
static point floor_search(const search *s, const rp_tune_desc *d,
                          rp_predict_fn predict, void *user, double start,
                          int *iters) {
  point cheapest;
  search f;
  int i, done = 0, have_ub = 0;
  cheapest.r = s->lb;
  cheapest.t = s->t_lb;
  if (!(!s->have_best && s->have_lb && s->ub > s->lb &&
        *iters < d->max_iters && !spent(start, d->max_time_us)))
    return cheapest;
  search_init(&f, s->t_lb * (1.0 + TUNE_FLOOR_SLACK),
              fmin(d->tolerance,
                   0.5 * TUNE_FLOOR_SLACK / (1.0 + TUNE_FLOOR_SLACK)),
              s->lb, s->ub);
  memcpy(f.bad, s->bad, sizeof f.bad);
  f.nbad = s->nbad;
  for (i = 0; i < f.nbad; i++)
    have_ub |= f.bad[i] == s->ub; /* asked already, and unpriced */
  for (i = 0; i < s->nseen && !done; i++)
    if (s->seen[i].r <= s->ub) {
      have_ub |= s->seen[i].r == s->ub;
      done = record(&f, s->seen[i].r, s->seen[i].t);
    }
  if (!done && !have_ub && !(f.have_best && f.best.r >= s->ub)) {
    double t = predict(user, s->ub);
    (*iters)++;
    done = file_prediction(&f, s->ub, t);
  }
  if (!done && !(f.have_best && f.best.r >= s->ub))
    run_search(&f, s->ub, d, predict, user, start, iters);
  if (f.have_best && f.best.r >= TUNE_FLOOR_GAIN * s->lb)
    cheapest = f.best;
  return cheapest;
}

/* The call's answer from its searches; `cheapest` is floor_search's. */
static void tune_result(const search *s, const rp_tune_desc *d,
                        point cheapest, rp_tune_result *out) {
  double r;
  if (s->have_best) {
    out->rho = s->best.r;
    out->predicted_ms = s->best.t;
    out->limited = held_at_ub(s);
  } else if (s->have_lb) {
    /* Even rho_min is over the target: rho_min, or the density within
     * TUNE_FLOOR_SLACK of its time found above. */
    out->rho = cheapest.r;
    out->predicted_ms = cheapest.t;
    out->limited = 1;
  } else if (s->have_hi) {
    /* Every valid prediction was over the target and the budget ran out
     * before rho_min was tried: Eq. 2's step down from the lowest one,
     * unverified. */
    r = extrapolate(s, s->hi, s->have_hi2 ? &s->hi2 : NULL, s->lb);
    /* A step into or past a density the model could not price is no
     * guess at all: rho_min then. */
    out->rho = r >= s->lb && r < s->hi.r && bad_below(s, s->hi.r) < r
                   ? r
                   : s->lb;
    out->predicted_ms = NAN;
    out->limited = out->rho <= s->lb;
  } else {
    /* The model priced nothing: keep last frame's density. */
    out->rho = d->rho_prev > 0
                   ? fmin(fmax(d->rho_prev, d->rho_min), d->rho_max)
                   : d->rho_max;
    out->predicted_ms = NAN;
  }
}

int rp_tune(const rp_tune_desc *desc, rp_predict_fn predict, void *user,
            rp_tune_result *out) {
  rp_tune_desc d;
  search s;
  point cheapest;
  double r0, start, r;
  int err, iters = 0;
  if (desc == NULL || predict == NULL || out == NULL)
    return rp__fail(NULL, RP_EINVAL, "tune: NULL argument");
  d = tune_defaults(desc);
  if ((err = check_desc(&d)) != 0)
    return err;

  /* The clamps: rho in [rho_min, ub], ub = min(rho_max, rho_prev *
   * raise_limit) (seed 000 §6.1: damping applies to rises only), and
   * never under rho_min, which wins over the damping. */
  r = d.rho_max;
  if (d.rho_prev > 0 && d.rho_prev * d.raise_limit < r)
    r = d.rho_prev * d.raise_limit;
  search_init(&s, d.target_ms, d.tolerance, d.rho_min,
              r < d.rho_min ? d.rho_min : r);
  /* Start at last frame's density: Eq. 2 extrapolates from it, and for
   * a scene that did not change it is the answer already. */
  r0 = d.rho_prev > 0 ? fmin(fmax(d.rho_prev, s.lb), s.ub) : s.ub;

  start = rp__now_ms() * 1e3; /* microseconds */
  run_search(&s, r0, &d, predict, user, start, &iters);
  memset(out, 0, sizeof *out);
  lift(&s, &d, predict, user, start, &iters);
  cheapest = floor_search(&s, &d, predict, user, start, &iters);
  out->iters = iters;
  tune_result(&s, &d, cheapest, out);
  return 0;
}
