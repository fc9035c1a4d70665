/* The arithmetic of a group's split (DESIGN section 7): each device's
 * model of its time, the shares that make the devices finish together,
 * what a frame teaches the model, the predicted time of the frame, and
 * sums of predicted tile cost. Pure: no threads, no devices, no
 * allocation; every function may run on any thread. The group
 * (group.c) holds the state and calls these. */
#ifndef RP_SHARES_H
#define RP_SHARES_H

#include <stdint.h>

#include "raypace.h"
#include "raypace_group.h"
#include "raypace_pace.h"

/* The rate is the median of the device's last RP__RATE_FRAMES measured
 * rates: one stalled frame (a descheduled thread on a shared machine:
 * 10x and more) moves nothing, a device that really slows down is
 * followed from its second frame. */
#define RP__RATE_FRAMES 3
/* The least fraction of the frame's predicted cost a region must have for
 * its time to raise the device's rate. A sliver's time is mostly what
 * every render costs (launch, readback); taken as a rate, it would make
 * the device look slow, give it a thinner sliver, and so on down. It is
 * still an upper bound on the rate, so a sliver that measures lower than
 * the rate counts: a device squeezed by one stalled frame recovers. */
#define RP__MIN_RATE_FRACTION 0.05
/* How much of the gap to this frame a device's depth-pass frequency (a
 * running mean) closes per frame. */
#define RP__DEPTH_FREQ_GAIN 0.25

/* The split's model of one device: its time for a region is
 * depth_freq * depth_est + rate * (the region's predicted tile cost).
 * rate: wall ms per unit of predicted tile cost outside its depth pass
 * (0: unknown), the median of `rates` (a ring of the last measured);
 * depth_est: its last depth pass's ms; depth_freq: how often a frame
 * needs one. Zero-initialised: nothing known. */
typedef struct rp__split_model {
  double rate, depth_est, depth_freq;
  double rates[RP__RATE_FRAMES];
  uint32_t n_rates, next_rate;
} rp__split_model;

/* Files a measured rate and sets m->rate to the median of the last ones
 * (of two, the lower: the other may be the stall). */
void rp__rate_add(rp__split_model *m, double measured);

/* What one device did in a frame's first round, for rp__split_learn. */
typedef struct rp__split_sample {
  int rendered;          /* it rendered a region or strips */
  double cost;           /* their predicted tile cost */
  uint32_t depth_passes; /* depth passes it ran (0: reused) */
  double depth_ms;       /* their wall time */
  double busy_ms;        /* its whole wall time for the frame */
} rp__split_sample;

/* What the split learns from a device's frame: its wall time per unit of
 * predicted cost outside the depth pass (rp__rate_add; a region under
 * RP__MIN_RATE_FRACTION of `total_cost` only when it lowers the rate),
 * and how often frames need its depth pass. A device idle this frame
 * still follows the frames' need for a depth pass (`frame_depth`: 1 when
 * the frame needed one): charged a pass the frames no longer need, a
 * device the split squeezed out would stay out. */
void rp__split_learn(rp__split_model *m, const rp__split_sample *s,
                     double total_cost, int frame_depth);

/* This frame's shares into shares[0 .. count-1]; dev[i] NULL: device i
 * is dropped (share 0). Dynamic (d->share_mode): the shares that make
 * the devices' modelled times over `cost` (the frame's total predicted
 * tile cost; 0: unknown, every device counts as average) equal
 * (rp_balance_shares_fixed), damped against `prev` (last frame's
 * shares, NULL or summing to 0 over the live devices: none) by
 * d->damping and d->damp_rate. Fixed: d->fixed_shares of the live
 * devices, renormalised (all 0: even). A device not yet measured counts
 * as an average one.
 * \returns 0, RP_ENODEV (no live device), or rp_balance_*'s error. */
int rp__frame_shares(const rp_group_desc *d,
                     const rp__split_model *const *dev, uint32_t count,
                     const double *prev, double cost, double *shares);

/* A device's whole-frame estimate split into what its share does not
 * scale (c0, times the frame factor Q, which scales it too) and what it
 * does (the raycast: its samples, and its cost per ray, which scales
 * with the region's area rather than its samples, near enough). */
typedef struct rp__device_cost {
  double fixed, var;
  rp_cost_estimate e;
  int ok; /* finite fixed, var > 0 */
} rp__device_cost;

/* Fills c->fixed, c->var and c->ok from c->e. */
void rp__device_cost_split(rp__device_cost *c);

/* The frame's predicted time: the slowest device's fixed + share * var
 * over the devices with c[i].ok, a device whose share buys less than
 * half of the frame's `tiles` paying nothing (it gets an empty region).
 * *fastest: the index of the device of least var, -1 with no device
 * (the time is then NaN). */
double rp__predict_frame(const rp__device_cost *c, const double *shares,
                         uint32_t count, double tiles, int *fastest);

/* Whether a region holds no pixel (or tile). */
int rp__region_empty(const rp_region *r);

/* Sum of the tile costs over the tile rectangle t of a grid tx wide. */
double rp__region_cost(const float *cost, uint32_t tx, const rp_region *t);

/* The tail (rp_group_desc.tail_fraction) of a tx x ty grid of tile
 * costs summing to `total`: the fewest bottom rows (never all) whose
 * cost reaches `fraction` of it, cut along x into `n` strips (capped at
 * tx and RP_GROUP_MAX_STRIPS) of about equal cost, each at least one
 * tile wide, into strips[] (tile units). Returns the strip count, 0 for
 * no tail (a grid of one row, no cost, or an empty band). */
uint32_t rp__tail_cut(const float *cost, uint32_t tx, uint32_t ty,
                      double fraction, uint32_t n, double total,
                      rp_region *strips);

#endif /* RP_SHARES_H */
