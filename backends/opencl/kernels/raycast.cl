/* Raycast: one work-group per 8x8 tile of a region, each work-item a
 * packet of RP_CL_W rays (see common.cl). The lanes march in lockstep on
 * their own lattices (lane j at step k takes its sample i0_j + k) and
 * drop out as they finish; the loop ends when all lanes have. Then one
 * stats record per tile, reduced in local memory (integer sums and a
 * fixed-order float sum, so a tile's record does not depend on
 * scheduling).
 *
 * Memory reads per lane (voxel pairs, LUT entries, grid bytes) are
 * written as short loops over private arrays, the form LLVM turns into
 * AVX-512 gathers; on a GPU they are plain loads.
 *
 * Options (each compiles code in or out; nothing is a run-time test on a
 * uniform):
 *   RP_VOXEL_T        uchar, ushort or float: the volume's native type
 *   RP_VOXEL_BYTES    its size: 1, 2 or 4
 *   RP_INDEX_T        int, or long for volumes of 2^31 voxels or more
 *                     (signed, so that gathers can use 32-bit indices)
 *   RP_CL_W           rays per work-item (common.cl)
 *   RP_SHADING        headlight gradient shading (six more fetches per
 *                     sample with opacity above 0)
 *   RP_ERT            early ray termination at fp.ert_threshold
 *   RP_SKIP           refine the depth pass's limits on the block grid
 *   RP_COUNT_FETCHES  also count volume fetches per tile */

#ifndef RP_INDEX_T
#define RP_INDEX_T int
#endif
#ifndef RP_VOXEL_BYTES
#define RP_VOXEL_BYTES 1
#endif

typedef RP_CL_VEC(RP_INDEX_T) vindex;
#define to_vindex RP_CL_CONVERT(RP_INDEX_T)

typedef struct rp_cl_tile {
  uint samples;
  uint rays_hit;
  float mean_depth;
} rp_cl_tile;

/* What trilinear sampling needs of the volume. The low corner is clamped
 * to dims - 2 (0 for a one-voxel axis) with the weight then reaching 1,
 * so the two voxels along x are always adjacent and come in one load;
 * along y and z the upper neighbour is one row or slice on, or the same
 * one for a one-voxel axis. */
typedef struct rp_cl_grid {
  float topx, topy, topz; /* dims - 1: where coordinates clamp */
  int lomx, lomy, lomz;   /* max(dims - 2, 0) */
  RP_INDEX_T row, slice, dy, dz; /* strides; upper y and z neighbours */
} rp_cl_grid;

rp_cl_grid rp_cl_grid_of(const rp_cl_frame *fp) {
  rp_cl_grid g;
  g.topx = fp->dims[0] - 1.0f;
  g.topy = fp->dims[1] - 1.0f;
  g.topz = fp->dims[2] - 1.0f;
  g.lomx = fp->idims[0] > 1u ? (int)fp->idims[0] - 2 : 0;
  g.lomy = fp->idims[1] > 1u ? (int)fp->idims[1] - 2 : 0;
  g.lomz = fp->idims[2] > 1u ? (int)fp->idims[2] - 2 : 0;
  g.row = fp->idims[0];
  g.slice = (RP_INDEX_T)fp->idims[0] * fp->idims[1];
  g.dy = fp->idims[1] > 1u ? g.row : 0u;
  g.dz = fp->idims[2] > 1u ? g.slice : 0u;
  return g;
}

/* Two x-adjacent voxels read as one unaligned integer: the unit the
 * gathers below move. uchar reads four bytes and keeps two (the buffer is
 * padded past its end for that). */
#if RP_VOXEL_BYTES == 4
#define RP_CL_PAIR_T ulong
#else
#define RP_CL_PAIR_T uint
#endif
typedef RP_CL_VEC(RP_CL_PAIR_T) vpair;
typedef struct __attribute__((packed)) rp_cl_pair {
  RP_CL_PAIR_T v;
} rp_cl_pair;

/* The voxel pair at each lane's index (a gather: per-lane inserts into a
 * vector cost twice as much on PoCL). */
vpair rp_cl_gather(__global const RP_VOXEL_T *vol, vindex at) {
  RP_CL_PAIR_T out[RP_CL_W];
  RP_INDEX_T idx[RP_CL_W];
  int j;
  vstore_w(at, 0, idx);
#pragma clang loop vectorize(enable) vectorize_width(RP_CL_W)
  for (j = 0; j < RP_CL_W; j++)
    out[j] = ((__global const rp_cl_pair *)(vol + idx[j]))->v;
  return vload_w(0, out);
}

/* Linear interpolation along x within each lane's voxel pair. */
vfloat rp_cl_lerp_pair(vpair q, vfloat w) {
#if RP_VOXEL_BYTES == 1
  vfloat lo = to_vfloat(q & 0xffu), hi = to_vfloat((q >> 8) & 0xffu);
#elif RP_VOXEL_BYTES == 2
  vfloat lo = to_vfloat(q & 0xffffu), hi = to_vfloat(q >> 16);
#else
  vfloat lo = as_vfloat(RP_CL_CONVERT(uint)(q));
  vfloat hi = as_vfloat(RP_CL_CONVERT(uint)(q >> 32));
#endif
  return mix(lo, hi, w);
}

/* Trilinear interpolation of the packet's points: clamp to [0, dims - 1],
 * interpolate along x, then y, then z. Clamped coordinates are >= 0, so
 * truncation is floor. */
vfloat rp_cl_sample(__global const RP_VOXEL_T *vol, const rp_cl_grid *g,
                    vfloat px, vfloat py, vfloat pz) {
  vfloat cx = min(max(px, 0.0f), g->topx);
  vfloat cy = min(max(py, 0.0f), g->topy);
  vfloat cz = min(max(pz, 0.0f), g->topz);
  vint ix = min(to_vint(cx), g->lomx), iy = min(to_vint(cy), g->lomy);
  vint iz = min(to_vint(cz), g->lomz);
  vfloat wx = cx - to_vfloat(ix), wy = cy - to_vfloat(iy);
  vfloat wz = cz - to_vfloat(iz);
  vindex base = to_vindex(ix) + to_vindex(iy) * g->row +
                to_vindex(iz) * g->slice;
  vfloat e0 = rp_cl_lerp_pair(rp_cl_gather(vol, base), wx);
  vfloat e1 = rp_cl_lerp_pair(rp_cl_gather(vol, base + g->dy), wx);
  vfloat e2 = rp_cl_lerp_pair(rp_cl_gather(vol, base + g->dz), wx);
  vfloat e3 = rp_cl_lerp_pair(rp_cl_gather(vol, base + g->dy + g->dz), wx);
  return mix(mix(e0, e1, wy), mix(e2, e3, wy), wz);
}

#ifdef RP_COUNT_FETCHES
/* Counts one fetch in each lane of `used` (the lanes that use the
 * result). A call rather than a comma expression, so that two fetches in
 * one expression do not modify the counter unsequenced. */
vfloat rp_cl_counted(__global const RP_VOXEL_T *vol, const rp_cl_grid *g,
                     vfloat px, vfloat py, vfloat pz, vint used,
                     vuint *count) {
  *count += to_vuint(used & 1);
  return rp_cl_sample(vol, g, px, py, pz);
}
#define RP_CL_FETCH(x, y, z, used)                                            \
  rp_cl_counted(vol, &g, x, y, z, used, &fetches)
#else
#define RP_CL_FETCH(x, y, z, used) rp_cl_sample(vol, &g, x, y, z)
#endif

/* Index of the last lattice sample s + i * step <= t1 in each lane (as a
 * float; -1 where the lane has no ray). The quotient estimates it, the
 * predicate on the positions as computed decides, as in the reference's
 * rp__lattice_count. */
vfloat rp_cl_lattice_last(const rp_cl_packet *k, float step) {
  vfloat i = clamp(floor((k->t1 - k->s) / step), 0.0f, 16777216.0f);
  vint over;
  while (any(over = (i > 0.0f) & (k->s + i * step > k->t1)))
    i -= to_vfloat(over & 1);
  while (any(over = k->s + (i + 1.0f) * step <= k->t1))
    i += to_vfloat(over & 1);
  return select((vfloat)(-1.0f), i, k->hit);
}

#ifdef RP_SKIP
/* Whether each lane's sample i lies in an occupied block. */
vint rp_cl_occupied(const rp_cl_frame *fp, __global const uchar *grid,
                    const rp_cl_packet *k, vfloat i) {
  vfloat t = k->s + i * fp->step;
  return rp_cl_occupied_at(fp, grid, k->p0x + t * k->dpx,
                           k->p0y + t * k->dpy, k->p0z + t * k->dpz);
}
#endif

/* Opacity for `step` from opacity a over the reference step:
 * 1 - (1 - a)^ratio = -expm1(ratio * log1p(-a)), exact at 0 and 1.
 *
 * Written out rather than calling log1p and expm1: the library versions
 * cost a third of a CPU frame. Both halves keep relative precision where
 * it matters. log1p(-a) = 2 atanh(s), s = t / (2 + t), with t = -a
 * itself for a < 1/4 (no rounding of 1 - a), else t = m - 1 for the
 * mantissa m in [0.71, 1.41) of 1 - a (exact there); |s| <= 0.172, so
 * the series to s^7 is good to 1e-7. expm1(x) = 2^n (expm1(y) + 1) - 1
 * with x = n ln 2 + y, |y| <= ln 2 / 2, and a Taylor series to y^7; for
 * small x, n = 0 and the result is expm1(y) itself. Relative error about
 * 2e-7, far below what an 8-bit pixel can show. */
vfloat rp_cl_correct(vfloat a, float ratio) {
  vint small = a < 0.25f;
  vint bits = as_vint(1.0f - a);
  vint e = ((bits >> 23) & 0xff) - 127;
  vfloat m = as_vfloat((bits & 0x7fffff) | 0x3f800000);
  vint top = m > 1.41421356f;
  vfloat t, s, s2, ln, x, y, em, p2;
  vint n;
  m = select(m, 0.5f * m, top);
  e -= top; /* top is -1 where true */
  t = select(m - 1.0f, -a, small);
  s = t / (2.0f + t);
  s2 = s * s;
  ln = 2.0f * s * (1.0f + s2 * (1.0f / 3.0f +
                                 s2 * (1.0f / 5.0f + s2 * (1.0f / 7.0f)))) +
       select(to_vfloat(e), (vfloat)(0.0f), small) * 0.693147181f;
  /* e^-87 is below the smallest normal float: the result is 1 there. */
  x = max(ratio * ln, -87.0f);
  n = RP_CL_CAT(to_vint, _rte)(x * 1.44269504f);
  y = x - to_vfloat(n) * 0.693147181f;
  em = y * (1.0f + y * (1.0f / 2.0f +
                        y * (1.0f / 6.0f +
                             y * (1.0f / 24.0f +
                                  y * (1.0f / 120.0f +
                                       y * (1.0f / 720.0f +
                                            y * (1.0f / 5040.0f)))))));
  p2 = as_vfloat((n + 127) << 23); /* 2^n, normal */
  x = -(em * p2 + (p2 - 1.0f));
  x = select(x, (vfloat)(0.0f), a <= 0.0f);
  return select(x, (vfloat)(1.0f), a >= 1.0f);
}

/* Each lane's RGBA from the LUT: entries e and e + 1 mixed by w. */
void rp_cl_classify(__global const float4 *lut, vint e, vfloat w,
                    vfloat *r, vfloat *g, vfloat *b, vfloat *a) {
  __global const float *lf = (__global const float *)lut;
  float c[8][RP_CL_W];
  int idx[RP_CL_W], j;
  vstore_w(e * 4, 0, idx);
#pragma clang loop vectorize(enable) vectorize_width(RP_CL_W)
  for (j = 0; j < RP_CL_W; j++) {
    __global const float *q = lf + idx[j];
    c[0][j] = q[0];
    c[1][j] = q[1];
    c[2][j] = q[2];
    c[3][j] = q[3];
    c[4][j] = q[4];
    c[5][j] = q[5];
    c[6][j] = q[6];
    c[7][j] = q[7];
  }
#define RP_CL_ROW(i) vload_w(0, c[i])
  *r = mix(RP_CL_ROW(0), RP_CL_ROW(4), w);
  *g = mix(RP_CL_ROW(1), RP_CL_ROW(5), w);
  *b = mix(RP_CL_ROW(2), RP_CL_ROW(6), w);
  *a = mix(RP_CL_ROW(3), RP_CL_ROW(7), w);
#undef RP_CL_ROW
}

#ifdef RP_SHADING
/* Headlight (L = -dir, two-sided) on straight colour; (gx, gy, gz) is the
 * gradient per world unit. A gradient below 1e-6 of the data range is
 * noise, lit as if it faced the light. */
void rp_cl_shade(vfloat *r, vfloat *g, vfloat *b, vfloat gx, vfloat gy,
                 vfloat gz, const rp_cl_packet *k, float range) {
  vfloat len = sqrt(gx * gx + gy * gy + gz * gz);
  vfloat n = fmin(1.0f, fabs(gx * k->dirx + gy * k->diry + gz * k->dirz) /
                            len);
  vfloat n2, n4, n16, gain, spec;
  if (range > 0.0f)
    n = select(n, (vfloat)(1.0f), !(len / range >= 1e-6f));
  else
    n = 1.0f;
  n2 = n * n;
  n4 = n2 * n2;
  n16 = n4 * n4;
  n16 *= n16;
  gain = 0.3f + 0.7f * n;
  spec = 0.2f * (n16 * n4);
  *r = clamp(*r * gain + spec, 0.0f, 1.0f);
  *g = clamp(*g * gain + spec, 0.0f, 1.0f);
  *b = clamp(*b * gain + spec, 0.0f, 1.0f);
}
#endif

/* Global size (region tiles across, region tiles down * 64 / RP_CL_W),
 * local size (1, 64 / RP_CL_W): one work-group per tile of the region
 * [x0, x1) x [y0, y1), whose pixels are written compactly (row pitch
 * x1 - x0) and whose tiles are numbered within the region. */
__kernel __attribute__((reqd_work_group_size(
    1, RP_CL_TILE * RP_CL_TILE / RP_CL_W, 1)))
void rp_cl_raycast(rp_cl_frame fp, uint x0, uint y0, uint x1, uint y1,
                   __global const RP_VOXEL_T *vol,
                   __global const float4 *lut, __global const uchar *grid,
                   __global const float2 *front_back, __global uint *rgba,
                   __global rp_cl_tile *tiles,
                   __global ulong *tile_fetches) {
  __local uint l_samples[RP_CL_TILE * RP_CL_TILE];
  __local float l_depth[RP_CL_TILE * RP_CL_TILE];
#ifdef RP_COUNT_FETCHES
  __local uint l_fetches[RP_CL_TILE * RP_CL_TILE];
  vuint fetches = 0;
#endif
  vfloat px, py;
  uint slot = rp_cl_lane_coords(x0, y0, &px, &py);
  vint inside = (px < (float)x1) & (py < (float)y1);
  vuint samples = 0;
  vfloat last_t = 0.0f;

  if (any(inside)) {
    rp_cl_packet k = rp_cl_make_packet(&fp, px + 0.5f, py + 0.5f, inside);
    /* Lane j takes samples i0_j .. i1_j of its lattice s + i * step. */
    vfloat i0 = 0.0f, i1 = rp_cl_lattice_last(&k, fp.step);
    rp_cl_grid g = rp_cl_grid_of(&fp);
    vfloat cr = 0.0f, cg = 0.0f, cb = 0.0f, acc = 0.0f, step_i = 0.0f;
    vfloat front, back;
    vint live;
    float range = fp.value_max - fp.value_min;
    /* x * (lut_size - 1) in one multiply; a constant field sits at 0. */
    float lut_scale = range > 0.0f ? (float)(fp.lut_size - 1u) / range
                                   : 0.0f;
    float lut_top = (float)(fp.lut_size - 1u);
    int lut_last = (int)fp.lut_size - 2;
    float ratio = fp.step / fp.ref_step;
#ifdef RP_SHADING
    float gsx = 0.5f * fp.inv_spacing[0], gsy = 0.5f * fp.inv_spacing[1];
    float gsz = 0.5f * fp.inv_spacing[2];
#endif
    {
      /* The depth pass's (D_front, D_back) of each lane; lanes outside
       * the image read a pixel inside it and ignore it. */
      vuint cx = min(to_vuint(px), fp.width - 1u);
      vuint cy = min(to_vuint(py), fp.height - 1u);
      vuint at = cy * fp.width + cx;
#define RP_CL_SPAN(j)                                                         \
  {                                                                           \
    float2 v = front_back[at.s##j];                                           \
    front.s##j = v.x;                                                         \
    back.s##j = v.y;                                                          \
  }
      RP_CL_LANES(RP_CL_SPAN)
#undef RP_CL_SPAN
    }
    /* No occupied block (or a miss): +inf > -inf empties the range. */
    i1 = select((vfloat)(-1.0f), i1, front <= back);
#ifdef RP_SKIP
    {
      /* Start one lattice step outside the depth pass's span so that a
       * rounding difference between the passes never drops a sample in
       * an occupied block; the walks then settle on the first and last
       * samples whose block is occupied. */
      vint more;
      vfloat lo = ceil((front - k.s) / fp.step) - 1.0f;
      vfloat hi = floor((back - k.s) / fp.step) + 1.0f;
      i1 = select(i1, fmin(i1, hi), front <= back);
      i0 = select(i0, fmax(lo, 0.0f), front <= back);
      while (any(more = (i0 <= i1) &
                        !rp_cl_occupied(&fp, grid, &k, i0)))
        i0 += to_vfloat(more & 1);
      while (any(more = (i1 > i0) &
                        !rp_cl_occupied(&fp, grid, &k, i1)))
        i1 -= to_vfloat(more & 1);
    }
#endif
    while (any(live = i0 + step_i <= i1)) {
      vfloat t = k.s + (i0 + step_i) * fp.step;
      vfloat qx = k.p0x + t * k.dpx, qy = k.p0y + t * k.dpy;
      vfloat qz = k.p0z + t * k.dpz;
      vfloat v = RP_CL_FETCH(qx, qy, qz, live);
      vfloat f = clamp((v - fp.value_min) * lut_scale, 0.0f, lut_top);
      vint e = min(to_vint(f), lut_last);
      vfloat w = f - to_vfloat(e), r, gr, b, a, wgt;
      rp_cl_classify(lut, e, w, &r, &gr, &b, &a);
      /* At the TF's own step the correction is the identity (the
       * reference's double evaluation rounds back to a exactly). */
      if (ratio != 1.0f)
        a = rp_cl_correct(a, ratio);
#ifdef RP_SHADING
      {
        /* A transparent sample adds exactly 0 whatever its colour, so the
         * gradient is fetched only where some lane's sample shows: on a
         * CT's soft tissue and air inside occupied blocks that is most
         * packets (bonsai, 512^2: 46 -> 147 M samples/s). The lanes that
         * show are the ones counted. */
        vint lit = live & (a > 0.0f);
        if (any(lit)) {
          vfloat gx = (RP_CL_FETCH(qx + 1.0f, qy, qz, lit) -
                       RP_CL_FETCH(qx - 1.0f, qy, qz, lit)) * gsx;
          vfloat gy = (RP_CL_FETCH(qx, qy + 1.0f, qz, lit) -
                       RP_CL_FETCH(qx, qy - 1.0f, qz, lit)) * gsy;
          vfloat gz = (RP_CL_FETCH(qx, qy, qz + 1.0f, lit) -
                       RP_CL_FETCH(qx, qy, qz - 1.0f, lit)) * gsz;
          rp_cl_shade(&r, &gr, &b, gx, gy, gz, &k, range);
        }
      }
#endif
      wgt = select((vfloat)(0.0f), (1.0f - acc) * a, live);
      cr += wgt * r;
      cg += wgt * gr;
      cb += wgt * b;
      acc += wgt;
      samples += to_vuint(live & 1);
      last_t = select(last_t, t, live);
#ifdef RP_ERT
      /* A lane that reached the threshold ends its range here. */
      i1 = select(i1, (vfloat)(-1.0f), live & (acc >= fp.ert_threshold));
#endif
      step_i += 1.0f;
    }
    {
      vuint pr = to_vuint_sat(floor(clamp(cr, 0.0f, 1.0f) * 255.0f + 0.5f));
      vuint pg = to_vuint_sat(floor(clamp(cg, 0.0f, 1.0f) * 255.0f + 0.5f));
      vuint pb = to_vuint_sat(floor(clamp(cb, 0.0f, 1.0f) * 255.0f + 0.5f));
      vuint pa = to_vuint_sat(floor(clamp(acc, 0.0f, 1.0f) * 255.0f + 0.5f));
      /* RGBA8 bytes in memory order, one uint per pixel. */
      vuint pix = pr | pg << 8 | pb << 16 | pa << 24;
      vuint ox = to_vuint(px) - x0, oy = to_vuint(py) - y0;
      uint pitch = x1 - x0;
#define RP_CL_STORE(j)                                                        \
  if (inside.s##j)                                                            \
    rgba[oy.s##j * pitch + ox.s##j] = pix.s##j;
      RP_CL_LANES(RP_CL_STORE)
#undef RP_CL_STORE
    }
  }

  vstore_w(samples, 0, l_samples + slot);
  vstore_w(last_t, 0, l_depth + slot);
#ifdef RP_COUNT_FETCHES
  vstore_w(fetches, 0, l_fetches + slot);
#endif
  barrier(CLK_LOCAL_MEM_FENCE);
  if (slot == 0u) {
    ulong sum = 0;
    uint hits = 0, j;
    float depth = 0.0f;
    rp_cl_tile out;
#ifdef RP_COUNT_FETCHES
    ulong fsum = 0;
#endif
    /* Row by row, as the reference sums its tile. */
    for (j = 0; j < RP_CL_TILE * RP_CL_TILE; j++) {
      sum += l_samples[j];
      if (l_samples[j] > 0u) {
        hits++;
        depth += l_depth[j];
      }
#ifdef RP_COUNT_FETCHES
      fsum += l_fetches[j];
#endif
    }
    out.samples = sum > 0xffffffffu ? 0xffffffffu : (uint)sum;
    out.rays_hit = hits;
    out.mean_depth = hits > 0u ? depth / (float)hits : 0.0f;
    j = get_group_id(1) * get_num_groups(0) + get_group_id(0);
    tiles[j] = out;
#ifdef RP_COUNT_FETCHES
    tile_fetches[j] = fsum;
#endif
  }
}
