/* Lab tier (README, "Headers"): public for research use, and may change
 * between minor versions. An app embedding the runtime needs none of it:
 * every setting it makes is declared in the product headers.
 *
 * raypace device groups: one frame rendered by several devices at once
 * (DESIGN section 7, milestone M6).
 *
 * A group opens its devices, gives each an owner (a worker thread with a
 * job queue), keeps a cost model per device (its sigma) and, per frame:
 *   shares from the models (rp_balance_shares, damped) -> each 8x8 tile's
 *   predicted cost from the probe's ray spans -> the kd-tree split
 *   (rp_balancer_split) of all but a tail of the image -> every device
 *   renders its region concurrently into a buffer of its own, then takes
 *   strips of the tail until none is left -> regions and strips are
 *   copied into one image.
 * A device that fails, or is still rendering past its deadline, is
 * dropped from the frame: the devices left re-render its region in the
 * same frame (the frame is late, never missing or corrupt) and the
 * shares re-converge over the devices left. A frame fails only when no
 * device is left. Dropped is not gone (rp_device_state, since 0.12): a
 * device late on a frame returns on probation once that work ends, at
 * most RP_GROUP_PROBATION_SHARE of the frame until it has been on time
 * for RP_GROUP_PROBATION_FRAMES frames in a row; a device that fails is
 * re-created after a back-off, and stays out after
 * RP_GROUP_MAX_FAILURES failures in a row. A device's first render of
 * an effect set since its volume upload (a kernel build) and a render
 * while its build lane builds have no deadline.
 *
 * A group of one device does exactly what that device alone does, on the
 * caller's thread.
 *
 * Threading: a group belongs to one thread at a time. Each device is
 * called only by its own worker (with two devices or more): the group's
 * uploads, render rounds and AO steps are jobs on it, and kernels built
 * ahead run on a second thread of the same owner, beside them. A device
 * given up on at its deadline keeps its worker busy until it finishes;
 * only destroy waits for that. */
#ifndef RAYPACE_GROUP_H
#define RAYPACE_GROUP_H

#include <stdint.h>

#include "raypace.h"
#include "raypace_ao.h"
#include "raypace_balance.h"
#include "raypace_pace.h"

#ifdef __cplusplus
extern "C" {
#endif

#define RP_GROUP_MAX_DEVICES 8
#define RP_GROUP_MAX_STRIPS 64

typedef struct rp_device_group rp_device_group;

/** How the shares are chosen each frame. */
typedef enum rp_share_mode {
  /* From each device's learned cost (its model's whole-frame raycast
   * time), w_i proportional to 1 / t_i, then damped. */
  RP_SHARES_DYNAMIC = 0,
  /* desc.fixed_shares every frame: a static split, the baseline the
   * dynamic one is measured against. */
  RP_SHARES_FIXED = 1
} rp_share_mode;

/** Zero fields take the defaults. */
typedef struct rp_group_desc {
  const rp_device_desc *devices; /* required, `count` of them */
  uint32_t count;                /* 1..RP_GROUP_MAX_DEVICES */
  rp_share_mode share_mode;
  const double *fixed_shares;    /* RP_SHARES_FIXED: `count` finite
                                    values >= 0, positive sum */
  rp_damping damping;            /* RP_SHARES_DYNAMIC; default smooth */
  double damp_rate;              /* in (0, 1]; 0: 0.5 */
  int split_by_count;            /* 1: the split ignores the predicted
                                    tile costs (every tile costs 1) */
  rp_cost_model_desc model;      /* every device's cost model */
  /* A device still rendering deadline_factor times its predicted time
   * (at least deadline_min_ms) after the frame's render began is given
   * up on, dropped for the frame and left to end its work; then it comes
   * back on probation (rp_device_state). A device yet without a model
   * has deadline_factor times its slowest peer's time. Never on a cold
   * render (a kernel build). deadline_factor 0: 4; negative: no
   * deadline.
   * deadline_min_ms 0: 200. */
  double deadline_factor;
  double deadline_min_ms;
  /* The tail: this fraction of the frame's predicted cost, a band of
   * tile rows at the bottom of the image cut into `tail_strips` strips
   * of equal predicted cost, is not split in advance: a device that
   * finishes its region takes the next strip, until none is left. A
   * device slowed for part of a frame (a descheduled thread, a clock
   * that drops) then costs the frame at most about one strip of its
   * time, where a split made before the frame would wait for all of it.
   * At most 0.5; 0: 0.15; negative: no tail (every pixel split in
   * advance). tail_strips 0: four per device; at most
   * RP_GROUP_MAX_STRIPS. A strip a device fails or runs late on goes to
   * the devices left; the region it finished is kept. */
  double tail_fraction;
  uint32_t tail_strips;
} rp_group_desc;

/** One device's part of a frame. */
typedef struct rp_group_device {
  char name[168];       /* backend:device */
  int status;           /* 0, or the RP_E* it failed with this frame (its
                           region was re-rendered by the others; or,
                           since 0.12, coming back at its start: its
                           re-creation or its uploads failed) */
  int dropped;          /* 1 while it has no share: from the frame it
                           failed or ran late on until it is back
                           (state) */
  int late;             /* 1 if it was given up on at its deadline */
  double share;         /* its share this frame, [0, 1] */
  double cost_share;    /* its region's fraction of the predicted tile
                           cost */
  rp_region region;     /* scaled-image pixels it was given; empty: none */
  double depth_ms;      /* its depth pass, wall (a device that keeps its
                           own clock, the test backend: on that clock,
                           as busy_ms; since 0.12); 0 when reused */
  uint32_t depth_passes; /* depth passes it ran (0 when reused) */
  double raycast_ms;    /* device time of its raycast */
  double upload_ms;     /* out of core: device time of the bricks it
                           uploaded first (not in raycast_ms) */
  double busy_ms;       /* its worker's wall time for the frame: depth
                           pass, raycast, readback; on its own clock
                           when it keeps one */
  uint64_t samples;     /* samples its region took */
  double predicted_ms;  /* its model's time for its region, NaN unknown */
  uint32_t strips;      /* tail strips it rendered (rp_group_desc) */
  double strip_cost_share; /* their fraction of the predicted tile cost */
  char error[256];      /* why it failed this frame (status != 0): its
                           own message, the device's context's; "" else */
  /* Where it stands after this frame; its failures in a row (RETRY and
   * OUT); in RETRY, the renders it still sits out before it is
   * re-created (0: at the next render). \since 0.12 */
  rp_device_state state;
  uint32_t failures;
  uint32_t retry_in;
} rp_group_device;

/** What a frame's render did, per device. */
typedef struct rp_group_report {
  uint32_t count;         /* devices in the group, dropped ones included */
  uint32_t alive;         /* devices not dropped after this frame
                             (active or on probation) */
  uint32_t lost;          /* devices dropped during this frame */
  uint32_t returned;      /* devices back on probation at its start (late
                             work ended, or re-created). \since 0.12 */
  double render_ms;       /* wall: dispatch to the last region in, the
                             re-render included */
  double rerender_ms;     /* wall spent re-rendering lost regions (0
                             when a lost strip was taken in the round) */
  double imbalance;       /* (max - min) / mean of the busy_ms of the
                             devices that rendered a region (first
                             round), rp_balance_metric */
  rp_group_device devices[RP_GROUP_MAX_DEVICES];
  /* The tail's strips (scaled-image pixels) and the device that rendered
   * each, in the first round; a strip no device finished there was
   * re-rendered with the lost regions (strip_device RP_GROUP_MAX_DEVICES). */
  uint32_t strip_count;
  rp_region strips[RP_GROUP_MAX_STRIPS];
  uint8_t strip_device[RP_GROUP_MAX_STRIPS];
} rp_group_report;

/** Opens every device (each with a context of its own, made from `ctx`'s
 *  description) and starts a worker per device, the device's one caller,
 *  when there are two or more. `ctx` is kept for the group's own messages.
 *  \returns 0, RP_EINVAL (a NULL argument, a bad field), RP_ERANGE,
 *  RP_ENOTFINITE, RP_ENODEV / RP_EDEVICE (a device would not open: the
 *  message names it), RP_ENOMEM. \since 0.1 */
RP_API int rp_device_group_create(rp_context *ctx, const rp_group_desc *desc,
                                  rp_device_group **out);
/** Joins the workers (waiting for a late device to finish) and closes the
 *  devices. NULL: no-op. \since 0.1 */
RP_API void rp_device_group_destroy(rp_device_group *g);

/** Devices in the group, and those not dropped (active or on
 *  probation). \since 0.1 */
RP_API uint32_t rp_device_group_count(const rp_device_group *g);
RP_API uint32_t rp_device_group_alive(const rp_device_group *g);
/** Device i's caps (i < count). \since 0.1 */
RP_API void rp_device_group_get_caps(const rp_device_group *g, uint32_t i,
                                     rp_caps *caps);

/** Uploads to every live device, concurrently. A device that fails is
 *  dropped; the call fails only when none is left (the message says
 *  why). \since 0.1 */
RP_API int rp_device_group_set_volume(rp_device_group *g,
                                      const rp_volume *vol);
RP_API int rp_device_group_set_tf(rp_device_group *g, const rp_tf *tf,
                                  const rp_occupancy *occ);
/** Builds the kernels a frame with `effects` will need on every live
 *  device (rp_device_prepare), each on a thread beside the device's
 *  worker (its build lane, started on its first build, at a lower
 *  priority), and returns at once; rp_device_group_prepared says
 *  when they are done. Asking again for a set asked for or done is
 *  free. A new volume (rp_device_group_set_volume) forgets what was
 *  asked and done: the kernels are built for its voxel type. 0 at once
 *  when no device builds ahead (the reference and MPI devices build on
 *  first use). \since 0.2 */
RP_API int rp_device_group_prepare(rp_device_group *g, uint32_t effects);
/** 1 once a preparation of `effects` asked for since the last volume
 *  upload has finished (a failed one included: the frame then builds
 *  the kernels itself and reports the error), or when no device builds
 *  ahead; 0 otherwise. \since 0.2 */
RP_API int rp_device_group_prepared(rp_device_group *g, uint32_t effects);

/** AO on every live device (raypace_ao.h): computed as rp_ao_compute
 *  would over the live devices, each device's jobs on its own worker
 *  (with one device, on the calling thread; a device lost doing it is
 *  dropped), and set for RP_EFFECT_AO renders
 *  (NULL releases every device's AO memory); the bytes they hold. Not
 *  while a frame is in flight. Without speeds in `schedule`, a static
 *  split takes each device's speed from the group's previous AO
 *  computation. \since 0.2 */
RP_API int rp_device_group_compute_ao(rp_device_group *g,
                                      const rp_ao_plan *plan,
                                      const rp_ao_schedule *schedule,
                                      rp_ao **out, rp_ao_report *report);
/** The same in steps (rp_ao_run_step between frames): begin picks the
 *  live devices and their learned speeds; end takes the run's status (0,
 *  or the error a step returned), finishes it when 0, drops the devices
 *  it lost and learns the others' speeds. The caller destroys the run.
 *  Only one run at a time per group. \since 0.2 */
RP_API int rp_device_group_ao_begin(rp_device_group *g,
                                    const rp_ao_plan *plan,
                                    const rp_ao_schedule *schedule,
                                    rp_ao_run **out);
RP_API int rp_device_group_ao_end(rp_device_group *g, rp_ao_run *run,
                                  int status, rp_ao **out,
                                  rp_ao_report *report);
RP_API int rp_device_group_set_ao(rp_device_group *g, const rp_ao *ao);
RP_API uint64_t rp_device_group_ao_bytes(const rp_device_group *g);

/** The shares the next frame renders with (`count` values, 0 for dropped
 *  devices), for a frame of probe `p` at (step, scale). \since 0.1 */
RP_API int rp_device_group_shares(rp_device_group *g,
                                  const rp_frame_probe *p, float step,
                                  float scale, double *shares);

/** Out of core: the time the live devices would spend uploading bricks
 *  before rendering `cam` and `desc` (rp_device_upload_estimate of the
 *  whole image times last frame's share; the largest), 0 in core. The
 *  runtime takes it off the render budget and adds it to the prediction,
 *  and training leaves measured uploads out of the cost models.
 *  \since 0.1 */
RP_API int rp_device_group_upload_ms(rp_device_group *g,
                                     const rp_camera *cam,
                                     const rp_render_desc *desc, double *ms);
/** The frame's predicted time at (step, scale) with those shares: the
 *  slowest device's launch + its share of its whole-frame raycast + its
 *  fixed cost c0. `out->ms` is that; the other fields are the fastest
 *  live device's. \since 0.1 */
RP_API int rp_device_group_predict(rp_device_group *g,
                                   const rp_frame_probe *p, float step,
                                   float scale, rp_cost_estimate *out);

/** Renders the scaled image of `desc` (rp_scaled_size) into `rgba`
 *  (scaled width x height RGBA8) and its tiles into `tiles` (may be
 *  NULL), split across the live devices. `probe` (may be NULL: split by
 *  tile count) must be for this camera and desc's width, height and
 *  effects; it gives each tile's predicted cost. `report` may be NULL.
 *  \returns 0 (some devices may have been lost: see the report), or the
 *  error of the last device when none is left, RP_EINVAL, RP_ENOMEM.
 *  \since 0.1 */
RP_API int rp_device_group_render(rp_device_group *g, const rp_camera *cam,
                                  const rp_render_desc *desc,
                                  const rp_frame_probe *probe, uint8_t *rgba,
                                  rp_tile_stats *tiles,
                                  rp_group_report *report);

/** Trains every device that rendered in the last frame on its own
 *  region: its samples and times scaled to the whole frame (its rate
 *  over its region, times the frame's samples), so that each model
 *  learns the device's cost of a whole frame. `frame_ms` is the caller's
 *  wall time for the frame's render (what the fixed cost c0 covers: the
 *  group's render plus whatever the caller adds, an upscale). Call once
 *  after rp_device_group_render with the same probe, step and scale.
 *  \returns 0, RP_ESTATE (no frame to learn from), or a model's error.
 *  \since 0.1 */
RP_API int rp_device_group_train(rp_device_group *g,
                                 const rp_frame_probe *p, float step,
                                 float scale, double frame_ms);

/** Tile costs from a probe's ray spans for the scaled image of `desc`
 *  (tiles_x * tiles_y floats, rp_tile_grid of rp_scaled_size): each
 *  tile's rays times (1 + L / step), L the span of the probe ray nearest
 *  the tile's centre. The +1 is a ray's own cost (set-up, depth lookup)
 *  in samples. \since 0.1 */
RP_API int rp_probe_tile_costs(const rp_frame_probe *p,
                               const rp_render_desc *desc, float *cost);

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_GROUP_H */
