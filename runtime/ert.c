/* ERT pre-pass in scalar C (DESIGN section 3, backends/README.md): per
 * coarse ray, a random walk through the blocks' opacity histograms that
 * estimates where early ray termination will stop the real raycast.
 *
 * Everything random is uint32 arithmetic so the draws are bit-identical
 * in C, OpenCL and GLSL; only the compositing is floating point, which is
 * why a backend's termination may differ by one coarse step on rare rays.
 */
#include <math.h>

#include "raypace_backend.h"
#include "passes.h"

uint32_t rp__ert_mix(uint32_t x) {
  /* A 32-bit integer hash with good avalanche: neighbouring ray ids must
   * not give correlated streams. */
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}

void rp__taus_seed(rp__taus *t, uint32_t seed, uint32_t frame,
                   uint32_t ray_id) {
  uint32_t base = rp__ert_mix(seed ^ rp__ert_mix(frame + 0x9e3779b9u));
  /* The Tausworthe components need seeds above 1, 7 and 15; setting bit 7
   * is a cheap way to guarantee it. */
  t->z1 = rp__ert_mix(base ^ ray_id) | 128u;
  t->z2 = rp__ert_mix(t->z1 + 0x632be5abu) | 128u;
  t->z3 = rp__ert_mix(t->z2 + 0x85157af5u) | 128u;
  t->z4 = rp__ert_mix(t->z3 + 0x2545f491u);
}

static uint32_t taus_step(uint32_t z, int s1, int s2, int s3, uint32_t m) {
  uint32_t b = ((z << s1) ^ z) >> s2;
  return ((z & m) << s3) ^ b;
}

uint32_t rp__taus_next(rp__taus *t) {
  t->z1 = taus_step(t->z1, 13, 19, 12, 4294967294u);
  t->z2 = taus_step(t->z2, 2, 25, 4, 4294967288u);
  t->z3 = taus_step(t->z3, 3, 11, 17, 4294967280u);
  t->z4 = 1664525u * t->z4 + 1013904223u;
  return t->z1 ^ t->z2 ^ t->z3 ^ t->z4;
}

int rp__ert_pick_bin(const uint8_t h[16], uint32_t tau) {
  uint32_t total = 0, target, cum = 0;
  int k;
  for (k = 0; k < RP_OPACITY_BINS; k++)
    total += h[k];
  /* tau / 2^32 scaled to [0, total): the top 32 bits of a 64-bit
   * product, exact in every language with a 32x32->64 multiply. */
  target = (uint32_t)(((uint64_t)tau * total) >> 32);
  for (k = 0; k < RP_OPACITY_BINS - 1; k++) {
    cum += h[k];
    if (cum > target)
      return k;
  }
  return RP_OPACITY_BINS - 1;
}

double rp__ert_bin_alpha(int bin) {
  return bin <= 0 ? 0.0 : (bin - 0.5) / (RP_OPACITY_BINS - 1);
}

void rp__ert_grid(uint32_t width, uint32_t height, uint32_t *gw,
                  uint32_t *gh) {
  *gw = width / RP_ERT_RAY_STRIDE + (width % RP_ERT_RAY_STRIDE != 0);
  *gh = height / RP_ERT_RAY_STRIDE + (height % RP_ERT_RAY_STRIDE != 0);
}

void rp__ert_corrected(const float *bin_alpha, float ref_step,
                       double corr[RP_OPACITY_BINS]) {
  double ratio = RP_ERT_COARSE_STEP / (double)ref_step;
  int k;
  /* Opacity correction to the coarse step depends only on the bin and
   * the step ratio: once per pre-pass, not twice per draw
   * (docs/runtime.md, "Overhead"). */
  for (k = 0; k < RP_OPACITY_BINS; k++) {
    double a = bin_alpha != NULL ? (double)bin_alpha[k]
                                 : rp__ert_bin_alpha(k);
    corr[k] = -expm1(ratio * log1p(-a));
  }
}

float rp__ert_march(const rp__ray *ray, uint32_t ray_id, uint64_t j0,
                    uint64_t j1, const uint8_t *grid,
                    const uint8_t *alpha_hist,
                    const double corr[RP_OPACITY_BINS],
                    const uint32_t blocks[3], float threshold,
                    uint32_t seed, uint32_t frame) {
  uint64_t j, n;
  double A = 0.0;
  rp__taus rng;
  if (!ray->hit)
    return INFINITY;
  rp__taus_seed(&rng, seed, frame, ray_id);
  n = rp__lattice_count(ray->s, ray->t1, RP_ERT_COARSE_STEP);
  if (j1 > n)
    j1 = n;
  for (j = j0; j < j1; j++) {
    double t = ray->s + (double)j * RP_ERT_COARSE_STEP, p[3];
    uint32_t b;
    int axis;
    for (axis = 0; axis < 3; axis++)
      p[axis] = ray->p0[axis] + t * ray->dp[axis];
    b = rp__block_of(p, blocks);
    if (!grid[b])
      continue;
    A += (1.0 - A) * corr[rp__ert_pick_bin(
                         alpha_hist + (size_t)b * RP_OPACITY_BINS,
                         rp__taus_next(&rng))];
    if (A >= threshold)
      return (float)t;
  }
  return INFINITY;
}

float rp__ert_prepass_ray(const rp__raygen *rg, uint32_t cx, uint32_t cy,
                          const uint8_t *grid, const uint8_t *alpha_hist,
                          const double corr[RP_OPACITY_BINS],
                          const uint32_t blocks[3], float threshold,
                          uint32_t seed, uint32_t frame) {
  uint32_t gw, gh;
  rp__ray ray;
  rp__ert_grid(rg->width, rg->height, &gw, &gh);
  /* Through the centre of the ray's 4x4 pixel group. */
  rp__raygen_ray_at(rg, (double)(RP_ERT_RAY_STRIDE * cx) + 2.0,
                    (double)(RP_ERT_RAY_STRIDE * cy) + 2.0, &ray);
  return rp__ert_march(&ray, cy * gw + cx, 0, UINT64_MAX, grid, alpha_hist,
                       corr, blocks, threshold, seed, frame);
}

void rp__ert_prepass(const rp__raygen *rg, const uint8_t *grid,
                     const uint8_t *alpha_hist, const uint32_t blocks[3],
                     float ref_step, float threshold, uint32_t seed,
                     uint32_t frame, float *d_ert) {
  uint32_t gw, gh, cx, cy;
  double corr[RP_OPACITY_BINS];
  rp__ert_grid(rg->width, rg->height, &gw, &gh);
  rp__ert_corrected(NULL, ref_step, corr);
  for (cy = 0; cy < gh; cy++)
    for (cx = 0; cx < gw; cx++)
      d_ert[cy * gw + cx] = rp__ert_prepass_ray(
          rg, cx, cy, grid, alpha_hist, corr, blocks, threshold, seed, frame);
}
