/* The MPI backend (raypace_mpi.h): devices on other ranks. Run under
 * mpirun with 3 ranks (tests/CMakeLists.txt): rank 0 runs the cases,
 * ranks 1 and 2 serve their local device (the first backend with one, as
 * rp_device_create chooses). argv[1] picks the cases:
 *   group  every backend op through a proxy, against the same op on a
 *          local device; frames of a group of the two ranks (and of a
 *          local device with them) against one local device alone
 *   stall  rank 2 is started with RP_MPI_STALL_AT: it stalls on a
 *          raycast, is dropped at its deadline and given up on at the
 *          proxy's timeout; every frame is still whole and right
 *   return rank 2 is started with RP_MPI_STALL_AT and a stall under the
 *          proxy's timeout: dropped at its deadline, it comes back on
 *          probation when the raycast returns, then active
 *   kill   rank 2 is started with RP_MPI_DIE_AT (and mpirun with
 *          --enable-recovery): it dies on a raycast; the same holds
 *   device ranks 1 and 2 are started with RP_MPI_DEVICE=1 and 99: rank
 *          1 serves its backend's device 1, rank 2 no device
 *
 * The oracle is a local device of the servers' backend, so images are
 * compared byte for byte (a region's pixels depend only on its rays, as
 * in test_group); if rank 0 has no device of that backend the reference
 * is used, within the conformance suite's 2/255 on 99.9 % of pixels. */
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <uv.h>

#include "passes.h"
#include "raypace_ao.h"
#include "raypace_group.h"
#include "raypace_mpi.h"
#include "test_util.h"

#define W 64
#define H 64
#define EFFECTS (RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP)

typedef struct scene {
  rp_context *ctx;
  rp_volume *vol;
  rp_histograms *h;
  rp_tf *tf;
  rp_occupancy *occ;
  rp_camera cam;
  rp_render_desc desc;
  rp_frame_probe probe;
  char remote[32];      /* the servers' backend */
  const char *local;    /* the oracle's */
  int exact;            /* the two are the same backend */
} scene;

/* The backend named in a proxy's device name, "rank N BACKEND: ...". */
static void remote_backend(const rp_caps *caps, char *out, size_t size) {
  int rank;
  char name[32] = "";
  if (sscanf(caps->device, "rank %d %31[^:]", &rank, name) != 2)
    fail_msg("proxy device name '%s' does not say its rank and backend",
             caps->device);
  snprintf(out, size, "%s", name);
}

static void scene_camera(scene *s, float azimuth) {
  rp_camera_orbit(&s->cam, s->vol, azimuth, 20.0f, 2.0f);
  assert_int_equal(rp_frame_probe_compute(s->ctx, s->vol, s->tf, s->occ,
                                          &s->cam, &s->desc, 1, 0,
                                          &s->probe),
                   0);
}

static void scene_make(scene *s) {
  rp_generate_desc g = {0};
  rp_device_desc dd = {0};
  rp_device *dev = NULL;
  rp_caps caps;
  uint32_t n = 0;
  int err;
  memset(s, 0, sizeof *s);
  s->ctx = rp_test_context();
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = 48;
  g.seed = 7;
  assert_int_equal(rp_volume_generate(s->ctx, &g, &s->vol), 0);
  assert_int_equal(rp_histograms_build(s->ctx, s->vol, &s->h), 0);
  s->tf = rp_test_preset(s->ctx, "minmax-bone");
  assert_int_equal(rp_occupancy_build(s->ctx, s->h, s->tf, &s->occ), 0);
  s->desc.width = W;
  s->desc.height = H;
  s->desc.effects = EFFECTS;
  scene_camera(s, 30.0f);
  /* What the servers run: ask rank 1. */
  dd.backend = "mpi";
  err = rp_device_create(s->ctx, &dd, &dev);
  if (err == RP_ENODEV && strstr(rp_last_error(s->ctx), "rank 1") != NULL) {
    print_message("rank 1 has no device: %s\n", rp_last_error(s->ctx));
    skip();
  }
  if (err != 0)
    fail_msg("opening mpi:0: %s", rp_last_error(s->ctx));
  rp_device_get_caps(dev, &caps);
  rp_device_destroy(dev);
  remote_backend(&caps, s->remote, sizeof s->remote);
  if (rp_device_count(s->ctx, s->remote, &n) == 0 && n > 0) {
    s->local = s->remote;
    s->exact = 1;
  } else {
    s->local = "reference";
  }
}

static void scene_free(scene *s) {
  rp_occupancy_destroy(s->occ);
  rp_tf_destroy(s->tf);
  rp_histograms_destroy(s->h);
  rp_volume_destroy(s->vol);
  rp_context_destroy(s->ctx);
}

static rp_device *open_device(scene *s, const char *backend, uint32_t index,
                              uint64_t budget) {
  rp_device_desc dd = {0};
  rp_device *dev = NULL;
  dd.backend = backend;
  dd.index = index;
  dd.budget_bytes = budget;
  dd.brick_size = budget != 0 ? 8 : 0;
  if (rp_device_create(s->ctx, &dd, &dev) != 0)
    fail_msg("opening %s:%u: %s", backend, index, rp_last_error(s->ctx));
  assert_int_equal(rp_device_set_volume(dev, s->vol), 0);
  assert_int_equal(rp_device_set_tf(dev, s->tf, s->occ), 0);
  return dev;
}

/* The image as one local device renders it alone. */
static void render_oracle(scene *s, uint8_t *rgba, rp_tile_stats *tiles) {
  rp_device *dev = open_device(s, s->local, 0, 0);
  assert_int_equal(rp_device_render(dev, &s->cam, &s->desc, NULL, rgba,
                                    tiles),
                   0);
  rp_device_destroy(dev);
}

/* Byte for byte on the same backend; else the conformance bound. */
static void assert_images_match(const scene *s, const uint8_t *want,
                                const uint8_t *got, const char *what) {
  size_t i, over = 0, n = (size_t)W * H * 4;
  if (s->exact) {
    if (memcmp(want, got, n) != 0)
      fail_msg("%s: the image differs from %s's", what, s->local);
    return;
  }
  for (i = 0; i < n; i += 4) {
    int c, worst = 0;
    for (c = 0; c < 4; c++) {
      int d = abs((int)want[i + c] - (int)got[i + c]);
      worst = d > worst ? d : worst;
    }
    if (worst > 8)
      fail_msg("%s: pixel %zu off by %d", what, i / 4, worst);
    over += worst > 2;
  }
  if (over * 1000 > (size_t)W * H)
    fail_msg("%s: %zu pixels off by more than 2/255", what, over);
}

/* ---- group ------------------------------------------------------------------ */

/* Every op a front end makes, through mpi:0, against a local device. */
static void test_ops_match_local(void **state) {
  scene s;
  rp_device *remote, *local;
  rp_caps caps;
  uint32_t gw, gh, tx, ty, n = 0;
  size_t px = (size_t)W * H;
  float *fb_r = malloc(px * 2 * sizeof(float));
  float *fb_l = malloc(px * 2 * sizeof(float));
  float *ert_r, *ert_l;
  uint8_t *img_r = malloc(px * 4), *img_l = malloc(px * 4);
  rp_tile_stats t_r[64], t_l[64];
  uint64_t f_r[64], f_l[64];
  rp_region part = {8, 16, 40, 64};
  (void)state;
  scene_make(&s);
  assert_int_equal(rp_device_count(s.ctx, "mpi", &n), 0);
  assert_int_equal(n, 2);
  remote = open_device(&s, "mpi", 0, 0);
  local = open_device(&s, s.local, 0, 0);
  rp_device_get_caps(remote, &caps);
  assert_string_equal(caps.backend, "mpi");
  assert_non_null(strstr(caps.device, "rank 1 "));
  /* Depth pass read back, and the ERT pre-pass: raw outputs, comparable
   * only on one backend. */
  rp__ert_grid(W, H, &gw, &gh);
  ert_r = malloc((size_t)gw * gh * sizeof(float));
  ert_l = malloc((size_t)gw * gh * sizeof(float));
  assert_int_equal(rp_device_depth_pass(remote, &s.cam, &s.desc, fb_r), 0);
  assert_int_equal(rp_device_depth_pass(local, &s.cam, &s.desc, fb_l), 0);
  assert_int_equal(
      rp_device_ert_prepass(remote, &s.cam, &s.desc, 3, 5, ert_r), 0);
  assert_int_equal(rp_device_ert_prepass(local, &s.cam, &s.desc, 3, 5, ert_l),
                   0);
  if (s.exact) {
    assert_memory_equal(fb_r, fb_l, px * 2 * sizeof(float));
    assert_memory_equal(ert_r, ert_l, (size_t)gw * gh * sizeof(float));
  }
  /* A whole frame with its tiles, and its device time. */
  assert_int_equal(rp_device_render(remote, &s.cam, &s.desc, NULL, img_r,
                                    t_r),
                   0);
  assert_true(rp_device_last_time_ns(remote) > 0);
  assert_int_equal(rp_device_render(local, &s.cam, &s.desc, NULL, img_l,
                                    t_l),
                   0);
  assert_images_match(&s, img_l, img_r, "whole frame");
  if (s.exact)
    assert_memory_equal(t_r, t_l, sizeof t_r);
  /* A region: its pixels, tiles and fetch counts, and nothing else. */
  rp_tile_grid(W, H, &tx, &ty);
  memset(img_r, 0x5a, px * 4);
  memset(t_r, 0x6b, sizeof t_r);
  memset(f_r, 0x7c, sizeof f_r);
  memset(f_l, 0x7c, sizeof f_l);
  assert_int_equal(rp__device_render(remote, &s.cam, &s.desc, &part, img_r,
                                     t_r, f_r),
                   0);
  assert_int_equal(rp__device_render(local, &s.cam, &s.desc, &part, img_l,
                                     t_l, f_l),
                   0);
  {
    uint32_t x, y;
    for (y = 0; y < H; y++)
      for (x = 0; x < W; x++) {
        const uint8_t *p = img_r + ((size_t)y * W + x) * 4;
        int in = x >= part.x0 && x < part.x1 && y >= part.y0 && y < part.y1;
        if (in && s.exact)
          assert_memory_equal(p, img_l + ((size_t)y * W + x) * 4, 4);
        else if (!in)
          assert_true(p[0] == 0x5a && p[3] == 0x5a);
      }
    for (y = 0; y < ty; y++)
      for (x = 0; x < tx; x++) {
        size_t i = (size_t)y * tx + x;
        int in = x >= part.x0 / 8 && x < part.x1 / 8 && y >= part.y0 / 8 &&
                 y < part.y1 / 8;
        if (in && s.exact) {
          assert_memory_equal(&t_r[i], &t_l[i], sizeof t_r[i]);
          assert_true(f_r[i] == f_l[i]);
        } else if (!in) {
          assert_true(f_r[i] == 0x7c7c7c7c7c7c7c7cull);
        }
      }
  }
  rp_device_destroy(remote);
  rp_device_destroy(local);
  free(fb_r);
  free(fb_l);
  free(ert_r);
  free(ert_l);
  free(img_r);
  free(img_l);
  scene_free(&s);
}

/* Ambient occlusion through the proxy: a box computed there, and an AO
 * volume uploaded and rendered with. */
static void test_ao(void **state) {
  scene s;
  rp_device *remote, *local;
  rp_ao_desc desc = {4, 2, 3.0f, 1.0f, 0};
  rp_ao_plan *plan = NULL;
  rp_ao *ao = NULL;
  uint32_t lo[3] = {4, 8, 12}, end[3] = {40, 36, 44};
  size_t box = 36 * 28 * 32, px = (size_t)W * H;
  uint8_t *a_r = malloc(box), *a_l = malloc(box);
  uint8_t *img_r = malloc(px * 4), *img_l = malloc(px * 4);
  rp_render_desc d;
  (void)state;
  scene_make(&s);
  remote = open_device(&s, "mpi", 1, 0);
  local = open_device(&s, s.local, 0, 0);
  assert_int_equal(rp_ao_plan_create(s.ctx, s.vol, s.tf, &desc, &plan), 0);
  assert_int_equal(rp_device_compute_ao(remote, plan, lo, end, a_r), 0);
  assert_int_equal(rp_device_compute_ao(local, plan, lo, end, a_l), 0);
  if (s.exact)
    assert_memory_equal(a_r, a_l, box);
  assert_int_equal(rp_ao_compute_reference(s.ctx, s.vol, s.tf, &desc, NULL,
                                           NULL, &ao),
                   0);
  assert_int_equal(rp_device_set_ao(remote, ao), 0);
  assert_int_equal(rp_device_set_ao(local, ao), 0);
  d = s.desc;
  d.effects |= RP_EFFECT_AO;
  assert_int_equal(rp_device_render(remote, &s.cam, &d, NULL, img_r, NULL),
                   0);
  assert_int_equal(rp_device_render(local, &s.cam, &d, NULL, img_l, NULL),
                   0);
  assert_images_match(&s, img_l, img_r, "AO render");
  assert_int_equal(rp_device_set_ao(remote, NULL), 0);
  rp_ao_destroy(ao);
  rp_ao_plan_destroy(plan);
  rp_device_destroy(remote);
  rp_device_destroy(local);
  free(a_r);
  free(a_l);
  free(img_r);
  free(img_l);
  scene_free(&s);
}

/* Out of core through the proxy: a pool of half the volume in 8^3
 * bricks on the rank (set_brick_pool, then upload_bricks for each of the
 * parts the render is cut into), the in-core image. */
static void test_out_of_core(void **state) {
  scene s;
  rp_device *remote, *local;
  rp_brick_stats st;
  size_t px = (size_t)W * H;
  uint8_t *img_r = malloc(px * 4), *img_l = malloc(px * 4);
  (void)state;
  scene_make(&s);
  remote = open_device(&s, "mpi", 0, 48 * 48 * 48 / 2);
  assert_int_equal(rp_device_get_brick_stats(remote, &st), 0);
  assert_true(st.out_of_core);
  local = open_device(&s, s.local, 0, 0);
  if (rp_device_render(remote, &s.cam, &s.desc, NULL, img_r, NULL) != 0)
    fail_msg("out-of-core render: %s", rp_last_error(s.ctx));
  assert_int_equal(rp_device_get_brick_stats(remote, &st), 0);
  assert_true(st.misses > 0 && st.last_upload_bytes > 0);
  print_message("out of core on rank 1: %u of %u bricks resident, render "
                "in %u parts\n", st.resident, st.bricks, st.last_pieces);
  assert_int_equal(rp_device_render(local, &s.cam, &s.desc, NULL, img_l,
                                    NULL),
                   0);
  assert_images_match(&s, img_l, img_r, "out-of-core render");
  rp_device_destroy(remote);
  rp_device_destroy(local);
  free(img_r);
  free(img_l);
  scene_free(&s);
}

/* One device per rank, and only as many as there are server ranks. */
static void test_open_errors(void **state) {
  scene s;
  rp_device_desc dd = {0};
  rp_device *a = NULL, *b = NULL;
  (void)state;
  scene_make(&s);
  dd.backend = "mpi";
  assert_int_equal(rp_device_create(s.ctx, &dd, &a), 0);
  assert_int_equal(rp_device_create(s.ctx, &dd, &b), RP_EBUSY);
  assert_non_null(strstr(rp_last_error(s.ctx), "rank 1"));
  rp_device_destroy(a);
  assert_int_equal(rp_device_create(s.ctx, &dd, &b), 0);
  rp_device_destroy(b);
  dd.index = 2;
  assert_int_equal(rp_device_create(s.ctx, &dd, &b), RP_ENODEV);
  scene_free(&s);
}

/* A group on the scene (deadline `factor`: -1 none). */
static rp_device_group *make_group(scene *s, const rp_device_desc *dd,
                                   uint32_t count, double factor,
                                   double tail) {
  rp_group_desc gd = {0};
  rp_device_group *g = NULL;
  gd.devices = dd;
  gd.count = count;
  gd.deadline_factor = factor;
  gd.tail_fraction = tail;
  if (rp_device_group_create(s->ctx, &gd, &g) != 0)
    fail_msg("rp_device_group_create: %s", rp_last_error(s->ctx));
  assert_int_equal(rp_device_group_set_volume(g, s->vol), 0);
  assert_int_equal(rp_device_group_set_tf(g, s->tf, s->occ), 0);
  return g;
}

/* Frame f of an orbit, rendered by g and trained on, against the oracle.
 * The report in *rep. */
static void group_frame(scene *s, rp_device_group *g, int f,
                        rp_group_report *rep) {
  size_t px = (size_t)W * H;
  uint8_t *want = malloc(px * 4), *got = malloc(px * 4);
  char what[64];
  double sum = 0.0;
  uint32_t i;
  scene_camera(s, 30.0f + 7.0f * (float)f);
  render_oracle(s, want, NULL);
  memset(got, 0xab, px * 4);
  if (rp_device_group_render(g, &s->cam, &s->desc, &s->probe, got, NULL,
                             rep) != 0)
    fail_msg("frame %d: %s", f, rp_last_error(s->ctx));
  assert_int_equal(rp_device_group_train(g, &s->probe, 1.0f, 1.0f,
                                         rep->render_ms),
                   0);
  snprintf(what, sizeof what, "frame %d", f);
  assert_images_match(s, want, got, what);
  for (i = 0; i < rep->count; i++)
    sum += rep->devices[i].share;
  assert_true(fabs(sum - 1.0) < 1e-12);
  free(want);
  free(got);
}

static int region_empty(const rp_region *r) {
  return r->x0 >= r->x1 || r->y0 >= r->y1;
}

/* The two ranks as a group, then with a local device beside them: every
 * frame the oracle's image, every device a region. */
static void test_group_frames(void **state) {
  scene s;
  rp_device_desc dd[3];
  rp_device_group *g;
  rp_group_report rep;
  uint32_t i;
  int f;
  (void)state;
  scene_make(&s);
  memset(dd, 0, sizeof dd);
  dd[0].backend = dd[1].backend = "mpi";
  dd[1].index = 1;
  g = make_group(&s, dd, 2, -1.0, 0.0);
  for (f = 0; f < 6; f++) {
    group_frame(&s, g, f, &rep);
    assert_int_equal(rep.alive, 2);
    assert_int_equal(rep.lost, 0);
    for (i = 0; i < 2; i++)
      assert_false(region_empty(&rep.devices[i].region));
    print_message("frame %d: shares %.3f %.3f, busy %.1f %.1f ms\n", f,
                  rep.devices[0].share, rep.devices[1].share,
                  rep.devices[0].busy_ms, rep.devices[1].busy_ms);
  }
  rp_device_group_destroy(g);
  /* Rank 0 renders too. */
  dd[2] = dd[0];
  dd[0].backend = s.local;
  dd[0].index = 0;
  g = make_group(&s, dd, 3, -1.0, 0.0);
  for (f = 0; f < 3; f++) {
    group_frame(&s, g, f, &rep);
    assert_int_equal(rep.alive, 3);
  }
  rp_device_group_destroy(g);
  scene_free(&s);
}

/* ---- stall and kill --------------------------------------------------------- */

/* Without a tail (rp_group_desc), a device raycasts once a frame: the
 * launch's RP_MPI_STALL_AT / RP_MPI_DIE_AT then fall in a known frame. */
#define NO_TAIL -1.0

/* Rank 2 fails on a raycast of the group (stalls or dies, as the launch
 * set it up): the frame it fails in is whole and right, rank 2 is
 * dropped, later frames are rank 1's, the group reports it out for good
 * after its re-creations fail, and the proxy has given it up. `warm`:
 * frames of a group without deadlines first, so that kernels are built
 * before deadlines and timeouts count; `timeout` is set as the proxies'
 * RP_MPI_TIMEOUT_MS for the group that fails. */
static void lose_rank_2(int warm, const char *timeout) {
  scene s;
  rp_device_desc dd[2];
  rp_device_group *g;
  rp_group_report rep;
  rp_device *dev = NULL;
  int f, lost_at = -1;
  scene_make(&s);
  memset(dd, 0, sizeof dd);
  dd[0].backend = dd[1].backend = "mpi";
  dd[1].index = 1;
  if (warm > 0) {
    g = make_group(&s, dd, 2, -1.0, NO_TAIL);
    for (f = 0; f < warm; f++) {
      group_frame(&s, g, f, &rep);
      assert_false(region_empty(&rep.devices[1].region));
    }
    rp_device_group_destroy(g);
  }
  if (timeout != NULL)
    setenv("RP_MPI_TIMEOUT_MS", timeout, 1); /* no thread reads it now */
  g = make_group(&s, dd, 2, 0.0, NO_TAIL); /* the default deadline */
  for (f = 0; f < 8; f++) {
    group_frame(&s, g, f, &rep);
    if (lost_at < 0 && rep.lost > 0) {
      lost_at = f;
      assert_int_equal(rep.lost, 1);
      assert_true(rep.devices[1].dropped);
      assert_int_equal(rep.devices[1].status, RP_EDEVICE);
      print_message("frame %d: rank 2 lost (%s): %s\n", f,
                    rep.devices[1].late ? "late" : "failed",
                    rep.devices[1].error);
    } else if (lost_at >= 0) {
      assert_int_equal(rep.alive, 1);
      assert_true(region_empty(&rep.devices[1].region));
    } else {
      assert_int_equal(rep.alive, 2);
      assert_false(region_empty(&rep.devices[1].region));
    }
  }
  if (lost_at < 0)
    fail_msg("rank 2 was never lost");
  /* Once the proxy's verdict is in (its worker is still in the raycast),
   * the late work has failed: each re-creation after a back-off fails
   * too (the rank is given up on), and after RP_GROUP_MAX_FAILURES the
   * report says it is out for good. Frames 20 ms apart meanwhile. */
  for (f = 8; f < 600 && rep.devices[1].state != RP_DEVICE_OUT; f++) {
    group_frame(&s, g, f, &rep);
    assert_int_equal(rep.alive, 1);
    if (rep.devices[1].status != 0)
      assert_non_null(strstr(rep.devices[1].error, "rank 2"));
    uv_sleep(20);
  }
  print_message("frame %d: rank 2 %s after %u failures: %s\n", f - 1,
                rep.devices[1].state == RP_DEVICE_OUT ? "out" : "not out",
                rep.devices[1].failures, rep.devices[1].error);
  assert_int_equal(rep.devices[1].state, RP_DEVICE_OUT);
  assert_int_equal(rep.devices[1].failures, RP_GROUP_MAX_FAILURES);
  rp_device_group_destroy(g);
  dd[1].backend = "mpi";
  assert_int_equal(rp_device_create(s.ctx, &dd[1], &dev), RP_EDEVICE);
  print_message("reopening rank 2: %s\n", rp_last_error(s.ctx));
  assert_non_null(strstr(rp_last_error(s.ctx), "rank 2"));
  /* Rank 1 is as good as ever. */
  g = make_group(&s, dd, 1, -1.0, 0.0);
  group_frame(&s, g, 9, &rep);
  rp_device_group_destroy(g);
  scene_free(&s);
}

/* Rank 2 runs with RP_MPI_STALL_AT=5 and RP_MPI_STALL_MS=4000: its 5th
 * raycast, the third frame of the deadline group, after two warm-up
 * frames. The group drops it at its deadline (hundreds of ms); the
 * proxy, at 1.5 s, gives it up. */
static void test_stall(void **state) {
  (void)state;
  lose_rank_2(2, "1500");
}

/* Rank 2 runs with RP_MPI_STALL_AT=5 and RP_MPI_STALL_MS=2000, well
 * under the proxy's timeout (RP_MPI_TIMEOUT_MS, 60 s): a rank that
 * stalls and returns (its heartbeat goes on). After two warm-up frames
 * its 5th raycast is the third frame of the deadline group: the group
 * gives it up at its deadline (that frame whole and right, rank 1
 * re-rendering its region) and it is LATE, rank 1 carrying every frame,
 * until the raycast returns; at the next frame it is back on probation
 * (its share at most RP_GROUP_PROBATION_SHARE), and active
 * RP_GROUP_PROBATION_FRAMES frames on time later, never counted as
 * failed. Frames come 20 ms apart while it is away, as an app's. On a
 * machine loaded by others, rank 1 too may run late on a frame (it
 * comes back the same way) or rank 2 may be late before its stall: the
 * bounds are on the ranks' failures (none), on rank 2 having been given
 * up on, and on its last return. */
static void test_return(void **state) {
  scene s;
  rp_device_desc dd[2];
  rp_device_group *g;
  rp_group_report rep;
  int f, late_f = -1, back_f = -1, active_f = -1;
  uint32_t away = 0;
  (void)state;
  scene_make(&s);
  memset(dd, 0, sizeof dd);
  dd[0].backend = dd[1].backend = "mpi";
  dd[1].index = 1;
  g = make_group(&s, dd, 2, -1.0, NO_TAIL);
  for (f = 0; f < 2; f++)
    group_frame(&s, g, f, &rep);
  rp_device_group_destroy(g);
  g = make_group(&s, dd, 2, 0.0, NO_TAIL);
  for (f = 0; f < 500 && (active_f < 0 || f <= 2); f++) {
    const rp_group_device *rd = &rep.devices[1];
    group_frame(&s, g, f, &rep);
    assert_int_equal(rd->failures, 0);
    assert_int_equal(rep.devices[0].failures, 0);
    if (rd->late && late_f < 0)
      late_f = f;
    if (rd->state == RP_DEVICE_LATE) {
      assert_int_equal(rep.alive, 1);
      away++;
      uv_sleep(20);
      continue;
    }
    if (rep.returned > 0 && rd->state == RP_DEVICE_PROBATION) {
      back_f = f;
      active_f = -1;
    }
    if (rd->state == RP_DEVICE_PROBATION)
      assert_true(rd->share <= RP_GROUP_PROBATION_SHARE + 1e-12);
    if (back_f >= 0 && rd->state == RP_DEVICE_ACTIVE && active_f < 0)
      active_f = f;
  }
  print_message("rank 2: late at frame %d, away %u frames, back on "
                "probation at %d, active at %d (share %.3f)\n", late_f,
                away, back_f, active_f, rep.devices[1].share);
  assert_true(late_f >= 0 && back_f > late_f);
  assert_int_equal(active_f - back_f, RP_GROUP_PROBATION_FRAMES - 1);
  rp_device_group_destroy(g);
  scene_free(&s);
}

/* Rank 2 runs with RP_MPI_DIE_AT=3 and dies (SIGKILL) in the third frame:
 * dropped at the group's deadline or, at the latest, when its heartbeat
 * has been silent for RP_MPI_SILENCE_MS. */
static void test_kill(void **state) {
  (void)state;
  lose_rank_2(0, NULL);
}

/* ---- which device a rank serves ---------------------------------------------- */

/* Rank 1 runs with RP_MPI_DEVICE=1, rank 2 with RP_MPI_DEVICE=99: rank 1
 * serves its backend's device 1 (the caps a local device 1 has), rank 2
 * none, and every open of it says why. */
static void test_device_choice(void **state) {
  rp_context *ctx = rp_test_context();
  rp_device_desc dd = {0};
  rp_device *dev = NULL, *local = NULL;
  rp_caps remote, mine;
  char backend[32];
  uint32_t n = 0;
  int err;
  (void)state;
  dd.backend = "mpi";
  dd.index = 1;
  assert_int_not_equal(rp_device_create(ctx, &dd, &dev), 0);
  print_message("mpi:1: %s\n", rp_last_error(ctx));
  assert_non_null(strstr(rp_last_error(ctx), "device 99 (RP_MPI_DEVICE)"));
  dd.index = 0;
  if ((err = rp_device_create(ctx, &dd, &dev)) != 0) {
    /* A backend with one device here: device 1 is refused the same way. */
    print_message("mpi:0: %s\n", rp_last_error(ctx));
    assert_non_null(strstr(rp_last_error(ctx), "device 1 (RP_MPI_DEVICE)"));
    rp_context_destroy(ctx);
    skip();
  }
  rp_device_get_caps(dev, &remote);
  rp_device_destroy(dev);
  remote_backend(&remote, backend, sizeof backend);
  if (rp_device_count(ctx, backend, &n) == 0 && n >= 2) {
    rp_device_desc ld = {0};
    ld.backend = backend;
    ld.index = 1;
    assert_int_equal(rp_device_create(ctx, &ld, &local), 0);
    rp_device_get_caps(local, &mine);
    rp_device_destroy(local);
    print_message("mpi:0 serves '%s' (%u compute units); local %s:1 is "
                  "'%s' (%u)\n", remote.device, remote.compute_units,
                  backend, mine.device, mine.compute_units);
    {
      /* The remote name is "rank R BACKEND: " + the local name, cut to
       * the caps field's size: a long CPU name loses its tail. */
      const char *colon = strstr(remote.device, ": ");
      assert_non_null(colon);
      assert_true(strlen(colon + 2) > 0);
      assert_int_equal(strncmp(colon + 2, mine.device, strlen(colon + 2)),
                       0);
    }
    assert_int_equal(remote.compute_units, mine.compute_units);
    assert_int_equal(remote.sub_device, mine.sub_device);
  }
  rp_context_destroy(ctx);
}

int main(int argc, char **argv) {
  static const struct CMUnitTest group[] = {
      cmocka_unit_test(test_ops_match_local),
      cmocka_unit_test(test_ao),
      cmocka_unit_test(test_out_of_core),
      cmocka_unit_test(test_open_errors),
      cmocka_unit_test(test_group_frames),
  };
  static const struct CMUnitTest stall[] = {cmocka_unit_test(test_stall)};
  static const struct CMUnitTest kill[] = {cmocka_unit_test(test_kill)};
  static const struct CMUnitTest back[] = {cmocka_unit_test(test_return)};
  static const struct CMUnitTest device[] = {
      cmocka_unit_test(test_device_choice)};
  const char *mode;
  int rank = 0, size = 1, rc;
  if (rp_mpi_init(&argc, &argv, &rank, &size) != 0) {
    rp_mpi_finalize();
    return 1;
  }
  mode = argc > 1 ? argv[1] : "group";
  if (size != 3) {
    if (rank == 0)
      fprintf(stderr, "test_mpi: run under mpirun -np 3 (%d rank%s)\n",
              size, size == 1 ? "" : "s");
    rp_mpi_finalize();
    return 77;
  }
  if (rank > 0) {
    rp_context *ctx = rp_test_context();
    rc = rp_mpi_serve(ctx, NULL);
    if (rc != 0)
      fprintf(stderr, "test_mpi: rank %d: %s\n", rank, rp_last_error(ctx));
    rp_context_destroy(ctx);
    rp_mpi_finalize();
    return rc != 0;
  }
  if (strcmp(mode, "stall") == 0)
    rc = cmocka_run_group_tests_name("mpi stall", stall, NULL, NULL);
  else if (strcmp(mode, "return") == 0)
    rc = cmocka_run_group_tests_name("mpi return", back, NULL, NULL);
  else if (strcmp(mode, "kill") == 0)
    rc = cmocka_run_group_tests_name("mpi kill", kill, NULL, NULL);
  else if (strcmp(mode, "device") == 0)
    rc = cmocka_run_group_tests_name("mpi device", device, NULL, NULL);
  else
    rc = cmocka_run_group_tests_name("mpi", group, NULL, NULL);
  /* The verdict, before MPI_Finalize: tests/cli/test_mpi_kill.sh reads it
   * when Open MPI does not end a job that lost a rank. */
  printf("test_mpi: rank 0 done, %d failed\n", rc);
  fflush(stdout);
  rp_mpi_finalize();
  return rc;
}
