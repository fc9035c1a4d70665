/* Out-of-core volumes (DESIGN section 9): a device whose memory budget is
 * smaller than the volume keeps it as bricks. Not part of the public API.
 *
 * A brick is brick_size^3 voxels plus a one-voxel border on the high side
 * of each axis ("stored" = brick_size + 1 per axis), the voxel its
 * neighbour starts with, replicated from the edge past the volume's end.
 * Trilinear sampling reads a cell's low corner and the next voxel along
 * each axis, and clamps the low corner to dims - 2: so every cell lies in
 * the one brick of its low corner and a sample reads one brick, never
 * two. The host keeps every brick (main memory is the level below); the
 * device keeps a pool of slots filled with least-recently-used
 * replacement, and a table (one uint32 per brick) that says which slot
 * holds it. Slot 0 is never a brick's: it is filled with one value the
 * current TF makes transparent, and every brick not resident points there.
 *
 * Which bricks a region needs: those that are visible under the TF (its
 * value range, border included, reaches a LUT entry above 0) and whose
 * projection covers a pixel centre of the region. With shading, the
 * gradient reads one voxel beyond a sample, so an invisible brick next to
 * a visible one is needed too, and the footprint grows by that voxel. A
 * sample in a brick that is not needed reads slot 0 and is transparent,
 * as it is in core: the image is the in-core image, bit for bit. */
#ifndef RP_BRICKS_H
#define RP_BRICKS_H

#include <stdint.h>

#include "device.h"
#include "internal.h"
#include "raygen.h"

/* 16 by default: larger bricks cull more coarsely and upload several
 * times the bytes a frame; smaller ones carry a larger share of border
 * (docs/out_of_core.md, "Bricks"). */
#define RP__BRICK_DEFAULT 16
#define RP__BRICK_MIN 8
#define RP__BRICK_MAX 256
#define RP__BRICK_NONE 0xffffffffu

typedef struct rp__bricks rp__bricks;

/* Bricks `vol` (a copy: the volume may go afterwards) for a pool of
 * `slots` slots, slot 0 included; slots >= 2. */
int rp__bricks_create(rp_context *ctx, const rp_volume *vol,
                      uint32_t brick_size, uint32_t slots, rp__bricks **out);
void rp__bricks_destroy(rp__bricks *b);

/* Bytes of one stored brick of `type`, and the bricks along each axis. */
size_t rp__bricks_stored_bytes(uint32_t brick_size, rp_voxel_type type);
void rp__bricks_grid(const uint32_t dims[3], uint32_t brick_size,
                     uint32_t grid[3]);

/* Visibility under `tf`, and slot 0's value (rp__bricks_fill). */
void rp__bricks_set_tf(rp__bricks *b, const rp_tf *tf);

/* The footprint of every candidate brick for this camera (rg's scaled
 * image) and effect set; queries below are for regions of that image. */
void rp__bricks_frame(rp__bricks *b, const rp__raygen *rg, int shading);
/* Bricks `r` needs (listed inside b for rp__bricks_admit). */
uint32_t rp__bricks_needed(rp__bricks *b, const rp_region *r);
/* Of those, the ones not resident now. */
uint32_t rp__bricks_missing(const rp__bricks *b);

/* Makes the last rp__bricks_needed list resident (it must fit: count <=
 * slots - 1), evicting the least recently used slots outside it; ties go
 * to the lowest slot. Lists the bricks to upload (upload_count, with
 * upload_slots and upload_bricks) and updates the table. */
void rp__bricks_admit(rp__bricks *b);

/* What the device's upload_bricks op receives. */
uint32_t rp__bricks_upload_count(const rp__bricks *b);
const uint32_t *rp__bricks_upload_slots(const rp__bricks *b);
/* Voxel pointers of the bricks to upload, upload_count of them. */
const void *const *rp__bricks_upload_data(const rp__bricks *b);
const uint32_t *rp__bricks_table(const rp__bricks *b);
/* Slot 0's contents: stored^3 voxels of the transparent value, and
 * whether they changed since rp__bricks_fill_sent. */
const void *rp__bricks_fill(const rp__bricks *b, int *changed);
void rp__bricks_fill_sent(rp__bricks *b);
/* Depth slabs, for a region whose needed list (the last
 * rp__bricks_needed) exceeds `cap` bricks: cuts along the rays so that
 * the bricks each slab [cuts[k-1], cuts[k]) meets fit (cuts[-1] = -inf,
 * the last cut +inf), at most max_cuts of them. -1 when the bricks at
 * one depth exceed cap (*worst: how many), or more cuts are needed. The
 * region's list is kept; rp__bricks_slab_needed then makes a slab's the
 * needed list. */
int rp__bricks_slabs(rp__bricks *b, uint32_t cap, float *cuts,
                     uint32_t max_cuts, uint32_t *n_slabs, uint32_t *worst);
void rp__bricks_slab_needed(rp__bricks *b, float t0, float t1);

/* A dry run: the pool's bookkeeping as it is now, and back to it (what
 * a render would upload is simulated with admit in between). */
void rp__bricks_checkpoint(rp__bricks *b);
void rp__bricks_rollback(rp__bricks *b);
/* Nothing is resident any more: after a failed upload, when what the
 * device holds is unknown. */
void rp__bricks_forget(rp__bricks *b);

/* Tests' view: a brick's stored voxels, its visibility, the last needed
 * list, and a needed list set directly (ids < count, no repeats, at most
 * slots - 1 of them). */
const void *rp__bricks_voxels(const rp__bricks *b, uint32_t brick);
int rp__bricks_visible(const rp__bricks *b, uint32_t brick);
const uint32_t *rp__bricks_need_list(const rp__bricks *b);
void rp__bricks_set_needed(rp__bricks *b, const uint32_t *ids, uint32_t n);

typedef struct rp__bricks_info {
  uint32_t brick_size, stored;
  uint32_t grid[3];
  uint32_t count, visible, slots, resident;
  uint64_t hits, misses, evictions;
  size_t stored_bytes;
} rp__bricks_info;
void rp__bricks_get_info(const rp__bricks *b, rp__bricks_info *info);

/* ---- brick_plan.c: one device's out-of-core plan --------------------- */

/* How a device holds its volume, and how a render or an estimate walks
 * the pool: which volume goes whole and which as bricks, the parts a
 * region is cut into so that each part's bricks fit, the depth slabs of a
 * tile that still does not fit, and the measured upload rate. The device
 * front end (backend.c) validates and calls in; everything out of core
 * happens here and in the pool above. */
typedef struct rp__brick_plan {
  rp_context *ctx;
  const rp_backend_ops *ops; /* the device's backend */
  void *impl;
  const rp_caps *caps;       /* the device's, for limits and messages */
  uint64_t budget_bytes;     /* rp_device_desc's; 0: the largest buffer */
  uint32_t brick_size;
  rp__bricks *bricks;        /* NULL while the whole volume is on the
                                device (or none is) */
  int table_sent;            /* the pool's table is the host's */
  /* Renders alternate the order of their parts, so that the last part's
   * bricks are the first the next frame needs: in one fixed order, LRU
   * evicts exactly the bricks the next part needs (docs/out_of_core.md,
   * "What a render loads"). */
  int reverse_parts;
  rp_brick_stats stats;      /* but out_of_core and the pool's counters */
  double upload_ns_per_byte; /* measured on its uploads (smoothed) */
} rp__brick_plan;

/* A plan for a device that holds no volume yet; brick_size resolved. */
void rp__brick_plan_init(rp__brick_plan *pl, rp_context *ctx,
                         const rp_backend_ops *ops, void *impl,
                         const rp_caps *caps, uint64_t budget_bytes,
                         uint32_t brick_size);
/* Frees the host's bricks (the device is going). */
void rp__brick_plan_release(rp__brick_plan *pl);
/* What the volume may take on the device. */
uint64_t rp__brick_plan_budget(const rp__brick_plan *pl);
/* Uploads `vol` whole when it fits the budget, else as bricks with an
 * empty pool. A failure changes nothing, except that a backend whose
 * pool could not be set holds no volume any more (it dropped the old
 * one first): then *lost is 1. */
int rp__brick_plan_upload(rp__brick_plan *pl, const rp_volume *vol,
                          int *lost);
/* The TF uploaded: bricks' visibility and slot 0's transparent value. */
void rp__brick_plan_set_tf(rp__brick_plan *pl, const rp_tf *tf);
/* A frame's brick fields (brick_shift, brick_grid, one slab). */
void rp__brick_plan_frame(const rp__brick_plan *pl, rp_frame_params *p);
/* Raycasts `region` out of core: the bricks of each part made resident,
 * then the part cast (its depth slabs in turn). *ns receives the device
 * time of it all, uploads included. The depth pass has run. */
int rp__brick_plan_render(rp__brick_plan *pl, const rp__host_frame *f,
                          const rp_region *region, uint8_t *rgba,
                          rp_tile_stats *tiles, uint64_t *fetches,
                          uint64_t *ns);
/* rp_device_upload_estimate out of core: the render's own plan, run on a
 * copy of the pool's bookkeeping. */
int rp__brick_plan_estimate(rp__brick_plan *pl, const rp__raygen *rg,
                            uint32_t effects, const rp_region *r,
                            rp_upload_estimate *out);
void rp__brick_plan_stats(const rp__brick_plan *pl, rp_brick_stats *out);
/* RP_EUNSUPPORTED for AO on bricks (fn names the call): AO reads and
 * darkens the whole volume. */
int rp__brick_plan_no_ao(const rp__brick_plan *pl, const char *fn);

#endif /* RP_BRICKS_H */
