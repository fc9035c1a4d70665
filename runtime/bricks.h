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

#include "internal.h"
#include "raygen.h"

/* 16: on bonsai and engine at 512^2 (bench_bricks), bricks of 32^3
 * uploaded 3 to 9 times the bytes per frame of 16^3 ones at the same
 * budget (coarser culling, more parts evicting each other), and at an
 * eighth of engine one tile's bricks no longer fit the pool. 8^3 bricks
 * store 42 % more than they hold (the border). */
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

#endif /* RP_BRICKS_H */
