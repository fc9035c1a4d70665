/* Product tier (README, "Headers"): the interface an app is supported on.
 *
 * raypace ambient occlusion (DESIGN section 8, seed 004).
 *
 * Local ambient occlusion per voxel, computed only when a scene asks for
 * it and stored as an 8-bit volume the raycast reads with one extra fetch
 * per visible sample (RP_EFFECT_AO). Its form here, for voxel v at voxel
 * centre x_v and direction d_l (l = 0 .. L-1, even on the sphere):
 *
 *   step  D = (R - a) / M,   sample m at p_m = x_v + (a + m D) d_l,
 *         m = 0 .. M-1, in voxel units (index space)
 *   alpha_m = opacity of the TF at p_m (trilinear value, the raycast's
 *             classification), corrected from the TF's reference step to D;
 *             0 outside the volume's box [-0.5, dims - 0.5]
 *   I_l   = (1/M) sum_{m=1..M} prod_{i<m} (1 - alpha_i)
 *   AO(v) = (1/L) sum_l I_l,  stored as floor(AO * 255 + 0.5)
 *
 * 255 is unoccluded. Seed 004's Eq. 3 sums m = 0 .. M, whose m = 0 term is
 * always 1/M: an unoccluded voxel would get 1 + 1/M. We drop that term, so
 * I_l is the mean transmittance after each of the M samples, in [0, 1].
 *
 * Bricking (seed 004 section 4): the grid is cut into 4^3 bricks. A brick
 * is full when the TF has opacity above 0 anywhere in the value range of
 * its voxels and a one-voxel overlap around them; only voxels of full
 * bricks are computed, the others are stored as 255. The overlap is what
 * keeps the image free of seams: every trilinear cell a visible sample
 * interpolates has all eight corners in full bricks, so the raycast never
 * reads a skipped voxel and a bricked AO volume renders exactly as an
 * unbricked one.
 */
#ifndef RAYPACE_AO_H
#define RAYPACE_AO_H

#include <stdint.h>

#include "raypace.h"

#ifdef __cplusplus
extern "C" {
#endif

#define RP_AO_BRICK 4            /* brick edge, voxels */
#define RP_AO_MAX_DIRECTIONS 256
#define RP_AO_MAX_SAMPLES 256
#define RP_AO_MAX_RADIUS 256.0f  /* voxels */

typedef struct rp_ao_desc {
  uint32_t directions; /* L; 0: 8; at most RP_AO_MAX_DIRECTIONS */
  uint32_t samples;    /* M per direction; 0: 16; at most
                          RP_AO_MAX_SAMPLES */
  float radius;        /* R in voxels; 0: 8; at most RP_AO_MAX_RADIUS */
  float offset;        /* a in voxels, in (0, R); 0: 1 (seed 004's) */
  int unbricked;       /* 1: compute every voxel (seed 004's reference
                          time); 0: skip the voxels of empty bricks */
} rp_ao_desc;

/** Direction l of L (even on the sphere: a Fibonacci spiral), as the
 *  float vector every backend uses:
 *  z = 1 - (2 l + 1) / L, r = sqrt(1 - z^2), phi = l * pi * (3 - sqrt 5),
 *  d = (r cos phi, r sin phi, z), evaluated in double and rounded. */
RP_API void rp_ao_direction(uint32_t l, uint32_t count, float d[3]);

/** Progress of a long computation: `fraction` done, in [0, 1], from the
 *  calling thread; called at least once with 1 on success. */
typedef void (*rp_progress_fn)(double fraction, void *user);

/* rp_ao (raypace.h): an AO volume, one byte per voxel of the volume it
 * was computed for, for one transfer function. */

/** The scalar C reference: computes AO for `vol` under `tf` on ctx's
 *  worker threads, in double. `desc` may be NULL (all defaults);
 *  `progress` may be NULL. \since 0.2 */
RP_API int rp_ao_compute_reference(rp_context *ctx, const rp_volume *vol,
                                   const rp_tf *tf, const rp_ao_desc *desc,
                                   rp_progress_fn progress, void *user,
                                   rp_ao **out);
RP_API void rp_ao_destroy(rp_ao *ao);
/** The AO values (x fastest, the volume's dims) and their count. */
RP_API const uint8_t *rp_ao_data(const rp_ao *ao, uint32_t dims[3]);
/** The desc it was computed with, defaults resolved. */
RP_API void rp_ao_get_desc(const rp_ao *ao, rp_ao_desc *desc);
/** Bricks the computation took (full ones; all of them unbricked) and
 *  bricks in the grid. */
RP_API void rp_ao_bricks(const rp_ao *ao, uint64_t *computed,
                         uint64_t *total);

/** What a computation needs before any voxel is computed: the desc with
 *  defaults resolved, the directions, and (bricked) the brick mask of
 *  `tf` on `vol`, built on ctx's worker threads. The plan keeps neither
 *  `vol` nor `tf`. \since 0.2 */
typedef struct rp_ao_plan rp_ao_plan;
RP_API int rp_ao_plan_create(rp_context *ctx, const rp_volume *vol,
                             const rp_tf *tf, const rp_ao_desc *desc,
                             rp_ao_plan **out);
RP_API void rp_ao_plan_destroy(rp_ao_plan *plan);
/** Full bricks among the bricks that overlap voxels [lo, end) (all of
 *  them unbricked): seed 004's cost of computing that block. O(1). */
RP_API uint64_t rp_ao_plan_full_bricks(const rp_ao_plan *plan,
                                       const uint32_t lo[3],
                                       const uint32_t end[3]);

/** Computes AO for voxels [lo, end) of the device's volume under its
 *  transfer function, which must be the ones the plan was made for
 *  (RP_ESTATE otherwise), into `out` ((end - lo) product bytes, x
 *  fastest). The unit the distribution schemes hand out. \since 0.2 */
RP_API int rp_device_compute_ao(rp_device *dev, const rp_ao_plan *plan,
                                const uint32_t lo[3], const uint32_t end[3],
                                uint8_t *out);

/** Uploads an AO volume for RP_EFFECT_AO renders; NULL releases the
 *  device's AO memory. A render with RP_EFFECT_AO needs one computed for
 *  the device's current volume and transfer function (RP_ESTATE
 *  otherwise). \since 0.2 */
RP_API int rp_device_set_ao(rp_device *dev, const rp_ao *ao);
/** Bytes the device holds for AO (0 when none is set). */
RP_API uint64_t rp_device_ao_bytes(const rp_device *dev);

/* ---- Across devices (seed 004 section 5) ------------------------------ */

#define RP_AO_MAX_DEVICES 16
/* Dynamic block edge for AO computed in steps between frames (the
 * runtime's default, raypace replay's): small enough that one job fits
 * a frame's share of the target on bonsai-sized volumes (about 2.5 ms
 * per 16^3 block on one PoCL core); a whole computation is faster with
 * the default 32. */
#define RP_AO_FRAME_BLOCK 16

typedef enum rp_ao_scheme {
  /* Fixed-size blocks in a queue that idle devices take from; blocks
   * without a full brick are filled on the host and never queued. */
  RP_AO_DYNAMIC = 0,
  /* A BSP split along the longest axis into one block per device, each
   * splitting plane then moved, top down, by the difference of the full
   * bricks on its two sides (per unit of speed) until balanced or out of
   * time. */
  RP_AO_STATIC = 1,
  /* The same BSP split into volumes in proportion to speed (equal by
   * default), planes never moved. */
  RP_AO_STATIC_NAIVE = 2
} rp_ao_scheme;

typedef struct rp_ao_schedule {
  rp_ao_scheme scheme;
  uint32_t block;      /* dynamic: block edge in voxels, a multiple of 4;
                          0: 32 */
  double balance_ms;   /* static: time limit for moving planes; 0: 100
                          (seed 004's) */
  double tolerance;    /* static: a plane is balanced when the full bricks
                          per device on its sides differ by at most this
                          share of the smaller side; 0: 0.02 */
  /* static: each device's relative speed (full bricks per ms, or any
   * unit common to all); planes are placed and moved so that each device
   * gets bricks in proportion to it. 0: 1 (alike, seed 004's). The
   * previous computation's report gives it: full_bricks / busy_ms. */
  double speed[RP_AO_MAX_DEVICES];
  rp_progress_fn progress; /* may be NULL; called on the calling thread */
  void *user;
} rp_ao_schedule;

/** Where a computation's time went (seed 004 Table 1's columns). */
typedef struct rp_ao_report {
  double total_ms;      /* wall, from the call to the assembled volume */
  double balance_ms;    /* static: moving the planes */
  double min_ms, max_ms; /* over devices that took work: compute wall */
  uint32_t device_count;
  struct {
    double busy_ms;     /* its thread's wall time computing */
    uint64_t voxels;    /* voxels of the blocks it computed */
    uint64_t full_bricks; /* full bricks overlapping them */
    uint32_t jobs;      /* blocks (or slabs of its block) it computed */
    uint32_t block_lo[3], block_end[3]; /* static: its BSP block */
    int status;         /* 0, or the RP_E* it failed with: its work went
                           to the others */
  } devices[RP_AO_MAX_DEVICES];
} rp_ao_report;

/** Computes AO over `count` devices, each holding the plan's volume and
 *  transfer function (rp_device_set_volume, rp_device_set_tf), one thread
 *  per device (the run's: see rp_ao_run_create); the result is assembled
 *  on the host. A device that fails
 *  has its remaining work taken by the others; only when every device
 *  fails does the call fail, with the first device's error. `sched` and
 *  `report` may be NULL; the report is filled on failure too. Each
 *  device needs a context of its own. \since 0.2 */
RP_API int rp_ao_compute(rp_context *ctx, rp_device *const *devices,
                         uint32_t count, const rp_ao_plan *plan,
                         const rp_ao_schedule *sched, rp_ao **out,
                         rp_ao_report *report);

/** The same computation in steps, for a frame loop that must not stall:
 *  each step computes jobs for about `budget_ms` of wall time (a device
 *  takes a further job only when its mean job time so far ends before
 *  the budget does; its first job of a step it always takes, so a step
 *  overruns by at most one job, and every step makes progress), then
 *  returns with the fraction of jobs done. INFINITY runs to the end. The
 *  devices and the plan must stay as they are (same volume and TF) until
 *  the run is finished or destroyed; between steps they are free for
 *  rendering. A run owns a worker thread per device, made by create and
 *  joined by destroy: during a step each device is called from its worker
 *  only, and progress is reported on the thread calling the step. rp_ao_run_finish hands over the AO volume once every job
 *  is done (RP_ESTATE before). \since 0.2 */
typedef struct rp_ao_run rp_ao_run;
RP_API int rp_ao_run_create(rp_context *ctx, rp_device *const *devices,
                            uint32_t count, const rp_ao_plan *plan,
                            const rp_ao_schedule *sched, rp_ao_run **out);
RP_API int rp_ao_run_step(rp_ao_run *run, double budget_ms,
                          double *fraction);
RP_API int rp_ao_run_finish(rp_ao_run *run, rp_ao **out,
                            rp_ao_report *report);
/** What the devices did so far (after a failed step: which failed). */
RP_API void rp_ao_run_report(const rp_ao_run *run, rp_ao_report *report);
RP_API void rp_ao_run_destroy(rp_ao_run *run);

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_AO_H */
