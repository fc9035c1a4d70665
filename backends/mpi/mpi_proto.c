/* The MPI backend's protocol without MPI (mpi_proto.h): the payload
 * layouts both sides compute, and rank 0's decoding of what a server
 * sends it, pure functions that tests and the fuzz target call on bytes
 * of their own. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "mpi_proto.h"
#include "passes.h"

/* ---- Layouts --------------------------------------------------------------- */

/* Appends a piece of count * size bytes; -1 on overflow. */
static int piece(rp_mpi__layout *l, uint64_t count, uint64_t size) {
  size_t off = (l->total + 15) / 16 * 16;
  if (size != 0 && count > SIZE_MAX / size)
    return -1;
  if (off < l->total || count * size > SIZE_MAX - off)
    return -1;
  l->off[l->n] = off;
  l->len[l->n] = (size_t)(count * size);
  l->total = off + l->len[l->n];
  l->n++;
  return 0;
}

void rp_mpi__region_tiles(const rp_region *r, uint32_t *tx0, uint32_t *ty0,
                          uint32_t *tw, uint32_t *th) {
  *tx0 = r->x0 / RP_TILE_SIZE;
  *ty0 = r->y0 / RP_TILE_SIZE;
  *tw = r->x1 > r->x0 ? (r->x1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE - *tx0
                      : 0;
  *th = r->y1 > r->y0 ? (r->y1 + RP_TILE_SIZE - 1) / RP_TILE_SIZE - *ty0
                      : 0;
}

int rp_mpi__request_layout(const rp_mpi_request *q, rp_mpi__layout *l) {
  memset(l, 0, sizeof *l);
  switch (q->op) {
  case RP_MPI_UPLOAD_VOLUME: {
    const rp_mpi_volume_args *a = &q->a.volume;
    if (a->type != RP_U8 && a->type != RP_U16 && a->type != RP_F32)
      return -1;
    return piece(l, a->voxels, rp__voxel_size((rp_voxel_type)a->type));
  }
  case RP_MPI_UPLOAD_TF:
    return piece(l, q->a.tf.lut_size, 4 * sizeof(float));
  case RP_MPI_UPLOAD_OCCUPANCY: {
    const uint32_t *b = q->a.occupancy.blocks;
    uint64_t n = (uint64_t)b[0] * b[1] * b[2];
    return piece(l, n, 1) || piece(l, n, RP_OPACITY_BINS) ? -1 : 0;
  }
  case RP_MPI_COMPUTE_AO: {
    const rp_ao_job *j = &q->a.ao.job;
    if (piece(l, j->directions, 4 * sizeof(float)) != 0)
      return -1;
    return q->a.ao.has_bricks
               ? piece(l, (uint64_t)j->brick_grid[0] * j->brick_grid[1] *
                              j->brick_grid[2],
                       1)
               : 0;
  }
  case RP_MPI_UPLOAD_AO:
    return q->a.upload_ao.present ? piece(l, q->a.upload_ao.bytes, 1) : 0;
  case RP_MPI_UPLOAD_BRICKS: {
    const rp_mpi_bricks_args *a = &q->a.bricks;
    if (piece(l, a->count, sizeof(uint32_t)) != 0 ||
        piece(l, a->count, a->brick_bytes) != 0)
      return -1;
    return a->has_table ? piece(l, a->table_entries, sizeof(uint32_t)) : 0;
  }
  case RP_MPI_OPEN:
  case RP_MPI_CLOSE:
  case RP_MPI_DEPTH_PASS:
  case RP_MPI_ERT_PREPASS:
  case RP_MPI_RAYCAST:
  case RP_MPI_SET_BRICK_POOL:
  case RP_MPI_SHUTDOWN:
    return 0;
  default:
    return -1;
  }
}

int rp_mpi__reply_layout(const rp_mpi_request *q, rp_mpi__layout *l) {
  const rp_mpi_frame_args *f = &q->a.frame;
  memset(l, 0, sizeof *l);
  switch (q->op) {
  case RP_MPI_DEPTH_PASS:
    if (!(f->want & RP_MPI_WANT_FRONT_BACK))
      return 0;
    return piece(l, (uint64_t)f->p.width * f->p.height, 2 * sizeof(float));
  case RP_MPI_ERT_PREPASS: {
    uint32_t gw, gh;
    rp__ert_grid(f->p.width, f->p.height, &gw, &gh);
    return piece(l, (uint64_t)gw * gh, sizeof(float));
  }
  case RP_MPI_RAYCAST: {
    uint32_t tx0, ty0, tw, th;
    uint64_t px = (uint64_t)(f->region.x1 - f->region.x0) *
                  (f->region.y1 - f->region.y0);
    if (f->region.x1 < f->region.x0 || f->region.y1 < f->region.y0)
      return -1;
    rp_mpi__region_tiles(&f->region, &tx0, &ty0, &tw, &th);
    if (piece(l, px, 4) != 0)
      return -1;
    if ((f->want & RP_MPI_WANT_TILES) &&
        piece(l, (uint64_t)tw * th, sizeof(rp_tile_stats)) != 0)
      return -1;
    if ((f->want & RP_MPI_WANT_FETCHES) &&
        piece(l, (uint64_t)tw * th, sizeof(uint64_t)) != 0)
      return -1;
    return 0;
  }
  case RP_MPI_COMPUTE_AO: {
    const rp_ao_job *j = &q->a.ao.job;
    uint64_t n = 1;
    int i;
    for (i = 0; i < 3; i++)
      n *= j->end[i] > j->lo[i] ? j->end[i] - j->lo[i] : 0;
    return piece(l, n, 1);
  }
  default:
    return q->op >= RP_MPI_OPEN && q->op < RP_MPI_OP_END ? 0 : -1;
  }
}

const char *rp_mpi__op_name(uint32_t op) {
  static const char *const names[] = {
      "?",          "open",           "close",       "upload_volume",
      "upload_tf",  "upload_occupancy", "depth_pass", "ert_prepass",
      "raycast",    "compute_ao",     "upload_ao",   "set_brick_pool",
      "upload_bricks", "shutdown"};
  return op < sizeof names / sizeof names[0] ? names[op] : "?";
}

/* ---- Decoding a reply ------------------------------------------------------ */

/* A server's text as rank 0 may print it: terminated within its `size`
 * bytes, control bytes (a terminal's escapes) replaced by '?'. */
static void printable(char *s, size_t size) {
  size_t i;
  s[size - 1] = '\0';
  for (i = 0; s[i] != '\0'; i++)
    if ((unsigned char)s[i] < 0x20 || s[i] == 0x7f)
      s[i] = '?';
}

int rp_mpi__reply_check(const rp_mpi_request *req, rp_mpi_reply *rep,
                        uint64_t elapsed_ns, rp_mpi__layout *payload,
                        char *why, size_t size) {
  const char *op = rp_mpi__op_name(req->op);
  memset(payload, 0, sizeof *payload);
  if (rep->magic != RP_MPI_MAGIC || rep->op != req->op ||
      rep->seq != req->seq) {
    snprintf(why, size, "its reply to %s (seq %u) reads as op %u seq %u: "
             "the ranks run different builds?", op, req->seq, rep->op,
             rep->seq);
    return -1;
  }
  if (rep->status != 0 &&
      strcmp(rp_err_name(rep->status), "UNKNOWN") == 0) {
    snprintf(why, size, "its reply to %s has status %d, not an error "
             "code", op, rep->status);
    return -1;
  }
  if (rep->status != 0 && rep->payload_bytes != 0) {
    snprintf(why, size, "its reply to %s fails (%s) yet announces %llu "
             "bytes of outputs", op, rp_err_name(rep->status),
             (unsigned long long)rep->payload_bytes);
    return -1;
  }
  if (rep->status == 0 && rp_mpi__reply_layout(req, payload) != 0) {
    snprintf(why, size, "%s asks for outputs too large to address", op);
    memset(payload, 0, sizeof *payload);
    return -1;
  }
  if (rep->status == 0 && rep->payload_bytes != payload->total) {
    snprintf(why, size, "its reply to %s carries %llu bytes where %zu "
             "were due", op, (unsigned long long)rep->payload_bytes,
             payload->total);
    memset(payload, 0, sizeof *payload);
    return -1;
  }
  printable(rep->error, sizeof rep->error);
  printable(rep->caps.backend, sizeof rep->caps.backend);
  printable(rep->caps.device, sizeof rep->caps.device);
  if (rep->last_ns > elapsed_ns)
    rep->last_ns = elapsed_ns;
  return 0;
}

int rp_mpi__reply_payload_check(const rp_mpi_request *req,
                                const rp_mpi__layout *payload,
                                const void *in, char *why, size_t size) {
  const rp_tile_stats *t;
  size_t i, n;
  /* Only a raycast's tile statistics are read by rank 0 beyond being
   * copied out (the shares and the cost model learn from them); pixels,
   * depths, AO and fetch counts are anyone's values. */
  if (req->op != RP_MPI_RAYCAST || !(req->a.frame.want & RP_MPI_WANT_TILES))
    return 0;
  t = (const rp_tile_stats *)((const char *)in + payload->off[1]);
  n = payload->len[1] / sizeof *t;
  for (i = 0; i < n; i++)
    if (t[i].rays_hit > RP_TILE_SIZE * RP_TILE_SIZE ||
        !isfinite(t[i].mean_depth)) {
      snprintf(why, size, "its raycast reports tile %zu with %u rays hit "
               "and mean depth %g", i, t[i].rays_hit,
               (double)t[i].mean_depth);
      return -1;
    }
  return 0;
}
