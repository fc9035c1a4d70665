/* Out-of-core volumes: the host's bricks, their visibility under the TF,
 * their footprints on the image, and the device pool's LRU bookkeeping.
 * bricks.h states the layout and why an out-of-core image is the in-core
 * one. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bounds.h"
#include "bricks.h"

struct rp__bricks {
  rp_context *ctx;
  rp_voxel_type type;
  size_t voxel_bytes;
  uint32_t dims[3];
  uint32_t size, shift, stored;
  uint32_t grid[3], count, slots;
  size_t stored_voxels, stored_bytes;
  uint8_t *store;       /* count bricks of stored_bytes, x fastest */
  double *vmin, *vmax;  /* per brick, its border included */
  rp__value_range values; /* the volume's, for the TF's range */
  uint8_t *visible;     /* per brick, under the current TF */
  uint32_t visible_count;
  double fill_value;    /* slot 0's transparent value */
  int fill_changed;
  uint8_t *fill;        /* stored_voxels of fill_value */
  /* The current frame's footprints: per brick, the pixel-index box
   * [x0, x1] x [y0, y1] its projection lies in; FOOT_NONE bricks are
   * not needed anywhere. */
  uint8_t *foot_kind;
  float *foot;          /* 4 per brick */
  /* and the ray parameters (voxel units along the ray) its box spans */
  float *t_near, *t_far;
  uint32_t *region, region_count; /* a region's list, while cut in slabs */
  float *cuts_scratch;  /* candidate cuts, one per brick */
  /* The pool. */
  uint32_t *table;      /* brick -> slot, 0 when not resident */
  uint32_t *slot_brick; /* slot -> brick, RP__BRICK_NONE when free */
  uint64_t *slot_used;  /* the clock at its last use */
  struct lru_entry *lru; /* admit's scratch: the slots it may take */
  uint64_t clock;
  uint32_t resident;
  uint64_t hits, misses, evictions;
  uint32_t *need, need_count;
  uint32_t *up_slots, up_count;
  const void **up_data;
  /* rp__bricks_checkpoint's copy of the pool's bookkeeping. */
  uint32_t *saved_table, *saved_slot_brick;
  uint64_t *saved_slot_used;
  uint64_t saved_clock, saved_hits, saved_misses, saved_evictions;
  uint32_t saved_resident;
};

enum { FOOT_NONE = 0, FOOT_BOX = 1 };

typedef struct lru_entry {
  uint64_t used;
  uint32_t slot;
} lru_entry;

size_t rp__bricks_stored_bytes(uint32_t brick_size, rp_voxel_type type) {
  size_t s = (size_t)brick_size + 1;
  return s * s * s * rp__voxel_size(type);
}

void rp__bricks_grid(const uint32_t dims[3], uint32_t brick_size,
                     uint32_t grid[3]) {
  int a;
  for (a = 0; a < 3; a++)
    grid[a] = dims[a] / brick_size + (dims[a] % brick_size != 0);
}

/* ---- building ------------------------------------------------------------ */

typedef struct build_job {
  rp__bricks *b;
  const rp_volume *vol;
} build_job;

/* Bricks of z-layers [begin, end): copy with the border clamped to the
 * volume, and the value range of what was copied. */
static void build_layers(uint32_t begin, uint32_t end, void *user) {
  build_job *j = user;
  rp__bricks *b = j->b;
  const rp_volume *vol = j->vol;
  const uint8_t *src = vol->data;
  size_t vb = b->voxel_bytes, row = (size_t)vol->dims[0];
  size_t slice = row * vol->dims[1];
  uint32_t bx, by, bz, x, y, z, s = b->stored;
  for (bz = begin; bz < end; bz++)
    for (by = 0; by < b->grid[1]; by++)
      for (bx = 0; bx < b->grid[0]; bx++) {
        size_t id = ((size_t)bz * b->grid[1] + by) * b->grid[0] + bx;
        uint8_t *dst = b->store + id * b->stored_bytes;
        double lo = INFINITY, hi = -INFINITY;
        for (z = 0; z < s; z++) {
          uint32_t vz = bz * b->size + z;
          vz = vz < vol->dims[2] ? vz : vol->dims[2] - 1;
          for (y = 0; y < s; y++) {
            uint32_t vy = by * b->size + y;
            vy = vy < vol->dims[1] ? vy : vol->dims[1] - 1;
            for (x = 0; x < s; x++) {
              uint32_t vx = bx * b->size + x;
              vx = vx < vol->dims[0] ? vx : vol->dims[0] - 1;
              memcpy(dst, src + (vz * slice + vy * row + vx) * vb, vb);
              dst += vb;
            }
          }
        }
        /* The range over the voxels actually stored (the border included:
         * a cell's upper corner lives there). */
        dst = b->store + id * b->stored_bytes;
        for (x = 0; x < b->stored_voxels; x++) {
          double v = vol->type == RP_U8    ? dst[x]
                     : vol->type == RP_U16 ? ((const uint16_t *)dst)[x]
                                           : ((const float *)dst)[x];
          lo = v < lo ? v : lo;
          hi = v > hi ? v : hi;
        }
        b->vmin[id] = lo;
        b->vmax[id] = hi;
      }
}

void rp__bricks_destroy(rp__bricks *b) {
  rp_context *ctx;
  if (b == NULL)
    return;
  ctx = b->ctx;
  rp__free(ctx, b->store);
  rp__free(ctx, b->vmin);
  rp__free(ctx, b->vmax);
  rp__free(ctx, b->visible);
  rp__free(ctx, b->fill);
  rp__free(ctx, b->foot_kind);
  rp__free(ctx, b->foot);
  rp__free(ctx, b->t_near);
  rp__free(ctx, b->t_far);
  rp__free(ctx, b->region);
  rp__free(ctx, b->cuts_scratch);
  rp__free(ctx, b->table);
  rp__free(ctx, b->slot_brick);
  rp__free(ctx, b->slot_used);
  rp__free(ctx, b->lru);
  rp__free(ctx, b->need);
  rp__free(ctx, b->up_slots);
  rp__free(ctx, (void *)b->up_data);
  rp__free(ctx, b->saved_table);
  rp__free(ctx, b->saved_slot_brick);
  rp__free(ctx, b->saved_slot_used);
  rp__free(ctx, b);
}

int rp__bricks_create(rp_context *ctx, const rp_volume *vol,
                      uint32_t brick_size, uint32_t slots, rp__bricks **out) {
  rp__bricks *b;
  build_job job;
  uint32_t i;
  int err;
  uint64_t count;
  b = rp__calloc(ctx, 1, sizeof *b);
  if (b == NULL)
    return rp__fail(ctx, RP_ENOMEM, "out-of-core volume: out of memory");
  b->ctx = ctx;
  b->type = vol->type;
  b->voxel_bytes = rp__voxel_size(vol->type);
  memcpy(b->dims, vol->dims, sizeof b->dims);
  b->size = brick_size;
  for (b->shift = 0; (1u << b->shift) < brick_size; b->shift++)
    ;
  b->stored = brick_size + 1;
  b->stored_voxels = (size_t)b->stored * b->stored * b->stored;
  b->stored_bytes = b->stored_voxels * b->voxel_bytes;
  rp__bricks_grid(vol->dims, brick_size, b->grid);
  count = (uint64_t)b->grid[0] * b->grid[1] * b->grid[2];
  b->count = (uint32_t)count;
  b->slots = slots;
  rp__volume_values(vol, &b->values);
  {
    char what[96];
    snprintf(what, sizeof what, "out-of-core volume: %llu bricks of %zu "
             "bytes", (unsigned long long)count, b->stored_bytes);
    if (rp__check_memory(ctx, what, count * b->stored_bytes) != 0) {
      rp__bricks_destroy(b);
      return RP_ENOMEM;
    }
  }
  b->store = count * b->stored_bytes <= SIZE_MAX
                 ? rp__malloc(ctx, (size_t)count * b->stored_bytes)
                 : NULL;
  b->vmin = rp__malloc(ctx, b->count * sizeof(double));
  b->vmax = rp__malloc(ctx, b->count * sizeof(double));
  b->visible = rp__calloc(ctx, b->count, 1);
  b->fill = rp__calloc(ctx, b->stored_voxels, b->voxel_bytes);
  b->foot_kind = rp__calloc(ctx, b->count, 1);
  b->foot = rp__malloc(ctx, (size_t)b->count * 4 * sizeof(float));
  b->t_near = rp__malloc(ctx, (size_t)b->count * sizeof(float));
  b->t_far = rp__malloc(ctx, (size_t)b->count * sizeof(float));
  b->region = rp__malloc(ctx, (size_t)b->count * sizeof(uint32_t));
  b->cuts_scratch = rp__malloc(ctx, (size_t)b->count * sizeof(float));
  b->table = rp__calloc(ctx, b->count, sizeof(uint32_t));
  b->slot_brick = rp__malloc(ctx, (size_t)slots * sizeof(uint32_t));
  b->slot_used = rp__calloc(ctx, slots, sizeof(uint64_t));
  b->lru = rp__malloc(ctx, (size_t)slots * sizeof *b->lru);
  b->need = rp__malloc(ctx, b->count * sizeof(uint32_t));
  b->up_slots = rp__malloc(ctx, (size_t)slots * sizeof(uint32_t));
  b->up_data = rp__malloc(ctx, (size_t)slots * sizeof(void *));
  b->saved_table = rp__malloc(ctx, b->count * sizeof(uint32_t));
  b->saved_slot_brick = rp__malloc(ctx, (size_t)slots * sizeof(uint32_t));
  b->saved_slot_used = rp__malloc(ctx, (size_t)slots * sizeof(uint64_t));
  if (b->t_near == NULL || b->t_far == NULL || b->region == NULL ||
      b->cuts_scratch == NULL ||
      b->saved_table == NULL || b->saved_slot_brick == NULL ||
      b->saved_slot_used == NULL || b->store == NULL || b->vmin == NULL || b->vmax == NULL ||
      b->visible == NULL || b->fill == NULL || b->foot_kind == NULL ||
      b->foot == NULL || b->table == NULL || b->slot_brick == NULL ||
      b->slot_used == NULL || b->lru == NULL || b->need == NULL || b->up_slots == NULL ||
      b->up_data == NULL) {
    rp__bricks_destroy(b);
    return rp__fail(ctx, RP_ENOMEM, "out-of-core volume: out of memory for "
                    "%llu bricks of %zu bytes", (unsigned long long)count,
                    rp__bricks_stored_bytes(brick_size, vol->type));
  }
  for (i = 0; i < slots; i++)
    b->slot_brick[i] = RP__BRICK_NONE;
  job.b = b;
  job.vol = vol;
  if ((err = rp__parallel_for(ctx, b->grid[2], build_layers, &job)) != 0) {
    rp__bricks_destroy(b);
    return err;
  }
  b->fill_changed = 1;
  *out = b;
  return 0;
}

/* ---- visibility ---------------------------------------------------------- */

/* The same TF-space clamp rp__tf_alpha_max applies, widened by one LUT
 * entry each way: the kernels place a value in the LUT in float, and a
 * brick they see must never be called invisible here. */
static int range_visible(const rp_tf *tf, const double span[2], double lo,
                         double hi) {
  double pad = tf->lut_size > 1 ? 1.0 / (tf->lut_size - 1) : 1.0;
  return rp__tf_alpha_max(tf, rp__value_to_x(lo, span[0], span[1]) - pad,
                          rp__value_to_x(hi, span[0], span[1]) + pad) >
         0.0f;
}

static void write_fill(rp__bricks *b, double v) {
  size_t i;
  for (i = 0; i < b->stored_voxels; i++) {
    if (b->type == RP_U8)
      b->fill[i] = (uint8_t)v;
    else if (b->type == RP_U16)
      ((uint16_t *)b->fill)[i] = (uint16_t)v;
    else
      ((float *)b->fill)[i] = (float)v;
  }
}

void rp__bricks_set_tf(rp__bricks *b, const rp_tf *tf) {
  uint32_t i;
  int have_fill = 0;
  double fill = b->fill_value, span[2];
  rp__tf_stored_range(tf, &b->values, span);
  b->visible_count = 0;
  for (i = 0; i < b->count; i++) {
    b->visible[i] = (uint8_t)range_visible(tf, span, b->vmin[i], b->vmax[i]);
    b->visible_count += b->visible[i];
    /* Slot 0 holds a value an invisible brick holds: transparent, with
     * the margin above, wherever the kernels place it. */
    if (!b->visible[i] && !have_fill) {
      have_fill = 1;
      fill = b->vmin[i];
    }
  }
  if (have_fill && fill != b->fill_value) {
    b->fill_value = fill;
    write_fill(b, fill);
    b->fill_changed = 1;
  }
}

const void *rp__bricks_fill(const rp__bricks *b, int *changed) {
  *changed = b->fill_changed;
  return b->fill;
}

void rp__bricks_fill_sent(rp__bricks *b) { b->fill_changed = 0; }

void rp__bricks_forget(rp__bricks *b) {
  uint32_t s;
  memset(b->table, 0, (size_t)b->count * sizeof *b->table);
  for (s = 0; s < b->slots; s++) {
    b->slot_brick[s] = RP__BRICK_NONE;
    b->slot_used[s] = 0;
  }
  b->resident = 0;
  b->up_count = 0;
  b->fill_changed = 1;
}

/* ---- footprints ---------------------------------------------------------- */

/* Whether brick (x, y, z) or, with `shading`, one of its 26 neighbours is
 * visible. */
static int brick_candidate(const rp__bricks *b, uint32_t x, uint32_t y,
                           uint32_t z, int shading) {
  uint32_t c[3] = {x, y, z}, lo[3], hi[3], i, j, k;
  int a;
  if (!shading)
    return b->visible[((size_t)z * b->grid[1] + y) * b->grid[0] + x];
  for (a = 0; a < 3; a++) {
    lo[a] = c[a] > 0 ? c[a] - 1 : 0;
    hi[a] = c[a] + 1 < b->grid[a] ? c[a] + 1 : c[a];
  }
  for (k = lo[2]; k <= hi[2]; k++)
    for (j = lo[1]; j <= hi[1]; j++)
      for (i = lo[0]; i <= hi[0]; i++)
        if (b->visible[((size_t)k * b->grid[1] + j) * b->grid[0] + i])
          return 1;
  return 0;
}

/* The voxel-space interval along axis a that samples reading brick c lie
 * in (sampling clamps to [0, dims - 1] and the low corner to dims - 2);
 * 0 when nothing reads it: past the brick of cell dims - 2, not even a
 * gradient does, since its fetches clamp the same way. */
static int brick_span(const rp__bricks *b, int a, uint32_t c, double *lo,
                      double *hi) {
  uint32_t d = b->dims[a];
  uint32_t last = d >= 2 ? (d - 2) / b->size : 0;
  if (c > last)
    return 0;
  *lo = c == 0 ? -0.5 : (double)c * b->size;
  *hi = c == last ? (double)d - 0.5 : (double)(c + 1) * b->size;
  return 1;
}

/* Projects the box [lo, hi] (voxel space) to pixel indices of rg's image:
 * FOOT_NONE when nothing of it is in front of the camera. A perspective
 * box across the eye plane is clipped to just in front of it first: the
 * part close to the plane projects far out, to the side it lies on, so a
 * brick beside the eye still covers only that side of the image. */
static int project_box(const rp__raygen *rg, const double lo[3],
                       const double hi[3], float out[4], float *t_near,
                       float *t_far) {
  double x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
  double near_d = 0.0, far_d = 0.0, zmin = INFINITY, zmax = -INFINITY;
  double v[8][3], z[8], near = 1e-6 * rg->min_spacing;
  double pts[8 + 12][3];
  int corner, a, e, n = 0, front = 0;
  for (corner = 0; corner < 8; corner++) {
    double w[3];
    for (a = 0; a < 3; a++) {
      double p = (corner >> a) & 1 ? hi[a] : lo[a];
      w[a] = (p - 0.5 * rg->dims[a] + 0.5) * rg->spacing[a] - rg->eye[a];
    }
    /* Camera space: right, up, forward. */
    v[corner][0] = w[0] * rg->r[0] + w[1] * rg->r[1] + w[2] * rg->r[2];
    v[corner][1] = w[0] * rg->u[0] + w[1] * rg->u[1] + w[2] * rg->u[2];
    v[corner][2] = z[corner] =
        w[0] * rg->f[0] + w[1] * rg->f[1] + w[2] * rg->f[2];
    front += z[corner] > 0.0;
    zmin = fmin(zmin, z[corner]);
    zmax = fmax(zmax, z[corner]);
    far_d = fmax(far_d, sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]));
  }
  /* Where along a ray the box can be: perspective rays start at the eye
   * with unit world direction, so between the box's distance from the
   * eye and its farthest corner's; orthographic ones start on the eye
   * plane, so between its nearest and farthest depth. In voxel units of
   * the ray parameter: world length / min_spacing. */
  if (rg->ortho) {
    near_d = fmax(zmin, 0.0);
    far_d = zmax;
  } else {
    double d2 = 0.0;
    for (a = 0; a < 3; a++) {
      double l = (lo[a] - 0.5 * rg->dims[a] + 0.5) * rg->spacing[a];
      double h = (hi[a] - 0.5 * rg->dims[a] + 0.5) * rg->spacing[a];
      double c = rg->eye[a] < l ? l - rg->eye[a]
                 : rg->eye[a] > h ? rg->eye[a] - h
                                  : 0.0;
      d2 += c * c;
    }
    near_d = sqrt(d2);
  }
  *t_near = (float)(near_d / rg->min_spacing);
  *t_far = (float)(far_d / rg->min_spacing);
  /* Rays sample at t >= 0 only, in front of the eye plane. */
  if (front == 0)
    return FOOT_NONE;
  for (corner = 0; corner < 8; corner++)
    if (rg->ortho || z[corner] >= near)
      memcpy(pts[n++], v[corner], sizeof v[corner]);
  if (!rg->ortho)
    for (corner = 0; corner < 8; corner++)
      for (e = 0; e < 3; e++) {
        int other = corner | (1 << e);
        double t;
        /* Each of the 12 edges once, where it crosses z = near. */
        if (other == corner || (z[corner] < near) == (z[other] < near))
          continue;
        t = (near - z[corner]) / (z[other] - z[corner]);
        for (a = 0; a < 3; a++)
          pts[n][a] = v[corner][a] + t * (v[other][a] - v[corner][a]);
        pts[n++][2] = near;
      }
  for (e = 0; e < n; e++) {
    double su = pts[e][0], sv = pts[e][1], px, py;
    if (!rg->ortho) {
      su /= pts[e][2];
      sv /= pts[e][2];
    }
    px = 0.5 * (su / rg->half_w + 1.0) * rg->width - 0.5;
    py = 0.5 * (1.0 - sv / rg->half_h) * rg->height - 0.5;
    x0 = px < x0 ? px : x0;
    x1 = px > x1 ? px : x1;
    y0 = py < y0 ? py : y0;
    y1 = py > y1 ? py : y1;
  }
  if (n == 0)
    return FOOT_NONE;
  /* Far beyond the image either way is as good as infinity, and keeps
   * the floats finite. */
  out[0] = (float)fmax(floor(x0), -1e30);
  out[1] = (float)fmin(ceil(x1), 1e30);
  out[2] = (float)fmax(floor(y0), -1e30);
  out[3] = (float)fmin(ceil(y1), 1e30);
  return FOOT_BOX;
}

void rp__bricks_frame(rp__bricks *b, const rp__raygen *rg, int shading) {
  /* Rounding: the kernels place samples in float, a few 1e-4 voxels off
   * the double geometry here; the gradient reads one voxel further. */
  double margin = 0.01 + (shading ? 1.0 : 0.0);
  uint32_t x, y, z;
  for (z = 0; z < b->grid[2]; z++)
    for (y = 0; y < b->grid[1]; y++)
      for (x = 0; x < b->grid[0]; x++) {
        size_t id = ((size_t)z * b->grid[1] + y) * b->grid[0] + x;
        uint32_t c[3] = {x, y, z};
        double lo[3], hi[3];
        int a, used = 1;
        b->foot_kind[id] = FOOT_NONE;
        for (a = 0; a < 3 && used; a++) {
          if (!(used = brick_span(b, a, c[a], &lo[a], &hi[a])))
            break;
          lo[a] -= margin;
          hi[a] += margin;
        }
        if (!used || !brick_candidate(b, x, y, z, shading))
          continue;
        b->foot_kind[id] = (uint8_t)project_box(rg, lo, hi, b->foot + 4 * id,
                                                &b->t_near[id],
                                                &b->t_far[id]);
      }
}

uint32_t rp__bricks_needed(rp__bricks *b, const rp_region *r) {
  uint32_t i;
  float rx0 = (float)r->x0, rx1 = (float)r->x1 - 1.0f;
  float ry0 = (float)r->y0, ry1 = (float)r->y1 - 1.0f;
  b->need_count = 0;
  for (i = 0; i < b->count; i++) {
    const float *f = b->foot + 4 * (size_t)i;
    if (b->foot_kind[i] == FOOT_NONE || f[1] < rx0 || f[0] > rx1 ||
        f[3] < ry0 || f[2] > ry1)
      continue;
    b->need[b->need_count++] = i;
  }
  return b->need_count;
}

uint32_t rp__bricks_missing(const rp__bricks *b) {
  uint32_t i, n = 0;
  for (i = 0; i < b->need_count; i++)
    n += b->table[b->need[i]] == 0;
  return n;
}

/* ---- the pool ------------------------------------------------------------ */

static int cmp_lru(const void *a, const void *b) {
  const lru_entry *x = a, *y = b;
  if (x->used != y->used)
    return x->used < y->used ? -1 : 1;
  return x->slot < y->slot ? -1 : x->slot > y->slot;
}

void rp__bricks_admit(rp__bricks *b) {
  uint64_t now = ++b->clock;
  uint32_t i, s, free_slots = 0, next = 0, misses = 0;
  b->up_count = 0;
  /* Hits first, so that no brick this region needs is evicted for
   * another it needs. */
  for (i = 0; i < b->need_count; i++) {
    s = b->table[b->need[i]];
    if (s != 0) {
      b->slot_used[s] = now;
      b->hits++;
    } else {
      misses++;
    }
  }
  if (misses == 0)
    return;
  /* The slots a miss may take, least recently used first, ties to the
   * lowest slot: the order in which scanning for the oldest slot before
   * each miss would take them, in one sort per admit rather than a scan
   * of the pool per miss (a cold frame of a large pool misses
   * thousands of bricks). */
  for (s = 1; s < b->slots; s++)
    if (b->slot_used[s] < now) {
      b->lru[free_slots].used = b->slot_used[s];
      b->lru[free_slots].slot = s;
      free_slots++;
    }
  qsort(b->lru, free_slots, sizeof *b->lru, cmp_lru);
  for (i = 0; i < b->need_count && next < free_slots; i++) {
    uint32_t id = b->need[i];
    if (b->table[id] != 0)
      continue;
    s = b->lru[next++].slot;
    if (b->slot_brick[s] != RP__BRICK_NONE) {
      b->table[b->slot_brick[s]] = 0;
      b->evictions++;
    } else {
      b->resident++;
    }
    b->slot_brick[s] = id;
    b->slot_used[s] = now;
    b->table[id] = s;
    b->misses++;
    b->up_slots[b->up_count] = s;
    b->up_data[b->up_count] = b->store + (size_t)id * b->stored_bytes;
    b->up_count++;
  }
}

uint32_t rp__bricks_upload_count(const rp__bricks *b) { return b->up_count; }
const uint32_t *rp__bricks_upload_slots(const rp__bricks *b) {
  return b->up_slots;
}
const void *const *rp__bricks_upload_data(const rp__bricks *b) {
  return b->up_data;
}
const uint32_t *rp__bricks_table(const rp__bricks *b) { return b->table; }

void rp__bricks_get_info(const rp__bricks *b, rp__bricks_info *info) {
  memset(info, 0, sizeof *info);
  info->brick_size = b->size;
  info->stored = b->stored;
  memcpy(info->grid, b->grid, sizeof info->grid);
  info->count = b->count;
  info->visible = b->visible_count;
  info->slots = b->slots;
  info->resident = b->resident;
  info->hits = b->hits;
  info->misses = b->misses;
  info->evictions = b->evictions;
  info->stored_bytes = b->stored_bytes;
}

const void *rp__bricks_voxels(const rp__bricks *b, uint32_t brick) {
  return b->store + (size_t)brick * b->stored_bytes;
}

int rp__bricks_visible(const rp__bricks *b, uint32_t brick) {
  return b->visible[brick];
}

const uint32_t *rp__bricks_need_list(const rp__bricks *b) { return b->need; }

void rp__bricks_set_needed(rp__bricks *b, const uint32_t *ids, uint32_t n) {
  memcpy(b->need, ids, (size_t)n * sizeof *ids);
  b->need_count = n;
}

void rp__bricks_checkpoint(rp__bricks *b) {
  memcpy(b->saved_table, b->table, (size_t)b->count * sizeof *b->table);
  memcpy(b->saved_slot_brick, b->slot_brick,
         (size_t)b->slots * sizeof *b->slot_brick);
  memcpy(b->saved_slot_used, b->slot_used,
         (size_t)b->slots * sizeof *b->slot_used);
  b->saved_clock = b->clock;
  b->saved_hits = b->hits;
  b->saved_misses = b->misses;
  b->saved_evictions = b->evictions;
  b->saved_resident = b->resident;
}

void rp__bricks_rollback(rp__bricks *b) {
  memcpy(b->table, b->saved_table, (size_t)b->count * sizeof *b->table);
  memcpy(b->slot_brick, b->saved_slot_brick,
         (size_t)b->slots * sizeof *b->slot_brick);
  memcpy(b->slot_used, b->saved_slot_used,
         (size_t)b->slots * sizeof *b->slot_used);
  b->clock = b->saved_clock;
  b->hits = b->saved_hits;
  b->misses = b->saved_misses;
  b->evictions = b->saved_evictions;
  b->resident = b->saved_resident;
  b->up_count = 0;
}

/* ---- depth slabs --------------------------------------------------------- */

/* Slack on slab membership, voxel units: the kernels place samples in
 * float, a few 1e-4 voxels off the double geometry here. */
#define SLAB_SLACK 0.05f

/* Of the region's bricks, those whose depth span meets [t0, t1). */
static uint32_t slab_count(const rp__bricks *b, float t0, float t1,
                           uint32_t *out) {
  uint32_t i, n = 0;
  for (i = 0; i < b->region_count; i++) {
    uint32_t id = b->region[i];
    if (b->t_far[id] >= t0 - SLAB_SLACK && b->t_near[id] < t1 + SLAB_SLACK) {
      if (out != NULL)
        out[n] = id;
      n++;
    }
  }
  return n;
}

static int cmp_float(const void *a, const void *b) {
  float x = *(const float *)a, y = *(const float *)b;
  return x < y ? -1 : x > y;
}

int rp__bricks_slabs(rp__bricks *b, uint32_t cap, float *cuts,
                     uint32_t max_cuts, uint32_t *n_slabs, uint32_t *worst) {
  float *cand = b->cuts_scratch;
  float t0 = -INFINITY;
  uint32_t i, n = 0, nc = 0;
  memcpy(b->region, b->need, (size_t)b->need_count * sizeof *b->need);
  b->region_count = b->need_count;
  /* A cut is worth trying where a brick starts. */
  for (i = 0; i < b->region_count; i++)
    cand[nc++] = b->t_near[b->region[i]];
  qsort(cand, nc, sizeof *cand, cmp_float);
  *worst = 0;
  while (n < max_cuts) {
    uint32_t lo = 0, hi = nc, first;
    if (slab_count(b, t0, INFINITY, NULL) <= cap) {
      cuts[n++] = INFINITY;
      *n_slabs = n;
      return 0;
    }
    /* The candidates past t0; the count grows with the cut, so binary
     * search for the last that fits. */
    while (lo < nc && !(cand[lo] > t0))
      lo++;
    first = lo;
    /* No brick starts past t0 (every one left is already met there), or
     * the bricks met just past t0 alone exceed the pool. */
    *worst = slab_count(b, t0, first == nc ? INFINITY : cand[first], NULL);
    if (first == nc || *worst > cap)
      return -1;
    while (hi - lo > 1) {
      uint32_t mid = lo + (hi - lo) / 2;
      if (slab_count(b, t0, cand[mid], NULL) <= cap)
        lo = mid;
      else
        hi = mid;
    }
    cuts[n++] = cand[lo];
    t0 = cand[lo];
  }
  return -1;
}

void rp__bricks_slab_needed(rp__bricks *b, float t0, float t1) {
  b->need_count = slab_count(b, t0, t1, b->need);
}
