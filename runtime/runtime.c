/* The runtime: events, pacing and delivery around the frame engine
 * (frame.c), DESIGN sections 1 and 11.
 *
 * Three kinds of thread touch a runtime on a loop, each with its own
 * data:
 * - any app thread posts events: they write `posted` under `lock`, then
 *   wake the loop (uv_async_send, which coalesces);
 * - the loop thread paces and schedules: it moves `posted` into the job
 *   at a frame's start, hands the job to the worker, and when the worker
 *   is done delivers the frame and trains the cost model;
 * - the worker thread runs the engine's frame.
 * One frame is in flight at a time, so the job, the image and the engine
 * pass between the loop and the worker without being shared: the
 * hand-over is `work_lock` (job_ready / job_done), which is also what
 * orders the memory (the uv_async only wakes the loop; libuv's own
 * signalling is not something ThreadSanitizer can see).
 *
 * Manual pacing has neither loop nor worker: rp_runtime_step takes the
 * posted events and runs the same engine frame on its caller's thread,
 * then delivers and trains in the same order as the loop does. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "ao.h"
#include "bounds.h"
#include "frame.h"
#include "internal.h"
#include "passes.h"
#include "raypace_pace.h"
#include "raypace_runtime.h"


struct rp_runtime {
  rp_context *ctx; /* the engine's; the setters use a scratch copy */
  rp_runtime_desc desc;
  rp__engine *engine; /* the worker's during a frame, the loop's between
                         frames (training); manual: the stepping
                         thread's */
  int manual;         /* RP_PACE_MANUAL: no loop, no worker */

  uv_loop_t *loop;
  uv_loop_t own_loop;
  int own;
  uv_thread_t loop_thread;
  uv_async_t wake, done;
  uv_timer_t pace;
  int handles_open;

  /* Guards posted, requests, closing, counters. */
  uv_mutex_t lock;
  rp__events posted;
  uint64_t requests;
  int closing;        /* no more events accepted */
  int close_asked;    /* own loop: rp_runtime_destroy is waiting */
  int have_vol, have_tf, have_cam; /* ever posted */
  rp_runtime_counters counters;    /* events and frames */

  /* Loop thread only (manual: the stepping thread's). */
  int in_flight, due, delivering, close_begun;
  double period_ms;
  double deadline;     /* timer pacing: when the next frame is due */
  double frame_start, handoff;
  double last_train_ms;
  rp_runtime_closed_cb closed_cb;
  void *closed_user;

  /* Worker hand-over, guarded by work_lock. */
  uv_mutex_t work_lock;
  uv_cond_t work_cv;
  int job_ready, job_done, quit;
  uv_thread_t worker;
  int worker_started;

  /* The job: written by the loop before hand-over, by the worker during
   * the frame, read by the loop after completion. */
  rp__events job_in;
  uint64_t job_events;
  uint64_t frame_no;
  double worker_begin, worker_end;
  rp_frame frame;
};

/* ---- Names --------------------------------------------------------------- */

const char *rp_pacing_name(rp_pacing pacing) {
  switch (pacing) {
  case RP_PACE_TIMER: return "timer";
  case RP_PACE_ON_REQUEST: return "on-request";
  case RP_PACE_MANUAL: return "manual";
  }
  return "unknown";
}

int rp_pacing_from_name(const char *name, rp_pacing *out) {
  if (name == NULL || out == NULL)
    return RP_EINVAL;
  if (strcmp(name, "timer") == 0)
    *out = RP_PACE_TIMER;
  else if (strcmp(name, "on-request") == 0)
    *out = RP_PACE_ON_REQUEST;
  else if (strcmp(name, "manual") == 0)
    *out = RP_PACE_MANUAL;
  else
    return RP_EINVAL;
  return 0;
}

/* ---- A frame, whoever drives it ------------------------------------------ */

/* Takes the posted events into the job when a frame may start: a volume,
 * a TF and a camera have been posted. Under `lock`. */
static int take_posted(rp_runtime *rt) {
  if (!(rt->have_vol && rt->have_tf && rt->have_cam))
    return 0;
  rt->job_in = rt->posted;
  rt->job_events = rt->counters.events;
  rt->posted.marks = 0;
  rt->posted.vol = NULL;
  rt->posted.tf = NULL;
  rt->requests = 0;
  return 1;
}

/* The engine's frame, on the worker (or the stepping thread). */
static void run_frame(rp_runtime *rt) {
  rt->worker_begin = rp__now_ms();
  rp__engine_frame(rt->engine, &rt->job_in, rt->frame_no, rt->job_events,
                   &rt->frame);
  rt->worker_end = rp__now_ms();
}

/* Completes the frame's stats as the driver knows them, counts it and
 * hands it to the app. `now`: delivery time. */
static void deliver(rp_runtime *rt, double now) {
  rp_frame_stats *st = (rp_frame_stats *)rt->frame.stats;
  rt->frame_no++;
  st->dispatch_ms = rt->manual ? 0.0
                               : (rt->worker_begin - rt->handoff) +
                                     (now - rt->worker_end);
  st->train_ms = rt->last_train_ms;
  st->total_ms = now - rt->frame_start;
  uv_mutex_lock(&rt->lock);
  rt->counters.frames++;
  uv_mutex_unlock(&rt->lock);
  rp_runtime_get_counters(rt, &st->counters);
  rt->delivering = 1;
  rt->desc.on_frame(rt, &rt->frame, rt->desc.user);
  rt->delivering = 0;
}

/* Training on the frame just delivered: on the loop thread (or the
 * stepping thread) between frames, never on the worker. */
static void train(rp_runtime *rt) {
  rt->last_train_ms = rp__engine_train(rt->engine);
}

int rp_runtime_step(rp_runtime *rt) {
  rp_context scratch;
  int ready;
  if (rt == NULL)
    return RP_EINVAL;
  memset(&scratch, 0, sizeof scratch);
  scratch.desc = rt->ctx->desc;
  if (!rt->manual || rt->delivering)
    return rp__fail(&scratch, RP_ESTATE, "rp_runtime_step: %s",
                    rt->manual ? "called from the frame callback"
                               : "the runtime is not in manual pacing");
  uv_mutex_lock(&rt->lock);
  ready = !rt->closing && take_posted(rt);
  uv_mutex_unlock(&rt->lock);
  if (!ready)
    return rp__fail(&scratch, RP_ESTATE, "rp_runtime_step: %s",
                    rt->closing ? "the runtime is being destroyed"
                                : "no frame before a volume, a transfer "
                                  "function and a camera are set");
  rt->frame_start = rp__now_ms();
  run_frame(rt);
  deliver(rt, rp__now_ms());
  train(rt);
  return rt->frame.stats->status;
}

static void worker_main(void *arg) {
  rp_runtime *rt = arg;
  uv_mutex_lock(&rt->work_lock);
  for (;;) {
    while (!rt->job_ready && !rt->quit)
      uv_cond_wait(&rt->work_cv, &rt->work_lock);
    if (!rt->job_ready)
      break;
    rt->job_ready = 0;
    uv_mutex_unlock(&rt->work_lock);
    run_frame(rt);
    uv_mutex_lock(&rt->work_lock);
    rt->job_done = 1;
    uv_async_send(&rt->done);
  }
  uv_mutex_unlock(&rt->work_lock);
}

/* ---- The loop thread ------------------------------------------------------ */

static void begin_close(rp_runtime *rt);
static void on_pace(uv_timer_t *t);

/* Starts a frame when one is wanted, none is in flight and the scene has
 * a volume, a TF and a camera. */
static void try_start(rp_runtime *rt) {
  int wanted, ready = 0;
  if (rt->in_flight || rt->close_begun)
    return;
  uv_mutex_lock(&rt->lock);
  wanted = rt->desc.pacing == RP_PACE_TIMER ? rt->due : rt->requests > 0;
  if (wanted)
    ready = take_posted(rt);
  uv_mutex_unlock(&rt->lock);
  if (!wanted || !ready)
    return;
  rt->due = 0;
  if (rt->job_in.marks & RP__POSTED_TARGET)
    rt->period_ms = rt->job_in.target_ms;
  rt->frame_start = rp__now_ms();
  if (rt->desc.pacing == RP_PACE_TIMER) {
    /* Deadlines advance by whole periods from the first frame, so the
     * millisecond rounding of uv timers does not accumulate; a frame that
     * starts after its successor's deadline moves the schedule, so a late
     * frame is followed by one frame at once, not by a burst. */
    double wait;
    rt->deadline = rt->deadline > 0.0 ? rt->deadline + rt->period_ms
                                      : rt->frame_start + rt->period_ms;
    if (rt->deadline < rt->frame_start)
      rt->deadline = rt->frame_start;
    wait = ceil(rt->deadline - rt->frame_start);
    uv_timer_start(&rt->pace, on_pace, (uint64_t)wait, 0);
  }
  rt->in_flight = 1;
  rt->handoff = rp__now_ms();
  uv_mutex_lock(&rt->work_lock);
  rt->job_ready = 1;
  uv_cond_signal(&rt->work_cv);
  uv_mutex_unlock(&rt->work_lock);
}

static void on_pace(uv_timer_t *t) {
  rp_runtime *rt = t->data;
  rt->due = 1;
  try_start(rt);
}

static void on_wake(uv_async_t *a) {
  rp_runtime *rt = a->data;
  int close_asked;
  uv_mutex_lock(&rt->lock);
  close_asked = rt->close_asked;
  uv_mutex_unlock(&rt->lock);
  if (close_asked) {
    begin_close(rt);
    return;
  }
  try_start(rt);
}

static void finish_close(rp_runtime *rt);

static void on_done(uv_async_t *a) {
  rp_runtime *rt = a->data;
  int done;
  uv_mutex_lock(&rt->work_lock);
  done = rt->job_done;
  rt->job_done = 0;
  uv_mutex_unlock(&rt->work_lock);
  if (!done)
    return;
  rt->in_flight = 0;
  if (rt->close_begun) {
    rt->frame_no++;
    finish_close(rt);
    return;
  }
  deliver(rt, rp__now_ms());
  if (rt->close_begun) {
    finish_close(rt);
    return;
  }
  train(rt);
  try_start(rt);
}

/* ---- Lifetime ------------------------------------------------------------ */

/* Everything but the handles and the loop, which are closed first. */
static void free_runtime(rp_runtime *rt) {
  rp_context *ctx = rt->ctx;
  rp__events_drop(&rt->posted);
  rp__events_drop(&rt->job_in);
  rp__engine_destroy(rt->engine);
  uv_mutex_destroy(&rt->lock);
  uv_mutex_destroy(&rt->work_lock);
  uv_cond_destroy(&rt->work_cv);
  rp__free(ctx, rt);
  rp_context_destroy(ctx);
}

static void on_handle_closed(uv_handle_t *h) {
  rp_runtime *rt = h->data;
  rp_runtime_closed_cb cb;
  void *user;
  if (--rt->handles_open > 0 || rt->own)
    return; /* own loop: rp_runtime_destroy frees after uv_run returns */
  cb = rt->closed_cb;
  user = rt->closed_user;
  free_runtime(rt);
  if (cb != NULL)
    cb(user);
}

/* The worker is idle (no frame in flight): stop it, close the handles. */
static void finish_close(rp_runtime *rt) {
  if (rt->in_flight || rt->delivering)
    return;
  uv_mutex_lock(&rt->work_lock);
  rt->quit = 1;
  uv_cond_signal(&rt->work_cv);
  uv_mutex_unlock(&rt->work_lock);
  if (rt->worker_started)
    uv_thread_join(&rt->worker);
  rt->worker_started = 0;
  rt->handles_open = 3;
  uv_close((uv_handle_t *)&rt->pace, on_handle_closed);
  uv_close((uv_handle_t *)&rt->wake, on_handle_closed);
  uv_close((uv_handle_t *)&rt->done, on_handle_closed);
}

static void begin_close(rp_runtime *rt) {
  if (rt->close_begun)
    return;
  rt->close_begun = 1;
  uv_mutex_lock(&rt->lock);
  rt->closing = 1;
  uv_mutex_unlock(&rt->lock);
  uv_timer_stop(&rt->pace);
  finish_close(rt); /* or on_done / after delivery does, later */
}

int rp_runtime_close(rp_runtime *rt, rp_runtime_closed_cb closed,
                     void *user) {
  if (rt == NULL)
    return RP_EINVAL;
  if (rt->own || rt->manual || rt->close_begun)
    return RP_ESTATE;
  rt->closed_cb = closed;
  rt->closed_user = user;
  begin_close(rt);
  return 0;
}

int rp_runtime_destroy(rp_runtime *rt) {
  uv_thread_t self;
  if (rt == NULL)
    return 0;
  if (rt->manual) {
    if (rt->delivering)
      return RP_ESTATE;
    free_runtime(rt);
    return 0;
  }
  self = uv_thread_self();
  if (!rt->own || uv_thread_equal(&self, &rt->loop_thread))
    return RP_ESTATE;
  uv_mutex_lock(&rt->lock);
  rt->close_asked = 1;
  rt->closing = 1;
  uv_async_send(&rt->wake);
  uv_mutex_unlock(&rt->lock);
  uv_thread_join(&rt->loop_thread);
  /* Every handle is closed: uv_run returned because none was left. */
  uv_loop_close(&rt->own_loop);
  free_runtime(rt);
  return 0;
}

static void loop_main(void *arg) {
  rp_runtime *rt = arg;
  uv_run(rt->loop, UV_RUN_DEFAULT);
}

/* A controller's starting density: finite and in the space's range. */
static int check_density(rp_context *ctx, const char *fn, const char *what,
                         const rp_space_desc *space, double rho) {
  double lo = rp_space_min_density(space), hi = rp_space_max_density(space);
  if (!isfinite(rho))
    return rp__fail(ctx, RP_ENOTFINITE, "%s: %s is %g", fn, what, rho);
  if (!(rho >= lo && rho <= hi))
    return rp__fail(ctx, RP_ERANGE, "%s: %s is %g; the %s space's "
                    "densities are [%g, %g]", fn, what, rho,
                    rp_space_name(space->space), lo, hi);
  return 0;
}

static int check_desc(rp_context *ctx, const rp_runtime_desc *d) {
  static const char fn[] = "rp_runtime_create";
  rp_ao_desc ao = {0};
  rp_ao_schedule sched;
  int err;
  if (d->on_frame == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->on_frame is NULL", fn);
  if (d->pacing != RP_PACE_TIMER && d->pacing != RP_PACE_ON_REQUEST &&
      d->pacing != RP_PACE_MANUAL)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->pacing is %d", fn,
                    (int)d->pacing);
  if (d->pacing == RP_PACE_MANUAL && d->loop != NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->loop is set, but manual "
                    "pacing runs frames in rp_runtime_step, on no loop",
                    fn);
  if ((int)d->controller < 0 || d->controller >= RP_CONTROL_COUNT)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->controller is %d", fn,
                    (int)d->controller);
  if (!isfinite(d->target_ms))
    return rp__fail(ctx, RP_ENOTFINITE, "%s: desc->target_ms is %g", fn,
                    d->target_ms);
  if (d->target_ms < 0.0 || d->target_ms > 60000.0)
    return rp__fail(ctx, RP_ERANGE, "%s: desc->target_ms is %g; must be "
                    "in (0, 60000] (0: 1000 / 60)", fn, d->target_ms);
  if (rp__check_image_size(ctx, fn, "rp_runtime_desc.width x height",
                           d->width != 0 ? d->width : 512,
                           d->height != 0 ? d->height : 512) != 0)
    return RP_ERANGE;
  if ((err = rp__space_check(ctx, fn, "rp_runtime_desc.space",
                             &d->space)) != 0)
    return err;
  if (d->effects & ~(uint32_t)RP__KNOWN_EFFECTS)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->effects has unknown bits "
                    "0x%x", fn, d->effects);
  if ((int)d->jitter < RP_JITTER_DEFAULT || d->jitter > RP_JITTER_FIXED)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->jitter is %d; must be "
                    "RP_JITTER_DEFAULT (0), RP_JITTER_ON (1), "
                    "RP_JITTER_OFF (2) or RP_JITTER_FIXED (3)", fn,
                    (int)d->jitter);
  if (d->device_count > RP_RUNTIME_MAX_DEVICES)
    return rp__fail(ctx, RP_ERANGE, "%s: %u devices; at most %d", fn,
                    d->device_count, RP_RUNTIME_MAX_DEVICES);
  if (d->device_count > 0 && d->devices == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->devices is NULL", fn);
  if (!isfinite(d->ao_frame_share))
    return rp__fail(ctx, RP_ENOTFINITE, "%s: desc->ao_frame_share is %g",
                    fn, d->ao_frame_share);
  if (d->ao_frame_share < 0.0 || d->ao_frame_share > 1.0)
    return rp__fail(ctx, RP_ERANGE, "%s: desc->ao_frame_share is %g; must "
                    "be in (0, 1] (0: 0.25)", fn, d->ao_frame_share);
  if (!isfinite(d->miss_rate))
    return rp__fail(ctx, RP_ENOTFINITE, "%s: desc->miss_rate is %g", fn,
                    d->miss_rate);
  if (d->miss_rate > 0.5)
    return rp__fail(ctx, RP_ERANGE, "%s: desc->miss_rate is %g; a share of "
                    "frames late, at most 0.5 (0: 0.05; negative: no "
                    "margin)", fn, d->miss_rate);
  if (!(d->headroom >= 0.0 && d->headroom <= 0.9))
    return rp__fail(ctx, isfinite(d->headroom) ? RP_ERANGE : RP_ENOTFINITE,
                    "%s: desc->headroom is %g; a share of the target kept "
                    "free, in [0, 0.9]", fn, d->headroom);
  if (d->density != 0.0 &&
      (err = check_density(ctx, fn, "desc->density", &d->space,
                           d->density)) != 0)
    return err;
  if ((err = rp__ao_desc_resolve(ctx, fn, &d->ao, &ao)) != 0 ||
      (err = rp__ao_schedule_resolve(ctx, fn, &d->ao_schedule, &sched)) != 0)
    return err;
  return 0;
}

/* An app loop's handles made before a failed create: the last one closed
 * frees the runtime (the loop still holds them until their callbacks). */
static void free_on_close(uv_handle_t *h) {
  rp_runtime *rt = h->data;
  if (--rt->handles_open == 0)
    free_runtime(rt);
}

/* Creates the three handles on rt->loop. On failure, closes those made
 * and frees the runtime: at once on our own loop, from the close
 * callbacks on the app's. */
static int init_handles(rp_runtime *rt) {
  uv_handle_t *made[2];
  int n = 0, i;
  rt->wake.data = rt->done.data = rt->pace.data = rt;
  uv_timer_init(rt->loop, &rt->pace); /* cannot fail */
  made[n++] = (uv_handle_t *)&rt->pace;
  if (uv_async_init(rt->loop, &rt->wake, on_wake) == 0) {
    made[n++] = (uv_handle_t *)&rt->wake;
    if (uv_async_init(rt->loop, &rt->done, on_done) == 0)
      return 0;
  }
  rt->handles_open = n;
  for (i = 0; i < n; i++)
    uv_close(made[i], rt->own ? NULL : free_on_close);
  if (rt->own) {
    uv_run(rt->loop, UV_RUN_NOWAIT);
    uv_loop_close(rt->loop);
    free_runtime(rt);
  }
  return RP_EDEVICE;
}

/* The desc with its defaults filled in (STYLE rule 3): no other code
 * tests a field for zero. */
static void resolve_desc(const rp_runtime_desc *in, rp_runtime_desc *d) {
  *d = *in;
  if (d->target_ms == 0.0)
    d->target_ms = 1000.0 / 60.0;
  if (d->width == 0)
    d->width = 512;
  if (d->height == 0)
    d->height = 512;
  if (d->ao_frame_share == 0.0)
    d->ao_frame_share = 0.25;
  if (d->ao_schedule.block == 0)
    d->ao_schedule.block = RP_AO_FRAME_BLOCK;
  if (d->jitter == RP_JITTER_DEFAULT)
    d->jitter = RP_JITTER_ON;
  if (d->jitter_seed == 0)
    d->jitter_seed = RP_JITTER_SEED;
}

/* The locks; on failure nothing is left made. */
static int init_locks(rp_runtime *rt) {
  if (uv_mutex_init(&rt->lock) != 0)
    return RP_EDEVICE;
  if (uv_mutex_init(&rt->work_lock) != 0) {
    uv_mutex_destroy(&rt->lock);
    return RP_EDEVICE;
  }
  if (uv_cond_init(&rt->work_cv) != 0) {
    uv_mutex_destroy(&rt->work_lock);
    uv_mutex_destroy(&rt->lock);
    return RP_EDEVICE;
  }
  return 0;
}

/* The loop (ours or the app's), its handles, the worker and, on our own
 * loop, the loop thread. On failure the runtime is freed (at once, or
 * from the app loop's close callbacks). */
static int start_loop(rp_context *ctx, rp_runtime *rt) {
  static const char fn[] = "rp_runtime_create";
  int err = 0;
  rt->own = rt->desc.loop == NULL;
  if (rt->own) {
    if (uv_loop_init(&rt->own_loop) != 0) {
      free_runtime(rt);
      return rp__fail(ctx, RP_EDEVICE, "%s: uv_loop_init failed", fn);
    }
    rt->loop = &rt->own_loop;
  } else {
    rt->loop = rt->desc.loop;
  }
  if ((err = init_handles(rt)) != 0)
    return rp__fail(ctx, err, "%s: libuv handle init failed", fn);
  if (uv_thread_create(&rt->worker, worker_main, rt) != 0) {
    err = RP_EDEVICE;
  } else {
    rt->worker_started = 1;
    if (rt->own && uv_thread_create(&rt->loop_thread, loop_main, rt) != 0)
      err = RP_EDEVICE;
  }
  if (err != 0) {
    /* Close as if the app had: the worker stops, handles close. */
    if (rt->own) {
      begin_close(rt);
      uv_run(rt->loop, UV_RUN_DEFAULT);
      uv_loop_close(rt->loop);
      free_runtime(rt);
    } else {
      begin_close(rt); /* frees from the handles' close callbacks */
    }
    return rp__fail(ctx, err, "%s: thread creation failed", fn);
  }
  return 0;
}

int rp_runtime_create(rp_context *ctx, const rp_runtime_desc *desc,
                      rp_runtime **out) {
  static const char fn[] = "rp_runtime_create";
  rp_context *own_ctx = NULL;
  rp_runtime *rt;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (desc == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: desc and out are required", fn);
  if ((err = check_desc(ctx, desc)) != 0)
    return err;
  if ((err = rp_context_create(&ctx->desc, &own_ctx)) != 0)
    return rp__fail(ctx, err, "%s: the runtime's context", fn);
  rt = rp__calloc(own_ctx, 1, sizeof *rt);
  if (rt == NULL) {
    rp_context_destroy(own_ctx);
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory", fn);
  }
  rt->ctx = own_ctx;
  resolve_desc(desc, &rt->desc);
  rt->manual = rt->desc.pacing == RP_PACE_MANUAL;
  rt->posted.target_ms = rt->period_ms = rt->desc.target_ms;
  rt->posted.width = rt->desc.width;
  rt->posted.height = rt->desc.height;
  rt->posted.effects = rt->desc.effects;
  rt->posted.controller = rt->desc.controller;
  rt->posted.density = rt->desc.density;
  rt->due = 1;
  if (init_locks(rt) != 0) {
    rp__free(own_ctx, rt);
    rp_context_destroy(own_ctx);
    return rp__fail(ctx, RP_EDEVICE, "%s: a mutex or condition variable "
                    "could not be made", fn);
  }
  /* From here on free_runtime undoes everything made so far. */
  if ((err = rp__engine_create(own_ctx, &rt->desc, &rt->engine)) != 0) {
    rp__fail(ctx, err, "%s: %s", fn, rp_last_error(own_ctx));
    free_runtime(rt);
    return err;
  }
  rt->desc.devices = NULL; /* the group copied them */
  if (!rt->manual && (err = start_loop(ctx, rt)) != 0)
    return err;
  *out = rt;
  return 0;
}

/* ---- Events --------------------------------------------------------------- */

/* Runs `apply` on the posted state under the lock unless the runtime is
 * closing, counts the event and wakes the loop. The wake-up is sent under
 * the lock so that close, which takes the lock to set `closing`, can
 * never race a send on a handle it is about to close. `apply` runs under
 * the lock too: it may only move values and free what it replaces. */
typedef void (*apply_fn)(rp_runtime *rt, const void *arg);

static int post(rp_runtime *rt, apply_fn apply, const void *arg,
                int request) {
  uv_mutex_lock(&rt->lock);
  if (rt->closing) {
    uv_mutex_unlock(&rt->lock);
    return RP_ESTATE;
  }
  if (apply != NULL) {
    apply(rt, arg);
    rt->counters.events++;
  }
  if (request)
    rt->requests++;
  if (!rt->manual)
    uv_async_send(&rt->wake);
  uv_mutex_unlock(&rt->lock);
  return 0;
}

/* A stack context carrying the runtime's allocator and logger: the
 * setters' messages go to the app's log without touching the worker's
 * context. */
static void scratch_context(const rp_runtime *rt, rp_context *c) {
  memset(c, 0, sizeof *c);
  c->desc = rt->ctx->desc;
}

static void apply_volume(rp_runtime *rt, const void *arg) {
  rp_volume *vol = (rp_volume *)arg, *old = rt->posted.vol;
  /* The runtime's context frees it from now on (same allocator). */
  vol->ctx = rt->ctx;
  rt->posted.vol = vol;
  rt->posted.marks |= RP__POSTED_VOLUME;
  rt->have_vol = 1;
  /* A volume posted and replaced before any frame took it: nobody else
   * has it, the caller gave it up. */
  rp_volume_destroy(old);
}

int rp_runtime_set_volume(rp_runtime *rt, rp_volume *vol) {
  rp_context scratch;
  if (rt == NULL || vol == NULL)
    return RP_EINVAL;
  scratch_context(rt, &scratch);
  if (memcmp(&vol->ctx->desc.allocator, &rt->ctx->desc.allocator,
             sizeof(rp_allocator)) != 0)
    return rp__fail(&scratch, RP_EINVAL, "rp_runtime_set_volume: the "
                    "volume's context has another allocator");
  return post(rt, apply_volume, vol, 0);
}

static void apply_tf(rp_runtime *rt, const void *arg) {
  rp_tf *old = rt->posted.tf;
  rt->posted.tf = (rp_tf *)arg;
  rt->posted.marks |= RP__POSTED_TF;
  rt->have_tf = 1;
  rp_tf_destroy(old);
}

int rp_runtime_set_tf(rp_runtime *rt, const rp_tf *tf) {
  rp_context scratch;
  rp_tf *copy = NULL;
  int err;
  if (rt == NULL || tf == NULL)
    return RP_EINVAL;
  /* Copied on the caller's thread: the allocator is malloc or the app's,
   * which must then be callable from the threads that post. */
  scratch_context(rt, &scratch);
  if ((err = rp__tf_clone(&scratch, tf, &copy)) != 0)
    return err;
  copy->ctx = rt->ctx;
  if ((err = post(rt, apply_tf, copy, 0)) != 0)
    rp_tf_destroy(copy);
  return err;
}

static void apply_camera(rp_runtime *rt, const void *arg) {
  rt->posted.cam = *(const rp_camera *)arg;
  rt->posted.marks |= RP__POSTED_CAMERA;
  rt->have_cam = 1;
}

int rp_runtime_set_camera(rp_runtime *rt, const rp_camera *cam) {
  rp_context scratch;
  int err;
  if (rt == NULL || cam == NULL)
    return RP_EINVAL;
  scratch_context(rt, &scratch);
  if ((err = rp__camera_check(&scratch, cam)) != 0)
    return err;
  return post(rt, apply_camera, cam, 0);
}

static void apply_viewport(rp_runtime *rt, const void *arg) {
  const uint32_t *wh = arg;
  rt->posted.width = wh[0];
  rt->posted.height = wh[1];
  rt->posted.marks |= RP__POSTED_CAMERA;
}

int rp_runtime_set_viewport(rp_runtime *rt, uint32_t width,
                            uint32_t height) {
  uint32_t wh[2];
  if (rt == NULL)
    return RP_EINVAL;
  /* No message: this may run on any thread, and ctx is the loop's. */
  if (rp__check_image_size(NULL, "rp_runtime_set_viewport",
                           "width x height", width, height) != 0)
    return RP_ERANGE;
  wh[0] = width;
  wh[1] = height;
  return post(rt, apply_viewport, wh, 0);
}

static void apply_target(rp_runtime *rt, const void *arg) {
  rt->posted.target_ms = *(const double *)arg;
  rt->posted.marks |= RP__POSTED_TARGET;
}

int rp_runtime_set_target(rp_runtime *rt, double target_ms) {
  if (rt == NULL)
    return RP_EINVAL;
  if (!isfinite(target_ms))
    return RP_ENOTFINITE;
  if (!(target_ms > 0.0) || target_ms > 60000.0)
    return RP_ERANGE;
  return post(rt, apply_target, &target_ms, 0);
}

static void apply_effects(rp_runtime *rt, const void *arg) {
  rt->posted.effects = *(const uint32_t *)arg;
  rt->posted.marks |= RP__POSTED_EFFECTS;
}

int rp_runtime_set_effects(rp_runtime *rt, uint32_t effects) {
  if (rt == NULL || effects & ~(uint32_t)RP__KNOWN_EFFECTS)
    return RP_EINVAL;
  return post(rt, apply_effects, &effects, 0);
}

static void apply_controller(rp_runtime *rt, const void *arg) {
  rt->posted.controller = *(const rp_controller_kind *)arg;
  rt->posted.marks |= RP__POSTED_CONTROLLER;
}

int rp_runtime_set_controller(rp_runtime *rt, rp_controller_kind kind) {
  if (rt == NULL || (int)kind < 0 || kind >= RP_CONTROL_COUNT)
    return RP_EINVAL;
  return post(rt, apply_controller, &kind, 0);
}

static void apply_density(rp_runtime *rt, const void *arg) {
  rt->posted.density = *(const double *)arg;
  rt->posted.marks |= RP__POSTED_DENSITY;
}

int rp_runtime_set_density(rp_runtime *rt, double density) {
  rp_context scratch;
  int err;
  if (rt == NULL)
    return RP_EINVAL;
  scratch_context(rt, &scratch);
  if ((err = check_density(&scratch, "rp_runtime_set_density", "density",
                           &rt->desc.space, density)) != 0)
    return err;
  return post(rt, apply_density, &density, 0);
}

int rp_runtime_request_frame(rp_runtime *rt) {
  if (rt == NULL)
    return RP_EINVAL;
  if (rt->desc.pacing != RP_PACE_ON_REQUEST)
    return RP_ESTATE;
  return post(rt, NULL, NULL, 1);
}

void rp_runtime_get_counters(rp_runtime *rt, rp_runtime_counters *out) {
  uint64_t events, frames;
  if (rt == NULL || out == NULL)
    return;
  uv_mutex_lock(&rt->lock);
  events = rt->counters.events;
  frames = rt->counters.frames;
  uv_mutex_unlock(&rt->lock);
  rp__engine_counters(rt->engine, out);
  out->events = events;
  out->frames = frames;
}
