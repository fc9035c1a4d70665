/* Devices that come back (rp_device_state, raypace_group.h).
 *
 * A stall is not a failure. A device given up on at its deadline (a
 * thread descheduled on a busy machine, a driver that paused) is LATE:
 * dropped from the split while its worker ends the late work, which the
 * caller's image never sees. At the next render after that work ended it
 * is on PROBATION: its share is capped at RP_GROUP_PROBATION_SHARE, so a
 * device that is still slow costs a frame little, and after
 * RP_GROUP_PROBATION_FRAMES frames on time in a row it is ACTIVE again,
 * on its rate's share. The late work's time teaches its rate like any
 * frame's: one stall is outvoted by the median of three (shares.h), a
 * device that really slowed is followed.
 *
 * A device that fails (RP_EDEVICE, or an upload it cannot hold) is
 * RETRY: after a back-off of RP_GROUP_RETRY_FRAMES << (failures - 1)
 * renders it is re-created from its desc and given the group's volume,
 * TF and AO again, then on probation. RP_GROUP_MAX_FAILURES failures in
 * a row (a failed re-creation counts; probation passed resets them) and
 * it is OUT for good. The back-off counts renders, not time: what a
 * re-creation costs (a context, uploads) is then paid at most once in
 * so many frames, however fast frames come.
 *
 * Everything here runs on the coordinator's thread, between rounds. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "device.h"
#include "group.h"

void rp__health_keep_desc(rp__member *w, const rp_device_desc *dd) {
  const rp_ext_header *e;
  const void *next = NULL;
  w->dd = *dd;
  if (dd->backend != NULL) {
    snprintf(w->backend, sizeof w->backend, "%s", dd->backend);
    w->dd.backend = w->backend;
  }
  /* The chain was checked when the device opened: only known types,
   * each once. */
  if ((e = rp__ext_find(dd->next, RP_EXT_TEST_BACKEND)) != NULL) {
    memcpy(&w->ext_test, e, sizeof w->ext_test);
    w->ext_test.header.next = next;
    next = &w->ext_test;
  }
  if ((e = rp__ext_find(dd->next, RP_EXT_FAULTS)) != NULL) {
    memcpy(&w->ext_faults, e, sizeof w->ext_faults);
    w->ext_faults.header.next = next;
    next = &w->ext_faults;
  }
  w->dd.next = next;
}

void rp__health_fail(rp_device_group *g, rp__member *w) {
  w->dropped = 1;
  w->on_time = 0;
  w->failures++;
  if (w->failures >= RP_GROUP_MAX_FAILURES) {
    w->state = RP_DEVICE_OUT;
  } else {
    w->state = RP_DEVICE_RETRY;
    /* It sits out that many renders and is re-created at the next. */
    w->retry_at = g->frame_no + 1 +
                  ((uint64_t)RP_GROUP_RETRY_FRAMES << (w->failures - 1));
  }
  g->have_prev = 0;
}

void rp__health_late(rp_device_group *g, rp__member *w, double cost) {
  w->dropped = 1;
  w->on_time = 0;
  w->state = RP_DEVICE_LATE;
  w->late_cost = cost;
  g->have_prev = 0;
}

void rp__health_on_time(rp_device_group *g, rp__member *w) {
  if (w->state != RP_DEVICE_PROBATION)
    return;
  if (++w->on_time >= RP_GROUP_PROBATION_FRAMES) {
    w->state = RP_DEVICE_ACTIVE;
    w->failures = 0;
    /* Straight to its rate's share: damping from the capped one would
     * keep it under it for several frames more. */
    g->have_prev = 0;
  }
}

/* Gives the device what the group last set and it does not hold: after
 * a new volume, its TF and AO too (they were made for the volume). */
static int catch_up(rp_device_group *g, rp__member *w) {
  int err, fresh = 0;
  if (g->vol == NULL)
    return 0; /* nothing set yet: the first set_volume reaches it */
  if (w->have_vol_gen != g->vol_gen) {
    w->vol = g->vol;
    w->vol_gen = g->vol_gen;
    if ((err = rp__group_run_one(g, w, RP__JOB_VOLUME)) != 0)
      return err;
    fresh = 1;
  }
  if (g->tf != NULL && (fresh || w->have_tf_gen != g->tf_gen)) {
    w->tf = g->tf;
    w->occ = g->occ;
    w->tf_gen = g->tf_gen;
    if ((err = rp__group_run_one(g, w, RP__JOB_TF)) != 0)
      return err;
  }
  /* An AO it lacks, or one released while it was away. */
  if (g->ao != NULL ? fresh || w->have_ao_gen != g->ao_gen
                    : w->have_ao_gen != 0 && w->have_ao_gen != g->ao_gen) {
    w->ao = g->ao;
    w->ao_gen = g->ao_gen;
    if ((err = rp__group_run_one(g, w, RP__JOB_AO)) != 0)
      return err;
  }
  return 0;
}

/* Why re-creating w failed, into w->why (through a buffer of its own:
 * the message may lie in w too). */
static void recreate_failed(rp__member *w, const char *what) {
  char why[sizeof w->why];
  snprintf(why, sizeof why, "re-creating '%s': %s", w->name, what);
  memcpy(w->why, why, sizeof why);
}

/* Re-creates w's device and executor from its kept desc. Builds it was
 * asked for count as tried (the frame builds what it needs), so that
 * rp_device_group_prepared does not wait for a device that is gone. */
static int recreate(rp_device_group *g, rp__member *w) {
  rp_device *dev = NULL;
  uint32_t set;
  int err;
  uv_mutex_lock(&g->build_lock);
  for (set = 0; set < 32; set++) {
    if (!((w->build_want >> set) & 1u))
      continue;
    if (g->build_left[set] > 0 &&
        --g->build_left[set] == 0) {
      g->build_asked &= ~(1u << set);
      g->build_done |= 1u << set;
    }
  }
  w->build_want = 0;
  uv_mutex_unlock(&g->build_lock);
  /* The new device first: the old one stays, and its executor with it,
   * until there is one to replace it (an AO run may hold the executor). */
  rp__clear_error(w->ctx);
  if ((err = rp_device_create(w->ctx, &w->dd, &dev)) != 0) {
    recreate_failed(w, rp_last_error(w->ctx));
    return err;
  }
  /* Its worker is idle (a failed job ended); a build under way ends
   * first. */
  err = rp__executor_rebind(w->ex, dev);
  {
    /* Its clock goes on from the old device's (its lanes are stopped:
     * this thread may read it). */
    uint64_t ns;
    if (rp__device_clock_ns(w->dev, &ns))
      w->clock_base += ns;
  }
  rp_device_destroy(w->dev);
  w->dev = dev;
  w->build_queued = 0;
  w->warm_sets = 0;
  w->key_valid = 0;
  w->have_vol_gen = w->have_tf_gen = w->have_ao_gen = 0;
  w->ao_bytes = 0;
  if (err != 0) {
    /* No worker: nothing submitted to it would run. Out for good. */
    recreate_failed(w, "its worker thread would not start");
    w->failures = RP_GROUP_MAX_FAILURES - 1;
    return err;
  }
  rp_device_get_caps(w->dev, &w->caps);
  w->builds_ahead = rp__device_builds_ahead(w->dev);
  g->can_prepare |= w->builds_ahead;
  return 0;
}

/* Back on probation, its frames on time counted from 0. */
static void readmit(rp_device_group *g, rp__member *w) {
  w->state = RP_DEVICE_PROBATION;
  w->dropped = 0;
  w->on_time = 0;
  w->late_cost = 0.0;
  g->have_prev = 0;
}

/* w's late work ended with `status`: its time teaches its rate (the
 * split learns only from work that ended), then probation, or a failure
 * when the work failed. */
static int late_ended(rp_device_group *g, rp__member *w, int status) {
  if (status != 0 && rp__group_loses_device(status, 0)) {
    w->back_status = status;
    memcpy(w->why, w->error, sizeof w->why);
    rp__health_fail(g, w);
    return 0;
  }
  if (status == 0 && w->late_cost > 0.0) {
    double measured = fmax(w->busy_ms - w->depth_ms, 1e-6) / w->late_cost;
    if (isfinite(measured))
      rp__rate_add(&w->sm, measured);
  }
  if ((w->back_status = catch_up(g, w)) != 0) {
    /* An upload its peers took and it did not: a failure either way. */
    rp__health_fail(g, w);
    return 0;
  }
  readmit(g, w);
  return 1;
}

uint32_t rp__health_begin(rp_device_group *g) {
  uint32_t i, back = 0;
  for (i = 0; i < g->count; i++) {
    rp__member *w = &g->m[i];
    w->back_status = w->ao_lost;
    w->ao_lost = 0;
    if (w->state == RP_DEVICE_LATE) {
      int running;
      uv_mutex_lock(&g->lock);
      running = w->running;
      uv_mutex_unlock(&g->lock);
      /* Ended: what its worker wrote before it said so is ours now. */
      if (!running)
        back += (uint32_t)late_ended(g, w, w->status);
    } else if (w->state == RP_DEVICE_RETRY && g->frame_no >= w->retry_at) {
      int err = recreate(g, w);
      if (err == 0)
        err = catch_up(g, w);
      if (err != 0) {
        w->back_status = err;
        rp__health_fail(g, w);
        continue;
      }
      readmit(g, w);
      back++;
    }
  }
  return back;
}

void rp__health_cap_shares(const rp_device_group *g, double *shares) {
  double excess = 0.0, active = 0.0;
  uint32_t i;
  for (i = 0; i < g->count; i++) {
    if (g->m[i].dropped)
      continue;
    if (g->m[i].state == RP_DEVICE_PROBATION &&
        shares[i] > RP_GROUP_PROBATION_SHARE) {
      excess += shares[i] - RP_GROUP_PROBATION_SHARE;
      shares[i] = RP_GROUP_PROBATION_SHARE;
    } else if (g->m[i].state == RP_DEVICE_ACTIVE) {
      active += shares[i];
    }
  }
  if (!(excess > 0.0))
    return;
  if (!(active > 0.0)) {
    /* Every live device is on probation: someone must render it all. */
    for (i = 0; i < g->count; i++)
      if (!g->m[i].dropped)
        shares[i] += excess / (double)rp_device_group_alive(g);
    return;
  }
  for (i = 0; i < g->count; i++)
    if (!g->m[i].dropped && g->m[i].state == RP_DEVICE_ACTIVE)
      shares[i] += excess * shares[i] / active;
}

void rp__health_report(const rp_device_group *g, rp_group_report *rep) {
  uint32_t i;
  for (i = 0; i < g->count; i++) {
    const rp__member *w = &g->m[i];
    rp_group_device *rd = &rep->devices[i];
    rd->state = w->state;
    rd->failures = w->failures;
    if (w->back_status != 0 && rd->status == 0) {
      rd->status = w->back_status;
      snprintf(rd->error, sizeof rd->error, "%s", w->why);
    }
    rd->dropped = w->dropped;
    rd->retry_in = w->state == RP_DEVICE_RETRY && w->retry_at > g->frame_no
                       ? (uint32_t)(w->retry_at - g->frame_no - 1)
                       : 0;
  }
}
