/* Ambient occlusion across devices (seed 004 section 5): the static BSP
 * split with its planes moved by full-brick counts, the naive split, and
 * the dynamic queue of fixed blocks; one thread per device, the result
 * assembled on the host.
 *
 * Departures from seed 004, and why:
 * - Every device already holds the whole volume (the raycast needs it),
 *   so a block's R halo is never transferred: a job is only a box to
 *   compute, and the halo costs nothing here.
 * - The raycast is sort-first (every device renders a region of the
 *   image from the whole volume), so every device needs the whole AO
 *   volume: blocks are read back and assembled, then uploaded to all.
 * - Both schemes are one mechanism: a list of jobs, each owned by a
 *   device (static) or by none (dynamic). A device that fails releases
 *   its jobs to the others, so a lost device costs time, not the result.
 * - A device's part of a step is a job on its executor (executor.h),
 *   the device's one owner thread: a group's run (rp_device_group_ao_
 *   begin) uses the executors the group renders on, a run made from
 *   plain devices (rp_ao_run_create) executors of its own, made with
 *   the run and joined when it is destroyed.
 * - Static splits weigh each side of a plane by the speeds of the
 *   devices under it (rp_ao_schedule.speed; all 1 by default, which is
 *   the seed's criterion per device, and also covers odd device counts,
 *   whose sides hold different numbers of devices). The seed's GPUs were
 *   alike; ours are not (a CPU part next to lavapipe, a slowed device),
 *   and an even split of the bricks leaves the fast device waiting. */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <string.h>

#include "ao.h"

#define DEFAULT_BLOCK 32u
#define DEFAULT_BALANCE_MS 100.0
#define DEFAULT_TOLERANCE 0.02
/* Slabs per static block: how often a device reports progress. */
#define STATIC_SLABS 8u

/* A box of voxels [lo, end). */
typedef struct box {
  uint32_t lo[3], end[3];
} box;

typedef struct job {
  box b;
  int owner;  /* device index, or -1: any device */
  int state;  /* 0 waiting, 1 taken, 2 done */
} job;

/* A device's part of a step: its job on the device's executor. */
typedef struct ao_lane {
  rp__job job;
  rp_ao_run *s;
  uint32_t index;
} ao_lane;

/* A computation in progress: the jobs, the volume being assembled, and
 * what the devices did so far. Guarded by mu while a step's jobs run;
 * the caller's between steps. */
struct rp_ao_run {
  rp_context *ctx;
  const rp_ao_plan *plan;
  rp__executor *ex[RP_AO_MAX_DEVICES]; /* device i's owner */
  int own_ex;          /* made for the run (rp_ao_run_create) */
  ao_lane lanes[RP_AO_MAX_DEVICES];
  uint32_t n;
  rp_ao_schedule sc;
  rp_ao *ao;           /* being assembled; the caller's after finish */
  job *jobs;
  uint32_t njobs, done;
  int alive[RP_AO_MAX_DEVICES];
  uint32_t alive_count;
  double t0;           /* creation, for the report's total */
  double deadline;     /* the current step's, absolute ms; INFINITY */
  uint32_t active;     /* the current step's device jobs still running */
  uint32_t reported;   /* jobs done at the last progress report */
  uint32_t taken[RP_AO_MAX_DEVICES]; /* jobs each took this step */
  pthread_mutex_t mu;
  pthread_cond_t cv;
  rp_ao_report rep;
  char first_error[256];
  int first_err;
};

static uint64_t box_voxels(const box *b) {
  return (uint64_t)(b->end[0] - b->lo[0]) * (b->end[1] - b->lo[1]) *
         (b->end[2] - b->lo[2]);
}

/* Copies a computed box into the volume (x fastest). */
static void scatter(uint8_t *vol, const uint32_t dims[3], const box *b,
                    const uint8_t *part) {
  uint32_t nx = b->end[0] - b->lo[0], ny = b->end[1] - b->lo[1], y, z;
  for (z = b->lo[2]; z < b->end[2]; z++)
    for (y = b->lo[1]; y < b->end[1]; y++)
      memcpy(vol + ((size_t)z * dims[1] + y) * dims[0] + b->lo[0],
             part + ((size_t)(z - b->lo[2]) * ny + (y - b->lo[1])) * nx, nx);
}

/* The next job device i may take: its own first, then unowned ones. */
static job *take(rp_ao_run *s, uint32_t i) {
  uint32_t k;
  for (k = 0; k < s->njobs; k++)
    if (s->jobs[k].state == 0 && s->jobs[k].owner == (int)i)
      return &s->jobs[k];
  for (k = 0; k < s->njobs; k++)
    if (s->jobs[k].state == 0 && s->jobs[k].owner < 0)
      return &s->jobs[k];
  return NULL;
}

/* Whether device i takes a job now: always its first of the step, so
 * that every step makes progress; later ones only when its mean job time
 * so far says it ends before the step's deadline. */
static int in_time(const rp_ao_run *s, uint32_t i) {
  const rp_ao_report *r = &s->rep;
  double mean;
  if (s->taken[i] == 0 || s->deadline == INFINITY)
    return 1;
  mean = r->devices[i].jobs > 0 ? r->devices[i].busy_ms / r->devices[i].jobs
                                : 0.0;
  return rp__now_ms() + mean <= s->deadline;
}

/* Reports progress from the caller's thread (under s->mu, released for
 * the call) when jobs were done since the last report and some are left.
 * 1: reported. */
static int report_progress(rp_ao_run *s) {
  double f;
  if (s->sc.progress == NULL || s->done == s->reported ||
      s->done >= s->njobs)
    return 0;
  f = (double)s->done / (double)s->njobs;
  s->reported = s->done;
  pthread_mutex_unlock(&s->mu);
  s->sc.progress(f, s->sc.user);
  pthread_mutex_lock(&s->mu);
  return 1;
}

/* Device i's part of a step, on its executor: jobs until none is left
 * for it or the step's time is up. */
static void device_job(rp__job *lane_job, rp_context *dctx) {
  ao_lane *w = RP__JOB_OWNER(lane_job, ao_lane, job);
  rp_ao_run *s = w->s;
  /* The executor's device now: a device group may have re-created a
   * device that failed since the run began (rp__executor_rebind). */
  rp_device *dev = rp__executor_device(s->ex[w->index]);
  /* An inline executor runs this on the caller's thread, which reports
   * progress between jobs itself. */
  int inline_run = !rp__executor_threaded(s->ex[w->index]);
  uint8_t *part = NULL;
  size_t cap = 0;
  pthread_mutex_lock(&s->mu);
  for (;;) {
    job *j = NULL;
    int err;
    double t0, took;
    size_t need;
    while (s->done < s->njobs && in_time(s, w->index)) {
      if ((j = take(s, w->index)) != NULL)
        break;
      /* Nothing to take now. With a deadline the step ends here for this
       * device (jobs a failing device releases go in the next step);
       * without one, wait for them or for the end. */
      if (s->deadline != INFINITY || s->alive_count == 0)
        break;
      pthread_cond_wait(&s->cv, &s->mu);
    }
    if (j == NULL)
      break;
    j->state = 1;
    s->taken[w->index]++;
    pthread_mutex_unlock(&s->mu);
    need = (size_t)box_voxels(&j->b);
    err = 0;
    if (need > cap) {
      rp__free(dctx, part);
      part = rp__malloc(dctx, need);
      cap = part != NULL ? need : 0;
      if (part == NULL)
        err = rp__fail(dctx, RP_ENOMEM, "rp_ao_compute: out of memory "
                       "for a block of %zu voxels", need);
    }
    t0 = rp__now_ms();
    if (err == 0)
      err = rp_device_compute_ao(dev, s->plan, j->b.lo, j->b.end, part);
    if (err == 0 && part != NULL)
      scatter(s->ao->data, s->plan->dims, &j->b, part);
    took = rp__now_ms() - t0;
    pthread_mutex_lock(&s->mu);
    s->rep.devices[w->index].busy_ms += took;
    if (err != 0) {
      uint32_t k;
      /* Lost: this job and every other of this device go to the rest. */
      j->state = 0;
      for (k = 0; k < s->njobs; k++)
        if (s->jobs[k].owner == (int)w->index)
          s->jobs[k].owner = -1;
      s->alive[w->index] = 0;
      s->alive_count--;
      if (s->first_err == 0) {
        s->first_err = err;
        snprintf(s->first_error, sizeof s->first_error, "device %u: %s",
                 w->index, rp_last_error(dctx));
      }
      s->rep.devices[w->index].status = err;
      pthread_cond_broadcast(&s->cv);
      break;
    }
    j->state = 2;
    s->done++;
    s->rep.devices[w->index].voxels += need;
    s->rep.devices[w->index].full_bricks +=
        rp_ao_plan_full_bricks(s->plan, j->b.lo, j->b.end);
    s->rep.devices[w->index].jobs++;
    pthread_cond_broadcast(&s->cv);
    if (inline_run)
      (void)report_progress(s);
  }
  s->active--;
  pthread_cond_broadcast(&s->cv);
  pthread_mutex_unlock(&s->mu);
  /* The run is its caller's again: only the device's context from here. */
  rp__free(dctx, part);
}

/* ---- Static split ------------------------------------------------------ */

typedef struct bsp_node {
  box b;
  uint32_t devices;    /* devices under this node */
  uint32_t first;      /* index of its first device */
  double cap_left, cap_right; /* summed device speeds on each side */
  int axis;            /* split axis; -1 for a leaf */
  uint32_t plane;      /* split position, voxels, a multiple of 4 inside */
  int left, right;     /* children's node indices */
} bsp_node;

static int longest_axis(const box *b) {
  int a, best = 0;
  for (a = 1; a < 3; a++)
    if (b->end[a] - b->lo[a] > b->end[best] - b->lo[best])
      best = a;
  return best;
}

/* Places `plane` on the brick grid inside (lo, end) when the box allows,
 * so that no brick is split between two devices. */
static uint32_t snap_plane(uint32_t plane, uint32_t lo, uint32_t end) {
  uint32_t p = (plane + RP_AO_BRICK / 2) / RP_AO_BRICK * RP_AO_BRICK;
  if (p <= lo || p >= end)
    p = plane;
  if (p <= lo)
    p = lo + 1;
  if (p >= end)
    p = end - 1;
  return p;
}

static double capacity(const double *speed, uint32_t first, uint32_t n) {
  double c = 0.0;
  uint32_t i;
  for (i = 0; i < n; i++)
    c += speed[first + i];
  return c;
}

/* Builds the BSP under node `k` (already holding its box and devices);
 * nodes are appended to `nodes`. The first split puts the plane where
 * the sides' volumes are in the ratio of their devices' speeds. */
static void bsp_build(bsp_node *nodes, int *count, int k,
                      const double *speed) {
  bsp_node *nd = &nodes[k];
  uint32_t nl, len;
  int a;
  nd->axis = -1;
  nd->left = nd->right = -1;
  if (nd->devices < 2)
    return;
  a = longest_axis(&nd->b);
  len = nd->b.end[a] - nd->b.lo[a];
  if (len < 2)
    return; /* a one-voxel box cannot be split: one device gets it */
  nl = nd->devices / 2;
  nd->axis = a;
  nd->cap_left = capacity(speed, nd->first, nl);
  nd->cap_right = capacity(speed, nd->first + nl, nd->devices - nl);
  nd->plane = snap_plane(
      nd->b.lo[a] + (uint32_t)((double)len * nd->cap_left /
                               (nd->cap_left + nd->cap_right)),
      nd->b.lo[a], nd->b.end[a]);
  nd->left = (*count)++;
  nd->right = (*count)++;
  nodes[nd->left].b = nd->b;
  nodes[nd->left].b.end[a] = nd->plane;
  nodes[nd->left].devices = nl;
  nodes[nd->left].first = nd->first;
  nodes[nd->right].b = nd->b;
  nodes[nd->right].b.lo[a] = nd->plane;
  nodes[nd->right].devices = nd->devices - nl;
  nodes[nd->right].first = nd->first + nl;
  bsp_build(nodes, count, nd->left, speed);
  bsp_build(nodes, count, nd->right, speed);
}

/* Re-derives the children's boxes after a plane moved. */
static void bsp_reshape(bsp_node *nodes, int k) {
  bsp_node *nd = &nodes[k];
  uint32_t len;
  int a = nd->axis;
  if (a < 0)
    return;
  len = nd->b.end[a] - nd->b.lo[a];
  if (len < 2) {
    nd->axis = -1;
    return;
  }
  if (nd->plane <= nd->b.lo[a] || nd->plane >= nd->b.end[a])
    nd->plane = nd->b.lo[a] + len / 2;
  nodes[nd->left].b = nd->b;
  nodes[nd->left].b.end[a] = nd->plane;
  nodes[nd->right].b = nd->b;
  nodes[nd->right].b.lo[a] = nd->plane;
  bsp_reshape(nodes, nd->left);
  bsp_reshape(nodes, nd->right);
}

/* Full bricks per unit of device speed on each side of node k's plane
 * at `plane`: D = left - right (seed 004's D(B_i, B_j), per device when
 * the devices are alike). */
static double imbalance(const rp_ao_plan *plan, const bsp_node *nd,
                        uint32_t plane, double *smaller) {
  box l = nd->b, r = nd->b;
  double fl, fr, nl = 0, nr = 0;
  l.end[nd->axis] = plane;
  r.lo[nd->axis] = plane;
  fl = (double)rp_ao_plan_full_bricks(plan, l.lo, l.end);
  fr = (double)rp_ao_plan_full_bricks(plan, r.lo, r.end);
  nl = fl / nd->cap_left;
  nr = fr / nd->cap_right;
  *smaller = nl < nr ? nl : nr;
  return nl - nr;
}

/* Moves node k's plane, then its children's, until each is balanced or
 * the time runs out (seed 004 section 5.2.6). A move is as many brick
 * layers as the difference of full bricks fills, given the full bricks
 * of the layer at the plane: the difference in counts sets the step, as
 * the seed does, and a step is never under one layer. Where the seed
 * stops when the sign of D flips, we keep the two planes either side of
 * the flip and halve the gap between them until it is one layer: a
 * sparse layer at the plane makes the proportional step overshoot far,
 * and stopping there would keep the unbalanced plane (docs/ao.md,
 * "Across devices"). D is monotonic in the plane, so the halving
 * converges. */
static void bsp_balance(const rp_ao_plan *plan, bsp_node *nodes, int k,
                        double tolerance, double deadline) {
  bsp_node *nd = &nodes[k];
  int a = nd->axis, bracketed = 0;
  uint32_t other = 0; /* with bracketed: the plane across the flip */
  double d_other = 0.0;
  if (a < 0)
    return;
  for (;;) {
    double smaller, d = imbalance(plan, nd, nd->plane, &smaller), d2, s2;
    uint32_t next;
    if (fabs(d) <= tolerance * (smaller > 1.0 ? smaller : 1.0) ||
        rp__now_ms() > deadline)
      break;
    if (bracketed) {
      uint32_t lo = other < nd->plane ? other : nd->plane;
      uint32_t hi = other < nd->plane ? nd->plane : other;
      if (hi - lo <= RP_AO_BRICK) {
        if (fabs(d_other) < fabs(d))
          nd->plane = other;
        break;
      }
      next = snap_plane(lo + (hi - lo) / 2, lo, hi);
    } else {
      double layer, dn, moved;
      uint32_t steps;
      box slab = nd->b;
      /* The full bricks of the one-brick layer just past the plane on
       * the heavier side. */
      if (d > 0) {
        slab.lo[a] = nd->plane >= RP_AO_BRICK ? nd->plane - RP_AO_BRICK : 0;
        slab.end[a] = nd->plane;
      } else {
        slab.lo[a] = nd->plane;
        slab.end[a] = nd->plane + RP_AO_BRICK;
      }
      if (slab.lo[a] < nd->b.lo[a])
        slab.lo[a] = nd->b.lo[a];
      if (slab.end[a] > nd->b.end[a])
        slab.end[a] = nd->b.end[a];
      layer = slab.end[a] > slab.lo[a]
                  ? (double)rp_ao_plan_full_bricks(plan, slab.lo, slab.end)
                  : 0.0;
      /* Moving one layer from the heavier side to the lighter changes
       * the difference by about layer * (1/cap_left + 1/cap_right). */
      dn = layer * (1.0 / nd->cap_left + 1.0 / nd->cap_right);
      moved = dn > 0.0 ? fabs(d) / dn : 1.0;
      steps = moved < 1.0 ? 1u : moved > 1e6 ? 1000000u : (uint32_t)moved;
      if (d > 0) {
        uint64_t back = (uint64_t)steps * RP_AO_BRICK;
        next = nd->plane - nd->b.lo[a] > back ? nd->plane - (uint32_t)back
                                              : nd->b.lo[a] + 1;
      } else {
        uint64_t fwd = (uint64_t)nd->plane + (uint64_t)steps * RP_AO_BRICK;
        next = fwd < nd->b.end[a] ? (uint32_t)fwd : nd->b.end[a] - 1;
      }
    }
    if (next == nd->plane)
      break;
    d2 = imbalance(plan, nd, next, &s2);
    if ((d2 > 0) != (d > 0)) {
      /* Across the balance point: next and the plane bracket it. */
      bracketed = 1;
      other = next;
      d_other = d2;
      if (fabs(d2) < fabs(d)) {
        other = nd->plane;
        d_other = d;
        nd->plane = next;
      }
    } else {
      nd->plane = next;
    }
  }
  bsp_reshape(nodes, k);
  bsp_balance(plan, nodes, nd->left, tolerance, deadline);
  bsp_balance(plan, nodes, nd->right, tolerance, deadline);
}

/* ---- Jobs -------------------------------------------------------------- */

/* v rounded down to the brick grid, but not below lo. */
static uint32_t brick_floor(uint32_t v, uint32_t lo) {
  uint32_t f = v / RP_AO_BRICK * RP_AO_BRICK;
  return f > lo ? f : lo;
}

static int static_jobs(rp_context *ctx, const rp_ao_plan *plan, uint32_t n,
                       int balanced, const rp_ao_schedule *sc, job **out,
                       uint32_t *njobs, double *balance_ms,
                       rp_ao_report *rep) {
  bsp_node nodes[2 * RP_AO_MAX_DEVICES];
  int count = 1, k;
  uint32_t nj = 0, s;
  job *jobs;
  double t0 = rp__now_ms();
  memset(nodes, 0, sizeof nodes);
  memcpy(nodes[0].b.end, plan->dims, sizeof nodes[0].b.end);
  nodes[0].devices = n;
  bsp_build(nodes, &count, 0, sc->speed);
  if (balanced)
    bsp_balance(plan, nodes, 0, sc->tolerance, t0 + sc->balance_ms);
  *balance_ms = balanced ? rp__now_ms() - t0 : 0.0;
  jobs = rp__calloc(ctx, (size_t)count * STATIC_SLABS, sizeof *jobs);
  if (jobs == NULL)
    return RP__AO_FAIL(ctx, RP_ENOMEM, "rp_ao_compute: out of memory");
  /* Each leaf's block, as z-slabs so its device reports progress; a
   * block without a full brick is left to the host fill. */
  for (k = 0; k < count; k++) {
    const bsp_node *nd = &nodes[k];
    uint32_t depth = nd->b.end[2] - nd->b.lo[2];
    uint32_t slabs = depth < STATIC_SLABS ? depth : STATIC_SLABS;
    if (nd->axis >= 0 || nd->devices == 0)
      continue;
    if (rep != NULL) {
      memcpy(rep->devices[nd->first].block_lo, nd->b.lo, sizeof nd->b.lo);
      memcpy(rep->devices[nd->first].block_end, nd->b.end,
             sizeof nd->b.end);
    }
    for (s = 0; s < slabs; s++) {
      box b = nd->b;
      /* Slab faces on the brick grid, so no brick counts twice. */
      b.lo[2] = brick_floor(nd->b.lo[2] + (uint32_t)((uint64_t)depth * s /
                                                     slabs),
                            nd->b.lo[2]);
      b.end[2] = s + 1 == slabs
                     ? nd->b.end[2]
                     : brick_floor(nd->b.lo[2] +
                                       (uint32_t)((uint64_t)depth * (s + 1) /
                                                  slabs),
                                   nd->b.lo[2]);
      if (b.end[2] <= b.lo[2] ||
          rp_ao_plan_full_bricks(plan, b.lo, b.end) == 0)
        continue;
      jobs[nj].b = b;
      jobs[nj].owner = (int)nd->first;
      nj++;
    }
  }
  *out = jobs;
  *njobs = nj;
  return 0;
}

static int dynamic_jobs(rp_context *ctx, const rp_ao_plan *plan,
                        uint32_t edge, job **out, uint32_t *njobs) {
  uint32_t g[3], a, x, y, z, nj = 0;
  size_t total;
  job *jobs;
  for (a = 0; a < 3; a++)
    g[a] = plan->dims[a] / edge + (plan->dims[a] % edge != 0);
  total = (size_t)g[0] * g[1] * g[2];
  jobs = rp__calloc(ctx, total > 0 ? total : 1, sizeof *jobs);
  if (jobs == NULL)
    return RP__AO_FAIL(ctx, RP_ENOMEM,
                       "rp_ao_compute: out of memory for %zu blocks", total);
  for (z = 0; z < g[2]; z++)
    for (y = 0; y < g[1]; y++)
      for (x = 0; x < g[0]; x++) {
        box b;
        uint32_t c[3] = {x, y, z};
        for (a = 0; a < 3; a++) {
          b.lo[a] = c[a] * edge;
          b.end[a] = b.lo[a] + edge < plan->dims[a] ? b.lo[a] + edge
                                                    : plan->dims[a];
        }
        if (rp_ao_plan_full_bricks(plan, b.lo, b.end) == 0)
          continue;
        jobs[nj].b = b;
        jobs[nj].owner = -1;
        nj++;
      }
  *out = jobs;
  *njobs = nj;
  return 0;
}

/* ---- The call ---------------------------------------------------------- */

int rp__ao_schedule_resolve(rp_context *ctx, const char *fn,
                            const rp_ao_schedule *in, rp_ao_schedule *sc) {
  uint32_t i;
  memset(sc, 0, sizeof *sc);
  if (in != NULL)
    *sc = *in;
  if (sc->block == 0)
    sc->block = DEFAULT_BLOCK;
  if (sc->balance_ms == 0.0)
    sc->balance_ms = DEFAULT_BALANCE_MS;
  if (sc->tolerance == 0.0)
    sc->tolerance = DEFAULT_TOLERANCE;
  for (i = 0; i < RP_AO_MAX_DEVICES; i++) {
    if (!isfinite(sc->speed[i]))
      return RP__AO_FAIL(ctx, RP_ENOTFINITE, "%s: speed[%u] is %g", fn, i,
                         sc->speed[i]);
    if (sc->speed[i] < 0.0)
      return RP__AO_FAIL(ctx, RP_ERANGE, "%s: speed[%u] is %g; must not be "
                         "negative", fn, i, sc->speed[i]);
    if (sc->speed[i] == 0.0)
      sc->speed[i] = 1.0;
  }
  if (sc->scheme != RP_AO_DYNAMIC && sc->scheme != RP_AO_STATIC &&
      sc->scheme != RP_AO_STATIC_NAIVE)
    return RP__AO_FAIL(ctx, RP_EINVAL, "%s: unknown scheme %d", fn,
                       (int)sc->scheme);
  if (sc->block % RP_AO_BRICK != 0)
    return RP__AO_FAIL(ctx, RP_EINVAL,
                       "%s: block %u is not a multiple of the %u-voxel brick",
                       fn, sc->block, RP_AO_BRICK);
  if (!isfinite(sc->balance_ms) || !isfinite(sc->tolerance))
    return RP__AO_FAIL(ctx, RP_ENOTFINITE,
                       "%s: balance_ms and tolerance must be finite", fn);
  if (sc->balance_ms < 0.0 || sc->tolerance < 0.0)
    return RP__AO_FAIL(
        ctx, RP_ERANGE,
        "%s: balance_ms %g and tolerance %g must not be negative", fn,
        sc->balance_ms, sc->tolerance);
  return 0;
}

static int check_args(rp_context *ctx, rp_device *const *devs, uint32_t n,
                      const rp_ao_plan *plan, const rp_ao_schedule *in,
                      rp_ao_schedule *sc) {
  static const char *fn = "rp_ao_compute";
  uint32_t i, k;
  int err;
  if (devs == NULL || plan == NULL) {
    /* Not rp__fail's code: the analyzer then sees no caller go on with
     * a NULL. */
    rp__fail(ctx, RP_EINVAL, "%s: devices and plan are required", fn);
    return RP_EINVAL;
  }
  if (n < 1 || n > RP_AO_MAX_DEVICES)
    return RP__AO_FAIL(ctx, RP_ERANGE, "%s: %u devices; 1 to %u are allowed",
                       fn, n, RP_AO_MAX_DEVICES);
  if ((err = rp__ao_schedule_resolve(ctx, fn, in, sc)) != 0)
    return err;
  for (i = 0; i < n; i++) {
    if (devs[i] == NULL)
      return RP__AO_FAIL(ctx, RP_EINVAL, "%s: device %u is NULL", fn, i);
    /* A context serves one thread at a time, and each device here runs
     * on a thread of its own. */
    for (k = 0; k < i; k++)
      if (devs[k] == devs[i] ||
          rp__device_context(devs[k]) == rp__device_context(devs[i]))
        return RP__AO_FAIL(ctx, RP_EINVAL,
                           "%s: devices %u and %u %s; each "
                           "device needs a context of its own",
                           fn, k, i,
                           devs[k] == devs[i] ? "are the same device"
                                              : "share a context");
    if (!rp__device_holds(devs[i], plan->vol_id, plan->tf_id))
      return RP__AO_FAIL(
          ctx, RP_ESTATE,
          "%s: device %u does not hold the plan's volume and transfer function",
          fn, i);
  }
  return 0;
}

/* The run over `count` executors (their devices checked by check_args),
 * which it owns when own_ex. On failure the caller keeps the executors. */
static int run_make(rp_context *ctx, rp__executor *const *ex, uint32_t count,
                    int own_ex, const rp_ao_plan *plan,
                    const rp_ao_schedule *sc, rp_ao_run **out) {
  rp_ao_run *s;
  double balance_ms = 0.0;
  uint32_t i;
  int err;
  if ((s = rp__calloc(ctx, 1, sizeof *s)) == NULL)
    return RP__AO_FAIL(ctx, RP_ENOMEM, "rp_ao_run_create: out of memory");
  s->ctx = ctx;
  s->plan = plan;
  s->n = count;
  s->sc = *sc;
  s->t0 = rp__now_ms();
  s->rep.device_count = count;
  for (i = 0; i < count; i++) {
    s->ex[i] = ex[i];
    s->alive[i] = 1;
    s->lanes[i].job.run = device_job;
    s->lanes[i].s = s;
    s->lanes[i].index = i;
  }
  s->alive_count = count;
  if ((err = rp__ao_new(ctx, plan, &s->ao)) != 0) {
    rp__free(ctx, s);
    return err;
  }
  /* Voxels no job computes (bricks without a full brick) are unoccluded
   * by definition. */
  memset(s->ao->data, 255,
         (size_t)plan->dims[0] * plan->dims[1] * plan->dims[2]);
  err = sc->scheme == RP_AO_DYNAMIC
            ? dynamic_jobs(ctx, plan, sc->block, &s->jobs, &s->njobs)
            : static_jobs(ctx, plan, count, sc->scheme == RP_AO_STATIC, sc,
                          &s->jobs, &s->njobs, &balance_ms, &s->rep);
  if (err != 0) {
    rp_ao_destroy(s->ao);
    rp__free(ctx, s);
    return err;
  }
  s->rep.balance_ms = balance_ms;
  s->own_ex = own_ex;
  pthread_mutex_init(&s->mu, NULL);
  pthread_cond_init(&s->cv, NULL);
  *out = s;
  return 0;
}

int rp__ao_run_create(rp_context *ctx, rp__executor *const *ex,
                      uint32_t count, const rp_ao_plan *plan,
                      const rp_ao_schedule *schedule, rp_ao_run **out) {
  rp_device *devs[RP_AO_MAX_DEVICES];
  rp_ao_schedule sc = {0};
  uint32_t i;
  int err;
  *out = NULL;
  for (i = 0; i < count && i < RP_AO_MAX_DEVICES; i++)
    devs[i] = rp__executor_device(ex[i]);
  if ((err = check_args(ctx, devs, count, plan, schedule, &sc)) != 0)
    return err;
  return run_make(ctx, ex, count, 0, plan, &sc, out);
}

int rp_ao_run_create(rp_context *ctx, rp_device *const *devices,
                     uint32_t count, const rp_ao_plan *plan,
                     const rp_ao_schedule *schedule, rp_ao_run **out) {
  rp__executor *ex[RP_AO_MAX_DEVICES];
  rp_ao_schedule sc = {0};
  uint32_t i, made;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (out == NULL) {
    rp__fail(ctx, RP_EINVAL, "rp_ao_run_create: out is required");
    return RP_EINVAL;
  }
  *out = NULL;
  if ((err = check_args(ctx, devices, count, plan, schedule, &sc)) != 0)
    return err;
  /* Plain devices get owners for the run's life: one worker each, the
   * caller's thread reporting progress while they run. */
  for (made = 0; made < count; made++)
    if ((err = rp__executor_create(ctx, devices[made], 1, &ex[made])) != 0)
      break;
  if (err == 0 &&
      (err = run_make(ctx, ex, count, 1, plan, &sc, out)) == 0)
    return 0;
  for (i = 0; i < made; i++)
    rp__executor_destroy(ex[i]);
  return err;
}

int rp_ao_run_step(rp_ao_run *s, double budget_ms, double *fraction) {
  uint32_t idx[RP_AO_MAX_DEVICES], i, n = 0;
  int err = 0;
  if (s == NULL)
    return RP_EINVAL;
  if (isnan(budget_ms))
    return RP__AO_FAIL(s->ctx, RP_ENOTFINITE, "rp_ao_run_step: budget_ms "
                       "is NaN");
  if (!(budget_ms > 0.0))
    return RP__AO_FAIL(s->ctx, RP_ERANGE, "rp_ao_run_step: budget_ms %g "
                       "must be above 0 (INFINITY: to the end)", budget_ms);
  pthread_mutex_lock(&s->mu);
  s->deadline = budget_ms == INFINITY ? INFINITY : rp__now_ms() + budget_ms;
  memset(s->taken, 0, sizeof s->taken);
  s->reported = s->done;
  if (s->done < s->njobs)
    for (i = 0; i < s->n; i++)
      if (s->alive[i])
        idx[n++] = i;
  s->active = n;
  pthread_mutex_unlock(&s->mu);
  /* Outside the lock: an inline executor runs the job here. */
  for (i = 0; i < n; i++)
    rp__executor_submit(s->ex[idx[i]], &s->lanes[idx[i]].job);
  /* Progress from the calling thread, on every job finished. */
  pthread_mutex_lock(&s->mu);
  while (s->active > 0)
    if (!report_progress(s))
      pthread_cond_wait(&s->cv, &s->mu);
  pthread_mutex_unlock(&s->mu);
  if (s->alive_count == 0 && s->done < s->njobs) {
    err = s->first_err != 0 ? s->first_err : RP_EDEVICE;
    rp__fail(s->ctx, err, "rp_ao_compute: every device failed; first, %s",
             s->first_error);
  }
  if (fraction != NULL)
    *fraction = s->njobs > 0 ? (double)s->done / (double)s->njobs : 1.0;
  return err;
}

int rp_ao_run_finish(rp_ao_run *s, rp_ao **out, rp_ao_report *report) {
  uint32_t i;
  if (s == NULL)
    return RP_EINVAL;
  if (out == NULL)
    return RP__AO_FAIL(s->ctx, RP_EINVAL, "rp_ao_run_finish: out is NULL");
  if (s->done < s->njobs || s->ao == NULL)
    return RP__AO_FAIL(s->ctx, RP_ESTATE, "rp_ao_run_finish: %u of %u jobs "
                       "done", s->done, s->njobs);
  if (s->sc.progress != NULL)
    s->sc.progress(1.0, s->sc.user);
  s->rep.total_ms = rp__now_ms() - s->t0;
  s->rep.min_ms = INFINITY;
  s->rep.max_ms = 0.0;
  for (i = 0; i < s->n; i++) {
    if (s->rep.devices[i].jobs == 0)
      continue;
    s->rep.min_ms = fmin(s->rep.min_ms, s->rep.devices[i].busy_ms);
    s->rep.max_ms = fmax(s->rep.max_ms, s->rep.devices[i].busy_ms);
  }
  if (s->rep.min_ms == INFINITY)
    s->rep.min_ms = 0.0;
  if (report != NULL)
    *report = s->rep;
  *out = s->ao;
  s->ao = NULL;
  return 0;
}

void rp_ao_run_report(const rp_ao_run *s, rp_ao_report *report) {
  if (s != NULL && report != NULL)
    *report = s->rep;
}

void rp_ao_run_destroy(rp_ao_run *s) {
  uint32_t i;
  if (s == NULL)
    return;
  for (i = 0; i < s->n && s->own_ex; i++)
    rp__executor_destroy(s->ex[i]);
  pthread_cond_destroy(&s->cv);
  pthread_mutex_destroy(&s->mu);
  rp_ao_destroy(s->ao);
  rp__free(s->ctx, s->jobs);
  rp__free(s->ctx, s);
}

int rp_ao_compute(rp_context *ctx, rp_device *const *devices, uint32_t count,
                  const rp_ao_plan *plan, const rp_ao_schedule *schedule,
                  rp_ao **out, rp_ao_report *report) {
  rp_ao_run *run = NULL;
  rp_ao *ao = NULL;
  rp_ao_report rep;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (out == NULL) {
    rp__fail(ctx, RP_EINVAL, "rp_ao_compute: out is required");
    return RP_EINVAL;
  }
  if ((err = rp_ao_run_create(ctx, devices, count, plan, schedule, &run)) !=
      0)
    return err;
  if ((err = rp_ao_run_step(run, INFINITY, NULL)) == 0)
    err = rp_ao_run_finish(run, &ao, &rep);
  else
    rp_ao_run_report(run, &rep);
  rp_ao_run_destroy(run);
  /* The report says which device failed, even when the call fails. */
  if (report != NULL)
    *report = rep;
  if (err != 0)
    return err;
  *out = ao;
  return 0;
}
