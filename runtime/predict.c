/* The hybrid cost model (DESIGN section 5, seed 000 section 5):
 *   t' = (a R + sigma' * k * kappa * S' + c0) * Q,
 *   sigma' = exp(m + f(x)) * q.
 * What each part is for, and the measurements that chose its form:
 * docs/pacing.md, "The cost model" (one bullet per part).
 *
 * The analytic part. S' comes from a probe of the frame: the depth pass
 * and the ERT pre-pass run on the pre-pass grid of the OUTPUT image (one
 * ray per 4x4 pixels). A probe ray's sampled span is
 * L = min(D_back, D'_ERT) - D_front (D'_ERT only with ERT on) and the
 * raycast takes about L / step + 1/2 lattice samples on it (the lattice
 * starts at the box entry, so the first sample lies uniformly within one
 * step of D_front), or L / step + 1 when ERT ends it (the sample that
 * crosses the threshold is taken too: a ray ended at once takes one).
 * At image scale s the raycast casts rp_scaled_size() rays over the same
 * frustum: the same distribution of spans, sampled more or less densely:
 *   S'(step, s) = rays(s) / probe_rays * sum_i (L_i / step + e_i),
 * e_i = 1 for rays ERT ends and 1/2 for the others. With the ray starts
 * jittered (rp_jitter) the lattice's phase on L is uniform, so a ray that
 * runs through L takes L / step samples on average: e_i = 0 for the rays
 * ERT does not end. One that ERT ends still takes the sample that
 * crosses the threshold (a ray ended at once takes one): e_i = 1.
 * One probe serves every (step, s) the tuner tries.
 *
 * sigma, the cost of one volume fetch, is learned per device by KRLS
 * (runtime/krls.h) from the frame's raycast, R the rays cast at its
 * scale and S_measured its tiles' sample counts (the truth, so that an
 * error in S' is not folded into sigma):
 *   raycast time = a R + sigma * k * S_measured,
 *   sigma_measured = (raycast time - a R) / (k * S_measured).
 * KRLS learns the residual r = ln(sigma) - m around a robust running
 * mean m of ln(sigma) (below): far from every dictionary element an RBF
 * model goes to 0, and on the residual an unseen view falls back to the
 * mean cost instead of a free frame; in the logarithm the model is
 * multiplicative, as cache effects are, and sigma' is positive whatever
 * the fit does. m follows a slow drift (a warming cache, the OS) that
 * KRLS's forgetting alone would take a dictionary's worth of frames to
 * follow. Each new dictionary element starts from a prior
 * (noise_ratio, runtime/krls.h), so that one noisy frame is not taken as
 * the cost of every view beside it.
 *
 * kappa = S_measured / S', the sample estimate's own bias, is learned by
 * a second KRLS on the same features, in the same residual-around-a-mean
 * form. The probe draws the mean opacity of the volume's voxels in each
 * opacity bin (rp_occupancy's bin_alpha), not the bin's centre, so kappa
 * is left with what the probe's 4x4 grid and the lattice miss.
 *
 * a, the raycast's own cost per ray (ray setup, the box entry, the walk
 * past empty blocks, the pixel write; the launch shared among the rays):
 * per ray, not per launch, so that frames at every scale share one line.
 * It is the intercept of a Theil-Sen line (the median of the pairwise
 * slopes, then the median intercept) through the last LAUNCH_WINDOW
 * frames' (k S_measured / R, raycast time / R): a quarter of them may be
 * stalls without moving it, where a least-squares line follows any one.
 * Left out of the fit: pairs closer than a factor LAUNCH_SPREAD in
 * k S / R (in this noise they carry no slope), and pairs, and frames for
 * the intercept, rendered with other effects than the newest frame (with
 * shading, the gradient's fetches hit the cache the sample's own fetch
 * just filled, so a fetch costs less: a line through both mixes two
 * costs per fetch). With fewer than LAUNCH_PAIRS pairs left (a steady
 * scene, where a and sigma cannot be told apart and need not be) a stays
 * as it was. a is clamped to [0, LAUNCH_SHARE of the cheapest raycast per
 * ray in the window], fit or no fit: a neighbour on the machine only ever
 * adds time, so the cheapest frame bounds a, and a frame of a new scene
 * cheaper than the old a says so at once. When a moves, sigma is learned
 * again from the window's frames (sigma_relearn). A frame whose fetches
 * take under half its raycast, or less than SIGMA_CLEAR times the fit's
 * noise, does not teach sigma (sigma_learn): its sigma is a small
 * difference of noisy times, and its own time hardly depends on sigma.
 * The fit's noise is relative (the median of |residual| / raycast), as
 * the machine's is.
 *
 * q, the short-term correction: when the last RECENT_FRAMES frames all
 * came in dearer than sigma' (or all cheaper), q is the smallest of those
 * ratios, bounded to [1/2, 2]; otherwise 1. It follows a slow spell of
 * the machine from its third frame, where m follows at a rate of 1/16.
 * One stalled frame does not move q, and a view that the model prices
 * low next to one it prices high (alternating) leaves it at 1.
 *
 * Q, the frame correction: formed like q, but from the frames that do
 * not teach sigma, as ln(frame time / t' without Q), bounded to
 * [1/4, 4]; a frame that teaches sigma sets Q back to 1. Those frames'
 * time is mostly a and c0, and neither q nor KRLS ever sees them. Only
 * they feed Q, so a slow spell on frames that teach sigma is not
 * corrected twice (by q and again by Q).
 *
 * c0, the per-frame fixed cost (depth pass, readback, upscale), is
 * measured per frame as frame time - raycast time and averaged the same
 * way, apart for frames at scale 1 and frames upscaled from a smaller
 * image: the upscale is a pass over every output pixel that a full-scale
 * frame does not have, and a tuner stepping across scale 1 must see it.
 *
 * Robust running mean: the plain mean of the first 16 values, then an
 * exponential mean of rate 1/16; after the first 4 values a value moves
 * it at most as far as 4 times the running mean absolute deviation (plus
 * a floor), the clamp KRLS applies to its residuals. One timing 1000x off
 * then moves the mean by at most a quarter of its usual spread, while a
 * true step (a new transfer function that makes fetches dearer) is
 * followed within a few tens of frames: each clamped value widens the
 * limit by about a fifth.
 *
 * Features, each scaled to [0, 1] with fixed bounds (so a new frame
 * never rescales what was learned) and clamped:
 *   0-2  view direction, (d + 1) / 2 per axis. DESIGN names two view
 *        angles; an azimuth wraps at 360 degrees, which puts two nearly
 *        equal views at opposite ends of the feature range, while the
 *        direction vector is continuous.
 *   3    splatted voxel size at the rendered scale, pixels per voxel,
 *        log2 over [1/16, 16]: how far apart neighbouring rays sample
 *        (cache reuse);
 *   4    step, log2 over [1/8, 16] voxels;
 *   5    the share of the span ERT removes. DESIGN (after seed 000) names
 *        the ERT pre-pass time; a time carries the machine's noise and
 *        needs a scale, while the share it stands for is exact;
 *   6, 7 max and mean span over the volume diagonal. */
#include <math.h>
#include <string.h>

#include "bounds.h"
#include "internal.h"
#include "krls.h"
#include "passes.h"
#include "raypace_pace.h"

/* The launch-cost fit (above): frames kept, the spread in k S that makes
 * a pair, the pairs a fit needs, and a's ceiling against the cheapest
 * raycast kept. */
#define LAUNCH_WINDOW 24
#define LAUNCH_SPREAD 4.0
#define LAUNCH_PAIRS 8
#define LAUNCH_SHARE 0.9
#define LAUNCH_RELEARN 0.1
/* The least share of a raycast its fetches must take to teach sigma. */
#define SIGMA_SHARE 0.5
/* ... and how many times the launch fit's noise it must stand clear of. */
#define SIGMA_CLEAR 4.0

typedef struct launch_fit {
  double x[LAUNCH_WINDOW]; /* k * S_measured per ray */
  double y[LAUNCH_WINDOW]; /* raycast ms per ray */
  double feat[LAUNCH_WINDOW][RP_COST_FEATURES]; /* to relearn sigma */
  uint32_t effects[LAUNCH_WINDOW];
  uint32_t n, next;
  double a;     /* ms per ray */
  double noise; /* median |raycast - (a + b k S)| / raycast over the
                   window */
} launch_fit;

/* The short-term corrections (above): frames that must agree, and the
 * bounds of ln q, ln 2, and of ln Q, ln 4. */
#define RECENT_FRAMES 3
#define RECENT_BOUND 0.6931471805599453
#define FRAME_BOUND 1.3862943611198906
/* How far (in [0, 1] feature units) a frame's scene features may be from
 * the last trained frame's for q and Q to apply to it whole: more than a
 * camera move changes them in a frame, less than a TF switch does
 * (docs/pacing.md, "The cost model", the bullet on q). */
#define SCENE_NEAR 0.1

/* The last RECENT_FRAMES log ratios (measured over predicted), the
 * correction they give (recent_add), and the scene of the newest: the
 * features and effects of the frame that filed it (carried). */
typedef struct recent_bias {
  double v[RECENT_FRAMES];
  uint32_t n, next;
  double log_corr;
  double x[RP_COST_FEATURES];
  uint32_t effects;
} recent_bias;

/* The robust running mean (above): window, clamp start and factor. */
#define MEAN_WINDOW 16
#define MEAN_CLAMP_AFTER 4
#define MEAN_CLAMP 4.0

typedef struct robust_mean {
  double mean, spread; /* spread: running mean absolute deviation */
  double min_spread;   /* smallest spread the clamp assumes */
  uint64_t n;
} robust_mean;

struct rp_cost_model {
  rp_context *ctx;
  rp_cost_model_desc d;
  rp__krls *krls;        /* sigma's residual */
  rp__krls *kappa_krls;  /* kappa's residual */
  robust_mean log_sigma; /* m: of ln(sigma_ns) */
  robust_mean log_kappa; /* of ln(S_measured / S') */
  robust_mean c0[2];     /* of frame - raycast time, ms: [0] frames at
                            scale 1, [1] upscaled ones */
  launch_fit launch;
  /* The short-term corrections (header): q from the last frames' ln(sigma
   * measured / sigma'), Q from the last frames' ln(frame time / t') of
   * the frames that do not teach sigma. */
  recent_bias sigma_bias, frame_bias;
};

static double clamp01(double v) {
  return v > 0.0 ? (v < 1.0 ? v : 1.0) : 0.0; /* NaN -> 0 */
}

uint32_t rp_fetches_per_sample(uint32_t effects) {
  return 1u + ((effects & RP_EFFECT_SHADING) ? 6u : 0u) +
         ((effects & RP_EFFECT_AO) ? 1u : 0u);
}

/* ---- Probe --------------------------------------------------------------- */

/* One probe row's sums, added up in row order afterwards. */
typedef struct probe_row {
  double span, span_no_ert, max, lit_span, lit_ends;
  uint32_t hit, ended;
} probe_row;

typedef struct probe_job {
  const rp__raygen *rg;
  const uint8_t *grid;       /* occupancy, or NULL */
  const uint8_t *alpha_hist; /* H-alpha, or NULL */
  const float *visible;      /* per block, or NULL: no shading */
  double corr[RP_OPACITY_BINS]; /* bin opacities at the coarse step */
  const uint32_t *blocks;
  int skip, ert;
  double end_extra; /* 1/2 unjittered, else 0: the e_i of a ray not ended */
  float threshold;
  uint32_t seed, frame, gw;
  uint32_t sub; /* trace every sub-th pre-pass ray along each axis */
  uint32_t map_w;  /* rays per subgrid row */
  probe_row *rows;
  float *span;     /* the probe's span map */
} probe_job;

/* The most pre-pass rays a probe traces: a subgrid of this many estimates
 * the mean span well inside a frame's own noise, and kappa corrects the
 * rest (docs/runtime.md, "Overhead"). */
#define PROBE_MAX_RAYS ((uint32_t)RP_PROBE_MAX_RAYS)

/* Rays in the subgrid of every sub-th ray of a gw x gh grid. */
static uint32_t probe_rays(uint32_t gw, uint32_t gh, uint32_t sub) {
  return ((gw + sub - 1) / sub) * ((gh + sub - 1) / sub);
}

/* The share of voxels that show in the blocks along [front, stop] of a
 * ray: the mean over points half a block apart (at least one), each at
 * the centre of its stretch. The blocks' shares are exact counts (of the
 * voxels whose density bin has opacity above 0); what this misses is
 * interpolation across a bin edge, and that a SIMD packet or a GPU warp
 * shades all its lanes when one shows, which sigma absorbs. */
static double visible_share(const probe_job *j, const rp__ray *ray,
                            double front, double stop) {
  double len = stop - front, n = ceil(len / RP_ERT_COARSE_STEP), sum = 0.0;
  uint32_t k, count;
  if (!(n >= 1.0))
    n = 1.0;
  count = n > 4096.0 ? 4096u : (uint32_t)n;
  for (k = 0; k < count; k++) {
    double t = front + ((double)k + 0.5) * len / (double)count, p[3];
    int a;
    for (a = 0; a < 3; a++)
      p[a] = ray->p0[a] + t * ray->dp[a];
    sum += j->visible[rp__block_of(p, j->blocks)];
  }
  return sum / (double)count;
}

static void probe_rows(uint32_t begin, uint32_t end, void *user) {
  const probe_job *j = user;
  uint32_t cy, cx;
  for (cy = begin; cy < end; cy++) {
    probe_row r = {0.0, 0.0, 0.0, 0.0, 0.0, 0, 0};
    if (cy % j->sub != 0) {
      j->rows[cy] = r;
      continue;
    }
    for (cx = 0; cx < j->gw; cx += j->sub) {
      rp__ray ray;
      double front, back, stop;
      int ended;
      rp__raygen_ray_at(j->rg, (double)(RP_ERT_RAY_STRIDE * cx) + 2.0,
                        (double)(RP_ERT_RAY_STRIDE * cy) + 2.0, &ray);
      float *span = &j->span[(cy / j->sub) * j->map_w + cx / j->sub];
      *span = 0.0f;
      if (!ray.hit)
        continue;
      rp__depth_ray(&ray, j->rg->dims, j->skip ? j->grid : NULL, j->blocks,
                    &front, &back);
      if (!(front <= back))
        continue;
      stop = back;
      ended = 0;
      if (j->ert) {
        /* Lattice points before D_front and past D_back lie in empty
         * blocks, where the pre-pass draws nothing: it marches from one
         * point before the first occupied block to one past the last
         * (a coarse step of margin for the depths' rounding), and ends
         * where the whole ray would. */
        double first = floor((front - ray.s) / RP_ERT_COARSE_STEP) - 1.0,
               last = ceil((back - ray.s) / RP_ERT_COARSE_STEP) + 2.0;
        double d = rp__ert_march(
            &ray, cy * j->gw + cx, first > 0.0 ? (uint64_t)first : 0,
            last > 0.0 ? (uint64_t)last : 0, j->grid, j->alpha_hist, j->corr,
            j->blocks, j->threshold, j->seed, j->frame);
        if (d <= stop) {
          stop = d > front ? d : front;
          r.ended++;
          ended = 1;
        }
      }
      if (j->visible != NULL) {
        double v = visible_share(j, &ray, front, stop);
        r.lit_span += (stop - front) * v;
        r.lit_ends += ended ? 1.0 : j->end_extra * v;
      }
      r.span += stop - front;
      *span = (float)(stop - front);
      r.span_no_ert += back - front;
      if (stop - front > r.max)
        r.max = stop - front;
      r.hit++;
    }
    j->rows[cy] = r;
  }
}

/* Output pixels one voxel (of the finest spacing) spans where the view
 * axis meets the volume centre; an eye at or inside the centre counts as
 * one voxel away. */
static double pixels_per_voxel(const rp__raygen *rg) {
  double dist = 0.0, world_h;
  int a;
  if (rg->ortho) {
    world_h = 2.0 * rg->half_h;
  } else {
    /* The centre is the world origin: its depth along f. */
    for (a = 0; a < 3; a++)
      dist -= rg->eye[a] * rg->f[a];
    if (dist < rg->min_spacing)
      dist = rg->min_spacing;
    world_h = 2.0 * rg->half_h * dist;
  }
  return (double)rg->height * rg->min_spacing / world_h;
}

uint32_t rp__probe_ray_budget(double budget_ms, double ms_per_ray) {
  double n;
  if (!(ms_per_ray > 0.0) || !(budget_ms >= 0.0))
    return PROBE_MAX_RAYS; /* nothing measured yet: the full probe */
  n = budget_ms / ms_per_ray;
  if (!(n >= (double)RP__PROBE_MIN_RAYS))
    return RP__PROBE_MIN_RAYS;
  return n >= (double)PROBE_MAX_RAYS ? PROBE_MAX_RAYS : (uint32_t)n;
}

int rp_frame_probe_compute(rp_context *ctx, const rp_volume *vol,
                           const rp_tf *tf, const rp_occupancy *occ,
                           const rp_camera *cam, const rp_render_desc *desc,
                           uint32_t seed, uint32_t frame,
                           rp_frame_probe *out) {
  return rp__frame_probe_compute(ctx, vol, tf, occ, cam, desc, seed, frame,
                                 PROBE_MAX_RAYS, out);
}

int rp__frame_probe_compute(rp_context *ctx, const rp_volume *vol,
                            const rp_tf *tf, const rp_occupancy *occ,
                            const rp_camera *cam, const rp_render_desc *desc,
                            uint32_t seed, uint32_t frame, uint32_t max_rays,
                            rp_frame_probe *out) {
  static const char fn[] = "rp_frame_probe_compute";
  const char *missing = vol == NULL   ? "vol"
                        : tf == NULL  ? "tf"
                        : occ == NULL ? "occ"
                        : cam == NULL ? "cam"
                        : desc == NULL ? "desc"
                        : out == NULL ? "out"
                                      : NULL;
  rp_render_desc d;
  rp__raygen rg;
  probe_job job;
  uint32_t gw, gh, y;
  double t0 = rp__now_ms(), span_no_ert = 0.0;
  int err, a;
  if (ctx == NULL)
    return RP_EINVAL;
  if (missing != NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: %s is NULL", fn, missing);
  d = rp__render_desc_defaults(desc);
  if ((err = rp__check_render_desc(ctx, fn, &d)) != 0)
    return err;
  /* The ERT pre-pass reads H-alpha even without skipping, so the
   * occupancy is always required and must match. */
  if ((err = rp__occupancy_check(ctx, fn, occ, tf->id, vol->id)) != 0)
    return err;
  if ((err = rp__raygen_init(ctx, cam, vol, d.width, d.height, &rg)) != 0)
    return err;
  {
    /* The frame's work bound, before the probe walks its rays. */
    rp__raygen scaled = rg;
    rp_scaled_size(&d, &scaled.width, &scaled.height);
    if ((err = rp__check_work(ctx, fn, &scaled, d.step)) != 0)
      return err;
  }
  rp__ert_grid(d.width, d.height, &gw, &gh);
  memset(out, 0, sizeof(*out));
  job.rows = rp__calloc(ctx, gh, sizeof(probe_row));
  if (job.rows == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: %u probe rows", fn, gh);
  job.rg = &rg;
  job.grid = occ->grid;
  job.alpha_hist = occ->alpha_hist;
  /* The visible share is needed only when something is shaded or
   * occluded. */
  job.visible =
      (d.effects & (RP_EFFECT_SHADING | RP_EFFECT_AO)) ? occ->visible : NULL;
  rp__ert_corrected(occ->bin_alpha, tf->reference_step, job.corr);
  job.blocks = occ->h->blocks;
  job.skip = (d.effects & RP_EFFECT_SKIP) != 0;
  job.ert = (d.effects & RP_EFFECT_ERT) != 0;
  job.threshold = d.ert_threshold;
  job.end_extra = d.jitter == RP_JITTER_OFF ? 0.5 : 0.0;
  job.seed = seed;
  job.frame = frame;
  job.gw = gw;
  /* S' is a mean over rays scaled to the image: a regular subgrid of
   * PROBE_MAX_RAYS estimates it as well as the whole grid, and keeps the
   * probe's cost flat while the raycast's grows with the pixels. The
   * runtime asks for fewer where the frame is short (rp__probe_ray_
   * budget): the probe's cost is its rays'. */
  if (max_rays < 1 || max_rays > PROBE_MAX_RAYS)
    max_rays = PROBE_MAX_RAYS;
  job.sub = 1;
  while (probe_rays(gw, gh, job.sub) > max_rays)
    job.sub++;
  job.map_w = (gw + job.sub - 1) / job.sub;
  job.span = out->span;
  /* On the calling thread: at most PROBE_MAX_RAYS rays are a few tenths
   * of a millisecond of work, less than starting and joining threads
   * costs while the device's own threads hold the cores
   * (docs/runtime.md, "Overhead"). */
  probe_rows(0, gh, &job);
  for (y = 0; y < gh; y++) {
    out->depth_sum += job.rows[y].span;
    span_no_ert += job.rows[y].span_no_ert;
    out->rays_hit += job.rows[y].hit;
    out->rays_ended += job.rows[y].ended;
    out->lit_span += job.rows[y].lit_span;
    out->lit_ends += job.rows[y].lit_ends;
    if (job.rows[y].max > out->depth_max)
      out->depth_max = job.rows[y].max;
  }
  rp__free(ctx, job.rows);
  out->width = d.width;
  out->height = d.height;
  out->effects = d.effects;
  out->jitter = d.jitter != RP_JITTER_OFF;
  out->rays = probe_rays(gw, gh, job.sub);
  out->map_width = job.map_w;
  out->map_height = (gh + job.sub - 1) / job.sub;
  out->map_stride = RP_ERT_RAY_STRIDE * job.sub;
  out->ert_cut = span_no_ert > 0.0 ? 1.0 - out->depth_sum / span_no_ert
                                   : 0.0;
  out->ert_cut = clamp01(out->ert_cut);
  for (a = 0; a < 3; a++)
    out->view[a] = rg.f[a];
  out->pixels_per_voxel = pixels_per_voxel(&rg);
  out->diagonal = 0.0;
  for (a = 0; a < 3; a++) {
    double e = rg.dims[a] * rg.spacing[a] / rg.min_spacing;
    out->diagonal += e * e;
  }
  out->diagonal = sqrt(out->diagonal);
  out->probe_ms = rp__now_ms() - t0;
  return 0;
}

/* ---- Model --------------------------------------------------------------- */

static void mean_reset(robust_mean *r, double start, double min_spread) {
  r->mean = start;
  r->spread = 0.0;
  r->min_spread = min_spread;
  r->n = 0;
}

/* Adds v and returns it as the mean took it: clamped. */
static double mean_add(robust_mean *r, double v) {
  double dev = v - r->mean, rate, lim;
  r->n++;
  if (r->n == 1) {
    r->mean = v;
    return v;
  }
  lim = MEAN_CLAMP * (r->spread + r->min_spread);
  if (r->n > MEAN_CLAMP_AFTER)
    dev = dev > lim ? lim : dev < -lim ? -lim : dev;
  rate = 1.0 / (double)(r->n < MEAN_WINDOW ? r->n : MEAN_WINDOW);
  v = r->mean + dev;
  r->mean += rate * dev;
  r->spread += rate * (fabs(dev) - r->spread);
  return v;
}

/* The k-th smallest of v[0..n) (0-based), reordering v: Hoare's
 * selection, expected O(n). */
static double select_kth(double *v, int n, int k) {
  int lo = 0, hi = n - 1;
  while (lo < hi) {
    double pivot = v[lo + (hi - lo) / 2], t;
    int i = lo, j = hi;
    while (i <= j) {
      while (v[i] < pivot)
        i++;
      while (v[j] > pivot)
        j--;
      if (i <= j) {
        t = v[i];
        v[i++] = v[j];
        v[j--] = t;
      }
    }
    if (k <= j)
      hi = j;
    else if (k >= i)
      lo = i;
    else
      return v[k];
  }
  return v[k];
}

static double median_of(double *v, uint32_t n) {
  return select_kth(v, (int)n, (int)(n / 2));
}

static void launch_reset(launch_fit *f) { memset(f, 0, sizeof *f); }

/* Adds a frame and refits a (Theil-Sen, see the header) and the noise
 * around the line. Returns 1 when a moved by more than LAUNCH_RELEARN of
 * the median raycast kept: what sigma learned under the old a is then
 * off by as much. */
static int launch_add(launch_fit *f, const double *feat, uint32_t effects,
                      double x, double y) {
  double slopes[LAUNCH_WINDOW * (LAUNCH_WINDOW - 1) / 2];
  /* Zeroed: the static analyzer cannot follow the loops that fill it. */
  double v[LAUNCH_WINDOW] = {0}, b, a, ymin, old = f->a;
  uint32_t i, j, n, nv, np = 0;
  f->x[f->next] = x;
  f->y[f->next] = y;
  memcpy(f->feat[f->next], feat, sizeof f->feat[0]);
  f->effects[f->next] = effects;
  f->next = (f->next + 1) % LAUNCH_WINDOW;
  if (f->n < LAUNCH_WINDOW)
    f->n++;
  n = f->n < LAUNCH_WINDOW ? f->n : LAUNCH_WINDOW; /* said for it too */
  ymin = f->y[0];
  for (i = 1; i < n; i++)
    ymin = fmin(ymin, f->y[i]);
  for (i = 0; i < n; i++)
    for (j = i + 1; j < n; j++) {
      double lo = fmin(f->x[i], f->x[j]), hi = fmax(f->x[i], f->x[j]);
      if (hi > LAUNCH_SPREAD * lo && f->effects[i] == effects &&
          f->effects[j] == effects)
        slopes[np++] = (f->y[j] - f->y[i]) / (f->x[j] - f->x[i]);
    }
  if (np >= LAUNCH_PAIRS && (b = median_of(slopes, np)) > 0.0) {
    /* The line of the newest frame's effects, and its frames only. */
    for (i = nv = 0; i < n; i++)
      if (f->effects[i] == effects)
        v[nv++] = f->y[i] - b * f->x[i];
    a = median_of(v, nv);
    f->a = fmin(fmax(a, 0.0), LAUNCH_SHARE * ymin);
    for (i = nv = 0; i < n; i++)
      if (f->effects[i] == effects)
        v[nv++] = f->y[i] > 0.0
                      ? fabs(f->y[i] - f->a - b * f->x[i]) / f->y[i]
                      : 0.0;
    f->noise = median_of(v, nv);
  } else {
    /* No line (too few pairs, or time not rising with the work): a
     * stays, but never above what the cheapest frame kept allows. A
     * fit made across a change of scene can leave an a larger than a
     * whole raycast of the new one. */
    f->a = fmin(f->a, LAUNCH_SHARE * ymin);
  }
  for (i = 0; i < n; i++)
    v[i] = f->y[i];
  return fabs(f->a - old) > LAUNCH_RELEARN * median_of(v, n);
}

static rp_cost_model_desc model_defaults(const rp_cost_model_desc *in) {
  rp_cost_model_desc d = {0};
  if (in != NULL)
    d = *in;
  if (d.gamma == 0)
    d.gamma = 2.0;
  if (d.nu == 0)
    d.nu = 1e-3;
  if (d.max_dict == 0)
    d.max_dict = 32;
  if (d.forget == 0)
    d.forget = 0.995;
  if (d.clip == 0)
    d.clip = 4.0;
  if (d.sigma0_ns == 0)
    d.sigma0_ns = 5.0;
  if (d.noise_ratio == 0)
    d.noise_ratio = 0.05;
  return d;
}

int rp_cost_model_create(rp_context *ctx, const rp_cost_model_desc *desc,
                         rp_cost_model **out) {
  rp_cost_model *m;
  rp__krls_desc kd = {0};
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_cost_model_create: out is NULL");
  *out = NULL;
  m = rp__calloc(ctx, 1, sizeof(*m));
  if (m == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_cost_model_create: out of memory");
  m->ctx = ctx;
  m->d = model_defaults(desc);
  if (!(m->d.sigma0_ns > 0.0) || !isfinite(m->d.sigma0_ns)) {
    double s0 = m->d.sigma0_ns;
    rp__free(ctx, m);
    return rp__fail(ctx, isfinite(s0) ? RP_EINVAL : RP_ENOTFINITE,
                    "rp_cost_model_create: sigma0_ns = %g: must be > 0",
                    s0);
  }
  /* KRLS checks its own fields and names the bad one. */
  kd.dim = RP_COST_FEATURES;
  kd.gamma = m->d.gamma;
  kd.nu = m->d.nu;
  kd.max_dict = m->d.max_dict;
  kd.forget = m->d.forget;
  kd.clip = m->d.clip;
  /* Negative is "none"; NaN reaches KRLS, which names the field. */
  kd.noise_ratio = m->d.noise_ratio < 0 ? 0 : m->d.noise_ratio;
  kd.signed_y = 1;
  if ((err = rp__krls_create(ctx, &kd, &m->krls)) != 0 ||
      (err = rp__krls_create(ctx, &kd, &m->kappa_krls)) != 0) {
    rp__krls_destroy(m->krls);
    rp__free(ctx, m);
    return err;
  }
  rp_cost_model_reset(m);
  *out = m;
  return 0;
}

void rp_cost_model_destroy(rp_cost_model *m) {
  if (m == NULL)
    return;
  rp__krls_destroy(m->krls);
  rp__krls_destroy(m->kappa_krls);
  rp__free(m->ctx, m);
}

void rp_cost_model_reset(rp_cost_model *m) {
  if (m == NULL)
    return;
  rp__krls_reset(m->krls);
  rp__krls_reset(m->kappa_krls);
  mean_reset(&m->log_kappa, 0.0, 0.02);
  /* Floors: 2 % in sigma; 10 microseconds of fixed cost. */
  mean_reset(&m->log_sigma, log(m->d.sigma0_ns), 0.02);
  mean_reset(&m->c0[0], 0.0, 0.01);
  mean_reset(&m->c0[1], 0.0, 0.01);
  launch_reset(&m->launch);
  memset(&m->sigma_bias, 0, sizeof m->sigma_bias);
  memset(&m->frame_bias, 0, sizeof m->frame_bias);
}

static double log2_unit(double v, double lo_log2, double hi_log2) {
  return clamp01((log2(v) - lo_log2) / (hi_log2 - lo_log2));
}

static void features(const rp_frame_probe *p, float step, float scale,
                     double *x) {
  int a;
  for (a = 0; a < 3; a++)
    x[a] = clamp01(0.5 * (p->view[a] + 1.0));
  x[3] = log2_unit(p->pixels_per_voxel * scale, -4.0, 4.0);
  x[4] = log2_unit(step, -3.0, 4.0);
  x[5] = clamp01(p->ert_cut);
  x[6] = p->diagonal > 0.0 ? clamp01(p->depth_max / p->diagonal) : 0.0;
  x[7] = p->diagonal > 0.0 && p->rays_hit > 0
             ? clamp01(p->depth_sum / p->rays_hit / p->diagonal)
             : 0.0;
}

/* The probe rays' samples at `step`: sum_i (L_i / step + e_i), e_i = 1
 * for rays ERT ends and 1/2 for the others, 0 for those with jitter
 * (header). */
static double probe_samples(const rp_frame_probe *p, float step) {
  double rest = p->jitter ? 0.0 : 0.5;
  /* Pre-integrated with skipping, a ray whose last occupied sample is
   * not its lattice's last takes one sample more (the segment leaving
   * it, reference.c). Not counted: on a volume whose occupied blocks
   * reach its faces most rays end in them (the phantom: no sample more
   * on 96^2 rays; with ERT 0.08 %), and the probe does not tell which. */
  return p->depth_sum / (double)step +
         rest * (double)(p->rays_hit - p->rays_ended) +
         (double)p->rays_ended;
}

/* Rays the raycast casts at image scale `scale`. */
static double rays_at(const rp_frame_probe *p, float scale) {
  rp_render_desc d = {0};
  uint32_t w, h;
  d.width = p->width;
  d.height = p->height;
  d.image_scale = scale;
  rp_scaled_size(&d, &w, &h);
  return (double)w * (double)h;
}

/* S' at `step` for a raycast of `rays` rays (rays_at). */
static double estimate_samples(const rp_frame_probe *p, float step,
                               double rays) {
  if (p->rays == 0)
    return 0.0;
  return rays / (double)p->rays * probe_samples(p, step);
}

/* k at `step`: a fetch per sample, and per sample that shows (the
 * probe's share of them) six more with shading and one more with AO:
 * transparent samples take neither. A frame with no sample gets the
 * share 1: its k prices nothing, and the most is the safe side. With
 * pre-integration each ray that samples fetches the value before its
 * first sample too: rays_hit more over the probe's samples. (Its table
 * reads replace the LUT's, which no backend counts as fetches.) */
static double fetches_per_sample(const rp_frame_probe *p, float step) {
  double k = 1.0, extra = ((p->effects & RP_EFFECT_SHADING) ? 6.0 : 0.0) +
                          ((p->effects & RP_EFFECT_AO) ? 1.0 : 0.0);
  double all = probe_samples(p, step);
  if (extra > 0.0) {
    double lit = p->lit_span / (double)step + p->lit_ends;
    k += extra * (all > 0.0 ? clamp01(lit / all) : 1.0);
  }
  if ((p->effects & RP_EFFECT_PREINT) && all > 0.0)
    k += (double)p->rays_hit / all;
  return k;
}

static int check_point(rp_context *ctx, const char *fn,
                       const rp_frame_probe *p, float step, float scale) {
  if (p == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: probe is NULL", fn);
  if (!isfinite(step) || !isfinite(scale))
    return rp__fail(ctx, RP_ENOTFINITE, "%s: step %g, scale %g", fn,
                    (double)step, (double)scale);
  if (!(step > 0.0f) || !(scale > 0.0f && scale <= 1.0f))
    return rp__fail(ctx, RP_EINVAL, "%s: step %g must be > 0 and scale %g "
                    "in (0, 1]", fn, (double)step, (double)scale);
  if (!isfinite(p->depth_sum) || !isfinite(p->depth_max) ||
      p->depth_sum < 0.0 || p->width == 0 || p->height == 0 ||
      !(p->lit_span >= 0.0 && p->lit_span <= p->depth_sum * (1.0 + 1e-9)) ||
      !(p->lit_ends >= 0.0 && p->lit_ends <= (double)p->rays_hit) ||
      p->rays_hit > p->rays || p->rays_ended > p->rays_hit)
    return rp__fail(ctx, RP_EINVAL, "%s: the probe was not filled in by "
                    "rp_frame_probe_compute", fn);
  return 0;
}

/* A learned logarithm at features x: the running mean plus the KRLS
 * residual, as sigma and kappa are both kept. The residual model is
 * trusted within a factor of e^3 = 20 of the mean: a wild extrapolation
 * must not decide a frame on its own. */
static double log_at(const rp__krls *k, const robust_mean *mean,
                     const double *x) {
  double r = mean->n > 0 ? rp__krls_predict(k, x) : 0.0;
  if (!isfinite(r))
    r = 0.0;
  r = r < -3.0 ? -3.0 : r > 3.0 ? 3.0 : r;
  return mean->mean + r;
}

/* ln sigma' at features x, before the short-term correction. */
static double log_sigma_at(const rp_cost_model *m, const double *x) {
  return log_at(m->krls, &m->log_sigma, x);
}

/* Files one frame's log ratio and sets the correction: when the last
 * RECENT_FRAMES all err the same way, the smallest of them (the bias
 * they agree on), within +-bound; else 0. One stalled frame then moves
 * nothing, a machine slowed for a while is followed from its third
 * frame, and a model that errs one way for one view and the other way
 * for another (alternating views) is left to KRLS. */
static void recent_add(recent_bias *r, double log_ratio, double bound,
                       const double *x, uint32_t effects) {
  double lo = INFINITY, hi = -INFINITY;
  uint32_t i;
  memcpy(r->x, x, sizeof r->x);
  r->effects = effects;
  r->v[r->next] = log_ratio;
  r->next = (r->next + 1) % RECENT_FRAMES;
  if (r->n < RECENT_FRAMES)
    r->n++;
  r->log_corr = 0.0;
  if (r->n < RECENT_FRAMES)
    return;
  for (i = 0; i < RECENT_FRAMES; i++) {
    lo = fmin(lo, r->v[i]);
    hi = fmax(hi, r->v[i]);
  }
  if (lo > 0.0)
    r->log_corr = fmin(lo, bound);
  else if (hi < 0.0)
    r->log_corr = fmax(hi, -bound);
}

/* Whether features x with `effects` show the scene of the frame that
 * last filed into r: the same effects, and the features the density
 * does not set (all but 3 and 4) within SCENE_NEAR of its. */
static int same_scene(const recent_bias *r, const double *x,
                      uint32_t effects) {
  static const int scene[] = {0, 1, 2, 5, 6, 7};
  size_t k;
  if (effects != r->effects)
    return 0;
  for (k = 0; k < sizeof scene / sizeof scene[0]; k++)
    if (fabs(x[scene[k]] - r->x[scene[k]]) > SCENE_NEAR)
      return 0;
  return 1;
}

/* A correction q or Q for a frame: whole on the scene it was learned on;
 * on another (a TF switch, effects toggled) only if it raises the
 * prediction. The recent frames' errors may be the machine, which
 * carries over, or the model's error on their scene, which does not:
 * carried over, a correction that lowers the cost risks an overshoot on
 * exactly the switch frame (docs/pacing.md, "The cost model", the bullet
 * on q). A correction that raises it costs at most an image coarser than
 * the budget allowed. */
static double carried(const recent_bias *r, const double *x,
                      uint32_t effects) {
  return r->log_corr > 0.0 || same_scene(r, x, effects) ? r->log_corr
                                                        : 0.0;
}

int rp_cost_predict(const rp_cost_model *m, const rp_frame_probe *p,
                    float step, float scale, rp_cost_estimate *out) {
  double rays;
  int err, up;
  if (m == NULL)
    return RP_EINVAL;
  if ((err = check_point(m->ctx, "rp_cost_predict", p, step, scale)) != 0)
    return err;
  if (out == NULL)
    return rp__fail(m->ctx, RP_EINVAL, "rp_cost_predict: out is NULL");
  features(p, step, scale, out->features);
  rays = rays_at(p, scale);
  out->samples = estimate_samples(p, step, rays);
  out->fetches = fetches_per_sample(p, step);
  out->sigma_ns =
      exp(log_sigma_at(m, out->features) +
          carried(&m->sigma_bias, out->features, p->effects));
  out->sample_ratio =
      exp(log_at(m->kappa_krls, &m->log_kappa, out->features));
  /* Until frames of its own kind arrive, the other kind's is the best
   * guess. */
  up = scale < 1.0f;
  out->c0_ms = m->c0[up].n > 0 ? m->c0[up].mean : m->c0[!up].mean;
  out->launch_ms = m->launch.a * rays;
  out->frame_factor =
      exp(carried(&m->frame_bias, out->features, p->effects));
  out->novelty = m->log_sigma.n > 0
                     ? fmax(rp__krls_novelty(m->krls, out->features),
                            rp__krls_novelty(m->kappa_krls, out->features))
                     : 1.0;
  out->ms = (out->launch_ms +
             out->sigma_ns * 1e-6 * out->fetches * out->sample_ratio *
                 out->samples +
             out->c0_ms) *
            out->frame_factor;
  return 0;
}

/* Learns one frame's cost per fetch: its raycast less the launch cost,
 * over its fetches. A frame whose fetches are under SIGMA_SHARE of its
 * raycast is left out: its time is mostly a, and its sigma is a small
 * difference of two noisy times (docs/pacing.md, "The cost model", the
 * bullet on a). Such a frame's time does not depend on sigma much, which
 * is why it need not teach it. KRLS learns the clamped value too: a
 * stalled frame must not reach the model through the back door of a huge
 * residual. */
static int sigma_teaches(const rp_cost_model *m, double raycast_ms) {
  double per_fetch_ms = raycast_ms - m->launch.a; /* both per ray */
  return per_fetch_ms >= SIGMA_SHARE * raycast_ms &&
         per_fetch_ms >= SIGMA_CLEAR * m->launch.noise * raycast_ms;
}

/* fetches and raycast_ms per ray, as the launch fit keeps them. */
static int sigma_learn(rp_cost_model *m, const double *x, uint32_t effects,
                       double fetches, double raycast_ms, int relearning) {
  double ls;
  if (!sigma_teaches(m, raycast_ms))
    return 0;
  ls = log((raycast_ms - m->launch.a) * 1e6 / fetches);
  if (!relearning)
    recent_add(&m->sigma_bias, ls - log_sigma_at(m, x), RECENT_BOUND, x,
               effects);
  ls = mean_add(&m->log_sigma, ls);
  return rp__krls_update(m->krls, x, ls - m->log_sigma.mean);
}

/* sigma learned again from the frames the launch fit keeps, oldest
 * first, under the new a: cheaper than letting KRLS forget a
 * dictionary's worth of residuals that were all off by the same amount
 * (tests/test_predict.c: sigma within 0.1 % after 48 frames, where
 * waiting for the forgetting left it 1.3 % off). */
static int sigma_relearn(rp_cost_model *m) {
  const launch_fit *f = &m->launch;
  uint32_t i, first = f->n < LAUNCH_WINDOW ? 0 : f->next;
  int err;
  rp__krls_reset(m->krls);
  mean_reset(&m->log_sigma, log(m->d.sigma0_ns), 0.02);
  for (i = 0; i < f->n; i++) {
    uint32_t k = (first + i) % LAUNCH_WINDOW;
    if ((err = sigma_learn(m, f->feat[k], f->effects[k], f->x[k], f->y[k],
                           1)) != 0)
      return err;
  }
  return 0;
}

/* Files a frame that does not teach sigma into Q: its time against t'
 * without Q (both positive, or nothing is filed). */
static void frame_feed(rp_cost_model *m, const double *x, uint32_t effects,
                       double frame_ms, double base_ms) {
  if (frame_ms > 0.0 && base_ms > 0.0 && isfinite(base_ms))
    recent_add(&m->frame_bias, log(frame_ms / base_ms), FRAME_BOUND, x,
               effects);
}

int rp_cost_train(rp_cost_model *m, const rp_frame_probe *p, float step,
                  float scale, uint64_t samples, double raycast_ms,
                  double frame_ms) {
  static const char fn[] = "rp_cost_train";
  const double *x;
  double ls, lk, est, fetches, base_ms, rays;
  rp_cost_estimate e;
  int err;
  if (m == NULL)
    return RP_EINVAL;
  if ((err = check_point(m->ctx, fn, p, step, scale)) != 0)
    return err;
  if (!isfinite(raycast_ms) || !isfinite(frame_ms))
    return rp__fail(m->ctx, RP_ENOTFINITE, "%s: raycast_ms %g, frame_ms "
                    "%g", fn, raycast_ms, frame_ms);
  if (raycast_ms < 0.0 || frame_ms < 0.0)
    return rp__fail(m->ctx, RP_ERANGE, "%s: negative timing (raycast_ms "
                    "%g, frame_ms %g)", fn, raycast_ms, frame_ms);
  /* A raycast the device could not time (0) costs the whole frame. */
  if (raycast_ms == 0.0 || raycast_ms > frame_ms)
    raycast_ms = frame_ms;
  /* t' without Q as the controller saw it, before this frame is learned:
   * what Q's ratio is taken against. Its features, S' and k are this
   * frame's too. */
  if (rp_cost_predict(m, p, step, scale, &e) != 0)
    return RP_EINVAL; /* checked above; said for readers */
  x = e.features;
  est = e.samples;
  fetches = e.fetches * (double)samples;
  /* Everything is checked before anything is learned: a time so large
   * that its cost per fetch overflows is refused whole. What sigma_learn
   * takes the log of lies between SIGMA_SHARE of this and this. */
  ls = samples > 0 && raycast_ms > 0.0
           ? log(SIGMA_SHARE * raycast_ms * 1e6 / fetches)
           : 0.0;
  lk = samples > 0 && est > 0.0 ? log((double)samples / est) : 0.0;
  if (!isfinite(ls) || !isfinite(lk))
    return rp__fail(m->ctx, RP_ERANGE, "%s: raycast_ms %g for %llu "
                    "samples is out of range", fn, raycast_ms,
                    (unsigned long long)samples);
  rays = rays_at(p, scale);
  base_ms = e.ms / e.frame_factor;
  (void)mean_add(&m->c0[scale < 1.0f], frame_ms - raycast_ms);
  /* A frame with no sample (all empty) or no measurable time says
   * nothing about the cost of a fetch. */
  if (samples == 0 || raycast_ms <= 0.0) {
    frame_feed(m, x, p->effects, frame_ms, base_ms);
    return 0;
  }
  err = launch_add(&m->launch, x, p->effects, fetches / rays,
                   raycast_ms / rays)
            ? sigma_relearn(m)
            : sigma_learn(m, x, p->effects, fetches / rays,
                          raycast_ms / rays, 0);
  if (err != 0)
    return err;
  /* Judged by the launch fit sigma_learn just used. */
  if (sigma_teaches(m, raycast_ms / rays))
    memset(&m->frame_bias, 0, sizeof m->frame_bias);
  else
    frame_feed(m, x, p->effects, frame_ms, base_ms);
  if (est <= 0.0)
    return 0;
  lk = mean_add(&m->log_kappa, lk);
  return rp__krls_update(m->kappa_krls, x, lk - m->log_kappa.mean);
}
