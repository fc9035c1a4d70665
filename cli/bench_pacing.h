/* raypace bench pacing, shared between its goals (bench_pacing.c: M4's
 * ratios over repeated replays) and its Pareto sweep (bench_pareto.c,
 * --pareto: density against measured miss rate, each reactive rule's
 * headroom and predicted's miss rate swept). */
#ifndef RP_CLI_BENCH_PACING_H
#define RP_CLI_BENCH_PACING_H

#include <stdint.h>

#include "commands.h"

#define CLI_PACING_MAX_RUNS 100
#define CLI_PACING_MAX_SEQUENCES 32
/* The options passed through to replay: each with its value. */
#define CLI_PACING_MAX_PASSED 16
/* What a replay's argv may hold: its own options, the passed ones, the
 * extra ones a caller adds (at most CLI_PACING_MAX_EXTRA), "--", the
 * volume and the NULL. */
#define CLI_PACING_MAX_EXTRA 8
#define CLI_PACING_MAX_ARGS \
  (9 + 2 * CLI_PACING_MAX_PASSED + CLI_PACING_MAX_EXTRA)

/* What the command line asks for. */
typedef struct pacing_opts {
  const char *seqs[CLI_PACING_MAX_SEQUENCES], *volume;
  int nseq;
  char *passed[2 * CLI_PACING_MAX_PASSED]; /* option, value pairs */
  char names[CLI_PACING_MAX_PASSED][24];   /* "--" and an option's name */
  int npassed;
  char seq_list[4096];
  uint32_t runs;
  int json, quiet;
  /* --pareto and its options; NULL: the defaults (bench_pareto.c). */
  int pareto;
  const char *headrooms, *miss_rates, *controllers, *plot;
} pacing_opts;

/* The argv of one replay of sequence `seq` under `controller`: replay's
 * own options, the passed ones, extra[0..nextra) (nextra <=
 * CLI_PACING_MAX_EXTRA), then "--" and the volume; args holds
 * CLI_PACING_MAX_ARGS. Returns argc. */
int cli_pacing_args(const pacing_opts *o, const char *seq,
                    const char *controller, char *const *extra, int nextra,
                    char **args);
/* The median of the finite values among v[0..n) (reordered); NaN if
 * none. */
double cli_finite_median(double *v, int n);

/* ---- bench_pareto.c ------------------------------------------------------ */

/* The goals of M10 (issue 29) the comparison is held to: predicted's
 * mean density over the best reactive rule's at its measured miss rate,
 * and over vtk's as VTK ships it. */
#define CLI_GOAL_PARETO_BEST 1.3
#define CLI_GOAL_PARETO_VTK 1.5
/* The miss rate predicted is compared at: the runtime's default. */
#define CLI_PARETO_COMPARE_AT 0.05
/* The default settings: from each reactive rule as it ships (at or
 * near the target: about half its frames late) to half the target kept
 * free, where a frame must take twice what its rule aimed for to be
 * late, which a frame-to-frame scatter of 0.6 to 1.4x (issue 29) all
 * but never gives; and the contract's miss rates from strict to loose
 * (docs/pacing.md, "A fair comparison"). */
#define CLI_PARETO_HEADROOMS "default,0.05,0.1,0.2,0.3,0.4,0.5"
#define CLI_PARETO_MISS_RATES "0.01,0.02,0.05,0.1,0.2,0.3"
/* The most settings a list may hold. */
#define CLI_PARETO_MAX_SETTINGS 16

/* Where a miss rate lies against a rule's measured curve
 * (cli_pareto_density_at). */
enum {
  CLI_PARETO_INSIDE, /* within its measured miss rates: interpolated */
  CLI_PARETO_ABOVE,  /* over its largest: its best density, a floor */
  CLI_PARETO_BELOW,  /* under its smallest: unknown, NaN */
  CLI_PARETO_EMPTY   /* no finite point (or more than the most): NaN */
};

/* A rule's density at miss rate m, from its measured points (miss[i],
 * density[i]), i < n <= CLI_PARETO_MAX_SETTINGS, non-finite points left
 * out: along the upper envelope of what it reached, the most density it
 * had at a miss rate at most m. Sorted by miss rate, a point is kept
 * when its density is over every point's with a smaller or equal miss
 * rate (the frontier); m between two kept points is interpolated
 * linearly, m past the last kept point but within the measured range
 * takes that point's density. Under the smallest measured miss rate:
 * NaN (BELOW); over the largest: the frontier's top density (ABOVE), a
 * floor, as the rule never missed that often. *where (may be NULL)
 * says which. */
double cli_pareto_density_at(const double *miss, const double *density,
                             int n, double m, int *where);

/* The reactive rules a comparison holds, in this order. */
#define CLI_PARETO_RULES 4
extern const rp_controller_kind cli_pareto_rules[CLI_PARETO_RULES];

/* One run's comparison. */
typedef struct cli_pareto_cmp {
  double miss, density;          /* predicted's, at the compared rate */
  double at[CLI_PARETO_RULES];   /* each rule's density at `miss` */
  int where[CLI_PARETO_RULES];   /* CLI_PARETO_* */
  int best;                      /* the rule with the most there; -1 */
  double ratio_best;             /* density / at[best] */
  double vtk_shipped, ratio_vtk; /* vtk at its own headroom; density /
                                    vtk_shipped */
} cli_pareto_cmp;

/* Compares predicted's point (miss, density) with each rule r's curve
 * (miss[r][i], density[r][i]), i < n[r]; vtk_shipped is vtk's density
 * at its own headroom (NaN when not played). Ties for the best go to
 * the earlier rule. */
void cli_pareto_compare(double miss, double density,
                        double (*rule_miss)[CLI_PARETO_MAX_SETTINGS],
                        double (*rule_density)[CLI_PARETO_MAX_SETTINGS],
                        const int *n, double vtk_shipped,
                        cli_pareto_cmp *out);

/* raypace bench pacing --pareto: 0, or the exit status (printed). */
int cli_bench_pareto(const pacing_opts *o);

#endif
