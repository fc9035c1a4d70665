/* ERT pre-pass: per pre-pass ray, the depth where a coarse march through
 * the blocks' opacity histograms is expected to terminate (+inf: never).
 *
 * One pre-pass ray per 4x4 scaled pixels, through the centre of its 4x4
 * cell, in packets like every kernel here (global size (tiles across,
 * tiles down * 64 / RP_CL_W) over the pre-pass grid, local size (1,
 * 64 / RP_CL_W)). At every coarse step in an occupied block a random draw
 * picks an opacity bin with probability proportional to its count. The
 * random stream (hybrid Tausworthe, seeding below) is exactly the
 * contract's, in 32-bit integer lanes, so every backend draws the same
 * numbers for the same (seed, frame, ray); a lane's stream advances only
 * when that lane draws. */

#define RP_CL_ERT_STRIDE 4
#define RP_CL_ERT_STEP 8.0f

vuint rp_cl_taus(vuint z, uint s1, uint s2, uint s3, uint m) {
  vuint b = ((z << s1) ^ z) >> s2;
  return ((z & m) << s3) ^ b;
}

typedef struct rp_cl_rng {
  vuint z1, z2, z3, z4;
} rp_cl_rng;

/* One draw in the lanes where `take` is set; the others keep their
 * state. */
vuint rp_cl_draw(rp_cl_rng *g, vint take) {
  vuint z1 = rp_cl_taus(g->z1, 13u, 19u, 12u, 4294967294u);
  vuint z2 = rp_cl_taus(g->z2, 2u, 25u, 4u, 4294967288u);
  vuint z3 = rp_cl_taus(g->z3, 3u, 11u, 17u, 4294967280u);
  vuint z4 = 1664525u * g->z4 + 1013904223u;
  vuint m = RP_CL_CAT(as_uint, RP_CL_W)(take);
  g->z1 = (z1 & m) | (g->z1 & ~m);
  g->z2 = (z2 & m) | (g->z2 & ~m);
  g->z3 = (z3 & m) | (g->z3 & ~m);
  g->z4 = (z4 & m) | (g->z4 & ~m);
  return z1 ^ z2 ^ z3 ^ z4;
}

/* `alpha` holds the 16 bins' opacities already corrected to the coarse
 * step (computed once on the host, in double). */
__kernel __attribute__((reqd_work_group_size(
    1, RP_CL_TILE * RP_CL_TILE / RP_CL_W, 1)))
void rp_cl_ert(rp_cl_frame fp, __global const uchar *grid,
               __global const uint *alpha_hist, float16 alpha,
               __global float *out) {
  uint gw = (fp.width + RP_CL_ERT_STRIDE - 1) / RP_CL_ERT_STRIDE;
  uint gh = (fp.height + RP_CL_ERT_STRIDE - 1) / RP_CL_ERT_STRIDE;
  vfloat cx, cy, acc = 0.0f, result = INFINITY, j, end;
  vint inside, live;
  vuint base, id;
  rp_cl_packet k;
  rp_cl_rng g;
  rp_cl_lane_coords(0, 0, &cx, &cy);
  inside = (cx < (float)gw) & (cy < (float)gh);
  if (!any(inside))
    return;
  k = rp_cl_make_packet(&fp, RP_CL_ERT_STRIDE * cx + 2.0f,
                        RP_CL_ERT_STRIDE * cy + 2.0f, inside);
  id = to_vuint(cy) * gw + to_vuint(cx);
  base = rp_cl_mix((vuint)(fp.ert_seed) ^
                   rp_cl_mix((vuint)(fp.frame + 0x9e3779b9u)));
  g.z1 = rp_cl_mix(base ^ id) | 128u;
  g.z2 = rp_cl_mix(g.z1 + 0x632be5abu) | 128u;
  g.z3 = rp_cl_mix(g.z2 + 0x85157af5u) | 128u;
  g.z4 = rp_cl_mix(g.z3 + 0x2545f491u);
  /* Draws happen only in occupied blocks, and those lie in the box of
   * the occupied blocks: the march skips the lattice points before and
   * after the ray's span inside it, keeping a point of margin at each
   * end for rounding at the faces. The points marched, the draws and
   * the result are those of a march over the whole of [s, t1]. */
  {
    vfloat lo, hi;
    live = rp_cl_occupied_box_span(&fp, &k, &lo, &hi);
    j = fmax(floor((lo - k.s) * (1.0f / RP_CL_ERT_STEP)) - 1.0f, 0.0f);
    end = fmin(k.t1, hi + RP_CL_ERT_STEP);
  }
  while (rp_cl_any(live)) {
    vfloat t = k.s + j * RP_CL_ERT_STEP;
    vint b, draw;
    live &= t <= end;
    b = rp_cl_block_index(
        &fp, rp_cl_block_axis(k.p0x + t * k.dpx, fp.blocks[0]),
        rp_cl_block_axis(k.p0y + t * k.dpy, fp.blocks[1]),
        rp_cl_block_axis(k.p0z + t * k.dpz, fp.blocks[2]));
    draw = live & (rp_cl_gather_byte(grid, b) != 0);
    if (rp_cl_any(draw)) {
      vuint tau = rp_cl_draw(&g, draw), cum[15], sum = 0, target;
      vint bin = 0;
      int q;
      rp_cl_int_lanes at;
      rp_cl_uint_lanes w[4];
      vfloat a;
      /* The lanes' 16-byte histograms, as four words each. */
      at.v = b * 4;
#pragma clang loop vectorize(enable) vectorize_width(RP_CL_W)
      for (q = 0; q < RP_CL_W; q++) {
        w[0].a[q] = alpha_hist[at.a[q]];
        w[1].a[q] = alpha_hist[at.a[q] + 1];
        w[2].a[q] = alpha_hist[at.a[q] + 2];
        w[3].a[q] = alpha_hist[at.a[q] + 3];
      }
      /* Running sums of the bins. The bin drawn is the first whose sum
       * passes target = ((uint64)tau * total) >> 32; the sums never
       * decrease, so it is also the number of the first 15 that do not
       * pass it (15 when all do not): a compare and an add per bin,
       * where a search for the first kept two more masks. */
#pragma unroll
      for (q = 0; q < 15; q++) {
        sum += (w[q / 4].v >> (8 * (q % 4))) & 0xffu;
        cum[q] = sum;
      }
      /* mul_hi(tau, total) from two 32-bit products, exact because a
       * histogram's total is under 2^16 (16 bytes): PoCL builds mul_hi
       * on 32-bit lanes from four. */
      sum += w[3].v >> 24;
      target = ((tau >> 16) * sum + (((tau & 0xffffu) * sum) >> 16)) >> 16;
#pragma unroll
      for (q = 0; q < 15; q++)
        bin -= cum[q] <= target;
      /* The bin's corrected opacity from the 16 in registers, by the
       * bin's four bits: 15 blends and no memory, where a gather from
       * a private array took 64-bit addresses. */
      {
        vint b0 = (bin & 1) != 0, b1 = (bin & 2) != 0, b2 = (bin & 4) != 0;
        vfloat p0 = select((vfloat)(alpha.s0), (vfloat)(alpha.s1), b0);
        vfloat p2 = select((vfloat)(alpha.s2), (vfloat)(alpha.s3), b0);
        vfloat p4 = select((vfloat)(alpha.s4), (vfloat)(alpha.s5), b0);
        vfloat p6 = select((vfloat)(alpha.s6), (vfloat)(alpha.s7), b0);
        vfloat p8 = select((vfloat)(alpha.s8), (vfloat)(alpha.s9), b0);
        vfloat pa = select((vfloat)(alpha.sa), (vfloat)(alpha.sb), b0);
        vfloat pc = select((vfloat)(alpha.sc), (vfloat)(alpha.sd), b0);
        vfloat pe = select((vfloat)(alpha.se), (vfloat)(alpha.sf), b0);
        p0 = select(p0, p2, b1);
        p4 = select(p4, p6, b1);
        p8 = select(p8, pa, b1);
        pc = select(pc, pe, b1);
        p0 = select(p0, p4, b2);
        p8 = select(p8, pc, b2);
        a = select(p0, p8, (bin & 8) != 0);
      }
      acc = select(acc, acc + (1.0f - acc) * a, draw);
      draw &= acc >= fp.ert_threshold;
      result = select(result, t, draw);
      live &= ~draw;
    }
    j += 1.0f;
  }
  {
    vuint at = id;
#define RP_CL_PUT(n)                                                          \
  if (inside.s##n)                                                            \
    out[at.s##n] = result.s##n;
    RP_CL_LANES(RP_CL_PUT)
#undef RP_CL_PUT
  }
}
