/* The Vulkan backend's kernels and pipelines: a shader module per kernel,
 * a pipeline per combination of specialization constants, kept in the
 * variant cache every backend shares, and prepare, which builds them
 * ahead on another thread (the one op that may run beside the others,
 * hence the lock). */
#include <string.h>

#include "vk_internal.h"

#include "ao.spv.h"
#include "depth.spv.h"
#include "ert.spv.h"
#include "raycast.spv.h"

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

int rp_vk__make_modules(rp_vk_impl *impl) {
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

uint32_t rp_vk__pipeline_key(rp_vk_kernel k, const rp_frame_params *p,
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
uint32_t rp_vk__ao_pipeline_key(int correct, int quad, rp_voxel_type type) {
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
int rp_vk__get_pipeline(rp_vk_impl *impl, uint32_t key, VkPipeline *out) {
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
int rp_vk__prepare(void *ip, rp_context *ctx, uint32_t effects) {
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
  keys[n++] = rp_vk__pipeline_key(RP_VK_DEPTH, &p, 0, 0, 0);
  /* A brick pool holds no AO volume (set_brick_pool drops it, upload_ao
   * refuses): no frame on it can use the AO raycast. */
  for (i = 0; i < 2 && !(bricked && (effects & RP_EFFECT_AO)); i++) {
    p.step = 1.0f;
    p.ref_step = i == 0 ? 1.0f : 2.0f; /* RP_VK_KEY_CORRECT off, on */
    keys[n++] = rp_vk__pipeline_key(RP_VK_RAYCAST, &p, 0, type, quad);
  }
  /* compute_ao's, as it keys it, with its step against the TF's either
   * way (not on a brick pool, where AO is not computed). */
  for (i = 0; i < 2 && !bricked && (effects & RP_EFFECT_AO); i++)
    keys[n++] = rp_vk__ao_pipeline_key(i, quad, type);
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

void rp_vk__variant_stats(void *ip, rp_variant_stats *out) {
  rp_vk_impl *impl = ip;
  pthread_mutex_lock(&impl->lock);
  *out = impl->variants.stats;
  pthread_mutex_unlock(&impl->lock);
}
