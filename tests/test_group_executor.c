/* The devices' executors (runtime/executor.c): one owner thread per
 * device running jobs in the order they came, a build lane that runs
 * beside it, inline executors for a device alone, and a destroy that
 * waits for a job still running. Then the group's AO on its one-device
 * (inline) executor: on the caller's thread, equal to a lone device's. */
#ifdef __linux__
#define _GNU_SOURCE /* syscall(SYS_gettid) */
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif
#include <string.h>
#include <uv.h>

#include "ao.h"
#include "executor.h"
#include "raypace_group.h"
#include "test_util.h"

#define JOBS 6

/* What the test jobs saw, under `mu`. */
typedef struct jlog {
  uv_mutex_t mu;
  uv_cond_t cv;
  int order[JOBS], n;
  uv_thread_t thread[JOBS];
  rp_context *ctx[JOBS];
  int nice[JOBS];
  int flag, saw_flag, again;
} jlog;

typedef struct tjob {
  rp__job job;
  jlog *lg;
  int id;
  int sleep_ms; /* before it records */
  int wait_ms;  /* waits that long at most for lg->flag */
  rp__executor *ex; /* resubmits itself here while lg->again > 0 */
} tjob;

static int thread_nice(void) {
#ifdef __linux__
  return getpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid));
#else
  return 0;
#endif
}

static void record(rp__job *j, rp_context *ctx) {
  tjob *t = RP__JOB_OWNER(j, tjob, job);
  jlog *lg = t->lg;
  int k;
  if (t->sleep_ms > 0)
    uv_sleep((unsigned)t->sleep_ms);
  uv_mutex_lock(&lg->mu);
  if (t->wait_ms > 0) {
    uint64_t end = uv_hrtime() + (uint64_t)t->wait_ms * 1000000u;
    while (!lg->flag && uv_hrtime() < end)
      (void)uv_cond_timedwait(&lg->cv, &lg->mu, 10000000u);
    lg->saw_flag = lg->flag;
  }
  k = lg->n++;
  lg->order[k] = t->id;
  lg->thread[k] = uv_thread_self();
  lg->ctx[k] = ctx;
  lg->nice[k] = thread_nice();
  lg->flag = 1;
  uv_cond_broadcast(&lg->cv);
  if (t->ex != NULL && lg->again > 0) {
    lg->again--;
    t->id++;
    /* Handed back above; the executor reads it no more. */
    rp__executor_submit(t->ex, &t->job);
  }
  uv_mutex_unlock(&lg->mu);
}

typedef struct fixture {
  rp_context *ctx;
  rp_device *dev;
  jlog lg;
  tjob t[JOBS];
} fixture;

static void fixture_make(fixture *f) {
  rp_device_desc dd = {0};
  int i;
  memset(f, 0, sizeof *f);
  f->ctx = rp_test_context();
  dd.backend = "reference";
  assert_int_equal(rp_device_create(f->ctx, &dd, &f->dev), 0);
  assert_int_equal(uv_mutex_init(&f->lg.mu), 0);
  assert_int_equal(uv_cond_init(&f->lg.cv), 0);
  for (i = 0; i < JOBS; i++) {
    f->t[i].job.run = record;
    f->t[i].lg = &f->lg;
    f->t[i].id = i;
  }
}

static void fixture_free(fixture *f) {
  uv_cond_destroy(&f->lg.cv);
  uv_mutex_destroy(&f->lg.mu);
  rp_device_destroy(f->dev);
  rp_context_destroy(f->ctx);
}

/* Jobs run in the order they came, all on one thread that is not the
 * caller's, each given the device's context; destroy runs those still
 * queued (the first sleeps, so the others are queued behind it). */
static void test_one_owner_in_order(void **state) {
  uv_thread_t self = uv_thread_self();
  rp__executor *ex = NULL;
  fixture f;
  int i;
  (void)state;
  fixture_make(&f);
  assert_int_equal(rp__executor_create(f.ctx, f.dev, 1, &ex), 0);
  assert_true(rp__executor_threaded(ex));
  assert_ptr_equal(rp__executor_device(ex), f.dev);
  f.t[0].sleep_ms = 50;
  for (i = 0; i < JOBS; i++)
    rp__executor_submit(ex, &f.t[i].job);
  rp__executor_destroy(ex);
  assert_int_equal(f.lg.n, JOBS);
  for (i = 0; i < JOBS; i++) {
    assert_int_equal(f.lg.order[i], i);
    assert_true(uv_thread_equal(&f.lg.thread[i], &f.lg.thread[0]));
    assert_ptr_equal(f.lg.ctx[i], rp__device_context(f.dev));
  }
  assert_false(uv_thread_equal(&f.lg.thread[0], &self));
  fixture_free(&f);
}

/* Inline: the job has run, on the caller's thread, when submit returns. */
static void test_inline(void **state) {
  uv_thread_t self = uv_thread_self();
  rp__executor *ex = NULL;
  fixture f;
  (void)state;
  fixture_make(&f);
  assert_int_equal(rp__executor_create(f.ctx, f.dev, 0, &ex), 0);
  assert_false(rp__executor_threaded(ex));
  rp__executor_submit(ex, &f.t[0].job);
  assert_int_equal(f.lg.n, 1);
  assert_true(uv_thread_equal(&f.lg.thread[0], &self));
  assert_ptr_equal(f.lg.ctx[0], rp__device_context(f.dev));
  rp__executor_destroy(ex);
  fixture_free(&f);
}

/* The build lane runs beside the worker: a worker job that waits for a
 * build job submitted after it sees it run (on one queue it would wait
 * its full 10 s and see nothing). The build lane has a thread and a
 * context of its own, and yields to the worker (nice + 5), also beside
 * an inline executor. */
static void test_build_lane_overlaps(void **state) {
  rp__executor *ex = NULL;
  int threaded;
  (void)state;
  for (threaded = 1; threaded >= 0; threaded--) {
    uv_thread_t self = uv_thread_self();
    fixture f;
    int base, want;
    fixture_make(&f);
    base = thread_nice();
    want = base + 5 > 19 ? 19 : base + 5;
    assert_int_equal(rp__executor_create(f.ctx, f.dev, threaded, &ex), 0);
    if (threaded) {
      f.t[0].wait_ms = 10000;
      rp__executor_submit(ex, &f.t[0].job);
    }
    assert_int_equal(rp__executor_submit_build(ex, &f.t[1].job), 0);
    rp__executor_destroy(ex);
    assert_int_equal(f.lg.n, threaded ? 2 : 1);
    /* The build job ran first whatever the order it was submitted in. */
    assert_int_equal(f.lg.order[0], 1);
    assert_false(uv_thread_equal(&f.lg.thread[0], &self));
    assert_non_null(f.lg.ctx[0]);
    assert_true(f.lg.ctx[0] != rp__device_context(f.dev) &&
                f.lg.ctx[0] != f.ctx);
#ifdef __linux__
    assert_int_equal(f.lg.nice[0], want);
#endif
    if (threaded) {
      assert_true(f.lg.saw_flag);
      assert_false(uv_thread_equal(&f.lg.thread[1], &f.lg.thread[0]));
      assert_int_equal(f.lg.nice[1], base);
    }
    fixture_free(&f);
  }
}

/* A job may hand itself back and be submitted again from inside its own
 * run (the executor reads it no more once it runs): it runs again after,
 * in order. */
static void test_resubmit(void **state) {
  rp__executor *ex = NULL;
  fixture f;
  (void)state;
  fixture_make(&f);
  assert_int_equal(rp__executor_create(f.ctx, f.dev, 1, &ex), 0);
  f.t[0].ex = ex;
  f.lg.again = 3;
  rp__executor_submit(ex, &f.t[0].job);
  uv_mutex_lock(&f.lg.mu);
  while (f.lg.n < 4)
    uv_cond_wait(&f.lg.cv, &f.lg.mu);
  uv_mutex_unlock(&f.lg.mu);
  rp__executor_destroy(ex);
  assert_int_equal(f.lg.n, 4);
  assert_true(f.lg.order[0] == 0 && f.lg.order[3] == 3);
  fixture_free(&f);
}

/* ---- A group's AO on its one device ------------------------------------ */

typedef struct progress_log {
  uv_thread_t caller;
  int calls, off_thread;
  double last;
  int rising;
} progress_log;

static void on_progress(double fraction, void *user) {
  progress_log *p = user;
  uv_thread_t now = uv_thread_self();
  p->off_thread |= !uv_thread_equal(&now, &p->caller);
  p->rising &= fraction >= p->last;
  p->last = fraction;
  p->calls++;
}

/* A group of one device computes AO through its inline executor: every
 * progress report comes from the caller's thread, rising, one between
 * jobs (8^3 blocks of a 32^3 phantom: more than the final 1), and
 * the volume equals one device's alone, byte for byte. */
static void test_group_of_one_ao(void **state) {
  rp_context *ctx = rp_test_context();
  rp_generate_desc gen = {0};
  rp_device_desc dd = {0};
  rp_group_desc gd = {0};
  rp_ao_schedule sc = {0};
  rp_volume *vol = NULL;
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  rp_ao_plan *plan = NULL;
  rp_ao *grouped = NULL, *alone = NULL;
  rp_device_group *g = NULL;
  rp_device *dev = NULL;
  progress_log p;
  uint32_t dims[3];
  rp_tf *tf;
  (void)state;
  gen.kind = RP_GEN_PHANTOM;
  gen.dims[0] = gen.dims[1] = gen.dims[2] = 32;
  assert_int_equal(rp_volume_generate(ctx, &gen, &vol), 0);
  tf = rp_test_preset(ctx, "minmax-bone");
  assert_int_equal(rp_histograms_build(ctx, vol, &h), 0);
  assert_int_equal(rp_occupancy_build(ctx, h, tf, &occ), 0);
  assert_int_equal(rp_ao_plan_create(ctx, vol, tf, NULL, &plan), 0);
  dd.backend = "reference";
  gd.devices = &dd;
  gd.count = 1;
  assert_int_equal(rp_device_group_create(ctx, &gd, &g), 0);
  assert_int_equal(rp_device_group_set_volume(g, vol), 0);
  assert_int_equal(rp_device_group_set_tf(g, tf, occ), 0);
  memset(&p, 0, sizeof p);
  p.caller = uv_thread_self();
  p.rising = 1;
  sc.scheme = RP_AO_DYNAMIC;
  sc.block = 8;
  sc.progress = on_progress;
  sc.user = &p;
  assert_int_equal(rp_device_group_compute_ao(g, plan, &sc, &grouped, NULL),
                   0);
  assert_false(p.off_thread);
  assert_true(p.rising && p.last == 1.0 && p.calls >= 2);
  assert_int_equal(rp_device_create(ctx, &dd, &dev), 0);
  assert_int_equal(rp_device_set_volume(dev, vol), 0);
  assert_int_equal(rp_device_set_tf(dev, tf, occ), 0);
  sc.progress = NULL;
  assert_int_equal(rp_ao_compute(ctx, &dev, 1, plan, &sc, &alone, NULL), 0);
  (void)rp_ao_data(grouped, dims);
  assert_memory_equal(rp_ao_data(grouped, NULL), rp_ao_data(alone, NULL),
                      (size_t)dims[0] * dims[1] * dims[2]);
  rp_ao_destroy(alone);
  rp_ao_destroy(grouped);
  rp_device_destroy(dev);
  rp_device_group_destroy(g);
  rp_ao_plan_destroy(plan);
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_one_owner_in_order),
      cmocka_unit_test(test_inline),
      cmocka_unit_test(test_build_lane_overlaps),
      cmocka_unit_test(test_resubmit),
      cmocka_unit_test(test_group_of_one_ao),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
