/* The Vulkan backend's ambient occlusion: compute_ao runs kernels/ao.comp
 * over a job's box, upload_ao keeps a result for the raycast's RP_AO
 * variant (the design at the top of vk_backend.c). */
#include <string.h>

#include "vk_internal.h"

/* Bytes of compute_ao's output buffer per submission at most: a box whose
 * words need more is computed in slabs of whole brick layers. */
#define RP_VK_AO_CHUNK ((VkDeviceSize)64 << 20)

/* Releases the AO volume: no AO memory while AO is off. */
void rp_vk__drop_ao(rp_vk_impl *impl) {
  if (impl->ao.buf == VK_NULL_HANDLE && impl->ao_view == VK_NULL_HANDLE)
    return;
  rp_vk__free_view(impl, &impl->ao_view);
  rp_vk__buffer_free(impl, &impl->ao);
  impl->stats.ao_bytes = 0;
  rp_vk__bind_all(impl);
}

int rp_vk__upload_ao(void *p, const uint8_t *ao) {
  rp_vk_impl *impl = p;
  uint64_t n = (uint64_t)impl->dims[0] * impl->dims[1] * impl->dims[2];
  rp_vk_copy_fill c;
  int err;
  if (ao == NULL) {
    rp_vk__drop_ao(impl);
    return 0;
  }
  if ((err = rp_vk__alive(impl)) != 0)
    return err;
  if (impl->voxel_type == 0)
    return rp__fail(impl->ctx, RP_ESTATE, "vulkan: an AO volume needs the "
                    "volume it belongs to uploaded first");
  if (impl->bricked)
    return rp__fail(impl->ctx, RP_ESTATE, "vulkan: upload_ao on a brick "
                    "pool (AO needs the whole volume on the device)");
  if (!rp_vk__format_ok(impl, VK_FORMAT_R8_UINT))
    return rp__fail(impl->ctx, RP_EUNSUPPORTED, "vulkan: device cannot "
                    "read bytes from a texel buffer (AO volume)");
  if (impl->ao.buf == VK_NULL_HANDLE || impl->ao.size != n) {
    rp_vk__drop_ao(impl);
    if ((err = rp_vk__buffer(impl, "AO volume", n,
                             VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                 VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                             0, &impl->ao)) != 0 ||
        (err = rp_vk__make_view(impl, impl->ao.buf, VK_FORMAT_R8_UINT,
                                &impl->ao_view)) != 0) {
      rp_vk__drop_ao(impl);
      return err;
    }
    impl->stats.ao_bytes = n;
    rp_vk__bind_all(impl);
  }
  c.src = ao;
  c.bytes = (size_t)n;
  if ((err = rp_vk__write_buffer(impl, &impl->ao, "AO volume staging",
                                 rp_vk__fill_copy, &c)) != 0) {
    /* Half-written data must not be rendered with. */
    rp_vk__drop_ao(impl);
    return err;
  }
  return 0;
}

/* compute_ao's buffers exist only during the call. */
static void ao_scratch_free(rp_vk_impl *impl) {
  rp_vk__free_view(impl, &impl->ao_dirs_view);
  rp_vk__free_view(impl, &impl->ao_bricks_view);
  rp_vk__buffer_free(impl, &impl->ao_out);
  rp_vk__buffer_free(impl, &impl->ao_dirs);
  rp_vk__buffer_free(impl, &impl->ao_bricks);
  rp_vk__bind_all(impl);
}

/* The directions, the brick mask (when there is one) and an output
 * buffer of `out_bytes`. */
static int ao_scratch(rp_vk_impl *impl, const rp_ao_job *job,
                      VkDeviceSize out_bytes) {
  const VkBufferUsageFlags usage = VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                                   VK_BUFFER_USAGE_TRANSFER_DST_BIT;
  rp_vk_copy_fill c;
  int err;
  c.src = job->dirs;
  c.bytes = (size_t)job->directions * 4 * sizeof(float);
  if ((err = rp_vk__buffer(impl, "AO directions", c.bytes, usage, 0,
                           &impl->ao_dirs)) != 0 ||
      (err = rp_vk__make_view(impl, impl->ao_dirs.buf,
                              VK_FORMAT_R32G32B32A32_SFLOAT,
                              &impl->ao_dirs_view)) != 0 ||
      (err = rp_vk__write_buffer(impl, &impl->ao_dirs, "AO directions staging",
                                 rp_vk__fill_copy, &c)) != 0)
    return err;
  if (job->bricks != NULL) {
    c.src = job->bricks;
    c.bytes = (size_t)job->brick_grid[0] * job->brick_grid[1] *
              job->brick_grid[2];
    if ((err = rp_vk__buffer(impl, "AO brick mask", c.bytes, usage, 0,
                             &impl->ao_bricks)) != 0 ||
        (err = rp_vk__make_view(impl, impl->ao_bricks.buf, VK_FORMAT_R8_UINT,
                                &impl->ao_bricks_view)) != 0 ||
        (err = rp_vk__write_buffer(impl, &impl->ao_bricks, "AO brick staging",
                                   rp_vk__fill_copy, &c)) != 0)
      return err;
  }
  if ((err = rp_vk__buffer(impl, "AO output", out_bytes,
                           VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, 1,
                           &impl->ao_out)) != 0)
    return err;
  rp_vk__bind_all(impl);
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
        job->brick_grid[a] != rp_vk__div_up(impl->dims[a], 4))
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

int rp_vk__compute_ao(void *p, const rp_ao_job *job, uint8_t *out) {
  rp_vk_impl *impl = p;
  const uint32_t *lo = job->lo, *end = job->end;
  uint32_t nx, ny, nz, words, bricks_y, layers, z0, z1, y, z;
  VkDeviceSize row_bytes, slab, cap, range, fit;
  uint64_t ns = 0;
  VkPipeline pipe;
  uint32_t key;
  int err;
  if ((err = rp_vk__alive(impl)) != 0 || (err = check_ao_job(impl, job)) != 0)
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
  if ((err = rp_vk__check_groups(impl, "AO", words, bricks_y)) != 0)
    return err;
  if (layers / 4 + 1 > impl->props.limits.maxComputeWorkGroupCount[2])
    layers = (impl->props.limits.maxComputeWorkGroupCount[2] - 1) * 4;
  key = rp_vk__ao_pipeline_key(job->step != job->ref_step, impl->quad,
                               impl->voxel_type);
  if ((err = rp_vk__get_pipeline(impl, key, &pipe)) != 0)
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
    if ((err = rp_vk__begin(impl)) != 0)
      break;
    rp_vk__bind(impl, pipe);
    vkCmdDispatch(impl->cmd, words, bricks_y, (z1 - 1) / 4 - z0 / 4 + 1);
    rp_vk__after_dispatch(impl);
    if ((err = rp_vk__finish(impl, "ambient occlusion")) != 0)
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
