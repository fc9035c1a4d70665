/* raypace replay, shared between the driver (replay.c: plays the
 * sequence through rp_runtime) and its report (replay_report.c: the
 * summaries, the goals, the table, JSON, CSV and plots). */
#ifndef RP_CLI_REPLAY_H
#define RP_CLI_REPLAY_H

#include <stdint.h>
#include <stdio.h>

#include "cli_util.h"
#include "commands.h"
#include "raypace.h"
#include "raypace_group.h"
#include "raypace_pace.h"
#include "raypace_runtime.h"
#include "raypace_sequence.h"

typedef struct replay_opts {
  const char *volume, *sequence, *controller, *backend, *csv, *plot;
  const char *trace, *noise_csv;
  double target_ms, target_fraction;
  double miss_rate; /* --miss-rate; 0: the runtime's default */
  double headroom;  /* --headroom; 0: each reactive rule's own */
  uint32_t split;   /* --split R: repeats of each frame; 0: no split */
#define REPLAY_SPLIT_MAX 50
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

/* One device's part of a frame (--devices): its share and region are the
 * last pass's, its times and samples the frame's. */
typedef struct device_row {
  double share, busy_ms, raycast_ms;
  uint64_t samples;
  double strip_share; /* the tail strips it took (rp_group_desc) */
} device_row;

/* What happens on a recorded frame, from its sequence state
 * (replay_frame_events): bits of a mask. */
#define REPLAY_EV_TF 1u      /* a TF switch */
#define REPLAY_EV_CUT 2u     /* a camera cut (docs/sequences.md) */
#define REPLAY_EV_EFFECTS 4u /* the effect set changed */
#define REPLAY_EV_TARGET 8u  /* the target changed */

/* The report's event classes (docs/pacing.md): class 0 is smooth, class
 * c > 0 holds the frames of event bit c - 1 and the REPLAY_CLASS_AFTER
 * frames after each (replay_frame_classes). A rule that reacts to the
 * last frame learns of an event from the event frame's own time, so the
 * miss the event costs it lands on that frame and the next one or two;
 * counted as smooth, they would flatter it on the event. A frame in the
 * reach of several events counts in each of their classes; smooth
 * frames are in the reach of none. */
#define REPLAY_CLASSES 5
#define REPLAY_CLASS_AFTER 2

/* What a controller's frames of one class came to; NaN figures for a
 * class without frames. */
typedef struct class_stats {
  uint32_t frames;
  double miss_rate;      /* share with measured_ms > target_ms */
  double share_over_1_2; /* share with measured_ms > 1.2 target_ms */
  double p95, p99;       /* of measured_ms / target_ms (cli_quantile) */
  double mean_density;
} class_stats;

/* One recorded frame of one controller: what its runtime reported
 * (rp_frame_stats). */
typedef struct frame_row {
  uint32_t frame;
  int passes;
  uint32_t events; /* REPLAY_EV_* */
  double target_ms, measured_ms, predicted_ms;
  double pass_predicted_ms; /* the cost model's t' of the last pass */
  double render_ms; /* the render passes (rp_frame_stats.render_ms) */
  uint32_t effects; /* rendered */
  double margin;    /* the predicted controller's (rp_frame_stats) */
  double novelty;   /* the cost model's, when the controller decided */
  /* --split (replay_split.c): the same frame on a runtime of its own,
   * at the same density: its first render after the frame before, and
   * the median and standard deviation of the R renders right after it.
   * NaN where not measured. */
  double split_first_ms, split_ms, split_sd_ms;
  double probe_ms;  /* the probe and the controller's decision */
  double ao_ms;     /* the AO step (in measured_ms) */
  int ao;           /* rendered with AO */
  double upload_ms, upload_pred_ms; /* out of core: bricks uploaded, and
                                       predicted */
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

/* --split: where the predicted controller's error comes from
 * (docs/pacing.md, "Where the error comes from"). Over its single-pass
 * frames whose split run rendered the same effects, each term a share
 * of the frame's target: the pass's error (render - t') is the sum of
 * - context: render - first, what running in the replay (interleaved
 *   with the other controllers' runtimes, or not) added to the frame;
 * - switching: first - settled, what the first render at the frame's
 *   settings, right after the frame before's, costs over the same frame
 *   rendered again and again (new step or scale, buffers, kernels,
 *   caches);
 * - model: settled - t', the cost model's own error;
 * and noise is the repeats' own spread (the machine at fixed settings),
 * part of each term. `outside` is the frame's error (measured -
 * predicted) less the pass's: what happened outside the render passes
 * after the decision. */
typedef struct error_split {
  uint32_t frames, repeats;
  double pass_rms, context_rms, switch_rms, model_rms, noise_rms;
  double pass_mean, context_mean, switch_mean, model_mean;
  double frame_rms, outside_rms;
  /* Each term beyond what the noise alone would give it: sqrt(max(0,
   * rms^2 - v)), v the noise's share of its mean square (noise_rms^2
   * times 2 for context, two single renders; 1 + pi / 2R for switching,
   * a render less a median of R; pi / 2R for the model, a median of R). */
  double context_excess, switch_excess, model_excess;
  /* The typical frame's: the median of each term's absolute value (the
   * noise's: the median of the repeats' spreads). The machine's bursts
   * (a frame twice as long, now and then) are heavy tails that the rms
   * weighs by their square. */
  double pass_med, context_med, switch_med, model_med, noise_med;
} error_split;

typedef struct summary {
  rp_controller_kind kind;
  uint32_t frames;
  double rmse_ms, rmse_rel, max_over, share_over_20, mean_density;
  double miss_rate;    /* share with measured_ms > target_ms */
  double rmse_open_ms; /* over frames where the target was reachable */
  double switch_over;  /* max overshoot on a TF switch and SWITCH_AFTER
                          frames after it; 0 without switches */
  double pred_rmse_ms, sigma_err_30, overhead_ms, mean_ms, mean_target;
  double mean_imbalance; /* --devices */
  uint32_t devices_alive; /* --devices: at the end of the run */
  class_stats classes[REPLAY_CLASSES];
  /* The slowest frame of a TF switch or camera cut itself, t / target;
   * NaN without one. */
  double event_frame_max;
  error_split split; /* --split: the predicted controller's */
} summary;

/* What the report needs of a finished replay. */
typedef struct replay_result {
  const replay_opts *o;
  const rp_sequence *seq;
  uint32_t frames;
  rp_space_desc space;
  double full_ms;        /* the frame without adaptation, at the start */
  noise_floor noise;
  char device_names[RP_GROUP_MAX_DEVICES][168]; /* --devices */
  const double *still_ms;      /* per recorded frame, or NULL */
  const uint32_t *still_seg;
} replay_result;

typedef struct replay replay;

/* ---- replay.c: the players (for replay_split.c) ---------------------- */

/* One runtime and the sequence's events it was last given. */
typedef struct player {
  replay *r;
  rp_controller_kind kind;
  rp_runtime *rt;
  frame_row *rows;       /* the recorded frames; NULL for the still */
  int tf;                /* the TF index posted; -1: none yet */
  uint32_t effects;
  int have_effects;
  double target;
  rp_camera cam;
  int have_cam;
  rp_frame_stats st;     /* the last frame's */
  uint32_t step_no;      /* frames stepped in the sequence (--trace) */
  int tracing;           /* its controller plays: frames are numbered */
  uint32_t devices_alive; /* --devices: after its frames */
} player;

struct replay {
  replay_opts o;
  rp_context *ctx;
  rp_volume *vol; /* for cameras; each runtime loads a volume of its own */
  rp_tf **tfs;
  int tf_count;
  rp_sequence *seq;
  uint32_t frames;
  rp_space_desc space;
  const char *backend; /* what the runtimes open: --backend, or the
                          reference when nothing else is here */
  double full_ms;     /* frame time without adaptation, at the start */
  double seq_target0; /* the sequence's first target, ms */
  rp_camera still_cam;
  double *still_ms;   /* per recorded frame */
  uint32_t *still_seg;
  int still_tf;
  uint32_t still_effects;
  noise_floor noise;
  char device_names[RP_GROUP_MAX_DEVICES][168];
  FILE *trace; /* --trace */
  /* --split: the runtime that renders the predicted controller's frames
   * again (replay_split.c), and room for its repeats' times. */
  player split;
  double *split_t;
};

/* Steps p's runtime one frame; 1 (printed) when it failed. */
int replay_step(player *p, const char *what);
/* Posts what frame `st` changes for p's runtime (each only when it
 * differs from what it was last given); 0 or 1 (printed). */
int replay_post_state(replay *r, player *p, const rp_sequence_state *st,
                      const rp_camera *cam, double target);
/* The target of frame `st`, as the command line scales it. */
double replay_frame_target(const replay *r, const rp_sequence_state *st);
/* Frame f's state and camera; 0 or 1 (printed). */
int replay_sequence_frame(replay *r, uint32_t f, rp_sequence_state *st,
                          rp_camera *cam);
/* A warm runtime for p->kind with a volume of its own; RP_ENODEV
 * unprinted with quiet_nodev, any other failure printed and 1. */
int replay_player_open(replay *r, player *p, int quiet_nodev);
void replay_player_close(player *p);

/* ---- replay_split.c ---------------------------------------------------- */

/* --split: opens r->split, the runtime that renders each frame of the
 * predicted controller again (controller none, at the density the
 * controller chose), right after it; 0 or 1 (printed). */
int replay_split_open(replay *r);
void replay_split_close(replay *r);
/* Frame f of the sequence (a settle frame when row is NULL) on r->split,
 * at the density p's runtime just rendered it at: once, and for a
 * recorded row R times more, into its split_* figures; 0 or 1
 * (printed). */
int replay_split_frame(replay *r, const player *p, uint32_t f,
                       frame_row *row);
/* The split's figures over n rows into *out. */
void replay_split_summarise(const frame_row *rows, uint32_t n,
                            uint32_t repeats, error_split *out);

/* ---- replay_report.c ---------------------------------------------------- */

/* The spread of n still-frame times `ms` in segments `seg` into *out
 * (its rho kept); `work` holds n doubles. */
void replay_noise_stats(const double *ms, const uint32_t *seg, uint32_t n,
                        double *work, noise_floor *out);
/* The events of sequence frame `st`: 0 on frame 0, which the settle
 * frames played before it was recorded. */
uint32_t replay_frame_events(const rp_sequence_state *st);
/* The events whose reach frame i of `rows` (indexed by frame) is in:
 * those of frames i - REPLAY_CLASS_AFTER to i; 0 for a smooth frame. */
uint32_t replay_frame_classes(const frame_row *rows, uint32_t i);
/* Class c's name: "smooth", "tf_switch", "camera_cut", "effect_toggle",
 * "target_change". */
const char *replay_class_name(int c);
/* The summary of one controller's n rows; 0, or RP_ENOMEM. */
int replay_summarise(rp_controller_kind kind, const frame_row *rows,
                     uint32_t n, double rho_max, summary *s);
/* The goals as ratios within this run; NaN where the controllers a
 * figure compares were not played. */
void replay_goals(const replay_result *r, const summary *sums, int nctl,
                  cli_pacing_goals *g);
void replay_goals_clear(cli_pacing_goals *g);
/* The outputs the options ask for: table and goal line, or JSON; the
 * CSV, the noise CSV and the plots. 0, or 1 (printed). */
int replay_report(const replay_result *r, const summary *sums,
                  frame_row *const *rows, int nctl);

#endif
