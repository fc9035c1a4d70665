/* Devices: the backend registry, selection, and the front end that
 * validates every call before it reaches a backend (STYLE rules 7-9).
 *
 * The "reference" device is not a vtable backend: it runs the scalar C
 * passes (reference.c, depth.c, ert.c) on the camera in double, exactly as
 * rp_render_reference does, so that it IS the oracle rather than a float
 * copy of it. Every other device receives rp_frame_params. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "ao.h"
#include "bricks.h"
#include "passes.h"
#include "raypace_backend.h"

#ifdef RP_WITH_OPENCL
extern const rp_backend_bootstrap rp_cl_bootstrap;
#endif
#ifdef RP_WITH_VULKAN
extern const rp_backend_bootstrap rp_vk_bootstrap;
#endif
#ifdef RP_WITH_MPI
extern const rp_backend_bootstrap rp_mpi_bootstrap;
#endif

/* Selection order when none is named: the first with a device. */
static const rp_backend_bootstrap *const registry[] = {
#ifdef RP_WITH_OPENCL
    &rp_cl_bootstrap,
#endif
#ifdef RP_WITH_VULKAN
    &rp_vk_bootstrap,
#endif
#ifdef RP_WITH_MPI
    &rp_mpi_bootstrap,
#endif
    NULL};

/* Backends opened only by name, never chosen by default: "mpi" is
 * another rank's device (raypace_mpi.h), which an application uses on
 * purpose, not because this machine has no device of its own. */
static int named_only(const rp_backend_bootstrap *b) {
#ifdef RP_WITH_MPI
  return b == &rp_mpi_bootstrap;
#else
  (void)b;
  return 0;
#endif
}

#define REFERENCE "reference"

struct rp_device {
  rp_context *ctx;
  const rp_backend_ops *ops; /* NULL: the reference device */
  void *impl;
  rp_caps caps;
  /* The scene as uploaded. `shape` is a volume without voxels: what the
   * camera code needs (dims, spacing) to resolve a camera. */
  int have_volume, have_tf;
  rp_volume shape;
  uint32_t blocks[3];
  uint64_t vol_id, tf_id;
  float ref_step;
  uint32_t lut_size;
  /* The reference device's own copies of the scene. */
  rp_volume *ref_vol;
  rp_tf ref_tf;
  uint8_t *ref_grid, *ref_alpha;
  /* The AO volume set for RP_EFFECT_AO renders: what it was computed
   * for, and its size on the device (0: none, and no AO memory). The
   * reference device keeps a copy in ref_ao. */
  uint64_t ao_vol_id, ao_tf_id, ao_bytes;
  rp_ao *ref_ao;
  /* The uploaded occupancy's box of occupied blocks. */
  uint32_t box_lo[3], box_end[3];
  /* The frame the device's current depth-pass result belongs to. */
  int depth_valid;
  rp_frame_params depth_params;
  uint64_t last_ns;
  /* rp_device_desc's testing knobs, and renders so far. */
  double slowdown;
  uint32_t fail_at_render, renders;
  uint32_t fail_at_ao, ao_jobs;
  uint32_t stall_at_render;
  double stall_ms;
  /* Out-of-core (rp_device_desc.budget_bytes): the host's bricks of the
   * volume, NULL while the whole volume is on the device. */
  uint64_t budget_bytes;
  uint32_t brick_size;
  rp__bricks *bricks;
  int table_sent; /* the pool's table is the host's */
  /* Renders alternate the order of their parts: the last part's bricks
   * are then the first the next frame needs. In the same order every
   * frame, least-recently-used replacement evicts exactly the bricks the
   * next part needs (the cyclic worst case: measured 45 % hits on
   * bonsai at half the volume, camera still). */
  int reverse_parts;
  rp_brick_stats brick_stats;
  double upload_ns_per_byte; /* measured on its uploads (smoothed) */
};

/* Upload rate assumed until a device has measured its own: 2 GB/s, a
 * host memcpy or a PCIe transfer, within a factor of a few either way. */
#define NOMINAL_UPLOAD_NS_PER_BYTE 0.5
/* Weight of the newest upload in the smoothed rate. */
#define UPLOAD_RATE_WEIGHT 0.25

const char *const *rp_backend_names(void) {
  static const char *names[sizeof registry / sizeof registry[0] + 1];
  size_t i;
  for (i = 0; registry[i] != NULL; i++)
    names[i] = registry[i]->name;
  names[i++] = REFERENCE;
  names[i] = NULL;
  return names;
}

static const rp_backend_bootstrap *find(const char *name) {
  size_t i;
  for (i = 0; registry[i] != NULL; i++)
    if (strcmp(registry[i]->name, name) == 0)
      return registry[i];
  return NULL;
}

static int unknown_backend(rp_context *ctx, const char *name) {
  char list[256] = "";
  const char *const *n;
  for (n = rp_backend_names(); *n != NULL; n++) {
    strncat(list, list[0] ? ", " : "", sizeof list - strlen(list) - 1);
    strncat(list, *n, sizeof list - strlen(list) - 1);
  }
  return rp__fail(ctx, RP_EINVAL, "backend '%s' is not compiled in; "
                  "available: %s", name, list);
}

int rp_device_count(rp_context *ctx, const char *backend, uint32_t *count) {
  const rp_backend_bootstrap *b;
  if (ctx == NULL)
    return RP_EINVAL;
  if (backend == NULL || count == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_device_count: backend and count "
                    "are required");
  if (strcmp(backend, REFERENCE) == 0) {
    *count = 1;
    return 0;
  }
  if ((b = find(backend)) == NULL)
    return unknown_backend(ctx, backend);
  *count = 0;
  if (b->probe(ctx, count) != 0)
    *count = 0; /* a failing probe means "no device", not an error */
  return 0;
}

static void reference_caps(rp_caps *caps) {
  memset(caps, 0, sizeof *caps);
  strcpy(caps->backend, REFERENCE);
  strcpy(caps->device, "scalar C reference (one thread)");
  caps->effects =
      RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_AO;
  caps->voxel_types = (1u << RP_U8) | (1u << RP_U16) | (1u << RP_F32);
  caps->global_mem_bytes = UINT64_MAX;
  caps->max_alloc_bytes = SIZE_MAX;
  caps->compute_units = 1;
}

/* A partition of `units` compute units (0: the whole device) is one
 * the backend can make of device `index`. */
static int check_units(rp_context *ctx, const rp_backend_bootstrap *b,
                       uint32_t index, uint32_t units) {
  uint32_t have = 0;
  int err;
  if (units == 0)
    return 0;
  if (b->partition_units == NULL)
    return rp__fail(ctx, RP_EUNSUPPORTED, "rp_device_create: backend '%s' "
                    "cannot partition a device (compute_units %u; 0 opens "
                    "the whole device)", b->name, units);
  if ((err = b->partition_units(ctx, index, &have)) != 0)
    return err;
  if (units > have)
    return rp__fail(ctx, RP_ERANGE, "rp_device_create: compute_units %u "
                    "exceeds the %u of %s device %u", units, have, b->name,
                    index);
  return 0;
}

static int open_backend(rp_context *ctx, const char *name, uint32_t index,
                        uint32_t units, const rp_backend_ops **ops,
                        void **impl, rp_caps *caps) {
  const rp_backend_bootstrap *b = find(name);
  uint32_t count = 0;
  int err;
  if (b == NULL)
    return unknown_backend(ctx, name);
  if (b->probe(ctx, &count) != 0 || index >= count)
    return rp__fail(ctx, RP_ENODEV, "backend '%s' has %u device(s) here; "
                    "index %u requested (driver missing?)", name, count,
                    index);
  if ((err = check_units(ctx, b, index, units)) != 0)
    return err;
  memset(caps, 0, sizeof *caps);
  err = b->create(ctx, index, units, ops, impl, caps);
  if (err != 0)
    return err;
  if (caps->backend[0] == '\0')
    strncpy(caps->backend, name, sizeof caps->backend - 1);
  return 0;
}

/* Device `index` of the named backend, or (name NULL) of the first
 * backend, in registry order, that has it, leaving out the named-only
 * ones. */
static int choose_backend(rp_context *ctx, const char *name, uint32_t index,
                          uint32_t units, const rp_backend_ops **ops,
                          void **impl, rp_caps *caps) {
  char tried[256] = "";
  int err = RP_ENODEV;
  size_t i;
  if (name != NULL)
    return open_backend(ctx, name, index, units, ops, impl, caps);
  for (i = 0; registry[i] != NULL && err != 0; i++) {
    uint32_t count = 0;
    if (named_only(registry[i]))
      continue;
    strncat(tried, tried[0] ? ", " : "", sizeof tried - strlen(tried) - 1);
    strncat(tried, registry[i]->name, sizeof tried - strlen(tried) - 1);
    if (registry[i]->probe(ctx, &count) == 0 && index < count)
      err = open_backend(ctx, registry[i]->name, index, units, ops, impl,
                         caps);
  }
  if (err == RP_ENODEV)
    rp__fail(ctx, RP_ENODEV, "no backend has device %u (tried: %s); "
             "name backend 'reference' for the scalar C renderer", index,
             tried[0] ? tried : "none compiled in");
  return err;
}

/* The backend name a desc asks for: its own, else RP_BACKEND, else NULL
 * (the first with a device). */
static const char *wanted_backend(const char *name) {
  if (name == NULL || name[0] == '\0') {
    name = getenv("RP_BACKEND");
    if (name != NULL && name[0] == '\0')
      name = NULL;
  }
  return name;
}

int rp__backend_open(rp_context *ctx, const char *name, uint32_t index,
                     const rp_backend_ops **ops, void **impl,
                     rp_caps *caps) {
  name = wanted_backend(name);
  if (name != NULL && strcmp(name, REFERENCE) == 0)
    return rp__fail(ctx, RP_EUNSUPPORTED, "backend 'reference' has no "
                    "backend ops (it renders from the camera, in double, "
                    "in the front end); name a backend with a device");
  if (name != NULL && find(name) != NULL && named_only(find(name)))
    return rp__fail(ctx, RP_EUNSUPPORTED, "backend '%s' cannot be opened "
                    "here: it stands for a device elsewhere", name);
  return choose_backend(ctx, name, index, 0, ops, impl, caps);
}

int rp_device_create(rp_context *ctx, const rp_device_desc *desc,
                     rp_device **out) {
  rp_device_desc d = {0};
  rp_device *dev;
  const char *name;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_device_create: out is required");
  if (desc != NULL)
    d = *desc;
  if (!(d.slowdown == 0.0 || (d.slowdown >= 1.0 && d.slowdown <= 1e4)))
    return rp__fail(ctx, isfinite(d.slowdown) ? RP_ERANGE : RP_ENOTFINITE,
                    "rp_device_create: slowdown %g is not 0 or in "
                    "[1, 10000]", d.slowdown);
  if (!(d.stall_ms >= 0.0 && d.stall_ms <= 60000.0))
    return rp__fail(ctx, isfinite(d.stall_ms) ? RP_ERANGE : RP_ENOTFINITE,
                    "rp_device_create: stall_ms %g is not in [0, 60000]",
                    d.stall_ms);
  if (d.brick_size != 0 &&
      (d.brick_size < RP__BRICK_MIN || d.brick_size > RP__BRICK_MAX ||
       (d.brick_size & (d.brick_size - 1)) != 0))
    return rp__fail(ctx, RP_ERANGE, "rp_device_create: brick_size %u is "
                    "not a power of two in [%u, %u]", d.brick_size,
                    RP__BRICK_MIN, RP__BRICK_MAX);
  name = wanted_backend(d.backend);
  dev = rp__calloc(ctx, 1, sizeof *dev);
  if (dev == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_device_create: out of memory");
  dev->ctx = ctx;
  dev->slowdown = d.slowdown;
  dev->fail_at_render = d.fail_at_render;
  dev->fail_at_ao = d.fail_at_ao;
  dev->stall_at_render = d.stall_at_render;
  dev->stall_ms = d.stall_ms;
  dev->budget_bytes = d.budget_bytes;
  dev->upload_ns_per_byte = NOMINAL_UPLOAD_NS_PER_BYTE;
  dev->brick_size = d.brick_size != 0 ? d.brick_size : RP__BRICK_DEFAULT;
  if (name != NULL && strcmp(name, REFERENCE) == 0) {
    if (d.budget_bytes != 0) {
      rp__free(ctx, dev);
      return rp__fail(ctx, RP_EUNSUPPORTED, "rp_device_create: backend "
                      "'reference' holds the whole volume; it takes no "
                      "memory budget (budget_bytes %llu)",
                      (unsigned long long)d.budget_bytes);
    }
    if (d.index != 0) {
      rp__free(ctx, dev);
      return rp__fail(ctx, RP_ENODEV, "backend 'reference' has one device; "
                      "index %u requested", d.index);
    }
    if (d.compute_units != 0) {
      rp__free(ctx, dev);
      return rp__fail(ctx, RP_EUNSUPPORTED, "rp_device_create: backend "
                      "'reference' cannot partition its device "
                      "(compute_units %u; it runs on one thread)",
                      d.compute_units);
    }
    reference_caps(&dev->caps);
    err = 0;
  } else {
    err = choose_backend(ctx, name, d.index, d.compute_units, &dev->ops,
                         &dev->impl, &dev->caps);
  }
  if (err != 0) {
    rp__free(ctx, dev);
    return err;
  }
  *out = dev;
  return 0;
}

static void drop_reference_scene(rp_device *dev) {
  rp_volume_destroy(dev->ref_vol);
  dev->ref_vol = NULL;
  rp__free(dev->ctx, dev->ref_tf.lut);
  dev->ref_tf.lut = NULL;
  rp__free(dev->ctx, dev->ref_grid);
  rp__free(dev->ctx, dev->ref_alpha);
  dev->ref_grid = dev->ref_alpha = NULL;
  rp_ao_destroy(dev->ref_ao);
  dev->ref_ao = NULL;
}

void rp_device_destroy(rp_device *dev) {
  if (dev == NULL)
    return;
  if (dev->ops != NULL)
    dev->ops->destroy(dev->impl);
  rp__bricks_destroy(dev->bricks);
  drop_reference_scene(dev);
  rp__free(dev->ctx, dev);
}

void rp_device_get_caps(const rp_device *dev, rp_caps *caps) {
  if (dev != NULL && caps != NULL)
    *caps = dev->caps;
}

uint64_t rp_device_last_time_ns(const rp_device *dev) {
  return dev != NULL ? dev->last_ns : 0;
}

/* Reads only what is fixed at create (ops, impl): another thread may be
 * running the device meanwhile, so the front end's scene fields are not
 * this call's to look at; the backend checks its own state under its
 * lock. */
int rp__device_builds_ahead(const rp_device *dev) {
  return dev->ops != NULL && dev->ops->prepare != NULL;
}

int rp__device_clock_ns(const rp_device *dev, uint64_t *ns) {
  (void)dev;
  (void)ns;
  return 0; /* no backend here keeps a clock of its own yet */
}

int rp_device_prepare(rp_device *dev, rp_context *ctx, uint32_t effects) {
  if (dev == NULL || ctx == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_device_prepare: NULL %s",
                    dev == NULL ? "device" : "context");
  if (effects & ~(uint32_t)RP__KNOWN_EFFECTS)
    return rp__fail(ctx, RP_EINVAL, "rp_device_prepare: unknown effect "
                    "bits 0x%x", effects);
  if (dev->ops == NULL || dev->ops->prepare == NULL)
    return 0;
  return dev->ops->prepare(dev->impl, ctx, effects);
}

static void sleep_ns(uint64_t ns) {
  struct timespec ts;
  ts.tv_sec = (time_t)(ns / 1000000000u);
  ts.tv_nsec = (long)(ns % 1000000000u);
  while (nanosleep(&ts, &ts) != 0)
    ; /* interrupted by a signal: sleep the rest */
}

/* An operation's device time, `ns`; a slowed device (rp_device_desc's
 * slowdown) then waits the difference, so wall time and reported time
 * both stretch as a slower device's would. */
static void record_ns(rp_device *dev, uint64_t ns) {
  dev->last_ns = ns;
  if (dev->slowdown > 1.0) {
    double extra = (dev->slowdown - 1.0) * (double)dev->last_ns;
    sleep_ns((uint64_t)extra);
    dev->last_ns += (uint64_t)extra;
  }
}

/* The last operation's device time (the backend's, or the reference's
 * wall time since `start`). */
static void record_time(rp_device *dev, uint64_t start) {
  record_ns(dev, dev->ops != NULL ? dev->ops->last_time_ns(dev->impl)
                                  : rp__now_ns() - start);
}

/* rp_device_desc's stall, on its render. */
static void injected_stall(rp_device *dev) {
  uint64_t ns;
  if (dev->stall_at_render == 0 || dev->renders != dev->stall_at_render)
    return;
  ns = (uint64_t)(dev->stall_ms * 1e6);
  sleep_ns(ns);
  dev->last_ns += ns;
}

/* Frees the device's AO memory (backend buffer or reference copy). */
static int release_ao(rp_device *dev) {
  int err = 0;
  if (dev->ops != NULL && dev->ao_bytes != 0)
    err = dev->ops->upload_ao(dev->impl, NULL);
  rp_ao_destroy(dev->ref_ao);
  dev->ref_ao = NULL;
  dev->ao_bytes = 0;
  return err;
}

/* ---- Out-of-core ----------------------------------------------------------- */

static int prepare_frame(rp_device *dev, const char *fn,
                         const rp_camera *cam, const rp_render_desc *desc,
                         rp_render_desc *d, rp__raygen *rg,
                         rp_frame_params *p);
static int prepare_region(rp_device *dev, const char *fn,
                          const rp_camera *cam, const rp_render_desc *desc,
                          const rp_region *region, rp_render_desc *d,
                          rp__raygen *rg, rp_frame_params *p,
                          rp_region *r);

/* What the volume may take on the device. */
static uint64_t device_budget(const rp_device *dev) {
  uint64_t b = dev->budget_bytes != 0 ? dev->budget_bytes
                                      : dev->caps.max_alloc_bytes;
  return b < dev->caps.max_alloc_bytes ? b : dev->caps.max_alloc_bytes;
}

/* Bytes a backend may add to the pool buffer past its bricks. */
#define RP__POOL_PAD 64u

/* AO reads and darkens the whole volume: not built for bricks. */
static int out_of_core_ao(rp_device *dev, const char *fn) {
  return rp__fail(dev->ctx, RP_EUNSUPPORTED, "%s: device '%s' (%s) holds "
                  "its volume as bricks (out of core, budget %llu bytes); "
                  "ambient occlusion needs the whole volume on the device",
                  fn, dev->caps.device, dev->caps.backend,
                  (unsigned long long)device_budget(dev));
}

/* A volume larger than the budget: bricks on the host, a pool of as many
 * as the budget holds on the device. A failure before the pool is set
 * changes nothing; a backend whose pool could not be set holds no volume
 * any more (it dropped the old one first), and the device says so. */
static int set_bricked_volume(rp_device *dev, const rp_volume *vol,
                              size_t bytes) {
  rp_context *ctx = dev->ctx;
  rp__bricks *b = NULL;
  rp_brick_pool pool;
  uint64_t budget = device_budget(dev), slots, count;
  size_t brick = rp__bricks_stored_bytes(dev->brick_size, vol->type);
  int err;
  if (dev->ops->set_brick_pool == NULL || dev->ops->upload_bricks == NULL)
    return rp__fail(ctx, RP_EUNSUPPORTED, "rp_device_set_volume: %zu bytes "
                    "exceed the budget of %llu bytes, and backend '%s' "
                    "cannot hold a volume as bricks", bytes,
                    (unsigned long long)budget, dev->caps.backend);
  memset(&pool, 0, sizeof pool);
  rp__bricks_grid(vol->dims, dev->brick_size, pool.grid);
  count = (uint64_t)pool.grid[0] * pool.grid[1] * pool.grid[2];
  slots = budget / brick;
  /* The pool is one buffer, and backends pad theirs by a few bytes
   * (OpenCL 16 for vector loads): keep it under the largest buffer even
   * when the budget is exactly that size (the default). */
  if (slots * brick + RP__POOL_PAD > dev->caps.max_alloc_bytes)
    slots = dev->caps.max_alloc_bytes > RP__POOL_PAD
                ? (dev->caps.max_alloc_bytes - RP__POOL_PAD) / brick
                : 0;
  /* Slot 0 is the transparent one; more slots than bricks is waste. */
  if (slots > count + 1)
    slots = count + 1;
  if (slots < 2)
    return rp__fail(ctx, RP_ENOMEM, "rp_device_set_volume: a budget of "
                    "%llu bytes holds %llu bricks of %zu bytes (%u^3 voxels "
                    "and a border); out-of-core rendering needs at least 2 "
                    "(a larger budget or a smaller brick_size)",
                    (unsigned long long)budget, (unsigned long long)slots,
                    brick, dev->brick_size);
  if (count > UINT32_MAX / 2)
    return rp__fail(ctx, RP_ERANGE, "rp_device_set_volume: %llu bricks "
                    "of %u^3 voxels are too many (a larger brick_size)",
                    (unsigned long long)count, dev->brick_size);
  if ((err = rp__bricks_create(ctx, vol, dev->brick_size, (uint32_t)slots,
                               &b)) != 0)
    return err;
  pool.type = vol->type;
  memcpy(pool.dims, vol->dims, sizeof pool.dims);
  pool.brick_size = dev->brick_size;
  pool.slots = (uint32_t)slots;
  if ((err = dev->ops->set_brick_pool(dev->impl, &pool)) != 0) {
    rp__bricks_destroy(b);
    rp__bricks_destroy(dev->bricks);
    dev->bricks = NULL;
    dev->have_volume = dev->have_tf = 0;
    dev->depth_valid = 0;
    return err;
  }
  rp__bricks_destroy(dev->bricks);
  dev->bricks = b;
  dev->table_sent = 0;
  return 0;
}

int rp_device_get_brick_stats(const rp_device *dev, rp_brick_stats *out) {
  rp__bricks_info info;
  if (dev == NULL || out == NULL)
    return RP_EINVAL;
  *out = dev->brick_stats;
  out->out_of_core = dev->bricks != NULL;
  if (dev->bricks == NULL)
    return 0;
  rp__bricks_get_info(dev->bricks, &info);
  out->brick_size = info.brick_size;
  out->bricks = info.count;
  out->visible = info.visible;
  out->slots = info.slots;
  out->resident = info.resident;
  out->hits = info.hits;
  out->misses = info.misses;
  out->evictions = info.evictions;
  return 0;
}

/* Makes the bricks `r` needs resident and raycasts it; *ns and the
 * stats gain the device time of both. */
static int render_piece(rp_device *dev, const rp_frame_params *p,
                        const rp_region *r, uint8_t *rgba,
                        rp_tile_stats *tiles, uint64_t *fetches,
                        uint64_t *ns) {
  rp__bricks *b = dev->bricks;
  int changed, err;
  uint32_t n;
  const void *fill = rp__bricks_fill(b, &changed);
  if (changed) {
    static const uint32_t slot0 = 0;
    if ((err = dev->ops->upload_bricks(dev->impl, 1, &slot0, &fill,
                                       NULL)) != 0)
      return err;
    rp__bricks_fill_sent(b);
    *ns += dev->ops->last_time_ns(dev->impl);
  }
  rp__bricks_admit(b);
  n = rp__bricks_upload_count(b);
  if (n > 0 || !dev->table_sent) {
    uint64_t t;
    if ((err = dev->ops->upload_bricks(dev->impl, n,
                                       rp__bricks_upload_slots(b),
                                       rp__bricks_upload_data(b),
                                       rp__bricks_table(b))) != 0) {
      /* Which writes landed is unknown: start the pool over. */
      rp__bricks_forget(b);
      dev->table_sent = 0;
      return err;
    }
    dev->table_sent = 1;
    t = dev->ops->last_time_ns(dev->impl);
    *ns += t;
    dev->brick_stats.last_upload_ns += t;
    dev->brick_stats.last_upload_bytes += (uint64_t)n * rp__bricks_stored_bytes(
        dev->brick_size, dev->shape.type);
  }
  if ((err = dev->ops->raycast(dev->impl, p, r, rgba, tiles, fetches)) != 0)
    return err;
  *ns += dev->ops->last_time_ns(dev->impl);
  dev->brick_stats.last_pieces++;
  if (p->slab_flags != (RP_SLAB_FIRST | RP_SLAB_LAST))
    dev->brick_stats.last_slabs++;
  return 0;
}

/* One part of an out-of-core region: pixels, and the depth slab of their
 * rays (slab_cut +inf and both flags: the whole rays). The pool's needed
 * list is the part's when fn is called. */
typedef struct part {
  rp_region r;
  float slab_cut;
  uint32_t slab_flags;
} part;

typedef int (*part_fn)(rp_device *dev, const part *pt, void *user);

/* Slabs of one tile at most: a tile needing more passes than this is
 * refused rather than rendered at a crawl. */
#define MAX_SLABS 64

/* A tile whose bricks do not fit the pool: its rays in depth slabs. */
static int for_each_slab(rp_device *dev, const rp_region *r, uint32_t need,
                         uint32_t cap, part_fn fn, void *user) {
  float cuts[MAX_SLABS], t0 = -INFINITY;
  uint32_t n = 0, k, worst = 0;
  int err;
  if (rp__bricks_slabs(dev->bricks, cap, cuts, MAX_SLABS, &n, &worst) != 0)
    return rp__fail(dev->ctx, RP_ENOMEM, "rp_device_render: the pixels "
                    "[%u,%u)x[%u,%u) need %u bricks, %s, and the pool holds "
                    "%u (budget %llu bytes, bricks of %zu bytes): a larger "
                    "budget or a smaller brick_size", r->x0, r->x1, r->y0,
                    r->y1, need, worst > cap ? "more than that at one depth"
                                             : "in more than 64 depth slabs",
                    cap, (unsigned long long)device_budget(dev),
                    rp__bricks_stored_bytes(dev->brick_size,
                                            dev->shape.type));
  for (k = 0; k < n; k++) {
    part pt;
    pt.r = *r;
    pt.slab_cut = cuts[k];
    pt.slab_flags = (k == 0 ? RP_SLAB_FIRST : 0u) |
                    (k + 1 == n ? RP_SLAB_LAST : 0u);
    rp__bricks_slab_needed(dev->bricks, t0, cuts[k]);
    if ((err = fn(dev, &pt, user)) != 0)
      return err;
    t0 = cuts[k];
  }
  return 0;
}

/* Cuts `region` into halves (on the tile grid, across the longer side)
 * until each part's bricks fit the pool, a tile that still does not fit
 * into depth slabs, and calls fn on the parts in order, or in reverse
 * order with dev->reverse_parts: the plan a render follows and an
 * estimate simulates. Call rp__bricks_frame first. */
static int for_each_part(rp_device *dev, const rp_region *region, part_fn fn,
                         void *user) {
  /* Depth-first halving keeps at most one pending part per level, and
   * a level at least halves a side of at most 2^32 pixels. */
  rp_region stack[2 * 32 + 2];
  uint32_t depth = 0, cap;
  rp__bricks_info info;
  rp__bricks_get_info(dev->bricks, &info);
  cap = info.slots - 1;
  stack[depth++] = *region;
  while (depth > 0) {
    rp_region r = stack[--depth], lo, hi;
    uint32_t w = r.x1 - r.x0, h = r.y1 - r.y0, need, cut;
    int err;
    need = rp__bricks_needed(dev->bricks, &r);
    if (need <= cap) {
      part pt;
      pt.r = r;
      pt.slab_cut = INFINITY;
      pt.slab_flags = RP_SLAB_FIRST | RP_SLAB_LAST;
      if ((err = fn(dev, &pt, user)) != 0)
        return err;
      continue;
    }
    if (w <= RP_TILE_SIZE && h <= RP_TILE_SIZE) {
      if ((err = for_each_slab(dev, &r, need, cap, fn, user)) != 0)
        return err;
      continue;
    }
    lo = hi = r;
    if (w >= h && w > RP_TILE_SIZE) {
      cut = r.x0 + (w / 2 + RP_TILE_SIZE - 1) / RP_TILE_SIZE * RP_TILE_SIZE;
      if (cut >= r.x1)
        cut = r.x0 + RP_TILE_SIZE;
      lo.x1 = hi.x0 = cut;
    } else {
      cut = r.y0 + (h / 2 + RP_TILE_SIZE - 1) / RP_TILE_SIZE * RP_TILE_SIZE;
      if (cut >= r.y1)
        cut = r.y0 + RP_TILE_SIZE;
      lo.y1 = hi.y0 = cut;
    }
    stack[depth++] = dev->reverse_parts ? lo : hi;
    stack[depth++] = dev->reverse_parts ? hi : lo;
  }
  return 0;
}

typedef struct render_job {
  const rp_frame_params *p;
  uint8_t *rgba;
  rp_tile_stats *tiles;
  uint64_t *fetches;
  uint64_t ns;
} render_job;

static int render_part(rp_device *dev, const part *pt, void *user) {
  render_job *j = user;
  rp_frame_params p = *j->p;
  p.slab_cut = pt->slab_cut;
  p.slab_flags = pt->slab_flags;
  return render_piece(dev, &p, &pt->r, j->rgba, j->tiles, j->fetches,
                      &j->ns);
}

/* Raycasts `region` out of core, part by part (for_each_part). */
static int render_bricked(rp_device *dev, const rp__raygen *rg,
                          const rp_frame_params *p, const rp_region *region,
                          uint8_t *rgba, rp_tile_stats *tiles,
                          uint64_t *fetches, uint64_t *ns) {
  render_job j;
  int err;
  j.p = p;
  j.rgba = rgba;
  j.tiles = tiles;
  j.fetches = fetches;
  j.ns = 0;
  rp__bricks_frame(dev->bricks, rg, (p->effects & RP_EFFECT_SHADING) != 0);
  dev->brick_stats.last_pieces = dev->brick_stats.last_slabs = 0;
  dev->brick_stats.last_upload_bytes = 0;
  dev->brick_stats.last_upload_ns = 0;
  err = for_each_part(dev, region, render_part, &j);
  dev->reverse_parts = !dev->reverse_parts;
  *ns = j.ns;
  dev->brick_stats.uploaded_bytes += dev->brick_stats.last_upload_bytes;
  dev->brick_stats.upload_ns += dev->brick_stats.last_upload_ns;
  if (err != 0)
    return err;
  /* Large uploads only: a few bricks measure the call, not the rate. */
  if (dev->brick_stats.last_upload_bytes >= (1u << 20)) {
    double rate = (double)dev->brick_stats.last_upload_ns /
                  (double)dev->brick_stats.last_upload_bytes;
    dev->upload_ns_per_byte =
        dev->brick_stats.uploaded_bytes == dev->brick_stats.last_upload_bytes
            ? rate
            : (1.0 - UPLOAD_RATE_WEIGHT) * dev->upload_ns_per_byte +
                  UPLOAD_RATE_WEIGHT * rate;
  }
  return 0;
}

/* An estimate's part: admit its bricks in the dry run, count uploads. */
static int count_part(rp_device *dev, const part *pt, void *user) {
  (void)pt;
  rp__bricks_admit(dev->bricks);
  *(uint32_t *)user += rp__bricks_upload_count(dev->bricks);
  return 0;
}

int rp_device_upload_estimate(rp_device *dev, const rp_camera *cam,
                              const rp_render_desc *desc,
                              const rp_region *region,
                              rp_upload_estimate *out) {
  rp_render_desc d = {0};
  rp__raygen rg = {0};
  rp_frame_params p = {0};
  rp_region r;
  uint32_t uploads = 0;
  int err;
  if (dev == NULL)
    return RP_EINVAL;
  if (out == NULL)
    return rp__fail(dev->ctx, RP_EINVAL, "rp_device_upload_estimate: out "
                    "is NULL");
  memset(out, 0, sizeof *out);
  if ((err = prepare_region(dev, "rp_device_upload_estimate", cam, desc,
                            region, &d, &rg, &p, &r)) != 0)
    return err;
  if (dev->bricks == NULL)
    return 0;
  rp__bricks_frame(dev->bricks, &rg, (d.effects & RP_EFFECT_SHADING) != 0);
  out->bricks = rp__bricks_needed(dev->bricks, &r);
  /* The render's own plan, run on a copy of the pool's bookkeeping: the
   * bricks it would load, a brick loaded by two parts twice. */
  rp__bricks_checkpoint(dev->bricks);
  err = for_each_part(dev, &r, count_part, &uploads);
  rp__bricks_rollback(dev->bricks);
  if (err != 0)
    return err;
  out->loads = uploads;
  out->bytes = (uint64_t)uploads *
               rp__bricks_stored_bytes(dev->brick_size, dev->shape.type);
  out->ms = (double)out->bytes * dev->upload_ns_per_byte * 1e-6;
  if (dev->slowdown > 1.0)
    out->ms *= dev->slowdown;
  return 0;
}

int rp_device_set_volume(rp_device *dev, const rp_volume *vol) {
  rp_context *ctx;
  size_t bytes;
  int err, a;
  uint64_t t0 = rp__now_ns();
  if (dev == NULL)
    return RP_EINVAL;
  ctx = dev->ctx;
  if (vol == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_device_set_volume: vol is NULL");
  if (!(dev->caps.voxel_types & (1u << vol->type)))
    return rp__fail(ctx, RP_EUNSUPPORTED, "rp_device_set_volume: device "
                    "'%s' cannot hold %s voxels", dev->caps.device,
                    rp_voxel_type_name(vol->type));
  bytes = vol->voxel_count * rp__voxel_size(vol->type);
  if (dev->ops != NULL && bytes > device_budget(dev)) {
    err = set_bricked_volume(dev, vol, bytes);
  } else if (dev->ops != NULL) {
    err = dev->ops->upload_volume(dev->impl, vol);
    if (err == 0) {
      rp__bricks_destroy(dev->bricks);
      dev->bricks = NULL;
    }
  } else {
    rp_volume_desc d = {0};
    rp_volume *copy = NULL;
    for (a = 0; a < 3; a++) {
      d.dims[a] = vol->dims[a];
      d.spacing[a] = vol->spacing[a];
    }
    d.type = vol->type;
    d.data = vol->data;
    err = rp_volume_create(ctx, &d, &copy);
    if (err == 0) {
      rp_volume_destroy(dev->ref_vol);
      dev->ref_vol = copy;
    }
  }
  if (err != 0)
    return err;
  /* A new volume invalidates the TF upload (occupancy is per volume) and
   * the AO volume, whose memory goes with it. */
  (void)release_ao(dev); /* a release cannot fail */
  memset(&dev->brick_stats, 0, sizeof dev->brick_stats);
  dev->have_volume = 1;
  dev->have_tf = 0;
  dev->depth_valid = 0;
  dev->vol_id = vol->id;
  dev->shape = *vol;
  dev->shape.data = NULL;
  dev->shape.ctx = ctx;
  for (a = 0; a < 3; a++)
    dev->blocks[a] = rp__blocks_along(vol->dims[a]);
  record_time(dev, t0);
  return 0;
}

int rp_device_set_tf(rp_device *dev, const rp_tf *tf,
                     const rp_occupancy *occ) {
  rp_context *ctx;
  uint32_t nb;
  int err;
  uint64_t t0 = rp__now_ns();
  if (dev == NULL)
    return RP_EINVAL;
  ctx = dev->ctx;
  if (tf == NULL || occ == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_device_set_tf: tf and occ are "
                    "required");
  if (!dev->have_volume)
    return rp__fail(ctx, RP_ESTATE, "rp_device_set_tf: no volume on the "
                    "device yet (rp_device_set_volume first)");
  if ((err = rp__occupancy_check(ctx, "rp_device_set_tf", occ, tf->id,
                                 dev->vol_id)) != 0)
    return err;
  nb = occ->h->block_count;
  if (dev->ops != NULL) {
    err = dev->ops->upload_tf(dev->impl, tf->lut, (uint32_t)tf->lut_size);
    if (err == 0)
      err = dev->ops->upload_occupancy(dev->impl, occ->grid, occ->alpha_hist,
                                       occ->h->blocks);
  } else {
    float *lut = rp__malloc(ctx, (size_t)tf->lut_size * 4 * sizeof(float));
    uint8_t *grid = rp__malloc(ctx, nb);
    uint8_t *alpha = rp__malloc(ctx, (size_t)nb * RP_OPACITY_BINS);
    err = 0;
    if (lut == NULL || grid == NULL || alpha == NULL) {
      rp__free(ctx, lut);
      rp__free(ctx, grid);
      rp__free(ctx, alpha);
      err = rp__fail(ctx, RP_ENOMEM, "rp_device_set_tf: out of memory");
    } else {
      memcpy(lut, tf->lut, (size_t)tf->lut_size * 4 * sizeof(float));
      memcpy(grid, occ->grid, nb);
      memcpy(alpha, occ->alpha_hist, (size_t)nb * RP_OPACITY_BINS);
      rp__free(ctx, dev->ref_tf.lut);
      rp__free(ctx, dev->ref_grid);
      rp__free(ctx, dev->ref_alpha);
      dev->ref_tf = *tf;
      dev->ref_tf.lut = lut;
      dev->ref_grid = grid;
      dev->ref_alpha = alpha;
    }
  }
  if (err != 0) {
    dev->have_tf = 0; /* a half-done upload must not be rendered with */
    return err;
  }
  dev->have_tf = 1;
  if (dev->bricks != NULL)
    rp__bricks_set_tf(dev->bricks, tf);
  memcpy(dev->box_lo, occ->box_lo, sizeof dev->box_lo);
  memcpy(dev->box_end, occ->box_end, sizeof dev->box_end);
  dev->depth_valid = 0;
  dev->tf_id = tf->id;
  dev->ref_step = tf->reference_step;
  dev->lut_size = (uint32_t)tf->lut_size;
  record_time(dev, t0);
  return 0;
}

int rp__frame_params(rp_context *ctx, const rp_volume *shape,
                     const rp_occupancy *occ, const rp_camera *cam,
                     const rp_render_desc *d, float ref_step,
                     uint32_t lut_size, rp__raygen *rg, rp_frame_params *p) {
  int err, a;
  if ((err = rp__raygen_init(ctx, cam, shape, d->width, d->height, rg)) != 0)
    return err;
  rp_scaled_size(d, &rg->width, &rg->height);
  memset(p, 0, sizeof *p);
  for (a = 0; a < 3; a++) {
    p->eye[a] = (float)rg->eye[a];
    p->f[a] = (float)rg->f[a];
    p->r[a] = (float)rg->r[a];
    p->u[a] = (float)rg->u[a];
    p->dims[a] = (float)rg->dims[a];
    p->inv_spacing[a] = (float)(1.0 / rg->spacing[a]);
    p->idims[a] = shape->dims[a];
    p->blocks[a] = rp__blocks_along(shape->dims[a]);
    p->occupied_lo[a] = occ != NULL ? occ->box_lo[a] : 0u;
    p->occupied_end[a] = occ != NULL ? occ->box_end[a] : p->blocks[a];
  }
  p->half_w = (float)rg->half_w;
  p->half_h = (float)rg->half_h;
  p->ortho = rg->ortho;
  p->width = rg->width;
  p->height = rg->height;
  p->min_spacing = (float)rg->min_spacing;
  p->step = d->step;
  p->ref_step = ref_step;
  p->ert_threshold = d->ert_threshold;
  p->effects = d->effects;
  p->value_min = (float)shape->min;
  p->value_max = (float)shape->max;
  p->lut_size = lut_size;
  return 0;
}

/* The checks every frame operation shares, then the camera resolved for
 * the scaled image and its float form for the kernels. */
static int prepare_frame(rp_device *dev, const char *fn,
                         const rp_camera *cam, const rp_render_desc *desc,
                         rp_render_desc *d, rp__raygen *rg,
                         rp_frame_params *p) {
  rp_context *ctx = dev->ctx;
  int err;
  uint32_t unsupported;
  if (cam == NULL || desc == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: cam and desc are required", fn);
  if (!dev->have_volume || !dev->have_tf)
    return rp__fail(ctx, RP_ESTATE, "%s: the device has no %s yet", fn,
                    dev->have_volume ? "transfer function (rp_device_set_tf)"
                                     : "volume (rp_device_set_volume)");
  *d = rp__render_desc_defaults(desc);
  if ((err = rp__check_render_desc(ctx, fn, d)) != 0)
    return err;
  unsupported = d->effects & ~dev->caps.effects;
  if (unsupported != 0)
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: device '%s' (%s) cannot "
                    "render effects 0x%x", fn, dev->caps.device,
                    dev->caps.backend, (unsigned)unsupported);
  if ((err = rp__frame_params(ctx, &dev->shape, NULL, cam, d, dev->ref_step,
                              dev->lut_size, rg, p)) != 0)
    return err;
  memcpy(p->occupied_lo, dev->box_lo, sizeof dev->box_lo);
  memcpy(p->occupied_end, dev->box_end, sizeof dev->box_end);
  if (dev->bricks != NULL) {
    rp__bricks_info info;
    rp__bricks_get_info(dev->bricks, &info);
    for (p->brick_shift = 0; (1u << p->brick_shift) < info.brick_size;
         p->brick_shift++)
      ;
    memcpy(p->brick_grid, info.grid, sizeof p->brick_grid);
    /* One pass, unless render_bricked cuts a tile into depth slabs. */
    p->slab_cut = INFINITY;
    p->slab_flags = RP_SLAB_FIRST | RP_SLAB_LAST;
  }
  return 0;
}

/* Whether the device's depth result is the one `p` needs: everything
 * but the ERT stream, the ERT threshold and the step shapes it (D_front
 * and D_back are block-grid geometry), so a frame that only retunes its
 * step reuses the depth pass. */
static int same_depth_frame(const rp_frame_params *a,
                            const rp_frame_params *b) {
  rp_frame_params x = *a, y = *b;
  x.step = y.step = 0.0f;
  x.ert_seed = y.ert_seed = 0;
  x.frame = y.frame = 0;
  x.ert_threshold = y.ert_threshold = 0;
  x.effects &= RP_EFFECT_SKIP;
  y.effects &= RP_EFFECT_SKIP;
  return memcmp(&x, &y, sizeof x) == 0;
}

static void reference_depth(const rp_device *dev, const rp__raygen *rg,
                            const rp_render_desc *d, float *front_back) {
  const uint8_t *grid = (d->effects & RP_EFFECT_SKIP) ? dev->ref_grid : NULL;
  uint32_t x, y;
  for (y = 0; y < rg->height; y++)
    for (x = 0; x < rg->width; x++) {
      rp__ray ray;
      double f, b;
      size_t i = ((size_t)y * rg->width + x) * 2;
      rp__raygen_ray(rg, x, y, &ray);
      rp__depth_ray(&ray, rg->dims, grid, dev->blocks, &f, &b);
      front_back[i] = (float)f;
      front_back[i + 1] = (float)b;
    }
}

int rp_device_depth_pass(rp_device *dev, const rp_camera *cam,
                         const rp_render_desc *desc, float *front_back) {
  rp_render_desc d = {0};
  rp__raygen rg = {0};
  rp_frame_params p = {0};
  uint64_t t0 = rp__now_ns();
  int err;
  if (dev == NULL)
    return RP_EINVAL;
  if ((err = prepare_frame(dev, "rp_device_depth_pass", cam, desc, &d, &rg,
                           &p)) != 0)
    return err;
  if (dev->ops != NULL) {
    err = dev->ops->depth_pass(dev->impl, &p, front_back);
  } else if (front_back != NULL) {
    /* The reference raycast derives its own skipping range per ray, so
     * its depth pass is only ever computed to be looked at. */
    reference_depth(dev, &rg, &d, front_back);
  }
  if (err != 0) {
    dev->depth_valid = 0;
    return err;
  }
  dev->depth_valid = 1;
  dev->depth_params = p;
  record_time(dev, t0);
  return 0;
}

int rp_device_ert_prepass(rp_device *dev, const rp_camera *cam,
                          const rp_render_desc *desc, uint32_t seed,
                          uint32_t frame, float *d_ert) {
  rp_render_desc d = {0};
  rp__raygen rg = {0};
  rp_frame_params p = {0};
  uint64_t t0 = rp__now_ns();
  int err;
  if (dev == NULL)
    return RP_EINVAL;
  if (d_ert == NULL)
    return rp__fail(dev->ctx, RP_EINVAL, "rp_device_ert_prepass: d_ert is "
                    "NULL");
  if ((err = prepare_frame(dev, "rp_device_ert_prepass", cam, desc, &d, &rg,
                           &p)) != 0)
    return err;
  p.ert_seed = seed;
  p.frame = frame;
  if (dev->ops != NULL)
    err = dev->ops->ert_prepass(dev->impl, &p, d_ert);
  else
    rp__ert_prepass(&rg, dev->ref_grid, dev->ref_alpha, dev->blocks,
                    dev->ref_step, d.ert_threshold, seed, frame, d_ert);
  if (err != 0)
    return err;
  record_time(dev, t0);
  return 0;
}

static int check_region(rp_context *ctx, const char *fn, const rp_region *r,
                        uint32_t w, uint32_t h) {
  if (!(r->x0 < r->x1 && r->x1 <= w && r->y0 < r->y1 && r->y1 <= h))
    return rp__fail(ctx, RP_EINVAL, "%s: region [%u,%u)x[%u,%u) is "
                    "empty or outside the %ux%u scaled image", fn, r->x0,
                    r->x1, r->y0, r->y1, w, h);
  if (r->x0 % RP_TILE_SIZE || r->y0 % RP_TILE_SIZE ||
      (r->x1 % RP_TILE_SIZE && r->x1 != w) ||
      (r->y1 % RP_TILE_SIZE && r->y1 != h))
    return rp__fail(ctx, RP_EINVAL, "%s: region [%u,%u)x[%u,%u) has a "
                    "corner off the 8x8 tile grid", fn, r->x0, r->x1, r->y0,
                    r->y1);
  return 0;
}

/* prepare_frame, then the region: `region` checked, or the whole scaled
 * image when NULL, into *r. */
static int prepare_region(rp_device *dev, const char *fn,
                          const rp_camera *cam, const rp_render_desc *desc,
                          const rp_region *region, rp_render_desc *d,
                          rp__raygen *rg, rp_frame_params *p,
                          rp_region *r) {
  int err;
  if ((err = prepare_frame(dev, fn, cam, desc, d, rg, p)) != 0)
    return err;
  if (region == NULL) {
    r->x0 = r->y0 = 0;
    r->x1 = rg->width;
    r->y1 = rg->height;
    return 0;
  }
  *r = *region;
  return check_region(dev->ctx, fn, region, rg->width, rg->height);
}

int rp__device_render(rp_device *dev, const rp_camera *cam,
                      const rp_render_desc *desc, const rp_region *region,
                      uint8_t *rgba, rp_tile_stats *tiles,
                      uint64_t *fetches) {
  rp_render_desc d = {0};
  rp__raygen rg = {0};
  rp_frame_params p = {0};
  rp_region all;
  uint64_t t0;
  int err;
  if (dev == NULL)
    return RP_EINVAL;
  if (rgba == NULL)
    return rp__fail(dev->ctx, RP_EINVAL, "rp_device_render: rgba is NULL");
  if ((err = prepare_region(dev, "rp_device_render", cam, desc, region, &d,
                            &rg, &p, &all)) != 0)
    return err;
  region = &all;
  if ((d.effects & RP_EFFECT_AO) && dev->bricks != NULL)
    return out_of_core_ao(dev, "rp_device_render");
  if ((d.effects & RP_EFFECT_AO) &&
      (dev->ao_bytes == 0 || dev->ao_vol_id != dev->vol_id ||
       dev->ao_tf_id != dev->tf_id))
    return rp__fail(dev->ctx, RP_ESTATE, "rp_device_render: RP_EFFECT_AO "
                    "needs an AO volume computed for the device's current "
                    "volume and transfer function (rp_device_set_ao): %s",
                    dev->ao_bytes == 0 ? "none is set"
                                       : "the one set is for another");
  dev->renders++;
  if (dev->fail_at_render != 0 && dev->renders >= dev->fail_at_render)
    return rp__fail(dev->ctx, RP_EDEVICE, "rp_device_render: device '%s' "
                    "(%s) failed (injected at render %u)", dev->caps.device,
                    dev->caps.backend, dev->fail_at_render);
  t0 = rp__now_ns();
  if (dev->ops == NULL) {
    rp_volume ao_view;
    if (dev->ref_ao != NULL)
      rp__ao_view(dev->ref_ao, &ao_view);
    rp__reference_render(dev->ref_vol, &dev->ref_tf, dev->ref_grid,
                         dev->blocks, dev->ref_ao != NULL ? &ao_view : NULL,
                         &rg, &d, region, rgba, tiles, fetches);
    record_time(dev, t0);
    injected_stall(dev);
    return 0;
  }
  if (!dev->depth_valid || !same_depth_frame(&dev->depth_params, &p)) {
    if ((err = dev->ops->depth_pass(dev->impl, &p, NULL)) != 0) {
      dev->depth_valid = 0;
      return err;
    }
    dev->depth_valid = 1;
    dev->depth_params = p;
  }
  if (dev->bricks != NULL) {
    uint64_t ns = 0;
    if ((err = render_bricked(dev, &rg, &p, region, rgba, tiles, fetches,
                              &ns)) != 0)
      return err;
    record_ns(dev, ns);
    injected_stall(dev);
    return 0;
  }
  if ((err = dev->ops->raycast(dev->impl, &p, region, rgba, tiles,
                               fetches)) != 0)
    return err;
  record_time(dev, t0);
  injected_stall(dev);
  return 0;
}

void rp_device_forget_depth(rp_device *dev) {
  if (dev != NULL)
    dev->depth_valid = 0;
}

int rp_device_render(rp_device *dev, const rp_camera *cam,
                     const rp_render_desc *desc, const rp_region *region,
                     uint8_t *rgba, rp_tile_stats *tiles) {
  return rp__device_render(dev, cam, desc, region, rgba, tiles, NULL);
}

/* ---- Ambient occlusion ---------------------------------------------------- */

int rp_device_compute_ao(rp_device *dev, const rp_ao_plan *plan,
                         const uint32_t lo[3], const uint32_t end[3],
                         uint8_t *out) {
  static const char *fn = "rp_device_compute_ao";
  rp_context *ctx;
  uint64_t t0 = rp__now_ns();
  int a, err = 0;
  if (dev == NULL)
    return RP_EINVAL;
  ctx = dev->ctx;
  if (plan == NULL || lo == NULL || end == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "%s: plan, lo, end and out are "
                    "required", fn);
  if (!dev->have_volume || !dev->have_tf)
    return rp__fail(ctx, RP_ESTATE, "%s: the device has no %s yet", fn,
                    dev->have_volume ? "transfer function (rp_device_set_tf)"
                                     : "volume (rp_device_set_volume)");
  if (plan->vol_id != dev->vol_id || plan->tf_id != dev->tf_id)
    return rp__fail(ctx, RP_ESTATE, "%s: the plan was made for another %s "
                    "than the device holds", fn,
                    plan->vol_id != dev->vol_id ? "volume"
                                                : "transfer function");
  for (a = 0; a < 3; a++)
    if (!(lo[a] < end[a] && end[a] <= dev->shape.dims[a]))
      return rp__fail(ctx, RP_EINVAL, "%s: box [%u, %u) along axis %d is "
                      "empty or outside the volume's %u voxels", fn, lo[a],
                      end[a], a, dev->shape.dims[a]);
  if (dev->bricks != NULL)
    return out_of_core_ao(dev, fn);
  if (!(dev->caps.effects & RP_EFFECT_AO))
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: device '%s' (%s) cannot "
                    "compute ambient occlusion", fn, dev->caps.device,
                    dev->caps.backend);
  dev->ao_jobs++;
  if (dev->fail_at_ao != 0 && dev->ao_jobs >= dev->fail_at_ao)
    return rp__fail(ctx, RP_EDEVICE, "%s: device '%s' (%s) failed "
                    "(injected at AO job %u)", fn, dev->caps.device,
                    dev->caps.backend, dev->fail_at_ao);
  if (dev->ops != NULL) {
    rp_ao_job job;
    rp__ao_job(plan, lo, end, dev->ref_step, dev->shape.min, dev->shape.max,
               dev->lut_size, &job);
    err = dev->ops->compute_ao(dev->impl, &job, out);
  } else {
    rp__ao_reference_box(dev->ref_vol, &dev->ref_tf, plan, lo, end, lo[2],
                         end[2], out);
  }
  if (err != 0)
    return err;
  record_time(dev, t0);
  return 0;
}

int rp_device_set_ao(rp_device *dev, const rp_ao *ao) {
  static const char *fn = "rp_device_set_ao";
  rp_context *ctx;
  size_t bytes;
  int err = 0;
  if (dev == NULL)
    return RP_EINVAL;
  ctx = dev->ctx;
  if (ao == NULL)
    return release_ao(dev);
  if (!dev->have_volume)
    return rp__fail(ctx, RP_ESTATE, "%s: no volume on the device yet", fn);
  if (ao->vol_id != dev->vol_id)
    return rp__fail(ctx, RP_EINVAL, "%s: the AO volume was computed for "
                    "another volume than the device holds", fn);
  if (dev->bricks != NULL)
    return out_of_core_ao(dev, fn);
  if (!(dev->caps.effects & RP_EFFECT_AO))
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: device '%s' (%s) cannot "
                    "render ambient occlusion", fn, dev->caps.device,
                    dev->caps.backend);
  bytes = (size_t)ao->dims[0] * ao->dims[1] * ao->dims[2];
  if (bytes > dev->caps.max_alloc_bytes)
    return rp__fail(ctx, RP_ENOMEM, "%s: %zu bytes exceed the device's "
                    "largest buffer (%llu bytes)", fn, bytes,
                    (unsigned long long)dev->caps.max_alloc_bytes);
  if (dev->ops != NULL) {
    err = dev->ops->upload_ao(dev->impl, ao->data);
  } else {
    rp_ao *copy = rp__calloc(ctx, 1, sizeof *copy);
    uint8_t *data = rp__malloc(ctx, bytes);
    if (copy == NULL || data == NULL) {
      rp__free(ctx, copy);
      rp__free(ctx, data);
      err = rp__fail(ctx, RP_ENOMEM, "%s: out of memory", fn);
    } else {
      *copy = *ao;
      copy->ctx = ctx;
      copy->data = data;
      memcpy(data, ao->data, bytes);
      rp_ao_destroy(dev->ref_ao);
      dev->ref_ao = copy;
    }
  }
  if (err != 0) {
    /* What the device holds now is unknown: no AO render until a set
     * succeeds. */
    dev->ao_tf_id = 0;
    return err;
  }
  dev->ao_vol_id = ao->vol_id;
  dev->ao_tf_id = ao->tf_id;
  dev->ao_bytes = bytes;
  return 0;
}

uint64_t rp_device_ao_bytes(const rp_device *dev) {
  return dev != NULL ? dev->ao_bytes : 0;
}

rp_context *rp__device_context(const rp_device *dev) { return dev->ctx; }

int rp__device_holds(const rp_device *dev, uint64_t vol_id, uint64_t tf_id) {
  return dev->have_volume && dev->have_tf && dev->vol_id == vol_id &&
         dev->tf_id == tf_id;
}
