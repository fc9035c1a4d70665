/* libFuzzer target: what a hostile or corrupt MPI rank can send rank 0,
 * decoded without MPI (backends/mpi/mpi_proto.h). One input is
 *   [rp_mpi_request][rp_mpi_reply][uint64 elapsed ns][reply payload]
 * (missing bytes read as zeros): rank 0's request, here arbitrary too so
 * that every op and shape is reached, the server's reply header to it,
 * how long the exchange took, and the outputs that follow. The request's
 * layouts and the reply's decoding are held to mpi_proto.h's promises:
 * layouts whose pieces are aligned, disjoint and inside their total; a
 * reply either refused with a reason or made safe (a known status,
 * printable terminated text, a device time within the exchange, outputs
 * exactly as large as the request's reply layout). fuzz/mpi_wire_seeds.c
 * writes the seeds. */
#include <stdio.h>

#include "fuzz_common.h"
#include "mpi_proto.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* Outputs larger than this are decoded but not materialised here; rank 0
 * allocates what its own request asks for, which a fuzzed request can
 * make arbitrary. */
#define FUZZ_MAX_PAYLOAD ((size_t)1 << 20)

static void take(void *dst, size_t n, const uint8_t **p, size_t *left) {
  size_t k = *left < n ? *left : n;
  memset(dst, 0, n);
  memcpy(dst, *p, k);
  *p += k;
  *left -= k;
}

static void check_layout(const rp_mpi__layout *l) {
  size_t end = 0;
  uint32_t i;
  if (l->n > RP_MPI_MAX_PIECES)
    abort();
  for (i = 0; i < l->n; i++) {
    if (l->off[i] % 16 != 0 || l->off[i] < end ||
        l->len[i] > l->total - l->off[i])
      abort();
    end = l->off[i] + l->len[i];
  }
  if (l->total != end)
    abort();
}

static int printable(const char *s, size_t size) {
  size_t n = strnlen(s, size), i;
  if (n == size)
    return 0;
  for (i = 0; i < n; i++)
    if ((unsigned char)s[i] < 0x20 || s[i] == 0x7f)
      return 0;
  return 1;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  rp_mpi_request req;
  rp_mpi_reply rep;
  rp_mpi__layout l, pl;
  uint64_t elapsed;
  char why[320];
  const uint8_t *p = data;
  size_t left = size;
  void *in;

  take(&req, sizeof req, &p, &left);
  take(&rep, sizeof rep, &p, &left);
  take(&elapsed, sizeof elapsed, &p, &left);
  if (rp_mpi__op_name(req.op) == NULL)
    abort();
  if (rp_mpi__request_layout(&req, &l) == 0)
    check_layout(&l);
  why[0] = '\0';
  if (rp_mpi__reply_check(&req, &rep, elapsed, &pl, why, sizeof why) != 0) {
    if (why[0] == '\0' || pl.total != 0)
      abort();
    return 0;
  }
  if (rep.magic != RP_MPI_MAGIC || rep.op != req.op || rep.seq != req.seq ||
      rep.last_ns > elapsed || !printable(rep.error, sizeof rep.error) ||
      !printable(rep.caps.backend, sizeof rep.caps.backend) ||
      !printable(rep.caps.device, sizeof rep.caps.device))
    abort();
  if (rep.status != 0) {
    if (rep.status > 0 || rep.payload_bytes != 0 || pl.total != 0)
      abort();
    return 0;
  }
  check_layout(&pl);
  if (rep.payload_bytes != pl.total || rp_mpi__reply_layout(&req, &l) != 0 ||
      l.total != pl.total)
    abort();
  if (pl.total == 0 || pl.total > FUZZ_MAX_PAYLOAD)
    return 0;
  /* As rank 0 receives them: zeroed, then what arrived. */
  if ((in = calloc(1, pl.total)) == NULL)
    abort();
  memcpy(in, p, left < pl.total ? left : pl.total);
  why[0] = '\0';
  if (rp_mpi__reply_payload_check(&req, &pl, in, why, sizeof why) != 0 &&
      why[0] == '\0')
    abort();
  free(in);
  return 0;
}
