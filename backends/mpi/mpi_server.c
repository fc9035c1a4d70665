/* The MPI backend on ranks >= 1: rp_mpi_serve runs rank 0's requests on
 * this rank's local device (raypace_mpi.h, protocol in mpi_internal.h).
 *
 * One request at a time, in order: receive it (its header, then its
 * payload), check it against the protocol and against what this session
 * has uploaded (the backend trusts its inputs; a request is the one input
 * from outside the process), run the op on the local backend's ops, and
 * reply. A heartbeat thread tells rank 0 the rank is alive while an op
 * runs. The local device is opened at the first session's open and kept
 * between sessions (a session: rank 0's proxy device from open to close),
 * so kernels built for one session serve the next. */
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <uv.h>

#include "bricks.h"
#include "mpi_internal.h"
#include "raypace_ao.h"
#include "raypace_mpi.h"

typedef struct server {
  rp_context *ctx;
  int rank;
  const char *backend; /* rp_mpi_serve's */
  uint32_t device;     /* its index within the backend (RP_MPI_DEVICE) */
  int tried;           /* the device was opened, or failed to open */
  const rp_backend_ops *ops; /* NULL: not open */
  void *impl;
  rp_caps caps;
  int open_err;
  char open_msg[RP__ERRMSG_MAX];
  /* The session's scene, what later requests are checked against. */
  uint64_t voxels;      /* of the uploaded volume; 0: none */
  uint64_t brick_bytes; /* of the pool's bricks; 0: no pool */
  uint64_t brick_count;
  uint32_t slots;
  /* and the shapes a frame's parameters must match, since the kernels
   * index the device's buffers with them: the volume's (or pool's)
   * dims, the pool's brick shift (0: a whole volume) and grid, the LUT's
   * size and the occupancy grid (0: not uploaded). */
  uint32_t dims[3], brick_shift, grid[3], lut_size, blocks[3];
  /* Raycast scratch: the backend writes a region into whole-image
   * buffers. */
  uint8_t *rgba;
  size_t rgba_cap;
  rp_tile_stats *tiles;
  size_t tiles_cap;
  uint64_t *fetches;
  size_t fetches_cap;
  /* Testing knobs (RP_MPI_DIE_AT, RP_MPI_STALL_AT, RP_MPI_STALL_MS). */
  uint32_t raycasts, die_at, stall_at;
  double stall_ms;
  /* The heartbeat, under beat_lock: sent while `busy`, for busy_seq. */
  uv_thread_t beat_thread;
  uv_mutex_t beat_lock;
  uv_cond_t beat_cond;
  int beat_started, busy, quit;
  uint32_t busy_seq;
} server;

/* ---- Heartbeat ------------------------------------------------------------- */

/* The beat's buffer is static, not the server's: a beat send still
 * pending when the server ends may read it later. */
static uint32_t beat_value;

static void beat_main(void *arg) {
  server *s = arg;
  MPI_Request req = MPI_REQUEST_NULL;
  uv_mutex_lock(&s->beat_lock);
  while (!s->quit) {
    (void)uv_cond_timedwait(&s->beat_cond, &s->beat_lock,
                            (uint64_t)RP_MPI_BEAT_MS * 1000000u);
    if (s->quit || !s->busy)
      continue;
    rp_mpi__lock();
    {
      int done = 1;
      if (req != MPI_REQUEST_NULL &&
          MPI_Test(&req, &done, MPI_STATUS_IGNORE) != MPI_SUCCESS)
        done = 0;
      /* One beat in flight at most: a rank 0 that is not listening gets
       * no pile of them. */
      if (done) {
        beat_value = s->busy_seq;
        if (MPI_Isend(&beat_value, 1, MPI_UINT32_T, 0, RP_MPI_TAG_BEAT,
                      rp_mpi__comm(), &req) != MPI_SUCCESS)
          req = MPI_REQUEST_NULL;
      }
    }
    rp_mpi__unlock();
  }
  uv_mutex_unlock(&s->beat_lock);
  if (req != MPI_REQUEST_NULL) {
    rp_mpi__lock();
    MPI_Request_free(&req);
    rp_mpi__unlock();
  }
}

static void set_busy(server *s, int busy, uint32_t seq) {
  uv_mutex_lock(&s->beat_lock);
  s->busy = busy;
  s->busy_seq = seq;
  uv_mutex_unlock(&s->beat_lock);
}

/* ---- Receiving and replying ------------------------------------------------ */

/* How long a reply's sends may stay pending once rank 0 has sent its
 * next request: normally the last chunk's completion is only waiting for
 * this rank's next progress call. */
#define REPLY_GRACE_MS 1000.0

/* Polls x until its requests are done. With `watch`, also stops (returns
 * 1) when a new request from rank 0 has been waiting for REPLY_GRACE_MS:
 * rank 0 sends its next request after taking this reply whole, or
 * without taking it when it has given this rank up, and then it can only
 * be a shutdown. 0 when done, -1 on an MPI error (why says it). */
static int wait_xfer(rp_mpi__xfer *x, int watch, char *why, size_t size) {
  double seen = -1.0;
  uint32_t us = 0;
  for (;;) {
    int done = 0, progress = 0, rc, flag = 0;
    if ((rc = rp_mpi__test(x, &done, &progress)) != MPI_SUCCESS) {
      char msg[MPI_MAX_ERROR_STRING];
      rp_mpi__error_string(rc, msg, sizeof msg);
      snprintf(why, size, "%s", msg);
      return -1;
    }
    if (done)
      return 0;
    if (watch && seen < 0.0) {
      rp_mpi__lock();
      rc = MPI_Iprobe(0, RP_MPI_TAG_REQUEST, rp_mpi__comm(), &flag,
                      MPI_STATUS_IGNORE);
      rp_mpi__unlock();
      if (rc == MPI_SUCCESS && flag)
        seen = rp_mpi__now_ms();
    }
    if (seen >= 0.0 && rp_mpi__now_ms() - seen > REPLY_GRACE_MS)
      return 1;
    rp_mpi__backoff(&us, progress || seen >= 0.0 ? 50 : 1000);
  }
}

/* Receives and discards `bytes` of request payload in its chunks, one at
 * a time through a chunk-sized buffer: what a request whose payload this
 * rank cannot hold (or read) costs, so that rank 0's sends complete and
 * the next request is read from the start. -1 when even that fails. */
static int drain(size_t bytes, char *why, size_t size) {
  size_t left = bytes, n = bytes < RP_MPI_CHUNK ? bytes : RP_MPI_CHUNK;
  rp_mpi__xfer *x = rp_mpi__xfer_new(0);
  void *sink = malloc(n > 0 ? n : 1);
  int rc = 0;
  if (x == NULL || sink == NULL) {
    snprintf(why, size, "no memory to receive the request's payload");
    rp_mpi__xfer_free(x);
    free(sink);
    return -1;
  }
  /* The transfer owns the sink: a receive that matched cannot be
   * cancelled, so an abandoned one keeps its buffer until MPI ends. */
  x->in = sink;
  x->in_bytes = n;
  while (left > 0 && rc == 0) {
    size_t c = left < RP_MPI_CHUNK ? left : RP_MPI_CHUNK;
    if (rp_mpi__post(x, 0, sink, c, RP_MPI_TAG_REQUEST_DATA) !=
        MPI_SUCCESS) {
      snprintf(why, size, "MPI failed receiving the request's payload");
      rc = -1;
    } else {
      rc = wait_xfer(x, 0, why, size);
    }
    left -= c;
  }
  if (rc != 0)
    rp_mpi__abandon(x);
  else
    rp_mpi__xfer_free(x);
  return rc;
}

/* The next request from rank 0 into *out (header, and payload in `in`).
 * A payload that cannot be held is drained and *refused set (RP_ENOMEM,
 * RP_EINVAL: the request is answered with it, not run). 0, or -1 when
 * MPI failed (why). */
static int next_request(rp_mpi__xfer **out, int *refused, char *why,
                        size_t size, server *s) {
  rp_mpi__xfer *x = rp_mpi__xfer_new(0);
  rp_mpi__layout l;
  *out = NULL;
  *refused = 0;
  if (x == NULL) {
    snprintf(why, size, "no memory for a request");
    return -1;
  }
  if (rp_mpi__post(x, 0, &x->req, sizeof x->req, RP_MPI_TAG_REQUEST) !=
          MPI_SUCCESS ||
      wait_xfer(x, 0, why, size) != 0) {
    if (why[0] == '\0')
      snprintf(why, size, "MPI failed receiving a request");
    rp_mpi__abandon(x);
    return -1;
  }
  *out = x;
  if (x->req.magic != RP_MPI_MAGIC) {
    /* Nothing that follows can be trusted to be read right. */
    snprintf(why, size, "a request without the protocol's magic number");
    return -1;
  }
  if (x->req.op == RP_MPI_SHUTDOWN)
    return 0;
  set_busy(s, 1, x->req.seq);
  if (rp_mpi__request_layout(&x->req, &l) != 0 ||
      l.total != x->req.payload_bytes) {
    *refused = RP_EINVAL;
    return drain(x->req.payload_bytes, why, size);
  }
  if (l.total == 0)
    return 0;
  if ((x->in = malloc(l.total)) == NULL) {
    *refused = RP_ENOMEM;
    return drain(l.total, why, size);
  }
  x->in_bytes = l.total;
  if (rp_mpi__post(x, 0, x->in, l.total, RP_MPI_TAG_REQUEST_DATA) !=
          MPI_SUCCESS ||
      wait_xfer(x, 0, why, size) != 0) {
    if (why[0] == '\0')
      snprintf(why, size, "MPI failed receiving a request's payload");
    return -1;
  }
  return 0;
}

/* Sends x's reply (rep, and out when the status is 0). 0 when it went,
 * 1 when rank 0 gave up on it (x is abandoned then), -1 on an MPI
 * error. */
static int reply(rp_mpi__xfer *x, char *why, size_t size) {
  int rc;
  x->rep.magic = RP_MPI_MAGIC;
  x->rep.op = x->req.op;
  x->rep.seq = x->req.seq;
  x->rep.payload_bytes = x->rep.status == 0 ? x->out_bytes : 0;
  if (rp_mpi__post(x, 1, &x->rep, sizeof x->rep, RP_MPI_TAG_REPLY) !=
          MPI_SUCCESS ||
      (x->rep.payload_bytes > 0 &&
       rp_mpi__post(x, 1, x->out, x->out_bytes, RP_MPI_TAG_REPLY_DATA) !=
           MPI_SUCCESS)) {
    snprintf(why, size, "MPI failed sending a reply");
    rp_mpi__abandon(x);
    return -1;
  }
  rc = wait_xfer(x, 1, why, size);
  if (rc != 0)
    rp_mpi__abandon(x);
  return rc;
}

/* ---- Ops -------------------------------------------------------------------- */

static int fail(server *s, int err, const char *fmt, const char *detail) {
  return rp__fail(s->ctx, err, fmt, detail);
}

/* Allocates the reply's payload by the request's reply layout. */
static int reply_buffer(server *s, rp_mpi__xfer *x, rp_mpi__layout *l) {
  if (rp_mpi__reply_layout(&x->req, l) != 0)
    return fail(s, RP_ERANGE, "%s: the reply is too large to address",
                rp_mpi__op_name(x->req.op));
  if (l->total == 0)
    return 0;
  if ((x->out = malloc(l->total)) == NULL)
    return rp__fail(s->ctx, RP_ENOMEM, "no memory for a %zu-byte reply",
                    l->total);
  x->out_bytes = l->total;
  return 0;
}

static int grow(server *s, void **buf, size_t *cap, size_t bytes) {
  void *p;
  if (bytes <= *cap)
    return 0;
  if ((p = malloc(bytes)) == NULL)
    return rp__fail(s->ctx, RP_ENOMEM, "no memory for a %zu-byte image "
                    "buffer", bytes);
  free(*buf);
  *buf = p;
  *cap = bytes;
  return 0;
}

static void sleep_ms(double ms) {
  struct timespec ts;
  ts.tv_sec = (time_t)(ms / 1000.0);
  ts.tv_nsec = (long)((ms - (double)ts.tv_sec * 1000.0) * 1e6);
  while (nanosleep(&ts, &ts) != 0)
    ; /* interrupted: sleep the rest */
}

static int check_open(server *s, const rp_mpi_open_args *a) {
  if (a->abi == RP_BACKEND_ABI && a->frame_bytes == sizeof(rp_frame_params) &&
      a->tile_bytes == sizeof(rp_tile_stats) &&
      a->caps_bytes == sizeof(rp_caps) &&
      a->pool_bytes == sizeof(rp_brick_pool) &&
      a->request_bytes == sizeof(rp_mpi_request))
    return 0;
  return rp__fail(s->ctx, RP_EUNSUPPORTED, "rank 0 speaks backend ABI %u "
                  "(frame %u, tile %u, caps %u, pool %u, request %u bytes), "
                  "this rank ABI %d (%zu, %zu, %zu, %zu, %zu): every rank "
                  "must run the same raypace build", a->abi, a->frame_bytes,
                  a->tile_bytes, a->caps_bytes, a->pool_bytes,
                  a->request_bytes, RP_BACKEND_ABI, sizeof(rp_frame_params),
                  sizeof(rp_tile_stats), sizeof(rp_caps),
                  sizeof(rp_brick_pool), sizeof(rp_mpi_request));
}

/* The session's scene is gone (open, close, a failed upload). */
static void forget_scene(server *s) {
  s->voxels = s->brick_bytes = s->brick_count = 0;
  s->slots = s->brick_shift = s->lut_size = 0;
  memset(s->dims, 0, sizeof s->dims);
  memset(s->grid, 0, sizeof s->grid);
  memset(s->blocks, 0, sizeof s->blocks);
}

static int same3(const uint32_t a[3], const uint32_t b[3]) {
  return a[0] == b[0] && a[1] == b[1] && a[2] == b[2];
}

/* A frame must describe the scene this session uploaded and a region
 * inside its image: the backend trusts both. */
static int check_frame(server *s, const rp_mpi_frame_args *f, int raycast) {
  const rp_region *r = &f->region;
  const rp_frame_params *p = &f->p;
  if (s->voxels == 0 && s->brick_bytes == 0)
    return rp__fail(s->ctx, RP_ESTATE, "a frame without a volume");
  if (!same3(p->idims, s->dims) || p->brick_shift != s->brick_shift ||
      (s->brick_shift != 0 && !same3(p->brick_grid, s->grid)) ||
      (s->lut_size != 0 && p->lut_size != s->lut_size) ||
      (s->blocks[0] != 0 && !same3(p->blocks, s->blocks)))
    return rp__fail(s->ctx, RP_EINVAL, "a frame of a %ux%ux%u volume "
                    "(brick shift %u, LUT %u, blocks %ux%ux%u) for the "
                    "uploaded %ux%ux%u (brick shift %u, LUT %u, blocks "
                    "%ux%ux%u)", p->idims[0], p->idims[1], p->idims[2],
                    p->brick_shift, p->lut_size, p->blocks[0], p->blocks[1],
                    p->blocks[2], s->dims[0], s->dims[1], s->dims[2],
                    s->brick_shift, s->lut_size, s->blocks[0], s->blocks[1],
                    s->blocks[2]);
  if (f->p.width == 0 || f->p.height == 0 || f->p.width > 65536 ||
      f->p.height > 65536)
    return rp__fail(s->ctx, RP_EINVAL, "an image of %ux%u rays",
                    f->p.width, f->p.height);
  if (raycast && !(r->x0 < r->x1 && r->x1 <= f->p.width && r->y0 < r->y1 &&
                   r->y1 <= f->p.height && r->x0 % RP_TILE_SIZE == 0 &&
                   r->y0 % RP_TILE_SIZE == 0))
    return rp__fail(s->ctx, RP_EINVAL, "region [%u,%u)x[%u,%u) is not on "
                    "the tile grid of the %ux%u image", r->x0, r->x1, r->y0,
                    r->y1, f->p.width, f->p.height);
  return 0;
}

static int op_raycast(server *s, rp_mpi__xfer *x) {
  const rp_mpi_frame_args *f = &x->req.a.frame;
  const rp_region *r = &f->region;
  uint32_t tx0, ty0, tw, th, tiles_x, tiles_y, y;
  size_t px, tiles, rw = r->x1 - r->x0;
  rp_mpi__layout l;
  uint8_t *out;
  int err;
  if ((err = check_frame(s, f, 1)) != 0)
    return err;
  rp_tile_grid(f->p.width, f->p.height, &tiles_x, &tiles_y);
  px = (size_t)f->p.width * f->p.height;
  tiles = (size_t)tiles_x * tiles_y;
  if ((err = grow(s, (void **)&s->rgba, &s->rgba_cap, px * 4)) != 0 ||
      (err = grow(s, (void **)&s->tiles, &s->tiles_cap,
                  tiles * sizeof *s->tiles)) != 0 ||
      ((f->want & RP_MPI_WANT_FETCHES) &&
       (err = grow(s, (void **)&s->fetches, &s->fetches_cap,
                   tiles * sizeof *s->fetches)) != 0) ||
      (err = reply_buffer(s, x, &l)) != 0)
    return err;
  s->raycasts++;
  if (s->die_at != 0 && s->raycasts == s->die_at) {
    fprintf(stderr, "raypace: rank %d: dying at raycast %u "
                    "(RP_MPI_DIE_AT)\n", s->rank, s->raycasts);
    fflush(stderr);
    raise(SIGKILL);
  }
  if ((err = s->ops->raycast(
           s->impl, &f->p, r, s->rgba,
           (f->want & RP_MPI_WANT_TILES) ? s->tiles : NULL,
           (f->want & RP_MPI_WANT_FETCHES) ? s->fetches : NULL)) != 0)
    return err;
  if (s->stall_at != 0 && s->raycasts == s->stall_at)
    sleep_ms(s->stall_ms);
  /* The region's rows, compact, as the layout has them. */
  rp_mpi__region_tiles(r, &tx0, &ty0, &tw, &th);
  out = x->out;
  for (y = r->y0; y < r->y1; y++)
    memcpy(out + l.off[0] + (size_t)(y - r->y0) * rw * 4,
           s->rgba + ((size_t)y * f->p.width + r->x0) * 4, rw * 4);
  for (y = 0; y < th && (f->want & RP_MPI_WANT_TILES); y++)
    memcpy(out + l.off[1] + (size_t)y * tw * sizeof *s->tiles,
           s->tiles + (size_t)(ty0 + y) * tiles_x + tx0,
           tw * sizeof *s->tiles);
  for (y = 0; y < th && (f->want & RP_MPI_WANT_FETCHES); y++)
    memcpy(out + l.off[(f->want & RP_MPI_WANT_TILES) ? 2 : 1] +
               (size_t)y * tw * sizeof *s->fetches,
           s->fetches + (size_t)(ty0 + y) * tiles_x + tx0,
           tw * sizeof *s->fetches);
  return 0;
}

static int op_upload_volume(server *s, rp_mpi__xfer *x) {
  const rp_mpi_volume_args *a = &x->req.a.volume;
  rp_volume v;
  uint64_t n = (uint64_t)a->dims[0] * a->dims[1];
  int i, err;
  if (a->dims[0] == 0 || a->dims[1] == 0 || a->dims[2] == 0 ||
      n > UINT64_MAX / a->dims[2] || n * a->dims[2] != a->voxels)
    return rp__fail(s->ctx, RP_EINVAL, "a volume of %ux%ux%u voxels said "
                    "to hold %llu", a->dims[0], a->dims[1], a->dims[2],
                    (unsigned long long)a->voxels);
  memset(&v, 0, sizeof v);
  v.ctx = s->ctx;
  for (i = 0; i < 3; i++) {
    v.dims[i] = a->dims[i];
    v.spacing[i] = a->spacing[i];
  }
  v.type = (rp_voxel_type)a->type; /* checked by the layout */
  v.min = a->min;
  v.max = a->max;
  v.voxel_count = (size_t)a->voxels;
  v.data = x->in;
  /* Until this upload succeeds no frame is run: after a failure the
   * front end holds no volume either. */
  forget_scene(s);
  if ((err = s->ops->upload_volume(s->impl, &v)) != 0)
    return err;
  s->voxels = a->voxels;
  memcpy(s->dims, a->dims, sizeof s->dims);
  return 0;
}

static int op_compute_ao(server *s, rp_mpi__xfer *x) {
  const rp_mpi_ao_args *a = &x->req.a.ao;
  rp_mpi__layout in, out;
  rp_ao_job job;
  int i, err;
  if (s->ops->compute_ao == NULL)
    return rp__fail(s->ctx, RP_EUNSUPPORTED, "backend '%s' cannot compute "
                    "ambient occlusion", s->caps.backend);
  if (s->voxels == 0)
    return rp__fail(s->ctx, RP_ESTATE, "compute_ao without a volume");
  for (i = 0; i < 3; i++)
    if (a->job.lo[i] >= a->job.end[i])
      return rp__fail(s->ctx, RP_EINVAL, "an empty AO box along axis %d",
                      i);
  if ((err = reply_buffer(s, x, &out)) != 0)
    return err;
  (void)rp_mpi__request_layout(&x->req, &in); /* checked on receipt */
  job = a->job;
  job.dirs = (const float *)((const char *)x->in + in.off[0]);
  job.bricks = a->has_bricks ? (const uint8_t *)x->in + in.off[1] : NULL;
  return s->ops->compute_ao(s->impl, &job, x->out);
}

static int op_set_brick_pool(server *s, rp_mpi__xfer *x) {
  const rp_mpi_pool_args *a = &x->req.a.pool;
  const rp_brick_pool *p = &a->pool;
  uint64_t e, count = 0;
  uint32_t grid[3], shift = 0;
  int err, ok;
  if (s->ops->set_brick_pool == NULL)
    return rp__fail(s->ctx, RP_EUNSUPPORTED, "backend '%s' cannot hold a "
                    "volume as bricks", s->caps.backend);
  /* The same rules as rp_device_create and rp_device_set_volume: the
   * backends size their buffers from these. */
  ok = !a->present ||
       (p->brick_size >= 8 && p->brick_size <= 256 &&
        (p->brick_size & (p->brick_size - 1)) == 0 && p->dims[0] != 0 &&
        p->dims[1] != 0 && p->dims[2] != 0 &&
        (p->type == RP_U8 || p->type == RP_U16 || p->type == RP_F32));
  if (ok && a->present) {
    rp__bricks_grid(p->dims, p->brick_size, grid);
    count = (uint64_t)grid[0] * grid[1] * grid[2];
    ok = same3(grid, p->grid) && p->slots >= 2 && p->slots <= count + 1;
    while ((1u << shift) < p->brick_size)
      shift++;
  }
  if (!ok)
    return rp__fail(s->ctx, RP_EINVAL, "a brick pool of %u slots of "
                    "bricks of %u voxels, grid %ux%ux%u, for a %ux%ux%u "
                    "volume", p->slots, p->brick_size, p->grid[0],
                    p->grid[1], p->grid[2], p->dims[0], p->dims[1],
                    p->dims[2]);
  /* The volume is gone, replaced by the pool or released. */
  forget_scene(s);
  if ((err = s->ops->set_brick_pool(s->impl, a->present ? p : NULL)) != 0)
    return err;
  if (a->present) {
    e = (uint64_t)p->brick_size + 1;
    s->brick_bytes = e * e * e * rp__voxel_size(p->type);
    s->brick_count = count;
    s->slots = p->slots;
    s->brick_shift = shift;
    memcpy(s->dims, p->dims, sizeof s->dims);
    memcpy(s->grid, p->grid, sizeof s->grid);
  }
  return 0;
}

static int op_upload_bricks(server *s, rp_mpi__xfer *x) {
  const rp_mpi_bricks_args *a = &x->req.a.bricks;
  rp_mpi__layout l;
  const uint32_t *slots;
  const void **voxels;
  uint32_t i;
  int err;
  if (s->brick_bytes == 0)
    return rp__fail(s->ctx, RP_ESTATE, "upload_bricks without a brick "
                    "pool");
  if (a->brick_bytes != s->brick_bytes || a->table_entries != s->brick_count)
    return rp__fail(s->ctx, RP_EINVAL, "bricks of %llu bytes and a table "
                    "of %llu entries for a pool of %llu and %llu",
                    (unsigned long long)a->brick_bytes,
                    (unsigned long long)a->table_entries,
                    (unsigned long long)s->brick_bytes,
                    (unsigned long long)s->brick_count);
  (void)rp_mpi__request_layout(&x->req, &l); /* checked on receipt */
  slots = (const uint32_t *)((const char *)x->in + l.off[0]);
  for (i = 0; i < a->count; i++)
    if (slots[i] >= s->slots)
      return rp__fail(s->ctx, RP_EINVAL, "brick slot %u of a pool of %u",
                      slots[i], s->slots);
  if (a->has_table) {
    const uint32_t *table = (const uint32_t *)((const char *)x->in + l.off[2]);
    uint64_t k;
    for (k = 0; k < a->table_entries; k++)
      if (table[k] >= s->slots)
        return rp__fail(s->ctx, RP_EINVAL, "brick %llu in slot %u of a "
                        "pool of %u", (unsigned long long)k, table[k],
                        s->slots);
  }
  if ((voxels = malloc((a->count > 0 ? a->count : 1) * sizeof *voxels)) ==
      NULL)
    return rp__fail(s->ctx, RP_ENOMEM, "no memory for %u bricks",
                    a->count);
  for (i = 0; i < a->count; i++)
    voxels[i] = (const char *)x->in + l.off[1] + (size_t)i * s->brick_bytes;
  err = s->ops->upload_bricks(
      s->impl, a->count, slots, voxels,
      a->has_table ? (const uint32_t *)((const char *)x->in + l.off[2])
                   : NULL);
  free(voxels);
  return err;
}

/* Opens the local device, once: at rank 0's first open of this rank, so
 * that a rank that rank 0 never opens starts no driver, and a slow driver
 * start-up happens while the heartbeat runs. A device that does not open
 * is not tried again; every open is answered with why. */
static void open_device(server *s) {
  int err;
  s->tried = 1;
  if ((err = rp__backend_open(s->ctx, s->backend, s->device, &s->ops,
                              &s->impl, &s->caps)) != 0) {
    s->ops = NULL;
    s->open_err = err;
    snprintf(s->open_msg, sizeof s->open_msg, "rank %d, device %u "
             "(RP_MPI_DEVICE): %s", s->rank, s->device,
             rp_last_error(s->ctx));
  }
}

/* Runs request x on the local device; its status, message and time go
 * into x->rep, its outputs into x->out. */
static void run(server *s, rp_mpi__xfer *x, int refused) {
  const rp_mpi_request *q = &x->req;
  const char *op = rp_mpi__op_name(q->op);
  rp_mpi__layout l;
  int err = 0;
  rp__clear_error(s->ctx);
  if (refused != 0) {
    err = rp__fail(s->ctx, refused, refused == RP_ENOMEM
                   ? "no memory for the request's %llu-byte payload"
                   : "the request's %llu-byte payload does not fit its "
                     "arguments", (unsigned long long)q->payload_bytes);
  } else if (q->op == RP_MPI_OPEN) {
    if ((err = check_open(s, &q->a.open)) == 0 && !s->tried)
      open_device(s);
    if (err == 0 && s->ops == NULL)
      err = rp__fail(s->ctx, s->open_err, "%s", s->open_msg);
    if (err == 0) {
      x->rep.caps = s->caps;
      forget_scene(s);
    }
  } else if (s->ops == NULL) {
    err = s->tried ? rp__fail(s->ctx, s->open_err, "%s", s->open_msg)
                   : fail(s, RP_ESTATE, "%s before open", op);
  } else {
    switch (q->op) {
    case RP_MPI_CLOSE:
      /* The device stays open for the next session; its memory goes. */
      if (s->ops->upload_ao != NULL)
        (void)s->ops->upload_ao(s->impl, NULL);
      if (s->ops->set_brick_pool != NULL)
        (void)s->ops->set_brick_pool(s->impl, NULL);
      forget_scene(s);
      break;
    case RP_MPI_UPLOAD_VOLUME:
      err = op_upload_volume(s, x);
      break;
    case RP_MPI_UPLOAD_TF:
      err = q->a.tf.lut_size < 2
                ? fail(s, RP_EINVAL, "%s: a LUT of fewer than 2 entries", op)
                : s->ops->upload_tf(s->impl, x->in, q->a.tf.lut_size);
      s->lut_size = err == 0 ? q->a.tf.lut_size : 0;
      break;
    case RP_MPI_UPLOAD_OCCUPANCY:
      (void)rp_mpi__request_layout(q, &l);
      err = s->ops->upload_occupancy(s->impl, x->in,
                                     (const uint8_t *)x->in + l.off[1],
                                     q->a.occupancy.blocks);
      if (err == 0)
        memcpy(s->blocks, q->a.occupancy.blocks, sizeof s->blocks);
      else
        memset(s->blocks, 0, sizeof s->blocks);
      break;
    case RP_MPI_DEPTH_PASS:
      if ((err = check_frame(s, &q->a.frame, 0)) == 0 &&
          (err = reply_buffer(s, x, &l)) == 0)
        err = s->ops->depth_pass(s->impl, &q->a.frame.p,
                                 l.total > 0 ? x->out : NULL);
      break;
    case RP_MPI_ERT_PREPASS:
      if ((err = check_frame(s, &q->a.frame, 0)) == 0 &&
          (err = reply_buffer(s, x, &l)) == 0)
        err = s->ops->ert_prepass(s->impl, &q->a.frame.p, x->out);
      break;
    case RP_MPI_RAYCAST:
      err = op_raycast(s, x);
      break;
    case RP_MPI_COMPUTE_AO:
      err = op_compute_ao(s, x);
      break;
    case RP_MPI_UPLOAD_AO:
      if (s->ops->upload_ao == NULL)
        err = fail(s, RP_EUNSUPPORTED, "%s: the backend has no AO", op);
      else if (q->a.upload_ao.present && q->a.upload_ao.bytes != s->voxels)
        err = fail(s, RP_EINVAL, "%s: not one byte per voxel of the "
                   "volume", op);
      else
        err = s->ops->upload_ao(s->impl, q->a.upload_ao.present ? x->in
                                                                : NULL);
      break;
    case RP_MPI_SET_BRICK_POOL:
      err = op_set_brick_pool(s, x);
      break;
    case RP_MPI_UPLOAD_BRICKS:
      err = op_upload_bricks(s, x);
      break;
    default:
      err = fail(s, RP_EINVAL, "unknown request '%s'", op);
      break;
    }
  }
  x->rep.status = err;
  x->rep.last_ns = err == 0 && s->ops != NULL && q->op != RP_MPI_OPEN &&
                           q->op != RP_MPI_CLOSE
                       ? s->ops->last_time_ns(s->impl)
                       : 0;
  if (err != 0) {
    snprintf(x->rep.error, sizeof x->rep.error, "%s",
             rp_last_error(s->ctx));
    free(x->out); /* no outputs with an error */
    x->out = NULL;
    x->out_bytes = 0;
  }
}

/* ---- Serving --------------------------------------------------------------- */

static int env_u32(rp_context *ctx, const char *name, uint32_t *out) {
  const char *s = getenv(name);
  char *end;
  unsigned long v;
  *out = 0;
  if (s == NULL || s[0] == '\0')
    return 0;
  v = strtoul(s, &end, 10);
  if (end == s || *end != '\0' || s[0] == '-' || v > UINT32_MAX)
    return rp__fail(ctx, RP_EINVAL, "rp_mpi_serve: %s='%s' is not a "
                    "whole number >= 0", name, s);
  *out = (uint32_t)v;
  return 0;
}

static int read_knobs(server *s) {
  const char *ms = getenv("RP_MPI_STALL_MS");
  int err;
  s->stall_ms = 5000.0;
  if ((err = env_u32(s->ctx, "RP_MPI_DEVICE", &s->device)) != 0 ||
      (err = env_u32(s->ctx, "RP_MPI_DIE_AT", &s->die_at)) != 0 ||
      (err = env_u32(s->ctx, "RP_MPI_STALL_AT", &s->stall_at)) != 0)
    return err;
  if (ms != NULL && ms[0] != '\0') {
    char *end;
    double v = strtod(ms, &end);
    if (end == ms || *end != '\0' || !(v >= 0.0 && v <= 600000.0))
      return rp__fail(s->ctx, RP_EINVAL, "rp_mpi_serve: RP_MPI_STALL_MS="
                      "'%s' is not a number of milliseconds in [0, "
                      "600000]", ms);
    s->stall_ms = v;
  }
  return 0;
}

static void server_close(server *s) {
  if (s->beat_started) {
    uv_mutex_lock(&s->beat_lock);
    s->quit = 1;
    uv_cond_signal(&s->beat_cond);
    uv_mutex_unlock(&s->beat_lock);
    uv_thread_join(&s->beat_thread);
    uv_cond_destroy(&s->beat_cond);
    uv_mutex_destroy(&s->beat_lock);
  }
  if (s->ops != NULL)
    s->ops->destroy(s->impl);
  free(s->rgba);
  free(s->tiles);
  free(s->fetches);
}

int rp_mpi_serve(rp_context *ctx, const char *backend) {
  server s;
  char why[RP__ERRMSG_MAX];
  int rank, size, err = 0;
  if (ctx == NULL)
    return RP_EINVAL;
  if (!rp_mpi__ready(&rank, &size))
    return rp__fail(ctx, RP_ESTATE, "rp_mpi_serve: MPI is not set up "
                    "(rp_mpi_init, in a process started by mpirun)");
  if (rank == 0)
    return rp__fail(ctx, RP_ESTATE, "rp_mpi_serve: rank 0 runs the "
                    "application; ranks 1 to %d serve it", size - 1);
  memset(&s, 0, sizeof s);
  s.ctx = ctx;
  s.rank = rank;
  s.backend = backend;
  if ((err = read_knobs(&s)) != 0)
    return err;
  if (uv_mutex_init(&s.beat_lock) != 0) {
    server_close(&s);
    return rp__fail(ctx, RP_EDEVICE, "rp_mpi_serve: uv_mutex_init failed");
  }
  if (uv_cond_init(&s.beat_cond) != 0) {
    uv_mutex_destroy(&s.beat_lock);
    server_close(&s);
    return rp__fail(ctx, RP_EDEVICE, "rp_mpi_serve: uv_cond_init failed");
  }
  if (uv_thread_create(&s.beat_thread, beat_main, &s) != 0) {
    uv_cond_destroy(&s.beat_cond);
    uv_mutex_destroy(&s.beat_lock);
    server_close(&s);
    return rp__fail(ctx, RP_EDEVICE, "rp_mpi_serve: no heartbeat thread");
  }
  s.beat_started = 1;
  for (;;) {
    rp_mpi__xfer *x = NULL;
    int refused = 0, rc;
    why[0] = '\0';
    rc = next_request(&x, &refused, why, sizeof why, &s);
    if (rc != 0) {
      set_busy(&s, 0, 0);
      rp_mpi__abandon(x);
      err = rp__fail(ctx, RP_EDEVICE, "rp_mpi_serve: rank %d: %s", rank,
                     why);
      break;
    }
    if (x->req.op == RP_MPI_SHUTDOWN) {
      rp_mpi__xfer_free(x);
      break;
    }
    run(&s, x, refused);
    set_busy(&s, 0, 0);
    if ((rc = reply(x, why, sizeof why)) < 0) {
      err = rp__fail(ctx, RP_EDEVICE, "rp_mpi_serve: rank %d: %s", rank,
                     why);
      break;
    }
    if (rc == 0)
      rp_mpi__xfer_free(x); /* else abandoned: the module keeps it */
  }
  server_close(&s);
  return err;
}
