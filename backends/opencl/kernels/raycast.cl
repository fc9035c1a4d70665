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
 * AVX-512 gathers; on a GPU they are plain loads. Trilinear sampling,
 * classification and opacity correction are sample.cl's.
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
 *   RP_AO             darken each sample with opacity above 0 by the AO
 *                     volume at its point (one more fetch for those)
 *   RP_ERT            early ray termination at fp.ert_threshold
 *   RP_SKIP           refine the depth pass's limits on the block grid
 *   RP_BRICKED        the volume is a brick pool read through a table
 *                     (out-of-core; sample.cl), and a region may be cast
 *                     in depth slabs: each pass takes the samples before
 *                     fp.slab_cut and leaves its rays' state for the
 *                     next (rp_cl_slab below)
 *   RP_PREINT         pre-integrated classification: each sample takes
 *                     the segment from the previous lattice sample
 *                     (sample.cl's rp_cl_preint; one more fetch per ray,
 *                     for the value before its first sample)
 *   RP_COUNT_FETCHES  also count volume fetches per tile */

typedef struct rp_cl_tile {
  uint samples;
  uint rays_hit;
  float mean_depth;
} rp_cl_tile;

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
/* Counts a fetch made by other means than RP_CL_FETCH. */
#define RP_CL_COUNT(used) (fetches += to_vuint((used) & 1))
#else
#define RP_CL_FETCH(x, y, z, used) rp_cl_sample(vol, &g, x, y, z)
#define RP_CL_COUNT(used) ((void)0)
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

#ifdef RP_SHADING
/* Headlight (L = -dir, two-sided) on straight colour; (gx, gy, gz) is the
 * gradient per world unit. Below 2 % of the data range per voxel of the
 * finest spacing its direction is increasingly noise, and the light
 * blends towards "facing the light": n' = 1 - m (1 - n), m = min(1,
 * |g| * surface) with surface = min_spacing / (0.02 range), 0 for a
 * data range of 0 (the reference's RP__SURFACE_GRADIENT). */
void rp_cl_shade(vfloat *r, vfloat *g, vfloat *b, vfloat gx, vfloat gy,
                 vfloat gz, const rp_cl_packet *k, float surface) {
  vfloat len = sqrt(gx * gx + gy * gy + gz * gz);
  vfloat n = fmin(1.0f, fabs(gx * k->dirx + gy * k->diry + gz * k->dirz) /
                            len);
  vfloat m = fmin(1.0f, len * surface);
  vfloat n2, n4, n16, gain, spec;
  n = select(1.0f - m * (1.0f - n), (vfloat)(1.0f), !(m > 0.0f));
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

#ifdef RP_BRICKED
/* Depth slabs (out-of-core tiles whose bricks do not fit the pool at
 * once): per pixel of the region, 8 floats carried from one pass to the
 * next: colour and opacity, the last sample's depth, the index of the
 * next sample (RP_CL_DONE once the ray has no more), and the samples and
 * fetches so far (their bits). The first pass (fp.slab_flags & 1) starts
 * from nothing; only the last (& 2) writes pixels and tile stats, from
 * the carried figures, so that the result is the single pass's bit for
 * bit: samples are taken in the same order with the same arithmetic. */
#define RP_CL_SLAB_FIRST 1u
#define RP_CL_SLAB_LAST 2u
/* Past every lattice index (those stop at 2^24) yet small enough that a
 * finished lane's unused sample position, (index + 1) * step, stays
 * finite at any step: an infinite one times a zero direction is NaN,
 * which the cell lookup would turn into a brick index out of the table. */
#define RP_CL_DONE 33554432.0f

/* The last lattice index whose position lies before `cut` (as a float; a
 * lane's whole range when cut is +inf): the same predicate-decided walk
 * as rp_cl_lattice_last. */
vfloat rp_cl_lattice_before(const rp_cl_packet *k, float step, float cut) {
  vfloat i;
  vint over;
  if (isinf(cut))
    return (vfloat)(RP_CL_DONE);
  i = clamp(ceil((cut - k->s) / step) - 1.0f, -1.0f, 16777216.0f);
  while (any(over = (i >= 0.0f) & (k->s + i * step >= cut)))
    i -= to_vfloat(over & 1);
  while (any(over = k->s + (i + 1.0f) * step < cut))
    i += to_vfloat(over & 1);
  return i;
}
#endif

/* Global size (region tiles across, region tiles down * 64 / RP_CL_W),
 * local size (1, 64 / RP_CL_W): one work-group per tile of the region
 * [x0, x1) x [y0, y1), whose pixels are written compactly (row pitch
 * x1 - x0) and whose tiles are numbered within the region. `ao` is the
 * AO volume (one byte per voxel, padded like the volume), read with
 * RP_AO only. */
__kernel __attribute__((reqd_work_group_size(
    1, RP_CL_TILE * RP_CL_TILE / RP_CL_W, 1)))
void rp_cl_raycast(rp_cl_frame fp, uint x0, uint y0, uint x1, uint y1,
                   __global const RP_VOXEL_T *vol,
                   __global const float4 *lut, __global const uchar *grid,
                   __global const float2 *front_back, __global uint *rgba,
                   __global rp_cl_tile *tiles,
                   __global ulong *tile_fetches,
                   __global const uchar *ao,
                   __global const uint *brick_table,
                   __global float *slab_state) {
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
#ifdef RP_BRICKED
  /* This lane's pixel in the region (lanes outside it: pixel 0, unused). */
  vuint at_px = select((vuint)0u,
                       (to_vuint(py) - y0) * (x1 - x0) + to_vuint(px) - x0,
                       to_vuint(inside));
#endif

  if (any(inside)) {
    rp_cl_packet k = rp_cl_make_packet(&fp, px + 0.5f, py + 0.5f, inside);
    rp_cl_jitter(&fp, &k, px, py);
    /* Lane j takes samples i0_j .. i1_j of its lattice s + i * step. */
    vfloat i0 = 0.0f, i1 = rp_cl_lattice_last(&k, fp.step);
#ifdef RP_BRICKED
    rp_cl_grid g = rp_cl_grid_bricked(fp.dims, fp.idims, fp.brick_shift,
                                      fp.brick_grid, brick_table);
    rp_cl_brick_cache bcache = {(vint)(-1), (vindex)(0)};
#else
    rp_cl_grid g = rp_cl_grid_make(fp.dims, fp.idims);
#endif
    rp_cl_lutpos lp =
        rp_cl_lutpos_make(fp.value_min, fp.value_max, fp.lut_size);
    vfloat cr = 0.0f, cg = 0.0f, cb = 0.0f, acc = 0.0f, step_i = 0.0f;
#ifdef RP_PREINT
    vfloat f_prev;
#endif
    vfloat front, back;
    vint live;
    float ratio = fp.step / fp.ref_step;
#ifdef RP_SHADING
    float range = fp.value_max - fp.value_min;
    float surface = range > 0.0f ? fp.min_spacing / (0.02f * range) : 0.0f;
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
#if defined(RP_PREINT) && defined(RP_SKIP)
    vfloat i_lattice = i1;
#endif
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
#ifdef RP_PREINT
    {
      /* As the reference: with skipping the segment leaving the last
       * occupied sample is the next sample's; and each lane's first
       * sample takes the segment from the lattice depth before it. (Not
       * with RP_BRICKED: the host refuses it, that value's brick may be
       * gone by a later slab.) */
      vint has;
      vfloat t;
#ifdef RP_SKIP
      i1 = select(i1, fmin(i1 + 1.0f, i_lattice), i0 <= i1);
#endif
      has = i0 <= i1;
      t = k.s + (i0 - 1.0f) * fp.step;
      f_prev = rp_cl_lut_pos(&lp, RP_CL_FETCH(k.p0x + t * k.dpx,
                                              k.p0y + t * k.dpy,
                                              k.p0z + t * k.dpz, has));
    }
#endif
#ifdef RP_BRICKED
    /* Resume where the last slab left each ray, and stop before the cut:
     * i1 keeps the ray's own end, i_cut this pass's. */
    vfloat i_cut;
    {
      vfloat i_end = fmin(i1, rp_cl_lattice_before(&k, fp.step,
                                                    fp.slab_cut));
      if (!(fp.slab_flags & RP_CL_SLAB_FIRST)) {
        vfloat next;
#define RP_CL_LOAD(j)                                                         \
  if (inside.s##j) {                                                          \
    __global const float *q = slab_state + 8u * at_px.s##j;                   \
    cr.s##j = q[0];                                                           \
    cg.s##j = q[1];                                                           \
    cb.s##j = q[2];                                                           \
    acc.s##j = q[3];                                                          \
    last_t.s##j = q[4];                                                       \
    next.s##j = q[5];                                                         \
    samples.s##j = as_uint(q[6]);                                             \
    RP_CL_LOAD_FETCHES(j)                                                     \
  } else {                                                                    \
    next.s##j = RP_CL_DONE;                                                   \
  }
#ifdef RP_COUNT_FETCHES
#define RP_CL_LOAD_FETCHES(j) fetches.s##j = as_uint(q[7]);
#else
#define RP_CL_LOAD_FETCHES(j)
#endif
        RP_CL_LANES(RP_CL_LOAD)
#undef RP_CL_LOAD
#undef RP_CL_LOAD_FETCHES
        i0 = fmax(i0, next);
      }
      i_cut = i_end;
    }
#define RP_CL_END i_cut
#else
#define RP_CL_END i1
#endif
    while (any(live = i0 + step_i <= RP_CL_END)) {
      vfloat t = k.s + (i0 + step_i) * fp.step;
      vfloat qx = k.p0x + t * k.dpx, qy = k.p0y + t * k.dpy;
      vfloat qz = k.p0z + t * k.dpz;
#ifdef RP_BRICKED
      rp_cl_cell cell = rp_cl_cell_at_cached(&g, &bcache, qx, qy, qz);
#else
      rp_cl_cell cell = rp_cl_cell_at(&g, qx, qy, qz);
#endif
      vfloat v = rp_cl_sample_cell(vol, &g, &cell), r, gr, b, a, wgt;
#if defined(RP_SHADING) || defined(RP_AO)
      vint lit;
#endif
      RP_CL_COUNT(live);
#ifdef RP_PREINT
      {
        vfloat f = rp_cl_lut_pos(&lp, v);
        rp_cl_preint(lut, &lp, f_prev, f, ratio, &r, &gr, &b, &a);
        f_prev = f;
      }
#else
      {
        vfloat w;
        vint e = rp_cl_lut_entry(&lp, v, &w);
        rp_cl_classify(lut, e, w, &r, &gr, &b, &a);
      }
      /* At the TF's own step the correction is the identity (the
       * reference's double evaluation rounds back to a exactly). */
      if (ratio != 1.0f)
        a = rp_cl_correct(a, ratio);
#endif
#if defined(RP_SHADING) || defined(RP_AO)
      /* A transparent sample adds exactly 0 whatever its colour, so the
       * gradient and the AO are fetched only where some lane's sample
       * shows: on a CT's soft tissue and air inside occupied blocks that
       * is most packets (bonsai, 512^2: 46 -> 147 M samples/s shaded).
       * The lanes that show are the ones counted. */
      lit = live & (a > 0.0f);
#endif
#ifdef RP_PREINT
      /* A segment is shaded and occluded at its middle (reference.c). */
      {
        vfloat tm = k.s + (i0 + step_i - 0.5f) * fp.step;
        qx = k.p0x + tm * k.dpx;
        qy = k.p0y + tm * k.dpy;
        qz = k.p0z + tm * k.dpz;
      }
#endif
#ifdef RP_SHADING
      if (any(lit)) {
        vfloat gx = (RP_CL_FETCH(qx + 1.0f, qy, qz, lit) -
                     RP_CL_FETCH(qx - 1.0f, qy, qz, lit)) * gsx;
        vfloat gy = (RP_CL_FETCH(qx, qy + 1.0f, qz, lit) -
                     RP_CL_FETCH(qx, qy - 1.0f, qz, lit)) * gsy;
        vfloat gz = (RP_CL_FETCH(qx, qy, qz + 1.0f, lit) -
                     RP_CL_FETCH(qx, qy, qz - 1.0f, lit)) * gsz;
        rp_cl_shade(&r, &gr, &b, gx, gy, gz, &k, surface);
      }
#endif
#ifdef RP_AO
      /* After shading: the AO volume at the density's own point, from
       * the cell that point already found (pre-integrated: at the
       * segment's middle, a cell of its own). */
      if (any(lit)) {
#ifdef RP_PREINT
#ifdef RP_BRICKED
        cell = rp_cl_cell_at_cached(&g, &bcache, qx, qy, qz);
#else
        cell = rp_cl_cell_at(&g, qx, qy, qz);
#endif
#endif
        vfloat occ = rp_cl_sample_bytes(ao, &g, &cell) / 255.0f;
        RP_CL_COUNT(lit);
        r *= occ;
        gr *= occ;
        b *= occ;
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
#ifdef RP_BRICKED
      i_cut = fmin(i_cut, i1);
#endif
#endif
      step_i += 1.0f;
    }
#undef RP_CL_END
#ifdef RP_BRICKED
    if (!(fp.slab_flags & RP_CL_SLAB_LAST)) {
      /* The next sample of each ray: past the cut, or none (ended by ERT,
       * or its range is done). */
      vfloat next = select((vfloat)(RP_CL_DONE), i_cut + 1.0f, i_cut < i1);
      next = select(next, (vfloat)(RP_CL_DONE), i1 < 0.0f);
#define RP_CL_SAVE(j)                                                         \
  if (inside.s##j) {                                                          \
    __global float *q = slab_state + 8u * at_px.s##j;                         \
    q[0] = cr.s##j;                                                           \
    q[1] = cg.s##j;                                                           \
    q[2] = cb.s##j;                                                           \
    q[3] = acc.s##j;                                                          \
    q[4] = last_t.s##j;                                                       \
    q[5] = fmax(next.s##j, i0.s##j);                                          \
    q[6] = as_float(samples.s##j);                                            \
    RP_CL_SAVE_FETCHES(j)                                                     \
  }
#ifdef RP_COUNT_FETCHES
#define RP_CL_SAVE_FETCHES(j) q[7] = as_float(fetches.s##j);
#else
#define RP_CL_SAVE_FETCHES(j)
#endif
      RP_CL_LANES(RP_CL_SAVE)
#undef RP_CL_SAVE
#undef RP_CL_SAVE_FETCHES
    }
#endif
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

#ifdef RP_BRICKED
  /* A slab before the last leaves pixels and stats to the last one (the
   * flag is uniform: every work-item returns, none waits at the barrier
   * below). */
  if (!(fp.slab_flags & RP_CL_SLAB_LAST))
    return;
#endif
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
