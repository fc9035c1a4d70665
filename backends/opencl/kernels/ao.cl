/* Ambient occlusion volume (backends/README.md, "Ambient occlusion
 * volume"): per voxel of a box, the mean over L directions of the mean
 * transmittance after each of M samples along the direction. Built after
 * common.cl and sample.cl, so a sample is classified and corrected by the
 * very functions the raycast uses.
 *
 * A work-item takes a packet of RP_CL_W voxels in vector lanes, as the
 * raycast takes rays: 4 along x by RP_CL_W / 4 along y in one z-slice,
 * aligned to the 4^3 brick grid of the whole volume (not to the box), so
 * that a packet lies in one brick and the brick mask is one test per
 * packet. All lanes walk the same direction and the same sample index at
 * once; their points are neighbours, so the gathers stay in cache. Lanes
 * outside the box compute on clamped points and are not stored; a lane
 * computes the same arithmetic whichever lane of whichever packet it is,
 * so a voxel's value does not depend on the box it was computed in.
 *
 * Options: RP_VOXEL_T, RP_VOXEL_BYTES, RP_INDEX_T and RP_CL_W as for the
 * raycast.
 *
 * Global size (packets across, packets down, slices) of the box, local
 * size (1, 1, 1): a packet has L x M samples to take, far more than a
 * work-group's overhead. */

#define RP_CL_AO_BRICK 4
#define RP_CL_AO_ROWS (RP_CL_W / RP_CL_AO_BRICK)

/* rp_cl_ao_args of cl_internal.h: 4-byte fields, no padding. */
typedef struct rp_cl_ao_args {
  float dims[3];
  uint idims[3];
  uint lo[3], end[3];
  uint directions, samples;
  float offset, step, ref_step;
  float value_min, value_max;
  uint lut_size;
  uint brick_grid[3];
  uint bricked; /* 0: no mask, every voxel is computed */
} rp_cl_ao_args;

__kernel __attribute__((reqd_work_group_size(1, 1, 1)))
void rp_cl_ao(rp_cl_ao_args job, __global const RP_VOXEL_T *vol,
              __global const float4 *lut, __global const uchar *bricks,
              __global const float4 *dirs, __global uchar *out) {
  uint x0 = (job.lo[0] / RP_CL_AO_BRICK + get_global_id(0)) * RP_CL_AO_BRICK;
  uint y0 = (job.lo[1] / RP_CL_AO_ROWS + get_global_id(1)) * RP_CL_AO_ROWS;
  uint z = job.lo[2] + get_global_id(2);
  vfloat lane = RP_CL_LANE_IDS;
  vfloat ly = floor(lane * (1.0f / RP_CL_AO_BRICK));
  vfloat vx = (float)x0 + (lane - RP_CL_AO_BRICK * ly);
  vfloat vy = (float)y0 + ly, vz = (float)z;
  vint store = (vx >= (float)job.lo[0]) & (vx < (float)job.end[0]) &
               (vy >= (float)job.lo[1]) & (vy < (float)job.end[1]);
  vuint value = 255u;
  int full = 1;

  if (job.bricked)
    full = bricks[((z / RP_CL_AO_BRICK) * job.brick_grid[1] +
                   y0 / RP_CL_AO_BRICK) * job.brick_grid[0] +
                  x0 / RP_CL_AO_BRICK] != 0;
  if (full) {
    rp_cl_grid g = rp_cl_grid_make(job.dims, job.idims);
    rp_cl_lutpos lp =
        rp_cl_lutpos_make(job.value_min, job.value_max, job.lut_size);
    float ratio = job.step / job.ref_step;
    float hx = job.dims[0] - 0.5f, hy = job.dims[1] - 0.5f;
    float hz = job.dims[2] - 0.5f;
    vfloat acc = 0.0f;
    uint l, m;
    for (l = 0; l < job.directions; l++) {
      float4 d = dirs[l];
      vfloat T = 1.0f, I = 0.0f;
      for (m = 0; m < job.samples; m++) {
        float s = job.offset + (float)m * job.step;
        vfloat px = vx + s * d.x, py = vy + s * d.y, pz = vz + s * d.z;
        vint in = (px >= -0.5f) & (px <= hx) & (py >= -0.5f) &
                  (py <= hy) & (pz >= -0.5f) & (pz <= hz);
        vfloat a = 0.0f;
        /* A packet whose points have all left the box adds T as it is:
         * near the faces, many directions do after a few samples. */
        if (any(in)) {
          vfloat w, v = rp_cl_sample(vol, &g, px, py, pz);
          vint e = rp_cl_lut_entry(&lp, v, &w);
          a = rp_cl_classify_alpha(lut, e, w);
          /* At the TF's own step the correction is the identity, and it
           * maps 0 to 0 exactly: in empty space it is skipped. */
          if (ratio != 1.0f && any(a > 0.0f))
            a = rp_cl_correct(a, ratio);
          a = select((vfloat)(0.0f), a, in);
        }
        T *= 1.0f - a;
        I += T;
      }
      acc += I / (float)job.samples;
    }
    acc = clamp(acc / (float)job.directions, 0.0f, 1.0f);
    value = to_vuint(floor(acc * 255.0f + 0.5f));
  }
  {
    uint nx = job.end[0] - job.lo[0], ny = job.end[1] - job.lo[1];
    ulong slice = ((ulong)(z - job.lo[2]) * ny) * nx;
    vuint ox = to_vuint(vx) - job.lo[0], oy = to_vuint(vy) - job.lo[1];
#define RP_CL_STORE(j)                                                        \
  if (store.s##j)                                                             \
    out[slice + (ulong)oy.s##j * nx + ox.s##j] = (uchar)value.s##j;
    RP_CL_LANES(RP_CL_STORE)
#undef RP_CL_STORE
  }
}
