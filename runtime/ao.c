/* Ambient occlusion (DESIGN section 8, seed 004): the scalar C reference,
 * the brick mask, and the job a device receives. The formula and the
 * bricking rule are stated in include/raypace_ao.h and, for kernels, in
 * backends/README.md; this file is the oracle both are held to.
 *
 * Numerics: every quantity is double here; the inputs the devices get in
 * float (step, offset, directions) are rounded to float first and widened,
 * so the reference and the kernels sample the same positions up to the
 * kernels' own float arithmetic. Transmittance only ever multiplies by
 * factors in [0, 1], so it cannot grow or go negative, and the mean of
 * M * L such values cannot leave [0, 1]. */
#include <math.h>
#include <string.h>

#include "ao.h"
#include "bounds.h"

/* L and M: 8 x 16 costs about what 16 x 8 does at 0.6 of its error: at
 * R = 8 four or eight samples step over thin structures, and more
 * directions cannot mend that (docs/ao.md, "Measured"). */
#define AO_DEFAULT_DIRECTIONS 8u
#define AO_DEFAULT_SAMPLES 16u
#define AO_DEFAULT_RADIUS 8.0f
#define AO_DEFAULT_OFFSET 1.0f
/* Slices of z per progress report of the reference: small enough for a
 * smooth bar, large enough that a report costs nothing. */
#define AO_PROGRESS_STEPS 64u

void rp_ao_direction(uint32_t l, uint32_t count, float d[3]) {
  const double golden = 3.14159265358979323846 * (3.0 - sqrt(5.0));
  double z, r, phi;
  if (count == 0) {
    d[0] = d[1] = 0.0f;
    d[2] = 1.0f;
    return;
  }
  z = 1.0 - (2.0 * (double)l + 1.0) / (double)count;
  r = sqrt(fmax(0.0, 1.0 - z * z));
  phi = (double)l * golden;
  d[0] = (float)(r * cos(phi));
  d[1] = (float)(r * sin(phi));
  d[2] = (float)z;
}

int rp__ao_desc_resolve(rp_context *ctx, const char *fn,
                        const rp_ao_desc *in, rp_ao_desc *out) {
  rp_ao_desc d = {0};
  if (in != NULL)
    d = *in;
  if (d.directions == 0)
    d.directions = AO_DEFAULT_DIRECTIONS;
  if (d.samples == 0)
    d.samples = AO_DEFAULT_SAMPLES;
  if (d.radius == 0.0f)
    d.radius = AO_DEFAULT_RADIUS;
  if (d.offset == 0.0f)
    d.offset = AO_DEFAULT_OFFSET;
  if (d.directions > RP_AO_MAX_DIRECTIONS)
    return RP__AO_FAIL(ctx, RP_ERANGE, "%s: directions %u is above %u", fn,
                       d.directions, RP_AO_MAX_DIRECTIONS);
  if (d.samples > RP_AO_MAX_SAMPLES)
    return RP__AO_FAIL(ctx, RP_ERANGE, "%s: samples %u is above %u", fn,
                       d.samples, RP_AO_MAX_SAMPLES);
  if (!isfinite(d.radius) || !isfinite(d.offset))
    return RP__AO_FAIL(ctx, RP_ENOTFINITE,
                       "%s: radius %g and offset %g must be finite", fn,
                       (double)d.radius, (double)d.offset);
  if (!(d.radius > 0.0f && d.radius <= RP_AO_MAX_RADIUS))
    return RP__AO_FAIL(ctx, RP_ERANGE,
                       "%s: radius %g is outside (0, %g] voxels", fn,
                       (double)d.radius, (double)RP_AO_MAX_RADIUS);
  if (!(d.offset > 0.0f && d.offset < d.radius))
    return RP__AO_FAIL(ctx, RP_ERANGE,
                       "%s: offset %g is outside (0, radius %g)", fn,
                       (double)d.offset, (double)d.radius);
  if (d.unbricked != 0 && d.unbricked != 1)
    return RP__AO_FAIL(ctx, RP_EINVAL, "%s: unbricked is %d, not 0 or 1", fn,
                       d.unbricked);
  *out = d;
  return 0;
}

float rp__ao_step(const rp_ao_desc *d) {
  return (d->radius - d->offset) / (float)d->samples;
}

int rp__ao_dirs(rp_context *ctx, uint32_t count, float **out) {
  uint32_t l;
  float *dirs = rp__malloc(ctx, (size_t)count * 4 * sizeof *dirs);
  if (dirs == NULL)
    return RP__AO_FAIL(ctx, RP_ENOMEM,
                       "ambient occlusion: out of memory for %u directions",
                       count);
  for (l = 0; l < count; l++) {
    rp_ao_direction(l, count, dirs + 4 * (size_t)l);
    dirs[4 * (size_t)l + 3] = 0.0f;
  }
  *out = dirs;
  return 0;
}

void rp__ao_brick_grid(const uint32_t dims[3], uint32_t grid[3]) {
  int a;
  /* Not (d + 3) / 4, which wraps for d near 2^32. */
  for (a = 0; a < 3; a++)
    grid[a] = dims[a] / RP_AO_BRICK + (dims[a] % RP_AO_BRICK != 0);
}

void rp__ao_job(const rp_ao_plan *plan, const uint32_t lo[3],
                const uint32_t end[3], float ref_step, double value_min,
                double value_max, uint32_t lut_size, rp_ao_job *job) {
  memset(job, 0, sizeof *job);
  memcpy(job->lo, lo, sizeof job->lo);
  memcpy(job->end, end, sizeof job->end);
  job->directions = plan->desc.directions;
  job->samples = plan->desc.samples;
  job->offset = plan->desc.offset;
  job->step = plan->step;
  job->ref_step = ref_step;
  job->value_min = (float)value_min;
  job->value_max = (float)value_max;
  job->lut_size = lut_size;
  job->dirs = plan->dirs;
  job->bricks = plan->bricks;
  memcpy(job->brick_grid, plan->brick_grid, sizeof job->brick_grid);
}

/* ---- Brick mask ---------------------------------------------------------- */

/* Each brick's value range with a one-voxel overlap: the overlap covers
 * every trilinear cell a brick's voxels are corners of. It depends on
 * the volume alone, and reading every voxel is what a mask costs (about
 * 70 ms for a 256^3 volume on this 2-core VM), so it is kept per volume
 * and a new TF's mask reads only the ranges (rp__ao_ranges). */
struct rp__ao_ranges {
  rp_context *ctx;
  uint64_t vol_id;
  uint32_t grid[3];
  float *range; /* 2 per brick, x fastest: min and max */
};

typedef struct range_job {
  const rp_volume *vol;
  const uint32_t *grid;
  float *range;
} range_job;

/* Bricks of z-layers [begin, end). Values are held in float: voxels of
 * every type are exact in it (8 and 16 bits, or float themselves). */
static void range_layers(uint32_t begin, uint32_t end, void *user) {
  range_job *j = user;
  const rp_volume *vol = j->vol;
  const uint32_t *g = j->grid;
  uint32_t bx, by, bz;
  for (bz = begin; bz < end; bz++)
    for (by = 0; by < g[1]; by++)
      for (bx = 0; bx < g[0]; bx++) {
        uint32_t b[3] = {bx, by, bz}, lo[3], hi[3], x, y, z;
        double vmin = INFINITY, vmax = -INFINITY;
        size_t at = ((size_t)bz * g[1] + by) * g[0] + bx;
        int a;
        for (a = 0; a < 3; a++) {
          lo[a] = b[a] * RP_AO_BRICK;
          lo[a] = lo[a] > 0 ? lo[a] - 1 : 0;
          hi[a] = b[a] * RP_AO_BRICK + RP_AO_BRICK + 1; /* exclusive */
          if (hi[a] > vol->dims[a])
            hi[a] = vol->dims[a];
        }
        for (z = lo[2]; z < hi[2]; z++)
          for (y = lo[1]; y < hi[1]; y++)
            for (x = lo[0]; x < hi[0]; x++) {
              double v = rp__voxel(vol, x, y, z);
              vmin = v < vmin ? v : vmin;
              vmax = v > vmax ? v : vmax;
            }
        j->range[2 * at] = (float)vmin;
        j->range[2 * at + 1] = (float)vmax;
      }
}

int rp__ao_ranges_build(rp_context *ctx, const rp_volume *vol,
                        rp__ao_ranges **out) {
  rp__ao_ranges *r;
  range_job j;
  size_t n;
  int err;
  if ((r = rp__calloc(ctx, 1, sizeof *r)) == NULL)
    return RP__AO_FAIL(ctx, RP_ENOMEM, "ambient occlusion: out of memory");
  r->ctx = ctx;
  r->vol_id = vol->id;
  rp__ao_brick_grid(vol->dims, r->grid);
  n = (size_t)r->grid[0] * r->grid[1] * r->grid[2];
  if ((r->range = rp__malloc(ctx, 2 * n * sizeof *r->range)) == NULL) {
    rp__free(ctx, r);
    return RP__AO_FAIL(ctx, RP_ENOMEM,
                       "ambient occlusion: out of memory for %zu bricks", n);
  }
  j.vol = vol;
  j.grid = r->grid;
  j.range = r->range;
  if ((err = rp__parallel_for(ctx, r->grid[2], range_layers, &j)) != 0) {
    rp__ao_ranges_destroy(r);
    return err;
  }
  *out = r;
  return 0;
}

void rp__ao_ranges_destroy(rp__ao_ranges *r) {
  if (r == NULL)
    return;
  rp__free(r->ctx, r->range);
  rp__free(r->ctx, r);
}

uint64_t rp__ao_ranges_volume(const rp__ao_ranges *r) { return r->vol_id; }

/* The mask from the ranges: a brick is full when the TF is non-zero
 * anywhere on its range. */
static int brick_mask(rp_context *ctx, const rp_volume *vol,
                      const rp_tf *tf, const rp__ao_ranges *r,
                      uint8_t **mask, uint64_t *full) {
  size_t n = (size_t)r->grid[0] * r->grid[1] * r->grid[2], b;
  double span[2];
  uint8_t *m = rp__malloc(ctx, n);
  uint32_t *prefix = rp__malloc(ctx, ((size_t)tf->lut_size + 1) *
                                         sizeof *prefix);
  if (m == NULL || prefix == NULL) {
    rp__free(ctx, m);
    rp__free(ctx, prefix);
    return RP__AO_FAIL(ctx, RP_ENOMEM,
                       "ambient occlusion: out of memory for %zu bricks", n);
  }
  /* The TF's non-zero entries counted once: each brick's test is then
   * constant time, where scanning its range of the table made a plan
   * of a 256^3 volume take about 60 ms here. */
  rp__tf_alpha_prefix(tf, prefix);
  rp__tf_volume_range(tf, vol, span);
  *full = 0;
  for (b = 0; b < n; b++) {
    m[b] = (uint8_t)rp__tf_alpha_any(
        tf, prefix, rp__value_to_x(r->range[2 * b], span[0], span[1]),
        rp__value_to_x(r->range[2 * b + 1], span[0], span[1]));
    *full += m[b];
  }
  rp__free(ctx, prefix);
  *mask = m;
  return 0;
}

/* ---- Reference AO -------------------------------------------------------- */

uint8_t rp__ao_voxel(const rp_volume *vol, const rp_tf *tf,
                     const rp_ao_job *s, uint32_t i, uint32_t j,
                     uint32_t k) {
  double acc = 0.0, ao;
  uint32_t l, m;
  float ref_step = rp_tf_reference_step(tf);
  for (l = 0; l < s->directions; l++) {
    const float *d = s->dirs + 4 * (size_t)l;
    double T = 1.0, I = 0.0;
    for (m = 0; m < s->samples; m++) {
      double t = (double)s->offset + (double)m * (double)s->step, p[3];
      double alpha = 0.0;
      int a, inside = 1;
      p[0] = (double)i + t * (double)d[0];
      p[1] = (double)j + t * (double)d[1];
      p[2] = (double)k + t * (double)d[2];
      for (a = 0; a < 3; a++)
        inside &= p[a] >= -0.5 && p[a] <= (double)vol->dims[a] - 0.5;
      if (inside) {
        float rgba[4];
        double v = rp__sample_trilinear(vol, p);
        rp__tf_sample(tf, rp__value_to_x(v, s->value_min, s->value_max),
                      rgba);
        alpha = rp_opacity_correct(rgba[3], s->step, ref_step);
      }
      T *= 1.0 - alpha;
      I += T;
    }
    acc += I / (double)s->samples;
  }
  ao = acc / (double)s->directions;
  ao = ao < 0.0 ? 0.0 : ao > 1.0 ? 1.0 : ao;
  return (uint8_t)floor(ao * 255.0 + 0.5);
}

/* Whether voxel (i, j, k) is computed: its brick is full, or there is no
 * mask. */
static int voxel_wanted(const rp_ao_job *s, uint32_t i, uint32_t j,
                        uint32_t k) {
  const uint32_t *g = s->brick_grid;
  if (s->bricks == NULL)
    return 1;
  return s->bricks[((size_t)(k / RP_AO_BRICK) * g[1] + j / RP_AO_BRICK) *
                       g[0] +
                   i / RP_AO_BRICK] != 0;
}

void rp__ao_reference_job(const rp_volume *vol, const rp_tf *tf,
                          const rp_ao_job *job, uint32_t z0, uint32_t z1,
                          uint8_t *out) {
  const uint32_t *lo = job->lo, *end = job->end;
  uint32_t nx = end[0] - lo[0], ny = end[1] - lo[1], i, j, k;
  for (k = z0; k < z1; k++)
    for (j = lo[1]; j < end[1]; j++)
      for (i = lo[0]; i < end[0]; i++) {
        size_t o = ((size_t)(k - lo[2]) * ny + (j - lo[1])) * nx +
                   (i - lo[0]);
        out[o] = voxel_wanted(job, i, j, k)
                     ? rp__ao_voxel(vol, tf, job, i, j, k)
                     : 255;
      }
}

void rp__ao_reference_box(const rp_volume *vol, const rp_tf *tf,
                          const rp_ao_plan *s, const uint32_t lo[3],
                          const uint32_t end[3], uint32_t z0, uint32_t z1,
                          uint8_t *out) {
  rp_ao_job job;
  double span[2];
  rp__tf_volume_range(tf, vol, span);
  rp__ao_job(s, lo, end, rp_tf_reference_step(tf), span[0], span[1],
             (uint32_t)tf->lut_size, &job);
  rp__ao_reference_job(vol, tf, &job, z0, z1, out);
}

typedef struct ref_job {
  const rp_volume *vol;
  const rp_tf *tf;
  const rp_ao_plan *plan;
  uint32_t z0;
  uint8_t *out;
} ref_job;

static void ref_layers(uint32_t begin, uint32_t end, void *user) {
  const ref_job *j = user;
  uint32_t lo[3] = {0, 0, 0};
  rp__ao_reference_box(j->vol, j->tf, j->plan, lo, j->vol->dims,
                       j->z0 + begin, j->z0 + end, j->out);
}

int rp__ao_new(rp_context *ctx, const rp_ao_plan *plan, rp_ao **out) {
  size_t n = (size_t)plan->dims[0] * plan->dims[1] * plan->dims[2];
  rp_ao *ao;
  /* Failures return their code here rather than rp__fail's, so that the
   * analyzer sees *out set on every path that returns 0. */
  if (rp__check_memory(ctx, "ambient occlusion: a byte per voxel", n) != 0)
    return RP_ENOMEM;
  ao = rp__calloc(ctx, 1, sizeof *ao);
  if (ao == NULL) {
    rp__fail(ctx, RP_ENOMEM, "ambient occlusion: out of memory");
    return RP_ENOMEM;
  }
  ao->ctx = ctx;
  ao->vol_id = plan->vol_id;
  ao->tf_id = plan->tf_id;
  memcpy(ao->dims, plan->dims, sizeof ao->dims);
  ao->desc = plan->desc;
  ao->bricks_computed = plan->full;
  ao->bricks_total = plan->total;
  ao->data = rp__malloc(ctx, n);
  if (ao->data == NULL) {
    rp__free(ctx, ao);
    rp__fail(ctx, RP_ENOMEM, "ambient occlusion: out of memory for %zu "
             "voxels", n);
    return RP_ENOMEM;
  }
  *out = ao;
  return 0;
}

/* The summed-volume table of the mask: sum[z][y][x] = full bricks with
 * all three indices below (x, y, z). */
static int full_sum_build(rp_ao_plan *p) {
  const uint32_t *g = p->brick_grid;
  size_t sx = (size_t)g[0] + 1, sy = (size_t)g[1] + 1;
  uint32_t x, y, z;
  uint32_t *t = rp__calloc(p->ctx, sx * sy * ((size_t)g[2] + 1), sizeof *t);
  if (t == NULL)
    return RP__AO_FAIL(p->ctx, RP_ENOMEM,
                       "ambient occlusion: out of memory for the brick counts");
  for (z = 1; z <= g[2]; z++)
    for (y = 1; y <= g[1]; y++)
      for (x = 1; x <= g[0]; x++) {
        size_t i = ((size_t)z * sy + y) * sx + x;
        /* Inclusion-exclusion over the seven lower neighbours. */
        t[i] = p->bricks[(((size_t)z - 1) * g[1] + (y - 1)) * g[0] + (x - 1)] +
               t[i - 1] + t[i - sx] + t[i - sx * sy] - t[i - 1 - sx] -
               t[i - 1 - sx * sy] - t[i - sx - sx * sy] +
               t[i - 1 - sx - sx * sy];
      }
  p->full_sum = t;
  return 0;
}

int rp_ao_plan_create(rp_context *ctx, const rp_volume *vol,
                      const rp_tf *tf, const rp_ao_desc *desc,
                      rp_ao_plan **out) {
  return rp__ao_plan_create(ctx, vol, tf, desc, NULL, out);
}

int rp__ao_plan_create(rp_context *ctx, const rp_volume *vol,
                       const rp_tf *tf, const rp_ao_desc *desc,
                       const rp__ao_ranges *ranges, rp_ao_plan **out) {
  static const char *fn = "rp_ao_plan_create";
  rp__ao_ranges *own = NULL;
  rp_ao_plan *p;
  rp_ao_desc d = {0};
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (vol == NULL || tf == NULL || out == NULL)
    return RP__AO_FAIL(ctx, RP_EINVAL, "%s: vol, tf and out are required", fn);
  if (ranges != NULL && ranges->vol_id != vol->id)
    return RP__AO_FAIL(ctx, RP_EINVAL, "%s: the brick ranges are of "
                       "another volume", fn);
  if ((err = rp__ao_desc_resolve(ctx, fn, desc, &d)) != 0)
    return err;
  if ((p = rp__calloc(ctx, 1, sizeof *p)) == NULL) {
    rp__fail(ctx, RP_ENOMEM, "%s: out of memory", fn);
    return RP_ENOMEM; /* not rp__fail's: *out is set on every 0 */
  }
  p->ctx = ctx;
  p->vol_id = vol->id;
  p->tf_id = tf->id;
  memcpy(p->dims, vol->dims, sizeof p->dims);
  p->desc = d;
  p->step = rp__ao_step(&d);
  rp__ao_brick_grid(vol->dims, p->brick_grid);
  p->total = (uint64_t)p->brick_grid[0] * p->brick_grid[1] *
             p->brick_grid[2];
  p->full = p->total;
  err = rp__ao_dirs(ctx, d.directions, &p->dirs);
  if (err == 0 && !d.unbricked) {
    if (ranges == NULL && (err = rp__ao_ranges_build(ctx, vol, &own)) == 0)
      ranges = own;
    if (err == 0)
      err = brick_mask(ctx, vol, tf, ranges, &p->bricks, &p->full);
    if (err == 0)
      err = full_sum_build(p);
    rp__ao_ranges_destroy(own);
  }
  if (err != 0) {
    rp_ao_plan_destroy(p);
    return err;
  }
  *out = p;
  return 0;
}

void rp_ao_plan_destroy(rp_ao_plan *p) {
  if (p == NULL)
    return;
  rp__free(p->ctx, p->dirs);
  rp__free(p->ctx, p->bricks);
  rp__free(p->ctx, p->full_sum);
  rp__free(p->ctx, p);
}

uint64_t rp_ao_plan_full_bricks(const rp_ao_plan *p, const uint32_t lo[3],
                                const uint32_t end[3]) {
  uint32_t b0[3], b1[3];
  size_t sx, sy;
  int a;
  if (p == NULL || lo == NULL || end == NULL)
    return 0;
  for (a = 0; a < 3; a++) {
    uint32_t e = end[a] < p->dims[a] ? end[a] : p->dims[a];
    if (lo[a] >= e)
      return 0;
    b0[a] = lo[a] / RP_AO_BRICK;
    b1[a] = (e - 1) / RP_AO_BRICK + 1;
  }
  if (p->full_sum == NULL)
    return (uint64_t)(b1[0] - b0[0]) * (b1[1] - b0[1]) * (b1[2] - b0[2]);
  sx = (size_t)p->brick_grid[0] + 1;
  sy = (size_t)p->brick_grid[1] + 1;
#define AT(x, y, z) ((int64_t)p->full_sum[((size_t)(z) * sy + (y)) * sx + (x)])
  return (uint64_t)(AT(b1[0], b1[1], b1[2]) - AT(b0[0], b1[1], b1[2]) -
                    AT(b1[0], b0[1], b1[2]) - AT(b1[0], b1[1], b0[2]) +
                    AT(b0[0], b0[1], b1[2]) + AT(b0[0], b1[1], b0[2]) +
                    AT(b1[0], b0[1], b0[2]) - AT(b0[0], b0[1], b0[2]));
#undef AT
}

int rp_ao_compute_reference(rp_context *ctx, const rp_volume *vol,
                            const rp_tf *tf, const rp_ao_desc *desc,
                            rp_progress_fn progress, void *user,
                            rp_ao **out) {
  rp_ao_plan *plan = NULL;
  rp_ao *ao = NULL;
  ref_job j;
  uint32_t z, chunk;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (vol == NULL || tf == NULL || out == NULL)
    return RP__AO_FAIL(ctx, RP_EINVAL,
                       "rp_ao_compute_reference: vol, tf and out are required");
  if ((err = rp_ao_plan_create(ctx, vol, tf, desc, &plan)) != 0)
    return err;
  if ((err = rp__ao_new(ctx, plan, &ao)) != 0) {
    rp_ao_plan_destroy(plan);
    return err;
  }
  j.vol = vol;
  j.tf = tf;
  j.plan = plan;
  j.out = ao->data;
  /* Chunks of whole z-layers, each spread over the workers, so that the
   * calling thread can report progress between them. */
  chunk = vol->dims[2] / AO_PROGRESS_STEPS + 1;
  for (z = 0; z < vol->dims[2] && err == 0; z += chunk) {
    uint32_t n = vol->dims[2] - z < chunk ? vol->dims[2] - z : chunk;
    j.z0 = z;
    err = rp__parallel_for(ctx, n, ref_layers, &j);
    if (err == 0 && progress != NULL)
      progress((double)(z + n) / (double)vol->dims[2], user);
  }
  rp_ao_plan_destroy(plan);
  if (err != 0) {
    rp_ao_destroy(ao);
    return err;
  }
  *out = ao;
  return 0;
}

void rp_ao_destroy(rp_ao *ao) {
  if (ao == NULL)
    return;
  rp__free(ao->ctx, ao->data);
  rp__free(ao->ctx, ao);
}

const uint8_t *rp_ao_data(const rp_ao *ao, uint32_t dims[3]) {
  if (ao == NULL)
    return NULL;
  if (dims != NULL)
    memcpy(dims, ao->dims, sizeof ao->dims);
  return ao->data;
}

void rp_ao_get_desc(const rp_ao *ao, rp_ao_desc *desc) {
  if (ao != NULL && desc != NULL)
    *desc = ao->desc;
}

void rp_ao_bricks(const rp_ao *ao, uint64_t *computed, uint64_t *total) {
  if (computed != NULL)
    *computed = ao != NULL ? ao->bricks_computed : 0;
  if (total != NULL)
    *total = ao != NULL ? ao->bricks_total : 0;
}

int rp__ao_check(rp_context *ctx, const char *fn, const rp_ao *ao,
                 uint64_t vol_id, uint64_t tf_id) {
  if (ao->vol_id != vol_id)
    return RP__AO_FAIL(ctx, RP_EINVAL,
                       "%s: the AO volume was computed for another volume", fn);
  if (ao->tf_id != tf_id)
    return RP__AO_FAIL(ctx, RP_EINVAL,
                       "%s: the AO volume was computed for another transfer "
                       "function (tf id %llu, AO for %llu)",
                       fn, (unsigned long long)tf_id,
                       (unsigned long long)ao->tf_id);
  return 0;
}

void rp__ao_view(const rp_ao *ao, rp_volume *view) {
  int a;
  memset(view, 0, sizeof *view);
  view->ctx = ao->ctx;
  view->type = RP_U8;
  for (a = 0; a < 3; a++) {
    view->dims[a] = ao->dims[a];
    view->spacing[a] = 1.0f;
  }
  view->min = 0.0;
  view->max = 255.0;
  view->voxel_count = (size_t)ao->dims[0] * ao->dims[1] * ao->dims[2];
  view->data = ao->data;
}
