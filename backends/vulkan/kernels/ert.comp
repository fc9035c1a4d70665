/* ERT pre-pass (backends/README.md): per pre-pass ray, one per 4x4 pixels
 * of the scaled image, a random walk through the blocks' opacity
 * histograms at a coarse step, giving the depth where early ray
 * termination is expected (+inf when it never is).
 *
 * The random stream is uint32 arithmetic only and the bin choice's 64-bit
 * product comes from umulExtended, so every draw equals the C reference's
 * bit for bit. Only the compositing is float. */
#version 450
#include "common.glsl"

/* 16 H-alpha bytes per block, one RGBA32 texel. */
layout(set = 0, binding = 4) uniform usamplerBuffer alpha_hist;
layout(set = 0, binding = 8, std430) writeonly buffer Ert {
  float d_ert[];
};

uint taus(uint z, int s1, int s2, int s3, uint m) {
  uint b = ((z << s1) ^ z) >> s2;
  return ((z & m) << s3) ^ b;
}

uvec4 rng;

uint next_tau() {
  rng.x = taus(rng.x, 13, 19, 12, 4294967294u);
  rng.y = taus(rng.y, 2, 25, 4, 4294967288u);
  rng.z = taus(rng.z, 3, 11, 17, 4294967280u);
  rng.w = 1664525u * rng.w + 1013904223u;
  return rng.x ^ rng.y ^ rng.z ^ rng.w;
}

uint hist_byte(uvec4 h, uint k) {
  return (h[k >> 2] >> ((k & 3u) * 8u)) & 0xffu;
}

/* The first bin whose running count exceeds tau's share of the total:
 * target = (tau * total) >> 32, the high word of a 32x32 product. */
uint pick_bin(uvec4 h, uint tau) {
  uint total = 0u;
  for (uint k = 0u; k < 16u; k++)
    total += hist_byte(h, k);
  uint target, low;
  umulExtended(tau, total, target, low);
  uint cum = 0u;
  for (uint k = 0u; k < 15u; k++) {
    cum += hist_byte(h, k);
    if (cum > target)
      return k;
  }
  return 15u;
}

void main() {
  load_params();
  uvec2 c = gl_GlobalInvocationID.xy;
  if (c.x >= P.misc.y || c.y >= P.misc.z)
    return;
  uint id = c.y * P.misc.y + c.x;
  float result = RP_INF;
  /* Through the centre of the ray's 4x4 pixel group. */
  Ray ray = make_ray(float(4u * c.x) + 2.0, float(4u * c.y) + 2.0);
  if (ray.hit) {
    uint base = mix32(P.seed.x ^ mix32(P.seed.y + 0x9e3779b9u));
    rng.x = mix32(base ^ id) | 128u;
    rng.y = mix32(rng.x + 0x632be5abu) | 128u;
    rng.z = mix32(rng.y + 0x85157af5u) | 128u;
    rng.w = mix32(rng.z + 0x2545f491u);
    float A = 0.0, lo, hi;
    /* Draws happen only in occupied blocks, and those lie in the box of
     * the occupied blocks: the march skips the lattice points before and
     * after the ray's span inside it, keeping a point of margin at each
     * end for rounding at the faces. The points marched, the draws and
     * the result are those of a march over the whole of [s, t1]. */
    bool in_box = occupied_box_span(ray, lo, hi);
    uint j0 = uint(max(floor((lo - ray.s) * (1.0 / 8.0)) - 1.0, 0.0));
    float end = min(ray.t1, hi + 8.0);
    for (uint j = j0; in_box; j++) {
      float t = ray.s + float(j) * 8.0;
      if (t > end)
        break;
      uint b = block_index(block_cell(ray.p0 + t * ray.dp));
      if (!block_occupied(b))
        continue;
      uint k = pick_bin(texelFetch(alpha_hist, int(b)), next_tau());
      float a = P.ert_a[k >> 2][k & 3u];
      A += (1.0 - A) * a;
      if (A >= P.inv_sp.w) {
        result = t;
        break;
      }
    }
  }
  d_ert[id] = result;
}
