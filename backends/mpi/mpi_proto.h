/* The MPI backend's wire protocol: the messages, their structs and
 * their payloads' layouts, shared by the proxy on rank 0
 * (mpi_backend.c) and the servers on ranks >= 1 (mpi_server.c). Nothing
 * here calls MPI, so that a test and a fuzz target reach the decoding of
 * a message without an MPI job (mpi_proto.c).
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
 * Rank 0 trusts no server: a reply is decoded by rp_mpi__reply_check and
 * its outputs by rp_mpi__reply_payload_check before anything of them is
 * used, and what rank 0 allocates for a reply is bounded by its own
 * request (the layout of what it asked for), never by a size the server
 * states. A reply that breaks the protocol gives the rank up. */
#ifndef RP_MPI_PROTO_H
#define RP_MPI_PROTO_H

#include <stddef.h>
#include <stdint.h>

#include "internal.h"
#include "raypace_backend.h"

#define RP_MPI_MAGIC 0x52504d49u /* "RPMI" */
/* Messages carry at most this many bytes (an MPI count is an int). */
#define RP_MPI_CHUNK ((size_t)8 << 20)
#define RP_MPI_BEAT_MS 100
/* Beats rank 0 drains per poll of an exchange. */
#define RP_MPI_BEATS_PER_POLL 64
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

/* ---- Decoding a reply (rank 0) ------------------------------------------- */

/* A server's reply header `rep` to rank 0's request `req`, received
 * `elapsed_ns` after the request was sent. Returns 0 when it reads as the
 * answer to req, and -1 (the reason in `why`) when it breaks the
 * protocol: another op or sequence number, a status that is not an RP_E*
 * code, a failure that announces outputs, outputs of another size than
 * req's reply layout. On 0, rep is made safe to use: its error message is
 * terminated and printable, its caps' names too, its device time at most
 * elapsed_ns (a server cannot have worked longer than the exchange took);
 * when rep->status is 0, *payload is the layout of the outputs still to be
 * received, rp_mpi__reply_layout(req): never more than req asked for. */
int rp_mpi__reply_check(const rp_mpi_request *req, rp_mpi_reply *rep,
                        uint64_t elapsed_ns, rp_mpi__layout *payload,
                        char *why, size_t size);

/* The outputs `in` (laid out as `payload`, from rp_mpi__reply_check) of
 * a successful reply to req, before they are copied out: 0, or -1 (why)
 * when they hold what no device writes (a tile's rays_hit beyond its 64
 * pixels, a tile's mean depth that is not finite). */
int rp_mpi__reply_payload_check(const rp_mpi_request *req,
                                const rp_mpi__layout *payload,
                                const void *in, char *why, size_t size);

#endif /* RP_MPI_PROTO_H */
