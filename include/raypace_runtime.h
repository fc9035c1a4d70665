/* Product tier (README, "Headers"): the interface an app is supported on.
 *
 * raypace runtime: the frame pipeline an app embeds (DESIGN sections 1
 * and 11).
 *
 * An rp_runtime runs frames on a libuv loop -- the app's own (desc.loop),
 * or one the runtime makes and runs on a thread of its own (desc.loop
 * NULL) -- or, in manual pacing, on the caller's thread, one frame per
 * rp_runtime_step and no loop or thread at all. The app posts events --
 * volume, transfer function, camera, viewport, target, effects,
 * controller, density -- from any thread; each marks the derived data it
 * invalidates and the next frame recomputes only that:
 *
 *   volume      -> block histograms H, device upload, then as for a TF
 *   TF          -> H-alpha + occupancy, device upload, then as for a camera
 *   camera, viewport, ERT/skip toggled -> the probe (depth pass and ERT
 *                  pre-pass on the host, the cost model's input)
 *   AO turned on -> the AO volume, computed over the next frames in
 *   steps (desc.ao_frame_share of each), which render without AO until
 *   it is done; turned off -> the AO memory freed (with AO on, a volume
 *   or TF change recomputes it too)
 *   target, shading toggled, controller, density -> nothing derived
 *
 * Events between two frames coalesce: the latest value of each kind wins
 * and each recompute runs at most once per frame. A frame is: recompute
 * -> predict -> tune -> render (runtime/frame.c, the one place a frame's
 * logic lives, whichever pacing drives it); the frame is delivered to
 * the app's callback, and then the cost model trains on it. With a loop,
 * the frame runs on the runtime's worker thread and completion comes
 * back to the loop through a uv_async: the loop thread never waits on a
 * device.
 *
 * Thread safety, per function:
 * - rp_runtime_create: any thread; with desc.loop set, the loop must not
 *   be running on another thread at the time (libuv handle init is not
 *   thread-safe).
 * - rp_runtime_set_*, rp_runtime_request_frame: any thread, concurrently,
 *   until close or destroy begins; afterwards they return RP_ESTATE. The
 *   caller must stop calling them before the close callback (or destroy)
 *   returns: the runtime's memory is gone after that.
 * - rp_runtime_step (manual pacing): one thread at a time, not from the
 *   frame callback.
 * - rp_runtime_close: the loop's thread only (an app loop).
 * - rp_runtime_destroy: own loop: any thread but the runtime's loop
 *   thread; manual pacing: any thread, not during rp_runtime_step.
 * - The frame callback runs on the loop thread (manual pacing: inside
 *   rp_runtime_step, on its caller's thread). It may call the setters
 *   and rp_runtime_request_frame, and (app loop) rp_runtime_close.
 */
#ifndef RAYPACE_RUNTIME_H
#define RAYPACE_RUNTIME_H

#include <stdint.h>
#include <uv.h>

#include "raypace.h"
#include "raypace_ao.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct rp_runtime rp_runtime;

/** Who decides when a frame starts. */
typedef enum rp_pacing {
  /* The runtime starts a frame every target_ms (a uv_timer): one period
   * after the last frame began, or at once when that frame ran late. */
  RP_PACE_TIMER = 0,
  /* Each rp_runtime_request_frame starts one frame (VR compositors drive
   * frames themselves). Requests made while a frame is in flight
   * coalesce into the next one. */
  RP_PACE_ON_REQUEST = 1,
  /* No loop and no thread: each rp_runtime_step runs one frame on the
   * caller's thread and delivers it before returning (a test, a replay,
   * a benchmark, an app with a render loop of its own). desc.loop must
   * be NULL. \since 0.2 */
  RP_PACE_MANUAL = 2
} rp_pacing;

#define RP_RUNTIME_MAX_DEVICES 8

/** How many times each pass has run since the runtime was created:
 *  cumulative, so that the difference between two frames says what a
 *  frame recomputed. */
typedef struct rp_runtime_counters {
  uint64_t events;          /* set_* calls accepted */
  uint64_t histograms;      /* H builds (volume loaded) */
  uint64_t volume_uploads;
  uint64_t occupancies;     /* H-alpha + occupancy builds (TF changed) */
  uint64_t tf_uploads;
  uint64_t ao_computes;     /* AO volumes computed (AO on and the TF or
                               volume changed, or AO turned on) */
  uint64_t ao_bytes;        /* AO memory the devices hold now: 0 while
                               AO is off */
  uint64_t probes;          /* host depth pass + ERT pre-pass */
  uint64_t device_depth;    /* device depth passes */
  uint64_t renders;         /* render passes (two-pass frames count 2) */
  uint64_t frames;          /* frames delivered, failed ones included */
} rp_runtime_counters;

/** One device's share of a frame (summed over a two-pass frame's
 *  passes; share, region and status are the last pass's). */
typedef struct rp_device_frame {
  char name[168];       /* backend:device */
  double raycast_ms;    /* device time of the raycast kernel(s) */
  double upload_ms;     /* out of core: device time of brick uploads */
  double depth_ms;      /* device depth pass, wall; 0 when reused */
  double readback_ms;   /* its worker's wall time minus the raycast's
                           device time and the depth pass: enqueue and
                           copying its region back */
  double busy_ms;       /* its worker's wall time for the frame */
  uint32_t rows;        /* scaled-image rows its first-round region spans */
  uint64_t samples;     /* samples it took */
  double share;         /* its share of the work, [0, 1] */
  rp_region region;     /* scaled-image pixels it was given */
  uint32_t strips;      /* tail strips it took (rp_group_desc) */
  double strip_share;   /* their share of the frame's predicted cost */
  int status;           /* 0, or the RP_E* it was lost with */
  char error[256];      /* why, when status != 0; "" otherwise */
  int dropped;          /* 1 while it has no share: from the frame it
                           was lost in until it is back (state) */
  /* Where it stands after the frame, and its failures in a row
   * (rp_device_state: late devices come back on probation, failed ones
   * are re-created after a back-off and stay out after
   * RP_GROUP_MAX_FAILURES). \since 0.12 */
  rp_device_state state;
  uint32_t failures;
} rp_device_frame;

/** What a frame cost and what the runtime expected. Times in ms. */
typedef struct rp_frame_stats {
  uint64_t frame;          /* sequence number, from 0 */
  uint64_t events;         /* events this frame includes: the value of
                              counters.events when it started */
  int status;              /* 0, or the RP_E* the frame failed with */
  char error[256];         /* the message when status != 0 */
  rp_controller_kind controller;
  double target_ms;
  double predicted_ms;     /* what the frame was expected to take: the
                              time it had spent when the controller
                              decided (recompute, probe), earlier passes,
                              and the cost model's t' for its last pass
                              whatever the controller (only "predicted"
                              acts on it); NaN when the model has none */
  double measured_ms;      /* the frame on the worker, wall: recompute,
                              probe, decision and every render pass. The
                              target is held on it: the render passes get
                              the target minus what the frame had spent
                              before them (at least a quarter of it), and
                              the controller and the cost model learn
                              the passes alone */
  double delta;            /* measured / predicted - 1 (NaN if none) */
  double rho;              /* sampling density rendered */
  float step, scale;       /* its step (voxels) and image scale */
  uint32_t jitter_seed;    /* the ray-start jitter's seed it rendered
                              with (rp_render_desc.jitter_seed); 0: jitter
                              off. \since 0.11 */
  uint32_t passes;         /* render passes (2 when two-pass re-rendered) */
  uint32_t effects;        /* RP_EFFECT_* rendered */
  uint32_t effects_wanted; /* the scene's (rp_runtime_set_effects). The
                              frame renders fewer while AO is being
                              computed, and the last frame's while the
                              kernels of a set not rendered before on
                              this volume are built on the devices'
                              build lanes, beside their rendering
                              (rp_device_group_prepare); the first
                              frame on a volume builds its own.
                              \since 0.2 */
  uint64_t samples;        /* samples the raycast took (tile sums) */
  /* The render passes alone, summed: the part of measured_ms the
   * controller's budget is for and the cost model learns. \since 0.2 */
  double render_ms;
  /* The cost model's view of the last pass (NaN when it had none): its
   * time t' (the part of predicted_ms that is the model's), the samples
   * it expected (S' kappa), the volume fetches per sample (k) and the
   * cost per fetch (sigma); then the pass's raycast time as the model
   * reads it (device time; with several devices, the fastest device's
   * rate times the frame's samples) and the time the models learn from
   * (the pass, without brick uploads when it had some; NaN when the
   * frame teaches nothing, see train_ms). \since 0.2 */
  double pass_predicted_ms;
  /* The predicted controller's log-margin m: the frame was aimed at
   * target * exp(-m) so that its share of late frames holds to
   * rp_runtime_desc.miss_rate; 0 for the other controllers. \since 0.3 */
  double margin;
  /* How new the frame was to the cost model (rp_cost_estimate.novelty)
   * when the controller decided: ~0 on a scene it learned, 1 far from
   * all it saw. The predicted controller keeps the residuals of novel
   * frames apart (rp_controller_set_novelty). \since 0.3 */
  double novelty;
  double samples_predicted, fetches, sigma_predicted_ns;
  double raycast_ms, learn_ms;
  /* Per stage. Zero when the stage did not run for this frame. */
  double histograms_ms;    /* H build */
  double volume_upload_ms;
  double occupancy_ms;     /* H-alpha + occupancy */
  double tf_upload_ms;
  double ao_ms;            /* AO plan, its step this frame and upload */
  double ao_progress;      /* AO being computed: the fraction done after
                              this frame's step (the frame rendered
                              without AO unless it reached 1); 0 when
                              no AO was being computed */
  double probe_ms;         /* host depth pass + ERT pre-pass */
  double predict_ms;       /* the controller's decision (tune and every
                              prediction it made) and the prediction
                              reported above */
  double upscale_ms;       /* the scaled image to the output size */
  double upload_ms;        /* out of core: bricks uploaded before the
                              render passes (the device that spent the
                              most); its prediction, made before the
                              controller decides and taken off the
                              passes' budget, is upload_predicted_ms
                              (also in predicted_ms) */
  double upload_predicted_ms;
  double train_ms;         /* training on the PREVIOUS frame: it runs
                              after that frame was delivered. Zero when
                              that frame taught nothing: it failed, or
                              was the first with its effect set since the
                              volume was uploaded (a kernel variant's
                              build is not what frames cost) */
  double dispatch_ms;      /* loop -> worker hand-off and worker -> loop
                              completion, wall */
  double total_ms;         /* frame start on the loop to delivery */
  uint32_t device_count;    /* devices the runtime opened */
  uint32_t devices_alive;   /* not lost, after this frame */
  uint32_t devices_lost;    /* lost during this frame: their regions
                               were re-rendered by the others */
  double rerender_ms;       /* wall spent on those re-renders */
  double imbalance;         /* (max - min) / mean of the devices' busy
                               times (seed 001 section 6); 0 with one */
  rp_device_frame devices[RP_RUNTIME_MAX_DEVICES];
  rp_runtime_counters counters; /* as of this frame's delivery */
} rp_frame_stats;

/** A delivered frame. `rgba` (premultiplied RGBA8, width x height, the
 *  viewport) and `stats` are valid during the callback only. `rgba` is
 *  NULL when stats->status != 0. */
/* What the cost model reads of a frame (lab tier, raypace_pace.h). */
struct rp_frame_probe;

typedef struct rp_frame {
  const uint8_t *rgba;
  uint32_t width, height;
  const rp_frame_stats *stats;
  /* What the cost model predicted the frame from (the host's depth pass
   * and ERT pre-pass; its fields are in the lab header raypace_pace.h);
   * NULL when the frame failed.
   * \since 0.2 */
  const struct rp_frame_probe *probe;
} rp_frame;

typedef void (*rp_frame_cb)(rp_runtime *rt, const rp_frame *frame,
                            void *user);
typedef void (*rp_runtime_closed_cb)(void *user);

/** Zero fields take the defaults. */
typedef struct rp_runtime_desc {
  uv_loop_t *loop;        /* the app's loop; NULL: the runtime's own loop
                             on its own thread */
  rp_device_desc device;  /* which device renders (device_count 0) */
  /* Several devices rendering each frame together (DESIGN section 7,
   * raypace_group.h): device_count of them, at most
   * RP_RUNTIME_MAX_DEVICES; copied. 0: `device` alone. */
  const rp_device_desc *devices;
  uint32_t device_count;
  rp_damping damping;     /* how the devices' shares move per frame */
  rp_pacing pacing;
  rp_frame_cb on_frame;   /* required */
  void *user;
  rp_controller_kind controller; /* 0: RP_CONTROL_NONE; see
                             rp_runtime_set_controller */
  /* The density before the first frame (rp_controller_desc.rho_start):
   * RP_CONTROL_NONE renders it every frame, the others start from it.
   * 0: 1, clamped to the space's range; else within the space's range
   * (rp_space_min_density and rp_space_max_density, raypace_pace.h). See
   * rp_runtime_set_density. \since 0.2 */
  double density;
  /* RP_CONTROL_PREDICTED's deadline contract: the share of frames
   * allowed over their target (rp_controller_desc.miss_rate, DESIGN
   * section 12); each frame is aimed under the target by a margin the
   * controller learns (rp_frame_stats.margin). In (0, 0.5]; 0: 0.05;
   * negative: no margin, frames aimed at the target itself. \since 0.3 */
  double miss_rate;
  /* The reactive controllers' headroom (rp_controller_desc.headroom): the
   * share of the target they keep free; 0: each rule's own. For research
   * comparisons at equal miss rates. \since 0.3 */
  double headroom;
  double target_ms;       /* 0: 1000 / 60 */
  uint32_t width, height; /* viewport; 0: 512 x 512 */
  uint32_t effects;       /* RP_EFFECT_*; 0: none */
  rp_space_desc space;    /* where quality is traded; zero: ray space
                             with its defaults */
  rp_cost_model_desc model; /* zero: defaults */
  uint32_t ert_seed;      /* ERT pre-pass random stream */
  /* Ray-start jitter (rp_render_desc.jitter); 0: on. Frame n renders
   * with seed rp_jitter_frame_seed(jitter_seed, n), so that the jitter's
   * noise differs from frame to frame and averages out over frames; the
   * seed each frame used is in rp_frame_stats.jitter_seed;
   * RP_JITTER_FIXED: jitter_seed itself in every frame. \since 0.11 */
  rp_jitter jitter;
  uint32_t jitter_seed;   /* 0: RP_JITTER_SEED. \since 0.11 */
  rp_ao_desc ao;          /* ambient occlusion (RP_EFFECT_AO); zero:
                             defaults */
  rp_ao_schedule ao_schedule; /* how AO is spread over the devices; its
                             progress callback runs on the runtime's
                             worker thread; block 0:
                             RP_AO_FRAME_BLOCK */
  /* While AO is being computed (turned on, or the volume or TF changed
   * with it on) each frame spends this share of the target on it and
   * renders without AO until it is done, so that the frame rate holds;
   * 1: all of it in the first frame (which then runs late). 0: 0.25. */
  double ao_frame_share;
} rp_runtime_desc;

/** Creates the runtime, opens its device and starts its worker thread
 *  (and, with desc.loop NULL, its loop thread; in manual pacing neither:
 *  frames run inside rp_runtime_step). The runtime keeps its own
 *  context, made from `ctx`'s description (allocator, logger, threads):
 *  `ctx` is only used for this call's error message. Nothing renders until
 *  a volume, a TF and a camera have been set.
 *  \returns 0, RP_EINVAL (a NULL argument, no on_frame, a bad field),
 *  RP_ENOTFINITE, RP_ENODEV (no device), RP_ENOMEM, RP_EDEVICE (a
 *  libuv call failed). \since 0.1 */
RP_API int rp_runtime_create(rp_context *ctx, const rp_runtime_desc *desc,
                             rp_runtime **out);

/** App loop only, on the loop thread: stops pacing, lets a frame in
 *  flight finish without delivering it, joins the worker, closes the
 *  handles and frees everything; then calls `closed(user)` (may be NULL)
 *  from the loop. Calling it twice, or on an own-loop or manual runtime,
 *  returns RP_ESTATE. \since 0.1 */
RP_API int rp_runtime_close(rp_runtime *rt, rp_runtime_closed_cb closed,
                            void *user);

/** Own loop, from any thread but the runtime's loop thread: as
 *  rp_runtime_close, then stops the loop thread; returns when all is
 *  freed. Manual pacing: frees everything at once (not during a step).
 *  NULL: no-op. Returns RP_ESTATE (and does nothing) on an app loop or
 *  from the loop thread. \since 0.1 */
RP_API int rp_runtime_destroy(rp_runtime *rt);

/* ---- Events: any thread. Each returns 0, RP_ESTATE after close began,
 * or the error named; a refused event changes nothing. ---------------- */

/** The volume to render. On success the runtime owns `vol` (the caller
 *  must not use or destroy it); on failure the caller keeps it. `vol`
 *  must come from a context with the same allocator as the runtime's.
 *  RP_EINVAL otherwise or when NULL. \since 0.1 */
RP_API int rp_runtime_set_volume(rp_runtime *rt, rp_volume *vol);
/** The transfer function: copied, the caller keeps `tf`. RP_EINVAL when
 *  NULL, RP_ENOMEM. \since 0.1 */
RP_API int rp_runtime_set_tf(rp_runtime *rt, const rp_tf *tf);
/** Copied. RP_EINVAL when NULL or when rp_render_reference would refuse
 *  it: a NaN or infinite field, eye == center, fov outside
 *  [RP_FOV_MIN_DEG, RP_FOV_MAX_DEG] (\since 0.12; (0, 180) before), a
 *  negative ortho_height (the message goes to the context's logger).
 *  The bounds that depend on the volume (RP_CAMERA_DISTANCE_MAX,
 *  RP_ORTHO_HEIGHT_MIN/MAX) fail the frame instead. \since 0.1 */
RP_API int rp_runtime_set_camera(rp_runtime *rt, const rp_camera *cam);
/** Output size, 1..RP_IMAGE_MAX_DIM (16384) each and at most
 *  RP_IMAGE_MAX_PIXELS in all (\since 0.12); RP_ERANGE otherwise.
 *  \since 0.1 */
RP_API int rp_runtime_set_viewport(rp_runtime *rt, uint32_t width,
                                   uint32_t height);
/** Frame-time target, ms, finite and in (0, 60000] (RP_ENOTFINITE,
 *  RP_ERANGE). In timer pacing it is also the frame period. \since 0.1 */
RP_API int rp_runtime_set_target(rp_runtime *rt, double target_ms);
/** RP_EFFECT_* bits (RP_EINVAL for unknown bits; a device that lacks
 *  one fails the frames that use it, with the reason). A set not yet
 *  rendered on the volume shows once its kernels are built, frames
 *  rendering the last set meanwhile (rp_frame_stats.effects_wanted).
 *  \since 0.1 */
RP_API int rp_runtime_set_effects(rp_runtime *rt, uint32_t effects);
/** Changes the controller; its history starts afresh, the cost model
 *  keeps what it learned. RP_EINVAL for an unknown kind. \since 0.1 */
RP_API int rp_runtime_set_controller(rp_runtime *rt,
                                     rp_controller_kind kind);
/** The controller's starting density (rp_runtime_desc.density): what
 *  RP_CONTROL_NONE renders from the next frame on, as an app with a
 *  fixed quality setting wants; the controller starts afresh as with
 *  rp_runtime_set_controller. RP_ENOTFINITE, RP_ERANGE outside the
 *  space's [min, max] density. \since 0.2 */
RP_API int rp_runtime_set_density(rp_runtime *rt, double density);
/** On-request pacing: asks for one frame. RP_ESTATE in timer pacing.
 *  \since 0.1 */
RP_API int rp_runtime_request_frame(rp_runtime *rt);

/** Manual pacing: runs one frame now, on the calling thread, with the
 *  events posted since the last one; delivers it to desc.on_frame before
 *  returning, then trains the cost model on it. Returns the frame's
 *  status (0, or the RP_E* it failed with: the callback got it too);
 *  RP_ESTATE, with nothing run, in another pacing mode, from the frame
 *  callback, after destroy began, or before a volume, a TF and a camera
 *  were set (the message goes to the context's logger). \since 0.2 */
RP_API int rp_runtime_step(rp_runtime *rt);

/** The counters as of now (any thread). \since 0.1 */
RP_API void rp_runtime_get_counters(rp_runtime *rt,
                                    rp_runtime_counters *out);

/** "timer", "on-request", "manual"; RP_EINVAL for an unknown name.
 *  \since 0.1 */
RP_API const char *rp_pacing_name(rp_pacing pacing);
RP_API int rp_pacing_from_name(const char *name, rp_pacing *out);

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_RUNTIME_H */
