/* The Vulkan compute backend: rp_backend_ops for any Vulkan 1.1 device
 * with a compute queue (developed on Mesa's lavapipe).
 *
 * Design, in short:
 * - Four kernels (kernels/NAME.comp: raycast, depth, ert, ao), compiled to
 *   SPIR-V by glslc at build time and embedded. The effects, the counting
 *   variant, the voxel type, the volume layout and whether opacity needs
 *   correcting are specialization constants: a pipeline is made the first
 *   time a combination is used and kept in the variant cache every
 *   backend keeps (../variant_cache.h: a bounded table, the least
 *   recently used replaced), and a
 *   VkPipelineCache file carries what the driver is willing to store
 *   between runs (lavapipe stores only a header; its compiled code goes
 *   to Mesa's own shader cache).
 * - Everything a kernel reads per sample or per block is a uniform texel
 *   buffer read with texelFetch: exact values, no filtering, hand-written
 *   trilinear (why: kernels/common.glsl). When memory allows, each volume
 *   texel holds a 2x2 voxel footprint ("quad" layout, 4x the volume's
 *   bytes) so that a trilinear sample is two fetches, not eight.
 * - The frame parameters are a storage buffer, not a uniform buffer or
 *   push constants, which lavapipe would bake into a recompiled shader
 *   whenever they change (kernels/common.glsl).
 * - Every operation records one command buffer, submits it and waits on a
 *   fence: the ops are synchronous by contract. Timestamps around the
 *   work give the device time. A barrier follows every dispatch, so the
 *   depth buffer a depth pass writes is visible to the raycast that reads
 *   it, in the same submission or a later one.
 * - Outputs live in host-visible memory sized to the largest request so
 *   far and reused, so a steady frame loop allocates nothing.
 * - Ambient occlusion: compute_ao runs kernels/ao.comp over the job's box
 *   in slabs of whole bricks, through buffers that live only during the
 *   call; upload_ao keeps one byte per voxel in an R8 texel buffer that
 *   the raycast's RP_AO variant reads, and nothing AO-sized while no AO
 *   volume is uploaded (its binding then holds the 256-byte stand-in).
 * - Out-of-core (set_brick_pool, upload_bricks): the volume binding holds
 *   a pool of bricks in the plain layout (the quad one would take four
 *   times the memory budget the pool was sized to), and an R32 texel
 *   buffer the slot of each brick; the raycast's RP_BRICKED variant reads
 *   through it and gives the in-core floats (kernels/common.glsl). A
 *   region cast in depth slabs keeps 32 bytes of ray state per pixel in
 *   a device-local buffer from pass to pass; only the last pass writes
 *   the outputs and is read back (kernels/raycast.comp).
 *
 * The files: vk_backend.c sets the device up (the descriptor set and its
 * stand-ins), records and submits command buffers and holds the ops
 * table; vk_pipeline.c makes the kernels' modules and pipelines (the
 * variant cache, prepare); vk_upload.c uploads the volume, the transfer
 * function and the occupancy grid; vk_frame.c runs the depth pass, the
 * ERT pre-pass and the raycast; vk_ao.c ambient occlusion; vk_bricks.c
 * the out-of-core brick pool; vk_device.c is the device layer beneath
 * them all, and vk_internal.h what they share. */

#include <stdio.h>
#include <string.h>

#include "vk_internal.h"

rp_vk_test_hooks rp_vk_hooks;

_Static_assert(sizeof(rp_vk_params) == 320,
               "rp_vk_params must match the Params block in common.glsl");

static const rp_backend_ops vk_ops;

/* ---- set-up -------------------------------------------------------------- */

/* Everything the kernels read per sample or per block is a texel buffer:
 * on lavapipe a texel fetch is a vector gather, a storage buffer load in
 * divergent code a loop over the lanes. The rest are storage buffers. */
static int is_texel(int binding) {
  return (binding >= RP_VK_BIND_VOLUME && binding <= RP_VK_BIND_ALPHA) ||
         binding == RP_VK_BIND_AO || binding == RP_VK_BIND_AO_DIRS ||
         binding == RP_VK_BIND_AO_BRICKS ||
         binding == RP_VK_BIND_BRICK_TABLE;
}

static int make_layout(rp_vk_impl *impl) {
  VkDescriptorSetLayoutBinding b[RP_VK_BIND_COUNT];
  VkDescriptorSetLayoutCreateInfo sinfo = {0};
  VkPipelineLayoutCreateInfo linfo = {0};
  VkDescriptorPoolSize sizes[2] = {
      {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, 0},
      {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 0}};
  VkDescriptorPoolCreateInfo pinfo = {0};
  VkDescriptorSetAllocateInfo ainfo = {0};
  VkResult r;
  int i;
  memset(b, 0, sizeof b);
  for (i = 0; i < RP_VK_BIND_COUNT; i++) {
    b[i].binding = (uint32_t)i;
    b[i].descriptorCount = 1;
    b[i].stageFlags = VK_SHADER_STAGE_COMPUTE_BIT;
    b[i].descriptorType = is_texel(i)
                              ? VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER
                              : VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    sizes[is_texel(i) ? 0 : 1].descriptorCount++;
  }
  sinfo.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO;
  sinfo.bindingCount = RP_VK_BIND_COUNT;
  sinfo.pBindings = b;
  if ((r = vkCreateDescriptorSetLayout(impl->dev, &sinfo, NULL,
                                       &impl->set_layout)) != VK_SUCCESS)
    return rp_vk__fail(impl->ctx, r, "vkCreateDescriptorSetLayout");
  linfo.sType = VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO;
  linfo.setLayoutCount = 1;
  linfo.pSetLayouts = &impl->set_layout;
  if ((r = vkCreatePipelineLayout(impl->dev, &linfo, NULL, &impl->layout)) !=
      VK_SUCCESS)
    return rp_vk__fail(impl->ctx, r, "vkCreatePipelineLayout");
  pinfo.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO;
  pinfo.maxSets = 1;
  pinfo.poolSizeCount = 2;
  pinfo.pPoolSizes = sizes;
  if ((r = vkCreateDescriptorPool(impl->dev, &pinfo, NULL,
                                  &impl->desc_pool)) != VK_SUCCESS)
    return rp_vk__fail(impl->ctx, r, "vkCreateDescriptorPool");
  ainfo.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO;
  ainfo.descriptorPool = impl->desc_pool;
  ainfo.descriptorSetCount = 1;
  ainfo.pSetLayouts = &impl->set_layout;
  if ((r = vkAllocateDescriptorSets(impl->dev, &ainfo, &impl->set)) !=
      VK_SUCCESS)
    return rp_vk__fail(impl->ctx, r, "vkAllocateDescriptorSets");
  return 0;
}

int rp_vk__make_view(rp_vk_impl *impl, VkBuffer buf, VkFormat format,
                     VkBufferView *out) {
  VkBufferViewCreateInfo info = {0};
  VkResult r;
  info.sType = VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO;
  info.buffer = buf;
  info.format = format;
  info.range = VK_WHOLE_SIZE;
  r = vkCreateBufferView(impl->dev, &info, NULL, out);
  if (r != VK_SUCCESS) {
    *out = VK_NULL_HANDLE;
    return rp_vk__fail(impl->ctx, r, "vkCreateBufferView");
  }
  return 0;
}

void rp_vk__free_view(rp_vk_impl *impl, VkBufferView *v) {
  if (*v != VK_NULL_HANDLE)
    vkDestroyBufferView(impl->dev, *v, NULL);
  *v = VK_NULL_HANDLE;
}

static VkBufferView view_or(VkBufferView v, VkBufferView stand_in) {
  return v != VK_NULL_HANDLE ? v : stand_in;
}

/* Points every binding at its buffer, or at the stand-in while the real
 * one does not exist yet. Called after any buffer is (re)made; the set is
 * never in use then, since every operation waits for its work. */
void rp_vk__bind_all(rp_vk_impl *impl) {
  const rp_vk_buffer *bufs[RP_VK_BIND_COUNT] = {
      &impl->params, &impl->volume, &impl->lut,    &impl->grid,
      &impl->alpha,  &impl->depth,  &impl->image,  &impl->tiles,
      &impl->ert,    &impl->ao,     &impl->ao_out, &impl->ao_dirs,
      &impl->ao_bricks, &impl->brick_table, &impl->slab_state};
  VkDescriptorBufferInfo info[RP_VK_BIND_COUNT];
  VkWriteDescriptorSet w[RP_VK_BIND_COUNT];
  VkBufferView views[RP_VK_BIND_COUNT];
  int i;
  memset(w, 0, sizeof w);
  views[RP_VK_BIND_VOLUME] = view_or(impl->volume_view, impl->dummy_u_view);
  views[RP_VK_BIND_LUT] = view_or(impl->lut_view, impl->dummy_f_view);
  views[RP_VK_BIND_GRID] = view_or(impl->grid_view, impl->dummy_u_view);
  views[RP_VK_BIND_ALPHA] = view_or(impl->alpha_view, impl->dummy_u_view);
  /* While AO is off the raycast's AO binding holds the 256-byte stand-in,
   * never an AO-volume-sized buffer. */
  views[RP_VK_BIND_AO] = view_or(impl->ao_view, impl->dummy_u_view);
  views[RP_VK_BIND_AO_DIRS] = view_or(impl->ao_dirs_view, impl->dummy_f_view);
  views[RP_VK_BIND_AO_BRICKS] =
      view_or(impl->ao_bricks_view, impl->dummy_u_view);
  views[RP_VK_BIND_BRICK_TABLE] =
      view_or(impl->brick_table_view, impl->dummy_u_view);
  for (i = 0; i < RP_VK_BIND_COUNT; i++) {
    const rp_vk_buffer *b = bufs[i];
    w[i].sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
    w[i].dstSet = impl->set;
    w[i].dstBinding = (uint32_t)i;
    w[i].descriptorCount = 1;
    if (is_texel(i)) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
      w[i].pTexelBufferView = &views[i];
      continue;
    }
    info[i].buffer = b->buf != VK_NULL_HANDLE ? b->buf : impl->dummy.buf;
    info[i].offset = 0;
    info[i].range = VK_WHOLE_SIZE;
    w[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    w[i].pBufferInfo = &info[i];
  }
  vkUpdateDescriptorSets(impl->dev, RP_VK_BIND_COUNT, w, 0, NULL);
}

static int make_buffers(rp_vk_impl *impl) {
  int err;
  if ((err = rp_vk__buffer(impl, "frame parameters", sizeof(rp_vk_params),
                           VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1,
                           &impl->params)) != 0 ||
      (err = rp_vk__buffer(impl, "unbound-slot filler", 256,
                           VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                               VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                           1, &impl->dummy)) != 0)
    return err;
  memset(impl->dummy.map, 0, 256);
  memset(impl->params.map, 0, sizeof(rp_vk_params));
  if ((err = rp_vk__make_view(impl, impl->dummy.buf, VK_FORMAT_R32_UINT,
                              &impl->dummy_u_view)) != 0 ||
      (err = rp_vk__make_view(impl, impl->dummy.buf,
                              VK_FORMAT_R32G32B32A32_SFLOAT,
                              &impl->dummy_f_view)) != 0)
    return err;
  rp_vk__bind_all(impl);
  return 0;
}

static void vk_destroy(void *p) {
  rp_vk_impl *impl = p;
  uint32_t i;
  if (impl == NULL)
    return;
  if (impl->dev != VK_NULL_HANDLE) {
    vkDeviceWaitIdle(impl->dev);
    if (impl->lost == NULL)
      rp_vk__cache_save(impl);
    for (i = 0; i < RP_VARIANT_CACHE_SIZE; i++)
      if (impl->pipes[i] != VK_NULL_HANDLE)
        vkDestroyPipeline(impl->dev, impl->pipes[i], NULL);
    if (impl->cache != VK_NULL_HANDLE)
      vkDestroyPipelineCache(impl->dev, impl->cache, NULL);
    for (i = 0; i < RP_VK_KERNEL_COUNT; i++)
      if (impl->modules[i] != VK_NULL_HANDLE)
        vkDestroyShaderModule(impl->dev, impl->modules[i], NULL);
    rp_vk__free_view(impl, &impl->volume_view);
    rp_vk__free_view(impl, &impl->lut_view);
    rp_vk__free_view(impl, &impl->grid_view);
    rp_vk__free_view(impl, &impl->alpha_view);
    rp_vk__free_view(impl, &impl->ao_view);
    rp_vk__free_view(impl, &impl->ao_dirs_view);
    rp_vk__free_view(impl, &impl->ao_bricks_view);
    rp_vk__free_view(impl, &impl->brick_table_view);
    rp_vk__free_view(impl, &impl->dummy_u_view);
    rp_vk__free_view(impl, &impl->dummy_f_view);
    rp_vk__buffer_free(impl, &impl->params);
    rp_vk__buffer_free(impl, &impl->volume);
    rp_vk__buffer_free(impl, &impl->lut);
    rp_vk__buffer_free(impl, &impl->grid);
    rp_vk__buffer_free(impl, &impl->alpha);
    rp_vk__buffer_free(impl, &impl->depth);
    rp_vk__buffer_free(impl, &impl->image);
    rp_vk__buffer_free(impl, &impl->tiles);
    rp_vk__buffer_free(impl, &impl->ert);
    rp_vk__buffer_free(impl, &impl->ao);
    rp_vk__buffer_free(impl, &impl->ao_out);
    rp_vk__buffer_free(impl, &impl->ao_dirs);
    rp_vk__buffer_free(impl, &impl->ao_bricks);
    rp_vk__buffer_free(impl, &impl->brick_table);
    rp_vk__buffer_free(impl, &impl->slab_state);
    rp_vk__buffer_free(impl, &impl->dummy);
    if (impl->desc_pool != VK_NULL_HANDLE)
      vkDestroyDescriptorPool(impl->dev, impl->desc_pool, NULL);
    if (impl->layout != VK_NULL_HANDLE)
      vkDestroyPipelineLayout(impl->dev, impl->layout, NULL);
    if (impl->set_layout != VK_NULL_HANDLE)
      vkDestroyDescriptorSetLayout(impl->dev, impl->set_layout, NULL);
  }
  rp_vk__close(impl);
  pthread_mutex_destroy(&impl->lock);
  rp__free(impl->ctx, impl);
}

static int vk_probe(rp_context *ctx, uint32_t *count) {
  VkInstance inst;
  (void)ctx;
  *count = 0;
  /* Probing is how selection skips absent drivers: no message, no
   * error, just zero devices. */
  if (rp_vk__instance(NULL, &inst) != 0)
    return 0;
  if (rp_vk__compute_devices(inst, NULL, 0, count) != 0)
    *count = 0;
  vkDestroyInstance(inst, NULL);
  return 0;
}

static int vk_create(rp_context *ctx, uint32_t index, uint32_t units,
                     const rp_backend_ops **ops, void **out, rp_caps *caps) {
  rp_vk_impl *impl;
  int err;
  /* Vulkan has no sub-devices (no partition_units op below). */
  if (units != 0)
    return rp__fail(ctx, RP_EUNSUPPORTED, "vulkan: cannot partition a "
                    "device (compute_units %u)", (unsigned)units);
  impl = rp__calloc(ctx, 1, sizeof *impl);
  if (impl == NULL)
    return rp__fail(ctx, RP_ENOMEM, "vulkan: out of memory for the device "
                    "(%zu bytes)", sizeof *impl);
  impl->ctx = ctx;
  if (pthread_mutex_init(&impl->lock, NULL) != 0) {
    rp__free(ctx, impl);
    return rp__fail(ctx, RP_ENOMEM, "vulkan: no mutex for device %u",
                    (unsigned)index);
  }
  if ((err = rp_vk__open(impl, index, caps)) != 0 ||
      (err = rp_vk__make_modules(impl)) != 0 ||
      (err = make_layout(impl)) != 0 || (err = make_buffers(impl)) != 0) {
    vk_destroy(impl);
    return err;
  }
  rp_vk__cache_load(impl);
  *ops = &vk_ops;
  *out = impl;
  return 0;
}

/* ---- buffers and submissions --------------------------------------------- */

/* Makes storage buffer `b` at least `size` bytes, keeping it when it
 * already is. Grows to a whole 64 KiB, within the range one descriptor may
 * cover, so that slowly growing requests reallocate rarely. */
int rp_vk__ensure(rp_vk_impl *impl, rp_vk_buffer *b, const char *what,
                  VkDeviceSize size, VkBufferUsageFlags usage, int host) {
  VkDeviceSize range = impl->props.limits.maxStorageBufferRange;
  int err;
  if (b->buf != VK_NULL_HANDLE && b->size >= size)
    return 0;
  if (size > range)
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: the %s needs "
                    "%llu bytes; a kernel can address at most %llu "
                    "(maxStorageBufferRange): render a smaller image or "
                    "region", what, (unsigned long long)size,
                    (unsigned long long)range);
  rp_vk__buffer_free(impl, b);
  size = (size + 65535u) & ~(VkDeviceSize)65535u;
  if (size > range)
    size = range;
  if ((err = rp_vk__buffer(impl, what, size, usage, host, b)) != 0) {
    rp_vk__bind_all(impl); /* the binding must not keep the freed buffer */
    return err;
  }
  rp_vk__bind_all(impl);
  return 0;
}

int rp_vk__alive(rp_vk_impl *impl) {
  if (impl->lost != NULL)
    return rp__fail(impl->ctx, RP_EDEVICE, "vulkan: the device was lost "
                    "during %s; destroy it and create a new one",
                    impl->lost);
  return 0;
}

int rp_vk__begin(rp_vk_impl *impl) {
  VkCommandBufferBeginInfo info = {0};
  VkResult r;
  info.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO;
  info.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  if ((r = vkResetCommandBuffer(impl->cmd, 0)) != VK_SUCCESS)
    return rp_vk__fail(impl->ctx, r, "vkResetCommandBuffer");
  if ((r = vkBeginCommandBuffer(impl->cmd, &info)) != VK_SUCCESS)
    return rp_vk__fail(impl->ctx, r, "vkBeginCommandBuffer");
  if (impl->queries != VK_NULL_HANDLE) {
    vkCmdResetQueryPool(impl->cmd, impl->queries, 0, 2);
    vkCmdWriteTimestamp(impl->cmd, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT,
                        impl->queries, 0);
  }
  return 0;
}

void rp_vk__barrier(rp_vk_impl *impl, VkPipelineStageFlags src,
                    VkAccessFlags src_access, VkPipelineStageFlags dst,
                    VkAccessFlags dst_access) {
  VkMemoryBarrier mb = {0};
  mb.sType = VK_STRUCTURE_TYPE_MEMORY_BARRIER;
  mb.srcAccessMask = src_access;
  mb.dstAccessMask = dst_access;
  vkCmdPipelineBarrier(impl->cmd, src, dst, 0, 1, &mb, 0, NULL, 0, NULL);
}

/* After a dispatch: its writes reach later kernels (this submission or a
 * later one) and the host once the fence has signalled. */
void rp_vk__after_dispatch(rp_vk_impl *impl) {
  rp_vk__barrier(
      impl, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
      VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_HOST_BIT,
      VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT |
          VK_ACCESS_HOST_READ_BIT);
}

/* Ends, submits and waits for the command buffer; `op` names the
 * operation in errors and in a later "device was lost" report. */
int rp_vk__finish(rp_vk_impl *impl, const char *op) {
  VkSubmitInfo submit = {0};
  uint64_t t0, ts[2];
  VkResult r;
  char what[96];
  if (impl->queries != VK_NULL_HANDLE)
    vkCmdWriteTimestamp(impl->cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT,
                        impl->queries, 1);
  if ((r = vkEndCommandBuffer(impl->cmd)) != VK_SUCCESS) {
    snprintf(what, sizeof what, "%s (vkEndCommandBuffer)", op);
    return rp_vk__fail(impl->ctx, r, what);
  }
  submit.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
  submit.commandBufferCount = 1;
  submit.pCommandBuffers = &impl->cmd;
  vkResetFences(impl->dev, 1, &impl->fence);
  t0 = rp__now_ns();
  r = vkQueueSubmit(impl->queue, 1, &submit, impl->fence);
  if (r == VK_SUCCESS) {
    snprintf(what, sizeof what, "%s (vkWaitForFences)", op);
    r = vkWaitForFences(impl->dev, 1, &impl->fence, VK_TRUE, UINT64_MAX);
  } else {
    snprintf(what, sizeof what, "%s (vkQueueSubmit)", op);
  }
  if (r != VK_SUCCESS) {
    if (r == VK_ERROR_DEVICE_LOST) {
      pthread_mutex_lock(&impl->lock);
      impl->lost = op;
      pthread_mutex_unlock(&impl->lock);
    }
    return rp_vk__fail(impl->ctx, r, what);
  }
  impl->last_ns = rp__now_ns() - t0;
  if (impl->queries != VK_NULL_HANDLE &&
      vkGetQueryPoolResults(impl->dev, impl->queries, 0, 2, sizeof ts, ts,
                            sizeof ts[0],
                            VK_QUERY_RESULT_64_BIT |
                                VK_QUERY_RESULT_WAIT_BIT) == VK_SUCCESS)
    impl->last_ns = (uint64_t)((double)((ts[1] - ts[0]) & impl->ts_mask) *
                               impl->props.limits.timestampPeriod);
  return 0;
}

/* Fills `dst` through fill(dst, user): in place when the buffer is mapped,
 * else through a staging buffer and a copy. */
int rp_vk__write_buffer(rp_vk_impl *impl, rp_vk_buffer *dst, const char *what,
                        void (*fill)(void *dst, void *user), void *user) {
  rp_vk_buffer staging;
  VkBufferCopy region = {0, 0, 0};
  int err;
  if (dst->map != NULL && !rp_vk_hooks.force_staging) {
    fill(dst->map, user);
    return 0;
  }
  if ((err = rp_vk__buffer(impl, what, dst->size,
                           VK_BUFFER_USAGE_TRANSFER_SRC_BIT, 1, &staging)) !=
      0)
    return err;
  fill(staging.map, user);
  region.size = dst->size;
  if ((err = rp_vk__begin(impl)) == 0) {
    vkCmdCopyBuffer(impl->cmd, staging.buf, dst->buf, 1, &region);
    rp_vk__barrier(
        impl, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
        VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_READ_BIT);
    err = rp_vk__finish(impl, "upload");
  }
  rp_vk__buffer_free(impl, &staging);
  return err;
}

void rp_vk__fill_copy(void *dst, void *user) {
  const rp_vk_copy_fill *c = user;
  memcpy(dst, c->src, c->bytes);
}

static uint64_t vk_last_time_ns(void *ip) {
  return ((rp_vk_impl *)ip)->last_ns;
}

void rp_vk_get_stats(void *ip, rp_vk_stats *out) {
  rp_vk_impl *impl = ip;
  pthread_mutex_lock(&impl->lock);
  *out = impl->stats;
  pthread_mutex_unlock(&impl->lock);
}

static const rp_backend_ops vk_ops = {
    .destroy = vk_destroy,
    .upload_volume = rp_vk__upload_volume,
    .upload_tf = rp_vk__upload_tf,
    .upload_occupancy = rp_vk__upload_occupancy,
    .depth_pass = rp_vk__depth_pass,
    .ert_prepass = rp_vk__ert_prepass,
    .raycast = rp_vk__raycast,
    .compute_ao = rp_vk__compute_ao,
    .upload_ao = rp_vk__upload_ao,
    .set_brick_pool = rp_vk__set_brick_pool,
    .upload_bricks = rp_vk__upload_bricks,
    .last_time_ns = vk_last_time_ns,
    .prepare = rp_vk__prepare};

const rp_backend_bootstrap rp_vk_bootstrap = {"vulkan", vk_probe, vk_create,
                                              NULL};
