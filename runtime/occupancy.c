/* Opacity histograms H-alpha and the occupancy grid (DESIGN section 2),
 * recomputed on every transfer-function change from H alone.
 *
 * Occupancy here is stricter than "no voxel of the block maps to non-zero
 * opacity, dilated by one block": trilinear sampling interpolates between
 * voxel values, and an interpolated value can cross a peak of the TF that
 * no voxel value hits (air next to bone passing through soft tissue). So a
 * block is empty only when the TF is zero over the whole interval from the
 * lowest to the highest non-empty density bin of the block and its 26
 * neighbours. Every sample taken inside a block's region interpolates
 * voxels of that neighbourhood, so its value lies in the interval and its
 * opacity is zero: skipping such blocks cannot change the image. The
 * neighbourhood also gives the dilation DESIGN asks for. */
#include <string.h>

#include "internal.h"
#include "passes.h"

/* Per block, the lowest and highest non-empty bin, then a 3x3x3 min/max
 * filter (separable: exact for a box). */
static void neighbourhood_bins(rp_occupancy *occ) {
  const rp_histograms *h = occ->h;
  uint32_t n = h->block_count, b, a;
  uint8_t *lo = occ->bin_lo, *hi = occ->bin_hi;
  for (b = 0; b < n; b++) {
    const uint32_t *c = h->counts + (size_t)b * RP_DENSITY_BINS;
    int l = 0, u = RP_DENSITY_BINS - 1;
    while (l < RP_DENSITY_BINS && c[l] == 0)
      l++;
    while (u >= 0 && c[u] == 0)
      u--;
    /* Every block holds at least one voxel, so l <= u always. */
    lo[b] = (uint8_t)l;
    hi[b] = (uint8_t)u;
  }
  for (a = 0; a < 3; a++) {
    uint32_t stride = a == 0 ? 1 : a == 1 ? h->blocks[0]
                                          : h->blocks[0] * h->blocks[1];
    uint32_t len = h->blocks[a];
    for (b = 0; b < n; b++) {
      uint32_t pos = (b / stride) % len;
      /* Process each line once, from its first block. */
      uint8_t prev_lo, prev_hi, i;
      uint32_t k;
      if (pos != 0)
        continue;
      prev_lo = lo[b], prev_hi = hi[b];
      for (k = 0; k < len; k++) {
        uint32_t cur = b + k * stride;
        uint8_t cl = lo[cur], ch = hi[cur], nl = cl, nh = ch;
        if (k > 0) {
          nl = prev_lo < nl ? prev_lo : nl;
          nh = prev_hi > nh ? prev_hi : nh;
        }
        if (k + 1 < len) {
          i = lo[cur + stride];
          nl = i < nl ? i : nl;
          i = hi[cur + stride];
          nh = i > nh ? i : nh;
        }
        prev_lo = cl, prev_hi = ch;
        lo[cur] = nl, hi[cur] = nh;
      }
    }
  }
}

int rp_occupancy_build(rp_context *ctx, const rp_histograms *h,
                       const rp_tf *tf, rp_occupancy **out) {
  rp_occupancy *occ;
  size_t n;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (h == NULL || tf == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_occupancy_build: h, tf and out are "
                    "required");
  n = h->block_count;
  occ = rp__calloc(ctx, 1, sizeof *occ);
  if (occ == NULL)
    return rp__fail(ctx, RP_ENOMEM, "occupancy: out of memory");
  occ->ctx = ctx;
  occ->h = h;
  occ->alpha_hist = rp__malloc(ctx, n * RP_OPACITY_BINS);
  occ->grid = rp__malloc(ctx, n);
  occ->visible = rp__malloc(ctx, n * sizeof *occ->visible);
  occ->bin_lo = rp__malloc(ctx, n);
  occ->bin_hi = rp__malloc(ctx, n);
  if (occ->alpha_hist == NULL || occ->grid == NULL || occ->visible == NULL ||
      occ->bin_lo == NULL || occ->bin_hi == NULL) {
    rp_occupancy_destroy(occ);
    return rp__fail(ctx, RP_ENOMEM, "occupancy: out of memory for %zu "
                    "blocks", n);
  }
  neighbourhood_bins(occ);
  err = rp_occupancy_update(occ, tf);
  if (err != 0) {
    rp_occupancy_destroy(occ);
    return err;
  }
  *out = occ;
  return 0;
}

/* Opacity bin of a mean opacity: 0 only for exactly zero, so "empty" is
 * never a rounding artefact; bin j >= 1 holds (j-1)/15 < a <= j/15. */
static int opacity_bin(double a) {
  int j;
  if (!(a > 0.0))
    return 0;
  j = (int)(a * (RP_OPACITY_BINS - 1));
  if (j < (RP_OPACITY_BINS - 1) && j < a * (RP_OPACITY_BINS - 1))
    j++; /* ceil, without trusting ceil() on a value already integral */
  if (j < 1)
    j = 1;
  return j > RP_OPACITY_BINS - 1 ? RP_OPACITY_BINS - 1 : j;
}

/* The box of the occupied blocks, in block indices. */
static void occupied_box(rp_occupancy *occ) {
  const uint32_t *nb = occ->h->blocks;
  uint32_t x, y, z, a;
  for (a = 0; a < 3; a++) {
    occ->box_lo[a] = nb[a];
    occ->box_end[a] = 0;
  }
  for (z = 0; z < nb[2]; z++)
    for (y = 0; y < nb[1]; y++)
      for (x = 0; x < nb[0]; x++) {
        uint32_t c[3];
        if (!occ->grid[((size_t)z * nb[1] + y) * nb[0] + x])
          continue;
        c[0] = x, c[1] = y, c[2] = z;
        for (a = 0; a < 3; a++) {
          if (c[a] < occ->box_lo[a])
            occ->box_lo[a] = c[a];
          if (c[a] + 1 > occ->box_end[a])
            occ->box_end[a] = c[a] + 1;
        }
      }
}

int rp_occupancy_update(rp_occupancy *occ, const rp_tf *tf) {
  const rp_histograms *h;
  const rp__value_range *r;
  int bin_opacity[RP_DENSITY_BINS];
  double bin_mean[RP_DENSITY_BINS], weight[RP_OPACITY_BINS] = {0};
  double alpha_sum[RP_OPACITY_BINS] = {0};
  uint64_t voxels[RP_DENSITY_BINS] = {0};
  double start[RP_DENSITY_BINS], end[RP_DENSITY_BINS];
  /* reach[l][u]: largest alpha over [start(l), end(u)], u >= l. */
  static const int N = RP_DENSITY_BINS;
  float reach[RP_DENSITY_BINS][RP_DENSITY_BINS];
  uint32_t b, empty = 0;
  double span[2];
  int i, j;
  if (occ == NULL)
    return RP_EINVAL;
  if (tf == NULL)
    return rp__fail(occ->ctx, RP_EINVAL, "rp_occupancy_update: tf is "
                    "required");
  h = occ->h;
  r = &h->range;
  rp__tf_stored_range(tf, r, span);
  for (i = 0; i < N; i++) {
    double lo, hi, x0, x1;
    rp__bin_value_range(r, i, &lo, &hi);
    start[i] = lo;
    end[i] = hi;
    x0 = rp__value_to_x(lo, span[0], span[1]);
    x1 = rp__value_to_x(hi >= lo ? hi : lo, span[0], span[1]);
    bin_mean[i] = rp__tf_alpha_mean(tf, x0, x1);
    bin_opacity[i] = opacity_bin(bin_mean[i]);
  }
  /* end() never decreases with the bin, so extending an interval by one
   * bin only adds [end(u-1), end(u)]. */
  for (i = 0; i < N; i++) {
    double x0 = rp__value_to_x(start[i], span[0], span[1]);
    double x1 = rp__value_to_x(end[i] >= start[i] ? end[i] : start[i],
                               span[0], span[1]);
    reach[i][i] = rp__tf_alpha_max(tf, x0, x1);
    for (j = i + 1; j < N; j++) {
      double xa = rp__value_to_x(end[j - 1] > start[i] ? end[j - 1]
                                                       : start[i],
                                 span[0], span[1]);
      double xb = rp__value_to_x(end[j] > start[i] ? end[j] : start[i],
                                 span[0], span[1]);
      float m = rp__tf_alpha_max(tf, xa, xb);
      reach[i][j] = m > reach[i][j - 1] ? m : reach[i][j - 1];
    }
  }
  for (b = 0; b < h->block_count; b++) {
    const uint32_t *c = h->counts + (size_t)b * RP_DENSITY_BINS;
    uint64_t acc[RP_OPACITY_BINS] = {0}, total = 0;
    uint8_t *out = occ->alpha_hist + (size_t)b * RP_OPACITY_BINS;
    for (i = 0; i < N; i++) {
      acc[bin_opacity[i]] += c[i];
      total += c[i];
      voxels[i] += c[i];
    }
    for (j = 0; j < RP_OPACITY_BINS; j++) {
      uint64_t q = (acc[j] * 510 + total) / (2 * total); /* round(f*255) */
      out[j] = (uint8_t)(acc[j] > 0 && q == 0 ? 1 : q);
    }
    occ->visible[b] = (float)((double)(total - acc[0]) / (double)total);
    occ->grid[b] = reach[occ->bin_lo[b]][occ->bin_hi[b]] > 0.0f;
    empty += occ->grid[b] == 0;
  }
  for (i = 0; i < N; i++) {
    weight[bin_opacity[i]] += (double)voxels[i];
    alpha_sum[bin_opacity[i]] += (double)voxels[i] * bin_mean[i];
  }
  /* A bin no voxel falls in keeps its centre: it is never drawn. */
  for (j = 0; j < RP_OPACITY_BINS; j++)
    occ->bin_alpha[j] = j == 0 ? 0.0f
                        : weight[j] > 0.0
                            ? (float)(alpha_sum[j] / weight[j])
                            : (float)rp__ert_bin_alpha(j);
  occupied_box(occ);
  occ->empty = empty;
  occ->tf_id = tf->id;
  return 0;
}

void rp_occupancy_destroy(rp_occupancy *occ) {
  if (occ == NULL)
    return;
  rp__free(occ->ctx, occ->alpha_hist);
  rp__free(occ->ctx, occ->grid);
  rp__free(occ->ctx, occ->visible);
  rp__free(occ->ctx, occ->bin_lo);
  rp__free(occ->ctx, occ->bin_hi);
  rp__free(occ->ctx, occ);
}

const uint8_t *rp_occupancy_alpha_hist(const rp_occupancy *occ) {
  return occ != NULL ? occ->alpha_hist : NULL;
}

const uint8_t *rp_occupancy_grid(const rp_occupancy *occ) {
  return occ != NULL ? occ->grid : NULL;
}

uint32_t rp_occupancy_empty_blocks(const rp_occupancy *occ) {
  return occ != NULL ? occ->empty : 0;
}

int rp__occupancy_check(rp_context *ctx, const char *fn,
                        const rp_occupancy *occ, uint64_t tf_id,
                        uint64_t vol_id) {
  if (occ->tf_id != tf_id)
    return rp__fail(ctx, RP_EINVAL, "%s: occ was built for another "
                    "transfer function (tf id %llu, occ for %llu)", fn,
                    (unsigned long long)tf_id,
                    (unsigned long long)occ->tf_id);
  if (occ->h->vol_id != vol_id)
    return rp__fail(ctx, RP_EINVAL, "%s: occ was built from the "
                    "histograms of another volume", fn);
  return 0;
}
