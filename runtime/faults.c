/* Fault injection (raypace_testing.h, rp_fault_desc): a backend that
 * wraps any other, forwards every operation to it and adds the faults a
 * test asked for, so that the front end and every real backend stay free
 * of test knobs (SDL keeps its debug switches behind a debug mode, sokol
 * its dummy backend out of the product path).
 *
 * - slowdown: each timed operation (rp_backend_ops.last_time_ns lists
 *   them) is followed by a wait of (slowdown - 1) times its device time,
 *   and reports the stretched time.
 * - fail_at_ao: counted on compute_ao, one per rp_device_compute_ao.
 * - fail_at_render, stall_at_render: counted per front-end render, which
 *   the front end marks (rp__faults_render_begin/_end): an out-of-core
 *   render reaches the backend as several raycasts and uploads, and must
 *   still count once.
 *
 * The waits are in wall time, unless the inner backend keeps its own
 * clock (the test backend): then they advance that clock instead, and a
 * slowed or stalled test device stays deterministic. */
#include <math.h>
#include <string.h>
#include <time.h>

#include "device.h"

struct rp__faults {
  rp_context *ctx;
  rp_backend_ops ops;        /* this wrapper's: an op is present exactly
                                when the inner backend's is */
  const rp_backend_ops *in;  /* the inner backend, owned */
  void *in_impl;
  rp_fault_desc d;
  char device[128], backend[32]; /* the inner device, for messages */
  uint32_t renders, ao_jobs;
  uint64_t last_ns;
  uint64_t waited_ns;        /* on the inner backend's own clock */
};

int rp__faults_check(rp_context *ctx, const rp_fault_desc *fd) {
  if (!(fd->slowdown == 0.0 ||
        (fd->slowdown >= 1.0 && fd->slowdown <= 1e4)))
    return rp__fail(ctx, isfinite(fd->slowdown) ? RP_ERANGE : RP_ENOTFINITE,
                    "rp_device_create: rp_fault_desc.slowdown %g is not 0 "
                    "or in [1, 10000]", fd->slowdown);
  if (!(fd->stall_ms >= 0.0 && fd->stall_ms <= 60000.0))
    return rp__fail(ctx, isfinite(fd->stall_ms) ? RP_ERANGE : RP_ENOTFINITE,
                    "rp_device_create: rp_fault_desc.stall_ms %g is not in "
                    "[0, 60000]", fd->stall_ms);
  return 0;
}

/* Waits `ns` the way the inner device lives: its own clock, or the wall. */
static void wait_ns(rp__faults *f, uint64_t ns) {
  struct timespec ts;
  if (f->in->clock_ns != NULL) {
    f->waited_ns += ns;
    return;
  }
  ts.tv_sec = (time_t)(ns / 1000000000u);
  ts.tv_nsec = (long)(ns % 1000000000u);
  while (nanosleep(&ts, &ts) != 0)
    ; /* interrupted by a signal: sleep the rest */
}

/* After a timed operation that succeeded: its time, stretched. */
static int timed(rp__faults *f, int err) {
  uint64_t ns, extra = 0;
  if (err != 0)
    return err;
  ns = f->in->last_time_ns(f->in_impl);
  if (f->d.slowdown > 1.0) {
    extra = (uint64_t)((f->d.slowdown - 1.0) * (double)ns);
    wait_ns(f, extra);
  }
  f->last_ns = ns + extra;
  return 0;
}

/* ---- forwarding ---------------------------------------------------------- */

static void f_destroy(void *p) {
  rp__faults *f = p;
  f->in->destroy(f->in_impl);
  rp__free(f->ctx, f);
}

static int f_upload_volume(void *p, const rp_volume *vol) {
  rp__faults *f = p;
  return timed(f, f->in->upload_volume(f->in_impl, vol));
}

static int f_upload_tf(void *p, const float *lut, uint32_t lut_size) {
  rp__faults *f = p;
  return timed(f, f->in->upload_tf(f->in_impl, lut, lut_size));
}

static int f_upload_occupancy(void *p, const uint8_t *grid,
                              const uint8_t *alpha_hist,
                              const uint32_t blocks[3]) {
  rp__faults *f = p;
  return timed(f, f->in->upload_occupancy(f->in_impl, grid, alpha_hist,
                                          blocks));
}

static int f_depth_pass(void *p, const rp_frame_params *fp,
                        float *front_back) {
  rp__faults *f = p;
  return timed(f, f->in->depth_pass(f->in_impl, fp, front_back));
}

static int f_ert_prepass(void *p, const rp_frame_params *fp, float *d_ert) {
  rp__faults *f = p;
  return timed(f, f->in->ert_prepass(f->in_impl, fp, d_ert));
}

static int f_raycast(void *p, const rp_frame_params *fp, const rp_region *r,
                     uint8_t *rgba, rp_tile_stats *tiles,
                     uint64_t *fetches) {
  rp__faults *f = p;
  return timed(f, f->in->raycast(f->in_impl, fp, r, rgba, tiles, fetches));
}

static int f_compute_ao(void *p, const rp_ao_job *job, uint8_t *out) {
  rp__faults *f = p;
  f->ao_jobs++;
  if (f->d.fail_at_ao != 0 && f->ao_jobs >= f->d.fail_at_ao)
    return rp__fail(f->ctx, RP_EDEVICE, "rp_device_compute_ao: device '%s' "
                    "(%s) failed (injected at AO job %u)", f->device,
                    f->backend, f->d.fail_at_ao);
  return timed(f, f->in->compute_ao(f->in_impl, job, out));
}

static int f_upload_ao(void *p, const uint8_t *ao) {
  rp__faults *f = p;
  int err = f->in->upload_ao(f->in_impl, ao);
  return ao != NULL ? timed(f, err) : err; /* a release is not timed */
}

static int f_set_brick_pool(void *p, const rp_brick_pool *pool) {
  rp__faults *f = p;
  return f->in->set_brick_pool(f->in_impl, pool);
}

static int f_upload_bricks(void *p, uint32_t count, const uint32_t *slots,
                           const void *const *voxels,
                           const uint32_t *table) {
  rp__faults *f = p;
  return timed(f, f->in->upload_bricks(f->in_impl, count, slots, voxels,
                                       table));
}

static uint64_t f_last_time_ns(void *p) {
  return ((const rp__faults *)p)->last_ns;
}

/* May run on another thread than every other op (rp_backend_ops): reads
 * only what is fixed at wrap time. */
static int f_prepare(void *p, rp_context *ctx, uint32_t effects) {
  const rp__faults *f = p;
  return f->in->prepare(f->in_impl, ctx, effects);
}

static uint64_t f_clock_ns(void *p) {
  const rp__faults *f = p;
  return f->in->clock_ns(f->in_impl) + f->waited_ns;
}

static const rp_backend_ops wrapper_ops = {
    .destroy = f_destroy,
    .upload_volume = f_upload_volume,
    .upload_tf = f_upload_tf,
    .upload_occupancy = f_upload_occupancy,
    .depth_pass = f_depth_pass,
    .ert_prepass = f_ert_prepass,
    .raycast = f_raycast,
    .compute_ao = f_compute_ao,
    .upload_ao = f_upload_ao,
    .set_brick_pool = f_set_brick_pool,
    .upload_bricks = f_upload_bricks,
    .last_time_ns = f_last_time_ns,
    .prepare = f_prepare,
    .clock_ns = f_clock_ns,
};

/* ---- the front end's side ----------------------------------------------- */

int rp__faults_wrap(rp_context *ctx, const rp_fault_desc *fd,
                    const rp_caps *caps, const rp_backend_ops **ops,
                    void **impl, rp__faults **out) {
  const rp_backend_ops *in = *ops;
  rp__faults *f = rp__calloc(ctx, 1, sizeof *f);
  if (f == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_device_create: out of memory");
  f->ctx = ctx;
  f->in = in;
  f->in_impl = *impl;
  f->d = *fd;
  f->d.header.next = NULL;
  memcpy(f->device, caps->device, sizeof f->device);
  memcpy(f->backend, caps->backend, sizeof f->backend);
  f->ops = wrapper_ops;
  /* The front end reads an optional op's absence as a capability (no
   * bricks, no building ahead, real time): the wrapper keeps it. */
  if (in->set_brick_pool == NULL)
    f->ops.set_brick_pool = NULL;
  if (in->upload_bricks == NULL)
    f->ops.upload_bricks = NULL;
  if (in->compute_ao == NULL)
    f->ops.compute_ao = NULL;
  if (in->upload_ao == NULL)
    f->ops.upload_ao = NULL;
  if (in->prepare == NULL)
    f->ops.prepare = NULL;
  if (in->clock_ns == NULL)
    f->ops.clock_ns = NULL;
  *ops = &f->ops;
  *impl = f;
  *out = f;
  return 0;
}

int rp__faults_render_begin(rp__faults *f) {
  if (f == NULL)
    return 0;
  f->renders++;
  if (f->d.fail_at_render != 0 && f->renders >= f->d.fail_at_render)
    return rp__fail(f->ctx, RP_EDEVICE, "rp_device_render: device '%s' "
                    "(%s) failed (injected at render %u)", f->device,
                    f->backend, f->d.fail_at_render);
  return 0;
}

int rp__faults_set_slowdown(rp__faults *f, double slowdown) {
  rp_fault_desc d = f->d;
  int err;
  d.slowdown = slowdown;
  if ((err = rp__faults_check(f->ctx, &d)) != 0)
    return err;
  f->d.slowdown = slowdown;
  return 0;
}

uint64_t rp__faults_render_end(rp__faults *f) {
  uint64_t ns;
  if (f == NULL || f->d.stall_at_render == 0 ||
      f->renders != f->d.stall_at_render)
    return 0;
  ns = (uint64_t)(f->d.stall_ms * 1e6);
  wait_ns(f, ns);
  return ns;
}
