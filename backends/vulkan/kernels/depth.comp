/* Depth pass: per ray of the scaled image, (D_front, D_back) in voxel
 * units. With RP_SKIP the ray walks the 16^3 block grid (3D DDA): D_front
 * is where it enters the first occupied block, D_back where it leaves the
 * last one, clipped to [s, t1]. Without, the box clip [s, t1]. No
 * occupied block, or a miss: (+inf, -inf). The result stays on the device
 * for the raycast. */
#version 450
#include "common.glsl"

layout(set = 0, binding = 5, std430) writeonly buffer Depth {
  vec2 depth[];
};

/* The walk keeps, per axis, the depth of the next block boundary. Each is
 * computed from the boundary's position rather than accumulated, so that
 * long rays do not drift. */
float boundary(int cell, float p0, float dp) {
  float plane = dp > 0.0 ? float(16 * (cell + 1)) - 0.5
                         : float(16 * cell) - 0.5;
  return (plane - p0) / dp;
}

vec2 walk(Ray ray) {
  /* Only the box of the occupied blocks (its faces are block faces) can
   * hold D_front and D_back: the walk runs over the ray's span inside
   * it, and a ray that misses it meets no occupied block. Those rays were
   * the ones that crossed the whole grid. */
  float lo, hi;
  if (!occupied_box_span(ray, lo, hi))
    return vec2(RP_INF, -RP_INF);
  ray.s = lo;
  ray.t1 = hi;
  ivec3 dir = ivec3(sign(ray.dp));
  /* A ray crosses at most one boundary per block along each axis; the
   * bound only guards against a pathological float loop. */
  int guard = int(P.blocks.x + P.blocks.y + P.blocks.z) + 3;
  /* Two walks, each ending at the first occupied block it meets: forward
   * from s (D_front: where it is entered), then backward from t1 (D_back:
   * where it is left). A ray through a solid object stops early at both
   * ends; only rays that meet nothing inside the box cross it. */
  ivec3 cell = block_cell(ray.p0 + ray.s * ray.dp);
  vec3 next;
  for (int a = 0; a < 3; a++)
    next[a] = dir[a] == 0 ? RP_BIG
                          : boundary(cell[a], ray.p0[a], ray.dp[a]);
  float front = RP_BIG, t = ray.s;
  for (int n = 0; n < guard; n++) {
    if (block_occupied(block_index(cell))) {
      front = t;
      break;
    }
    float exit_t = min(min(next.x, next.y), next.z);
    if (exit_t >= ray.t1)
      break;
    int a = next.x <= next.y ? (next.x <= next.z ? 0 : 2)
                             : (next.y <= next.z ? 1 : 2);
    cell[a] += dir[a];
    /* Leaving the grid before t1 happens only by rounding at the far
     * face: the rest of the ray is outside every block. */
    if (cell[a] < 0 || cell[a] >= int(P.blocks[a]))
      break;
    t = next[a];
    next[a] = boundary(cell[a], ray.p0[a], ray.dp[a]);
  }
  if (front == RP_BIG)
    return vec2(RP_INF, -RP_INF);
  /* Backward: per axis the depth where the ray entered the current block
   * (the exit plane of the block before it), the latest of them first. */
  cell = block_cell(ray.p0 + ray.t1 * ray.dp);
  vec3 prev;
  for (int a = 0; a < 3; a++)
    prev[a] = dir[a] == 0 ? -RP_BIG
                          : boundary(cell[a] - dir[a], ray.p0[a], ray.dp[a]);
  float back = front;
  t = ray.t1;
  for (int n = 0; n < guard; n++) {
    if (block_occupied(block_index(cell))) {
      back = t;
      break;
    }
    float enter_t = max(max(prev.x, prev.y), prev.z);
    /* The forward walk met an occupied block at D_front, so this walk
     * meets one by then; the bound only guards rounding. */
    if (enter_t <= front)
      break;
    int a = prev.x >= prev.y ? (prev.x >= prev.z ? 0 : 2)
                             : (prev.y >= prev.z ? 1 : 2);
    cell[a] -= dir[a];
    if (cell[a] < 0 || cell[a] >= int(P.blocks[a]))
      break;
    t = prev[a];
    prev[a] = boundary(cell[a] - dir[a], ray.p0[a], ray.dp[a]);
  }
  return vec2(front, max(back, front));
}

void main() {
  load_params();
  uvec2 pix = gl_GlobalInvocationID.xy;
  if (pix.x >= P.blocks.w || pix.y >= P.misc.x)
    return;
  Ray ray = make_ray(float(pix.x) + 0.5, float(pix.y) + 0.5);
  vec2 fb = vec2(RP_INF, -RP_INF);
  if (ray.hit)
    fb = RP_SKIP ? walk(ray) : vec2(ray.s, ray.t1);
  depth[pix.y * P.blocks.w + pix.x] = fb;
}
