/* Block density histograms H (DESIGN section 2): 16^3 blocks, x fastest,
 * 64 bins over the volume's [min, max]; built once per volume. */
#include <math.h>
#include <string.h>

#include "internal.h"

int rp__bin_of(const rp__value_range *r, double value) {
  double b;
  if (r->type != RP_F32) {
    /* (v - min) * 64 / (max - min + 1) in integer arithmetic: exact, so
     * brute force and every backend agree to the voxel. Values outside
     * [min, max] (and NaN) are settled before any cast to an integer. */
    int64_t v, lo = (int64_t)r->min, hi = (int64_t)r->max;
    if (!(value > r->min))
      return 0;
    v = value >= r->max ? hi : (int64_t)value;
    return (int)((v - lo) * RP_DENSITY_BINS / (hi - lo + 1));
  }
  if (!(r->max > r->min) || !(value > r->min))
    return 0;
  b = floor((value - r->min) / (r->max - r->min) * RP_DENSITY_BINS);
  return b >= RP_DENSITY_BINS - 1 ? RP_DENSITY_BINS - 1 : (int)b;
}

void rp__bin_value_range(const rp__value_range *r, int b, double *lo,
                         double *hi) {
  if (r->type != RP_F32) {
    /* v is in bin b iff b*R <= (v-min)*64 < (b+1)*R, R = max - min + 1. */
    int64_t R = (int64_t)r->max - (int64_t)r->min + 1;
    int64_t a = ((int64_t)b * R + RP_DENSITY_BINS - 1) / RP_DENSITY_BINS;
    int64_t e = ((int64_t)(b + 1) * R + RP_DENSITY_BINS - 1) /
                    RP_DENSITY_BINS - 1;
    *lo = r->min + (double)a;
    *hi = r->min + (double)e;
    return;
  }
  {
    double w = (r->max - r->min) / RP_DENSITY_BINS;
    *lo = r->min + b * w;
    *hi = b == RP_DENSITY_BINS - 1 ? r->max : r->min + (b + 1) * w;
  }
}

typedef struct build_job {
  const rp_volume *vol;
  rp_histograms *h;
  const uint8_t *table; /* bin per value for integer types, else NULL */
} build_job;

/* One unit of work is a row of blocks along x (fixed by, bz): rows write
 * disjoint counters, so threads need no locks and the sums are exact. */
static void build_rows(uint32_t begin, uint32_t end, void *user) {
  const build_job *job = user;
  const rp_volume *v = job->vol;
  rp_histograms *h = job->h;
  uint32_t row, x, y, z;
  for (row = begin; row < end; row++) {
    uint32_t by = row % h->blocks[1], bz = row / h->blocks[1];
    uint32_t y0 = by * RP_BLOCK_SIZE, z0 = bz * RP_BLOCK_SIZE;
    uint32_t y1 = y0 + RP_BLOCK_SIZE, z1 = z0 + RP_BLOCK_SIZE;
    uint32_t *row_counts = h->counts + (size_t)row * h->blocks[0] *
                                           RP_DENSITY_BINS;
    if (y1 > v->dims[1])
      y1 = v->dims[1];
    if (z1 > v->dims[2])
      z1 = v->dims[2];
    for (z = z0; z < z1; z++) {
      for (y = y0; y < y1; y++) {
        size_t base = ((size_t)z * v->dims[1] + y) * v->dims[0];
        for (x = 0; x < v->dims[0]; x++) {
          uint32_t *bc = row_counts + (size_t)(x / RP_BLOCK_SIZE) *
                                          RP_DENSITY_BINS;
          int bin;
          if (v->type == RP_U8)
            bin = job->table[((const uint8_t *)v->data)[base + x]];
          else if (v->type == RP_U16)
            bin = job->table[((const uint16_t *)v->data)[base + x]];
          else
            bin = rp__bin_of(&h->range, ((const float *)v->data)[base + x]);
          bc[bin]++;
        }
      }
    }
  }
}

int rp_histograms_build(rp_context *ctx, const rp_volume *vol,
                        rp_histograms **out) {
  rp_histograms *h;
  build_job job;
  uint8_t *table = NULL;
  uint64_t nblocks = 1;
  int a, err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (vol == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_histograms_build: vol and out are "
                    "required");
  h = rp__calloc(ctx, 1, sizeof *h);
  if (h == NULL)
    return rp__fail(ctx, RP_ENOMEM, "histograms: out of memory");
  h->ctx = ctx;
  for (a = 0; a < 3; a++) {
    h->dims[a] = vol->dims[a];
    h->blocks[a] = rp__blocks_along(vol->dims[a]);
    nblocks *= h->blocks[a];
  }
  /* Blocks and their rows are counted in 32 bits and the counters fill
   * block_count * 64 words: refuse grids beyond that, not wrap. */
  if (nblocks > UINT32_MAX / RP_DENSITY_BINS) {
    rp__free(ctx, h);
    return rp__fail(ctx, RP_ERANGE, "histograms: %u x %u x %u blocks are "
                    "more than this build can count", vol->dims[0] / 16u,
                    vol->dims[1] / 16u, vol->dims[2] / 16u);
  }
  h->block_count = (uint32_t)nblocks;
  h->vol_id = vol->id;
  rp__volume_values(vol, &h->range);
  h->counts = rp__calloc(ctx, (size_t)h->block_count * RP_DENSITY_BINS,
                         sizeof *h->counts);
  if (vol->type != RP_F32)
    table = rp__malloc(ctx, vol->type == RP_U8 ? 256 : 65536);
  if (h->counts == NULL || (vol->type != RP_F32 && table == NULL)) {
    uint32_t blocks = h->block_count;
    rp__free(ctx, table);
    rp_histograms_destroy(h);
    return rp__fail(ctx, RP_ENOMEM, "histograms: out of memory for %u "
                    "blocks", blocks);
  }
  if (table != NULL) {
    uint32_t v, n = vol->type == RP_U8 ? 256 : 65536;
    for (v = 0; v < n; v++)
      table[v] = (uint8_t)rp__bin_of(&h->range, v);
  }
  job.vol = vol;
  job.h = h;
  job.table = table;
  err = rp__parallel_for(ctx, h->blocks[1] * h->blocks[2], build_rows, &job);
  rp__free(ctx, table);
  if (err != 0) {
    rp_histograms_destroy(h);
    return rp__fail(ctx, err, "histograms: worker threads failed");
  }
  *out = h;
  return 0;
}

void rp_histograms_destroy(rp_histograms *h) {
  if (h == NULL)
    return;
  rp__free(h->ctx, h->counts);
  rp__free(h->ctx, h);
}

uint32_t rp_histograms_block_count(const rp_histograms *h) {
  return h != NULL ? h->block_count : 0;
}

const uint32_t *rp_histograms_block(const rp_histograms *h, uint32_t b) {
  if (h == NULL || b >= h->block_count)
    return NULL;
  return h->counts + (size_t)b * RP_DENSITY_BINS;
}

int rp_histograms_bin_of(const rp_histograms *h, double value) {
  return h != NULL ? rp__bin_of(&h->range, value) : -1;
}
