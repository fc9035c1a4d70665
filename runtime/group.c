/* Several devices rendering one frame (DESIGN section 7).
 *
 * The group's thread (the caller's) is the coordinator: it computes the
 * shares and the split, hands each device a job and waits. The tail's
 * strips (rp_group_desc.tail_fraction) are claimed under `lock` by the
 * worker that finished a job, or handed by the coordinator to a device
 * that is idle. Each device
 * has a worker thread (two devices or more) that owns the device and its
 * buffers while a job runs; the hand-over is `lock`, so a job's inputs
 * and outputs are ordered by it. A worker renders into buffers of its
 * own, never into the caller's image: a device given up on at its
 * deadline may still be writing when the others have re-rendered its
 * region, and the caller's image must not see it. The coordinator copies
 * each finished region across, which costs one image copy per frame.
 *
 * Dropped devices stay dropped: their worker may still be busy with the
 * job they were late on, and only destroy waits for it.
 *
 * Kernels a coming frame needs can be built ahead (rp_device_group_
 * prepare) on one more thread, the builder, started on the first request:
 * it calls rp_device_prepare, the one device call made for any thread,
 * on the devices live when it was asked, which stay open until destroy
 * has joined it. */
#ifdef __linux__
#define _GNU_SOURCE /* syscall(SYS_gettid): see builder_main */
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <uv.h>

#include "internal.h"
#include "raypace_ao.h"
#include "passes.h"
#include "raypace_group.h"

enum { JOB_NONE, JOB_VOLUME, JOB_TF, JOB_AO, JOB_RENDER, JOB_QUIT };

#define DEFAULT_DEADLINE_FACTOR 4.0
/* bench_balance, cl-slow and cl-vk pairs, 512^2, 40 frames, three runs
 * each: the balance deviation 0.036-0.071 with a 0.15 tail against
 * 0.095-0.204 without, the frame time within the runs' noise
 * (docs/runtime.md). */
#define DEFAULT_TAIL_FRACTION 0.15
/* A stall a shared machine can produce (a descheduled thread) must not
 * cost a device for good. */
#define DEFAULT_DEADLINE_MIN_MS 200.0
/* A device trains only on a region that took at least this fraction of
 * the frame's samples: a sliver's time is mostly launch and readback,
 * and scaled up to a whole frame it would teach noise. */
#define MIN_TRAIN_FRACTION 0.02
/* The least fraction of the frame's predicted cost a region must have for
 * its time to raise the device's rate. A sliver's time is mostly what
 * every render costs (launch, readback); taken as a rate, it would make
 * the device look slow, give it a thinner sliver, and so on down. It is
 * still an upper bound on the rate, so a sliver that measures lower than
 * the rate counts: a device squeezed by one stalled frame recovers. */
#define MIN_RATE_FRACTION 0.05
/* The rate is the median of the device's last RATE_FRAMES measured
 * rates: one stalled frame (a descheduled thread on a shared machine:
 * 10x and more) moves nothing, a device that really slows down is
 * followed from its second frame. */
#define RATE_FRAMES 3

/* What a device's current depth pass was run for (memset before filling:
 * compared with memcmp). */
typedef struct depth_key {
  rp_camera cam;
  uint32_t sw, sh, skip;
  uint64_t vol_gen, tf_gen;
} depth_key;

/* A member's figures summed over its render jobs. */
typedef struct job_sums {
  double depth_ms, raycast_ms, upload_ms, busy_ms;
  uint32_t depth_passes, jobs;
  uint64_t samples;
} job_sums;

enum { STRIP_FREE, STRIP_CLAIMED, STRIP_DONE };

typedef struct member {
  rp_device_group *g;
  uint32_t index;
  rp_context *ctx; /* the device's own: errors on two threads at once */
  rp_device *dev;
  rp_caps caps;
  char name[168];
  rp_cost_model *model;
  int dropped, trained;
  /* Effect sets it has rendered since its volume upload, bit (1 << set):
   * a set's first render builds a kernel variant, which no deadline may
   * count as the device being slow. */
  uint32_t warm_sets;
  uv_thread_t thread;
  int thread_started;
  uv_cond_t wake;

  /* The job, under g->lock: `job` is set by the coordinator and cleared
   * by the worker when it is done; `busy` while it runs. */
  int job, busy;
  const rp_volume *vol;
  const rp_tf *tf;
  const rp_occupancy *occ;
  const rp_ao *ao;      /* JOB_AO: NULL releases the device's AO */
  double ao_speed;      /* full bricks per ms of its last AO work; 0:
                           unknown */
  rp_camera cam;
  rp_render_desc desc;
  rp_region region;
  uint64_t vol_gen, tf_gen;

  /* Results, the worker's during a job, the coordinator's after it. */
  int status;
  char error[256];
  uint8_t *rgba;
  size_t rgba_cap;
  rp_tile_stats *tiles;
  size_t tiles_cap;
  double depth_ms, raycast_ms, busy_ms;
  double upload_ms; /* out of core: bricks uploaded for the render */
  uint32_t depth_passes;
  uint64_t samples;
  depth_key key;
  int key_valid;
  /* Its render jobs that succeeded this round, banked by the worker as
   * each ends: the fields above hold the last job only, and with a tail
   * a device renders its region and then strips. */
  job_sums round;

  /* The coordinator's, per frame. `outcome` and `why` are the job's
   * status and message, taken under the lock when it ended (a late
   * worker's own fields stay its own). */
  double deadline;  /* absolute ms; INFINITY: none */
  /* When its job should end by its rate (absolute ms), and how long it
   * should take: INFINITY and 0 while it has no rate. */
  double job_end, job_len;
  int by_peers;     /* no model yet: deadline from the peers' times */
  int pending, outcome;
  char why[256];
  double frame_raycast_ms, frame_busy_ms, frame_upload_ms;
  uint64_t frame_samples;
  int rendered;     /* rendered a region this frame */
  int started;      /* given a job this round */
  int region_done;  /* its region's job succeeded (known with a tail) */
  int strip;        /* the tail strip its current job renders; -1 none */
  uint32_t strips_done; /* tail strips it finished this frame */
  double strip_cost;    /* and their predicted cost */
  /* The split's model of the device (see frame_shares): wall ms per unit
   * of predicted tile cost outside its depth pass (0: unknown), its depth
   * pass's ms, and how often a frame needs one (running mean). */
  double rate, depth_est, depth_freq;
  double rates[RATE_FRAMES]; /* the last measured rates, a ring */
  uint32_t n_rates, next_rate;
} member;

struct rp_device_group {
  rp_context *ctx;
  rp_group_desc desc;
  double fixed_shares[RP_GROUP_MAX_DEVICES];
  uint32_t count;
  member m[RP_GROUP_MAX_DEVICES];
  uv_mutex_t lock;
  uv_cond_t done;
  int threads; /* workers run the jobs (count >= 2) */
  uint64_t vol_gen, tf_gen;
  double prev_shares[RP_GROUP_MAX_DEVICES];
  int have_prev;
  /* The members an AO run (rp_device_group_ao_begin) computes on: run
   * device i is member ao_members[i]. */
  uint32_t ao_members[RP_AO_MAX_DEVICES], ao_count;
  rp_balancer *balancer;
  uint32_t balancer_tiles;
  float *cost;
  double *sub_cost;
  size_t cost_cap;
  /* The first round's tail (rp_group_desc.tail_fraction), the
   * coordinator's, under `lock` while the round runs: each strip's
   * pixels, predicted cost, state and the device that finished it. */
  int tail_active;
  double wake_at; /* when wait_jobs next wakes by itself (absolute ms) */
  uint32_t strip_n;
  rp_region strip_px[RP_GROUP_MAX_STRIPS];
  double strip_cost[RP_GROUP_MAX_STRIPS];
  uint8_t strip_state[RP_GROUP_MAX_STRIPS];
  uint8_t strip_owner[RP_GROUP_MAX_STRIPS];
  /* The last frame's, for rp_device_group_train. */
  int can_train;
  double last_render_ms;
  uint64_t last_samples;
  /* The builder (rp_device_group_prepare). `can_prepare`: a device
   * builds ahead (else preparing is a no-op). Under build_lock: the
   * effect sets asked for (bit 1 << set) and not yet taken, the one
   * being built, those done for volume generation build_gen (tried: one
   * that failed is the frame's to build and report), and the devices of
   * the last request. */
  int can_prepare;
  uv_mutex_t build_lock;
  uv_cond_t build_cv;
  uv_thread_t builder;
  int builder_started, build_quit;
  rp_context *build_ctx; /* the builder's, for its errors */
  uint32_t build_want, build_busy, build_done;
  uint64_t build_gen;
  rp_device *build_devs[RP_GROUP_MAX_DEVICES];
  uint32_t build_ndev;
};

static double now_ms(void) { return (double)uv_hrtime() * 1e-6; }

/* ---- Jobs ---------------------------------------------------------------- */

static int reserve(member *w, void **buf, size_t *cap, size_t bytes) {
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

static int do_render(member *w) {
  rp_render_desc *d = &w->desc;
  const rp_region *r = &w->region;
  uint32_t sw, sh, tx, ty, x, y;
  depth_key key;
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
    t0 = now_ms();
    if ((err = rp_device_depth_pass(w->dev, &w->cam, d, NULL)) != 0)
      return err;
    w->depth_ms = now_ms() - t0;
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

/* Runs w's job on the calling thread. */
static void run_job(member *w, int job) {
  double t0 = now_ms();
  int err = 0;
  rp__clear_error(w->ctx);
  w->depth_ms = w->raycast_ms = w->upload_ms = 0.0;
  w->depth_passes = 0;
  w->samples = 0;
  switch (job) {
  case JOB_VOLUME:
    w->key_valid = 0;
    w->warm_sets = 0;
    err = rp_device_set_volume(w->dev, w->vol);
    break;
  case JOB_TF:
    w->key_valid = 0;
    err = rp_device_set_tf(w->dev, w->tf, w->occ);
    break;
  case JOB_AO:
    err = rp_device_set_ao(w->dev, w->ao);
    break;
  case JOB_RENDER:
    err = do_render(w);
    break;
  default:
    break;
  }
  w->status = err;
  if (err != 0)
    snprintf(w->error, sizeof w->error, "%s", rp_last_error(w->ctx));
  w->busy_ms = now_ms() - t0;
  if (job == JOB_RENDER && err == 0) {
    w->round.depth_ms += w->depth_ms;
    w->round.raycast_ms += w->raycast_ms;
    w->round.upload_ms += w->upload_ms;
    w->round.busy_ms += w->busy_ms;
    w->round.depth_passes += w->depth_passes;
    w->round.samples += w->samples;
    w->round.jobs++;
  }
}

static int next_strip(rp_device_group *g, member *w, double now);

static void worker_main(void *arg) {
  member *w = arg;
  rp_device_group *g = w->g;
  uv_mutex_lock(&g->lock);
  for (;;) {
    int job;
    while (w->job == JOB_NONE)
      uv_cond_wait(&w->wake, &g->lock);
    if (w->job == JOB_QUIT)
      break;
    job = w->job;
    w->busy = 1;
    uv_mutex_unlock(&g->lock);
    run_job(w, job);
    uv_mutex_lock(&g->lock);
    w->busy = 0;
    /* In the tail, a device goes from one strip to the next itself: a
     * hand-back through the coordinator costs two thread wake-ups, a
     * millisecond or more each on a machine whose cores the devices
     * hold. Not once it was given up on (no longer pending). */
    if (job == JOB_RENDER && w->pending && g->tail_active &&
        next_strip(g, w, now_ms())) {
      if (w->deadline < g->wake_at)
        uv_cond_broadcast(&g->done);
      continue;
    }
    w->job = JOB_NONE;
    uv_cond_broadcast(&g->done);
  }
  uv_mutex_unlock(&g->lock);
}

/* Starts `job` on w (its inputs are set): inline with one device. */
static void start_job(rp_device_group *g, member *w, int job) {
  if (!g->threads) {
    w->pending = 1;
    run_job(w, job);
    w->pending = 0;
    w->outcome = w->status;
    memcpy(w->why, w->error, sizeof w->why);
    return;
  }
  uv_mutex_lock(&g->lock);
  w->pending = 1;
  w->job = job;
  uv_cond_signal(&w->wake);
  uv_mutex_unlock(&g->lock);
}

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
static int worth_taking(const rp_device_group *g, const member *w,
                        uint32_t s, double now, double *retry) {
  double mine = w->rate * g->strip_cost[s], free_cost = 0.0;
  uint32_t k;
  int take = 1;
  if (!(w->rate > 0.0))
    return 1;
  for (k = 0; k < g->strip_n; k++)
    if (g->strip_state[k] == STRIP_FREE)
      free_cost += g->strip_cost[k];
  for (k = 0; k < g->count; k++) {
    const member *o = &g->m[k];
    double patience;
    /* A member's job fields are written before it is made pending, under
     * g->lock: read them only once it is. */
    if (o == w || !o->pending || !(o->rate > 0.0))
      continue;
    patience = o->job_end + fmax(LATE_SLACK * o->job_len, mine);
    if (!(now <= patience))
      continue;
    if (fmax(o->job_end - now, 0.0) + o->rate * free_cost < mine) {
      take = 0;
      *retry = fmin(*retry, patience);
    }
  }
  return take;
}

/* Starts w (idle, under g->lock) on the first free tail strip, with a
 * deadline from its rate when it has one, if worth_taking. 1: started;
 * 0: none free, or left to a faster peer (*retry: see worth_taking). */
static int claim_strip(rp_device_group *g, member *w, double now,
                       double *retry) {
  uint32_t s;
  for (s = 0; s < g->strip_n && g->strip_state[s] != STRIP_FREE; s++)
    ;
  if (s == g->strip_n || !worth_taking(g, w, s, now, retry))
    return 0;
  g->strip_state[s] = STRIP_CLAIMED;
  w->strip = (int)s;
  w->region = g->strip_px[s];
  w->by_peers = 0;
  w->deadline = INFINITY;
  w->job_len = w->rate * g->strip_cost[s];
  if (w->round.jobs == 0) /* its first job this round: the depth pass */
    w->job_len += w->depth_freq * w->depth_est;
  w->job_end = w->rate > 0.0 ? now + w->job_len : INFINITY;
  if (g->desc.deadline_factor > 0.0 && w->rate > 0.0 &&
      ((w->warm_sets >> (w->desc.effects & 15u)) & 1u))
    w->deadline = now + fmax(g->desc.deadline_min_ms,
                             g->desc.deadline_factor * w->job_len);
  w->started = 1;
  w->pending = 1;
  w->job = JOB_RENDER;
  uv_cond_signal(&w->wake);
  return 1;
}

/* w's job ended (under g->lock): settles the strip it rendered -- done,
 * or free again for the others if it failed -- and, if it succeeded,
 * starts it on the next free strip. 1: started. */
static int next_strip(rp_device_group *g, member *w, double now) {
  double retry = INFINITY; /* left to a peer: feed_idle offers it again */
  int s = w->strip;
  w->strip = -1;
  if (s < 0 && w->status == 0)
    w->region_done = 1;
  if (s >= 0 && w->status == 0) {
    g->strip_state[s] = STRIP_DONE;
    g->strip_owner[s] = (uint8_t)w->index;
    w->strips_done++;
    w->strip_cost += g->strip_cost[s];
  } else if (s >= 0) {
    g->strip_state[s] = STRIP_FREE;
  }
  return w->status == 0 && claim_strip(g, w, now, &retry);
}

/* Free strips -- freed by a device that failed or ran late, or left by
 * an idle one to a faster peer -- go to devices that finished (under
 * g->lock). Returns when to offer them again (INFINITY: no need). */
static double feed_idle(rp_device_group *g, double now) {
  double retry = INFINITY;
  uint32_t i;
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    if (w->started && !w->pending && w->outcome == 0 && !w->dropped &&
        w->job == JOB_NONE)
      (void)claim_strip(g, w, now, &retry);
  }
  return retry;
}

/* Waits until every pending member is done or past its deadline; a late
 * one is marked (outcome RP_EDEVICE, late) and left running. A member
 * without a model of its own (by_peers) gets its deadline when a peer
 * finishes: deadline_factor times the longest peer's time since `start`
 * -- a device that many times slower than its peers at an even split is
 * not worth waiting for. */
static void wait_jobs(rp_device_group *g, rp_group_report *rep,
                      double start) {
  uint32_t i;
  double peer_ms = 0.0;
  if (!g->threads)
    return; /* the jobs ran in start_job */
  uv_mutex_lock(&g->lock);
  for (;;) {
    double next = INFINITY, now = now_ms();
    int waiting;
    for (i = 0; i < g->count; i++) {
      member *w = &g->m[i];
      if (!w->pending)
        continue;
      if (w->job == JOB_NONE) {
        /* With a tail its worker has settled its strip and found none to
         * take (worker_main); feed_idle below offers it any freed since. */
        w->pending = 0;
        w->outcome = w->status;
        memcpy(w->why, w->error, sizeof w->why);
        /* Its whole round: with a tail, busy_ms is its last strip's. */
        if (w->outcome == 0 && w->round.busy_ms > peer_ms)
          peer_ms = w->round.busy_ms;
      }
    }
    for (i = 0; i < g->count; i++) {
      member *w = &g->m[i];
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
        if (w->strip >= 0)
          g->strip_state[w->strip] = STRIP_FREE;
        w->strip = -1;
        if (rep != NULL)
          rep->devices[i].late = 1;
        continue;
      }
      if (w->deadline < next)
        next = w->deadline;
    }
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

/* ---- Lifetime ------------------------------------------------------------ */

static void stop_workers(rp_device_group *g) {
  uint32_t i;
  uv_mutex_lock(&g->lock);
  for (i = 0; i < g->count; i++) {
    /* A late worker finishes its job first: QUIT waits in `job`
     * until it has cleared it. */
    while (g->m[i].thread_started && g->m[i].job != JOB_NONE)
      uv_cond_wait(&g->done, &g->lock);
    g->m[i].job = JOB_QUIT;
    uv_cond_signal(&g->m[i].wake);
  }
  uv_mutex_unlock(&g->lock);
  for (i = 0; i < g->count; i++)
    if (g->m[i].thread_started)
      uv_thread_join(&g->m[i].thread);
}

static void stop_builder(rp_device_group *g) {
  if (!g->builder_started)
    return;
  uv_mutex_lock(&g->build_lock);
  g->build_quit = 1;
  uv_cond_signal(&g->build_cv);
  uv_mutex_unlock(&g->build_lock);
  uv_thread_join(&g->builder);
  g->builder_started = 0;
}

void rp_device_group_destroy(rp_device_group *g) {
  uint32_t i;
  rp_context *ctx;
  if (g == NULL)
    return;
  ctx = g->ctx;
  stop_builder(g);
  rp_context_destroy(g->build_ctx);
  if (g->threads)
    stop_workers(g);
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    if (w->thread_started || g->threads)
      uv_cond_destroy(&w->wake);
    rp_cost_model_destroy(w->model);
    rp_device_destroy(w->dev);
    if (w->ctx != NULL) {
      rp__free(w->ctx, w->rgba);
      rp__free(w->ctx, w->tiles);
      rp_context_destroy(w->ctx);
    }
  }
  rp_balancer_destroy(g->balancer);
  rp__free(ctx, g->cost);
  rp__free(ctx, g->sub_cost);
  uv_mutex_destroy(&g->build_lock);
  uv_cond_destroy(&g->build_cv);
  uv_mutex_destroy(&g->lock);
  uv_cond_destroy(&g->done);
  rp__free(ctx, g);
}

static int check_desc(rp_context *ctx, const rp_group_desc *d) {
  static const char fn[] = "rp_device_group_create";
  uint32_t i;
  double sum = 0.0;
  if (d->devices == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: devices is NULL", fn);
  if (d->count == 0 || d->count > RP_GROUP_MAX_DEVICES)
    return rp__fail(ctx, RP_ERANGE, "%s: count %u is not in 1..%d", fn,
                    d->count, RP_GROUP_MAX_DEVICES);
  if (d->share_mode != RP_SHARES_DYNAMIC && d->share_mode != RP_SHARES_FIXED)
    return rp__fail(ctx, RP_EINVAL, "%s: unknown share mode %d", fn,
                    (int)d->share_mode);
  if (d->damping != RP_DAMP_SMOOTH && d->damping != RP_DAMP_EVEN)
    return rp__fail(ctx, RP_EINVAL, "%s: unknown damping %d", fn,
                    (int)d->damping);
  if (!isfinite(d->damp_rate) || !isfinite(d->deadline_factor) ||
      !isfinite(d->deadline_min_ms))
    return rp__fail(ctx, RP_ENOTFINITE, "%s: damp_rate, deadline_factor "
                    "and deadline_min_ms must be finite", fn);
  if (d->damp_rate < 0.0 || d->damp_rate > 1.0)
    return rp__fail(ctx, RP_ERANGE, "%s: damp_rate %g is not in (0, 1]",
                    fn, d->damp_rate);
  if (d->deadline_min_ms < 0.0)
    return rp__fail(ctx, RP_ERANGE, "%s: deadline_min_ms %g < 0", fn,
                    d->deadline_min_ms);
  if (!isfinite(d->tail_fraction))
    return rp__fail(ctx, RP_ENOTFINITE, "%s: tail_fraction is not finite",
                    fn);
  if (d->tail_fraction > 0.5)
    return rp__fail(ctx, RP_ERANGE, "%s: tail_fraction %g is over 0.5",
                    fn, d->tail_fraction);
  if (d->tail_strips > RP_GROUP_MAX_STRIPS)
    return rp__fail(ctx, RP_ERANGE, "%s: tail_strips %u is over %d", fn,
                    d->tail_strips, RP_GROUP_MAX_STRIPS);
  if (d->share_mode == RP_SHARES_FIXED) {
    if (d->fixed_shares == NULL)
      return rp__fail(ctx, RP_EINVAL, "%s: fixed shares without "
                      "fixed_shares", fn);
    for (i = 0; i < d->count; i++) {
      if (!isfinite(d->fixed_shares[i]))
        return rp__fail(ctx, RP_ENOTFINITE, "%s: fixed_shares[%u] is not "
                        "finite", fn, i);
      if (d->fixed_shares[i] < 0.0)
        return rp__fail(ctx, RP_ERANGE, "%s: fixed_shares[%u] < 0", fn, i);
      sum += d->fixed_shares[i];
    }
    if (!(sum > 0.0))
      return rp__fail(ctx, RP_EINVAL, "%s: fixed_shares sum to 0", fn);
  }
  return 0;
}

int rp_device_group_create(rp_context *ctx, const rp_group_desc *desc,
                           rp_device_group **out) {
  static const char fn[] = "rp_device_group_create";
  rp_device_group *g;
  uint32_t i;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (desc == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: %s is NULL", fn,
                    desc == NULL ? "desc" : "out");
  *out = NULL;
  if ((err = check_desc(ctx, desc)) != 0)
    return err;
  if ((g = rp__calloc(ctx, 1, sizeof *g)) == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory", fn);
  g->ctx = ctx;
  g->desc = *desc;
  g->desc.devices = NULL;
  g->count = desc->count;
  if (desc->share_mode == RP_SHARES_FIXED) {
    memcpy(g->fixed_shares, desc->fixed_shares,
           desc->count * sizeof(double));
    g->desc.fixed_shares = g->fixed_shares;
  }
  if (g->desc.damp_rate == 0.0)
    g->desc.damp_rate = 0.5;
  if (g->desc.deadline_factor == 0.0)
    g->desc.deadline_factor = DEFAULT_DEADLINE_FACTOR;
  if (g->desc.deadline_min_ms == 0.0)
    g->desc.deadline_min_ms = DEFAULT_DEADLINE_MIN_MS;
  if (g->desc.tail_fraction == 0.0)
    g->desc.tail_fraction = DEFAULT_TAIL_FRACTION;
  g->threads = g->count >= 2;
  if (uv_mutex_init(&g->lock) != 0) {
    rp__free(ctx, g);
    return rp__fail(ctx, RP_EDEVICE, "%s: uv_mutex_init failed", fn);
  }
  if (uv_cond_init(&g->done) != 0) {
    uv_mutex_destroy(&g->lock);
    rp__free(ctx, g);
    return rp__fail(ctx, RP_EDEVICE, "%s: uv_cond_init failed", fn);
  }
  if (uv_mutex_init(&g->build_lock) != 0) {
    uv_cond_destroy(&g->done);
    uv_mutex_destroy(&g->lock);
    rp__free(ctx, g);
    return rp__fail(ctx, RP_EDEVICE, "%s: uv_mutex_init failed", fn);
  }
  if (uv_cond_init(&g->build_cv) != 0) {
    uv_mutex_destroy(&g->build_lock);
    uv_cond_destroy(&g->done);
    uv_mutex_destroy(&g->lock);
    rp__free(ctx, g);
    return rp__fail(ctx, RP_EDEVICE, "%s: uv_cond_init failed", fn);
  }
  /* From here on rp_device_group_destroy frees whatever was made. */
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    w->g = g;
    w->index = i;
    w->deadline = INFINITY;
    if (g->threads && uv_cond_init(&w->wake) != 0) {
      /* Conds made so far are destroyed by destroy: count them. */
      g->count = i;
      rp_device_group_destroy(g);
      return rp__fail(ctx, RP_EDEVICE, "%s: uv_cond_init failed", fn);
    }
  }
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    if ((err = rp_context_create(&ctx->desc, &w->ctx)) != 0) {
      rp_device_group_destroy(g);
      return rp__fail(ctx, err, "%s: a context for device %u", fn, i);
    }
    if ((err = rp_device_create(w->ctx, &desc->devices[i], &w->dev)) != 0) {
      rp__fail(ctx, err, "%s: device %u: %s", fn, i, rp_last_error(w->ctx));
      rp_device_group_destroy(g);
      return err;
    }
    rp_device_get_caps(w->dev, &w->caps);
    g->can_prepare |= rp__device_builds_ahead(w->dev);
    {
      char name[sizeof w->name];
      snprintf(name, sizeof name, "%s:%s", w->caps.backend, w->caps.device);
      memcpy(w->name, name, sizeof name);
    }
    if ((err = rp_cost_model_create(w->ctx, &desc->model, &w->model)) != 0) {
      rp__fail(ctx, err, "%s: %s", fn, rp_last_error(w->ctx));
      rp_device_group_destroy(g);
      return err;
    }
  }
  if (g->threads) {
    for (i = 0; i < g->count; i++) {
      member *w = &g->m[i];
      if (uv_thread_create(&w->thread, worker_main, w) != 0) {
        rp_device_group_destroy(g);
        return rp__fail(ctx, RP_EDEVICE, "%s: uv_thread_create failed", fn);
      }
      w->thread_started = 1;
    }
  }
  *out = g;
  return 0;
}

rp_device *rp__group_device(const rp_device_group *g, uint32_t i) {
  return g != NULL && i < g->count ? g->m[i].dev : NULL;
}

uint32_t rp_device_group_count(const rp_device_group *g) {
  return g != NULL ? g->count : 0;
}

uint32_t rp_device_group_alive(const rp_device_group *g) {
  uint32_t i, n = 0;
  if (g == NULL)
    return 0;
  for (i = 0; i < g->count; i++)
    n += !g->m[i].dropped;
  return n;
}

void rp_device_group_get_caps(const rp_device_group *g, uint32_t i,
                              rp_caps *caps) {
  if (g == NULL || caps == NULL)
    return;
  if (i >= g->count) {
    memset(caps, 0, sizeof *caps);
    return;
  }
  *caps = g->m[i].caps;
}

/* ---- Uploads ------------------------------------------------------------- */

/* Whether an error means the device is gone (lost, or unable to hold the
 * scene) rather than a request no device could do (an effect it lacks, a
 * bad argument): only the first kind drops it. */
static int loses_device(int err, int upload) {
  return err == RP_EDEVICE || (upload && err == RP_ENOMEM);
}

/* Runs `job` on every live device and drops those that lost it. */
static int upload(rp_device_group *g, int job, const char *fn) {
  uint32_t i;
  int last = 0;
  const char *why = "";
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    if (w->dropped)
      continue;
    w->deadline = INFINITY;
    w->by_peers = 0;
    start_job(g, w, job);
  }
  wait_jobs(g, NULL, 0.0);
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    if (w->dropped || w->outcome == 0)
      continue;
    if (!loses_device(w->outcome, 1))
      return rp__fail(g->ctx, w->outcome, "%s: %s", fn, w->why);
    w->dropped = 1;
    last = w->outcome;
    why = w->why;
    g->have_prev = 0;
  }
  if (rp_device_group_alive(g) == 0)
    return rp__fail(g->ctx, last != 0 ? last : RP_ENODEV,
                    "%s: no device left; the last said: %s", fn, why);
  return 0;
}

int rp_device_group_set_volume(rp_device_group *g, const rp_volume *vol) {
  uint32_t i;
  if (g == NULL)
    return RP_EINVAL;
  if (vol == NULL)
    return rp__fail(g->ctx, RP_EINVAL,
                    "rp_device_group_set_volume: vol is NULL");
  g->vol_gen++;
  g->can_train = 0;
  for (i = 0; i < g->count; i++) {
    g->m[i].vol = vol;
    g->m[i].vol_gen = g->vol_gen;
  }
  /* What was built or asked for was for the old volume (its voxel type
   * is in the kernels' keys); a build under way counts for nothing. */
  uv_mutex_lock(&g->build_lock);
  g->build_gen = g->vol_gen;
  g->build_want = g->build_busy = g->build_done = 0;
  uv_mutex_unlock(&g->build_lock);
  return upload(g, JOB_VOLUME, "rp_device_group_set_volume");
}

/* ---- Kernels built ahead ------------------------------------------------ */

static void builder_main(void *arg) {
  rp_device_group *g = arg;
#ifdef __linux__
  /* A build is compiler work on the host's cores, which a CPU device
   * renders on too. At nice 5 it leaves frames most of them and still
   * ends within a few frames; at 19 it never ended while frames kept
   * the cores busy (docs/runtime.md). Linux keeps nice values per
   * thread. */
  (void)setpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid), 5);
#endif
  uv_mutex_lock(&g->build_lock);
  for (;;) {
    rp_device *devs[RP_GROUP_MAX_DEVICES];
    uint32_t set = 0, n, i;
    uint64_t gen;
    while (!g->build_quit && g->build_want == 0)
      uv_cond_wait(&g->build_cv, &g->build_lock);
    if (g->build_quit)
      break;
    while (!((g->build_want >> set) & 1u))
      set++;
    g->build_want &= ~(1u << set);
    g->build_busy = 1u << set;
    gen = g->build_gen;
    n = g->build_ndev;
    memcpy(devs, g->build_devs, n * sizeof *devs);
    uv_mutex_unlock(&g->build_lock);
    /* A failure is left to the frame: it builds the kernels itself and
     * reports what went wrong where the app looks, in its status. */
    for (i = 0; i < n; i++)
      (void)rp_device_prepare(devs[i], g->build_ctx, set);
    uv_mutex_lock(&g->build_lock);
    g->build_busy = 0;
    if (gen == g->build_gen)
      g->build_done |= 1u << set;
  }
  uv_mutex_unlock(&g->build_lock);
}

int rp_device_group_prepare(rp_device_group *g, uint32_t effects) {
  static const char fn[] = "rp_device_group_prepare";
  uint32_t set, i;
  int err;
  if (g == NULL)
    return RP_EINVAL;
  if (effects & ~(uint32_t)RP__KNOWN_EFFECTS)
    return rp__fail(g->ctx, RP_EINVAL, "%s: unknown effect bits 0x%x", fn,
                    effects);
  if (!g->can_prepare)
    return 0;
  if (!g->builder_started) {
    if (g->build_ctx == NULL &&
        (err = rp_context_create(&g->ctx->desc, &g->build_ctx)) != 0)
      return rp__fail(g->ctx, err, "%s: a context for the builder", fn);
    if (uv_thread_create(&g->builder, builder_main, g) != 0)
      return rp__fail(g->ctx, RP_EDEVICE, "%s: uv_thread_create failed",
                      fn);
    g->builder_started = 1;
  }
  set = effects;
  uv_mutex_lock(&g->build_lock);
  /* A frame waiting for the set asks every frame: once is enough. */
  if (!(((g->build_done | g->build_want | g->build_busy) >> set) & 1u)) {
    g->build_want |= 1u << set;
    g->build_ndev = 0;
    for (i = 0; i < g->count; i++)
      if (!g->m[i].dropped)
        g->build_devs[g->build_ndev++] = g->m[i].dev;
    uv_cond_signal(&g->build_cv);
  }
  uv_mutex_unlock(&g->build_lock);
  return 0;
}

int rp_device_group_prepared(rp_device_group *g, uint32_t effects) {
  int done;
  if (g == NULL || (effects & ~(uint32_t)RP__KNOWN_EFFECTS))
    return 0;
  if (!g->can_prepare)
    return 1;
  uv_mutex_lock(&g->build_lock);
  done = (g->build_done >> effects) & 1u;
  uv_mutex_unlock(&g->build_lock);
  return done;
}

int rp_device_group_set_tf(rp_device_group *g, const rp_tf *tf,
                           const rp_occupancy *occ) {
  uint32_t i;
  if (g == NULL)
    return RP_EINVAL;
  if (tf == NULL || occ == NULL)
    return rp__fail(g->ctx, RP_EINVAL, "rp_device_group_set_tf: %s is NULL",
                    tf == NULL ? "tf" : "occ");
  g->tf_gen++;
  for (i = 0; i < g->count; i++) {
    g->m[i].tf = tf;
    g->m[i].occ = occ;
    g->m[i].tf_gen = g->tf_gen;
  }
  return upload(g, JOB_TF, "rp_device_group_set_tf");
}

int rp_device_group_set_ao(rp_device_group *g, const rp_ao *ao) {
  uint32_t i;
  if (g == NULL)
    return RP_EINVAL;
  for (i = 0; i < g->count; i++)
    g->m[i].ao = ao;
  return upload(g, JOB_AO, "rp_device_group_set_ao");
}

uint64_t rp_device_group_ao_bytes(const rp_device_group *g) {
  uint64_t sum = 0;
  uint32_t i;
  if (g == NULL)
    return 0;
  for (i = 0; i < g->count; i++)
    sum += rp_device_ao_bytes(g->m[i].dev);
  return sum;
}

/* Between frames every live member's worker waits for a job, so the
 * devices are free for an AO run's threads; each has a context of its
 * own, as rp_ao_compute requires.
 *
 * Unless the caller gives speeds, a static split uses each device's
 * speed from the group's last AO computation (full bricks per ms), so
 * that the split follows the devices from the second TF on; a device
 * not yet measured counts as the mean of those that were. */
int rp_device_group_ao_begin(rp_device_group *g, const rp_ao_plan *plan,
                             const rp_ao_schedule *schedule,
                             rp_ao_run **out) {
  rp_device *devs[RP_AO_MAX_DEVICES];
  uint32_t n = 0, i, known = 0;
  rp_ao_schedule sc;
  double sum = 0.0;
  int given = 0;
  if (g == NULL)
    return RP_EINVAL;
  memset(&sc, 0, sizeof sc);
  if (schedule != NULL)
    sc = *schedule;
  for (i = 0; i < g->count && n < RP_AO_MAX_DEVICES; i++)
    if (!g->m[i].dropped) {
      g->ao_members[n] = i;
      devs[n++] = g->m[i].dev;
    }
  if (n == 0)
    return rp__fail(g->ctx, RP_ENODEV, "rp_device_group_ao_begin: no "
                    "device left");
  g->ao_count = n;
  for (i = 0; i < RP_AO_MAX_DEVICES; i++)
    given |= sc.speed[i] != 0.0;
  if (!given) {
    for (i = 0; i < n; i++)
      if (g->m[g->ao_members[i]].ao_speed > 0.0) {
        sum += g->m[g->ao_members[i]].ao_speed;
        known++;
      }
    for (i = 0; i < n && known > 0; i++) {
      double v = g->m[g->ao_members[i]].ao_speed;
      sc.speed[i] = v > 0.0 ? v : sum / known;
    }
  }
  return rp_ao_run_create(g->ctx, devs, n, plan, &sc, out);
}

/* A device the run lost is dropped, as a lost upload would drop it; the
 * others' speeds are learned. */
static void ao_learn(rp_device_group *g, const rp_ao_report *rep, int err) {
  uint32_t i;
  for (i = 0; i < g->ao_count; i++) {
    member *w = &g->m[g->ao_members[i]];
    if (loses_device(rep->devices[i].status, 0) || err == RP_EDEVICE) {
      w->dropped = 1;
      g->have_prev = 0;
    } else if (err == 0 && rep->devices[i].busy_ms > 0.0 &&
               rep->devices[i].full_bricks > 0) {
      w->ao_speed =
          (double)rep->devices[i].full_bricks / rep->devices[i].busy_ms;
    }
  }
}

int rp_device_group_ao_end(rp_device_group *g, rp_ao_run *run, int status,
                           rp_ao **out, rp_ao_report *report) {
  rp_ao_report rep;
  int err = status;
  if (g == NULL || run == NULL)
    return RP_EINVAL;
  memset(&rep, 0, sizeof rep);
  if (err == 0)
    err = rp_ao_run_finish(run, out, &rep);
  else
    rp_ao_run_report(run, &rep);
  ao_learn(g, &rep, err);
  if (err == 0 && report != NULL)
    *report = rep;
  return err;
}

int rp_device_group_compute_ao(rp_device_group *g, const rp_ao_plan *plan,
                               const rp_ao_schedule *schedule, rp_ao **out,
                               rp_ao_report *report) {
  rp_ao_run *run = NULL;
  int err;
  if (g == NULL)
    return RP_EINVAL;
  if ((err = rp_device_group_ao_begin(g, plan, schedule, &run)) != 0)
    return err;
  err = rp_ao_run_step(run, INFINITY, NULL);
  err = rp_device_group_ao_end(g, run, err, out, report);
  rp_ao_run_destroy(run);
  return err;
}

/* ---- Shares and prediction ----------------------------------------------- */

/* Each live device's whole-frame estimate: fixed part (c0) and the part
 * its share scales (the raycast: its samples, and its cost per ray,
 * which scales with the region's area rather than its samples, near
 * enough). */
typedef struct device_cost {
  double fixed, var;
  rp_cost_estimate e;
  int ok;
} device_cost;

static void device_costs(rp_device_group *g, const rp_frame_probe *p,
                         float step, float scale, device_cost *c) {
  uint32_t i;
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    c[i].ok = 0;
    if (w->dropped || p == NULL)
      continue;
    if (rp_cost_predict(w->model, p, step, scale, &c[i].e) != 0)
      continue;
    /* t' = (a R + c0 + variable) * Q: Q scales the fixed part too. */
    c[i].fixed = c[i].e.c0_ms * c[i].e.frame_factor;
    c[i].var = c[i].e.ms - c[i].fixed;
    c[i].ok = isfinite(c[i].var) && c[i].var > 0.0 && isfinite(c[i].fixed);
  }
}

static int grow_split(rp_device_group *g, size_t tiles);

/* Total predicted tile cost of the frame: what the rates multiply (only
 * dynamic shares use it; 0 for fixed ones and without a probe). */
static double frame_cost(rp_device_group *g, const rp_frame_probe *p,
                         float step, float scale) {
  rp_render_desc d = {0};
  uint32_t sw, sh, tx, ty;
  double sum = 0.0;
  size_t i;
  if (g->desc.share_mode != RP_SHARES_DYNAMIC || p == NULL ||
      p->width == 0 || p->height == 0)
    return 0.0;
  d.width = p->width;
  d.height = p->height;
  d.step = step;
  d.image_scale = scale;
  rp_scaled_size(&d, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  if (g->desc.split_by_count)
    return (double)tx * ty;
  if (grow_split(g, (size_t)tx * ty) != 0 ||
      rp_probe_tile_costs(p, &d, g->cost) != 0)
    return 0.0;
  for (i = 0; i < (size_t)tx * ty; i++)
    sum += g->cost[i];
  return sum;
}

/* Files a measured rate and takes the median of the last ones. */
static void rate_add(member *w, double measured) {
  double v[RATE_FRAMES], t;
  uint32_t i, j;
  w->rates[w->next_rate] = measured;
  w->next_rate = (w->next_rate + 1) % RATE_FRAMES;
  if (w->n_rates < RATE_FRAMES)
    w->n_rates++;
  memcpy(v, w->rates, w->n_rates * sizeof *v);
  for (i = 1; i < w->n_rates; i++) /* insertion sort of at most three */
    for (j = i; j > 0 && v[j - 1] > v[j]; j--)
      t = v[j], v[j] = v[j - 1], v[j - 1] = t;
  /* Of two, the lower: the other may be the stall. */
  w->rate = v[(w->n_rates - 1) / 2];
}

/* This frame's shares (dropped devices: 0). Dynamic: each device's time
 * is modelled as depth_freq * depth_est + rate * (its region's predicted
 * tile cost), both measured on its last frames, and the shares are those
 * that make the devices finish together (rp_balance_shares_fixed), damped
 * against the last frame's. A device not yet measured counts as an
 * average one.
 *
 * This sigma (the rate) is per unit of the split's own cost, not the
 * paper's cost per sample from the device's KRLS model: the split divides
 * predicted tile cost, so a cost map that is off by a factor for a whole
 * view is off the same way for every device and cancels; and the depth
 * pass, which every device runs over the whole image whatever its share,
 * is a fixed cost the paper's shares cannot express. The KRLS models
 * still predict the frame's time (rp_device_group_predict).
 * `cost` is the frame's total predicted tile cost (frame_cost; 0:
 * unknown, every device counts as average). */
static int frame_shares(rp_device_group *g, double cost, double *shares) {
  double var[RP_GROUP_MAX_DEVICES], fixed[RP_GROUP_MAX_DEVICES];
  double target[RP_GROUP_MAX_DEVICES], prev[RP_GROUP_MAX_DEVICES];
  double psum = 0.0;
  uint32_t idx[RP_GROUP_MAX_DEVICES], n = 0, i;
  int err;
  for (i = 0; i < g->count; i++) {
    const member *w = &g->m[i];
    shares[i] = 0.0;
    if (w->dropped)
      continue;
    idx[n] = i;
    if (g->desc.share_mode == RP_SHARES_FIXED) {
      target[n] = g->fixed_shares[i];
    } else {
      var[n] = w->rate > 0.0 && cost > 0.0 ? w->rate * cost : NAN;
      fixed[n] = w->depth_freq * w->depth_est;
    }
    prev[n] = g->prev_shares[i];
    psum += prev[n];
    n++;
  }
  if (n == 0)
    return RP_ENODEV;
  if (g->desc.share_mode == RP_SHARES_FIXED) {
    double sum = 0.0;
    for (i = 0; i < n; i++)
      sum += target[i];
    if (!(sum > 0.0)) /* the live devices all had share 0: even */
      for (i = 0; i < n; i++)
        target[i] = 1.0;
    if ((err = rp_balance_damp(RP_DAMP_SMOOTH, 1.0, NULL, target, n,
                               target)) != 0)
      return err;
  } else {
    if ((err = rp_balance_shares_fixed(var, fixed, n, target)) != 0)
      return err;
    if ((err = rp_balance_damp(g->desc.damping, g->desc.damp_rate,
                               g->have_prev && psum > 0.0 ? prev : NULL,
                               target, n, target)) != 0)
      return err;
  }
  for (i = 0; i < n; i++)
    shares[idx[i]] = target[i];
  return 0;
}

int rp_device_group_shares(rp_device_group *g, const rp_frame_probe *p,
                           float step, float scale, double *shares) {
  int err;
  if (g == NULL)
    return RP_EINVAL;
  if (shares == NULL)
    return rp__fail(g->ctx, RP_EINVAL,
                    "rp_device_group_shares: shares is NULL");
  if ((err = frame_shares(g, frame_cost(g, p, step, scale), shares)) != 0)
    return rp__fail(g->ctx, err, "rp_device_group_shares: no device left");
  return 0;
}

int rp_device_group_upload_ms(rp_device_group *g, const rp_camera *cam,
                              const rp_render_desc *desc, double *ms) {
  uint32_t i, alive = 0;
  if (g == NULL)
    return RP_EINVAL;
  if (cam == NULL || desc == NULL || ms == NULL)
    return rp__fail(g->ctx, RP_EINVAL, "rp_device_group_upload_ms: cam, "
                    "desc and ms are required");
  *ms = 0.0;
  for (i = 0; i < g->count; i++)
    alive += !g->m[i].dropped;
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    rp_upload_estimate e;
    double share;
    int err;
    if (w->dropped)
      continue;
    if ((err = rp_device_upload_estimate(w->dev, cam, desc, NULL, &e)) != 0)
      return rp__fail(g->ctx, err, "rp_device_group_upload_ms: %s",
                      rp_last_error(w->ctx));
    /* Its region is not cut yet: last frame's share of the image's
     * bricks, an even one before any. */
    share = g->have_prev ? g->prev_shares[i] : 1.0 / alive;
    if (e.ms * share > *ms)
      *ms = e.ms * share;
  }
  return 0;
}

int rp_device_group_predict(rp_device_group *g, const rp_frame_probe *p,
                            float step, float scale, rp_cost_estimate *out) {
  device_cost c[RP_GROUP_MAX_DEVICES];
  double shares[RP_GROUP_MAX_DEVICES], worst = -INFINITY, best = INFINITY;
  double tiles;
  uint32_t i;
  int err, any = 0;
  memset(c, 0, sizeof c);
  for (i = 0; i < RP_GROUP_MAX_DEVICES; i++)
    shares[i] = 0.0;
  if (g == NULL)
    return RP_EINVAL;
  if (p == NULL || out == NULL)
    return rp__fail(g->ctx, RP_EINVAL, "rp_device_group_predict: %s is "
                    "NULL", p == NULL ? "p" : "out");
  device_costs(g, p, step, scale, c);
  if ((err = frame_shares(g, frame_cost(g, p, step, scale), shares)) != 0)
    return rp__fail(g->ctx, err, "rp_device_group_predict: no device left");
  {
    rp_render_desc d = {0};
    uint32_t sw, sh, tx, ty;
    d.width = p->width > 0 ? p->width : 1;
    d.height = p->height > 0 ? p->height : 1;
    d.image_scale = scale;
    rp_scaled_size(&d, &sw, &sh);
    rp_tile_grid(sw, sh, &tx, &ty);
    tiles = (double)tx * ty;
  }
  for (i = 0; i < g->count; i++) {
    double t;
    if (g->m[i].dropped)
      continue;
    if (!c[i].ok) {
      /* The model refused the point or predicts nothing: say so. */
      if (rp_cost_predict(g->m[i].model, p, step, scale, out) != 0)
        return rp__fail(g->ctx, RP_EINVAL, "rp_device_group_predict: %s",
                        rp_last_error(g->m[i].ctx));
      continue;
    }
    any = 1;
    /* A device whose share buys less than half a tile gets an empty
     * region (rp_balancer_split) and pays nothing. */
    t = shares[i] * tiles >= 0.5 ? c[i].fixed + shares[i] * c[i].var : 0.0;
    if (t > worst)
      worst = t;
    if (c[i].var < best) {
      best = c[i].var;
      *out = c[i].e;
    }
  }
  if (!any) {
    out->ms = NAN;
    return 0;
  }
  out->ms = worst;
  return 0;
}

/* ---- Tile costs ---------------------------------------------------------- */

int rp_probe_tile_costs(const rp_frame_probe *p, const rp_render_desc *desc,
                        float *cost) {
  uint32_t sw, sh, tx, ty, x, y;
  double step, sx, sy;
  if (p == NULL || desc == NULL || cost == NULL || desc->width == 0 ||
      desc->height == 0)
    return RP_EINVAL;
  step = rp__render_desc_defaults(desc).step;
  if (!isfinite(step))
    return RP_ENOTFINITE;
  if (!(step > 0.0))
    return RP_ERANGE;
  rp_scaled_size(desc, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  /* Scaled pixel -> output pixel. */
  sx = (double)desc->width / sw;
  sy = (double)desc->height / sh;
  for (y = 0; y < ty; y++) {
    uint32_t y0 = y * RP_TILE_SIZE;
    uint32_t y1 = y0 + RP_TILE_SIZE < sh ? y0 + RP_TILE_SIZE : sh;
    double oy = 0.5 * (y0 + y1) * sy;
    for (x = 0; x < tx; x++) {
      uint32_t x0 = x * RP_TILE_SIZE;
      uint32_t x1 = x0 + RP_TILE_SIZE < sw ? x0 + RP_TILE_SIZE : sw;
      double ox = 0.5 * (x0 + x1) * sx, span = 0.0;
      if (p->map_width > 0 && p->map_height > 0 && p->map_stride > 0 &&
          (size_t)p->map_width * p->map_height <= RP_PROBE_MAX_RAYS) {
        /* The probe ray nearest the tile's centre. */
        double fi = floor((ox - 2.0) / p->map_stride + 0.5);
        double fj = floor((oy - 2.0) / p->map_stride + 0.5);
        uint32_t i = fi <= 0.0 ? 0
                     : fi >= p->map_width - 1 ? p->map_width - 1
                                              : (uint32_t)fi;
        uint32_t j = fj <= 0.0 ? 0
                     : fj >= p->map_height - 1 ? p->map_height - 1
                                               : (uint32_t)fj;
        span = p->span[(size_t)j * p->map_width + i];
        if (!(span >= 0.0) || !isfinite(span))
          span = 0.0;
      }
      cost[(size_t)y * tx + x] =
          (float)((double)(x1 - x0) * (y1 - y0) * (1.0 + span / step));
    }
  }
  return 0;
}

/* ---- Rendering ----------------------------------------------------------- */

static int grow_split(rp_device_group *g, size_t tiles) {
  if (tiles > g->balancer_tiles) {
    rp_balancer_desc bd = {0};
    rp_balancer *b = NULL;
    int err;
    bd.max_devices = RP_GROUP_MAX_DEVICES;
    bd.max_tiles = (uint32_t)tiles;
    if ((err = rp_balancer_create(g->ctx, &bd, &b)) != 0)
      return err;
    rp_balancer_destroy(g->balancer);
    g->balancer = b;
    g->balancer_tiles = (uint32_t)tiles;
  }
  if (tiles > g->cost_cap) {
    float *c = rp__malloc(g->ctx, tiles * sizeof *c);
    double *s = rp__malloc(g->ctx, tiles * sizeof *s);
    if (c == NULL || s == NULL) {
      rp__free(g->ctx, c);
      rp__free(g->ctx, s);
      return rp__fail(g->ctx, RP_ENOMEM, "device group: %zu tile costs",
                      tiles);
    }
    rp__free(g->ctx, g->cost);
    rp__free(g->ctx, g->sub_cost);
    g->cost = c;
    g->sub_cost = s;
    g->cost_cap = tiles;
  }
  return 0;
}

/* Splits the tile rectangle `area` (tile units) of a tx-wide grid among
 * the devices by `shares`; regions[i] in tile units of the whole grid. */
static int split_area(rp_device_group *g, const rp_region *area, uint32_t tx,
                      const double *shares, rp_region *regions) {
  uint32_t w = area->x1 - area->x0, h = area->y1 - area->y0, x, y, i;
  int err;
  for (y = 0; y < h; y++)
    for (x = 0; x < w; x++)
      g->sub_cost[(size_t)y * w + x] =
          g->cost[(size_t)(area->y0 + y) * tx + area->x0 + x];
  if ((err = rp_balancer_split(g->balancer, g->sub_cost, w, h, shares,
                               g->count, regions)) != 0)
    return err;
  for (i = 0; i < g->count; i++) {
    regions[i].x0 += area->x0;
    regions[i].x1 += area->x0;
    regions[i].y0 += area->y0;
    regions[i].y1 += area->y0;
  }
  return 0;
}

static int region_empty(const rp_region *r) {
  return r->x0 >= r->x1 || r->y0 >= r->y1;
}

static double region_cost(const rp_device_group *g, const rp_region *t,
                          uint32_t tx) {
  double sum = 0.0;
  uint32_t x, y;
  for (y = t->y0; y < t->y1; y++)
    for (x = t->x0; x < t->x1; x++)
      sum += g->cost[(size_t)y * tx + x];
  return sum;
}

/* Copies w's region (pixels) from its buffers into the caller's. */
static void take_region(const member *w, const rp_region *r, uint32_t sw,
                        uint32_t tx, uint8_t *rgba, rp_tile_stats *tiles) {
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

/* One round: every device with a non-empty region renders it, and with
 * a tail (g->tail_active) goes on to take strips, as does a device
 * without a region; finished regions and strips are copied across; the
 * regions of devices that failed or ran late, and strips nobody
 * finished, are appended to `lost` (pixels). Returns the last failure;
 * an error that does not lose the device (an effect it lacks) is
 * returned in *refused and fails the frame. */
static int render_round(rp_device_group *g, const rp_camera *cam,
                        const rp_render_desc *d, const rp_region *px,
                        const double *predicted, double start,
                        uint8_t *rgba, rp_tile_stats *tiles,
                        rp_group_report *rep, rp_region *lost,
                        uint32_t *n_lost, int first_round, int *refused) {
  uint32_t sw, sh, tx, i;
  int last = 0;
  rp_scaled_size(d, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, NULL);
  /* Workers started below read their peers' state (worth_taking): all
   * of it is reset first, under the lock. */
  uv_mutex_lock(&g->lock);
  for (i = 0; i < g->count; i++) {
    g->m[i].pending = g->m[i].started = g->m[i].region_done = 0;
    g->m[i].strip = -1;
  }
  uv_mutex_unlock(&g->lock);
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    if (w->dropped)
      continue;
    memset(&w->round, 0, sizeof w->round);
    w->cam = *cam;
    w->desc = *d;
    if (first_round)
      rep->devices[i].region = px[i];
    if (region_empty(&px[i])) {
      /* Without a region it is idle from the start: wait_jobs offers it
       * strips (feed_idle). */
      w->started = g->tail_active;
      w->outcome = 0;
      continue;
    }
    w->region = px[i];
    w->deadline = INFINITY;
    w->by_peers = 0;
    w->job_end = INFINITY;
    w->job_len = 0.0;
    if (g->tail_active && w->rate > 0.0) {
      rp_region tr = {px[i].x0 / RP_TILE_SIZE, px[i].y0 / RP_TILE_SIZE,
                      (px[i].x1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE,
                      (px[i].y1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE};
      w->job_len = w->depth_freq * w->depth_est +
                   w->rate * region_cost(g, &tr, tx);
      w->job_end = start + w->job_len;
    }
    if (g->desc.deadline_factor > 0.0 && !isinf(predicted[i]) &&
        ((w->warm_sets >> (d->effects & 15u)) & 1u)) {
      if (w->trained && isfinite(predicted[i]))
        w->deadline = start + fmax(g->desc.deadline_min_ms,
                                   g->desc.deadline_factor * predicted[i]);
      else
        w->by_peers = 1;
    }
    w->started = 1;
    start_job(g, w, JOB_RENDER);
  }
  wait_jobs(g, rep, start);
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    rp_group_device *rd = &rep->devices[i];
    if (!w->started)
      continue;
    if (w->outcome != 0 && !loses_device(w->outcome, 0)) {
      rd->status = w->outcome;
      snprintf(rd->error, sizeof rd->error, "%s", w->why);
      *refused = rp__fail(g->ctx, w->outcome, "%s", w->why);
      continue;
    }
    if (w->outcome != 0) {
      w->dropped = 1;
      g->have_prev = 0;
      rd->status = w->outcome;
      snprintf(rd->error, sizeof rd->error, "%s", w->why);
      rd->dropped = 1;
      rep->lost++;
      last = w->outcome;
      rp__fail(g->ctx, w->outcome, "device group: %s", w->why);
      /* Lost on a strip, its region is done and in its buffer, which its
       * late worker (writing the strip) does not touch. */
      if (w->region_done)
        take_region(w, &px[i], sw, tx, rgba, tiles);
      else if (!region_empty(&px[i]))
        lost[(*n_lost)++] = px[i];
      continue;
    }
    if (w->round.jobs == 0)
      continue; /* no region, and no strip came its way */
    if (!region_empty(&px[i]))
      take_region(w, &px[i], sw, tx, rgba, tiles);
    w->warm_sets |= 1u << (d->effects & 15u);
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
  }
  if (g->tail_active) {
    /* A strip's pixels are in the buffer of the device that finished it,
     * which no job of that device writes again this frame: a worker
     * writes only its job's pixels, and a strip a device is late on is
     * not one of them. */
    uint32_t s;
    for (s = 0; s < g->strip_n; s++) {
      if (g->strip_state[s] == STRIP_DONE) {
        take_region(&g->m[g->strip_owner[s]], &g->strip_px[s], sw, tx, rgba,
                    tiles);
        rep->strip_device[s] = g->strip_owner[s];
      } else {
        lost[(*n_lost)++] = g->strip_px[s];
        rep->strip_device[s] = RP_GROUP_MAX_DEVICES;
      }
    }
    uv_mutex_lock(&g->lock); /* a late worker reads it */
    g->tail_active = 0;
    uv_mutex_unlock(&g->lock);
  }
  return last;
}

/* Cuts the tail off the bottom of the tx x ty tile grid: the fewest
 * rows (never all) whose predicted cost reaches tail_fraction of the
 * frame's `total`, in strips of equal cost along x, each at least one
 * tile wide. `main_area` keeps the rows above. No tail when the band
 * would cost nothing (an empty bottom: nothing there worth balancing). */
static void cut_tail(rp_device_group *g, uint32_t tx, uint32_t ty,
                     uint32_t sw, uint32_t sh, double total,
                     rp_region *main_area) {
  rp_region t[RP_GROUP_MAX_STRIPS];
  uint32_t rows = 0, n, k = 0, x, x0 = 0, y;
  double band = 0.0, acc = 0.0;
  g->strip_n = 0;
  if (ty < 2 || !(total > 0.0))
    return;
  while (rows < ty - 1 && band < g->desc.tail_fraction * total) {
    rows++;
    for (x = 0; x < tx; x++)
      band += g->cost[(size_t)(ty - rows) * tx + x];
  }
  if (!(band > 0.0))
    return;
  n = g->desc.tail_strips != 0 ? g->desc.tail_strips : 4 * g->count;
  if (n > tx)
    n = tx;
  if (n > RP_GROUP_MAX_STRIPS)
    n = RP_GROUP_MAX_STRIPS;
  for (x = 0; x < tx && k + 1 < n; x++) {
    for (y = ty - rows; y < ty; y++)
      acc += g->cost[(size_t)y * tx + x];
    /* Close strip k at its share of the band, if the strips after it
     * still get a column each, and when they need every column left. */
    if ((acc >= band * (double)(k + 1) / (double)n &&
         tx - (x + 1) >= n - 1 - k) ||
        tx - (x + 1) == n - 1 - k) {
      rp_region r = {x0, ty - rows, x + 1, ty};
      t[k++] = r;
      x0 = x + 1;
    }
  }
  {
    rp_region r = {x0, ty - rows, tx, ty};
    t[k++] = r;
  }
  if (rp_balance_to_pixels(t, k, sw, sh, g->strip_px) != 0)
    return;
  for (x = 0; x < k; x++) {
    g->strip_cost[x] = region_cost(g, &t[x], tx);
    g->strip_state[x] = STRIP_FREE;
  }
  g->strip_n = k;
  main_area->y1 = ty - rows;
}

int rp_device_group_render(rp_device_group *g, const rp_camera *cam,
                           const rp_render_desc *desc,
                           const rp_frame_probe *probe, uint8_t *rgba,
                           rp_tile_stats *tiles, rp_group_report *report) {
  static const char fn[] = "rp_device_group_render";
  rp_group_report local;
  rp_group_report *rep = report != NULL ? report : &local;
  device_cost c[RP_GROUP_MAX_DEVICES];
  double shares[RP_GROUP_MAX_DEVICES], predicted[RP_GROUP_MAX_DEVICES];
  double total_cost, times[RP_GROUP_MAX_DEVICES];
  double cost_abs[RP_GROUP_MAX_DEVICES];
  rp_region t[RP_GROUP_MAX_DEVICES], px[RP_GROUP_MAX_DEVICES];
  rp_region lost[RP_GROUP_MAX_DEVICES + RP_GROUP_MAX_STRIPS], all, main_area;
  rp_render_desc d;
  uint32_t sw, sh, tx, ty, i, n_lost = 0, rounds;
  double start, t_rr, share_cost;
  int err, last, refused = 0, frame_depth;
  if (g == NULL)
    return RP_EINVAL;
  if (cam == NULL || desc == NULL || rgba == NULL)
    return rp__fail(g->ctx, RP_EINVAL, "%s: %s is NULL", fn,
                    cam == NULL ? "cam" : desc == NULL ? "desc" : "rgba");
  if (desc->width == 0 || desc->height == 0)
    return rp__fail(g->ctx, RP_EINVAL, "%s: a zero image size", fn);
  g->can_train = 0;
  d = rp__render_desc_defaults(desc);
  memset(rep, 0, sizeof *rep);
  memset(c, 0, sizeof c);
  memset(t, 0, sizeof t);
  memset(px, 0, sizeof px);
  for (i = 0; i < RP_GROUP_MAX_DEVICES; i++) {
    shares[i] = cost_abs[i] = times[i] = 0.0;
    predicted[i] = NAN;
  }
  rep->count = g->count;
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    snprintf(rep->devices[i].name, sizeof rep->devices[i].name, "%s",
             w->name);
    rep->devices[i].dropped = w->dropped;
    rep->devices[i].predicted_ms = NAN;
    w->rendered = 0;
    w->frame_raycast_ms = w->frame_busy_ms = w->frame_upload_ms = 0.0;
    w->frame_samples = 0;
    w->strips_done = 0;
    w->strip_cost = 0.0;
  }
  rp_scaled_size(&d, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  if ((err = grow_split(g, (size_t)tx * ty)) != 0)
    return err;
  if (probe != NULL && !g->desc.split_by_count) {
    if ((err = rp_probe_tile_costs(probe, &d, g->cost)) != 0)
      return rp__fail(g->ctx, err, "%s: the tile costs", fn);
  } else {
    for (i = 0; i < tx * ty; i++)
      g->cost[i] = 1.0f;
  }
  all.x0 = all.y0 = 0;
  all.x1 = tx;
  all.y1 = ty;
  total_cost = region_cost(g, &all, tx);
  /* The rates are per unit of this frame's costs: what frame_cost would
   * give, computed once here. */
  share_cost = g->desc.share_mode == RP_SHARES_DYNAMIC && probe != NULL
                   ? total_cost
                   : 0.0;
  device_costs(g, probe, d.step, d.image_scale, c);
  if ((err = frame_shares(g, share_cost, shares)) != 0)
    return rp__fail(g->ctx, err, "%s: no device left", fn);
  main_area = all;
  g->strip_n = 0;
  if (g->desc.tail_fraction > 0.0 && g->threads &&
      rp_device_group_alive(g) >= 2)
    cut_tail(g, tx, ty, sw, sh, total_cost, &main_area);
  rep->strip_count = g->strip_n;
  memcpy(rep->strips, g->strip_px, g->strip_n * sizeof *rep->strips);
  if ((err = split_area(g, &main_area, tx, shares, t)) != 0 ||
      (err = rp_balance_to_pixels(t, g->count, sw, sh, px)) != 0)
    return err; /* the balancer's message is in g->ctx */
  for (i = 0; i < g->count; i++) {
    rp_group_device *rd = &rep->devices[i];
    rd->share = shares[i];
    cost_abs[i] = region_cost(g, &t[i], tx);
    rd->cost_share = total_cost > 0.0 ? cost_abs[i] / total_cost : 0.0;
    predicted[i] = c[i].ok ? c[i].fixed + rd->cost_share * c[i].var : NAN;
    rd->predicted_ms = region_empty(&t[i]) ? NAN : predicted[i];
  }
  memcpy(g->prev_shares, shares, sizeof shares);
  g->have_prev = 1;
  start = now_ms();
  uv_mutex_lock(&g->lock);
  g->tail_active = g->strip_n > 0;
  uv_mutex_unlock(&g->lock);
  last = render_round(g, cam, &d, px, predicted, start, rgba, tiles, rep,
                      lost, &n_lost, 1, &refused);
  if (refused != 0) {
    rep->alive = rp_device_group_alive(g);
    return refused;
  }
  for (i = 0; i < g->count; i++) {
    rep->devices[i].strips = g->m[i].strips_done;
    rep->devices[i].strip_cost_share =
        total_cost > 0.0 ? g->m[i].strip_cost / total_cost : 0.0;
    cost_abs[i] += g->m[i].strip_cost;
  }
  /* Whether this frame needed a depth pass: a property of the frame (a
   * new camera or TF), seen on any device that rendered. */
  frame_depth = 0;
  for (i = 0; i < g->count; i++)
    if (!g->m[i].dropped && g->m[i].rendered && cost_abs[i] > 0.0 &&
        rep->devices[i].depth_passes > 0)
      frame_depth = 1;
  /* What the split learns: each device that finished its region, its
   * wall time per unit of predicted cost outside the depth pass (rate_add
   * keeps the median of the last three), and how often frames need its
   * depth pass. */
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    const rp_group_device *rd = &rep->devices[i];
    double ran, measured;
    if (w->dropped)
      continue;
    if (!w->rendered || !(cost_abs[i] > 0.0)) {
      /* Idle this frame: its fixed cost must still follow the frames.
       * Charged a depth pass the frames no longer need, a device the
       * split squeezed out (one slow depth pass, say) would stay out. */
      if (w->rate > 0.0)
        w->depth_freq += 0.25 * ((double)frame_depth - w->depth_freq);
      continue;
    }
    ran = rd->depth_passes > 0;
    if (ran)
      w->depth_est = rd->depth_ms;
    w->depth_freq = w->rate > 0.0 ? w->depth_freq + 0.25 * (ran - w->depth_freq)
                                  : ran;
    measured = fmax(rd->busy_ms - rd->depth_ms, 1e-6) / cost_abs[i];
    if (w->rate > 0.0 && cost_abs[i] < MIN_RATE_FRACTION * total_cost &&
        !(measured < w->rate))
      continue;
    rate_add(w, measured);
  }
  /* The balance of the first round: a device lost in it counts as one
   * that rendered nothing. */
  for (i = 0; i < g->count; i++) {
    static const rp_region some = {0, 0, 1, 1};
    times[i] = rep->devices[i].busy_ms;
    /* Only whether it rendered anything counts here. */
    px[i] = rep->devices[i].strips > 0 ? some : rep->devices[i].region;
    if (rep->devices[i].status != 0)
      px[i].x1 = px[i].x0;
  }
  (void)rp_balance_metric(times, px, g->count, &rep->imbalance);
  /* Lost regions go to the devices left, split by their shares; a device
   * lost in a later round adds its part again. Each round drops at
   * least one device, so there are at most count rounds. */
  t_rr = now_ms();
  for (rounds = 0; n_lost > 0 && rounds < g->count; rounds++) {
    rp_region redo[RP_GROUP_MAX_DEVICES + RP_GROUP_MAX_STRIPS];
    uint32_t n_redo = n_lost, k;
    memcpy(redo, lost, n_lost * sizeof *lost);
    n_lost = 0;
    for (k = 0; k < n_redo; k++) {
      rp_region area;
      if (rp_device_group_alive(g) == 0)
        break;
      if (frame_shares(g, share_cost, shares) != 0)
        break;
      area.x0 = redo[k].x0 / RP_TILE_SIZE;
      area.y0 = redo[k].y0 / RP_TILE_SIZE;
      area.x1 = (redo[k].x1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE;
      area.y1 = (redo[k].y1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE;
      if ((err = split_area(g, &area, tx, shares, t)) != 0 ||
          (err = rp_balance_to_pixels(t, g->count, sw, sh, px)) != 0)
        return rp__fail(g->ctx, err, "%s: the re-render split", fn);
      for (i = 0; i < g->count; i++)
        predicted[i] = INFINITY; /* no deadline: the frame must finish */
      err = render_round(g, cam, &d, px, predicted, now_ms(), rgba, tiles,
                         rep, lost, &n_lost, 0, &refused);
      if (refused != 0) {
        rep->alive = rp_device_group_alive(g);
        return refused;
      }
      if (err != 0)
        last = err;
    }
  }
  if (n_lost > 0 || rp_device_group_alive(g) == 0) {
    char why[RP__ERRMSG_MAX];
    /* The message reads the context it is written to: copy it first. */
    snprintf(why, sizeof why, "%s", rp_last_error(g->ctx));
    rep->alive = rp_device_group_alive(g);
    return rp__fail(g->ctx, last != 0 ? last : RP_ENODEV,
                    "%s: every device failed; the last said: %s", fn, why);
  }
  rep->rerender_ms = rounds > 0 ? now_ms() - t_rr : 0.0;
  rep->render_ms = now_ms() - start;
  rep->alive = rp_device_group_alive(g);
  g->last_render_ms = g->threads ? rep->render_ms : g->m[0].frame_busy_ms;
  g->last_samples = 0;
  for (i = 0; i < g->count; i++)
    g->last_samples += g->m[i].frame_samples;
  g->can_train = 1;
  return 0;
}

int rp_device_group_train(rp_device_group *g, const rp_frame_probe *p,
                          float step, float scale, double frame_ms) {
  static const char fn[] = "rp_device_group_train";
  uint32_t i;
  int err = 0;
  if (g == NULL)
    return RP_EINVAL;
  if (!g->can_train)
    return rp__fail(g->ctx, RP_ESTATE, "%s: no frame to learn from", fn);
  if (p == NULL)
    return rp__fail(g->ctx, RP_EINVAL, "%s: p is NULL", fn);
  g->can_train = 0;
  for (i = 0; i < g->count; i++) {
    member *w = &g->m[i];
    double f, raycast, frame;
    int e;
    if (w->dropped || !w->rendered || w->frame_samples == 0 ||
        (double)w->frame_samples <
            MIN_TRAIN_FRACTION * (double)g->last_samples)
      continue;
    /* The device's rate over its region, for the whole frame; what the
     * caller added to the group's render, and the device's own time
     * outside its raycast, are its fixed cost. One device: exactly the
     * caller's figures. */
    f = (double)g->last_samples / (double)w->frame_samples;
    raycast = w->frame_raycast_ms * f;
    frame = raycast + (frame_ms - g->last_render_ms) +
            (w->frame_busy_ms - w->frame_raycast_ms);
    if (g->count == 1)
      frame = frame_ms;
    /* Brick uploads are predicted apart (rp_device_group_upload_ms). */
    if (w->frame_upload_ms > 0.0)
      frame = fmax(frame - w->frame_upload_ms, raycast);
    if ((e = rp_cost_train(w->model, p, step, scale, g->last_samples,
                           raycast, frame)) != 0) {
      err = rp__fail(g->ctx, e, "%s: %s", fn, rp_last_error(w->ctx));
      continue;
    }
    w->trained++;
  }
  return err;
}
