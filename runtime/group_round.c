/* One round of a group's frame on the devices' executors (group.h).
 *
 * The caller's thread is the coordinator: it hands each device a job
 * and waits. A job runs on the device's executor, the one thread that
 * calls the device; the hand-over is g->lock, so a job's inputs and
 * outputs are ordered by it. The tail's strips (rp_group_desc.
 * tail_fraction) are claimed under the lock by the worker that finished
 * a job, or handed by the coordinator to a device that is idle. A device
 * still rendering past its deadline is given up on and its worker left
 * running: it renders into buffers of its own, which the caller's image
 * never sees again. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "group.h"
#include "passes.h"

static double now_ms(void) { return (double)uv_hrtime() * 1e-6; }

/* Now on w's own clock, for its worker's timings: the device's when it
 * keeps one (the test backend: a job's time is then its simulated time,
 * an injected stall included, and a group of test devices learns and
 * splits the same on every run and machine), else the wall's. Deadlines
 * stay in wall time: only real time can run late. */
static double member_ms(const rp__member *w) {
  uint64_t ns;
  if (rp__device_clock_ns(w->dev, &ns))
    return (double)ns * 1e-6;
  return now_ms();
}

/* ---- Jobs ---------------------------------------------------------------- */

static int reserve(rp__member *w, void **buf, size_t *cap, size_t bytes) {
  void *p;
  if (bytes <= *cap)
    return 0;
  if ((p = rp__malloc(w->ctx, bytes)) == NULL)
    return rp__fail(w->ctx, RP_ENOMEM, "device group: %zu bytes for '%s'",
                    bytes, w->name);
  rp__free(w->ctx, *buf);
  *buf = p;
  *cap = bytes;
  return 0;
}

static int do_render(rp__member *w) {
  rp_render_desc *d = &w->desc;
  const rp_region *r = &w->region;
  uint32_t sw, sh, tx, ty, x, y;
  rp__depth_key key;
  double t0;
  int err;
  rp_scaled_size(d, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  if ((err = reserve(w, (void **)&w->rgba, &w->rgba_cap,
                     (size_t)sw * sh * 4)) != 0 ||
      (err = reserve(w, (void **)&w->tiles, &w->tiles_cap,
                     (size_t)tx * ty * sizeof(rp_tile_stats))) != 0)
    return err;
  memset(&key, 0, sizeof key);
  key.cam = w->cam;
  key.sw = sw;
  key.sh = sh;
  key.skip = (d->effects & RP_EFFECT_SKIP) != 0;
  key.vol_gen = w->vol_gen;
  key.tf_gen = w->tf_gen;
  if (!w->key_valid || memcmp(&key, &w->key, sizeof key) != 0) {
    w->key_valid = 0;
    t0 = member_ms(w);
    if ((err = rp_device_depth_pass(w->dev, &w->cam, d, NULL)) != 0)
      return err;
    w->depth_ms = member_ms(w) - t0;
    w->depth_passes = 1;
    w->key = key;
    w->key_valid = 1;
  }
  if ((err = rp_device_render(w->dev, &w->cam, d, r, w->rgba, w->tiles)) !=
      0)
    return err;
  w->raycast_ms = (double)rp_device_last_time_ns(w->dev) * 1e-6;
  {
    /* Bricks uploaded first are no part of the raycast the cost model
     * learns: the runtime predicts them on their own. */
    rp_brick_stats st;
    if (rp_device_get_brick_stats(w->dev, &st) == 0 && st.out_of_core) {
      w->upload_ms = (double)st.last_upload_ns * 1e-6;
      w->raycast_ms = fmax(w->raycast_ms - w->upload_ms, 0.0);
    }
  }
  for (y = r->y0 / RP_TILE_SIZE; y * RP_TILE_SIZE < r->y1; y++)
    for (x = r->x0 / RP_TILE_SIZE; x * RP_TILE_SIZE < r->x1; x++)
      w->samples += w->tiles[(size_t)y * tx + x].samples;
  return 0;
}

/* Runs one job of w's on the calling thread (its executor's). */
static void run_job(rp__member *w, int kind) {
  double t0 = member_ms(w);
  int err = 0;
  rp__clear_error(w->ctx);
  w->depth_ms = w->raycast_ms = w->upload_ms = 0.0;
  w->depth_passes = 0;
  w->samples = 0;
  switch (kind) {
  case RP__JOB_VOLUME:
    w->key_valid = 0;
    w->warm_sets = 0;
    err = rp_device_set_volume(w->dev, w->vol);
    break;
  case RP__JOB_TF:
    w->key_valid = 0;
    err = rp_device_set_tf(w->dev, w->tf, w->occ);
    break;
  case RP__JOB_AO:
    err = rp_device_set_ao(w->dev, w->ao);
    break;
  case RP__JOB_RENDER:
    err = do_render(w);
    break;
  case RP__JOB_ESTIMATE:
    err = rp_device_upload_estimate(w->dev, &w->cam, &w->desc, NULL,
                                    &w->est);
    break;
  default:
    break;
  }
  w->status = err;
  if (err != 0)
    snprintf(w->error, sizeof w->error, "%s", rp_last_error(w->ctx));
  else if (kind == RP__JOB_VOLUME)
    w->have_vol_gen = w->vol_gen;
  else if (kind == RP__JOB_TF)
    w->have_tf_gen = w->tf_gen;
  else if (kind == RP__JOB_AO)
    w->have_ao_gen = w->ao_gen;
  w->busy_ms = member_ms(w) - t0;
  if (kind == RP__JOB_RENDER && err == 0) {
    w->round.depth_ms += w->depth_ms;
    w->round.raycast_ms += w->raycast_ms;
    w->round.upload_ms += w->upload_ms;
    w->round.busy_ms += w->busy_ms;
    w->round.depth_passes += w->depth_passes;
    w->round.samples += w->samples;
    w->round.jobs++;
  }
}

static int next_strip(rp_device_group *g, rp__member *w, double now);

void rp__group_member_job(rp__job *job, rp_context *ctx) {
  rp__member *w = RP__JOB_OWNER(job, rp__member, job);
  rp_device_group *g = w->g;
  int kind = w->kind;
  (void)ctx; /* the device's context: w->ctx */
  for (;;) {
    run_job(w, kind);
    uv_mutex_lock(&g->lock);
    w->ao_bytes = rp_device_ao_bytes(w->dev);
    /* In the tail, a device goes from one strip to the next itself: a
     * hand-back through the coordinator costs two thread wake-ups, a
     * millisecond or more each on a machine whose cores the devices
     * hold. Not once it was given up on (no longer pending). */
    if (kind == RP__JOB_RENDER && w->pending && g->tail_active &&
        next_strip(g, w, now_ms())) {
      if (w->deadline < g->wake_at)
        uv_cond_broadcast(&g->done);
      uv_mutex_unlock(&g->lock);
      continue;
    }
    w->running = 0;
    uv_cond_broadcast(&g->done);
    uv_mutex_unlock(&g->lock);
    return;
  }
}

void rp__group_start_job(rp_device_group *g, rp__member *w, int kind) {
  uv_mutex_lock(&g->lock);
  w->pending = 1;
  w->kind = kind;
  w->running = 1;
  uv_mutex_unlock(&g->lock);
  rp__executor_submit(w->ex, &w->job);
}

int rp__group_run_one(rp_device_group *g, rp__member *w, int kind) {
  w->deadline = INFINITY;
  w->by_peers = 0;
  rp__group_start_job(g, w, kind);
  rp__group_wait(g, NULL, 0.0);
  return w->outcome;
}

int rp__member_warm(rp_device_group *g, rp__member *w, uint32_t effects) {
  int building;
  if (!((w->warm_sets >> (effects & 31u)) & 1u))
    return 0;
  /* A build on its lane competes with its render for the device (and
   * for the host's cores, with a CPU device): not the device's own
   * speed either. */
  uv_mutex_lock(&g->build_lock);
  building = w->build_queued;
  uv_mutex_unlock(&g->build_lock);
  return !building;
}

/* ---- The tail ------------------------------------------------------------ */

/* How late, as a fraction of its expected job time, a busy peer may be
 * and still be counted on to take strips (worth_taking). */
#define LATE_SLACK 0.5

/* Whether w taking strip s ends the frame sooner than leaving it: not
 * when a peer still busy would finish its job and every free strip (s
 * included) before w finished s alone, by their rates. A slow device
 * then takes strips early in the tail, when the fast one has many left,
 * and leaves the last ones, which it would finish after the fast one had
 * done them all. A peer is counted on until it is late by half its
 * expected job time or by w's time for s, whichever is more: a model's
 * error or a thread's wake-up is not a stall, and a peer that is late
 * by more than w's strip would take has likely stalled (descheduled),
 * so w takes it. When it declines, *retry is when to ask again: the
 * earliest time a peer it counted on stops counting. */
static int worth_taking(const rp_device_group *g, const rp__member *w,
                        uint32_t s, double now, double *retry) {
  double mine = w->sm.rate * g->strip_cost[s], free_cost = 0.0;
  uint32_t k;
  int take = 1;
  if (!(w->sm.rate > 0.0))
    return 1;
  for (k = 0; k < g->strip_n; k++)
    if (g->strip_state[k] == RP__STRIP_FREE)
      free_cost += g->strip_cost[k];
  for (k = 0; k < g->count; k++) {
    const rp__member *o = &g->m[k];
    double patience;
    /* A member's job fields are written before it is made pending, under
     * g->lock: read them only once it is. */
    if (o == w || !o->pending || !(o->sm.rate > 0.0))
      continue;
    patience = o->job_end + fmax(LATE_SLACK * o->job_len, mine);
    if (!(now <= patience))
      continue;
    if (fmax(o->job_end - now, 0.0) + o->sm.rate * free_cost < mine) {
      take = 0;
      *retry = fmin(*retry, patience);
    }
  }
  return take;
}

/* Gives w (idle, under g->lock) the first free tail strip, with a
 * deadline from its rate when it has one, if worth_taking; the caller
 * runs the job (its worker) or submits it (the coordinator). 1: given;
 * 0: none free, or left to a faster peer (*retry: see worth_taking). */
static int claim_strip(rp_device_group *g, rp__member *w, double now,
                       double *retry) {
  uint32_t s;
  for (s = 0; s < g->strip_n && g->strip_state[s] != RP__STRIP_FREE; s++)
    ;
  if (s == g->strip_n || !worth_taking(g, w, s, now, retry))
    return 0;
  g->strip_state[s] = RP__STRIP_CLAIMED;
  w->strip = (int)s;
  w->region = g->strip_px[s];
  w->by_peers = 0;
  w->deadline = INFINITY;
  w->job_len = w->sm.rate * g->strip_cost[s];
  if (w->round.jobs == 0) /* its first job this round: the depth pass */
    w->job_len += w->sm.depth_freq * w->sm.depth_est;
  w->job_end = w->sm.rate > 0.0 ? now + w->job_len : INFINITY;
  if (g->desc.deadline_factor > 0.0 && w->sm.rate > 0.0 &&
      rp__member_warm(g, w, w->desc.effects))
    w->deadline = now + fmax(g->desc.deadline_min_ms,
                             g->desc.deadline_factor * w->job_len);
  w->started = 1;
  w->pending = 1;
  w->kind = RP__JOB_RENDER;
  w->running = 1;
  return 1;
}

/* w's job ended (under g->lock): settles the strip it rendered -- done,
 * or free again for the others if it failed -- and, if it succeeded,
 * gives it the next free strip. 1: given. */
static int next_strip(rp_device_group *g, rp__member *w, double now) {
  double retry = INFINITY; /* left to a peer: feed_idle offers it again */
  int s = w->strip;
  w->strip = -1;
  if (s < 0 && w->status == 0)
    w->region_done = 1;
  if (s >= 0 && w->status == 0) {
    g->strip_state[s] = RP__STRIP_DONE;
    g->strip_owner[s] = (uint8_t)w->index;
    w->strips_done++;
    w->strip_cost += g->strip_cost[s];
  } else if (s >= 0) {
    g->strip_state[s] = RP__STRIP_FREE;
  }
  return w->status == 0 && claim_strip(g, w, now, &retry);
}

/* Free strips -- freed by a device that failed or ran late, or left by
 * an idle one to a faster peer -- go to devices that finished (under
 * g->lock, and submitted under it: a tail has two devices or more, whose
 * executors have workers, so no job runs inside submit). Returns when to
 * offer them again (INFINITY: no need). */
static double feed_idle(rp_device_group *g, double now) {
  double retry = INFINITY;
  uint32_t i;
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    if (w->started && !w->pending && w->outcome == 0 && !w->dropped &&
        !w->running && claim_strip(g, w, now, &retry))
      rp__executor_submit(w->ex, &w->job);
  }
  return retry;
}

/* ---- Waiting ------------------------------------------------------------- */

/* Members whose job has ended (under g->lock) are no longer pending:
 * their outcome is taken. Returns the longest whole round of those that
 * succeeded, at least `peer_ms`. */
static double settle_ended(rp_device_group *g, double peer_ms) {
  uint32_t i;
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    if (!w->pending || w->running)
      continue;
    /* With a tail its worker has settled its strip and found none to
     * take (member_job); feed_idle offers it any freed since. */
    w->pending = 0;
    w->outcome = w->status;
    memcpy(w->why, w->error, sizeof w->why);
    /* Its whole round: with a tail, busy_ms is its last strip's. */
    if (w->outcome == 0 && w->round.busy_ms > peer_ms)
      peer_ms = w->round.busy_ms;
  }
  return peer_ms;
}

/* Gives up on the pending members past their deadline (under g->lock);
 * returns the earliest deadline of the others (INFINITY: none). */
static double give_up_late(rp_device_group *g, rp_group_report *rep,
                           double start, double peer_ms, double now) {
  double next = INFINITY;
  uint32_t i;
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    if (!w->pending)
      continue;
    /* Late only once a peer finished: someone must re-render the
     * region, and the last device is never given up on. */
    if (peer_ms <= 0.0)
      continue;
    if (w->by_peers)
      w->deadline = start + fmax(g->desc.deadline_min_ms,
                                 g->desc.deadline_factor * peer_ms);
    if (w->deadline <= now) {
      char why[sizeof w->why];
      w->pending = 0;
      w->outcome = RP_EDEVICE;
      snprintf(why, sizeof why, "device '%s' still rendering %.1f ms "
               "after its deadline", w->name, now - w->deadline);
      memcpy(w->why, why, sizeof why);
      /* What its late work will have cost when it ends: a strip's
       * predicted cost, or (-1) its region's, which the round knows. */
      w->gave_up = 1;
      w->late_cost = w->strip >= 0 ? g->strip_cost[w->strip] : -1.0;
      if (w->strip >= 0)
        g->strip_state[w->strip] = RP__STRIP_FREE;
      w->strip = -1;
      if (rep != NULL)
        rep->devices[i].late = 1;
      continue;
    }
    if (w->deadline < next)
      next = w->deadline;
  }
  return next;
}

/* A member without a model of its own (by_peers) gets its deadline when
 * a peer finishes: deadline_factor times the longest peer's time since
 * `start` -- a device that many times slower than its peers at an even
 * split is not worth waiting for. */
void rp__group_wait(rp_device_group *g, rp_group_report *rep,
                    double start) {
  uint32_t i;
  double peer_ms = 0.0;
  uv_mutex_lock(&g->lock);
  for (;;) {
    double next, now = now_ms();
    int waiting;
    peer_ms = settle_ended(g, peer_ms);
    next = give_up_late(g, rep, start, peer_ms, now);
    if (g->tail_active) {
      next = fmin(next, feed_idle(g, now));
      for (i = 0; i < g->count; i++) /* the jobs feed_idle started */
        if (g->m[i].pending && g->m[i].deadline > now)
          next = fmin(next, g->m[i].deadline);
    }
    for (waiting = 0, i = 0; i < g->count; i++)
      waiting |= g->m[i].pending;
    if (!waiting)
      break;
    /* A worker that takes a strip itself wakes the coordinator only when
     * the strip's deadline comes before this. */
    g->wake_at = next;
    if (isinf(next)) {
      uv_cond_wait(&g->done, &g->lock);
    } else {
      double ms = next - now;
      (void)uv_cond_timedwait(&g->done, &g->lock,
                              (uint64_t)(ms * 1e6) + 1u);
    }
  }
  uv_mutex_unlock(&g->lock);
}

/* ---- The round ----------------------------------------------------------- */

/* Copies w's region (pixels) from its buffers into the caller's. */
static void take_region(const rp__member *w, const rp_region *r,
                        uint32_t sw, uint32_t tx, uint8_t *rgba,
                        rp_tile_stats *tiles) {
  uint32_t y, x;
  size_t row = (size_t)(r->x1 - r->x0) * 4;
  for (y = r->y0; y < r->y1; y++)
    memcpy(rgba + ((size_t)y * sw + r->x0) * 4,
           w->rgba + ((size_t)y * sw + r->x0) * 4, row);
  if (tiles == NULL)
    return;
  for (y = r->y0 / RP_TILE_SIZE; y * RP_TILE_SIZE < r->y1; y++)
    for (x = r->x0 / RP_TILE_SIZE; x * RP_TILE_SIZE < r->x1; x++)
      tiles[(size_t)y * tx + x] = w->tiles[(size_t)y * tx + x];
}

/* w's job and deadline for its region px (not empty) of frame f. */
static void region_job(rp_device_group *g, rp__member *w,
                       const rp__frame *f, const rp_region *px) {
  double predicted = f->predicted[w->index];
  w->region = *px;
  w->deadline = INFINITY;
  w->by_peers = 0;
  w->job_end = INFINITY;
  w->job_len = 0.0;
  if (g->tail_active && w->sm.rate > 0.0) {
    rp_region tr = {px->x0 / RP_TILE_SIZE, px->y0 / RP_TILE_SIZE,
                    (px->x1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE,
                    (px->y1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE};
    w->job_len = w->sm.depth_freq * w->sm.depth_est +
                 w->sm.rate * rp__region_cost(g->cost, f->tx, &tr);
    w->job_end = f->start + w->job_len;
  }
  if (g->desc.deadline_factor > 0.0 && !isinf(predicted) &&
      rp__member_warm(g, w, f->d.effects)) {
    if (w->trained && isfinite(predicted))
      w->deadline = f->start + fmax(g->desc.deadline_min_ms,
                                    g->desc.deadline_factor * predicted);
    else
      w->by_peers = 1;
  }
}

/* Starts every live device on its region of the round (an idle one, with
 * a tail, waits for strips). */
static void round_start(rp_device_group *g, const rp_camera *cam,
                        const rp__frame *f, rp_group_report *rep,
                        int first_round) {
  uint32_t i;
  /* Workers started below read their peers' state (worth_taking): all
   * of it is reset first, under the lock. */
  uv_mutex_lock(&g->lock);
  for (i = 0; i < g->count; i++) {
    g->m[i].pending = g->m[i].started = g->m[i].region_done = 0;
    g->m[i].gave_up = 0;
    g->m[i].strip = -1;
  }
  uv_mutex_unlock(&g->lock);
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    if (w->dropped)
      continue;
    memset(&w->round, 0, sizeof w->round);
    w->cam = *cam;
    w->desc = f->d;
    if (first_round)
      rep->devices[i].region = f->px[i];
    if (rp__region_empty(&f->px[i])) {
      /* Without a region it is idle from the start: the wait offers it
       * strips (feed_idle). */
      w->started = g->tail_active;
      w->outcome = 0;
      continue;
    }
    region_job(g, w, f, &f->px[i]);
    w->started = 1;
    rp__group_start_job(g, w, RP__JOB_RENDER);
  }
}

/* What member i's round came to: its region taken, or lost (its region
 * added to f->lost and the member dropped: late or failed, as
 * group_health.c says). Returns the error it was lost with, 0
 * otherwise. */
static int round_settle(rp_device_group *g, uint32_t i, rp__frame *f,
                        uint8_t *rgba, rp_tile_stats *tiles,
                        rp_group_report *rep) {
  rp__member *w = &g->m[i];
  rp_group_device *rd = &rep->devices[i];
  if (w->outcome != 0) {
    if (w->gave_up)
      rp__health_late(g, w, w->late_cost >= 0.0 ? w->late_cost
                                                 : f->cost_abs[i]);
    else
      rp__health_fail(g, w);
    rd->status = w->outcome;
    snprintf(rd->error, sizeof rd->error, "%s", w->why);
    rd->dropped = 1;
    rep->lost++;
    rp__fail(g->ctx, w->outcome, "device group: %s", w->why);
    /* Lost on a strip, its region is done and in its buffer, which its
     * late worker (writing the strip) does not touch. */
    if (w->region_done)
      take_region(w, &f->px[i], f->sw, f->tx, rgba, tiles);
    else if (!rp__region_empty(&f->px[i]))
      f->lost[f->n_lost++] = f->px[i];
    return w->outcome;
  }
  if (w->round.jobs == 0)
    return 0; /* no region, and no strip came its way */
  if (!rp__region_empty(&f->px[i]))
    take_region(w, &f->px[i], f->sw, f->tx, rgba, tiles);
  w->warm_sets |= 1u << (f->d.effects & 31u);
  rd->depth_ms += w->round.depth_ms;
  rd->depth_passes += w->round.depth_passes;
  rd->raycast_ms += w->round.raycast_ms;
  rd->upload_ms += w->round.upload_ms;
  rd->busy_ms += w->round.busy_ms;
  rd->samples += w->round.samples;
  w->rendered = 1;
  w->frame_raycast_ms += w->round.raycast_ms;
  w->frame_upload_ms += w->round.upload_ms;
  w->frame_busy_ms += w->round.busy_ms;
  w->frame_samples += w->round.samples;
  return 0;
}

/* The tail's strips into the caller's image: each from the buffer of the
 * device that finished it, which no job of that device writes again this
 * frame (a worker writes only its job's pixels, and a strip a device is
 * late on is not one of them); the others to f->lost. */
static void tail_settle(rp_device_group *g, rp__frame *f, uint8_t *rgba,
                        rp_tile_stats *tiles, rp_group_report *rep) {
  uint32_t s;
  for (s = 0; s < g->strip_n; s++) {
    if (g->strip_state[s] == RP__STRIP_DONE) {
      take_region(&g->m[g->strip_owner[s]], &g->strip_px[s], f->sw, f->tx,
                  rgba, tiles);
      rep->strip_device[s] = g->strip_owner[s];
    } else {
      f->lost[f->n_lost++] = g->strip_px[s];
      rep->strip_device[s] = RP_GROUP_MAX_DEVICES;
    }
  }
  uv_mutex_lock(&g->lock); /* a late worker reads it */
  g->tail_active = 0;
  uv_mutex_unlock(&g->lock);
}

int rp__group_round(rp_device_group *g, const rp_camera *cam, rp__frame *f,
                    uint8_t *rgba, rp_tile_stats *tiles,
                    rp_group_report *rep, int first_round) {
  uint32_t i;
  int last = 0, err;
  round_start(g, cam, f, rep, first_round);
  rp__group_wait(g, rep, f->start);
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    if (!w->started)
      continue;
    if (w->outcome != 0 && !rp__group_loses_device(w->outcome, 0)) {
      rep->devices[i].status = w->outcome;
      snprintf(rep->devices[i].error, sizeof rep->devices[i].error, "%s",
               w->why);
      f->refused = rp__fail(g->ctx, w->outcome, "%s", w->why);
      continue;
    }
    if ((err = round_settle(g, i, f, rgba, tiles, rep)) != 0)
      last = err;
  }
  if (g->tail_active)
    tail_settle(g, f, rgba, tiles, rep);
  return last;
}
