/* Several devices rendering one frame (DESIGN section 7): plan -> round
 * -> learn -> re-render.
 *
 * Plan: the shares that make the devices finish together (shares.c),
 * each tile's predicted cost, and the kd-tree split of all but a tail of
 * the image. Round (group_round.c): every device renders its region as
 * a job on its executor and goes on to take strips of the tail. Learn:
 * each device's rate and depth-pass frequency (shares.c). Re-render: the
 * regions of devices lost or late go to the devices left, in the same
 * frame.
 *
 * Each device has one owner, its executor (executor.h): uploads, upload
 * estimates, render rounds and AO steps (rp_device_group_ao_begin) are
 * jobs on it, kernels built ahead (rp_device_group_prepare) jobs on its
 * build lane, which overlaps rendering. With two devices or more each
 * executor has a worker thread; a group of one device has an inline
 * executor, and does exactly what that device alone does, on the
 * caller's thread. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "ao.h"
#include "group.h"
#include "passes.h"

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

static double now_ms(void) { return (double)uv_hrtime() * 1e-6; }

int rp__group_loses_device(int err, int upload) {
  return err == RP_EDEVICE || (upload && err == RP_ENOMEM);
}

/* ---- Lifetime ------------------------------------------------------------ */

void rp_device_group_destroy(rp_device_group *g) {
  uint32_t i;
  rp_context *ctx;
  if (g == NULL)
    return;
  ctx = g->ctx;
  /* Builds asked for and not begun are dropped: one under way ends
   * first (destroying an executor runs what it has). */
  uv_mutex_lock(&g->build_lock);
  for (i = 0; i < g->count; i++)
    g->m[i].build_want = 0;
  uv_mutex_unlock(&g->build_lock);
  /* A late worker finishes its job first: its device, buffers and the
   * group's lock stay until then. */
  for (i = 0; i < g->count; i++)
    rp__executor_destroy(g->m[i].ex);
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
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

static void build_job(rp__job *job, rp_context *ctx);

/* The group's locks; on failure nothing is left made. */
static int init_locks(rp_device_group *g) {
  if (uv_mutex_init(&g->lock) != 0)
    return RP_EDEVICE;
  if (uv_cond_init(&g->done) != 0) {
    uv_mutex_destroy(&g->lock);
    return RP_EDEVICE;
  }
  if (uv_mutex_init(&g->build_lock) != 0) {
    uv_cond_destroy(&g->done);
    uv_mutex_destroy(&g->lock);
    return RP_EDEVICE;
  }
  return 0;
}

/* Opens member i: its context, device, executor and cost model. */
static int open_member(rp_device_group *g, const rp_group_desc *desc,
                       uint32_t i) {
  static const char fn[] = "rp_device_group_create";
  rp__member *w = &g->m[i];
  char name[sizeof w->name];
  int err;
  if ((err = rp_context_create(&g->ctx->desc, &w->ctx)) != 0)
    return rp__fail(g->ctx, err, "%s: a context for device %u", fn, i);
  if ((err = rp_device_create(w->ctx, &desc->devices[i], &w->dev)) != 0)
    return rp__fail(g->ctx, err, "%s: device %u: %s", fn, i,
                    rp_last_error(w->ctx));
  rp__health_keep_desc(w, &desc->devices[i]);
  rp_device_get_caps(w->dev, &w->caps);
  w->builds_ahead = rp__device_builds_ahead(w->dev);
  g->can_prepare |= w->builds_ahead;
  snprintf(name, sizeof name, "%s:%s", w->caps.backend, w->caps.device);
  memcpy(w->name, name, sizeof name);
  if ((err = rp_cost_model_create(w->ctx, &desc->model, &w->model)) != 0)
    return rp__fail(g->ctx, err, "%s: %s", fn, rp_last_error(w->ctx));
  /* From here on the executor is the device's one caller. */
  if ((err = rp__executor_create(g->ctx, w->dev, g->threads, &w->ex)) != 0)
    return rp__fail(g->ctx, err, "%s: device %u: %s", fn, i,
                    rp_last_error(g->ctx));
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
  if (init_locks(g) != 0) {
    rp__free(ctx, g);
    return rp__fail(ctx, RP_EDEVICE, "%s: a lock would not start", fn);
  }
  /* From here on rp_device_group_destroy frees whatever was made. */
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    w->g = g;
    w->index = i;
    w->deadline = INFINITY;
    w->job.run = rp__group_member_job;
    w->build_job.run = build_job;
  }
  for (i = 0; i < g->count; i++) {
    if ((err = open_member(g, desc, i)) != 0) {
      rp_device_group_destroy(g);
      return err;
    }
  }
  *out = g;
  return 0;
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

rp_device *rp__group_device(const rp_device_group *g, uint32_t i) {
  return g != NULL && i < g->count ? g->m[i].dev : NULL;
}

int rp__group_clock_ns(const rp_device_group *g, uint32_t i, uint64_t *ns) {
  if (g == NULL || i >= g->count || !rp__device_clock_ns(g->m[i].dev, ns))
    return 0;
  *ns += g->m[i].clock_base;
  return 1;
}

/* ---- Uploads ------------------------------------------------------------- */

/* Runs a job of `kind` on every live device and waits for them all. */
static void run_on_live(rp_device_group *g, int kind) {
  uint32_t i;
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    if (w->dropped)
      continue;
    w->deadline = INFINITY;
    w->by_peers = 0;
    rp__group_start_job(g, w, kind);
  }
  rp__group_wait(g, NULL, 0.0);
}

/* Uploads on every live device; drops those that lost it. */
static int upload(rp_device_group *g, int kind, const char *fn) {
  uint32_t i;
  int last = 0;
  const char *why = "";
  run_on_live(g, kind);
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    if (w->dropped || w->outcome == 0)
      continue;
    if (!rp__group_loses_device(w->outcome, 1))
      return rp__fail(g->ctx, w->outcome, "%s: %s", fn, w->why);
    rp__health_fail(g, w);
    last = w->outcome;
    why = w->why;
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
  g->vol = vol;
  /* A late worker still reads its own inputs: it gets the volume when
   * it comes back (group_health.c). */
  for (i = 0; i < g->count; i++) {
    if (g->m[i].state == RP_DEVICE_LATE)
      continue;
    g->m[i].vol = vol;
    g->m[i].vol_gen = g->vol_gen;
  }
  /* What was built or asked for was for the old volume (its voxel type
   * is in the kernels' keys); a build under way counts for nothing. */
  uv_mutex_lock(&g->build_lock);
  g->build_gen = g->vol_gen;
  g->build_asked = g->build_done = 0;
  memset(g->build_left, 0, sizeof g->build_left);
  for (i = 0; i < g->count; i++)
    g->m[i].build_want = 0;
  uv_mutex_unlock(&g->build_lock);
  return upload(g, RP__JOB_VOLUME, "rp_device_group_set_volume");
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
  g->tf = tf;
  g->occ = occ;
  for (i = 0; i < g->count; i++) {
    if (g->m[i].state == RP_DEVICE_LATE)
      continue;
    g->m[i].tf = tf;
    g->m[i].occ = occ;
    g->m[i].tf_gen = g->tf_gen;
  }
  return upload(g, RP__JOB_TF, "rp_device_group_set_tf");
}

int rp_device_group_set_ao(rp_device_group *g, const rp_ao *ao) {
  uint32_t i;
  if (g == NULL)
    return RP_EINVAL;
  g->ao_gen++;
  g->ao = ao;
  for (i = 0; i < g->count; i++) {
    if (g->m[i].state == RP_DEVICE_LATE)
      continue;
    g->m[i].ao = ao;
    g->m[i].ao_gen = g->ao_gen;
  }
  return upload(g, RP__JOB_AO, "rp_device_group_set_ao");
}

void rp__group_forget_ao(rp_device_group *g) {
  if (g != NULL)
    g->ao = NULL;
}

uint64_t rp_device_group_ao_bytes(const rp_device_group *g) {
  rp_device_group *mg = (rp_device_group *)(uintptr_t)g; /* its lock */
  uint64_t sum = 0;
  uint32_t i;
  if (g == NULL)
    return 0;
  /* As each device's job last left it: a late worker may still run. */
  uv_mutex_lock(&mg->lock);
  for (i = 0; i < g->count; i++)
    sum += g->m[i].ao_bytes;
  uv_mutex_unlock(&mg->lock);
  return sum;
}

/* ---- Kernels built ahead ------------------------------------------------ */

/* A member's build job, on its executor's build lane: the sets it is
 * asked for, lowest first, until none is left. A failure is left to the
 * frame: it builds the kernels itself and reports what went wrong where
 * the app looks, in its status. */
static void build_job(rp__job *job, rp_context *ctx) {
  rp__member *w = RP__JOB_OWNER(job, rp__member, build_job);
  rp_device_group *g = w->g;
  uv_mutex_lock(&g->build_lock);
  while (w->build_want != 0) {
    uint32_t set = 0;
    uint64_t gen = g->build_gen;
    while (!((w->build_want >> set) & 1u))
      set++;
    w->build_want &= ~(1u << set);
    uv_mutex_unlock(&g->build_lock);
    (void)rp_device_prepare(w->dev, ctx, set);
    uv_mutex_lock(&g->build_lock);
    /* The set is done once every device asked has tried it; a build for
     * an older volume counts for nothing. */
    if (gen == g->build_gen && g->build_left[set] > 0 &&
        --g->build_left[set] == 0) {
      g->build_asked &= ~(1u << set);
      g->build_done |= 1u << set;
    }
  }
  w->build_queued = 0;
  uv_mutex_unlock(&g->build_lock);
}

int rp_device_group_prepare(rp_device_group *g, uint32_t effects) {
  static const char fn[] = "rp_device_group_prepare";
  uint32_t set = effects, bit, i;
  int err = 0;
  if (g == NULL)
    return RP_EINVAL;
  if (effects & ~(uint32_t)RP__KNOWN_EFFECTS)
    return rp__fail(g->ctx, RP_EINVAL, "%s: unknown effect bits 0x%x", fn,
                    effects);
  if (!g->can_prepare)
    return 0;
  bit = 1u << set;
  uv_mutex_lock(&g->build_lock);
  /* A frame waiting for the set asks every frame: once is enough. */
  if ((g->build_done | g->build_asked) & bit) {
    uv_mutex_unlock(&g->build_lock);
    return 0;
  }
  g->build_asked |= bit;
  g->build_left[set] = 1; /* held until every device is asked */
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    int e;
    if (w->dropped || !w->builds_ahead)
      continue;
    w->build_want |= bit;
    g->build_left[set]++;
    if (w->build_queued)
      continue; /* its job takes the set after the one it builds */
    if ((e = rp__executor_submit_build(w->ex, &w->build_job)) == 0) {
      w->build_queued = 1;
    } else {
      /* Counted as tried: the frame builds it itself. The message reads
       * the context it is written to: copied first. */
      char why[RP__ERRMSG_MAX];
      snprintf(why, sizeof why, "%s", rp_last_error(g->ctx));
      w->build_want &= ~bit;
      g->build_left[set]--;
      err = rp__fail(g->ctx, e, "%s: %s", fn, why);
    }
  }
  if (--g->build_left[set] == 0) {
    g->build_asked &= ~bit;
    g->build_done |= bit;
  }
  uv_mutex_unlock(&g->build_lock);
  return err;
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

/* ---- Ambient occlusion --------------------------------------------------- */

/* The run's jobs go to the live members' executors, which are idle
 * between frames; each device has a context of its own, as
 * rp_ao_compute requires.
 *
 * Unless the caller gives speeds, a static split uses each device's
 * speed from the group's last AO computation (full bricks per ms), so
 * that the split follows the devices from the second TF on; a device
 * not yet measured counts as the mean of those that were. */
int rp_device_group_ao_begin(rp_device_group *g, const rp_ao_plan *plan,
                             const rp_ao_schedule *schedule,
                             rp_ao_run **out) {
  rp__executor *ex[RP_AO_MAX_DEVICES];
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
      ex[n++] = g->m[i].ex;
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
  return rp__ao_run_create(g->ctx, ex, n, plan, &sc, out);
}

/* A device the run lost is dropped, as a lost upload would drop it; the
 * others' speeds are learned. */
static void ao_learn(rp_device_group *g, const rp_ao_report *rep, int err) {
  uint32_t i;
  for (i = 0; i < g->ao_count; i++) {
    rp__member *w = &g->m[g->ao_members[i]];
    int lost = rep->devices[i].status != 0 ? rep->devices[i].status : err;
    if (rp__group_loses_device(rep->devices[i].status, 0) ||
        err == RP_EDEVICE) {
      /* Through a buffer of its own: name and why are w's both. */
      char why[sizeof w->why];
      snprintf(why, sizeof why, "%s: lost in an ambient-occlusion job "
               "(%s)", w->name, rp_err_name(lost));
      memcpy(w->why, why, sizeof why);
      w->ao_lost = lost;
      rp__health_fail(g, w);
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

/* The live members' split models (NULL: dropped), for rp__frame_shares. */
static void live_models(const rp_device_group *g,
                        const rp__split_model **m) {
  uint32_t i;
  for (i = 0; i < g->count; i++)
    m[i] = g->m[i].dropped ? NULL : &g->m[i].sm;
}

/* This frame's shares (rp__frame_shares) over the live members, those
 * on probation capped (group_health.c). */
static int frame_shares(rp_device_group *g, double cost, double *shares) {
  const rp__split_model *m[RP_GROUP_MAX_DEVICES];
  int err;
  live_models(g, m);
  if ((err = rp__frame_shares(&g->desc, m, g->count,
                              g->have_prev ? g->prev_shares : NULL, cost,
                              shares)) != 0)
    return err;
  rp__health_cap_shares(g, shares);
  return 0;
}

/* Each live device's whole-frame estimate, split (rp__device_cost). */
static void device_costs(rp_device_group *g, const rp_frame_probe *p,
                         float step, float scale, rp__device_cost *c) {
  uint32_t i;
  for (i = 0; i < g->count; i++) {
    c[i].ok = 0;
    if (g->m[i].dropped || p == NULL ||
        rp_cost_predict(g->m[i].model, p, step, scale, &c[i].e) != 0)
      continue;
    rp__device_cost_split(&c[i]);
  }
}

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

/* Total predicted tile cost of the frame: what the rates multiply (only
 * dynamic shares use it; 0 for fixed ones and without a probe). */
static double frame_cost(rp_device_group *g, const rp_frame_probe *p,
                         float step, float scale) {
  rp_render_desc d = {0};
  uint32_t sw, sh, tx, ty;
  rp_region all = {0, 0, 0, 0};
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
  all.x1 = tx;
  all.y1 = ty;
  return rp__region_cost(g->cost, tx, &all);
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

/* Each live device estimates on its executor, all at once. */
int rp_device_group_upload_ms(rp_device_group *g, const rp_camera *cam,
                              const rp_render_desc *desc, double *ms) {
  uint32_t i, alive = 0;
  if (g == NULL)
    return RP_EINVAL;
  if (cam == NULL || desc == NULL || ms == NULL)
    return rp__fail(g->ctx, RP_EINVAL, "rp_device_group_upload_ms: cam, "
                    "desc and ms are required");
  *ms = 0.0;
  for (i = 0; i < g->count; i++) {
    if (g->m[i].dropped)
      continue; /* a late worker may still read its inputs */
    alive++;
    g->m[i].cam = *cam;
    g->m[i].desc = *desc;
  }
  run_on_live(g, RP__JOB_ESTIMATE);
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    double share;
    if (w->dropped)
      continue;
    if (w->outcome != 0)
      return rp__fail(g->ctx, w->outcome, "rp_device_group_upload_ms: %s",
                      w->why);
    /* Its region is not cut yet: last frame's share of the image's
     * bricks, an even one before any. */
    share = g->have_prev ? g->prev_shares[i] : 1.0 / alive;
    if (w->est.ms * share > *ms)
      *ms = w->est.ms * share;
  }
  return 0;
}

int rp_device_group_predict(rp_device_group *g, const rp_frame_probe *p,
                            float step, float scale, rp_cost_estimate *out) {
  rp__device_cost c[RP_GROUP_MAX_DEVICES];
  double shares[RP_GROUP_MAX_DEVICES], tiles, ms;
  rp_render_desc d = {0};
  uint32_t sw, sh, tx, ty, i;
  int err, fastest;
  memset(c, 0, sizeof c);
  if (g == NULL)
    return RP_EINVAL;
  if (p == NULL || out == NULL)
    return rp__fail(g->ctx, RP_EINVAL, "rp_device_group_predict: %s is "
                    "NULL", p == NULL ? "p" : "out");
  device_costs(g, p, step, scale, c);
  if ((err = frame_shares(g, frame_cost(g, p, step, scale), shares)) != 0)
    return rp__fail(g->ctx, err, "rp_device_group_predict: no device left");
  d.width = p->width > 0 ? p->width : 1;
  d.height = p->height > 0 ? p->height : 1;
  d.image_scale = scale;
  rp_scaled_size(&d, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  tiles = (double)tx * ty;
  for (i = 0; i < g->count; i++) {
    /* A model that refused the point says so; one that predicts nothing
     * leaves the device out. */
    if (!g->m[i].dropped && !c[i].ok &&
        rp_cost_predict(g->m[i].model, p, step, scale, out) != 0)
      return rp__fail(g->ctx, RP_EINVAL, "rp_device_group_predict: %s",
                      rp_last_error(g->m[i].ctx));
  }
  ms = rp__predict_frame(c, shares, g->count, tiles, &fastest);
  if (fastest >= 0)
    *out = c[fastest].e;
  out->ms = ms;
  return 0;
}

/* ---- Rendering ----------------------------------------------------------- */

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

/* Cuts the tail off the bottom of the grid (rp__tail_cut) into
 * g->strip_*; `main_area` keeps the rows above. */
static void cut_tail(rp_device_group *g, const rp__frame *f,
                     rp_region *main_area) {
  rp_region t[RP_GROUP_MAX_STRIPS];
  uint32_t n = g->desc.tail_strips != 0 ? g->desc.tail_strips
                                        : 4 * g->count,
           k, s;
  g->strip_n = 0;
  k = rp__tail_cut(g->cost, f->tx, f->ty, g->desc.tail_fraction, n,
                   f->total_cost, t);
  if (k == 0 || rp_balance_to_pixels(t, k, f->sw, f->sh, g->strip_px) != 0)
    return;
  for (s = 0; s < k; s++) {
    g->strip_cost[s] = rp__region_cost(g->cost, f->tx, &t[s]);
    g->strip_state[s] = RP__STRIP_FREE;
  }
  g->strip_n = k;
  main_area->y1 = t[0].y0;
}

/* The report and the members' per-frame figures, cleared. */
static void frame_reset(rp_device_group *g, rp__frame *f,
                        rp_group_report *rep) {
  uint32_t i;
  memset(rep, 0, sizeof *rep);
  memset(f->px, 0, sizeof f->px);
  f->n_lost = 0;
  f->refused = 0;
  for (i = 0; i < RP_GROUP_MAX_DEVICES; i++) {
    f->shares[i] = f->cost_abs[i] = 0.0;
    f->predicted[i] = NAN;
  }
  rep->count = g->count;
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
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
}

/* Plan: tile costs, shares, the tail, the split into f->px, and each
 * device's predicted time for its region. */
static int plan_frame(rp_device_group *g, const rp_frame_probe *probe,
                      rp__frame *f, rp_group_report *rep) {
  static const char fn[] = "rp_device_group_render";
  rp__device_cost c[RP_GROUP_MAX_DEVICES];
  rp_region t[RP_GROUP_MAX_DEVICES], all = {0, 0, 0, 0}, main_area;
  uint32_t i;
  int err;
  memset(c, 0, sizeof c);
  memset(t, 0, sizeof t);
  rp_scaled_size(&f->d, &f->sw, &f->sh);
  rp_tile_grid(f->sw, f->sh, &f->tx, &f->ty);
  if ((err = grow_split(g, (size_t)f->tx * f->ty)) != 0)
    return err;
  if (probe != NULL && !g->desc.split_by_count) {
    if ((err = rp_probe_tile_costs(probe, &f->d, g->cost)) != 0)
      return rp__fail(g->ctx, err, "%s: the tile costs", fn);
  } else {
    for (i = 0; i < f->tx * f->ty; i++)
      g->cost[i] = 1.0f;
  }
  all.x1 = f->tx;
  all.y1 = f->ty;
  f->total_cost = rp__region_cost(g->cost, f->tx, &all);
  /* The rates are per unit of this frame's costs: what frame_cost would
   * give, computed once here. */
  f->share_cost = g->desc.share_mode == RP_SHARES_DYNAMIC && probe != NULL
                      ? f->total_cost
                      : 0.0;
  device_costs(g, probe, f->d.step, f->d.image_scale, c);
  if ((err = frame_shares(g, f->share_cost, f->shares)) != 0)
    return rp__fail(g->ctx, err, "%s: no device left", fn);
  main_area = all;
  g->strip_n = 0;
  if (g->desc.tail_fraction > 0.0 && g->threads &&
      rp_device_group_alive(g) >= 2)
    cut_tail(g, f, &main_area);
  rep->strip_count = g->strip_n;
  memcpy(rep->strips, g->strip_px, g->strip_n * sizeof *rep->strips);
  if ((err = split_area(g, &main_area, f->tx, f->shares, t)) != 0 ||
      (err = rp_balance_to_pixels(t, g->count, f->sw, f->sh, f->px)) != 0)
    return err; /* the balancer's message is in g->ctx */
  for (i = 0; i < g->count; i++) {
    rp_group_device *rd = &rep->devices[i];
    rd->share = f->shares[i];
    f->cost_abs[i] = rp__region_cost(g->cost, f->tx, &t[i]);
    rd->cost_share =
        f->total_cost > 0.0 ? f->cost_abs[i] / f->total_cost : 0.0;
    f->predicted[i] = c[i].ok ? c[i].fixed + rd->cost_share * c[i].var : NAN;
    rd->predicted_ms = rp__region_empty(&t[i]) ? NAN : f->predicted[i];
  }
  memcpy(g->prev_shares, f->shares, sizeof f->shares);
  g->have_prev = 1;
  return 0;
}

/* Learn: what the split learns from the first round (rp__split_learn),
 * and the round's balance, a device lost in it counting as one that
 * rendered nothing. */
static void learn_frame(rp_device_group *g, rp__frame *f,
                        rp_group_report *rep) {
  double times[RP_GROUP_MAX_DEVICES];
  rp_region some[RP_GROUP_MAX_DEVICES];
  uint32_t i;
  int frame_depth = 0;
  for (i = 0; i < g->count; i++) {
    rep->devices[i].strips = g->m[i].strips_done;
    rep->devices[i].strip_cost_share =
        f->total_cost > 0.0 ? g->m[i].strip_cost / f->total_cost : 0.0;
    f->cost_abs[i] += g->m[i].strip_cost;
  }
  /* Whether this frame needed a depth pass: a property of the frame (a
   * new camera or TF), seen on any device that rendered. */
  for (i = 0; i < g->count; i++)
    if (!g->m[i].dropped && g->m[i].rendered && f->cost_abs[i] > 0.0 &&
        rep->devices[i].depth_passes > 0)
      frame_depth = 1;
  for (i = 0; i < g->count; i++) {
    const rp_group_device *rd = &rep->devices[i];
    rp__split_sample s;
    if (g->m[i].dropped)
      continue;
    s.rendered = g->m[i].rendered;
    s.cost = f->cost_abs[i];
    s.depth_passes = rd->depth_passes;
    s.depth_ms = rd->depth_ms;
    s.busy_ms = rd->busy_ms;
    rp__split_learn(&g->m[i].sm, &s, f->total_cost, frame_depth);
  }
  for (i = 0; i < g->count; i++) {
    static const rp_region one = {0, 0, 1, 1};
    times[i] = rep->devices[i].busy_ms;
    /* Only whether it rendered anything counts here. */
    some[i] = rep->devices[i].strips > 0 ? one : rep->devices[i].region;
    if (rep->devices[i].status != 0)
      some[i].x1 = some[i].x0;
  }
  (void)rp_balance_metric(times, some, g->count, &rep->imbalance);
}

/* Re-render: lost regions go to the devices left, split by their
 * shares; a device lost in a later round adds its part again. Each
 * round drops at least one device, so there are at most count rounds.
 * Returns the last device failure (*rounds: the rounds run), or an
 * error that fails the frame in f->refused. */
static int rerender(rp_device_group *g, const rp_camera *cam, rp__frame *f,
                    uint8_t *rgba, rp_tile_stats *tiles,
                    rp_group_report *rep, uint32_t *rounds) {
  rp_region t[RP_GROUP_MAX_DEVICES];
  uint32_t i;
  int err, last = 0;
  for (*rounds = 0; f->n_lost > 0 && *rounds < g->count; (*rounds)++) {
    rp_region redo[RP_GROUP_MAX_DEVICES + RP_GROUP_MAX_STRIPS];
    uint32_t n_redo = f->n_lost, k;
    memcpy(redo, f->lost, n_redo * sizeof *redo);
    f->n_lost = 0;
    for (k = 0; k < n_redo; k++) {
      rp_region area;
      if (rp_device_group_alive(g) == 0 ||
          frame_shares(g, f->share_cost, f->shares) != 0)
        break;
      area.x0 = redo[k].x0 / RP_TILE_SIZE;
      area.y0 = redo[k].y0 / RP_TILE_SIZE;
      area.x1 = (redo[k].x1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE;
      area.y1 = (redo[k].y1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE;
      if ((err = split_area(g, &area, f->tx, f->shares, t)) != 0 ||
          (err = rp_balance_to_pixels(t, g->count, f->sw, f->sh, f->px)) !=
              0)
        return f->refused = rp__fail(g->ctx, err, "rp_device_group_render: "
                                     "the re-render split");
      for (i = 0; i < g->count; i++)
        f->predicted[i] = INFINITY; /* no deadline: the frame must finish */
      f->start = now_ms();
      err = rp__group_round(g, cam, f, rgba, tiles, rep, 0);
      if (f->refused != 0)
        return f->refused;
      if (err != 0)
        last = err;
    }
  }
  return last;
}

int rp_device_group_render(rp_device_group *g, const rp_camera *cam,
                           const rp_render_desc *desc,
                           const rp_frame_probe *probe, uint8_t *rgba,
                           rp_tile_stats *tiles, rp_group_report *report) {
  static const char fn[] = "rp_device_group_render";
  rp_group_report local;
  rp_group_report *rep = report != NULL ? report : &local;
  rp__frame f;
  uint32_t i, rounds = 0, returned;
  double start, t_rr = 0.0;
  int err, last;
  if (g == NULL)
    return RP_EINVAL;
  if (cam == NULL || desc == NULL || rgba == NULL)
    return rp__fail(g->ctx, RP_EINVAL, "%s: %s is NULL", fn,
                    cam == NULL ? "cam" : desc == NULL ? "desc" : "rgba");
  if (desc->width == 0 || desc->height == 0)
    return rp__fail(g->ctx, RP_EINVAL, "%s: a zero image size", fn);
  g->can_train = 0;
  f.d = rp__render_desc_defaults(desc);
  g->frame_no++;
  returned = rp__health_begin(g);
  frame_reset(g, &f, rep);
  rep->returned = returned;
  if ((err = plan_frame(g, probe, &f, rep)) != 0) {
    rp__health_report(g, rep);
    return err;
  }
  start = f.start = now_ms();
  uv_mutex_lock(&g->lock);
  g->tail_active = g->strip_n > 0;
  uv_mutex_unlock(&g->lock);
  last = rp__group_round(g, cam, &f, rgba, tiles, rep, 1);
  /* Those on probation that came through the first round, the one with
   * deadlines, were on time. */
  for (i = 0; i < g->count; i++)
    if (!g->m[i].dropped)
      rp__health_on_time(g, &g->m[i]);
  if (f.refused == 0) {
    learn_frame(g, &f, rep);
    t_rr = now_ms();
    err = rerender(g, cam, &f, rgba, tiles, rep, &rounds);
    if (err != 0)
      last = err;
  }
  rep->alive = rp_device_group_alive(g);
  rp__health_report(g, rep);
  if (f.refused != 0)
    return f.refused;
  if (f.n_lost > 0 || rep->alive == 0) {
    char why[RP__ERRMSG_MAX];
    /* The message reads the context it is written to: copy it first. */
    snprintf(why, sizeof why, "%s", rp_last_error(g->ctx));
    return rp__fail(g->ctx, last != 0 ? last : RP_ENODEV,
                    "%s: every device failed; the last said: %s", fn, why);
  }
  rep->rerender_ms = rounds > 0 ? now_ms() - t_rr : 0.0;
  rep->render_ms = now_ms() - start;
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
    rp__member *w = &g->m[i];
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
