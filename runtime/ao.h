/* Ambient occlusion internals shared by the reference (ao.c), the device
 * front end (backend.c) and the distribution across devices. */
#ifndef RP_AO_INTERNAL_H
#define RP_AO_INTERNAL_H

#include <stdint.h>

#include "executor.h"
#include "internal.h"
#include "raygen.h"
#include "raypace_backend.h"
#include "raypace_ao.h"

/* rp__fail that yields `code` itself rather than rp__fail's result, so
 * that the analyzer sees every failure path return non-zero and never a
 * caller go on with an output unset. */
#define RP__AO_FAIL(ctx, code, ...)                                         \
  (rp__fail((ctx), (code), __VA_ARGS__), (code))

struct rp_ao {
  rp_context *ctx;
  uint64_t vol_id, tf_id; /* what it was computed for */
  uint32_t dims[3];
  rp_ao_desc desc;        /* defaults resolved */
  uint64_t bricks_computed, bricks_total;
  uint8_t *data;          /* dims product bytes, owned */
};

/* What one AO computation needs besides the volume and TF: the float
 * inputs every device receives, and the brick mask (NULL: unbricked). */
struct rp_ao_plan {
  rp_context *ctx;
  uint64_t vol_id, tf_id; /* what it was made for */
  uint32_t dims[3];
  rp_ao_desc desc;        /* defaults resolved */
  float step;             /* rp__ao_step(&desc) */
  float *dirs;            /* directions x 4 floats, owned */
  uint8_t *bricks;        /* brick_grid product bytes or NULL, owned */
  uint32_t brick_grid[3];
  /* Summed-volume table of the mask over (grid + 1) per axis: full
   * bricks in any box in eight reads. NULL when unbricked. */
  uint32_t *full_sum;
  uint64_t full, total;   /* full bricks (all when unbricked), bricks */
};

/* The desc with defaults resolved, validated (message prefixed by fn). */
int rp__ao_desc_resolve(rp_context *ctx, const char *fn,
                        const rp_ao_desc *in, rp_ao_desc *out);
/* D = (R - a) / M in float: the one value reference and kernels use. */
float rp__ao_step(const rp_ao_desc *d);
/* rp_ao_direction for l = 0 .. count-1, 4 floats each (w = 0). */
int rp__ao_dirs(rp_context *ctx, uint32_t count, float **out);
/* ceil(dims / 4) per axis. */
void rp__ao_brick_grid(const uint32_t dims[3], uint32_t grid[3]);
/* Each 4^3 brick's value range (with a one-voxel overlap) of a volume,
 * on ctx's workers: what every TF's brick mask is read from, kept per
 * volume so that a new TF's AO plan does not read the voxels again. */
typedef struct rp__ao_ranges rp__ao_ranges;
int rp__ao_ranges_build(rp_context *ctx, const rp_volume *vol,
                        rp__ao_ranges **out);
void rp__ao_ranges_destroy(rp__ao_ranges *r);
/* The id of the volume they were built from. */
uint64_t rp__ao_ranges_volume(const rp__ao_ranges *r);
/* rp_ao_plan_create with the volume's ranges (NULL: built and dropped
 * here). */
int rp__ao_plan_create(rp_context *ctx, const rp_volume *vol,
                       const rp_tf *tf, const rp_ao_desc *desc,
                       const rp__ao_ranges *ranges, rp_ao_plan **out);
/* AO of one voxel, in double, with the directions, samples, offset and
 * step of `job` (its box and brick mask are not looked at). */
uint8_t rp__ao_voxel(const rp_volume *vol, const rp_tf *tf,
                     const rp_ao_job *job, uint32_t i, uint32_t j,
                     uint32_t k);
/* AO of job's box [lo, end) restricted to layers z0 .. z1-1 into `out`,
 * which holds the whole box (x fastest); voxels of bricks the job's mask
 * calls empty get 255. The reference backend's compute_ao. */
void rp__ao_reference_job(const rp_volume *vol, const rp_tf *tf,
                          const rp_ao_job *job, uint32_t z0, uint32_t z1,
                          uint8_t *out);
/* The same for the box [lo, end) under `plan`: rp__ao_job's job. */
void rp__ao_reference_box(const rp_volume *vol, const rp_tf *tf,
                          const rp_ao_plan *s, const uint32_t lo[3],
                          const uint32_t end[3], uint32_t z0, uint32_t z1,
                          uint8_t *out);
/* The job a backend receives for voxels [lo, end) under `plan`, on a
 * device holding a volume of data range [value_min, value_max] and a TF
 * of `ref_step` and `lut_size` entries. Points into `plan`. */
void rp__ao_job(const rp_ao_plan *plan, const uint32_t lo[3],
                const uint32_t end[3], float ref_step, double value_min,
                double value_max, uint32_t lut_size, rp_ao_job *job);
/* An rp_ao for the plan's volume and TF, data uninitialised. */
int rp__ao_new(rp_context *ctx, const rp_ao_plan *plan, rp_ao **out);

/* RP_EINVAL with a message unless `ao` was computed for this volume and
 * transfer function. */
int rp__ao_check(rp_context *ctx, const char *fn, const rp_ao *ao,
                 uint64_t vol_id, uint64_t tf_id);
/* The AO values as a volume of 8-bit voxels (no copy: `view` points into
 * `ao`), for the raycast's trilinear read. */
void rp__ao_view(const rp_ao *ao, rp_volume *view);

/* The schedule with defaults resolved, validated (message prefixed by
 * fn). */
int rp__ao_schedule_resolve(rp_context *ctx, const char *fn,
                            const rp_ao_schedule *in, rp_ao_schedule *out);

/* rp_ao_run_create on the devices of `count` executors, which stay the
 * caller's (a group's: rp_device_group_ao_begin): each step's work for a
 * device is a job on its executor. */
int rp__ao_run_create(rp_context *ctx, rp__executor *const *ex,
                      uint32_t count, const rp_ao_plan *plan,
                      const rp_ao_schedule *schedule, rp_ao_run **out);

/* backend.c: the context a device was made from, and whether it holds
 * this volume and transfer function. */
rp_context *rp__device_context(const rp_device *dev);
int rp__device_holds(const rp_device *dev, uint64_t vol_id, uint64_t tf_id);

#endif /* RP_AO_INTERNAL_H */
