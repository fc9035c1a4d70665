/* Backend "reference": the scalar C passes (reference.c, depth.c, ert.c,
 * ao.c) behind rp_backend_ops, like a driver, so that the front end
 * drives every device the same way.
 *
 * It stays the oracle: it renders from the camera in double, the one
 * rp_render_reference builds (the host frame, device.h), never from the
 * float camera in rp_frame_params, and from its own copies of the scene
 * (the volume, the TF's LUT, the occupancy grid and H-alpha, the AO
 * volume), so that its images are rp_render_reference's bit for bit. Its
 * device time is the wall time of each operation on the calling thread.
 * It holds the whole volume (no brick pool) on one thread (no partition),
 * and builds no kernels (no prepare). */
#include <string.h>

#include "ao.h"
#include "device.h"
#include "passes.h"

typedef struct ref_impl {
  rp_context *ctx;
  rp_volume *vol;  /* a copy of the uploaded volume */
  rp_tf tf;        /* LUT copy; reference_step set by each operation */
  uint8_t *grid, *alpha;
  uint32_t blocks[3];
  uint8_t *ao;     /* the AO volume, one byte per voxel of vol; or NULL */
  uint64_t last_ns;
} ref_impl;

static void ref_destroy(void *p) {
  ref_impl *r = p;
  if (r == NULL)
    return;
  rp_volume_destroy(r->vol);
  rp__free(r->ctx, r->tf.lut);
  rp__free(r->ctx, r->grid);
  rp__free(r->ctx, r->alpha);
  rp__free(r->ctx, r->ao);
  rp__free(r->ctx, r);
}

/* The time of the operation that began at `t0`. */
static void timed(ref_impl *r, uint64_t t0) { r->last_ns = rp__now_ns() - t0; }

static int ref_upload_volume(void *p, const rp_volume *vol) {
  ref_impl *r = p;
  rp_volume_desc d = {0};
  rp_volume *copy = NULL;
  uint64_t t0 = rp__now_ns();
  int a, err;
  for (a = 0; a < 3; a++) {
    d.dims[a] = vol->dims[a];
    d.spacing[a] = vol->spacing[a];
  }
  d.type = vol->type;
  d.data = vol->data;
  if ((err = rp_volume_create(r->ctx, &d, &copy)) != 0)
    return err;
  rp_volume_destroy(r->vol);
  r->vol = copy;
  timed(r, t0);
  return 0;
}

static int ref_upload_tf(void *p, const float *lut, uint32_t lut_size) {
  ref_impl *r = p;
  size_t bytes = (size_t)lut_size * 4 * sizeof(float);
  uint64_t t0 = rp__now_ns();
  float *copy = rp__malloc(r->ctx, bytes);
  if (copy == NULL)
    return rp__fail(r->ctx, RP_ENOMEM, "rp_device_set_tf: out of memory");
  memcpy(copy, lut, bytes);
  rp__free(r->ctx, r->tf.lut);
  r->tf.ctx = r->ctx;
  r->tf.lut = copy;
  r->tf.lut_size = (int)lut_size;
  timed(r, t0);
  return 0;
}

static int ref_upload_occupancy(void *p, const uint8_t *grid,
                                const uint8_t *alpha_hist,
                                const uint32_t blocks[3]) {
  ref_impl *r = p;
  size_t nb = (size_t)blocks[0] * blocks[1] * blocks[2];
  uint64_t t0 = rp__now_ns();
  uint8_t *g = rp__malloc(r->ctx, nb);
  uint8_t *a = rp__malloc(r->ctx, nb * RP_OPACITY_BINS);
  if (g == NULL || a == NULL) {
    rp__free(r->ctx, g);
    rp__free(r->ctx, a);
    return rp__fail(r->ctx, RP_ENOMEM, "rp_device_set_tf: out of memory");
  }
  memcpy(g, grid, nb);
  memcpy(a, alpha_hist, nb * RP_OPACITY_BINS);
  rp__free(r->ctx, r->grid);
  rp__free(r->ctx, r->alpha);
  r->grid = g;
  r->alpha = a;
  memcpy(r->blocks, blocks, sizeof r->blocks);
  timed(r, t0);
  return 0;
}

/* The raycast derives its own skipping range per ray, so the depth pass
 * is only computed when someone looks at it. */
static int ref_depth_pass(void *p, const rp_frame_params *fp,
                          float *front_back) {
  ref_impl *r = p;
  const rp__raygen *rg = rp__host_frame_of(fp)->rg;
  const uint8_t *grid = (fp->effects & RP_EFFECT_SKIP) ? r->grid : NULL;
  uint64_t t0 = rp__now_ns();
  uint32_t x, y;
  for (y = 0; front_back != NULL && y < rg->height; y++)
    for (x = 0; x < rg->width; x++) {
      rp__ray ray;
      double f, b;
      size_t i = ((size_t)y * rg->width + x) * 2;
      rp__raygen_ray(rg, x, y, &ray);
      rp__depth_ray(&ray, rg->dims, grid, r->blocks, &f, &b);
      front_back[i] = (float)f;
      front_back[i + 1] = (float)b;
    }
  timed(r, t0);
  return 0;
}

static int ref_ert_prepass(void *p, const rp_frame_params *fp,
                           float *d_ert) {
  ref_impl *r = p;
  uint64_t t0 = rp__now_ns();
  rp__ert_prepass(rp__host_frame_of(fp)->rg, r->grid, r->alpha, r->blocks,
                  fp->ref_step, fp->ert_threshold, fp->ert_seed, fp->frame,
                  d_ert);
  timed(r, t0);
  return 0;
}

static int ref_raycast(void *p, const rp_frame_params *fp,
                       const rp_region *region, uint8_t *rgba,
                       rp_tile_stats *tiles, uint64_t *fetches) {
  ref_impl *r = p;
  rp_render_desc d = {0};
  rp_volume ao_view;
  uint64_t t0 = rp__now_ns();
  int a;
  /* What rp__reference_render reads of the desc; the rest of the frame
   * is the double camera. */
  d.step = fp->step;
  d.ert_threshold = fp->ert_threshold;
  d.effects = fp->effects;
  d.jitter = fp->jitter ? RP_JITTER_ON : RP_JITTER_OFF;
  d.jitter_seed = fp->jitter_seed;
  r->tf.reference_step = fp->ref_step;
  /* The LUT came without its range: the frame's span is it. */
  r->tf.range = RP_TF_RANGE_DATA;
  r->tf.range_lo = (double)fp->value_min + r->vol->data_offset;
  r->tf.range_hi = (double)fp->value_max + r->vol->data_offset;
  if (r->ao != NULL) {
    memset(&ao_view, 0, sizeof ao_view);
    ao_view.ctx = r->ctx;
    ao_view.type = RP_U8;
    for (a = 0; a < 3; a++) {
      ao_view.dims[a] = r->vol->dims[a];
      ao_view.spacing[a] = 1.0f;
    }
    ao_view.min = 0.0;
    ao_view.max = 255.0;
    ao_view.voxel_count = r->vol->voxel_count;
    ao_view.data = r->ao;
  }
  rp__reference_render(r->vol, &r->tf, r->grid, r->blocks,
                       r->ao != NULL ? &ao_view : NULL,
                       rp__host_frame_of(fp)->rg, &d, region, rgba, tiles,
                       fetches);
  timed(r, t0);
  return 0;
}

static int ref_compute_ao(void *p, const rp_ao_job *job, uint8_t *out) {
  ref_impl *r = p;
  uint64_t t0 = rp__now_ns();
  r->tf.reference_step = job->ref_step;
  rp__ao_reference_job(r->vol, &r->tf, job, job->lo[2], job->end[2], out);
  timed(r, t0);
  return 0;
}

static int ref_upload_ao(void *p, const uint8_t *ao) {
  ref_impl *r = p;
  uint64_t t0 = rp__now_ns();
  uint8_t *copy;
  if (ao == NULL) {
    rp__free(r->ctx, r->ao);
    r->ao = NULL;
    return 0;
  }
  copy = rp__malloc(r->ctx, r->vol->voxel_count);
  if (copy == NULL)
    return rp__fail(r->ctx, RP_ENOMEM, "rp_device_set_ao: out of memory");
  memcpy(copy, ao, r->vol->voxel_count);
  rp__free(r->ctx, r->ao);
  r->ao = copy;
  timed(r, t0);
  return 0;
}

static uint64_t ref_last_time_ns(void *p) {
  return ((const ref_impl *)p)->last_ns;
}

const rp_backend_ops rp__ref_ops = {
    .destroy = ref_destroy,
    .upload_volume = ref_upload_volume,
    .upload_tf = ref_upload_tf,
    .upload_occupancy = ref_upload_occupancy,
    .depth_pass = ref_depth_pass,
    .ert_prepass = ref_ert_prepass,
    .raycast = ref_raycast,
    .compute_ao = ref_compute_ao,
    .upload_ao = ref_upload_ao,
    .last_time_ns = ref_last_time_ns,
};

int rp__ref_open(rp_context *ctx, void **impl) {
  ref_impl *r = rp__calloc(ctx, 1, sizeof *r);
  if (r == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_device_create: out of memory");
  r->ctx = ctx;
  *impl = r;
  return 0;
}

void rp__ref_caps(rp_caps *caps) {
  memset(caps, 0, sizeof *caps);
  strcpy(caps->backend, "reference");
  strcpy(caps->device, "scalar C reference (one thread)");
  caps->effects =
      RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_AO |
      RP_EFFECT_PREINT;
  caps->voxel_types = (1u << RP_U8) | (1u << RP_U16) | (1u << RP_F32);
  caps->global_mem_bytes = UINT64_MAX;
  caps->max_alloc_bytes = SIZE_MAX;
  caps->compute_units = 1;
}

int rp__ref_check(rp_context *ctx, const char *name,
                  const rp_device_desc *desc) {
  if (desc->budget_bytes != 0)
    return rp__fail(ctx, RP_EUNSUPPORTED, "rp_device_create: backend '%s' "
                    "holds the whole volume; it takes no memory budget "
                    "(budget_bytes %llu)", name,
                    (unsigned long long)desc->budget_bytes);
  if (desc->index != 0)
    return rp__fail(ctx, RP_ENODEV, "backend '%s' has one device; index %u "
                    "requested", name, desc->index);
  if (desc->compute_units != 0)
    return rp__fail(ctx, RP_EUNSUPPORTED, "rp_device_create: backend '%s' "
                    "cannot partition its device (compute_units %u; it "
                    "runs on one thread)", name, desc->compute_units);
  return 0;
}

static int ref_create(rp_context *ctx, const rp_device_desc *desc,
                      const rp_backend_ops **ops, void **impl,
                      rp_caps *caps) {
  int err;
  if ((err = rp__ref_check(ctx, "reference", desc)) != 0 ||
      (err = rp__ref_open(ctx, impl)) != 0)
    return err;
  *ops = &rp__ref_ops;
  rp__ref_caps(caps);
  return 0;
}

const rp__host_backend rp__ref_backend = {"reference", ref_create};
