/* The Vulkan backend's out-of-core volume: set_brick_pool makes the pool
 * of bricks and the table of their slots; upload_bricks fills them, in
 * place where the memory is mapped, else through staging copies. */
#include <string.h>

#include "vk_internal.h"

/* Staging bytes one upload_bricks submission uses at most (more only
 * where a single brick or the table is larger). */
#define RP_VK_BRICK_CHUNK ((VkDeviceSize)16 << 20)

int rp_vk__set_brick_pool(void *p, const rp_brick_pool *pool) {
  rp_vk_impl *impl = p;
  const VkBufferUsageFlags usage = VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                   VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  uint64_t stored, es, voxels, count, bytes;
  uint32_t limit = impl->props.limits.maxTexelBufferElements;
  int err;
  impl->last_ns = 0;
  /* The pool replaces the volume, and AO is not rendered from one. */
  rp_vk__drop_volume(impl);
  rp_vk__drop_ao(impl);
  memset(impl->dims, 0, sizeof impl->dims);
  if (pool == NULL) {
    rp_vk__bind_all(impl);
    return 0;
  }
  if ((err = rp_vk__alive(impl)) != 0) {
    rp_vk__bind_all(impl);
    return err;
  }
  stored = (uint64_t)pool->brick_size + 1;
  es = rp__voxel_size(pool->type);
  voxels = stored * stored * stored * pool->slots;
  count = (uint64_t)pool->grid[0] * pool->grid[1] * pool->grid[2];
  /* Whole 32-bit words, so that one fill clears every byte. */
  bytes = (voxels * es + 3) / 4 * 4;
  /* texelFetch takes an int, and a view holds at most the limit. */
  if (bytes / es > limit || bytes / es > INT32_MAX || count > limit) {
    rp_vk__bind_all(impl);
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: a pool of %u "
                    "bricks of %u^3 voxels (and a border) takes %llu "
                    "voxels, its table %llu entries; this device reads at "
                    "most %u per buffer (maxTexelBufferElements): a smaller "
                    "budget_bytes", pool->slots, pool->brick_size,
                    (unsigned long long)voxels, (unsigned long long)count,
                    (unsigned)limit);
  }
  if (!rp_vk__format_ok(impl, rp_vk__plain_fmt[pool->type]) ||
      !rp_vk__format_ok(impl, VK_FORMAT_R32_UINT)) {
    rp_vk__bind_all(impl);
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: device cannot "
                    "read %s voxels and 32-bit slots from texel buffers "
                    "(brick pool)", rp_voxel_type_name(pool->type));
  }
  if ((err = rp_vk__buffer(impl, "brick pool", bytes, usage, 0,
                           &impl->volume)) == 0 &&
      (err = rp_vk__buffer(impl, "brick table", count * sizeof(uint32_t), usage,
                           0, &impl->brick_table)) == 0 &&
      (err = rp_vk__make_view(impl, impl->volume.buf,
                              rp_vk__plain_fmt[pool->type],
                              &impl->volume_view)) == 0 &&
      (err = rp_vk__make_view(impl, impl->brick_table.buf, VK_FORMAT_R32_UINT,
                              &impl->brick_table_view)) == 0 &&
      (err = rp_vk__begin(impl)) == 0) {
    /* Every brick starts in slot 0 (the front end's transparent one), and
     * the pool is defined before any brick arrives. */
    vkCmdFillBuffer(impl->cmd, impl->volume.buf, 0, VK_WHOLE_SIZE, 0);
    vkCmdFillBuffer(impl->cmd, impl->brick_table.buf, 0, VK_WHOLE_SIZE, 0);
    rp_vk__barrier(
        impl, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
        VK_PIPELINE_STAGE_TRANSFER_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
        VK_ACCESS_TRANSFER_WRITE_BIT | VK_ACCESS_SHADER_READ_BIT);
    err = rp_vk__finish(impl, "clearing the brick pool");
  }
  if (err != 0) {
    rp_vk__drop_volume(impl);
    rp_vk__bind_all(impl);
    return err;
  }
  rp_vk__bind_all(impl);
  impl->brick_slots = pool->slots;
  impl->brick_count = (uint32_t)count;
  impl->brick_bytes = (VkDeviceSize)(stored * stored * stored * es);
  memcpy(impl->dims, pool->dims, sizeof impl->dims);
  /* One voxel per texel: the quad layout would take four times the
   * memory the front end sized the pool to. */
  rp_vk__set_volume_state(impl, pool->type, 0, 1);
  return 0;
}

/* upload_bricks through a staging buffer and copies, in chunks of whole
 * bricks; the table goes with the last. */
static int upload_bricks_staged(rp_vk_impl *impl, uint32_t count,
                                const uint32_t *slots,
                                const void *const *voxels,
                                const uint32_t *table) {
  VkDeviceSize bb = impl->brick_bytes;
  VkDeviceSize tb = table != NULL ? impl->brick_count * sizeof *table : 0;
  VkDeviceSize total = (VkDeviceSize)count * bb + tb;
  VkDeviceSize size = RP_VK_BRICK_CHUNK, used;
  rp_vk_buffer staging;
  uint64_t ns = 0;
  uint32_t i = 0;
  int table_done = table == NULL, err;
  size = size > bb ? size : bb;
  size = size > tb ? size : tb;
  size = size < total ? size : total;
  if (size == 0)
    return 0;
  if ((err = rp_vk__buffer(impl, "brick staging", size,
                           VK_BUFFER_USAGE_TRANSFER_SRC_BIT, 1, &staging)) !=
      0)
    return err;
  /* Each round moves at least one brick, or the table once all bricks
   * have gone, so the loop ends. */
  while (err == 0 && (i < count || !table_done)) {
    uint8_t *dst = staging.map;
    if ((err = rp_vk__begin(impl)) != 0)
      break;
    for (used = 0; i < count && used + bb <= size; i++, used += bb) {
      VkBufferCopy c;
      c.srcOffset = used;
      c.dstOffset = (VkDeviceSize)slots[i] * bb;
      c.size = bb;
      memcpy(dst + used, voxels[i], (size_t)bb);
      vkCmdCopyBuffer(impl->cmd, staging.buf, impl->volume.buf, 1, &c);
    }
    if (i == count && !table_done && used + tb <= size) {
      VkBufferCopy c;
      c.srcOffset = used;
      c.dstOffset = 0;
      c.size = tb;
      memcpy(dst + used, table, (size_t)tb);
      vkCmdCopyBuffer(impl->cmd, staging.buf, impl->brick_table.buf, 1, &c);
      table_done = 1;
    }
    rp_vk__barrier(
        impl, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
        VK_PIPELINE_STAGE_TRANSFER_BIT | VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
        VK_ACCESS_TRANSFER_WRITE_BIT | VK_ACCESS_SHADER_READ_BIT);
    if ((err = rp_vk__finish(impl, "brick upload")) == 0)
      ns += impl->last_ns;
  }
  rp_vk__buffer_free(impl, &staging);
  impl->last_ns = err == 0 ? ns : 0;
  return err;
}

int rp_vk__upload_bricks(void *p, uint32_t count, const uint32_t *slots,
                         const void *const *voxels, const uint32_t *table) {
  rp_vk_impl *impl = p;
  uint64_t t0;
  uint32_t i;
  int err;
  impl->last_ns = 0;
  if ((err = rp_vk__alive(impl)) != 0)
    return err;
  if (!impl->bricked)
    return rp__fail(impl->ctx, RP_ESTATE, "vulkan: upload_bricks without "
                    "a brick pool (set_brick_pool)");
  /* A slot past the pool would be written outside its buffer (in place
   * below, with nothing to catch it). */
  for (i = 0; i < count; i++)
    if (slots[i] >= impl->brick_slots)
      return rp__fail(impl->ctx, RP_EINVAL, "vulkan: brick slot %u of a "
                      "pool of %u", slots[i], impl->brick_slots);
  if (impl->volume.map == NULL || impl->brick_table.map == NULL ||
      rp_vk_hooks.force_staging)
    return upload_bricks_staged(impl, count, slots, voxels, table);
  /* Mapped (coherent) memory, and no kernel runs between operations:
   * written in place, and the time is the host's. */
  t0 = rp__now_ns();
  for (i = 0; i < count; i++)
    memcpy((uint8_t *)impl->volume.map + (size_t)slots[i] * impl->brick_bytes,
           voxels[i], (size_t)impl->brick_bytes);
  if (table != NULL)
    memcpy(impl->brick_table.map, table,
           (size_t)impl->brick_count * sizeof *table);
  impl->last_ns = rp__now_ns() - t0;
  return 0;
}
