/* The ambient-occlusion volume (backends/README.md, "Ambient occlusion
 * volume"): one invocation per voxel of the job's box, one workgroup per
 * 4^3 brick of the grid. For each of L directions, M samples at
 * offset + m * step voxels from the voxel centre, classified through the
 * LUT like the raycast's and corrected to the step; the mean
 * transmittance after each sample, averaged over the directions, is the
 * voxel's AO byte (255: unoccluded).
 *
 * Why a brick per workgroup: with a brick mask, a whole workgroup is
 * skipped or computed together, so no SIMD batch mixes the two (lavapipe
 * runs masked lanes' code anyway). The four voxels of a brick row are one
 * output word: they meet in shared memory and one invocation writes them.
 *
 * The Params block is read with AO meanings (vk_ao.c, set_ao_params):
 *   dims.xyz, idims.xyz   the volume
 *   idims.w, vrange       the LUT size and value range, as for a raycast,
 *                         vrange.w = step / ref_step
 *   eye.x, eye.y          offset and step, voxels
 *   rect.xyz, rect.w      the box's low corner (this dispatch's), L
 *   misc.xyz, misc.w      the box's end (exclusive), M
 *   blocks.xyz, blocks.w  the brick grid, 1 when the brick mask is bound
 *   seed.x                output words per row
 * Workgroup (gx, gy, gz) is brick floor(rect / 4) + (gx, gy, gz). Output
 * row (z - rect.z) * (misc.y - rect.y) + (y - rect.y), word
 * gx: voxels 4 * (rect.x / 4 + gx) .. + 3 of that row. */
#version 450
#define RP_VK_OWN_LOCAL_SIZE 1
#include "common.glsl"

/* x + 4 y + 16 z within the brick. */
layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

/* The box's AO bytes, four per word (x fastest), rows padded to whole
 * bricks (above). */
layout(set = 0, binding = 10, std430) writeonly buffer AoOut {
  uint ao_out[];
};
/* L directions, RGBA32F (w unused). */
layout(set = 0, binding = 11) uniform samplerBuffer ao_dirs;
/* One R8 texel per brick of the grid, x fastest: 0 empty, else full. */
layout(set = 0, binding = 12) uniform usamplerBuffer ao_bricks;

shared uint s_ao[64];

/* AO of voxel v in [0, 1] over L directions (L = 0: not computed).
 * lavapipe runs an `if` whose lanes are all masked off anyway, but leaves
 * a loop once every lane has: a voxel that is skipped says so with its
 * trip count. */
float ao_voxel(vec3 v, uint L) {
  uint M = P.misc.w;
  float offset = P.eye.x, step = P.eye.y;
  vec3 hi = P.dims.xyz - 0.5;
  float acc = 0.0;
  for (uint l = 0u; l < L; l++) {
    vec3 d = texelFetch(ao_dirs, int(l)).xyz;
    float T = 1.0, I = 0.0;
    for (uint m = 0u; m < M; m++) {
      vec3 p = v + (offset + float(m) * step) * d;
      /* sample_volume clamps p, so a point outside the box reads a valid
       * texel and is then given no opacity. */
      float a = classify_alpha(sample_volume(p));
      a = RP_CORRECT ? correct(a) : a;
      bool inside = all(greaterThanEqual(p, vec3(-0.5))) &&
                    all(lessThanEqual(p, hi));
      T *= 1.0 - (inside ? a : 0.0);
      I += T;
    }
    acc += I / float(M);
  }
  return acc / float(max(L, 1u));
}

void main() {
  load_params();
  uint lid = gl_LocalInvocationIndex;
  uvec3 brick = P.rect.xyz / 4u + gl_WorkGroupID;
  uvec3 v = brick * 4u + uvec3(lid & 3u, (lid >> 2) & 3u, lid >> 4);
  bool in_box = all(greaterThanEqual(v, P.rect.xyz)) &&
                all(lessThan(v, P.misc.xyz));
  bool full = true;
  if (P.blocks.w != 0u) {
    uint b = (brick.z * P.blocks.y + brick.y) * P.blocks.x + brick.x;
    full = texelFetch(ao_bricks, int(b)).x != 0u;
  }
  bool work = in_box && full;
  float ao = ao_voxel(vec3(v), work ? P.rect.w : 0u);
  uint q = work ? uint(floor(clamp(ao, 0.0, 1.0) * 255.0 + 0.5)) : 255u;
  s_ao[lid] = q;
  barrier();
  /* The first voxel of each brick row writes the row's word, when the
   * row is in the box (voxels of it outside the box are not copied out
   * by the host). */
  if ((lid & 3u) == 0u && v.y >= P.rect.y && v.y < P.misc.y &&
      v.z >= P.rect.z && v.z < P.misc.z) {
    uint row = (v.z - P.rect.z) * (P.misc.y - P.rect.y) + (v.y - P.rect.y);
    ao_out[row * P.seed.x + gl_WorkGroupID.x] =
        s_ao[lid] | (s_ao[lid + 1u] << 8) | (s_ao[lid + 2u] << 16) |
        (s_ao[lid + 3u] << 24);
  }
}
