/* raypace bench pacing: M4's goals (DESIGN section 10) as medians over
 * repeated replays of every controller.
 *
 * One replay's ratios move a lot from run to run on a shared machine
 * (its timing noise drifts over minutes; the still frame of
 * `raypace replay` measures it), so a goal is judged on the median of
 * several runs, each run's figure still a ratio within that run. Every
 * run is `raypace replay VOLUME --sequence S --controller all` with the
 * options given here passed through, played afresh: a new context,
 * device and cost models, as a user's separate runs would be. */
#include <cjson/cJSON.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_pacing.h"
#include "cli_util.h"
#include "raypace_sequence.h"

#define MAX_RUNS CLI_PACING_MAX_RUNS
#define MAX_SEQUENCES CLI_PACING_MAX_SEQUENCES
#define MAX_PASSED CLI_PACING_MAX_PASSED

/* The figures of one sequence's table row, in cli_pacing_goals order. */
enum {
  F_RATIO,
  F_OPEN,
  F_NOISE,
  F_MAX_OVER,
  F_SWITCH_OVER,
  F_DENS_2P,
  F_DENS_LF,
  F_NOISE_SD,
  F_NOISE_MAX,
  F_FULL_MS,
  F_LATE,
  F_OVER_1_2,
  F_EVENT,
  FIGURES
};

static const char *const figure_names[FIGURES] = {
    "ratio",         "ratio_reachable",    "ratio_from_noise",
    "max_overshoot", "switch_overshoot",   "density_vs_two_pass",
    "density_vs_last_frame", "still_sd_best", "still_slowest",
    "no_adaptation_ms", "late", "over_1_2", "event_frame_max"};

static void figures_of(const cli_pacing_goals *g, double *f) {
  f[F_RATIO] = g->ratio;
  f[F_OPEN] = g->ratio_open;
  f[F_NOISE] = g->ratio_noise;
  f[F_MAX_OVER] = g->max_over;
  f[F_SWITCH_OVER] = g->switch_over;
  f[F_DENS_2P] = g->density_two_pass;
  f[F_DENS_LF] = g->density_last_frame;
  f[F_NOISE_SD] = g->noise_sd_best;
  f[F_NOISE_MAX] = g->noise_max_over;
  f[F_FULL_MS] = g->full_ms;
  f[F_LATE] = g->late;
  f[F_OVER_1_2] = g->over_1_2;
  f[F_EVENT] = g->event_frame_max;
}

static void usage(FILE *f) {
  fprintf(f,
      "usage: raypace bench pacing VOLUME [--sequences LIST] [--runs N]\n"
      "                            [replay options] [--json] [--quiet]\n"
      "       raypace bench pacing VOLUME --pareto [--headrooms LIST]\n"
      "                            [--miss-rates LIST] [--controllers "
      "LIST]\n"
      "                            [--plot FILE.png] [--sequences LIST]\n"
      "                            [--runs N] [replay options] [--json]\n\n"
      "Plays each sequence N times under every controller (raypace\n"
      "replay --controller all) and prints M4's goals, each a ratio\n"
      "within one run, as the median over the runs (NaN runs left out),\n"
      "then each run's figures.\n\n"
      "  --sequences LIST      comma-separated built-in names or JSON\n"
      "                        files (default: every built-in sequence)\n"
      "  --runs N              runs per sequence, 1..%d (default 3)\n"
      "  --json                one JSON object per sequence: the medians\n"
      "                        and every run's figures\n"
      "  --quiet               no per-run progress on stderr\n\n"
      "With --pareto, sweeps each reactive rule's headroom and\n"
      "predicted's miss rate instead, and prints each setting's measured\n"
      "miss rate, share over 1.2x the target and mean density (medians\n"
      "over the runs), then predicted's density at its measured miss\n"
      "rate (asked %g) against each rule's there (docs/pacing.md, \"A\n"
      "fair comparison\"). Replay i of a run plays the i-th headroom and\n"
      "the i-th miss rate, every controller once, without the still\n"
      "frame.\n\n"
      "  --pareto              the sweep\n"
      "  --headrooms LIST      the reactive rules' headrooms, each\n"
      "                        'default' (each rule's own: VTK, Valve and\n"
      "                        last-frame none, UE5 0.1) or in (0, 0.9]\n"
      "                        (default %s)\n"
      "  --miss-rates LIST     predicted's miss rates, each 'none' or in\n"
      "                        (0, 0.5] (default %s)\n"
      "  --controllers LIST    of last-frame, vtk, ue5, valve and\n"
      "                        predicted (default all five)\n"
      "  --plot FILE.png       mean density against measured miss rate, a\n"
      "                        panel per sequence, a curve per controller\n"
      "                        (gnuplot)\n\n"
      "Passed to each replay (see raypace replay --help): --target-ms,\n"
      "--target-fraction, --space, --base-step, --min-step, --size,\n"
      "--backend, --device, --settle, --frames, --seed, --miss-rate,\n"
      "--headroom (the last two not with --pareto).\n\n"
      "Columns: ratio = the predicted controller's target RMSE over the\n"
      "best of last-frame, vtk, ue5 and valve (goal <= %g), on all\n"
      "frames and on those whose target was reachable; noise = where\n"
      "the reachable ratio lands from timing noise alone; max_ovr and\n"
      "sw_ovr = its largest overshoot, anywhere and on TF switches (goal\n"
      "<= %g %%); d/2p and d/lf = its mean density over two-pass's (goal\n"
      ">= %g) and last-frame's (>= %g); still_sd and still_max = the\n"
      "still frame's best-predictor spread and slowest frame; late\n"
      "and >1.2T = its share of frames over the target (goal <= %g %%)\n"
      "and over 1.2x it (<= %g %%); event = its slowest TF-switch or\n"
      "camera-cut frame over that frame's target (<= %g); met = the\n"
      "goals the medians meet: R (reachable ratio), O (max overshoot),\n"
      "D (d/2p), L (d/lf), M (late), T (>1.2T), E (event), '.' for\n"
      "one missed.\n",
      MAX_RUNS, CLI_PARETO_COMPARE_AT, CLI_PARETO_HEADROOMS,
      CLI_PARETO_MISS_RATES, CLI_GOAL_RATIO,
      100 * CLI_GOAL_OVERSHOOT, CLI_GOAL_TWO_PASS, CLI_GOAL_LAST_FRAME,
      100 * CLI_GOAL_LATE, 100 * CLI_GOAL_OVER_1_2, CLI_GOAL_EVENT_FRAME);
}

double cli_finite_median(double *v, int n) {
  int i, m = 0;
  for (i = 0; i < n; i++)
    if (isfinite(v[i]))
      v[m++] = v[i];
  return m > 0 ? cli_median(v, m) : NAN;
}

/* One figure of a run's progress line: "-" for NaN, as in the table. */
static void progress_figure(const char *name, double v, double scale,
                            const char *unit) {
  if (isfinite(v))
    fprintf(stderr, "%s %.3g%s", name, scale * v, unit);
  else
    fprintf(stderr, "%s -", name);
}

static void print_cell(double v, const char *fmt, int width) {
  if (isfinite(v))
    printf(fmt, v);
  else
    printf("%*s", width, "-");
}

static void print_row(const char *name, const double *f) {
  printf("%-16s", name);
  print_cell(f[F_RATIO], " %6.3f", 7);
  print_cell(f[F_OPEN], " %9.3f", 10);
  print_cell(f[F_NOISE], " %6.3f", 7);
  print_cell(100 * f[F_MAX_OVER], " %6.1f%%", 8);
  print_cell(100 * f[F_SWITCH_OVER], " %6.1f%%", 8);
  print_cell(f[F_DENS_2P], " %5.2f", 6);
  print_cell(f[F_DENS_LF], " %5.2f", 6);
  print_cell(100 * f[F_NOISE_SD], " %7.1f%%", 9);
  print_cell(100 * f[F_NOISE_MAX], " %8.1f%%", 10);
  print_cell(100 * f[F_LATE], " %5.1f%%", 7);
  print_cell(100 * f[F_OVER_1_2], " %5.1f%%", 7);
  print_cell(f[F_EVENT], " %5.2f", 6);
}

static void print_header(void) {
  printf("%-16s %6s %9s %6s %7s %7s %5s %5s %8s %9s %6s %6s %5s\n",
         "sequence", "ratio", "reachable", "noise", "max_ovr", "sw_ovr",
         "d/2p", "d/lf", "still_sd", "still_max", "late", ">1.2T",
         "event");
}

/* M4's and M10's goals met by the medians f, as letters (usage). A
 * sequence without a TF switch or cut meets the event goal. */
static void goals_met(const double *f, char met[8]) {
  met[0] = f[F_OPEN] <= CLI_GOAL_RATIO ? 'R' : '.';
  met[1] = f[F_MAX_OVER] <= CLI_GOAL_OVERSHOOT ? 'O' : '.';
  met[2] = f[F_DENS_2P] >= CLI_GOAL_TWO_PASS ? 'D' : '.';
  met[3] = f[F_DENS_LF] >= CLI_GOAL_LAST_FRAME ? 'L' : '.';
  met[4] = f[F_LATE] <= CLI_GOAL_LATE ? 'M' : '.';
  met[5] = f[F_OVER_1_2] <= CLI_GOAL_OVER_1_2 ? 'T' : '.';
  met[6] = !(f[F_EVENT] > CLI_GOAL_EVENT_FRAME) ? 'E' : '.';
  met[7] = '\0';
}

static void json_figures(cJSON *o, const double *f) {
  int i;
  for (i = 0; i < FIGURES; i++)
    cJSON_AddNumberToObject(o, figure_names[i], f[i]);
}

static int print_json(const char *sequence, int runs,
                      double (*each)[FIGURES], const double *median) {
  cJSON *o = cJSON_CreateObject(), *m, *a;
  char *text;
  int i;
  if (o == NULL)
    return 1;
  cJSON_AddStringToObject(o, "sequence", sequence);
  cJSON_AddNumberToObject(o, "runs", runs);
  if ((m = cJSON_AddObjectToObject(o, "median")) != NULL)
    json_figures(m, median);
  if ((a = cJSON_AddArrayToObject(o, "each")) != NULL)
    for (i = 0; i < runs; i++) {
      cJSON *r = cJSON_CreateObject();
      if (r == NULL)
        break;
      json_figures(r, each[i]);
      cJSON_AddItemToArray(a, r);
    }
  text = cJSON_PrintUnformatted(o);
  cJSON_Delete(o);
  if (m == NULL || a == NULL || text == NULL) {
    free(text);
    fprintf(stderr, "raypace bench pacing: out of memory\n");
    return 1;
  }
  printf("%s\n", text);
  free(text);
  return 0;
}

/* The sequences to play: --sequences, or every built-in. 0 or 2. */
static int sequences_of(pacing_opts *o) {
  char *tok, *save = NULL;
  if (o->seq_list[0] == '\0') {
    const char *const *builtins = rp_sequence_builtin_names();
    for (; builtins[o->nseq] != NULL && o->nseq < MAX_SEQUENCES; o->nseq++)
      o->seqs[o->nseq] = builtins[o->nseq];
    return 0;
  }
  for (tok = strtok_r(o->seq_list, ",", &save); tok != NULL;
       tok = strtok_r(NULL, ",", &save)) {
    if (o->nseq == MAX_SEQUENCES) {
      fprintf(stderr, "raypace bench pacing: more than %d sequences\n",
              MAX_SEQUENCES);
      return 2;
    }
    o->seqs[o->nseq++] = tok;
  }
  if (o->nseq == 0) {
    fprintf(stderr, "raypace bench pacing: --sequences names none\n");
    return 2;
  }
  return 0;
}

/* --pareto's options without it, or the options it sets per replay
 * with it; 0 or 2 (printed). */
static int check_pareto(const pacing_opts *o) {
  const char *alone = o->headrooms != NULL     ? "--headrooms"
                      : o->miss_rates != NULL  ? "--miss-rates"
                      : o->controllers != NULL ? "--controllers"
                      : o->plot != NULL        ? "--plot"
                                               : NULL;
  int k;
  if (!o->pareto && alone != NULL) {
    fprintf(stderr, "raypace bench pacing: %s needs --pareto\n", alone);
    return 2;
  }
  for (k = 0; o->pareto && k < o->npassed; k++)
    if (strcmp(o->names[k], "--headroom") == 0 ||
        strcmp(o->names[k], "--miss-rate") == 0) {
      fprintf(stderr, "raypace bench pacing: --pareto sweeps %s itself "
                      "(see --%s)\n", o->names[k],
              strcmp(o->names[k], "--headroom") == 0 ? "headrooms"
                                                      : "miss-rates");
      return 2;
    }
  return 0;
}

/* The options passed to each replay, checked as replay checks them
 * before the first run; and --plot. 0 or 2 (printed). */
static int check_passed(const pacing_opts *o) {
  static const char *const png[] = {".png", NULL};
  char *args[CLI_PACING_MAX_ARGS];
  int n = cli_pacing_args(o, o->seqs[0], "all", NULL, 0, args);
  if (o->plot != NULL &&
      cli_check_output("bench pacing", "--plot", o->plot, png) != 0)
    return 2;
  return cli_replay_check("bench pacing", n, args);
}

/* 0, 1 after --help (printed), or 2 (printed). */
static int parse_opts(int argc, char **argv, pacing_opts *o) {
  static const struct option opts[] = {
      {"sequences", required_argument, 0, 'q'},
      {"runs", required_argument, 0, 'r'},
      {"json", no_argument, 0, 'j'},
      {"quiet", no_argument, 0, 'Q'},
      {"help", no_argument, 0, 'h'},
      {"pareto", no_argument, 0, 'x'},
      {"headrooms", required_argument, 0, 'H'},
      {"miss-rates", required_argument, 0, 'M'},
      {"controllers", required_argument, 0, 'c'},
      {"plot", required_argument, 0, 'P'},
      /* passed through */
      {"target-ms", required_argument, 0, 'p'},
      {"target-fraction", required_argument, 0, 'p'},
      {"space", required_argument, 0, 'p'},
      {"base-step", required_argument, 0, 'p'},
      {"min-step", required_argument, 0, 'p'},
      {"size", required_argument, 0, 'p'},
      {"backend", required_argument, 0, 'p'},
      {"device", required_argument, 0, 'p'},
      {"settle", required_argument, 0, 'p'},
      {"frames", required_argument, 0, 'p'},
      {"seed", required_argument, 0, 'p'},
      {"miss-rate", required_argument, 0, 'p'},
      {"headroom", required_argument, 0, 'p'},
      {0, 0, 0, 0}};
  int c, li = 0;
  memset(o, 0, sizeof *o);
  o->runs = 3;
  optind = 0; /* as replay's: forget any scan before */
  while ((c = getopt_long(argc, argv, "h", opts, &li)) != -1) {
    switch (c) {
    case 'q':
      if (strlen(optarg) >= sizeof o->seq_list) {
        fprintf(stderr, "raypace bench pacing: --sequences too long\n");
        return 2;
      }
      strcpy(o->seq_list, optarg);
      break;
    case 'r':
      if (cli_parse_whole("bench pacing", "--runs", optarg, 1, MAX_RUNS,
                          &o->runs) != 0)
        return 2;
      break;
    case 'j': o->json = 1; break;
    case 'Q': o->quiet = 1; break;
    case 'h': usage(stdout); return 1;
    case 'x': o->pareto = 1; break;
    case 'H': o->headrooms = optarg; break;
    case 'M': o->miss_rates = optarg; break;
    case 'c': o->controllers = optarg; break;
    case 'P': o->plot = optarg; break;
    case 'p':
      if (o->npassed == MAX_PASSED) {
        fprintf(stderr, "raypace bench pacing: more than %d options to "
                        "pass to replay\n", MAX_PASSED);
        return 2;
      }
      snprintf(o->names[o->npassed], sizeof o->names[0], "--%s",
               opts[li].name);
      o->passed[2 * o->npassed] = o->names[o->npassed];
      o->passed[2 * o->npassed + 1] = optarg;
      o->npassed++;
      break;
    default: usage(stderr); return 2;
    }
  }
  if (optind + 1 != argc) {
    usage(stderr);
    return 2;
  }
  /* Each replay parses its own options: optind is not ours after. */
  o->volume = argv[optind];
  if (check_pareto(o) != 0 || sequences_of(o) != 0)
    return 2;
  return check_passed(o);
}

int cli_pacing_args(const pacing_opts *o, const char *seq,
                    const char *controller, char *const *extra, int nextra,
                    char **args) {
  int n = 0, k;
  args[n++] = "replay";
  args[n++] = "--sequence";
  args[n++] = (char *)seq;
  args[n++] = "--controller";
  args[n++] = (char *)controller;
  args[n++] = "--quiet";
  for (k = 0; k < 2 * o->npassed; k++)
    args[n++] = o->passed[k];
  for (k = 0; k < nextra && k < CLI_PACING_MAX_EXTRA; k++)
    args[n++] = extra[k];
  /* A volume named like an option is still the volume. */
  args[n++] = "--";
  args[n++] = (char *)o->volume;
  args[n] = NULL;
  return n;
}

/* Run i of sequence `seq`: one replay of every controller, its figures
 * into f. */
static int play_run(const pacing_opts *o, const char *seq, int i,
                    double *f) {
  char *args[CLI_PACING_MAX_ARGS];
  cli_pacing_goals g;
  int n = cli_pacing_args(o, seq, "all", NULL, 0, args), rc;
  if ((rc = cli_replay_goals(n, args, &g)) != 0) {
    fprintf(stderr, "raypace bench pacing: %s, run %d failed\n", seq,
            i + 1);
    return rc;
  }
  figures_of(&g, f);
  if (!o->quiet) {
    fprintf(stderr, "bench pacing: %s run %d/%u:", seq, i + 1, o->runs);
    progress_figure(" ratio", g.ratio, 1, "");
    progress_figure(", reachable", g.ratio_open, 1, "");
    progress_figure(", from noise", g.ratio_noise, 1, "");
    progress_figure(", max overshoot", g.max_over, 100, "%");
    fputc('\n', stderr);
  }
  return 0;
}

/* Every run of sequence s, then its medians' row (or JSON). */
static int play_sequence(const pacing_opts *o, int s,
                         double (*run)[FIGURES]) {
  double median[FIGURES], column[MAX_RUNS];
  char met[8];
  int i, k, rc;
  for (i = 0; i < (int)o->runs; i++) {
    for (k = 0; k < FIGURES; k++)
      run[i][k] = NAN; /* a figure the run does not give */
    if ((rc = play_run(o, o->seqs[s], i, run[i])) != 0)
      return rc;
  }
  for (k = 0; k < FIGURES; k++) {
    for (i = 0; i < (int)o->runs; i++)
      column[i] = run[i][k];
    median[k] = cli_finite_median(column, (int)o->runs);
  }
  if (o->json)
    return print_json(o->seqs[s], (int)o->runs, run, median);
  print_row(o->seqs[s], median);
  goals_met(median, met);
  printf("  met %s\n", met);
  fflush(stdout);
  return 0;
}

int cli_cmd_bench_pacing(int argc, char **argv) {
  pacing_opts o;
  double(*each)[FIGURES] = NULL;
  int rc, s, i, k;
  if ((rc = parse_opts(argc, argv, &o)) != 0)
    return rc == 1 ? 0 : rc;
  if (o.pareto)
    return cli_bench_pareto(&o);
  each = malloc((size_t)o.nseq * o.runs * sizeof *each);
  if (each == NULL) {
    fprintf(stderr, "raypace bench pacing: out of memory\n");
    return 1;
  }
  if (!o.json) {
    printf("bench pacing: %s, %u run%s per sequence, every controller",
           o.volume, o.runs, o.runs == 1 ? "" : "s");
    for (k = 0; k < o.npassed; k++)
      printf("%s%s %s", k == 0 ? " (" : " ", o.passed[2 * k],
             o.passed[2 * k + 1]);
    printf("%s; medians over the runs\n", o.npassed > 0 ? ")" : "");
    print_header();
  }
  for (s = 0; s < o.nseq; s++)
    if ((rc = play_sequence(&o, s, each + (size_t)s * o.runs)) != 0)
      goto out;
  if (!o.json && o.runs > 1) {
    printf("each run:\n");
    print_header();
    for (s = 0; s < o.nseq; s++)
      for (i = 0; i < (int)o.runs; i++) {
        char name[80];
        snprintf(name, sizeof name, "%.56s #%d", o.seqs[s], i + 1);
        print_row(name, each[(size_t)s * o.runs + i]);
        printf("\n");
      }
  }
out:
  free(each);
  return rc;
}
