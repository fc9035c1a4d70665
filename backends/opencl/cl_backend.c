/* The OpenCL backend: rp_backend_ops on an OpenCL device (PoCL's CPU
 * device here, its one-core sub-devices, or any GPU with an ICD).
 *
 * Kernels are compiled per effect set: a disabled effect is compiled out
 * with its -D option, never skipped by a branch on a uniform. Programs
 * are built on first use and kept in the variant cache every backend
 * keeps (../variant_cache.h: a bounded table, the least recently used
 * replaced), keyed by the option set, so a set in use is not built
 * twice (PoCL would find its own disk cache, but still spends tens of
 * milliseconds per build).
 *
 * Buffers only, no images: PoCL's linear-filtered images are about half
 * as fast as hand-written trilinear on a buffer, and image access from a
 * sub-device's context aborts in PoCL 3.1.
 *
 * Every kernel runs one work-group per 8x8 tile of rays, its four
 * work-items each taking a packet of 16 rays in vector lanes (common.cl):
 * on PoCL that is what puts the CPU's SIMD units to work, one local size
 * means one compile per kernel (PoCL compiles again for each new local
 * size), and a tile per work-group lets the raycast reduce its tile
 * statistics in local memory without atomics. The AO kernel (kernels/
 * ao.cl) is the exception: a packet of 16 voxels per work-item, one
 * work-item per work-group. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "cl_internal.h"
#include "passes.h"
#include "raypace_ao.h"

#include "ao_cl.h"
#include "common_cl.h"
#include "depth_cl.h"
#include "ert_cl.h"
#include "raycast_cl.h"
#include "sample_cl.h"

/* Rays per work-item (RP_CL_W in common.cl): two tile rows in the
 * sixteen float lanes of an AVX-512 register; eight (one row) measured
 * 40 % slower on PoCL. */
#define RP_CL_PACKET 16
#define RP_CL_PACKETS_PER_TILE (RP_TILE_SIZE * RP_TILE_SIZE / RP_CL_PACKET)
#define RP_CL_EFFECT_BITS                                                     \
  (RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_AO |       \
   RP_EFFECT_PREINT)
/* Zero bytes after the last voxel (and grid byte): kernels read voxel
 * pairs and grid bytes as unaligned words, and trilinear reads two voxels
 * along x even on a one-voxel-wide axis (the second with weight zero). */
#define RP_CL_VOLUME_PAD 16

/* The kernel's rp_cl_frame mirrors rp_frame_params field by field. */
_Static_assert(sizeof(rp_frame_params) == 53 * 4,
               "rp_frame_params must stay 53 packed 4-byte fields");
_Static_assert(sizeof(rp_tile_stats) == 12,
               "rp_tile_stats must match the kernel's rp_cl_tile");
_Static_assert(sizeof(rp_cl_ao_args) == 24 * 4,
               "rp_cl_ao_args must stay 24 packed 4-byte fields");

static const char *const kind_names[] = {"raycast", "depth", "ert",
                                         "ambient occlusion"};
static const char *const kind_kernels[] = {"rp_cl_raycast", "rp_cl_depth",
                                           "rp_cl_ert", "rp_cl_ao"};

/* ---- programs ------------------------------------------------------------ */

/* The build options of an option set. -cl-fast-relaxed-math is left out
 * on purpose: it assumes no infinities, and D_front = +inf is how a ray
 * that meets nothing is marked (the one costly function it would have
 * sped up, the opacity correction, is written out in raycast.cl). */
static void key_options(rp_cl_kind kind, uint32_t key, char *buf,
                        size_t n) {
  static const char *const types[] = {"uchar", "uchar", "ushort", "float"};
  static const int bytes[] = {1, 1, 2, 4};
  uint32_t type = (key >> RP_CL_KEY_TYPE_SHIFT) & 3u;
  if (kind != RP_CL_RAYCAST && kind != RP_CL_AO)
    type = 0;
  snprintf(buf, n,
           "-cl-std=CL1.2 -cl-mad-enable%s%s%s%s%s%s%s -DRP_VOXEL_T=%s "
           "-DRP_VOXEL_BYTES=%d -DRP_INDEX_T=%s -DRP_CL_W=%d",
           (key & RP_EFFECT_SHADING) ? " -DRP_SHADING" : "",
           (key & RP_EFFECT_ERT) ? " -DRP_ERT" : "",
           (key & RP_EFFECT_SKIP) ? " -DRP_SKIP" : "",
           (key & RP_EFFECT_AO) ? " -DRP_AO" : "",
           (key & RP_EFFECT_PREINT) ? " -DRP_PREINT" : "",
           (key & RP_CL_KEY_COUNT) ? " -DRP_COUNT_FETCHES" : "",
           (key & RP_CL_KEY_BRICKED) ? " -DRP_BRICKED" : "",
           types[type], bytes[type], (key & RP_CL_KEY_BIG) ? "long" : "int",
           RP_CL_PACKET);
}

static void release_program(rp_cl_program *p) {
  if (p->kernel != NULL)
    clReleaseKernel(p->kernel);
  if (p->program != NULL)
    clReleaseProgram(p->program);
  p->kernel = NULL;
  p->program = NULL;
}

/* The variant cache's key of (kind, key). */
static uint32_t variant_key(rp_cl_kind kind, uint32_t key) {
  return (uint32_t)kind << RP_CL_KEY_KIND_SHIFT | key;
}

/* Builds the program of (kind, key) and its kernel; errors to `ctx`. Any
 * thread: it reads only what rp_cl__open fixed. */
static int build_kernel(rp_cl_impl *impl, rp_context *ctx, rp_cl_kind kind,
                        uint32_t key, cl_program *prog, cl_kernel *kernel) {
  const char *sources[3];
  cl_uint count = 0;
  char options[192];
  cl_int err;
  int rc;
  sources[count++] = rp_cl_src_common;
  if (kind == RP_CL_RAYCAST || kind == RP_CL_AO)
    sources[count++] = rp_cl_src_sample;
  sources[count++] = kind == RP_CL_RAYCAST ? rp_cl_src_raycast
                     : kind == RP_CL_DEPTH ? rp_cl_src_depth
                     : kind == RP_CL_ERT   ? rp_cl_src_ert
                                           : rp_cl_src_ao;
  key_options(kind, key, options, sizeof options);
  if ((rc = rp_cl__build(impl, ctx, kind_names[kind], sources, count,
                         options, prog)) != 0)
    return rc;
  *kernel = clCreateKernel(*prog, kind_kernels[kind], &err);
  if (*kernel == NULL) {
    char op[64];
    clReleaseProgram(*prog);
    *prog = NULL;
    snprintf(op, sizeof op, "clCreateKernel(%s)", kind_kernels[kind]);
    return rp_cl__fail(ctx, err, op);
  }
  return 0;
}

/* Puts a built (prog, kernel) for (kind, key) in the variant cache and
 * sets *out to the kernel to use: the cache's own when it has one
 * already (the other thread built it meanwhile; ours is released). The
 * render thread (`owner`) replaces the least recently used entry when
 * none is free; prepare only fills a free entry, and releases what it
 * built when there is none (*out NULL). An evicted kernel is released
 * at once: only the owner runs kernels, and it has none in hand here but
 * the ones of this op, which are the most recently used; a launch
 * enqueued before retains its kernel until it completes. */
static void keep_kernel(rp_cl_impl *impl, rp_cl_kind kind, uint32_t key,
                        cl_program prog, cl_kernel kernel, int owner,
                        cl_kernel *out) {
  rp_cl_program mine = {prog, kernel}, old = {NULL, NULL};
  rp_variant_fate fate;
  int i;
  pthread_mutex_lock(&impl->lock);
  fate = rp__variant_insert(&impl->variants, variant_key(kind, key), owner,
                            &i);
  if (fate == RP_VARIANT_REPLACED)
    old = impl->programs[i];
  if (fate == RP_VARIANT_KEPT || fate == RP_VARIANT_REPLACED) {
    impl->programs[i] = mine;
    mine.program = NULL;
    mine.kernel = NULL;
  }
  *out = fate != RP_VARIANT_DROPPED ? impl->programs[i].kernel : NULL;
  pthread_mutex_unlock(&impl->lock);
  release_program(&old);
  release_program(&mine);
}

/* The calling (render) thread is the only one that uses kernels from the
 * cache or evicts them; prepare only fills free entries. So a kernel
 * handed out here stays valid while this thread uses it, and the lock is
 * held only to look up and to insert, never across a build. */
int rp_cl__kernel(rp_cl_impl *impl, rp_cl_kind kind, uint32_t key,
                  cl_kernel *out) {
  cl_program prog;
  cl_kernel kernel;
  int rc, i;
  pthread_mutex_lock(&impl->lock);
  i = rp__variant_use(&impl->variants, variant_key(kind, key));
  if (i >= 0)
    *out = impl->programs[i].kernel;
  pthread_mutex_unlock(&impl->lock);
  if (i >= 0)
    return 0;
  if ((rc = build_kernel(impl, impl->ctx, kind, key, &prog, &kernel)) != 0)
    return rc;
  keep_kernel(impl, kind, key, prog, kernel, 1, out);
  return 0;
}

/* ---- buffers and launches ------------------------------------------------ */

/* Makes `b` at least `size` bytes. Grows only; the old contents are not
 * kept (every user rewrites what it reads). */
static int ensure_buffer(rp_cl_impl *impl, rp_cl_buffer *b, size_t size,
                         cl_mem_flags flags, const char *what) {
  cl_mem mem;
  cl_int err;
  char op[96];
  if (size == 0)
    size = 1;
  if (b->mem != NULL && b->size >= size)
    return 0;
  mem = clCreateBuffer(impl->context, flags, size, NULL, &err);
  if (mem == NULL) {
    snprintf(op, sizeof op, "clCreateBuffer for %s (%zu bytes)", what,
             size);
    return rp_cl__fail(impl->ctx, err, op);
  }
  if (b->mem != NULL)
    clReleaseMemObject(b->mem);
  b->mem = mem;
  b->size = size;
  return 0;
}

/* Replaces `b` with a new buffer holding `size` bytes of `data` (plus
 * `pad` zero bytes); the old one stays if this fails. */
static int upload(rp_cl_impl *impl, rp_cl_buffer *b, const void *data,
                  size_t size, size_t pad, const char *what) {
  rp_cl_buffer nb = {NULL, 0};
  cl_event ev = NULL;
  cl_ulong t0 = 0, t1 = 0;
  cl_int err;
  int rc;
  char op[96];
  if ((rc = ensure_buffer(impl, &nb, size + pad, CL_MEM_READ_ONLY, what)))
    return rc;
  err = clEnqueueWriteBuffer(impl->queue, nb.mem, CL_TRUE, 0, size, data, 0,
                             NULL, &ev);
  if (err == CL_SUCCESS && pad > 0) {
    static const uint8_t zeros[RP_CL_VOLUME_PAD];
    err = clEnqueueWriteBuffer(impl->queue, nb.mem, CL_TRUE, size, pad,
                               zeros, 0, NULL, NULL);
  }
  if (err != CL_SUCCESS) {
    if (ev != NULL)
      clReleaseEvent(ev);
    clReleaseMemObject(nb.mem);
    snprintf(op, sizeof op, "clEnqueueWriteBuffer for %s (%zu bytes)", what,
             size);
    return rp_cl__fail(impl->ctx, err, op);
  }
  clGetEventProfilingInfo(ev, CL_PROFILING_COMMAND_START, sizeof t0, &t0,
                          NULL);
  clGetEventProfilingInfo(ev, CL_PROFILING_COMMAND_END, sizeof t1, &t1,
                          NULL);
  clReleaseEvent(ev);
  impl->last_ns = t1 > t0 ? t1 - t0 : 0;
  if (b->mem != NULL)
    clReleaseMemObject(b->mem);
  *b = nb;
  return 0;
}

static int set_arg(rp_cl_impl *impl, cl_kernel k, cl_uint i, size_t size,
                   const void *value, const char *kernel) {
  cl_int err = clSetKernelArg(k, i, size, value);
  char op[80];
  if (err == CL_SUCCESS)
    return 0;
  snprintf(op, sizeof op, "clSetKernelArg(%s, %u)", kernel, (unsigned)i);
  return rp_cl__fail(impl->ctx, err, op);
}

static int set_mem(rp_cl_impl *impl, cl_kernel k, cl_uint i,
                   const rp_cl_buffer *b, const char *kernel) {
  return set_arg(impl, k, i, sizeof(cl_mem), &b->mem, kernel);
}

static size_t round_up(size_t v, size_t m) { return (v + m - 1) / m * m; }

/* Runs `k` over the global[0] x ... x global[dims - 1] work-items in
 * groups of local[0] x ..., waits, and keeps its device time in last_ns. */
static int launch_nd(rp_cl_impl *impl, cl_kernel k, cl_uint dims,
                     const size_t *global, const size_t *local,
                     const char *kernel) {
  cl_event ev = NULL;
  cl_ulong t0 = 0, t1 = 0;
  cl_int err;
  char op[80];
  err = clEnqueueNDRangeKernel(impl->queue, k, dims, NULL, global, local,
                               0, NULL, &ev);
  if (err == CL_SUCCESS)
    err = clWaitForEvents(1, &ev);
  if (err == CL_SUCCESS) {
    clGetEventProfilingInfo(ev, CL_PROFILING_COMMAND_START, sizeof t0, &t0,
                            NULL);
    clGetEventProfilingInfo(ev, CL_PROFILING_COMMAND_END, sizeof t1, &t1,
                            NULL);
    impl->last_ns = t1 > t0 ? t1 - t0 : 0;
  }
  if (ev != NULL)
    clReleaseEvent(ev);
  if (err == CL_SUCCESS)
    return 0;
  snprintf(op, sizeof op, "running %s (%zux%zux%zu)", kernel, global[0],
           dims > 1 ? global[1] : 1, dims > 2 ? global[2] : 1);
  return rp_cl__fail(impl->ctx, err, op);
}

static int launch(rp_cl_impl *impl, cl_kernel k, const size_t global[2],
                  const size_t local[2], const char *kernel) {
  return launch_nd(impl, k, 2, global, local, kernel);
}

/* A kernel over a w x h grid of rays: one work-group per 8x8 tile, its
 * work-items each taking a packet of rays. */
static int launch_tiles(rp_cl_impl *impl, cl_kernel k, size_t w, size_t h,
                        const char *kernel) {
  size_t global[2] = {round_up(w, RP_TILE_SIZE) / RP_TILE_SIZE,
                      round_up(h, RP_TILE_SIZE) / RP_TILE_SIZE *
                          RP_CL_PACKETS_PER_TILE};
  size_t local[2] = {1, RP_CL_PACKETS_PER_TILE};
  return launch(impl, k, global, local, kernel);
}

static int read_back(rp_cl_impl *impl, const rp_cl_buffer *b, void *dst,
                     size_t size, const char *what) {
  cl_int err = clEnqueueReadBuffer(impl->queue, b->mem, CL_TRUE, 0, size,
                                   dst, 0, NULL, NULL);
  char op[80];
  if (err == CL_SUCCESS)
    return 0;
  snprintf(op, sizeof op, "reading back %s (%zu bytes)", what, size);
  return rp_cl__fail(impl->ctx, err, op);
}

/* Copies a compact rows x row_bytes block from the device into a host
 * image with pitch host_pitch, at byte column `col` of row `row`. */
static int read_rect(rp_cl_impl *impl, const rp_cl_buffer *b, void *host,
                     size_t col, size_t row, size_t row_bytes, size_t rows,
                     size_t host_pitch, const char *what) {
  size_t origin[3] = {0, 0, 0}, host_origin[3] = {col, row, 0};
  size_t region[3] = {row_bytes, rows, 1};
  cl_int err = clEnqueueReadBufferRect(impl->queue, b->mem, CL_TRUE, origin,
                                       host_origin, region, row_bytes, 0,
                                       host_pitch, 0, host, 0, NULL, NULL);
  char op[80];
  if (err == CL_SUCCESS)
    return 0;
  snprintf(op, sizeof op, "reading back %s (%zux%zu)", what, row_bytes,
           rows);
  return rp_cl__fail(impl->ctx, err, op);
}

/* ---- ops ----------------------------------------------------------------- */

static void release_buffer(rp_cl_buffer *b) {
  if (b->mem != NULL)
    clReleaseMemObject(b->mem);
  b->mem = NULL;
  b->size = 0;
}

static void cl_destroy(void *p) {
  rp_cl_impl *impl = p;
  size_t i;
  if (impl == NULL)
    return;
  for (i = 0; i < RP_VARIANT_CACHE_SIZE; i++)
    release_program(&impl->programs[i]);
  release_buffer(&impl->volume);
  release_buffer(&impl->brick_table);
  release_buffer(&impl->lut);
  release_buffer(&impl->grid);
  release_buffer(&impl->bordered_grid);
  release_buffer(&impl->alpha_hist);
  release_buffer(&impl->ao);
  release_buffer(&impl->front_back);
  release_buffer(&impl->d_ert);
  release_buffer(&impl->rgba);
  release_buffer(&impl->tiles);
  release_buffer(&impl->fetches);
  release_buffer(&impl->slab_state);
  rp__free(impl->ctx, impl->brick_staging);
  rp__free(impl->ctx, impl->brick_order);
  rp_cl__close(impl);
  pthread_mutex_destroy(&impl->lock);
  rp__free(impl->ctx, impl);
}

static int cl_upload_volume(void *p, const rp_volume *vol) {
  rp_cl_impl *impl = p;
  size_t bytes = vol->voxel_count * rp__voxel_size(vol->type);
  int rc = upload(impl, &impl->volume, vol->data, bytes, RP_CL_VOLUME_PAD,
                  "the volume");
  if (rc == 0) {
    release_buffer(&impl->brick_table);
    memcpy(impl->dims, vol->dims, sizeof impl->dims);
    impl->voxels = vol->voxel_count;
    pthread_mutex_lock(&impl->lock);
    impl->bricked = 0;
    impl->voxel_type = vol->type;
    /* Kernels index voxels with signed 32-bit integers (that is what
     * lets gathers use 32-bit offsets) unless the volume is too big. */
    impl->big_volume = vol->voxel_count + RP_CL_VOLUME_PAD >= 0x7fffffffu;
    pthread_mutex_unlock(&impl->lock);
  }
  return rc;
}

/* The LUT and, after it, its pre-integration table (8 floats an entry,
 * rp__preint_table), which the RP_PREINT raycast reads: 32 KiB for the
 * default 1024 entries, built whether or not a frame will use it, so that
 * switching the effect on costs no upload. */
static int cl_upload_tf(void *p, const float *lut, uint32_t lut_size) {
  rp_cl_impl *impl = p;
  size_t n = (size_t)lut_size * 12;
  float *all = rp__malloc(impl->ctx, n * sizeof *all);
  int rc;
  if (all == NULL)
    return rp__fail(impl->ctx, RP_ENOMEM, "opencl: no memory to stage the "
                    "transfer function (%u entries)", (unsigned)lut_size);
  memcpy(all, lut, (size_t)lut_size * 4 * sizeof *all);
  rp__preint_table(lut, lut_size, all + (size_t)lut_size * 4);
  rc = upload(impl, &impl->lut, all, n * sizeof *all, 0,
              "the transfer function");
  rp__free(impl->ctx, all);
  return rc;
}

static int cl_upload_occupancy(void *p, const uint8_t *grid,
                               const uint8_t *alpha_hist,
                               const uint32_t blocks[3]) {
  rp_cl_impl *impl = p;
  size_t n = (size_t)blocks[0] * blocks[1] * blocks[2];
  size_t bx = blocks[0] + 2, by = blocks[1] + 2, bz = blocks[2] + 2;
  size_t y, z;
  uint64_t ns = 0;
  uint8_t *bordered = rp__calloc(impl->ctx, bx * by * bz, 1);
  int rc;
  if (bordered == NULL)
    return rp__fail(impl->ctx, RP_ENOMEM, "opencl: out of memory for the "
                    "bordered occupancy grid (%zu blocks)", bx * by * bz);
  for (z = 0; z < blocks[2]; z++)
    for (y = 0; y < blocks[1]; y++)
      memcpy(bordered + ((z + 1) * by + y + 1) * bx + 1,
             grid + (z * blocks[1] + y) * blocks[0], blocks[0]);
  /* Kernels read grid bytes as the low byte of 32-bit words. */
  rc = upload(impl, &impl->grid, grid, n, RP_CL_VOLUME_PAD,
              "the occupancy grid");
  ns += rc == 0 ? impl->last_ns : 0;
  if (rc == 0)
    rc = upload(impl, &impl->bordered_grid, bordered, bx * by * bz,
                RP_CL_VOLUME_PAD, "the bordered occupancy grid");
  ns += rc == 0 ? impl->last_ns : 0;
  rp__free(impl->ctx, bordered);
  if (rc == 0)
    rc = upload(impl, &impl->alpha_hist, alpha_hist, n * RP_OPACITY_BINS, 0,
                "the opacity histograms");
  impl->last_ns += ns;
  return rc;
}

static int cl_depth_pass(void *p, const rp_frame_params *fp,
                         float *front_back) {
  rp_cl_impl *impl = p;
  size_t rays = (size_t)fp->width * fp->height;
  cl_kernel k;
  int rc;
  if ((rc = rp_cl__kernel(impl, RP_CL_DEPTH, fp->effects & RP_EFFECT_SKIP,
                          &k)) != 0 ||
      (rc = ensure_buffer(impl, &impl->front_back, rays * 2 * sizeof(float),
                          CL_MEM_READ_WRITE, "the depth pass")) != 0)
    return rc;
  if ((rc = set_arg(impl, k, 0, sizeof *fp, fp, "rp_cl_depth")) != 0 ||
      (rc = set_mem(impl, k, 1, &impl->bordered_grid, "rp_cl_depth")) !=
          0 ||
      (rc = set_mem(impl, k, 2, &impl->front_back, "rp_cl_depth")) != 0 ||
      (rc = launch_tiles(impl, k, fp->width, fp->height, "rp_cl_depth")))
    return rc;
  if (front_back != NULL)
    return read_back(impl, &impl->front_back, front_back,
                     rays * 2 * sizeof(float), "the depth pass");
  return 0;
}

static int cl_ert_prepass(void *p, const rp_frame_params *fp,
                          float *d_ert) {
  rp_cl_impl *impl = p;
  uint32_t gw, gh;
  cl_float16 alpha;
  cl_kernel k;
  int rc, b;
  double corr[RP_OPACITY_BINS];
  rp__ert_grid(fp->width, fp->height, &gw, &gh);
  /* The 16 bins' centre opacities at the coarse step, once, in double,
   * as the C pre-pass corrects them. */
  rp__ert_corrected(NULL, fp->ref_step, corr);
  for (b = 0; b < RP_OPACITY_BINS; b++)
    alpha.s[b] = (float)corr[b];
  if ((rc = rp_cl__kernel(impl, RP_CL_ERT, 0, &k)) != 0 ||
      (rc = ensure_buffer(impl, &impl->d_ert,
                          (size_t)gw * gh * sizeof(float),
                          CL_MEM_WRITE_ONLY, "the ERT pre-pass")) != 0)
    return rc;
  if ((rc = set_arg(impl, k, 0, sizeof *fp, fp, "rp_cl_ert")) != 0 ||
      (rc = set_mem(impl, k, 1, &impl->grid, "rp_cl_ert")) != 0 ||
      (rc = set_mem(impl, k, 2, &impl->alpha_hist, "rp_cl_ert")) != 0 ||
      (rc = set_arg(impl, k, 3, sizeof alpha, &alpha, "rp_cl_ert")) != 0 ||
      (rc = set_mem(impl, k, 4, &impl->d_ert, "rp_cl_ert")) != 0 ||
      (rc = launch_tiles(impl, k, gw, gh, "rp_cl_ert")) != 0)
    return rc;
  if (d_ert == NULL)
    return 0;
  return read_back(impl, &impl->d_ert, d_ert,
                   (size_t)gw * gh * sizeof(float), "the ERT pre-pass");
}

static uint32_t raycast_key(const rp_cl_impl *impl, uint32_t effects,
                            int count) {
  return (effects & RP_CL_EFFECT_BITS) | (count ? RP_CL_KEY_COUNT : 0u) |
         (impl->big_volume ? RP_CL_KEY_BIG : 0u) |
         (impl->bricked ? RP_CL_KEY_BRICKED : 0u) |
         ((uint32_t)impl->voxel_type << RP_CL_KEY_TYPE_SHIFT);
}

/* The AO program's key: the voxel type and index width. */
static uint32_t ao_key(const rp_cl_impl *impl) {
  return (impl->big_volume ? RP_CL_KEY_BIG : 0u) |
         ((uint32_t)impl->voxel_type << RP_CL_KEY_TYPE_SHIFT);
}

static int cl_raycast(void *p, const rp_frame_params *fp, const rp_region *r,
                      uint8_t *rgba, rp_tile_stats *tiles,
                      uint64_t *fetches) {
  rp_cl_impl *impl = p;
  const char *name = "rp_cl_raycast";
  size_t rw = r->x1 > r->x0 ? r->x1 - r->x0 : 0;
  size_t rh = r->y1 > r->y0 ? r->y1 - r->y0 : 0;
  size_t tw = (rw + RP_TILE_SIZE - 1) / RP_TILE_SIZE;
  size_t th = (rh + RP_TILE_SIZE - 1) / RP_TILE_SIZE;
  size_t tiles_x = fp->width / RP_TILE_SIZE + (fp->width % RP_TILE_SIZE != 0);
  cl_uint region[4] = {r->x0, r->y0, r->x1, r->y1};
  cl_kernel k;
  int rc, i;
  impl->last_ns = 0;
  if (rw == 0 || rh == 0)
    return 0;
  /* The front end orders the calls; this only turns a slip into an error
   * instead of a kernel reading a missing buffer. */
  if (impl->volume.mem == NULL || impl->lut.mem == NULL ||
      impl->front_back.mem == NULL)
    return rp__fail(impl->ctx, RP_ESTATE, "opencl: raycast before the "
                    "volume, transfer function or depth pass");
  if ((fp->brick_shift != 0) != impl->bricked)
    return rp__fail(impl->ctx, RP_ESTATE, "opencl: raycast %s a brick "
                    "table, but the device holds %s", fp->brick_shift != 0
                    ? "through" : "without", impl->bricked
                    ? "a brick pool" : "the whole volume");
  if ((fp->effects & RP_EFFECT_PREINT) && impl->bricked)
    return rp__fail(impl->ctx, RP_EINVAL, "opencl: RP_EFFECT_PREINT with an "
                    "out-of-core volume (a brick pool) is not supported: "
                    "a depth slab cannot read the value before its first "
                    "sample");
  if ((fp->effects & RP_EFFECT_AO) &&
      (impl->ao.mem == NULL || impl->ao_voxels != impl->voxels))
    return rp__fail(impl->ctx, RP_ESTATE, "opencl: raycast with "
                    "RP_EFFECT_AO but no AO volume uploaded for this "
                    "volume");
  if ((rc = rp_cl__kernel(impl, RP_CL_RAYCAST,
                          raycast_key(impl, fp->effects, fetches != NULL),
                          &k)) != 0 ||
      (rc = ensure_buffer(impl, &impl->rgba, rw * rh * 4, CL_MEM_WRITE_ONLY,
                          "the image")) != 0 ||
      (rc = ensure_buffer(impl, &impl->tiles, tw * th * sizeof *tiles,
                          CL_MEM_WRITE_ONLY, "the tile stats")) != 0 ||
      (fetches != NULL &&
       (rc = ensure_buffer(impl, &impl->fetches, tw * th * sizeof *fetches,
                           CL_MEM_WRITE_ONLY, "the fetch counts")) != 0) ||
      (impl->bricked && fp->slab_flags != (RP_SLAB_FIRST | RP_SLAB_LAST) &&
       (rc = ensure_buffer(impl, &impl->slab_state,
                           rw * rh * 8 * sizeof(float), CL_MEM_READ_WRITE,
                           "the depth slabs' ray state")) != 0))
    return rc;
  if ((rc = set_arg(impl, k, 0, sizeof *fp, fp, name)) != 0)
    return rc;
  for (i = 0; i < 4; i++)
    if ((rc = set_arg(impl, k, 1 + i, sizeof(cl_uint), &region[i], name)))
      return rc;
  if ((rc = set_mem(impl, k, 5, &impl->volume, name)) != 0 ||
      (rc = set_mem(impl, k, 6, &impl->lut, name)) != 0 ||
      (rc = set_mem(impl, k, 7, &impl->grid, name)) != 0 ||
      (rc = set_mem(impl, k, 8, &impl->front_back, name)) != 0 ||
      (rc = set_mem(impl, k, 9, &impl->rgba, name)) != 0 ||
      (rc = set_mem(impl, k, 10, &impl->tiles, name)) != 0 ||
      (rc = set_mem(impl, k, 11, &impl->fetches, name)) != 0 ||
      (rc = set_mem(impl, k, 12, &impl->ao, name)) != 0 ||
      (rc = set_mem(impl, k, 13, &impl->brick_table, name)) != 0 ||
      (rc = set_mem(impl, k, 14, &impl->slab_state, name)) != 0 ||
      (rc = launch_tiles(impl, k, rw, rh, name)) != 0)
    return rc;
  /* A slab before the last leaves its rays' state on the device. */
  if (impl->bricked && !(fp->slab_flags & RP_SLAB_LAST))
    return 0;
  if ((rc = read_rect(impl, &impl->rgba, rgba, (size_t)r->x0 * 4, r->y0,
                      rw * 4, rh, (size_t)fp->width * 4, "the image")) != 0)
    return rc;
  if (tiles != NULL &&
      (rc = read_rect(impl, &impl->tiles, tiles,
                      (size_t)(r->x0 / RP_TILE_SIZE) * sizeof *tiles,
                      r->y0 / RP_TILE_SIZE, tw * sizeof *tiles, th,
                      tiles_x * sizeof *tiles, "the tile stats")) != 0)
    return rc;
  if (fetches != NULL &&
      (rc = read_rect(impl, &impl->fetches, fetches,
                      (size_t)(r->x0 / RP_TILE_SIZE) * sizeof *fetches,
                      r->y0 / RP_TILE_SIZE, tw * sizeof *fetches, th,
                      tiles_x * sizeof *fetches, "the fetch counts")) != 0)
    return rc;
  return 0;
}

/* A read-only buffer holding a copy of `size` bytes at `data`. */
static int upload_copy(rp_cl_impl *impl, rp_cl_buffer *b, const void *data,
                       size_t size, const char *what) {
  cl_int err;
  char op[96];
  b->mem = clCreateBuffer(impl->context,
                          CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, size,
                          (void *)data, &err);
  b->size = size;
  if (b->mem != NULL)
    return 0;
  snprintf(op, sizeof op, "clCreateBuffer for %s (%zu bytes)", what, size);
  return rp_cl__fail(impl->ctx, err, op);
}

/* Computes the job's box on the device. Its buffers (directions, brick
 * mask, result) live for this call only: AO is computed once per volume
 * and transfer function, and memory for it must not outlive it. */
static int cl_compute_ao(void *p, const rp_ao_job *job, uint8_t *out) {
  rp_cl_impl *impl = p;
  const char *name = "rp_cl_ao";
  rp_cl_buffer dirs = {NULL, 0}, bricks = {NULL, 0}, res = {NULL, 0};
  rp_cl_ao_args a;
  size_t n[3], global[3], local[3] = {1, 1, 1};
  size_t cols = RP_AO_BRICK, rows = RP_CL_PACKET / RP_AO_BRICK, total;
  cl_kernel k;
  int rc, i;
  impl->last_ns = 0;
  if (impl->volume.mem == NULL || impl->lut.mem == NULL || impl->bricked)
    return rp__fail(impl->ctx, RP_ESTATE, "opencl: compute_ao %s",
                    impl->bricked ? "on a brick pool (AO needs the whole "
                                    "volume)"
                                  : "before the volume or transfer "
                                    "function");
  for (i = 0; i < 3; i++)
    n[i] = job->end[i] > job->lo[i] ? job->end[i] - job->lo[i] : 0;
  total = n[0] * n[1] * n[2];
  if (total == 0)
    return 0;
  memset(&a, 0, sizeof a);
  for (i = 0; i < 3; i++) {
    a.dims[i] = (float)impl->dims[i];
    a.idims[i] = impl->dims[i];
    a.lo[i] = job->lo[i];
    a.end[i] = job->end[i];
    a.brick_grid[i] = job->brick_grid[i];
  }
  a.directions = job->directions;
  a.samples = job->samples;
  a.offset = job->offset;
  a.step = job->step;
  a.ref_step = job->ref_step;
  a.value_min = job->value_min;
  a.value_max = job->value_max;
  a.lut_size = job->lut_size;
  a.bricked = job->bricks != NULL;
  /* Packets of cols x rows voxels aligned to the whole grid's bricks,
   * from the one holding lo to the one holding end - 1. */
  global[0] = (job->end[0] - 1) / cols - job->lo[0] / cols + 1;
  global[1] = (job->end[1] - 1) / rows - job->lo[1] / rows + 1;
  global[2] = n[2];
  rc = rp_cl__kernel(impl, RP_CL_AO, ao_key(impl), &k);
  if (rc == 0)
    rc = upload_copy(impl, &dirs, job->dirs,
                     (size_t)job->directions * 4 * sizeof(float),
                     "the AO directions");
  /* Without a mask the kernel never reads it, but needs a buffer. */
  if (rc == 0)
    rc = job->bricks != NULL
             ? upload_copy(impl, &bricks, job->bricks,
                           (size_t)job->brick_grid[0] * job->brick_grid[1] *
                               job->brick_grid[2],
                           "the AO brick mask")
             : ensure_buffer(impl, &bricks, 1, CL_MEM_READ_ONLY,
                             "the AO brick mask");
  if (rc == 0)
    rc = ensure_buffer(impl, &res, total, CL_MEM_WRITE_ONLY, "the AO box");
  if (rc == 0 && (rc = set_arg(impl, k, 0, sizeof a, &a, name)) == 0 &&
      (rc = set_mem(impl, k, 1, &impl->volume, name)) == 0 &&
      (rc = set_mem(impl, k, 2, &impl->lut, name)) == 0 &&
      (rc = set_mem(impl, k, 3, &bricks, name)) == 0 &&
      (rc = set_mem(impl, k, 4, &dirs, name)) == 0 &&
      (rc = set_mem(impl, k, 5, &res, name)) == 0 &&
      (rc = launch_nd(impl, k, 3, global, local, name)) == 0) {
    uint64_t ns = impl->last_ns;
    rc = read_back(impl, &res, out, total, "the AO box");
    impl->last_ns = ns;
  }
  release_buffer(&dirs);
  release_buffer(&bricks);
  release_buffer(&res);
  return rc;
}

/* The AO volume raycasts read; NULL releases it. */
static int cl_upload_ao(void *p, const uint8_t *ao) {
  rp_cl_impl *impl = p;
  int rc;
  if (ao == NULL) {
    release_buffer(&impl->ao);
    impl->ao_voxels = 0;
    impl->last_ns = 0;
    return 0;
  }
  if (impl->volume.mem == NULL || impl->bricked)
    return rp__fail(impl->ctx, RP_ESTATE, "opencl: upload_ao %s",
                    impl->bricked ? "on a brick pool" : "before the volume");
  /* Padded as the volume is: trilinear reads bytes in 32-bit words. */
  rc = upload(impl, &impl->ao, ao, impl->voxels, RP_CL_VOLUME_PAD,
              "the AO volume");
  if (rc == 0)
    impl->ao_voxels = impl->voxels;
  return rc;
}

/* ---- out-of-core ---------------------------------------------------------- */

static int cl_set_brick_pool(void *p, const rp_brick_pool *pool) {
  rp_cl_impl *impl = p;
  static const uint32_t zero = 0;
  size_t s, count, bytes, padded;
  cl_int err;
  int rc;
  impl->last_ns = 0;
  release_buffer(&impl->volume);
  release_buffer(&impl->brick_table);
  release_buffer(&impl->ao);
  impl->ao_voxels = 0;
  impl->voxels = 0;
  pthread_mutex_lock(&impl->lock);
  impl->bricked = 0;
  pthread_mutex_unlock(&impl->lock);
  if (pool == NULL)
    return 0;
  s = (size_t)pool->brick_size + 1;
  count = (size_t)pool->grid[0] * pool->grid[1] * pool->grid[2];
  impl->brick_bytes = s * s * s * rp__voxel_size(pool->type);
  bytes = impl->brick_bytes * pool->slots;
  /* Padded as the whole volume is (voxel pairs are read as words), and
   * to the fill pattern's size. */
  padded = round_up(bytes + RP_CL_VOLUME_PAD, sizeof zero);
  if ((rc = ensure_buffer(impl, &impl->volume, padded, CL_MEM_READ_ONLY,
                          "the brick pool")) != 0 ||
      (rc = ensure_buffer(impl, &impl->brick_table, count * sizeof zero,
                          CL_MEM_READ_ONLY, "the brick table")) != 0)
    return rc;
  /* Every brick starts in slot 0 (the transparent one), and the pad is
   * defined. */
  err = clEnqueueFillBuffer(impl->queue, impl->brick_table.mem, &zero,
                            sizeof zero, 0, count * sizeof zero, 0, NULL,
                            NULL);
  if (err == CL_SUCCESS)
    err = clEnqueueFillBuffer(impl->queue, impl->volume.mem, &zero,
                              sizeof zero, 0, padded, 0, NULL, NULL);
  if (err == CL_SUCCESS)
    err = clFinish(impl->queue);
  if (err != CL_SUCCESS)
    return rp_cl__fail(impl->ctx, err, "clearing the brick pool");
  memcpy(impl->dims, pool->dims, sizeof impl->dims);
  impl->brick_count = count;
  pthread_mutex_lock(&impl->lock);
  impl->voxel_type = pool->type;
  impl->bricked = 1;
  impl->big_volume =
      bytes / rp__voxel_size(pool->type) + RP_CL_VOLUME_PAD >= 0x7fffffffu;
  pthread_mutex_unlock(&impl->lock);
  return 0;
}

/* Keeps the first and the latest of a run of events. */
static void keep_event(cl_event ev, cl_event *first, cl_event *last) {
  if (*first == NULL) {
    *first = ev;
    return;
  }
  if (*last != NULL)
    clReleaseEvent(*last);
  *last = ev;
}

/* qsort has no context argument: upload_bricks sorts indices into its
 * slots through this, under no lock, so a device's uploads must not run
 * on two threads at once (a device is one thread's at a time). */
static _Thread_local const uint32_t *sort_slots;

static int by_slot(const void *a, const void *b) {
  uint32_t x = sort_slots[*(const uint32_t *)a];
  uint32_t y = sort_slots[*(const uint32_t *)b];
  return x < y ? -1 : x > y;
}

/* Grows *buf to at least `bytes` (contents not kept). */
static int grow_scratch(rp_cl_impl *impl, void **buf, size_t *cap,
                        size_t bytes) {
  void *nb;
  if (*cap >= bytes)
    return 0;
  if ((nb = rp__malloc(impl->ctx, bytes)) == NULL)
    return rp__fail(impl->ctx, RP_ENOMEM, "opencl: no memory to stage "
                    "%zu bytes of bricks", bytes);
  rp__free(impl->ctx, *buf);
  *buf = nb;
  *cap = bytes;
  return 0;
}

static int cl_upload_bricks(void *p, uint32_t count, const uint32_t *slots,
                            const void *const *voxels,
                            const uint32_t *table) {
  rp_cl_impl *impl = p;
  cl_event first = NULL, last = NULL, ev;
  cl_ulong t0 = 0, t1 = 0;
  cl_int err = CL_SUCCESS, done;
  uint32_t i, run, k;
  uint64_t begin = rp__now_ns();
  int rc;
  impl->last_ns = 0;
  if (!impl->bricked)
    return rp__fail(impl->ctx, RP_ESTATE, "opencl: upload_bricks without "
                    "a brick pool");
  /* One write per brick costs PoCL about 10 us of command overhead, more
   * than copying the brick (5 KB at 16^3 u8): a frame that misses 1800
   * bricks spent 25 ms on them. So the bricks are taken in slot order and
   * each run of consecutive slots is staged side by side and written at
   * once; LRU hands out the slots of one earlier admit together, so runs
   * are long. */
  if ((rc = grow_scratch(impl, (void **)&impl->brick_order,
                         &impl->brick_order_cap,
                         (size_t)count * sizeof *impl->brick_order)) != 0 ||
      (rc = grow_scratch(impl, (void **)&impl->brick_staging,
                         &impl->brick_staging_cap,
                         (size_t)count * impl->brick_bytes)) != 0)
    return rc;
  for (i = 0; i < count; i++)
    impl->brick_order[i] = i;
  sort_slots = slots;
  qsort(impl->brick_order, count, sizeof *impl->brick_order, by_slot);
  sort_slots = NULL;
  /* Non-blocking writes on the in-order queue; the first and the last
   * event bound the device time of them all. */
  for (i = 0; i < count && err == CL_SUCCESS; i = run) {
    uint8_t *stage = impl->brick_staging + (size_t)i * impl->brick_bytes;
    uint32_t lo = slots[impl->brick_order[i]];
    for (run = i + 1;
         run < count && slots[impl->brick_order[run]] == lo + (run - i);
         run++)
      ;
    for (k = i; k < run; k++)
      memcpy(stage + (size_t)(k - i) * impl->brick_bytes,
             voxels[impl->brick_order[k]], impl->brick_bytes);
    ev = NULL;
    err = clEnqueueWriteBuffer(impl->queue, impl->volume.mem, CL_FALSE,
                               (size_t)lo * impl->brick_bytes,
                               (size_t)(run - i) * impl->brick_bytes, stage,
                               0, NULL, &ev);
    if (err == CL_SUCCESS)
      keep_event(ev, &first, &last);
  }
  if (err == CL_SUCCESS && table != NULL) {
    ev = NULL;
    err = clEnqueueWriteBuffer(impl->queue, impl->brick_table.mem, CL_FALSE,
                               0, impl->brick_count * sizeof *table, table, 0,
                               NULL, &ev);
    if (err == CL_SUCCESS)
      keep_event(ev, &first, &last);
  }
  /* The staged bricks and the table must stay put until every write is
   * done, failed or not. */
  done = clFinish(impl->queue);
  if (err == CL_SUCCESS)
    err = done;
  if (err == CL_SUCCESS && first != NULL) {
    clGetEventProfilingInfo(first, CL_PROFILING_COMMAND_START, sizeof t0,
                            &t0, NULL);
    clGetEventProfilingInfo(last != NULL ? last : first,
                            CL_PROFILING_COMMAND_END, sizeof t1, &t1, NULL);
    impl->last_ns = t1 > t0 ? t1 - t0 : 0;
  }
  /* The staging copies are the upload's cost too (the render waits for
   * them), though no event times them. */
  if (err == CL_SUCCESS && rp__now_ns() - begin > impl->last_ns)
    impl->last_ns = rp__now_ns() - begin;
  if (first != NULL)
    clReleaseEvent(first);
  if (last != NULL)
    clReleaseEvent(last);
  if (err != CL_SUCCESS)
    return rp_cl__fail(impl->ctx, err, "writing bricks to the pool");
  return 0;
}

static uint64_t cl_last_time_ns(void *p) {
  return ((const rp_cl_impl *)p)->last_ns;
}

/* The frame's kernels ahead of it, on the calling thread (rp_backend_ops
 * says what may run meanwhile): the depth pass and the raycast, and with
 * AO the AO volume kernel (the runtime's AO run waits for it rather than
 * build it on a frame). The keys come from the volume's fields, read
 * under the lock; a volume uploaded while this builds makes them stale,
 * which costs the frame a build of its own, never a wrong kernel: the
 * key says what a program was built for. PoCL still compiles a kernel's
 * work-group function at its first launch: from its disk cache that is
 * quick, but cold it cost the first frame 460-480 ms here. Launching
 * from here instead stalled a frame just as long (PoCL's device holds
 * its queues while it compiles), so the frame is left to do it. */
static int cl_prepare(void *p, rp_context *ctx, uint32_t effects) {
  rp_cl_impl *impl = p;
  rp_cl_kind kinds[3] = {RP_CL_DEPTH, RP_CL_RAYCAST, RP_CL_AO};
  uint32_t keys[3];
  int i, n = 2, have, rc;
  pthread_mutex_lock(&impl->lock);
  have = impl->voxel_type != 0;
  keys[0] = effects & RP_EFFECT_SKIP;
  keys[1] = raycast_key(impl, effects, 0);
  keys[2] = ao_key(impl);
  /* AO is not computed on a brick pool (set_brick_pool). */
  if ((effects & RP_EFFECT_AO) && !impl->bricked)
    n = 3;
  pthread_mutex_unlock(&impl->lock);
  if (!have)
    return rp__fail(ctx, RP_ESTATE, "opencl: prepare before a volume was "
                    "uploaded (the raycast is built for its voxel type)");
  for (i = 0; i < n; i++) {
    cl_program prog;
    cl_kernel kernel;
    pthread_mutex_lock(&impl->lock);
    have = rp__variant_find(&impl->variants,
                            variant_key(kinds[i], keys[i])) >= 0;
    pthread_mutex_unlock(&impl->lock);
    if (have)
      continue;
    if ((rc = build_kernel(impl, ctx, kinds[i], keys[i], &prog,
                           &kernel)) != 0)
      return rc;
    /* Kept, there already, or dropped for want of room: 0 either way. */
    keep_kernel(impl, kinds[i], keys[i], prog, kernel, 0, &kernel);
  }
  return 0;
}

static const rp_backend_ops cl_ops = {
    .destroy = cl_destroy,
    .upload_volume = cl_upload_volume,
    .upload_tf = cl_upload_tf,
    .upload_occupancy = cl_upload_occupancy,
    .depth_pass = cl_depth_pass,
    .ert_prepass = cl_ert_prepass,
    .raycast = cl_raycast,
    .compute_ao = cl_compute_ao,
    .upload_ao = cl_upload_ao,
    .set_brick_pool = cl_set_brick_pool,
    .upload_bricks = cl_upload_bricks,
    .last_time_ns = cl_last_time_ns,
    .prepare = cl_prepare};

/* ---- bootstrap ----------------------------------------------------------- */

static int cl_probe(rp_context *ctx, uint32_t *device_count) {
  (void)ctx;
  return rp_cl__count_devices(device_count);
}

static int cl_create(rp_context *ctx, uint32_t index, uint32_t units,
                     const rp_backend_ops **ops, void **out, rp_caps *caps) {
  rp_cl_impl *impl = rp__calloc(ctx, 1, sizeof *impl);
  int rc;
  if (impl == NULL)
    return rp__fail(ctx, RP_ENOMEM, "opencl: out of memory for device %u",
                    (unsigned)index);
  impl->ctx = ctx;
  if (pthread_mutex_init(&impl->lock, NULL) != 0) {
    rp__free(ctx, impl);
    return rp__fail(ctx, RP_ENOMEM, "opencl: no mutex for device %u",
                    (unsigned)index);
  }
  if ((rc = rp_cl__open(impl, index, units, caps)) != 0) {
    pthread_mutex_destroy(&impl->lock);
    rp__free(ctx, impl);
    return rc;
  }
  *ops = &cl_ops;
  *out = impl;
  return 0;
}

const rp_backend_bootstrap rp_cl_bootstrap = {"opencl", cl_probe, cl_create,
                                              rp_cl__partition_units};

/* ---- test hooks ---------------------------------------------------------- */

int rp_cl__build_program_for_test(void *p, const char *source,
                                  const char *options) {
  rp_cl_impl *impl = p;
  cl_program prog;
  int rc = rp_cl__build(impl, impl->ctx, "test", &source, 1, options,
                        &prog);
  if (rc == 0)
    clReleaseProgram(prog);
  return rc;
}

void rp_cl__variant_stats(void *p, rp_variant_stats *out) {
  rp_cl_impl *impl = p;
  pthread_mutex_lock(&impl->lock);
  *out = impl->variants.stats;
  pthread_mutex_unlock(&impl->lock);
}

/* A kernel that applies the raycast's opacity correction to an array;
 * built after common.cl and sample.cl, so it calls the very function
 * frames use. */
static const char correct_test_src[] =
    "__kernel void rp_cl_correct_test(__global const float *a, float r,\n"
    "                                 __global float *out) {\n"
    "  size_t i = get_global_id(0);\n"
    "  RP_CL_CAT(vstore, RP_CL_W)(rp_cl_correct(\n"
    "      RP_CL_CAT(vload, RP_CL_W)(i, a), r), i, out);\n"
    "}\n";

int rp_cl__correct_for_test(void *p, const float *alpha, size_t n,
                            float ratio, float *out) {
  rp_cl_impl *impl = p;
  const char *sources[3] = {rp_cl_src_common, rp_cl_src_sample,
                            correct_test_src};
  size_t groups = (n + RP_CL_PACKET - 1) / RP_CL_PACKET;
  size_t bytes = groups * RP_CL_PACKET * sizeof(float);
  size_t global[2] = {groups, 1}, local[2] = {1, 1};
  rp_cl_buffer in = {NULL, 0}, res = {NULL, 0};
  char options[192];
  cl_program prog = NULL;
  cl_kernel k = NULL;
  cl_int err;
  int rc;
  key_options(RP_CL_RAYCAST, 0, options, sizeof options);
  if ((rc = rp_cl__build(impl, impl->ctx, "correction test", sources, 3,
                         options, &prog)) != 0)
    return rc;
  k = clCreateKernel(prog, "rp_cl_correct_test", &err);
  if (k == NULL)
    rc = rp_cl__fail(impl->ctx, err, "clCreateKernel(rp_cl_correct_test)");
  if (rc == 0)
    rc = ensure_buffer(impl, &in, bytes, CL_MEM_READ_ONLY, "test input");
  if (rc == 0)
    rc = ensure_buffer(impl, &res, bytes, CL_MEM_WRITE_ONLY, "test output");
  if (rc == 0 && (err = clEnqueueWriteBuffer(impl->queue, in.mem, CL_TRUE,
                                             0, n * sizeof(float), alpha, 0,
                                             NULL, NULL)) != CL_SUCCESS)
    rc = rp_cl__fail(impl->ctx, err, "writing the test input");
  if (rc == 0)
    rc = set_mem(impl, k, 0, &in, "rp_cl_correct_test");
  if (rc == 0)
    rc = set_arg(impl, k, 1, sizeof ratio, &ratio, "rp_cl_correct_test");
  if (rc == 0)
    rc = set_mem(impl, k, 2, &res, "rp_cl_correct_test");
  if (rc == 0)
    rc = launch(impl, k, global, local, "rp_cl_correct_test");
  if (rc == 0)
    rc = read_back(impl, &res, out, n * sizeof(float), "the test output");
  if (k != NULL)
    clReleaseKernel(k);
  clReleaseProgram(prog);
  release_buffer(&in);
  release_buffer(&res);
  return rc;
}
