/* The MPI backend on rank 0: rp_backend_ops as a proxy for a device on
 * another rank (raypace_mpi.h). Device i is rank i + 1.
 *
 * Each op stages its arguments in a transfer of its own (mpi_internal.h),
 * sends them to the rank, and waits for the reply, polling: the reply
 * header, then its outputs, which are copied into the caller's buffers.
 * The wait gives the rank up when it sends nothing for the silence limit
 * (a server beats while it works, so that is a dead rank) or has not
 * answered by the op's timeout (a hung one); the op then fails with
 * RP_EDEVICE naming the rank, which drops the device from a group, and
 * the rank is never waited on again.
 *
 * The caps are the remote device's, under backend "mpi" and a device
 * name that says which rank and which backend there. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mpi_internal.h"
#include "passes.h"
#include "raypace_ao.h"

typedef struct proxy {
  rp_context *ctx;
  int rank;
  uint32_t seq;
  uint64_t last_ns;
  double timeout_ms, silence_ms;
  /* What later ops' sizes follow from: the uploaded volume's voxels (an
   * AO volume has one byte each) and the pool's bricks. */
  uint64_t voxels;
  uint64_t brick_bytes, brick_count;
} proxy;

/* A positive number of milliseconds from the environment, or `def`. */
static int env_ms(rp_context *ctx, const char *name, double def,
                  double *out) {
  const char *s = getenv(name);
  char *end;
  double v;
  *out = def;
  if (s == NULL || s[0] == '\0')
    return 0;
  v = strtod(s, &end);
  if (end == s || *end != '\0' || !(v > 0.0) || !isfinite(v))
    return rp__fail(ctx, RP_EINVAL, "mpi: %s='%s' is not a positive "
                    "number of milliseconds", name, s);
  *out = v;
  return 0;
}

/* ---- One exchange ---------------------------------------------------------- */

/* Gives the rank up: the exchange is abandoned with its buffers, the op
 * fails. */
static int lose(proxy *px, rp_mpi__xfer *x, const char *why) {
  rp_mpi__abandon(x);
  rp_mpi__rank_lose(px->rank, why);
  return rp__fail(px->ctx, RP_EDEVICE, "mpi: rank %d given up on: %s",
                  px->rank, why);
}

/* Polls x's requests until they are all done, draining the rank's
 * heartbeats. 0, or the reason to give the rank up in `why`. */
static int wait_all(proxy *px, rp_mpi__xfer *x, const char *op,
                    double start, double *life, char *why, size_t size) {
  MPI_Comm comm = rp_mpi__comm();
  uint32_t us = 0;
  for (;;) {
    int done = 0, progress = 0, rc, flag = 1, beats;
    double now;
    if ((rc = rp_mpi__test(x, &done, &progress)) != MPI_SUCCESS) {
      char msg[MPI_MAX_ERROR_STRING];
      rp_mpi__error_string(rc, msg, sizeof msg);
      snprintf(why, size, "%s failed in MPI: %s", op, msg);
      return -1;
    }
    if (done)
      return 0;
    if (progress)
      *life = rp_mpi__now_ms();
    /* A beat for this request or a late one for an earlier request: the
     * rank is alive either way. */
    rp_mpi__lock();
    /* At most RP_MPI_BEATS_PER_POLL: a rank that floods beats must not
     * keep this loop, and the lock, forever; the deadlines below still
     * run. */
    for (beats = 0; flag && beats < RP_MPI_BEATS_PER_POLL; beats++) {
      MPI_Message m;
      uint32_t seq;
      if (MPI_Improbe(x->peer, RP_MPI_TAG_BEAT, comm, &flag, &m,
                      MPI_STATUS_IGNORE) != MPI_SUCCESS)
        break;
      if (flag) {
        MPI_Mrecv(&seq, 1, MPI_UINT32_T, &m, MPI_STATUS_IGNORE);
        *life = rp_mpi__now_ms();
      }
    }
    rp_mpi__unlock();
    now = rp_mpi__now_ms();
    if (now - *life > px->silence_ms) {
      snprintf(why, size, "no sign of life for %.0f ms during %s "
               "(RP_MPI_SILENCE_MS %.0f): the rank died?", now - *life, op,
               px->silence_ms);
      return -1;
    }
    if (now - start > px->timeout_ms) {
      snprintf(why, size, "no answer to %s within %.0f ms "
               "(RP_MPI_TIMEOUT_MS)", op, px->timeout_ms);
      return -1;
    }
    rp_mpi__backoff(&us, 250);
  }
}

/* Runs the request in *xp (op and arguments set, payload in out) on the
 * proxy's rank. On success *xp holds the reply and its outputs (in) for
 * the caller to read and free; on failure it has been freed or abandoned
 * and is NULL, and px->ctx says why. */
static int call(proxy *px, rp_mpi__xfer **xp) {
  rp_mpi__xfer *x = *xp;
  const char *op = rp_mpi__op_name(x->req.op);
  rp_mpi__layout want;
  double start = rp_mpi__now_ms(), life = start;
  char why[320];
  int rc;
  *xp = NULL;
  if (!rp_mpi__ready(NULL, NULL)) {
    rp_mpi__xfer_free(x);
    return rp__fail(px->ctx, RP_ESTATE, "mpi: %s on rank %d after "
                    "rp_mpi_finalize", op, px->rank);
  }
  if (rp_mpi__rank_lost(px->rank)) {
    rp_mpi__xfer_free(x);
    return rp__fail(px->ctx, RP_EDEVICE, "mpi: %s: rank %d was given up "
                    "on earlier", op, px->rank);
  }
  x->req.magic = RP_MPI_MAGIC;
  x->req.seq = ++px->seq;
  x->req.payload_bytes = x->out_bytes;
  /* The reply's receive first, so that it is matched however soon the
   * rank answers. */
  if ((rc = rp_mpi__post(x, 0, &x->rep, sizeof x->rep,
                         RP_MPI_TAG_REPLY)) != MPI_SUCCESS ||
      (rc = rp_mpi__post(x, 1, &x->req, sizeof x->req,
                         RP_MPI_TAG_REQUEST)) != MPI_SUCCESS ||
      (x->out_bytes > 0 &&
       (rc = rp_mpi__post(x, 1, x->out, x->out_bytes,
                          RP_MPI_TAG_REQUEST_DATA)) != MPI_SUCCESS)) {
    char msg[MPI_MAX_ERROR_STRING];
    rp_mpi__error_string(rc, msg, sizeof msg);
    snprintf(why, sizeof why, "sending %s failed in MPI: %s", op, msg);
    return lose(px, x, why);
  }
  if (wait_all(px, x, op, start, &life, why, sizeof why) != 0)
    return lose(px, x, why);
  /* The request's payload is delivered: the staging copy can go. */
  free(x->out);
  x->out = NULL;
  if (rp_mpi__reply_check(&x->req, &x->rep,
                          (uint64_t)((rp_mpi__now_ms() - start) * 1e6),
                          &want, why, sizeof why) != 0)
    return lose(px, x, why);
  px->last_ns = x->rep.last_ns;
  if (x->rep.status != 0) {
    rc = rp__fail(px->ctx, x->rep.status, "mpi: rank %d: %s: %s", px->rank,
                  op, x->rep.error);
    rp_mpi__xfer_free(x);
    return rc;
  }
  if (want.total > 0) {
    /* Zeroed: a rank that sends short chunks leaves zeros, not this
     * process's old memory, in what is copied out. */
    if ((x->in = calloc(1, want.total)) == NULL) {
      /* The rank has sent, or is sending, what it owes; without a place
       * to put it, the exchange cannot finish. */
      snprintf(why, sizeof why, "no memory for its %zu-byte reply to %s",
               want.total, op);
      return lose(px, x, why);
    }
    x->in_bytes = want.total;
    if ((rc = rp_mpi__post(x, 0, x->in, want.total,
                           RP_MPI_TAG_REPLY_DATA)) != MPI_SUCCESS) {
      char msg[MPI_MAX_ERROR_STRING];
      rp_mpi__error_string(rc, msg, sizeof msg);
      snprintf(why, sizeof why, "receiving %s failed in MPI: %s", op, msg);
      return lose(px, x, why);
    }
    if (wait_all(px, x, op, start, &life, why, sizeof why) != 0 ||
        rp_mpi__reply_payload_check(&x->req, &want, x->in, why,
                                    sizeof why) != 0)
      return lose(px, x, why);
  }
  *xp = x;
  return 0;
}

/* A transfer for `op`, its arguments to be set; NULL (RP_ENOMEM, said
 * in px->ctx) when there is no memory for one. */
static rp_mpi__xfer *begin(proxy *px, uint32_t op) {
  rp_mpi__xfer *x = rp_mpi__xfer_new(px->rank);
  if (x == NULL) {
    rp__fail(px->ctx, RP_ENOMEM, "mpi: no memory for %s on rank %d",
             rp_mpi__op_name(op), px->rank);
    return NULL;
  }
  x->req.op = op;
  return x;
}

/* Lays out the request's payload from its arguments (set by now) and
 * allocates it in x->out, for the caller to fill; frees x on failure. */
static int stage(proxy *px, rp_mpi__xfer *x, rp_mpi__layout *l) {
  const char *op = rp_mpi__op_name(x->req.op);
  if (rp_mpi__request_layout(&x->req, l) != 0) {
    rp_mpi__xfer_free(x);
    return rp__fail(px->ctx, RP_ERANGE, "mpi: %s for rank %d is too large "
                    "to address", op, px->rank);
  }
  if (l->total == 0)
    return 0;
  if ((x->out = malloc(l->total)) == NULL) {
    rp_mpi__xfer_free(x);
    return rp__fail(px->ctx, RP_ENOMEM, "mpi: no memory to stage %s for "
                    "rank %d (%zu bytes)", op, px->rank, l->total);
  }
  x->out_bytes = l->total;
  return 0;
}

/* A request whose payload is `pieces` (n of them, in layout order; a NULL
 * piece is left out by the layout): staged, run, and freed. */
static int simple_call(proxy *px, rp_mpi__xfer *x, const void *const *pieces,
                       uint32_t n) {
  rp_mpi__layout l;
  uint32_t i;
  int err;
  if ((err = stage(px, x, &l)) != 0)
    return err;
  for (i = 0; i < l.n && i < n; i++)
    if (pieces[i] != NULL) /* the layout leaves absent pieces out */
      memcpy((char *)x->out + l.off[i], pieces[i], l.len[i]);
  if ((err = call(px, &x)) != 0)
    return err;
  rp_mpi__xfer_free(x);
  return 0;
}

/* ---- ops ----------------------------------------------------------------- */

static void mpi_destroy(void *p) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  if (px == NULL)
    return;
  /* Nothing is sent to a rank given up on, nor after finalize: call()
   * checks both. The server frees the device's memory on close. */
  if ((x = begin(px, RP_MPI_CLOSE)) != NULL && call(px, &x) == 0)
    rp_mpi__xfer_free(x);
  if (rp_mpi__ready(NULL, NULL))
    rp_mpi__rank_release(px->rank);
  rp__free(px->ctx, px);
}

static int mpi_upload_volume(void *p, const rp_volume *vol) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  const void *pieces[1];
  int a, err;
  if ((x = begin(px, RP_MPI_UPLOAD_VOLUME)) == NULL)
    return RP_ENOMEM;
  for (a = 0; a < 3; a++) {
    x->req.a.volume.dims[a] = vol->dims[a];
    x->req.a.volume.spacing[a] = vol->spacing[a];
  }
  x->req.a.volume.type = (uint32_t)vol->type;
  x->req.a.volume.min = vol->min;
  x->req.a.volume.max = vol->max;
  x->req.a.volume.voxels = vol->voxel_count;
  pieces[0] = vol->data;
  if ((err = simple_call(px, x, pieces, 1)) != 0)
    return err;
  px->voxels = vol->voxel_count;
  px->brick_bytes = px->brick_count = 0;
  return 0;
}

static int mpi_upload_tf(void *p, const float *lut, uint32_t lut_size) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  const void *pieces[1];
  if ((x = begin(px, RP_MPI_UPLOAD_TF)) == NULL)
    return RP_ENOMEM;
  x->req.a.tf.lut_size = lut_size;
  pieces[0] = lut;
  return simple_call(px, x, pieces, 1);
}

static int mpi_upload_occupancy(void *p, const uint8_t *grid,
                                const uint8_t *alpha_hist,
                                const uint32_t blocks[3]) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  const void *pieces[2];
  if ((x = begin(px, RP_MPI_UPLOAD_OCCUPANCY)) == NULL)
    return RP_ENOMEM;
  memcpy(x->req.a.occupancy.blocks, blocks,
         sizeof x->req.a.occupancy.blocks);
  pieces[0] = grid;
  pieces[1] = alpha_hist;
  return simple_call(px, x, pieces, 2);
}

/* A frame op: its arguments, and the call. On success *xp holds the
 * outputs. */
static int frame_call(proxy *px, uint32_t op, const rp_frame_params *fp,
                      const rp_region *r, uint32_t want, rp_mpi__xfer **xp) {
  rp_mpi__xfer *x = NULL;
  int err;
  if ((x = begin(px, op)) == NULL)
    return RP_ENOMEM;
  x->req.a.frame.p = *fp;
  if (r != NULL)
    x->req.a.frame.region = *r;
  x->req.a.frame.want = want;
  if ((err = call(px, &x)) != 0)
    return err;
  *xp = x;
  return 0;
}

static int mpi_depth_pass(void *p, const rp_frame_params *fp,
                          float *front_back) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  int err = frame_call(px, RP_MPI_DEPTH_PASS, fp, NULL,
                       front_back != NULL ? RP_MPI_WANT_FRONT_BACK : 0u, &x);
  if (err != 0)
    return err;
  if (front_back != NULL)
    memcpy(front_back, x->in, x->in_bytes);
  rp_mpi__xfer_free(x);
  return 0;
}

static int mpi_ert_prepass(void *p, const rp_frame_params *fp,
                           float *d_ert) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  int err = frame_call(px, RP_MPI_ERT_PREPASS, fp, NULL, 0, &x);
  if (err != 0)
    return err;
  memcpy(d_ert, x->in, x->in_bytes);
  rp_mpi__xfer_free(x);
  return 0;
}

/* Copies `rows` rows of `row` bytes from a compact block into an image of
 * `pitch` bytes per row, at byte column `col` of row `y0`. */
static void scatter(uint8_t *dst, size_t pitch, size_t col, size_t y0,
                    const uint8_t *src, size_t row, size_t rows) {
  size_t y;
  for (y = 0; y < rows; y++)
    memcpy(dst + (y0 + y) * pitch + col, src + y * row, row);
}

static int mpi_raycast(void *p, const rp_frame_params *fp,
                       const rp_region *r, uint8_t *rgba,
                       rp_tile_stats *tiles, uint64_t *fetches) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  rp_mpi__layout l;
  uint32_t tx0, ty0, tw, th, tiles_x, want = 0;
  size_t rw, rh;
  int err;
  if (r->x1 <= r->x0 || r->y1 <= r->y0) {
    px->last_ns = 0;
    return 0;
  }
  want |= tiles != NULL ? RP_MPI_WANT_TILES : 0u;
  want |= fetches != NULL ? RP_MPI_WANT_FETCHES : 0u;
  if ((err = frame_call(px, RP_MPI_RAYCAST, fp, r, want, &x)) != 0)
    return err;
  (void)rp_mpi__reply_layout(&x->req, &l); /* checked by call() */
  rw = r->x1 - r->x0;
  rh = r->y1 - r->y0;
  rp_mpi__region_tiles(r, &tx0, &ty0, &tw, &th);
  rp_tile_grid(fp->width, fp->height, &tiles_x, NULL);
  scatter(rgba, (size_t)fp->width * 4, (size_t)r->x0 * 4, r->y0,
          (const uint8_t *)x->in + l.off[0], rw * 4, rh);
  if (tiles != NULL)
    scatter((uint8_t *)tiles, tiles_x * sizeof *tiles, tx0 * sizeof *tiles,
            ty0, (const uint8_t *)x->in + l.off[1], tw * sizeof *tiles, th);
  if (fetches != NULL)
    scatter((uint8_t *)fetches, tiles_x * sizeof *fetches,
            tx0 * sizeof *fetches, ty0,
            (const uint8_t *)x->in + l.off[tiles != NULL ? 2 : 1],
            tw * sizeof *fetches, th);
  rp_mpi__xfer_free(x);
  return 0;
}

static int mpi_compute_ao(void *p, const rp_ao_job *job, uint8_t *out) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  rp_mpi_ao_args *a;
  rp_mpi__layout l;
  int err;
  if ((x = begin(px, RP_MPI_COMPUTE_AO)) == NULL)
    return RP_ENOMEM;
  a = &x->req.a.ao;
  a->job = *job;
  a->job.dirs = NULL;
  a->job.bricks = NULL;
  a->has_bricks = job->bricks != NULL;
  if ((err = stage(px, x, &l)) != 0)
    return err;
  memcpy((char *)x->out + l.off[0], job->dirs, l.len[0]);
  if (job->bricks != NULL)
    memcpy((char *)x->out + l.off[1], job->bricks, l.len[1]);
  if ((err = call(px, &x)) != 0)
    return err;
  memcpy(out, x->in, x->in_bytes);
  rp_mpi__xfer_free(x);
  return 0;
}

static int mpi_upload_ao(void *p, const uint8_t *ao) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  const void *pieces[1];
  if ((x = begin(px, RP_MPI_UPLOAD_AO)) == NULL)
    return RP_ENOMEM;
  x->req.a.upload_ao.present = ao != NULL;
  x->req.a.upload_ao.bytes = ao != NULL ? px->voxels : 0;
  pieces[0] = ao;
  return simple_call(px, x, pieces, 1);
}

static int mpi_set_brick_pool(void *p, const rp_brick_pool *pool) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  int err;
  if ((x = begin(px, RP_MPI_SET_BRICK_POOL)) == NULL)
    return RP_ENOMEM;
  x->req.a.pool.present = pool != NULL;
  if (pool != NULL)
    x->req.a.pool.pool = *pool;
  if ((err = simple_call(px, x, NULL, 0)) != 0)
    return err;
  /* As on any backend, the volume is gone either way. */
  px->voxels = 0;
  px->brick_bytes = px->brick_count = 0;
  if (pool != NULL) {
    uint64_t s = (uint64_t)pool->brick_size + 1;
    px->brick_bytes = s * s * s * rp__voxel_size(pool->type);
    px->brick_count = (uint64_t)pool->grid[0] * pool->grid[1] * pool->grid[2];
  }
  return 0;
}

static int mpi_upload_bricks(void *p, uint32_t count, const uint32_t *slots,
                             const void *const *voxels,
                             const uint32_t *table) {
  proxy *px = p;
  rp_mpi__xfer *x = NULL;
  rp_mpi__layout l;
  uint32_t i;
  int err;
  if (px->brick_bytes == 0)
    return rp__fail(px->ctx, RP_ESTATE, "mpi: upload_bricks to rank %d "
                    "without a brick pool", px->rank);
  if ((x = begin(px, RP_MPI_UPLOAD_BRICKS)) == NULL)
    return RP_ENOMEM;
  x->req.a.bricks.count = count;
  x->req.a.bricks.has_table = table != NULL;
  x->req.a.bricks.brick_bytes = px->brick_bytes;
  x->req.a.bricks.table_entries = px->brick_count;
  if ((err = stage(px, x, &l)) != 0)
    return err;
  /* The bricks are the host's, scattered in its memory: one copy puts
   * them in a row for the wire. */
  memcpy((char *)x->out + l.off[0], slots, l.len[0]);
  for (i = 0; i < count; i++)
    memcpy((char *)x->out + l.off[1] + (size_t)i * px->brick_bytes,
           voxels[i], px->brick_bytes);
  if (table != NULL)
    memcpy((char *)x->out + l.off[2], table, l.len[2]);
  if ((err = call(px, &x)) != 0)
    return err;
  rp_mpi__xfer_free(x);
  return 0;
}

static uint64_t mpi_last_time_ns(void *p) {
  return ((const proxy *)p)->last_ns;
}

static const rp_backend_ops mpi_ops = {
    .destroy = mpi_destroy,
    .upload_volume = mpi_upload_volume,
    .upload_tf = mpi_upload_tf,
    .upload_occupancy = mpi_upload_occupancy,
    .depth_pass = mpi_depth_pass,
    .ert_prepass = mpi_ert_prepass,
    .raycast = mpi_raycast,
    .compute_ao = mpi_compute_ao,
    .upload_ao = mpi_upload_ao,
    .set_brick_pool = mpi_set_brick_pool,
    .upload_bricks = mpi_upload_bricks,
    .last_time_ns = mpi_last_time_ns};

/* ---- bootstrap ----------------------------------------------------------- */

/* A device per server rank, on rank 0 of an MPI job of two or more; none
 * anywhere else, so the backend is simply absent outside mpirun. */
static int mpi_probe(rp_context *ctx, uint32_t *device_count) {
  int rank, size;
  (void)ctx;
  *device_count = 0;
  if (rp_mpi__ready(&rank, &size) && rank == 0 && size > 1)
    *device_count = (uint32_t)(size - 1);
  return 0;
}

static int mpi_create(rp_context *ctx, uint32_t index, uint32_t units,
                      const rp_backend_ops **ops, void **out,
                      rp_caps *caps) {
  proxy *px;
  rp_mpi__xfer *x = NULL;
  rp_caps remote;
  int rank = (int)index + 1, err;
  (void)units; /* no partition_units: the front end refuses units > 0 */
  if ((err = rp_mpi__rank_claim(ctx, rank)) != 0)
    return err;
  if ((px = rp__calloc(ctx, 1, sizeof *px)) == NULL) {
    rp_mpi__rank_release(rank);
    return rp__fail(ctx, RP_ENOMEM, "mpi: out of memory for rank %d",
                    rank);
  }
  px->ctx = ctx;
  px->rank = rank;
  if ((err = env_ms(ctx, "RP_MPI_TIMEOUT_MS", RP_MPI_DEFAULT_TIMEOUT_MS,
                    &px->timeout_ms)) != 0 ||
      (err = env_ms(ctx, "RP_MPI_SILENCE_MS", RP_MPI_DEFAULT_SILENCE_MS,
                    &px->silence_ms)) != 0 ||
      (x = begin(px, RP_MPI_OPEN)) == NULL) {
    rp_mpi__rank_release(rank);
    rp__free(ctx, px);
    return err != 0 ? err : RP_ENOMEM;
  }
  x->req.a.open.abi = RP_BACKEND_ABI;
  x->req.a.open.frame_bytes = sizeof(rp_frame_params);
  x->req.a.open.tile_bytes = sizeof(rp_tile_stats);
  x->req.a.open.caps_bytes = sizeof(rp_caps);
  x->req.a.open.pool_bytes = sizeof(rp_brick_pool);
  x->req.a.open.request_bytes = sizeof(rp_mpi_request);
  if ((err = call(px, &x)) != 0 || x == NULL) {
    rp_mpi__rank_release(rank);
    rp__free(ctx, px);
    return err != 0 ? err : RP_EDEVICE;
  }
  remote = x->rep.caps;
  rp_mpi__xfer_free(x);
  remote.backend[sizeof remote.backend - 1] = '\0';
  remote.device[sizeof remote.device - 1] = '\0';
  *caps = remote;
  snprintf(caps->backend, sizeof caps->backend, "mpi");
  snprintf(caps->device, sizeof caps->device, "rank %d %s: %.70s", rank,
           remote.backend, remote.device);
  *ops = &mpi_ops;
  *out = px;
  return 0;
}

const rp_backend_bootstrap rp_mpi_bootstrap = {"mpi", mpi_probe, mpi_create,
                                               NULL};
