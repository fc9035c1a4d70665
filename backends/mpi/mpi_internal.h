/* The MPI backend's module and transfers, shared by the proxy on
 * rank 0 (mpi_backend.c) and the servers on ranks >= 1 (mpi_server.c).
 *
 * The protocol (the messages, their structs and payload layouts) is in
 * mpi_proto.h, which needs no MPI.
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

#include "mpi_proto.h"

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
