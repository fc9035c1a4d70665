/* Controllers: the rule that picks each frame's sampling density rho
 * (DESIGN section 6). All share one life cycle: begin_frame gives the
 * density of the frame's first render pass, end_pass takes each pass's
 * measured time, and a frame ends when end_pass says so (one pass, or two
 * for two-pass). Decisions are made at begin_frame, from what the
 * previous frames measured and this frame's target, so that a target that
 * changes between frames is honoured at once. Every density leaves
 * through emit(), which keeps it finite and inside [rho_min, rho_max].
 *
 * The three reactive rules from other systems are re-implemented from
 * their published behaviour; each rule's block below cites its source. */
#include <math.h>
#include <string.h>

#include "internal.h"
#include "raypace_pace.h"

/* VTK (Kitware, https://github.com/Kitware/VTK: vtkFixedPointVolumeRay
 * CastMapper.cxx, ComputeRequiredImageSampleDistance() and Render();
 * vtkVolumeRayCastMapper.cxx, Render()): image sample distances 1 .. 10
 * (Minimum/MaximumImageSampleDistance defaults). The fixed-point mapper
 * stores t * (1 + 0.66 (d_used - d) / d) where d_used is the ray sample
 * distance the frame used; for renders allotted under one second it uses
 * InteractiveSampleDistance 2 against SampleDistance 1, so f = 1.66 there
 * and 1 otherwise. */
#define VTK_ISD_MIN 1.0
#define VTK_ISD_MAX 10.0
#define VTK_F_INTERACTIVE (1.0 + 0.66 * (2.0 - 1.0) / 1.0)
#define VTK_INTERACTIVE_MS 1000.0

/* Unreal Engine 5 dynamic resolution, console variables and defaults
 * (https://dev.epicgames.com/documentation/en-us/unreal-engine/
 * dynamic-resolution-in-unreal-engine; the r.DynamicRes.* help texts in
 * the UE 5 console variable reference; DynamicRenderScaling::
 * FHeuristicSettings, https://dev.epicgames.com/documentation/en-us/
 * unreal-engine/API/Runtime/RenderCore/FHeuristicSettings). */
#define UE_HISTORY 16     /* r.DynamicRes.HistorySize */
#define UE_WEIGHT 0.9     /* r.DynamicRes.FrameWeightExponent */
#define UE_HEADROOM 0.10  /* r.DynamicRes.TargetedGPUHeadRoomPercentage */
#define UE_PERIOD 8       /* r.DynamicRes.MinResolutionChangePeriod */
#define UE_PANIC 2 /* r.DynamicRes.MaxConsecutiveOverbudgetGPUFrameCount */
#define UE_THRESHOLD 0.02 /* r.DynamicRes.ChangePercentageThreshold 2 % */
#define UE_AMORTIZE 0.9   /* r.DynamicRes.IncreaseAmortizationBlendFactor */

/* Valve adaptive quality (A. Vlachos, "Advanced VR Rendering
 * Performance", GDC 2016, https://gdcvault.com/play/1023134/; its
 * published implementation, ValveCamera.cs UpdateAdaptiveQuality in
 * https://github.com/ValveSoftware/the_lab_renderer). Thresholds in
 * shares of the frame budget; a quality level is one fill-rate step. */
#define VALVE_LOW 0.70     /* raise under this for 3 frames */
#define VALVE_PREDICT 0.85 /* extrapolate when the last frame is over */
#define VALVE_HIGH 0.90    /* drop over this for 3 frames */
#define VALVE_WAIT 2       /* frames ignored after any change */
#define VALVE_DROP 2       /* levels per drop */
#define VALVE_STEP 1.15    /* fill rate per level (15 % steps) */
#define VALVE_MAX_LEVELS 4096

/* predicted: a frame that took more than this times its prediction
 * shows the model wrong for the scene at hand (an effect toggled, a TF
 * it has not learned), and the next frame does not raise the density.
 * The model's log residual has a standard deviation of about 0.17 on a
 * trusted scene, so ln 1.5 = 0.41 is 2.4 of them: a hold after a stall
 * costs one frame's rise, a hold after a wrong model stops the damped
 * climb from compounding its error (docs/pacing.md, "Tuner and
 * controllers"). */
#define PREDICT_TRUST 1.5
/* predicted: a frame that came in within this factor of its t' (either
 * way), on a scene that the model still prices within this factor of
 * that frame's time at that frame's density, shows the model right for
 * the scene at hand; the next frame then lifts a damped rise at
 * PREDICT_LIFT of the target instead of rp_tune's quarter. To
 * overshoot, the model would have to be off by 2x at the new density
 * just after it was off by under 1.2x at the old one. ln 1.2 = 0.18 is
 * one to four standard deviations of the model's log residual on a
 * scene it knows. The second test catches a scene that changed since
 * (docs/pacing.md, "Tuner and controllers", has both measured). */
#define PREDICT_CLOSE 1.2
#define PREDICT_LIFT 0.5

/* predicted's deadline contract (DESIGN section 12): each frame is aimed
 * at target * exp(-m). Its log residual r = ln(t / t') exceeds m exactly
 * when the frame is late (the target binding), so m must be the (1 - q)
 * quantile of r. The residuals' law drifts (a cold model, a new TF, a
 * zoom the model lags behind), so m is tracked online, in the
 * residuals' own scale: m = mean + k * spread, mean and spread
 * exponentially weighted (weight MISS_BETA: a surprise fades over some
 * tens of frames, not a window's length), and k moved after each frame
 * by k += MISS_GAMMA (late - q), late = r > m: the stochastic-
 * approximation step of online quantile tracking, the same as adaptive
 * conformal inference (Gibbs and Candes, 2021) takes on its level. Its
 * long-run share of late frames is q whatever the law, as long as k
 * stays inside its bounds; in the residuals' scale, a device whose noise
 * shrinks gets a margin that shrinks with it at once, where a step in
 * absolute terms would creep down at q of a step per frame. */
#define MISS_DEFAULT 0.05
/* The log residuals' spread assumed before any is seen: the model's on
 * a scene it knows is about 0.17 (PREDICT_TRUST), a new one's more. */
#define MISS_PRIOR_SD 0.2
#define MISS_BETA 0.15
#define MISS_GAMMA 0.1
/* The spread used is never under this: on a noise-free device k would
 * otherwise multiply nothing. */
#define MISS_SPREAD_MIN 0.005
/* The margin's bounds: under e^-0.5 a frame would aim past 1.6x its
 * target, over e^1.5 under a quarter of it; beyond both the residuals
 * say the model is not worth following, and the damping takes over. */
#define MISS_MARGIN_MIN (-0.5)
#define MISS_MARGIN_MAX 1.5
#define MISS_K_MAX 10.0
#define MISS_RESIDUAL_MAX 3.0
/* Novel frames (rp_controller_set_novelty over MISS_NOVEL_AT: the cost
 * model's learned points leave over half the kernel's prior variance
 * unexplained) keep statistics of their own, Mondrian-style: each group
 * holds the miss rate on its own, so that the model's error on new
 * scenes (a TF switch, a cut, a zoom never seen) widens the margin of
 * the next new scene and not of every frame, and the familiar frames'
 * calm does not narrow it for new ones. Their prior spread is twice the
 * familiar's: a new scene is where the model errs most. */
#define MISS_NOVEL_AT 0.5
#define MISS_PRIOR_SD_NOVEL 0.4

typedef struct miss_tracker {
  double r_mean, r_spread, k;
} miss_tracker;

struct rp_controller {
  rp_context *ctx;
  rp_controller_desc d; /* defaults filled in */
  int open;             /* a frame has begun and not ended */
  int pass;             /* passes ended in the open frame */
  double target;        /* the open frame's target */
  double frame_ms;      /* its passes' time so far */
  double rho_pass;      /* density of its current pass */
  uint64_t frames;      /* frames ended since create or reset */
  double rho_last;      /* final density of the last frame (rho_start
                           before the first) */
  double t_last;        /* its time */
  double pred_ms;       /* predicted: t' of the open frame, then of the
                           last one (NaN if none) */
  /* UE5: history newest first, the screen fraction s (rho = s^2) and
   * decisions since the last change. */
  double ue_t[UE_HISTORY], ue_s[UE_HISTORY];
  int ue_n;
  double ue_frac;
  int ue_since;
  /* Valve: ladder top, current level, frames rendered at it and the
   * last three frame times, newest first. */
  int v_top, v_level, v_since;
  double v_t[3];
  /* predicted's contract: per group (0 familiar, 1 novel frames) the
   * residuals' weighted mean and spread (mean absolute deviation) and
   * the quantile in spreads; the open (or last) frame's margin, its
   * group and the novelty set for the coming frame. */
  miss_tracker miss[2];
  double margin, novelty;
  int novel;
  int binding; /* the open (or last) frame's target bound its density */
};

/* ---- names and desc ---------------------------------------------------- */

static const char *const names[RP_CONTROL_COUNT] = {
    "none", "last-frame", "two-pass", "predicted", "vtk", "ue5", "valve"};

const char *rp_controller_name(rp_controller_kind kind) {
  return (unsigned)kind < RP_CONTROL_COUNT ? names[kind] : "unknown";
}

int rp_controller_from_name(const char *name, rp_controller_kind *out) {
  int i;
  if (name == NULL || out == NULL)
    return RP_EINVAL;
  for (i = 0; i < RP_CONTROL_COUNT; i++)
    if (strcmp(name, names[i]) == 0) {
      *out = (rp_controller_kind)i;
      return 0;
    }
  return RP_EINVAL;
}

/* a within PREDICT_CLOSE of b, either way; false for NaN. */
static int close_to(double a, double b) {
  return a <= PREDICT_CLOSE * b && a * PREDICT_CLOSE >= b;
}

/* The desc with its defaults filled in: the one place that knows them
 * (STYLE rule 3). */
static rp_controller_desc controller_defaults(const rp_controller_desc *in) {
  rp_controller_desc d;
  if (in != NULL)
    d = *in;
  else
    memset(&d, 0, sizeof d);
  if (d.rho_min == 0)
    d.rho_min = RP__RHO_MIN;
  if (d.rho_max == 0)
    d.rho_max = RP__RHO_MAX;
  /* Density 1 (the base step at full size) unless the bounds exclude it:
   * a density above 1 is for a frame the budget is known to allow. */
  if (d.rho_start == 0)
    d.rho_start = fmax(d.rho_min, fmin(1.0, d.rho_max));
  if (d.raise_limit == 0)
    d.raise_limit = RP__RAISE_LIMIT;
  if (d.miss_rate == 0)
    d.miss_rate = MISS_DEFAULT;
  /* vtk_f = 0 stays: VTK's own f depends on each frame's target, so
   * vtk_factor() resolves it per frame. */
  return d;
}

static int check_desc(rp_context *ctx, const rp_controller_desc *d) {
  const struct {
    const char *name;
    double v;
  } f[] = {{"rho_min", d->rho_min},
           {"rho_max", d->rho_max},
           {"rho_start", d->rho_start},
           {"raise_limit", d->raise_limit},
           {"vtk_f", d->vtk_f},
           {"tune_time_us", d->tune_time_us},
           {"miss_rate", d->miss_rate},
           {"headroom", d->headroom}};
  size_t i;
  if ((unsigned)d->kind >= RP_CONTROL_COUNT)
    return rp__fail(ctx, RP_EINVAL, "controller: field 'kind' = %d is not "
                    "a controller kind", (int)d->kind);
  for (i = 0; i < sizeof f / sizeof f[0]; i++)
    if (!isfinite(f[i].v))
      return rp__fail(ctx, RP_ENOTFINITE, "controller: field '%s' is %g",
                      f[i].name, f[i].v);
  if (!(d->rho_min > 0) || d->rho_min > d->rho_max)
    return rp__fail(ctx, RP_EINVAL, "controller: need 0 < rho_min (%g) <= "
                    "rho_max (%g)", d->rho_min, d->rho_max);
  if (d->rho_start < d->rho_min || d->rho_start > d->rho_max)
    return rp__fail(ctx, RP_EINVAL, "controller: field 'rho_start' = %g is "
                    "not in [rho_min, rho_max] = [%g, %g]", d->rho_start,
                    d->rho_min, d->rho_max);
  if (d->raise_limit < 1)
    return rp__fail(ctx, RP_EINVAL, "controller: field 'raise_limit' = %g "
                    "is under 1", d->raise_limit);
  if (d->vtk_f < 0)
    return rp__fail(ctx, RP_EINVAL, "controller: field 'vtk_f' = %g is "
                    "negative", d->vtk_f);
  if (d->tune_time_us < 0)
    return rp__fail(ctx, RP_EINVAL, "controller: field 'tune_time_us' = %g "
                    "is negative", d->tune_time_us);
  if (d->headroom < 0 || d->headroom > 0.9)
    return rp__fail(ctx, RP_EINVAL, "controller: field 'headroom' = %g is "
                    "not in [0, 0.9] (a share of the target kept free)",
                    d->headroom);
  if (d->miss_rate > 0.5)
    return rp__fail(ctx, RP_EINVAL, "controller: field 'miss_rate' = %g is "
                    "over 0.5 (a share of frames late; negative: no "
                    "margin)", d->miss_rate);
  return 0;
}

/* ---- shared helpers ---------------------------------------------------- */

static double clampd(double v, double lo, double hi) {
  return v < lo ? lo : v > hi ? hi : v;
}

/* The share of the target a reactive rule aims at: 1 - headroom. */
static double aim(const rp_controller *c) { return 1.0 - c->d.headroom; }

/* The one exit for densities: finite and inside [rho_min, rho_max]. A
 * rule that produced NaN (it should not) repeats last frame's density. */
static double emit(const rp_controller *c, double rho) {
  if (isnan(rho))
    rho = c->rho_last;
  return clampd(rho, c->d.rho_min, c->d.rho_max);
}

/* Seed 000 §6.1's damping: a rise is capped at raise_limit times the
 * reference, a fall is taken at once. */
static double damp(const rp_controller *c, double rho, double ref) {
  return fmin(rho, ref * c->d.raise_limit);
}

/* rho * target / t, the linear extrapolation every "last frame" rule
 * shares. t = 0 (an empty frame) asks for the most there is; the damping
 * or the clamp then bounds it. */
static double scale_to(double rho, double target, double t) {
  return t > 0 ? rho * (target / t) : INFINITY;
}

/* ---- Valve ladder ------------------------------------------------------ */

/* Level k of 0..v_top has rho_max * 1.15^(k - v_top), the bottom level
 * clamped to rho_min: ValveCamera.cs builds its ladder in 15 % fill-rate
 * steps (m_nFillRatePercentStep = 15), scale_{k+1} = sqrt(1.15) scale_k,
 * and fill rate is rho here. Valve's ladder spans render scales 0.8 to
 * 1.4; ours spans the controller's [rho_min, rho_max]. */
static double valve_rho(const rp_controller *c, int level) {
  return fmax(c->d.rho_min,
              c->d.rho_max * pow(VALVE_STEP, (double)(level - c->v_top)));
}

static void valve_init(rp_controller *c) {
  double steps = log(c->d.rho_max / c->d.rho_min) / log(VALVE_STEP);
  int down;
  c->v_top = (int)fmin(ceil(steps - 1e-9), VALVE_MAX_LEVELS - 1);
  /* The start: the highest level not above rho_start. */
  down = (int)ceil(log(c->d.rho_max / c->d.rho_start) / log(VALVE_STEP) -
                   1e-9);
  c->v_level = c->v_top - (down < 0 ? 0 : down > c->v_top ? c->v_top : down);
  c->v_since = 0;
}

static double normal_quantile(double p);

/* ---- create / reset ---------------------------------------------------- */

void rp_controller_reset(rp_controller *c) {
  int i;
  if (c == NULL)
    return;
  c->open = 0;
  c->pass = 0;
  c->frame_ms = 0;
  c->frames = 0;
  c->rho_last = c->d.rho_start;
  c->t_last = 0;
  c->pred_ms = NAN;
  c->ue_n = 0;
  c->ue_frac = sqrt(c->d.rho_start);
  c->ue_since = 0;
  valve_init(c);
  memset(c->v_t, 0, sizeof c->v_t);
  for (i = 0; i < 2; i++) {
    miss_tracker *t = &c->miss[i];
    t->r_mean = 0.0;
    /* A normal law's mean absolute deviation is 0.8 of its deviation. */
    t->r_spread = 0.8 * (i ? MISS_PRIOR_SD_NOVEL : MISS_PRIOR_SD);
    t->k = c->d.miss_rate > 0
               ? normal_quantile(1.0 - c->d.miss_rate) / 0.8
               : 0.0;
  }
  c->margin = 0.0;
  c->novel = 0;
}

int rp_controller_create(rp_context *ctx, const rp_controller_desc *desc,
                         rp_controller **out) {
  rp_controller_desc d;
  rp_controller *c;
  int err;
  if (ctx == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "controller: NULL %s",
                    ctx == NULL ? "context" : "output");
  d = controller_defaults(desc);
  if ((err = check_desc(ctx, &d)) != 0)
    return err;
  c = rp__calloc(ctx, 1, sizeof *c);
  if (c == NULL)
    return rp__fail(ctx, RP_ENOMEM, "controller: out of memory");
  c->ctx = ctx;
  c->d = d;
  rp_controller_reset(c);
  *out = c;
  return 0;
}

void rp_controller_destroy(rp_controller *c) {
  if (c != NULL)
    rp__free(c->ctx, c);
}

/* ---- the rules --------------------------------------------------------- */

/* Seed 000 §7 "Last frame", with §6.1's damping: rho * target / t_last. */
static double rule_last_frame(const rp_controller *c, double target) {
  return damp(c, scale_to(c->rho_last, aim(c) * target, c->t_last),
              c->rho_last);
}

/* VTK: isd' = isd * sqrt(t_last * f / budget), isd clamped to [1, 10],
 * no damping; rho = 1 / isd^2 (isd is pixels per ray along each image
 * axis). VTK picks f by the allotted time; vtk_f overrides it. */
static double vtk_factor(const rp_controller *c, double target) {
  if (c->d.vtk_f > 0)
    return c->d.vtk_f;
  return target < VTK_INTERACTIVE_MS ? VTK_F_INTERACTIVE : 1.0;
}

static double rule_vtk(const rp_controller *c, double target) {
  double isd = 1.0 / sqrt(c->rho_last);
  isd *= sqrt(c->t_last * vtk_factor(c, target) / (aim(c) * target));
  isd = clampd(isd, VTK_ISD_MIN, VTK_ISD_MAX);
  return 1.0 / (isd * isd);
}

/* UE5's heuristic on the primary screen fraction s, GPU time ~ s^2
 * (the Quadratic model), rho = s^2. Once more than UE_PANIC frames are
 * known, at each frame:
 * - targeted time T = budget * (1 - 10 %);
 * - over: the last 2 frames both over T; panic: both over the budget;
 * - each history frame k (newest first, weight 0.9^k; only the last 2
 *   when over) suggests s_k * sqrt(T / t_k), capped at s_k in a panic;
 *   the new s is the weighted mean;
 * - a rise is amortised: s + 0.9 (new - s); then clamped to the bounds;
 * - taken when over, or when >= 8 decisions passed since the last change
 *   and it moves s by more than 2 % (or onto a bound).
 * Departures: the bounds are the controller's sqrt(rho_min) ..
 * sqrt(rho_max), not r.DynamicRes.Min/MaxScreenPercentage (50 .. 100),
 * so that every controller searches the same space; UE's skip of the
 * first frame after a reset (its timing predates the reset) does not
 * apply to frames measured synchronously. Returns s. */
static double ue_decide(rp_controller *c, double budget) {
  const double smin = sqrt(c->d.rho_min), smax = sqrt(c->d.rho_max);
  const double T =
      budget * (1.0 - (c->d.headroom > 0 ? c->d.headroom : UE_HEADROOM));
  double s = c->ue_frac, sum = 0, wsum = 0, w = 1, next;
  int k, n = c->ue_n, panic = 1, over = 1, take;
  if (n <= UE_PANIC)
    return s; /* not enough history: no decision, nothing counted */
  for (k = 0; k < UE_PANIC; k++) {
    panic &= c->ue_t[k] > budget;
    over &= c->ue_t[k] > T;
  }
  if (panic || over)
    n = UE_PANIC;
  for (k = 0; k < n; k++) {
    /* t = 0 (an empty frame) asks for the largest fraction there is. */
    double f = c->ue_t[k] > 0 ? sqrt(T / c->ue_t[k]) : smax / c->ue_s[k];
    if (panic && f > 1)
      f = 1;
    sum += w * f * c->ue_s[k];
    wsum += w;
    w *= UE_WEIGHT;
  }
  next = sum / wsum;
  if (next > s)
    next = s + UE_AMORTIZE * (next - s);
  next = clampd(next, smin, smax);
  take = over || (c->ue_since >= UE_PERIOD &&
                  (next > s * (1 + UE_THRESHOLD) ||
                   next < s * (1 - UE_THRESHOLD) ||
                   (next != s && (next == smin || next == smax))));
  if (take) {
    c->ue_frac = next;
    c->ue_since = 0;
  } else {
    c->ue_since++;
  }
  return c->ue_frac;
}

/* Valve's rules, first match wins, each looking only at frames rendered
 * at the current level after the first VALVE_WAIT of them:
 * - the last 3 frames over 90 % of the budget: drop 2 levels;
 * - the last frame over 85 % and the linear extrapolation of the last two,
 *   t0 + (t0 - t1), over 90 %: drop 2 levels;
 * - the last 3 frames under 70 %: raise 1 level.
 * A change restarts the count (so a 3-frame rule fires at the earliest on
 * the 6th frame at a level). Drops of 2 levels and the 2-frame wait are
 * ValveCamera.cs's. That file also drops on any single frame over 90 %
 * and, with three frames known, extrapolates with max(t0 - t1,
 * (t0 - t2) / 2); both are left out here: this controller follows the
 * rule as the project states it (3 frames over 90 %, or 1 over 85 %
 * extrapolated from the last two). Returns the level. */
static int valve_decide(rp_controller *c, double budget) {
  const double lo = VALVE_LOW * aim(c) * budget,
               pr = VALVE_PREDICT * aim(c) * budget,
               hi = VALVE_HIGH * aim(c) * budget;
  const double *t = c->v_t;
  int level = c->v_level;
  if (c->v_since >= VALVE_WAIT + 3 && t[0] > hi && t[1] > hi && t[2] > hi)
    level -= VALVE_DROP;
  else if (c->v_since >= VALVE_WAIT + 2 && t[0] > pr &&
           t[0] + (t[0] - t[1]) > hi)
    level -= VALVE_DROP;
  else if (c->v_since >= VALVE_WAIT + 3 && t[0] < lo && t[1] < lo &&
           t[2] < lo)
    level += 1;
  level = level < 0 ? 0 : level > c->v_top ? c->v_top : level;
  if (level != c->v_level) {
    c->v_level = level;
    c->v_since = 0;
  }
  return c->v_level;
}

/* ---- predicted's deadline contract -------------------------------------- */

/* The standard normal's p-quantile, p in (0, 1): Abramowitz and Stegun
 * 26.2.23, within 4.5e-4 (the margin needs two digits). */
static double normal_quantile(double p) {
  double q = p < 0.5 ? p : 1.0 - p, t = sqrt(-2.0 * log(q)), z;
  z = t - (2.515517 + t * (0.802853 + t * 0.010328)) /
              (1.0 + t * (1.432788 + t * (0.189269 + t * 0.001308)));
  return p < 0.5 ? -z : z;
}

/* The margin the contract gives the next frame, from its group's
 * statistics. */
static double contract_margin(const rp_controller *c) {
  const miss_tracker *t = &c->miss[c->novel];
  return clampd(t->r_mean + t->k * fmax(t->r_spread, MISS_SPREAD_MIN),
                MISS_MARGIN_MIN, MISS_MARGIN_MAX);
}

/* After a frame of time t against `target` whose prediction was `pred`:
 * on a frame the target bound (the tuner aimed at it, no clamp or
 * damping between), late or not moves k; then the residual goes into
 * the mean and spread. An unpriced frame teaches nothing. A frame the
 * target did not bind (at the top density, a rise damped) would teach
 * k that frames are never late, and the first frame it binds again
 * would pay for it. */
static void contract_learn(rp_controller *c, double t, double target,
                           double pred) {
  miss_tracker *m = &c->miss[c->novel];
  double r;
  if (!(pred > 0.0) || !(t > 0.0) || !isfinite(pred))
    return;
  /* Logs apart (t / pred can overflow or vanish), and a frame off by
   * more than e^3 = 20x moves the statistics no more than one 20x off:
   * it says the model is wrong, not how wrong. */
  r = clampd(log(t) - log(pred), -MISS_RESIDUAL_MAX, MISS_RESIDUAL_MAX);
  if (c->binding)
    m->k = clampd(m->k + MISS_GAMMA * ((t > target ? 1.0 : 0.0) -
                                       c->d.miss_rate),
                  -MISS_K_MAX, MISS_K_MAX);
  m->r_spread += MISS_BETA * (fabs(r - m->r_mean) - m->r_spread);
  m->r_mean += MISS_BETA * (r - m->r_mean);
}

double rp_controller_margin(const rp_controller *c) {
  return c != NULL ? c->margin : 0.0;
}

void rp_controller_set_novelty(rp_controller *c, double novelty) {
  if (c != NULL)
    c->novelty = novelty >= 0.0 && novelty <= 1.0 ? novelty : 1.0;
}

/* ---- frame life cycle -------------------------------------------------- */

int rp_controller_begin_frame(rp_controller *c, double target_ms,
                              rp_predict_fn predict, void *user,
                              double *rho) {
  double r;
  if (c == NULL || rho == NULL)
    return rp__fail(c != NULL ? c->ctx : NULL, RP_EINVAL,
                    "controller: NULL %s", c == NULL ? "controller" : "rho");
  if (c->open)
    return rp__fail(c->ctx, RP_EINVAL, "controller: begin_frame while a "
                    "frame is open (%d passes ended); end it with "
                    "rp_controller_end_pass first", c->pass);
  if (isnan(target_ms) || isinf(target_ms))
    return rp__fail(c->ctx, RP_ENOTFINITE, "controller: target_ms is %g",
                    target_ms);
  if (!(target_ms > 0))
    return rp__fail(c->ctx, RP_EINVAL, "controller: target_ms = %g is not "
                    "positive", target_ms);
  if (c->d.kind == RP_CONTROL_PREDICTED && predict == NULL)
    return rp__fail(c->ctx, RP_EINVAL, "controller: 'predicted' needs a "
                    "predict function");

  switch (c->d.kind) {
  case RP_CONTROL_NONE: r = c->d.rho_start; break;
  case RP_CONTROL_LAST_FRAME:
    r = c->frames > 0 ? rule_last_frame(c, target_ms) : c->d.rho_start;
    break;
  case RP_CONTROL_TWO_PASS:
    /* Seed 000 §7 "Two pass": the first pass at a quarter of the last
     * frame's final density (rho_start stands in for it at first). */
    r = 0.25 * c->rho_last;
    break;
  case RP_CONTROL_PREDICTED: {
    rp_tune_desc td;
    rp_tune_result res;
    /* The last frame has a t' to be held against (NaN fails this). */
    int priced = c->frames > 0 && c->pred_ms > 0;
    int err;
    memset(&td, 0, sizeof td);
    c->novel = c->novelty > MISS_NOVEL_AT;
    c->margin = c->d.miss_rate > 0 ? contract_margin(c) : 0.0;
    td.target_ms = target_ms * exp(-c->margin);
    td.rho_prev = c->rho_last; /* rho_start before the first frame */
    td.rho_min = c->d.rho_min;
    td.rho_max = c->d.rho_max;
    td.raise_limit = c->d.raise_limit;
    td.max_time_us = c->d.tune_time_us; /* 0: rp_tune's default */
    /* The last frame against its own t', and this frame's scene at the
     * last frame's density against the last frame: a scene that changed
     * (an effect toggled, a new TF) is one the model has not yet been
     * right about. One prediction past rp_tune's budget. NaN compares
     * false. */
    if (priced && close_to(c->t_last, c->pred_ms) &&
        close_to(predict(user, c->rho_last), c->t_last))
      td.lift = PREDICT_LIFT;
    if ((err = rp_tune(&td, predict, user, &res)) != 0)
      return rp__fail(c->ctx, err, "controller: rp_tune failed (%s)",
                      rp_err_name(err));
    r = res.rho;
    c->binding = !res.limited;
    if (priced && c->t_last > PREDICT_TRUST * c->pred_ms &&
        r > c->rho_last) {
      /* Held, priced at the held density when the model can: one
       * prediction past rp_tune's max_iters and time. */
      r = c->rho_last;
      res.predicted_ms = predict(user, r);
      c->binding = 0;
    }
    c->pred_ms = res.predicted_ms;
    break;
  }
  case RP_CONTROL_VTK:
    r = c->frames > 0 ? rule_vtk(c, target_ms) : c->d.rho_start;
    break;
  case RP_CONTROL_UE5: {
    double s = ue_decide(c, target_ms);
    r = s * s;
    break;
  }
  case RP_CONTROL_VALVE: r = valve_rho(c, valve_decide(c, target_ms)); break;
  default: r = c->d.rho_start; break; /* unreachable: checked at create */
  }

  r = emit(c, r);
  c->open = 1;
  c->pass = 0;
  c->target = target_ms;
  c->frame_ms = 0;
  c->rho_pass = r;
  *rho = r;
  return 0;
}

/* What the rules learn from a finished frame of time t whose final
 * density was rho. */
static void end_frame(rp_controller *c, double t, double rho) {
  int k;
  if (c->d.kind == RP_CONTROL_PREDICTED && c->d.miss_rate > 0)
    contract_learn(c, t, c->target, c->pred_ms);
  c->open = 0;
  c->frames++;
  c->rho_last = rho;
  c->t_last = t;
  for (k = UE_HISTORY - 1; k > 0; k--) {
    c->ue_t[k] = c->ue_t[k - 1];
    c->ue_s[k] = c->ue_s[k - 1];
  }
  c->ue_t[0] = t;
  c->ue_s[0] = c->ue_frac;
  if (c->ue_n < UE_HISTORY)
    c->ue_n++;
  c->v_t[2] = c->v_t[1];
  c->v_t[1] = c->v_t[0];
  c->v_t[0] = t;
  c->v_since++;
}

int rp_controller_end_pass(rp_controller *c, double pass_ms, int *again,
                           double *rho) {
  double t;
  if (c == NULL || again == NULL || rho == NULL)
    return rp__fail(c != NULL ? c->ctx : NULL, RP_EINVAL,
                    "controller: NULL %s", c == NULL ? "controller"
                                           : again == NULL ? "again"
                                                           : "rho");
  if (!c->open)
    return rp__fail(c->ctx, RP_EINVAL, "controller: end_pass without "
                    "begin_frame (no frame is open)");
  if (isnan(pass_ms) || isinf(pass_ms))
    return rp__fail(c->ctx, RP_ENOTFINITE, "controller: pass_ms is %g",
                    pass_ms);
  if (pass_ms < 0)
    return rp__fail(c->ctx, RP_ERANGE, "controller: pass_ms = %g is "
                    "negative", pass_ms);

  t = c->frame_ms + pass_ms;
  c->pass++;
  if (c->d.kind == RP_CONTROL_TWO_PASS && c->pass == 1 &&
      pass_ms < 0.5 * aim(c) * c->target) {
    /* Under half the budget: extrapolate linearly to what is left of it
     * and render again; no damping (the paper's mode has none). */
    double r2 = emit(c, scale_to(c->rho_pass, aim(c) * c->target - pass_ms,
                                 pass_ms));
    if (r2 > c->rho_pass) {
      c->frame_ms = t;
      c->rho_pass = r2;
      *again = 1;
      *rho = r2;
      return 0;
    }
  }
  end_frame(c, t, c->rho_pass);
  *again = 0;
  *rho = c->rho_pass;
  return 0;
}
