/* Devices: the backend registry, selection, and the front end that
 * validates every call before it reaches a backend (STYLE rules 7-9).
 *
 * Every device is a backend behind rp_backend_ops: a driver's (OpenCL,
 * Vulkan, MPI), or a host backend that runs in the library (the scalar
 * reference, ref_backend.c; the deterministic test device,
 * test_backend.c), possibly wrapped in fault injection (faults.c). The
 * front end checks arguments and state, resolves the frame, and calls
 * through the ops; an out-of-core volume goes through the brick plan
 * (brick_plan.c), which drives the same ops. */
#include <stdlib.h>
#include <string.h>

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

/* The host backends, always compiled in and, like "mpi", opened only by
 * name: the scalar oracle is slow, and the test device's time is a
 * formula, neither what an application means by "a device". */
static const rp__host_backend *const hosts[] = {&rp__ref_backend,
                                                &rp__test_backend, NULL};

struct rp_device {
  rp_context *ctx;
  const rp_backend_ops *ops;
  void *impl;
  /* The fault wrapper (rp_fault_desc), when impl is one: told where a
   * render begins and ends. NULL: no faults. */
  rp__faults *faults;
  rp_caps caps;
  /* The scene as uploaded. `shape` is a volume without voxels: what the
   * camera code needs (dims, spacing) to resolve a camera. */
  int have_volume, have_tf;
  rp_volume shape;
  uint64_t vol_id, tf_id;
  float ref_step;
  uint32_t lut_size;
  double tf_span[2]; /* rp__tf_volume_range of the uploaded TF */
  /* The AO volume set for RP_EFFECT_AO renders: what it was computed
   * for, and its size on the device (0: none, and no AO memory). */
  uint64_t ao_vol_id, ao_tf_id, ao_bytes;
  /* The uploaded occupancy's box of occupied blocks. */
  uint32_t box_lo[3], box_end[3];
  /* The frame the device's current depth-pass result belongs to. */
  int depth_valid;
  rp_frame_params depth_params;
  uint64_t last_ns;
  /* How the device holds its volume: whole, or as bricks. */
  rp__brick_plan plan;
};

const char *const *rp_backend_names(void) {
  static const char *names[sizeof registry / sizeof registry[0] +
                           sizeof hosts / sizeof hosts[0]];
  size_t i, h;
  for (i = 0; registry[i] != NULL; i++)
    names[i] = registry[i]->name;
  for (h = 0; hosts[h] != NULL; h++)
    names[i++] = hosts[h]->name;
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

static const rp__host_backend *find_host(const char *name) {
  size_t i;
  for (i = 0; name != NULL && hosts[i] != NULL; i++)
    if (strcmp(hosts[i]->name, name) == 0)
      return hosts[i];
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
  if (find_host(backend) != NULL) {
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
  if (find_host(name) != NULL)
    return rp__fail(ctx, RP_EUNSUPPORTED, "backend '%s' runs inside this "
                    "process's front end (it renders from the front end's "
                    "camera, in double) and cannot serve another; name a "
                    "backend with a device", name);
  if (name != NULL && find(name) != NULL && named_only(find(name)))
    return rp__fail(ctx, RP_EUNSUPPORTED, "backend '%s' cannot be opened "
                    "here: it stands for a device elsewhere", name);
  return choose_backend(ctx, name, index, 0, ops, impl, caps);
}

/* ---- Creating a device --------------------------------------------------- */

/* Opens the backend the desc asks for (named `name`), then wraps it in
 * fault injection when the chain asks for faults. */
static int open_device(rp_device *dev, const rp_device_desc *d,
                       const char *name, const rp_fault_desc *faults) {
  const rp__host_backend *host = find_host(name);
  int err;
  if (host != NULL) {
    memset(&dev->caps, 0, sizeof dev->caps);
    err = host->create(dev->ctx, d, &dev->ops, &dev->impl, &dev->caps);
  } else {
    err = choose_backend(dev->ctx, name, d->index, d->compute_units,
                         &dev->ops, &dev->impl, &dev->caps);
  }
  if (err != 0 || faults == NULL)
    return err;
  if ((err = rp__faults_wrap(dev->ctx, faults, &dev->caps, &dev->ops,
                             &dev->impl, &dev->faults)) != 0)
    dev->ops->destroy(dev->impl);
  return err;
}

int rp_device_create(rp_context *ctx, const rp_device_desc *desc,
                     rp_device **out) {
  rp_device_desc d = {0};
  const rp_fault_desc *faults;
  rp_device *dev;
  const char *name;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_device_create: out is required");
  if (desc != NULL)
    d = *desc;
  name = wanted_backend(d.backend);
  if ((err = rp__ext_check(ctx, d.next, name, &faults)) != 0)
    return err;
  if (d.brick_size != 0 &&
      (d.brick_size < RP__BRICK_MIN || d.brick_size > RP__BRICK_MAX ||
       (d.brick_size & (d.brick_size - 1)) != 0))
    return rp__fail(ctx, RP_ERANGE, "rp_device_create: brick_size %u is "
                    "not a power of two in [%u, %u]", d.brick_size,
                    RP__BRICK_MIN, RP__BRICK_MAX);
  dev = rp__calloc(ctx, 1, sizeof *dev);
  if (dev == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_device_create: out of memory");
  dev->ctx = ctx;
  if ((err = open_device(dev, &d, name, faults)) != 0) {
    rp__free(ctx, dev);
    return err;
  }
  rp__brick_plan_init(&dev->plan, ctx, dev->ops, dev->impl, &dev->caps,
                      d.budget_bytes,
                      d.brick_size != 0 ? d.brick_size : RP__BRICK_DEFAULT);
  *out = dev;
  return 0;
}

void rp_device_destroy(rp_device *dev) {
  if (dev == NULL)
    return;
  dev->ops->destroy(dev->impl);
  rp__brick_plan_release(&dev->plan);
  rp__free(dev->ctx, dev);
}

void rp_device_get_caps(const rp_device *dev, rp_caps *caps) {
  if (dev != NULL && caps != NULL)
    *caps = dev->caps;
}

uint64_t rp_device_last_time_ns(const rp_device *dev) {
  return dev != NULL ? dev->last_ns : 0;
}

int rp__device_clock_ns(const rp_device *dev, uint64_t *ns) {
  if (dev->ops->clock_ns == NULL)
    return 0;
  *ns = dev->ops->clock_ns(dev->impl);
  return 1;
}

/* Reads only what is fixed at create (ops, impl): another thread may be
 * running the device meanwhile, so the front end's scene fields are not
 * this call's to look at; the backend checks its own state under its
 * lock. */
int rp__device_set_slowdown(rp_device *dev, double slowdown) {
  if (dev == NULL)
    return RP_EINVAL;
  if (dev->faults == NULL)
    return rp__fail(dev->ctx, RP_EINVAL, "rp__device_set_slowdown: the "
                    "device was opened without fault injection");
  return rp__faults_set_slowdown(dev->faults, slowdown);
}

int rp__device_builds_ahead(const rp_device *dev) {
  return dev->ops->prepare != NULL;
}

int rp_device_prepare(rp_device *dev, rp_context *ctx, uint32_t effects) {
  if (dev == NULL || ctx == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_device_prepare: NULL %s",
                    dev == NULL ? "device" : "context");
  if (effects & ~(uint32_t)RP__KNOWN_EFFECTS)
    return rp__fail(ctx, RP_EINVAL, "rp_device_prepare: unknown effect "
                    "bits 0x%x", effects);
  if (dev->ops->prepare == NULL)
    return 0;
  return dev->ops->prepare(dev->impl, ctx, effects);
}

/* The last operation's device time, as the backend reports it. */
static void record_time(rp_device *dev) {
  dev->last_ns = dev->ops->last_time_ns(dev->impl);
}

/* Frees the device's AO memory. */
static int release_ao(rp_device *dev) {
  int err = 0;
  if (dev->ao_bytes != 0)
    err = dev->ops->upload_ao(dev->impl, NULL);
  dev->ao_bytes = 0;
  return err;
}

/* ---- The scene ----------------------------------------------------------- */

int rp_device_get_brick_stats(const rp_device *dev, rp_brick_stats *out) {
  if (dev == NULL || out == NULL)
    return RP_EINVAL;
  rp__brick_plan_stats(&dev->plan, out);
  return 0;
}

int rp_device_set_volume(rp_device *dev, const rp_volume *vol) {
  rp_context *ctx;
  int err, lost;
  if (dev == NULL)
    return RP_EINVAL;
  ctx = dev->ctx;
  if (vol == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_device_set_volume: vol is NULL");
  if (!(dev->caps.voxel_types & (1u << vol->type)))
    return rp__fail(ctx, RP_EUNSUPPORTED, "rp_device_set_volume: device "
                    "'%s' cannot hold %s voxels", dev->caps.device,
                    rp_voxel_type_name(vol->type));
  if ((err = rp__brick_plan_upload(&dev->plan, vol, &lost)) != 0) {
    if (lost) /* the backend dropped its volume before failing */
      dev->have_volume = dev->have_tf = dev->depth_valid = 0;
    return err;
  }
  /* A new volume invalidates the TF upload (occupancy is per volume) and
   * the AO volume, whose memory goes with it. */
  (void)release_ao(dev); /* a release cannot fail */
  dev->have_volume = 1;
  dev->have_tf = 0;
  dev->depth_valid = 0;
  dev->vol_id = vol->id;
  dev->shape = *vol;
  dev->shape.data = NULL;
  dev->shape.ctx = ctx;
  record_time(dev);
  return 0;
}

int rp_device_set_tf(rp_device *dev, const rp_tf *tf,
                     const rp_occupancy *occ) {
  rp_context *ctx;
  int err;
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
  err = dev->ops->upload_tf(dev->impl, tf->lut, (uint32_t)tf->lut_size);
  if (err == 0)
    err = dev->ops->upload_occupancy(dev->impl, occ->grid, occ->alpha_hist,
                                     occ->h->blocks);
  if (err != 0) {
    dev->have_tf = 0; /* a half-done upload must not be rendered with */
    return err;
  }
  dev->have_tf = 1;
  rp__brick_plan_set_tf(&dev->plan, tf);
  memcpy(dev->box_lo, occ->box_lo, sizeof dev->box_lo);
  memcpy(dev->box_end, occ->box_end, sizeof dev->box_end);
  dev->depth_valid = 0;
  dev->tf_id = tf->id;
  dev->ref_step = tf->reference_step;
  dev->lut_size = (uint32_t)tf->lut_size;
  rp__tf_volume_range(tf, &dev->shape, dev->tf_span);
  record_time(dev);
  return 0;
}

/* ---- Frames -------------------------------------------------------------- */

/* The checks every frame operation shares, then the camera resolved for
 * the scaled image (*rg) and the frame every backend receives (*f, whose
 * rg points to *rg). */
static int prepare_frame(rp_device *dev, const char *fn,
                         const rp_camera *cam, const rp_render_desc *desc,
                         rp_render_desc *d, rp__raygen *rg,
                         rp__host_frame *f) {
  rp_context *ctx = dev->ctx;
  rp_frame_params *p = &f->p;
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
                              dev->lut_size, dev->tf_span, rg, p)) != 0)
    return err;
  memcpy(p->occupied_lo, dev->box_lo, sizeof dev->box_lo);
  memcpy(p->occupied_end, dev->box_end, sizeof dev->box_end);
  rp__brick_plan_frame(&dev->plan, p);
  f->rg = rg;
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
  x.jitter = y.jitter = 0;
  x.jitter_seed = y.jitter_seed = 0;
  x.effects &= RP_EFFECT_SKIP;
  y.effects &= RP_EFFECT_SKIP;
  return memcmp(&x, &y, sizeof x) == 0;
}

/* Runs the depth pass, and remembers the frame its result is for. */
static int run_depth(rp_device *dev, const rp__host_frame *f,
                     float *front_back) {
  int err;
  if ((err = dev->ops->depth_pass(dev->impl, &f->p, front_back)) != 0) {
    dev->depth_valid = 0;
    return err;
  }
  dev->depth_valid = 1;
  dev->depth_params = f->p;
  return 0;
}

int rp_device_depth_pass(rp_device *dev, const rp_camera *cam,
                         const rp_render_desc *desc, float *front_back) {
  rp_render_desc d = {0};
  rp__raygen rg = {0};
  rp__host_frame f;
  int err;
  if (dev == NULL)
    return RP_EINVAL;
  if ((err = prepare_frame(dev, "rp_device_depth_pass", cam, desc, &d, &rg,
                           &f)) != 0)
    return err;
  if ((err = run_depth(dev, &f, front_back)) != 0)
    return err;
  record_time(dev);
  return 0;
}

int rp_device_ert_prepass(rp_device *dev, const rp_camera *cam,
                          const rp_render_desc *desc, uint32_t seed,
                          uint32_t frame, float *d_ert) {
  rp_render_desc d = {0};
  rp__raygen rg = {0};
  rp__host_frame f;
  int err;
  if (dev == NULL)
    return RP_EINVAL;
  if (d_ert == NULL)
    return rp__fail(dev->ctx, RP_EINVAL, "rp_device_ert_prepass: d_ert is "
                    "NULL");
  if ((err = prepare_frame(dev, "rp_device_ert_prepass", cam, desc, &d, &rg,
                           &f)) != 0)
    return err;
  f.p.ert_seed = seed;
  f.p.frame = frame;
  if ((err = dev->ops->ert_prepass(dev->impl, &f.p, d_ert)) != 0)
    return err;
  record_time(dev);
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
                          rp__raygen *rg, rp__host_frame *f, rp_region *r) {
  int err;
  if ((err = prepare_frame(dev, fn, cam, desc, d, rg, f)) != 0)
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

/* Whether the device can render RP_EFFECT_AO now (fn names the call). */
static int check_ao_state(const rp_device *dev, const char *fn) {
  if (dev->plan.bricks != NULL)
    return rp__brick_plan_no_ao(&dev->plan, fn);
  if (dev->ao_bytes == 0 || dev->ao_vol_id != dev->vol_id ||
      dev->ao_tf_id != dev->tf_id)
    return rp__fail(dev->ctx, RP_ESTATE, "%s: RP_EFFECT_AO needs an AO "
                    "volume computed for the device's current volume and "
                    "transfer function (rp_device_set_ao): %s", fn,
                    dev->ao_bytes == 0 ? "none is set"
                                       : "the one set is for another");
  return 0;
}

int rp__device_render(rp_device *dev, const rp_camera *cam,
                      const rp_render_desc *desc, const rp_region *region,
                      uint8_t *rgba, rp_tile_stats *tiles,
                      uint64_t *fetches) {
  static const char *fn = "rp_device_render";
  rp_render_desc d = {0};
  rp__raygen rg = {0};
  rp__host_frame f;
  rp_region all;
  uint64_t ns = 0;
  int err;
  if (dev == NULL)
    return RP_EINVAL;
  if (rgba == NULL)
    return rp__fail(dev->ctx, RP_EINVAL, "%s: rgba is NULL", fn);
  if ((err = prepare_region(dev, fn, cam, desc, region, &d, &rg, &f,
                            &all)) != 0 ||
      ((d.effects & RP_EFFECT_AO) && (err = check_ao_state(dev, fn)) != 0))
    return err;
  /* One render, however many raycasts it takes. */
  if ((err = rp__faults_render_begin(dev->faults)) != 0)
    return err;
  if ((!dev->depth_valid || !same_depth_frame(&dev->depth_params, &f.p)) &&
      (err = run_depth(dev, &f, NULL)) != 0)
    return err;
  if (dev->plan.bricks != NULL) {
    err = rp__brick_plan_render(&dev->plan, &f, &all, rgba, tiles, fetches,
                                &ns);
  } else if ((err = dev->ops->raycast(dev->impl, &f.p, &all, rgba, tiles,
                                      fetches)) == 0) {
    ns = dev->ops->last_time_ns(dev->impl);
  }
  if (err != 0)
    return err;
  dev->last_ns = ns + rp__faults_render_end(dev->faults);
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

int rp_device_upload_estimate(rp_device *dev, const rp_camera *cam,
                              const rp_render_desc *desc,
                              const rp_region *region,
                              rp_upload_estimate *out) {
  rp_render_desc d = {0};
  rp__raygen rg = {0};
  rp__host_frame f;
  rp_region r;
  int err;
  if (dev == NULL)
    return RP_EINVAL;
  if (out == NULL)
    return rp__fail(dev->ctx, RP_EINVAL, "rp_device_upload_estimate: out "
                    "is NULL");
  memset(out, 0, sizeof *out);
  if ((err = prepare_region(dev, "rp_device_upload_estimate", cam, desc,
                            region, &d, &rg, &f, &r)) != 0)
    return err;
  return rp__brick_plan_estimate(&dev->plan, &rg, d.effects, &r, out);
}

/* ---- Ambient occlusion --------------------------------------------------- */

int rp_device_compute_ao(rp_device *dev, const rp_ao_plan *plan,
                         const uint32_t lo[3], const uint32_t end[3],
                         uint8_t *out) {
  static const char *fn = "rp_device_compute_ao";
  rp_context *ctx;
  rp_ao_job job;
  int a, err;
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
  if (dev->plan.bricks != NULL)
    return rp__brick_plan_no_ao(&dev->plan, fn);
  if (!(dev->caps.effects & RP_EFFECT_AO))
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: device '%s' (%s) cannot "
                    "compute ambient occlusion", fn, dev->caps.device,
                    dev->caps.backend);
  rp__ao_job(plan, lo, end, dev->ref_step, dev->tf_span[0], dev->tf_span[1],
             dev->lut_size, &job);
  if ((err = dev->ops->compute_ao(dev->impl, &job, out)) != 0)
    return err;
  record_time(dev);
  return 0;
}

int rp_device_set_ao(rp_device *dev, const rp_ao *ao) {
  static const char *fn = "rp_device_set_ao";
  rp_context *ctx;
  size_t bytes;
  int err;
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
  if (dev->plan.bricks != NULL)
    return rp__brick_plan_no_ao(&dev->plan, fn);
  if (!(dev->caps.effects & RP_EFFECT_AO))
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: device '%s' (%s) cannot "
                    "render ambient occlusion", fn, dev->caps.device,
                    dev->caps.backend);
  bytes = (size_t)ao->dims[0] * ao->dims[1] * ao->dims[2];
  if (bytes > dev->caps.max_alloc_bytes)
    return rp__fail(ctx, RP_ENOMEM, "%s: %zu bytes exceed the device's "
                    "largest buffer (%llu bytes)", fn, bytes,
                    (unsigned long long)dev->caps.max_alloc_bytes);
  if ((err = dev->ops->upload_ao(dev->impl, ao->data)) != 0) {
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
