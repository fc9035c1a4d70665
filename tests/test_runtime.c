/* The libuv runtime (runtime/runtime.c): which passes each kind of event
 * runs, coalescing, both pacing modes, events from another thread, close
 * and destroy with a frame in flight, and refused input.
 *
 * Frames render on the reference device with the "none" controller, so a
 * frame is the full-quality image: each one is checked against
 * rp_render_reference for the camera and TF the test posted last, an
 * oracle outside the runtime. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <uv.h>

#include "raypace_ao.h"
#include "raypace_runtime.h"
#include "test_util.h"

#define W 40
#define H 32
#define EFFECTS (RP_EFFECT_ERT | RP_EFFECT_SKIP)

/* What the frame callback saw; guarded by `lock` for the tests whose
 * runtime delivers on its own loop thread. */
typedef struct seen {
  uv_mutex_t lock;
  int frames, failed;
  rp_frame_stats last;
  uint8_t image[W * H * 4];
  int has_image;
  int close_in_callback; /* app loop: close from inside the callback */
  int closed;
  rp_runtime *rt;
} seen;

static void on_closed(void *user) { ((seen *)user)->closed = 1; }

static void on_frame(rp_runtime *rt, const rp_frame *f, void *user) {
  seen *s = user;
  uv_mutex_lock(&s->lock);
  s->frames++;
  s->last = *f->stats;
  s->has_image = f->rgba != NULL;
  if (f->stats->status != 0)
    s->failed++;
  if (f->rgba != NULL) {
    assert_int_equal(f->width, W);
    assert_int_equal(f->height, H);
    memcpy(s->image, f->rgba, sizeof s->image);
  }
  uv_mutex_unlock(&s->lock);
  if (s->close_in_callback)
    assert_int_equal(rp_runtime_close(rt, on_closed, s), 0);
}

static rp_volume *make_volume(rp_context *ctx, uint32_t n, uint32_t seed) {
  rp_generate_desc g = {0};
  rp_volume *vol = NULL;
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = n;
  g.seed = seed;
  assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
  return vol;
}

static rp_camera orbit(const rp_volume *vol, float az) {
  rp_camera cam = {0};
  rp_camera_orbit(&cam, vol, az, 20.0f, 2.2f);
  return cam;
}

/* Posts a volume (the runtime takes it), a TF preset and a camera: the
 * least a frame needs. Returns the TF, which stays the caller's. */
static rp_tf *post_scene(rp_runtime *rt, rp_context *ctx, rp_volume *vol,
                         const char *tf_name, const rp_camera *cam) {
  rp_tf *tf = NULL;
  assert_int_equal(rp_tf_create_preset(ctx, tf_name, &tf), 0);
  assert_int_equal(rp_runtime_set_volume(rt, vol), 0);
  assert_int_equal(rp_runtime_set_tf(rt, tf), 0);
  assert_int_equal(rp_runtime_set_camera(rt, cam), 0);
  return tf;
}

/* The oracle: the reference raycaster at full quality, with `ao` (NULL:
 * without AO). */
static void expect_reference_ao(rp_context *ctx, const rp_volume *vol,
                                const rp_tf *tf, const rp_ao *ao,
                                const rp_camera *cam, uint32_t seed,
                                const uint8_t *got) {
  rp_test_expect_reference(ctx, vol, tf, ao, cam, W, H, EFFECTS, seed, got);
}

static void expect_reference(rp_context *ctx, const rp_volume *vol,
                             const rp_tf *tf, const rp_camera *cam,
                             uint32_t seed, const uint8_t *got) {
  expect_reference_ao(ctx, vol, tf, NULL, cam, seed, got);
}

/* ---- App loop, on-request pacing --------------------------------------- */

typedef struct app {
  rp_context *ctx;
  uv_loop_t loop;
  rp_runtime *rt;
  seen s;
} app;

/* devices / count: the runtime's device list (count 0: one reference
 * device through desc.device). */
static void app_open_full(app *a, const rp_device_desc *devices,
                          uint32_t count, double ao_frame_share,
                          float min_step) {
  rp_runtime_desc d = {0};
  memset(a, 0, sizeof *a);
  a->ctx = rp_test_context();
  assert_int_equal(uv_mutex_init(&a->s.lock), 0);
  assert_int_equal(uv_loop_init(&a->loop), 0);
  d.loop = &a->loop;
  d.device.backend = "reference";
  d.pacing = RP_PACE_ON_REQUEST;
  d.on_frame = on_frame;
  d.user = &a->s;
  d.width = W;
  d.height = H;
  d.effects = EFFECTS;
  d.target_ms = 1000.0;
  d.devices = devices;
  d.device_count = count;
  d.ao_frame_share = ao_frame_share;
  d.space.min_step = min_step;
  assert_int_equal(rp_runtime_create(a->ctx, &d, &a->rt), 0);
  a->s.rt = a->rt;
}

static void app_open_ao(app *a, const rp_device_desc *devices,
                        uint32_t count, double ao_frame_share) {
  app_open_full(a, devices, count, ao_frame_share, 0.0f);
}

static void app_open_devices(app *a, const rp_device_desc *devices,
                             uint32_t count) {
  app_open_ao(a, devices, count, 0.0);
}

static void app_open(app *a) { app_open_devices(a, NULL, 0); }

static void app_close(app *a) {
  assert_int_equal(rp_runtime_close(a->rt, on_closed, &a->s), 0);
  while (!a->s.closed && uv_run(&a->loop, UV_RUN_ONCE) != 0)
    ;
  assert_true(a->s.closed);
  /* Nothing of the runtime is left on the loop. */
  assert_int_equal(uv_run(&a->loop, UV_RUN_NOWAIT), 0);
  assert_int_equal(uv_loop_close(&a->loop), 0);
  uv_mutex_destroy(&a->s.lock);
}

/* Requests one frame and runs the loop until it is delivered; returns
 * the counters' change over that frame. */
static rp_runtime_counters frame(app *a) {
  rp_runtime_counters before, d;
  int n = a->s.frames;
  uint64_t included = a->s.last.events;
  rp_runtime_get_counters(a->rt, &before);
  assert_int_equal(rp_runtime_request_frame(a->rt), 0);
  while (a->s.frames == n)
    uv_run(&a->loop, UV_RUN_ONCE);
  assert_int_equal(a->s.frames, n + 1);
  d = a->s.last.counters;
  /* Events are counted when posted, before `before`: what a frame
   * includes is the difference of stats.events. */
  d.events = a->s.last.events - included;
#define SUB(f) d.f -= before.f
  SUB(histograms); SUB(volume_uploads); SUB(occupancies);
  SUB(tf_uploads); SUB(probes); SUB(device_depth); SUB(renders);
  SUB(frames);
#undef SUB
  return d;
}

#define expect_passes(d, hist, occ_, probe)                                  \
  do {                                                                       \
    assert_int_equal((d).histograms, (hist));                                \
    assert_int_equal((d).volume_uploads, (hist));                            \
    assert_int_equal((d).occupancies, (occ_));                               \
    assert_int_equal((d).tf_uploads, (occ_));                                \
    assert_int_equal((d).probes, (probe));                                   \
    assert_int_equal((d).renders, 1);                                        \
    assert_int_equal((d).frames, 1);                                         \
  } while (0)

static void test_passes_per_event(void **state) {
  app a;
  rp_volume *vol, *vol2;
  rp_tf *bone = NULL, *soft = NULL;
  rp_runtime_counters d;
  rp_camera cam;
  int i;
  (void)state;
  app_open(&a);
  vol = make_volume(a.ctx, 32, 1);
  /* The runtime takes `vol`; the oracle needs one of its own. */
  vol2 = make_volume(a.ctx, 32, 1);
  assert_int_equal(rp_tf_create_preset(a.ctx, "minmax-bone", &bone), 0);
  assert_int_equal(rp_tf_create_preset(a.ctx, "minmax-soft", &soft), 0);
  cam = orbit(vol2, 30.0f);
  assert_int_equal(rp_runtime_set_volume(a.rt, vol), 0);
  assert_int_equal(rp_runtime_set_tf(a.rt, bone), 0);
  assert_int_equal(rp_runtime_set_camera(a.rt, &cam), 0);

  d = frame(&a); /* first frame: everything */
  expect_passes(d, 1, 1, 1);
  assert_int_equal(d.device_depth, 1);
  assert_int_equal(a.s.last.status, 0);
  expect_reference(a.ctx, vol2, bone, &cam, a.s.last.jitter_seed,
                   a.s.image);
  /* Jittered by default, a seed of its own per frame. */
  assert_int_equal(a.s.last.jitter_seed,
                   rp_jitter_frame_seed(0u, a.s.last.frame));

  d = frame(&a); /* nothing changed: nothing recomputed, depth reused */
  expect_passes(d, 0, 0, 0);
  assert_int_equal(d.device_depth, 0);

  assert_int_equal(rp_runtime_set_tf(a.rt, soft), 0); /* TF only */
  d = frame(&a);
  expect_passes(d, 0, 1, 1); /* the probe reads H-alpha and occupancy */
  assert_int_equal(d.device_depth, 1); /* D_front follows occupancy */
  expect_reference(a.ctx, vol2, soft, &cam, a.s.last.jitter_seed,
                   a.s.image);

  cam = orbit(vol2, 75.0f); /* camera only */
  assert_int_equal(rp_runtime_set_camera(a.rt, &cam), 0);
  d = frame(&a);
  expect_passes(d, 0, 0, 1);
  assert_int_equal(d.device_depth, 1);
  expect_reference(a.ctx, vol2, soft, &cam, a.s.last.jitter_seed,
                   a.s.image);

  cam = orbit(vol2, 120.0f); /* both */
  assert_int_equal(rp_runtime_set_camera(a.rt, &cam), 0);
  assert_int_equal(rp_runtime_set_tf(a.rt, bone), 0);
  d = frame(&a);
  expect_passes(d, 0, 1, 1);
  expect_reference(a.ctx, vol2, bone, &cam, a.s.last.jitter_seed,
                   a.s.image);

  /* A burst of 1000 events of each kind between two frames: one
   * recompute each, and the frame shows the last of each. */
  for (i = 0; i < 1000; i++) {
    cam = orbit(vol2, (float)i * 0.37f);
    assert_int_equal(rp_runtime_set_camera(a.rt, &cam), 0);
    assert_int_equal(rp_runtime_set_tf(a.rt, i % 2 ? soft : bone), 0);
  }
  d = frame(&a);
  expect_passes(d, 0, 1, 1);
  assert_int_equal(d.events, 2000);
  assert_int_equal(d.device_depth, 1);
  expect_reference(a.ctx, vol2, soft, &cam, a.s.last.jitter_seed,
                   a.s.image);

  /* The target changes no derived data. Every effect does the probe:
   * shading sets its fetches per sample (k), so a probe left from
   * before priced a shaded frame as an unshaded one. */
  assert_int_equal(rp_runtime_set_target(a.rt, 500.0), 0);
  d = frame(&a);
  expect_passes(d, 0, 0, 0);
  assert_int_equal(a.s.last.target_ms, 500.0);
  assert_int_equal(rp_runtime_set_effects(a.rt, EFFECTS |
                                          RP_EFFECT_SHADING), 0);
  d = frame(&a);
  expect_passes(d, 0, 0, 1);
  assert_int_equal(a.s.last.effects, EFFECTS | RP_EFFECT_SHADING);
  assert_int_equal(rp_runtime_set_effects(a.rt, RP_EFFECT_SKIP), 0);
  d = frame(&a);
  expect_passes(d, 0, 0, 1);
  assert_int_equal(rp_runtime_set_effects(a.rt, EFFECTS), 0);
  d = frame(&a);
  expect_passes(d, 0, 0, 1);
  expect_reference(a.ctx, vol2, soft, &cam, a.s.last.jitter_seed,
                   a.s.image);

  /* A new volume: everything once. */
  vol = make_volume(a.ctx, 32, 1);
  assert_int_equal(rp_runtime_set_volume(a.rt, vol), 0);
  d = frame(&a);
  expect_passes(d, 1, 1, 1);
  expect_reference(a.ctx, vol2, soft, &cam, a.s.last.jitter_seed,
                   a.s.image);
  assert_int_equal(a.s.failed, 0);

  app_close(&a);
  rp_tf_destroy(bone);
  rp_tf_destroy(soft);
  rp_volume_destroy(vol2);
  rp_context_destroy(a.ctx);
}

/* Requests made while nothing can render wait for the scene; requests
 * made before a frame starts coalesce into one frame. */
static void test_requests(void **state) {
  app a;
  rp_volume *vol;
  rp_tf *tf = NULL;
  rp_camera cam;
  (void)state;
  app_open(&a);
  assert_int_equal(rp_runtime_request_frame(a.rt), 0);
  uv_run(&a.loop, UV_RUN_NOWAIT);
  assert_int_equal(a.s.frames, 0); /* no scene yet */
  vol = make_volume(a.ctx, 24, 3);
  cam = orbit(vol, 10.0f);
  tf = post_scene(a.rt, a.ctx, vol, "minmax-bone", &cam);
  assert_int_equal(rp_runtime_request_frame(a.rt), 0);
  assert_int_equal(rp_runtime_request_frame(a.rt), 0);
  while (a.s.frames == 0)
    uv_run(&a.loop, UV_RUN_ONCE);
  /* Three requests, one frame: nothing else starts. */
  uv_run(&a.loop, UV_RUN_NOWAIT);
  uv_run(&a.loop, UV_RUN_NOWAIT);
  {
    rp_runtime_counters c;
    rp_runtime_get_counters(a.rt, &c);
    assert_int_equal(c.renders, 1);
  }
  assert_int_equal(a.s.frames, 1);
  assert_int_equal(a.s.last.events, 3);
  app_close(&a);
  rp_tf_destroy(tf);
  rp_context_destroy(a.ctx);
}

/* Refused events change nothing and leave the caller's data alone, and
 * the next good frame renders. */
static void test_bad_input(void **state) {
  app a;
  rp_volume *vol;
  rp_tf *tf = NULL;
  rp_camera cam, bad;
  rp_runtime_counters c;
  (void)state;
  app_open(&a);
  vol = make_volume(a.ctx, 24, 2);
  cam = orbit(vol, 40.0f);
  assert_int_equal(rp_runtime_set_volume(a.rt, NULL), RP_EINVAL);
  assert_int_equal(rp_runtime_set_tf(a.rt, NULL), RP_EINVAL);
  assert_int_equal(rp_runtime_set_camera(a.rt, NULL), RP_EINVAL);
  bad = cam;
  bad.eye[1] = NAN;
  assert_int_equal(rp_runtime_set_camera(a.rt, &bad), RP_EINVAL);
  bad = cam;
  memcpy(bad.center, bad.eye, sizeof bad.eye);
  assert_int_equal(rp_runtime_set_camera(a.rt, &bad), RP_EINVAL);
  bad = cam;
  bad.fov_y_deg = 180.0f;
  assert_int_equal(rp_runtime_set_camera(a.rt, &bad), RP_EINVAL);
  assert_int_equal(rp_runtime_set_target(a.rt, NAN), RP_ENOTFINITE);
  assert_int_equal(rp_runtime_set_target(a.rt, INFINITY), RP_ENOTFINITE);
  assert_int_equal(rp_runtime_set_target(a.rt, 0.0), RP_ERANGE);
  assert_int_equal(rp_runtime_set_target(a.rt, -5.0), RP_ERANGE);
  assert_int_equal(rp_runtime_set_viewport(a.rt, 0, 10), RP_ERANGE);
  assert_int_equal(rp_runtime_set_viewport(a.rt, 10, 16385), RP_ERANGE);
  assert_int_equal(rp_runtime_set_effects(a.rt, 1u << 9), RP_EINVAL);
  assert_int_equal(rp_runtime_set_controller(a.rt, RP_CONTROL_COUNT),
                   RP_EINVAL);
  assert_int_equal(rp_runtime_set_controller(a.rt, (rp_controller_kind)-1),
                   RP_EINVAL);
  rp_runtime_get_counters(a.rt, &c);
  assert_int_equal(c.events, 0);

  tf = post_scene(a.rt, a.ctx, vol, "minmax-bone", &cam);
  (void)frame(&a);
  assert_int_equal(a.s.last.status, 0);
  assert_true(a.s.has_image);
  app_close(&a);
  rp_tf_destroy(tf);
  rp_context_destroy(a.ctx);
}

/* Frames until the AO being computed renders (at most 300): the frames
 * before it render without AO, their progress never falling, below 1.
 * Returns how many frames it took, the one with AO included. */
static int frames_until_ao(app *a) {
  double last = 0.0;
  int n;
  for (n = 1; n <= 300; n++) {
    (void)frame(a);
    assert_int_equal(a->s.last.status, 0);
    if (a->s.last.effects & RP_EFFECT_AO)
      return n;
    assert_true(a->s.last.ao_progress >= last &&
                a->s.last.ao_progress < 1.0);
    last = a->s.last.ao_progress;
  }
  fail_msg("AO not ready after 300 frames");
  return 0;
}

/* AO costs nothing while off: no computation, no AO memory. Turned on,
 * it is computed once (not per frame) and the frame is the reference's
 * with the reference AO; a TF change recomputes it; turned off, its
 * memory goes, and TF changes no longer recompute it. */
static void test_ao_only_when_on(void **state) {
  app a;
  rp_volume *vol, *copy;
  rp_tf *tf, *tf2 = NULL;
  rp_camera cam;
  rp_runtime_counters c;
  rp_ao *ao = NULL;
  (void)state;
  app_open(&a);
  vol = make_volume(a.ctx, 24, 2);
  copy = make_volume(a.ctx, 24, 2); /* the same voxels: the oracle's */
  cam = orbit(vol, 40.0f);
  tf = post_scene(a.rt, a.ctx, vol, "minmax-soft", &cam);
  (void)frame(&a);
  (void)frame(&a);
  rp_runtime_get_counters(a.rt, &c);
  assert_int_equal(c.ao_computes, 0);
  assert_int_equal(c.ao_bytes, 0);
  assert_true(a.s.last.ao_ms == 0.0);

  assert_int_equal(rp_runtime_set_effects(a.rt, EFFECTS | RP_EFFECT_AO), 0);
  (void)frames_until_ao(&a);
  rp_runtime_get_counters(a.rt, &c);
  assert_int_equal(c.ao_computes, 1);
  assert_int_equal(c.ao_bytes, 24 * 24 * 24);
  assert_int_equal(rp_ao_compute_reference(a.ctx, copy, tf, NULL, NULL, NULL,
                                           &ao),
                   0);
  expect_reference_ao(a.ctx, copy, tf, ao, &cam, a.s.last.jitter_seed,
                   a.s.image);
  rp_ao_destroy(ao);
  (void)frame(&a);
  rp_runtime_get_counters(a.rt, &c);
  assert_int_equal(c.ao_computes, 1);
  assert_true(a.s.last.ao_ms == 0.0);
  assert_true(a.s.last.effects & RP_EFFECT_AO);

  assert_int_equal(rp_tf_create_preset(a.ctx, "minmax-bone", &tf2), 0);
  assert_int_equal(rp_runtime_set_tf(a.rt, tf2), 0);
  (void)frames_until_ao(&a);
  rp_runtime_get_counters(a.rt, &c);
  assert_int_equal(c.ao_computes, 2);

  assert_int_equal(rp_runtime_set_effects(a.rt, EFFECTS), 0);
  (void)frame(&a);
  rp_runtime_get_counters(a.rt, &c);
  assert_int_equal(c.ao_bytes, 0);
  assert_int_equal(rp_runtime_set_tf(a.rt, tf), 0);
  (void)frame(&a);
  rp_runtime_get_counters(a.rt, &c);
  assert_int_equal(c.ao_computes, 2);
  assert_int_equal(c.ao_bytes, 0);
  assert_int_equal(a.s.last.status, 0);
  expect_reference(a.ctx, copy, tf, &cam, a.s.last.jitter_seed,
                   a.s.image);
  app_close(&a);
  rp_tf_destroy(tf);
  rp_tf_destroy(tf2);
  rp_volume_destroy(copy);
  rp_context_destroy(a.ctx);
}

/* With a small share of each frame for AO (2 ms of the 1000 ms target:
 * one 16^3 block per frame, the least a step does), AO takes several
 * frames; those render the reference's image without AO, each spends
 * time on AO, and the first frame with AO is the reference's with the
 * reference AO. A TF change in the middle of a run starts it again for
 * the new TF. */
static void test_ao_in_steps(void **state) {
  app a;
  rp_volume *vol, *copy;
  rp_tf *tf, *tf2 = NULL;
  rp_camera cam;
  rp_runtime_counters c;
  rp_ao *ao = NULL;
  int n;
  (void)state;
  app_open_ao(&a, NULL, 0, 0.002);
  vol = make_volume(a.ctx, 24, 2);
  copy = make_volume(a.ctx, 24, 2); /* the same voxels: the oracle's */
  cam = orbit(vol, 40.0f);
  tf = post_scene(a.rt, a.ctx, vol, "minmax-soft", &cam);
  assert_int_equal(rp_runtime_set_effects(a.rt, EFFECTS | RP_EFFECT_AO), 0);
  (void)frame(&a);
  assert_int_equal(a.s.last.status, 0);
  assert_false(a.s.last.effects & RP_EFFECT_AO);
  assert_true(a.s.last.ao_ms > 0.0);
  assert_true(a.s.last.ao_progress > 0.0 && a.s.last.ao_progress < 1.0);
  expect_reference(a.ctx, copy, tf, &cam, a.s.last.jitter_seed,
                   a.s.image);
  /* A TF change mid-run: the run restarts for the new TF. */
  assert_int_equal(rp_tf_create_preset(a.ctx, "minmax-bone", &tf2), 0);
  assert_int_equal(rp_runtime_set_tf(a.rt, tf2), 0);
  n = frames_until_ao(&a);
  print_message("AO in steps: ready after %d frames\n", n);
  assert_true(n >= 3);
  rp_runtime_get_counters(a.rt, &c);
  assert_int_equal(c.ao_computes, 1);
  assert_int_equal(rp_ao_compute_reference(a.ctx, copy, tf2, NULL, NULL,
                                           NULL, &ao),
                   0);
  expect_reference_ao(a.ctx, copy, tf2, ao, &cam, a.s.last.jitter_seed,
                   a.s.image);
  rp_ao_destroy(ao);
  app_close(&a);
  rp_tf_destroy(tf);
  rp_tf_destroy(tf2);
  rp_volume_destroy(copy);
  rp_context_destroy(a.ctx);
}

/* Three devices, one of them lost at its third render -- in the third
 * frame, or earlier when it took tail strips (rp_group_desc): every
 * frame is the reference image, the lost frame says which device went
 * and that its region was re-rendered, and afterwards the two left share
 * the frame while it waits to be re-created (rp_device_state: RETRY,
 * then back on probation, as the stats say). The device list is copied:
 * the caller's array may go. */
static void test_several_devices(void **state) {
  app a;
  rp_device_desc *dd = calloc(3, sizeof *dd);
  rp_fault_desc fd = {{RP_EXT_FAULTS, NULL}, 0.0, 3, 0, 0, 0.0};
  rp_volume *vol, *vol2;
  rp_tf *tf;
  rp_camera cam;
  uint32_t i, f;
  int lost_at = -1;
  (void)state;
  for (i = 0; i < 3; i++)
    dd[i].backend = "reference";
  rp_test_faults(&dd[1], &fd); /* lost at its third render */
  memset(&a, 0, sizeof a);
  app_open_devices(&a, dd, 3);
  free(dd);
  vol = make_volume(a.ctx, 32, 3);
  vol2 = make_volume(a.ctx, 32, 3);
  cam = orbit(vol2, 50.0f);
  tf = post_scene(a.rt, a.ctx, vol, "minmax-bone", &cam);
  for (f = 0; f < 5; f++) {
    double sum = 0.0, tail = 0.0;
    (void)frame(&a);
    assert_int_equal(a.s.last.status, 0);
    assert_true(a.s.has_image);
    expect_reference(a.ctx, vol2, tf, &cam, a.s.last.jitter_seed,
                   a.s.image);
    assert_int_equal(a.s.last.device_count, 3);
    {
      const rp_device_frame *df = &a.s.last.devices[1];
      int live = df->state == RP_DEVICE_ACTIVE ||
                 df->state == RP_DEVICE_PROBATION;
      if (a.s.last.devices_lost > 0) {
        if (lost_at < 0)
          lost_at = (int)f;
        assert_non_null(strstr(df->error, "injected"));
        assert_int_equal(df->status, RP_EDEVICE);
        assert_int_equal(df->state, RP_DEVICE_RETRY);
        assert_true(df->failures >= 1);
      }
      if (lost_at < 0)
        assert_int_equal(df->state, RP_DEVICE_ACTIVE);
      assert_true(a.s.last.devices_lost <= 1);
      assert_int_equal(a.s.last.devices_alive, live ? 3 : 2);
      assert_int_equal(df->dropped, !live);
    }
    assert_string_equal(a.s.last.devices[0].error, "");
    for (i = 0; i < 3; i++) {
      sum += a.s.last.devices[i].share;
      tail += a.s.last.devices[i].strip_share;
    }
    assert_true(sum == 1.0);
    {
      /* The default tail is cut when the scaled image has two tile rows
       * or more (every tile costs at least its rays, so the band's share
       * is positive), and taken whole in the round: a strip the lost
       * device failed on goes to the others. The band is the fewest
       * rows holding 0.15 of the cost, but never every row, so it may
       * hold less. */
      rp_render_desc d = {0};
      uint32_t sw, sh, ty;
      d.width = W;
      d.height = H;
      d.image_scale = a.s.last.scale;
      rp_scaled_size(&d, &sw, &sh);
      rp_tile_grid(sw, sh, NULL, &ty);
      if (ty >= 2)
        assert_true(tail > 0.0 && tail < 1.0);
      else
        assert_true(tail == 0.0);
    }
    if (a.s.last.devices[1].dropped && a.s.last.devices_lost == 0)
      assert_true(a.s.last.devices[1].share == 0.0);
    if (a.s.last.devices[1].state == RP_DEVICE_PROBATION)
      assert_true(a.s.last.devices[1].share <=
                  RP_GROUP_PROBATION_SHARE + 1e-12);
  }
  assert_true(lost_at >= 0 && lost_at <= 2);
  app_close(&a);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol2);
  rp_context_destroy(a.ctx);
}

/* Out of core (M8): a device with half the volume's memory. Every frame
 * uploads bricks and predicted it would before it started; the upload
 * is reported apart from the raycast. (That the predicted bytes are the
 * uploaded ones is test_bricks'.) */
static void test_out_of_core(void **state) {
  app a;
  rp_device_desc dd = {0};
  rp_volume *vol;
  rp_tf *tf;
  rp_camera cam, back;
  int f;
  (void)state;
  memset(&a, 0, sizeof a);
  if (!rp_test_has_device("opencl"))
    skip();
  dd.backend = "opencl";
  dd.budget_bytes = 64 * 64 * 64 / 2;
  dd.brick_size = 8;
  app_open_devices(&a, &dd, 1);
  vol = make_volume(a.ctx, 64, 3);
  cam = orbit(vol, 30.0f);
  back = orbit(vol, 210.0f);
  tf = post_scene(a.rt, a.ctx, vol, "minmax-bone", &cam);
  for (f = 0; f < 3; f++) {
    (void)frame(&a);
    if (a.s.last.status != 0)
      fail_msg("frame %d: %s", f, a.s.last.error);
    if (f == 0) {
      assert_true(a.s.last.upload_ms > 0.0);
      assert_true(a.s.last.upload_predicted_ms > 0.0);
      assert_true(a.s.last.devices[0].upload_ms > 0.0);
    } else {
      /* Half the volume holds less than the view needs: the frame is cut
       * into parts that evict each other's bricks, every frame, and the
       * prediction knows it. */
      assert_true(a.s.last.upload_ms > 0.0);
      assert_true(a.s.last.upload_predicted_ms > 0.0);
    }
    assert_true(isfinite(a.s.last.predicted_ms));
  }
  assert_int_equal(rp_runtime_set_camera(a.rt, &back), 0);
  (void)frame(&a);
  assert_int_equal(a.s.last.status, 0);
  assert_true(a.s.last.upload_predicted_ms > 0.0);
  assert_true(a.s.last.upload_ms > 0.0);
  app_close(&a);
  rp_tf_destroy(tf);
  rp_context_destroy(a.ctx);
}

/* Kernels built ahead: a frame never waits for a kernel build. On a
 * device that builds ahead (OpenCL), the frame after an effect set new
 * on this volume renders the last frame's set while the group's builder
 * builds the new one, and frames show it once it is built; a set
 * rendered before on the volume, and the first frame on a volume, render
 * at once. The images are held to the reference in
 * tests/conformance; here, what each frame rendered. */
static void test_effects_wait_for_kernels(void **state) {
  const uint32_t lit = EFFECTS | RP_EFFECT_SHADING;
  app a;
  rp_device_desc dd = {0};
  rp_volume *vol, *vol2;
  rp_tf *tf;
  rp_camera cam;
  uint64_t t0;
  int f;
  (void)state;
  memset(&a, 0, sizeof a);
  if (!rp_test_has_device("opencl"))
    skip();
  dd.backend = "opencl";
  app_open_devices(&a, &dd, 1);
  vol = make_volume(a.ctx, 24, 5);
  cam = orbit(vol, 40.0f);
  tf = post_scene(a.rt, a.ctx, vol, "minmax-bone", &cam);
  (void)frame(&a);
  assert_int_equal(a.s.last.status, 0);
  assert_int_equal(a.s.last.effects, EFFECTS); /* built by the frame */
  assert_int_equal(a.s.last.effects_wanted, EFFECTS);

  assert_int_equal(rp_runtime_set_effects(a.rt, lit), 0);
  (void)frame(&a);
  assert_int_equal(a.s.last.status, 0);
  assert_int_equal(a.s.last.effects_wanted, lit);
  assert_int_equal(a.s.last.effects, EFFECTS); /* its kernels building */
  /* Shown once built: a PoCL build takes a second or two cold here
   * (1576 frames of this size), a minute is plenty under sanitizers. */
  t0 = uv_hrtime();
  for (f = 0; a.s.last.effects != lit && uv_hrtime() - t0 < 60e9; f++) {
    (void)frame(&a);
    assert_int_equal(a.s.last.status, 0);
    assert_true(a.s.last.effects == EFFECTS || a.s.last.effects == lit);
  }
  assert_int_equal(a.s.last.effects, lit);
  print_message("shading shown %d frames after the first that wanted "
                "it\n", f + 1);

  /* AO: the run waits for its kernels (the AO volume's and the
   * raycast's), built ahead, then steps; frames render without AO until
   * it is done, and with it from then on, none building a kernel. */
  assert_int_equal(rp_runtime_set_effects(a.rt, lit | RP_EFFECT_AO), 0);
  (void)frame(&a);
  assert_int_equal(a.s.last.status, 0);
  assert_int_equal(a.s.last.effects, lit);
  assert_true(a.s.last.ao_progress == 0.0);
  t0 = uv_hrtime();
  for (f = 0; a.s.last.effects != (lit | RP_EFFECT_AO) &&
              uv_hrtime() - t0 < 60e9; f++) {
    (void)frame(&a);
    assert_int_equal(a.s.last.status, 0);
  }
  assert_int_equal(a.s.last.effects, lit | RP_EFFECT_AO);
  print_message("AO shown %d frames after the first that wanted it\n",
                f + 1);

  /* Back to a set this volume has rendered: at once. */
  assert_int_equal(rp_runtime_set_effects(a.rt, EFFECTS), 0);
  (void)frame(&a);
  assert_int_equal(a.s.last.effects, EFFECTS);

  /* A new volume: its first frame builds what it needs itself. */
  vol2 = make_volume(a.ctx, 16, 6);
  assert_int_equal(rp_runtime_set_volume(a.rt, vol2), 0);
  assert_int_equal(rp_runtime_set_effects(a.rt, lit), 0);
  (void)frame(&a);
  assert_int_equal(a.s.last.status, 0);
  assert_int_equal(a.s.last.effects, lit);
  assert_int_equal(a.s.failed, 0);
  app_close(&a);
  rp_tf_destroy(tf);
  rp_context_destroy(a.ctx);
}

static void *other_alloc(size_t size, void *user) {
  (void)user;
  return malloc(size);
}

static void other_free(void *ptr, void *user) {
  (void)user;
  free(ptr);
}

static void test_volume_other_allocator(void **state) {
  app a;
  rp_context *other;
  rp_context_desc cd = {0};
  rp_generate_desc g = {0};
  rp_volume *vol = NULL;
  (void)state;
  app_open(&a);
  cd.allocator.alloc = other_alloc;
  cd.allocator.free = other_free;
  assert_int_equal(rp_context_create(&cd, &other), 0);
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = 8;
  assert_int_equal(rp_volume_generate(other, &g, &vol), 0);
  assert_int_equal(rp_runtime_set_volume(a.rt, vol), RP_EINVAL);
  rp_volume_destroy(vol); /* still ours */
  rp_context_destroy(other);
  app_close(&a);
  rp_context_destroy(a.ctx);
}

/* Close while the worker renders: the frame is not delivered, nothing
 * leaks (ASan), the loop is left empty (app_close checks). The device is
 * slowed 100x so that the frame is still rendering when close comes: at
 * full speed it could finish, and its completion be delivered, inside
 * the first uv_run below, which also serves the worker's wake-up. And
 * close from inside the frame callback. */
static void test_close_in_flight(void **state) {
  app a;
  rp_volume *vol;
  rp_tf *tf = NULL;
  rp_camera cam;
  rp_device_desc slow = {0};
  rp_fault_desc fd = {{RP_EXT_FAULTS, NULL}, 100.0, 0, 0, 0, 0.0};
  (void)state;
  slow.backend = "reference";
  rp_test_faults(&slow, &fd);
  app_open_devices(&a, &slow, 1);
  vol = make_volume(a.ctx, 64, 4);
  cam = orbit(vol, 30.0f);
  tf = post_scene(a.rt, a.ctx, vol, "minmax-soft", &cam);
  assert_int_equal(rp_runtime_request_frame(a.rt), 0);
  uv_run(&a.loop, UV_RUN_NOWAIT); /* the frame starts on the worker */
  for (;;) { /* wait until the worker is inside the frame */
    rp_runtime_counters c;
    rp_runtime_get_counters(a.rt, &c);
    if (c.histograms == 1)
      break;
    uv_sleep(1);
  }
  app_close(&a); /* delivered or not, the frame is never shown */
  assert_int_equal(a.s.frames, 0);
  rp_tf_destroy(tf);
  rp_context_destroy(a.ctx);

  app_open(&a);
  vol = make_volume(a.ctx, 16, 4);
  cam = orbit(vol, 30.0f);
  tf = post_scene(a.rt, a.ctx, vol, "minmax-soft", &cam);
  a.s.close_in_callback = 1;
  assert_int_equal(rp_runtime_request_frame(a.rt), 0);
  while (!a.s.closed && uv_run(&a.loop, UV_RUN_ONCE) != 0)
    ;
  assert_true(a.s.closed);
  assert_int_equal(a.s.frames, 1);
  assert_int_equal(uv_loop_close(&a.loop), 0);
  uv_mutex_destroy(&a.s.lock);
  rp_tf_destroy(tf);
  rp_context_destroy(a.ctx);
}

/* ---- Own loop, timer pacing -------------------------------------------- */

static double now_ms(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

static int frames_of(seen *s, rp_frame_stats *last) {
  int n;
  uv_mutex_lock(&s->lock);
  n = s->frames;
  if (last != NULL)
    *last = s->last;
  uv_mutex_unlock(&s->lock);
  return n;
}

static rp_runtime *own_runtime(rp_context *ctx, seen *s, double target) {
  rp_runtime_desc d = {0};
  rp_runtime *rt = NULL;
  d.device.backend = "reference";
  d.pacing = RP_PACE_TIMER;
  d.on_frame = on_frame;
  d.user = s;
  d.width = W;
  d.height = H;
  d.effects = EFFECTS;
  d.target_ms = target;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  return rt;
}

/* The timer never starts frames faster than the target period: after T
 * ms at most T / period + 1 frames (the first starts at once). */
static void test_timer_pacing(void **state) {
  rp_context *ctx = rp_test_context();
  seen s;
  rp_runtime *rt;
  rp_volume *vol;
  rp_tf *tf = NULL;
  rp_camera cam;
  double t0, elapsed, period = 25.0;
  int n;
  (void)state;
  memset(&s, 0, sizeof s);
  assert_int_equal(uv_mutex_init(&s.lock), 0);
  rt = own_runtime(ctx, &s, period);
  assert_int_equal(rp_runtime_close(rt, NULL, NULL), RP_ESTATE);
  assert_int_equal(rp_runtime_request_frame(rt), RP_ESTATE);
  vol = make_volume(ctx, 16, 5);
  cam = orbit(vol, 0.0f);
  t0 = now_ms();
  tf = post_scene(rt, ctx, vol, "minmax-bone", &cam);
  while (frames_of(&s, NULL) < 6 && now_ms() - t0 < 20000.0)
    uv_sleep(5);
  n = frames_of(&s, NULL);
  elapsed = now_ms() - t0;
  assert_int_equal(rp_runtime_destroy(rt), 0);
  assert_true(n >= 6);
  assert_true(n <= (int)(elapsed / period) + 2);
  assert_int_equal(s.failed, 0);
  assert_int_equal(s.last.target_ms, period);
  uv_mutex_destroy(&s.lock);
  rp_tf_destroy(tf);
  rp_context_destroy(ctx);
}

/* Destroy with a frame in flight on the runtime's own loop. */
static void test_destroy_in_flight(void **state) {
  rp_context *ctx = rp_test_context();
  seen s;
  rp_runtime *rt;
  rp_volume *vol;
  rp_tf *tf = NULL;
  rp_camera cam;
  (void)state;
  memset(&s, 0, sizeof s);
  assert_int_equal(uv_mutex_init(&s.lock), 0);
  rt = own_runtime(ctx, &s, 10.0);
  vol = make_volume(ctx, 48, 6);
  cam = orbit(vol, 0.0f);
  tf = post_scene(rt, ctx, vol, "minmax-soft", &cam);
  uv_sleep(2);
  assert_int_equal(rp_runtime_destroy(rt), 0);
  assert_int_equal(rp_runtime_destroy(NULL), 0);
  uv_mutex_destroy(&s.lock);
  rp_tf_destroy(tf);
  rp_context_destroy(ctx);
}

/* A second thread posts a camera every millisecond while the runtime
 * renders on its own loop. The first frame that includes the last event
 * (stats.events) shows exactly the last camera. */
typedef struct poster {
  rp_runtime *rt;
  const rp_volume *vol;
  int count;
  rp_camera last;
} poster;

static void post_cameras(void *arg) {
  poster *p = arg;
  int i;
  for (i = 0; i < p->count; i++) {
    p->last = orbit(p->vol, (float)i * 1.7f);
    assert_int_equal(rp_runtime_set_camera(p->rt, &p->last), 0);
    uv_sleep(1);
  }
}

static void test_camera_thread_1khz(void **state) {
  rp_context *ctx = rp_test_context();
  seen s;
  rp_runtime *rt;
  rp_volume *vol, *vol2;
  rp_tf *tf = NULL;
  rp_frame_stats last;
  uv_thread_t thread;
  poster p;
  double t0;
  uint64_t total;
  (void)state;
  memset(&s, 0, sizeof s);
  assert_int_equal(uv_mutex_init(&s.lock), 0);
  rt = own_runtime(ctx, &s, 5.0);
  vol = make_volume(ctx, 32, 7);
  vol2 = make_volume(ctx, 32, 7);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tf), 0);
  assert_int_equal(rp_runtime_set_volume(rt, vol), 0);
  assert_int_equal(rp_runtime_set_tf(rt, tf), 0);
  p.rt = rt;
  p.vol = vol2;
  p.count = 300;
  assert_int_equal(uv_thread_create(&thread, post_cameras, &p), 0);
  assert_int_equal(uv_thread_join(&thread), 0);
  total = 2 + (uint64_t)p.count; /* volume, TF, cameras */
  t0 = now_ms();
  for (;;) {
    frames_of(&s, &last);
    if (last.events == total || now_ms() - t0 > 30000.0)
      break;
    uv_sleep(2);
  }
  assert_int_equal(rp_runtime_destroy(rt), 0);
  assert_int_equal(last.events, total);
  assert_int_equal(last.status, 0);
  /* Frames rendered while the thread posted: fewer than the events,
   * every one coalesced. */
  assert_true(s.frames >= 1 && (uint64_t)s.frames < total);
  expect_reference(ctx, vol2, tf, &p.last, last.jitter_seed, s.image);
  uv_mutex_destroy(&s.lock);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol2);
  rp_context_destroy(ctx);
}

static void test_names(void **state) {
  rp_pacing p;
  (void)state;
  assert_string_equal(rp_pacing_name(RP_PACE_TIMER), "timer");
  assert_string_equal(rp_pacing_name(RP_PACE_ON_REQUEST), "on-request");
  assert_int_equal(rp_pacing_from_name("on-request", &p), 0);
  assert_int_equal(p, RP_PACE_ON_REQUEST);
  assert_int_equal(rp_pacing_from_name("vsync", &p), RP_EINVAL);
}

static void test_create_refuses(void **state) {
  rp_context *ctx = rp_test_context();
  rp_runtime_desc d = {0};
  rp_runtime *rt = NULL;
  (void)state;
  d.device.backend = "reference";
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_EINVAL); /* cb */
  assert_non_null(strstr(rp_last_error(ctx), "on_frame"));
  d.on_frame = on_frame;
  d.target_ms = NAN;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_ENOTFINITE);
  d.target_ms = -1.0;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_ERANGE);
  d.target_ms = 0.0;
  d.ao_frame_share = NAN;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_ENOTFINITE);
  d.ao_frame_share = 1.5;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "ao_frame_share"));
  d.ao_frame_share = 0.0;
  d.ao.radius = -1.0f;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_ERANGE);
  d.ao.radius = 0.0f;
  d.ao_schedule.block = 6;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_EINVAL);
  d.ao_schedule.block = 0;
  d.device.backend = "no-such-backend";
  assert_true(rp_runtime_create(ctx, &d, &rt) < 0);
  assert_null(rt);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_names),
      cmocka_unit_test(test_create_refuses),
      cmocka_unit_test(test_passes_per_event),
      cmocka_unit_test(test_requests),
      cmocka_unit_test(test_bad_input),
      cmocka_unit_test(test_ao_only_when_on),
      cmocka_unit_test(test_ao_in_steps),
      cmocka_unit_test(test_several_devices),
      cmocka_unit_test(test_out_of_core),
      cmocka_unit_test(test_effects_wait_for_kernels),
      cmocka_unit_test(test_volume_other_allocator),
      cmocka_unit_test(test_close_in_flight),
      cmocka_unit_test(test_timer_pacing),
      cmocka_unit_test(test_destroy_in_flight),
      cmocka_unit_test(test_camera_thread_1khz),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
