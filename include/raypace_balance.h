/* Lab tier (README, "Headers"): public for research use, and may change
 * between minor versions. An app embedding the runtime needs none of it:
 * every setting it makes is declared in the product headers.
 *
 * raypace load balancing: one frame's image split across several devices
 * (DESIGN section 7, milestone M6). Pure host arithmetic, no device:
 * - shares: each device's fraction of the frame's work from its cost per
 *   unit of work sigma, w_i = (1 / sigma_i) / sum_j (1 / sigma_j), and
 *   the paper's Eq. 3 for comparison;
 * - damping: how far the shares may move from frame to frame;
 * - split: a kd-tree over the image's 8x8-pixel tiles, cut where each
 *   device group's predicted cost matches its share;
 * - the balance metric (max - min) / mean of the devices' times.
 *
 * Shares returned by this header are multiples of 2^-53 whose sum is
 * exactly 1: added up in any order, in double, they give 1.0 (every
 * partial sum is a multiple of 2^-53 no greater than 1, which a double
 * holds exactly).
 *
 * Only the split needs memory (a balancer, made once); shares, damping,
 * pixels and the metric are pure functions. A frame goes: sigma from the
 * devices' last times over their last work -> rp_balance_shares() ->
 * rp_balance_damp() against last frame's shares -> rp_balancer_split() on
 * the tiles' predicted costs -> rp_balance_to_pixels() -> render, skipping
 * devices with an empty region.
 *
 * Threading: the free functions keep no state and may run on any thread;
 * a balancer belongs to one thread at a time. */
#ifndef RAYPACE_BALANCE_H
#define RAYPACE_BALANCE_H

#include <stdint.h>

#include "raypace.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Most devices any function here accepts. */
#define RP_BALANCE_MAX_DEVICES 1024
/** Most tiles (tiles_x * tiles_y) a balancer can be made for. */
#define RP_BALANCE_MAX_TILES (1u << 28)

/* ---- Shares ------------------------------------------------------------- */

/** Each device's share of the work from its cost per unit sigma_i:
 *  w_i = (1 / sigma_i) / sum_j (1 / sigma_j). A sigma that is NaN or 0
 *  means "not measured yet" (the first frames): such a device is given
 *  the mean of the known devices' 1 / sigma, so it is treated as an
 *  average device; when no sigma is known the split is even. `w` may be
 *  `sigma`. No context: errors carry no message.
 *  \returns 0; RP_EINVAL (NULL, n == 0), RP_ENOTFINITE (an infinite
 *  sigma), RP_ERANGE (a negative sigma, n > RP_BALANCE_MAX_DEVICES); a
 *  failed call leaves `w` untouched. \threadsafety any thread.
 *  \since 0.1 */
RP_API int rp_balance_shares(const double *sigma, uint32_t n, double *w);

/** Shares that make the devices finish together when each also pays a
 *  cost its share does not scale (a depth pass over the whole image, a
 *  launch): device i takes fixed_i + w_i var_i, var_i being its time for
 *  the whole frame's share-scaled work. Then w_i = (T - fixed_i) / var_i
 *  with T = (1 + sum_j fixed_j / var_j) / sum_j (1 / var_j), over the
 *  devices whose fixed cost is below T (the others get 0). With every
 *  fixed_i 0 it is rp_balance_shares(var). An unknown var (NaN or 0)
 *  counts as the known devices' mean speed. Sums to exactly 1.
 *  \returns 0; RP_EINVAL (NULL, n == 0), RP_ENOTFINITE (an infinite var,
 *  a NaN or infinite fixed), RP_ERANGE (a negative value, n >
 *  RP_BALANCE_MAX_DEVICES); a failed call leaves `w` untouched.
 *  \threadsafety any thread. \since 0.1 */
RP_API int rp_balance_shares_fixed(const double *var, const double *fixed,
                                   uint32_t n, double *w);

/** The paper's Eq. 3, w_i = prod_{j != i} sigma_j / sum_k sigma_k, for
 *  comparison only: it equals rp_balance_shares() for two devices, and
 *  for three or more its shares do not sum to one. Not renormalised.
 *  Every sigma must be positive and finite.
 *  \returns 0; RP_EINVAL (NULL, n == 0), RP_ENOTFINITE, RP_ERANGE
 *  (n > RP_BALANCE_MAX_DEVICES, sigma <= 0, a product or sum that
 *  overflows); a failed call leaves `w` untouched.
 *  \threadsafety any thread. \since 0.1 */
RP_API int rp_balance_shares_eq3(const double *sigma, uint32_t n,
                                 double *w);

/* ---- Damping ------------------------------------------------------------ */

/* rp_damping, the two rules, is in raypace.h (the runtime's setting). */

/** One frame's damping step from this frame's target shares (e.g.
 *  rp_balance_shares()) and, for RP_DAMP_SMOOTH, the previous frame's
 *  shares, which the caller keeps (NULL: the even split, for the first
 *  frame or after the device set changed). `rate` is lambda
 *  (RP_DAMP_SMOOTH) or zeta (RP_DAMP_EVEN), in (0, 1]; 0: 0.5. `prev`
 *  is ignored by RP_DAMP_EVEN. `prev` and `target` must
 *  hold finite values >= 0 with a positive sum; each is divided by its
 *  own sum first. The result is renormalised to sum to exactly 1 (see
 *  the top of this header). `out` may be `prev` or `target`.
 *  \returns 0; RP_EINVAL (NULL, n == 0, unknown mode, a zero or
 *  overflowing sum), RP_ENOTFINITE, RP_ERANGE (n >
 *  RP_BALANCE_MAX_DEVICES, a rate outside (0, 1], a negative share); a
 *  failed call leaves `out` untouched.
 *  \threadsafety any thread. \since 0.1 */
RP_API int rp_balance_damp(rp_damping mode, double rate, const double *prev,
                           const double *target, uint32_t n, double *out);

/* ---- The split ---------------------------------------------------------- */

/** The split's workspace: all the memory a split needs, allocated once
 *  at create, so that rp_balancer_split() allocates nothing. */
typedef struct rp_balancer rp_balancer;

/** Zero fields take the defaults. */
typedef struct rp_balancer_desc {
  uint32_t max_devices; /* 0: 8; at most RP_BALANCE_MAX_DEVICES */
  uint32_t max_tiles;   /* most tiles_x * tiles_y a split takes; 0: 512 *
                           512 (a 4096 x 4096 image); at most
                           RP_BALANCE_MAX_TILES. Costs 16 bytes a tile */
} rp_balancer_desc;

/** `desc` may be NULL (all defaults). `ctx` is kept: failed calls leave
 *  their message in rp_last_error(ctx).
 *  \returns 0, RP_EINVAL, RP_ERANGE (a field over its limit) or
 *  RP_ENOMEM. \since 0.1 */
RP_API int rp_balancer_create(rp_context *ctx, const rp_balancer_desc *desc,
                              rp_balancer **out);
/** NULL is a no-op. \since 0.1 */
RP_API void rp_balancer_destroy(rp_balancer *b);

/** Splits a tiles_x x tiles_y grid of 8x8-pixel tiles (rp_tile_grid())
 *  among n devices. `cost` holds each tile's predicted cost, row by row,
 *  x fastest; every cost finite and >= 0. When every cost is 0 each tile
 *  counts as cost 1 (the split is by tile count). `shares` are finite,
 *  >= 0, with a positive sum (only their ratios matter).
 *
 *  `tiles[i]` receives device i's rectangle in TILE units, half-open
 *  [x0, x1) x [y0, y1). The rectangles are disjoint and cover the grid.
 *  A device may receive an EMPTY rectangle (x0 == x1 or y0 == y1) when
 *  its share buys less than about half a row or column of tiles (a
 *  device 1000x slower than another, more devices than tiles, a zero
 *  share, which always gets an empty one): the caller skips it for the
 *  frame.
 *
 *  The kd-tree: devices [d0, d1) and a rectangle; the devices split into
 *  two contiguous groups [d0, m), [m, d1) at the m that makes the two
 *  groups' share sums closest (ties, within 1e-12 of the sum: the m
 *  nearest the middle, then the larger m); the rectangle is cut across
 *  its longer side (in tiles; a square is cut across x), the lower
 *  coordinates going to the lower device indices, at the tile boundary
 *  where the left part's cost is closest to the cost times the left
 *  group's share fraction. Among boundaries equally close (tiles of cost
 *  0, or two candidates equally far), the one nearest the same fraction
 *  of the tile COUNT, then the larger. Each cut misses its target by at
 *  most half the cost of the one row or column of tiles it passes, so
 *  device i's cost differs from share_i / sum(shares) times the total by
 *  at most the sum of those halves over the cuts above it (at most n - 1
 *  cuts).
 *  \returns 0; RP_EINVAL (NULL, n == 0, a zero-size grid, a zero share
 *  sum), RP_ERANGE (n > max_devices, tiles_x * tiles_y > max_tiles, a
 *  negative cost or share), RP_ENOTFINITE (a NaN or infinite cost or
 *  share, message naming the tile); a failed call leaves `tiles`
 *  untouched. \since 0.1 */
RP_API int rp_balancer_split(rp_balancer *b, const double *cost,
                             uint32_t tiles_x, uint32_t tiles_y,
                             const double *shares, uint32_t n,
                             rp_region *tiles);
/** rp_balancer_split() for float costs. \since 0.1 */
RP_API int rp_balancer_split_f(rp_balancer *b, const float *cost,
                               uint32_t tiles_x, uint32_t tiles_y,
                               const double *shares, uint32_t n,
                               rp_region *tiles);

/** Tile rectangles to pixel rectangles of a width x height image: each
 *  edge times 8, clamped to the image (the last tile column and row may
 *  be partial). Empty stays empty. `pixels` may be `tiles`.
 *  \returns 0; RP_EINVAL (NULL, n == 0, a zero size), RP_ERANGE (a
 *  rectangle with x0 > x1 or y0 > y1 or outside the image's tile grid);
 *  a failed call leaves `pixels` untouched. \threadsafety any thread.
 *  \since 0.1 */
RP_API int rp_balance_to_pixels(const rp_region *tiles, uint32_t n,
                                uint32_t width, uint32_t height,
                                rp_region *pixels);

/* ---- Balance metric ----------------------------------------------------- */

/** One frame's imbalance (seed 001 section 6): (max - min) / mean of the
 *  devices' times (any one unit). Devices whose region is empty did no
 *  work and are left out (their time says nothing about the balance);
 *  `regions` may be NULL to count every device. 0 when no device counts
 *  or the mean is 0. Average it over frames for a run.
 *  \returns 0; RP_EINVAL (NULL, n == 0), RP_ENOTFINITE, RP_ERANGE (a
 *  negative time); a failed call leaves `out` untouched.
 *  \threadsafety any thread. \since 0.1 */
RP_API int rp_balance_metric(const double *times, const rp_region *regions,
                             uint32_t n, double *out);

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_BALANCE_H */
