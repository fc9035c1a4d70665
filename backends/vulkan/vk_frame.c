/* The Vulkan backend's frame: the depth pass, the ERT pre-pass and the
 * raycast, each recorded into one command buffer over one parameter block,
 * submitted and waited for. */
#include <string.h>

#include "passes.h"
#include "vk_internal.h"

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

void rp_vk__bind(rp_vk_impl *impl, VkPipeline pipe) {
  vkCmdBindPipeline(impl->cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe);
  vkCmdBindDescriptorSets(impl->cmd, VK_PIPELINE_BIND_POINT_COMPUTE,
                          impl->layout, 0, 1, &impl->set, 0, NULL);
}

/* Records the depth pass over the whole scaled image. */
static void record_depth(rp_vk_impl *impl, VkPipeline pipe,
                         const rp_frame_params *p) {
  rp_vk__bind(impl, pipe);
  vkCmdDispatch(impl->cmd, rp_vk__div_up(p->width, RP_TILE_SIZE),
                rp_vk__div_up(p->height, RP_TILE_SIZE), 1);
  rp_vk__after_dispatch(impl);
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
  return rp_vk__ensure(impl, &impl->depth, "depth buffer", bytes,
                       VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1);
}

/* Whether a grid of gx x gy workgroups can be dispatched at once. */
int rp_vk__check_groups(rp_vk_impl *impl, const char *what, uint32_t gx,
                        uint32_t gy) {
  const uint32_t *max = impl->props.limits.maxComputeWorkGroupCount;
  if (gx > max[0] || gy > max[1])
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: the %s needs "
                    "%ux%u workgroups; the device dispatches at most %ux%u",
                    what, gx, gy, max[0], max[1]);
  return 0;
}

int rp_vk__depth_pass(void *ip, const rp_frame_params *p, float *front_back) {
  rp_vk_impl *impl = ip;
  VkPipeline pipe;
  int err;
  if ((err = rp_vk__alive(impl)) != 0 ||
      (err = rp_vk__check_groups(
           impl, "depth pass", rp_vk__div_up(p->width, RP_TILE_SIZE),
           rp_vk__div_up(p->height, RP_TILE_SIZE))) != 0 ||
      (err = ensure_depth(impl, p)) != 0 ||
      (err = rp_vk__get_pipeline(
           impl, rp_vk__pipeline_key(RP_VK_DEPTH, p, 0, 0, 0), &pipe)) != 0)
    return err;
  set_params(impl, p);
  impl->depth_ok = 0;
  if ((err = rp_vk__begin(impl)) != 0)
    return err;
  record_depth(impl, pipe, p);
  if ((err = rp_vk__finish(impl, "depth pass")) != 0)
    return err;
  impl->depth_frame = *p;
  impl->depth_gen = impl->occupancy_gen;
  impl->depth_ok = 1;
  if (front_back != NULL)
    memcpy(front_back, impl->depth.map,
           (size_t)p->width * p->height * 2 * sizeof(float));
  return 0;
}

int rp_vk__ert_prepass(void *ip, const rp_frame_params *p, float *d_ert) {
  rp_vk_impl *impl = ip;
  VkPipeline pipe;
  uint32_t gw, gh;
  int err;
  rp__ert_grid(p->width, p->height, &gw, &gh);
  if ((err = rp_vk__alive(impl)) != 0 ||
      (err = rp_vk__check_groups(impl, "ERT pre-pass", rp_vk__div_up(gw, 8),
                                 rp_vk__div_up(gh, 8))) != 0 ||
      (err = rp_vk__ensure(impl, &impl->ert, "ERT result",
                           (VkDeviceSize)gw * gh * sizeof(float),
                           VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1)) != 0 ||
      (err = rp_vk__get_pipeline(
           impl, rp_vk__pipeline_key(RP_VK_ERT, p, 0, 0, 0), &pipe)) != 0)
    return err;
  set_params(impl, p);
  if ((err = rp_vk__begin(impl)) != 0)
    return err;
  set_rect(impl, 0, 0, gw, gh);
  rp_vk__bind(impl, pipe);
  vkCmdDispatch(impl->cmd, rp_vk__div_up(gw, 8), rp_vk__div_up(gh, 8), 1);
  rp_vk__after_dispatch(impl);
  if ((err = rp_vk__finish(impl, "ERT pre-pass")) != 0)
    return err;
  memcpy(d_ert, impl->ert.map, (size_t)gw * gh * sizeof(float));
  return 0;
}

int rp_vk__raycast(void *ip, const rp_frame_params *p, const rp_region *r,
                   uint8_t *rgba, rp_tile_stats *tiles, uint64_t *fetches) {
  rp_vk_impl *impl = ip;
  uint32_t rw = r->x1 - r->x0, rh = r->y1 - r->y0;
  uint32_t ntx = rp_vk__div_up(rw, RP_TILE_SIZE),
           nty = rp_vk__div_up(rh, RP_TILE_SIZE);
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
  if ((err = rp_vk__alive(impl)) != 0)
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
  if ((err = rp_vk__check_groups(impl, "raycast", ntx, nty)) != 0 ||
      (skip && (err = rp_vk__check_groups(
                    impl, "depth pass", rp_vk__div_up(p->width, RP_TILE_SIZE),
                    rp_vk__div_up(p->height, RP_TILE_SIZE))) != 0))
    return err;
  /* The front end runs the depth pass first; a caller that did not (a
   * test driving the ops) gets one recorded ahead of the raycast. */
  redo_depth = skip && !depth_current(impl, p);
  if ((redo_depth && (err = ensure_depth(impl, p)) != 0) ||
      (err = rp_vk__ensure(impl, &impl->image, "image",
                           (VkDeviceSize)rw * rh * 4,
                           VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1)) != 0 ||
      (err = rp_vk__ensure(impl, &impl->tiles, "tile statistics",
                           (VkDeviceSize)ntx * nty * 4 * sizeof(uint32_t),
                           VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1)) != 0 ||
      (slabs &&
       (err = rp_vk__ensure(impl, &impl->slab_state,
                            "depth slabs' ray state",
                            (VkDeviceSize)rw * rh * 32,
                            VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 0)) != 0) ||
      (err = rp_vk__get_pipeline(
           impl,
           rp_vk__pipeline_key(RP_VK_RAYCAST, p, fetches != NULL,
                               impl->voxel_type, impl->quad),
           &cast)) != 0 ||
      (redo_depth &&
       (err = rp_vk__get_pipeline(
            impl, rp_vk__pipeline_key(RP_VK_DEPTH, p, 0, 0, 0), &depth)) != 0))
    return err;
  set_params(impl, p);
  if ((err = rp_vk__begin(impl)) != 0)
    return err;
  if (redo_depth) {
    impl->depth_ok = 0;
    record_depth(impl, depth, p);
  }
  set_rect(impl, r->x0, r->y0, rw, rh);
  rp_vk__bind(impl, cast);
  vkCmdDispatch(impl->cmd, ntx, nty, 1);
  rp_vk__after_dispatch(impl);
  if ((err = rp_vk__finish(impl, "raycast")) != 0)
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
