/* The MPI backend's wire protocol and transfers, shared by the proxy on
 * rank 0 (mpi_backend.c) and the servers on ranks >= 1 (mpi_server.c).
 *
 * One exchange per backend operation, always started by rank 0:
 *   rank 0 -> server  TAG_REQUEST       one rp_mpi_request (op, sequence
 *                                       number, the op's fixed arguments,
 *                                       the payload's size)
 *                     TAG_REQUEST_DATA  the payload (the op's arrays, one
 *                                       after the other) in chunks of at
 *                                       most RP_MPI_CHUNK bytes
 *   server -> rank 0  TAG_BEAT          a heartbeat (the sequence number)
 *                                       every RP_MPI_BEAT_MS while the
 *                                       server works on the request
 *                     TAG_REPLY         one rp_mpi_reply (status, error
 *                                       message, device time, caps)
 *                     TAG_REPLY_DATA    the outputs, chunked likewise,
 *                                       only when the status is 0
 * The payloads' layouts follow from the request alone (rp_mpi__layout):
 * each side computes them and checks what it receives against them.
 * Shutdown is a request without a reply.
 *
 * Every transfer is non-blocking and polled under one process-wide lock
 * (rp_mpi__lock): MPI_THREAD_SERIALIZED is all that needs, a wait can
 * give up at a deadline (MPI has no timed wait), and a thread waiting on
 * one rank never holds up another rank's. Buffers a transfer reads or
 * fills belong to its rp_mpi__xfer, never to a caller: an exchange given
 * up on may still complete later (a stalled rank waking up), so its
 * buffers go to the module with it (rp_mpi__abandon) and are freed only
 * once MPI is finalised. They are malloc'd, not a context's: they outlive
 * the device and its context. */
#ifndef RP_MPI_INTERNAL_H
#define RP_MPI_INTERNAL_H

#include <mpi.h>
#include <stddef.h>
#include <stdint.h>

#include "internal.h"
#include "raypace_backend.h"

#define RP_MPI_MAGIC 0x52504d49u /* "RPMI" */
/* Messages carry at most this many bytes (an MPI count is an int). */
#define RP_MPI_CHUNK ((size_t)8 << 20)
#define RP_MPI_BEAT_MS 100
#define RP_MPI_DEFAULT_TIMEOUT_MS 60000.0
#define RP_MPI_DEFAULT_SILENCE_MS 2000.0

enum {
  RP_MPI_TAG_REQUEST = 1,
  RP_MPI_TAG_REQUEST_DATA = 2,
  RP_MPI_TAG_REPLY = 3,
  RP_MPI_TAG_REPLY_DATA = 4,
  RP_MPI_TAG_BEAT = 5
};

typedef enum rp_mpi_op {
  RP_MPI_OPEN = 1,
  RP_MPI_CLOSE,
  RP_MPI_UPLOAD_VOLUME,
  RP_MPI_UPLOAD_TF,
  RP_MPI_UPLOAD_OCCUPANCY,
  RP_MPI_DEPTH_PASS,
  RP_MPI_ERT_PREPASS,
  RP_MPI_RAYCAST,
  RP_MPI_COMPUTE_AO,
  RP_MPI_UPLOAD_AO,
  RP_MPI_SET_BRICK_POOL,
  RP_MPI_UPLOAD_BRICKS,
  RP_MPI_SHUTDOWN,
  RP_MPI_OP_END
} rp_mpi_op;

/* rp_mpi_frame_args.want */
enum {
  RP_MPI_WANT_FRONT_BACK = 1,
  RP_MPI_WANT_TILES = 2,
  RP_MPI_WANT_FETCHES = 4
};

/* What both sides must agree on to read each other's structs. */
typedef struct rp_mpi_open_args {
  uint32_t abi;
  uint32_t frame_bytes, tile_bytes, caps_bytes, pool_bytes, request_bytes;
} rp_mpi_open_args;

typedef struct rp_mpi_volume_args {
  uint32_t dims[3];
  uint32_t type; /* rp_voxel_type */
  float spacing[3];
  uint32_t pad;
  double min, max;
  uint64_t voxels;
} rp_mpi_volume_args;

typedef struct rp_mpi_tf_args {
  uint32_t lut_size;
} rp_mpi_tf_args;

typedef struct rp_mpi_occupancy_args {
  uint32_t blocks[3];
} rp_mpi_occupancy_args;

/* Depth pass, ERT pre-pass and raycast. */
typedef struct rp_mpi_frame_args {
  rp_frame_params p;
  rp_region region; /* raycast */
  uint32_t want;    /* RP_MPI_WANT_* */
} rp_mpi_frame_args;

/* The job as the backend op takes it, its pointers NULL on the wire: dirs
 * and bricks travel as payload and are pointed at there on receipt. */
typedef struct rp_mpi_ao_args {
  rp_ao_job job;
  uint32_t has_bricks;
} rp_mpi_ao_args;

typedef struct rp_mpi_upload_ao_args {
  uint32_t present; /* 0: release the AO volume */
  uint32_t pad;
  uint64_t bytes;
} rp_mpi_upload_ao_args;

typedef struct rp_mpi_pool_args {
  uint32_t present; /* 0: release the pool */
  rp_brick_pool pool;
} rp_mpi_pool_args;

typedef struct rp_mpi_bricks_args {
  uint32_t count, has_table;
  uint64_t brick_bytes; /* (brick_size + 1)^3 voxels */
  uint64_t table_entries;
} rp_mpi_bricks_args;

typedef struct rp_mpi_request {
  uint32_t magic, op, seq, pad;
  uint64_t payload_bytes;
  union {
    rp_mpi_open_args open;
    rp_mpi_volume_args volume;
    rp_mpi_tf_args tf;
    rp_mpi_occupancy_args occupancy;
    rp_mpi_frame_args frame;
    rp_mpi_ao_args ao;
    rp_mpi_upload_ao_args upload_ao;
    rp_mpi_pool_args pool;
    rp_mpi_bricks_args bricks;
  } a;
} rp_mpi_request;

typedef struct rp_mpi_reply {
  uint32_t magic, op, seq;
  int32_t status;       /* 0 or an RP_E* code */
  uint64_t last_ns;     /* the server device's time for the op */
  uint64_t payload_bytes;
  rp_caps caps;         /* RP_MPI_OPEN */
  char error[RP__ERRMSG_MAX];
} rp_mpi_reply;

/* Where an op's arrays lie in its payload: piece i is len[i] bytes at
 * off[i] (16-byte aligned, so any element type can be read in place). */
#define RP_MPI_MAX_PIECES 4
typedef struct rp_mpi__layout {
  uint32_t n;
  size_t off[RP_MPI_MAX_PIECES], len[RP_MPI_MAX_PIECES];
  size_t total;
} rp_mpi__layout;

/* The request payload's layout, and the reply payload's (when the status
 * is 0). -1 when the sizes overflow or the op is unknown: a request no
 * build of this protocol sends. */
int rp_mpi__request_layout(const rp_mpi_request *req, rp_mpi__layout *l);
int rp_mpi__reply_layout(const rp_mpi_request *req, rp_mpi__layout *l);
/* The raycast's tile columns and rows of region r: the tiles holding its
 * pixels, [x0 / 8, ceil(x1 / 8)) and likewise in y. */
void rp_mpi__region_tiles(const rp_region *r, uint32_t *tx0, uint32_t *ty0,
                          uint32_t *tw, uint32_t *th);
/* The op's name, for messages. */
const char *rp_mpi__op_name(uint32_t op);

/* ---- The module (mpi_wire.c) ---------------------------------------------- */

/* 1 when rp_mpi_init set MPI up (and it is not finalised): then rank and
 * size are this process's. */
int rp_mpi__ready(int *rank, int *size);
MPI_Comm rp_mpi__comm(void);
void rp_mpi__lock(void);
void rp_mpi__unlock(void);
/* MPI's message for an error code, into buf. */
void rp_mpi__error_string(int code, char *buf, size_t size);
/* Seconds-resolution clocks are too coarse: milliseconds, monotonic. */
double rp_mpi__now_ms(void);
/* Sleeps between polls: *us grows from 20 us to max_us. */
void rp_mpi__backoff(uint32_t *us, uint32_t max_us);

/* Server ranks as rank 0 sees them. claim: a proxy opens rank r (fails
 * with RP_EBUSY when another proxy has it, RP_EDEVICE when r was lost;
 * the message goes to ctx). lose: r is given up on for good, `why` kept
 * for later messages. */
int rp_mpi__rank_claim(rp_context *ctx, int rank);
void rp_mpi__rank_release(int rank);
void rp_mpi__rank_lose(int rank, const char *why);
int rp_mpi__rank_lost(int rank);

/* One side's messages of one exchange with `peer`, and the buffers they
 * read or fill: `req` and `rep` (the headers), `out` (the payload this
 * side sends) and `in` (the one it receives), both malloc'd. */
typedef struct rp_mpi__xfer {
  int peer;
  rp_mpi_request req;
  rp_mpi_reply rep;
  void *out, *in;
  size_t out_bytes, in_bytes;
  MPI_Request *reqs;
  int *idx; /* MPI_Testsome's indices, cap of them */
  int nreq, cap;
  struct rp_mpi__xfer *next; /* the module's list of abandoned ones */
} rp_mpi__xfer;

rp_mpi__xfer *rp_mpi__xfer_new(int peer);
/* Frees x and its buffers; only when none of its requests is pending. */
void rp_mpi__xfer_free(rp_mpi__xfer *x);
/* Posts a send (send 1) or receive of `bytes` at buf with `tag`, in
 * chunks of RP_MPI_CHUNK; takes the lock. MPI's error code. */
int rp_mpi__post(rp_mpi__xfer *x, int send, void *buf, size_t bytes,
                 int tag);
/* *done = 1 when every request posted on x has completed (they are then
 * forgotten, so x can post again); *progress = 1 when some completed in
 * this call. Takes the lock. MPI's error code. */
int rp_mpi__test(rp_mpi__xfer *x, int *done, int *progress);
/* Gives x up: cancels its receives and keeps x, buffers and all, until
 * MPI is finalised (its sends cannot be cancelled and may still read). */
void rp_mpi__abandon(rp_mpi__xfer *x);

#endif /* RP_MPI_INTERNAL_H */
