/* Embedding the raypace runtime in an app that owns its libuv loop.
 *
 *   sample_embed_uv [VOLUME_FILE] [--frames N] [--target-ms T]
 *                   [--size WxH] [--backend NAME]
 *
 * The app makes a loop, creates an rp_runtime on it and hands it a volume
 * (a generated CT-like phantom without a file). The runtime then renders
 * a frame every target_ms on its own, holding that frame time with the
 * predicted controller, and calls on_frame on the loop thread for each.
 * The app drives the camera, transfer function, effects and target from
 * a uv_timer of its own, playing a scripted user (the events of raypace
 * replay's "mixed" sequence, without its pan): as a UI would, at its own
 * rate; events between two frames coalesce. At the end of the script (or
 * after --frames N frames) it closes the runtime and its timer, and
 * uv_run returns because nothing is left on the loop. */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <uv.h>

#include "raypace.h"
#include "raypace_runtime.h"

#define TICK_MS 33 /* the app's input rate: 30 Hz */

/* The scripted user: SCRIPT_TICKS ticks. The camera orbits through the
 * keys, linearly between them; the other settings change in steps, each
 * holding until the next. */
#define SCRIPT_TICKS 200
typedef struct script_key {
  uint32_t tick;
  float azimuth, elevation, distance; /* rp_camera_orbit's */
} script_key;
static const script_key script_keys[] = {
    {0, 0, 10, 3}, {80, 120, 35, 1.8f}, {160, 200, 10, 2.5f},
    {199, 240, 10, 2.5f}};

static const char *const script_tfs[] = {"minmax-bone", "minmax-soft", "opaque",
                                         "nearly-transparent"};
#define SCRIPT_TF_COUNT (sizeof script_tfs / sizeof script_tfs[0])
#define PLAIN (RP_EFFECT_ERT | RP_EFFECT_SKIP)
#define SHADED (RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP)
typedef struct script_step {
  uint32_t tick;
  int tf;              /* index into script_tfs */
  uint32_t effects;
  double target_scale; /* of --target-ms */
} script_step;
static const script_step script_steps[] = {
    {0, 0, PLAIN, 1},    {40, 1, PLAIN, 1},    {60, 1, SHADED, 1},
    {100, 2, SHADED, 0.6}, {120, 3, SHADED, 0.6}, {140, 3, PLAIN, 0.6},
    {160, 0, PLAIN, 0.6}};

typedef struct app {
  uv_loop_t loop;
  uv_timer_t tick;
  rp_runtime *rt;
  rp_tf *tfs[SCRIPT_TF_COUNT]; /* the runtime copies the one it is given */
  rp_camera cams[SCRIPT_TICKS];
  uint32_t next;       /* the tick whose state is posted next */
  uint32_t max_frames; /* 0: until the script ends */
  double target_ms;
  int closing, status;
} app;

/* Prints a failed call; ctx NULL for calls that leave no message. */
static int check(rp_context *ctx, int err, const char *what) {
  if (err != 0)
    fprintf(stderr, "%s: %s%s%s\n", what, rp_strerror(err),
            ctx != NULL ? ": " : "", ctx != NULL ? rp_last_error(ctx) : "");
  return err;
}

static void on_closed(void *user) {
  app *a = user;
  a->rt = NULL; /* its memory is gone */
}

/* Loop thread only. Nothing else on the loop once both handles close. */
static void stop(app *a, int status) {
  if (status != 0)
    a->status = status;
  if (a->closing)
    return;
  a->closing = 1;
  uv_close((uv_handle_t *)&a->tick, NULL);
  if (a->rt != NULL)
    rp_runtime_close(a->rt, on_closed, a);
}

/* The step that holds at tick i. */
static const script_step *step_at(uint32_t i) {
  size_t k = 0;
  while (k + 1 < sizeof script_steps / sizeof script_steps[0] &&
         script_steps[k + 1].tick <= i)
    k++;
  return &script_steps[k];
}

/* Posts what changed at the next tick of the script: every setting at
 * tick 0, then the camera while it moves and a step's changes. */
static void on_tick(uv_timer_t *t) {
  app *a = t->data;
  const script_step *st, *prev;
  uint32_t i = a->next;
  int err = 0;
  if (i >= SCRIPT_TICKS) {
    stop(a, 0);
    return;
  }
  st = step_at(i);
  prev = i > 0 ? step_at(i - 1) : NULL;
  if (prev == NULL || memcmp(&a->cams[i], &a->cams[i - 1],
                             sizeof a->cams[i]) != 0)
    err = rp_runtime_set_camera(a->rt, &a->cams[i]);
  if (err == 0 && (prev == NULL || st->tf != prev->tf))
    err = rp_runtime_set_tf(a->rt, a->tfs[st->tf]);
  if (err == 0 && (prev == NULL || st->effects != prev->effects))
    err = rp_runtime_set_effects(a->rt, st->effects);
  if (err == 0 && (prev == NULL || st->target_scale != prev->target_scale))
    err = rp_runtime_set_target(a->rt, a->target_ms * st->target_scale);
  if (err != 0) {
    fprintf(stderr, "state %u: %s\n", a->next, rp_strerror(err));
    stop(a, 1);
  }
  a->next++;
}

/* One line per frame. The stats are valid during the call only. */
static void on_frame(rp_runtime *rt, const rp_frame *f, void *user) {
  app *a = user;
  const rp_frame_stats *s = f->stats;
  (void)rt;
  if (a->closing)
    return;
  if (s->status != 0) {
    fprintf(stderr, "frame %llu: %s: %s\n", (unsigned long long)s->frame,
            rp_strerror(s->status), s->error);
    stop(a, 1);
    return;
  }
  /* eff/want: the effects rendered and wanted (RP_EFFECT_* bits); they
   * differ while AO is computed or a new set's kernels are built. */
  printf("%5llu %6.1f %6.2f %6.2f %+6.1f%% %5.3f %5.2f %5.3f "
         "%6.2f %7.3f %6.3f %6.3f %6llu %4llu %3x %4x\n",
         (unsigned long long)s->frame, s->target_ms, s->predicted_ms,
         s->measured_ms, 100 * s->delta, s->rho, s->step, s->scale,
         s->probe_ms, s->predict_ms, s->train_ms, s->dispatch_ms,
         (unsigned long long)s->counters.probes,
         (unsigned long long)s->counters.occupancies, s->effects,
         s->effects_wanted);
  if (a->max_frames > 0 && s->frame + 1 >= a->max_frames)
    stop(a, 0);
  else if (s->frame == 0) /* the script plays on from here */
    uv_timer_start(&a->tick, on_tick, TICK_MS, TICK_MS);
}

static int parse(int argc, char **argv, rp_runtime_desc *d, app *a,
                 const char **volume) {
  static const struct option opts[] = {
      {"frames", required_argument, 0, 'f'},
      {"target-ms", required_argument, 0, 't'},
      {"size", required_argument, 0, 's'},
      {"backend", required_argument, 0, 'b'},
      {0, 0, 0, 0}};
  int c, li = 0;
  while ((c = getopt_long(argc, argv, "", opts, &li)) != -1) {
    char *end = optarg;
    switch (c) {
    case 'f': a->max_frames = (uint32_t)strtoul(optarg, &end, 10); break;
    case 't': a->target_ms = strtod(optarg, &end); break;
    case 's':
      d->width = (uint32_t)strtoul(optarg, &end, 10);
      if (*end == 'x')
        d->height = (uint32_t)strtoul(end + 1, &end, 10);
      break;
    case 'b': d->device.backend = optarg; continue;
    default: return 1;
    }
    if (end == optarg || *end != '\0' || !(a->target_ms > 0) ||
        (c == 's' && (d->width == 0 || d->height == 0))) {
      fprintf(stderr, "bad value '%s' for --%s\n", optarg, opts[li].name);
      return 1;
    }
  }
  *volume = optind < argc ? argv[optind] : NULL;
  return optind + 1 < argc;
}

/* The script's transfer functions and every tick's camera: made before
 * the volume is handed over, after which it is the runtime's. */
static int prepare(app *a, rp_context *ctx, const rp_volume *vol) {
  uint32_t i, k = 0;
  int err;
  for (i = 0; i < SCRIPT_TF_COUNT; i++)
    if ((err = check(ctx, rp_tf_create_preset(ctx, script_tfs[i],
                                              &a->tfs[i]), "tf")) != 0)
      return err;
  for (i = 0; i < SCRIPT_TICKS; i++) {
    const script_key *p, *q;
    float t;
    while (k + 2 < sizeof script_keys / sizeof script_keys[0] &&
           script_keys[k + 1].tick <= i)
      k++;
    p = &script_keys[k];
    q = &script_keys[k + 1];
    t = i >= q->tick ? 1.0f : (float)(i - p->tick) / (float)(q->tick - p->tick);
    rp_camera_orbit(&a->cams[i], vol,
                    p->azimuth + t * (q->azimuth - p->azimuth),
                    p->elevation + t * (q->elevation - p->elevation),
                    p->distance + t * (q->distance - p->distance));
  }
  return 0;
}

/* Creates the runtime on our loop, hands it the volume and runs the loop
 * until the runtime and the timer have closed. */
static int run(app *a, rp_context *ctx, rp_runtime_desc *d,
               rp_volume **vol) {
  int err = uv_loop_init(&a->loop);
  if (err != 0) {
    fprintf(stderr, "uv_loop_init: %s\n", uv_strerror(err));
    return err;
  }
  uv_timer_init(&a->loop, &a->tick);
  a->tick.data = a;
  d->loop = &a->loop;
  d->pacing = RP_PACE_TIMER;
  d->controller = RP_CONTROL_PREDICTED;
  d->target_ms = a->target_ms;
  d->space.space = RP_SPACE_HYBRID;
  d->on_frame = on_frame;
  d->user = a;
  err = check(ctx, rp_runtime_create(ctx, d, &a->rt), "runtime");
  if (err == 0 &&
      (err = check(NULL, rp_runtime_set_volume(a->rt, *vol), "volume")) == 0)
    *vol = NULL; /* the runtime's now */
  if (err == 0) {
    printf("%5s %6s %6s %6s %7s %5s %5s %5s %6s %7s %6s %6s %6s %4s %3s "
           "%4s\n", "frame", "target", "pred", "meas", "delta", "rho",
           "step", "scale", "probe", "predict", "train", "disp", "probes",
           "occ", "eff", "want");
    /* The first frame builds the device's kernels, which can take
     * seconds: the first tick posts state 0 and the rest wait for it. */
    uv_timer_start(&a->tick, on_tick, 0, 0);
  } else {
    stop(a, 1);
  }
  uv_run(&a->loop, UV_RUN_DEFAULT);
  /* UV_EBUSY here would mean a handle was left open on the loop. */
  if (uv_loop_close(&a->loop) != 0 || a->rt != NULL) {
    fprintf(stderr, "the loop did not close cleanly\n");
    a->status = 1;
  }
  return err;
}

int main(int argc, char **argv) {
  app a;
  rp_runtime_desc d = {0};
  rp_context *ctx = NULL;
  rp_volume *vol = NULL;
  const char *path;
  size_t i;
  int err;

  memset(&a, 0, sizeof a);
  a.target_ms = 30;
  if (parse(argc, argv, &d, &a, &path) != 0) {
    fprintf(stderr, "usage: %s [VOLUME_FILE] [--frames N] [--target-ms T]"
                    " [--size WxH] [--backend NAME]\n", argv[0]);
    return 1;
  }
  if (rp_context_create(NULL, &ctx) != 0)
    return 1;
  if (path != NULL) {
    err = check(ctx, rp_volume_load(ctx, path, &vol), path);
  } else {
    rp_generate_desc g = {0};
    g.kind = RP_GEN_PHANTOM;
    g.dims[0] = g.dims[1] = g.dims[2] = 128;
    err = check(ctx, rp_volume_generate(ctx, &g, &vol), "generate");
  }
  if (err == 0)
    err = prepare(&a, ctx, vol);
  if (err == 0)
    err = run(&a, ctx, &d, &vol);
  for (i = 0; i < SCRIPT_TF_COUNT; i++)
    rp_tf_destroy(a.tfs[i]);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
  return err == 0 && a.status == 0 ? 0 : 1;
}
