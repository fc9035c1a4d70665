/* The runtime in manual pacing (RP_PACE_MANUAL, rp_runtime_step): the
 * same engine frame as on a loop, run on the caller's thread. Frames
 * render on the reference device, checked against rp_render_reference
 * (an oracle outside the runtime); the loop-driven runtime on the same
 * events is the second witness: it must deliver the same images and run
 * the same passes. Also the controller's density (rp_runtime_set_density)
 * and a TF switched away and back while AO is being computed.
 *
 * Pacing is tested on the deterministic test device (raypace_testing.h):
 * its times are a formula of each frame's real work plus seeded noise,
 * on a clock of its own that the runtime reads, so what a controller
 * decides is the same on every run and machine, and a bound on it holds
 * or fails for a reason in the code. */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <uv.h>

#include "raypace_ao.h"
#include "raypace_pace.h"
#include "raypace_runtime.h"
#include "frame.h"
#include "raypace_group.h"
#include "raypace_testing.h"
#include "test_util.h"

#define W 40
#define H 32
#define EFFECTS (RP_EFFECT_ERT | RP_EFFECT_SKIP)
#define FRAMES 6

typedef struct seen {
  int frames;
  rp_frame_stats last;
  uint8_t image[FRAMES + 1][W * H * 4];
  uint8_t latest[W * H * 4];
  int has_image;
  int step_in_callback; /* tries rp_runtime_step from the callback */
  int step_err;
  uint32_t probe_rays; /* the last frame's probe's, 0 without one */
} seen;

static void on_frame(rp_runtime *rt, const rp_frame *f, void *user) {
  seen *s = user;
  s->last = *f->stats;
  s->has_image = f->rgba != NULL;
  s->probe_rays = f->probe != NULL ? f->probe->rays : 0;
  if (f->rgba != NULL && s->frames <= FRAMES)
    memcpy(s->image[s->frames], f->rgba, W * H * 4);
  if (f->rgba != NULL)
    memcpy(s->latest, f->rgba, W * H * 4);
  s->frames++;
  if (s->step_in_callback)
    s->step_err = rp_runtime_step(rt);
}

/* The phantom every test here renders, n^3. */
static rp_volume *make_volume(rp_context *ctx, uint32_t n) {
  return rp_test_generate(ctx, RP_GEN_PHANTOM, n, n, n, RP_U8, 0);
}

static rp_camera orbit(const rp_volume *vol, float az) {
  rp_camera cam = {0};
  rp_camera_orbit(&cam, vol, az, 20.0f, 2.2f);
  return cam;
}

static void base_desc(rp_runtime_desc *d, seen *s, rp_pacing pacing) {
  memset(d, 0, sizeof *d);
  d->device.backend = "reference";
  d->pacing = pacing;
  d->on_frame = on_frame;
  d->user = s;
  d->width = W;
  d->height = H;
  d->effects = EFFECTS;
  d->target_ms = 1000.0;
}

static void expect_reference_ao(rp_context *ctx, const rp_volume *vol,
                                const rp_tf *tf, const rp_ao *ao,
                                const rp_camera *cam, uint32_t seed,
                                const uint8_t *got) {
  rp_test_expect_reference(ctx, vol, tf, ao, cam, W, H, EFFECTS, seed, got);
}

/* The events of frame i of a short script: a volume and TF at 0, the
 * camera every frame, a TF switch at 3. */
static void post_events(rp_runtime *rt, rp_context *ctx, int i,
                        rp_tf *const *tfs) {
  rp_volume *vol = make_volume(ctx, 24);
  rp_camera cam = orbit(vol, 20.0f + 7.0f * (float)i);
  if (i == 0) {
    assert_int_equal(rp_runtime_set_volume(rt, vol), 0);
    vol = NULL;
  }
  if (i == 0 || i == 3)
    assert_int_equal(rp_runtime_set_tf(rt, tfs[i == 3]), 0);
  assert_int_equal(rp_runtime_set_camera(rt, &cam), 0);
  rp_volume_destroy(vol);
}

/* Manual pacing runs a frame inside rp_runtime_step and nowhere else:
 * refusals first, then FRAMES frames, each the reference's image, with
 * the passes its events ask for. */
static void test_step(void **state) {
  rp_context *ctx = rp_test_context();
  rp_runtime_desc d;
  rp_runtime *rt = NULL;
  rp_tf *tfs[2] = {NULL, NULL};
  rp_volume *oracle = make_volume(ctx, 24);
  uv_loop_t loop;
  seen *s = calloc(1, sizeof *s);
  int i;
  (void)state;
  assert_non_null(s);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tfs[0]), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tfs[1]), 0);
  /* Manual pacing has no loop to be given. */
  assert_int_equal(uv_loop_init(&loop), 0);
  base_desc(&d, s, RP_PACE_MANUAL);
  d.loop = &loop;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "desc->loop"));
  assert_int_equal(uv_loop_close(&loop), 0);
  base_desc(&d, s, RP_PACE_MANUAL);
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  /* Nothing to render yet; the other pacings' calls are refused. */
  assert_int_equal(rp_runtime_step(rt), RP_ESTATE);
  assert_int_equal(rp_runtime_request_frame(rt), RP_ESTATE);
  assert_int_equal(rp_runtime_close(rt, NULL, NULL), RP_ESTATE);
  assert_int_equal(s->frames, 0);
  for (i = 0; i < FRAMES; i++) {
    rp_camera cam = orbit(oracle, 20.0f + 7.0f * (float)i);
    post_events(rt, ctx, i, tfs);
    assert_int_equal(s->frames, i); /* posting runs nothing */
    assert_int_equal(rp_runtime_step(rt), 0);
    assert_int_equal(s->frames, i + 1); /* delivered before returning */
    assert_int_equal(s->last.frame, (uint64_t)i);
    assert_int_equal(s->last.status, 0);
    assert_int_equal(s->last.counters.frames, (uint64_t)i + 1);
    assert_int_equal(s->last.counters.histograms, 1);
    assert_int_equal(s->last.counters.occupancies, i < 3 ? 1 : 2);
    assert_int_equal(s->last.counters.probes, (uint64_t)i + 1);
    assert_true(s->last.dispatch_ms == 0.0);
    expect_reference_ao(ctx, oracle, tfs[i >= 3], NULL, &cam,
                        s->last.jitter_seed, s->image[i]);
  }
  /* No step inside a step. */
  s->step_in_callback = 1;
  s->step_err = 0;
  assert_int_equal(rp_runtime_step(rt), 0);
  assert_int_equal(s->step_err, RP_ESTATE);
  assert_int_equal(s->frames, FRAMES + 1);
  assert_int_equal(rp_runtime_destroy(rt), 0);
  rp_tf_destroy(tfs[0]);
  rp_tf_destroy(tfs[1]);
  rp_volume_destroy(oracle);
  rp_context_destroy(ctx);
  free(s);
}

/* The same events through an app loop (on-request pacing) and through
 * rp_runtime_step: the same images, bit for bit, and the same passes. */
static void test_step_as_loop(void **state) {
  rp_context *ctx = rp_test_context();
  rp_runtime_desc d;
  rp_runtime *manual = NULL, *looped = NULL;
  rp_tf *tfs[2] = {NULL, NULL};
  uv_loop_t loop;
  seen *a = calloc(1, sizeof *a), *b = calloc(1, sizeof *b);
  int i;
  (void)state;
  assert_non_null(a);
  assert_non_null(b);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tfs[0]), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tfs[1]), 0);
  assert_int_equal(uv_loop_init(&loop), 0);
  base_desc(&d, a, RP_PACE_MANUAL);
  d.controller = RP_CONTROL_LAST_FRAME;
  assert_int_equal(rp_runtime_create(ctx, &d, &manual), 0);
  base_desc(&d, b, RP_PACE_ON_REQUEST);
  d.controller = RP_CONTROL_LAST_FRAME;
  d.loop = &loop;
  assert_int_equal(rp_runtime_create(ctx, &d, &looped), 0);
  for (i = 0; i < FRAMES; i++) {
    post_events(manual, ctx, i, tfs);
    post_events(looped, ctx, i, tfs);
    assert_int_equal(rp_runtime_step(manual), 0);
    assert_int_equal(rp_runtime_request_frame(looped), 0);
    while (b->frames == i)
      uv_run(&loop, UV_RUN_ONCE);
    assert_int_equal(b->last.status, 0);
    /* The target is far above a 40x32 frame: last-frame holds the top
     * density on both, so the images compare. */
    assert_true(a->last.rho == b->last.rho);
    assert_memory_equal(a->image[i], b->image[i], W * H * 4);
    assert_int_equal(a->last.counters.probes, b->last.counters.probes);
    assert_int_equal(a->last.counters.occupancies,
                     b->last.counters.occupancies);
    assert_int_equal(a->last.counters.renders, b->last.counters.renders);
  }
  assert_int_equal(rp_runtime_destroy(manual), 0);
  assert_int_equal(rp_runtime_close(looped, NULL, NULL), 0);
  while (uv_run(&loop, UV_RUN_ONCE) != 0)
    ;
  assert_int_equal(uv_loop_close(&loop), 0);
  rp_tf_destroy(tfs[0]);
  rp_tf_destroy(tfs[1]);
  rp_context_destroy(ctx);
  free(a);
  free(b);
}

/* The controller none renders the density it is given, from the desc and
 * then from rp_runtime_set_density; densities outside the space's range
 * are refused naming the value. */
static void test_density(void **state) {
  rp_context *ctx = rp_test_context();
  rp_runtime_desc d;
  rp_runtime *rt = NULL;
  rp_tf *tfs[2] = {NULL, NULL};
  seen *s = calloc(1, sizeof *s);
  float step, scale;
  (void)state;
  assert_non_null(s);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tfs[0]), 0);
  base_desc(&d, s, RP_PACE_MANUAL);
  d.space.space = RP_SPACE_HYBRID;
  d.density = 2.0; /* over the hybrid space's top density, 1 */
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_ERANGE);
  assert_non_null(strstr(rp_last_error(ctx), "desc->density is 2"));
  d.density = NAN;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), RP_ENOTFINITE);
  d.density = 0.25;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  post_events(rt, ctx, 0, tfs);
  assert_int_equal(rp_runtime_step(rt), 0);
  assert_true(s->last.rho == 0.25);
  rp_space_map(&d.space, 0.25, &step, &scale);
  assert_true(s->last.step == step && s->last.scale == scale);
  assert_int_equal(rp_runtime_set_density(rt, 0.5), 0);
  assert_int_equal(rp_runtime_step(rt), 0);
  assert_true(s->last.rho == 0.5);
  assert_int_equal(rp_runtime_set_density(rt, 0.0), RP_ERANGE);
  assert_int_equal(rp_runtime_set_density(rt, INFINITY), RP_ENOTFINITE);
  assert_int_equal(rp_runtime_set_density(rt, 1.5), RP_ERANGE);
  assert_int_equal(rp_runtime_step(rt), 0);
  assert_true(s->last.rho == 0.5); /* refused: nothing changed */
  assert_int_equal(rp_runtime_destroy(rt), 0);
  rp_tf_destroy(tfs[0]);
  rp_context_destroy(ctx);
  free(s);
}

/* AO held for a TF, a switch to another whose AO takes several frames,
 * and back (a copy of the first, as an app posts it) before that is
 * done: the devices still hold the first TF's AO, so the frame renders
 * with it at once, the reference's image with the reference's AO, and no
 * AO is computed again. */
static void test_ao_switch_back(void **state) {
  rp_context *ctx = rp_test_context();
  rp_runtime_desc d;
  rp_runtime *rt = NULL;
  rp_tf *tfs[2] = {NULL, NULL}, *copy = NULL;
  rp_volume *oracle = make_volume(ctx, 24);
  rp_camera cam = orbit(oracle, 20.0f);
  rp_runtime_counters c;
  rp_ao *ao = NULL;
  seen *s = calloc(1, sizeof *s);
  int n;
  (void)state;
  assert_non_null(s);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tfs[0]), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tfs[1]), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &copy), 0);
  base_desc(&d, s, RP_PACE_MANUAL);
  d.effects = EFFECTS | RP_EFFECT_AO;
  d.ao_frame_share = 0.002; /* 2 ms of the target: a block a frame */
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  post_events(rt, ctx, 0, tfs);
  for (n = 0; n < 300 && !(s->last.effects & RP_EFFECT_AO); n++)
    assert_int_equal(rp_runtime_step(rt), 0);
  assert_true(s->last.effects & RP_EFFECT_AO);
  assert_int_equal(rp_runtime_set_tf(rt, tfs[1]), 0);
  assert_int_equal(rp_runtime_step(rt), 0);
  assert_false(s->last.effects & RP_EFFECT_AO); /* the run has begun */
  assert_true(s->last.ao_progress > 0.0 && s->last.ao_progress < 1.0);
  assert_int_equal(rp_runtime_set_tf(rt, copy), 0);
  assert_int_equal(rp_runtime_step(rt), 0);
  assert_true(s->last.effects & RP_EFFECT_AO);
  assert_true(s->last.ao_progress == 0.0); /* no run */
  rp_runtime_get_counters(rt, &c);
  assert_int_equal(c.ao_computes, 1);
  assert_int_equal(rp_ao_compute_reference(ctx, oracle, tfs[0], NULL, NULL,
                                           NULL, &ao),
                   0);
  expect_reference_ao(ctx, oracle, tfs[0], ao, &cam, s->last.jitter_seed,
                      s->latest);
  rp_ao_destroy(ao);
  assert_int_equal(rp_runtime_destroy(rt), 0);
  rp_tf_destroy(tfs[0]);
  rp_tf_destroy(tfs[1]);
  rp_tf_destroy(copy);
  rp_volume_destroy(oracle);
  rp_context_destroy(ctx);
  free(s);
}


/* ---- Pacing on the test device ------------------------------------------ */

/* A runtime on the test device, noise `noise_sd` (negative: none). */
static rp_runtime *open_test_device(rp_context *ctx, seen *s,
                                    rp_controller_kind kind, double noise_sd,
                                    float min_step, double target_ms,
                                    double miss_rate) {
  rp_runtime_desc d;
  rp_test_backend_desc t;
  rp_runtime *rt = NULL;
  memset(&t, 0, sizeof t);
  t.header.type = RP_EXT_TEST_BACKEND;
  t.seed = 7;
  t.noise_sd = noise_sd;
  base_desc(&d, s, RP_PACE_MANUAL);
  d.device.backend = "test";
  d.device.next = &t;
  d.controller = kind;
  d.target_ms = target_ms;
  d.space.space = RP_SPACE_HYBRID;
  d.space.min_step = min_step;
  d.miss_rate = miss_rate;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  return rt;
}

/* A min_step under the base step lets the predicted controller go past
 * density 1 when the budget allows: a 1000 ms target on a 40x32 frame,
 * which the test device prices at well under a millisecond, ends at the
 * finest step, 0.25 (density 4); without one, at the base step. */
static void test_min_step(void **state) {
  static const float min_steps[2] = {0.0f, 0.25f};
  rp_context *ctx = rp_test_context();
  rp_tf *tfs[2] = {NULL, NULL};
  seen *s = calloc(1, sizeof *s);
  int k, f;
  (void)state;
  assert_non_null(s);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tfs[0]), 0);
  for (k = 0; k < 2; k++) {
    rp_runtime *rt = open_test_device(ctx, s, RP_CONTROL_PREDICTED, -1.0,
                                      min_steps[k], 1000.0, 0.0);
    post_events(rt, ctx, 0, tfs);
    for (f = 0; f < 12; f++)
      assert_int_equal(rp_runtime_step(rt), 0);
    assert_true(s->last.measured_ms < 5.0);
    assert_true(s->last.rho == (k ? 4.0 : 1.0));
    assert_true(s->last.step == (k ? 0.25f : 1.0f));
    assert_true(s->last.scale == 1.0f);
    assert_int_equal(rp_runtime_destroy(rt), 0);
  }
  rp_tf_destroy(tfs[0]);
  rp_context_destroy(ctx);
  free(s);
}

/* A lone test device failing at its 4th render since each creation: the
 * frames fail while it is away (their stats say which device, and that
 * it waits to be re-created), then it is re-created and the frames are
 * the reference's again. The engine's time is the device's own clock,
 * which goes on across the re-creation (a new device's starts at 0): no
 * frame measures a negative time, nor one beyond the target. */
static void test_lone_device_recreated(void **state) {
  rp_context *ctx = rp_test_context();
  rp_tf *tfs[2] = {NULL, NULL};
  seen *s = calloc(1, sizeof *s);
  rp_runtime_desc d;
  rp_test_backend_desc t;
  rp_fault_desc fd;
  rp_runtime *rt = NULL;
  rp_volume *vol;
  rp_camera cam;
  int f, failed = 0, back = 0;
  (void)state;
  assert_non_null(s);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tfs[0]), 0);
  memset(&t, 0, sizeof t);
  t.header.type = RP_EXT_TEST_BACKEND;
  t.seed = 7;
  t.noise_sd = -1.0;
  memset(&fd, 0, sizeof fd);
  fd.fail_at_render = 4;
  base_desc(&d, s, RP_PACE_MANUAL);
  d.device.backend = "test";
  d.device.next = &t;
  rp_test_faults(&d.device, &fd);
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  post_events(rt, ctx, 0, tfs);
  vol = make_volume(ctx, 24);
  cam = orbit(vol, 20.0f);
  for (f = 0; f < 16; f++) {
    const rp_device_frame *df = &s->last.devices[0];
    (void)rp_runtime_step(rt);
    assert_true(s->last.measured_ms >= 0.0 &&
                s->last.measured_ms <= d.target_ms);
    if (s->last.status != 0) {
      failed++;
      assert_true(df->state == RP_DEVICE_RETRY);
      assert_false(s->has_image);
      continue;
    }
    if (failed > 0) {
      back++;
      assert_true(df->state == RP_DEVICE_PROBATION ||
                  df->state == RP_DEVICE_ACTIVE);
      rp_test_expect_reference(ctx, vol, tfs[0], NULL, &cam, W, H, EFFECTS,
                               s->last.jitter_seed, s->latest);
    }
  }
  print_message("%d frames failed while the device was away, %d right "
                "after it came back\n", failed, back);
  assert_true(failed > 0 && back > 0);
  assert_int_equal(rp_runtime_destroy(rt), 0);
  rp_volume_destroy(vol);
  rp_tf_destroy(tfs[0]);
  rp_context_destroy(ctx);
  free(s);
}

/* Plays an n-frame orbit (3 degrees a frame, the TF switched at frame
 * 30 and then every 150) under `kind` at `target` and returns the
 * frames' measured times over the target in ratio[], their densities in
 * rho[]. */
static void orbit_on_test_device(rp_context *ctx, rp_controller_kind kind,
                                 double noise_sd, double target,
                                 double miss_rate, int n, double *ratio,
                                 double *rho) {
  rp_tf *tfs[2] = {NULL, NULL};
  rp_volume *vol = make_volume(ctx, 24);
  seen *s = calloc(1, sizeof *s);
  rp_runtime *rt;
  int i;
  assert_non_null(s);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tfs[0]), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-bone", &tfs[1]), 0);
  rt = open_test_device(ctx, s, kind, noise_sd, 0.0f, target, miss_rate);
  assert_int_equal(rp_runtime_set_volume(rt, make_volume(ctx, 24)), 0);
  for (i = 0; i < n; i++) {
    rp_camera cam = orbit(vol, 3.0f * (float)i);
    if (i == 0 || (i >= 30 && (i - 30) % 150 == 0))
      assert_int_equal(rp_runtime_set_tf(rt, tfs[i >= 30 &&
                                                  (i - 30) / 150 % 2 == 0]),
                       0);
    assert_int_equal(rp_runtime_set_camera(rt, &cam), 0);
    assert_int_equal(rp_runtime_step(rt), 0);
    ratio[i] = s->last.measured_ms / target;
    rho[i] = s->last.rho;
  }
  assert_int_equal(rp_runtime_destroy(rt), 0);
  rp_tf_destroy(tfs[0]);
  rp_tf_destroy(tfs[1]);
  rp_volume_destroy(vol);
  free(s);
}

/* The runtime's frame is a function of its events and the device's
 * seed: two runs give the same times, to the bit. */
static void test_pacing_deterministic(void **state) {
  rp_context *ctx = rp_test_context();
  double r1[60], r2[60], d1[60], d2[60];
  int i;
  (void)state;
  orbit_on_test_device(ctx, RP_CONTROL_PREDICTED, 0.02, 0.3, 0.0, 60, r1,
                       d1);
  orbit_on_test_device(ctx, RP_CONTROL_PREDICTED, 0.02, 0.3, 0.0, 60, r2,
                       d2);
  for (i = 0; i < 60; i++) {
    assert_true(r1[i] == r2[i]);
    assert_true(d1[i] == d2[i]);
  }
  rp_context_destroy(ctx);
}

/* The frame at density 1 of the orbit's scene on the test device, ms:
 * the controller none's first frames. */
static double full_frame_ms(rp_context *ctx) {
  double ratio[60], rho[60];
  orbit_on_test_device(ctx, RP_CONTROL_NONE, -1.0, 1.0, 0.0, 60, ratio,
                       rho);
  assert_true(rho[59] == 1.0);
  return ratio[59];
}

/* Half the density-1 frame as the target, on a noise-free device: the
 * predicted controller's first frames are late (a cold model prices
 * them at about half their time), its deadline contract then aims it
 * under the target while its residuals say the model was wrong, and
 * from frame 5 no frame is over 1.05x the target, through the TF switch
 * at 30; once that surprise has faded from its residuals (25 frames
 * later) every frame is within 10 % under it. Measured: 1.74 and 1.42 at
 * frames 0 and 1, at most 0.994 after; 0.81 to 0.83 at 44 to 50, while
 * the switch's residuals still widen the margin; 0.93 to 0.95 at 54 to
 * 59. */
static void test_pacing_holds_target(void **state) {
  rp_context *ctx = rp_test_context();
  double target = 0.5 * full_frame_ms(ctx), ratio[60], rho[60];
  int i;
  (void)state;
  orbit_on_test_device(ctx, RP_CONTROL_PREDICTED, -1.0, target, 0.0, 60,
                       ratio, rho);
  for (i = 5; i < 60; i++)
    assert_true(ratio[i] <= 1.05);
  for (i = 55; i < 60; i++)
    assert_true(ratio[i] > 0.9 && rho[i] < 1.0);
  rp_context_destroy(ctx);
}

/* The contract through the runtime: 600 frames of an orbit with a TF
 * switch every 150, the device's times with 5 % log-normal noise, half
 * the density-1 frame as the target. Asked 5 and 20 %, the share of late
 * frames after the 50th is within four binomial deviations of it; with
 * no margin (the rule before the contract) it is near half. */
static void test_pacing_miss_rates(void **state) {
  static const double asked[2] = {0.05, 0.2};
  rp_context *ctx = rp_test_context();
  double target = 0.5 * full_frame_ms(ctx), *ratio, *rho;
  int k, i, n = 600, scored = 550;
  (void)state;
  ratio = malloc((size_t)n * sizeof *ratio);
  rho = malloc((size_t)n * sizeof *rho);
  assert_non_null(ratio);
  assert_non_null(rho);
  for (k = 0; k < 3; k++) {
    double q = k < 2 ? asked[k] : -1.0, late = 0.0;
    orbit_on_test_device(ctx, RP_CONTROL_PREDICTED, 0.05, target, q, n,
                         ratio, rho);
    for (i = n - scored; i < n; i++)
      late += ratio[i] > 1.0;
    late /= scored;
    print_message("miss_rate %g: late %.4f\n", q, late);
    if (k < 2)
      assert_true(fabs(late - q) <= 4.0 * sqrt(q * (1 - q) / scored));
    else
      assert_true(late > 0.35);
  }
  free(ratio);
  free(rho);
  rp_context_destroy(ctx);
}

/* The probe's rays on the reference backend (the wall clock) at a
 * target, after five frames of an orbit: the first probe is untimed
 * and traces them all; the later ones what 2 % of the target pays for at
 * the probe's own cost per ray (docs/pacing.md, "Prediction's own
 * cost"). Returns the last probe's rays and the first's in *first. */
static uint32_t probe_rays_at(rp_context *ctx, double target,
                              uint32_t *first) {
  rp_runtime_desc d;
  rp_runtime *rt = NULL;
  rp_volume *vol = make_volume(ctx, 24);
  seen *s = calloc(1, sizeof *s);
  rp_tf *tf = NULL;
  int i;
  assert_non_null(s);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tf), 0);
  base_desc(&d, s, RP_PACE_MANUAL);
  d.controller = RP_CONTROL_NONE;
  d.target_ms = target;
  /* Large enough for the whole pre-pass grid (a 40x32 frame has 80 of
   * its rays); on_frame copies only its first W x H pixels. */
  d.width = d.height = 256;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  assert_int_equal(rp_runtime_set_volume(rt, make_volume(ctx, 24)), 0);
  assert_int_equal(rp_runtime_set_tf(rt, tf), 0);
  for (i = 0; i < 5; i++) {
    rp_camera cam = orbit(vol, 5.0f * (float)i);
    assert_int_equal(rp_runtime_set_camera(rt, &cam), 0);
    int err = rp_runtime_step(rt);
    if (err != 0)
      fail_msg("target %g, frame %d: %s: %s", target, i, rp_strerror(err),
               s->last.error);
    if (i == 0)
      *first = s->probe_rays;
  }
  i = (int)s->probe_rays;
  assert_int_equal(rp_runtime_destroy(rt), 0);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  free(s);
  return (uint32_t)i;
}

/* 2 % of a 0.1 ms target pays for 2 us of probe: under the floor of
 * 128 rays on any machine this runs on (a ray costs 0.3 to 1 us here,
 * and no CPU does one in under 0.015 us); 2 % of a 60 s target (the
 * largest) pays for 1.2 s: every ray on any (a ray would have to cost
 * over 1 ms). The
 * bounds are a hundred times wider than this machine's figures, so no
 * load makes the test flaky. */
/* The first effect set rendered on a volume builds its kernels inside
 * that frame, and only the variants that frame used (on Vulkan, the
 * raycast without the opacity correction at step 1). The frame must then
 * ask the devices' build lanes for the rest of the set, or the first
 * frame at another step builds in its own time: +15 ms on lavapipe, 1.8-
 * 2.5x the target at a TF switch with AO (M10's ao-tf-switch, before
 * 79179eb). Each backend that builds ahead: after one frame the set is
 * being prepared, and is prepared within a minute. */
static void check_first_set_prepared(const char *backend) {
  rp_context *ctx = rp_test_context();
  rp_runtime_desc d;
  rp_runtime *rt = NULL;
  rp_tf *tf = NULL;
  seen *s = calloc(1, sizeof *s);
  int i;
  assert_non_null(s);
  if (!rp_test_has_device(backend)) {
    printf("# %s: no device here; skipped\n", backend);
    free(s);
    rp_context_destroy(ctx);
    return;
  }
  base_desc(&d, s, RP_PACE_MANUAL);
  d.device.backend = backend;
  d.effects = RP_EFFECT_SHADING | EFFECTS;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tf), 0);
  post_events(rt, ctx, 0, (rp_tf *const[]){tf, tf});
  assert_int_equal(rp_runtime_step(rt), 0);
  assert_int_equal(s->last.status, 0);
  assert_int_equal(s->last.effects, d.effects);
  /* Builds run on the lanes beside the caller: poll, 10 ms apart. */
  for (i = 0; i < 6000; i++) {
    if (rp_device_group_prepared(rp__runtime_group(rt), d.effects))
      break;
    uv_sleep(10);
  }
  if (i == 6000)
    fail_msg("%s: effect set 0x%x never prepared after its first frame",
             backend, (unsigned)d.effects);
  assert_int_equal(rp_runtime_destroy(rt), 0);
  rp_tf_destroy(tf);
  rp_context_destroy(ctx);
  free(s);
}

static void test_first_set_prepared(void **state) {
  (void)state;
  check_first_set_prepared("vulkan");
  check_first_set_prepared("opencl");
}

static void test_probe_follows_target(void **state) {
  rp_context *ctx = rp_test_context();
  uint32_t first_small, first_large;
  uint32_t small = probe_rays_at(ctx, 0.1, &first_small);
  uint32_t large = probe_rays_at(ctx, 60000.0, &first_large);
  (void)state;
  print_message("probe rays: %u (first %u) at 0.1 ms, %u (first %u) at "
                "60 s\n", small, first_small, large, first_large);
  assert_true(first_small == first_large && first_large > 128);
  assert_true(small <= 128 && small > 0);
  assert_int_equal(large, first_large);
  rp_context_destroy(ctx);
}

/* A device re-created after a new volume was posted while AO was on:
 * the group gives a re-created device the AO it was last set to, and the
 * new volume freed that AO (the soak, under ASan: a use after free in
 * rp_device_set_ao). Device 1 fails from its 20th render since each
 * creation; once AO is on the frames and device 1 is waiting out its
 * back-off, a new volume is posted, whose AO takes several frames (a
 * block a frame); device 1 comes back during them.
 * Every frame succeeds (device 0 carries them); ASan and UBSan (dev.sh)
 * hold the rest. */
static void test_ao_device_back_after_new_volume(void **state) {
  rp_context *ctx = rp_test_context();
  rp_runtime_desc d;
  rp_runtime *rt = NULL;
  rp_device_desc dd[2];
  rp_fault_desc fd;
  rp_tf *tf = NULL;
  rp_volume *shape = make_volume(ctx, 48); /* the cameras' (the runtime
                                             owns what it is given) */
  rp_camera cam;
  seen *s = calloc(1, sizeof *s);
  int f, posted = -1, back = -1;
  (void)state;
  assert_non_null(s);
  memset(dd, 0, sizeof dd);
  memset(&fd, 0, sizeof fd);
  dd[0].backend = dd[1].backend = "reference";
  fd.fail_at_render = 20;
  rp_test_faults(&dd[1], &fd);
  base_desc(&d, s, RP_PACE_MANUAL);
  d.devices = dd;
  d.device_count = 2;
  d.effects = EFFECTS | RP_EFFECT_AO;
  d.ao_frame_share = 0.002; /* 2 ms of the target: a block a frame, so
                               that the new volume's run spans frames */
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tf), 0);
  assert_int_equal(rp_runtime_set_volume(rt, make_volume(ctx, 48)), 0);
  assert_int_equal(rp_runtime_set_tf(rt, tf), 0);
  for (f = 0; f < 160 && back < 0; f++) {
    cam = orbit(shape, 30.0f + (float)f);
    assert_int_equal(rp_runtime_set_camera(rt, &cam), 0);
    if (rp_runtime_step(rt) != 0 || s->last.status != 0)
      fail_msg("frame %d: %s", f, s->last.error);
    if (posted < 0 && (s->last.effects & RP_EFFECT_AO) &&
        s->last.devices[1].state == RP_DEVICE_RETRY) {
      assert_int_equal(rp_runtime_set_volume(rt, make_volume(ctx, 48)), 0);
      posted = f;
    } else if (posted >= 0 &&
               s->last.devices[1].state == RP_DEVICE_PROBATION) {
      back = f;
      print_message("new volume at frame %d; device 1 back at %d, its AO "
                    "%.0f %% done\n", posted, back,
                    100.0 * s->last.ao_progress);
    }
  }
  if (posted < 0 || back < 0)
    fail_msg("new volume posted at frame %d, device 1 back at %d", posted,
             back);
  assert_int_equal(rp_runtime_destroy(rt), 0);
  rp_volume_destroy(shape);
  rp_tf_destroy(tf);
  rp_context_destroy(ctx);
  free(s);
}

/* Every frame says which devices the runtime opened and which are lost,
 * also one that fails before a render pass could report them: two
 * devices that fail from their first render lose frame 0 in its render;
 * frame 1's TF upload then finds no device left. Both frames must count
 * the two devices opened (the desc's count), none alive, both dropped.
 * (The soak found frames after the last loss reporting 0 devices.) */
static void test_lost_devices_reported(void **state) {
  rp_context *ctx = rp_test_context();
  rp_runtime_desc d;
  rp_runtime *rt = NULL;
  rp_device_desc dd[2];
  rp_fault_desc fd[2];
  rp_tf *tf = NULL;
  rp_volume *vol = make_volume(ctx, 16);
  rp_camera cam = orbit(vol, 30.0f);
  seen *s = calloc(1, sizeof *s);
  int i, f;
  (void)state;
  assert_non_null(s);
  memset(dd, 0, sizeof dd);
  memset(fd, 0, sizeof fd);
  for (i = 0; i < 2; i++) {
    dd[i].backend = "reference";
    fd[i].fail_at_render = 1;
    rp_test_faults(&dd[i], &fd[i]);
  }
  base_desc(&d, s, RP_PACE_MANUAL);
  d.devices = dd;
  d.device_count = 2;
  assert_int_equal(rp_runtime_create(ctx, &d, &rt), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tf), 0);
  assert_int_equal(rp_runtime_set_volume(rt, vol), 0);
  for (f = 0; f < 2; f++) {
    assert_int_equal(rp_runtime_set_tf(rt, tf), 0);
    assert_int_equal(rp_runtime_set_camera(rt, &cam), 0);
    /* RP_EDEVICE or, once none is left, RP_ENODEV. */
    assert_int_not_equal(rp_runtime_step(rt), 0);
    assert_int_equal(s->last.frame, (uint64_t)f);
    assert_false(s->has_image);
    assert_int_equal(s->last.device_count, 2);
    assert_int_equal(s->last.devices_alive, 0);
    for (i = 0; i < 2; i++) {
      assert_int_equal(s->last.devices[i].dropped, 1);
      assert_non_null(strstr(s->last.devices[i].name, "reference"));
    }
  }
  assert_int_equal(rp_runtime_destroy(rt), 0);
  rp_tf_destroy(tf);
  rp_context_destroy(ctx);
  free(s);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_step),
      cmocka_unit_test(test_step_as_loop),
      cmocka_unit_test(test_density),
      cmocka_unit_test(test_ao_switch_back),
      cmocka_unit_test(test_min_step),
      cmocka_unit_test(test_lone_device_recreated),
      cmocka_unit_test(test_pacing_deterministic),
      cmocka_unit_test(test_pacing_holds_target),
      cmocka_unit_test(test_pacing_miss_rates),
      cmocka_unit_test(test_probe_follows_target),
      cmocka_unit_test(test_first_set_prepared),
      cmocka_unit_test(test_lost_devices_reported),
      cmocka_unit_test(test_ao_device_back_after_new_volume),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
