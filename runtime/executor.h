/* One owner per device (DESIGN section 11): an executor is a device's
 * worker thread and its job queue. Everything that calls the device --
 * a group's render rounds and uploads, an AO run's steps -- submits a
 * job and the worker runs it, so a device is called from one thread, in
 * the order the jobs were submitted, whoever submitted them. The model
 * is libuv's threadpool (one queue, one set of workers), with one worker
 * per queue because a device runs one thing at a time.
 *
 * The build lane: kernel builds (rp_device_prepare) run on a second
 * thread of the same executor, the device's builder. A build is compiler
 * work that takes from tens of milliseconds to over a second; queued on
 * the worker it would hold up the frame behind it, and a frame must
 * never wait for a build it does not need yet. rp_device_prepare is the
 * one device call the backend contract allows while another thread
 * runs any other call on the device (rp_backend_ops.prepare), so the
 * build lane runs jobs that call only it, at a lower priority than the
 * worker; it starts on its first job.
 *
 * Inline executors: a device alone (a group of one) has no worker, and
 * its jobs run inside submit, on the caller's thread, exactly as the
 * device alone would run them. Its build lane is still a thread.
 *
 * Threading: the executor belongs to its creator's thread (create,
 * submit, destroy); jobs run on the lane's thread. */
#ifndef RP_EXECUTOR_H
#define RP_EXECUTOR_H

#include <stddef.h>
#include <stdint.h>

#include "internal.h"

typedef struct rp__executor rp__executor;
typedef struct rp__job rp__job;

/* A unit of work, kept in its submitter's memory: the queue links jobs
 * through `next` and allocates nothing. `run` gets the lane's context,
 * where the job's errors go: the device's own on the worker (inline: the
 * same), a context of the build lane's own there. From the moment `run`
 * is called the executor never touches the job again, so `run` may tell
 * its owner it is done before it returns, and the owner may submit the
 * same job again (it runs after this call returns). */
struct rp__job {
  void (*run)(rp__job *job, rp_context *ctx);
  rp__job *next;
};

/* The struct of `type` whose member `field` is the job `job`. */
#define RP__JOB_OWNER(job, type, field)                                     \
  ((type *)(void *)((char *)(job) - offsetof(type, field)))

/* An executor for `dev` (which it does not own: destroy it after the
 * executor), threaded (a worker thread, started here) or inline (0).
 * `ctx` is for its allocations and messages.
 * \returns 0, RP_ENOMEM, RP_EDEVICE (a thread or lock would not start). */
int rp__executor_create(rp_context *ctx, rp_device *dev, int threaded,
                        rp__executor **out);
/* Runs the jobs submitted to both lanes -- one still running (a device
 * given up on at its deadline) included -- then joins the threads. Jobs
 * may not be submitted meanwhile. NULL: no-op. */
void rp__executor_destroy(rp__executor *ex);
/* Gives the executor a new device (a device group re-creating one that
 * failed): runs what both lanes hold, stops them, and starts the worker
 * again on `dev`; the build lane starts again on its next job. The
 * executor stays the same object, so whoever holds it (an AO run) still
 * may. The creator's thread; the caller destroys the old device after.
 * \returns 0, RP_EDEVICE (the worker would not start: jobs submitted
 * then never run, so the device must not be used again). */
int rp__executor_rebind(rp__executor *ex, rp_device *dev);
/* Queues `job` for the worker; an inline executor runs it before it
 * returns. */
void rp__executor_submit(rp__executor *ex, rp__job *job);
/* Queues `job` on the build lane, starting the lane's thread and context
 * on the first job. Its `run` may call only rp_device_prepare on the
 * executor's device (with the context it is given).
 * \returns 0, or RP_ENOMEM / RP_EDEVICE when the lane would not start
 * (the job is then not queued; the message is in the executor's ctx). */
int rp__executor_submit_build(rp__executor *ex, rp__job *job);

rp_device *rp__executor_device(const rp__executor *ex);
/* 1 when jobs run on a worker thread, 0 when inline. */
int rp__executor_threaded(const rp__executor *ex);

#endif /* RP_EXECUTOR_H */
