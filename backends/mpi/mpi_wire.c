/* The MPI backend's module: MPI set-up and shutdown (raypace_mpi.h), the
 * server ranks as rank 0 sees them and the polled, chunked transfers both
 * sides use (mpi_internal.h). The payload layouts are mpi_proto.c's. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <uv.h>

#include "mpi_internal.h"
#include "raypace_mpi.h"

/* A server rank as rank 0 sees it. */
typedef struct rank_state {
  int open; /* a proxy device has it */
  int lost; /* given up on: never waited on again */
  char why[256];
} rank_state;

static struct {
  int ready;  /* rp_mpi_init set MPI up and it is not finalised */
  int owns;   /* rp_mpi_init initialised MPI, so finalises it */
  MPI_Comm comm;
  int rank, size;
  uv_mutex_t lock;
  rank_state *ranks; /* size entries (rank 0's unused) */
  rp_mpi__xfer *abandoned;
} mod;

/* ---- Set-up ---------------------------------------------------------------- */

/* Whether an MPI launcher started this process: Open MPI's mpirun sets
 * OMPI_COMM_WORLD_SIZE, MPICH's hydra and Slurm's PMI set PMI_SIZE, a
 * PMIx launcher PMIX_RANK. Without one, MPI_Init would start a singleton
 * (and, with Open MPI, its daemon) for nothing. */
static int launched(void) {
  return getenv("OMPI_COMM_WORLD_SIZE") != NULL ||
         getenv("PMI_SIZE") != NULL || getenv("PMIX_RANK") != NULL;
}

int rp_mpi_init(int *argc, char ***argv, int *rank, int *size) {
  int inited = 0, provided = 0, rc;
  char msg[MPI_MAX_ERROR_STRING];
  if (rank != NULL)
    *rank = 0;
  if (size != NULL)
    *size = 1;
  if (mod.ready) {
    if (rank != NULL)
      *rank = mod.rank;
    if (size != NULL)
      *size = mod.size;
    return 0;
  }
  MPI_Initialized(&inited);
  if (!inited && !launched())
    return 0;
  if (!inited) {
    rc = MPI_Init_thread(argc, argv, MPI_THREAD_MULTIPLE, &provided);
    if (rc != MPI_SUCCESS) {
      rp_mpi__error_string(rc, msg, sizeof msg);
      fprintf(stderr, "raypace: MPI_Init_thread failed: %s\n", msg);
      return RP_EDEVICE;
    }
    mod.owns = 1;
  } else {
    MPI_Query_thread(&provided);
  }
  if (provided < MPI_THREAD_SERIALIZED) {
    fprintf(stderr, "raypace: MPI provides thread level %d; the mpi "
                    "backend needs MPI_THREAD_SERIALIZED (%d) or more: "
                    "device groups call it from their worker threads\n",
            provided, MPI_THREAD_SERIALIZED);
    return RP_EUNSUPPORTED;
  }
  /* A communicator of our own: our tags cannot meet the application's
   * messages, and its errors come back as codes instead of aborting the
   * job, which is what lets a lost rank be survived. */
  if ((rc = MPI_Comm_dup(MPI_COMM_WORLD, &mod.comm)) != MPI_SUCCESS) {
    rp_mpi__error_string(rc, msg, sizeof msg);
    fprintf(stderr, "raypace: MPI_Comm_dup failed: %s\n", msg);
    return RP_EDEVICE;
  }
  MPI_Comm_set_errhandler(mod.comm, MPI_ERRORS_RETURN);
  MPI_Comm_rank(mod.comm, &mod.rank);
  MPI_Comm_size(mod.comm, &mod.size);
  mod.ranks = calloc((size_t)mod.size, sizeof *mod.ranks);
  if (mod.ranks == NULL || uv_mutex_init(&mod.lock) != 0) {
    free(mod.ranks);
    mod.ranks = NULL;
    fprintf(stderr, "raypace: out of memory setting up MPI\n");
    return RP_EDEVICE;
  }
  mod.ready = 1;
  if (rank != NULL)
    *rank = mod.rank;
  if (size != NULL)
    *size = mod.size;
  return 0;
}

/* Rank 0: a shutdown request to every server. A rank given up on is sent
 * one too (a stalled rank that wakes up should leave, not wait forever),
 * but never waited on; the others' sends are tiny and complete at once,
 * within RP_MPI_DEFAULT_SILENCE_MS in any case. */
static void shutdown_servers(void) {
  static rp_mpi_request bye; /* static: a send left pending reads it */
  MPI_Request *reqs = calloc((size_t)mod.size, sizeof *reqs);
  double deadline = rp_mpi__now_ms() + RP_MPI_DEFAULT_SILENCE_MS;
  uint32_t us = 0;
  int r, pending;
  if (reqs == NULL)
    return; /* the servers die with the job: mpirun ends them */
  bye.magic = RP_MPI_MAGIC;
  bye.op = RP_MPI_SHUTDOWN;
  uv_mutex_lock(&mod.lock);
  for (r = 1; r < mod.size; r++) {
    reqs[r] = MPI_REQUEST_NULL;
    if (MPI_Isend(&bye, (int)sizeof bye, MPI_BYTE, r, RP_MPI_TAG_REQUEST,
                  mod.comm, &reqs[r]) != MPI_SUCCESS)
      reqs[r] = MPI_REQUEST_NULL;
    else if (mod.ranks[r].lost)
      MPI_Request_free(&reqs[r]);
  }
  uv_mutex_unlock(&mod.lock);
  do {
    pending = 0;
    uv_mutex_lock(&mod.lock);
    for (r = 1; r < mod.size; r++) {
      int done = 1;
      if (reqs[r] != MPI_REQUEST_NULL &&
          MPI_Test(&reqs[r], &done, MPI_STATUS_IGNORE) != MPI_SUCCESS)
        done = 1;
      pending |= !done;
    }
    uv_mutex_unlock(&mod.lock);
    if (pending)
      rp_mpi__backoff(&us, 1000);
  } while (pending && rp_mpi__now_ms() < deadline);
  uv_mutex_lock(&mod.lock);
  for (r = 1; r < mod.size; r++)
    if (reqs[r] != MPI_REQUEST_NULL)
      MPI_Request_free(&reqs[r]);
  uv_mutex_unlock(&mod.lock);
  free(reqs);
}

void rp_mpi_finalize(void) {
  int finalized = 0;
  if (!mod.ready) {
    /* rp_mpi_init may have initialised MPI and then refused it (thread
     * level): finalise what it started. */
    if (mod.owns && MPI_Finalized(&finalized) == MPI_SUCCESS && !finalized)
      MPI_Finalize();
    mod.owns = 0;
    return;
  }
  if (mod.rank == 0)
    shutdown_servers();
  mod.ready = 0;
  if (!mod.owns)
    return; /* the application's MPI: it finalises, and the abandoned
               transfers stay the module's (see rp_mpi__abandon) */
  MPI_Finalize();
  mod.owns = 0;
  while (mod.abandoned != NULL) {
    rp_mpi__xfer *x = mod.abandoned;
    mod.abandoned = x->next;
    rp_mpi__xfer_free(x);
  }
  free(mod.ranks);
  mod.ranks = NULL;
  uv_mutex_destroy(&mod.lock);
}

int rp_mpi__ready(int *rank, int *size) {
  if (!mod.ready)
    return 0;
  if (rank != NULL)
    *rank = mod.rank;
  if (size != NULL)
    *size = mod.size;
  return 1;
}

MPI_Comm rp_mpi__comm(void) { return mod.comm; }
void rp_mpi__lock(void) { uv_mutex_lock(&mod.lock); }
void rp_mpi__unlock(void) { uv_mutex_unlock(&mod.lock); }

void rp_mpi__error_string(int code, char *buf, size_t size) {
  char s[MPI_MAX_ERROR_STRING];
  int len = 0;
  if (MPI_Error_string(code, s, &len) != MPI_SUCCESS)
    snprintf(s, sizeof s, "MPI error %d", code);
  snprintf(buf, size, "%s", s);
}

double rp_mpi__now_ms(void) { return (double)uv_hrtime() * 1e-6; }

void rp_mpi__backoff(uint32_t *us, uint32_t max_us) {
  struct timespec ts;
  *us = *us == 0 ? 20 : *us * 2 > max_us ? max_us : *us * 2;
  ts.tv_sec = 0;
  ts.tv_nsec = (long)*us * 1000;
  nanosleep(&ts, NULL);
}

/* ---- Server ranks -------------------------------------------------------- */

int rp_mpi__rank_claim(rp_context *ctx, int rank) {
  int err = 0;
  uv_mutex_lock(&mod.lock);
  if (mod.ranks[rank].lost)
    err = rp__fail(ctx, RP_EDEVICE, "mpi: rank %d was given up on "
                   "earlier (%s)", rank, mod.ranks[rank].why);
  else if (mod.ranks[rank].open)
    err = rp__fail(ctx, RP_EBUSY, "mpi: rank %d is already open as "
                   "another device of this process (one device per rank)",
                   rank);
  else
    mod.ranks[rank].open = 1;
  uv_mutex_unlock(&mod.lock);
  return err;
}

void rp_mpi__rank_release(int rank) {
  uv_mutex_lock(&mod.lock);
  mod.ranks[rank].open = 0;
  uv_mutex_unlock(&mod.lock);
}

void rp_mpi__rank_lose(int rank, const char *why) {
  uv_mutex_lock(&mod.lock);
  if (!mod.ranks[rank].lost) {
    mod.ranks[rank].lost = 1;
    snprintf(mod.ranks[rank].why, sizeof mod.ranks[rank].why, "%s", why);
  }
  uv_mutex_unlock(&mod.lock);
}

int rp_mpi__rank_lost(int rank) {
  int lost;
  uv_mutex_lock(&mod.lock);
  lost = mod.ranks[rank].lost;
  uv_mutex_unlock(&mod.lock);
  return lost;
}

/* ---- Transfers ------------------------------------------------------------- */

rp_mpi__xfer *rp_mpi__xfer_new(int peer) {
  rp_mpi__xfer *x = calloc(1, sizeof *x);
  if (x != NULL)
    x->peer = peer;
  return x;
}

void rp_mpi__xfer_free(rp_mpi__xfer *x) {
  if (x == NULL)
    return;
  free(x->reqs);
  free(x->idx);
  free(x->out);
  free(x->in);
  free(x);
}

int rp_mpi__post(rp_mpi__xfer *x, int send, void *buf, size_t bytes,
                 int tag) {
  size_t chunks = bytes == 0 ? 1 : (bytes + RP_MPI_CHUNK - 1) / RP_MPI_CHUNK;
  size_t c;
  int rc = MPI_SUCCESS;
  if ((size_t)(x->cap - x->nreq) < chunks) {
    size_t cap = (size_t)x->nreq + chunks + 4;
    MPI_Request *r;
    int *idx;
    if (cap > (size_t)(INT32_MAX / 2))
      return MPI_ERR_NO_MEM;
    if ((r = realloc(x->reqs, cap * sizeof *r)) == NULL)
      return MPI_ERR_NO_MEM;
    x->reqs = r;
    if ((idx = realloc(x->idx, cap * sizeof *idx)) == NULL)
      return MPI_ERR_NO_MEM;
    x->idx = idx;
    x->cap = (int)cap;
  }
  uv_mutex_lock(&mod.lock);
  for (c = 0; c < chunks && rc == MPI_SUCCESS; c++) {
    size_t at = c * RP_MPI_CHUNK;
    int n = (int)(bytes - at < RP_MPI_CHUNK ? bytes - at : RP_MPI_CHUNK);
    char *p = (char *)buf + at;
    rc = send ? MPI_Isend(p, n, MPI_BYTE, x->peer, tag, mod.comm,
                          &x->reqs[x->nreq])
              : MPI_Irecv(p, n, MPI_BYTE, x->peer, tag, mod.comm,
                          &x->reqs[x->nreq]);
    if (rc == MPI_SUCCESS)
      x->nreq++;
  }
  uv_mutex_unlock(&mod.lock);
  return rc;
}

int rp_mpi__test(rp_mpi__xfer *x, int *done, int *progress) {
  int rc, count = 0, i;
  *done = 1;
  *progress = 0;
  if (x->nreq == 0)
    return MPI_SUCCESS;
  /* Testsome rather than Testall: a chunk of a long transfer arriving is
   * a sign of life. Completed requests become MPI_REQUEST_NULL, and
   * count is MPI_UNDEFINED once none is left active. */
  uv_mutex_lock(&mod.lock);
  rc = MPI_Testsome(x->nreq, x->reqs, &count, x->idx, MPI_STATUSES_IGNORE);
  uv_mutex_unlock(&mod.lock);
  if (rc != MPI_SUCCESS)
    return rc;
  *progress = count != MPI_UNDEFINED && count > 0;
  for (i = 0; i < x->nreq; i++)
    if (x->reqs[i] != MPI_REQUEST_NULL)
      *done = 0;
  if (*done)
    x->nreq = 0;
  return MPI_SUCCESS;
}

void rp_mpi__abandon(rp_mpi__xfer *x) {
  int i;
  if (x == NULL)
    return;
  uv_mutex_lock(&mod.lock);
  /* Receives are cancelled (Open MPI cancels a receive not yet matched);
   * a send cannot be. Whatever stays pending keeps its buffer here. */
  for (i = 0; i < x->nreq; i++)
    if (x->reqs[i] != MPI_REQUEST_NULL) {
      MPI_Cancel(&x->reqs[i]);
      MPI_Request_free(&x->reqs[i]);
    }
  x->nreq = 0;
  x->next = mod.abandoned;
  mod.abandoned = x;
  uv_mutex_unlock(&mod.lock);
}
