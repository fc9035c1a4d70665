/* Sampling shared by the raycast and the AO kernels (after common.cl):
 * trilinear interpolation of the volume from a buffer, the LUT
 * classification and the opacity correction, exactly as backends/README.md
 * states them. The raycast and the AO volume classify a point the same
 * way because both call these.
 *
 * Options: RP_VOXEL_T, RP_VOXEL_BYTES and RP_INDEX_T, as raycast.cl
 * describes them. */

#ifndef RP_INDEX_T
#define RP_INDEX_T int
#endif
#ifndef RP_VOXEL_BYTES
#define RP_VOXEL_BYTES 1
#endif

typedef RP_CL_VEC(RP_INDEX_T) vindex;
#define to_vindex RP_CL_CONVERT(RP_INDEX_T)

/* What trilinear sampling needs of the volume. The low corner is clamped
 * to dims - 2 (0 for a one-voxel axis) with the weight then reaching 1,
 * so the two voxels along x are always adjacent and come in one load;
 * along y and z the upper neighbour is one row or slice on, or the same
 * one for a one-voxel axis. */
typedef struct rp_cl_grid {
  float topx, topy, topz; /* dims - 1: where coordinates clamp */
  int lomx, lomy, lomz;   /* max(dims - 2, 0) */
  RP_INDEX_T row, slice, dy, dz; /* strides; upper y and z neighbours */
#ifdef RP_BRICKED
  /* Out-of-core (raypace_backend.h, rp_frame_params.brick_shift): `row`
   * and `slice` are a stored brick's, and a cell's brick is found in
   * the table. The border is replicated past the volume's end, so the
   * upper neighbours are always one row and one slice on. */
  __global const uint *table;
  int shift, mask;
  int bgx, bgxy;          /* bricks per row and per slice of the grid */
  RP_INDEX_T brick_voxels;
#endif
} rp_cl_grid;

/* The grid of a volume of idims voxels; dims is the same in float. */
rp_cl_grid rp_cl_grid_make(const float dims[3], const uint idims[3]) {
  rp_cl_grid g;
  g.topx = dims[0] - 1.0f;
  g.topy = dims[1] - 1.0f;
  g.topz = dims[2] - 1.0f;
  g.lomx = idims[0] > 1u ? (int)idims[0] - 2 : 0;
  g.lomy = idims[1] > 1u ? (int)idims[1] - 2 : 0;
  g.lomz = idims[2] > 1u ? (int)idims[2] - 2 : 0;
  g.row = idims[0];
  g.slice = (RP_INDEX_T)idims[0] * idims[1];
  g.dy = idims[1] > 1u ? g.row : 0u;
  g.dz = idims[2] > 1u ? g.slice : 0u;
  return g;
}

#ifdef RP_BRICKED
/* The same grid read through a brick table. */
rp_cl_grid rp_cl_grid_bricked(const float dims[3], const uint idims[3],
                              uint shift, const uint grid[3],
                              __global const uint *table) {
  rp_cl_grid g = rp_cl_grid_make(dims, idims);
  int stored = (1 << shift) + 1;
  g.table = table;
  g.shift = (int)shift;
  g.mask = (1 << shift) - 1;
  g.bgx = (int)grid[0];
  g.bgxy = (int)(grid[0] * grid[1]);
  g.row = stored;
  g.slice = (RP_INDEX_T)stored * stored;
  g.dy = g.row;
  g.dz = g.slice;
  g.brick_voxels = g.slice * stored;
  return g;
}
#endif

/* Two x-adjacent voxels read as one unaligned integer: the unit the
 * gathers below move. uchar reads four bytes and keeps two (the buffer is
 * padded past its end for that). */
#if RP_VOXEL_BYTES == 4
#define RP_CL_PAIR_T ulong
#else
#define RP_CL_PAIR_T uint
#endif
typedef RP_CL_VEC(RP_CL_PAIR_T) vpair;
/* A vector and its lanes, as rp_cl_int_lanes (common.cl). */
typedef union rp_cl_pair_lanes {
  vpair v;
  RP_CL_PAIR_T a[RP_CL_W];
} rp_cl_pair_lanes;
typedef union rp_cl_index_lanes {
  vindex v;
  RP_INDEX_T a[RP_CL_W];
} rp_cl_index_lanes;
typedef struct __attribute__((packed)) rp_cl_pair {
  RP_CL_PAIR_T v;
} rp_cl_pair;

/* The voxel pair at each lane's index (a gather: per-lane inserts into a
 * vector cost twice as much on PoCL). Lanes go through unions
 * (rp_cl_int_lanes): private arrays with vstore/vload added lane shuffles
 * about every gather here, and dropping them made the raycast about 1.3x
 * as fast (bonsai 512^2 unshaded, one quiet run: 245 -> 320 M
 * samples/s). */
vpair rp_cl_gather(__global const RP_VOXEL_T *vol, vindex at) {
  rp_cl_pair_lanes out;
  rp_cl_index_lanes idx;
  int j;
  idx.v = at;
#pragma clang loop vectorize(enable) vectorize_width(RP_CL_W)
  for (j = 0; j < RP_CL_W; j++)
    out.a[j] = ((__global const rp_cl_pair *)(vol + idx.a[j]))->v;
  return out.v;
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

/* Where each lane's point reads the volume: the index of its cell's low
 * corner and the weights along each axis, after clamping to
 * [0, dims - 1]. Clamped coordinates are >= 0, so truncation is floor. */
typedef struct rp_cl_cell {
  vindex base;
  vfloat wx, wy, wz;
} rp_cl_cell;

/* Each lane's cell: its low corner (clamped so that the upper
 * neighbours exist) and the weights within it. */
rp_cl_cell rp_cl_cell_corner(const rp_cl_grid *g, vfloat px, vfloat py,
                             vfloat pz, vint *ix, vint *iy, vint *iz) {
  rp_cl_cell c;
  vfloat cx = min(max(px, 0.0f), g->topx);
  vfloat cy = min(max(py, 0.0f), g->topy);
  vfloat cz = min(max(pz, 0.0f), g->topz);
  *ix = min(to_vint(cx), g->lomx);
  *iy = min(to_vint(cy), g->lomy);
  *iz = min(to_vint(cz), g->lomz);
  c.wx = cx - to_vfloat(*ix);
  c.wy = cy - to_vfloat(*iy);
  c.wz = cz - to_vfloat(*iz);
  return c;
}

#ifdef RP_BRICKED
/* Each lane's brick (the one of its cell's low corner). */
vint rp_cl_brick_of(const rp_cl_grid *g, vint ix, vint iy, vint iz) {
  return (ix >> g->shift) + (iy >> g->shift) * g->bgx +
         (iz >> g->shift) * g->bgxy;
}

/* Where each lane's brick starts in the pool: its slot from the table, a
 * gather. No vectorize pragma: clang cannot honour one on it and would
 * warn at every kernel build. */
vindex rp_cl_brick_origin(const rp_cl_grid *g, vint brick) {
  rp_cl_int_lanes at;
  rp_cl_uint_lanes slot;
  int j;
  at.v = brick;
  for (j = 0; j < RP_CL_W; j++)
    slot.a[j] = g->table[at.a[j]];
  return to_vindex(slot.v) * g->brick_voxels;
}

vindex rp_cl_in_brick(const rp_cl_grid *g, vint ix, vint iy, vint iz) {
  return to_vindex(ix & g->mask) + to_vindex(iy & g->mask) * g->row +
         to_vindex(iz & g->mask) * g->slice;
}

/* A ray's next sample is in the brick of its last for about brick_size /
 * step samples: the raycast keeps each lane's brick and origin here and
 * reads the table only when some lane moved to another brick (on bonsai
 * the gather was 12 of the 26 ms the table added to a 72 ms frame; with
 * this the table costs 1.2-1.3x in core instead of 1.36x). */
typedef struct rp_cl_brick_cache {
  vint brick;
  vindex origin;
} rp_cl_brick_cache;

rp_cl_cell rp_cl_cell_at_cached(const rp_cl_grid *g, rp_cl_brick_cache *bc,
                                vfloat px, vfloat py, vfloat pz) {
  vint ix, iy, iz, brick;
  rp_cl_cell c = rp_cl_cell_corner(g, px, py, pz, &ix, &iy, &iz);
  brick = rp_cl_brick_of(g, ix, iy, iz);
  if (any(brick != bc->brick)) {
    bc->brick = brick;
    bc->origin = rp_cl_brick_origin(g, brick);
  }
  c.base = bc->origin + rp_cl_in_brick(g, ix, iy, iz);
  return c;
}
#endif

rp_cl_cell rp_cl_cell_at(const rp_cl_grid *g, vfloat px, vfloat py,
                         vfloat pz) {
  vint ix, iy, iz;
  rp_cl_cell c = rp_cl_cell_corner(g, px, py, pz, &ix, &iy, &iz);
#ifdef RP_BRICKED
  c.base = rp_cl_brick_origin(g, rp_cl_brick_of(g, ix, iy, iz)) +
           rp_cl_in_brick(g, ix, iy, iz);
#else
  c.base = to_vindex(ix) + to_vindex(iy) * g->row +
           to_vindex(iz) * g->slice;
#endif
  return c;
}

/* Trilinear interpolation of the volume in each lane's cell: along x,
 * then y, then z. */
vfloat rp_cl_sample_cell(__global const RP_VOXEL_T *vol, const rp_cl_grid *g,
                         const rp_cl_cell *c) {
  vfloat e0 = rp_cl_lerp_pair(rp_cl_gather(vol, c->base), c->wx);
  vfloat e1 = rp_cl_lerp_pair(rp_cl_gather(vol, c->base + g->dy), c->wx);
  vfloat e2 = rp_cl_lerp_pair(rp_cl_gather(vol, c->base + g->dz), c->wx);
  vfloat e3 =
      rp_cl_lerp_pair(rp_cl_gather(vol, c->base + g->dy + g->dz), c->wx);
  return mix(mix(e0, e1, c->wy), mix(e2, e3, c->wy), c->wz);
}

/* Trilinear interpolation of the packet's points. */
vfloat rp_cl_sample(__global const RP_VOXEL_T *vol, const rp_cl_grid *g,
                    vfloat px, vfloat py, vfloat pz) {
  rp_cl_cell c = rp_cl_cell_at(g, px, py, pz);
  return rp_cl_sample_cell(vol, g, &c);
}

/* The same for a byte volume of the same grid (the AO volume, padded like
 * the volume): two x-adjacent bytes per lane from one 32-bit word. */
vfloat rp_cl_lerp_bytes(__global const uchar *bytes, vindex at, vfloat w) {
  rp_cl_uint_lanes out;
  rp_cl_index_lanes idx;
  int j;
  vuint q;
  idx.v = at;
#pragma clang loop vectorize(enable) vectorize_width(RP_CL_W)
  for (j = 0; j < RP_CL_W; j++)
    out.a[j] = ((__global const rp_cl_word *)(bytes + idx.a[j]))->v;
  q = out.v;
  return mix(to_vfloat(q & 0xffu), to_vfloat((q >> 8) & 0xffu), w);
}

vfloat rp_cl_sample_bytes(__global const uchar *bytes, const rp_cl_grid *g,
                          const rp_cl_cell *c) {
  vfloat e0 = rp_cl_lerp_bytes(bytes, c->base, c->wx);
  vfloat e1 = rp_cl_lerp_bytes(bytes, c->base + g->dy, c->wx);
  vfloat e2 = rp_cl_lerp_bytes(bytes, c->base + g->dz, c->wx);
  vfloat e3 = rp_cl_lerp_bytes(bytes, c->base + g->dy + g->dz, c->wx);
  return mix(mix(e0, e1, c->wy), mix(e2, e3, c->wy), c->wz);
}

/* 1 - e^x for x <= 0 (the expm1 half of rp_cl_correct below, which
 * says how). e^-87 is below the smallest normal float: the result is 1
 * there. */
vfloat rp_cl_one_minus_exp(vfloat x) {
  vfloat y, em, p2;
  vint n;
  x = max(x, -87.0f);
  n = RP_CL_CAT(to_vint, _rte)(x * 1.44269504f);
  y = x - to_vfloat(n) * 0.693147181f;
  em = y * (1.0f + y * (1.0f / 2.0f +
                        y * (1.0f / 6.0f +
                             y * (1.0f / 24.0f +
                                  y * (1.0f / 120.0f +
                                       y * (1.0f / 720.0f +
                                            y * (1.0f / 5040.0f)))))));
  p2 = as_vfloat((n + 127) << 23); /* 2^n, normal */
  return -(em * p2 + (p2 - 1.0f));
}

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
  vfloat t, s, s2, ln, x;
  m = select(m, 0.5f * m, top);
  e -= top; /* top is -1 where true */
  t = select(m - 1.0f, -a, small);
  s = t / (2.0f + t);
  s2 = s * s;
  ln = 2.0f * s * (1.0f + s2 * (1.0f / 3.0f +
                                 s2 * (1.0f / 5.0f + s2 * (1.0f / 7.0f)))) +
       select(to_vfloat(e), (vfloat)(0.0f), small) * 0.693147181f;
  x = select(rp_cl_one_minus_exp(ratio * ln), (vfloat)(0.0f), a <= 0.0f);
  return select(x, (vfloat)(1.0f), a >= 1.0f);
}

/* Each lane's RGBA from the LUT: entries e and e + 1 mixed by w. */
void rp_cl_classify(__global const float4 *lut, vint e, vfloat w,
                    vfloat *r, vfloat *g, vfloat *b, vfloat *a) {
  __global const float *lf = (__global const float *)lut;
  rp_cl_float_lanes c[8];
  rp_cl_int_lanes idx;
  int j;
  idx.v = e * 4;
#pragma clang loop vectorize(enable) vectorize_width(RP_CL_W)
  for (j = 0; j < RP_CL_W; j++) {
    __global const float *q = lf + idx.a[j];
    c[0].a[j] = q[0];
    c[1].a[j] = q[1];
    c[2].a[j] = q[2];
    c[3].a[j] = q[3];
    c[4].a[j] = q[4];
    c[5].a[j] = q[5];
    c[6].a[j] = q[6];
    c[7].a[j] = q[7];
  }
  *r = mix(c[0].v, c[4].v, w);
  *g = mix(c[1].v, c[5].v, w);
  *b = mix(c[2].v, c[6].v, w);
  *a = mix(c[3].v, c[7].v, w);
}


/* Opacity alone from the LUT, as rp_cl_classify computes it. */
vfloat rp_cl_classify_alpha(__global const float4 *lut, vint e, vfloat w) {
  __global const float *lf = (__global const float *)lut;
  rp_cl_float_lanes c[2];
  rp_cl_int_lanes idx;
  int j;
  idx.v = e * 4 + 3;
#pragma clang loop vectorize(enable) vectorize_width(RP_CL_W)
  for (j = 0; j < RP_CL_W; j++) {
    c[0].a[j] = lf[idx.a[j]];
    c[1].a[j] = lf[idx.a[j] + 4];
  }
  return mix(c[0].v, c[1].v, w);
}

/* The LUT position of values: x = (v - min) / (max - min) clamped to
 * [0, 1] (0 when max == min), f = x (lut_size - 1), entry
 * e = min(floor(f), lut_size - 2) and weight f - e. */
typedef struct rp_cl_lutpos {
  float min, scale, top; /* scale: (lut_size - 1) / range, or 0 */
  int last;              /* lut_size - 2 */
} rp_cl_lutpos;

rp_cl_lutpos rp_cl_lutpos_make(float value_min, float value_max,
                               uint lut_size) {
  rp_cl_lutpos q;
  float range = value_max - value_min;
  /* x * (lut_size - 1) in one multiply; a constant field sits at 0. */
  q.min = value_min;
  q.scale = range > 0.0f ? (float)(lut_size - 1u) / range : 0.0f;
  q.top = (float)(lut_size - 1u);
  q.last = (int)lut_size - 2;
  return q;
}

/* The position f alone. */
vfloat rp_cl_lut_pos(const rp_cl_lutpos *q, vfloat v) {
  return clamp((v - q->min) * q->scale, 0.0f, q->top);
}

vint rp_cl_lut_entry(const rp_cl_lutpos *q, vfloat v, vfloat *w) {
  vfloat f = rp_cl_lut_pos(q, v);
  vint e = min(to_vint(f), q->last);
  *w = f - to_vfloat(e);
  return e;
}

#ifdef RP_PREINT
/* Pre-integration (RP_EFFECT_PREINT; runtime/preint.c has the model and
 * the table). The table follows the LUT's lut_size entries in the same
 * buffer: entry i is 8 floats, (tau, tau r, tau g, tau b) at i and their
 * integrals over positions [0, i]. Each lane's 4 floats at t + idx. */
void rp_cl_gather4(__global const float *t, vint idx,
                   rp_cl_float_lanes c[4]) {
  rp_cl_int_lanes at;
  int j;
  at.v = idx;
#pragma clang loop vectorize(enable) vectorize_width(RP_CL_W)
  for (j = 0; j < RP_CL_W; j++) {
    __global const float *q = t + at.a[j];
    c[0].a[j] = q[0];
    c[1].a[j] = q[1];
    c[2].a[j] = q[2];
    c[3].a[j] = q[3];
  }
}

/* The segment over which the LUT position runs from fa to fb (either
 * order), of ratio = step / ref_step reference steps: straight colour and
 * opacity. As rp__preint_mean: within one LUT cell the mean of the ends
 * (no division), else the rest of fa's cell, the table's whole cells and
 * the start of fb's over fb - fa, so that no term loses the short
 * segments' precision to a difference of two large integrals. */
void rp_cl_preint(__global const float4 *lut, const rp_cl_lutpos *q,
                  vfloat fa, vfloat fb, float ratio, vfloat *r, vfloat *g,
                  vfloat *b, vfloat *a) {
  __global const float *t = (__global const float *)lut + 4 * (q->last + 2);
  vfloat lo = fmin(fa, fb), hi = fmax(fa, fb), m[4], inv_tau;
  vint elo = min(to_vint(lo), q->last), ehi = min(to_vint(hi), q->last);
  vfloat wlo = lo - to_vfloat(elo), whi = hi - to_vfloat(ehi);
  vint same = elo == ehi;
  vfloat inv = select(1.0f / (hi - lo), (vfloat)(0.0f), same);
  rp_cl_float_lanes p0[4], p1[4], h0[4], h1[4], i0[4], i1[4];
  int c;
  rp_cl_gather4(t, elo * 8, p0);
  rp_cl_gather4(t, elo * 8 + 8, p1);  /* node elo + 1 */
  rp_cl_gather4(t, elo * 8 + 12, i0); /* its integral */
  rp_cl_gather4(t, ehi * 8, h0);
  rp_cl_gather4(t, ehi * 8 + 4, i1);  /* node ehi's integral */
  rp_cl_gather4(t, ehi * 8 + 8, h1);
  for (c = 0; c < 4; c++) {
    vfloat pl = mix(p0[c].v, p1[c].v, wlo), ph = mix(h0[c].v, h1[c].v, whi);
    vfloat many = (0.5f * (1.0f - wlo) * (pl + p1[c].v) +
                   (i1[c].v - i0[c].v) + 0.5f * whi * (h0[c].v + ph)) *
                  inv;
    m[c] = select(many, 0.5f * (pl + ph), same);
  }
  *a = rp_cl_one_minus_exp(-ratio * m[0]);
  inv_tau = select((vfloat)(0.0f), 1.0f / m[0], m[0] > 0.0f);
  *r = clamp(m[1] * inv_tau, 0.0f, 1.0f);
  *g = clamp(m[2] * inv_tau, 0.0f, 1.0f);
  *b = clamp(m[3] * inv_tau, 0.0f, 1.0f);
}
#endif
