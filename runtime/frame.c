/* The frame engine (frame.h): events -> recompute -> predict -> tune ->
 * render -> measure, and training after delivery. The order of the
 * stages and what each event makes stale is DESIGN section 1's table;
 * docs/architecture.md follows one frame through here. */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <string.h>

#include "ao.h"
#include "bounds.h"
#include "frame.h"
#include "group.h"
#include "internal.h"
#include "passes.h"
#include "raypace_group.h"

/* Derived data that is out of date. A stage clears its bit only when it
 * succeeds, so a frame that fails half-way leaves the rest for the next
 * frame to retry. */
enum {
  STALE_HISTOGRAMS = 1u << 0,
  STALE_VOLUME_UPLOAD = 1u << 1,
  STALE_OCCUPANCY = 1u << 2,
  STALE_TF_UPLOAD = 1u << 3,
  STALE_PROBE = 1u << 4,
  STALE_CONTROLLER = 1u << 5,
  STALE_AO = 1u << 6 /* the AO volume, or (AO off) its memory */
};

/* The least share of the target a frame's render passes are given when
 * its recompute and probe already used more: the budget stays positive,
 * and one slow recompute (a volume load) does not drop the density. */
#define MIN_RENDER_SHARE 0.25

/* The tuner's wall-clock budget per frame when the engine's time is a
 * device's simulated clock: the frame's decisions must then depend on
 * that clock alone, so the tuner is not cut short by the host's speed
 * (a sanitizer build runs it many times slower). */
#define VIRTUAL_TUNE_TIME_US 1e9

/* The share of the target the probe may take, and how many of its last
 * costs per ray the budget takes the median of (one probe stalled by the
 * machine does not shrink the next ones): docs/pacing.md, "Prediction's
 * own cost". */
#define PROBE_SHARE 0.02
#define PROBE_COSTS 9

typedef struct scene {
  uint32_t stale;
  rp_volume *vol;
  rp_histograms *h;
  rp_tf *tf;
  rp_occupancy *occ;
  rp_camera cam;
  uint32_t width, height, effects;
  double target_ms;
  double density; /* rp_controller_desc.rho_start */
  rp_controller_kind controller_kind;
  rp_controller *controller;
  rp_frame_probe probe;
  /* The last probes' costs per ray (ms, on the engine's clock): a ring
   * of probe_costs values (at most PROBE_COSTS), the next at probe_next. */
  double probe_cost[PROBE_COSTS];
  uint32_t probe_costs, probe_next;
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
  /* The TF whose AO the devices hold (0: none), and that TF when it is
   * no longer the scene's: a TF posted again with the same content
   * while the devices still hold its AO (switched away and back before
   * the other TF's AO was done) takes its place, id and all, and its AO
   * renders at once. */
  uint64_t ao_tf_id;
  rp_tf *ao_tf;
  /* The volume's brick value ranges, built with its first AO plan: a
   * TF change's plan then reads them, not the voxels. And the last AO
   * volume the devices were given, which the group hands to a device it
   * re-creates; both go with the volume or when AO is turned off. */
  rp__ao_ranges *ao_ranges;
  rp_ao *ao_given;
  int ao_waits;  /* the run's first step waits for the build lanes to build
                    the AO kernels (rp_device_group_prepare) */
} scene;

/* What the cost models learn from the last frame, after delivery;
 * valid: 0 for a failed frame and a cold one (warm_sets). */
typedef struct training {
  int valid;
  rp_frame_probe probe;
  float step, scale;
  double pass_ms;
} training;

struct rp__engine {
  rp_context *ctx;
  rp_runtime_desc desc; /* defaults resolved; devices not kept */
  rp_space_desc space;
  rp_device_group *group;
  int own_clock; /* the single device keeps its own clock, which is the
                    engine's (rp__group_clock_ns); 0: CLOCK_MONOTONIC */
  pthread_mutex_t count_lock;
  rp_runtime_counters counters; /* the passes'; under count_lock */
  scene s;
  /* The frame being made, and after it the last one. */
  double begin_ms;
  uint64_t frame_no;
  rp_frame_stats stats;
  uint8_t *scaled, *image;
  size_t scaled_cap, image_cap;
  rp_tile_stats *tiles;
  size_t tiles_cap;
  const uint8_t *out_rgba;
  uint32_t out_w, out_h;
  training train;
  double rho_last; /* the last frame's final density; 0 before one */
};

/* ---- Time and counters --------------------------------------------------- */

rp_device_group *rp__engine_group(rp__engine *e) { return e->group; }

double rp__engine_now_ms(const rp__engine *e) {
  uint64_t ns;
  if (e->own_clock && rp__group_clock_ns(e->group, 0, &ns))
    return (double)ns * 1e-6;
  return rp__now_ms();
}

static void count(rp__engine *e, uint64_t *field) {
  pthread_mutex_lock(&e->count_lock);
  (*field)++;
  pthread_mutex_unlock(&e->count_lock);
}

void rp__engine_counters(rp__engine *e, rp_runtime_counters *out) {
  pthread_mutex_lock(&e->count_lock);
  *out = e->counters;
  pthread_mutex_unlock(&e->count_lock);
}

static void publish_ao_bytes(rp__engine *e) {
  uint64_t bytes = rp_device_group_ao_bytes(e->group);
  pthread_mutex_lock(&e->count_lock);
  e->counters.ao_bytes = bytes;
  pthread_mutex_unlock(&e->count_lock);
}

void rp__events_drop(rp__events *ev) {
  rp_volume_destroy(ev->vol);
  rp_tf_destroy(ev->tf);
  ev->vol = NULL;
  ev->tf = NULL;
  ev->marks = 0;
}

/* ---- Events and what they make stale ------------------------------------- */

/* Takes the events into the scene and marks what they invalidate.
 * Objects move; nothing here can fail. */
static void take_events(rp__engine *e, rp__events *in) {
  scene *s = &e->s;
  if (in->marks & RP__POSTED_VOLUME) {
    rp_tf_destroy(s->ao_tf); /* an AO of another volume */
    s->ao_tf = NULL;
    s->ao_tf_id = 0;
    rp__ao_ranges_destroy(s->ao_ranges);
    s->ao_ranges = NULL;
    /* The group gives the AO it was last set to a device it re-creates:
     * not this one, about to be freed (the devices' own copies are of
     * the old volume and go with it). */
    rp__group_forget_ao(e->group);
    rp_ao_destroy(s->ao_given);
    s->ao_given = NULL;
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
  if (in->marks & RP__POSTED_TF) {
    rp_tf *tf = in->tf;
    in->tf = NULL;
    if (s->ao_tf != NULL && rp__tf_same(s->ao_tf, tf)) {
      rp_tf_destroy(tf);
      tf = s->ao_tf;
      s->ao_tf = NULL;
    }
    if (s->tf != NULL && s->tf->id == s->ao_tf_id) {
      rp_tf_destroy(s->ao_tf);
      s->ao_tf = s->tf;
    } else {
      rp_tf_destroy(s->tf);
    }
    s->tf = tf;
    s->stale |= STALE_OCCUPANCY | STALE_TF_UPLOAD | STALE_AO | STALE_PROBE;
  }
  if (in->marks & RP__POSTED_CAMERA) {
    s->cam = in->cam;
    s->width = in->width;
    s->height = in->height;
    s->stale |= STALE_PROBE;
  }
  if (in->marks & RP__POSTED_EFFECTS) {
    /* The probe follows in choose_effects, which knows what renders. */
    if ((s->effects ^ in->effects) & RP_EFFECT_AO)
      s->stale |= STALE_AO;
    s->effects = in->effects;
  }
  if (in->marks & RP__POSTED_TARGET)
    s->target_ms = in->target_ms;
  if (in->marks & RP__POSTED_CONTROLLER &&
      in->controller != s->controller_kind) {
    s->controller_kind = in->controller;
    s->stale |= STALE_CONTROLLER;
  }
  if (in->marks & RP__POSTED_DENSITY && in->density != s->density) {
    s->density = in->density;
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
static void choose_effects(rp__engine *e) {
  scene *s = &e->s;
  uint32_t want = wanted_effects(s), eff = want;
  int can_wait = s->warm_sets != 0 &&
                 (!(s->shown_effects & RP_EFFECT_AO) || s->ao_ready);
  if (can_wait && !((s->warm_sets >> want) & 1u) &&
      !rp_device_group_prepared(e->group, want) &&
      rp_device_group_prepare(e->group, want) == 0)
    eff = s->shown_effects;
  /* Every effect is in the probe: ERT cuts the spans, skipping moves
   * D_front and D_back, shading and AO set k and the visible blocks. */
  if (eff != s->render_effects)
    s->stale |= STALE_PROBE;
  s->render_effects = eff;
}

/* ---- Ambient occlusion in steps ------------------------------------------ */

static void drop_ao_run(scene *s) {
  rp_ao_run_destroy(s->ao_run);
  rp_ao_plan_destroy(s->ao_plan);
  s->ao_run = NULL;
  s->ao_plan = NULL;
}

/* A volume, TF or AO toggle: any run in progress is for the old scene and
 * goes. AO on: a run starts for the current volume and TF, and frames
 * render without AO until it is done (advance_ao). AO off: the devices'
 * AO memory is released, so an effect that is off costs neither time
 * nor memory. */
static int update_ao(rp__engine *e) {
  scene *s = &e->s;
  int err = 0;
  drop_ao_run(s);
  s->ao_ready = 0;
  s->ao_waits = 0;
  if (!(s->effects & RP_EFFECT_AO)) {
    /* Also when no device holds AO memory: the group still refers to
     * the AO freed below, for devices it re-creates. */
    if (s->ao_given != NULL || rp_device_group_ao_bytes(e->group) != 0)
      err = rp_device_group_set_ao(e->group, NULL);
    rp_tf_destroy(s->ao_tf);
    s->ao_tf = NULL;
    s->ao_tf_id = 0;
    rp_ao_destroy(s->ao_given);
    s->ao_given = NULL;
  } else if (s->ao_tf_id == s->tf->id) {
    s->ao_ready = 1; /* back to the TF whose AO the devices hold */
  } else {
    /* AO's kernels (the AO volume's and the raycast that reads it) on
     * the build lanes: the run starts once they are built, and the frame AO
     * is ready in renders with them at once; no frame builds one. */
    s->ao_waits = rp_device_group_prepare(e->group, s->effects) == 0 &&
                  !rp_device_group_prepared(e->group, s->effects);
    if (s->ao_ranges == NULL && !e->desc.ao.unbricked)
      err = rp__ao_ranges_build(e->ctx, s->vol, &s->ao_ranges);
    if (err == 0)
      err = rp__ao_plan_create(e->ctx, s->vol, s->tf, &e->desc.ao,
                               s->ao_ranges, &s->ao_plan);
    /* Into a new AO, not over the one the devices hold (ao_given): the
     * group gives that one to a device it re-creates, and a TF switched
     * back before the run ends renders with it. Overwriting it in place
     * saved an allocation but gave a device re-created mid-run a half
     * computed AO, or a freed one (the soak, under ASan). */
    if (err == 0)
      err = rp_device_group_ao_begin(e->group, s->ao_plan,
                                     &e->desc.ao_schedule, &s->ao_run);
    if (err != 0)
      drop_ao_run(s);
  }
  publish_ao_bytes(e);
  return err;
}

/* One step of the AO run: ao_frame_share of the target (all of it at
 * once with share 1); the render passes then get what is left of the
 * target, as after any stage. When the run is done its AO goes to every
 * device and frames render with it from this one on. */
static int advance_ao(rp__engine *e) {
  scene *s = &e->s;
  rp_frame_stats *st = &e->stats;
  double budget = e->desc.ao_frame_share >= 1.0
                      ? INFINITY
                      : e->desc.ao_frame_share * s->target_ms;
  double fraction = 0.0;
  rp_ao *ao = NULL;
  int err;
  if (s->ao_waits) {
    st->ao_progress = 0.0;
    if (!rp_device_group_prepared(e->group, s->effects))
      return 0;
    s->ao_waits = 0;
  }
  err = rp_ao_run_step(s->ao_run, budget, &fraction);
  st->ao_progress = fraction;
  if (err == 0 && fraction < 1.0)
    return 0;
  err = rp_device_group_ao_end(e->group, s->ao_run, err, &ao, NULL);
  if (err == 0)
    err = rp_device_group_set_ao(e->group, ao);
  rp_ao_destroy(s->ao_given);
  s->ao_given = ao; /* the devices hold their copies */
  drop_ao_run(s);
  publish_ao_bytes(e);
  /* The AO the devices held before is replaced (or, failed, unknown). */
  rp_tf_destroy(s->ao_tf);
  s->ao_tf = NULL;
  s->ao_tf_id = 0;
  if (err != 0) {
    /* Tried again from the start next frame: a lost device is dropped
     * by now, and the others may finish it. */
    s->stale |= STALE_AO;
    return err;
  }
  s->ao_tf_id = s->tf->id;
  s->ao_ready = 1;
  count(e, &e->counters.ao_computes);
  return 0;
}

/* ---- Recompute ----------------------------------------------------------- */

/* H, then the volume upload, then H-alpha + occupancy and the TF upload:
 * what the volume and TF events made stale, in dependency order. */
static int recompute_scene(rp__engine *e) {
  scene *s = &e->s;
  rp_frame_stats *st = &e->stats;
  double t0;
  int err;
  if (s->stale & STALE_HISTOGRAMS) {
    t0 = rp__engine_now_ms(e);
    if ((err = rp_histograms_build(e->ctx, s->vol, &s->h)) != 0)
      return err;
    st->histograms_ms = rp__engine_now_ms(e) - t0;
    s->stale &= ~(uint32_t)STALE_HISTOGRAMS;
    count(e, &e->counters.histograms);
  }
  if (s->stale & STALE_VOLUME_UPLOAD) {
    t0 = rp__engine_now_ms(e);
    if ((err = rp_device_group_set_volume(e->group, s->vol)) != 0)
      return err;
    st->volume_upload_ms = rp__engine_now_ms(e) - t0;
    s->warm_sets = 0;
    s->stale &= ~(uint32_t)STALE_VOLUME_UPLOAD;
    count(e, &e->counters.volume_uploads);
  }
  if (s->stale & STALE_OCCUPANCY) {
    t0 = rp__engine_now_ms(e);
    err = s->occ == NULL ? rp_occupancy_build(e->ctx, s->h, s->tf, &s->occ)
                         : rp_occupancy_update(s->occ, s->tf);
    if (err != 0)
      return err;
    st->occupancy_ms = rp__engine_now_ms(e) - t0;
    s->stale &= ~(uint32_t)STALE_OCCUPANCY;
    count(e, &e->counters.occupancies);
  }
  if (s->stale & STALE_TF_UPLOAD) {
    t0 = rp__engine_now_ms(e);
    if ((err = rp_device_group_set_tf(e->group, s->tf, s->occ)) != 0)
      return err;
    st->tf_upload_ms = rp__engine_now_ms(e) - t0;
    s->stale &= ~(uint32_t)STALE_TF_UPLOAD;
    count(e, &e->counters.tf_uploads);
  }
  return 0;
}

/* The controller the scene asks for, made afresh when its kind or its
 * starting density changed (its history goes; the models keep theirs). */
static int make_controller(rp__engine *e) {
  scene *s = &e->s;
  rp_controller_desc cd = {0};
  rp_controller *c = NULL;
  int err;
  cd.kind = s->controller_kind;
  cd.rho_min = rp_space_min_density(&e->space);
  cd.rho_max = rp_space_max_density(&e->space);
  cd.rho_start = s->density;
  cd.miss_rate = e->desc.miss_rate;
  cd.headroom = e->desc.headroom;
  if (e->own_clock)
    cd.tune_time_us = VIRTUAL_TUNE_TIME_US;
  if ((err = rp_controller_create(e->ctx, &cd, &c)) != 0)
    return err;
  rp_controller_destroy(s->controller);
  s->controller = c;
  s->stale &= ~(uint32_t)STALE_CONTROLLER;
  return 0;
}

/* The median of the last probes' costs per ray (ms), 0 while none has
 * been measured. */
static double probe_cost_per_ray(const scene *s) {
  double v[PROBE_COSTS], x;
  uint32_t n = s->probe_costs, i, j;
  if (n == 0)
    return 0.0;
  for (i = 0; i < n; i++) { /* insertion sort: at most PROBE_COSTS */
    x = s->probe_cost[i];
    for (j = i; j > 0 && v[j - 1] > x; j--)
      v[j] = v[j - 1];
    v[j] = x;
  }
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* The probe of this frame's camera, TF and effects, with as many rays as
 * PROBE_SHARE of the target pays for at the probe's own recent cost per
 * ray (rp__probe_ray_budget; all of them until one was measured, and on
 * a simulated clock, where the probe takes no time). */
static int run_probe(rp__engine *e) {
  scene *s = &e->s;
  rp_render_desc d = {0};
  uint32_t rays = rp__probe_ray_budget(PROBE_SHARE * s->target_ms,
                                       probe_cost_per_ray(s));
  double t0, ms;
  int err;
  d.width = s->width;
  d.height = s->height;
  d.effects = s->render_effects;
  t0 = rp__engine_now_ms(e);
  if ((err = rp__frame_probe_compute(e->ctx, s->vol, s->tf, s->occ, &s->cam,
                                     &d, e->desc.ert_seed,
                                     (uint32_t)e->frame_no, rays,
                                     &s->probe)) != 0)
    return err;
  /* On the engine's clock, as every other stage. */
  ms = rp__engine_now_ms(e) - t0;
  s->probe.probe_ms = ms;
  e->stats.probe_ms = ms;
  if (ms > 0.0 && s->probe.rays > 0) {
    s->probe_cost[s->probe_next] = ms / s->probe.rays;
    s->probe_next = (s->probe_next + 1) % PROBE_COSTS;
    if (s->probe_costs < PROBE_COSTS)
      s->probe_costs++;
  }
  s->stale &= ~(uint32_t)STALE_PROBE;
  count(e, &e->counters.probes);
  return 0;
}

/* Every stale stage, then the AO step, the effects to render, the probe
 * and the controller. */
static int recompute(rp__engine *e) {
  scene *s = &e->s;
  rp_frame_stats *st = &e->stats;
  double t0;
  int err;
  if ((err = recompute_scene(e)) != 0)
    return err;
  if (s->stale & STALE_AO || s->ao_run != NULL) {
    t0 = rp__engine_now_ms(e);
    if (s->stale & STALE_AO) {
      s->stale &= ~(uint32_t)STALE_AO;
      if ((err = update_ao(e)) != 0)
        return err;
    }
    if (s->ao_run != NULL && (err = advance_ao(e)) != 0)
      return err;
    st->ao_ms = rp__engine_now_ms(e) - t0;
  }
  choose_effects(e);
  if (s->stale & STALE_PROBE && (err = run_probe(e)) != 0)
    return err;
  if (s->stale & STALE_CONTROLLER || s->controller == NULL)
    return make_controller(e);
  return 0;
}

/* ---- Predict, tune, render ----------------------------------------------- */

/* The controller's model of the frame: `user` is the engine. */
static double predict_at(void *user, double rho) {
  rp__engine *e = user;
  rp_cost_estimate est;
  float step, scale;
  rp_space_map(&e->space, rho, &step, &scale);
  if (rp_device_group_predict(e->group, &e->s.probe, step, scale, &est) != 0)
    return NAN;
  return est.ms;
}

/* Grows *buf to hold `bytes`; keeps the old one on failure. */
static int reserve(rp__engine *e, void **buf, size_t *cap, size_t bytes) {
  void *p;
  if (bytes <= *cap)
    return 0;
  if (rp__check_memory(e->ctx, "runtime: the frame's image buffer",
                       bytes) != 0)
    return RP_ENOMEM;
  p = rp__malloc(e->ctx, bytes);
  if (p == NULL)
    return rp__fail(e->ctx, RP_ENOMEM, "runtime: %zu bytes for the frame",
                    bytes);
  rp__free(e->ctx, *buf);
  *buf = p;
  *cap = bytes;
  return 0;
}

/* A group's raycast time for the pass, as one device's would be: the
 * fastest device's rate (its raycast time over its samples) times the
 * pass's samples; with one device, its raycast time. */
static double pass_raycast_ms(const rp_group_report *rep, uint64_t samples) {
  double best = INFINITY;
  uint32_t i;
  if (rep->count == 1)
    return rep->devices[0].raycast_ms;
  for (i = 0; i < rep->count; i++) {
    const rp_group_device *d = &rep->devices[i];
    if (d->samples > 0 && d->raycast_ms > 0 &&
        d->raycast_ms / (double)d->samples < best)
      best = d->raycast_ms / (double)d->samples;
  }
  return isfinite(best) ? best * (double)samples : 0.0;
}

/* The pass's per-device figures into the stats (summed over passes; a
 * lost device is part of the story, whatever happened). Returns the
 * most brick upload time any device spent. */
static double report_devices(rp__engine *e, const rp_group_report *rep,
                             int *depth) {
  rp_frame_stats *st = &e->stats;
  double upload = 0.0;
  uint32_t i;
  st->device_count = rep->count;
  st->devices_alive = rep->alive;
  st->devices_lost += rep->lost;
  st->imbalance = rep->imbalance;
  st->rerender_ms += rep->rerender_ms;
  *depth = 0;
  for (i = 0; i < rep->count && i < RP_RUNTIME_MAX_DEVICES; i++) {
    rp_device_frame *df = &st->devices[i];
    const rp_group_device *gd = &rep->devices[i];
    snprintf(df->name, sizeof df->name, "%s", gd->name);
    df->raycast_ms += gd->raycast_ms;
    df->upload_ms += gd->upload_ms;
    df->depth_ms += gd->depth_ms;
    df->busy_ms += gd->busy_ms;
    df->readback_ms +=
        gd->busy_ms - gd->raycast_ms - gd->upload_ms - gd->depth_ms;
    if (gd->upload_ms > upload)
      upload = gd->upload_ms;
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
    df->state = gd->state;
    df->failures = gd->failures;
    *depth |= gd->depth_passes > 0;
  }
  return upload;
}

/* One render pass at density rho: every device's depth pass when its
 * inputs changed, the raycast of its region with readback, and the
 * upscale. *pass_ms: what the controller holds to its budget (the pass
 * without its brick uploads, which were predicted and taken off). */
static int render_pass(rp__engine *e, double rho, double *pass_ms) {
  scene *s = &e->s;
  rp_frame_stats *st = &e->stats;
  rp_render_desc d = {0};
  rp_group_report rep;
  uint32_t sw, sh, tx, ty, i;
  double t0 = rp__engine_now_ms(e), t2, upload, ms;
  int err, depth = 0;
  rp_space_map(&e->space, rho, &st->step, &st->scale);
  d.width = s->width;
  d.height = s->height;
  d.step = st->step;
  d.image_scale = st->scale;
  d.effects = s->render_effects;
  /* A new jitter every frame: its noise averages out over frames. */
  d.jitter = e->desc.jitter;
  d.jitter_seed = e->desc.jitter == RP_JITTER_FIXED
                      ? e->desc.jitter_seed
                      : rp_jitter_frame_seed(e->desc.jitter_seed,
                                             (uint64_t)e->frame_no);
  st->jitter_seed = d.jitter == RP_JITTER_OFF ? 0u : d.jitter_seed;
  rp_scaled_size(&d, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  if ((err = reserve(e, (void **)&e->scaled, &e->scaled_cap,
                     (size_t)sw * sh * 4)) != 0 ||
      (err = reserve(e, (void **)&e->image, &e->image_cap,
                     (size_t)s->width * s->height * 4)) != 0 ||
      (err = reserve(e, (void **)&e->tiles, &e->tiles_cap,
                     (size_t)tx * ty * sizeof(rp_tile_stats))) != 0)
    return err;
  err = rp_device_group_render(e->group, &s->cam, &d, &s->probe, e->scaled,
                               e->tiles, &rep);
  t2 = rp__engine_now_ms(e);
  upload = report_devices(e, &rep, &depth);
  st->upload_ms += upload;
  if (depth)
    count(e, &e->counters.device_depth);
  if (err != 0)
    return err;
  count(e, &e->counters.renders);
  st->samples = 0;
  for (i = 0; i < tx * ty; i++)
    st->samples += e->tiles[i].samples;
  if (sw != s->width || sh != s->height) {
    rp_image_upscale(e->scaled, sw, sh, e->image, s->width, s->height);
    e->out_rgba = e->image;
    st->upscale_ms += rp__engine_now_ms(e) - t2;
  } else {
    e->out_rgba = e->scaled;
  }
  e->out_w = s->width;
  e->out_h = s->height;
  ms = rp__engine_now_ms(e) - t0;
  st->render_ms += ms;
  st->raycast_ms = pass_raycast_ms(&rep, st->samples);
  e->train.valid = (s->warm_sets >> s->render_effects) & 1u;
  s->warm_sets |= 1u << s->render_effects;
  /* A set the frame built for itself (the first on a volume) holds only
   * the variants this frame used: the others (the opacity correction at
   * another step) are built ahead now, on the build lanes, or a later
   * frame at another step pays for a build (a TF switch with AO on
   * lavapipe: +15 ms). Asking again for a set asked for is free. */
  (void)rp_device_group_prepare(e->group, s->render_effects);
  s->shown_effects = s->render_effects;
  e->train.probe = s->probe;
  e->train.step = st->step;
  e->train.scale = st->scale;
  e->train.pass_ms = ms;
  /* What rp_device_group_train will learn from: the pass, without its
   * brick uploads when it had some (never under its raycast then). */
  st->learn_ms = !e->train.valid ? NAN
                 : upload > 0.0  ? fmax(ms - upload, st->raycast_ms)
                                 : ms;
  *pass_ms = fmax(ms - upload, 0.0);
  return 0;
}

/* Out of core: the predicted brick uploads of the coming render (0 in
 * core, or when the estimate fails: the frame then only runs late). */
static double predicted_upload_ms(rp__engine *e) {
  scene *s = &e->s;
  rp_render_desc d = {0};
  double ms = 0.0;
  d.width = s->width;
  d.height = s->height;
  d.effects = s->render_effects;
  if (rp_device_group_upload_ms(e->group, &s->cam, &d, &ms) != 0)
    return 0.0;
  return ms;
}

/* The model's prediction for a pass at rho, into the stats; the time it
 * took goes to predict_ms. */
static void predict_pass(rp__engine *e, double rho) {
  rp_frame_stats *st = &e->stats;
  rp_cost_estimate est;
  float step, scale;
  double t0 = rp__engine_now_ms(e);
  rp_space_map(&e->space, rho, &step, &scale);
  if (rp_device_group_predict(e->group, &e->s.probe, step, scale, &est) ==
      0) {
    st->predicted_ms = st->pass_predicted_ms = est.ms;
    st->samples_predicted = est.samples * est.sample_ratio;
    st->fetches = est.fetches;
    st->sigma_predicted_ns = est.sigma_ns;
  } else {
    st->predicted_ms = st->pass_predicted_ms = st->samples_predicted = NAN;
    st->fetches = st->sigma_predicted_ns = NAN;
  }
  st->predict_ms += rp__engine_now_ms(e) - t0;
}

/* How new the coming frame is to the cost model, at the last frame's
 * density (rp_cost_estimate.novelty); 1 when the model cannot say. */
static double frame_novelty(rp__engine *e) {
  rp_cost_estimate est;
  float step, scale;
  rp_space_map(&e->space, e->rho_last > 0.0 ? e->rho_last : 1.0, &step,
               &scale);
  if (rp_device_group_predict(e->group, &e->s.probe, step, scale, &est) !=
          0 ||
      !isfinite(est.novelty))
    return 1.0;
  return est.novelty;
}

/* Controller, prediction and the render passes of one frame. The time the
 * frame already spent (recompute, probe) is known exactly when the
 * controller decides: it is taken off the target, and only the render
 * passes are predicted and learned. Frames with and without a probe then
 * cost the same in total, where a model that learned the probe as part of
 * an average c0 was wrong both ways. */
static int render_frame(rp__engine *e) {
  scene *s = &e->s;
  rp_frame_stats *st = &e->stats;
  double rho, t0, pass_ms = 0.0, budget, upload_before = 0.0;
  double spent = rp__engine_now_ms(e) - e->begin_ms;
  int err, again = 1;
  st->upload_predicted_ms = predicted_upload_ms(e);
  spent += st->upload_predicted_ms;
  budget = s->target_ms - spent;
  if (budget < MIN_RENDER_SHARE * s->target_ms)
    budget = MIN_RENDER_SHARE * s->target_ms;
  t0 = rp__engine_now_ms(e);
  st->novelty = frame_novelty(e);
  rp_controller_set_novelty(s->controller, st->novelty);
  if ((err = rp_controller_begin_frame(s->controller, budget, predict_at, e,
                                       &rho)) != 0)
    return err;
  st->predict_ms = rp__engine_now_ms(e) - t0;
  st->margin = rp_controller_margin(s->controller);
  while (again) {
    predict_pass(e, rho);
    upload_before = st->upload_ms;
    if ((err = render_pass(e, rho, &pass_ms)) != 0) {
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
  e->rho_last = rho;
  st->measured_ms = rp__engine_now_ms(e) - e->begin_ms;
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

/* A frame that ended before any render pass reported its devices (an
 * upload found none left, say) still says which devices the runtime
 * opened and which of them are lost, as rp_frame_stats promises: the
 * app learns of a loss from every frame, not only from rendered ones. */
static void report_members(rp__engine *e) {
  rp_frame_stats *st = &e->stats;
  uint32_t i, n = rp_device_group_count(e->group);
  st->device_count = n;
  st->devices_alive = rp_device_group_alive(e->group);
  for (i = 0; i < n && i < RP_RUNTIME_MAX_DEVICES; i++) {
    const rp__member *w = &e->group->m[i];
    rp_device_frame *df = &st->devices[i];
    snprintf(df->name, sizeof df->name, "%s", w->name);
    df->dropped = w->dropped;
    df->state = w->state;
    df->failures = w->failures;
    /* Lost in an AO job since its last render: why, as the next render's
     * report will say it. */
    if (w->ao_lost != 0) {
      df->status = w->ao_lost;
      snprintf(df->error, sizeof df->error, "%s", w->why);
    }
  }
}

void rp__engine_frame(rp__engine *e, rp__events *in, uint64_t frame_no,
                      uint64_t events, rp_frame *out) {
  rp_frame_stats *st = &e->stats;
  int err;
  e->begin_ms = rp__engine_now_ms(e);
  e->frame_no = frame_no;
  memset(st, 0, sizeof *st);
  st->frame = frame_no;
  st->events = events;
  st->predicted_ms = st->delta = st->learn_ms = NAN;
  st->samples_predicted = st->fetches = st->sigma_predicted_ns = NAN;
  st->pass_predicted_ms = NAN;
  e->out_rgba = NULL;
  e->train.valid = 0;
  rp__clear_error(e->ctx);
  take_events(e, in);
  st->controller = e->s.controller_kind;
  st->target_ms = e->s.target_ms;
  if ((err = recompute(e)) == 0)
    err = render_frame(e);
  st->effects = e->s.render_effects;
  st->effects_wanted = e->s.effects;
  if (st->device_count == 0)
    report_members(e);
  if (err != 0) {
    st->status = err;
    snprintf(st->error, sizeof st->error, "%s", rp_last_error(e->ctx));
    e->out_rgba = NULL;
    e->train.valid = 0;
    st->learn_ms = NAN;
  }
  out->rgba = e->out_rgba;
  out->width = e->out_w;
  out->height = e->out_h;
  out->stats = st;
  out->probe = err == 0 ? &e->s.probe : NULL;
}

double rp__engine_train(rp__engine *e) {
  training *t = &e->train;
  double t0 = rp__now_ms();
  if (!t->valid)
    return 0.0;
  /* A refused sample (a zero-sample frame, say) teaches nothing; the
   * models stay as they were, which is the right outcome. */
  (void)rp_device_group_train(e->group, &t->probe, t->step, t->scale,
                              t->pass_ms);
  t->valid = 0;
  return rp__now_ms() - t0;
}

/* ---- Lifetime ------------------------------------------------------------ */

int rp__engine_create(rp_context *ctx, const rp_runtime_desc *desc,
                      rp__engine **out) {
  rp__engine *e;
  rp_group_desc gd = {0};
  uint64_t ns;
  int err;
  e = rp__calloc(ctx, 1, sizeof *e);
  if (e == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_runtime_create: out of memory");
  if (pthread_mutex_init(&e->count_lock, NULL) != 0) {
    rp__free(ctx, e);
    return rp__fail(ctx, RP_EDEVICE, "rp_runtime_create: "
                    "pthread_mutex_init failed");
  }
  e->ctx = ctx;
  e->desc = *desc;
  e->desc.devices = NULL; /* the group copies them */
  e->space = desc->space;
  e->s.target_ms = desc->target_ms;
  e->s.width = desc->width;
  e->s.height = desc->height;
  e->s.effects = desc->effects;
  e->s.controller_kind = desc->controller;
  e->s.density = desc->density;
  gd.devices = desc->device_count > 0 ? desc->devices : &desc->device;
  gd.count = desc->device_count > 0 ? desc->device_count : 1;
  gd.damping = desc->damping;
  gd.model = desc->model;
  if ((err = rp_device_group_create(ctx, &gd, &e->group)) != 0) {
    rp__engine_destroy(e);
    return err;
  }
  /* One device that keeps its own clock sets the engine's time; with
   * several, each has its own and the frame's is the wall clock's. */
  e->own_clock = rp_device_group_count(e->group) == 1 &&
                 rp__group_clock_ns(e->group, 0, &ns);
  *out = e;
  return 0;
}

void rp__engine_destroy(rp__engine *e) {
  rp_context *ctx;
  scene *s;
  if (e == NULL)
    return;
  ctx = e->ctx;
  s = &e->s;
  drop_ao_run(s);
  rp_controller_destroy(s->controller);
  /* The group first: it holds the volume, TF and AO below for devices
   * that come back, and a late worker may still read them until the
   * group has joined it. */
  rp_device_group_destroy(e->group);
  rp_occupancy_destroy(s->occ);
  rp_histograms_destroy(s->h);
  rp_tf_destroy(s->tf);
  rp_tf_destroy(s->ao_tf);
  rp__ao_ranges_destroy(s->ao_ranges);
  rp_ao_destroy(s->ao_given);
  rp_volume_destroy(s->vol);
  rp__free(ctx, e->scaled);
  rp__free(ctx, e->image);
  rp__free(ctx, e->tiles);
  pthread_mutex_destroy(&e->count_lock);
  rp__free(ctx, e);
}
