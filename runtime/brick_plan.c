/* One device's out-of-core plan (bricks.h, DESIGN section 9): whole or
 * bricked upload, the parts and depth slabs of a render, the estimate
 * that simulates them, and the upload rate measured on the way. It drives
 * the device's backend through rp_backend_ops and the host's bricks
 * through the pool (bricks.c); the front end has validated every call. */
#include <math.h>
#include <string.h>

#include "bricks.h"

/* Upload rate assumed until a device has measured its own: 2 GB/s, a
 * host memcpy or a PCIe transfer, within a factor of a few either way. */
#define NOMINAL_UPLOAD_NS_PER_BYTE 0.5
/* Weight of the newest upload in the smoothed rate. */
#define UPLOAD_RATE_WEIGHT 0.25
/* Bytes a backend may add to the pool buffer past its bricks. */
#define POOL_PAD 64u
/* Slabs of one tile at most: a tile needing more passes than this is
 * refused rather than rendered at a crawl. */
#define MAX_SLABS 64

void rp__brick_plan_init(rp__brick_plan *pl, rp_context *ctx,
                         const rp_backend_ops *ops, void *impl,
                         const rp_caps *caps, uint64_t budget_bytes,
                         uint32_t brick_size) {
  memset(pl, 0, sizeof *pl);
  pl->ctx = ctx;
  pl->ops = ops;
  pl->impl = impl;
  pl->caps = caps;
  pl->budget_bytes = budget_bytes;
  pl->brick_size = brick_size;
  pl->upload_ns_per_byte = NOMINAL_UPLOAD_NS_PER_BYTE;
}

void rp__brick_plan_release(rp__brick_plan *pl) {
  rp__bricks_destroy(pl->bricks);
  pl->bricks = NULL;
}

uint64_t rp__brick_plan_budget(const rp__brick_plan *pl) {
  uint64_t b = pl->budget_bytes != 0 ? pl->budget_bytes
                                     : pl->caps->max_alloc_bytes;
  return b < pl->caps->max_alloc_bytes ? b : pl->caps->max_alloc_bytes;
}

int rp__brick_plan_no_ao(const rp__brick_plan *pl, const char *fn) {
  return rp__fail(pl->ctx, RP_EUNSUPPORTED, "%s: device '%s' (%s) holds "
                  "its volume as bricks (out of core, budget %llu bytes); "
                  "ambient occlusion needs the whole volume on the device",
                  fn, pl->caps->device, pl->caps->backend,
                  (unsigned long long)rp__brick_plan_budget(pl));
}

/* ---- the volume ---------------------------------------------------------- */

/* Slots of `brick` bytes the budget holds for `count` bricks, slot 0
 * (the transparent one) included. */
static uint64_t pool_slots(const rp__brick_plan *pl, size_t brick,
                           uint64_t count) {
  uint64_t max = pl->caps->max_alloc_bytes;
  uint64_t slots = rp__brick_plan_budget(pl) / brick;
  /* The pool is one buffer, and backends pad theirs by a few bytes
   * (OpenCL 16 for vector loads): keep it under the largest buffer even
   * when the budget is exactly that size (the default). */
  if (slots * brick + POOL_PAD > max)
    slots = max > POOL_PAD ? (max - POOL_PAD) / brick : 0;
  /* More slots than bricks is waste. */
  return slots > count + 1 ? count + 1 : slots;
}

/* A volume larger than the budget: bricks on the host, a pool of as many
 * as the budget holds on the device. */
static int set_bricked(rp__brick_plan *pl, const rp_volume *vol,
                       size_t bytes, int *lost) {
  rp_context *ctx = pl->ctx;
  rp__bricks *b = NULL;
  rp_brick_pool pool;
  uint64_t budget = rp__brick_plan_budget(pl), slots, count;
  size_t brick = rp__bricks_stored_bytes(pl->brick_size, vol->type);
  int err;
  if (pl->ops->set_brick_pool == NULL || pl->ops->upload_bricks == NULL)
    return rp__fail(ctx, RP_EUNSUPPORTED, "rp_device_set_volume: %zu bytes "
                    "exceed the budget of %llu bytes, and backend '%s' "
                    "cannot hold a volume as bricks", bytes,
                    (unsigned long long)budget, pl->caps->backend);
  memset(&pool, 0, sizeof pool);
  rp__bricks_grid(vol->dims, pl->brick_size, pool.grid);
  count = (uint64_t)pool.grid[0] * pool.grid[1] * pool.grid[2];
  slots = pool_slots(pl, brick, count);
  if (slots < 2)
    return rp__fail(ctx, RP_ENOMEM, "rp_device_set_volume: a budget of "
                    "%llu bytes holds %llu bricks of %zu bytes (%u^3 voxels "
                    "and a border); out-of-core rendering needs at least 2 "
                    "(a larger budget or a smaller brick_size)",
                    (unsigned long long)budget, (unsigned long long)slots,
                    brick, pl->brick_size);
  if (count > UINT32_MAX / 2)
    return rp__fail(ctx, RP_ERANGE, "rp_device_set_volume: %llu bricks "
                    "of %u^3 voxels are too many (a larger brick_size)",
                    (unsigned long long)count, pl->brick_size);
  if ((err = rp__bricks_create(ctx, vol, pl->brick_size, (uint32_t)slots,
                               &b)) != 0)
    return err;
  pool.type = vol->type;
  memcpy(pool.dims, vol->dims, sizeof pool.dims);
  pool.brick_size = pl->brick_size;
  pool.slots = (uint32_t)slots;
  if ((err = pl->ops->set_brick_pool(pl->impl, &pool)) != 0) {
    rp__bricks_destroy(b);
    rp__brick_plan_release(pl);
    *lost = 1;
    return err;
  }
  rp__bricks_destroy(pl->bricks);
  pl->bricks = b;
  pl->table_sent = 0;
  return 0;
}

int rp__brick_plan_upload(rp__brick_plan *pl, const rp_volume *vol,
                          int *lost) {
  size_t bytes = vol->voxel_count * rp__voxel_size(vol->type);
  int err;
  *lost = 0;
  if (bytes > rp__brick_plan_budget(pl)) {
    err = set_bricked(pl, vol, bytes, lost);
  } else if ((err = pl->ops->upload_volume(pl->impl, vol)) == 0) {
    rp__brick_plan_release(pl);
  }
  if (err == 0)
    memset(&pl->stats, 0, sizeof pl->stats);
  return err;
}

void rp__brick_plan_set_tf(rp__brick_plan *pl, const rp_tf *tf) {
  if (pl->bricks != NULL)
    rp__bricks_set_tf(pl->bricks, tf);
}

void rp__brick_plan_frame(const rp__brick_plan *pl, rp_frame_params *p) {
  rp__bricks_info info;
  if (pl->bricks == NULL)
    return;
  rp__bricks_get_info(pl->bricks, &info);
  for (p->brick_shift = 0; (1u << p->brick_shift) < info.brick_size;
       p->brick_shift++)
    ;
  memcpy(p->brick_grid, info.grid, sizeof p->brick_grid);
  /* One pass, unless the render cuts a tile into depth slabs. */
  p->slab_cut = INFINITY;
  p->slab_flags = RP_SLAB_FIRST | RP_SLAB_LAST;
}

void rp__brick_plan_stats(const rp__brick_plan *pl, rp_brick_stats *out) {
  rp__bricks_info info;
  *out = pl->stats;
  out->out_of_core = pl->bricks != NULL;
  if (pl->bricks == NULL)
    return;
  rp__bricks_get_info(pl->bricks, &info);
  out->brick_size = info.brick_size;
  out->bricks = info.count;
  out->visible = info.visible;
  out->slots = info.slots;
  out->resident = info.resident;
  out->hits = info.hits;
  out->misses = info.misses;
  out->evictions = info.evictions;
}

/* ---- parts and slabs ----------------------------------------------------- */

/* One part of an out-of-core region: pixels, and the depth slab of their
 * rays (slab_cut +inf and both flags: the whole rays). The pool's needed
 * list is the part's when fn is called. */
typedef struct part {
  rp_region r;
  float slab_cut;
  uint32_t slab_flags;
} part;

typedef int (*part_fn)(rp__brick_plan *pl, const part *pt, void *user);

/* A tile whose bricks do not fit the pool: its rays in depth slabs. */
static int for_each_slab(rp__brick_plan *pl, const rp_region *r,
                         uint32_t need, uint32_t cap, part_fn fn,
                         void *user) {
  float cuts[MAX_SLABS], t0 = -INFINITY;
  uint32_t n = 0, k, worst = 0;
  rp__bricks_info info;
  int err;
  if (rp__bricks_slabs(pl->bricks, cap, cuts, MAX_SLABS, &n, &worst) != 0) {
    rp__bricks_get_info(pl->bricks, &info);
    return rp__fail(pl->ctx, RP_ENOMEM, "rp_device_render: the pixels "
                    "[%u,%u)x[%u,%u) need %u bricks, %s, and the pool holds "
                    "%u (budget %llu bytes, bricks of %zu bytes): a larger "
                    "budget or a smaller brick_size", r->x0, r->x1, r->y0,
                    r->y1, need, worst > cap ? "more than that at one depth"
                                             : "in more than 64 depth slabs",
                    cap, (unsigned long long)rp__brick_plan_budget(pl),
                    info.stored_bytes);
  }
  for (k = 0; k < n; k++) {
    part pt;
    pt.r = *r;
    pt.slab_cut = cuts[k];
    pt.slab_flags = (k == 0 ? RP_SLAB_FIRST : 0u) |
                    (k + 1 == n ? RP_SLAB_LAST : 0u);
    rp__bricks_slab_needed(pl->bricks, t0, cuts[k]);
    if ((err = fn(pl, &pt, user)) != 0)
      return err;
    t0 = cuts[k];
  }
  return 0;
}

/* Cuts `region` into halves (on the tile grid, across the longer side)
 * until each part's bricks fit the pool, a tile that still does not fit
 * into depth slabs, and calls fn on the parts in order, or in reverse
 * order with pl->reverse_parts: the plan a render follows and an
 * estimate simulates. Call rp__bricks_frame first. */
static int for_each_part(rp__brick_plan *pl, const rp_region *region,
                         part_fn fn, void *user) {
  /* Depth-first halving keeps at most one pending part per level, and
   * a level at least halves a side of at most 2^32 pixels. */
  rp_region stack[2 * 32 + 2];
  uint32_t depth = 0, cap;
  rp__bricks_info info;
  rp__bricks_get_info(pl->bricks, &info);
  cap = info.slots - 1;
  stack[depth++] = *region;
  while (depth > 0) {
    rp_region r = stack[--depth], lo, hi;
    uint32_t w = r.x1 - r.x0, h = r.y1 - r.y0, need, cut;
    int err;
    need = rp__bricks_needed(pl->bricks, &r);
    if (need <= cap) {
      part pt;
      pt.r = r;
      pt.slab_cut = INFINITY;
      pt.slab_flags = RP_SLAB_FIRST | RP_SLAB_LAST;
      if ((err = fn(pl, &pt, user)) != 0)
        return err;
      continue;
    }
    if (w <= RP_TILE_SIZE && h <= RP_TILE_SIZE) {
      if ((err = for_each_slab(pl, &r, need, cap, fn, user)) != 0)
        return err;
      continue;
    }
    lo = hi = r;
    if (w >= h && w > RP_TILE_SIZE) {
      cut = r.x0 + (w / 2 + RP_TILE_SIZE - 1) / RP_TILE_SIZE * RP_TILE_SIZE;
      if (cut >= r.x1)
        cut = r.x0 + RP_TILE_SIZE;
      lo.x1 = hi.x0 = cut;
    } else {
      cut = r.y0 + (h / 2 + RP_TILE_SIZE - 1) / RP_TILE_SIZE * RP_TILE_SIZE;
      if (cut >= r.y1)
        cut = r.y0 + RP_TILE_SIZE;
      lo.y1 = hi.y0 = cut;
    }
    stack[depth++] = pl->reverse_parts ? lo : hi;
    stack[depth++] = pl->reverse_parts ? hi : lo;
  }
  return 0;
}

/* ---- rendering ----------------------------------------------------------- */

/* Slot 0's transparent fill, when the TF changed it. */
static int send_fill(rp__brick_plan *pl, uint64_t *ns) {
  static const uint32_t slot0 = 0;
  int changed, err;
  const void *fill = rp__bricks_fill(pl->bricks, &changed);
  if (!changed)
    return 0;
  if ((err = pl->ops->upload_bricks(pl->impl, 1, &slot0, &fill, NULL)) != 0)
    return err;
  rp__bricks_fill_sent(pl->bricks);
  *ns += pl->ops->last_time_ns(pl->impl);
  return 0;
}

/* Makes the bricks of the part's needed list resident and raycasts it;
 * *ns and the stats gain the device time of both. */
static int render_piece(rp__brick_plan *pl, const rp_frame_params *p,
                        const rp_region *r, uint8_t *rgba,
                        rp_tile_stats *tiles, uint64_t *fetches,
                        uint64_t *ns) {
  rp__bricks *b = pl->bricks;
  rp__bricks_info info;
  int err;
  uint32_t n;
  if ((err = send_fill(pl, ns)) != 0)
    return err;
  rp__bricks_admit(b);
  n = rp__bricks_upload_count(b);
  if (n > 0 || !pl->table_sent) {
    uint64_t t;
    if ((err = pl->ops->upload_bricks(pl->impl, n,
                                      rp__bricks_upload_slots(b),
                                      rp__bricks_upload_data(b),
                                      rp__bricks_table(b))) != 0) {
      /* Which writes landed is unknown: start the pool over. */
      rp__bricks_forget(b);
      pl->table_sent = 0;
      return err;
    }
    pl->table_sent = 1;
    t = pl->ops->last_time_ns(pl->impl);
    rp__bricks_get_info(b, &info);
    *ns += t;
    pl->stats.last_upload_ns += t;
    pl->stats.last_upload_bytes += (uint64_t)n * info.stored_bytes;
  }
  if ((err = pl->ops->raycast(pl->impl, p, r, rgba, tiles, fetches)) != 0)
    return err;
  *ns += pl->ops->last_time_ns(pl->impl);
  pl->stats.last_pieces++;
  if (p->slab_flags != (RP_SLAB_FIRST | RP_SLAB_LAST))
    pl->stats.last_slabs++;
  return 0;
}

typedef struct render_job {
  const rp__host_frame *f;
  uint8_t *rgba;
  rp_tile_stats *tiles;
  uint64_t *fetches;
  uint64_t ns;
} render_job;

static int render_part(rp__brick_plan *pl, const part *pt, void *user) {
  render_job *j = user;
  rp__host_frame f = *j->f; /* the part's slab, the frame's camera */
  f.p.slab_cut = pt->slab_cut;
  f.p.slab_flags = pt->slab_flags;
  return render_piece(pl, &f.p, &pt->r, j->rgba, j->tiles, j->fetches,
                      &j->ns);
}

/* Large uploads only: a few bricks measure the call, not the rate. */
static void learn_upload_rate(rp__brick_plan *pl) {
  double rate;
  if (pl->stats.last_upload_bytes < (1u << 20))
    return;
  rate = (double)pl->stats.last_upload_ns /
         (double)pl->stats.last_upload_bytes;
  pl->upload_ns_per_byte =
      pl->stats.uploaded_bytes == pl->stats.last_upload_bytes
          ? rate
          : (1.0 - UPLOAD_RATE_WEIGHT) * pl->upload_ns_per_byte +
                UPLOAD_RATE_WEIGHT * rate;
}

int rp__brick_plan_render(rp__brick_plan *pl, const rp__host_frame *f,
                          const rp_region *region, uint8_t *rgba,
                          rp_tile_stats *tiles, uint64_t *fetches,
                          uint64_t *ns) {
  render_job j;
  int err;
  j.f = f;
  j.rgba = rgba;
  j.tiles = tiles;
  j.fetches = fetches;
  j.ns = 0;
  rp__bricks_frame(pl->bricks, f->rg,
                   (f->p.effects & RP_EFFECT_SHADING) != 0);
  pl->stats.last_pieces = pl->stats.last_slabs = 0;
  pl->stats.last_upload_bytes = 0;
  pl->stats.last_upload_ns = 0;
  err = for_each_part(pl, region, render_part, &j);
  pl->reverse_parts = !pl->reverse_parts;
  *ns = j.ns;
  pl->stats.uploaded_bytes += pl->stats.last_upload_bytes;
  pl->stats.upload_ns += pl->stats.last_upload_ns;
  if (err != 0)
    return err;
  learn_upload_rate(pl);
  return 0;
}

/* ---- the estimate -------------------------------------------------------- */

/* An estimate's part: admit its bricks in the dry run, count uploads. */
static int count_part(rp__brick_plan *pl, const part *pt, void *user) {
  (void)pt;
  rp__bricks_admit(pl->bricks);
  *(uint32_t *)user += rp__bricks_upload_count(pl->bricks);
  return 0;
}

int rp__brick_plan_estimate(rp__brick_plan *pl, const rp__raygen *rg,
                            uint32_t effects, const rp_region *r,
                            rp_upload_estimate *out) {
  rp__bricks_info info;
  uint32_t uploads = 0;
  int err;
  memset(out, 0, sizeof *out);
  if (pl->bricks == NULL)
    return 0;
  rp__bricks_frame(pl->bricks, rg, (effects & RP_EFFECT_SHADING) != 0);
  out->bricks = rp__bricks_needed(pl->bricks, r);
  /* The render's own plan, run on a copy of the pool's bookkeeping: the
   * bricks it would load, a brick loaded by two parts twice. */
  rp__bricks_checkpoint(pl->bricks);
  err = for_each_part(pl, r, count_part, &uploads);
  rp__bricks_rollback(pl->bricks);
  if (err != 0)
    return err;
  rp__bricks_get_info(pl->bricks, &info);
  out->loads = uploads;
  out->bytes = (uint64_t)uploads * info.stored_bytes;
  out->ms = (double)out->bytes * pl->upload_ns_per_byte * 1e-6;
  return 0;
}
