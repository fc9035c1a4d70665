/* The frame engine: one synchronous frame, the only place a frame's
 * logic lives (DESIGN section 11).
 *
 * A frame: take the events -> recompute what they made stale (H, the
 * volume upload, H-alpha + occupancy, the TF upload, the AO step, the
 * probe) -> predict and tune (the controller) -> render on the device
 * group (split, dispatch, composite) -> measure. Training on the frame
 * runs apart, after the frame was delivered (rp__engine_train), so that
 * a driver delivers first and learns after, as an app's loop does.
 *
 * The engine knows nothing of loops or threads of its own: rp_runtime
 * (runtime.c) drives it from a libuv loop's worker, or from the caller's
 * thread in manual pacing (rp_runtime_step). Replay and every benchmark
 * drive that same runtime; none has a copy of what is here.
 *
 * Threading: one thread at a time calls the engine (the runtime hands it
 * from its loop to its worker); rp__engine_counters may be called from
 * any thread. */
#ifndef RP_FRAME_H
#define RP_FRAME_H

#include <stdint.h>

#include "raypace_runtime.h"

/* What the events between two frames ask for; the latest value of each
 * kind wins. Marks say which fields were posted. */
enum {
  RP__POSTED_VOLUME = 1u << 0,
  RP__POSTED_TF = 1u << 1,
  RP__POSTED_CAMERA = 1u << 2, /* camera or viewport */
  RP__POSTED_EFFECTS = 1u << 3,
  RP__POSTED_TARGET = 1u << 4,
  RP__POSTED_CONTROLLER = 1u << 5,
  RP__POSTED_DENSITY = 1u << 6
};

typedef struct rp__events {
  uint32_t marks;   /* RP__POSTED_* */
  rp_volume *vol;   /* owned; set only with RP__POSTED_VOLUME */
  rp_tf *tf;        /* owned copy; set only with RP__POSTED_TF */
  rp_camera cam;
  uint32_t width, height;
  double target_ms;
  uint32_t effects;
  rp_controller_kind controller;
  double density;
} rp__events;

/* Frees what the events own and clears them. */
void rp__events_drop(rp__events *ev);

typedef struct rp__engine rp__engine;
struct rp_device_group;

/* `desc` is the runtime's, defaults resolved (rp_runtime_create). The
 * engine opens the device group on `ctx`, which it uses from then on for
 * every message; the caller keeps `ctx` alive until destroy. */
int rp__engine_create(rp_context *ctx, const rp_runtime_desc *desc,
                      rp__engine **out);
void rp__engine_destroy(rp__engine *e);

/* One frame: takes `in`'s events (objects move into the engine; `in` is
 * left empty), then recomputes, predicts, tunes and renders. The frame,
 * failed or not, is in *out until the next call: its image (NULL when it
 * failed), stats and probe. `frame_no` numbers it (the ERT stream's
 * frame); `events` is the runtime's event count it includes. */
void rp__engine_frame(rp__engine *e, rp__events *in, uint64_t frame_no,
                      uint64_t events, rp_frame *out);

/* Trains the cost models on the last frame, once; the wall time it
 * took, 0 when the frame taught nothing (it failed, or was the first of
 * its effect set on the volume). */
double rp__engine_train(rp__engine *e);

/* The passes' counters (every field but events and frames), any
 * thread. */
void rp__engine_counters(rp__engine *e, rp_runtime_counters *out);

/* Time as the engine measures it, ms: the device's own clock when the
 * runtime's single device keeps one (the deterministic test backend),
 * else CLOCK_MONOTONIC. */
double rp__engine_now_ms(const rp__engine *e);

/* The engine's device group, so that a test can see what a frame asked
 * of it (rp_device_group_prepared); the runtime's: its engine's. Between
 * frames only, from the thread that steps them. */
struct rp_device_group *rp__engine_group(rp__engine *e);
struct rp_device_group *rp__runtime_group(rp_runtime *rt);

#endif /* RP_FRAME_H */
