/* raypace replay: plays an interaction sequence under each frame-time
 * controller and reports how well each held the target (DESIGN section
 * 10): per-frame CSV, a plot of frame times against the target (seed 000
 * Fig. 5), and one summary per controller.
 *
 * Every controller sees the same frames: the same sequence, device, cost
 * model settings and target. Before recording, each plays `--settle`
 * frames of the sequence's first state (every controller's first frame
 * is blind; what is compared is how they hold the target afterwards).
 * On one device they play frame by frame in turn, so that the machine's
 * noise falls on all of them alike (play()).
 * The cost model is trained for every controller, so prediction error is
 * reported for all; only "predicted" acts on it.
 *
 * After each such round a still frame renders too: the first frame's
 * camera at one density, with the round's TF and effects. Its times
 * carry the machine's noise over the same minutes as the controllers'
 * frames, and say how close to the target a perfect model could come
 * (noise_floor, "timing noise" in the table).
 *
 * Frame time is the wall time of the frame's render passes (device
 * render with readback, plus the upscale when the image scale is below
 * 1). The probe (depth pass + ERT pre-pass on the host) and the
 * prediction run before the frame and are reported apart as overhead.
 *
 * With --devices every frame renders through a device group instead
 * (DESIGN section 7): the probe's tile costs guide the split, the
 * group's per-device models predict (rp_device_group_predict) and learn
 * (rp_device_group_train) in place of the single cost model, and the
 * rows gain each device's share, times and samples and the frame's
 * imbalance. Each controller gets a group of its own, opened and warmed
 * like the first, so that none inherits what another's frames taught
 * the devices' models. */
#include <cjson/cJSON.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli_util.h"
#include "raypace_ao.h"
#include "commands.h"
#include "raypace.h"
#include "raypace_group.h"
#include "raypace_pace.h"
#include "raypace_sequence.h"

/* The still frame (play(), still_frame()): frames spent finding the
 * density whose frame takes the first target, and the smoothing factors
 * of the EWMA predictors tried on its times. */
#define STILL_AIM_FRAMES 4
#define NOISE_EWMAS 4
static const double NOISE_ALPHAS[NOISE_EWMAS] = {0.1, 0.2, 0.3, 0.5};

typedef struct replay_opts {
  const char *volume, *sequence, *controller, *backend, *csv, *plot;
  const char *trace, *noise_csv;
  double target_ms, target_fraction;
  uint32_t device, width, height, settle, frames, seed;
  int no_noise; /* --no-noise: no still frame */
  float base_step;
  float min_step; /* 0: base_step */
  rp_space space;
  int json, list, quiet;
  int device_given;
  const char *devices_spec;
  rp_device_desc devices[RP_GROUP_MAX_DEVICES];
  cli_device_ext device_ext[RP_GROUP_MAX_DEVICES]; /* devices[i].next */
  uint32_t ndevices; /* 0: one device, no group */
  cli_memory mem;
} replay_opts;

/* One device's part of a frame's last pass (--devices). */
typedef struct device_row {
  double share, busy_ms, raycast_ms;
  uint64_t samples;
  double strip_share; /* the tail strips it took (rp_group_desc) */
} device_row;

/* One recorded frame of one controller. */
typedef struct frame_row {
  uint32_t frame;
  int passes, tf_changed;
  double target_ms, measured_ms, predicted_ms, probe_ms;
  double last_pass_ms; /* the pass the prediction is for */
  double ao_ms;        /* AO computed this frame (in measured_ms) */
  int ao;              /* rendered with AO */
  double upload_ms, upload_pred_ms; /* out of core: bricks uploaded in
                          the last pass (in its time), and predicted */
  double rho;
  float step, scale;
  double samples_est;
  uint64_t samples;
  double sigma_pred_ns, sigma_ns;
  double imbalance; /* --devices: the last pass's */
  device_row dev[RP_GROUP_MAX_DEVICES];
} frame_row;

/* The machine's timing noise, from the still frame's times (natural
 * logs), within each stretch of frames that rendered the same TF and
 * effects (a segment): about what a controller's error cannot go
 * under, whatever its model. */
typedef struct noise_floor {
  uint32_t frames; /* 0: not measured */
  uint32_t segments;
  double rho, median_ms;
  double sd;       /* against the segment's median: a model that knew
                      each frame's cost exactly (an oracle) */
  double sd_last;  /* against the frame before: last-frame's rule */
  double sd_best;  /* the least of sd, sd_last and the EWMAs of
                      NOISE_ALPHAS: the best of these predictors */
  double max_over; /* slowest frame / its segment's median - 1 */
} noise_floor;

typedef struct summary {
  rp_controller_kind kind;
  uint32_t frames;
  double rmse_ms, rmse_rel, max_over, share_over_20, mean_density;
  double rmse_open_ms; /* over frames where the target was reachable */
  double switch_over;  /* max overshoot on a TF switch and SWITCH_AFTER
                          frames after it; 0 without switches */
  double pred_rmse_ms, sigma_err_30, overhead_ms, mean_ms, mean_target;
  double mean_imbalance; /* --devices */
  uint32_t devices_alive; /* --devices: at the end of the run */
} summary;

/* What the device played on holds for the frames played on it: the
 * device (NULL with a group), the TF on it, its AO, and AO as the runtime
 * does it: computed in steps over frames for the active TF, frames
 * rendering without AO until it is ready. A controller with a device of
 * its own keeps its slot in its player (play()). */
typedef struct device_slot {
  rp_device *dev;
  rp_ao_plan *ao_plan;
  rp_ao_run *ao_run;
  int tf_active; /* the TF the device(s) hold */
  int ao_tf;     /* the TF whose AO the devices hold; -1: none */
  int run_tf;    /* the TF ao_run computes for */
} device_slot;

typedef struct replay {
  replay_opts o;
  rp_context *ctx;
  rp_volume *vol;
  rp_histograms *h;
  rp_occupancy *occ;
  rp_tf **tfs;
  int tf_count;
  int occ_tf; /* the TF occ is built for */
  device_slot on;
  rp_device_group *group; /* --devices, instead of on.dev */
  int group_used;         /* its models have learned from a controller */
  rp_group_report rep;    /* the last group pass's */
  rp_sequence *seq;
  uint32_t frames;
  rp_space_desc space;
  uint8_t *scaled, *image;
  rp_tile_stats *tiles;
  double full_ms;     /* frame time without adaptation, at the start */
  double seq_target0; /* the sequence's first target, ms */
  /* The still frame, rendered after each round of the controllers'
   * frames: the first frame's camera at a fixed density, with the
   * round's TF and effects. */
  rp_camera still_cam;
  double *still_ms;    /* per recorded frame */
  uint32_t *still_seg; /* its segment */
  uint32_t still_tf, still_effects;
  noise_floor noise;
  FILE *trace; /* --trace */
} replay;

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
      "                        ue5, valve, or all (default all)\n"
      "  --target-ms T         frame-time target in ms; the sequence's "
      "own\n"
      "                        target changes scale with it\n"
      "  --target-fraction F   target as a fraction of the frame time "
      "without\n"
      "                        adaptation, measured at the start\n"
      "                        (default: the sequence's target)\n"
      "  --space S             ray, image or hybrid (default hybrid)\n"
      "  --base-step D         step at density 1, voxels (default 1)\n"
      "  --min-step D          finest step, voxels: a step under the base\n"
      "                        step (density above 1) where the budget\n"
      "                        allows; image space stops at 1 (default:\n"
      "                        the base step)\n"
      "  --size WxH            output size (default 384x384)\n"
      "  --backend NAME        opencl, vulkan, reference, test or mpi\n"
      "  --device N            device index within the backend\n"
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
      "  --settle N            unrecorded frames before the sequence "
      "(default 10)\n"
      "  --frames N            play only the first N frames\n"
      "  --seed N              ERT pre-pass seed (default 1)\n"
      "  --no-noise            no still frame: by default, after each\n"
      "                        frame of every controller, the first\n"
      "                        frame's camera renders at a fixed density\n"
      "                        (as long as the first target), to measure\n"
      "                        the machine's timing noise: the floor under\n"
      "                        every controller's error (two or more\n"
      "                        controllers, one device, in core)\n"
      "  --noise-csv FILE      the still frame's times, a row each\n"
      "  --csv FILE            per-frame rows of every controller\n"
      "  --trace FILE          what each controller's cost model learned "
      "from,\n"
      "                        a row per pass (one device): input to\n"
      "                        bench_costmodel\n"
      "  --plot FILE.png       frame times and densities against the "
      "target\n"
      "                        (gnuplot); with 2+ --devices also "
      "FILE-devices.png,\n"
      "                        per-device busy times and stacked shares\n"
      "  --json                one JSON summary object per controller, "
      "one\n"
      "                        per line\n"
      "  --budget-mb MB        device memory the volume may take; a larger"
      "\n"
      "                        volume is rendered out of core, from bricks\n"
      "  --brick-size N        out-of-core brick edge in voxels (8..256, a\n"
      "                        power of two; default 16)\n"
      "  --quiet               no per-controller progress on stderr\n"
      "  --list                name the built-in sequences and "
      "controllers\n");
}

static int parse_opts(int argc, char **argv, replay_opts *o) {
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
    int bad = 0;
    float v = 0.0f;
    switch (c) {
    case 'q': o->sequence = optarg; break;
    case 'c': o->controller = optarg; break;
    case 't':
      bad = cli_parse_positive(optarg, &v);
      o->target_ms = v;
      break;
    case 'F':
      bad = cli_parse_positive(optarg, &v) || v > 100.0f;
      o->target_fraction = v;
      break;
    case 'p': bad = rp_space_from_name(optarg, &o->space) != 0; break;
    case 'd': bad = cli_parse_positive(optarg, &o->base_step); break;
    case 'm': bad = cli_parse_positive(optarg, &o->min_step); break;
    case 's': bad = cli_parse_size(optarg, &o->width, &o->height); break;
    case 'B':
      o->backend = optarg;
      o->device_given = 1;
      break;
    case 'D':
      bad = cli_parse_u32(optarg, 1024, &o->device);
      o->device_given = 1;
      break;
    case 'L':
      /* The parser names the bad part itself. */
      if (cli_parse_devices("--devices", optarg, o->devices, o->device_ext,
                            RP_GROUP_MAX_DEVICES, &o->ndevices) != 0)
        return 2;
      o->devices_spec = optarg;
      break;
    case 'S': bad = cli_parse_u32(optarg, 100000, &o->settle); break;
    case 'n': bad = cli_parse_u32(optarg, 10000000, &o->frames); break;
    case 'e': bad = cli_parse_u32(optarg, UINT32_MAX, &o->seed); break;
    case 'N': o->no_noise = 1; break;
    case 'W': o->noise_csv = optarg; break;
    case 'C': o->csv = optarg; break;
    case 'T': o->trace = optarg; break;
    case 'P': o->plot = optarg; break;
    case 'j': o->json = 1; break;
    case 'Q': o->quiet = 1; break;
    case 'M': bad = cli_parse_budget_mb(optarg, &o->mem.budget_bytes); break;
    case 'Z': bad = cli_parse_u32(optarg, 256, &o->mem.brick_size); break;
    case 'l': o->list = 1; break;
    case 'h': usage(stdout); return 1;
    default: usage(stderr); return 2;
    }
    if (bad) {
      fprintf(stderr, "raypace replay: bad value '%s' for --%s\n", optarg,
              opts[li].name);
      return 2;
    }
  }
  if (o->target_ms > 0 && o->target_fraction > 0) {
    fprintf(stderr, "raypace replay: --target-ms and --target-fraction "
                    "exclude each other\n");
    return 2;
  }
  if (o->min_step > o->base_step) {
    fprintf(stderr, "raypace replay: --min-step %g is over the base step "
                    "%g\n", (double)o->min_step, (double)o->base_step);
    return 2;
  }
  if (o->devices_spec != NULL && o->device_given) {
    fprintf(stderr, "raypace replay: --devices excludes --backend and "
                    "--device\n");
    return 2;
  }
  if (o->noise_csv != NULL && (o->no_noise || o->devices_spec != NULL)) {
    fprintf(stderr, "raypace replay: --noise-csv needs the still frame, "
                    "which %s\n", o->no_noise ? "--no-noise turns off"
                                              : "a group does not render "
                                                "(not with --devices)");
    return 2;
  }
  if (o->devices_spec != NULL && o->trace != NULL) {
    fprintf(stderr, "raypace replay: --trace records one device's cost "
                    "model; a group has one per device (not with "
                    "--devices)\n");
    return 2;
  }
  for (c = 0; c < (int)o->ndevices; c++) {
    o->devices[c].budget_bytes = o->mem.budget_bytes;
    o->devices[c].brick_size = o->mem.brick_size;
  }
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
    printf("  %-12s %s\n", *n, rp_sequence_builtin_about(*n));
  printf("controllers:\n");
  for (k = 0; k < RP_CONTROL_COUNT; k++)
    printf("  %s\n", rp_controller_name((rp_controller_kind)k));
  printf("spaces:\n  ray\n  image\n  hybrid\n");
  return 0;
}

/* ---- Rendering ----------------------------------------------------------- */

typedef struct pass_result {
  double ms, raycast_ms;
  double upload_ms; /* out of core: brick uploads (in ms, not raycast_ms) */
  uint64_t samples;
  float step, scale;
} pass_result;

/* A group's raycast time for the frame, as one device's would be: the
 * fastest device's rate (its raycast time over its samples) times the
 * frame's samples. With the fastest device's predicted sigma
 * (rp_device_group_predict) it gives the rows' measured sigma. */
static double group_raycast_ms(const rp_group_report *rep,
                               uint64_t samples) {
  double best = INFINITY;
  uint32_t i;
  for (i = 0; i < rep->count; i++) {
    const rp_group_device *d = &rep->devices[i];
    if (d->samples > 0 && d->raycast_ms > 0 &&
        d->raycast_ms / (double)d->samples < best)
      best = d->raycast_ms / (double)d->samples;
  }
  return isfinite(best) ? best * (double)samples : 0.0;
}

/* One pass at density rho. `probe` (for this camera and effects; may be
 * NULL) guides a group's split. */
static int render_pass(replay *r, const rp_camera *cam, uint32_t effects,
                       double rho, const rp_frame_probe *probe,
                       pass_result *out) {
  rp_render_desc d = {0};
  uint32_t sw, sh, tx, ty, i;
  double t0;
  int err;
  rp_space_map(&r->space, rho, &out->step, &out->scale);
  d.width = r->o.width;
  d.height = r->o.height;
  d.step = out->step;
  d.image_scale = out->scale;
  d.effects = effects;
  rp_scaled_size(&d, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  t0 = cli_now();
  if (r->group != NULL)
    err = rp_device_group_render(r->group, cam, &d, probe, r->scaled,
                                 r->tiles, &r->rep);
  else
    err = rp_device_render(r->on.dev, cam, &d, NULL, r->scaled, r->tiles);
  if (err != 0)
    return cli_error(r->ctx, "render", err);
  if (sw != d.width || sh != d.height)
    rp_image_upscale(r->scaled, sw, sh, r->image, d.width, d.height);
  out->ms = (cli_now() - t0) * 1e3;
  out->samples = 0;
  for (i = 0; i < tx * ty; i++)
    out->samples += r->tiles[i].samples;
  out->upload_ms = 0.0;
  if (r->group != NULL) {
    out->raycast_ms = group_raycast_ms(&r->rep, out->samples);
    for (i = 0; i < r->rep.count; i++)
      out->upload_ms = fmax(out->upload_ms, r->rep.devices[i].upload_ms);
    if (r->rep.lost > 0 && !r->o.quiet)
      fprintf(stderr, "replay: %u device(s) lost, %u left: %s\n",
              r->rep.lost, r->rep.alive, rp_last_error(r->ctx));
  } else {
    rp_brick_stats bs;
    out->raycast_ms = rp_device_last_time_ns(r->on.dev) * 1e-6;
    if (rp_device_get_brick_stats(r->on.dev, &bs) == 0 && bs.out_of_core) {
      out->upload_ms = bs.last_upload_ns * 1e-6;
      out->raycast_ms = fmax(out->raycast_ms - out->upload_ms, 0.0);
    }
  }
  return 0;
}

/* Out of core: what the coming pass will spend uploading bricks, as the
 * runtime predicts it (0 in core, or when the estimate fails). */
static double predicted_upload_ms(replay *r, const rp_camera *cam,
                                  uint32_t effects) {
  rp_render_desc d = {0};
  rp_upload_estimate e;
  double ms = 0.0;
  d.width = r->o.width;
  d.height = r->o.height;
  d.effects = effects;
  if (r->group != NULL)
    return rp_device_group_upload_ms(r->group, cam, &d, &ms) == 0 ? ms : 0.0;
  return rp_device_upload_estimate(r->on.dev, cam, &d, NULL, &e) == 0 ? e.ms
                                                                   : 0.0;
}

/* Makes TF `index` current on the host (occupancy) and the device. The
 * two are kept apart: with a device per controller (play()), the host's
 * occupancy may already be the TF's when the next controller's device
 * still holds the one before. */
static int use_tf(replay *r, int index) {
  int err;
  if (index != r->occ_tf) {
    if ((err = rp_occupancy_update(r->occ, r->tfs[index])) != 0)
      return cli_error(r->ctx, "transfer function", err);
    r->occ_tf = index;
  }
  if (index == r->on.tf_active)
    return 0;
  if ((err = r->group != NULL
                 ? rp_device_group_set_tf(r->group, r->tfs[index], r->occ)
                 : rp_device_set_tf(r->on.dev, r->tfs[index], r->occ)) != 0)
    return cli_error(r->ctx, "transfer function", err);
  r->on.tf_active = index;
  return 0;
}

/* The share of a frame's target spent on AO while it is computed (the
 * runtime's default ao_frame_share). */
#define AO_FRAME_SHARE 0.25

static void ao_drop_run(replay *r) {
  rp_ao_run_destroy(r->on.ao_run);
  rp_ao_plan_destroy(r->on.ao_plan);
  r->on.ao_run = NULL;
  r->on.ao_plan = NULL;
}

/* The effects a frame renders: AO only once its volume is ready. */
static uint32_t ao_effects(const replay *r, uint32_t effects) {
  return r->on.ao_tf == r->on.tf_active ? effects
                                        : effects & ~(uint32_t)RP_EFFECT_AO;
}

/* Starts AO for the active TF unless the devices hold it or a run for it
 * is under way; drops a run for another TF (the devices no longer hold
 * that TF). */
static int ao_start(replay *r) {
  rp_ao_schedule sc = {0};
  int err;
  /* A run for another TF goes first: the devices no longer hold its TF,
   * even when they still hold the AO of the one now active. */
  if (r->on.ao_run != NULL && r->on.run_tf != r->on.tf_active)
    ao_drop_run(r);
  if (r->on.ao_tf == r->on.tf_active || r->on.ao_run != NULL)
    return 0;
  sc.block = RP_AO_FRAME_BLOCK;
  err = rp_ao_plan_create(r->ctx, r->vol, r->tfs[r->on.tf_active], NULL,
                          &r->on.ao_plan);
  if (err == 0)
    err = r->group != NULL
              ? rp_device_group_ao_begin(r->group, r->on.ao_plan, &sc,
                                         &r->on.ao_run)
              : rp_ao_run_create(r->ctx, &r->on.dev, 1, r->on.ao_plan, &sc,
                                 &r->on.ao_run);
  if (err != 0) {
    ao_drop_run(r);
    return cli_error(r->ctx, "ambient occlusion", err);
  }
  r->on.run_tf = r->on.tf_active;
  return 0;
}

/* One step of `budget_ms` (INFINITY: to the end); once done, the AO goes
 * to the device(s). */
static int ao_step(replay *r, double budget_ms) {
  rp_ao *ao = NULL;
  double fraction = 0.0;
  int err = rp_ao_run_step(r->on.ao_run, budget_ms, &fraction);
  if (err == 0 && fraction < 1.0)
    return 0;
  if (r->group != NULL)
    err = rp_device_group_ao_end(r->group, r->on.ao_run, err, &ao, NULL);
  else if (err == 0)
    err = rp_ao_run_finish(r->on.ao_run, &ao, NULL);
  if (err == 0)
    err = r->group != NULL ? rp_device_group_set_ao(r->group, ao)
                           : rp_device_set_ao(r->on.dev, ao);
  rp_ao_destroy(ao);
  ao_drop_run(r);
  if (err != 0)
    return cli_error(r->ctx, "ambient occlusion", err);
  r->on.ao_tf = r->on.run_tf;
  return 0;
}

/* AO for the active TF, all of it now (warming up, calibrating). */
static int ao_now(replay *r, uint32_t effects) {
  if (!(effects & RP_EFFECT_AO) || r->on.ao_tf == r->on.tf_active)
    return 0;
  if (ao_start(r) != 0)
    return 1;
  return ao_step(r, INFINITY);
}

static double seq_target_ms(const replay *r, const rp_sequence_state *st) {
  return st->target_ms > 0 ? st->target_ms
                           : st->target_fraction * r->full_ms;
}

/* The target of a frame: the sequence's, rescaled so that its first
 * target becomes the command line's when one was given. */
static double frame_target(const replay *r, const rp_sequence_state *st) {
  double t = seq_target_ms(r, st);
  if (r->o.target_ms > 0)
    return r->o.target_ms * t / r->seq_target0;
  if (r->o.target_fraction > 0)
    return r->o.target_fraction * r->full_ms * t / r->seq_target0;
  return t;
}

typedef struct predict_ctx {
  const replay *r;
  const rp_cost_model *model;
  const rp_frame_probe *probe;
} predict_ctx;

static double predict_ms(void *user, double rho) {
  const predict_ctx *p = user;
  rp_cost_estimate e;
  float step, scale;
  rp_space_map(&p->r->space, rho, &step, &scale);
  if (p->r->group != NULL) {
    if (rp_device_group_predict(p->r->group, p->probe, step, scale, &e) !=
        0)
      return NAN;
    return e.ms;
  }
  if (rp_cost_predict(p->model, p->probe, step, scale, &e) != 0)
    return NAN;
  return e.ms;
}

static int probe_frame(replay *r, const rp_camera *cam, uint32_t effects,
                       uint32_t frame, rp_frame_probe *p) {
  rp_render_desc d = {0};
  int err;
  d.width = r->o.width;
  d.height = r->o.height;
  d.effects = effects;
  err = rp_frame_probe_compute(r->ctx, r->vol, r->tfs[r->on.tf_active], r->occ,
                               cam, &d, r->o.seed, frame, p);
  return err != 0 ? cli_error(r->ctx, "probe", err) : 0;
}

/* Warms every kernel variant the sequence uses: a first build must not
 * land in a recorded frame. An effect set with AO also renders without
 * it, for the frames that wait for a TF's AO (ao_effects): unwarmed,
 * that variant's build made the first switch of ao-tf-switch 43 % over
 * its target on every controller with a device of its own. */
static int warm_kernels(replay *r) {
  rp_sequence_state st;
  rp_camera cam;
  pass_result pr;
  uint32_t i, seen[16], nseen = 0, k, v;
  int err;
  for (i = 0; i < r->frames; i++) {
    if ((err = rp_sequence_frame(r->seq, i, &st)) != 0)
      return cli_error(r->ctx, "sequence", err);
    for (k = 0; k < nseen && seen[k] != st.effects; k++)
      ;
    if (k == nseen && nseen < 16) {
      uint32_t variants[2] = {st.effects,
                              st.effects & ~(uint32_t)RP_EFFECT_AO};
      seen[nseen++] = st.effects;
      rp_sequence_camera(&st, r->vol, &cam);
      if ((err = use_tf(r, st.tf)) != 0 || (err = ao_now(r, st.effects)))
        return err;
      for (v = 0; v < (variants[1] != variants[0] ? 2u : 1u); v++)
        if ((err = render_pass(r, &cam, variants[v], 1.0, NULL, &pr)) !=
                0 ||
            (err = render_pass(r, &cam, variants[v], 0.3, NULL, &pr)) != 0)
          return err;
    }
  }
  return 0;
}

/* Warms the kernels and measures the frame time without adaptation: the
 * median of 3 frames of the first state at density 1. */
static int calibrate(replay *r) {
  rp_sequence_state st;
  rp_camera cam;
  pass_result pr;
  uint32_t i;
  double t[3];
  int err;
  if ((err = warm_kernels(r)) != 0)
    return err;
  if ((err = rp_sequence_frame(r->seq, 0, &st)) != 0)
    return cli_error(r->ctx, "sequence", err);
  rp_sequence_camera(&st, r->vol, &cam);
  if ((err = use_tf(r, st.tf)) != 0 || (err = ao_now(r, st.effects)) != 0)
    return err;
  for (i = 0; i < 3; i++) {
    if ((err = render_pass(r, &cam, st.effects, 1.0, NULL, &pr)) != 0)
      return err;
    t[i] = pr.ms;
  }
  r->full_ms = cli_median(t, 3);
  r->seq_target0 = seq_target_ms(r, &st);
  if (!(r->seq_target0 > 0)) {
    fprintf(stderr, "raypace replay: the sequence's first target is not "
                    "positive\n");
    return 1;
  }
  return 0;
}

/* The spread of n frame times `ms` of the still frame, in segments
 * `seg` (noise_floor; its rho is kept). Within a segment, every
 * predictor is scored on its frames after the first, each from the
 * frames before it; the EWMAs start at the segment's first frame.
 * `work` holds n doubles. */
static void noise_stats(const double *ms, const uint32_t *seg, uint32_t n,
                        double *work, noise_floor *out) {
  double se = 0.0, se_last = 0.0, se_ew[NOISE_EWMAS] = {0};
  double ew[NOISE_EWMAS], best;
  uint32_t i, j, a, scored = 0;
  double rho = out->rho;
  memset(out, 0, sizeof *out);
  out->rho = rho;
  for (i = 0; i < n; i = j) {
    double lmed;
    for (j = i; j < n && seg[j] == seg[i]; j++)
      work[j - i] = ms[j];
    lmed = log(cli_median(work, (int)(j - i)));
    out->max_over = fmax(out->max_over, work[j - i - 1] / exp(lmed) - 1);
    out->segments++;
    for (a = 0; a < NOISE_EWMAS; a++)
      ew[a] = log(ms[i]);
    for (; i + 1 < j; i++) {
      double l = log(ms[i + 1]), e;
      se += (l - lmed) * (l - lmed);
      e = l - log(ms[i]);
      se_last += e * e;
      for (a = 0; a < NOISE_EWMAS; a++) {
        e = l - ew[a];
        se_ew[a] += e * e;
        ew[a] += NOISE_ALPHAS[a] * e;
      }
      scored++;
    }
  }
  memcpy(work, ms, n * sizeof *work);
  out->median_ms = n > 0 ? cli_median(work, (int)n) : 0.0;
  if (scored == 0)
    return;
  out->frames = n;
  out->sd = sqrt(se / scored);
  out->sd_last = sqrt(se_last / scored);
  best = fmin(se, se_last);
  for (a = 0; a < NOISE_EWMAS; a++)
    best = fmin(best, se_ew[a]);
  out->sd_best = sqrt(best / scored);
}

/* Sets up the still frame: the first frame's camera, at the density
 * whose frame takes the first target, found by last-frame's rule over
 * a few frames (frame time is not proportional to density: there is a
 * fixed cost per ray and per frame). Its frames are then as long as the
 * sequence's: the machine's noise is a larger share of a shorter frame. */
static int still_open(replay *r) {
  rp_sequence_state st;
  pass_result pr;
  double target, lo;
  uint32_t i;
  int err;
  r->still_ms = malloc(r->frames * sizeof *r->still_ms);
  r->still_seg = malloc(r->frames * sizeof *r->still_seg);
  if (r->still_ms == NULL || r->still_seg == NULL)
    return cli_error(r->ctx, "still frame", RP_ENOMEM);
  if ((err = rp_sequence_frame(r->seq, 0, &st)) != 0)
    return cli_error(r->ctx, "sequence", err);
  rp_sequence_camera(&st, r->vol, &r->still_cam);
  target = frame_target(r, &st);
  if (use_tf(r, st.tf) != 0 || ao_now(r, st.effects) != 0)
    return 1;
  lo = rp_space_min_density(&r->space);
  r->noise.rho = fmax(lo, fmin(1.0, target / r->full_ms));
  for (i = 0; i < STILL_AIM_FRAMES; i++) {
    if (render_pass(r, &r->still_cam, st.effects, r->noise.rho, NULL,
                    &pr) != 0)
      return 1;
    if (pr.ms > 0)
      r->noise.rho = fmax(lo, fmin(1.0, r->noise.rho * target / pr.ms));
  }
  return 0;
}

/* The still frame after recorded frame f of every controller: the TF
 * and effects that frame rendered on the shared device (so no TF or AO
 * is uploaded for it), its depth pass forgotten as the controllers' are.
 * A new TF or effect set starts a segment. */
static int still_frame(replay *r, uint32_t f) {
  rp_sequence_state st;
  pass_result pr;
  uint32_t effects;
  int err;
  if ((err = rp_sequence_frame(r->seq, f, &st)) != 0)
    return cli_error(r->ctx, "sequence", err);
  effects = ao_effects(r, st.effects);
  if (use_tf(r, st.tf) != 0)
    return 1;
  rp_device_forget_depth(r->on.dev);
  if (render_pass(r, &r->still_cam, effects, r->noise.rho, NULL, &pr) !=
      0)
    return 1;
  r->still_seg[f] = f == 0 ? 0
                    : r->still_seg[f - 1] +
                          ((uint32_t)st.tf != r->still_tf ||
                           effects != r->still_effects);
  r->still_tf = (uint32_t)st.tf;
  r->still_effects = effects;
  r->still_ms[f] = pr.ms > 0 ? pr.ms : 1e-6;
  return 0;
}

/* Writes --noise-csv. */
static int write_noise_csv(const replay *r) {
  FILE *f = fopen(r->o.noise_csv, "w");
  uint32_t i;
  int bad;
  if (f == NULL) {
    fprintf(stderr, "raypace replay: --noise-csv %s: cannot open for "
                    "writing\n", r->o.noise_csv);
    return 1;
  }
  fprintf(f, "frame,segment,density,measured_ms\n");
  for (i = 0; i < r->frames; i++)
    fprintf(f, "%u,%u,%.5f,%.6f\n", i, r->still_seg[i], r->noise.rho,
            r->still_ms[i]);
  bad = ferror(f);
  if (fclose(f) != 0 || bad) {
    fprintf(stderr, "raypace replay: --noise-csv %s: write failed\n",
            r->o.noise_csv);
    return 1;
  }
  return 0;
}

/* Opens the group of --devices with the current volume and TF. */
static int open_group(replay *r) {
  rp_group_desc gd = {0};
  int err;
  gd.devices = r->o.devices;
  gd.count = r->o.ndevices;
  ao_drop_run(r);
  r->on.ao_tf = -1; /* a new group holds no AO */
  if ((err = rp_device_group_create(r->ctx, &gd, &r->group)) != 0)
    return cli_error(r->ctx, "--devices", err);
  if ((err = rp_device_group_set_volume(r->group, r->vol)) != 0 ||
      (err = rp_device_group_set_tf(r->group, r->tfs[r->on.tf_active],
                                    r->occ)) != 0)
    return cli_error(r->ctx, "upload", err);
  r->group_used = 0;
  return 0;
}

/* A fresh, warm group for the next controller when the current one has
 * learned from another's frames. */
static int fresh_group(replay *r) {
  if (r->group == NULL || !r->group_used)
    return 0;
  rp_device_group_destroy(r->group);
  r->group = NULL;
  if (open_group(r) != 0)
    return 1;
  return warm_kernels(r);
}

/* The pass's per-device figures into the row (--devices). */
static void group_row(const replay *r, frame_row *row) {
  uint32_t i;
  row->imbalance = r->rep.imbalance;
  for (i = 0; i < r->rep.count; i++) {
    const rp_group_device *d = &r->rep.devices[i];
    row->dev[i].share = d->share;
    row->dev[i].busy_ms = d->busy_ms;
    row->dev[i].raycast_ms = d->raycast_ms;
    row->dev[i].samples = d->samples;
    row->dev[i].strip_share = d->strip_cost_share;
  }
}

/* ---- One controller over the sequence ------------------------------------ */

/* Exchanges the replay's device with the slot's: after one call the
 * replay plays on the slot's device, after a second on its own again. */
static void slot_swap(replay *r, device_slot *s) {
  device_slot t = *s;
  *s = r->on;
  r->on = t;
}

static int start_state(replay *r);

/* A second device like the replay's (the backend it opened, the same
 * index), with the volume, warmed and in the start state: a controller
 * of its own plays on it. -1 when the device cannot be had (the MPI
 * backend has one device per rank; memory for another copy of the
 * volume may be short): rp_last_error says why, and the caller plays
 * the controllers in turn instead. 1 on any other failure (reported). */
static int slot_open(replay *r, device_slot *s) {
  rp_device_desc dd = {0};
  rp_caps caps;
  int err;
  memset(s, 0, sizeof *s);
  s->tf_active = s->ao_tf = s->run_tf = -1;
  rp_device_get_caps(r->on.dev, &caps);
  dd.backend = r->o.backend != NULL ? r->o.backend : caps.backend;
  dd.index = r->o.device;
  dd.budget_bytes = r->o.mem.budget_bytes;
  dd.brick_size = r->o.mem.brick_size;
  if (rp_device_create(r->ctx, &dd, &s->dev) != 0 ||
      rp_device_set_volume(s->dev, r->vol) != 0)
    return -1;
  slot_swap(r, s);
  err = warm_kernels(r) != 0 || start_state(r) != 0;
  slot_swap(r, s);
  return err;
}

static void slot_close(device_slot *s) {
  rp_ao_run_destroy(s->ao_run);
  rp_ao_plan_destroy(s->ao_plan);
  rp_device_destroy(s->dev);
  memset(s, 0, sizeof *s);
}

/* One controller's part of a replay: its state and its rows. */
typedef struct player {
  rp_controller_kind kind;
  rp_controller *ctl;
  rp_cost_model *model;
  frame_row *rows;
  uint32_t devices_alive; /* --devices: in its group, after its frames;
                             0 without a group */
  device_slot slot; /* its own device (AO, frame by frame), when */
  int own_device;    /* set; else it plays on the replay's */
} player;

static int player_open(replay *r, player *p) {
  rp_controller_desc cd = {0};
  int err;
  cd.kind = p->kind;
  cd.rho_min = rp_space_min_density(&r->space);
  cd.rho_max = rp_space_max_density(&r->space);
  if ((err = rp_controller_create(r->ctx, &cd, &p->ctl)) != 0 ||
      (err = rp_cost_model_create(r->ctx, NULL, &p->model)) != 0)
    return cli_error(r->ctx, "controller", err);
  return 0;
}

static void player_close(player *p) {
  rp_cost_model_destroy(p->model);
  rp_controller_destroy(p->ctl);
  p->model = NULL;
  p->ctl = NULL;
}

/* --trace: the columns are rp_cost_train's arguments (the probe's fields
 * that rp_cost_predict reads, step, scale, samples, raycast and frame
 * time), each double to 17 digits so that bench_costmodel feeds a model
 * exactly what this one learned from. `frame` counts the settle frames. */
static const char trace_header[] =
    "controller,frame,width,height,effects,rays,rays_hit,rays_ended,"
    "depth_sum,depth_max,ert_cut,lit_span,lit_ends,view_x,view_y,view_z,"
    "pixels_per_voxel,diagonal,step,scale,samples,raycast_ms,frame_ms\n";

/* The frame time the cost model learns from: the pass without its brick
 * uploads, which the replay predicts apart. */
static double trained_ms(const pass_result *pr) {
  return fmax(pr->ms - pr->upload_ms, pr->raycast_ms);
}

static int trace_row(replay *r, rp_controller_kind kind, uint32_t i,
                     const rp_frame_probe *p, const pass_result *pr) {
  int n = fprintf(
      r->trace,
      "%s,%u,%u,%u,%u,%u,%u,%u,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,%.17g,"
      "%.17g,%.17g,%.17g,%.9g,%.9g,%llu,%.17g,%.17g\n",
      rp_controller_name(kind), i, p->width, p->height, p->effects,
      p->rays, p->rays_hit, p->rays_ended, p->depth_sum, p->depth_max,
      p->ert_cut, p->lit_span, p->lit_ends, p->view[0], p->view[1],
      p->view[2], p->pixels_per_voxel, p->diagonal, (double)pr->step,
      (double)pr->scale, (unsigned long long)pr->samples, pr->raycast_ms,
      trained_ms(pr));
  return n < 0;
}

/* Frame i of the settle frames and the sequence after them, for one
 * controller. */
static int play_frame(replay *r, player *p, uint32_t i) {
  rp_controller *ctl = p->ctl;
  rp_cost_model *model = p->model;
  frame_row *rows = p->rows;
  uint32_t f = i < r->o.settle ? 0 : i - r->o.settle;
  rp_sequence_state st;
  rp_camera cam;
  rp_frame_probe probe;
  rp_cost_estimate est;
  predict_ctx pc;
  pass_result pr;
  double rho, target, pass_target, frame_ms = 0.0, t0, ao_ms, upload;
  uint32_t effects;
  int err, again = 1, passes = 0;
  if ((err = rp_sequence_frame(r->seq, f, &st)) != 0)
    return cli_error(r->ctx, "sequence", err);
  if (use_tf(r, st.tf) != 0)
    return 1;
  rp_sequence_camera(&st, r->vol, &cam);
  target = frame_target(r, &st);
  /* AO as the runtime does it: a share of the target on its run, the
   * passes get the rest (at least a quarter of it). */
  ao_ms = 0.0;
  if (!(st.effects & RP_EFFECT_AO))
    ao_drop_run(r);
  else if (ao_start(r) != 0)
    return 1;
  if (r->on.ao_run != NULL) {
    t0 = cli_now();
    if (ao_step(r, AO_FRAME_SHARE * target) != 0)
      return 1;
    ao_ms = (cli_now() - t0) * 1e3;
  }
  effects = ao_effects(r, st.effects);
  t0 = cli_now();
  if (probe_frame(r, &cam, effects, f, &probe) != 0)
    return 1;
  /* Predicted brick uploads come off the passes' budget, as the AO
   * step does. */
  upload = predicted_upload_ms(r, &cam, effects);
  pass_target = target - ao_ms - upload > 0.25 * target
                    ? target - ao_ms - upload
                    : 0.25 * target;
  pc.r = r;
  pc.model = model;
  pc.probe = &probe;
  if ((err = rp_controller_begin_frame(ctl, pass_target, predict_ms, &pc,
                                       &rho)) != 0)
    return cli_error(r->ctx, "controller", err);
  if (i >= r->o.settle)
    rows[f].probe_ms = (cli_now() - t0) * 1e3;
  while (again) {
    if (render_pass(r, &cam, effects, rho, &probe, &pr) != 0)
      return 1;
    passes++;
    frame_ms += pr.ms;
    /* A group predicts before its training on this pass, as the
     * single model does. */
    if (r->group != NULL
            ? (err = rp_device_group_predict(r->group, &probe, pr.step,
                                             pr.scale, &est)) != 0
            : rp_cost_predict(model, &probe, pr.step, pr.scale, &est) != 0)
      return cli_error(r->ctx, "predict",
                       r->group != NULL ? err : RP_EINVAL);
    if (i >= r->o.settle) {
      frame_row *row = &rows[f];
      row->frame = f;
      row->tf_changed = st.tf_changed && f > 0;
      row->target_ms = target;
      row->predicted_ms = est.ms + upload;
      row->upload_ms = pr.upload_ms;
      row->upload_pred_ms = upload;
      row->last_pass_ms = pr.ms;
      row->ao_ms = ao_ms;
      row->ao = (effects & RP_EFFECT_AO) != 0;
      row->rho = rho;
      row->step = pr.step;
      row->scale = pr.scale;
      row->samples_est = est.samples * est.sample_ratio;
      row->samples = pr.samples;
      row->sigma_pred_ns = est.sigma_ns;
      row->sigma_ns = pr.samples > 0 && pr.raycast_ms > 0
                          ? pr.raycast_ms * 1e6 /
                                (est.fetches * (double)pr.samples)
                          : NAN;
      if (r->group != NULL)
        group_row(r, row);
    }
    if ((err = r->group != NULL
                   ? rp_device_group_train(r->group, &probe, pr.step,
                                           pr.scale, pr.ms)
                   : rp_cost_train(model, &probe, pr.step, pr.scale,
                                   pr.samples, pr.raycast_ms,
                                   trained_ms(&pr))) != 0 ||
        (err = rp_controller_end_pass(ctl, pr.ms - pr.upload_ms, &again,
                                      &rho)) != 0)
      return cli_error(r->ctx, "train", err);
    if (r->trace != NULL && trace_row(r, p->kind, i, &probe, &pr) != 0) {
      fprintf(stderr, "raypace replay: --trace %s: write failed\n",
              r->o.trace);
      return 1;
    }
  }
  if (i >= r->o.settle) {
    /* What the user waited for: the AO step and the passes. */
    rows[f].measured_ms = frame_ms + ao_ms;
    rows[f].passes = passes;
  }
  return 0;
}

/* Whether any frame of the sequence asks for AO. */
static int sequence_uses_ao(const replay *r) {
  rp_sequence_state st;
  uint32_t f;
  for (f = 0; f < r->frames; f++)
    if (rp_sequence_frame(r->seq, f, &st) == 0 &&
        (st.effects & RP_EFFECT_AO))
      return 1;
  return 0;
}

/* Every controller starts as the first does after calibrate(): frame 0's
 * TF current, its AO (when frame 0 asks for AO) held by the devices, and
 * no AO run under way from the controller before. */
static int start_state(replay *r) {
  rp_sequence_state st;
  int err;
  ao_drop_run(r);
  if ((err = rp_sequence_frame(r->seq, 0, &st)) != 0)
    return cli_error(r->ctx, "sequence", err);
  if (use_tf(r, st.tf) != 0 || ao_now(r, st.effects) != 0)
    return 1;
  return 0;
}

/* Whether the single device renders from bricks. */
static int out_of_core(const replay *r) {
  rp_brick_stats bs;
  return r->on.dev != NULL && rp_device_get_brick_stats(r->on.dev, &bs) == 0 &&
         bs.out_of_core;
}

/* Plays the sequence under every controller of `ps`. On one device and
 * in core they play frame by frame in turn, the order rotating each
 * frame, so that a burst of the machine's noise (ten frames at +30 %
 * are common on a shared machine) falls on all of them alike: every
 * frame's scene is the same for all, and each keeps its own controller
 * and cost model. With two or more, the device's depth pass is
 * forgotten before each frame, so that none reuses another's
 * (rp_device_render skips it for the same camera and scale); a single
 * controller still reuses its own, as it always has. A sequence with AO
 * gives each controller after the first a device of its own (same
 * backend and index, slot_open), because a device holds what one
 * controller's frames did to its AO: the run under way, the TF whose AO
 * it holds. A device group and a brick pool hold such things too (the
 * devices' models, the bricks loaded), so there each controller plays
 * the whole sequence in turn, each from the same start (start_state; a
 * group a fresh one). */
static int play(replay *r, player *ps, int n) {
  uint32_t total = r->o.settle + r->frames, i;
  int k, rc = 1, in_turn = r->group == NULL && !out_of_core(r);
  if (in_turn && n > 1 && sequence_uses_ao(r)) {
    int got = 0;
    for (k = 1; k < n && got == 0; k++) {
      ps[k].own_device = 1;
      got = slot_open(r, &ps[k].slot);
    }
    if (got > 0)
      goto out;
    if (got < 0) {
      if (!r->o.quiet)
        fprintf(stderr, "replay: no device for each controller (%s): "
                        "each plays the whole sequence in turn\n",
                rp_last_error(r->ctx));
      for (k = 0; k < n; k++) {
        slot_close(&ps[k].slot);
        ps[k].own_device = 0;
      }
      in_turn = 0;
    } else if (start_state(r) != 0) {
      goto out;
    }
  }
  if (in_turn) {
    if (!r->o.quiet && n > 1)
      fprintf(stderr, "replay: %d controllers, frame by frame in turn%s\n",
              n, ps[n - 1].own_device ? ", a device each (AO)" : "");
    /* One controller reuses its depth pass from frame to frame, which
     * a still frame between its frames would undo: none then. */
    if (!r->o.no_noise && n > 1 && still_open(r) != 0)
      goto out;
    for (k = 0; k < n; k++)
      if (player_open(r, &ps[k]) != 0)
        goto out;
    for (i = 0; i < total; i++) {
      for (k = 0; k < n; k++) {
        player *p = &ps[(i + (uint32_t)k) % (uint32_t)n];
        int err;
        if (p->own_device)
          slot_swap(r, &p->slot);
        if (n > 1)
          rp_device_forget_depth(r->on.dev);
        err = play_frame(r, p, i);
        if (p->own_device)
          slot_swap(r, &p->slot);
        if (err != 0)
          goto out;
      }
      if (r->still_ms != NULL && i >= r->o.settle &&
          still_frame(r, i - r->o.settle) != 0)
        goto out;
    }
    if (r->still_ms != NULL) {
      double *work = malloc(r->frames * sizeof *work);
      if (work == NULL) {
        cli_error(r->ctx, "still frame", RP_ENOMEM);
        goto out;
      }
      noise_stats(r->still_ms, r->still_seg, r->frames, work, &r->noise);
      free(work);
    }
  } else {
    for (k = 0; k < n; k++) {
      if (!r->o.quiet)
        fprintf(stderr, "replay: %s ...\n", rp_controller_name(ps[k].kind));
      if (fresh_group(r) != 0)
        goto out;
      if (r->group != NULL)
        r->group_used = 1;
      if (start_state(r) != 0 || player_open(r, &ps[k]) != 0)
        goto out;
      for (i = 0; i < total; i++)
        if (play_frame(r, &ps[k], i) != 0)
          goto out;
      ps[k].devices_alive = rp_device_group_alive(r->group);
      player_close(&ps[k]);
    }
  }
  rc = 0;
out:
  for (k = 0; k < n; k++) {
    player_close(&ps[k]);
    slot_close(&ps[k].slot);
    ps[k].own_device = 0;
  }
  return rc;
}

/* Frames after a TF switch that still count as the switch's: a reactive
 * rule learns of the switch from the switch frame's own time, so its
 * overshoot lands on that frame and the one or two after it. */
#define SWITCH_AFTER 2

static void summarise(rp_controller_kind kind, const frame_row *rows,
                      uint32_t n, double rho_max, summary *s) {
  uint32_t i, over = 0, sig_n = 0, open_n = 0, since_switch = UINT32_MAX;
  double se_open = 0;
  double se = 0, se_rel = 0, pe = 0, sig = 0, dens = 0, ov = 0, oh = 0;
  double mt = 0, mm = 0, imb = 0;
  memset(s, 0, sizeof(*s));
  s->kind = kind;
  s->frames = n;
  for (i = 0; i < n; i++) {
    const frame_row *w = &rows[i];
    double d = w->measured_ms - w->target_ms, rel = d / w->target_ms;
    se += d * d;
    se_rel += rel * rel;
    /* A frame at the top density that is still under the target had no
     * better choice: it is left out of rmse_open. */
    if (!(w->rho >= rho_max && d < 0.0)) {
      se_open += d * d;
      open_n++;
    }
    if (rel > ov)
      ov = rel;
    since_switch = w->tf_changed ? 0
                   : since_switch < UINT32_MAX ? since_switch + 1
                                               : since_switch;
    if (since_switch <= SWITCH_AFTER && rel > s->switch_over)
      s->switch_over = rel;
    over += w->measured_ms > 1.2 * w->target_ms;
    dens += w->rho;
    /* The last pass's prediction against the last pass's time: for
     * one-pass controllers that is the frame. */
    d = w->predicted_ms - w->last_pass_ms;
    pe += d * d;
    if (i >= 30 && isfinite(w->sigma_ns) && w->sigma_ns > 0) {
      sig += fabs(w->sigma_pred_ns - w->sigma_ns) / w->sigma_ns;
      sig_n++;
    }
    oh += w->probe_ms;
    mt += w->target_ms;
    mm += w->measured_ms;
    imb += w->imbalance;
  }
  if (n == 0)
    return;
  s->rmse_ms = sqrt(se / n);
  s->rmse_rel = sqrt(se_rel / n);
  s->rmse_open_ms = open_n > 0 ? sqrt(se_open / open_n) : 0.0;
  s->max_over = ov;
  s->share_over_20 = (double)over / n;
  s->mean_density = dens / n;
  s->pred_rmse_ms = sqrt(pe / n);
  s->sigma_err_30 = sig_n > 0 ? sig / sig_n : NAN;
  s->overhead_ms = oh / n;
  s->mean_target = mt / n;
  s->mean_ms = mm / n;
  s->mean_imbalance = imb / n;
}

/* ---- Output -------------------------------------------------------------- */

/* With `ndev` > 0 (--devices) each row ends in dev<i>_share,
 * dev<i>_busy_ms, dev<i>_raycast_ms, dev<i>_samples for every device and
 * the frame's imbalance, all of its last pass, and, after the AO and
 * upload columns, dev<i>_tail_share: the predicted cost of the tail
 * strips each device took. */
static int write_csv(const char *path, const summary *sums,
                     frame_row *const *rows, int nctl, uint32_t n,
                     uint32_t ndev) {
  FILE *f = fopen(path, "w");
  int k;
  uint32_t i, j;
  if (f == NULL) {
    fprintf(stderr, "raypace replay: cannot write '%s'\n", path);
    return 1;
  }
  fprintf(f, "controller,frame,target_ms,measured_ms,predicted_ms,"
             "delta_ms,passes,density,step,scale,samples_est,samples,"
             "sigma_pred_ns,sigma_ns,probe_ms,tf_switch");
  for (j = 0; j < ndev; j++)
    fprintf(f, ",dev%u_share,dev%u_busy_ms,dev%u_raycast_ms,dev%u_samples",
            j, j, j, j);
  /* Appended, so that the earlier columns keep their places. */
  fprintf(f, "%s,ao_ms,ao,upload_ms,upload_predicted_ms",
          ndev > 0 ? ",imbalance" : "");
  for (j = 0; j < ndev; j++)
    fprintf(f, ",dev%u_tail_share", j);
  fprintf(f, "\n");
  for (k = 0; k < nctl; k++) {
    for (i = 0; i < n; i++) {
      const frame_row *w = &rows[k][i];
      fprintf(f, "%s,%u,%.4f,%.4f,%.4f,%.4f,%d,%.5f,%.4f,%.4f,%.0f,%llu,"
                 "%.4f,%.4f,%.4f,%d",
              rp_controller_name(sums[k].kind), w->frame, w->target_ms,
              w->measured_ms, w->predicted_ms,
              w->measured_ms - w->target_ms, w->passes, w->rho,
              (double)w->step, (double)w->scale, w->samples_est,
              (unsigned long long)w->samples, w->sigma_pred_ns, w->sigma_ns,
              w->probe_ms, w->tf_changed);
      for (j = 0; j < ndev; j++)
        fprintf(f, ",%.5f,%.4f,%.4f,%llu", w->dev[j].share,
                w->dev[j].busy_ms, w->dev[j].raycast_ms,
                (unsigned long long)w->dev[j].samples);
      if (ndev > 0)
        fprintf(f, ",%.4f", w->imbalance);
      fprintf(f, ",%.4f,%d,%.4f,%.4f", w->ao_ms, w->ao, w->upload_ms,
              w->upload_pred_ms);
      for (j = 0; j < ndev; j++)
        fprintf(f, ",%.5f", w->dev[j].strip_share);
      fprintf(f, "\n");
    }
  }
  return fclose(f) == 0 ? 0 : 1;
}

/* Frame times of every controller against the target (top) and their
 * densities (bottom), like seed 000 Fig. 5, drawn by gnuplot from the
 * CSV. */
static int write_plot(const char *png, const char *csv, const summary *sums,
                      int nctl, const char *title) {
  cli_plot plot;
  FILE *g;
  int k;
  if (cli_plot_open(&plot, "raypace replay") != 0)
    return 1;
  g = plot.g;
  fprintf(g, "set terminal pngcairo size 1200,900 noenhanced\n"
             "set output ");
  cli_gnuplot_string(g, png);
  fprintf(g, "\nset datafile separator ','\n"
             "set key outside right top\n"
             "set multiplot layout 2,1 title ");
  cli_gnuplot_string(g, title);
  fprintf(g, "\nset ylabel 'frame time (ms)'\nset grid\nplot ");
  cli_gnuplot_string(g, csv);
  fprintf(g, " skip 1 using 2:(strcol(1) eq '%s' ? $3 : 1/0) "
             "with lines lw 3 lc rgb 'black' title 'target'",
          rp_controller_name(sums[0].kind));
  for (k = 0; k < nctl; k++)
    fprintf(g, ", '' skip 1 using 2:(strcol(1) eq '%s' ? $4 : 1/0) "
               "with lines title '%s'",
            rp_controller_name(sums[k].kind),
            rp_controller_name(sums[k].kind));
  fprintf(g, "\nset xlabel 'frame'\n"
             "set ylabel 'density (1 = base step, full size)'\n"
             "set logscale y\nplot ");
  for (k = 0; k < nctl; k++) {
    fprintf(g, "%s", k ? ", " : "");
    cli_gnuplot_string(g, csv);
    fprintf(g, " skip 1 using 2:(strcol(1) eq '%s' ? $8 : 1/0) "
               "with lines title '%s'",
            rp_controller_name(sums[k].kind),
            rp_controller_name(sums[k].kind));
  }
  fprintf(g, "\nunset multiplot\n");
  return cli_plot_close(&plot, "raypace replay");
}

/* Device i's label: its spec, as --devices gave it. */
static void device_label(const rp_device_desc *d, const rp_fault_desc *f,
                         uint32_t i, char *buf, size_t size) {
  int n = snprintf(buf, size, "dev%u %s:%u", i, d->backend, d->index);
  if (n > 0 && (size_t)n < size && d->compute_units > 0)
    n += snprintf(buf + n, size - (size_t)n, ":cu=%u", d->compute_units);
  if (n > 0 && (size_t)n < size && f->slowdown > 0)
    n += snprintf(buf + n, size - (size_t)n, ":slow=%g", f->slowdown);
  if (n > 0 && (size_t)n < size && f->fail_at_render > 0)
    snprintf(buf + n, size - (size_t)n, ":fail=%u", f->fail_at_render);
}

/* Per-device busy times (left) and stacked shares (right) per frame, one
 * row of panels per controller, like seed 000 Fig. 8: --devices with
 * two or more devices. The CSV's device columns start at 17 (write_csv).
 */
static int write_device_plot(const char *png, const char *csv,
                             const summary *sums, int nctl,
                             const replay *r) {
  uint32_t n = r->o.ndevices, i;
  cli_plot plot;
  FILE *g;
  int k;
  if (cli_plot_open(&plot, "raypace replay") != 0)
    return 1;
  g = plot.g;
  fprintf(g, "set terminal pngcairo size 1400,%d noenhanced\n"
             "set output ", 120 + 260 * nctl);
  cli_gnuplot_string(g, png);
  fprintf(g, "\nset datafile separator ','\nset grid\n"
             "set key outside right top\n"
             "set multiplot layout %d,2 title ", nctl);
  cli_gnuplot_string(g, "per-device busy time and share per frame");
  fprintf(g, "\n");
  for (k = 0; k < nctl; k++) {
    const char *name = rp_controller_name(sums[k].kind);
    fprintf(g, "set title '%s: busy'\nset ylabel 'ms'\nset yrange [*:*]\n"
               "plot ", name);
    /* A frame the device had no region in is a gap, not a 0. */
    for (i = 0; i < n; i++) {
      char label[96];
      device_label(&r->o.devices[i], &r->o.device_ext[i].faults, i, label,
                   sizeof(label));
      fprintf(g, "%s", i ? ", " : "");
      cli_gnuplot_string(g, csv);
      fprintf(g, " skip 1 using 2:(strcol(1) eq '%s' && $%u > 0 ? $%u : "
                 "1/0) with linespoints pt 7 ps 0.4 lc %u title ",
              name, 20 + 4 * i, 18 + 4 * i, i + 1);
      cli_gnuplot_string(g, label);
    }
    fprintf(g, "\nset title '%s: shares'\nset ylabel 'share'\n"
               "set yrange [0:1]\nplot ", name);
    for (i = 0; i < n; i++) {
      uint32_t j;
      fprintf(g, "%s", i ? ", " : "");
      cli_gnuplot_string(g, csv);
      fprintf(g, " skip 1 using 2:(strcol(1) eq '%s' ? 0", name);
      for (j = 0; j < i; j++)
        fprintf(g, " + $%u", 17 + 4 * j);
      fprintf(g, " : 1/0):(0");
      for (j = 0; j <= i; j++)
        fprintf(g, " + $%u", 17 + 4 * j);
      fprintf(g, ") with filledcurves lc %u fs solid 0.6 title 'dev%u'",
              i + 1, i);
    }
    fprintf(g, "\n");
  }
  fprintf(g, "unset multiplot\n");
  return cli_plot_close(&plot, "raypace replay");
}

static void print_json(const replay *r, const summary *s) {
  cJSON *o = cJSON_CreateObject();
  char *text;
  cJSON_AddStringToObject(o, "controller", rp_controller_name(s->kind));
  cJSON_AddStringToObject(o, "sequence", rp_sequence_name(r->seq));
  cJSON_AddStringToObject(o, "space", rp_space_name(r->space.space));
  cJSON_AddNumberToObject(o, "frames", s->frames);
  cJSON_AddNumberToObject(o, "full_ms", r->full_ms);
  cJSON_AddNumberToObject(o, "mean_target_ms", s->mean_target);
  cJSON_AddNumberToObject(o, "mean_ms", s->mean_ms);
  cJSON_AddNumberToObject(o, "target_rmse_ms", s->rmse_ms);
  cJSON_AddNumberToObject(o, "target_rmse_rel", s->rmse_rel);
  cJSON_AddNumberToObject(o, "target_rmse_open_ms", s->rmse_open_ms);
  cJSON_AddNumberToObject(o, "max_overshoot", s->max_over);
  cJSON_AddNumberToObject(o, "switch_overshoot", s->switch_over);
  cJSON_AddNumberToObject(o, "share_over_1_2", s->share_over_20);
  cJSON_AddNumberToObject(o, "mean_density", s->mean_density);
  cJSON_AddNumberToObject(o, "prediction_rmse_ms", s->pred_rmse_ms);
  if (isfinite(s->sigma_err_30))
    cJSON_AddNumberToObject(o, "sigma_error_after_30", s->sigma_err_30);
  else
    cJSON_AddNullToObject(o, "sigma_error_after_30");
  cJSON_AddNumberToObject(o, "overhead_ms", s->overhead_ms);
  if (r->noise.frames > 0) {
    cJSON *n = cJSON_AddObjectToObject(o, "noise");
    cJSON_AddNumberToObject(n, "frames", r->noise.frames);
    cJSON_AddNumberToObject(n, "segments", r->noise.segments);
    cJSON_AddNumberToObject(n, "density", r->noise.rho);
    cJSON_AddNumberToObject(n, "median_ms", r->noise.median_ms);
    cJSON_AddNumberToObject(n, "sd", r->noise.sd);
    cJSON_AddNumberToObject(n, "sd_last", r->noise.sd_last);
    cJSON_AddNumberToObject(n, "sd_best", r->noise.sd_best);
    cJSON_AddNumberToObject(n, "max_overshoot", r->noise.max_over);
  }
  if (r->o.ndevices > 0) {
    cJSON *a = cJSON_AddArrayToObject(o, "devices");
    uint32_t i;
    for (i = 0; i < r->o.ndevices; i++) {
      rp_caps caps;
      char name[168];
      rp_device_group_get_caps(r->group, i, &caps);
      snprintf(name, sizeof(name), "%s:%s", caps.backend, caps.device);
      cJSON_AddItemToArray(a, cJSON_CreateString(name));
    }
    cJSON_AddNumberToObject(o, "devices_alive", s->devices_alive);
    cJSON_AddNumberToObject(o, "mean_imbalance", s->mean_imbalance);
  }
  text = cJSON_PrintUnformatted(o);
  if (text != NULL)
    printf("%s\n", text);
  free(text);
  cJSON_Delete(o);
}

static void print_table(const replay *r, const summary *sums, int nctl) {
  int k;
  printf("sequence %s, %u frames, %ux%u, space %s; no-adaptation frame "
         "%.1f ms\n", rp_sequence_name(r->seq), r->frames, r->o.width,
         r->o.height, rp_space_name(r->space.space), r->full_ms);
  if (r->o.ndevices > 0)
    printf("devices %s (a group of %u)\n", r->o.devices_spec,
           r->o.ndevices);
  if (r->noise.frames > 0)
    printf("timing noise, a still frame after each round (%u frames, %u "
           "segment%s, density %.3f, median %.2f ms): sd %.1f%% about "
           "the median, %.1f%% frame to frame, %.1f%% the best "
           "predictor; slowest +%.1f%%\n",
           r->noise.frames, r->noise.segments,
           r->noise.segments == 1 ? "" : "s", r->noise.rho,
           r->noise.median_ms,
           100 * r->noise.sd, 100 * r->noise.sd_last,
           100 * r->noise.sd_best, 100 * r->noise.max_over);
  printf("%-11s %8s %8s %8s %8s %8s %7s %7s %8s %9s %8s %8s%s\n",
         "controller", "mean_ms", "target", "rmse_ms", "rmse_open",
         "rmse_rel", "max_ovr", "sw_ovr", ">1.2T", "density", "pred_rmse",
         "sigma_e30", r->o.ndevices > 0 ? "   imbal  alive" : "");
  for (k = 0; k < nctl; k++) {
    const summary *s = &sums[k];
    printf("%-11s %8.2f %8.2f %8.2f %8.2f %8.3f %6.1f%% %6.1f%% %7.1f%% "
           "%9.4f %8.2f ", rp_controller_name(s->kind), s->mean_ms,
           s->mean_target, s->rmse_ms, s->rmse_open_ms, s->rmse_rel,
           100 * s->max_over, 100 * s->switch_over,
           100 * s->share_over_20, s->mean_density, s->pred_rmse_ms);
    /* NaN when the run had no 30 frames to measure it after. */
    if (isfinite(s->sigma_err_30))
      printf("%8.3f", s->sigma_err_30);
    else
      printf("%8s", "-");
    if (r->o.ndevices > 0)
      printf(" %7.3f %6u", s->mean_imbalance, s->devices_alive);
    printf("\n");
  }
}

/* The reactive rules the predicted controller's RMSE is held against. */
static int is_reactive(rp_controller_kind k) {
  return k == RP_CONTROL_LAST_FRAME || k == RP_CONTROL_VTK ||
         k == RP_CONTROL_UE5 || k == RP_CONTROL_VALVE;
}

/* Every figure unknown: what a run that ends early reports. */
static void goals_clear(cli_pacing_goals *g) {
  g->ratio = g->ratio_open = g->ratio_noise = NAN;
  g->max_over = g->switch_over = NAN;
  g->density_two_pass = g->density_last_frame = NAN;
  g->noise_sd_best = g->noise_max_over = NAN;
  g->full_ms = NAN;
}

/* The goals as ratios within this run (cli_pacing_goals): NaN
 * where the controllers a figure compares were not played. */
static void goals_compute(const replay *r, const summary *sums, int nctl,
                          cli_pacing_goals *g) {
  const summary *by[RP_CONTROL_COUNT] = {0};
  const summary *p;
  double best = INFINITY, best_open = INFINITY;
  int k;
  goals_clear(g);
  g->full_ms = r->full_ms;
  for (k = 0; k < nctl; k++)
    by[sums[k].kind] = &sums[k];
  if (r->noise.frames > 0) {
    g->noise_sd_best = r->noise.sd_best;
    g->noise_max_over = r->noise.max_over;
  }
  if ((p = by[RP_CONTROL_PREDICTED]) == NULL)
    return;
  for (k = 0; k < RP_CONTROL_COUNT; k++) {
    if (!is_reactive((rp_controller_kind)k))
      continue;
    if (by[k] != NULL && by[k]->rmse_ms < best)
      best = by[k]->rmse_ms;
    if (by[k] != NULL && by[k]->rmse_open_ms < best_open)
      best_open = by[k]->rmse_open_ms;
  }
  if (isfinite(best) && best > 0)
    g->ratio = p->rmse_ms / best;
  if (isfinite(best_open) && best_open > 0) {
    g->ratio_open = p->rmse_open_ms / best_open;
    /* A model with no error but the machine's own would miss each
     * target by about noise.sd_best of it: about where the ratio lands
     * from the noise alone (an estimate from another frame, not a
     * bound). */
    if (r->noise.frames > 0)
      g->ratio_noise = r->noise.sd_best * p->mean_target / best_open;
  }
  g->max_over = p->max_over;
  g->switch_over = p->switch_over;
  if (by[RP_CONTROL_TWO_PASS] != NULL)
    g->density_two_pass =
        p->mean_density / by[RP_CONTROL_TWO_PASS]->mean_density;
  if (by[RP_CONTROL_LAST_FRAME] != NULL)
    g->density_last_frame =
        p->mean_density / by[RP_CONTROL_LAST_FRAME]->mean_density;
}

/* The goals' line, when the predicted controller was played. */
static void print_goals(const replay *r, const summary *sums, int nctl) {
  cli_pacing_goals g;
  int k, played = 0, reactive = 0;
  for (k = 0; k < nctl; k++) {
    played |= sums[k].kind == RP_CONTROL_PREDICTED;
    reactive |= is_reactive(sums[k].kind);
  }
  if (!played)
    return;
  goals_compute(r, sums, nctl, &g);
  /* With no reactive rule played (one controller) there is nothing to
   * hold the RMSE against: say so rather than print a NaN. */
  if (!reactive)
    printf("goals: predicted rmse / best reactive: no reactive "
           "controller played (--controller all)");
  else {
    printf("goals: predicted rmse / best reactive = ");
    if (isfinite(g.ratio))
      printf("%.3f", g.ratio);
    else
      printf("-");
    printf(" (<= %g), reachable frames only ", CLI_GOAL_RATIO);
    if (isfinite(g.ratio_open))
      printf("%.3f", g.ratio_open);
    else
      printf("- (none)");
    if (isfinite(g.ratio_noise))
      printf(" (%.3f from timing noise alone)", g.ratio_noise);
  }
  printf("; max overshoot %.1f%% (<= %g%%), on TF switches %.1f%%",
         100 * g.max_over, 100 * CLI_GOAL_OVERSHOOT, 100 * g.switch_over);
  if (isfinite(g.density_two_pass))
    printf("; density / two-pass = %.2f (>= %g)", g.density_two_pass,
           CLI_GOAL_TWO_PASS);
  if (isfinite(g.density_last_frame))
    printf("; density / last-frame = %.2f (>= %g)", g.density_last_frame,
           CLI_GOAL_LAST_FRAME);
  printf("\n");
}

/* ---- The command --------------------------------------------------------- */

static int open_scene(replay *r) {
  rp_sequence_state st;
  uint32_t tx, ty;
  size_t px = (size_t)r->o.width * r->o.height;
  int err, i;
  if ((err = rp_context_create(NULL, &r->ctx)) != 0)
    return cli_error(NULL, "context", err);
  if ((err = rp_sequence_load(r->ctx, r->o.sequence, &r->seq)) != 0)
    return cli_error(r->ctx, "--sequence", err);
  r->frames = rp_sequence_frames(r->seq);
  if (r->o.frames > 0 && r->o.frames < r->frames)
    r->frames = r->o.frames;
  if (cli_open_volume(r->ctx, r->o.volume, &r->vol) != 0)
    return 1;
  if ((err = rp_histograms_build(r->ctx, r->vol, &r->h)) != 0)
    return cli_error(r->ctx, "histograms", err);
  r->tf_count = rp_sequence_tf_count(r->seq);
  r->tfs = calloc((size_t)r->tf_count, sizeof(*r->tfs));
  if (r->tfs == NULL)
    return cli_error(r->ctx, "transfer functions", RP_ENOMEM);
  for (i = 0; i < r->tf_count; i++)
    if ((err = rp_sequence_tf_create(r->ctx, r->seq, i, &r->tfs[i])) != 0)
      return cli_error(r->ctx, "transfer function", err);
  if ((err = rp_sequence_frame(r->seq, 0, &st)) != 0)
    return cli_error(r->ctx, "sequence", err);
  if ((err = rp_occupancy_build(r->ctx, r->h, r->tfs[st.tf], &r->occ)) != 0)
    return cli_error(r->ctx, "occupancy", err);
  r->on.tf_active = r->occ_tf = st.tf;
  r->on.ao_tf = -1;
  if (r->o.ndevices > 0) {
    if (open_group(r) != 0)
      return 1;
  } else {
    if (cli_open_device(r->ctx, "--backend", r->o.backend, r->o.device,
                        &r->o.mem, &r->on.dev) != 0)
      return 1;
    if ((err = rp_device_set_volume(r->on.dev, r->vol)) != 0 ||
        (err = rp_device_set_tf(r->on.dev, r->tfs[st.tf], r->occ)) != 0)
      return cli_error(r->ctx, "upload", err);
  }
  r->space.space = r->o.space;
  r->space.base_step = r->o.base_step;
  r->space.min_step = r->o.min_step; /* 0, or over base_step: base_step */
  rp_tile_grid(r->o.width, r->o.height, &tx, &ty);
  r->scaled = malloc(px * 4);
  r->image = malloc(px * 4);
  r->tiles = malloc((size_t)tx * ty * sizeof(*r->tiles));
  if (r->scaled == NULL || r->image == NULL || r->tiles == NULL)
    return cli_error(r->ctx, "images", RP_ENOMEM);
  return 0;
}

static void close_scene(replay *r) {
  int i;
  ao_drop_run(r);
  free(r->still_ms);
  free(r->still_seg);
  free(r->scaled);
  free(r->image);
  free(r->tiles);
  rp_device_group_destroy(r->group);
  rp_device_destroy(r->on.dev);
  rp_occupancy_destroy(r->occ);
  for (i = 0; r->tfs != NULL && i < r->tf_count; i++)
    rp_tf_destroy(r->tfs[i]);
  free(r->tfs);
  rp_histograms_destroy(r->h);
  rp_volume_destroy(r->vol);
  rp_sequence_destroy(r->seq);
  rp_context_destroy(r->ctx);
}

/* The command; with `goals`, the goals of one run instead of any output
 * (cli_replay_goals). */
static int replay_main(int argc, char **argv, cli_pacing_goals *goals) {
  replay r;
  rp_controller_kind kinds[RP_CONTROL_COUNT];
  frame_row *rows[RP_CONTROL_COUNT] = {0};
  player players[RP_CONTROL_COUNT];
  summary sums[RP_CONTROL_COUNT];
  char csv_tmp[4096] = "";
  const char *csv;
  int nctl = 0, k, rc;
  memset(&r, 0, sizeof(r));
  memset(players, 0, sizeof(players));
  if (goals != NULL)
    goals_clear(goals);
  if ((rc = parse_opts(argc, argv, &r.o)) != 0)
    return rc == 1 ? 0 : rc;
  if (r.o.list)
    return list_all();
  if (strcmp(r.o.controller, "all") == 0) {
    for (k = 0; k < RP_CONTROL_COUNT; k++)
      kinds[nctl++] = (rp_controller_kind)k;
  } else if (rp_controller_from_name(r.o.controller, &kinds[0]) == 0) {
    nctl = 1;
  } else {
    fprintf(stderr, "raypace replay: unknown controller '%s' (see "
                    "--list)\n", r.o.controller);
    return 2;
  }
  if (r.o.plot != NULL && !cli_have_gnuplot()) {
    fprintf(stderr, "raypace replay: --plot needs gnuplot (Debian "
                    "gnuplot-nox)\n");
    return 1;
  }
  if (r.o.plot != NULL && r.o.csv == NULL &&
      (size_t)snprintf(csv_tmp, sizeof(csv_tmp), "%s.csv", r.o.plot) >=
          sizeof(csv_tmp)) {
    fprintf(stderr, "raypace replay: --plot path too long\n");
    return 2;
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
  if (open_scene(&r) != 0 || r.frames == 0 || calibrate(&r) != 0)
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
  if (r.o.noise_csv != NULL && r.still_ms == NULL)
    fprintf(stderr, "raypace replay: --noise-csv %s not written: no "
                    "still frame with one controller, or out of core "
                    "(the controllers play one after another)\n",
            r.o.noise_csv);
  else if (r.o.noise_csv != NULL && write_noise_csv(&r) != 0)
    goto out;
  for (k = 0; k < nctl; k++) {
    summarise(kinds[k], rows[k], r.frames, rp_space_max_density(&r.space),
              &sums[k]);
    sums[k].devices_alive = players[k].devices_alive;
  }
  if (goals != NULL) {
    goals_compute(&r, sums, nctl, goals);
  } else if (r.o.json) {
    for (k = 0; k < nctl; k++)
      print_json(&r, &sums[k]);
  } else {
    print_table(&r, sums, nctl);
    print_goals(&r, sums, nctl);
  }
  /* Without --csv the plot's data goes to PLOT.csv, removed after. */
  csv = r.o.csv != NULL ? r.o.csv : r.o.plot != NULL ? csv_tmp : NULL;
  if (csv != NULL &&
      write_csv(csv, sums, rows, nctl, r.frames, r.o.ndevices) != 0)
    goto out;
  if (r.o.plot != NULL) {
    char title[256];
    snprintf(title, sizeof(title), "%s: %s, space %s",
             rp_sequence_name(r.seq), r.o.volume,
             rp_space_name(r.space.space));
    if (write_plot(r.o.plot, csv, sums, nctl, title) != 0)
      goto out;
    if (r.o.ndevices >= 2) {
      char dplot[4096];
      size_t len = strlen(r.o.plot);
      if (len >= 4 && strcmp(r.o.plot + len - 4, ".png") == 0)
        len -= 4;
      if ((size_t)snprintf(dplot, sizeof(dplot), "%.*s-devices.png",
                           (int)len, r.o.plot) >= sizeof(dplot)) {
        fprintf(stderr, "raypace replay: --plot path too long\n");
        goto out;
      }
      if (write_device_plot(dplot, csv, sums, nctl, &r) != 0)
        goto out;
    }
    if (csv == csv_tmp)
      remove(csv_tmp);
  }
  rc = 0;
out:
  for (k = 0; k < nctl; k++)
    free(rows[k]);
  close_scene(&r);
  if (r.trace != NULL && fclose(r.trace) != 0 && rc == 0) {
    fprintf(stderr, "raypace replay: --trace %s: write failed\n",
            r.o.trace);
    rc = 1;
  }
  return rc;
}

int cli_cmd_replay(int argc, char **argv) {
  return replay_main(argc, argv, NULL);
}

int cli_replay_goals(int argc, char **argv, cli_pacing_goals *goals) {
  return replay_main(argc, argv, goals);
}
