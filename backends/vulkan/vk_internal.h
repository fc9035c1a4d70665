/* The Vulkan backend's internals, shared by its .c files and its test.
 * Nothing here is part of the public API. */
#ifndef RP_VK_INTERNAL_H
#define RP_VK_INTERNAL_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#include <vulkan/vulkan.h>

#include "internal.h"
#include "raypace_backend.h"
#include "variant_cache.h"

extern const rp_backend_bootstrap rp_vk_bootstrap;

/* The four kernels, one SPIR-V module each. */
typedef enum rp_vk_kernel {
  RP_VK_RAYCAST = 0,
  RP_VK_DEPTH = 1,
  RP_VK_ERT = 2,
  RP_VK_AO = 3,
  RP_VK_KERNEL_COUNT = 4
} rp_vk_kernel;

/* Specialization constant ids, as declared in kernels/common.glsl. */
enum {
  RP_VK_SPEC_SHADING = 0,
  RP_VK_SPEC_ERT = 1,
  RP_VK_SPEC_SKIP = 2,
  RP_VK_SPEC_COUNT = 3,
  RP_VK_SPEC_AO = 4,
  RP_VK_SPEC_VOXEL = 5,
  RP_VK_SPEC_QUAD = 6,
  RP_VK_SPEC_CORRECT = 7,
  RP_VK_SPEC_BRICKED = 8,
  RP_VK_SPEC_PREINT = 9,
  RP_VK_SPEC_TOTAL = 10
};

/* Descriptor bindings of the one set all kernels share. */
enum {
  RP_VK_BIND_PARAMS = 0,
  RP_VK_BIND_VOLUME = 1,
  RP_VK_BIND_LUT = 2,
  RP_VK_BIND_GRID = 3,
  RP_VK_BIND_ALPHA = 4,
  RP_VK_BIND_DEPTH = 5,
  RP_VK_BIND_IMAGE = 6,
  RP_VK_BIND_TILES = 7,
  RP_VK_BIND_ERT = 8,
  RP_VK_BIND_AO = 9,        /* the AO volume the raycast reads */
  RP_VK_BIND_AO_OUT = 10,   /* compute_ao: its output words */
  RP_VK_BIND_AO_DIRS = 11,  /* compute_ao: the directions */
  RP_VK_BIND_AO_BRICKS = 12, /* compute_ao: the brick mask */
  RP_VK_BIND_BRICK_TABLE = 13, /* out-of-core: slot of each brick */
  RP_VK_BIND_SLABS = 14,    /* out-of-core: the depth slabs' ray state */
  RP_VK_BIND_COUNT = 15
};

/* Pipeline key, its entry's key in the variant cache (variant_cache.h):
 * the kernel, the effect bits it was specialised for, the counting
 * variant, the voxel type, the layout, whether opacity needs correcting
 * (raycast and AO) and whether the volume is a brick pool (raycast). Bits
 * that do not change a kernel are cleared so that variants are shared. */
#define RP_VK_KEY_BRICKED (1u << 6)
#define RP_VK_KEY_CORRECT (1u << 7)
#define RP_VK_KEY_COUNT (1u << 8)
#define RP_VK_KEY_QUAD (1u << 9)
#define RP_VK_KEY_TYPE_SHIFT 10
#define RP_VK_KEY_KERNEL_SHIFT 12

/* The Params block of kernels/common.glsl (a storage buffer, vec4-packed:
 * see there for why it is not a uniform buffer). The AO kernel reads some
 * fields with other meanings (kernels/ao.comp). */
typedef struct rp_vk_params {
  float eye[4];    /* w: 1 for orthographic */
  float fwd[4];    /* w: half_w */
  float right[4];  /* w: half_h */
  float up[4];     /* w: step */
  float dims[4];   /* w: min_spacing */
  float inv_sp[4]; /* w: ert_threshold */
  float vrange[4]; /* value_min, 1/(max-min) or 0, max-min, step/ref_step */
  float ert_a[16]; /* coarse-step opacity of each H-alpha bin */
  uint32_t idims[4];  /* w: lut_size */
  uint32_t blocks[4]; /* w: width */
  uint32_t misc[4];   /* height, ERT grid w, ERT grid h, unused */
  uint32_t seed[4];   /* ert_seed, frame, jitter_seed, jitter */
  uint32_t rect[4];   /* region x0, y0, width, height */
  float box_lo[4];    /* xyz the occupied blocks' box, voxel space */
  float box_hi[4];
  uint32_t brick[4];  /* out-of-core: xyz brick grid, w log2 brick size */
  uint32_t slab[4];   /* out-of-core: slab_flags, slab_cut's bits */
} rp_vk_params;

/* A buffer with its own memory. `map` is the persistent mapping when the
 * memory is host-visible (always coherent), else NULL. */
typedef struct rp_vk_buffer {
  VkBuffer buf;
  VkDeviceMemory mem;
  VkDeviceSize size; /* bytes asked for */
  void *map;
} rp_vk_buffer;

/* What tests read back: pipeline cache and pipeline creation figures. */
typedef struct rp_vk_stats {
  int cache_loaded;          /* 1: a valid cache file was given to the
                                driver at create */
  char cache_reject[96];     /* why a cache file present was ignored */
  size_t cache_bytes;        /* driver data read from the file */
  char cache_path[512];      /* "" when persistence is off */
  uint32_t pipelines_created;
  uint32_t pipeline_cache_hits; /* driver-reported, when it reports */
  uint64_t pipeline_create_ns;  /* host time in vkCreateComputePipelines */
  int quad_layout;           /* the volume's layout (1: quad) */
  uint64_t ao_bytes;         /* device memory held for AO now: the AO
                                volume (compute_ao's buffers are freed
                                before it returns) */
  int timestamps;            /* 1: last_time_ns is device time */
} rp_vk_stats;

typedef struct rp_vk_impl {
  rp_context *ctx;
  VkInstance instance;
  VkPhysicalDevice phys;
  VkDevice dev;
  VkQueue queue;
  uint32_t queue_family;
  VkPhysicalDeviceProperties props;
  VkPhysicalDeviceMemoryProperties mem_props;
  VkDeviceSize max_alloc;    /* maxMemoryAllocationSize */
  int feedback;              /* pipeline creation feedback available */
  uint64_t ts_mask;          /* timestampValidBits as a mask; 0: none */
  VkCommandPool pool;
  VkCommandBuffer cmd;
  VkFence fence;
  VkQueryPool queries;
  VkDescriptorSetLayout set_layout;
  VkPipelineLayout layout;
  VkDescriptorPool desc_pool;
  VkDescriptorSet set;
  VkShaderModule modules[RP_VK_KERNEL_COUNT];
  VkPipelineCache cache;
  /* Guards the variant cache, the stats' pipeline figures and the
   * writes of the fields marked "lock" below (prepare reads them under
   * it; the other ops, their only writers, read them without): the ops'
   * one exception to one thread per impl is `prepare`, which builds on
   * another thread and adds what it built here. Held to look up, insert
   * or copy, never across a build. */
  pthread_mutex_t lock;
  /* Only this impl's own thread evicts (variant_cache.h), so a pipeline
   * it was handed stays valid without the lock until one of its own
   * later lookups replaces it. */
  rp_variant_table variants;
  VkPipeline pipes[RP_VARIANT_CACHE_SIZE]; /* at variants' index */
  /* Inputs: the parameters in host-visible memory (written by every
   * operation), the rest device-local where the device has such memory. */
  rp_vk_buffer params, volume, lut, grid, alpha;
  VkBufferView volume_view, lut_view, grid_view, alpha_view;
  /* Outputs, host-visible: read back after the fence. */
  rp_vk_buffer depth, image, tiles, ert;
  /* The AO volume (upload_ao): one R8 texel per voxel; no buffer while AO
   * is off. compute_ao's inputs and output exist only during the call. */
  rp_vk_buffer ao, ao_out, ao_dirs, ao_bricks;
  VkBufferView ao_view, ao_dirs_view, ao_bricks_view;
  /* Out-of-core (set_brick_pool): `volume` holds the pool, `brick_slots`
   * bricks of brick_bytes in the plain layout, and brick_table the slot
   * of each of the volume's brick_count bricks (an R32 texel each). */
  int bricked;               /* lock */
  uint32_t brick_slots, brick_count;
  VkDeviceSize brick_bytes;
  rp_vk_buffer brick_table;
  VkBufferView brick_table_view;
  /* Depth slabs (raycast with slab_flags other than FIRST | LAST): 32
   * bytes of ray state per pixel of the region, device-local, read and
   * written by the raycast only (kernels/raycast.comp). */
  rp_vk_buffer slab_state;
  /* Stand-ins bound before the real data exists, so that every binding
   * of the set is always valid. */
  rp_vk_buffer dummy;
  VkBufferView dummy_u_view, dummy_f_view;
  rp_voxel_type voxel_type;  /* 0 until a volume is uploaded; lock */
  uint32_t dims[3];          /* the uploaded volume's */
  int have_lut;              /* a transfer function was uploaded */
  int quad;                  /* the uploaded volume's layout; lock */
  /* The frame the device's depth buffer holds (valid when depth_ok). */
  rp_frame_params depth_frame;
  int depth_ok;
  uint64_t occupancy_gen, depth_gen;
  const char *lost;          /* the operation the device was lost in;
                                lock */
  uint64_t last_ns;
  rp_vk_stats stats;
} rp_vk_impl;

/* Test hooks (tests/test_vk_backend.c). All zero: normal operation. */
typedef struct rp_vk_test_hooks {
  int corrupt_kernel;  /* 1 + rp_vk_kernel whose SPIR-V is replaced by a
                          broken module at create; 0: none */
  int force_plain;     /* 1: one voxel per texel even when quad fits */
  int force_staging;   /* 1: upload through a staging copy even into
                          host-visible memory */
  uint32_t ao_chunk_bytes; /* > 0: compute_ao's output bytes per
                              submission at most (slabs tested small) */
} rp_vk_test_hooks;

extern rp_vk_test_hooks rp_vk_hooks;

/* ---- vk_device.c -------------------------------------------------------- */

/* "VK_ERROR_DEVICE_LOST" etc. */
const char *rp_vk__result_name(VkResult r);
/* Records "vulkan: <op>: <name>" and returns the matching code: RP_ENOMEM
 * for the out-of-memory results, RP_ENODEV for a missing driver,
 * RP_EDEVICE otherwise (device lost included). */
int rp_vk__fail(rp_context *ctx, VkResult r, const char *op);
/* Creates the instance; RP_ENODEV when the loader finds no driver. */
int rp_vk__instance(rp_context *ctx, VkInstance *out);
/* The physical devices with a compute queue, in enumeration order. At most
 * `cap` are stored; *count receives how many there are. */
int rp_vk__compute_devices(VkInstance inst, VkPhysicalDevice *list,
                           uint32_t cap, uint32_t *count);
/* Opens device `index` into impl (device, queue, command pool, fence,
 * query pool) and fills caps. */
int rp_vk__open(rp_vk_impl *impl, uint32_t index, rp_caps *caps);
void rp_vk__close(rp_vk_impl *impl);
/* A buffer of `size` bytes. `host` asks for host-visible memory (outputs
 * and staging); otherwise device-local is preferred. RP_ENOMEM names the
 * size and `what`. */
int rp_vk__buffer(rp_vk_impl *impl, const char *what, VkDeviceSize size,
                  VkBufferUsageFlags usage, int host, rp_vk_buffer *out);
void rp_vk__buffer_free(rp_vk_impl *impl, rp_vk_buffer *b);
/* Pipeline cache file: this header, then the driver's data (which starts
 * with its own VkPipelineCacheHeaderVersionOne). */
#define RP_VK_CACHE_MAGIC "RPVKPC01"
typedef struct rp_vk_cache_header {
  char magic[8];
  uint64_t size;     /* bytes of driver data that follow */
  uint64_t checksum; /* rp_vk__fnv1a of them */
} rp_vk_cache_header;
uint64_t rp_vk__fnv1a(const uint8_t *p, size_t n);
/* Pipeline cache: loaded (and validated) at open, saved at close. */
void rp_vk__cache_load(rp_vk_impl *impl);
void rp_vk__cache_save(rp_vk_impl *impl);
/* Checks that `words` looks like a SPIR-V module before a driver sees
 * it; RP_EBUILD naming `what` otherwise. */
int rp_vk__check_spirv(rp_context *ctx, const char *what,
                       const uint32_t *words, size_t bytes);

/* ---- vk_backend.c -------------------------------------------------------- */

/* Figures for tests (impl is the pointer create returned); the pipeline
 * figures are read under the lock, so a prepare may be running. */
void rp_vk_get_stats(void *impl, rp_vk_stats *out);

/* The rest of this header is what the backend's files share; the comment
 * at each definition says more. */

static inline uint32_t rp_vk__div_up(uint32_t a, uint32_t b) {
  return a / b + (a % b != 0);
}

/* A texel view of all of `buf`; rp_vk__free_view takes NULL handles. */
int rp_vk__make_view(rp_vk_impl *impl, VkBuffer buf, VkFormat format,
                     VkBufferView *out);
void rp_vk__free_view(rp_vk_impl *impl, VkBufferView *v);
/* Rewrites the descriptor set: after any buffer is made or freed. */
void rp_vk__bind_all(rp_vk_impl *impl);
/* A storage buffer of at least `size` bytes, kept while large enough. */
int rp_vk__ensure(rp_vk_impl *impl, rp_vk_buffer *b, const char *what,
                  VkDeviceSize size, VkBufferUsageFlags usage, int host);
/* RP_EDEVICE, naming the operation, once the device was lost. */
int rp_vk__alive(rp_vk_impl *impl);
/* One operation's command buffer: rp_vk__begin starts recording (and
 * timing), rp_vk__finish submits it and waits; the barriers go between. */
int rp_vk__begin(rp_vk_impl *impl);
void rp_vk__barrier(rp_vk_impl *impl, VkPipelineStageFlags src,
                    VkAccessFlags src_access, VkPipelineStageFlags dst,
                    VkAccessFlags dst_access);
void rp_vk__after_dispatch(rp_vk_impl *impl);
int rp_vk__finish(rp_vk_impl *impl, const char *op);
/* Fills `dst` through `fill`, staged when it is not mapped. */
int rp_vk__write_buffer(rp_vk_impl *impl, rp_vk_buffer *dst,
                        const char *what,
                        void (*fill)(void *dst, void *user), void *user);
/* A fill for rp_vk__write_buffer that copies `bytes` from `src`. */
typedef struct rp_vk_copy_fill {
  const void *src;
  size_t bytes;
} rp_vk_copy_fill;
void rp_vk__fill_copy(void *dst, void *user);

/* ---- vk_pipeline.c ------------------------------------------------------- */

int rp_vk__make_modules(rp_vk_impl *impl);
/* The variant-cache key of a frame's kernel, and of compute_ao's. */
uint32_t rp_vk__pipeline_key(rp_vk_kernel k, const rp_frame_params *p,
                             int counting, rp_voxel_type type, int quad);
uint32_t rp_vk__ao_pipeline_key(int correct, int quad, rp_voxel_type type);
/* The pipeline for `key`, built on first use (the owner thread's path). */
int rp_vk__get_pipeline(rp_vk_impl *impl, uint32_t key, VkPipeline *out);

/* ---- vk_upload.c --------------------------------------------------------- */

/* The volume's texel format per rp_voxel_type, one voxel per texel. */
extern const VkFormat rp_vk__plain_fmt[4];
/* Whether the device reads `f` from a uniform texel buffer. */
int rp_vk__format_ok(rp_vk_impl *impl, VkFormat f);
void rp_vk__set_volume_state(rp_vk_impl *impl, rp_voxel_type type,
                             int quad, int bricked);
void rp_vk__drop_volume(rp_vk_impl *impl);

/* ---- vk_frame.c ---------------------------------------------------------- */

/* Binds `pipe` and the one descriptor set. */
void rp_vk__bind(rp_vk_impl *impl, VkPipeline pipe);
int rp_vk__check_groups(rp_vk_impl *impl, const char *what, uint32_t gx,
                        uint32_t gy);

/* ---- vk_ao.c ------------------------------------------------------------- */

void rp_vk__drop_ao(rp_vk_impl *impl);

/* ---- the ops (rp_backend_ops says what each does) ------------------------ */

int rp_vk__prepare(void *ip, rp_context *ctx, uint32_t effects);
int rp_vk__upload_volume(void *p, const rp_volume *vol);
int rp_vk__upload_tf(void *p, const float *lut, uint32_t lut_size);
int rp_vk__upload_occupancy(void *p, const uint8_t *grid,
                            const uint8_t *alpha_hist,
                            const uint32_t blocks[3]);
int rp_vk__depth_pass(void *ip, const rp_frame_params *p, float *front_back);
int rp_vk__ert_prepass(void *ip, const rp_frame_params *p, float *d_ert);
int rp_vk__raycast(void *ip, const rp_frame_params *p, const rp_region *r,
                   uint8_t *rgba, rp_tile_stats *tiles, uint64_t *fetches);
int rp_vk__upload_ao(void *p, const uint8_t *ao);
int rp_vk__compute_ao(void *p, const rp_ao_job *job, uint8_t *out);
int rp_vk__set_brick_pool(void *p, const rp_brick_pool *pool);
int rp_vk__upload_bricks(void *p, uint32_t count, const uint32_t *slots,
                         const void *const *voxels, const uint32_t *table);

#endif /* RP_VK_INTERNAL_H */
