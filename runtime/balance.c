/* Load balancing across devices (DESIGN section 7, seed 000 section 6.2,
 * seed 001 section 4.3): shares from each device's cost per unit, their
 * damping over frames, and a kd-tree split of the tile grid.
 *
 * The split reads rectangle costs from a summed-area table (SAT): four
 * lookups each, so a cut is a binary search along one axis. The SAT holds
 * integers, not doubles: in double a rectangle's cost is a difference of
 * sums over the whole grid, which cancels small rectangles away (tiles of
 * 1 next to one of 1e12) and can make a prefix along a cut decrease, and
 * the binary search needs prefixes that never do. Integers subtract
 * exactly. Costs are scaled so that the largest tile is K = 2^(62 -
 * ceil(log2 T)) for T tiles, so the total is at most 2^62; rounding moves
 * a tile by at most half a unit, 2^-35 of the largest tile at
 * RP_BALANCE_MAX_TILES, far below what any cut can resolve. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "internal.h"
#include "raypace_balance.h"

#define BAL_DEVICES 8
#define BAL_TILES (512u * 512u)
#define BAL_RATE 0.5
/* Shares are k / 2^53 with integer k (quantise()). */
#define BAL_ONE 9007199254740992.0 /* 2^53 */
/* Group sums closer than this fraction of their total count as a tie. */
#define BAL_TIE 1e-12

/* A pending kd-tree node: a rectangle of tiles and its devices [d0, d1). */
typedef struct node {
  rp_region g;
  uint32_t d0, d1;
} node;

struct rp_balancer {
  rp_context *ctx;
  rp_balancer_desc d; /* defaults filled in */
  uint64_t *sat;      /* (tiles_x + 1) (tiles_y + 1) <= 2 max_tiles + 2 */
  node *stack;        /* pending nodes, max_devices (see split_tree) */
};

/* ---- Shares and damping ------------------------------------------------ */

/* Makes w (n values >= 0 with a positive finite sum) into shares that
 * sum to exactly 1: k_i = round(2^53 w_i / sum), the largest k absorbing
 * the rounding so that the k sum to 2^53, then w_i = k_i / 2^53. Every
 * partial sum is j / 2^53 with j <= 2^53, which a double holds exactly,
 * so they add to 1.0 in any order. The fix-up (under 2n) never makes the
 * largest k (at least 2^53 / n - 1) negative. */
static void quantise(double *w, uint32_t n) {
  double sum = 0;
  uint64_t total = 0;
  uint32_t i, big = 0;
  for (i = 0; i < n; i++)
    sum += w[i];
  for (i = 0; i < n; i++) {
    /* w_i / sum <= 1 (a rounded sum of non-negative terms is never less
     * than one of them), so k <= 2^53. */
    double k = floor(w[i] / sum * BAL_ONE + 0.5);
    w[i] = k;
    total += (uint64_t)k;
    if (k > w[big])
      big = i;
  }
  w[big] += (double)((int64_t)BAL_ONE - (int64_t)total);
  for (i = 0; i < n; i++)
    w[i] *= 1.0 / BAL_ONE; /* a power of two: exact */
}

/* The checks every entry point starts with; `null`: a pointer was NULL. */
static int check_n(rp_context *ctx, const char *fn, int null, uint32_t n,
                   uint32_t max) {
  if (null || n == 0) {
    /* Returned here, not through rp__fail, so that the analyzer sees
     * callers never pass on with a NULL. */
    rp__fail(ctx, RP_EINVAL, "%s: %s", fn, null ? "NULL argument" : "n is 0");
    return RP_EINVAL;
  }
  if (n > max)
    return rp__fail(ctx, RP_ERANGE, "%s: n = %u is over the limit %u", fn,
                    n, max);
  return 0;
}

/* Non-negative finite values with a positive finite sum. */
static int check_shares(rp_context *ctx, const char *fn, const char *what,
                        const double *w, uint32_t n) {
  double sum = 0;
  uint32_t i;
  for (i = 0; i < n; i++) {
    if (!isfinite(w[i]) || w[i] < 0)
      return rp__fail(ctx, isfinite(w[i]) ? RP_ERANGE : RP_ENOTFINITE,
                      "%s: %s[%u] = %g", fn, what, i, w[i]);
    sum += w[i];
  }
  if (!(sum > 0) || !isfinite(sum))
    return rp__fail(ctx, RP_EINVAL, "%s: %s sum to %g", fn, what, sum);
  return 0;
}

static int unknown(double sigma) { return isnan(sigma) || sigma == 0; }

int rp_balance_shares(const double *sigma, uint32_t n, double *w) {
  double smin = INFINITY, rsum = 0, rmean;
  uint32_t i, known = 0;
  int err = check_n(NULL, "balance_shares", sigma == NULL || w == NULL, n,
                    RP_BALANCE_MAX_DEVICES);
  if (err)
    return err;
  for (i = 0; i < n; i++) {
    double s = sigma[i];
    if (!unknown(s) && (isinf(s) || s < 0))
      return isinf(s) ? RP_ENOTFINITE : RP_ERANGE;
    if (!unknown(s))
      smin = fmin(smin, s);
  }
  /* Speeds relative to the fastest device, smin / sigma in (0, 1]: the
   * ratios of 1 / sigma, without overflow for a sigma of 1e-310. */
  for (i = 0; i < n; i++)
    if (!unknown(sigma[i])) {
      rsum += smin / sigma[i];
      known++;
    }
  /* An unknown device counts as the known ones' average; with none
   * known, every device is alike. One read and one write per element:
   * w may be sigma. */
  rmean = known > 0 ? rsum / known : 1.0;
  for (i = 0; i < n; i++)
    w[i] = unknown(sigma[i]) ? rmean : smin / sigma[i];
  quantise(w, n);
  return 0;
}

int rp_balance_shares_fixed(const double *var, const double *fixed,
                            uint32_t n, double *w) {
  double v[RP_BALANCE_MAX_DEVICES], rmean = 0, t = 0;
  uint32_t i, known = 0, in;
  int err = check_n(NULL, "balance_shares_fixed",
                    var == NULL || fixed == NULL || w == NULL, n,
                    RP_BALANCE_MAX_DEVICES);
  if (err)
    return err;
  for (i = 0; i < n; i++) {
    if ((!unknown(var[i]) && isinf(var[i])) || !isfinite(fixed[i]))
      return RP_ENOTFINITE;
    if ((!unknown(var[i]) && var[i] < 0) || fixed[i] < 0)
      return RP_ERANGE;
  }
  /* Unknown devices take the known ones' mean speed (1 / var), as in
   * rp_balance_shares. */
  for (i = 0; i < n; i++)
    if (!unknown(var[i])) {
      rmean += 1.0 / var[i];
      known++;
    }
  rmean = known > 0 ? rmean / known : 1.0;
  for (i = 0; i < n; i++)
    v[i] = unknown(var[i]) ? 1.0 / rmean : var[i];
  /* Finishing together at T: f_i + w_i v_i = T with sum w_i = 1 gives
   * T = (1 + sum f_i / v_i) / sum 1 / v_i over the devices in the race.
   * A device whose fixed cost alone is past T is left out (w 0) and T
   * recomputed; each round removes one, so at most n rounds, and the
   * fastest-finishing device (least f_i + v_i) never leaves. */
  for (;;) {
    double a = 0, b = 0;
    for (i = 0; i < n; i++)
      if (!isnan(v[i])) {
        a += fixed[i] / v[i];
        b += 1.0 / v[i];
      }
    t = (1.0 + a) / b;
    in = 0;
    for (i = 0; i < n; i++)
      if (!isnan(v[i]) && fixed[i] >= t) {
        v[i] = NAN;
        in++;
      }
    if (in == 0)
      break;
  }
  for (i = 0; i < n; i++)
    w[i] = isnan(v[i]) ? 0.0 : (t - fixed[i]) / v[i];
  quantise(w, n);
  return 0;
}

/* prod_{j != i} sigma_j, which may overflow (the caller checks). */
static double eq3_product(const double *sigma, uint32_t n, uint32_t i) {
  double p = 1;
  uint32_t j;
  for (j = 0; j < n; j++)
    if (j != i)
      p *= sigma[j];
  return p;
}

int rp_balance_shares_eq3(const double *sigma, uint32_t n, double *w) {
  double sum = 0;
  uint32_t i;
  int err = check_n(NULL, "balance_shares_eq3", sigma == NULL || w == NULL,
                    n, RP_BALANCE_MAX_DEVICES);
  if (err)
    return err;
  for (i = 0; i < n; i++) {
    if (!isfinite(sigma[i]) || !(sigma[i] > 0))
      return isfinite(sigma[i]) ? RP_ERANGE : RP_ENOTFINITE;
    sum += sigma[i];
  }
  for (i = 0; i < n; i++) /* a pass of its own: a failure writes nothing */
    if (!isfinite(eq3_product(sigma, n, i) / sum))
      return RP_ERANGE; /* also catches a sum that overflowed */
  for (i = 0; i < n; i++)
    w[i] = eq3_product(sigma, n, i) / sum;
  return 0;
}

int rp_balance_damp(rp_damping mode, double rate, const double *prev,
                    const double *target, uint32_t n, double *out) {
  double sp = n, st = 0;
  uint32_t i;
  int err = check_n(NULL, "balance_damp", target == NULL || out == NULL, n,
                    RP_BALANCE_MAX_DEVICES);
  if (err)
    return err;
  if (rate == 0)
    rate = BAL_RATE; /* the one place that knows what 0 means */
  if (!(rate > 0 && rate <= 1))
    return isfinite(rate) ? RP_ERANGE : RP_ENOTFINITE;
  if (mode != RP_DAMP_SMOOTH && mode != RP_DAMP_EVEN)
    return RP_EINVAL;
  if ((err = check_shares(NULL, "balance_damp", "target", target, n)))
    return err;
  if (mode == RP_DAMP_SMOOTH && prev != NULL) {
    if ((err = check_shares(NULL, "balance_damp", "prev", prev, n)))
      return err;
    for (sp = 0, i = 0; i < n; i++)
      sp += prev[i];
  }
  for (i = 0; i < n; i++)
    st += target[i];
  /* Elementwise, with the sums taken first: out may alias an input. */
  for (i = 0; i < n; i++) {
    double t = target[i] / st;
    if (mode == RP_DAMP_EVEN)
      out[i] = (1 - rate) / n + rate * t;
    else
      out[i] = (1 - rate) * (prev != NULL ? prev[i] : 1.0) / sp + rate * t;
  }
  quantise(out, n);
  return 0;
}

/* ---- The balancer: the split's workspace -------------------------------- */

int rp_balancer_create(rp_context *ctx, const rp_balancer_desc *desc,
                       rp_balancer **out) {
  const char *fn = "balancer_create";
  rp_balancer_desc d = desc != NULL ? *desc : (rp_balancer_desc){0};
  rp_balancer *b;
  size_t nsat, size;
  if (ctx == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: NULL argument", fn);
  /* The defaults, here only (no other code sees a zero field). */
  if (d.max_devices == 0)
    d.max_devices = BAL_DEVICES;
  if (d.max_tiles == 0)
    d.max_tiles = BAL_TILES;
  if (d.max_devices > RP_BALANCE_MAX_DEVICES ||
      d.max_tiles > RP_BALANCE_MAX_TILES)
    return rp__fail(ctx, RP_ERANGE, "%s: max_devices = %u (at most %u) or "
                    "max_tiles = %u (at most %u)", fn, d.max_devices,
                    RP_BALANCE_MAX_DEVICES, d.max_tiles, RP_BALANCE_MAX_TILES);
  /* (tx + 1)(ty + 1) = T + tx + ty + 1 <= 2 T + 2 for tx ty = T, since
   * tx + ty <= tx ty + 1 when both are >= 1: enough for every shape of
   * grid with T tiles. One block holds everything, most aligned first. */
  nsat = 2 * (size_t)d.max_tiles + 2;
  if (nsat > SIZE_MAX / 16) /* only where size_t has 32 bits */
    return rp__fail(ctx, RP_ENOMEM, "%s: max_tiles too large", fn);
  size = sizeof *b + nsat * sizeof(uint64_t) +
         (size_t)d.max_devices * sizeof(node);
  if ((b = rp__malloc(ctx, size)) == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory (%zu bytes)", fn,
                    size);
  b->ctx = ctx;
  b->d = d;
  b->sat = (uint64_t *)(b + 1);
  b->stack = (node *)(b->sat + nsat);
  *out = b;
  return 0;
}

void rp_balancer_destroy(rp_balancer *b) {
  if (b != NULL)
    rp__free(b->ctx, b);
}

/* ---- Tile costs and the summed-area table ------------------------------ */

static double cost_at(const double *cd, const float *cf, size_t i) {
  return cd != NULL ? cd[i] : (double)cf[i];
}

/* Checks every cost and builds the SAT: sat[y (tx + 1) + x] is the cost
 * of tiles [0, x) x [0, y), with row 0 and column 0 zero. */
static int build_sat(rp_balancer *b, const char *fn, const double *cd,
                     const float *cf, uint32_t tx, uint32_t ty) {
  size_t t = (size_t)tx * ty, i, stride = (size_t)tx + 1;
  double cmax = 0, scale;
  uint32_t x, y, lg = 0;
  for (i = 0; i < t; i++) {
    double c = cost_at(cd, cf, i);
    if (!isfinite(c) || c < 0)
      return rp__fail(b->ctx, isfinite(c) ? RP_ERANGE : RP_ENOTFINITE,
                      "%s: cost of tile (%zu, %zu) = %g", fn, i % tx,
                      i / tx, c);
    cmax = fmax(cmax, c);
  }
  while (((size_t)1 << lg) < t)
    lg++;
  /* The largest tile becomes K = 2^(62 - lg), so the T <= 2^lg tiles sum
   * to at most 2^62 (file comment). K a power of two makes c / cmax * K
   * exact, so no tile rounds above K. */
  scale = ldexp(1.0, 62 - (int)lg);
  memset(b->sat, 0, stride * sizeof *b->sat);
  for (y = 0; y < ty; y++) {
    uint64_t run = 0;
    uint64_t *row = b->sat + (y + 1) * stride;
    const uint64_t *above = row - stride;
    row[0] = 0;
    for (x = 0; x < tx; x++) {
      double c = cost_at(cd, cf, (size_t)y * tx + x);
      /* No cost anywhere: count tiles instead, so the devices still get
       * areas in proportion to their shares. */
      run += cmax > 0 ? (uint64_t)floor(c / cmax * scale + 0.5) : 1;
      row[x + 1] = above[x + 1] + run;
    }
  }
  return 0;
}

/* Cost of tiles [x0, x1) x [y0, y1). Unsigned arithmetic wraps, but the
 * exact result is in range, so it comes out right whatever the order. */
static uint64_t rect_cost(const rp_balancer *b, uint32_t stride, uint32_t x0,
                          uint32_t y0, uint32_t x1, uint32_t y1) {
  const uint64_t *s = b->sat;
  return s[(size_t)y1 * stride + x1] - s[(size_t)y0 * stride + x1] -
         s[(size_t)y1 * stride + x0] + s[(size_t)y0 * stride + x0];
}

/* One cut: along `axis` (0: x, 1: y) of rectangle r, P(p) is the cost of
 * the first p of its L slices; P never decreases, P(0) = 0, P(L) = C. */
typedef struct cut {
  const rp_balancer *b;
  const rp_region *r;
  uint32_t stride;
  int axis;
  uint32_t len;
  uint64_t total;
} cut;

static uint64_t prefix(const cut *c, uint32_t p) {
  const rp_region *r = c->r;
  if (c->axis == 0)
    return rect_cost(c->b, c->stride, r->x0, r->y0, r->x0 + p, r->y1);
  return rect_cost(c->b, c->stride, r->x0, r->y0, r->x1, r->y0 + p);
}

/* The smallest p in [0, L] with P(p) >= v, for v <= C: a binary search
 * that keeps P(hi) >= v, O(log L) SAT lookups. */
static uint32_t lower_bound(const cut *c, uint64_t v) {
  uint32_t lo = 0, hi = c->len;
  while (lo < hi) {
    uint32_t mid = lo + (hi - lo) / 2;
    if (prefix(c, mid) >= v)
      hi = mid;
    else
      lo = mid + 1;
  }
  return lo;
}

/* The p with P(p) = v (a value P takes) form one run [a, z], since P
 * never decreases; the one in it nearest the count position pc. */
static uint32_t in_run(const cut *c, uint64_t v, double pc) {
  uint32_t a = lower_bound(c, v);
  uint32_t z = v >= c->total ? c->len : lower_bound(c, v + 1) - 1;
  double p = floor(pc + 0.5);
  return p <= a ? a : p >= z ? z : (uint32_t)p;
}

/* Where to cut so that the left part costs frac C: the slice boundary
 * whose P is nearest the target t (the first P >= t or the one before
 * it; an error of at most half the slice that t falls in). Zero-cost
 * slices make a run of boundaries with the same P; within it, the one
 * nearest frac L, so that tiles with no predicted cost are still shared
 * by count and a group with a zero share gets nothing (frac 0 or 1 puts
 * the count position at an end of the run). */
static uint32_t choose_cut(const cut *c, double frac) {
  double pc = frac * c->len;
  uint64_t t = (uint64_t)floor((double)c->total * frac + 0.5);
  uint32_t hi, p_hi, p_lo;
  uint64_t v_hi, v_lo;
  if (t > c->total)
    t = c->total; /* rounding of the product */
  hi = lower_bound(c, t);
  v_hi = prefix(c, hi);
  p_hi = in_run(c, v_hi, pc);
  if (hi == 0)
    return p_hi;
  v_lo = prefix(c, hi - 1);
  if (t - v_lo != v_hi - t)
    return t - v_lo < v_hi - t ? in_run(c, v_lo, pc) : p_hi;
  /* Equally far in cost: the count position decides, then the larger. */
  p_lo = in_run(c, v_lo, pc);
  return fabs(p_lo - pc) < fabs(p_hi - pc) ? p_lo : p_hi;
}

/* The m in (d0, d1) splitting the devices into [d0, m) and [m, d1) with
 * the closest share sums (ties: nearest the middle, then the larger m).
 * *frac gets the left group's fraction of the two. O(d1 - d0). */
static uint32_t split_devices(const double *w, uint32_t d0, uint32_t d1,
                              double *frac) {
  double total = 0, left = 0, best = INFINITY, right;
  uint32_t i, m, bm = d0 + 1;
  for (i = d0; i < d1; i++)
    total += w[i];
  for (m = d0 + 1; m < d1; m++) {
    double diff;
    left += w[m - 1];
    diff = fabs(total - 2 * left);
    /* Better, or a tie nearer the middle (|2m - d0 - d1| is twice the
     * distance) or as near and larger. */
    if (diff < best - BAL_TIE * total ||
        (diff <= best + BAL_TIE * total &&
         llabs(2 * (int64_t)m - d0 - d1) <= llabs(2 * (int64_t)bm - d0 - d1))) {
      best = fmin(best, diff);
      bm = m;
    }
  }
  /* Each side summed on its own: no cancellation in total - left. */
  for (left = 0, i = d0; i < bm; i++)
    left += w[i];
  for (right = 0, i = bm; i < d1; i++)
    right += w[i];
  /* A group without a share always gets an empty rectangle and never
   * gets here; with all sums 0, every m ties and the middle wins. */
  *frac = left + right > 0 ? left / (left + right) : 0.5;
  return bm;
}

/* The kd-tree, without recursion: a stack of pending nodes. The pending
 * nodes' device ranges are disjoint and non-empty, so there are never
 * more than n of them. */
static void split_tree(rp_balancer *b, uint32_t tx, uint32_t ty,
                       const double *w, uint32_t n, rp_region *out) {
  node *st = b->stack;
  uint32_t sp = 0, d;
  node root = {{0, 0, tx, ty}, 0, n};
  st[sp++] = root;
  while (sp > 0) {
    node r = st[--sp], left, right;
    const rp_region *g = &r.g;
    uint32_t wx = g->x1 - g->x0, wy = g->y1 - g->y0, m, p;
    double frac;
    cut c;
    if (r.d1 - r.d0 == 1 || wx == 0 || wy == 0) {
      /* A leaf, or an empty rectangle that every device of the group
       * gets as its (empty) region. */
      for (d = r.d0; d < r.d1; d++)
        out[d] = *g;
      continue;
    }
    m = split_devices(w, r.d0, r.d1, &frac);
    c.b = b;
    c.r = g;
    c.stride = tx + 1;
    c.axis = wx >= wy ? 0 : 1; /* across the longer side; a tie: x */
    c.len = c.axis == 0 ? wx : wy;
    c.total = rect_cost(b, c.stride, g->x0, g->y0, g->x1, g->y1);
    p = choose_cut(&c, frac);
    left = right = r;
    left.d1 = right.d0 = m;
    if (c.axis == 0)
      left.g.x1 = right.g.x0 = g->x0 + p;
    else
      left.g.y1 = right.g.y0 = g->y0 + p;
    st[sp++] = right;
    st[sp++] = left;
  }
}

static int split_impl(rp_balancer *b, const char *fn, const double *cd,
                      const float *cf, uint32_t tx, uint32_t ty,
                      const double *shares, uint32_t n, rp_region *out) {
  int err;
  if (b == NULL)
    return RP_EINVAL;
  if ((err = check_n(b->ctx, fn,
                     (cd == NULL && cf == NULL) || !shares || !out, n,
                     b->d.max_devices)))
    return err;
  if (tx == 0 || ty == 0)
    return rp__fail(b->ctx, RP_EINVAL, "%s: the grid is %u x %u tiles", fn,
                    tx, ty);
  if ((uint64_t)tx * ty > b->d.max_tiles)
    return rp__fail(b->ctx, RP_ERANGE,
                    "%s: %u x %u tiles is over max_tiles = %u", fn, tx, ty,
                    b->d.max_tiles);
  if ((err = check_shares(b->ctx, fn, "shares", shares, n)) ||
      (err = build_sat(b, fn, cd, cf, tx, ty)))
    return err;
  split_tree(b, tx, ty, shares, n, out);
  return 0;
}

int rp_balancer_split(rp_balancer *b, const double *cost, uint32_t tiles_x,
                      uint32_t tiles_y, const double *shares, uint32_t n,
                      rp_region *tiles) {
  return split_impl(b, "balancer_split", cost, NULL, tiles_x, tiles_y,
                    shares, n, tiles);
}

int rp_balancer_split_f(rp_balancer *b, const float *cost, uint32_t tiles_x,
                        uint32_t tiles_y, const double *shares, uint32_t n,
                        rp_region *tiles) {
  return split_impl(b, "balancer_split_f", NULL, cost, tiles_x, tiles_y,
                    shares, n, tiles);
}

/* ---- Pixels and the metric --------------------------------------------- */

/* A tile edge in pixels, clamped to the image: in 64 bits, since 8 e
 * passes 2^32 for grids near the largest uint32 width. */
static uint32_t to_pixel(uint32_t e, uint32_t size) {
  uint64_t p = (uint64_t)e * RP_TILE_SIZE;
  return p < size ? (uint32_t)p : size;
}

int rp_balance_to_pixels(const rp_region *tiles, uint32_t n, uint32_t width,
                         uint32_t height, rp_region *pixels) {
  uint32_t tx, ty, i;
  if (tiles == NULL || pixels == NULL || n == 0 || width == 0 ||
      height == 0)
    return RP_EINVAL;
  rp_tile_grid(width, height, &tx, &ty);
  for (i = 0; i < n; i++) {
    const rp_region *t = &tiles[i];
    if (t->x0 > t->x1 || t->y0 > t->y1 || t->x1 > tx || t->y1 > ty)
      return RP_ERANGE;
  }
  for (i = 0; i < n; i++) {
    rp_region t = tiles[i]; /* pixels may be tiles */
    rp_region p = {to_pixel(t.x0, width), to_pixel(t.y0, height),
                   to_pixel(t.x1, width), to_pixel(t.y1, height)};
    pixels[i] = p;
  }
  return 0;
}

int rp_balance_metric(const double *times, const rp_region *regions,
                      uint32_t n, double *out) {
  double lo = INFINITY, hi = 0, sum = 0;
  uint32_t i, count = 0;
  if (times == NULL || out == NULL || n == 0)
    return RP_EINVAL;
  for (i = 0; i < n; i++) {
    if (!isfinite(times[i]) || times[i] < 0)
      return isfinite(times[i]) ? RP_ERANGE : RP_ENOTFINITE;
    if (regions != NULL &&
        (regions[i].x0 >= regions[i].x1 || regions[i].y0 >= regions[i].y1))
      continue; /* no work this frame */
    lo = fmin(lo, times[i]);
    hi = fmax(hi, times[i]);
    sum += times[i];
    count++;
  }
  *out = count > 0 && sum > 0 ? (hi - lo) / (sum / count) : 0;
  return 0;
}
