/* The frame pipeline on a libuv loop (DESIGN section 1).
 *
 * Three kinds of thread touch a runtime, each with its own data:
 * - any app thread posts events: they write `posted` under `lock`, then
 *   wake the loop (uv_async_send, which coalesces);
 * - the loop thread paces and schedules: it moves `posted` into the job
 *   at a frame's start, hands the job to the worker, and when the worker
 *   is done delivers the frame and trains the cost model;
 * - the worker thread owns the scene (volume, H, TF, occupancy, device,
 *   controller, probe) and runs a frame: recompute what is stale, probe,
 *   predict, tune, render.
 * One frame is in flight at a time, so the job, the image and the cost
 * model pass between the loop and the worker without being shared: the
 * hand-over is `work_lock` (job_ready / job_done), which is also what
 * orders the memory (the uv_async only wakes the loop; libuv's own
 * signalling is not something ThreadSanitizer can see). */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "ao.h"
#include "internal.h"
#include "passes.h"
#include "raypace_group.h"
#include "raypace_runtime.h"

/* What an event marks; posted by the setters, consumed per frame. */
enum {
  POSTED_VOLUME = 1u << 0,
  POSTED_TF = 1u << 1,
  POSTED_CAMERA = 1u << 2, /* camera or viewport */
  POSTED_EFFECTS = 1u << 3,
  POSTED_TARGET = 1u << 4,
  POSTED_CONTROLLER = 1u << 5
};

/* Derived data that is out of date, on the worker. A stage clears its bit
 * only when it succeeds, so a frame that fails half-way leaves the rest
 * for the next frame to retry. */
enum {
  STALE_HISTOGRAMS = 1u << 0,
  STALE_VOLUME_UPLOAD = 1u << 1,
  STALE_OCCUPANCY = 1u << 2,
  STALE_TF_UPLOAD = 1u << 3,
  STALE_PROBE = 1u << 4,
  STALE_CONTROLLER = 1u << 5,
  STALE_AO = 1u << 6 /* the AO volume, or (AO off) its memory */
};

#define MAX_VIEWPORT 16384u /* per axis, as the header states */

/* The latest value of each kind of event. */
typedef struct posted_state {
  uint32_t marks;   /* POSTED_* since the last frame started */
  rp_volume *vol;   /* owned; set only with POSTED_VOLUME */
  rp_tf *tf;        /* owned copy; set only with POSTED_TF */
  rp_camera cam;
  uint32_t width, height;
  double target_ms;
  uint32_t effects;
  rp_controller_kind controller;
} posted_state;

/* The worker's scene. */
typedef struct scene {
  uint32_t stale;
  rp_volume *vol;
  rp_histograms *h;
  rp_tf *tf;
  rp_occupancy *occ;
  rp_camera cam;
  uint32_t width, height, effects;
  double target_ms;
  rp_controller_kind controller_kind;
  rp_controller *controller;
  rp_frame_probe probe;
  /* Effect sets rendered since the volume was uploaded, bit (1 << set):
   * a set's first frame builds its kernel variant and allocates, a cost
   * the model must not learn as if every frame paid it. */
  uint32_t warm_sets;
  /* What this frame renders (choose_effects), and what the last frame
   * rendered, valid while warm_sets != 0. */
  uint32_t render_effects, shown_effects;
  /* AO being computed in steps (RP_EFFECT_AO on and not yet ready):
   * frames render without AO until the run finishes. */
  rp_ao_plan *ao_plan;
  rp_ao_run *ao_run;
  int ao_ready;  /* the devices hold AO for the current volume and TF */
  int ao_waits;  /* the run's first step waits for the builder to build
                    the AO kernels (rp_device_group_prepare) */
} scene;

/* What the cost model trains on after delivery. */
typedef struct training {
  int valid;
  rp_frame_probe probe;
  float step, scale;
  double pass_ms;
} training; /* valid: 0 for a failed frame and a cold one (warm_sets) */

struct rp_runtime {
  rp_context *ctx; /* the worker's, and the loop's between frames */
  rp_runtime_desc desc;
  rp_space_desc space;
  /* The devices, their cost models and the split (one device: exactly
   * that device). The worker's during a frame, the loop's between
   * frames (training). */
  rp_device_group *group;

  uv_loop_t *loop;
  uv_loop_t own_loop;
  int own;
  uv_thread_t loop_thread;
  uv_async_t wake, done;
  uv_timer_t pace;
  int handles_open;

  /* Guards posted, requests, closing, counters. */
  uv_mutex_t lock;
  posted_state posted;
  uint64_t requests;
  int closing;        /* no more events accepted */
  int close_asked;    /* own loop: rp_runtime_destroy is waiting */
  int have_vol, have_tf, have_cam; /* ever posted */
  rp_runtime_counters counters;

  /* Loop thread only. */
  int in_flight, due, delivering, close_begun;
  double period_ms;
  double deadline;     /* timer pacing: when the next frame is due */
  double frame_start, handoff;
  double last_train_ms;
  training train;
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
  posted_state job_in;
  uint64_t job_events;
  uint64_t frame_no;
  double worker_begin, worker_end;
  rp_frame_stats stats;
  uint8_t *scaled, *image;
  size_t scaled_cap, image_cap;
  rp_tile_stats *tiles;
  size_t tiles_cap;
  const uint8_t *out_rgba;
  uint32_t out_w, out_h;
  training job_train;

  scene s; /* worker only */
};

/* ---- Names --------------------------------------------------------------- */

const char *rp_pacing_name(rp_pacing pacing) {
  switch (pacing) {
  case RP_PACE_TIMER: return "timer";
  case RP_PACE_ON_REQUEST: return "on-request";
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
  else
    return RP_EINVAL;
  return 0;
}

/* ---- The worker: one frame ----------------------------------------------- */

static void count(rp_runtime *rt, uint64_t *field) {
  uv_mutex_lock(&rt->lock);
  (*field)++;
  uv_mutex_unlock(&rt->lock);
}

/* Takes the events the job carries into the scene and marks what they
 * invalidate. Objects move; nothing here can fail. */
static void take_events(rp_runtime *rt) {
  scene *s = &rt->s;
  posted_state *in = &rt->job_in;
  if (in->marks & POSTED_VOLUME) {
    rp_occupancy_destroy(s->occ);
    rp_histograms_destroy(s->h);
    rp_volume_destroy(s->vol);
    s->occ = NULL;
    s->h = NULL;
    s->vol = in->vol;
    in->vol = NULL;
    s->stale |= STALE_HISTOGRAMS | STALE_VOLUME_UPLOAD | STALE_OCCUPANCY |
                STALE_TF_UPLOAD | STALE_AO | STALE_PROBE;
  }
  if (in->marks & POSTED_TF) {
    rp_tf_destroy(s->tf);
    s->tf = in->tf;
    in->tf = NULL;
    s->stale |= STALE_OCCUPANCY | STALE_TF_UPLOAD | STALE_AO | STALE_PROBE;
  }
  if (in->marks & POSTED_CAMERA) {
    s->cam = in->cam;
    s->width = in->width;
    s->height = in->height;
    s->stale |= STALE_PROBE;
  }
  if (in->marks & POSTED_EFFECTS) {
    /* The probe follows in choose_effects, which knows what renders. */
    if ((s->effects ^ in->effects) & RP_EFFECT_AO)
      s->stale |= STALE_AO;
    s->effects = in->effects;
  }
  if (in->marks & POSTED_TARGET)
    s->target_ms = in->target_ms;
  if (in->marks & POSTED_CONTROLLER &&
      in->controller != s->controller_kind) {
    s->controller_kind = in->controller;
    s->stale |= STALE_CONTROLLER;
  }
  in->marks = 0;
}

/* The effects a frame should render: the scene's, without AO while it
 * is being computed. */
static uint32_t wanted_effects(const scene *s) {
  return s->ao_ready ? s->effects : s->effects & ~(uint32_t)RP_EFFECT_AO;
}

/* The effects this frame renders: those wanted, unless their kernels are
 * still being built ahead (a build takes from tens of milliseconds to
 * over a second): then what the last frame rendered, so that no frame
 * waits for a build. The first frame on a volume builds its own, and so
 * does a frame that has nothing to fall back on (the last set used AO,
 * which is off or being computed now). */
static void choose_effects(rp_runtime *rt) {
  scene *s = &rt->s;
  uint32_t want = wanted_effects(s), eff = want;
  int can_wait = s->warm_sets != 0 &&
                 (!(s->shown_effects & RP_EFFECT_AO) || s->ao_ready);
  if (can_wait && !((s->warm_sets >> want) & 1u) &&
      !rp_device_group_prepared(rt->group, want) &&
      rp_device_group_prepare(rt->group, want) == 0)
    eff = s->shown_effects;
  /* Every effect is in the probe: ERT cuts the spans, skipping moves
   * D_front and D_back, shading and AO set k and the visible blocks. */
  if (eff != s->render_effects)
    s->stale |= STALE_PROBE;
  s->render_effects = eff;
}

static void drop_ao_run(scene *s) {
  rp_ao_run_destroy(s->ao_run);
  rp_ao_plan_destroy(s->ao_plan);
  s->ao_run = NULL;
  s->ao_plan = NULL;
}

static void publish_ao_bytes(rp_runtime *rt) {
  uint64_t bytes = rp_device_group_ao_bytes(rt->group);
  uv_mutex_lock(&rt->lock);
  rt->counters.ao_bytes = bytes;
  uv_mutex_unlock(&rt->lock);
}

/* A volume, TF or AO toggle: any run in progress is for the old scene and
 * goes. AO on: a run starts for the current volume and TF, and frames
 * render without AO until it is done (advance_ao). AO off: the devices'
 * AO memory is released, so an effect that is off costs neither time
 * nor memory. */
static int update_ao(rp_runtime *rt) {
  scene *s = &rt->s;
  int err = 0;
  drop_ao_run(s);
  s->ao_ready = 0;
  s->ao_waits = 0;
  if (!(s->effects & RP_EFFECT_AO)) {
    if (rp_device_group_ao_bytes(rt->group) != 0)
      err = rp_device_group_set_ao(rt->group, NULL);
  } else {
    /* AO's kernels (the AO volume's and the raycast that reads it) on
     * the builder: the run starts once they are built, and the frame AO
     * is ready in renders with them at once; no frame builds one. */
    s->ao_waits = rp_device_group_prepare(rt->group, s->effects) == 0 &&
                  !rp_device_group_prepared(rt->group, s->effects);
    err = rp_ao_plan_create(rt->ctx, s->vol, s->tf, &rt->desc.ao,
                            &s->ao_plan);
    if (err == 0)
      err = rp_device_group_ao_begin(rt->group, s->ao_plan,
                                     &rt->desc.ao_schedule, &s->ao_run);
    if (err != 0)
      drop_ao_run(s);
  }
  publish_ao_bytes(rt);
  return err;
}

/* One step of the AO run: ao_frame_share of the target (all of it at
 * once with share 1); the render passes then get what is left of the
 * target, as after any stage. When the run is done its AO goes to every
 * device and frames render with it from this one on. */
static int advance_ao(rp_runtime *rt) {
  scene *s = &rt->s;
  rp_frame_stats *st = &rt->stats;
  double budget = rt->desc.ao_frame_share >= 1.0
                      ? INFINITY
                      : rt->desc.ao_frame_share * s->target_ms;
  double fraction = 0.0;
  rp_ao *ao = NULL;
  int err;
  if (s->ao_waits) {
    st->ao_progress = 0.0;
    if (!rp_device_group_prepared(rt->group, s->effects))
      return 0;
    s->ao_waits = 0;
  }
  err = rp_ao_run_step(s->ao_run, budget, &fraction);
  st->ao_progress = fraction;
  if (err == 0 && fraction < 1.0)
    return 0;
  err = rp_device_group_ao_end(rt->group, s->ao_run, err, &ao, NULL);
  if (err == 0)
    err = rp_device_group_set_ao(rt->group, ao);
  rp_ao_destroy(ao);
  drop_ao_run(s);
  publish_ao_bytes(rt);
  if (err != 0) {
    /* Tried again from the start next frame: a lost device is dropped
     * by now, and the others may finish it. */
    s->stale |= STALE_AO;
    return err;
  }
  s->ao_ready = 1;
  count(rt, &rt->counters.ao_computes);
  return 0;
}

/* Runs the stale stages in dependency order: H, then the volume upload,
 * then H-alpha + occupancy, the TF upload, and the probe. */
static int recompute(rp_runtime *rt) {
  scene *s = &rt->s;
  rp_frame_stats *st = &rt->stats;
  double t0;
  int err;
  if (s->stale & STALE_HISTOGRAMS) {
    t0 = rp__now_ms();
    if ((err = rp_histograms_build(rt->ctx, s->vol, &s->h)) != 0)
      return err;
    st->histograms_ms = rp__now_ms() - t0;
    s->stale &= ~(uint32_t)STALE_HISTOGRAMS;
    count(rt, &rt->counters.histograms);
  }
  if (s->stale & STALE_VOLUME_UPLOAD) {
    t0 = rp__now_ms();
    if ((err = rp_device_group_set_volume(rt->group, s->vol)) != 0)
      return err;
    st->volume_upload_ms = rp__now_ms() - t0;
    s->warm_sets = 0;
    s->stale &= ~(uint32_t)STALE_VOLUME_UPLOAD;
    count(rt, &rt->counters.volume_uploads);
  }
  if (s->stale & STALE_OCCUPANCY) {
    t0 = rp__now_ms();
    err = s->occ == NULL ? rp_occupancy_build(rt->ctx, s->h, s->tf, &s->occ)
                         : rp_occupancy_update(s->occ, s->tf);
    if (err != 0)
      return err;
    st->occupancy_ms = rp__now_ms() - t0;
    s->stale &= ~(uint32_t)STALE_OCCUPANCY;
    count(rt, &rt->counters.occupancies);
  }
  if (s->stale & STALE_TF_UPLOAD) {
    t0 = rp__now_ms();
    if ((err = rp_device_group_set_tf(rt->group, s->tf, s->occ)) != 0)
      return err;
    st->tf_upload_ms = rp__now_ms() - t0;
    s->stale &= ~(uint32_t)STALE_TF_UPLOAD;
    count(rt, &rt->counters.tf_uploads);
  }
  if (s->stale & STALE_AO || s->ao_run != NULL) {
    t0 = rp__now_ms();
    if (s->stale & STALE_AO) {
      s->stale &= ~(uint32_t)STALE_AO;
      if ((err = update_ao(rt)) != 0)
        return err;
    }
    if (s->ao_run != NULL && (err = advance_ao(rt)) != 0)
      return err;
    st->ao_ms = rp__now_ms() - t0;
  }
  choose_effects(rt);
  if (s->stale & STALE_PROBE) {
    rp_render_desc d = {0};
    d.width = s->width;
    d.height = s->height;
    d.effects = s->render_effects;
    if ((err = rp_frame_probe_compute(rt->ctx, s->vol, s->tf, s->occ,
                                      &s->cam, &d, rt->desc.ert_seed,
                                      (uint32_t)rt->frame_no,
                                      &s->probe)) != 0)
      return err;
    st->probe_ms = s->probe.probe_ms;
    s->stale &= ~(uint32_t)STALE_PROBE;
    count(rt, &rt->counters.probes);
  }
  if (s->stale & STALE_CONTROLLER || s->controller == NULL) {
    rp_controller_desc cd = {0};
    rp_controller *c = NULL;
    cd.kind = s->controller_kind;
    cd.rho_min = rp_space_min_density(&rt->space);
    cd.rho_max = rp_space_max_density(&rt->space);
    if ((err = rp_controller_create(rt->ctx, &cd, &c)) != 0)
      return err;
    rp_controller_destroy(s->controller);
    s->controller = c;
    s->stale &= ~(uint32_t)STALE_CONTROLLER;
  }
  return 0;
}

/* The controller's model of the frame: `user` is the runtime. */
static double predict_at(void *user, double rho) {
  rp_runtime *rt = user;
  rp_cost_estimate e;
  float step, scale;
  rp_space_map(&rt->space, rho, &step, &scale);
  if (rp_device_group_predict(rt->group, &rt->s.probe, step, scale, &e) != 0)
    return NAN;
  return e.ms;
}

/* Grows *buf to hold `bytes`; keeps the old one on failure. */
static int reserve(rp_runtime *rt, void **buf, size_t *cap, size_t bytes) {
  void *p;
  if (bytes <= *cap)
    return 0;
  p = rp__malloc(rt->ctx, bytes);
  if (p == NULL)
    return rp__fail(rt->ctx, RP_ENOMEM, "runtime: %zu bytes for the frame",
                    bytes);
  rp__free(rt->ctx, *buf);
  *buf = p;
  *cap = bytes;
  return 0;
}

/* One render pass at density rho: every device's depth pass when its
 * inputs changed, the raycast of its region with readback, and the
 * upscale. */
static int render_pass(rp_runtime *rt, double rho, double *pass_ms) {
  scene *s = &rt->s;
  rp_frame_stats *st = &rt->stats;
  rp_render_desc d = {0};
  rp_group_report rep;
  uint32_t sw, sh, tx, ty, i;
  double t0 = rp__now_ms(), t2, pass_upload = 0.0;
  int err, depth = 0;
  rp_space_map(&rt->space, rho, &st->step, &st->scale);
  d.width = s->width;
  d.height = s->height;
  d.step = st->step;
  d.image_scale = st->scale;
  d.effects = s->render_effects;
  rp_scaled_size(&d, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  if ((err = reserve(rt, (void **)&rt->scaled, &rt->scaled_cap,
                     (size_t)sw * sh * 4)) != 0 ||
      (err = reserve(rt, (void **)&rt->image, &rt->image_cap,
                     (size_t)s->width * s->height * 4)) != 0 ||
      (err = reserve(rt, (void **)&rt->tiles, &rt->tiles_cap,
                     (size_t)tx * ty * sizeof(rp_tile_stats))) != 0)
    return err;
  err = rp_device_group_render(rt->group, &s->cam, &d, &s->probe,
                               rt->scaled, rt->tiles, &rep);
  t2 = rp__now_ms();
  /* Per device, whatever happened: a lost device is part of the story. */
  st->device_count = rep.count;
  st->devices_alive = rep.alive;
  st->devices_lost += rep.lost;
  st->imbalance = rep.imbalance;
  st->rerender_ms += rep.rerender_ms;
  for (i = 0; i < rep.count && i < RP_RUNTIME_MAX_DEVICES; i++) {
    rp_device_frame *df = &st->devices[i];
    const rp_group_device *gd = &rep.devices[i];
    snprintf(df->name, sizeof df->name, "%s", gd->name);
    df->raycast_ms += gd->raycast_ms;
    df->upload_ms += gd->upload_ms;
    df->depth_ms += gd->depth_ms;
    df->busy_ms += gd->busy_ms;
    df->readback_ms +=
        gd->busy_ms - gd->raycast_ms - gd->upload_ms - gd->depth_ms;
    if (gd->upload_ms > pass_upload)
      pass_upload = gd->upload_ms;
    df->rows += gd->region.y1 - gd->region.y0;
    df->samples += gd->samples;
    df->share = gd->share;
    df->region = gd->region;
    df->strips = gd->strips;
    df->strip_share = gd->strip_cost_share;
    df->status = gd->status;
    if (gd->status != 0)
      snprintf(df->error, sizeof df->error, "%s", gd->error);
    df->dropped = gd->dropped;
    depth |= gd->depth_passes > 0;
  }
  st->upload_ms += pass_upload;
  if (depth)
    count(rt, &rt->counters.device_depth);
  if (err != 0)
    return err;
  count(rt, &rt->counters.renders);
  st->samples = 0;
  for (i = 0; i < tx * ty; i++)
    st->samples += rt->tiles[i].samples;
  if (sw != s->width || sh != s->height) {
    rp_image_upscale(rt->scaled, sw, sh, rt->image, s->width, s->height);
    rt->out_rgba = rt->image;
    st->upscale_ms += rp__now_ms() - t2;
  } else {
    rt->out_rgba = rt->scaled;
  }
  rt->out_w = s->width;
  rt->out_h = s->height;
  rt->job_train.valid = (s->warm_sets >> s->render_effects) & 1u;
  s->warm_sets |= 1u << s->render_effects;
  s->shown_effects = s->render_effects;
  rt->job_train.probe = s->probe;
  rt->job_train.step = st->step;
  rt->job_train.scale = st->scale;
  *pass_ms = rp__now_ms() - t0;
  rt->job_train.pass_ms = *pass_ms;
  /* The controller holds the passes to a budget the predicted upload
   * was already taken off. */
  *pass_ms = fmax(*pass_ms - pass_upload, 0.0);
  return 0;
}

/* Out of core: the predicted brick uploads of the coming render (0 in
 * core, or when the estimate fails: the frame then only runs late). */
static double predicted_upload_ms(rp_runtime *rt) {
  scene *s = &rt->s;
  rp_render_desc d = {0};
  double ms = 0.0;
  d.width = s->width;
  d.height = s->height;
  d.effects = s->render_effects;
  if (rp_device_group_upload_ms(rt->group, &s->cam, &d, &ms) != 0)
    return 0.0;
  return ms;
}

/* The least share of the target a frame's render passes are given when
 * its recompute and probe already used more: the budget stays positive,
 * and one slow recompute (a volume load) does not drop the density. */
#define MIN_RENDER_SHARE 0.25

/* Controller, prediction and the render passes of one frame. The time the
 * frame already spent (recompute, probe) is known exactly when the
 * controller decides: it is taken off the target, and only the render
 * passes are predicted and learned. Frames with and without a probe then
 * cost the same in total, where a model that learned the probe as part of
 * an average c0 was wrong both ways. */
static int render_frame(rp_runtime *rt) {
  scene *s = &rt->s;
  rp_frame_stats *st = &rt->stats;
  rp_cost_estimate est;
  double rho, t0, pass_ms = 0.0, budget, upload_before = 0.0;
  double spent = rp__now_ms() - rt->worker_begin;
  int err, again = 1;
  st->upload_predicted_ms = predicted_upload_ms(rt);
  spent += st->upload_predicted_ms;
  budget = s->target_ms - spent;
  if (budget < MIN_RENDER_SHARE * s->target_ms)
    budget = MIN_RENDER_SHARE * s->target_ms;
  t0 = rp__now_ms();
  if ((err = rp_controller_begin_frame(s->controller, budget, predict_at,
                                       rt, &rho)) != 0)
    return err;
  st->predict_ms = rp__now_ms() - t0;
  while (again) {
    float step, scale;
    rp_space_map(&rt->space, rho, &step, &scale);
    t0 = rp__now_ms();
    st->predicted_ms = rp_device_group_predict(rt->group, &s->probe, step,
                                               scale, &est) == 0
                           ? est.ms
                           : NAN;
    st->predict_ms += rp__now_ms() - t0;
    upload_before = st->upload_ms;
    if ((err = render_pass(rt, rho, &pass_ms)) != 0) {
      /* The controller's frame stays open otherwise; its history goes
       * with it, which is right after a device failed. */
      rp_controller_reset(s->controller);
      return err;
    }
    st->rho = rho;
    st->passes++;
    if ((err = rp_controller_end_pass(s->controller, pass_ms, &again,
                                      &rho)) != 0) {
      rp_controller_reset(s->controller);
      return err;
    }
  }
  st->measured_ms = rp__now_ms() - rt->worker_begin;
  /* What was known: the time spent before the last pass, and its
   * predicted upload (the last pass's measured one is not known). */
  st->predicted_ms += st->measured_ms - pass_ms -
                      (st->upload_ms - upload_before) +
                      st->upload_predicted_ms;
  st->delta = st->predicted_ms > 0.0
                  ? st->measured_ms / st->predicted_ms - 1.0
                  : NAN;
  return 0;
}

static void run_frame(rp_runtime *rt) {
  rp_frame_stats *st = &rt->stats;
  int err;
  rt->worker_begin = rp__now_ms();
  memset(st, 0, sizeof *st);
  st->frame = rt->frame_no;
  st->events = rt->job_events;
  st->predicted_ms = st->delta = NAN;
  rt->out_rgba = NULL;
  rt->job_train.valid = 0;
  rp__clear_error(rt->ctx);
  take_events(rt);
  st->controller = rt->s.controller_kind;
  st->target_ms = rt->s.target_ms;
  if ((err = recompute(rt)) == 0)
    err = render_frame(rt);
  st->effects = rt->s.render_effects;
  st->effects_wanted = rt->s.effects;
  if (err != 0) {
    st->status = err;
    snprintf(st->error, sizeof st->error, "%s", rp_last_error(rt->ctx));
    rt->out_rgba = NULL;
    rt->job_train.valid = 0;
  }
  rt->worker_end = rp__now_ms();
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
  int wanted, ready;
  if (rt->in_flight || rt->close_begun)
    return;
  uv_mutex_lock(&rt->lock);
  wanted = rt->desc.pacing == RP_PACE_TIMER ? rt->due : rt->requests > 0;
  ready = rt->have_vol && rt->have_tf && rt->have_cam;
  if (wanted && ready) {
    rt->job_in = rt->posted;
    rt->job_events = rt->counters.events;
    rt->posted.marks = 0;
    rt->posted.vol = NULL;
    rt->posted.tf = NULL;
    rt->requests = 0;
  }
  uv_mutex_unlock(&rt->lock);
  if (!wanted || !ready)
    return;
  rt->due = 0;
  if (rt->job_in.marks & POSTED_TARGET)
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

static void train(rp_runtime *rt) {
  training *t = &rt->train;
  double t0 = rp__now_ms();
  rt->last_train_ms = 0.0;
  if (!t->valid)
    return;
  /* A refused sample (a zero-sample frame, say) teaches nothing; the
   * models stay as they were, which is the right outcome. */
  (void)rp_device_group_train(rt->group, &t->probe, t->step, t->scale,
                              t->pass_ms);
  t->valid = 0;
  rt->last_train_ms = rp__now_ms() - t0;
}

static void finish_close(rp_runtime *rt);

static void on_done(uv_async_t *a) {
  rp_runtime *rt = a->data;
  rp_frame frame;
  int done;
  double now;
  uv_mutex_lock(&rt->work_lock);
  done = rt->job_done;
  rt->job_done = 0;
  uv_mutex_unlock(&rt->work_lock);
  if (!done)
    return;
  rt->in_flight = 0;
  rt->frame_no++;
  if (rt->close_begun) {
    finish_close(rt);
    return;
  }
  now = rp__now_ms();
  rt->stats.dispatch_ms = (rt->worker_begin - rt->handoff) +
                          (now - rt->worker_end);
  rt->stats.train_ms = rt->last_train_ms;
  rt->stats.total_ms = now - rt->frame_start;
  uv_mutex_lock(&rt->lock);
  rt->counters.frames++;
  rt->stats.counters = rt->counters;
  uv_mutex_unlock(&rt->lock);
  frame.rgba = rt->out_rgba;
  frame.width = rt->out_w;
  frame.height = rt->out_h;
  frame.stats = &rt->stats;
  rt->train = rt->job_train;
  rt->delivering = 1;
  rt->desc.on_frame(rt, &frame, rt->desc.user);
  rt->delivering = 0;
  if (rt->close_begun) {
    finish_close(rt);
    return;
  }
  train(rt);
  try_start(rt);
}

/* ---- Lifetime ------------------------------------------------------------ */

static void drop_posted(posted_state *p) {
  rp_volume_destroy(p->vol);
  rp_tf_destroy(p->tf);
  p->vol = NULL;
  p->tf = NULL;
}

/* Everything but the handles and the loop, which are closed first. */
static void free_runtime(rp_runtime *rt) {
  rp_context *ctx = rt->ctx;
  scene *s = &rt->s;
  drop_posted(&rt->posted);
  drop_posted(&rt->job_in);
  drop_ao_run(s);
  rp_controller_destroy(s->controller);
  rp_occupancy_destroy(s->occ);
  rp_histograms_destroy(s->h);
  rp_tf_destroy(s->tf);
  rp_volume_destroy(s->vol);
  rp_device_group_destroy(rt->group);
  rp__free(ctx, rt->scaled);
  rp__free(ctx, rt->image);
  rp__free(ctx, rt->tiles);
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
  if (rt->own || rt->close_begun)
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

static int check_desc(rp_context *ctx, const rp_runtime_desc *d) {
  static const char fn[] = "rp_runtime_create";
  rp_ao_desc ao = {0};
  rp_ao_schedule sched;
  int err;
  if (d->on_frame == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->on_frame is NULL", fn);
  if (d->pacing != RP_PACE_TIMER && d->pacing != RP_PACE_ON_REQUEST)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->pacing is %d", fn,
                    (int)d->pacing);
  if ((int)d->controller < 0 || d->controller >= RP_CONTROL_COUNT)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->controller is %d", fn,
                    (int)d->controller);
  if (!isfinite(d->target_ms))
    return rp__fail(ctx, RP_ENOTFINITE, "%s: desc->target_ms is %g", fn,
                    d->target_ms);
  if (d->target_ms < 0.0 || d->target_ms > 60000.0)
    return rp__fail(ctx, RP_ERANGE, "%s: desc->target_ms is %g; must be "
                    "in (0, 60000] (0: 1000 / 60)", fn, d->target_ms);
  if (d->width > MAX_VIEWPORT || d->height > MAX_VIEWPORT)
    return rp__fail(ctx, RP_ERANGE, "%s: viewport %ux%u; at most %u "
                    "each", fn, d->width, d->height, MAX_VIEWPORT);
  if (d->effects & ~(uint32_t)RP__KNOWN_EFFECTS)
    return rp__fail(ctx, RP_EINVAL, "%s: desc->effects has unknown bits "
                    "0x%x", fn, d->effects);
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

int rp_runtime_create(rp_context *ctx, const rp_runtime_desc *desc,
                      rp_runtime **out) {
  static const char fn[] = "rp_runtime_create";
  rp_context *own_ctx = NULL;
  rp_runtime *rt;
  rp_group_desc gd = {0};
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
  rt->desc = *desc;
  rt->desc.devices = NULL; /* the group copies them */
  rt->space = desc->space;
  if (rt->desc.target_ms == 0.0)
    rt->desc.target_ms = 1000.0 / 60.0;
  if (rt->desc.width == 0)
    rt->desc.width = 512;
  if (rt->desc.height == 0)
    rt->desc.height = 512;
  rt->posted.target_ms = rt->s.target_ms = rt->period_ms =
      rt->desc.target_ms;
  rt->posted.width = rt->s.width = rt->desc.width;
  rt->posted.height = rt->s.height = rt->desc.height;
  rt->posted.effects = rt->s.effects = rt->desc.effects;
  if (rt->desc.ao_frame_share == 0.0)
    rt->desc.ao_frame_share = 0.25;
  if (rt->desc.ao_schedule.block == 0)
    rt->desc.ao_schedule.block = RP_AO_FRAME_BLOCK;
  rt->posted.controller = rt->s.controller_kind = rt->desc.controller;
  rt->due = 1;
  if (uv_mutex_init(&rt->lock) != 0) {
    rp__free(own_ctx, rt);
    rp_context_destroy(own_ctx);
    return rp__fail(ctx, RP_EDEVICE, "%s: uv_mutex_init failed", fn);
  }
  if (uv_mutex_init(&rt->work_lock) != 0) {
    uv_mutex_destroy(&rt->lock);
    rp__free(own_ctx, rt);
    rp_context_destroy(own_ctx);
    return rp__fail(ctx, RP_EDEVICE, "%s: uv_mutex_init failed", fn);
  }
  if (uv_cond_init(&rt->work_cv) != 0) {
    uv_mutex_destroy(&rt->work_lock);
    uv_mutex_destroy(&rt->lock);
    rp__free(own_ctx, rt);
    rp_context_destroy(own_ctx);
    return rp__fail(ctx, RP_EDEVICE, "%s: uv_cond_init failed", fn);
  }
  /* From here on free_runtime undoes everything made so far. */
  gd.devices = desc->device_count > 0 ? desc->devices : &desc->device;
  gd.count = desc->device_count > 0 ? desc->device_count : 1;
  gd.damping = desc->damping;
  gd.model = desc->model;
  if ((err = rp_device_group_create(own_ctx, &gd, &rt->group)) != 0) {
    rp__fail(ctx, err, "%s: %s", fn, rp_last_error(own_ctx));
    free_runtime(rt);
    return err;
  }
  rt->own = desc->loop == NULL;
  if (rt->own) {
    if (uv_loop_init(&rt->own_loop) != 0) {
      free_runtime(rt);
      return rp__fail(ctx, RP_EDEVICE, "%s: uv_loop_init failed", fn);
    }
    rt->loop = &rt->own_loop;
  } else {
    rt->loop = desc->loop;
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
  rt->posted.marks |= POSTED_VOLUME;
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
  rt->posted.marks |= POSTED_TF;
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
  rt->posted.marks |= POSTED_CAMERA;
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
  rt->posted.marks |= POSTED_CAMERA;
}

int rp_runtime_set_viewport(rp_runtime *rt, uint32_t width,
                            uint32_t height) {
  uint32_t wh[2];
  if (rt == NULL)
    return RP_EINVAL;
  if (width < 1 || height < 1 || width > MAX_VIEWPORT ||
      height > MAX_VIEWPORT)
    return RP_ERANGE;
  wh[0] = width;
  wh[1] = height;
  return post(rt, apply_viewport, wh, 0);
}

static void apply_target(rp_runtime *rt, const void *arg) {
  rt->posted.target_ms = *(const double *)arg;
  rt->posted.marks |= POSTED_TARGET;
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
  rt->posted.marks |= POSTED_EFFECTS;
}

int rp_runtime_set_effects(rp_runtime *rt, uint32_t effects) {
  if (rt == NULL || effects & ~(uint32_t)RP__KNOWN_EFFECTS)
    return RP_EINVAL;
  return post(rt, apply_effects, &effects, 0);
}

static void apply_controller(rp_runtime *rt, const void *arg) {
  rt->posted.controller = *(const rp_controller_kind *)arg;
  rt->posted.marks |= POSTED_CONTROLLER;
}

int rp_runtime_set_controller(rp_runtime *rt, rp_controller_kind kind) {
  if (rt == NULL || (int)kind < 0 || kind >= RP_CONTROL_COUNT)
    return RP_EINVAL;
  return post(rt, apply_controller, &kind, 0);
}

int rp_runtime_request_frame(rp_runtime *rt) {
  if (rt == NULL)
    return RP_EINVAL;
  if (rt->desc.pacing != RP_PACE_ON_REQUEST)
    return RP_ESTATE;
  return post(rt, NULL, NULL, 1);
}

void rp_runtime_get_counters(rp_runtime *rt, rp_runtime_counters *out) {
  if (rt == NULL || out == NULL)
    return;
  uv_mutex_lock(&rt->lock);
  *out = rt->counters;
  uv_mutex_unlock(&rt->lock);
}
