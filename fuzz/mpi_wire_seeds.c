/* Writes fuzz_mpi_wire's seeds into a folder: for each op rank 0 sends,
 * a request as its proxy builds one, with a successful reply (and its
 * outputs) and a failed one, plus near misses of each check of
 * rp_mpi__reply_check and rp_mpi__reply_payload_check. The inputs are
 * the structs' bytes, so they follow this build's layout: rerun after a
 * change to the wire structs (`mpi_wire_seeds fuzz/corpus/mpi_wire`). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "mpi_proto.h"

static const char *dir;

/* [request][reply][elapsed][payload of `fill` bytes, each `byte`]. */
static void seed(const char *name, const rp_mpi_request *req,
                 const rp_mpi_reply *rep, uint64_t elapsed, size_t fill,
                 const void *payload) {
  char path[512];
  FILE *f;
  snprintf(path, sizeof path, "%s/%s", dir, name);
  if ((f = fopen(path, "wb")) == NULL) {
    perror(path);
    exit(1);
  }
  fwrite(req, sizeof *req, 1, f);
  fwrite(rep, sizeof *rep, 1, f);
  fwrite(&elapsed, sizeof elapsed, 1, f);
  if (fill > 0)
    fwrite(payload, 1, fill, f);
  fclose(f);
}

static void request(rp_mpi_request *q, uint32_t op) {
  memset(q, 0, sizeof *q);
  q->magic = RP_MPI_MAGIC;
  q->op = op;
  q->seq = 7;
}

/* The server's successful answer to q, and its outputs (zeros but for
 * what the payload check reads). */
static void answer(const rp_mpi_request *q, rp_mpi_reply *r, void **out,
                   size_t *bytes) {
  rp_mpi__layout l;
  if (rp_mpi__reply_layout(q, &l) != 0)
    abort();
  memset(r, 0, sizeof *r);
  r->magic = RP_MPI_MAGIC;
  r->op = q->op;
  r->seq = q->seq;
  r->last_ns = 1000000;
  r->payload_bytes = l.total;
  *bytes = l.total;
  *out = calloc(1, l.total + 1);
  if (q->op == RP_MPI_RAYCAST && (q->a.frame.want & RP_MPI_WANT_TILES)) {
    rp_tile_stats *t = (rp_tile_stats *)((char *)*out + l.off[1]);
    t[0].rays_hit = 64;
    t[0].samples = 640;
    t[0].mean_depth = 12.5f;
  }
}

/* q's good reply, its failure, and a reply off in `what`. */
static void both(const char *name, const rp_mpi_request *q) {
  rp_mpi_reply r;
  void *out;
  size_t bytes;
  char n[128];
  answer(q, &r, &out, &bytes);
  snprintf(n, sizeof n, "%s_ok", name);
  seed(n, q, &r, 2000000, bytes, out);
  memset(&r, 0, sizeof r);
  r.magic = RP_MPI_MAGIC;
  r.op = q->op;
  r.seq = q->seq;
  r.status = RP_EDEVICE;
  snprintf(r.error, sizeof r.error, "device lost during %s",
           rp_mpi__op_name(q->op));
  snprintf(n, sizeof n, "%s_failed", name);
  seed(n, q, &r, 2000000, 0, NULL);
  free(out);
}

static void frame(rp_mpi_request *q, uint32_t op, uint32_t w, uint32_t h,
                  uint32_t want) {
  request(q, op);
  q->a.frame.p.width = w;
  q->a.frame.p.height = h;
  q->a.frame.region.x0 = 0;
  q->a.frame.region.x1 = w;
  q->a.frame.region.y0 = 0;
  q->a.frame.region.y1 = h;
  q->a.frame.want = want;
}

int main(int argc, char **argv) {
  rp_mpi_request q;
  rp_mpi_reply r;
  void *out;
  size_t bytes;
  if (argc != 2) {
    fprintf(stderr, "usage: %s FOLDER\n", argv[0]);
    return 2;
  }
  dir = argv[1];

  request(&q, RP_MPI_OPEN);
  q.a.open.abi = RP_BACKEND_ABI;
  answer(&q, &r, &out, &bytes);
  snprintf(r.caps.backend, sizeof r.caps.backend, "opencl");
  snprintf(r.caps.device, sizeof r.caps.device, "pthread-cpu");
  r.caps.max_alloc_bytes = (uint64_t)1 << 30;
  r.caps.global_mem_bytes = (uint64_t)4 << 30;
  seed("open_ok", &q, &r, 5000000, 0, NULL);
  free(out);
  request(&q, RP_MPI_CLOSE);
  both("close", &q);
  request(&q, RP_MPI_UPLOAD_VOLUME);
  q.a.volume.dims[0] = q.a.volume.dims[1] = q.a.volume.dims[2] = 8;
  q.a.volume.voxels = 512;
  q.a.volume.type = RP_U16;
  both("upload_volume", &q);
  frame(&q, RP_MPI_DEPTH_PASS, 16, 8, RP_MPI_WANT_FRONT_BACK);
  both("depth_pass", &q);
  frame(&q, RP_MPI_ERT_PREPASS, 16, 8, 0);
  both("ert_prepass", &q);
  frame(&q, RP_MPI_RAYCAST, 16, 8,
        RP_MPI_WANT_TILES | RP_MPI_WANT_FETCHES);
  both("raycast_tiles_fetches", &q);
  frame(&q, RP_MPI_RAYCAST, 24, 16, RP_MPI_WANT_TILES);
  q.a.frame.region.x0 = 8;
  q.a.frame.region.y0 = 8;
  both("raycast_region_tiles", &q);
  frame(&q, RP_MPI_RAYCAST, 16, 8, 0);
  both("raycast", &q);
  request(&q, RP_MPI_COMPUTE_AO);
  q.a.ao.job.end[0] = q.a.ao.job.end[1] = q.a.ao.job.end[2] = 4;
  q.a.ao.job.directions = 16;
  q.a.ao.has_bricks = 1;
  q.a.ao.job.brick_grid[0] = q.a.ao.job.brick_grid[1] = 1;
  q.a.ao.job.brick_grid[2] = 1;
  both("compute_ao", &q);
  request(&q, RP_MPI_SET_BRICK_POOL);
  q.a.pool.present = 1;
  q.a.pool.pool.brick_size = 16;
  q.a.pool.pool.slots = 4;
  both("set_brick_pool", &q);

  /* Near misses: each should be refused. */
  frame(&q, RP_MPI_RAYCAST, 16, 8, RP_MPI_WANT_TILES);
  answer(&q, &r, &out, &bytes);
  ((rp_tile_stats *)((char *)out + 512))[1].rays_hit = 65;
  seed("raycast_rays_hit_65", &q, &r, 2000000, bytes, out);
  r.seq = 8;
  seed("reply_wrong_seq", &q, &r, 2000000, bytes, out);
  r.seq = q.seq;
  r.payload_bytes = bytes + 1;
  seed("reply_payload_plus_one", &q, &r, 2000000, bytes, out);
  r.payload_bytes = UINT64_MAX;
  seed("reply_payload_huge", &q, &r, 2000000, 0, NULL);
  r.payload_bytes = bytes;
  r.last_ns = UINT64_MAX;
  seed("reply_time_beyond_exchange", &q, &r, 2000000, bytes, out);
  free(out);
  request(&q, RP_MPI_CLOSE);
  answer(&q, &r, &out, &bytes);
  r.status = 5;
  seed("status_positive", &q, &r, 2000000, 0, NULL);
  r.status = RP_EINVAL;
  r.payload_bytes = 64;
  seed("failure_with_outputs", &q, &r, 2000000, 0, NULL);
  r.payload_bytes = 0;
  memset(r.error, '\033', sizeof r.error);
  seed("error_unterminated_escapes", &q, &r, 2000000, 0, NULL);
  free(out);
  return 0;
}
