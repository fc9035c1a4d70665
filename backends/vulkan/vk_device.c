/* The Vulkan backend's device layer: instance and device, memory and
 * buffers, the persistent pipeline cache, and error mapping.
 *
 * Nothing here knows about kernels; vk_backend.c and the files beside it
 * build the frame on top.
 * Every failure is reported through rp__fail with the Vulkan call that
 * failed, and no half-made object is left behind: rp_vk__close and
 * rp_vk__buffer_free accept partly built state. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "vk_internal.h"

/* ---- errors -------------------------------------------------------------- */

const char *rp_vk__result_name(VkResult r) {
  switch (r) {
#define RP_VK_NAME(x)                                                         \
  case x: return #x;
    RP_VK_NAME(VK_SUCCESS)
    RP_VK_NAME(VK_NOT_READY)
    RP_VK_NAME(VK_TIMEOUT)
    RP_VK_NAME(VK_INCOMPLETE)
    RP_VK_NAME(VK_ERROR_OUT_OF_HOST_MEMORY)
    RP_VK_NAME(VK_ERROR_OUT_OF_DEVICE_MEMORY)
    RP_VK_NAME(VK_ERROR_INITIALIZATION_FAILED)
    RP_VK_NAME(VK_ERROR_DEVICE_LOST)
    RP_VK_NAME(VK_ERROR_MEMORY_MAP_FAILED)
    RP_VK_NAME(VK_ERROR_LAYER_NOT_PRESENT)
    RP_VK_NAME(VK_ERROR_EXTENSION_NOT_PRESENT)
    RP_VK_NAME(VK_ERROR_FEATURE_NOT_PRESENT)
    RP_VK_NAME(VK_ERROR_INCOMPATIBLE_DRIVER)
    RP_VK_NAME(VK_ERROR_TOO_MANY_OBJECTS)
    RP_VK_NAME(VK_ERROR_FORMAT_NOT_SUPPORTED)
    RP_VK_NAME(VK_ERROR_FRAGMENTED_POOL)
    RP_VK_NAME(VK_ERROR_OUT_OF_POOL_MEMORY)
    RP_VK_NAME(VK_ERROR_INVALID_SHADER_NV)
#undef RP_VK_NAME
  default: return "VK_ERROR_UNKNOWN";
  }
}

int rp_vk__fail(rp_context *ctx, VkResult r, const char *op) {
  int err;
  switch (r) {
  case VK_ERROR_OUT_OF_HOST_MEMORY:
  case VK_ERROR_OUT_OF_DEVICE_MEMORY:
  case VK_ERROR_OUT_OF_POOL_MEMORY:
  case VK_ERROR_TOO_MANY_OBJECTS:
    err = RP_ENOMEM;
    break;
  case VK_ERROR_INCOMPATIBLE_DRIVER:
  case VK_ERROR_INITIALIZATION_FAILED:
    err = RP_ENODEV;
    break;
  default:
    err = RP_EDEVICE;
    break;
  }
  if (r == VK_ERROR_DEVICE_LOST)
    return rp__fail(ctx, err, "vulkan: device lost during %s", op);
  return rp__fail(ctx, err, "vulkan: %s: %s (%d)", op, rp_vk__result_name(r),
                  (int)r);
}

/* ---- instance and devices ------------------------------------------------ */

int rp_vk__instance(rp_context *ctx, VkInstance *out) {
  VkApplicationInfo app = {0};
  VkInstanceCreateInfo info = {0};
  uint32_t version = VK_API_VERSION_1_0;
  VkResult r;
  /* The kernels are SPIR-V 1.3 (Vulkan 1.1); a 1.0 loader cannot even
   * ask for that, so it counts as no driver. */
  if (vkEnumerateInstanceVersion(&version) != VK_SUCCESS ||
      version < VK_API_VERSION_1_1)
    return rp__fail(ctx, RP_ENODEV, "vulkan: the loader supports Vulkan "
                    "%u.%u; raypace needs 1.1", VK_VERSION_MAJOR(version),
                    VK_VERSION_MINOR(version));
  app.sType = VK_STRUCTURE_TYPE_APPLICATION_INFO;
  app.pApplicationName = "raypace";
  app.applicationVersion = RP_VERSION_HEX;
  app.pEngineName = "raypace";
  app.engineVersion = RP_VERSION_HEX;
  /* Ask for the highest we use (1.3: creation feedback in core), capped
   * by what the loader knows. */
  app.apiVersion = version < VK_API_VERSION_1_3 ? version : VK_API_VERSION_1_3;
  info.sType = VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO;
  info.pApplicationInfo = &app;
  rp__driver_setup_begin();
  r = vkCreateInstance(&info, NULL, out);
  rp__driver_setup_end();
  if (r != VK_SUCCESS) {
    *out = VK_NULL_HANDLE;
    if (r == VK_ERROR_INCOMPATIBLE_DRIVER)
      return rp__fail(ctx, RP_ENODEV, "vulkan: no Vulkan driver (ICD) "
                      "found by the loader");
    return rp_vk__fail(ctx, r, "vkCreateInstance");
  }
  return 0;
}

/* The first queue family that can run compute, preferring one that can
 * also time it. UINT32_MAX when there is none. */
static uint32_t compute_family(VkPhysicalDevice pd, uint32_t *ts_bits) {
  VkQueueFamilyProperties fam[16];
  uint32_t n = 16, i, best = UINT32_MAX;
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &n, fam);
  *ts_bits = 0;
  for (i = 0; i < n; i++) {
    if (!(fam[i].queueFlags & VK_QUEUE_COMPUTE_BIT) || fam[i].queueCount == 0)
      continue;
    if (best == UINT32_MAX ||
        (*ts_bits == 0 && fam[i].timestampValidBits > 0)) {
      best = i;
      *ts_bits = fam[i].timestampValidBits;
    }
  }
  return best;
}

int rp_vk__compute_devices(VkInstance inst, VkPhysicalDevice *list,
                           uint32_t cap, uint32_t *count) {
  VkPhysicalDevice all[32];
  uint32_t n = 32, i, k = 0;
  VkResult r;
  rp__driver_setup_begin();
  r = vkEnumeratePhysicalDevices(inst, &n, all);
  rp__driver_setup_end();
  *count = 0;
  if (r != VK_SUCCESS && r != VK_INCOMPLETE)
    return -1;
  for (i = 0; i < n; i++) {
    VkPhysicalDeviceProperties props;
    uint32_t bits;
    vkGetPhysicalDeviceProperties(all[i], &props);
    /* A device below 1.1 cannot run the kernels' SPIR-V 1.3. */
    if (props.apiVersion < VK_API_VERSION_1_1 ||
        compute_family(all[i], &bits) == UINT32_MAX)
      continue;
    if (k < cap)
      list[k] = all[i];
    k++;
  }
  *count = k;
  return 0;
}

static int has_extension(VkPhysicalDevice pd, const char *name) {
  VkExtensionProperties ext[512];
  uint32_t n = 512, i;
  VkResult r = vkEnumerateDeviceExtensionProperties(pd, NULL, &n, ext);
  if (r != VK_SUCCESS && r != VK_INCOMPLETE)
    return 0;
  for (i = 0; i < n; i++)
    if (strcmp(ext[i].extensionName, name) == 0)
      return 1;
  return 0;
}

static void fill_caps(const rp_vk_impl *impl, rp_caps *caps) {
  uint64_t local = 0;
  uint32_t i;
  memset(caps, 0, sizeof *caps);
  snprintf(caps->backend, sizeof caps->backend, "vulkan");
  /* deviceName may be longer than the field: keep its start. */
  memcpy(caps->device, impl->props.deviceName, sizeof caps->device - 1);
  caps->device[sizeof caps->device - 1] = '\0';
  caps->effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP |
                  RP_EFFECT_AO | RP_EFFECT_PREINT;
  caps->voxel_types = (1u << RP_U8) | (1u << RP_U16) | (1u << RP_F32);
  for (i = 0; i < impl->mem_props.memoryHeapCount; i++)
    if (impl->mem_props.memoryHeaps[i].flags &
        VK_MEMORY_HEAP_DEVICE_LOCAL_BIT)
      local += impl->mem_props.memoryHeaps[i].size;
  caps->global_mem_bytes = local;
  caps->max_alloc_bytes = impl->max_alloc;
  /* Vulkan does not say how many cores run a dispatch. A CPU driver
   * (lavapipe) spreads workgroups over the online processors. */
  caps->compute_units = 1;
  if (impl->props.deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU) {
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    caps->compute_units = n > 0 ? (uint32_t)n : 1;
  }
  caps->sub_device = 0;
}

int rp_vk__open(rp_vk_impl *impl, uint32_t index, rp_caps *caps) {
  rp_context *ctx = impl->ctx;
  VkPhysicalDevice list[32];
  VkPhysicalDeviceMaintenance3Properties m3 = {0};
  VkPhysicalDeviceProperties2 props2 = {0};
  VkDeviceQueueCreateInfo qinfo = {0};
  VkDeviceCreateInfo dinfo = {0};
  VkCommandPoolCreateInfo pinfo = {0};
  VkCommandBufferAllocateInfo cinfo = {0};
  VkFenceCreateInfo finfo = {0};
  const char *exts[1];
  uint32_t count = 0, ts_bits = 0;
  float priority = 1.0f;
  VkResult r;
  int err;

  if ((err = rp_vk__instance(ctx, &impl->instance)) != 0)
    return err;
  if (rp_vk__compute_devices(impl->instance, list, 32, &count) != 0 ||
      index >= count || index >= 32)
    return rp__fail(ctx, RP_ENODEV, "vulkan: %u device(s) with a compute "
                    "queue; index %u requested", count, index);
  impl->phys = list[index];
  vkGetPhysicalDeviceProperties(impl->phys, &impl->props);
  vkGetPhysicalDeviceMemoryProperties(impl->phys, &impl->mem_props);
  m3.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_MAINTENANCE_3_PROPERTIES;
  props2.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2;
  props2.pNext = &m3;
  vkGetPhysicalDeviceProperties2(impl->phys, &props2);
  impl->max_alloc = m3.maxMemoryAllocationSize;
  impl->queue_family = compute_family(impl->phys, &ts_bits);
  /* Timestamps need a queue that counts and, for compute queues, the
   * limit that says compute queues may be timed. */
  if (ts_bits > 0 && impl->props.limits.timestampComputeAndGraphics)
    impl->ts_mask = ts_bits >= 64 ? UINT64_MAX : ((uint64_t)1 << ts_bits) - 1;

  qinfo.sType = VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO;
  qinfo.queueFamilyIndex = impl->queue_family;
  qinfo.queueCount = 1;
  qinfo.pQueuePriorities = &priority;
  dinfo.sType = VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO;
  dinfo.queueCreateInfoCount = 1;
  dinfo.pQueueCreateInfos = &qinfo;
  /* Creation feedback only tells tests whether the pipeline cache hit;
   * it is core in 1.3 and an extension before. */
  if (impl->props.apiVersion >= VK_API_VERSION_1_3) {
    impl->feedback = 1;
  } else if (has_extension(impl->phys,
                           VK_EXT_PIPELINE_CREATION_FEEDBACK_EXTENSION_NAME)) {
    exts[0] = VK_EXT_PIPELINE_CREATION_FEEDBACK_EXTENSION_NAME;
    dinfo.enabledExtensionCount = 1;
    dinfo.ppEnabledExtensionNames = exts;
    impl->feedback = 1;
  }
  rp__driver_setup_begin();
  r = vkCreateDevice(impl->phys, &dinfo, NULL, &impl->dev);
  rp__driver_setup_end();
  if (r != VK_SUCCESS) {
    impl->dev = VK_NULL_HANDLE;
    return rp_vk__fail(ctx, r, "vkCreateDevice");
  }
  vkGetDeviceQueue(impl->dev, impl->queue_family, 0, &impl->queue);

  pinfo.sType = VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO;
  pinfo.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pinfo.queueFamilyIndex = impl->queue_family;
  if ((r = vkCreateCommandPool(impl->dev, &pinfo, NULL, &impl->pool)) !=
      VK_SUCCESS)
    return rp_vk__fail(ctx, r, "vkCreateCommandPool");
  cinfo.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO;
  cinfo.commandPool = impl->pool;
  cinfo.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  cinfo.commandBufferCount = 1;
  if ((r = vkAllocateCommandBuffers(impl->dev, &cinfo, &impl->cmd)) !=
      VK_SUCCESS)
    return rp_vk__fail(ctx, r, "vkAllocateCommandBuffers");
  finfo.sType = VK_STRUCTURE_TYPE_FENCE_CREATE_INFO;
  if ((r = vkCreateFence(impl->dev, &finfo, NULL, &impl->fence)) !=
      VK_SUCCESS)
    return rp_vk__fail(ctx, r, "vkCreateFence");
  if (impl->ts_mask != 0) {
    VkQueryPoolCreateInfo q = {0};
    q.sType = VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO;
    q.queryType = VK_QUERY_TYPE_TIMESTAMP;
    q.queryCount = 2;
    if ((r = vkCreateQueryPool(impl->dev, &q, NULL, &impl->queries)) !=
        VK_SUCCESS)
      return rp_vk__fail(ctx, r, "vkCreateQueryPool");
  }
  impl->stats.timestamps = impl->ts_mask != 0;
  fill_caps(impl, caps);
  return 0;
}

void rp_vk__close(rp_vk_impl *impl) {
  if (impl->dev != VK_NULL_HANDLE) {
    if (impl->queries != VK_NULL_HANDLE)
      vkDestroyQueryPool(impl->dev, impl->queries, NULL);
    if (impl->fence != VK_NULL_HANDLE)
      vkDestroyFence(impl->dev, impl->fence, NULL);
    if (impl->pool != VK_NULL_HANDLE)
      vkDestroyCommandPool(impl->dev, impl->pool, NULL);
    vkDestroyDevice(impl->dev, NULL);
  }
  if (impl->instance != VK_NULL_HANDLE)
    vkDestroyInstance(impl->instance, NULL);
  impl->queries = VK_NULL_HANDLE;
  impl->fence = VK_NULL_HANDLE;
  impl->pool = VK_NULL_HANDLE;
  impl->dev = VK_NULL_HANDLE;
  impl->instance = VK_NULL_HANDLE;
}

/* ---- memory -------------------------------------------------------------- */

static int popcount(uint32_t v) {
  int n = 0;
  for (; v != 0; v &= v - 1)
    n++;
  return n;
}

/* The first memory type in `bits` with all of `need` and as many of
 * `want` as any has; UINT32_MAX when none has `need`. */
static uint32_t pick_memory(const VkPhysicalDeviceMemoryProperties *mp,
                            uint32_t bits, VkMemoryPropertyFlags need,
                            VkMemoryPropertyFlags want) {
  uint32_t i, best = UINT32_MAX;
  int best_score = -1;
  for (i = 0; i < mp->memoryTypeCount; i++) {
    VkMemoryPropertyFlags f = mp->memoryTypes[i].propertyFlags;
    int score;
    if (!(bits & (1u << i)) || (f & need) != need)
      continue;
    score = popcount(f & want);
    if (score > best_score) {
      best = i;
      best_score = score;
    }
  }
  return best;
}

int rp_vk__buffer(rp_vk_impl *impl, const char *what, VkDeviceSize size,
                  VkBufferUsageFlags usage, int host, rp_vk_buffer *out) {
  rp_context *ctx = impl->ctx;
  const VkMemoryPropertyFlags coherent =
      VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT |
      VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
  VkBufferCreateInfo binfo = {0};
  VkMemoryAllocateInfo ainfo = {0};
  VkMemoryRequirements req;
  VkMemoryPropertyFlags need, want;
  uint32_t type;
  VkResult r;
  char op[128];

  memset(out, 0, sizeof *out);
  if (size > impl->max_alloc)
    return rp__fail(ctx, RP_ENOMEM, "vulkan: %s needs %llu bytes; the "
                    "device's largest allocation is %llu bytes", what,
                    (unsigned long long)size,
                    (unsigned long long)impl->max_alloc);
  binfo.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
  binfo.size = size;
  binfo.usage = usage;
  binfo.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  snprintf(op, sizeof op, "vkCreateBuffer (%s, %llu bytes)", what,
           (unsigned long long)size);
  if ((r = vkCreateBuffer(impl->dev, &binfo, NULL, &out->buf)) !=
      VK_SUCCESS) {
    out->buf = VK_NULL_HANDLE;
    return rp_vk__fail(ctx, r, op);
  }
  vkGetBufferMemoryRequirements(impl->dev, out->buf, &req);
  /* Outputs and staging are read or written by the host, so they must be
   * coherent (cached reads are much faster where offered). Inputs live
   * where kernels read fastest, and are mapped when that memory happens
   * to be host-visible too (always on a CPU driver). */
  need = host ? coherent : 0;
  want = host ? VK_MEMORY_PROPERTY_HOST_CACHED_BIT
              : VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT;
  type = pick_memory(&impl->mem_props, req.memoryTypeBits, need, want);
  if (type == UINT32_MAX) {
    rp_vk__buffer_free(impl, out);
    return rp__fail(ctx, RP_EUNSUPPORTED, "vulkan: no memory type for %s "
                    "(%s)", what, host ? "host-visible, coherent" : "any");
  }
  ainfo.sType = VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO;
  ainfo.allocationSize = req.size;
  ainfo.memoryTypeIndex = type;
  r = vkAllocateMemory(impl->dev, &ainfo, NULL, &out->mem);
  if (r != VK_SUCCESS) {
    out->mem = VK_NULL_HANDLE;
    rp_vk__buffer_free(impl, out);
    if (r == VK_ERROR_OUT_OF_DEVICE_MEMORY ||
        r == VK_ERROR_OUT_OF_HOST_MEMORY)
      return rp__fail(ctx, RP_ENOMEM, "vulkan: out of %s memory allocating "
                      "%llu bytes for %s",
                      r == VK_ERROR_OUT_OF_DEVICE_MEMORY ? "device" : "host",
                      (unsigned long long)req.size, what);
    snprintf(op, sizeof op, "vkAllocateMemory (%s, %llu bytes)", what,
             (unsigned long long)req.size);
    return rp_vk__fail(ctx, r, op);
  }
  if ((r = vkBindBufferMemory(impl->dev, out->buf, out->mem, 0)) !=
      VK_SUCCESS) {
    rp_vk__buffer_free(impl, out);
    return rp_vk__fail(ctx, r, "vkBindBufferMemory");
  }
  if ((impl->mem_props.memoryTypes[type].propertyFlags & coherent) ==
      coherent) {
    r = vkMapMemory(impl->dev, out->mem, 0, VK_WHOLE_SIZE, 0, &out->map);
    if (r != VK_SUCCESS) {
      rp_vk__buffer_free(impl, out);
      return rp_vk__fail(ctx, r, "vkMapMemory");
    }
  }
  out->size = size;
  return 0;
}

void rp_vk__buffer_free(rp_vk_impl *impl, rp_vk_buffer *b) {
  if (impl->dev == VK_NULL_HANDLE)
    return;
  if (b->buf != VK_NULL_HANDLE)
    vkDestroyBuffer(impl->dev, b->buf, NULL);
  /* Freeing memory unmaps it. */
  if (b->mem != VK_NULL_HANDLE)
    vkFreeMemory(impl->dev, b->mem, NULL);
  memset(b, 0, sizeof *b);
}

/* ---- SPIR-V -------------------------------------------------------------- */

int rp_vk__check_spirv(rp_context *ctx, const char *what,
                       const uint32_t *words, size_t bytes) {
  /* A driver handed a broken module may crash rather than fail, so the
   * header is checked here: magic, a 1.x version, a non-zero id bound. */
  if (words == NULL || bytes < 5 * sizeof(uint32_t) || bytes % 4 != 0)
    return rp__fail(ctx, RP_EBUILD, "vulkan: kernel '%s': SPIR-V module of "
                    "%zu bytes is truncated", what, bytes);
  if (words[0] != 0x07230203u)
    return rp__fail(ctx, RP_EBUILD, "vulkan: kernel '%s': not a SPIR-V "
                    "module (magic 0x%08x)", what, (unsigned)words[0]);
  if ((words[1] & 0xffff00ffu) != 0x00010000u || words[3] == 0)
    return rp__fail(ctx, RP_EBUILD, "vulkan: kernel '%s': unsupported "
                    "SPIR-V version 0x%08x or empty id bound", what,
                    (unsigned)words[1]);
  return 0;
}

/* ---- pipeline cache file --------------------------------------------------
 *
 * File layout: our header (magic, driver data size, FNV-1a 64 checksum of
 * the data), then vkGetPipelineCacheData's bytes. The checksum rejects a
 * torn or corrupted file before a driver parses it; the driver header
 * inside (vendor, device, cache UUID) rejects one from another driver or
 * driver version. A rejected file is ignored: the cache starts empty. */

uint64_t rp_vk__fnv1a(const uint8_t *p, size_t n) {
  uint64_t h = 0xcbf29ce484222325ull;
  size_t i;
  for (i = 0; i < n; i++) {
    h ^= p[i];
    h *= 0x100000001b3ull;
  }
  return h;
}

/* The cache directory: RP_VK_PIPELINE_CACHE, else the build tree's (set
 * by CMake); NULL when persistence is off (the variable set to ""). */
static const char *cache_dir(void) {
  const char *d = getenv("RP_VK_PIPELINE_CACHE");
  if (d != NULL)
    return d[0] != '\0' ? d : NULL;
#ifdef RP_VK_CACHE_DIR
  return RP_VK_CACHE_DIR;
#else
  return NULL;
#endif
}

static const char *check_driver_header(const rp_vk_impl *impl,
                                       const uint8_t *data, size_t n) {
  VkPipelineCacheHeaderVersionOne h;
  if (n < sizeof h)
    return "driver header truncated";
  memcpy(&h, data, sizeof h);
  if (h.headerSize < sizeof h || h.headerSize > n)
    return "driver header size invalid";
  if (h.headerVersion != VK_PIPELINE_CACHE_HEADER_VERSION_ONE)
    return "driver header version unknown";
  if (h.vendorID != impl->props.vendorID ||
      h.deviceID != impl->props.deviceID ||
      memcmp(h.pipelineCacheUUID, impl->props.pipelineCacheUUID,
             VK_UUID_SIZE) != 0)
    return "written by another device or driver version";
  return NULL;
}

/* Reads and validates the cache file; returns the driver data (rp__malloc)
 * or NULL, with the reason in impl->stats.cache_reject. */
static uint8_t *read_cache(rp_vk_impl *impl, size_t *len) {
  rp_vk_stats *st = &impl->stats;
  rp_vk_cache_header h;
  FILE *f = fopen(st->cache_path, "rb");
  uint8_t *data = NULL;
  const char *why = NULL;
  long end;
  if (f == NULL)
    return NULL; /* no file yet: not a rejection */
  if (fseek(f, 0, SEEK_END) != 0 || (end = ftell(f)) < 0 ||
      fseek(f, 0, SEEK_SET) != 0)
    why = "unreadable";
  else if ((size_t)end < sizeof h || fread(&h, sizeof h, 1, f) != 1)
    why = "shorter than its header";
  else if (memcmp(h.magic, RP_VK_CACHE_MAGIC, sizeof h.magic) != 0)
    why = "not a raypace cache file";
  else if (h.size != (uint64_t)end - sizeof h || h.size > (64u << 20))
    why = "size does not match the file";
  else if ((data = rp__malloc(impl->ctx, h.size + 1)) == NULL)
    why = "out of memory";
  else if (fread(data, 1, h.size, f) != h.size)
    why = "short read";
  else if (rp_vk__fnv1a(data, h.size) != h.checksum)
    why = "checksum mismatch (corrupt)";
  else
    why = check_driver_header(impl, data, h.size);
  fclose(f);
  if (why != NULL) {
    snprintf(st->cache_reject, sizeof st->cache_reject, "%s", why);
    rp__free(impl->ctx, data);
    return NULL;
  }
  *len = h.size;
  return data;
}

void rp_vk__cache_load(rp_vk_impl *impl) {
  rp_vk_stats *st = &impl->stats;
  VkPipelineCacheCreateInfo info = {0};
  const char *dir = cache_dir();
  uint8_t *data = NULL;
  size_t len = 0;
  st->cache_path[0] = '\0';
  if (dir != NULL)
    snprintf(st->cache_path, sizeof st->cache_path,
             "%s/raypace-vk-%04x-%04x.cache", dir,
             (unsigned)impl->props.vendorID, (unsigned)impl->props.deviceID);
  if (st->cache_path[0] != '\0')
    data = read_cache(impl, &len);
  /* No VK_PIPELINE_CACHE_CREATE_EXTERNALLY_SYNCHRONIZED_BIT: prepare
   * builds pipelines through the cache on another thread (vk_pipeline.c,
   * build_pipeline). */
  info.sType = VK_STRUCTURE_TYPE_PIPELINE_CACHE_CREATE_INFO;
  info.initialDataSize = len;
  info.pInitialData = data;
  if (vkCreatePipelineCache(impl->dev, &info, NULL, &impl->cache) !=
      VK_SUCCESS) {
    /* A driver that refuses the data still gets an empty cache. */
    info.initialDataSize = 0;
    info.pInitialData = NULL;
    if (data != NULL)
      snprintf(st->cache_reject, sizeof st->cache_reject,
               "refused by the driver");
    len = 0;
    if (vkCreatePipelineCache(impl->dev, &info, NULL, &impl->cache) !=
        VK_SUCCESS)
      impl->cache = VK_NULL_HANDLE; /* pipelines are made without one */
  }
  st->cache_loaded = len > 0;
  st->cache_bytes = len;
  rp__free(impl->ctx, data);
}

void rp_vk__cache_save(rp_vk_impl *impl) {
  const char *path = impl->stats.cache_path, *dir = cache_dir();
  rp_vk_cache_header h;
  char tmp[sizeof impl->stats.cache_path + 32];
  uint8_t *data;
  size_t n = 0;
  FILE *f;
  int ok;
  if (impl->cache == VK_NULL_HANDLE || path[0] == '\0' || dir == NULL ||
      vkGetPipelineCacheData(impl->dev, impl->cache, &n, NULL) !=
          VK_SUCCESS ||
      n == 0)
    return;
  if ((data = rp__malloc(impl->ctx, n)) == NULL)
    return;
  if (vkGetPipelineCacheData(impl->dev, impl->cache, &n, data) !=
      VK_SUCCESS) {
    rp__free(impl->ctx, data);
    return;
  }
  /* Saving is best effort: a read-only or missing tree costs the next
   * run its head start, nothing else. */
  if (mkdir(dir, 0777) != 0 && errno != EEXIST) {
    rp__free(impl->ctx, data);
    return;
  }
  memcpy(h.magic, RP_VK_CACHE_MAGIC, sizeof h.magic);
  h.size = n;
  h.checksum = rp_vk__fnv1a(data, n);
  /* Written aside and renamed over, so that a reader never sees half a
   * file and concurrent writers leave one whole file. */
  snprintf(tmp, sizeof tmp, "%s.%ld.tmp", path, (long)getpid());
  f = fopen(tmp, "wb");
  if (f == NULL) {
    rp__free(impl->ctx, data);
    return;
  }
  ok = fwrite(&h, sizeof h, 1, f) == 1 && fwrite(data, 1, n, f) == n;
  ok = fclose(f) == 0 && ok;
  if (!ok || rename(tmp, path) != 0)
    remove(tmp);
  rp__free(impl->ctx, data);
}
