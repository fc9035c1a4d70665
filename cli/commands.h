/* Subcommands of the raypace command that live in their own files. Each
 * takes argv with argv[0] = the subcommand's name and returns the exit
 * status. */
#ifndef RP_CLI_COMMANDS_H
#define RP_CLI_COMMANDS_H

#include <stdint.h>

#include "raypace.h"

/* raypace replay VOLUME ...: cli/replay.c */
int cli_cmd_replay(int argc, char **argv);
/* The goals of M4 (DESIGN section 10) from one replay of every
 * controller, each a ratio within the run; NaN where the controllers it
 * compares were not played, where the rule compared with had no error
 * (or no reachable frame, for ratio_open and ratio_noise), or where
 * there was no still frame. The goals' bounds, for the replay's goal
 * line and bench pacing's table alike: */
#define CLI_GOAL_RATIO 0.5       /* ratio_open <= */
#define CLI_GOAL_OVERSHOOT 0.25  /* max_over <= */
#define CLI_GOAL_TWO_PASS 1.5    /* density_two_pass >= */
#define CLI_GOAL_LAST_FRAME 0.9  /* density_last_frame >= */
/* M10's, at miss_rate 0.05: */
#define CLI_GOAL_LATE 0.07       /* late <= */
#define CLI_GOAL_OVER_1_2 0.02   /* over_1_2 <= */
#define CLI_GOAL_EVENT_FRAME 1.25 /* event_frame_max <= */
typedef struct cli_pacing_goals {
  double ratio;       /* predicted's target RMSE / the best of last-frame,
                         vtk, ue5 and valve */
  double ratio_open;  /* the same over frames whose target was reachable */
  double ratio_noise; /* where ratio_open lands from timing noise alone:
                         the still frame's sd_best x target / that best */
  double max_over, switch_over;         /* predicted's, as fractions */
  double density_two_pass;              /* predicted's / two-pass's */
  double density_last_frame;            /* predicted's / last-frame's */
  double noise_sd_best, noise_max_over; /* the still frame's */
  double full_ms; /* the no-adaptation frame, measured at the start */
  /* M10's, predicted's: its share of frames over the target and over
   * 1.2x it, and its slowest frame of a TF switch or camera cut against
   * that frame's target (NaN without one). */
  double late, over_1_2, event_frame_max;
} cli_pacing_goals;

/* Plays `raypace replay` with argv (argv[0] = "replay") and fills goals
 * instead of printing (all NaN if it stops before the summaries);
 * returns the command's exit status. */
int cli_replay_goals(int argc, char **argv, cli_pacing_goals *goals);
/* What one controller's frames came to in one replay, over all its
 * recorded frames. */
typedef struct cli_replay_point {
  rp_controller_kind kind;
  uint32_t frames;
  double miss_rate;      /* share with measured_ms > target_ms */
  double share_over_1_2; /* share with measured_ms > 1.2 target_ms */
  double mean_density;
} cli_replay_point;
/* Plays `raypace replay` with argv (argv[0] = "replay") and fills
 * points[0..*n) (room for RP_CONTROL_COUNT), one per controller played
 * in --controller's order, instead of printing (*n = 0 if it stops
 * before the summaries); returns the command's exit status. */
int cli_replay_points(int argc, char **argv, cli_replay_point *points,
                      int *n);
/* Parses `raypace replay`'s options in argv (argv[0] = "replay") and
 * checks them as a replay would, doing nothing else; the messages name
 * `cmd` ("bench pacing", which passes options on). 0, or 2 (printed). */
int cli_replay_check(const char *cmd, int argc, char **argv);
/* raypace bench pacing VOLUME ...: cli/bench_pacing.c */
int cli_cmd_bench_pacing(int argc, char **argv);
/* raypace bench quality VOLUME ...: cli/bench.c */
int cli_cmd_bench(int argc, char **argv);
/* raypace bench overhead VOLUME ...: cli/bench_overhead.c */
int cli_cmd_bench_overhead(int argc, char **argv);

#endif
