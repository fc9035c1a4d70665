/* The Vulkan backend's uploads: the volume (in the plain or the quad
 * layout), the transfer function with its pre-integration table, and the
 * occupancy grid with its opacity histograms. The AO volume and the brick
 * pool are uploaded in files of their own (vk_ao.c, vk_bricks.c). */
#include <string.h>

#include "vk_internal.h"

/* Texel formats of the volume per rp_voxel_type: one voxel per texel
 * (plain), or the 2x2 footprint of the quad layout. */
const VkFormat rp_vk__plain_fmt[4] = {
    VK_FORMAT_UNDEFINED, VK_FORMAT_R8_UINT, VK_FORMAT_R16_UINT,
    VK_FORMAT_R32_UINT};
static const VkFormat quad_fmt[4] = {
    VK_FORMAT_UNDEFINED, VK_FORMAT_R8G8B8A8_UINT, VK_FORMAT_R16G16B16A16_UINT,
    VK_FORMAT_R32G32B32A32_UINT};

typedef struct volume_fill {
  const rp_volume *vol;
  void *dst;
  int quad;
} volume_fill;

/* Quad layout rows: texel (x, y, z) = voxels (x, y), (x+1, y), (x, y+1),
 * (x+1, y+1) of slice z, with x+1 and y+1 clamped at the far faces (the
 * weight of a clamped neighbour is 0 there anyway). `row` is z * ny + y.
 * Float voxels are copied as their 32-bit patterns. */
#define RP_VK_QUAD_ROWS(name, T)                                              \
  static void name(const volume_fill *j, uint32_t begin, uint32_t end) {      \
    const T *src = (const T *)j->vol->data;                                   \
    T *dst = (T *)j->dst;                                                     \
    uint32_t nx = j->vol->dims[0], ny = j->vol->dims[1], row, x;              \
    for (row = begin; row < end; row++) {                                     \
      const T *r0 = src + (size_t)row * nx;                                   \
      const T *r1 = row % ny + 1 < ny ? r0 + nx : r0;                         \
      T *o = dst + (size_t)row * nx * 4;                                      \
      for (x = 0; x < nx; x++) {                                              \
        uint32_t x1 = x + 1 < nx ? x + 1 : x;                                 \
        o[4 * x] = r0[x];                                                     \
        o[4 * x + 1] = r0[x1];                                                \
        o[4 * x + 2] = r1[x];                                                 \
        o[4 * x + 3] = r1[x1];                                                \
      }                                                                       \
    }                                                                         \
  }

RP_VK_QUAD_ROWS(quad_rows_8, uint8_t)
RP_VK_QUAD_ROWS(quad_rows_16, uint16_t)
RP_VK_QUAD_ROWS(quad_rows_32, uint32_t)

static void quad_rows(uint32_t begin, uint32_t end, void *user) {
  const volume_fill *j = user;
  switch (j->vol->type) {
  case RP_U8: quad_rows_8(j, begin, end); break;
  case RP_U16: quad_rows_16(j, begin, end); break;
  default: quad_rows_32(j, begin, end); break;
  }
}

static void fill_volume(void *dst, void *user) {
  volume_fill *j = user;
  const rp_volume *vol = j->vol;
  uint32_t rows = vol->dims[1] * vol->dims[2];
  j->dst = dst;
  if (!j->quad) {
    memcpy(dst, vol->data, vol->voxel_count * rp__voxel_size(vol->type));
    return;
  }
  /* Parallel over rows; without threads (no memory for them) the same
   * work runs here. */
  if (rp__parallel_for(vol->ctx, rows, quad_rows, j) != 0)
    quad_rows(0, rows, j);
}

int rp_vk__format_ok(rp_vk_impl *impl, VkFormat f) {
  VkFormatProperties fp;
  vkGetPhysicalDeviceFormatProperties(impl->phys, f, &fp);
  return (fp.bufferFeatures & VK_FORMAT_FEATURE_UNIFORM_TEXEL_BUFFER_BIT) !=
         0;
}

/* Half the largest device-local heap: what the quad layout may take
 * before the plain one is preferred, leaving room for everything else. */
static uint64_t quad_budget(const rp_vk_impl *impl) {
  uint64_t best = 0;
  uint32_t i;
  for (i = 0; i < impl->mem_props.memoryHeapCount; i++) {
    const VkMemoryHeap *h = &impl->mem_props.memoryHeaps[i];
    if ((h->flags & VK_MEMORY_HEAP_DEVICE_LOCAL_BIT) && h->size > best)
      best = h->size;
  }
  return best / 2;
}

/* What the volume is, as prepare reads it: under the lock. */
void rp_vk__set_volume_state(rp_vk_impl *impl, rp_voxel_type type, int quad,
                             int bricked) {
  pthread_mutex_lock(&impl->lock);
  impl->voxel_type = type;
  impl->quad = quad;
  impl->bricked = bricked;
  impl->stats.quad_layout = quad;
  pthread_mutex_unlock(&impl->lock);
}

/* Releases the volume, whole or a brick pool, and its table. The caller
 * rebinds. */
void rp_vk__drop_volume(rp_vk_impl *impl) {
  rp_vk__free_view(impl, &impl->volume_view);
  rp_vk__buffer_free(impl, &impl->volume);
  rp_vk__free_view(impl, &impl->brick_table_view);
  rp_vk__buffer_free(impl, &impl->brick_table);
  rp_vk__set_volume_state(impl, 0, impl->quad, 0);
  impl->brick_slots = impl->brick_count = 0;
  impl->brick_bytes = 0;
  impl->depth_ok = 0;
}

int rp_vk__upload_volume(void *p, const rp_volume *vol) {
  rp_vk_impl *impl = p;
  rp_context *ctx = impl->ctx;
  uint64_t n = vol->voxel_count, es = rp__voxel_size(vol->type);
  uint32_t limit = impl->props.limits.maxTexelBufferElements;
  volume_fill job;
  int quad, err;
  if ((err = rp_vk__alive(impl)) != 0)
    return err;
  /* texelFetch takes an int, and a view holds at most the limit. */
  if (n > limit || n > INT32_MAX)
    return rp__fail(ctx, RP_EUNSUPPORTED, "vulkan: volume %ux%ux%u has "
                    "%llu voxels; this device reads at most %u per buffer "
                    "(maxTexelBufferElements)", vol->dims[0], vol->dims[1],
                    vol->dims[2], (unsigned long long)n, (unsigned)limit);
  if (!rp_vk__format_ok(impl, rp_vk__plain_fmt[vol->type]))
    return rp__fail(ctx, RP_EUNSUPPORTED, "vulkan: device cannot read %s "
                    "voxels from a texel buffer",
                    rp_voxel_type_name(vol->type));
  quad = !rp_vk_hooks.force_plain &&
         rp_vk__format_ok(impl, quad_fmt[vol->type]) &&
         4 * es * n <= impl->max_alloc && 4 * es * n <= quad_budget(impl);

  rp_vk__drop_volume(impl);
  /* An AO volume is one byte per voxel of the volume it was uploaded
   * for: it cannot survive a change of shape (whether it still fits the
   * new voxels is the front end's to judge). */
  if (memcmp(impl->dims, vol->dims, sizeof impl->dims) != 0)
    rp_vk__drop_ao(impl);
  memset(impl->dims, 0, sizeof impl->dims);
  err = rp_vk__buffer(impl, "volume", (quad ? 4 : 1) * es * n,
                      VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                          VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                      0, &impl->volume);
  if (err == 0) {
    job.vol = vol;
    job.quad = quad;
    err = rp_vk__write_buffer(impl, &impl->volume, "volume staging",
                              fill_volume, &job);
  }
  if (err == 0)
    err = rp_vk__make_view(impl, impl->volume.buf,
                           quad ? quad_fmt[vol->type]
                                : rp_vk__plain_fmt[vol->type],
                           &impl->volume_view);
  if (err != 0) {
    rp_vk__drop_volume(impl);
    rp_vk__drop_ao(impl);
    rp_vk__bind_all(impl);
    return err;
  }
  rp_vk__bind_all(impl);
  memcpy(impl->dims, vol->dims, sizeof impl->dims);
  rp_vk__set_volume_state(impl, vol->type, quad, 0);
  return 0;
}

int rp_vk__upload_tf(void *p, const float *lut, uint32_t lut_size) {
  rp_vk_impl *impl = p;
  rp_vk_copy_fill c;
  float *all;
  int err;
  if ((err = rp_vk__alive(impl)) != 0)
    return err;
  /* The LUT and its pre-integration table (rp__preint_table), which the
   * RP_PREINT raycast reads after the LUT's texels: 32 KiB for the
   * default 1024 entries, kept whether or not a frame uses it, so that
   * switching the effect on costs no upload. */
  c.bytes = (size_t)lut_size * 12 * sizeof(float);
  if ((uint64_t)lut_size * 3 > impl->props.limits.maxTexelBufferElements)
    return rp__fail(impl->ctx, RP_ERANGE, "vulkan: a transfer function of "
                    "%u entries and its pre-integration table need %llu "
                    "texels; the device's maxTexelBufferElements is %u",
                    (unsigned)lut_size, (unsigned long long)lut_size * 3,
                    (unsigned)impl->props.limits.maxTexelBufferElements);
  if ((all = rp__malloc(impl->ctx, c.bytes)) == NULL)
    return rp__fail(impl->ctx, RP_ENOMEM, "vulkan: no memory to stage the "
                    "transfer function (%u entries)", (unsigned)lut_size);
  memcpy(all, lut, (size_t)lut_size * 4 * sizeof(float));
  rp__preint_table(lut, lut_size, all + (size_t)lut_size * 4);
  c.src = all;
  if (impl->lut.size != c.bytes) {
    rp_vk__free_view(impl, &impl->lut_view);
    rp_vk__buffer_free(impl, &impl->lut);
    if ((err = rp_vk__buffer(impl, "transfer function", c.bytes,
                             VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                 VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                             0, &impl->lut)) != 0 ||
        (err = rp_vk__make_view(impl, impl->lut.buf,
                                VK_FORMAT_R32G32B32A32_SFLOAT,
                                &impl->lut_view)) != 0) {
      rp_vk__free_view(impl, &impl->lut_view);
      rp_vk__buffer_free(impl, &impl->lut);
      rp_vk__bind_all(impl);
      rp__free(impl->ctx, all);
      return err;
    }
    rp_vk__bind_all(impl);
  }
  impl->have_lut = 0;
  err = rp_vk__write_buffer(impl, &impl->lut, "transfer function staging",
                            rp_vk__fill_copy, &c);
  rp__free(impl->ctx, all);
  if (err != 0)
    return err;
  impl->have_lut = 1;
  return 0;
}

int rp_vk__upload_occupancy(void *p, const uint8_t *grid,
                            const uint8_t *alpha_hist,
                            const uint32_t blocks[3]) {
  rp_vk_impl *impl = p;
  size_t nb = (size_t)blocks[0] * blocks[1] * blocks[2];
  const VkBufferUsageFlags usage = VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                   VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  rp_vk_copy_fill c;
  int err;
  if ((err = rp_vk__alive(impl)) != 0)
    return err;
  if (nb > impl->props.limits.maxTexelBufferElements)
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: %zu blocks exceed "
                    "the device's %u texels per buffer", nb,
                    (unsigned)impl->props.limits.maxTexelBufferElements);
  impl->occupancy_gen++;
  impl->depth_ok = 0;
  if (impl->grid.size != nb) {
    rp_vk__free_view(impl, &impl->grid_view);
    rp_vk__free_view(impl, &impl->alpha_view);
    rp_vk__buffer_free(impl, &impl->grid);
    rp_vk__buffer_free(impl, &impl->alpha);
    /* One byte per block; H-alpha's 16 bytes per block as one RGBA32
     * texel. */
    if ((err = rp_vk__buffer(impl, "occupancy grid", nb, usage, 0,
                             &impl->grid)) != 0 ||
        (err = rp_vk__buffer(impl, "opacity histograms", nb * RP_OPACITY_BINS,
                             usage, 0, &impl->alpha)) != 0 ||
        (err = rp_vk__make_view(impl, impl->grid.buf, VK_FORMAT_R8_UINT,
                                &impl->grid_view)) != 0 ||
        (err = rp_vk__make_view(impl, impl->alpha.buf,
                                VK_FORMAT_R32G32B32A32_UINT,
                                &impl->alpha_view)) != 0) {
      rp_vk__free_view(impl, &impl->grid_view);
      rp_vk__free_view(impl, &impl->alpha_view);
      rp_vk__buffer_free(impl, &impl->grid);
      rp_vk__buffer_free(impl, &impl->alpha);
      rp_vk__bind_all(impl);
      return err;
    }
    rp_vk__bind_all(impl);
  }
  c.src = grid;
  c.bytes = nb;
  if ((err = rp_vk__write_buffer(impl, &impl->grid, "occupancy staging",
                                 rp_vk__fill_copy, &c)) != 0)
    return err;
  c.src = alpha_hist;
  c.bytes = nb * RP_OPACITY_BINS;
  return rp_vk__write_buffer(impl, &impl->alpha, "histogram staging",
                             rp_vk__fill_copy, &c);
}
