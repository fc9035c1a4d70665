/* Shared by the raypace Vulkan kernels (depth.comp, raycast.comp,
 * ert.comp, ao.comp): frame parameters, bindings, rays, box clipping, the
 * block grid, and the volume sampling and classification the raycast and
 * the AO kernel share. The formulas are those of backends/README.md,
 * evaluated in float.
 *
 * One descriptor set serves all kernels; each kernel touches only the
 * bindings it declares, and the host keeps every binding valid. */
#ifndef RP_VK_COMMON_GLSL
#define RP_VK_COMMON_GLSL

/* One workgroup per 8x8 tile of the scaled image (or of the ERT grid):
 * the tile statistics are then a reduction inside one workgroup. A kernel
 * with another shape (ao.comp) defines RP_VK_OWN_LOCAL_SIZE first. */
#ifndef RP_VK_OWN_LOCAL_SIZE
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
#endif

/* The effect set a pipeline is specialised for. Off means the code is
 * folded away when the driver specialises, so an effect that is off costs
 * nothing. The ids match rp_vk_spec in vk_internal.h. */
layout(constant_id = 0) const bool RP_SHADING = false;
layout(constant_id = 1) const bool RP_ERT = false;
layout(constant_id = 2) const bool RP_SKIP = false;
layout(constant_id = 3) const bool RP_COUNT = false;
/* Ambient occlusion: the raycast darkens each visible sample by the AO
 * volume (raycast.comp). */
layout(constant_id = 4) const bool RP_AO = false;
/* Voxel type as rp_voxel_type: 1 uint8, 2 uint16, 3 float32. */
layout(constant_id = 5) const uint RP_VOXEL = 1u;
/* Volume layout: true when each texel holds a 2x2 footprint (below). */
layout(constant_id = 6) const bool RP_QUAD = true;
/* Opacity correction: false when step == ref_step, where it is the
 * identity. Not an effect but worth a variant: the logarithm and the
 * exponential are a sixth of a sample's cost on lavapipe, where a branch
 * on a uniform value does not skip the code it guards. */
layout(constant_id = 7) const bool RP_CORRECT = true;
/* Out-of-core: the volume binding holds a pool of bricks read through a
 * table (sample_volume). A variant, so that the in-core raycast pays
 * nothing for it. */
layout(constant_id = 8) const bool RP_BRICKED = false;
/* Pre-integrated classification (RP_EFFECT_PREINT, raycast.comp). */
layout(constant_id = 9) const bool RP_PREINT = false;

/* The host's rp_vk_params (vec4-packed, so std430 and the C struct agree
 * without vec3 alignment rules).
 *
 * It is a storage buffer, and there are no push constants, on purpose:
 * lavapipe inlines UBO and push-constant values that steer control flow
 * into the shader and recompiles it whenever they change (measured: about
 * 200 ms per dispatch for a moving camera). Storage buffers are never
 * inlined. */
struct Params {
  vec4 eye;      /* xyz eye, w: 1 for orthographic */
  vec4 fwd;      /* xyz forward, w: half_w */
  vec4 right;    /* xyz right, w: half_h */
  vec4 up;       /* xyz up, w: step */
  vec4 dims;     /* xyz dims as floats, w: min_spacing */
  vec4 inv_sp;   /* xyz 1 / spacing, w: ert_threshold */
  vec4 vrange;   /* x value_min, y 1 / (max - min) or 0, z max - min,
                    w step / ref_step */
  vec4 ert_a[4]; /* opacity of each H-alpha bin at the coarse step */
  uvec4 idims;   /* xyz dims, w lut_size */
  uvec4 blocks;  /* xyz block grid, w scaled image width */
  uvec4 misc;    /* x height, y ERT grid width, z ERT grid height */
  uvec4 seed;    /* x ert_seed, y frame, z jitter_seed, w jitter */
  uvec4 rect;    /* the region: x0, y0, width, height (scaled pixels) */
  vec4 box_lo;   /* xyz: the box of the occupied blocks, voxel space */
  vec4 box_hi;
  uvec4 brick;   /* RP_BRICKED: xyz the brick grid, w log2 brick size */
  uvec4 slab;    /* RP_BRICKED depth slabs (raycast.comp): x slab_flags,
                    y slab_cut's bits */
};

layout(set = 0, binding = 0, std430) readonly buffer Frame {
  Params frame;
};

/* A private copy, read once at the top of main while every invocation is
 * active: a storage-buffer load there is one scalar load, while inside
 * divergent control flow lavapipe loads lane by lane. */
Params P;

void load_params() {
  P = frame;
}

/* The occupancy grid, one R8 texel per block (texel fetches are gathers
 * on lavapipe, storage-buffer loads in divergent code are not). */
layout(set = 0, binding = 3) uniform usamplerBuffer grid;

#define RP_INF uintBitsToFloat(0x7f800000u)
/* Stands in for infinity inside the arithmetic, where a compiler allowed
 * to assume finite values could fold a comparison with a real one. */
const float RP_BIG = 3.0e38;

/* A ray in voxel space: p(t) = p0 + t * dp; sampling starts at s and
 * ends at t1, both in voxel units of depth. */
struct Ray {
  vec3 p0;
  vec3 dp;
  vec3 dir; /* world space, unit length */
  float s;
  float t1;
  bool hit;
};

/* The ray's span [s, t1] narrowed to the box of the occupied blocks
 * (P.box_lo/box_hi, whose faces are block faces); false where it misses
 * the box. No occupied block lies outside it, so walks and marches that
 * look for one run over this span only. */
bool occupied_box_span(Ray ray, out float lo, out float hi) {
  lo = ray.s;
  hi = ray.t1;
  for (int a = 0; a < 3; a++) {
    if (ray.dp[a] == 0.0) {
      if (ray.p0[a] < P.box_lo[a] || ray.p0[a] > P.box_hi[a])
        return false;
    } else {
      float ta = (P.box_lo[a] - ray.p0[a]) / ray.dp[a];
      float tb = (P.box_hi[a] - ray.p0[a]) / ray.dp[a];
      lo = max(lo, min(ta, tb));
      hi = min(hi, max(ta, tb));
    }
  }
  return lo <= hi;
}

/* The ray through continuous image position (px, py) of the scaled
 * image: pixel (x, y) is (x + 0.5, y + 0.5). */
Ray make_ray(float px, float py) {
  Ray ray;
  float nu = 2.0 * px / float(P.blocks.w) - 1.0;
  float nv = 1.0 - 2.0 * py / float(P.misc.x);
  vec3 side = (nu * P.fwd.w) * P.right.xyz + (nv * P.right.w) * P.up.xyz;
  vec3 org;
  if (P.eye.w != 0.0) {
    org = P.eye.xyz + side;
    ray.dir = P.fwd.xyz;
  } else {
    org = P.eye.xyz;
    ray.dir = normalize(P.fwd.xyz + side);
  }
  ray.p0 = org * P.inv_sp.xyz + 0.5 * P.dims.xyz - 0.5;
  ray.dp = ray.dir * (P.dims.w * P.inv_sp.xyz);

  /* Slab test against [-0.5, dims - 0.5]. An axis the ray does not move
   * along only decides hit or miss, so no 0 * inf reaches the min/max. */
  float t0 = -RP_BIG, t1 = RP_BIG;
  bool inside = true;
  for (int a = 0; a < 3; a++) {
    float lo = -0.5, hi = P.dims[a] - 0.5;
    if (ray.dp[a] == 0.0) {
      inside = inside && ray.p0[a] >= lo && ray.p0[a] <= hi;
    } else {
      float ta = (lo - ray.p0[a]) / ray.dp[a];
      float tb = (hi - ray.p0[a]) / ray.dp[a];
      t0 = max(t0, min(ta, tb));
      t1 = min(t1, max(ta, tb));
    }
  }
  ray.hit = inside && t0 <= t1 && t1 >= 0.0;
  ray.s = max(t0, 0.0);
  ray.t1 = t1;
  return ray;
}

/* Integer finaliser that spreads seeds over all 32 bits (the ERT stream's
 * and the jitter's, backends/README.md). */
uint mix32(uint x) {
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  x ^= x >> 16;
  return x;
}

/* Ray-start jitter (rp_jitter_offset): the first sample of the ray
 * through pixel `pix` moves from s to s + j * step, j exact in float; a
 * ray whose first sample then lies past t1 takes none. */
void jitter_ray(inout Ray ray, uvec2 pix, float step) {
  if (P.seed.w == 0u)
    return;
  uint h = mix32(P.seed.z ^ mix32(pix.x ^ mix32(pix.y + 0x632be5abu)));
  ray.s += float(h >> 8) * (1.0 / 16777216.0) * step;
  ray.hit = ray.hit && ray.s <= ray.t1;
}

/* Block coordinates of voxel-space point p, clamped to the grid. */
ivec3 block_cell(vec3 p) {
  vec3 q = floor((p + 0.5) * (1.0 / 16.0));
  return clamp(ivec3(q), ivec3(0), ivec3(P.blocks.xyz) - 1);
}

uint block_index(ivec3 c) {
  return (uint(c.z) * P.blocks.y + uint(c.y)) * P.blocks.x + uint(c.x);
}

bool block_occupied(uint b) {
  return texelFetch(grid, int(b)).x != 0u;
}

/* ---- sampling (raycast.comp, ao.comp) ------------------------------------ */

/* The volume is a uniform texel buffer read with texelFetch: exact
 * values, no filtering, hand-written trilinear (lavapipe's 8-bit 3D
 * textures filter with coarse weights). A texel fetch is a vectorised
 * gather on lavapipe while a storage-buffer load is a loop over the lanes
 * with bounds checks: in a prototype sweep (no LUT, both cores, another
 * job running) uint8 storage buffers gave 35, packed uint storage 65, an
 * R8 texel buffer 56 and the RGBA8 quad texel buffer 100 M samples/s.
 * Float voxels travel as their bits in a UINT format so that one
 * declaration serves all three types. */
layout(set = 0, binding = 1) uniform usamplerBuffer volume;
/* lut_size RGBA32F entries, straight colour, alpha per reference step;
 * then the pre-integration table (raycast.comp's preint), two texels an
 * entry. */
layout(set = 0, binding = 2) uniform samplerBuffer lut;
/* RP_BRICKED: the pool slot of each brick of the volume, x fastest (one
 * R32 texel each; a stand-in texel otherwise). */
layout(set = 0, binding = 13) uniform usamplerBuffer brick_table;

/* a + w (b - a): one fused multiply-add after the subtraction. It differs
 * from the reference's (1 - w) a + w b in the last bit only. */
float lerp(float a, float b, float w) {
  return a + w * (b - a);
}
vec2 lerp(vec2 a, vec2 b, float w) {
  return a + w * (b - a);
}
vec4 lerp(vec4 a, vec4 b, float w) {
  return a + w * (b - a);
}

vec4 texel(uint i) {
  uvec4 q = texelFetch(volume, int(i));
  return RP_VOXEL == 3u ? uintBitsToFloat(q) : vec4(q);
}

/* Trilinear sample at voxel-space p, each coordinate clamped to
 * [0, dims - 1]. Quad layout: texel (x, y, z) holds voxels (x, y),
 * (x+1, y), (x, y+1), (x+1, y+1) of slice z, repeated at the far faces,
 * so the eight corners are two fetches. Plain layout: one voxel per
 * texel, eight fetches. Interpolates along x, then y, then z.
 *
 * RP_BRICKED (raypace_backend.h, rp_frame_params.brick_shift): the
 * plain layout, per brick. Each slot holds (B + 1)^3 voxels, x fastest:
 * a brick and its upper border, replicated past the volume's end. The
 * brick is the one of the cell's low corner clamped to dims - 2, where
 * the front end's footprints place it (runtime/bricks.h), so the eight
 * corners are in one slot. `lo` itself stays unclamped, as in core: at a
 * far face lo = dims - 1 is that brick's border voxel and its upper
 * neighbour is itself, so every fetch reads the voxel the in-core layout
 * holds there and the weights are the same: the same floats. Each call
 * looks its own brick up, gradient fetches included. */
float sample_volume(vec3 p) {
  p = clamp(p, vec3(0.0), P.dims.xyz - 1.0);
  vec3 fl = floor(p);
  uvec3 lo = uvec3(fl);
  vec3 w = p - fl;
  uint sx, sxy, i;
  if (RP_BRICKED) {
    uint shift = P.brick.w;
    uvec3 b = min(lo, max(P.idims.xyz, uvec3(2u)) - 2u) >> shift;
    uint slot = texelFetch(brick_table,
                           int((b.z * P.brick.y + b.y) * P.brick.x + b.x)).x;
    uvec3 l = lo - (b << shift); /* in [0, B]: B on the border only */
    sx = (1u << shift) + 1u;
    sxy = sx * sx;
    i = slot * sxy * sx + (l.z * sx + l.y) * sx + l.x;
  } else {
    sx = P.idims.x;
    sxy = P.idims.x * P.idims.y;
    i = (lo.z * P.idims.y + lo.y) * sx + lo.x;
  }
  uint dz = lo.z + 1u < P.idims.z ? sxy : 0u;
  vec4 z0, z1;
  if (RP_QUAD && !RP_BRICKED) {
    z0 = texel(i);
    z1 = texel(i + dz);
  } else {
    uint dx = lo.x + 1u < P.idims.x ? 1u : 0u;
    uint dy = lo.y + 1u < P.idims.y ? sx : 0u;
    z0 = vec4(texel(i).x, texel(i + dx).x, texel(i + dy).x,
              texel(i + dy + dx).x);
    i += dz;
    z1 = vec4(texel(i).x, texel(i + dx).x, texel(i + dy).x,
              texel(i + dy + dx).x);
  }
  vec2 c0 = lerp(z0.xz, z0.yw, w.x); /* rows y and y+1 of slice z */
  vec2 c1 = lerp(z1.xz, z1.yw, w.x);
  return lerp(lerp(c0.x, c0.y, w.y), lerp(c1.x, c1.y, w.y), w.z);
}

vec4 classify(float v) {
  float x = clamp((v - P.vrange.x) * P.vrange.y, 0.0, 1.0);
  float f = x * float(P.idims.w - 1u);
  int i = min(int(f), int(P.idims.w) - 2);
  return lerp(texelFetch(lut, i), texelFetch(lut, i + 1), f - float(i));
}

/* classify(v).a, the same arithmetic on the alpha channel alone. */
float classify_alpha(float v) {
  float x = clamp((v - P.vrange.x) * P.vrange.y, 0.0, 1.0);
  float f = x * float(P.idims.w - 1u);
  int i = min(int(f), int(P.idims.w) - 2);
  return lerp(texelFetch(lut, i).a, texelFetch(lut, i + 1).a, f - float(i));
}

/* Opacity of one step from the TF's alpha per reference step:
 * a' = -expm1(r * log1p(-a)), r = step / ref_step, in float but without
 * the cancellation of 1 - (1 - a)^r that ruins tiny opacities and steps.
 * log1p(-a) by Kahan's correction log(u) * (-a / (u - 1)), u = 1 - a;
 * expm1(y) by its series where |y| < 1/4 (terms to y^7: relative error
 * below 1e-8) and exp(y) - 1 elsewhere, where nothing cancels. `precise`
 * keeps the compiler from folding (1 - a) - 1 into -a. Only compiled in
 * when step != ref_step (RP_CORRECT): then a' == a. */
float correct(float a) {
  float ac = min(a, 0.99999994);
  precise float u = 1.0 - ac;
  precise float d = u - 1.0;
  float l = d == 0.0 ? -ac : log(u) * (-ac / d);
  float y = P.vrange.w * l;
  float series = y * (1.0 + y * (1.0 / 2.0 + y * (1.0 / 6.0 + y * (1.0 / 24.0 +
                 y * (1.0 / 120.0 + y * (1.0 / 720.0 + y * (1.0 / 5040.0)))))));
  float e = abs(y) < 0.25 ? series : exp(y) - 1.0;
  return a >= 1.0 ? 1.0 : clamp(-e, 0.0, 1.0);
}

#endif /* RP_VK_COMMON_GLSL */
