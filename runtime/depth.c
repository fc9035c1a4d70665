/* The depth pass in scalar C (DESIGN section 3, backends/README.md): per
 * ray, the depths where the first occupied block is entered and the last
 * one left, by stepping through the block grid (3D DDA, Amanatides and Woo
 * 1987). It also skips the interior empty runs DESIGN allows: the
 * raycast's lattice refinement does that per sample. */
#include <math.h>

#include "passes.h"

uint32_t rp__block_of(const double p[3], const uint32_t blocks[3]) {
  uint32_t b[3];
  int a;
  for (a = 0; a < 3; a++) {
    double q = (p[a] + 0.5) / RP_BLOCK_SIZE;
    /* floor(q) clamped to the grid, as a truncating cast: equal for
     * q >= 0, and floor() is a libm call on baseline x86-64, which made
     * this the host probe's hottest function. Written so that NaN lands
     * on 0 rather than reaching the cast. */
    if (!(q >= 0.0))
      q = 0.0;
    if (q > blocks[a] - 1.0)
      q = blocks[a] - 1.0;
    b[a] = (uint32_t)q;
  }
  return (b[2] * blocks[1] + b[1]) * blocks[0] + b[0];
}

/* fmin for the DDA's plane depths, which are never NaN: inline, where
 * fmin is a libm call. */
static double min2(double a, double b) { return a < b ? a : b; }

void rp__depth_ray(const rp__ray *ray, const double dims[3],
                   const uint8_t *grid, const uint32_t blocks[3],
                   double *front, double *back) {
  double p[3], next[3], delta[3], t;
  int32_t cell[3], stepv[3];
  int a;
  (void)dims;
  *front = INFINITY;
  *back = -INFINITY;
  if (!ray->hit)
    return;
  if (grid == NULL) {
    *front = ray->s;
    *back = ray->t1;
    return;
  }
  for (a = 0; a < 3; a++)
    p[a] = ray->p0[a] + ray->s * ray->dp[a];
  {
    uint32_t b = rp__block_of(p, blocks);
    cell[0] = (int32_t)(b % blocks[0]);
    cell[1] = (int32_t)((b / blocks[0]) % blocks[1]);
    cell[2] = (int32_t)(b / ((uint32_t)blocks[0] * blocks[1]));
  }
  /* Per axis: depth of the next block boundary and the depth between
   * boundaries. Boundaries sit at 16 b - 0.5 in voxel space. */
  for (a = 0; a < 3; a++) {
    if (ray->dp[a] > 0.0) {
      stepv[a] = 1;
      next[a] = (RP_BLOCK_SIZE * (cell[a] + 1) - 0.5 - ray->p0[a]) /
                ray->dp[a];
      delta[a] = RP_BLOCK_SIZE / ray->dp[a];
    } else if (ray->dp[a] < 0.0) {
      stepv[a] = -1;
      next[a] = (RP_BLOCK_SIZE * cell[a] - 0.5 - ray->p0[a]) / ray->dp[a];
      delta[a] = -RP_BLOCK_SIZE / ray->dp[a];
    } else {
      stepv[a] = 0;
      next[a] = INFINITY;
      delta[a] = INFINITY;
    }
  }
  t = ray->s;
  for (;;) {
    double exit_t = min2(next[0], min2(next[1], next[2]));
    uint32_t b = ((uint32_t)cell[2] * blocks[1] + (uint32_t)cell[1]) *
                     blocks[0] + (uint32_t)cell[0];
    int axis;
    if (exit_t > ray->t1)
      exit_t = ray->t1;
    if (grid[b]) {
      if (*front == INFINITY)
        *front = t;
      *back = exit_t;
    }
    if (exit_t >= ray->t1)
      break;
    axis = next[0] <= next[1] ? (next[0] <= next[2] ? 0 : 2)
                              : (next[1] <= next[2] ? 1 : 2);
    cell[axis] += stepv[axis];
    /* Leaving the grid before t1 only happens by rounding at the far
     * face; the remaining segment lies outside every block. */
    if (cell[axis] < 0 || (uint32_t)cell[axis] >= blocks[axis])
      break;
    t = next[axis];
    next[axis] += delta[axis];
  }
}
