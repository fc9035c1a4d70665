/* A device's executor (executor.h): a worker thread and a build lane,
 * each a FIFO of jobs under the executor's one lock. */
#ifdef __linux__
#define _GNU_SOURCE /* syscall(SYS_gettid): see lane_main */
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif
#include <string.h>
#include <uv.h>

#include "ao.h"
#include "executor.h"

enum { LANE_DEVICE, LANE_BUILD, LANES };

typedef struct lane {
  rp__executor *ex;
  int kind;
  uv_thread_t thread;
  int started;
  uv_cond_t wake;
  rp__job *head, *tail; /* under ex->lock */
  rp_context *ctx;      /* where its jobs' errors go */
} lane;

struct rp__executor {
  rp_context *ctx;
  rp_device *dev;
  int threaded;
  uv_mutex_t lock;
  int quit; /* under lock: destroy asked the lanes to drain and end */
  lane lanes[LANES];
  rp_context *build_ctx; /* the build lane's, owned */
};

static void lane_main(void *arg) {
  lane *l = arg;
  rp__executor *ex = l->ex;
#ifdef __linux__
  /* A build is compiler work on the host's cores, which a CPU device
   * renders on too. At nice 5 it leaves frames most of them and still
   * ends within a few frames; at 19 it never ended while frames kept
   * the cores busy (docs/runtime.md). Linux keeps nice values per
   * thread. */
  if (l->kind == LANE_BUILD)
    (void)setpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid), 5);
#endif
  uv_mutex_lock(&ex->lock);
  for (;;) {
    rp__job *j;
    while (l->head == NULL && !ex->quit)
      uv_cond_wait(&l->wake, &ex->lock);
    if ((j = l->head) == NULL)
      break; /* quit, and nothing left to run */
    l->head = j->next;
    if (l->head == NULL)
      l->tail = NULL;
    uv_mutex_unlock(&ex->lock);
    /* The job is its owner's again from here: not read after the call. */
    j->run(j, l->ctx);
    uv_mutex_lock(&ex->lock);
  }
  uv_mutex_unlock(&ex->lock);
}

static void enqueue(lane *l, rp__job *job) {
  job->next = NULL;
  if (l->tail != NULL)
    l->tail->next = job;
  else
    l->head = job;
  l->tail = job;
  uv_cond_signal(&l->wake);
}

static int lane_start(rp__executor *ex, lane *l) {
  if (uv_thread_create(&l->thread, lane_main, l) != 0)
    return rp__fail(ex->ctx, RP_EDEVICE, "executor: uv_thread_create failed "
                    "for a device's %s", l->kind == LANE_BUILD ? "builder"
                                                               : "worker");
  l->started = 1;
  return 0;
}

int rp__executor_create(rp_context *ctx, rp_device *dev, int threaded,
                        rp__executor **out) {
  rp__executor *ex;
  int k, err;
  *out = NULL;
  if ((ex = rp__calloc(ctx, 1, sizeof *ex)) == NULL)
    return rp__fail(ctx, RP_ENOMEM, "executor: out of memory");
  ex->ctx = ctx;
  ex->dev = dev;
  ex->threaded = threaded;
  if (uv_mutex_init(&ex->lock) != 0) {
    rp__free(ctx, ex);
    return rp__fail(ctx, RP_EDEVICE, "executor: uv_mutex_init failed");
  }
  for (k = 0; k < LANES; k++) {
    if (uv_cond_init(&ex->lanes[k].wake) != 0) {
      while (k-- > 0)
        uv_cond_destroy(&ex->lanes[k].wake);
      uv_mutex_destroy(&ex->lock);
      rp__free(ctx, ex);
      return rp__fail(ctx, RP_EDEVICE, "executor: uv_cond_init failed");
    }
    ex->lanes[k].ex = ex;
    ex->lanes[k].kind = k;
  }
  ex->lanes[LANE_DEVICE].ctx = rp__device_context(dev);
  if (threaded && (err = lane_start(ex, &ex->lanes[LANE_DEVICE])) != 0) {
    rp__executor_destroy(ex);
    return err;
  }
  *out = ex;
  return 0;
}

/* Runs what the lanes hold and joins their threads. */
static void lanes_stop(rp__executor *ex) {
  int k;
  uv_mutex_lock(&ex->lock);
  ex->quit = 1;
  for (k = 0; k < LANES; k++)
    uv_cond_signal(&ex->lanes[k].wake);
  uv_mutex_unlock(&ex->lock);
  for (k = 0; k < LANES; k++) {
    if (ex->lanes[k].started)
      uv_thread_join(&ex->lanes[k].thread);
    ex->lanes[k].started = 0;
  }
}

int rp__executor_rebind(rp__executor *ex, rp_device *dev) {
  lanes_stop(ex);
  ex->quit = 0; /* no lane runs: nothing else reads it */
  ex->dev = dev;
  ex->lanes[LANE_DEVICE].ctx = rp__device_context(dev);
  return ex->threaded ? lane_start(ex, &ex->lanes[LANE_DEVICE]) : 0;
}

void rp__executor_destroy(rp__executor *ex) {
  int k;
  if (ex == NULL)
    return;
  lanes_stop(ex);
  for (k = 0; k < LANES; k++)
    uv_cond_destroy(&ex->lanes[k].wake);
  uv_mutex_destroy(&ex->lock);
  rp_context_destroy(ex->build_ctx);
  rp__free(ex->ctx, ex);
}

void rp__executor_submit(rp__executor *ex, rp__job *job) {
  if (!ex->threaded) {
    job->next = NULL;
    job->run(job, ex->lanes[LANE_DEVICE].ctx);
    return;
  }
  uv_mutex_lock(&ex->lock);
  enqueue(&ex->lanes[LANE_DEVICE], job);
  uv_mutex_unlock(&ex->lock);
}

int rp__executor_submit_build(rp__executor *ex, rp__job *job) {
  lane *l = &ex->lanes[LANE_BUILD];
  int err;
  if (!l->started) {
    /* Only the creator's thread submits: the lane is not running yet,
     * so nothing else reads these fields. */
    if (ex->build_ctx == NULL &&
        (err = rp_context_create(&ex->ctx->desc, &ex->build_ctx)) != 0)
      return rp__fail(ex->ctx, err, "executor: a context for the builder");
    l->ctx = ex->build_ctx;
    if ((err = lane_start(ex, l)) != 0)
      return err;
  }
  uv_mutex_lock(&ex->lock);
  enqueue(l, job);
  uv_mutex_unlock(&ex->lock);
  return 0;
}

rp_device *rp__executor_device(const rp__executor *ex) { return ex->dev; }

int rp__executor_threaded(const rp__executor *ex) { return ex->threaded; }
