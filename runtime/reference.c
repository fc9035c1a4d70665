/* The scalar reference raycaster: the oracle the backends are held to.
 *
 * It is written to be read, not to be fast: one ray at a time, one
 * thread, every quantity in double. The rules below are the contract the
 * kernels reproduce (the spaces are defined in raygen.h):
 *
 * Lattice. A ray that meets the box on [t0, t1] samples at depths
 * s + i*step, s = max(t0, 0) + j*step, for i = 0, 1, ... while
 * s + i*step <= t1, where j in [0, 1) is the pixel's jitter
 * (rp_jitter_offset; 0 with RP_JITTER_OFF). Each depth is computed from
 * i, never accumulated, so that a kernel lands on the same positions
 * whatever order it visits them in.
 *
 * Skipping (RP_EFFECT_SKIP). A lattice sample at voxel-space p belongs to
 * block floor((p + 0.5) / 16) per axis, clamped to the grid: the block of
 * the voxel whose cell holds p. Only samples i_first..i_last are taken,
 * the first and last lattice samples in an occupied block; empty runs
 * between them are still sampled. That makes D_front and D_back lattice
 * depths, which a GPU depth pass can reproduce exactly. The occupancy is
 * conservative (a block is marked when any value a sample inside it can
 * interpolate, neighbours' voxels included, has non-zero opacity), so
 * every skipped sample has opacity exactly 0 and adds exactly 0: skipping
 * never changes a pixel, only the sample count.
 *
 * Per sample: v = trilinear value; x = rp__value_to_x(v) over the TF's
 * range on the volume (rp__tf_volume_range); TF at x gives
 * straight colour c and alpha a for the TF's reference step;
 * a' = rp_opacity_correct(a, step, reference step). With shading, c is
 * lit by a headlight (below). Front to back, premultiplied:
 * C += (1 - A) a' c, A += (1 - A) a'. With ERT the ray stops after a
 * sample that brings A to >= the threshold. With RP_EFFECT_PREINT,
 * sample i instead takes the segment from sample i - 1 (rp__preint_mean
 * over their positions, runtime/preint.c), sample first - 1 being
 * fetched for the first one, shading and AO at the segment's middle
 * s + (i - 1/2) step, and with skipping the range ends one
 * sample after the last occupied one (the segment leaving it). A pixel
 * channel is
 * floor(clamp(C, 0, 1) * 255 + 0.5). */
#include <math.h>

#include "ao.h"
#include "bounds.h"
#include "passes.h"

#define RP__DEFAULT_STEP 1.0f
#define RP__DEFAULT_ERT 0.99f
/* The gradient magnitude, as a share of the range the TF spans (the data
 * range for a [min, max] TF, the window for one in data units) per voxel
 * of the finest spacing, from which a sample is lit by its normal alone. Below
 * it the normal's direction is increasingly noise (the crest of a thin
 * shell or vessel wall, a plateau of quantised values: a gradient of a
 * level or two of 255 that points anywhere), so the light blends towards
 * "facing the light" in proportion: ndotl' = 1 - m (1 - ndotl), m =
 * min(1, |g| / threshold). A hard cut (0.10 had one at 1e-6 of the range)
 * shaded such samples by a random direction, and where the lattice met
 * the crest of the demo phantom's shell that drew a regular grid of dark
 * dots (docs/sampling.md). */
#define RP__SURFACE_GRADIENT 0.02

double rp__sample_trilinear(const rp_volume *vol, const double p[3]) {
  uint32_t lo[3], hi[3];
  double w[3], c00, c10, c01, c11, c0, c1;
  int a;
  for (a = 0; a < 3; a++) {
    double top = (double)vol->dims[a] - 1.0, c = p[a], fl;
    /* Written so that NaN lands on 0 instead of reaching the cast. */
    if (!(c >= 0.0))
      c = 0.0;
    if (c > top)
      c = top;
    fl = floor(c);
    lo[a] = (uint32_t)fl;
    hi[a] = lo[a] + 1 < vol->dims[a] ? lo[a] + 1 : lo[a];
    w[a] = c - fl;
  }
  /* Interpolate along x, then y, then z. */
  c00 = (1.0 - w[0]) * rp__voxel(vol, lo[0], lo[1], lo[2]) +
        w[0] * rp__voxel(vol, hi[0], lo[1], lo[2]);
  c10 = (1.0 - w[0]) * rp__voxel(vol, lo[0], hi[1], lo[2]) +
        w[0] * rp__voxel(vol, hi[0], hi[1], lo[2]);
  c01 = (1.0 - w[0]) * rp__voxel(vol, lo[0], lo[1], hi[2]) +
        w[0] * rp__voxel(vol, hi[0], lo[1], hi[2]);
  c11 = (1.0 - w[0]) * rp__voxel(vol, lo[0], hi[1], hi[2]) +
        w[0] * rp__voxel(vol, hi[0], hi[1], hi[2]);
  c0 = (1.0 - w[1]) * c00 + w[1] * c10;
  c1 = (1.0 - w[1]) * c01 + w[1] * c11;
  return (1.0 - w[2]) * c0 + w[2] * c1;
}

/* Everything a ray needs besides its own geometry, defaults resolved. */
typedef struct render_ctx {
  const rp_volume *vol;
  const rp_tf *tf;
  double span[2];      /* rp__tf_volume_range: the TF's stored values */
  const uint8_t *grid; /* NULL: no skipping */
  uint32_t blocks[3];
  double step;
  float step_f, ref_step;
  int shading, ert, preint;
  double ert_threshold; /* the float from the desc, widened exactly */
  const rp_volume *ao;  /* the AO volume as 8-bit voxels; NULL: no AO */
  int jitter;
  uint32_t jitter_seed;
  double min_spacing; /* the volume's finest spacing, world units */
} render_ctx;

/* What one ray produced. */
typedef struct ray_result {
  double rgba[4];   /* premultiplied */
  uint64_t samples; /* lattice samples taken */
  uint64_t lit;     /* of those, visible ones (opacity above 0) that
                       took shading or AO fetches */
  double last_depth; /* depth of the last one; meaningless if none */
} ray_result;

static double clamp01(double v) { return v < 0.0 ? 0.0 : v > 1.0 ? 1.0 : v; }

static void point_at(const rp__ray *ray, double t, double p[3]) {
  int a;
  for (a = 0; a < 3; a++)
    p[a] = ray->p0[a] + t * ray->dp[a];
}

static int occupied(const render_ctx *rc, const rp__ray *ray, uint64_t i) {
  double p[3];
  point_at(ray, ray->s + (double)i * rc->step, p);
  return rc->grid[rp__block_of(p, rc->blocks)] != 0;
}

/* Headlight shading of straight colour `rgb` at p, in place. The gradient
 * is central differences of the interpolated field one voxel either side
 * along each axis, per world unit: g_a = (f(p + e_a) - f(p - e_a)) / 2 /
 * spacing_a. The light comes from the eye, L = -dir, and lights both
 * faces: ndotl = |g . L| / |g|, blended towards 1 where |g| is below
 * RP__SURFACE_GRADIENT (1 for a flat field). Then
 * rgb = clamp(rgb (0.3 + 0.7 ndotl) + 0.2 ndotl^20, 0, 1). */
static void shade(const render_ctx *rc, const rp__ray *ray, const double p[3],
                  double rgb[3]) {
  const rp_volume *vol = rc->vol;
  double g[3], len, ndotl, range = rc->span[1] - rc->span[0], gain, spec, m;
  int a;
  for (a = 0; a < 3; a++) {
    double q[3] = {p[0], p[1], p[2]}, fp, fm;
    q[a] = p[a] + 1.0;
    fp = rp__sample_trilinear(vol, q);
    q[a] = p[a] - 1.0;
    fm = rp__sample_trilinear(vol, q);
    /* Per world unit, so anisotropic spacing tilts normals correctly. */
    g[a] = (fp - fm) * 0.5 / vol->spacing[a];
  }
  len = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
  m = len * rc->min_spacing / (range * RP__SURFACE_GRADIENT);
  if (!(range > 0.0) || !(m > 0.0)) {
    ndotl = 1.0;
  } else {
    /* L = -dir. Two-sided: an iso-surface seen from behind is lit too. */
    ndotl = fabs(-(g[0] * ray->dir[0] + g[1] * ray->dir[1] +
                   g[2] * ray->dir[2]) / len);
    if (ndotl > 1.0)
      ndotl = 1.0;
    if (m < 1.0)
      ndotl = 1.0 - m * (1.0 - ndotl);
  }
  gain = 0.3 + 0.7 * ndotl;
  spec = 0.2 * pow(ndotl, 20.0);
  for (a = 0; a < 3; a++)
    rgb[a] = clamp01(rgb[a] * gain + spec);
}

static void cast(const render_ctx *rc, const rp__ray *ray, ray_result *out) {
  const rp_volume *vol = rc->vol;
  uint64_t n, first = 0, last, i;
  double C[3] = {0.0, 0.0, 0.0}, A = 0.0, x_prev = 0.0;
  int c;
  out->samples = 0;
  out->lit = 0;
  out->last_depth = 0.0;
  for (c = 0; c < 4; c++)
    out->rgba[c] = 0.0;
  if (!ray->hit)
    return;
  n = rp__lattice_count(ray->s, ray->t1, rc->step);
  last = n - 1;
  if (rc->grid != NULL) {
    while (first < n && !occupied(rc, ray, first))
      first++;
    if (first == n)
      return;
    while (!occupied(rc, ray, last))
      last--;
    /* A pre-integrated sample stands for the segment before it: the one
     * leaving the last occupied sample is the next sample's. */
    if (rc->preint && last + 1 < n)
      last++;
  }
  if (rc->preint) {
    /* The value at the lattice depth before the first sample taken (off
     * the box when that is sample 0: the clamped field). */
    double p[3];
    point_at(ray, ray->s + ((double)first - 1.0) * rc->step, p);
    x_prev = rp__value_to_x(rp__sample_trilinear(vol, p), rc->span[0],
                            rc->span[1]);
  }
  for (i = first; i <= last; i++) {
    double t = ray->s + (double)i * rc->step, p[3], x, rgb[3], alpha, w;
    point_at(ray, t, p);
    x = rp__value_to_x(rp__sample_trilinear(vol, p), rc->span[0],
                       rc->span[1]);
    if (rc->preint) {
      double mean[4], seg[4];
      rp__preint_mean(rc->tf, x_prev, x, mean);
      rp__preint_classify(mean, rc->step / rc->ref_step, seg);
      for (c = 0; c < 3; c++)
        rgb[c] = seg[c];
      alpha = seg[3];
      x_prev = x;
    } else {
      float tf[4];
      rp__tf_sample(rc->tf, x, tf);
      alpha = rp_opacity_correct(tf[3], rc->step_f, rc->ref_step);
      for (c = 0; c < 3; c++)
        rgb[c] = tf[c];
    }
    /* A transparent sample adds exactly 0 whatever its colour, so its
     * gradient and AO fetches can be spared without changing a bit. */
    if ((rc->shading || rc->ao != NULL) && alpha > 0.0) {
      /* A segment is lit and occluded at its middle, where its samples
       * would be centred: at its end its colour lags half a step (MSE
       * 5x the plain lattice's at step 0.5 on the phantom). */
      if (rc->preint)
        point_at(ray, ray->s + ((double)i - 0.5) * rc->step, p);
      if (rc->shading)
        shade(rc, ray, p, rgb);
      if (rc->ao != NULL) {
        double occlusion = rp__sample_trilinear(rc->ao, p) / 255.0;
        for (c = 0; c < 3; c++)
          rgb[c] *= occlusion;
      }
      out->lit++;
    }
    w = (1.0 - A) * alpha;
    for (c = 0; c < 3; c++)
      C[c] += w * rgb[c];
    A += w;
    out->samples++;
    out->last_depth = t;
    if (rc->ert && A >= rc->ert_threshold)
      break;
  }
  for (c = 0; c < 3; c++)
    out->rgba[c] = C[c];
  out->rgba[3] = A;
}

static uint8_t to_u8(double v) {
  return (uint8_t)floor(clamp01(v) * 255.0 + 0.5);
}

void rp_tile_grid(uint32_t width, uint32_t height, uint32_t *tiles_x,
                  uint32_t *tiles_y) {
  /* Not (w + 7) / 8, which wraps for widths near 2^32. */
  if (tiles_x != NULL)
    *tiles_x = width / RP_TILE_SIZE + (width % RP_TILE_SIZE != 0);
  if (tiles_y != NULL)
    *tiles_y = height / RP_TILE_SIZE + (height % RP_TILE_SIZE != 0);
}

/* The desc with its zero fields replaced by their defaults: the one place
 * that knows what zero means, so that everything after it (validation
 * included) sees only real values. */
rp_render_desc rp__render_desc_defaults(const rp_render_desc *in) {
  rp_render_desc d = *in;
  if (d.step == 0.0f)
    d.step = RP__DEFAULT_STEP;
  if (d.ert_threshold == 0.0f)
    d.ert_threshold = RP__DEFAULT_ERT;
  if (d.image_scale == 0.0f)
    d.image_scale = 1.0f;
  if (d.jitter == RP_JITTER_DEFAULT || d.jitter == RP_JITTER_FIXED)
    d.jitter = RP_JITTER_ON;
  if (d.jitter_seed == 0)
    d.jitter_seed = RP_JITTER_SEED;
  return d;
}

void rp_scaled_size(const rp_render_desc *desc, uint32_t *width,
                    uint32_t *height) {
  double s = desc->image_scale == 0.0f ? 1.0 : desc->image_scale, w, h;
  if (!(s > 0.0 && s <= 1.0)) /* invalid scales are refused elsewhere */
    s = 1.0;
  w = floor(desc->width * s + 0.5);
  h = floor(desc->height * s + 0.5);
  *width = w < 1.0 ? 1u : (uint32_t)w;
  *height = h < 1.0 ? 1u : (uint32_t)h;
}

int rp__check_render_desc(rp_context *ctx, const char *fn,
                          const rp_render_desc *desc) {
  int err;
  /* The fields as the caller wrote them: zero fields were replaced by
   * their defaults, which are in range. */
  if ((err = rp__check_image_size(ctx, fn, "rp_render_desc.width x height",
                                  desc->width, desc->height)) != 0 ||
      (err = rp__check_range(ctx, fn, "rp_render_desc.step", desc->step, 1,
                             RP_STEP_MIN, RP_STEP_MAX, "voxels", "1")) != 0 ||
      (err = rp__check_range(ctx, fn, "rp_render_desc.ert_threshold",
                             desc->ert_threshold, 1, RP_ERT_THRESHOLD_MIN,
                             RP_ERT_THRESHOLD_MAX, "", "0.99")) != 0 ||
      (err = rp__check_range(ctx, fn, "rp_render_desc.image_scale",
                             desc->image_scale, 1, RP_SCALE_MIN,
                             RP_SCALE_MAX, "", "1")) != 0)
    return err;
  if (desc->jitter != RP_JITTER_ON && desc->jitter != RP_JITTER_OFF)
    return rp__fail(ctx, RP_EINVAL, "%s: rp_render_desc.jitter is %d; must "
                    "be RP_JITTER_DEFAULT (0), RP_JITTER_ON (1), "
                    "RP_JITTER_OFF (2) or RP_JITTER_FIXED (3)", fn,
                    (int)desc->jitter);
  if (desc->effects & ~(uint32_t)RP__KNOWN_EFFECTS)
    return rp__fail(ctx, RP_EINVAL, "%s: rp_render_desc.effects has "
                    "unknown bits 0x%x", fn,
                    (unsigned)(desc->effects & ~(uint32_t)RP__KNOWN_EFFECTS));
  return 0;
}

/* `desc` has its defaults filled in; NULL when the caller passed none. */
static int check_args(rp_context *ctx, const rp_volume *vol,
                      const rp_tf *tf, const rp_occupancy *occ,
                      const rp_ao *ao, const rp_camera *cam,
                      const rp_render_desc *desc, const uint8_t *rgba) {
  const char *missing = vol == NULL    ? "vol"
                        : tf == NULL   ? "tf"
                        : cam == NULL  ? "cam"
                        : desc == NULL ? "desc"
                        : rgba == NULL ? "rgba"
                                       : NULL;
  int err;
  if (missing != NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_render_reference: %s is NULL",
                    missing);
  if ((err = rp__check_render_desc(ctx, "rp_render_reference", desc)) != 0)
    return err;
  if ((desc->effects & RP_EFFECT_SKIP) && occ == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_render_reference: desc->effects has "
                    "RP_EFFECT_SKIP but occ is NULL");
  /* An occupancy passed without SKIP is unused, but a mismatched one is
   * still a caller bug worth reporting before it bites with SKIP on. */
  if (occ != NULL &&
      (err = rp__occupancy_check(ctx, "rp_render_reference", occ, tf->id,
                                 vol->id)) != 0)
    return err;
  if ((desc->effects & RP_EFFECT_AO) && ao == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_render_reference: desc->effects has "
                    "RP_EFFECT_AO but ao is NULL");
  if (ao != NULL)
    return rp__ao_check(ctx, "rp_render_reference", ao, vol->id, tf->id);
  return 0;
}

/* Renders one tile's pixels and fills its stats and its volume fetches
 * (either may be NULL): one per sample, six more per shaded one, one
 * more per AO one, and with PREINT one more per ray that samples. */
static void render_tile(const render_ctx *rc, const rp__raygen *rg,
                        uint32_t tx, uint32_t ty, uint8_t *rgba,
                        rp_tile_stats *stats, uint64_t *fetches) {
  uint32_t x0 = tx * RP_TILE_SIZE, y0 = ty * RP_TILE_SIZE, x, y;
  uint32_t x1 = rg->width - x0 < RP_TILE_SIZE ? rg->width : x0 + RP_TILE_SIZE;
  uint32_t y1 =
      rg->height - y0 < RP_TILE_SIZE ? rg->height : y0 + RP_TILE_SIZE;
  uint64_t samples = 0, hits = 0, lit = 0;
  double depth_sum = 0.0;
  for (y = y0; y < y1; y++) {
    for (x = x0; x < x1; x++) {
      rp__ray ray;
      ray_result res;
      uint8_t *px = rgba + ((size_t)y * rg->width + x) * 4;
      int c;
      rp__raygen_ray(rg, x, y, &ray);
      if (rc->jitter)
        rp__ray_jitter(&ray, rp_jitter_offset(x, y, rc->jitter_seed),
                       rc->step);
      cast(rc, &ray, &res);
      for (c = 0; c < 4; c++)
        px[c] = to_u8(res.rgba[c]);
      /* No wrap: at most 64 rays of at most 2^53 samples each. The
       * uint32 field saturates below. */
      samples += res.samples;
      lit += res.lit;
      if (res.samples > 0) {
        hits++;
        depth_sum += res.last_depth;
      }
    }
  }
  if (stats != NULL) {
    stats->samples = samples > UINT32_MAX ? UINT32_MAX : (uint32_t)samples;
    stats->rays_hit = (uint32_t)hits;
    stats->mean_depth = hits > 0 ? (float)(depth_sum / (double)hits) : 0.0f;
  }
  if (fetches != NULL)
    *fetches = samples + ((rc->shading ? 6u : 0u) + (rc->ao ? 1u : 0u)) * lit +
               (rc->preint ? hits : 0u);
}

void rp__reference_render(const rp_volume *vol, const rp_tf *tf,
                          const uint8_t *grid, const uint32_t blocks[3],
                          const rp_volume *ao,
                          const rp__raygen *rg, const rp_render_desc *d,
                          const rp_region *region, uint8_t *rgba,
                          rp_tile_stats *tiles, uint64_t *fetches) {
  render_ctx rc;
  uint32_t tiles_x, tx, ty;
  rc.vol = vol;
  rc.tf = tf;
  rp__tf_volume_range(tf, vol, rc.span);
  rc.grid = (d->effects & RP_EFFECT_SKIP) ? grid : NULL;
  if (rc.grid != NULL) {
    rc.blocks[0] = blocks[0];
    rc.blocks[1] = blocks[1];
    rc.blocks[2] = blocks[2];
  }
  rc.step_f = d->step;
  rc.step = d->step;
  rc.ref_step = rp_tf_reference_step(tf);
  rc.shading = (d->effects & RP_EFFECT_SHADING) != 0;
  rc.ert = (d->effects & RP_EFFECT_ERT) != 0;
  rc.preint = (d->effects & RP_EFFECT_PREINT) != 0;
  rc.ert_threshold = d->ert_threshold;
  rc.ao = (d->effects & RP_EFFECT_AO) ? ao : NULL;
  rc.jitter = d->jitter != RP_JITTER_OFF;
  rc.jitter_seed = d->jitter_seed;
  rc.min_spacing = rg->min_spacing;
  rp_tile_grid(rg->width, rg->height, &tiles_x, NULL);
  /* Region corners lie on the tile grid or the image edge, so the tiles
   * it touches are exactly its own. */
  for (ty = region->y0 / RP_TILE_SIZE;
       ty * RP_TILE_SIZE < region->y1; ty++)
    for (tx = region->x0 / RP_TILE_SIZE;
         tx * RP_TILE_SIZE < region->x1; tx++)
      render_tile(&rc, rg, tx, ty, rgba,
                  tiles != NULL ? &tiles[(size_t)ty * tiles_x + tx] : NULL,
                  fetches != NULL ? &fetches[(size_t)ty * tiles_x + tx]
                                  : NULL);
}

int rp_render_reference(rp_context *ctx, const rp_volume *vol,
                        const rp_tf *tf, const rp_occupancy *occ,
                        const rp_ao *ao, const rp_camera *cam,
                        const rp_render_desc *desc, uint8_t *rgba,
                        rp_tile_stats *tiles) {
  rp__raygen rg;
  rp_volume ao_view;
  rp_render_desc d = {0};
  rp_region all = {0, 0, 0, 0};
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (desc != NULL)
    d = rp__render_desc_defaults(desc);
  if ((err = check_args(ctx, vol, tf, occ, ao, cam,
                        desc != NULL ? &d : NULL, rgba)) != 0)
    return err;
  if ((err = rp__raygen_init(ctx, cam, vol, d.width, d.height, &rg)) != 0)
    return err;
  /* Rays on the scaled grid, frustum of the full output. */
  rp_scaled_size(&d, &rg.width, &rg.height);
  if ((err = rp__check_work(ctx, "rp_render_reference", &rg, d.step)) != 0)
    return err;
  all.x1 = rg.width;
  all.y1 = rg.height;
  if (ao != NULL)
    rp__ao_view(ao, &ao_view);
  rp__reference_render(vol, tf, occ != NULL ? occ->grid : NULL,
                       occ != NULL ? occ->h->blocks : NULL,
                       ao != NULL ? &ao_view : NULL, &rg, &d, &all, rgba,
                       tiles, NULL);
  return 0;
}
