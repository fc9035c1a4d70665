/* Ray generation and volume sampling: the geometry every backend copies.
 *
 * Spaces (the contract the OpenCL and Vulkan kernels reproduce):
 * - World space: the volume box is [-dims*spacing/2, +dims*spacing/2] on
 *   each axis and voxel (i, j, k) has its centre at
 *   ((i + 0.5 - dims_x/2) * spacing_x, ...). A 1x1x1 volume is a box of
 *   one voxel's size, not a point.
 * - Voxel space: p = world / spacing + dims/2 - 0.5 per axis. Voxel
 *   centres are at integer p; the box is [-0.5, dims - 0.5].
 * - Depth: distance along a ray in "voxel units", the world distance
 *   divided by the smallest spacing, measured from the ray origin. The
 *   point at depth t is p0 + t * dp in voxel space (rp__ray).
 *
 * Everything here is evaluated in double. */
#ifndef RP_RAYGEN_H
#define RP_RAYGEN_H

#include <stdint.h>

#include "internal.h"

/* Two unit vectors count as parallel when |a x b| is at most this (the
 * sine of the angle between them). Used for the default up vector. */
#define RP__PARALLEL_EPS 1e-6

/* A camera resolved against a volume and a viewport: defaults filled in,
 * basis built. Pixel (x, y), y = 0 at the top, has NDC
 * nu = 2 (x + 0.5) / W - 1 and nv = 1 - 2 (y + 0.5) / H.
 * Perspective: origin = eye, dir = normalize(f + nu*half_w*r +
 * nv*half_h*u) with half_h = tan(fov/2) and half_w = half_h * W/H.
 * Orthographic: origin = eye + nu*half_w*r + nv*half_h*u, dir = f, with
 * half_h = ortho_height / 2 and half_w = half_h * W/H. */
typedef struct rp__raygen {
  int ortho;             /* 1 for RP_ORTHOGRAPHIC */
  uint32_t width, height;
  double eye[3];
  double f[3], r[3], u[3]; /* forward, right, up: orthonormal */
  double half_w, half_h;
  double dims[3];          /* the volume's, as doubles */
  double spacing[3];
  double min_spacing;      /* world length of one voxel unit of depth */
} rp__raygen;

/* One ray. t0..t1 is where it is inside the box; s = max(t0, 0) is where
 * sampling starts (an eye inside the volume starts at the eye), moved on
 * by the pixel's jitter in the raycast (rp__ray_jitter). */
typedef struct rp__ray {
  double org[3], dir[3]; /* world space; dir has unit length */
  double p0[3], dp[3];   /* voxel space: p(t) = p0 + t * dp */
  double t0, t1, s;      /* voxel units; valid only when hit */
  int hit;
} rp__ray;

/* Validates `cam` (message names the field: RP_EINVAL) and resolves it
 * for `vol` and a width x height viewport (both >= 1, checked by the
 * caller). Defaults: up (0,1,0), or (0,0,1) when the view direction is
 * parallel to y; fov_y_deg 40; ortho_height = length of dims*spacing. */
int rp__raygen_init(rp_context *ctx, const rp_camera *cam,
                    const rp_volume *vol, uint32_t width, uint32_t height,
                    rp__raygen *rg);

/* The ray through pixel (x, y), clipped against the volume box. */
void rp__raygen_ray(const rp__raygen *rg, uint32_t x, uint32_t y,
                    rp__ray *ray);
/* The ray through continuous image position (px, py), where pixel (x, y)
 * covers [x, x+1) x [y, y+1): rp__raygen_ray is (x + 0.5, y + 0.5). */
void rp__raygen_ray_at(const rp__raygen *rg, double px, double py,
                       rp__ray *ray);

/* Jitters the ray's lattice (rp_jitter): its first sample moves from s
 * to s + offset * step, offset in [0, 1) from rp_jitter_offset. A ray
 * whose first sample then lies past t1 takes none and counts as a miss.
 * The passes that follow the lattice (the raycast, the cost model's
 * sample counts) call it; the depth pass and the ERT pre-pass work on
 * block geometry and their own coarse lattice, and do not. */
void rp__ray_jitter(rp__ray *ray, double offset, double step);

/* Number of lattice samples s + i*step (i = 0, 1, ...) that are <= t1,
 * each position computed as s + i*step exactly as the renderer does.
 * Requires s <= t1 and step > 0. Saturates at RP_MAX_SAMPLES_PER_RAY
 * (the work bound), so that every ray loop ends. */
uint64_t rp__lattice_count(double s, double t1, double step);

/* The volume at voxel-space position p: each coordinate clamped to
 * [0, dims - 1], then trilinear interpolation of the raw voxel values. */
double rp__sample_trilinear(const rp_volume *vol, const double p[3]);

#endif /* RP_RAYGEN_H */
