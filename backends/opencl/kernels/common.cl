/* Shared by every raypace OpenCL program: frame parameters, packets of
 * rays and the block grid. The geometry is the contract of
 * backends/README.md, in float; the scalar reference (runtime/) does it
 * in double.
 *
 * Every kernel works on packets: a work-item takes RP_CL_W rays (16: two
 * rows of an 8x8 tile) in the lanes of OpenCL vector types, so that on a
 * CPU device (PoCL) each step of each ray runs in SIMD. A work-group of
 * 64 / RP_CL_W work-items covers one 8x8 tile of rays. Lanes that have
 * nothing to do still compute, on finite dummy values, and are masked.
 *
 * Programs are built from this file followed by one kernel file, with -D
 * options that select the effect set (see cl_backend.c). */

#define RP_CL_TILE 8
#define RP_CL_BLOCK 16.0f

#ifndef RP_CL_W
#define RP_CL_W 16
#endif

/* Two levels, so that macro arguments (RP_CL_W, RP_VOXEL_T) expand
 * before they are pasted. */
#define RP_CL_CAT_(a, b) a##b
#define RP_CL_CAT(a, b) RP_CL_CAT_(a, b)
#define RP_CL_VEC(t) RP_CL_CAT(t, RP_CL_W)
#define RP_CL_CONVERT(t) RP_CL_CAT(convert_, RP_CL_VEC(t))

typedef RP_CL_VEC(float) vfloat;
typedef RP_CL_VEC(int) vint; /* comparison results: -1 true, 0 false */
typedef RP_CL_VEC(uint) vuint;
typedef RP_CL_VEC(uchar) vbyte;

#define to_vfloat RP_CL_CONVERT(float)
#define to_vint RP_CL_CONVERT(int)
#define to_vuint RP_CL_CONVERT(uint)
#define to_vuint_sat RP_CL_CAT(RP_CL_CONVERT(uint), _sat)
#define as_vint RP_CL_CAT(as_int, RP_CL_W)
#define as_vfloat RP_CL_CAT(as_float, RP_CL_W)
#define vstore_w RP_CL_CAT(vstore, RP_CL_W)

/* A vector and its lanes. A loop over `a` that reads memory at each
 * lane's index is the form LLVM turns into one hardware gather, with the
 * result read back as `v`; with vstore/vload through private arrays it
 * also shuffled the lanes about at both ends of the gather. */
typedef union rp_cl_int_lanes {
  vint v;
  int a[RP_CL_W];
} rp_cl_int_lanes;
typedef union rp_cl_uint_lanes {
  vuint v;
  uint a[RP_CL_W];
} rp_cl_uint_lanes;
typedef union rp_cl_float_lanes {
  vfloat v;
  float a[RP_CL_W];
} rp_cl_float_lanes;

/* Whether any lane of a comparison result is true. OpenCL's any() tests
 * the lanes one pair at a time with a branch after each (PoCL 3.1 on
 * x86); an OR-reduction of the lanes' "true" is one mask test, which the
 * hot loops (the depth walk, the ERT march) take every step. */
#if defined(__has_builtin)
#if __has_builtin(__builtin_reduce_or)
#define RP_CL_HAS_REDUCE_OR 1
#endif
#endif
#ifdef RP_CL_HAS_REDUCE_OR
#define rp_cl_any(m) (__builtin_reduce_or((m) < 0) != 0)
#else
#define rp_cl_any(m) any(m)
#endif

/* min and max of values that are never NaN: fmin/fmax must handle NaN,
 * which costs a compare and a blend per call on a CPU. */
#define rp_cl_min(a, b) select((b), (a), (a) < (b))
#define rp_cl_max(a, b) select((b), (a), (a) > (b))

/* M(lane) for every lane, lanes named by their swizzle digit. */
#if RP_CL_W == 8
#define RP_CL_LANES(M) M(0) M(1) M(2) M(3) M(4) M(5) M(6) M(7)
#define RP_CL_LANE_IDS (vfloat)(0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f)
#elif RP_CL_W == 16
#define RP_CL_LANES(M)                                                        \
  M(0) M(1) M(2) M(3) M(4) M(5) M(6) M(7)                                     \
  M(8) M(9) M(a) M(b) M(c) M(d) M(e) M(f)
#define RP_CL_LANE_IDS                                                        \
  (vfloat)(0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f, 8.f, 9.f, 10.f, 11.f,     \
           12.f, 13.f, 14.f, 15.f)
#else
#error "RP_CL_W must be 8 or 16"
#endif

/* The layout of rp_frame_params (include/raypace_backend.h): 53 four-byte
 * fields, no padding, passed by value as the first kernel argument. */
typedef struct rp_cl_frame {
  float eye[3], f[3], r[3], u[3];
  float half_w, half_h;
  int ortho;
  uint width, height;
  float dims[3];
  float inv_spacing[3];
  float min_spacing;
  uint idims[3];
  uint blocks[3];
  float step;
  float ref_step;
  float ert_threshold;
  uint effects;
  float value_min, value_max;
  uint lut_size;
  uint ert_seed, frame;
  uint occupied_lo[3], occupied_end[3];
  uint brick_shift;
  uint brick_grid[3];
  float slab_cut;
  uint slab_flags;
  uint jitter, jitter_seed;
} rp_cl_frame;

/* Integer finaliser that spreads seeds over all 32 bits (the ERT stream's
 * and the jitter's, backends/README.md). */
vuint rp_cl_mix(vuint x) {
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}

/* A packet of rays in voxel space, structure of arrays: p(t) = p0 +
 * t * dp, inside the box on [s, t1] where hit. Lanes that miss (or are
 * not rays at all) have s = t1 = 0 and finite geometry. */
typedef struct rp_cl_packet {
  vfloat p0x, p0y, p0z, dpx, dpy, dpz;
  vfloat dirx, diry, dirz; /* unit world direction: the headlight */
  vfloat s, t1;
  vint hit;
} rp_cl_packet;

/* This work-item's lanes as positions in a grid of rays tiled 8x8 (one
 * tile per work-group, shifted by (x0, y0)): lane j is (tx + j % 8,
 * ty + j / 8). Returns the index of the first lane within its tile. */
uint rp_cl_lane_coords(uint x0, uint y0, vfloat *x, vfloat *y) {
  uint slot = get_local_id(1) * RP_CL_W;
  uint tx = x0 + get_group_id(0) * RP_CL_TILE;
  uint ty = y0 + get_group_id(1) * RP_CL_TILE + slot / RP_CL_TILE;
  vfloat lane = RP_CL_LANE_IDS;
  vfloat ly = floor(lane * (1.0f / RP_CL_TILE));
  *x = (float)tx + (lane - RP_CL_TILE * ly);
  *y = (float)ty + ly;
  return slot;
}

/* The packet through continuous image positions (px, py), (x + 0.5,
 * y + 0.5) for pixel (x, y), clipped to the box [-0.5, dims - 0.5];
 * lanes where `valid` is false are misses. */
rp_cl_packet rp_cl_make_packet(const rp_cl_frame *fp, vfloat px, vfloat py,
                               vint valid) {
  rp_cl_packet k;
  vfloat nu = 2.0f * px / (float)fp->width - 1.0f;
  vfloat nv = 1.0f - 2.0f * py / (float)fp->height;
  vfloat su = nu * fp->half_w, sv = nv * fp->half_h;
  vfloat ox, oy, oz, t0 = -INFINITY, t1 = INFINITY;
  vint ok = valid;
  float ix = fp->min_spacing * fp->inv_spacing[0];
  float iy = fp->min_spacing * fp->inv_spacing[1];
  float iz = fp->min_spacing * fp->inv_spacing[2];
  if (fp->ortho) {
    ox = fp->eye[0] + su * fp->r[0] + sv * fp->u[0];
    oy = fp->eye[1] + su * fp->r[1] + sv * fp->u[1];
    oz = fp->eye[2] + su * fp->r[2] + sv * fp->u[2];
    k.dirx = fp->f[0];
    k.diry = fp->f[1];
    k.dirz = fp->f[2];
  } else {
    vfloat dx = fp->f[0] + su * fp->r[0] + sv * fp->u[0];
    vfloat dy = fp->f[1] + su * fp->r[1] + sv * fp->u[1];
    vfloat dz = fp->f[2] + su * fp->r[2] + sv * fp->u[2];
    vfloat inv = 1.0f / sqrt(dx * dx + dy * dy + dz * dz);
    ox = fp->eye[0];
    oy = fp->eye[1];
    oz = fp->eye[2];
    k.dirx = dx * inv;
    k.diry = dy * inv;
    k.dirz = dz * inv;
  }
  k.p0x = ox * fp->inv_spacing[0] + 0.5f * fp->dims[0] - 0.5f;
  k.p0y = oy * fp->inv_spacing[1] + 0.5f * fp->dims[1] - 0.5f;
  k.p0z = oz * fp->inv_spacing[2] + 0.5f * fp->dims[2] - 0.5f;
  k.dpx = k.dirx * ix;
  k.dpy = k.diry * iy;
  k.dpz = k.dirz * iz;
  /* Slabs. An axis the ray does not move along constrains nothing from
   * inside its slab and rules the ray out from outside it; its divisions
   * (by zero) are computed but not used. */
#define RP_CL_SLAB(p, d, hi)                                                  \
  {                                                                           \
    vfloat ta = (-0.5f - (p)) / (d), tb = ((hi) - (p)) / (d);                 \
    vint still = (d) == 0.0f;                                                 \
    ok &= ~still | (((p) >= -0.5f) & ((p) <= (hi)));                          \
    t0 = select(fmax(t0, fmin(ta, tb)), t0, still);                           \
    t1 = select(fmin(t1, fmax(ta, tb)), t1, still);                           \
  }
  RP_CL_SLAB(k.p0x, k.dpx, fp->dims[0] - 0.5f)
  RP_CL_SLAB(k.p0y, k.dpy, fp->dims[1] - 0.5f)
  RP_CL_SLAB(k.p0z, k.dpz, fp->dims[2] - 0.5f)
#undef RP_CL_SLAB
  /* A box wholly behind the origin is a miss too. */
  ok &= (t0 <= t1) & (t1 >= 0.0f);
  k.hit = ok;
  k.s = select((vfloat)(0.0f), fmax(t0, 0.0f), ok);
  k.t1 = select((vfloat)(0.0f), t1, ok);
  return k;
}

/* Ray-start jitter (rp_jitter_offset): each lane's first sample moves
 * from s to s + j * step, j the hash of its pixel (x, y), integral in px
 * and py, exact in float; a lane whose first sample then lies past t1
 * takes none. */
void rp_cl_jitter(const rp_cl_frame *fp, rp_cl_packet *k, vfloat px,
                  vfloat py) {
  vuint h;
  if (!fp->jitter)
    return;
  h = rp_cl_mix((vuint)(fp->jitter_seed) ^
                rp_cl_mix(to_vuint(px) ^
                          rp_cl_mix(to_vuint(py) + 0x632be5abu)));
  k->s += to_vfloat(h >> 8) * (1.0f / 16777216.0f) * fp->step;
  k->hit &= k->s <= k->t1;
}

/* Each lane's span [*lo, *hi] inside the box of the occupied blocks
 * (fp->occupied_lo/end, whose faces are block faces), within [s, t1];
 * the result is false where the ray misses the box. No occupied block
 * lies outside it, so walks and marches that look for one run over this
 * span only. */
vint rp_cl_occupied_box_span(const rp_cl_frame *fp, const rp_cl_packet *k,
                             vfloat *lo_out, vfloat *hi_out) {
  vfloat lo = k->s, hi = k->t1;
  vint in = k->hit;
#define RP_CL_BOX(p, d, a)                                                    \
  {                                                                           \
    float b0 = RP_CL_BLOCK * (float)fp->occupied_lo[a] - 0.5f;                \
    float b1 = RP_CL_BLOCK * (float)fp->occupied_end[a] - 0.5f;               \
    vfloat inv = 1.0f / (d);                                                  \
    vfloat ta = (b0 - (p)) * inv, tb = (b1 - (p)) * inv;                      \
    vint still = (d) == 0.0f;                                                 \
    in &= ~still | (((p) >= b0) & ((p) <= b1));                               \
    lo = select(fmax(lo, fmin(ta, tb)), lo, still);                           \
    hi = select(fmin(hi, fmax(ta, tb)), hi, still);                           \
  }
  RP_CL_BOX(k->p0x, k->dpx, 0)
  RP_CL_BOX(k->p0y, k->dpy, 1)
  RP_CL_BOX(k->p0z, k->dpz, 2)
#undef RP_CL_BOX
  *lo_out = lo;
  *hi_out = hi;
  return in & (lo <= hi);
}

/* Block coordinates of points: floor((p + 0.5) / 16), clamped to the
 * grid (so any finite point reads a real block). Clamping first and then
 * truncating gives the same integers, since the bounds are integers and
 * truncation is floor from 0 up. PoCL 3.1 builds floor() and clamp()
 * into 17 instructions per axis, this into 5; the ERT march takes three
 * every step (bonsai 512^2, alternating builds: its time 0.83-0.92 ->
 * 0.70-0.78 % of a raycast). */
vint rp_cl_block_axis(vfloat p, uint blocks) {
  vfloat x = (p + 0.5f) * (1.0f / RP_CL_BLOCK);
  return to_vint(rp_cl_min(rp_cl_max(x, 0.0f), (float)(blocks - 1u)));
}

vint rp_cl_block_index(const rp_cl_frame *fp, vint bx, vint by, vint bz) {
  return (bz * (int)fp->blocks[1] + by) * (int)fp->blocks[0] + bx;
}

/* One byte per lane from a byte table, read as the low byte of an
 * unaligned 32-bit word (tables are padded past their end for this): a
 * CPU gathers words, not bytes. */
typedef struct __attribute__((packed)) rp_cl_word {
  uint v;
} rp_cl_word;

vint rp_cl_gather_byte(__global const uchar *table, vint at) {
  rp_cl_int_lanes idx, out;
  int j;
  idx.v = at;
#pragma clang loop vectorize(enable) vectorize_width(RP_CL_W)
  for (j = 0; j < RP_CL_W; j++)
    out.a[j] = ((__global const rp_cl_word *)(table + idx.a[j]))->v;
  return out.v & 0xff;
}

/* Whether the block of each lane's point is occupied. */
vint rp_cl_occupied_at(const rp_cl_frame *fp, __global const uchar *grid,
                       vfloat px, vfloat py, vfloat pz) {
  vint b = rp_cl_block_index(fp, rp_cl_block_axis(px, fp->blocks[0]),
                             rp_cl_block_axis(py, fp->blocks[1]),
                             rp_cl_block_axis(pz, fp->blocks[2]));
  return rp_cl_gather_byte(grid, b) != 0;
}
