/* The raycast (backends/README.md): one invocation per pixel of the
 * region, one workgroup per 8x8 tile. Front-to-back compositing of
 * trilinear samples on the lattice s + i * step, classified through the
 * LUT, opacity-corrected to the step (or pre-integrated over the segment
 * from the previous sample), optionally shaded and darkened by
 * ambient occlusion, with optional early termination and empty-space
 * skipping. Each workgroup also reduces
 * its tile's statistics in shared memory (integers, and one float sum in
 * a fixed order, so a tile's numbers do not depend on the region). */
#version 450
#include "common.glsl"

layout(set = 0, binding = 5, std430) readonly buffer Depth {
  vec2 depth[];
};
/* The region's pixels, RGBA8 premultiplied, row by row. */
layout(set = 0, binding = 6, std430) writeonly buffer Image {
  uint image[];
};
/* The region's tiles: samples, rays hit, mean depth bits, fetches. */
layout(set = 0, binding = 7, std430) writeonly buffer Tiles {
  uvec4 tiles[];
};

/* RP_BRICKED depth slabs (raypace_backend.h: slab_cut, slab_flags): a
 * region whose bricks do not fit the pool is cast in passes, each taking
 * the lattice samples before the cut and resuming where the last left
 * each ray. Per pixel of the region, what a pass hands the next: the
 * colour and opacity, the last sample's depth, the index of the next
 * sample (RP_DONE once the ray has no more), and the samples and fetches
 * so far. Only the last pass writes pixels and tile statistics, from the
 * carried figures: the same samples in the same order with the same
 * arithmetic, so the result is the single pass's bit for bit. A stand-in
 * buffer outside the bricked variant, never touched there. */
struct SlabRay {
  vec4 C;
  float last;
  int next;
  uint samples;
  uint fetches;
};
layout(set = 0, binding = 14, std430) buffer Slabs {
  SlabRay slab_state[];
};
const uint RP_SLAB_FIRST = 1u;
const uint RP_SLAB_LAST = 2u;
/* Past any lattice index lattice_last gives (it caps them at 2e9). */
const int RP_DONE = 0x7fffffff;

/* The AO volume (RP_AO): one R8 texel per voxel, 255 unoccluded; a
 * stand-in texel when AO is off. */
layout(set = 0, binding = 9) uniform usamplerBuffer ao_volume;

/* Volume fetches of this invocation, kept only in the counting variant:
 * one where the loop consumes a sample, six where shade() runs, one where
 * sample_ao() runs. The one fetch the pipelined loop makes past the last
 * sample is no sample and is not counted. */
uint fetches = 0u;

/* The AO factor at voxel-space p: the AO bytes interpolated by the
 * density's clamp-and-weights rule (sample_volume), divided by 255. One
 * voxel per texel, eight texel fetches, counted as one fetch. */
float sample_ao(vec3 p) {
  p = clamp(p, vec3(0.0), P.dims.xyz - 1.0);
  vec3 fl = floor(p);
  uvec3 lo = uvec3(fl);
  vec3 w = p - fl;
  uint sx = P.idims.x, sxy = P.idims.x * P.idims.y;
  uint i = (lo.z * P.idims.y + lo.y) * sx + lo.x;
  uint dx = lo.x + 1u < P.idims.x ? 1u : 0u;
  uint dy = lo.y + 1u < P.idims.y ? sx : 0u;
  uint dz = lo.z + 1u < P.idims.z ? sxy : 0u;
  vec4 z0 = vec4(texelFetch(ao_volume, int(i)).x,
                 texelFetch(ao_volume, int(i + dx)).x,
                 texelFetch(ao_volume, int(i + dy)).x,
                 texelFetch(ao_volume, int(i + dy + dx)).x);
  i += dz;
  vec4 z1 = vec4(texelFetch(ao_volume, int(i)).x,
                 texelFetch(ao_volume, int(i + dx)).x,
                 texelFetch(ao_volume, int(i + dy)).x,
                 texelFetch(ao_volume, int(i + dy + dx)).x);
  vec2 c0 = lerp(z0.xz, z0.yw, w.x);
  vec2 c1 = lerp(z1.xz, z1.yw, w.x);
  return lerp(lerp(c0.x, c0.y, w.y), lerp(c1.x, c1.y, w.y), w.z) *
         (1.0 / 255.0);
}

/* Headlight shading: central differences one voxel either side, per world
 * unit; two-sided. Below 2 % of the data range per voxel of the finest
 * spacing the normal blends towards facing the light (the reference's
 * RP__SURFACE_GRADIENT): its direction is noise there. Six fetches. */
vec3 shade(vec3 rgb, vec3 p, vec3 dir) {
  vec3 g;
  for (int a = 0; a < 3; a++) {
    vec3 e = vec3(0.0);
    e[a] = 1.0;
    g[a] = (sample_volume(p + e) - sample_volume(p - e)) * 0.5 *
           P.inv_sp[a];
  }
  float len = length(g), ndotl = 1.0;
  float m = P.vrange.z > 0.0 ? min(1.0, len * P.dims.w /
                                            (0.02 * P.vrange.z))
                             : 0.0;
  if (m > 0.0)
    ndotl = 1.0 - m * (1.0 - min(1.0, abs(dot(g, dir)) / len));
  float n2 = ndotl * ndotl, n4 = n2 * n2, n16 = n4 * n4 * n4 * n4;
  return clamp(rgb * (0.3 + 0.7 * ndotl) + 0.2 * (n16 * n4), 0.0, 1.0);
}

/* Index of the last lattice sample s + i * step <= t1, from the quotient
 * nudged onto the predicate as evaluated. */
int lattice_last(float s, float t1, float step) {
  int k = int(min(floor((t1 - s) / step), 2.0e9));
  for (int g = 0; g < 4 && k > 0 && s + float(k) * step > t1; g++)
    k--;
  for (int g = 0; g < 4 && s + float(k + 1) * step <= t1; g++)
    k++;
  return k;
}

/* Index of the last lattice sample s + i * step < cut (-1: none), the
 * same quotient-then-predicate walk as lattice_last. */
int lattice_before(float s, float cut, float step) {
  int k = int(clamp(ceil((cut - s) / step) - 1.0, -1.0, 2.0e9));
  for (int g = 0; g < 4 && k >= 0 && s + float(k) * step >= cut; g++)
    k--;
  for (int g = 0; g < 4 && s + float(k + 1) * step < cut; g++)
    k++;
  return k;
}

/* The LUT position f in [0, lut_size - 1] of value v, as classify takes
 * it. */
float lut_pos(float v) {
  float x = clamp((v - P.vrange.x) * P.vrange.y, 0.0, 1.0);
  return x * float(P.idims.w - 1u);
}

/* Pre-integration (RP_PREINT; runtime/preint.c has the model and the
 * table): the segment over which the LUT position runs from fa to fb,
 * straight colour and opacity. The table follows the LUT's n texels:
 * entry i's (tau, tau rgb) at n + 2i, their integrals over [0, i] at
 * n + 2i + 1. Within one LUT cell the mean of the ends (no division);
 * else the rest of fa's cell, the table's whole cells and the start of
 * fb's over fb - fa, so that a short segment across an entry does not
 * lose its precision to a difference of two large integrals. 1 - e^y by
 * correct()'s series where |y| < 1/4. */
vec4 preint(float fa, float fb) {
  int n = int(P.idims.w), top = n - 2;
  float lo = min(fa, fb), hi = max(fa, fb);
  int elo = min(int(lo), top), ehi = min(int(hi), top);
  float wlo = lo - float(elo), whi = hi - float(ehi);
  vec4 p1 = texelFetch(lut, n + 2 * elo + 2);
  vec4 h0 = texelFetch(lut, n + 2 * ehi);
  vec4 pl = lerp(texelFetch(lut, n + 2 * elo), p1, wlo);
  vec4 ph = lerp(h0, texelFetch(lut, n + 2 * ehi + 2), whi);
  vec4 m = 0.5 * (pl + ph);
  if (elo != ehi)
    m = (0.5 * (1.0 - wlo) * (pl + p1) +
         (texelFetch(lut, n + 2 * ehi + 1) -
          texelFetch(lut, n + 2 * elo + 3)) +
         0.5 * whi * (h0 + ph)) /
        (hi - lo);
  float y = -P.vrange.w * m.x;
  float series = y * (1.0 + y * (1.0 / 2.0 + y * (1.0 / 6.0 + y * (1.0 / 24.0 +
                 y * (1.0 / 120.0 + y * (1.0 / 720.0 + y * (1.0 / 5040.0)))))));
  float e = abs(y) < 0.25 ? series : exp(y) - 1.0;
  vec3 rgb = m.x > 0.0 ? clamp(m.yzw / m.x, 0.0, 1.0) : vec3(0.0);
  return vec4(rgb, clamp(-e, 0.0, 1.0));
}

bool sample_occupied(Ray ray, int i) {
  float t = ray.s + float(i) * P.up.w;
  return block_occupied(block_index(block_cell(ray.p0 + t * ray.dp)));
}

struct Result {
  vec4 C;
  uint samples;
  float last;
};

/* The most transparent samples a lane marches before the samples that
 * show in other lanes are shaded. The march ends when every lane has met
 * a sample that shows, so without a cap a lane in a dense region waits
 * on the lane with the longest transparent run, and only the shading
 * after the march moves it on. Measured on lavapipe, bonsai 512^2 with
 * shading, ERT and skipping, three alternating runs each: no cap 216-252
 * ms, cap 3 241-260, 6 206-209, 8 197-198, 12 184-193, 16 186-188, 20
 * 196-204. */
const int MARCH_CAP = 12;

/* rpix: the pixel within the region, where its slab state is. */
Result cast_ray(uvec2 pix, uvec2 rpix) {
  Result res = Result(vec4(0.0), 0u, 0.0);
  Ray ray = make_ray(float(pix.x) + 0.5, float(pix.y) + 0.5);
  float step = P.up.w;
  jitter_ray(ray, pix, step);
  if (!ray.hit)
    return res;
  int first = 0, last = lattice_last(ray.s, ray.t1, step);
  int lattice_end = last;
  if (RP_SKIP) {
    /* The first and last lattice samples in an occupied block. The depth
     * pass brackets them; a little slack absorbs its rounding, and the
     * per-sample block test decides. */
    vec2 fb = depth[pix.y * P.blocks.w + pix.x];
    if (!(fb.x <= fb.y))
      return res;
    float lo = fb.x - 1e-4 * (1.0 + abs(fb.x));
    float hi = fb.y + 1e-4 * (1.0 + abs(fb.y));
    first = max(0, int(ceil((lo - ray.s) / step)));
    while (first > 0 && ray.s + float(first - 1) * step >= lo)
      first--;
    last = min(last, int(floor((hi - ray.s) / step)));
    while (first <= last && !sample_occupied(ray, first))
      first++;
    while (last >= first && !sample_occupied(ray, last))
      last--;
  }
  /* As the reference: with skipping, the segment leaving the last
   * occupied sample is the next sample's. */
  if (RP_PREINT && RP_SKIP && first <= last)
    last = min(last + 1, lattice_end);
  /* This pass takes samples start .. end: all of them in core, in a depth
   * slab those of [first, last] before the cut not taken yet. Samples
   * and fetches are carried, so those of this pass are added. */
  int start = first, end = last;
  if (RP_BRICKED) {
    float cut = uintBitsToFloat(P.slab.y);
    if (cut < RP_BIG) /* +inf: to the ray's end */
      end = min(last, lattice_before(ray.s, cut, step));
    if ((P.slab.x & RP_SLAB_FIRST) == 0u) {
      SlabRay q = slab_state[rpix.y * P.rect.z + rpix.x];
      res.C = q.C;
      res.last = q.last;
      res.samples = q.samples;
      if (RP_COUNT)
        fetches = q.fetches;
      start = max(first, q.next);
    }
  }
  /* Software pipelining: the value of sample i + 1 is fetched while
   * sample i is classified and composited, so that the gathers' memory
   * latency overlaps arithmetic instead of stalling it (measured: a
   * quarter less time per sample on lavapipe). The fetch past the last
   * sample is clamped into the volume and wasted. Only the value, the
   * colour and the index are carried from sample to sample: on lavapipe
   * each loop-carried variable costs a masked store per sample. The
   * slab cut bounds the samples consumed, not the fetches: the one past
   * `end` is wasted as the one past `last` is, and the next pass fetches
   * that sample again with the same expression. */
  int i = start;
  float v = sample_volume(ray.p0 + (ray.s + float(i) * step) * ray.dp);
  /* Pre-integration: the position before each sample, the first one's
   * from the lattice depth before it (one more fetch; not with
   * RP_BRICKED, which the host refuses: that value's brick may be gone by
   * a later slab). */
  float f_prev = 0.0;
  if (RP_PREINT && start <= end) {
    f_prev = lut_pos(sample_volume(ray.p0 + (ray.s + float(start - 1) *
                                             step) * ray.dp));
    if (RP_COUNT)
      fetches++;
  }
  while (i <= end) {
    vec4 c;
    float a;
    /* With shading or AO, march over transparent samples in a loop of
     * their own: they add exactly 0 whatever their colour, and so need no
     * gradient and no AO. lavapipe runs divergent branches as masked SIMD
     * lanes and executes their code even when every lane is masked off
     * (measured: shading tested per sample, or behind a subgroup vote,
     * saved nothing), but it does leave a loop once every lane has. The
     * shading and the AO fetch below then run once per sample that shows
     * in some lane, not once per sample. Without either the loop body
     * runs once. */
    int marched = 0;
    for (;;) {
      float t_next = ray.s + float(i + 1) * step;
      float v_next = sample_volume(ray.p0 + t_next * ray.dp);
      if (RP_COUNT)
        fetches++;
      if (RP_PREINT) {
        float f = lut_pos(v);
        c = preint(f_prev, f);
        f_prev = f;
        a = c.a;
      } else {
        c = classify(v);
        a = RP_CORRECT ? correct(c.a) : c.a;
      }
      v = v_next;
      /* A transparent sample at a slab's `end` (before `last`), or the
       * MARCH_CAP-th transparent sample in a row, leaves here and is
       * composited with weight 0 where the single pass skips it: adding
       * 0 changes no bit, and the ERT test after it sees the opacity it
       * saw at the last sample that showed (below the threshold, or the
       * ray would have ended; a ray starts at 0, and the front end keeps
       * the threshold in (0, 1]). */
      if (!(RP_SHADING || RP_AO) || a > 0.0 || i >= end ||
          ++marched >= MARCH_CAP)
        break;
      i++;
    }
    vec3 rgb = c.rgb;
    if ((RP_SHADING || RP_AO) && a > 0.0) {
      /* A pre-integrated segment is shaded and occluded at its middle
       * (reference.c). */
      vec3 p = ray.p0 + (ray.s + (float(i) - (RP_PREINT ? 0.5 : 0.0)) *
                                     step) * ray.dp;
      if (RP_SHADING) {
        rgb = shade(rgb, p, ray.dir);
        if (RP_COUNT)
          fetches += 6u;
      }
      /* After shading, or in its place (backends/README.md). */
      if (RP_AO) {
        rgb *= sample_ao(p);
        if (RP_COUNT)
          fetches++;
      }
    }
    float w = (1.0 - res.C.a) * a;
    res.C.rgb += w * rgb;
    res.C.a += w;
    i++;
    if (RP_ERT && res.C.a >= P.inv_sp.w)
      break;
  }
  if (i > start) {
    res.samples += uint(i - start);
    res.last = ray.s + float(i - 1) * step; /* the same expression */
  }
  if (RP_BRICKED && (P.slab.x & RP_SLAB_LAST) == 0u) {
    /* The ray ended when the last sample it took reached the ERT
     * threshold (the loop broke there, or would have at the next), or
     * when this pass took it to the end of its range. max: a cut whose
     * index lies before where this pass resumed never goes back. */
    bool ended = (RP_ERT && i > start && res.C.a >= P.inv_sp.w) ||
                 end >= last;
    int next = ended ? RP_DONE : max(end + 1, start);
    slab_state[rpix.y * P.rect.z + rpix.x] =
        SlabRay(res.C, res.last, next, res.samples, fetches);
  }
  return res;
}

shared uint s_samples[64];
shared uint s_hits[64];
shared float s_depth[64];
shared uint s_fetches[64];

/* Saturating, like the reference's uint32 tile field. */
uint add_sat(uint a, uint b) {
  uint s = a + b;
  return s < a ? 0xffffffffu : s;
}

void main() {
  load_params();
  uint lid = gl_LocalInvocationIndex;
  uvec2 rpix = gl_GlobalInvocationID.xy; /* within the region */
  uvec2 pix = P.rect.xy + rpix;
  Result res = Result(vec4(0.0), 0u, 0.0);
  if (rpix.x < P.rect.z && rpix.y < P.rect.w) {
    res = cast_ray(pix, rpix);
    uvec4 q = uvec4(floor(clamp(res.C, 0.0, 1.0) * 255.0 + 0.5));
    if (!RP_BRICKED || (P.slab.x & RP_SLAB_LAST) != 0u)
      image[rpix.y * P.rect.z + rpix.x] =
          q.x | (q.y << 8) | (q.z << 16) | (q.w << 24);
  }
  /* A slab before the last leaves pixels and statistics to the last one.
   * The flags are the same in every invocation: all return here, none
   * waits at a barrier below. */
  if (RP_BRICKED && (P.slab.x & RP_SLAB_LAST) == 0u)
    return;
  s_samples[lid] = res.samples;
  s_hits[lid] = res.samples > 0u ? 1u : 0u;
  s_depth[lid] = res.samples > 0u ? res.last : 0.0;
  s_fetches[lid] = fetches;
  for (uint half_ = 32u; half_ > 0u; half_ >>= 1) {
    barrier();
    if (lid < half_) {
      s_samples[lid] = add_sat(s_samples[lid], s_samples[lid + half_]);
      s_hits[lid] += s_hits[lid + half_];
      s_depth[lid] += s_depth[lid + half_];
      s_fetches[lid] = add_sat(s_fetches[lid], s_fetches[lid + half_]);
    }
  }
  if (lid == 0u) {
    uint tiles_x = (P.rect.z + 7u) / 8u;
    uint hits = s_hits[0];
    float mean = hits > 0u ? s_depth[0] / float(hits) : 0.0;
    tiles[gl_WorkGroupID.y * tiles_x + gl_WorkGroupID.x] =
        uvec4(s_samples[0], hits, floatBitsToUint(mean), s_fetches[0]);
  }
}
