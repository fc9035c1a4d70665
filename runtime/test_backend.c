/* Backend "test": the deterministic test device (raypace_testing.h),
 * after sokol_gfx's dummy backend and SDL's: a device a test can reason
 * about exactly.
 *
 * Its pixels are the reference backend's (it forwards every operation to
 * a reference impl of its own), so its images are rp_render_reference's.
 * Its device time is not measured: each operation that reports a time
 * costs a formula of the work it really did (rays, the volume fetches
 * the reference counted, voxels, bytes), times a log-normal noise factor
 * drawn from a stream that only the seed and the number of timed
 * operations so far determine. Nothing here sleeps or reads a clock, so
 * the same operations give the same times on every run, however loaded
 * the machine. A simulated clock sums the times (clock_ns), for a frame
 * engine to pace by. */
#include <math.h>
#include <stddef.h>
#include <string.h>

#include "device.h"
#include "passes.h"

typedef struct test_impl {
  rp_context *ctx;
  void *ref;                /* the reference impl that renders */
  rp_test_backend_desc d;   /* defaults resolved; negatives now 0 */
  uint64_t draws;           /* timed operations so far */
  uint64_t clock_ns, last_ns;
  size_t voxels;            /* of the uploaded volume: upload_ao's bytes */
  uint64_t *fetches;        /* the raycast's per-tile counts, when the */
  size_t fetch_cap;         /* caller asks for none: grown, never shrunk */
} test_impl;

/* ---- parameters ---------------------------------------------------------- */

/* Each double field: its default and its largest value. */
static const struct {
  const char *name;
  size_t offset;
  double def, max;
} fields[] = {
    {"noise_sd", offsetof(rp_test_backend_desc, noise_sd), 0.02, 1.0},
    {"launch_ns", offsetof(rp_test_backend_desc, launch_ns), 20000.0, 1e9},
    {"ray_ns", offsetof(rp_test_backend_desc, ray_ns), 50.0, 1e6},
    {"fetch_ns", offsetof(rp_test_backend_desc, fetch_ns), 2.0, 1e6},
    {"depth_ray_ns", offsetof(rp_test_backend_desc, depth_ray_ns), 5.0, 1e6},
    {"ns_per_byte", offsetof(rp_test_backend_desc, ns_per_byte), 0.5, 1e6},
    {"ao_voxel_ns", offsetof(rp_test_backend_desc, ao_voxel_ns), 100.0,
     1e6}};
#define FIELDS (sizeof fields / sizeof fields[0])

static double *field(rp_test_backend_desc *d, size_t i) {
  return (double *)(void *)((char *)d + fields[i].offset);
}

static int check_desc(rp_context *ctx, const rp_test_backend_desc *in) {
  rp_test_backend_desc d = *in;
  size_t i;
  for (i = 0; i < FIELDS; i++) {
    double v = *field(&d, i);
    if (!isfinite(v))
      return rp__fail(ctx, RP_ENOTFINITE, "rp_device_create: "
                      "rp_test_backend_desc.%s is %g; must be finite",
                      fields[i].name, v);
    if (v > fields[i].max)
      return rp__fail(ctx, RP_ERANGE, "rp_device_create: "
                      "rp_test_backend_desc.%s %g exceeds %g",
                      fields[i].name, v, fields[i].max);
  }
  return 0;
}

/* The one place that knows the defaults: zero takes the default, a
 * negative value means exactly 0. */
static rp_test_backend_desc desc_defaults(const rp_test_backend_desc *in) {
  rp_test_backend_desc d = *in;
  size_t i;
  for (i = 0; i < FIELDS; i++) {
    double *v = field(&d, i);
    *v = *v == 0.0 ? fields[i].def : *v < 0.0 ? 0.0 : *v;
  }
  d.header.next = NULL;
  return d;
}

/* ---- time ---------------------------------------------------------------- */

/* splitmix64's output for position k of the stream `seed`. */
static uint64_t mix(uint64_t seed, uint64_t k) {
  uint64_t z = seed + (k + 1) * 0x9E3779B97F4A7C15u;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9u;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBu;
  return z ^ (z >> 31);
}

/* The k-th standard normal of the stream: Box-Muller on two uniforms of
 * 53 bits, u1 in (0, 1] so that its log is finite. Counter-based, so
 * that the k-th draw is the same whatever happened before it. */
static double normal(uint64_t seed, uint64_t k) {
  double u1 = (double)((mix(seed, 2 * k) >> 11) + 1) * 0x1p-53;
  double u2 = (double)(mix(seed, 2 * k + 1) >> 11) * 0x1p-53;
  return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

/* A timed operation whose formula gives `base` ns: draws its noise,
 * reports it, and advances the clock by it. */
static void charge(test_impl *t, double base) {
  double ns = base;
  if (t->d.noise_sd > 0.0)
    ns *= exp(t->d.noise_sd * normal(t->d.seed, t->draws));
  t->draws++;
  ns = floor(ns + 0.5);
  t->last_ns = ns >= 18446744073709551615.0 ? UINT64_MAX : (uint64_t)ns;
  t->clock_ns += t->last_ns;
}

/* ---- ops ----------------------------------------------------------------- */

static void test_destroy(void *p) {
  test_impl *t = p;
  if (t == NULL)
    return;
  rp__ref_ops.destroy(t->ref);
  rp__free(t->ctx, t->fetches);
  rp__free(t->ctx, t);
}

static int test_upload_volume(void *p, const rp_volume *vol) {
  test_impl *t = p;
  int err = rp__ref_ops.upload_volume(t->ref, vol);
  if (err != 0)
    return err;
  t->voxels = vol->voxel_count;
  charge(t, t->d.ns_per_byte * (double)vol->voxel_count *
                (double)rp__voxel_size(vol->type));
  return 0;
}

static int test_upload_tf(void *p, const float *lut, uint32_t lut_size) {
  test_impl *t = p;
  int err = rp__ref_ops.upload_tf(t->ref, lut, lut_size);
  if (err != 0)
    return err;
  charge(t, t->d.ns_per_byte * (double)lut_size * 4.0 * sizeof(float));
  return 0;
}

static int test_upload_occupancy(void *p, const uint8_t *grid,
                                 const uint8_t *alpha_hist,
                                 const uint32_t blocks[3]) {
  test_impl *t = p;
  double nb = (double)blocks[0] * blocks[1] * blocks[2];
  int err = rp__ref_ops.upload_occupancy(t->ref, grid, alpha_hist, blocks);
  if (err != 0)
    return err;
  charge(t, t->d.ns_per_byte * nb * (1.0 + RP_OPACITY_BINS));
  return 0;
}

static int test_depth_pass(void *p, const rp_frame_params *fp,
                           float *front_back) {
  test_impl *t = p;
  int err = rp__ref_ops.depth_pass(t->ref, fp, front_back);
  if (err != 0)
    return err;
  charge(t, t->d.launch_ns +
                t->d.depth_ray_ns * (double)fp->width * fp->height);
  return 0;
}

static int test_ert_prepass(void *p, const rp_frame_params *fp,
                            float *d_ert) {
  test_impl *t = p;
  uint32_t gw, gh;
  int err = rp__ref_ops.ert_prepass(t->ref, fp, d_ert);
  if (err != 0)
    return err;
  rp__ert_grid(fp->width, fp->height, &gw, &gh);
  charge(t, t->d.launch_ns + t->d.depth_ray_ns * (double)gw * gh);
  return 0;
}

/* The raycast counts its fetches whether or not the caller asked: into
 * the caller's array, else into the impl's own. */
static int test_raycast(void *p, const rp_frame_params *fp,
                        const rp_region *r, uint8_t *rgba,
                        rp_tile_stats *tiles, uint64_t *fetches) {
  test_impl *t = p;
  uint32_t tx, ty, x, y;
  uint64_t sum = 0, *f = fetches;
  int err;
  rp_tile_grid(fp->width, fp->height, &tx, &ty);
  if (f == NULL) {
    size_t need = (size_t)tx * ty;
    if (need > t->fetch_cap) {
      uint64_t *grown = rp__malloc(t->ctx, need * sizeof *grown);
      if (grown == NULL)
        return rp__fail(t->ctx, RP_ENOMEM, "rp_device_render: out of "
                        "memory for %zu tiles' fetch counts", need);
      rp__free(t->ctx, t->fetches);
      t->fetches = grown;
      t->fetch_cap = need;
    }
    f = t->fetches;
  }
  if ((err = rp__ref_ops.raycast(t->ref, fp, r, rgba, tiles, f)) != 0)
    return err;
  /* Region corners lie on the tile grid or the image edge: its tiles are
   * exactly those the raycast wrote. */
  for (y = r->y0 / RP_TILE_SIZE; y * RP_TILE_SIZE < r->y1; y++)
    for (x = r->x0 / RP_TILE_SIZE; x * RP_TILE_SIZE < r->x1; x++)
      sum += f[(size_t)y * tx + x];
  charge(t, t->d.launch_ns +
                t->d.ray_ns * (double)(r->x1 - r->x0) * (r->y1 - r->y0) +
                t->d.fetch_ns * (double)sum);
  return 0;
}

static int test_compute_ao(void *p, const rp_ao_job *job, uint8_t *out) {
  test_impl *t = p;
  double voxels = (double)(job->end[0] - job->lo[0]) *
                  (job->end[1] - job->lo[1]) * (job->end[2] - job->lo[2]);
  int err = rp__ref_ops.compute_ao(t->ref, job, out);
  if (err != 0)
    return err;
  charge(t, t->d.launch_ns + t->d.ao_voxel_ns * voxels);
  return 0;
}

static int test_upload_ao(void *p, const uint8_t *ao) {
  test_impl *t = p;
  int err = rp__ref_ops.upload_ao(t->ref, ao);
  if (err != 0 || ao == NULL) /* a release takes no time */
    return err;
  charge(t, t->d.ns_per_byte * (double)t->voxels);
  return 0;
}

static uint64_t test_last_time_ns(void *p) {
  return ((const test_impl *)p)->last_ns;
}

static uint64_t test_clock_ns(void *p) {
  return ((const test_impl *)p)->clock_ns;
}

static const rp_backend_ops test_ops = {
    .destroy = test_destroy,
    .upload_volume = test_upload_volume,
    .upload_tf = test_upload_tf,
    .upload_occupancy = test_upload_occupancy,
    .depth_pass = test_depth_pass,
    .ert_prepass = test_ert_prepass,
    .raycast = test_raycast,
    .compute_ao = test_compute_ao,
    .upload_ao = test_upload_ao,
    .last_time_ns = test_last_time_ns,
    .clock_ns = test_clock_ns,
};

static int test_create(rp_context *ctx, const rp_device_desc *desc,
                       const rp_backend_ops **ops, void **impl,
                       rp_caps *caps) {
  const rp_test_backend_desc *in = (const rp_test_backend_desc *)(
      const void *)rp__ext_find(desc->next, RP_EXT_TEST_BACKEND);
  rp_test_backend_desc none = {{RP_EXT_TEST_BACKEND, NULL}, 0, 0, 0, 0,
                               0, 0, 0, 0};
  test_impl *t;
  int err;
  if (in == NULL)
    in = &none;
  if ((err = rp__ref_check(ctx, "test", desc)) != 0 ||
      (err = check_desc(ctx, in)) != 0)
    return err;
  if ((t = rp__calloc(ctx, 1, sizeof *t)) == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_device_create: out of memory");
  if ((err = rp__ref_open(ctx, &t->ref)) != 0) {
    rp__free(ctx, t);
    return err;
  }
  t->ctx = ctx;
  t->d = desc_defaults(in);
  *ops = &test_ops;
  *impl = t;
  rp__ref_caps(caps);
  strcpy(caps->backend, "test");
  strcpy(caps->device, "deterministic test device (scalar reference, "
                       "simulated time)");
  return 0;
}

const rp__host_backend rp__test_backend = {"test", test_create};
