/* Rank 0's decoding of what a server rank sends (backends/mpi/
 * mpi_proto.h), without MPI: replies built here as a corrupt or hostile
 * rank would send them. Expected sizes are worked out by hand from the
 * layout rule (pieces one after the other, each at a multiple of 16). */
#include <math.h>
#include <string.h>

#include "mpi_proto.h"
#include "test_util.h"

static void request(rp_mpi_request *q, uint32_t op) {
  memset(q, 0, sizeof *q);
  q->magic = RP_MPI_MAGIC;
  q->op = op;
  q->seq = 41;
}

/* A raycast of the region [0, w) x [0, h) of a w x h image. */
static void raycast(rp_mpi_request *q, uint32_t w, uint32_t h,
                    uint32_t want) {
  request(q, RP_MPI_RAYCAST);
  q->a.frame.p.width = w;
  q->a.frame.p.height = h;
  q->a.frame.region.x1 = w;
  q->a.frame.region.y1 = h;
  q->a.frame.want = want;
}

/* The reply a well-behaved server sends: `bytes` of outputs. */
static void reply_to(const rp_mpi_request *q, rp_mpi_reply *r,
                     uint64_t bytes) {
  memset(r, 0, sizeof *r);
  r->magic = RP_MPI_MAGIC;
  r->op = q->op;
  r->seq = q->seq;
  r->payload_bytes = bytes;
}

/* A 16 x 8 raycast with tile statistics: 16 * 8 * 4 = 512 bytes of
 * pixels, then 2 x 1 tiles of 12 bytes at offset 512: 536 in all. */
static void test_good_reply(void **state) {
  rp_mpi_request q;
  rp_mpi_reply r;
  rp_mpi__layout l;
  char why[320] = "";
  (void)state;
  raycast(&q, 16, 8, RP_MPI_WANT_TILES);
  reply_to(&q, &r, 536);
  r.last_ns = 3000;
  assert_int_equal(rp_mpi__reply_check(&q, &r, 5000, &l, why, sizeof why),
                   0);
  assert_int_equal(l.total, 536);
  assert_int_equal(l.n, 2);
  assert_int_equal(l.off[1], 512);
  assert_int_equal(l.len[1], 2 * sizeof(rp_tile_stats));
  assert_int_equal(r.last_ns, 3000);
}

/* Outputs of any other size than the request's layout are refused, and
 * nothing of the server's stated size reaches the layout: what rank 0
 * allocates stays bounded by its own request. */
static void test_payload_bound(void **state) {
  static const uint64_t sizes[] = {0, 535, 537, (uint64_t)1 << 40,
                                   UINT64_MAX};
  rp_mpi_request q;
  rp_mpi_reply r;
  rp_mpi__layout l;
  size_t i;
  (void)state;
  raycast(&q, 16, 8, RP_MPI_WANT_TILES);
  for (i = 0; i < sizeof sizes / sizeof sizes[0]; i++) {
    char why[320] = "";
    reply_to(&q, &r, sizes[i]);
    assert_int_equal(rp_mpi__reply_check(&q, &r, 1000, &l, why, sizeof why),
                     -1);
    assert_int_equal(l.total, 0);
    assert_non_null(strstr(why, "bytes where 536 were due"));
  }
  /* A request whose own layout overflows is no reply's bound either. */
  raycast(&q, 16, 8, 0);
  q.a.frame.region.x0 = 9; /* x1 < x0 */
  q.a.frame.region.x1 = 8;
  reply_to(&q, &r, 0);
  {
    char why[320] = "";
    assert_int_equal(rp_mpi__reply_check(&q, &r, 1000, &l, why, sizeof why),
                     -1);
    assert_non_null(strstr(why, "too large to address"));
  }
}

static void test_wrong_answer(void **state) {
  rp_mpi_request q;
  rp_mpi_reply r;
  rp_mpi__layout l;
  char why[320] = "";
  (void)state;
  request(&q, RP_MPI_CLOSE);
  reply_to(&q, &r, 0);
  r.seq = 40; /* an earlier request's */
  assert_int_equal(rp_mpi__reply_check(&q, &r, 1000, &l, why, sizeof why),
                   -1);
  assert_non_null(strstr(why, "seq 41"));
  reply_to(&q, &r, 0);
  r.op = RP_MPI_OPEN;
  assert_int_equal(rp_mpi__reply_check(&q, &r, 1000, &l, why, sizeof why),
                   -1);
  reply_to(&q, &r, 0);
  r.magic = 0;
  assert_int_equal(rp_mpi__reply_check(&q, &r, 1000, &l, why, sizeof why),
                   -1);
}

/* A failure carries one of the library's codes and no outputs; its
 * message comes out terminated and printable. */
static void test_failures(void **state) {
  static const int32_t bad[] = {1, 5, -16, -1000, INT32_MIN, INT32_MAX};
  rp_mpi_request q;
  rp_mpi_reply r;
  rp_mpi__layout l;
  char why[320];
  size_t i;
  (void)state;
  raycast(&q, 16, 8, 0);
  for (i = 0; i < sizeof bad / sizeof bad[0]; i++) {
    reply_to(&q, &r, 0);
    r.status = bad[i];
    why[0] = '\0';
    assert_int_equal(rp_mpi__reply_check(&q, &r, 1000, &l, why, sizeof why),
                     -1);
    assert_non_null(strstr(why, "not an error code"));
  }
  reply_to(&q, &r, 512);
  r.status = RP_EDEVICE;
  assert_int_equal(rp_mpi__reply_check(&q, &r, 1000, &l, why, sizeof why),
                   -1);
  reply_to(&q, &r, 0);
  r.status = RP_EDEVICE;
  memset(r.error, 'x', sizeof r.error);
  r.error[3] = '\033';
  r.error[4] = '\n';
  assert_int_equal(rp_mpi__reply_check(&q, &r, 1000, &l, why, sizeof why),
                   0);
  assert_int_equal(r.status, RP_EDEVICE);
  assert_int_equal(l.total, 0);
  assert_int_equal(strlen(r.error), sizeof r.error - 1);
  assert_memory_equal(r.error, "xxx??x", 6);
}

/* A device time beyond the exchange's is cut to it; the caps' names come
 * out terminated. */
static void test_time_and_caps(void **state) {
  rp_mpi_request q;
  rp_mpi_reply r;
  rp_mpi__layout l;
  char why[320] = "";
  (void)state;
  request(&q, RP_MPI_OPEN);
  reply_to(&q, &r, 0);
  r.last_ns = UINT64_MAX;
  memset(r.caps.backend, 'b', sizeof r.caps.backend);
  memset(r.caps.device, 'd', sizeof r.caps.device);
  assert_int_equal(rp_mpi__reply_check(&q, &r, 7000, &l, why, sizeof why),
                   0);
  assert_int_equal(r.last_ns, 7000);
  assert_int_equal(strlen(r.caps.backend), sizeof r.caps.backend - 1);
  assert_int_equal(strlen(r.caps.device), sizeof r.caps.device - 1);
}

/* A tile holds 64 pixels: more rays hit is a lie, as is a depth that is
 * not a number. */
static void test_tile_stats(void **state) {
  rp_mpi_request q;
  rp_mpi_reply r;
  rp_mpi__layout l;
  char why[320] = "";
  union {
    uint8_t bytes[536];
    float align;
  } in;
  rp_tile_stats t[2];
  (void)state;
  raycast(&q, 16, 8, RP_MPI_WANT_TILES);
  reply_to(&q, &r, 536);
  assert_int_equal(rp_mpi__reply_check(&q, &r, 1000, &l, why, sizeof why),
                   0);
  memset(&in, 0, sizeof in);
  memset(t, 0, sizeof t);
  t[0].rays_hit = 64;
  t[0].mean_depth = 3.5f;
  memcpy(in.bytes + 512, t, sizeof t);
  assert_int_equal(rp_mpi__reply_payload_check(&q, &l, in.bytes, why,
                                               sizeof why), 0);
  t[1].rays_hit = 65;
  memcpy(in.bytes + 512, t, sizeof t);
  assert_int_equal(rp_mpi__reply_payload_check(&q, &l, in.bytes, why,
                                               sizeof why), -1);
  assert_non_null(strstr(why, "tile 1 with 65 rays"));
  t[1].rays_hit = 0;
  t[1].mean_depth = NAN;
  memcpy(in.bytes + 512, t, sizeof t);
  assert_int_equal(rp_mpi__reply_payload_check(&q, &l, in.bytes, why,
                                               sizeof why), -1);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_good_reply),
      cmocka_unit_test(test_payload_bound),
      cmocka_unit_test(test_wrong_answer),
      cmocka_unit_test(test_failures),
      cmocka_unit_test(test_time_and_caps),
      cmocka_unit_test(test_tile_stats),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
