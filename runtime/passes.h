/* The per-frame passes in scalar C: the depth pass and the ERT pre-pass
 * of DESIGN section 3, written as backends/README.md states them. They are
 * the reference the OpenCL and Vulkan kernels are held to, and the
 * "reference" backend's implementation. */
#ifndef RP_PASSES_H
#define RP_PASSES_H

#include <stdint.h>

#include "raygen.h"
#include "raypace_backend.h"

/* Index of the 16^3 block holding voxel-space point p: floor((p + 0.5) /
 * 16) per axis, clamped to the grid; x fastest. */
uint32_t rp__block_of(const double p[3], const uint32_t blocks[3]);

/* Depth of one ray: with `grid` (skipping), where the first occupied
 * block is entered and the last one left, clipped to [s, t1]; without,
 * [s, t1]. No occupied block, or a miss: front = +inf, back = -inf. */
void rp__depth_ray(const rp__ray *ray, const double dims[3],
                   const uint8_t *grid, const uint32_t blocks[3],
                   double *front, double *back);

/* The hybrid Tausworthe generator (GPU Gems 3, ch. 37) and its seeding
 * by (seed, frame, ray id): backends/README.md. */
typedef struct rp__taus {
  uint32_t z1, z2, z3, z4;
} rp__taus;

uint32_t rp__ert_mix(uint32_t x);
void rp__taus_seed(rp__taus *t, uint32_t seed, uint32_t frame,
                   uint32_t ray_id);
uint32_t rp__taus_next(rp__taus *t);
/* The opacity bin tau selects from 16 H-alpha bytes (integer arithmetic,
 * so every backend picks the same bin), and that bin's opacity. */
int rp__ert_pick_bin(const uint8_t h[16], uint32_t tau);
double rp__ert_bin_alpha(int bin);

/* Size of the pre-pass ray grid for a width x height (scaled) image. */
void rp__ert_grid(uint32_t width, uint32_t height, uint32_t *gw,
                  uint32_t *gh);

/* The ERT pre-pass for every pre-pass ray of `rg` (already at the scaled
 * size): d_ert[gw * gh] receives the estimated termination depth or
 * +inf. It draws each bin's centre opacity, as the device kernels do.
 * rp__ert_prepass_ray is one of them, pre-pass ray (cx, cy), for callers
 * that split the grid across threads, with the bins' opacities corrected
 * to the coarse step by rp__ert_corrected: from bin_alpha
 * (RP_OPACITY_BINS values, rp_occupancy's bin_alpha, the mean opacity the
 * volume's voxels in each bin have) or, when it is NULL, the bin
 * centres. */
void rp__ert_corrected(const float *bin_alpha, float ref_step,
                       double corr[RP_OPACITY_BINS]);
float rp__ert_prepass_ray(const rp__raygen *rg, uint32_t cx, uint32_t cy,
                          const uint8_t *grid, const uint8_t *alpha_hist,
                          const double corr[RP_OPACITY_BINS],
                          const uint32_t blocks[3], float threshold,
                          uint32_t seed, uint32_t frame);
/* The same along a ray already generated, `ray_id` its index in the
 * pre-pass grid (cy * gw + cx), over its lattice points j0 <= j < j1
 * only (clipped to the ray's). The random draws are taken at occupied
 * blocks alone, so a caller that knows where the occupied blocks along
 * the ray begin and end (the depth pass) gets the whole ray's result
 * from the points that span them. */
float rp__ert_march(const rp__ray *ray, uint32_t ray_id, uint64_t j0,
                    uint64_t j1, const uint8_t *grid,
                    const uint8_t *alpha_hist,
                    const double corr[RP_OPACITY_BINS],
                    const uint32_t blocks[3], float threshold,
                    uint32_t seed, uint32_t frame);
void rp__ert_prepass(const rp__raygen *rg, const uint8_t *grid,
                     const uint8_t *alpha_hist, const uint32_t blocks[3],
                     float ref_step, float threshold, uint32_t seed,
                     uint32_t frame, float *d_ert);

/* Every RP_EFFECT_* bit: anything else in an effects field is refused. */
#define RP__KNOWN_EFFECTS                                                     \
  (RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_AO |     \
   RP_EFFECT_PREINT)

/* The render desc with its zero fields replaced by defaults (the one
 * place that knows them), and its validation (message prefixed by fn). */
rp_render_desc rp__render_desc_defaults(const rp_render_desc *in);
int rp__check_render_desc(rp_context *ctx, const char *fn,
                          const rp_render_desc *desc);

/* The reference raycast of `region` of rg's (scaled) image; `d` resolved
 * and checked, `grid` NULL when not skipping. Writes only the region's
 * pixels, tiles and fetches (each of the latter two: the whole image's
 * grid, row-major, or NULL). `ao`, the AO volume as 8-bit voxels, is
 * read with RP_EFFECT_AO. A tile's fetches are its samples plus, per
 * sample with opacity above 0, six with shading and one with AO: the
 * count the backends' counting variants report. */
void rp__reference_render(const rp_volume *vol, const rp_tf *tf,
                          const uint8_t *grid, const uint32_t blocks[3],
                          const rp_volume *ao, const rp__raygen *rg, const rp_render_desc *d,
                          const rp_region *region, uint8_t *rgba,
                          rp_tile_stats *tiles, uint64_t *fetches);

/* A frame's camera resolved for the scaled image (rg) and its float form
 * for kernels (p), as the front end hands it to a backend; `d` resolved
 * and checked. `shape` supplies dims and spacing, tf_span the stored
 * values the TF's LUT spans (rp__tf_volume_range); `occ` the
 * box of the occupied blocks (NULL: the whole grid). Backend tests build
 * their frames with it, so they drive a backend exactly as the front end
 * does. */
int rp__frame_params(rp_context *ctx, const rp_volume *shape,
                     const rp_occupancy *occ, const rp_camera *cam,
                     const rp_render_desc *d, float ref_step,
                     uint32_t lut_size, const double tf_span[2],
                     rp__raygen *rg, rp_frame_params *p);

/* rp_device_render that can also return per-tile fetch counts (backends
 * with a counting variant; tests check the cost model's k with it). */
int rp__device_render(rp_device *dev, const rp_camera *cam,
                      const rp_render_desc *desc, const rp_region *region,
                      uint8_t *rgba, rp_tile_stats *tiles,
                      uint64_t *fetches);

#endif /* RP_PASSES_H */
