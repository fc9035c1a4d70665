/* Declarations shared between runtime files (the rp__ prefix). Nothing here
 * is part of the public API or ABI. */
#ifndef RP_INTERNAL_H
#define RP_INTERNAL_H

#include <stdarg.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "raypace.h"

#define RP__ERRMSG_MAX 512

struct rp_context {
  rp_context_desc desc; /* with defaults filled in by rp__context_defaults */
  char last_error[RP__ERRMSG_MAX];
};

/* Per-mille quantiles kept of a volume's values (rp__value_range). */
#define RP__QUANTILES 1001

struct rp_volume {
  rp_context *ctx;
  uint64_t id; /* unique per volume object (rp__next_id) */
  uint32_t dims[3];
  /* `type` is how the voxels are stored, and always one a device reads
   * (RP_U8, RP_U16 or RP_F32); `data_type` is what the user gave. A data
   * value is the stored value plus `data_offset` (int8 and int16 are
   * stored offset by 128 and 32768; 32-bit integers as float32, offset
   * 0). min and max are in stored units, so that everything downstream
   * that maps values to TF positions works unchanged. */
  rp_voxel_type type;
  rp_voxel_type data_type;
  double data_offset;
  rp_orientation orientation;
  float spacing[3];
  double min, max;
  float quantile[RP__QUANTILES]; /* as rp__value_range.quantile */
  size_t voxel_count;
  void *data; /* owned; voxel_count values of `type` */
};

struct rp_tf {
  rp_context *ctx;
  uint64_t id; /* unique per TF object (rp__next_id): lets users of
                  derived data check that it was derived from this TF */
  int lut_size;
  float reference_step;
  float *lut; /* lut_size * 4 floats, RGBA, straight colour */
  /* Where the LUT's [0, 1] lies on a volume's values: resolved for each
   * volume by rp__tf_stored_range and nowhere else. */
  rp_tf_range range;
  double range_lo, range_hi;
};

/* What the histograms need to know of their volume, copied so that H does
 * not keep a pointer into an object the caller may destroy first. */
typedef struct rp__value_range {
  rp_voxel_type type; /* stored */
  double min, max;    /* stored units */
  double offset;      /* a data value is stored + offset */
  /* quantile[i]: the stored value below which i/1000 of the voxels lie
   * (0: min, 1000: max): what percentile ranges of a TF read. */
  float quantile[RP__QUANTILES];
} rp__value_range;

struct rp_histograms {
  rp_context *ctx;
  uint64_t vol_id; /* rp_volume.id of the volume it was built from */
  uint32_t dims[3];
  uint32_t blocks[3];
  uint32_t block_count;
  rp__value_range range;
  uint32_t *counts; /* block_count * RP_DENSITY_BINS */
};

struct rp_occupancy {
  rp_context *ctx;
  const rp_histograms *h; /* not owned; must outlive the occupancy */
  uint64_t tf_id;         /* rp_tf.id of the TF it was last built for */
  uint8_t *alpha_hist;    /* block_count * RP_OPACITY_BINS */
  /* Mean opacity of the volume's voxels in each opacity bin (bin 0: 0).
   * The cost model's ERT pre-pass draws these rather than bin centres:
   * bin 1 spans (0, 1/15], and a nearly transparent TF (alpha 0.004)
   * drawn at its centre 1/30 ends rays after a fraction of their real
   * depth. */
  float bin_alpha[RP_OPACITY_BINS];
  uint8_t *grid;          /* block_count */
  /* Per block, the share of its voxels whose density bin has a mean
   * opacity above 0: the samples there that show, and so are shaded.
   * The cost model's estimate of the shaded share. */
  float *visible;         /* block_count */
  /* The occupied blocks lie in [box_lo, box_end) along each axis (an
   * empty range when none is): the depth pass walks only that box. */
  uint32_t box_lo[3], box_end[3];
  /* Lowest and highest non-empty density bin over each block and its 26
   * neighbours: depends on H only, so it is computed once at build. */
  uint8_t *bin_lo, *bin_hi; /* bin_lo > bin_hi: no voxel at all */
  uint32_t empty;
};

/* Checks that `occ` was built for the transfer function with id `tf_id`
 * from the histograms of the volume with id `vol_id` (RP_EINVAL, message
 * prefixed by fn): same dims is not enough, an occupancy of another
 * volume or TF would let skipping drop visible samples without a trace.
 * One check for every entry point that takes an occupancy. */
int rp__occupancy_check(rp_context *ctx, const char *fn,
                        const rp_occupancy *occ, uint64_t tf_id,
                        uint64_t vol_id);

/* Defaults shared by the tuner and the controllers (rp_tune_desc,
 * rp_controller_desc): the density range and the largest rise of quality
 * per frame, 1 / 0.8 after seed 000 section 6.1 (Delta may shrink to
 * 0.8 Delta per frame). */
#define RP__RHO_MIN 1e-3
#define RP__RHO_MAX 1.0
#define RP__RAISE_LIMIT (1.0 / 0.8)
/* A caller's rp_space_desc (named `field` in messages) within raypace.h's
 * step and scale limits: 0 or RP_ERANGE. Zero fields are defaults. */
int rp__space_check(rp_context *ctx, const char *fn, const char *field,
                    const rp_space_desc *d);

/* ---- core.c ------------------------------------------------------------ */

void *rp__malloc(rp_context *ctx, size_t size);
void *rp__calloc(rp_context *ctx, size_t count, size_t size);
void rp__free(rp_context *ctx, void *ptr);
/* Records a message for rp_last_error and returns `err`, so that a failing
 * path reads `return rp__fail(ctx, RP_EINVAL, "...", ...);`. ctx may be
 * NULL (the message is dropped). */
int rp__fail(rp_context *ctx, int err, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;
void rp__clear_error(rp_context *ctx);
/* A process-wide unique, never-zero id for volumes and transfer functions,
 * so derived data (histograms, occupancy, device uploads) can be checked
 * against what it was derived from. */
uint64_t rp__next_id(void);
/* CLOCK_MONOTONIC, for every duration the library measures. */
uint64_t rp__now_ns(void);
double rp__now_ms(void);
int rp__thread_count(const rp_context *ctx);
/* Runs fn(i, user) for i in [0, n) on up to ctx's thread count threads,
 * each thread taking a contiguous range. Returns 0 or RP_ENOMEM. */
int rp__parallel_for(const rp_context *ctx, uint32_t n,
                     void (*fn)(uint32_t begin, uint32_t end, void *user),
                     void *user);

/* ---- volume.c ---------------------------------------------------------- */

/* 16^3 blocks along an axis of d voxels. Not (d + 15) / 16, which wraps
 * for d near 2^32. */
static inline uint32_t rp__blocks_along(uint32_t d) {
  return d / RP_BLOCK_SIZE + (d % RP_BLOCK_SIZE != 0);
}

size_t rp__voxel_size(rp_voxel_type type);
/* Validates an orientation (finite, orthonormal columns within 1e-3) and
 * writes it normalised to out; NULL or not known gives the identity.
 * `what` prefixes the message. */
int rp__orientation_check(rp_context *ctx, const char *what,
                          const rp_orientation *in, rp_orientation *out);
/* Takes ownership of `data` (allocated with rp__malloc on ctx), converts
 * signed and 32-bit integer voxels in place to the stored type, and
 * computes the range; rejects NaN/inf in float data. On failure frees
 * `data`. The orientation is left unknown. */
int rp__volume_adopt(rp_context *ctx, const uint32_t dims[3],
                     rp_voxel_type type, const float spacing[3], void *data,
                     rp_volume **out);
/* dims product and byte size with overflow checks, each axis within
 * RP_VOLUME_MAX_DIM, the bytes within the context's max_volume_bytes
 * (RP_ERANGE) and the memory the machine has (RP_ENOMEM, saying how much
 * was asked: call it before allocating the voxels); the message names
 * `what` (a file or function) and `field` (how the source names the
 * sizes: "field 'dims'", ...). */
int rp__volume_size(rp_context *ctx, const char *what, const char *field,
                    const uint64_t dims[3], rp_voxel_type type,
                    size_t *voxels, size_t *bytes);
/* A voxel spacing within [RP_SPACING_MIN, RP_SPACING_MAX]: 0, or
 * RP_ERANGE (RP_ENOTFINITE for NaN or an infinity) with "WHERE:
 * FIELD[AXIS] is V; must be in [1e-09, 1e+09] ..." (no [AXIS] when axis
 * is negative). Every path a spacing enters by calls it: the API and
 * each file format's field. */
int rp__spacing_check(rp_context *ctx, const char *where, const char *field,
                      int axis, double v);

/* Voxel (i, j, k) as a double, indices already in range. */
static inline double rp__voxel(const rp_volume *v, uint32_t i, uint32_t j,
                               uint32_t k) {
  size_t idx = ((size_t)k * v->dims[1] + j) * v->dims[0] + i;
  switch (v->type) {
  case RP_U8: return ((const uint8_t *)v->data)[idx];
  case RP_U16: return ((const uint16_t *)v->data)[idx];
  default: return ((const float *)v->data)[idx];
  }
}

/* ---- volume_header.c, volume_decode.c (the loader: volume_io.h) --------- */

/* A parsed file header, before any voxel is read. */
typedef struct rp__volume_header {
  uint64_t dims[3];
  rp_voxel_type type;
  float spacing[3];
  int big_endian;   /* data stored big-endian */
  int gzip;         /* payload is a gzip (or zlib) stream */
  uint64_t byte_skip; /* bytes skipped before the payload; for gzip, of the
                         inflated stream (as teem does) */
  int skip_to_end;  /* NRRD "byte skip: -1": payload is the file's tail */
  uint64_t line_skip; /* NRRD "line skip": lines skipped before byte skip */
  char data_file[1024]; /* detached payload path ("" = attached) */
  uint64_t payload_bytes; /* bytes the payload must hold exactly
                             (MetaImage's CompressedDataSize); 0: any */
  rp_orientation orientation; /* in LPS; known = 0: the file says nothing */
} rp__volume_header;

/* Parsers on memory, so that fuzz targets reach them without files.
 * `name` is used in messages. *header_len receives the offset where an
 * attached payload starts (NRRD only). */
int rp__nrrd_parse(rp_context *ctx, const char *name, const uint8_t *buf,
                   size_t len, rp__volume_header *hdr, size_t *header_len);
int rp__sidecar_parse(rp_context *ctx, const char *name, const uint8_t *buf,
                      size_t len, rp__volume_header *hdr);
/* Decodes a payload (raw or gzip, any endianness) into a new volume. */
int rp__volume_decode(rp_context *ctx, const char *name,
                      const rp__volume_header *hdr, const uint8_t *payload,
                      size_t len, rp_volume **out);

/* A transfer function file's text (rp_tf_load's format, `len` bytes, no
 * NUL inside, at most 1 MiB) into a new TF; rp_tf_load after reading the
 * file, and the fuzz target without one. `name` is used in messages. */
int rp__tf_parse(rp_context *ctx, const char *name, const char *text,
                 size_t len, rp_tf **out);

/* ---- transfer.c -------------------------------------------------------- */

/* A value in the volume's data units (HU for CT) in stored units. */
static inline double rp__volume_stored(const rp_volume *v, double data) {
  return data - v->data_offset;
}

/* The facts about a volume's values that a TF's range reads. */
void rp__volume_values(const rp_volume *v, rp__value_range *out);
/* The stored-value interval [out[0], out[1]] that the TF's LUT spans on
 * a volume whose values are `r` (rp_tf_range: [min, max], percentiles or
 * a window in data units). The one place TF positions are tied to a
 * volume: every renderer and every derived structure (occupancy, bricks,
 * AO) maps a stored value v to rp__value_to_x(v, out[0], out[1]). */
void rp__tf_stored_range(const rp_tf *tf, const rp__value_range *r,
                         double out[2]);
/* rp__tf_stored_range for a volume. */
void rp__tf_volume_range(const rp_tf *tf, const rp_volume *v,
                         double out[2]);

/* Position of a data value in TF space: (v - min) / (max - min), 0 when the
 * range is a single value. Not clamped. */
static inline double rp__value_to_x(double v, double min, double max) {
  return max > min ? (v - min) / (max - min) : 0.0;
}
/* The TF at x (clamped to [0, 1]), linear between LUT entries. */
/* A copy of `src` owned by `ctx`, with an id of its own. */
int rp__tf_clone(rp_context *ctx, const rp_tf *src, rp_tf **out);
/* Whether two TFs map every value alike: the same table and reference
 * step (ids aside). */
int rp__tf_same(const rp_tf *a, const rp_tf *b);
/* rp__raygen_init's checks of the camera alone (no volume, no
 * viewport), eye == center included. */
int rp__camera_check(rp_context *ctx, const rp_camera *cam);
void rp__tf_sample(const rp_tf *tf, double x, float rgba[4]);
/* Pre-integration (runtime/preint.c has the model). The table a backend
 * keeps for RP_EFFECT_PREINT: per LUT entry i, 8 floats: (tau, q_r, q_g,
 * q_b) at i and their integrals over positions [0, i] (LUT index units),
 * computed in double. */
void rp__preint_table(const float *lut, uint32_t lut_size, float *out);
/* The mean (tau, q) over TF positions [xa, xb] (either order, clamped to
 * [0, 1]), in double from the LUT alone: the oracle of the table. */
void rp__preint_mean(const rp_tf *tf, double xa, double xb, double out[4]);
/* A segment of (step / ref_step) = ratio with that mean: straight colour
 * and opacity. */
void rp__preint_classify(const double mean[4], double ratio,
                         double rgba[4]);
/* Largest alpha of the interpolated LUT over [x0, x1] (clamped). */
float rp__tf_alpha_max(const rp_tf *tf, double x0, double x1);
/* Counts of the LUT's entries with alpha above 0: prefix[i] of entries
 * 0 .. i-1, lut_size + 1 values. */
void rp__tf_alpha_prefix(const rp_tf *tf, uint32_t *prefix);
/* rp__tf_alpha_max(tf, x0, x1) > 0, exactly, in constant time with the
 * TF's prefix counts: what a mask over many intervals asks. */
int rp__tf_alpha_any(const rp_tf *tf, const uint32_t *prefix, double x0,
                     double x1);
/* Mean alpha of the interpolated LUT over [x0, x1]: the exact integral of
 * the piecewise-linear function divided by the width; the value at x0 when
 * x0 == x1. Zero exactly when alpha is zero over the whole interval. */
double rp__tf_alpha_mean(const rp_tf *tf, double x0, double x1);

/* ---- histogram.c ------------------------------------------------------- */

/* Data-value interval covered by density bin b: for integer data the
 * smallest and largest integer in the bin (lo > hi when no integer falls
 * in it), for float data the bin's edges. */
void rp__bin_value_range(const rp__value_range *r, int b, double *lo,
                         double *hi);
int rp__bin_of(const rp__value_range *r, double value);

/* ---- backend.c ----------------------------------------------------------- */

struct rp_backend_ops;
/* Opens device `index` of backend `name` as rp_device_create would choose
 * it (NULL: RP_BACKEND, else the first backend with that device), but
 * bare: its ops and impl without a front end, for a server running a
 * backend's ops on another process's behalf (backends/mpi). Neither a
 * host backend ("reference", "test": they read the front end's camera in
 * double, device.h) nor a named-only backend can be opened so
 * (RP_EUNSUPPORTED). The caller destroys it with ops->destroy(impl). */
int rp__backend_open(rp_context *ctx, const char *name, uint32_t index,
                     const struct rp_backend_ops **ops, void **impl,
                     rp_caps *caps);
/* The device's own simulated clock (rp_backend_ops.clock_ns): 1 with *ns
 * set when the device keeps one (the test backend, also under fault
 * injection), else 0, and its time is real time (rp__now_ns). The
 * device's owner thread only. */
int rp__device_clock_ns(const rp_device *dev, uint64_t *ns);
/* Sets the slowdown of a device opened with fault injection
 * (rp_fault_desc.slowdown, the same range) from its next operation on:
 * a test warms a device (its first render builds kernels, which lavapipe
 * counts as device time) before slowing it a thousandfold. The owner
 * thread, between operations. RP_EINVAL without fault injection. */
int rp__device_set_slowdown(rp_device *dev, double slowdown);

/* ---- predict.c: the probe's own cost ------------------------------------ */

/* The fewest rays a probe traces when the runtime scales it to the frame:
 * docs/pacing.md, "Prediction's own cost". */
#define RP__PROBE_MIN_RAYS 128
/* rp_frame_probe_compute tracing at most max_rays rays (a regular
 * subgrid of the pre-pass grid, every n-th ray per axis; 0 or above
 * RP_PROBE_MAX_RAYS: RP_PROBE_MAX_RAYS), so that its cost follows the
 * frame's. */
struct rp_frame_probe;
int rp__frame_probe_compute(rp_context *ctx, const rp_volume *vol,
                            const rp_tf *tf, const rp_occupancy *occ,
                            const rp_camera *cam,
                            const rp_render_desc *desc, uint32_t seed,
                            uint32_t frame, uint32_t max_rays,
                            struct rp_frame_probe *out);
/* The most rays a probe may trace to stay within budget_ms at ms_per_ray
 * (its own measured cost per ray): budget / cost, within
 * [RP__PROBE_MIN_RAYS, RP_PROBE_MAX_RAYS]; RP_PROBE_MAX_RAYS while no
 * cost is known (ms_per_ray <= 0 or NaN). */
uint32_t rp__probe_ray_budget(double budget_ms, double ms_per_ray);

/* ---- png.c ------------------------------------------------------------- */

int rp__png_write_rgb(rp_context *ctx, const char *path, const uint8_t *rgb,
                      uint32_t width, uint32_t height);

/* Whether the device builds kernels ahead (its backend has `prepare`). */
int rp__device_builds_ahead(const rp_device *dev);

/* ---- group.c ----------------------------------------------------------- */

struct rp_device_group;
/* Member i's device (NULL when i >= count), for code that reads a
 * group's device between frames (the frame engine, its clock). */
rp_device *rp__group_device(const struct rp_device_group *g, uint32_t i);
/* Member i's own clock (rp__device_clock_ns) as one clock across its
 * re-creations (a re-created device's starts again at 0): 1 with *ns,
 * or 0 when it keeps none. The coordinator's thread, between frames. */
int rp__group_clock_ns(const struct rp_device_group *g, uint32_t i,
                       uint64_t *ns);

/* Around a driver's set-up calls (OpenCL's first device query, Vulkan's
 * instance and device creation). Drivers keep what they allocate there
 * for the life of the process, some in libraries built without frame
 * pointers (hwloc under PoCL, Mesa's lavapipe), whose stacks LSan's fast
 * unwinder cannot walk: the report names no library, so no suppression
 * can match it. Under AddressSanitizer this thread's allocations in
 * between are not leak-checked; otherwise these do nothing. */
void rp__driver_setup_begin(void);
void rp__driver_setup_end(void);

#endif /* RP_INTERNAL_H */
