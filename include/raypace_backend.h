/* Product tier (README, "Headers"): the interface a device backend is
 * written against, versioned by RP_BACKEND_ABI.
 *
 * raypace backend interface: what a device backend implements.
 *
 * The front end (runtime/backend.c) validates every call and resolves all
 * defaults before it reaches a backend, so a backend trusts its inputs
 * (STYLE rules 7-9). An op a backend lacks is NULL.
 *
 * Everything a kernel needs for one frame is in rp_frame_params, in the
 * plain float/uint form kernels consume. The geometry is that of the
 * scalar reference (runtime/raygen.h, runtime/reference.c); a backend
 * reproduces it in float. */
#ifndef RAYPACE_BACKEND_H
#define RAYPACE_BACKEND_H

#include <stdint.h>

#include "raypace.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Bumped whenever rp_backend_ops, rp_backend_bootstrap or rp_frame_params
 * change layout. 7: rp_backend_ops.clock_ns. 8: rp_frame_params.jitter
 * and jitter_seed. */
#define RP_BACKEND_ABI 8

/* RP_EFFECT_PREINT: LUT alphas are clamped to this before their
 * extinction -ln(1 - a) is taken (runtime/preint.c says why). */
#define RP_PREINT_ALPHA_MAX (1.0 - 1e-6)

/* Coarse ERT pre-pass geometry (DESIGN section 3). */
#define RP_ERT_RAY_STRIDE 4    /* one pre-pass ray per 4x4 pixels */
#define RP_ERT_COARSE_STEP 8.0f /* half a block, in voxels */

/* One frame's parameters, defaults resolved. The camera is rp__raygen in
 * float: ray through scaled-image pixel (x, y) has NDC
 * nu = 2 (x + 0.5) / width - 1, nv = 1 - 2 (y + 0.5) / height, then
 * perspective: org = eye, dir = normalize(f + nu*half_w*r + nv*half_h*u);
 * orthographic: org = eye + nu*half_w*r + nv*half_h*u, dir = f.
 * Voxel space: p = (org + t*min_spacing*dir) * inv_spacing + dims/2 - 0.5.
 */
typedef struct rp_frame_params {
  float eye[3], f[3], r[3], u[3];
  float half_w, half_h;    /* of the OUTPUT frustum */
  int32_t ortho;
  uint32_t width, height;  /* rays: the scaled image's pixels */
  float dims[3];
  float inv_spacing[3];
  float min_spacing;
  uint32_t idims[3];
  uint32_t blocks[3];      /* 16^3 block grid */
  float step;              /* Delta, voxels */
  float ref_step;          /* the TF's Delta_0 */
  float ert_threshold;
  uint32_t effects;        /* RP_EFFECT_* */
  float value_min, value_max; /* TF position x = (v - min) / (max - min) */
  uint32_t lut_size;
  uint32_t ert_seed, frame; /* ERT pre-pass random stream */
  /* The occupied blocks lie in [occupied_lo, occupied_end) along each
   * axis (an empty range when none is): with RP_EFFECT_SKIP the depth
   * pass may clip rays to that box rather than walk the whole grid. */
  uint32_t occupied_lo[3], occupied_end[3];
  /* Out-of-core (set_brick_pool): 0 when the volume is whole on the
   * device; else log2 of the brick size B, and the raycast reads voxel
   * (x, y, z) from slot table[brick] of the pool at (x mod B, y mod B,
   * z mod B) of its (B + 1)^3 stored voxels, with brick = x / B +
   * brick_grid[0] * (y / B + brick_grid[1] * (z / B)), for the low corner
   * (x, y, z) of each trilinear cell (so a cell never spans two bricks). */
  uint32_t brick_shift;
  uint32_t brick_grid[3];
  /* Out-of-core depth slabs (brick_shift != 0 only): a region whose
   * bricks do not fit the pool at once, even one tile, is cast in passes
   * over slabs of depth. A pass takes each ray's samples before
   * slab_cut (voxel units along the ray; +inf: to its end), resuming
   * where the previous pass left it (its colour, opacity, next sample,
   * samples and fetches so far, kept on the device per pixel of the
   * region) unless slab_flags has RP_SLAB_FIRST; only a pass with
   * RP_SLAB_LAST writes pixels and tile stats (and is read back). A
   * single pass is FIRST | LAST with slab_cut = +inf; the result is the
   * same bit for bit either way. */
  float slab_cut;
  uint32_t slab_flags;
  /* Ray-start jitter (rp_jitter): when `jitter` is 1, the raycast's ray
   * through pixel (x, y) of the scaled image samples at s + (j + i) *
   * step with j = rp_jitter_offset(x, y, jitter_seed), computed as
   * (s + j * step) + i * step; 0: j = 0. The depth pass and the ERT
   * pre-pass do not depend on them. \since 0.11 */
  uint32_t jitter;
  uint32_t jitter_seed;
} rp_frame_params;

#define RP_SLAB_FIRST 1u
#define RP_SLAB_LAST 2u

/* An out-of-core volume's pool (bricks.h): `slots` bricks of
 * (brick_size + 1)^3 voxels of `type`, and a table of one uint32 slot per
 * brick of grid[3]. */
typedef struct rp_brick_pool {
  rp_voxel_type type;
  uint32_t dims[3];
  uint32_t brick_size;
  uint32_t grid[3];
  uint32_t slots;
} rp_brick_pool;

/* One ambient-occlusion job (raypace_ao.h, backends/README.md): voxels
 * [lo, end) of the uploaded volume, under the uploaded TF's LUT. */
typedef struct rp_ao_job {
  uint32_t lo[3], end[3];
  uint32_t directions;     /* L */
  uint32_t samples;        /* M */
  float offset, step;      /* a and D = (R - a) / M, voxels */
  float ref_step;          /* the TF's Delta_0: alpha is corrected to step */
  float value_min, value_max; /* TF position x = (v - min) / (max - min) */
  uint32_t lut_size;
  const float *dirs;       /* L x 4 floats: (x, y, z, 0) per direction */
  /* One byte per 4^3 brick of the whole grid, x fastest (1: full), over
   * bricks[3] = ceil(dims / 4) per axis; NULL: every brick is full. A
   * voxel of an empty brick is written as 255 without sampling. */
  const uint8_t *bricks;
  uint32_t brick_grid[3];
} rp_ao_job;

typedef struct rp_backend_ops {
  void (*destroy)(void *impl);
  /* Voxels in their native type, x fastest. */
  int (*upload_volume)(void *impl, const rp_volume *vol);
  /* lut_size RGBA float entries (straight colour, alpha per ref step).
   * A backend with RP_EFFECT_PREINT keeps beside them the LUT's
   * pre-integration table (rp__preint_table, runtime/preint.c: the model
   * and the RP_PREINT_ALPHA_MAX clamp), derived from these entries. */
  int (*upload_tf)(void *impl, const float *lut, uint32_t lut_size);
  /* One byte per block (occupied), and 16 bytes per block (H-alpha). */
  int (*upload_occupancy)(void *impl, const uint8_t *grid,
                          const uint8_t *alpha_hist,
                          const uint32_t blocks[3]);
  /* Per ray of the scaled image, (D_front, D_back) in voxel units; a ray
   * that meets no occupied block (or misses) gets (+inf, -inf). Without
   * RP_EFFECT_SKIP: the box clip (max(t0, 0), t1). Result stays on the
   * device for raycast; copied to `front_back` (2 floats per ray) when
   * not NULL. */
  int (*depth_pass)(void *impl, const rp_frame_params *p,
                    float *front_back);
  /* Per pre-pass ray ((width + 3) / 4 x (height + 3) / 4), the estimated
   * termination depth, or +inf when the estimate never terminates. */
  int (*ert_prepass)(void *impl, const rp_frame_params *p, float *d_ert);
  /* Raycasts `region` using the last depth pass's result; writes the
   * region's RGBA8 pixels into `rgba` (width x height, premultiplied) and
   * the stats of its tiles into `tiles` (tiles_x x tiles_y of the scaled
   * image). `fetches`, when not NULL, receives per-tile volume fetch
   * counts (a variant built for counting; used by tests). */
  int (*raycast)(void *impl, const rp_frame_params *p, const rp_region *r,
                 uint8_t *rgba, rp_tile_stats *tiles, uint64_t *fetches);
  /* AO of job->lo .. job->end into `out` ((end - lo) product bytes, x
   * fastest). */
  int (*compute_ao)(void *impl, const rp_ao_job *job, uint8_t *out);
  /* The AO volume (one byte per voxel of the uploaded volume) raycasts
   * with RP_EFFECT_AO read; NULL releases it. */
  int (*upload_ao)(void *impl, const uint8_t *ao);
  /* Replaces the volume with an empty pool (the front end has checked
   * that it fits the device); NULL releases the pool. Raycasts with
   * p->brick_shift != 0 read through it. AO is not computed on a pool. */
  int (*set_brick_pool)(void *impl, const rp_brick_pool *pool);
  /* Writes `count` bricks (each (brick_size + 1)^3 voxels at voxels[i])
   * into slots[i], then the whole table (one uint32 per brick) unless
   * `table` is NULL. */
  int (*upload_bricks)(void *impl, uint32_t count, const uint32_t *slots,
                       const void *const *voxels, const uint32_t *table);
  /* Device time of the last operation, nanoseconds. The operations that
   * report one: upload_volume, upload_tf, upload_occupancy, depth_pass,
   * ert_prepass, raycast, compute_ao, upload_ao (not a release) and
   * upload_bricks. */
  uint64_t (*last_time_ns)(void *impl);
  /* Optional (NULL: kernels are built on first use only). Builds every
   * kernel variant a frame with `effects` may use on the volume uploaded
   * now (depth pass and raycast, for any step and image size; with
   * RP_EFFECT_AO, on a whole volume, also compute_ao's, which makes what
   * that raycast reads), so that they are found built. The one op that
   * may run on one thread while another thread runs any other op on the
   * same impl: it reads
   * only what is fixed at create, and what the volume upload sets under
   * the backend's lock; it adds what it built to the backend's table
   * under that lock, and only where the table has a free entry, never
   * evicting one and never allocating from the impl's context; and it
   * reports failures to `ctx`, the calling thread's context. Returns 0
   * when the kernels are built (kept, or dropped for want of room: the
   * frame then builds them itself), RP_ESTATE before any volume was
   * uploaded, RP_EBUILD or RP_ENOMEM/RP_EDEVICE when a build fails. */
  int (*prepare)(void *impl, rp_context *ctx, uint32_t effects);
  /* Optional: the backend's own simulated clock, nanoseconds, for a
   * backend whose device time is a model rather than a measurement (the
   * "test" backend, raypace_testing.h): it starts at 0 and advances by
   * each operation's reported time, so that whoever paces frames reads
   * the device's time rather than the host's. NULL: real time
   * (CLOCK_MONOTONIC). */
  uint64_t (*clock_ns)(void *impl);
} rp_backend_ops;

typedef struct rp_backend_bootstrap {
  const char *name;
  /* Number of devices usable here (0 when the driver is missing); never
   * fails loudly: probing is how selection skips absent drivers. */
  int (*probe)(rp_context *ctx, uint32_t *device_count);
  /* Opens device `index`; with compute_units > 0, a sub-device of that
   * many compute units (rp_device_desc), which the front end has checked
   * against partition_units. */
  int (*create)(rp_context *ctx, uint32_t index, uint32_t compute_units,
                const rp_backend_ops **ops, void **impl, rp_caps *caps);
  /* Optional (NULL: the backend cannot partition a device). The compute
   * units device `index` has to partition; RP_EUNSUPPORTED, with a
   * message, when that device cannot be partitioned. */
  int (*partition_units)(rp_context *ctx, uint32_t index,
                         uint32_t *compute_units);
} rp_backend_bootstrap;

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_BACKEND_H */
