/* The OpenCL backend's internals, shared by its .c files and its test.
 * Nothing here is part of the public API. */
#ifndef RP_CL_INTERNAL_H
#define RP_CL_INTERNAL_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#include <CL/cl.h>

#include "internal.h"
#include "raypace_backend.h"
#include "variant_cache.h"

extern const rp_backend_bootstrap rp_cl_bootstrap;

/* The four programs; each is built per option set (below). */
typedef enum rp_cl_kind {
  RP_CL_RAYCAST = 0,
  RP_CL_DEPTH = 1,
  RP_CL_ERT = 2,
  RP_CL_AO = 3
} rp_cl_kind;

/* Option set of a program, the key of its entry in the variant cache
 * (variant_cache.h): the effect bits it was specialised for
 * (RP_EFFECT_SHADING | ERT | SKIP | AO), the fetch counting variant, the
 * voxel type and index width (raycast and AO only), and the program's
 * kind above them all. */
#define RP_CL_KEY_COUNT (1u << 8)
#define RP_CL_KEY_BIG (1u << 9) /* 2^31 voxels or more: 64-bit indices */
#define RP_CL_KEY_TYPE_SHIFT 10 /* two bits */
#define RP_CL_KEY_BRICKED (1u << 12) /* the volume is a brick pool */
#define RP_CL_KEY_KIND_SHIFT 16

/* The driver objects of a variant-cache entry. */
typedef struct rp_cl_program {
  cl_program program; /* NULL: free entry */
  cl_kernel kernel;
} rp_cl_program;

/* A device buffer that grows on demand and is reused otherwise, so that
 * a steady frame loop allocates nothing. */
typedef struct rp_cl_buffer {
  cl_mem mem;
  size_t size;
} rp_cl_buffer;

/* The AO kernel's first argument (rp_cl_ao_args in kernels/ao.cl): an
 * rp_ao_job without its pointers, plus the volume's dims. */
typedef struct rp_cl_ao_args {
  float dims[3];
  uint32_t idims[3];
  uint32_t lo[3], end[3];
  uint32_t directions, samples;
  float offset, step, ref_step;
  float value_min, value_max;
  uint32_t lut_size;
  uint32_t brick_grid[3];
  uint32_t bricked;
} rp_cl_ao_args;

typedef struct rp_cl_impl {
  rp_context *ctx;
  cl_device_id device; /* the one kernels run on */
  cl_device_id root;   /* its parent when a sub-device, else NULL */
  cl_context context;
  cl_command_queue queue;
  /* Guards the variant cache and the three fields after it: the ops'
   * one exception to one thread per impl is `prepare`, which builds on
   * another thread and adds what it built here. */
  pthread_mutex_t lock;
  rp_variant_table variants;
  rp_cl_program programs[RP_VARIANT_CACHE_SIZE]; /* at variants' index */
  rp_voxel_type voxel_type; /* 0 until a volume is uploaded */
  int big_volume;           /* see RP_CL_KEY_BIG */
  int bricked;              /* the volume is a brick pool (below) */
  uint32_t dims[3];         /* of the uploaded volume */
  size_t voxels;            /* its voxel count */
  size_t ao_voxels;         /* the AO volume's, when one is uploaded */
  /* Out-of-core (`bricked`): `volume` holds the pool, brick_table its
   * table. */
  size_t brick_bytes;       /* one stored brick */
  size_t brick_count;       /* entries of the table */
  rp_cl_buffer brick_table;
  /* upload_bricks' host scratch: the bricks of runs of consecutive slots
   * side by side, and the uploads' order by slot. */
  uint8_t *brick_staging;
  size_t brick_staging_cap;
  uint32_t *brick_order;
  size_t brick_order_cap;
  rp_cl_buffer volume, lut, grid, alpha_hist;
  /* The grid inside a border of empty blocks one deep: what the depth
   * pass walks, moving an index by a fixed stride per step. */
  rp_cl_buffer bordered_grid;
  rp_cl_buffer ao; /* the AO volume (RP_EFFECT_AO); none when AO is off */
  rp_cl_buffer front_back, d_ert, rgba, tiles, fetches;
  rp_cl_buffer slab_state; /* out-of-core depth slabs: 8 floats a pixel */
  uint64_t last_ns;
} rp_cl_impl;

/* ---- cl_device.c --------------------------------------------------------- */

/* "CL_OUT_OF_RESOURCES" etc., "CL_UNKNOWN_ERROR" for a code not listed. */
const char *rp_cl__error_name(cl_int err);
/* Records "opencl: <op>: <name> (<code>)" and returns RP_ENOMEM for the
 * out-of-memory codes, RP_EDEVICE for the others. */
int rp_cl__fail(rp_context *ctx, cl_int err, const char *op);
/* Devices: for each root device of each platform, the device itself, then
 * its one-compute-unit sub-devices when it can be partitioned. */
int rp_cl__count_devices(uint32_t *count);
/* Compute units of root device `index` to partition equally; otherwise
 * (a listed sub-device, no CL_DEVICE_PARTITION_EQUALLY) RP_EUNSUPPORTED. */
int rp_cl__partition_units(rp_context *ctx, uint32_t index,
                           uint32_t *units);
/* Opens device `index` of that list, or with compute_units > 0 the first
 * sub-device of that many compute units of it, into impl (context, queue)
 * and fills caps. On failure nothing is left allocated. */
int rp_cl__open(rp_cl_impl *impl, uint32_t index, uint32_t compute_units,
                rp_caps *caps);
void rp_cl__close(rp_cl_impl *impl);
/* Builds `sources` for impl's device. On failure the RP_EBUILD message,
 * to `ctx`, names `what` and quotes the start of the build log. Touches
 * nothing in impl but its device and context: any thread may call it. */
int rp_cl__build(rp_cl_impl *impl, rp_context *ctx, const char *what,
                 const char **sources, cl_uint count, const char *options,
                 cl_program *out);

/* ---- cl_backend.c -------------------------------------------------------- */

/* The kernel of `kind` for option set `key`, built on first use and
 * kept in impl's variant cache (variant_cache.h says which it evicts). */
int rp_cl__kernel(rp_cl_impl *impl, rp_cl_kind kind, uint32_t key,
                  cl_kernel *out);

/* ---- test hooks ---------------------------------------------------------- */

/* Builds an arbitrary program on impl's device and releases it: how the
 * test reaches the build-failure path. */
int rp_cl__build_program_for_test(void *impl, const char *source,
                                  const char *options);
/* Runs the raycast kernel's own opacity correction on n alphas for
 * step / ref_step = ratio, into out (n floats). */
int rp_cl__correct_for_test(void *impl, const float *alpha, size_t n,
                            float ratio, float *out);

#endif /* RP_CL_INTERNAL_H */
