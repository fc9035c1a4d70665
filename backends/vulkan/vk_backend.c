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
 *   the outputs and is read back (kernels/raycast.comp). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "passes.h"
#include "vk_internal.h"

#include "ao.spv.h"
#include "depth.spv.h"
#include "ert.spv.h"
#include "raycast.spv.h"

rp_vk_test_hooks rp_vk_hooks;

static const struct {
  const char *name;
  const uint32_t *words;
  size_t bytes;
} kernels[RP_VK_KERNEL_COUNT] = {
    {"raycast", rp_vk_spv_raycast, sizeof rp_vk_spv_raycast},
    {"depth", rp_vk_spv_depth, sizeof rp_vk_spv_depth},
    {"ert", rp_vk_spv_ert, sizeof rp_vk_spv_ert},
    {"ao", rp_vk_spv_ao, sizeof rp_vk_spv_ao},
};

_Static_assert(sizeof(rp_vk_params) == 320,
               "rp_vk_params must match the Params block in common.glsl");

static const rp_backend_ops vk_ops;

/* Texel formats of the volume per rp_voxel_type: one voxel per texel
 * (plain), or the 2x2 footprint of the quad layout. */
static const VkFormat plain_fmt[4] = {VK_FORMAT_UNDEFINED, VK_FORMAT_R8_UINT,
                                      VK_FORMAT_R16_UINT, VK_FORMAT_R32_UINT};
static const VkFormat quad_fmt[4] = {
    VK_FORMAT_UNDEFINED, VK_FORMAT_R8G8B8A8_UINT, VK_FORMAT_R16G16B16A16_UINT,
    VK_FORMAT_R32G32B32A32_UINT};

static uint32_t div_up(uint32_t a, uint32_t b) {
  return a / b + (a % b != 0);
}

/* ---- set-up -------------------------------------------------------------- */

static int make_modules(rp_vk_impl *impl) {
  /* What the corrupt_kernel hook substitutes: a module whose magic is
   * byte-swapped, as a file written with the wrong endianness would be. */
  static const uint32_t broken[5] = {0x03022307u, 0x00000301u, 0, 1, 0};
  int k, err;
  for (k = 0; k < RP_VK_KERNEL_COUNT; k++) {
    VkShaderModuleCreateInfo info = {0};
    const uint32_t *words = kernels[k].words;
    size_t bytes = kernels[k].bytes;
    VkResult r;
    if (rp_vk_hooks.corrupt_kernel == k + 1) {
      words = broken;
      bytes = sizeof broken;
    }
    if ((err = rp_vk__check_spirv(impl->ctx, kernels[k].name, words,
                                  bytes)) != 0)
      return err;
    info.sType = VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO;
    info.codeSize = bytes;
    info.pCode = words;
    r = vkCreateShaderModule(impl->dev, &info, NULL, &impl->modules[k]);
    if (r != VK_SUCCESS) {
      impl->modules[k] = VK_NULL_HANDLE;
      if (r == VK_ERROR_OUT_OF_HOST_MEMORY ||
          r == VK_ERROR_OUT_OF_DEVICE_MEMORY)
        return rp_vk__fail(impl->ctx, r, "vkCreateShaderModule");
      return rp__fail(impl->ctx, RP_EBUILD, "vulkan: kernel '%s': "
                      "vkCreateShaderModule: %s", kernels[k].name,
                      rp_vk__result_name(r));
    }
  }
  return 0;
}

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

static int make_view(rp_vk_impl *impl, VkBuffer buf, VkFormat format,
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

static void free_view(rp_vk_impl *impl, VkBufferView *v) {
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
static void bind_all(rp_vk_impl *impl) {
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
  if ((err = make_view(impl, impl->dummy.buf, VK_FORMAT_R32_UINT,
                       &impl->dummy_u_view)) != 0 ||
      (err = make_view(impl, impl->dummy.buf, VK_FORMAT_R32G32B32A32_SFLOAT,
                       &impl->dummy_f_view)) != 0)
    return err;
  bind_all(impl);
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
    free_view(impl, &impl->volume_view);
    free_view(impl, &impl->lut_view);
    free_view(impl, &impl->grid_view);
    free_view(impl, &impl->alpha_view);
    free_view(impl, &impl->ao_view);
    free_view(impl, &impl->ao_dirs_view);
    free_view(impl, &impl->ao_bricks_view);
    free_view(impl, &impl->brick_table_view);
    free_view(impl, &impl->dummy_u_view);
    free_view(impl, &impl->dummy_f_view);
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
      (err = make_modules(impl)) != 0 || (err = make_layout(impl)) != 0 ||
      (err = make_buffers(impl)) != 0) {
    vk_destroy(impl);
    return err;
  }
  rp_vk__cache_load(impl);
  *ops = &vk_ops;
  *out = impl;
  return 0;
}

/* ---- pipelines ----------------------------------------------------------- */

static uint32_t pipeline_key(rp_vk_kernel k, const rp_frame_params *p,
                             int counting, rp_voxel_type type, int quad) {
  uint32_t key = (uint32_t)k << RP_VK_KEY_KERNEL_SHIFT;
  uint32_t effects = p->effects;
  if (k == RP_VK_RAYCAST) {
    key |= effects & (RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP |
                      RP_EFFECT_AO | RP_EFFECT_PREINT);
    key |= p->step != p->ref_step ? RP_VK_KEY_CORRECT : 0;
    key |= counting ? RP_VK_KEY_COUNT : 0;
    key |= quad ? RP_VK_KEY_QUAD : 0;
    key |= (uint32_t)type << RP_VK_KEY_TYPE_SHIFT;
    key |= p->brick_shift != 0 ? RP_VK_KEY_BRICKED : 0;
  } else if (k == RP_VK_DEPTH) {
    key |= effects & RP_EFFECT_SKIP;
  }
  return key;
}

/* compute_ao's pipeline: its step against the TF's, the layout and the
 * voxel type. */
static uint32_t ao_pipeline_key(int correct, int quad, rp_voxel_type type) {
  return ((uint32_t)RP_VK_AO << RP_VK_KEY_KERNEL_SHIFT) |
         (correct ? RP_VK_KEY_CORRECT : 0u) | (quad ? RP_VK_KEY_QUAD : 0u) |
         ((uint32_t)type << RP_VK_KEY_TYPE_SHIFT);
}

/* The owner's lookup: the table's pipeline for `key`, stamped as used,
 * or VK_NULL_HANDLE. */
static VkPipeline lookup(rp_vk_impl *impl, uint32_t key) {
  VkPipeline pipe = VK_NULL_HANDLE;
  int i;
  pthread_mutex_lock(&impl->lock);
  if ((i = rp__variant_use(&impl->variants, key)) >= 0)
    pipe = impl->pipes[i];
  pthread_mutex_unlock(&impl->lock);
  return pipe;
}

/* Makes the pipeline for `key`, not in the table; failures go to `ctx`,
 * the calling thread's. Runs without the lock, so two threads may build
 * at once: the spec (vkCreatePipelineCache) has a cache's use by
 * vkCreate*Pipelines "internally synchronized, and the same pipeline
 * cache object can be used in multiple threads simultaneously" unless
 * it was created with VK_PIPELINE_CACHE_CREATE_EXTERNALLY_SYNCHRONIZED_BIT,
 * which rp_vk__cache_load does not set. */
static int build_pipeline(rp_vk_impl *impl, rp_context *ctx, uint32_t key,
                          VkPipeline *out) {
  rp_vk_kernel k = (rp_vk_kernel)(key >> RP_VK_KEY_KERNEL_SHIFT);
  uint32_t values[RP_VK_SPEC_TOTAL], i;
  VkSpecializationMapEntry map[RP_VK_SPEC_TOTAL];
  VkSpecializationInfo spec;
  VkComputePipelineCreateInfo info = {0};
  VkPipelineCreationFeedback fb = {0};
  VkPipelineCreationFeedbackCreateInfo fbinfo = {0};
  VkResult r;
  uint64_t t0, ns;

  /* Booleans are VkBool32, the voxel type a uint: all four bytes. */
  values[RP_VK_SPEC_SHADING] = (key & RP_EFFECT_SHADING) != 0;
  values[RP_VK_SPEC_ERT] = (key & RP_EFFECT_ERT) != 0;
  values[RP_VK_SPEC_SKIP] = (key & RP_EFFECT_SKIP) != 0;
  values[RP_VK_SPEC_COUNT] = (key & RP_VK_KEY_COUNT) != 0;
  values[RP_VK_SPEC_AO] = (key & RP_EFFECT_AO) != 0;
  values[RP_VK_SPEC_VOXEL] = (key >> RP_VK_KEY_TYPE_SHIFT) & 3u;
  if (values[RP_VK_SPEC_VOXEL] == 0)
    values[RP_VK_SPEC_VOXEL] = RP_U8;
  values[RP_VK_SPEC_QUAD] = (key & RP_VK_KEY_QUAD) != 0;
  values[RP_VK_SPEC_CORRECT] = (key & RP_VK_KEY_CORRECT) != 0;
  values[RP_VK_SPEC_BRICKED] = (key & RP_VK_KEY_BRICKED) != 0;
  values[RP_VK_SPEC_PREINT] = (key & RP_EFFECT_PREINT) != 0;
  for (i = 0; i < RP_VK_SPEC_TOTAL; i++) {
    map[i].constantID = i;
    map[i].offset = i * (uint32_t)sizeof(uint32_t);
    map[i].size = sizeof(uint32_t);
  }
  spec.mapEntryCount = RP_VK_SPEC_TOTAL;
  spec.pMapEntries = map;
  spec.dataSize = sizeof values;
  spec.pData = values;
  info.sType = VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO;
  info.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
  info.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  info.stage.module = impl->modules[k];
  info.stage.pName = "main";
  info.stage.pSpecializationInfo = &spec;
  info.layout = impl->layout;
  if (impl->feedback) {
    fbinfo.sType = VK_STRUCTURE_TYPE_PIPELINE_CREATION_FEEDBACK_CREATE_INFO;
    fbinfo.pPipelineCreationFeedback = &fb;
    info.pNext = &fbinfo;
  }
  t0 = rp__now_ns();
  r = vkCreateComputePipelines(impl->dev, impl->cache, 1, &info, NULL, out);
  ns = rp__now_ns() - t0;
  pthread_mutex_lock(&impl->lock);
  impl->stats.pipeline_create_ns += ns;
  if (r == VK_SUCCESS) {
    impl->stats.pipelines_created++;
    if ((fb.flags & VK_PIPELINE_CREATION_FEEDBACK_VALID_BIT) &&
        (fb.flags &
         VK_PIPELINE_CREATION_FEEDBACK_APPLICATION_PIPELINE_CACHE_HIT_BIT))
      impl->stats.pipeline_cache_hits++;
  }
  pthread_mutex_unlock(&impl->lock);
  if (r != VK_SUCCESS) {
    *out = VK_NULL_HANDLE;
    if (r == VK_ERROR_OUT_OF_HOST_MEMORY ||
        r == VK_ERROR_OUT_OF_DEVICE_MEMORY)
      return rp_vk__fail(ctx, r, "vkCreateComputePipelines");
    return rp__fail(ctx, RP_EBUILD, "vulkan: kernel '%s' (variant "
                    "0x%x): vkCreateComputePipelines: %s", kernels[k].name,
                    (unsigned)key, rp_vk__result_name(r));
  }
  return 0;
}

/* Adds `pipe` for `key` to the variant cache and sets *out to the
 * pipeline to use: the table's own when it has one already (the other
 * thread built it meanwhile; `pipe` is destroyed). The impl's own thread
 * (`owner`) replaces the least recently used entry when none is free;
 * prepare keeps a pipeline only in a free entry, and otherwise destroys
 * it and leaves the frame to build it (*out VK_NULL_HANDLE). An evicted
 * pipeline is destroyed at once, which is safe because only the owner
 * evicts and no command buffer that binds it can be pending then: every
 * op waits for its fence before it returns, a lost device runs no op
 * again, and an op looks up its pipelines before it records anything,
 * the one it looked up first being the most recently used entry, which
 * is never the one replaced. The caller holds nothing. */
static void keep_pipeline(rp_vk_impl *impl, uint32_t key, VkPipeline pipe,
                          int owner, VkPipeline *out) {
  VkPipeline old = VK_NULL_HANDLE;
  rp_variant_fate fate;
  int i;
  pthread_mutex_lock(&impl->lock);
  fate = rp__variant_insert(&impl->variants, key, owner, &i);
  if (fate == RP_VARIANT_REPLACED)
    old = impl->pipes[i];
  if (fate == RP_VARIANT_KEPT || fate == RP_VARIANT_REPLACED) {
    impl->pipes[i] = pipe;
    pipe = VK_NULL_HANDLE;
  }
  *out = fate != RP_VARIANT_DROPPED ? impl->pipes[i] : VK_NULL_HANDLE;
  pthread_mutex_unlock(&impl->lock);
  if (old != VK_NULL_HANDLE)
    vkDestroyPipeline(impl->dev, old, NULL);
  if (pipe != VK_NULL_HANDLE)
    vkDestroyPipeline(impl->dev, pipe, NULL);
}

/* The pipeline for `key`, made on first use: the ops' path, on the
 * thread that owns the impl. */
static int get_pipeline(rp_vk_impl *impl, uint32_t key, VkPipeline *out) {
  VkPipeline pipe;
  int err;
  if ((*out = lookup(impl, key)) != VK_NULL_HANDLE)
    return 0;
  if ((err = build_pipeline(impl, impl->ctx, key, &pipe)) != 0)
    return err;
  keep_pipeline(impl, key, pipe, 1, out);
  return 0;
}

/* The pipelines a frame with `effects` binds, built ahead on the calling
 * thread (rp_backend_ops says what may run meanwhile): the depth pass,
 * keyed by RP_EFFECT_SKIP (the front end runs one for every new camera,
 * skipping or not), and the raycast with and without the opacity
 * correction (the frame's step decides), for the layout, voxel type and
 * brick pool the device holds now; with AO, compute_ao's both ways too
 * (the runtime's AO run waits for them rather than build on a frame).
 * Not the fetch-counting raycast (tests and cost models ask for it) nor
 * the ERT pre-pass (a call of its own). The volume's fields are read under
 * the lock; a volume uploaded while this builds makes the keys stale,
 * which costs the frame a build of its own, never a wrong pipeline: the
 * key says what a pipeline was specialised for. */
static int vk_prepare(void *ip, rp_context *ctx, uint32_t effects) {
  rp_vk_impl *impl = ip;
  rp_frame_params p;
  uint32_t keys[5];
  rp_voxel_type type;
  const char *lost;
  VkPipeline pipe;
  int quad, bricked, n = 0, i, have, err;
  pthread_mutex_lock(&impl->lock);
  type = impl->voxel_type;
  quad = impl->quad;
  bricked = impl->bricked;
  lost = impl->lost;
  pthread_mutex_unlock(&impl->lock);
  if (lost != NULL)
    return rp__fail(ctx, RP_EDEVICE, "vulkan: the device was lost during "
                    "%s; destroy it and create a new one", lost);
  if (type == 0)
    return rp__fail(ctx, RP_ESTATE, "vulkan: prepare before a volume was "
                    "uploaded (the raycast is specialised for its voxel "
                    "type)");
  /* The keys as the ops make them, from the frame fields they read. */
  memset(&p, 0, sizeof p);
  p.effects = effects;
  p.brick_shift = bricked ? 1 : 0; /* only whether it is 0 counts */
  keys[n++] = pipeline_key(RP_VK_DEPTH, &p, 0, 0, 0);
  /* A brick pool holds no AO volume (set_brick_pool drops it, upload_ao
   * refuses): no frame on it can use the AO raycast. */
  for (i = 0; i < 2 && !(bricked && (effects & RP_EFFECT_AO)); i++) {
    p.step = 1.0f;
    p.ref_step = i == 0 ? 1.0f : 2.0f; /* RP_VK_KEY_CORRECT off, on */
    keys[n++] = pipeline_key(RP_VK_RAYCAST, &p, 0, type, quad);
  }
  /* compute_ao's, as it keys it, with its step against the TF's either
   * way (not on a brick pool, where AO is not computed). */
  for (i = 0; i < 2 && !bricked && (effects & RP_EFFECT_AO); i++)
    keys[n++] = ao_pipeline_key(i, quad, type);
  for (i = 0; i < n; i++) {
    pthread_mutex_lock(&impl->lock);
    have = rp__variant_find(&impl->variants, keys[i]) >= 0;
    pthread_mutex_unlock(&impl->lock);
    if (have)
      continue;
    if ((err = build_pipeline(impl, ctx, keys[i], &pipe)) != 0)
      return err;
    /* Kept, there already, or dropped for want of room: 0 either way. */
    keep_pipeline(impl, keys[i], pipe, 0, &pipe);
  }
  return 0;
}

/* ---- buffers and uploads ------------------------------------------------- */

/* Makes storage buffer `b` at least `size` bytes, keeping it when it
 * already is. Grows to a whole 64 KiB, within the range one descriptor may
 * cover, so that slowly growing requests reallocate rarely. */
static int ensure(rp_vk_impl *impl, rp_vk_buffer *b, const char *what,
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
    bind_all(impl); /* the binding must not keep the freed buffer */
    return err;
  }
  bind_all(impl);
  return 0;
}

static int alive(rp_vk_impl *impl) {
  if (impl->lost != NULL)
    return rp__fail(impl->ctx, RP_EDEVICE, "vulkan: the device was lost "
                    "during %s; destroy it and create a new one",
                    impl->lost);
  return 0;
}

static int begin(rp_vk_impl *impl) {
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

static void barrier(rp_vk_impl *impl, VkPipelineStageFlags src,
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
static void after_dispatch(rp_vk_impl *impl) {
  barrier(impl, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
          VK_ACCESS_SHADER_WRITE_BIT,
          VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_HOST_BIT,
          VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT |
              VK_ACCESS_HOST_READ_BIT);
}

/* Ends, submits and waits for the command buffer; `op` names the
 * operation in errors and in a later "device was lost" report. */
static int finish(rp_vk_impl *impl, const char *op) {
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
static int write_buffer(rp_vk_impl *impl, rp_vk_buffer *dst,
                        const char *what,
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
  if ((err = begin(impl)) == 0) {
    vkCmdCopyBuffer(impl->cmd, staging.buf, dst->buf, 1, &region);
    barrier(impl, VK_PIPELINE_STAGE_TRANSFER_BIT,
            VK_ACCESS_TRANSFER_WRITE_BIT,
            VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_READ_BIT);
    err = finish(impl, "upload");
  }
  rp_vk__buffer_free(impl, &staging);
  return err;
}

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

static int format_ok(rp_vk_impl *impl, VkFormat f) {
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

/* Releases the AO volume: no AO memory while AO is off. */
static void drop_ao(rp_vk_impl *impl) {
  if (impl->ao.buf == VK_NULL_HANDLE && impl->ao_view == VK_NULL_HANDLE)
    return;
  free_view(impl, &impl->ao_view);
  rp_vk__buffer_free(impl, &impl->ao);
  impl->stats.ao_bytes = 0;
  bind_all(impl);
}

/* What the volume is, as prepare reads it: under the lock. */
static void set_volume_state(rp_vk_impl *impl, rp_voxel_type type,
                             int quad, int bricked) {
  pthread_mutex_lock(&impl->lock);
  impl->voxel_type = type;
  impl->quad = quad;
  impl->bricked = bricked;
  impl->stats.quad_layout = quad;
  pthread_mutex_unlock(&impl->lock);
}

/* Releases the volume, whole or a brick pool, and its table. The caller
 * rebinds. */
static void drop_volume(rp_vk_impl *impl) {
  free_view(impl, &impl->volume_view);
  rp_vk__buffer_free(impl, &impl->volume);
  free_view(impl, &impl->brick_table_view);
  rp_vk__buffer_free(impl, &impl->brick_table);
  set_volume_state(impl, 0, impl->quad, 0);
  impl->brick_slots = impl->brick_count = 0;
  impl->brick_bytes = 0;
  impl->depth_ok = 0;
}

static int vk_upload_volume(void *p, const rp_volume *vol) {
  rp_vk_impl *impl = p;
  rp_context *ctx = impl->ctx;
  uint64_t n = vol->voxel_count, es = rp__voxel_size(vol->type);
  uint32_t limit = impl->props.limits.maxTexelBufferElements;
  volume_fill job;
  int quad, err;
  if ((err = alive(impl)) != 0)
    return err;
  /* texelFetch takes an int, and a view holds at most the limit. */
  if (n > limit || n > INT32_MAX)
    return rp__fail(ctx, RP_EUNSUPPORTED, "vulkan: volume %ux%ux%u has "
                    "%llu voxels; this device reads at most %u per buffer "
                    "(maxTexelBufferElements)", vol->dims[0], vol->dims[1],
                    vol->dims[2], (unsigned long long)n, (unsigned)limit);
  if (!format_ok(impl, plain_fmt[vol->type]))
    return rp__fail(ctx, RP_EUNSUPPORTED, "vulkan: device cannot read %s "
                    "voxels from a texel buffer",
                    rp_voxel_type_name(vol->type));
  quad = !rp_vk_hooks.force_plain && format_ok(impl, quad_fmt[vol->type]) &&
         4 * es * n <= impl->max_alloc && 4 * es * n <= quad_budget(impl);

  drop_volume(impl);
  /* An AO volume is one byte per voxel of the volume it was uploaded
   * for: it cannot survive a change of shape (whether it still fits the
   * new voxels is the front end's to judge). */
  if (memcmp(impl->dims, vol->dims, sizeof impl->dims) != 0)
    drop_ao(impl);
  memset(impl->dims, 0, sizeof impl->dims);
  err = rp_vk__buffer(impl, "volume", (quad ? 4 : 1) * es * n,
                      VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                          VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                      0, &impl->volume);
  if (err == 0) {
    job.vol = vol;
    job.quad = quad;
    err = write_buffer(impl, &impl->volume, "volume staging", fill_volume,
                       &job);
  }
  if (err == 0)
    err = make_view(impl, impl->volume.buf,
                    quad ? quad_fmt[vol->type] : plain_fmt[vol->type],
                    &impl->volume_view);
  if (err != 0) {
    drop_volume(impl);
    drop_ao(impl);
    bind_all(impl);
    return err;
  }
  bind_all(impl);
  memcpy(impl->dims, vol->dims, sizeof impl->dims);
  set_volume_state(impl, vol->type, quad, 0);
  return 0;
}

typedef struct copy_fill {
  const void *src;
  size_t bytes;
} copy_fill;

static void fill_copy(void *dst, void *user) {
  const copy_fill *c = user;
  memcpy(dst, c->src, c->bytes);
}

static int vk_upload_tf(void *p, const float *lut, uint32_t lut_size) {
  rp_vk_impl *impl = p;
  copy_fill c;
  float *all;
  int err;
  if ((err = alive(impl)) != 0)
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
    free_view(impl, &impl->lut_view);
    rp_vk__buffer_free(impl, &impl->lut);
    if ((err = rp_vk__buffer(impl, "transfer function", c.bytes,
                             VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                 VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                             0, &impl->lut)) != 0 ||
        (err = make_view(impl, impl->lut.buf, VK_FORMAT_R32G32B32A32_SFLOAT,
                         &impl->lut_view)) != 0) {
      free_view(impl, &impl->lut_view);
      rp_vk__buffer_free(impl, &impl->lut);
      bind_all(impl);
      free(all);
      return err;
    }
    bind_all(impl);
  }
  impl->have_lut = 0;
  err = write_buffer(impl, &impl->lut, "transfer function staging",
                     fill_copy, &c);
  free(all);
  if (err != 0)
    return err;
  impl->have_lut = 1;
  return 0;
}

static int vk_upload_occupancy(void *p, const uint8_t *grid,
                               const uint8_t *alpha_hist,
                               const uint32_t blocks[3]) {
  rp_vk_impl *impl = p;
  size_t nb = (size_t)blocks[0] * blocks[1] * blocks[2];
  const VkBufferUsageFlags usage = VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                   VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  copy_fill c;
  int err;
  if ((err = alive(impl)) != 0)
    return err;
  if (nb > impl->props.limits.maxTexelBufferElements)
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: %zu blocks exceed "
                    "the device's %u texels per buffer", nb,
                    (unsigned)impl->props.limits.maxTexelBufferElements);
  impl->occupancy_gen++;
  impl->depth_ok = 0;
  if (impl->grid.size != nb) {
    free_view(impl, &impl->grid_view);
    free_view(impl, &impl->alpha_view);
    rp_vk__buffer_free(impl, &impl->grid);
    rp_vk__buffer_free(impl, &impl->alpha);
    /* One byte per block; H-alpha's 16 bytes per block as one RGBA32
     * texel. */
    if ((err = rp_vk__buffer(impl, "occupancy grid", nb, usage, 0,
                             &impl->grid)) != 0 ||
        (err = rp_vk__buffer(impl, "opacity histograms",
                             nb * RP_OPACITY_BINS, usage, 0,
                             &impl->alpha)) != 0 ||
        (err = make_view(impl, impl->grid.buf, VK_FORMAT_R8_UINT,
                         &impl->grid_view)) != 0 ||
        (err = make_view(impl, impl->alpha.buf, VK_FORMAT_R32G32B32A32_UINT,
                         &impl->alpha_view)) != 0) {
      free_view(impl, &impl->grid_view);
      free_view(impl, &impl->alpha_view);
      rp_vk__buffer_free(impl, &impl->grid);
      rp_vk__buffer_free(impl, &impl->alpha);
      bind_all(impl);
      return err;
    }
    bind_all(impl);
  }
  c.src = grid;
  c.bytes = nb;
  if ((err = write_buffer(impl, &impl->grid, "occupancy staging", fill_copy,
                          &c)) != 0)
    return err;
  c.src = alpha_hist;
  c.bytes = nb * RP_OPACITY_BINS;
  return write_buffer(impl, &impl->alpha, "histogram staging", fill_copy,
                      &c);
}

/* ---- frames -------------------------------------------------------------- */

static void set_params(rp_vk_impl *impl, const rp_frame_params *p) {
  rp_vk_params *u = impl->params.map;
  double range = (double)p->value_max - (double)p->value_min;
  double coarse[RP_OPACITY_BINS];
  uint32_t gw, gh;
  int a, k;
  memset(u, 0, sizeof *u);
  for (a = 0; a < 3; a++) {
    u->eye[a] = p->eye[a];
    u->fwd[a] = p->f[a];
    u->right[a] = p->r[a];
    u->up[a] = p->u[a];
    u->dims[a] = p->dims[a];
    u->inv_sp[a] = p->inv_spacing[a];
    u->idims[a] = p->idims[a];
    u->blocks[a] = p->blocks[a];
    /* Block faces sit at 16 b - 0.5: exact in float. */
    u->box_lo[a] = (float)RP_BLOCK_SIZE * (float)p->occupied_lo[a] - 0.5f;
    u->box_hi[a] = (float)RP_BLOCK_SIZE * (float)p->occupied_end[a] - 0.5f;
  }
  u->eye[3] = p->ortho ? 1.0f : 0.0f;
  u->fwd[3] = p->half_w;
  u->right[3] = p->half_h;
  u->up[3] = p->step;
  u->dims[3] = p->min_spacing;
  u->inv_sp[3] = p->ert_threshold;
  u->vrange[0] = p->value_min;
  u->vrange[1] = range > 0.0 ? (float)(1.0 / range) : 0.0f;
  u->vrange[2] = range > 0.0 ? (float)range : 0.0f;
  u->vrange[3] = (float)((double)p->step / (double)p->ref_step);
  /* The pre-pass's 16 bin opacities depend on the frame only, so they are
   * corrected here once, in double as the reference does. */
  rp__ert_corrected(NULL, p->ref_step, coarse);
  for (k = 0; k < RP_OPACITY_BINS; k++)
    u->ert_a[k] = (float)coarse[k];
  rp__ert_grid(p->width, p->height, &gw, &gh);
  u->idims[3] = p->lut_size;
  u->blocks[3] = p->width;
  u->misc[0] = p->height;
  u->misc[1] = gw;
  u->misc[2] = gh;
  u->seed[0] = p->ert_seed;
  u->seed[1] = p->frame;
  u->seed[2] = p->jitter_seed;
  u->seed[3] = p->jitter;
  for (a = 0; a < 3; a++)
    u->brick[a] = p->brick_grid[a];
  u->brick[3] = p->brick_shift;
  u->slab[0] = p->slab_flags;
  memcpy(&u->slab[1], &p->slab_cut, sizeof(float));
}

/* The region a dispatch covers. Each operation records its dispatches
 * with one parameter block, so a command buffer holding a depth pass and
 * a raycast of a region sets the rect once, for the raycast, and the depth
 * pass reads the whole image's size from blocks.w / misc.x instead. */
static void set_rect(rp_vk_impl *impl, uint32_t x0, uint32_t y0, uint32_t w,
                     uint32_t h) {
  rp_vk_params *u = impl->params.map;
  u->rect[0] = x0;
  u->rect[1] = y0;
  u->rect[2] = w;
  u->rect[3] = h;
}

static void bind(rp_vk_impl *impl, VkPipeline pipe) {
  vkCmdBindPipeline(impl->cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe);
  vkCmdBindDescriptorSets(impl->cmd, VK_PIPELINE_BIND_POINT_COMPUTE,
                          impl->layout, 0, 1, &impl->set, 0, NULL);
}

/* Records the depth pass over the whole scaled image. */
static void record_depth(rp_vk_impl *impl, VkPipeline pipe,
                         const rp_frame_params *p) {
  bind(impl, pipe);
  vkCmdDispatch(impl->cmd, div_up(p->width, RP_TILE_SIZE),
                div_up(p->height, RP_TILE_SIZE), 1);
  after_dispatch(impl);
}

/* Whether the depth buffer holds the result `p` needs: every field but
 * the ERT stream, the threshold, the step and the non-skip effects. */
static int depth_current(const rp_vk_impl *impl, const rp_frame_params *p) {
  rp_frame_params a = impl->depth_frame, b = *p;
  if (!impl->depth_ok || impl->depth_gen != impl->occupancy_gen)
    return 0;
  a.ert_seed = b.ert_seed = 0;
  a.frame = b.frame = 0;
  a.jitter = b.jitter = 0;
  a.jitter_seed = b.jitter_seed = 0;
  a.ert_threshold = b.ert_threshold = 0.0f;
  a.step = b.step = 0.0f;
  a.ref_step = b.ref_step = 0.0f;
  a.lut_size = b.lut_size = 0;
  a.value_min = b.value_min = 0.0f;
  a.value_max = b.value_max = 0.0f;
  /* The depth pass reads the block grid, never the volume. */
  a.brick_shift = b.brick_shift = 0;
  memset(a.brick_grid, 0, sizeof a.brick_grid);
  memset(b.brick_grid, 0, sizeof b.brick_grid);
  /* Every depth slab of a region reuses the frame's depth pass. */
  a.slab_cut = b.slab_cut = 0.0f;
  a.slab_flags = b.slab_flags = 0;
  a.effects &= RP_EFFECT_SKIP;
  b.effects &= RP_EFFECT_SKIP;
  return memcmp(&a, &b, sizeof a) == 0;
}

static int ensure_depth(rp_vk_impl *impl, const rp_frame_params *p) {
  VkDeviceSize bytes = (VkDeviceSize)p->width * p->height * 2 * sizeof(float);
  if (impl->depth.buf == VK_NULL_HANDLE || impl->depth.size < bytes)
    impl->depth_ok = 0;
  return ensure(impl, &impl->depth, "depth buffer", bytes,
                VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1);
}

/* Whether a grid of gx x gy workgroups can be dispatched at once. */
static int check_groups(rp_vk_impl *impl, const char *what, uint32_t gx,
                        uint32_t gy) {
  const uint32_t *max = impl->props.limits.maxComputeWorkGroupCount;
  if (gx > max[0] || gy > max[1])
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: the %s needs "
                    "%ux%u workgroups; the device dispatches at most %ux%u",
                    what, gx, gy, max[0], max[1]);
  return 0;
}

static int vk_depth_pass(void *ip, const rp_frame_params *p,
                         float *front_back) {
  rp_vk_impl *impl = ip;
  VkPipeline pipe;
  int err;
  if ((err = alive(impl)) != 0 ||
      (err = check_groups(impl, "depth pass",
                          div_up(p->width, RP_TILE_SIZE),
                          div_up(p->height, RP_TILE_SIZE))) != 0 ||
      (err = ensure_depth(impl, p)) != 0 ||
      (err = get_pipeline(impl,
                          pipeline_key(RP_VK_DEPTH, p, 0, 0, 0),
                          &pipe)) != 0)
    return err;
  set_params(impl, p);
  impl->depth_ok = 0;
  if ((err = begin(impl)) != 0)
    return err;
  record_depth(impl, pipe, p);
  if ((err = finish(impl, "depth pass")) != 0)
    return err;
  impl->depth_frame = *p;
  impl->depth_gen = impl->occupancy_gen;
  impl->depth_ok = 1;
  if (front_back != NULL)
    memcpy(front_back, impl->depth.map,
           (size_t)p->width * p->height * 2 * sizeof(float));
  return 0;
}

static int vk_ert_prepass(void *ip, const rp_frame_params *p, float *d_ert) {
  rp_vk_impl *impl = ip;
  VkPipeline pipe;
  uint32_t gw, gh;
  int err;
  rp__ert_grid(p->width, p->height, &gw, &gh);
  if ((err = alive(impl)) != 0 ||
      (err = check_groups(impl, "ERT pre-pass", div_up(gw, 8),
                          div_up(gh, 8))) != 0 ||
      (err = ensure(impl, &impl->ert, "ERT result",
                    (VkDeviceSize)gw * gh * sizeof(float),
                    VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1)) != 0 ||
      (err = get_pipeline(impl, pipeline_key(RP_VK_ERT, p, 0, 0, 0),
                          &pipe)) != 0)
    return err;
  set_params(impl, p);
  if ((err = begin(impl)) != 0)
    return err;
  set_rect(impl, 0, 0, gw, gh);
  bind(impl, pipe);
  vkCmdDispatch(impl->cmd, div_up(gw, 8), div_up(gh, 8), 1);
  after_dispatch(impl);
  if ((err = finish(impl, "ERT pre-pass")) != 0)
    return err;
  memcpy(d_ert, impl->ert.map, (size_t)gw * gh * sizeof(float));
  return 0;
}

static int vk_raycast(void *ip, const rp_frame_params *p, const rp_region *r,
                      uint8_t *rgba, rp_tile_stats *tiles,
                      uint64_t *fetches) {
  rp_vk_impl *impl = ip;
  uint32_t rw = r->x1 - r->x0, rh = r->y1 - r->y0;
  uint32_t ntx = div_up(rw, RP_TILE_SIZE), nty = div_up(rh, RP_TILE_SIZE);
  uint32_t tiles_x, tx, ty, y;
  int skip = (p->effects & RP_EFFECT_SKIP) != 0, redo_depth, err;
  /* Out-of-core depth slabs: a pass of several keeps its rays' state on
   * the device, and only the last writes (and reads back) the outputs. */
  int slabs = impl->bricked &&
              p->slab_flags != (RP_SLAB_FIRST | RP_SLAB_LAST);
  int last_slab = !impl->bricked || (p->slab_flags & RP_SLAB_LAST) != 0;
  VkPipeline cast = VK_NULL_HANDLE, depth = VK_NULL_HANDLE;
  const uint32_t *tile_words;
  const uint8_t *px;
  if ((err = alive(impl)) != 0)
    return err;
  if ((p->brick_shift != 0) != impl->bricked)
    return rp__fail(impl->ctx, RP_ESTATE, "vulkan: raycast %s a brick "
                    "table, but the device holds %s",
                    p->brick_shift != 0 ? "through" : "without",
                    impl->bricked ? "a brick pool" : "the whole volume");
  if ((p->effects & RP_EFFECT_PREINT) && impl->bricked)
    return rp__fail(impl->ctx, RP_EINVAL, "vulkan: RP_EFFECT_PREINT with an "
                    "out-of-core volume (a brick pool) is not supported: "
                    "a depth slab cannot read the value before its first "
                    "sample");
  if ((p->effects & RP_EFFECT_AO) && impl->ao.buf == VK_NULL_HANDLE)
    return rp__fail(impl->ctx, RP_ESTATE, "vulkan: a raycast with "
                    "RP_EFFECT_AO needs an AO volume, and none is uploaded "
                    "(upload_ao)");
  if ((err = check_groups(impl, "raycast", ntx, nty)) != 0 ||
      (skip && (err = check_groups(impl, "depth pass",
                                   div_up(p->width, RP_TILE_SIZE),
                                   div_up(p->height, RP_TILE_SIZE))) != 0))
    return err;
  /* The front end runs the depth pass first; a caller that did not (a
   * test driving the ops) gets one recorded ahead of the raycast. */
  redo_depth = skip && !depth_current(impl, p);
  if ((redo_depth && (err = ensure_depth(impl, p)) != 0) ||
      (err = ensure(impl, &impl->image, "image",
                    (VkDeviceSize)rw * rh * 4,
                    VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1)) != 0 ||
      (err = ensure(impl, &impl->tiles, "tile statistics",
                    (VkDeviceSize)ntx * nty * 4 * sizeof(uint32_t),
                    VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1)) != 0 ||
      (slabs && (err = ensure(impl, &impl->slab_state, "depth slabs' ray "
                              "state", (VkDeviceSize)rw * rh * 32,
                              VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 0)) != 0) ||
      (err = get_pipeline(impl,
                          pipeline_key(RP_VK_RAYCAST, p, fetches != NULL,
                                       impl->voxel_type, impl->quad),
                          &cast)) != 0 ||
      (redo_depth &&
       (err = get_pipeline(impl,
                           pipeline_key(RP_VK_DEPTH, p, 0, 0, 0),
                           &depth)) != 0))
    return err;
  set_params(impl, p);
  if ((err = begin(impl)) != 0)
    return err;
  if (redo_depth) {
    impl->depth_ok = 0;
    record_depth(impl, depth, p);
  }
  set_rect(impl, r->x0, r->y0, rw, rh);
  bind(impl, cast);
  vkCmdDispatch(impl->cmd, ntx, nty, 1);
  after_dispatch(impl);
  if ((err = finish(impl, "raycast")) != 0)
    return err;
  if (redo_depth) {
    impl->depth_frame = *p;
    impl->depth_gen = impl->occupancy_gen;
    impl->depth_ok = 1;
  }
  /* A slab before the last leaves its rays' state on the device. */
  if (!last_slab)
    return 0;

  px = impl->image.map;
  for (y = 0; y < rh; y++)
    memcpy(rgba + (((size_t)r->y0 + y) * p->width + r->x0) * 4,
           px + (size_t)y * rw * 4, (size_t)rw * 4);
  /* Region corners lie on the tile grid (or the image edge), so region
   * tile (tx, ty) is image tile (x0 / 8 + tx, y0 / 8 + ty). */
  rp_tile_grid(p->width, p->height, &tiles_x, NULL);
  tile_words = impl->tiles.map;
  for (ty = 0; ty < nty; ty++)
    for (tx = 0; tx < ntx; tx++) {
      const uint32_t *t = tile_words + ((size_t)ty * ntx + tx) * 4;
      size_t i = ((size_t)(r->y0 / RP_TILE_SIZE) + ty) * tiles_x +
                 r->x0 / RP_TILE_SIZE + tx;
      if (tiles != NULL) {
        tiles[i].samples = t[0];
        tiles[i].rays_hit = t[1];
        memcpy(&tiles[i].mean_depth, &t[2], sizeof(float));
      }
      if (fetches != NULL)
        fetches[i] = t[3];
    }
  return 0;
}

/* ---- ambient occlusion --------------------------------------------------- */

/* Bytes of compute_ao's output buffer per submission at most: a box whose
 * words need more is computed in slabs of whole brick layers. */
#define RP_VK_AO_CHUNK ((VkDeviceSize)64 << 20)

static int vk_upload_ao(void *p, const uint8_t *ao) {
  rp_vk_impl *impl = p;
  uint64_t n = (uint64_t)impl->dims[0] * impl->dims[1] * impl->dims[2];
  copy_fill c;
  int err;
  if (ao == NULL) {
    drop_ao(impl);
    return 0;
  }
  if ((err = alive(impl)) != 0)
    return err;
  if (impl->voxel_type == 0)
    return rp__fail(impl->ctx, RP_ESTATE, "vulkan: an AO volume needs the "
                    "volume it belongs to uploaded first");
  if (impl->bricked)
    return rp__fail(impl->ctx, RP_ESTATE, "vulkan: upload_ao on a brick "
                    "pool (AO needs the whole volume on the device)");
  if (!format_ok(impl, VK_FORMAT_R8_UINT))
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: device cannot "
                    "read bytes from a texel buffer (AO volume)");
  if (impl->ao.buf == VK_NULL_HANDLE || impl->ao.size != n) {
    drop_ao(impl);
    if ((err = rp_vk__buffer(impl, "AO volume", n,
                             VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                 VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                             0, &impl->ao)) != 0 ||
        (err = make_view(impl, impl->ao.buf, VK_FORMAT_R8_UINT,
                         &impl->ao_view)) != 0) {
      drop_ao(impl);
      return err;
    }
    impl->stats.ao_bytes = n;
    bind_all(impl);
  }
  c.src = ao;
  c.bytes = (size_t)n;
  if ((err = write_buffer(impl, &impl->ao, "AO volume staging", fill_copy,
                          &c)) != 0) {
    /* Half-written data must not be rendered with. */
    drop_ao(impl);
    return err;
  }
  return 0;
}

/* compute_ao's buffers exist only during the call. */
static void ao_scratch_free(rp_vk_impl *impl) {
  free_view(impl, &impl->ao_dirs_view);
  free_view(impl, &impl->ao_bricks_view);
  rp_vk__buffer_free(impl, &impl->ao_out);
  rp_vk__buffer_free(impl, &impl->ao_dirs);
  rp_vk__buffer_free(impl, &impl->ao_bricks);
  bind_all(impl);
}

/* The directions, the brick mask (when there is one) and an output
 * buffer of `out_bytes`. */
static int ao_scratch(rp_vk_impl *impl, const rp_ao_job *job,
                      VkDeviceSize out_bytes) {
  const VkBufferUsageFlags usage = VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                   VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  copy_fill c;
  int err;
  c.src = job->dirs;
  c.bytes = (size_t)job->directions * 4 * sizeof(float);
  if ((err = rp_vk__buffer(impl, "AO directions", c.bytes, usage, 0,
                           &impl->ao_dirs)) != 0 ||
      (err = make_view(impl, impl->ao_dirs.buf,
                       VK_FORMAT_R32G32B32A32_SFLOAT,
                       &impl->ao_dirs_view)) != 0 ||
      (err = write_buffer(impl, &impl->ao_dirs, "AO directions staging",
                          fill_copy, &c)) != 0)
    return err;
  if (job->bricks != NULL) {
    c.src = job->bricks;
    c.bytes = (size_t)job->brick_grid[0] * job->brick_grid[1] *
              job->brick_grid[2];
    if ((err = rp_vk__buffer(impl, "AO brick mask", c.bytes, usage, 0,
                             &impl->ao_bricks)) != 0 ||
        (err = make_view(impl, impl->ao_bricks.buf, VK_FORMAT_R8_UINT,
                         &impl->ao_bricks_view)) != 0 ||
        (err = write_buffer(impl, &impl->ao_bricks, "AO brick staging",
                            fill_copy, &c)) != 0)
      return err;
  }
  if ((err = rp_vk__buffer(impl, "AO output", out_bytes,
                           VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1,
                           &impl->ao_out)) != 0)
    return err;
  bind_all(impl);
  return 0;
}

/* The Params block as kernels/ao.comp reads it, for layers [z0, z1) of
 * the job's box. */
static void set_ao_params(rp_vk_impl *impl, const rp_ao_job *job,
                          uint32_t z0, uint32_t z1, uint32_t words) {
  rp_vk_params *u = impl->params.map;
  double range = (double)job->value_max - (double)job->value_min;
  int a;
  memset(u, 0, sizeof *u);
  for (a = 0; a < 3; a++) {
    u->dims[a] = (float)impl->dims[a];
    u->idims[a] = impl->dims[a];
    u->blocks[a] = job->bricks != NULL ? job->brick_grid[a] : 0;
    u->rect[a] = job->lo[a];
    u->misc[a] = job->end[a];
  }
  u->rect[2] = z0;
  u->misc[2] = z1;
  u->rect[3] = job->directions;
  u->misc[3] = job->samples;
  u->blocks[3] = job->bricks != NULL;
  u->idims[3] = job->lut_size;
  u->eye[0] = job->offset;
  u->eye[1] = job->step;
  u->vrange[0] = job->value_min;
  u->vrange[1] = range > 0.0 ? (float)(1.0 / range) : 0.0f;
  u->vrange[2] = range > 0.0 ? (float)range : 0.0f;
  u->vrange[3] = (float)((double)job->step / (double)job->ref_step);
  u->seed[0] = words;
}

static int check_ao_job(rp_vk_impl *impl, const rp_ao_job *job) {
  int a;
  if (impl->voxel_type == 0 || !impl->have_lut)
    return rp__fail(impl->ctx, RP_ESTATE, "vulkan: compute_ao needs the "
                    "volume and the transfer function uploaded");
  if (impl->bricked)
    return rp__fail(impl->ctx, RP_ESTATE, "vulkan: compute_ao on a brick "
                    "pool (AO needs the whole volume on the device)");
  for (a = 0; a < 3; a++) {
    if (job->lo[a] > job->end[a] || job->end[a] > impl->dims[a])
      return rp__fail(impl->ctx, RP_EINVAL, "vulkan: AO box [%u, %u) on "
                      "axis %d is outside the volume's %u voxels",
                      job->lo[a], job->end[a], a, impl->dims[a]);
    if (job->bricks != NULL &&
        job->brick_grid[a] != div_up(impl->dims[a], 4))
      return rp__fail(impl->ctx, RP_EINVAL, "vulkan: AO brick grid %u on "
                      "axis %d does not fit %u voxels", job->brick_grid[a],
                      a, impl->dims[a]);
  }
  if (job->directions == 0 || job->samples == 0 || job->lut_size < 2 ||
      job->dirs == NULL)
    return rp__fail(impl->ctx, RP_EINVAL, "vulkan: AO job with %u "
                    "directions, %u samples, LUT of %u", job->directions,
                    job->samples, job->lut_size);
  return 0;
}

static int vk_compute_ao(void *p, const rp_ao_job *job, uint8_t *out) {
  rp_vk_impl *impl = p;
  const uint32_t *lo = job->lo, *end = job->end;
  uint32_t nx, ny, nz, words, bricks_y, layers, z0, z1, y, z;
  VkDeviceSize row_bytes, slab, cap, range, fit;
  uint64_t ns = 0;
  VkPipeline pipe;
  uint32_t key;
  int err;
  if ((err = alive(impl)) != 0 || (err = check_ao_job(impl, job)) != 0)
    return err;
  impl->last_ns = 0;
  nx = end[0] - lo[0];
  ny = end[1] - lo[1];
  nz = end[2] - lo[2];
  if (nx == 0 || ny == 0 || nz == 0)
    return 0;
  /* A workgroup per brick, an output word per brick row: rows run from
   * the first brick's first voxel to the last brick's last. */
  words = (end[0] - 1) / 4 - lo[0] / 4 + 1;
  bricks_y = (end[1] - 1) / 4 - lo[1] / 4 + 1;
  row_bytes = (VkDeviceSize)words * 4;
  slab = row_bytes * ny;
  range = impl->props.limits.maxStorageBufferRange;
  cap = range < RP_VK_AO_CHUNK ? range : RP_VK_AO_CHUNK;
  if (rp_vk_hooks.ao_chunk_bytes > 0 && rp_vk_hooks.ao_chunk_bytes < cap)
    cap = rp_vk_hooks.ao_chunk_bytes;
  /* Whole brick layers per submission, at least one brick's worth, at
   * most what covers the box in one. */
  fit = cap / slab;
  if (fit < 4)
    layers = 4;
  else if (fit > (VkDeviceSize)nz + 4)
    layers = (nz + 7) / 4 * 4;
  else
    layers = (uint32_t)(fit / 4 * 4);
  if ((VkDeviceSize)layers * slab > range)
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: AO of a %ux%u "
                    "slab needs %llu bytes per brick layer; a kernel can "
                    "address at most %llu (maxStorageBufferRange)", nx, ny,
                    (unsigned long long)(4 * slab),
                    (unsigned long long)range);
  if ((err = check_groups(impl, "AO", words, bricks_y)) != 0)
    return err;
  if (layers / 4 + 1 > impl->props.limits.maxComputeWorkGroupCount[2])
    layers = (impl->props.limits.maxComputeWorkGroupCount[2] - 1) * 4;
  key = ao_pipeline_key(job->step != job->ref_step, impl->quad,
                        impl->voxel_type);
  if ((err = get_pipeline(impl, key, &pipe)) != 0)
    return err;
  if ((err = ao_scratch(impl, job, slab * (layers < nz ? layers : nz))) !=
      0) {
    ao_scratch_free(impl);
    return err;
  }
  for (z0 = lo[2]; z0 < end[2] && err == 0; z0 = z1) {
    const uint8_t *src = impl->ao_out.map;
    /* Layers [z0, z1): brick layers z0 / 4 .. (z1 - 1) / 4. */
    z1 = z0 / 4 * 4 + layers;
    z1 = z1 < end[2] ? z1 : end[2];
    set_ao_params(impl, job, z0, z1, words);
    if ((err = begin(impl)) != 0)
      break;
    bind(impl, pipe);
    vkCmdDispatch(impl->cmd, words, bricks_y, (z1 - 1) / 4 - z0 / 4 + 1);
    after_dispatch(impl);
    if ((err = finish(impl, "ambient occlusion")) != 0)
      break;
    ns += impl->last_ns;
    for (z = z0; z < z1; z++)
      for (y = 0; y < ny; y++)
        memcpy(out + ((size_t)(z - lo[2]) * ny + y) * nx,
               src + ((size_t)(z - z0) * ny + y) * row_bytes + lo[0] % 4,
               nx);
  }
  ao_scratch_free(impl);
  impl->last_ns = ns;
  return err;
}

/* ---- out-of-core --------------------------------------------------------- */

/* Staging bytes one upload_bricks submission uses at most (more only
 * where a single brick or the table is larger). */
#define RP_VK_BRICK_CHUNK ((VkDeviceSize)16 << 20)

static int vk_set_brick_pool(void *p, const rp_brick_pool *pool) {
  rp_vk_impl *impl = p;
  const VkBufferUsageFlags usage = VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                   VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  uint64_t stored, es, voxels, count, bytes;
  uint32_t limit = impl->props.limits.maxTexelBufferElements;
  int err;
  impl->last_ns = 0;
  /* The pool replaces the volume, and AO is not rendered from one. */
  drop_volume(impl);
  drop_ao(impl);
  memset(impl->dims, 0, sizeof impl->dims);
  if (pool == NULL) {
    bind_all(impl);
    return 0;
  }
  if ((err = alive(impl)) != 0) {
    bind_all(impl);
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
    bind_all(impl);
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: a pool of %u "
                    "bricks of %u^3 voxels (and a border) takes %llu "
                    "voxels, its table %llu entries; this device reads at "
                    "most %u per buffer (maxTexelBufferElements): a smaller "
                    "budget_bytes", pool->slots, pool->brick_size,
                    (unsigned long long)voxels, (unsigned long long)count,
                    (unsigned)limit);
  }
  if (!format_ok(impl, plain_fmt[pool->type]) ||
      !format_ok(impl, VK_FORMAT_R32_UINT)) {
    bind_all(impl);
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: device cannot "
                    "read %s voxels and 32-bit slots from texel buffers "
                    "(brick pool)", rp_voxel_type_name(pool->type));
  }
  if ((err = rp_vk__buffer(impl, "brick pool", bytes, usage, 0,
                           &impl->volume)) == 0 &&
      (err = rp_vk__buffer(impl, "brick table", count * sizeof(uint32_t),
                           usage, 0, &impl->brick_table)) == 0 &&
      (err = make_view(impl, impl->volume.buf, plain_fmt[pool->type],
                       &impl->volume_view)) == 0 &&
      (err = make_view(impl, impl->brick_table.buf, VK_FORMAT_R32_UINT,
                       &impl->brick_table_view)) == 0 &&
      (err = begin(impl)) == 0) {
    /* Every brick starts in slot 0 (the front end's transparent one), and
     * the pool is defined before any brick arrives. */
    vkCmdFillBuffer(impl->cmd, impl->volume.buf, 0, VK_WHOLE_SIZE, 0);
    vkCmdFillBuffer(impl->cmd, impl->brick_table.buf, 0, VK_WHOLE_SIZE, 0);
    barrier(impl, VK_PIPELINE_STAGE_TRANSFER_BIT,
            VK_ACCESS_TRANSFER_WRITE_BIT,
            VK_PIPELINE_STAGE_TRANSFER_BIT |
                VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
            VK_ACCESS_TRANSFER_WRITE_BIT | VK_ACCESS_SHADER_READ_BIT);
    err = finish(impl, "clearing the brick pool");
  }
  if (err != 0) {
    drop_volume(impl);
    bind_all(impl);
    return err;
  }
  bind_all(impl);
  impl->brick_slots = pool->slots;
  impl->brick_count = (uint32_t)count;
  impl->brick_bytes = (VkDeviceSize)(stored * stored * stored * es);
  memcpy(impl->dims, pool->dims, sizeof impl->dims);
  /* One voxel per texel: the quad layout would take four times the
   * memory the front end sized the pool to. */
  set_volume_state(impl, pool->type, 0, 1);
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
    if ((err = begin(impl)) != 0)
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
    barrier(impl, VK_PIPELINE_STAGE_TRANSFER_BIT,
            VK_ACCESS_TRANSFER_WRITE_BIT,
            VK_PIPELINE_STAGE_TRANSFER_BIT |
                VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
            VK_ACCESS_TRANSFER_WRITE_BIT | VK_ACCESS_SHADER_READ_BIT);
    if ((err = finish(impl, "brick upload")) == 0)
      ns += impl->last_ns;
  }
  rp_vk__buffer_free(impl, &staging);
  impl->last_ns = err == 0 ? ns : 0;
  return err;
}

static int vk_upload_bricks(void *p, uint32_t count, const uint32_t *slots,
                            const void *const *voxels,
                            const uint32_t *table) {
  rp_vk_impl *impl = p;
  uint64_t t0;
  uint32_t i;
  int err;
  impl->last_ns = 0;
  if ((err = alive(impl)) != 0)
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

static uint64_t vk_last_time_ns(void *ip) {
  return ((rp_vk_impl *)ip)->last_ns;
}

void rp_vk_get_stats(void *ip, rp_vk_stats *out) {
  rp_vk_impl *impl = ip;
  pthread_mutex_lock(&impl->lock);
  *out = impl->stats;
  pthread_mutex_unlock(&impl->lock);
}

void rp_vk__variant_stats(void *ip, rp_variant_stats *out) {
  rp_vk_impl *impl = ip;
  pthread_mutex_lock(&impl->lock);
  *out = impl->variants.stats;
  pthread_mutex_unlock(&impl->lock);
}

static const rp_backend_ops vk_ops = {
    .destroy = vk_destroy,
    .upload_volume = vk_upload_volume,
    .upload_tf = vk_upload_tf,
    .upload_occupancy = vk_upload_occupancy,
    .depth_pass = vk_depth_pass,
    .ert_prepass = vk_ert_prepass,
    .raycast = vk_raycast,
    .compute_ao = vk_compute_ao,
    .upload_ao = vk_upload_ao,
    .set_brick_pool = vk_set_brick_pool,
    .upload_bricks = vk_upload_bricks,
    .last_time_ns = vk_last_time_ns,
    .prepare = vk_prepare};

const rp_backend_bootstrap rp_vk_bootstrap = {"vulkan", vk_probe, vk_create,
                                              NULL};
