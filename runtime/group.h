/* A device group's insides, shared by group.c (the group's lifetime, its
 * uploads, builds and AO, and the frame: plan -> round -> learn ->
 * re-render), group_round.c (one round of jobs on the devices'
 * executors: regions, the tail's strips, deadlines) and group_health.c
 * (devices that come back: probation, re-creation, back-off). */
#ifndef RP_GROUP_INTERNAL_H
#define RP_GROUP_INTERNAL_H

#include <stdint.h>
#include <uv.h>

#include "executor.h"
#include "internal.h"
#include "raypace_testing.h"
#include "raypace_group.h"
#include "shares.h"

/* What a member's job does. */
enum { RP__JOB_VOLUME, RP__JOB_TF, RP__JOB_AO, RP__JOB_RENDER,
       RP__JOB_ESTIMATE };

/* What a device's current depth pass was run for (memset before filling:
 * compared with memcmp). */
typedef struct rp__depth_key {
  rp_camera cam;
  uint32_t sw, sh, skip;
  uint64_t vol_gen, tf_gen;
} rp__depth_key;

/* A member's figures summed over its render jobs. */
typedef struct rp__job_sums {
  double depth_ms, raycast_ms, upload_ms, busy_ms;
  uint32_t depth_passes, jobs;
  uint64_t samples;
} rp__job_sums;

enum { RP__STRIP_FREE, RP__STRIP_CLAIMED, RP__STRIP_DONE };

typedef struct rp__member {
  rp_device_group *g;
  uint32_t index;
  rp_context *ctx; /* the device's own: errors on two threads at once */
  rp_device *dev;
  rp__executor *ex; /* the device's owner: every call to it is a job */
  rp__job job;      /* its job on the executor's worker */
  rp_caps caps;
  char name[168];
  rp_cost_model *model;
  int dropped, trained;
  /* Health (group_health.c), the coordinator's: its state
   * (rp_device_state; dropped is 1 in LATE, RETRY and OUT), failures in
   * a row, the group frame a RETRY re-creates it at, its frames on time
   * on probation, and, LATE, the predicted tile cost of the work it was
   * given up on (0: none known), whose time teaches its rate when it
   * ends. */
  rp_device_state state;
  uint32_t failures, on_time;
  uint64_t retry_at;
  double late_cost;
  int gave_up; /* given up on at its deadline this round */
  /* A failure coming back at this render's start (re-creation, catch-up
   * or late work), its message in `why`: the report's status. */
  int back_status;
  /* Lost in an AO job between renders (ao_learn), message in `why`: the
   * next render's back_status, so that its report says why it went. */
  int ao_lost;
  /* Its desc, kept to re-create it: the backend's name and the
   * extension structs, copied and chained again. */
  rp_device_desc dd;
  char backend[64];
  rp_fault_desc ext_faults;
  rp_test_backend_desc ext_test;
  /* Its earlier creations' own clocks, summed (rp__group_clock_ns). */
  uint64_t clock_base;
  /* What the device holds (the worker sets them when an upload job
   * succeeds): the volume, TF and AO generations; 0: none. */
  uint64_t have_vol_gen, have_tf_gen, have_ao_gen;
  /* Effect sets it has rendered since its volume upload, bit (1 << set):
   * a set's first render builds a kernel variant, which no deadline may
   * count as the device being slow. */
  uint32_t warm_sets;

  /* The job, under g->lock: `kind` and its inputs are set by the
   * coordinator before it submits; `running` from then until the job
   * has ended (the worker clears it). */
  int kind, running;
  const rp_volume *vol;
  const rp_tf *tf;
  const rp_occupancy *occ;
  const rp_ao *ao;      /* RP__JOB_AO: NULL releases the device's AO */
  double ao_speed;      /* full bricks per ms of its last AO work; 0:
                           unknown */
  uint64_t ao_bytes;    /* the device's AO bytes after its last job */
  rp_camera cam;
  rp_render_desc desc;
  rp_region region;
  uint64_t vol_gen, tf_gen, ao_gen;

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
  rp_upload_estimate est; /* RP__JOB_ESTIMATE */
  rp__depth_key key;
  int key_valid;
  /* Its render jobs that succeeded this round, banked by the worker as
   * each ends: the fields above hold the last job only, and with a tail
   * a device renders its region and then strips. */
  rp__job_sums round;

  /* Kernels built ahead on the executor's build lane, under
   * g->build_lock: the sets it is still to build (bit 1 << set), and
   * whether its build job is queued or running. */
  rp__job build_job;
  uint32_t build_want;
  int build_queued;
  int builds_ahead; /* its backend has `prepare` */

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
  /* The split's model of the device (shares.h). */
  rp__split_model sm;
} rp__member;

struct rp_device_group {
  rp_context *ctx;
  rp_group_desc desc;
  double fixed_shares[RP_GROUP_MAX_DEVICES];
  uint32_t count;
  rp__member m[RP_GROUP_MAX_DEVICES];
  /* Orders the coordinator's and the workers' view of the members (the
   * job fields above) and of the tail; `done` is signalled when a job
   * ends or a worker takes a strip whose deadline comes first. */
  uv_mutex_t lock;
  uv_cond_t done;
  int threads; /* the executors have workers (count >= 2) */
  uint64_t vol_gen, tf_gen, ao_gen;
  /* The last volume, TF and AO set: a device that comes back gets them
   * (catch-up, group_health.c). */
  const rp_volume *vol;
  const rp_tf *tf;
  const rp_occupancy *occ;
  const rp_ao *ao;
  uint64_t frame_no; /* renders asked for: the back-off's clock */
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
  double wake_at; /* when the round's wait next wakes by itself */
  uint32_t strip_n;
  rp_region strip_px[RP_GROUP_MAX_STRIPS];
  double strip_cost[RP_GROUP_MAX_STRIPS];
  uint8_t strip_state[RP_GROUP_MAX_STRIPS];
  uint8_t strip_owner[RP_GROUP_MAX_STRIPS];
  /* The last frame's, for rp_device_group_train. */
  int can_train;
  double last_render_ms;
  uint64_t last_samples;
  /* Kernels built ahead (rp_device_group_prepare). `can_prepare`: a
   * device builds ahead (else preparing is a no-op). Under build_lock:
   * the sets asked for and not finished (bit 1 << set), those finished
   * for volume generation build_gen (tried: one that failed is the
   * frame's to build and report), and per set the devices still
   * building it. */
  int can_prepare;
  uv_mutex_t build_lock;
  uint32_t build_asked, build_done;
  uint8_t build_left[32]; /* one per effect set (RP__KNOWN_EFFECTS) */
  uint64_t build_gen;
};

/* One frame's plan and what its rounds hand on (rp_device_group_render):
 * regions in pixels of the scaled image. */
typedef struct rp__frame {
  rp_render_desc d;
  uint32_t sw, sh, tx, ty;
  double total_cost, share_cost; /* share_cost: what the rates multiply */
  double start;                  /* the round's, absolute ms */
  double shares[RP_GROUP_MAX_DEVICES];
  double predicted[RP_GROUP_MAX_DEVICES]; /* ms; INFINITY: no deadline */
  double cost_abs[RP_GROUP_MAX_DEVICES];
  rp_region px[RP_GROUP_MAX_DEVICES]; /* this round's regions */
  rp_region lost[RP_GROUP_MAX_DEVICES + RP_GROUP_MAX_STRIPS];
  uint32_t n_lost;
  int refused; /* an error that fails the frame (not the device) */
} rp__frame;

/* Whether an error means the device is gone (lost, or unable to hold the
 * scene) rather than a request no device could do (an effect it lacks, a
 * bad argument): only the first kind drops it. */
int rp__group_loses_device(int err, int upload);

/* A member's job on its executor (every member's job.run): the job,
 * then (a render in the tail) strip after strip, then the hand-back under
 * g->lock. */
void rp__group_member_job(rp__job *job, rp_context *ctx);
/* Starts a job of `kind` on w (its inputs are set): on the caller's
 * thread with an inline executor. */
void rp__group_start_job(rp_device_group *g, rp__member *w, int kind);
/* Waits until every pending member is done or past its deadline (a late
 * one is marked, outcome RP_EDEVICE, and left running); rep may be NULL
 * (no report of who was late). */
void rp__group_wait(rp_device_group *g, rp_group_report *rep,
                    double start);
/* Whether w renders effect set `effects` warm: not its first render of
 * the set since its volume upload (a kernel build), and no build under
 * way on its build lane. Only a warm render has a deadline. */
int rp__member_warm(rp_device_group *g, rp__member *w, uint32_t effects);
/* Runs a job of `kind` on w alone and waits for it; its outcome. */
int rp__group_run_one(rp_device_group *g, rp__member *w, int kind);

/* ---- Health (group_health.c) ---- */

/* Keeps what re-creating member w needs from `dd`. */
void rp__health_keep_desc(rp__member *w, const rp_device_desc *dd);
/* At a render's start: members whose late work ended come back on
 * probation (or fail, if it failed), and those whose back-off is over
 * are re-created; each brought up to date. Returns how many came back. */
uint32_t rp__health_begin(rp_device_group *g);

/* The group no longer refers to the AO it was last set to (its owner is
 * about to free it): a device re-created from now on gets none until the
 * next rp_device_group_set_ao. The devices keep their own copies. */
void rp__group_forget_ao(rp_device_group *g);
/* w failed (an RP_E* that loses a device): dropped, and RETRY after its
 * back-off or OUT after RP_GROUP_MAX_FAILURES. */
void rp__health_fail(rp_device_group *g, rp__member *w);
/* w was given up on at its deadline, with work of predicted tile cost
 * `cost` left running: LATE. */
void rp__health_late(rp_device_group *g, rp__member *w, double cost);
/* w finished its first-round work this frame (or had none): on
 * probation, one more frame on time, and ACTIVE after
 * RP_GROUP_PROBATION_FRAMES of them. */
void rp__health_on_time(rp_device_group *g, rp__member *w);
/* Caps the shares of members on probation at RP_GROUP_PROBATION_SHARE,
 * the rest going to the active ones in proportion to theirs. */
void rp__health_cap_shares(const rp_device_group *g, double *shares);
/* Each member's state into the report. */
void rp__health_report(const rp_device_group *g, rp_group_report *rep);

/* One round of frame f: every live device renders f->px[i] and, with a
 * tail (g->tail_active), takes strips; finished regions and strips are
 * copied into rgba/tiles; what no device finished is appended to
 * f->lost. Returns the last failure; an error that does not lose the
 * device (an effect it lacks) goes to f->refused and fails the frame. */
int rp__group_round(rp_device_group *g, const rp_camera *cam, rp__frame *f,
                    uint8_t *rgba, rp_tile_stats *tiles,
                    rp_group_report *rep, int first_round);

#endif /* RP_GROUP_INTERNAL_H */
