/* raypace replay: plays an interaction sequence under each frame-time
 * controller and reports how well each held the target (DESIGN section
 * 10): per-frame CSV, a plot of frame times against the target (seed 000
 * Fig. 5), and one summary per controller (replay_report.c).
 *
 * Replay is a driver of the runtime an app embeds, nothing more: each
 * controller plays on an rp_runtime of its own in manual pacing
 * (rp_runtime_step), created with that controller; the sequence becomes
 * the runtime's events (TF, camera, effects, target) and each frame's
 * rp_frame_stats becomes a row. It calls no controller, cost model,
 * device group or AO function itself: a figure it reports is a figure
 * about the library.
 *
 * Every runtime is made the same way:
 * - warm-up (controller none, the largest target so that an AO
 *   computation ends in its first step): the first frame's TF and
 *   camera, then each effect set the sequence uses (and, for one with
 *   AO, the set without AO its frames render while AO is computed), each
 *   stepped until the runtime renders it, so that no recorded frame pays
 *   for a kernel build; the first frame's set last, so that the runtime
 *   ends in the first frame's state;
 * - then the first frame's target and the runtime's controller (its
 *   history afresh; the cost model keeps what the warm-up taught it),
 *   `--settle` unrecorded frames of the first frame, and the sequence.
 * The first runtime also measures the frame without adaptation before
 * its controller is set: the median of CALIBRATE_FRAMES frames at
 * density 1 (the controller none's). Targets given as a fraction are of
 * that time.
 *
 * With one device, in core, the controllers play frame by frame in
 * turn, each on its own runtime and device, the order rotating each
 * frame, so that a burst of the machine's noise falls on all of them
 * alike. After each such round a still frame renders on one more
 * runtime (controller none at a fixed density, found by last-frame's
 * rule over STILL_AIM_FRAMES frames at the first target): the first
 * frame's camera, with the round's TF and effects. Its render times
 * carry the machine's noise over the same minutes as the controllers'
 * frames, and say how close to the target a perfect model could come
 * (the noise floor). With --devices or --budget-mb, or when a second
 * device cannot be had (an MPI rank has one), each controller plays the
 * whole sequence in turn on a runtime made afresh, so that none
 * inherits another's devices' models or brick pool.
 *
 * Frame time is the runtime's measured_ms: everything the frame spent
 * on its thread (recompute, AO step, probe, decision and the render
 * passes); the probe and the decision are also reported apart as
 * overhead. */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "replay.h"

/* The command named in option messages: "replay", or the command that
 * passes its options on (cli_replay_check). */
static const char *cmd_name = "replay";
#define CMD cmd_name

/* Frames the still frame spends aiming at the first target. */
#define STILL_AIM_FRAMES 5
/* Frames of the first state whose median is the frame without
 * adaptation. */
#define CALIBRATE_FRAMES 3
/* The warm-up's target: the runtime's largest, so that an AO step (a
 * share of it) finishes the computation in one frame. */
#define WARM_TARGET_MS 60000.0
/* How long a warm-up may wait for one effect set to render (its kernels
 * being built ahead): frames and wall seconds. */
#define WARM_MAX_FRAMES 100000u
#define WARM_MAX_S 300.0

static void usage(FILE *f) {
  fprintf(f,
      "usage: raypace replay VOLUME [--sequence S] [--controller C|all]\n"
      "                      [--target-ms T | --target-fraction F] "
      "[options]\n"
      "       raypace replay --list\n\n"
      "  --sequence S          built-in name or JSON file (default "
      "tf-switch)\n"
      "  --controller C        none, last-frame, two-pass, predicted, "
      "vtk,\n"
      "                        ue5, valve, several joined by commas, or\n"
      "                        all (default all)\n"
      "  --target-ms T         frame-time target in ms, in (0, 60000]; the"
      "\n                        sequence's own target changes scale "
      "with it\n"
      "  --target-fraction F   target as a fraction of the frame time "
      "without\n"
      "                        adaptation, measured at the start, in\n"
      "                        (0, 100]\n"
      "                        (default: the sequence's target)\n"
      "  --space S             ray, image or hybrid (default hybrid)\n"
      "  --base-step D         step at density 1, voxels, in [0.001, 10000]"
      "\n                        (default 1)\n"
      "  --min-step D          finest step, voxels: a step under the base\n"
      "                        step (density above 1) where the budget\n"
      "                        allows; image space stops at 1 (default:\n"
      "                        the base step)\n"
      "  --size WxH            output size, each side 1..16384, at most\n"
      "                        67108864 pixels (default 384x384)\n"
      "  --backend NAME        opencl, vulkan, reference, test or mpi\n"
      "  --device N            device index within the backend, 0..1024\n"
      "  --devices LIST        render every frame on several devices at "
      "once\n"
      "                        (a device group; not with --backend/"
      "--device):\n"
      "                        SPEC[,SPEC...], SPEC BACKEND[:INDEX]"
      "[:cu=N]\n"
      "                        [:slow=S][:fail=F][:seed=N][:noise=X] as"
      "\n                        in 'raypace render'"
      "\n"
      "                        (mpi:I: MPI rank I + 1, under mpirun)\n"
      "  --settle N            unrecorded frames before the sequence, "
      "0..100000\n                        (default 10)\n"
      "  --frames N            play only the first N frames, 1..10000000\n"
      "                        (more than the sequence has: all of it)\n"
      "  --seed N              ERT pre-pass seed, 0..4294967295 (default 1)"
      "\n"
      "  --miss-rate Q         predicted: the share of frames allowed over\n"
      "                        the target, in (0, 0.5] (default 0.05), or\n"
      "                        'none' to aim at the target itself\n"
      "  --headroom H          the reactive rules: the share of the target\n"
      "                        kept free, in (0, 0.9] (default: each\n"
      "                        rule's own)\n"
      "  --split R             where the predicted controller's error\n"
      "                        comes from: each of its frames again on a\n"
      "                        runtime of its own at its density, then R\n"
      "                        (2..50) times more unchanged; the pass's\n"
      "                        error split into context, switching,\n"
      "                        model and noise (docs/pacing.md)\n"
      "  --no-noise            no still frame: by default, after each\n"
      "                        round of every controller's frame, a\n"
      "                        runtime of its own renders the first\n"
      "                        frame's camera at a fixed density (as\n"
      "                        long as the first target), to measure the\n"
      "                        machine's timing noise: the floor under\n"
      "                        every controller's error (two or more\n"
      "                        controllers, one device, in core)\n"
      "  --noise-csv FILE      the still frame's times, a row each\n"
      "  --csv FILE            per-frame rows of every controller\n"
      "  --trace FILE          what each controller's cost model learned "
      "from,\n"
      "                        a row per frame it learned from (one\n"
      "                        device): input to bench_costmodel\n"
      "  --plot FILE.png       frame times and densities against the "
      "target\n"
      "                        (gnuplot); with 2+ --devices also "
      "FILE-devices.png,\n"
      "                        per-device busy times and stacked shares\n"
      "  --json                one JSON summary object per controller, "
      "one\n"
      "                        per line\n"
      "  --budget-mb MB        device memory the volume may take, in\n"
      "                        [0.001, 1e9]; a larger"
      "\n"
      "                        volume is rendered out of core, from bricks\n"
      "  --brick-size N        out-of-core brick edge in voxels (8..256, a\n"
      "                        power of two; default 16)\n"
      "  --quiet               no per-controller progress on stderr\n"
      "  --list                name the built-in sequences and "
      "controllers\n");
}

/* The options' combinations; 0, or 2 (printed). */
static int check_opts(replay_opts *o) {
  if (o->target_ms > 0 && o->target_fraction > 0) {
    fprintf(stderr, "raypace replay: --target-ms and --target-fraction "
                    "exclude each other\n");
    return 2;
  }
  if (o->min_step > o->base_step) {
    char value[32];
    snprintf(value, sizeof value, "%g", (double)o->min_step);
    return cli_bad_option(CMD, "--min-step", value, "over the base step",
                          "must be at most --base-step (%g)",
                          (double)o->base_step);
  }
  if (o->noise_csv != NULL && (o->no_noise || o->devices_spec != NULL)) {
    fprintf(stderr, "raypace replay: --noise-csv needs the still frame, "
                    "which %s\n", o->no_noise ? "--no-noise turns off"
                                              : "a group does not render "
                                                "(not with --devices)");
    return 2;
  }
  if (o->split > 0 && (o->ndevices > 1 || o->mem.budget_bytes)) {
    fprintf(stderr, "raypace replay: --split renders on one device in "
                    "core (not with two or more --devices, nor with "
                    "--budget-mb)\n");
    return 2;
  }
  if (o->devices_spec != NULL && o->trace != NULL) {
    fprintf(stderr, "raypace replay: --trace records one device's cost "
                    "model; a group has one per device (not with "
                    "--devices)\n");
    return 2;
  }
  return 0;
}


/* The ranges of replay's numbers: the library's where it has one. */
static const cli_range target_range = {0.0, 60000.0, CLI_OPEN_LO, 0, "ms"};
static const cli_range fraction_range = {0.0, 100.0, CLI_OPEN_LO, 0,
                                         "times the frame without "
                                         "adaptation"};
static const cli_range step_range = {RP_STEP_MIN, RP_STEP_MAX, 0, 0,
                                     "voxels"};
static const cli_range headroom_range = {0.0, 0.9, CLI_OPEN_LO, 0,
                                         "of the target"};
static const cli_range miss_range = {0.0, 0.5, CLI_OPEN_LO, 0,
                                     "of the frames"};

/* --miss-rate: (0, 0.5] or "none"; 0 or 2 (printed). */
static int parse_miss_rate(const char *option, const char *arg,
                           replay_opts *o) {
  char want[96];
  double v = 0.0;
  const char *problem;
  /* "none" for the rule before the contract: aim at the target. */
  if (strcmp(arg, "none") == 0) {
    o->miss_rate = -1.0;
    return 0;
  }
  if ((problem = cli_number_problem(arg, &miss_range, &v)) == NULL) {
    o->miss_rate = v;
    return 0;
  }
  cli_range_text(&miss_range, want, sizeof want);
  return cli_bad_option(CMD, option, arg, problem, "must be %s, or none "
                        "to aim at the target itself", want);
}

/* A target: --target-ms or --target-fraction; 0 or 2 (printed). */
static int parse_target(const char *option, const char *arg,
                        const cli_range *r, double *out) {
  float v = 0.0f;
  int rc = cli_parse_float(CMD, option, arg, r, &v);
  *out = v;
  return rc;
}

/* The files replay writes, and the devices named; 0 or 2 (printed). */
static int check_files(replay_opts *o) {
  static const char *const png[] = {".png", NULL};
  if ((o->csv != NULL && cli_check_output(CMD, "--csv", o->csv, NULL)) ||
      (o->noise_csv != NULL &&
       cli_check_output(CMD, "--noise-csv", o->noise_csv, NULL)) ||
      (o->trace != NULL &&
       cli_check_output(CMD, "--trace", o->trace, NULL)) ||
      (o->plot != NULL && cli_check_output(CMD, "--plot", o->plot, png)))
    return 2;
  cli_device_opts d;
  CLI_DEVICE_OPTS_OF(o, &d);
  return cli_check_devices(CMD, &d);
}

static const struct option opts[] = {
    {"sequence", required_argument, 0, 'q'},
    {"controller", required_argument, 0, 'c'},
    {"target-ms", required_argument, 0, 't'},
    {"target-fraction", required_argument, 0, 'F'},
    {"space", required_argument, 0, 'p'},
    {"base-step", required_argument, 0, 'd'},
    {"min-step", required_argument, 0, 'm'},
    {"size", required_argument, 0, 's'},
    {"backend", required_argument, 0, 'B'},
    {"device", required_argument, 0, 'D'},
    {"devices", required_argument, 0, 'L'},
    {"settle", required_argument, 0, 'S'},
    {"frames", required_argument, 0, 'n'},
    {"seed", required_argument, 0, 'e'},
    {"miss-rate", required_argument, 0, 'R'},
    {"headroom", required_argument, 0, 'H'},
    {"split", required_argument, 0, 'X'},
    {"no-noise", no_argument, 0, 'N'},
    {"noise-csv", required_argument, 0, 'W'},
    {"csv", required_argument, 0, 'C'},
    {"trace", required_argument, 0, 'T'},
    {"plot", required_argument, 0, 'P'},
    {"json", no_argument, 0, 'j'},
    {"quiet", no_argument, 0, 'Q'},
    {"budget-mb", required_argument, 0, 'M'},
    {"brick-size", required_argument, 0, 'Z'},
    {"list", no_argument, 0, 'l'},
    {"help", no_argument, 0, 'h'},
    {0, 0, 0, 0}};

/* An option that takes a number or a name: checked into o; 0 or 2
 * (printed). */
static int parse_value(int c, const char *option, const char *arg,
                       replay_opts *o) {
  switch (c) {
  case 't': return parse_target(option, arg, &target_range, &o->target_ms);
  case 'F':
    return parse_target(option, arg, &fraction_range, &o->target_fraction);
  case 'p':
    return rp_space_from_name(arg, &o->space) != 0
               ? cli_bad_option(CMD, option, arg, "not a space",
                                "must be ray, image or hybrid")
               : 0;
  case 'd':
    return cli_parse_float(CMD, option, arg, &step_range, &o->base_step);
  case 'm':
    return cli_parse_float(CMD, option, arg, &step_range, &o->min_step);
  case 's': return cli_parse_size(CMD, option, arg, &o->width, &o->height);
  case 'S': return cli_parse_whole(CMD, option, arg, 0, 100000, &o->settle);
  /* 0 would read as "every frame": refused rather than surprising. */
  case 'n':
    return cli_parse_whole(CMD, option, arg, 1, 10000000, &o->frames);
  case 'e': return cli_parse_whole(CMD, option, arg, 0, UINT32_MAX, &o->seed);
  case 'R': return parse_miss_rate(option, arg, o);
  case 'H':
    return cli_parse_real(CMD, option, arg, &headroom_range, &o->headroom);
  case 'X':
    return cli_parse_whole(CMD, option, arg, 2, REPLAY_SPLIT_MAX, &o->split);
  default: {
    cli_device_opts d;
    CLI_DEVICE_OPTS_OF(o, &d);
    return cli_parse_device_option(CMD, c, option, arg, &d);
  }
  }
}

static int parse_opts(int argc, char **argv, replay_opts *o) {
  int c, li = 0;
  memset(o, 0, sizeof *o);
  o->sequence = "tf-switch";
  o->controller = "all";
  o->space = RP_SPACE_HYBRID;
  o->base_step = 1.0f;
  o->width = o->height = 384;
  o->settle = 10;
  o->seed = 1;
  /* 0, not 1: glibc's getopt then forgets a scan before this one (bench
   * pacing parses a replay's options once per run). */
  optind = 0;
  while ((c = getopt_long(argc, argv, "h", opts, &li)) != -1) {
    char option[40];
    switch (c) {
    case 'q': o->sequence = optarg; break;
    case 'c': o->controller = optarg; break;
    case 'N': o->no_noise = 1; break;
    case 'W': o->noise_csv = optarg; break;
    case 'C': o->csv = optarg; break;
    case 'T': o->trace = optarg; break;
    case 'P': o->plot = optarg; break;
    case 'j': o->json = 1; break;
    case 'Q': o->quiet = 1; break;
    case 'l': o->list = 1; break;
    case 'h': usage(stdout); return 1;
    case '?': usage(stderr); return 2;
    default:
      snprintf(option, sizeof option, "--%s", opts[li].name);
      if (parse_value(c, option, optarg, o) != 0)
        return 2;
    }
  }
  if (check_opts(o) != 0 || check_files(o) != 0)
    return 2;
  if (o->list)
    return optind == argc ? 0 : (usage(stderr), 2);
  if (optind + 1 != argc) {
    usage(stderr);
    return 2;
  }
  o->volume = argv[optind];
  return 0;
}

static int list_all(void) {
  const char *const *n;
  int k;
  printf("sequences:\n");
  for (n = rp_sequence_builtin_names(); *n != NULL; n++)
    printf("  %-14s %s\n", *n, rp_sequence_builtin_about(*n));
  printf("controllers:\n");
  for (k = 0; k < RP_CONTROL_COUNT; k++)
    printf("  %s\n", rp_controller_name((rp_controller_kind)k));
  printf("spaces:\n  ray\n  image\n  hybrid\n");
  return 0;
}


/* ---- Players: a runtime each --------------------------------------------- */

/* --trace: every frame the runtime's cost model learned from, from its
 * first (the warm-up's included: the model is the runtime's, which
 * learns from all of them). The columns are rp_cost_train's arguments
 * (the probe's fields that rp_cost_predict reads, step, scale, samples,
 * raycast and frame time), each double to 17 digits so that
 * bench_costmodel feeds a model exactly what this one learned from.
 * `frame` counts the settle frames; -1 before them (warm-up,
 * calibration). */
static const char trace_header[] =
    "controller,frame,width,height,effects,jitter,rays,rays_hit,rays_ended,"
    "depth_sum,depth_max,ert_cut,lit_span,lit_ends,view_x,view_y,view_z,"
    "pixels_per_voxel,diagonal,step,scale,samples,raycast_ms,frame_ms\n";

static void trace_row(replay *r, const player *p, const rp_frame *fr) {
  const rp_frame_probe *pr = fr->probe;
  const rp_frame_stats *st = fr->stats;
  fprintf(r->trace,
          "%s,%lld,%u,%u,%u,%u,%u,%u,%u,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,"
          "%.17g,%.17g,%.17g,%.17g,%.9g,%.9g,%llu,%.17g,%.17g\n",
          rp_controller_name(p->kind),
          p->tracing ? (long long)p->step_no : -1LL, pr->width, pr->height,
          pr->effects, pr->jitter, pr->rays, pr->rays_hit, pr->rays_ended,
          pr->depth_sum,
          pr->depth_max, pr->ert_cut, pr->lit_span, pr->lit_ends,
          pr->view[0], pr->view[1], pr->view[2], pr->pixels_per_voxel,
          pr->diagonal, (double)st->step, (double)st->scale,
          (unsigned long long)st->samples, st->raycast_ms, st->learn_ms);
}

/* The runtime's frame callback: keeps the stats; --trace writes what
 * the cost model will learn from the frame. */
static void on_frame(rp_runtime *rt, const rp_frame *fr, void *user) {
  player *p = user;
  (void)rt;
  p->st = *fr->stats;
  if (p->rows != NULL && p->r->trace != NULL && fr->probe != NULL &&
      isfinite(fr->stats->learn_ms))
    trace_row(p->r, p, fr);
}

/* Steps one frame; 1 (printed) when it failed. */
int replay_step(player *p, const char *what) {
  int err = rp_runtime_step(p->rt);
  if (err == 0)
    return 0;
  fprintf(stderr, "raypace: replay: %s (%s): %s: %s\n", what,
          rp_controller_name(p->kind), rp_strerror(err),
          p->st.status != 0 ? p->st.error : "the runtime refused the frame");
  return 1;
}

static int post_failed(const char *what, int err) {
  fprintf(stderr, "raypace: replay: %s: %s\n", what, rp_strerror(err));
  return 1;
}

/* Posts what frame `st` changes for p's runtime: its TF, camera,
 * effects and target, each only when it differs from what p's runtime
 * was last given (an app posts what changed). */
int replay_post_state(replay *r, player *p, const rp_sequence_state *st,
                      const rp_camera *cam, double target) {
  int err;
  if (st->tf != p->tf) {
    if ((err = rp_runtime_set_tf(p->rt, r->tfs[st->tf])) != 0)
      return post_failed("transfer function", err);
    p->tf = st->tf;
  }
  if (!p->have_cam || memcmp(cam, &p->cam, sizeof *cam) != 0) {
    if ((err = rp_runtime_set_camera(p->rt, cam)) != 0)
      return post_failed("camera", err);
    p->cam = *cam;
    p->have_cam = 1;
  }
  if (!p->have_effects || st->effects != p->effects) {
    if ((err = rp_runtime_set_effects(p->rt, st->effects)) != 0)
      return post_failed("effects", err);
    p->effects = st->effects;
    p->have_effects = 1;
  }
  if (target > 0.0 && target != p->target) {
    if ((err = rp_runtime_set_target(p->rt, target)) != 0)
      return post_failed("target", err);
    p->target = target;
  }
  return 0;
}

static double seq_target_ms(const replay *r, const rp_sequence_state *st) {
  return st->target_ms > 0 ? st->target_ms
                           : st->target_fraction * r->full_ms;
}

/* The target of a frame: the sequence's, rescaled so that its first
 * target becomes the command line's when one was given. */
double replay_frame_target(const replay *r, const rp_sequence_state *st) {
  double t = seq_target_ms(r, st);
  if (r->o.target_ms > 0)
    return r->o.target_ms * t / r->seq_target0;
  if (r->o.target_fraction > 0)
    return r->o.target_fraction * r->full_ms * t / r->seq_target0;
  return t;
}

/* Frame f's state and camera. */
int replay_sequence_frame(replay *r, uint32_t f, rp_sequence_state *st,
                          rp_camera *cam) {
  int err;
  if ((err = rp_sequence_frame(r->seq, f, st)) != 0)
    return cli_error(r->ctx, "sequence", err);
  rp_sequence_camera(st, r->vol, cam);
  return 0;
}

/* Steps until the runtime renders `effects` (its kernels built ahead,
 * its AO computed). */
static int warm_set(player *p, uint32_t effects) {
  double t0 = cli_now();
  uint32_t n;
  int err;
  if ((err = rp_runtime_set_effects(p->rt, effects)) != 0)
    return post_failed("effects", err);
  p->effects = effects;
  p->have_effects = 1;
  for (n = 0; n < WARM_MAX_FRAMES && cli_now() - t0 < WARM_MAX_S; n++) {
    if (replay_step(p, "warm-up") != 0)
      return 1;
    if (p->st.effects == effects)
      return 0;
  }
  fprintf(stderr, "raypace: replay: warm-up: effects 0x%x still not "
                  "rendered after %u frames (%.0f s)\n", effects, n,
          cli_now() - t0);
  return 1;
}

/* The warm-up (see the top of this file): every effect set the sequence
 * uses, the first frame's last, each with its AO-less variant first. */
static int warm(replay *r, player *p) {
  rp_sequence_state st, first;
  rp_camera cam;
  uint32_t sets[32], nsets = 0, i, k;
  if (replay_sequence_frame(r, 0, &first, &cam) != 0 ||
      replay_post_state(r, p, &first, &cam, 0.0) != 0)
    return 1;
  for (i = 1; i < r->frames; i++) {
    if (rp_sequence_frame(r->seq, i, &st) != 0)
      return cli_error(r->ctx, "sequence", RP_EINVAL);
    for (k = 0; k < nsets && sets[k] != st.effects; k++)
      ;
    if (k == nsets && st.effects != first.effects && nsets < 31)
      sets[nsets++] = st.effects;
  }
  sets[nsets++] = first.effects;
  for (k = 0; k < nsets; k++) {
    if ((sets[k] & RP_EFFECT_AO) &&
        warm_set(p, sets[k] & ~(uint32_t)RP_EFFECT_AO) != 0)
      return 1;
    if (warm_set(p, sets[k]) != 0)
      return 1;
  }
  return 0;
}

/* A runtime for p's controller, warmed up, with a volume of its own.
 * RP_ENODEV comes back unprinted when the device cannot be had, so that
 * the caller can fall back; any other failure is printed and 1. */
int replay_player_open(replay *r, player *p, int quiet_nodev) {
  rp_runtime_desc d;
  rp_volume *vol = NULL;
  int err;
  memset(&d, 0, sizeof d);
  p->r = r;
  p->tf = -1;
  p->have_cam = p->have_effects = 0;
  p->target = 0.0;
  d.pacing = RP_PACE_MANUAL;
  d.on_frame = on_frame;
  d.user = p;
  d.controller = RP_CONTROL_NONE;
  d.target_ms = WARM_TARGET_MS;
  d.width = r->o.width;
  d.height = r->o.height;
  d.space = r->space;
  d.ert_seed = r->o.seed;
  /* Jittered, with one seed for every frame: a frame replayed (--split)
   * then takes the samples it took the first time. */
  d.jitter = RP_JITTER_FIXED;
  d.miss_rate = r->o.miss_rate;
  d.headroom = r->o.headroom;
  if (r->o.ndevices > 0) {
    d.devices = r->o.devices;
    d.device_count = r->o.ndevices;
  } else {
    d.device.backend = r->backend;
    d.device.index = r->o.device;
    d.device.budget_bytes = r->o.mem.budget_bytes;
    d.device.brick_size = r->o.mem.brick_size;
  }
  err = rp_runtime_create(r->ctx, &d, &p->rt);
  if (err == RP_ENODEV && r->backend == NULL && r->o.ndevices == 0 &&
      r->o.device == 0) {
    /* As cli_open_device: a slow image rather than none. */
    fprintf(stderr, "raypace: %s; using the reference\n",
            rp_last_error(r->ctx));
    r->backend = d.device.backend = "reference";
    d.device.budget_bytes = 0; /* the reference holds the whole volume */
    err = rp_runtime_create(r->ctx, &d, &p->rt);
  }
  if (err != 0)
    return quiet_nodev ? err : cli_error(r->ctx, "runtime", err);
  if (cli_open_volume(r->ctx, r->o.volume, &vol) != 0)
    return 1;
  if ((err = rp_runtime_set_volume(p->rt, vol)) != 0) {
    rp_volume_destroy(vol);
    return post_failed("volume", err);
  }
  return warm(r, p);
}

void replay_player_close(player *p) {
  rp_runtime_destroy(p->rt);
  p->rt = NULL;
}

/* The frame without adaptation: the median of CALIBRATE_FRAMES frames
 * of the first state at density 1, on a warm runtime still under the
 * controller none. */
static int calibrate(replay *r, player *p) {
  rp_sequence_state st;
  rp_camera cam;
  double t[CALIBRATE_FRAMES];
  int i;
  if (replay_sequence_frame(r, 0, &st, &cam) != 0)
    return 1;
  for (i = 0; i < CALIBRATE_FRAMES; i++) {
    if (replay_step(p, "calibration") != 0)
      return 1;
    t[i] = p->st.measured_ms;
  }
  r->full_ms = cli_median(t, CALIBRATE_FRAMES);
  r->seq_target0 = seq_target_ms(r, &st);
  if (!(r->seq_target0 > 0)) {
    fprintf(stderr, "raypace replay: the sequence's first target is not "
                    "positive\n");
    return 1;
  }
  return 0;
}

/* The first frame's target and p's controller: p's runtime is ready to
 * play the settle frames. */
static int player_start(replay *r, player *p) {
  rp_sequence_state st;
  rp_camera cam;
  int err;
  if (replay_sequence_frame(r, 0, &st, &cam) != 0 ||
      replay_post_state(r, p, &st, &cam, replay_frame_target(r, &st)) != 0)
    return 1;
  if ((err = rp_runtime_set_controller(p->rt, p->kind)) != 0)
    return post_failed("controller", err);
  p->tracing = 1;
  p->step_no = 0;
  return 0;
}

/* The recorded row of frame f from the runtime's stats. */
static void fill_row(const replay *r, const player *p, uint32_t f,
                     uint32_t events, frame_row *row) {
  const rp_frame_stats *st = &p->st;
  uint32_t i;
  row->frame = f;
  row->events = events;
  row->passes = (int)st->passes;
  row->target_ms = st->target_ms;
  row->measured_ms = st->measured_ms;
  row->predicted_ms = st->predicted_ms;
  row->pass_predicted_ms = st->pass_predicted_ms;
  row->render_ms = st->render_ms;
  row->effects = st->effects;
  row->margin = st->margin;
  row->novelty = st->novelty;
  row->split_first_ms = row->split_ms = row->split_sd_ms = NAN;
  row->probe_ms = st->probe_ms + st->predict_ms;
  row->ao_ms = st->ao_ms;
  row->ao = (st->effects & RP_EFFECT_AO) != 0;
  row->upload_ms = st->upload_ms;
  row->upload_pred_ms = st->upload_predicted_ms;
  row->rho = st->rho;
  row->step = st->step;
  row->scale = st->scale;
  row->samples_est = st->samples_predicted;
  row->samples = st->samples;
  row->sigma_pred_ns = st->sigma_predicted_ns;
  row->sigma_ns = st->samples > 0 && st->raycast_ms > 0 &&
                          isfinite(st->fetches) && st->fetches > 0
                      ? st->raycast_ms * 1e6 /
                            (st->fetches * (double)st->samples)
                      : NAN;
  row->imbalance = st->imbalance;
  for (i = 0; i < r->o.ndevices && i < st->device_count; i++) {
    row->dev[i].share = st->devices[i].share;
    row->dev[i].busy_ms = st->devices[i].busy_ms;
    row->dev[i].raycast_ms = st->devices[i].raycast_ms;
    row->dev[i].samples = st->devices[i].samples;
    row->dev[i].strip_share = st->devices[i].strip_share;
  }
}

/* Frame i of the settle frames and the sequence after them, for p. */
static int play_frame(replay *r, player *p, uint32_t i) {
  uint32_t f = i < r->o.settle ? 0 : i - r->o.settle;
  rp_sequence_state st;
  rp_camera cam;
  if (replay_sequence_frame(r, f, &st, &cam) != 0 ||
      replay_post_state(r, p, &st, &cam, replay_frame_target(r, &st)) != 0 ||
      replay_step(p, "frame") != 0)
    return 1;
  p->step_no++;
  if (p->st.devices_lost > 0 && !r->o.quiet)
    fprintf(stderr, "replay: %u device(s) lost, %u left\n",
            p->st.devices_lost, p->st.devices_alive);
  p->devices_alive = p->st.devices_alive;
  if (i >= r->o.settle)
    fill_row(r, p, f, replay_frame_events(&st), &p->rows[f]);
  if (r->split.rt != NULL && p->kind == RP_CONTROL_PREDICTED &&
      replay_split_frame(r, p, f, i >= r->o.settle ? &p->rows[f] : NULL) !=
          0)
    return 1;
  return 0;
}

/* ---- The still frame ----------------------------------------------------- */

/* The still runtime, warm: aims at the first target by last-frame's
 * rule, then holds that density under the controller none. */
static int still_open(replay *r, player *s) {
  rp_sequence_state st;
  int i, err;
  r->still_ms = malloc(r->frames * sizeof *r->still_ms);
  r->still_seg = malloc(r->frames * sizeof *r->still_seg);
  if (r->still_ms == NULL || r->still_seg == NULL)
    return cli_error(r->ctx, "still frame", RP_ENOMEM);
  s->kind = RP_CONTROL_NONE;
  if (replay_player_open(r, s, 0) != 0)
    return 1;
  if (replay_sequence_frame(r, 0, &st, &r->still_cam) != 0 ||
      replay_post_state(r, s, &st, &r->still_cam, replay_frame_target(r, &st)) != 0)
    return 1;
  if ((err = rp_runtime_set_controller(s->rt, RP_CONTROL_LAST_FRAME)) != 0)
    return post_failed("controller", err);
  for (i = 0; i < STILL_AIM_FRAMES; i++)
    if (replay_step(s, "still frame") != 0)
      return 1;
  r->noise.rho = s->st.rho;
  if ((err = rp_runtime_set_density(s->rt, r->noise.rho)) != 0 ||
      (err = rp_runtime_set_controller(s->rt, RP_CONTROL_NONE)) != 0)
    return post_failed("still frame", err);
  return 0;
}

/* The still frame after round f: the first frame's camera with frame f's
 * TF and effects. A new TF or effect set starts a segment. Its time is
 * the render passes' (the TF upload a new segment's first frame pays is
 * no part of the noise). */
static int still_frame(replay *r, player *s, uint32_t f) {
  rp_sequence_state st;
  rp_camera cam;
  if (replay_sequence_frame(r, f, &st, &cam) != 0 ||
      replay_post_state(r, s, &st, &r->still_cam, 0.0) != 0 ||
      replay_step(s, "still frame") != 0)
    return 1;
  r->still_seg[f] = f == 0 ? 0
                    : r->still_seg[f - 1] +
                          (st.tf != r->still_tf ||
                           s->st.effects != r->still_effects);
  r->still_tf = st.tf;
  r->still_effects = s->st.effects;
  r->still_ms[f] = s->st.render_ms > 0 ? s->st.render_ms : 1e-6;
  return 0;
}

/* ---- Playing ------------------------------------------------------------- */

/* Every controller frame by frame in turn (see the top of the file);
 * ps[0] is open and calibrated. 0, 1 on failure (printed), or -1 when a
 * runtime for a second controller could not be made: then every player
 * but ps[0] is closed again and the caller plays them in turn. */
static int play_in_turn(replay *r, player *ps, int n) {
  uint32_t total = r->o.settle + r->frames, i;
  player still;
  int k, rc = 1, err;
  memset(&still, 0, sizeof still);
  for (k = 1; k < n; k++) {
    if ((err = replay_player_open(r, &ps[k], 1)) == RP_ENODEV ||
        (err != 0 && ps[k].rt == NULL)) {
      if (!r->o.quiet)
        fprintf(stderr, "replay: no device for each controller (%s): "
                        "each plays the whole sequence in turn\n",
                rp_last_error(r->ctx));
      while (k > 0)
        replay_player_close(&ps[k--]);
      return -1;
    }
    if (err != 0)
      goto out;
  }
  if (!r->o.no_noise && n > 1 && still_open(r, &still) != 0)
    goto out;
  if (!r->o.quiet && n > 1)
    fprintf(stderr, "replay: %d controllers, frame by frame in turn, a "
                    "runtime each\n", n);
  for (k = 0; k < n; k++)
    if (player_start(r, &ps[k]) != 0)
      goto out;
  for (i = 0; i < total; i++) {
    for (k = 0; k < n; k++)
      if (play_frame(r, &ps[(i + (uint32_t)k) % (uint32_t)n], i) != 0)
        goto out;
    if (still.rt != NULL && i >= r->o.settle &&
        still_frame(r, &still, i - r->o.settle) != 0)
      goto out;
  }
  if (still.rt != NULL) {
    double *work = malloc(r->frames * sizeof *work);
    if (work == NULL) {
      cli_error(r->ctx, "still frame", RP_ENOMEM);
      goto out;
    }
    replay_noise_stats(r->still_ms, r->still_seg, r->frames, work,
                       &r->noise);
    free(work);
  } else {
    free(r->still_ms);
    free(r->still_seg);
    r->still_ms = NULL;
    r->still_seg = NULL;
  }
  rc = 0;
out:
  replay_player_close(&still);
  return rc;
}

/* Each controller plays the whole sequence on a runtime made afresh;
 * ps[0] is open and calibrated. */
static int play_one_by_one(replay *r, player *ps, int n) {
  uint32_t total = r->o.settle + r->frames, i;
  int k;
  for (k = 0; k < n; k++) {
    if (!r->o.quiet && n > 1)
      fprintf(stderr, "replay: %s ...\n", rp_controller_name(ps[k].kind));
    if (ps[k].rt == NULL && replay_player_open(r, &ps[k], 0) != 0)
      return 1;
    if (player_start(r, &ps[k]) != 0)
      return 1;
    for (i = 0; i < total; i++)
      if (play_frame(r, &ps[k], i) != 0)
        return 1;
    replay_player_close(&ps[k]);
  }
  return 0;
}

/* Plays the sequence under every controller of `ps`. */
static int play(replay *r, player *ps, int n) {
  int in_turn = n > 1 && r->o.ndevices == 0 && r->o.mem.budget_bytes == 0;
  int rc = 1, k;
  if (replay_player_open(r, &ps[0], 0) != 0 || calibrate(r, &ps[0]) != 0 ||
      (r->o.split > 0 && replay_split_open(r) != 0))
    goto out;
  if (in_turn && (rc = play_in_turn(r, ps, n)) >= 0)
    goto out;
  rc = play_one_by_one(r, ps, n);
out:
  replay_split_close(r);
  for (k = 0; k < n; k++) {
    if (ps[k].st.device_count > 0) {
      uint32_t i;
      for (i = 0; i < ps[k].st.device_count && i < RP_GROUP_MAX_DEVICES;
           i++)
        snprintf(r->device_names[i], sizeof r->device_names[i], "%s",
                 ps[k].st.devices[i].name);
    }
    replay_player_close(&ps[k]);
  }
  return rc;
}

/* ---- The command --------------------------------------------------------- */

static int open_scene(replay *r) {
  int err, i;
  if ((err = rp_context_create(NULL, &r->ctx)) != 0)
    return cli_error(NULL, "context", err);
  if ((err = rp_sequence_load(r->ctx, r->o.sequence, &r->seq)) != 0)
    return cli_error(r->ctx, "--sequence", err);
  r->frames = rp_sequence_frames(r->seq);
  if (r->o.frames > 0 && r->o.frames < r->frames)
    r->frames = r->o.frames;
  /* The finest step any controller may render at. */
  if (cli_open_volume(r->ctx, r->o.volume, &r->vol) != 0 ||
      cli_check_work(CMD, r->o.min_step > 0 ? "--min-step" : "--base-step",
                     r->vol, r->o.min_step > 0 ? r->o.min_step
                                               : r->o.base_step,
                     r->o.width, r->o.height, 1.0f) != 0)
    return 1;
  r->tf_count = rp_sequence_tf_count(r->seq);
  r->tfs = calloc((size_t)r->tf_count, sizeof(*r->tfs));
  if (r->tfs == NULL)
    return cli_error(r->ctx, "transfer functions", RP_ENOMEM);
  for (i = 0; i < r->tf_count; i++)
    if ((err = rp_sequence_tf_create(r->ctx, r->seq, i, &r->tfs[i])) != 0)
      return cli_error(r->ctx, "transfer function", err);
  r->space.space = r->o.space;
  r->space.base_step = r->o.base_step;
  r->space.min_step = r->o.min_step; /* 0, or over base_step: base_step */
  r->backend = r->o.backend;
  return 0;
}

static void close_scene(replay *r) {
  int i;
  free(r->still_ms);
  free(r->still_seg);
  for (i = 0; r->tfs != NULL && i < r->tf_count; i++)
    rp_tf_destroy(r->tfs[i]);
  free(r->tfs);
  rp_volume_destroy(r->vol);
  rp_sequence_destroy(r->seq);
  rp_context_destroy(r->ctx);
}

/* The controllers --controller names ("all", or names joined by
 * commas, each at most once, played in that order), into kinds; 0 or 2
 * (printed). */
static int controllers_of(const char *name, rp_controller_kind *kinds,
                          int *n) {
  const char *p = name;
  int k;
  *n = 0;
  if (strcmp(name, "all") == 0) {
    for (k = 0; k < RP_CONTROL_COUNT; k++)
      kinds[(*n)++] = (rp_controller_kind)k;
    return 0;
  }
  for (;;) {
    size_t len = strcspn(p, ",");
    char one[32];
    int seen = 0;
    if (len == 0 || len >= sizeof one) {
      fprintf(stderr, "raypace replay: --controller '%s': %s\n", name,
              len == 0 ? "an empty name" : "a name too long");
      return 2;
    }
    memcpy(one, p, len);
    one[len] = '\0';
    if (rp_controller_from_name(one, &kinds[*n]) != 0) {
      fprintf(stderr, "raypace replay: unknown controller '%s' (see "
                      "--list)\n", one);
      return 2;
    }
    for (k = 0; k < *n; k++)
      seen |= kinds[k] == kinds[*n];
    if (seen) {
      fprintf(stderr, "raypace replay: --controller '%s' names '%s' "
                      "twice\n", name, one);
      return 2;
    }
    (*n)++;
    if (p[len] == '\0')
      return 0;
    p += len + 1;
  }
}

/* One controller's figures for cli_replay_points. */
static void point_of(const summary *s, cli_replay_point *pt) {
  pt->kind = s->kind;
  pt->frames = s->frames;
  pt->miss_rate = s->miss_rate;
  pt->share_over_1_2 = s->share_over_20;
  pt->mean_density = s->mean_density;
}

/* Where replay_main's results go instead of the report: goals, points
 * (RP_CONTROL_COUNT of them, *npoints set), or neither (the report). */
typedef struct replay_sink {
  cli_pacing_goals *goals;
  cli_replay_point *points;
  int *npoints;
} replay_sink;

/* The command; with a sink, the goals or the points of one run instead
 * of any output (cli_replay_goals, cli_replay_points). */
static int replay_main(int argc, char **argv, const replay_sink *sink) {
  replay r;
  replay_result res;
  rp_controller_kind kinds[RP_CONTROL_COUNT];
  frame_row *rows[RP_CONTROL_COUNT] = {0};
  player players[RP_CONTROL_COUNT];
  summary sums[RP_CONTROL_COUNT];
  int nctl = 0, k, rc;
  memset(&r, 0, sizeof(r));
  memset(players, 0, sizeof(players));
  if (sink->goals != NULL)
    replay_goals_clear(sink->goals);
  if (sink->npoints != NULL)
    *sink->npoints = 0;
  if ((rc = parse_opts(argc, argv, &r.o)) != 0)
    return rc == 1 ? 0 : rc;
  if (r.o.list)
    return list_all();
  if ((rc = controllers_of(r.o.controller, kinds, &nctl)) != 0)
    return rc;
  for (k = 0; k < nctl && kinds[k] != RP_CONTROL_PREDICTED; k++)
    ;
  if (r.o.split > 0 && k == nctl) {
    fprintf(stderr, "raypace replay: --split splits the predicted "
                    "controller's error: --controller %s does not play "
                    "it\n", r.o.controller);
    return 2;
  }
  if (r.o.plot != NULL && !cli_have_gnuplot()) {
    fprintf(stderr, "raypace replay: --plot needs gnuplot (Debian "
                    "gnuplot-nox)\n");
    return 1;
  }
  if (r.o.trace != NULL) {
    if ((r.trace = fopen(r.o.trace, "w")) == NULL) {
      fprintf(stderr, "raypace replay: --trace %s: cannot open for "
                      "writing\n", r.o.trace);
      return 1;
    }
    fputs(trace_header, r.trace);
  }
  rc = 1;
  /* A loaded sequence has at least one frame; said here for readers and
   * the analyzer alike. */
  if (open_scene(&r) != 0 || r.frames == 0)
    goto out;
  for (k = 0; k < nctl; k++) {
    rows[k] = calloc(r.frames, sizeof(frame_row));
    if (rows[k] == NULL) {
      cli_error(r.ctx, "rows", RP_ENOMEM);
      goto out;
    }
    players[k].kind = kinds[k];
    players[k].rows = rows[k];
  }
  if (play(&r, players, nctl) != 0)
    goto out;
  for (k = 0; k < nctl; k++) {
    if (replay_summarise(kinds[k], rows[k], r.frames,
                         rp_space_max_density(&r.space), &sums[k]) != 0) {
      cli_error(r.ctx, "summary", RP_ENOMEM);
      goto out;
    }
    sums[k].devices_alive = players[k].devices_alive;
    if (r.o.split > 0 && kinds[k] == RP_CONTROL_PREDICTED)
      replay_split_summarise(rows[k], r.frames, r.o.split, &sums[k].split);
  }
  memset(&res, 0, sizeof res);
  res.o = &r.o;
  res.seq = r.seq;
  res.frames = r.frames;
  res.space = r.space;
  res.full_ms = r.full_ms;
  res.noise = r.noise;
  memcpy(res.device_names, r.device_names, sizeof res.device_names);
  res.still_ms = r.still_ms;
  res.still_seg = r.still_seg;
  if (sink->goals != NULL)
    replay_goals(&res, sums, nctl, sink->goals);
  if (sink->points != NULL && sink->npoints != NULL) {
    for (k = 0; k < nctl; k++)
      point_of(&sums[k], &sink->points[k]);
    *sink->npoints = nctl;
  }
  if (sink->goals == NULL && sink->points == NULL &&
      replay_report(&res, sums, rows, nctl) != 0)
    goto out;
  rc = 0;
out:
  for (k = 0; k < nctl; k++)
    free(rows[k]);
  close_scene(&r);
  if (r.trace != NULL && (ferror(r.trace) | fclose(r.trace)) != 0 &&
      rc == 0) {
    fprintf(stderr, "raypace replay: --trace %s: write failed\n",
            r.o.trace);
    rc = 1;
  }
  return rc;
}

int cli_cmd_replay(int argc, char **argv) {
  const replay_sink none = {NULL, NULL, NULL};
  return replay_main(argc, argv, &none);
}

int cli_replay_check(const char *cmd, int argc, char **argv) {
  replay_opts o;
  int rc;
  cmd_name = cmd;
  rc = parse_opts(argc, argv, &o);
  cmd_name = "replay";
  return rc == 1 ? 0 : rc;
}

int cli_replay_goals(int argc, char **argv, cli_pacing_goals *goals) {
  const replay_sink sink = {goals, NULL, NULL};
  return replay_main(argc, argv, &sink);
}

int cli_replay_points(int argc, char **argv, cli_replay_point *points,
                      int *n) {
  const replay_sink sink = {NULL, points, n};
  return replay_main(argc, argv, &sink);
}
