/* raypace bench overhead: what each stage of a runtime frame costs (seed
 * 000 Table 3, DESIGN section 1).
 *
 * The runtime runs on this command's own loop, one frame per request
 * (RP_PACE_ON_REQUEST). Each frame posts a new orbit camera (azimuth
 * stepping 3 degrees), every 10th frame also switches between two
 * transfer functions, and the volume is posted again --loads times; each
 * event makes the runtime redo what it invalidates (raypace_runtime.h):
 *
 *   volume  -> H build, volume upload, then as for a TF
 *   TF      -> H-alpha + occupancy, TF upload, then as for a camera
 *   camera  -> probe (host depth pass + ERT pre-pass), device depth pass
 *   every frame -> predict, raycast, readback, upscale, dispatch, and
 *                  training on the frame before
 *
 * For each stage: how many frames ran it, its median and maximum, and the
 * median as a share of the median frame time (measured_ms: the frame's
 * work on the worker, which the target is held on). A stage runs in a frame when its time
 * is not zero (rp_frame_stats). The first frames build kernels and the
 * controller takes a while to recover from them: frames are left out
 * until its density settles. */
#include <cjson/cJSON.h>
#include <getopt.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <uv.h>

#include "cli_util.h"
#include "commands.h"
#include "raypace.h"
#include "raypace_runtime.h"

#define WARMUP_MIN 3      /* frames at least, for the kernel builds */
#define WARMUP_MAX 200    /* frames at most */
/* Settled: SETTLE_FRAMES frames in a row whose density changed by less
 * than SETTLE_CHANGE, i.e. slower than a controller climbing at its raise
 * limit (1 / 0.8 a frame). */
#define SETTLE_FRAMES 3
#define SETTLE_CHANGE 0.2
#define MAX_FRAMES 10000
#define MAX_LOADS 100
#define FRAME_TIMEOUT_MS 60000 /* a frame not delivered by then: a hang */

typedef struct overhead_opts {
  const char *volume, *backend;
  uint32_t width, height, device, frames, loads;
  rp_controller_kind controller;
  float target_ms;
  int shading, json;
} overhead_opts;

/* The two transfer functions frames switch between. */
static const char *const tf_names[2] = {"minmax-bone", "minmax-soft"};

/* The stages of seed 000 Table 3, as rp_frame_stats fields. */
typedef struct stage {
  const char *name, *when;
  size_t offset; /* of a double in rp_frame_stats */
  int work;      /* 1: the per-frame prediction work */
} stage;

#define STAGE(name, when, field, work)                                      \
  { name, when, offsetof(rp_frame_stats, field), work }
static const stage stages[] = {
    STAGE("H build", "volume", histograms_ms, 0),
    STAGE("volume upload", "volume", volume_upload_ms, 0),
    STAGE("H-alpha + occupancy", "TF", occupancy_ms, 0),
    STAGE("TF upload", "TF", tf_upload_ms, 0),
    STAGE("probe (host depth + ERT)", "camera", probe_ms, 1),
    STAGE("device depth pass", "camera", devices[0].depth_ms, 0),
    STAGE("predict", "frame", predict_ms, 1),
    STAGE("train", "frame", train_ms, 1),
    STAGE("dispatch", "frame", dispatch_ms, 0),
    STAGE("raycast", "frame", devices[0].raycast_ms, 0),
    STAGE("readback", "frame", devices[0].readback_ms, 0),
    STAGE("upscale", "frame", upscale_ms, 0),
    STAGE("frame (measured)", "frame", measured_ms, 0),
    STAGE("total", "frame", total_ms, 0),
};
#undef STAGE
#define STAGES (int)(sizeof stages / sizeof stages[0])
#define FRAME_STAGE (STAGES - 2) /* measured_ms: the shares' base */

typedef struct stage_result {
  int count;
  double median, max, share;
} stage_result;

/* One run: the runtime on our loop and the frames it delivered. */
typedef struct overhead {
  rp_context *ctx;
  uv_loop_t loop;
  uv_timer_t watchdog;
  rp_runtime *rt;
  rp_frame_stats *stats; /* every frame delivered, warm-up included */
  uint32_t delivered, cap, warmup, requested, received;
  int waiting, timed_out, failed;
} overhead;

static void usage_overhead(FILE *f) {
  fprintf(f,
          "usage: raypace bench overhead VOLUME [options]\n\n"
          "Runs the runtime one frame per request, a new camera every frame,"
          "\na transfer function switch (%s / %s) every 10th and the volume"
          "\nposted again --loads times, and reports each stage's median and"
          "\nmaximum time and its share of the median frame time.\n\n"
          "  --frames N            frames measured, 1..10000 (default 60),\n"
          "                        after a warm-up of %d to %d frames that"
          "\n                        ends when the density settles\n"
          "  --loads N             of those, how many post the volume again"
          "\n                        0..100 (default 3)\n"
          "  --size WxH            output size (default 512x512)\n"
          "  --backend NAME        opencl, vulkan or reference; default: the"
          "\n                        first with a device\n"
          "  --device N            device index within the backend, 0..1024\n"
          "  --controller NAME     frame-time controller (default predicted)"
          "\n"
          "  --target-ms T         frame-time target in ms, in (0, 60000]\n"
          "                        (default 50)\n"
          "  --shading             gradient shading\n"
          "  --json                one JSON object on stdout\n",
          tf_names[0], tf_names[1], WARMUP_MIN, WARMUP_MAX);
}

#define CMD "bench overhead"

/* An option of bench overhead that takes a value, checked into o; 0 or
 * 2 (printed). */
static int overhead_value(int c, const char *option, const char *arg,
                          overhead_opts *o) {
  /* The runtime's target range, rp_runtime_desc.target_ms. */
  static const cli_range target = {0.0, 60000.0, CLI_OPEN_LO, 0, "ms"};
  switch (c) {
  case 'n': return cli_parse_whole(CMD, option, arg, 1, MAX_FRAMES,
                                   &o->frames);
  case 'l': return cli_parse_whole(CMD, option, arg, 0, MAX_LOADS,
                                   &o->loads);
  case 's': return cli_parse_size(CMD, option, arg, &o->width, &o->height);
  case 'B': o->backend = arg; return cli_check_backend(CMD, arg);
  case 'D': return cli_parse_whole(CMD, option, arg, 0, 1024, &o->device);
  case 'c':
    return rp_controller_from_name(arg, &o->controller) != 0
               ? cli_bad_option(CMD, option, arg, "not a controller",
                                "must be none, last-frame, two-pass, "
                                "predicted, vtk, ue5 or valve")
               : 0;
  default: return cli_parse_float(CMD, option, arg, &target, &o->target_ms);
  }
}

static int parse_overhead(int argc, char **argv, overhead_opts *o) {
  static const struct option opts[] = {
      {"frames", required_argument, 0, 'n'},
      {"loads", required_argument, 0, 'l'},
      {"size", required_argument, 0, 's'},
      {"backend", required_argument, 0, 'B'},
      {"device", required_argument, 0, 'D'},
      {"controller", required_argument, 0, 'c'},
      {"target-ms", required_argument, 0, 't'},
      {"shading", no_argument, 0, 'S'},
      {"json", no_argument, 0, 'j'},
      {"help", no_argument, 0, 'h'},
      {0, 0, 0, 0}};
  int c, li = 0;
  memset(o, 0, sizeof *o);
  o->width = o->height = 512;
  o->frames = 60;
  o->loads = 3;
  o->controller = RP_CONTROL_PREDICTED;
  o->target_ms = 50;
  optind = 1;
  while ((c = getopt_long(argc, argv, "h", opts, &li)) != -1) {
    char option[40];
    snprintf(option, sizeof option, "--%s", opts[li].name);
    switch (c) {
    case 'S': o->shading = 1; break;
    case 'j': o->json = 1; break;
    case 'h': usage_overhead(stdout); return 1;
    case '?': usage_overhead(stderr); return 2;
    default:
      if (overhead_value(c, option, optarg, o) != 0)
        return 2;
    }
  }
  if (o->backend != NULL && strcmp(o->backend, "mpi") == 0 &&
      cli_check_mpi(CMD, "--backend", "mpi", o->device) != 0)
    return 2;
  if (optind + 1 != argc) {
    usage_overhead(stderr);
    return 2;
  }
  if (o->loads > o->frames) {
    char value[16];
    snprintf(value, sizeof value, "%u", o->loads);
    return cli_bad_option(CMD, "--loads", value, "more than --frames",
                          "must be at most --frames (%u)", o->frames);
  }
  o->volume = argv[optind];
  return 0;
}

/* Runtime calls leave no message in our context. */
static int rt_error(const char *what, int err) {
  fprintf(stderr, "raypace bench overhead: %s: %s\n", what,
          rp_strerror(err));
  return 1;
}

static void on_frame(rp_runtime *rt, const rp_frame *f, void *user) {
  overhead *b = user;
  const rp_frame_stats *s = f->stats;
  (void)rt;
  if (++b->received > b->requested)
    fprintf(stderr, "raypace bench overhead: frame %llu delivered "
            "without a request\n", (unsigned long long)s->frame);
  if (s->status != 0) {
    fprintf(stderr, "raypace bench overhead: frame %llu: %s: %s\n",
            (unsigned long long)s->frame, rp_strerror(s->status), s->error);
    b->failed = 1;
  } else if (b->delivered < b->cap) {
    b->stats[b->delivered++] = *s;
  }
  b->waiting = 0;
}

static void on_watchdog(uv_timer_t *t) {
  overhead *b = t->data;
  b->timed_out = 1;
  b->waiting = 0;
}

/* Requests one frame and runs the loop until the runtime delivers it. */
static int one_frame(overhead *b) {
  int err = rp_runtime_request_frame(b->rt);
  if (err != 0)
    return rt_error("request frame", err);
  b->requested++;
  b->waiting = 1;
  uv_timer_start(&b->watchdog, on_watchdog, FRAME_TIMEOUT_MS, 0);
  while (b->waiting)
    uv_run(&b->loop, UV_RUN_ONCE);
  uv_timer_stop(&b->watchdog);
  if (b->timed_out) {
    fprintf(stderr, "raypace bench overhead: no frame delivered in %d s\n",
            FRAME_TIMEOUT_MS / 1000);
    return 1;
  }
  return b->failed;
}

/* A fresh copy of `vol` for the runtime to own. */
static int post_volume(overhead *b, const rp_volume *vol) {
  rp_volume_info info;
  rp_volume_desc vd = {0};
  rp_volume *copy = NULL;
  int err;
  rp_volume_get_info(vol, &info);
  memcpy(vd.dims, info.dims, sizeof vd.dims);
  memcpy(vd.spacing, info.spacing, sizeof vd.spacing);
  vd.type = info.type;
  vd.data = rp_volume_data(vol);
  if ((err = rp_volume_create(b->ctx, &vd, &copy)) != 0)
    return cli_error(b->ctx, "volume copy", err);
  if ((err = rp_runtime_set_volume(b->rt, copy)) != 0) {
    rp_volume_destroy(copy);
    return rt_error("set volume", err);
  }
  return 0;
}

/* Posts frame i's events and renders it: a new camera every frame, a TF
 * switch every 10th, and the volume again when `load` is set. */
static int step_frame(overhead *b, const rp_volume *vol,
                      rp_tf *const tfs[2], uint32_t i, int load) {
  rp_camera cam = {0};
  int err;
  rp_camera_orbit(&cam, vol, 30.0f + 3.0f * (float)(i % 120), 20.0f, 2.5f);
  if (load && post_volume(b, vol) != 0)
    return 1;
  if (i % 10 == 0 &&
      (err = rp_runtime_set_tf(b->rt, tfs[(i / 10) % 2])) != 0)
    return rt_error("set tf", err);
  if ((err = rp_runtime_set_camera(b->rt, &cam)) != 0)
    return rt_error("set camera", err);
  return one_frame(b);
}

/* 1 when the last SETTLE_FRAMES frames' densities each differ from the
 * one before by under SETTLE_CHANGE. */
static int settled(const overhead *b) {
  uint32_t i, n = b->delivered;
  if (n < WARMUP_MIN || n <= SETTLE_FRAMES)
    return 0;
  for (i = n - SETTLE_FRAMES; i < n; i++)
    if (fabs(b->stats[i].rho / b->stats[i - 1].rho - 1) >= SETTLE_CHANGE)
      return 0;
  return 1;
}

/* The warm-up, then --frames frames, the first --loads of which post the
 * volume again. The warm-up ends when the density settles: the first
 * frames build kernels, the controller learns from their time and then
 * climbs back by at most 1 / 0.8 per frame. */
static int run_frames(overhead *b, const overhead_opts *o,
                      const rp_volume *vol, rp_tf *const tfs[2]) {
  uint32_t i = 0, j;
  do {
    if (step_frame(b, vol, tfs, i, i == 0) != 0)
      return 1;
    i++;
  } while (i < WARMUP_MAX && !settled(b));
  b->warmup = i;
  for (j = 0; j < o->frames; j++, i++)
    if (step_frame(b, vol, tfs, i, j < o->loads) != 0)
      return 1;
  return 0;
}

static double field(const rp_frame_stats *s, const stage *st) {
  return *(const double *)((const char *)s + st->offset);
}

static int summarise(const overhead *b, stage_result r[STAGES],
                     double *work) {
  uint32_t n = b->delivered - b->warmup, i;
  double *v = malloc((n > 0 ? n : 1) * sizeof *v);
  int s;
  if (v == NULL) {
    fprintf(stderr, "raypace bench overhead: out of memory\n");
    return 1;
  }
  memset(r, 0, STAGES * sizeof *r);
  for (s = 0; s < STAGES; s++) {
    for (i = 0; i < n; i++) {
      double ms = field(&b->stats[b->warmup + i], &stages[s]);
      if (ms > 0) {
        v[r[s].count++] = ms;
        if (ms > r[s].max)
          r[s].max = ms;
      }
    }
    if (r[s].count > 0)
      r[s].median = cli_median(v, r[s].count);
  }
  free(v);
  for (s = 0; s < STAGES; s++)
    r[s].share = r[FRAME_STAGE].median > 0
                     ? r[s].median / r[FRAME_STAGE].median
                     : 0;
  /* The sum of medians over the median frame, each over the frames
   * where the stage ran. */
  *work = 0;
  for (s = 0; s < STAGES; s++)
    if (stages[s].work)
      *work += r[s].share;
  return 0;
}

static void print_table(const overhead_opts *o, const overhead *b,
                        const stage_result r[STAGES], double work) {
  int s;
  printf("%s, %ux%u, %s, target %.1f ms%s, on %s\n", o->volume, o->width,
         o->height, rp_controller_name(o->controller), o->target_ms,
         o->shading ? ", shading" : "", b->stats[0].devices[0].name);
  printf("%u frames after %u warm-up; the first %u load the volume, "
         "every 10th switches the TF\n\n", o->frames, b->warmup, o->loads);
  printf("%-26s %-7s %5s %10s %10s %8s\n", "stage", "runs on", "count",
         "median ms", "max ms", "% frame");
  for (s = 0; s < STAGES; s++)
    if (r[s].count > 0)
      printf("%-26s %-7s %5d %10.3f %10.3f %7.1f%%\n", stages[s].name,
             stages[s].when, r[s].count, r[s].median, r[s].max,
             100 * r[s].share);
  printf("\nper-frame prediction work (probe + predict + train) = %.1f %% "
         "of the frame (goal <= 3 %%)\n", 100 * work);
}

static int print_json(const overhead_opts *o, const overhead *b,
                      const stage_result r[STAGES], double work) {
  cJSON *root = cJSON_CreateObject(), *arr;
  int s;
  cJSON_AddStringToObject(root, "volume", o->volume);
  cJSON_AddStringToObject(root, "device", b->stats[0].devices[0].name);
  cJSON_AddNumberToObject(root, "width", o->width);
  cJSON_AddNumberToObject(root, "height", o->height);
  cJSON_AddStringToObject(root, "controller",
                          rp_controller_name(o->controller));
  cJSON_AddNumberToObject(root, "target_ms", o->target_ms);
  cJSON_AddBoolToObject(root, "shading", o->shading);
  cJSON_AddNumberToObject(root, "frames", o->frames);
  cJSON_AddNumberToObject(root, "warmup", b->warmup);
  cJSON_AddNumberToObject(root, "loads", o->loads);
  arr = cJSON_AddArrayToObject(root, "stages");
  for (s = 0; s < STAGES; s++) {
    cJSON *e;
    if (r[s].count == 0)
      continue;
    e = cJSON_CreateObject();
    cJSON_AddStringToObject(e, "stage", stages[s].name);
    cJSON_AddStringToObject(e, "runs_on", stages[s].when);
    cJSON_AddNumberToObject(e, "count", r[s].count);
    cJSON_AddNumberToObject(e, "median_ms", r[s].median);
    cJSON_AddNumberToObject(e, "max_ms", r[s].max);
    cJSON_AddNumberToObject(e, "share", r[s].share);
    cJSON_AddItemToArray(arr, e);
  }
  cJSON_AddNumberToObject(root, "frame_median_ms", r[FRAME_STAGE].median);
  cJSON_AddNumberToObject(root, "prediction_share", work);
  return cli_print_json(root);
}

static void on_closed(void *user) { *(int *)user = 1; }

int cli_cmd_bench_overhead(int argc, char **argv) {
  overhead_opts o;
  overhead b;
  rp_runtime_desc d = {0};
  rp_volume *vol = NULL;
  rp_tf *tfs[2] = {NULL, NULL};
  stage_result r[STAGES];
  double work;
  int rc, err, i, loop_open = 0, closed = 0;
  if ((rc = parse_overhead(argc, argv, &o)) != 0)
    return rc == 1 ? 0 : rc;
  rc = 1;
  memset(&b, 0, sizeof b);
  b.cap = WARMUP_MAX + o.frames;
  if ((b.stats = malloc(b.cap * sizeof *b.stats)) == NULL) {
    fprintf(stderr, "raypace bench overhead: out of memory\n");
    return 1;
  }
  if ((err = rp_context_create(NULL, &b.ctx)) != 0) {
    cli_error(b.ctx, "context", err);
    goto out;
  }
  if (cli_open_volume(b.ctx, o.volume, &vol) != 0)
    goto out;
  for (i = 0; i < 2; i++)
    if ((err = rp_tf_create_preset(b.ctx, tf_names[i], &tfs[i])) != 0) {
      cli_error(b.ctx, "tf", err);
      goto out;
    }
  if ((err = uv_loop_init(&b.loop)) != 0) {
    fprintf(stderr, "raypace bench overhead: uv_loop_init: %s\n",
            uv_strerror(err));
    goto out;
  }
  loop_open = 1;
  uv_timer_init(&b.loop, &b.watchdog);
  b.watchdog.data = &b;
  d.loop = &b.loop;
  d.device.backend = o.backend;
  d.device.index = o.device;
  d.pacing = RP_PACE_ON_REQUEST;
  d.on_frame = on_frame;
  d.user = &b;
  d.controller = o.controller;
  d.target_ms = o.target_ms;
  d.width = o.width;
  d.height = o.height;
  d.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP |
              (o.shading ? RP_EFFECT_SHADING : 0);
  d.space.space = RP_SPACE_HYBRID;
  err = rp_runtime_create(b.ctx, &d, &b.rt);
  if (err == RP_ENODEV && o.backend == NULL && o.device == 0) {
    fprintf(stderr, "raypace: %s; using the reference\n",
            rp_last_error(b.ctx));
    d.device.backend = "reference";
    err = rp_runtime_create(b.ctx, &d, &b.rt);
  }
  if (err != 0) {
    cli_error(b.ctx, "runtime", err);
    goto out;
  }
  if (run_frames(&b, &o, vol, tfs) != 0 || summarise(&b, r, &work) != 0)
    goto out;
  if (o.json) {
    rc = print_json(&o, &b, r, work);
  } else {
    print_table(&o, &b, r, work);
    rc = 0;
  }
out:
  /* A runtime that hangs would hang its close too: leave it to exit. */
  if (loop_open && !b.timed_out) {
    /* Close the runtime and our timer, then run the loop until both are
     * gone: uv_loop_close says UV_EBUSY if a handle was left. */
    if (b.rt != NULL && (err = rp_runtime_close(b.rt, on_closed,
                                                &closed)) != 0)
      rt_error("close", err);
    uv_close((uv_handle_t *)&b.watchdog, NULL);
    uv_run(&b.loop, UV_RUN_DEFAULT);
    if ((b.rt != NULL && !closed) || uv_loop_close(&b.loop) != 0) {
      fprintf(stderr, "raypace bench overhead: the runtime did not close"
                      "\n");
      rc = 1;
    }
  }
  free(b.stats);
  rp_tf_destroy(tfs[0]);
  rp_tf_destroy(tfs[1]);
  rp_volume_destroy(vol);
  rp_context_destroy(b.ctx);
  return rc;
}
