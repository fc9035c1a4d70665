/* raypace bench pacing --pareto: M10's fair comparison (issue 29, point
 * 3). A reactive rule's miss rate is set by its headroom, so a rule that
 * misses more renders more: comparing densities means comparing them at
 * the same measured miss rate. Each reactive rule's headroom and
 * predicted's miss rate are swept; each setting's measured miss rate,
 * share over 1.2x the target and mean density make one point of its
 * controller's curve, and predicted's density at its measured miss rate
 * is held against each rule's curve there (docs/pacing.md, "A fair
 * comparison").
 *
 * Replay i of a run plays every chosen controller once: the reactive
 * rules at the i-th headroom, predicted at the i-th miss rate. A run is
 * thus as many replays as the longer list has settings, and every
 * controller of a replay meets the same spell of the machine. The still
 * frame is left out (--no-noise): it is no point of any curve, and a
 * frame rendered between the controllers' own would add a render per
 * round. */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_pacing.h"
#include "cli_util.h"

#define MAX_SET CLI_PARETO_MAX_SETTINGS
#define RULES CLI_PARETO_RULES
/* The controllers a sweep plays: the reactive rules, then predicted. */
#define CTLS (RULES + 1)
#define PRED RULES
#define VTK 1

const rp_controller_kind cli_pareto_rules[RULES] = {
    RP_CONTROL_LAST_FRAME, RP_CONTROL_VTK, RP_CONTROL_UE5,
    RP_CONTROL_VALVE};

/* The default lists (bench_pacing.h; docs/pacing.md says why). */
static const char DEFAULT_HEADROOMS[] = CLI_PARETO_HEADROOMS;
static const char DEFAULT_MISS_RATES[] = CLI_PARETO_MISS_RATES;

/* ---- the comparison ------------------------------------------------------ */

double cli_pareto_density_at(const double *miss, const double *density,
                             int n, double m, int *where) {
  int idx[MAX_SET], k = 0, i, j, kept = 0, w = CLI_PARETO_EMPTY;
  double fm[MAX_SET], fd[MAX_SET], d = NAN;
  for (i = 0; i < n && n <= MAX_SET; i++)
    if (isfinite(miss[i]) && isfinite(density[i]))
      idx[k++] = i;
  /* Insertion sort by miss rate, the denser first on a tie. */
  for (i = 1; i < k; i++)
    for (j = i; j > 0; j--) {
      int a = idx[j - 1], b = idx[j], t;
      if (miss[a] < miss[b] ||
          (miss[a] == miss[b] && density[a] >= density[b]))
        break;
      t = idx[j - 1];
      idx[j - 1] = idx[j];
      idx[j] = t;
    }
  /* The frontier: each point denser than every one before it. */
  for (i = 0; i < k; i++)
    if (kept == 0 || density[idx[i]] > fd[kept - 1]) {
      fm[kept] = miss[idx[i]];
      fd[kept++] = density[idx[i]];
    }
  if (k == 0 || !isfinite(m)) {
    w = CLI_PARETO_EMPTY;
  } else if (m < miss[idx[0]]) {
    w = CLI_PARETO_BELOW;
  } else if (m > miss[idx[k - 1]]) {
    w = CLI_PARETO_ABOVE;
    d = fd[kept - 1];
  } else {
    w = CLI_PARETO_INSIDE;
    for (i = 0; i + 1 < kept && fm[i + 1] <= m; i++)
      ;
    d = fd[i];
    /* fm[i] <= m < fm[i + 1]: on the segment between them. */
    if (i + 1 < kept)
      d += (fd[i + 1] - fd[i]) * (m - fm[i]) / (fm[i + 1] - fm[i]);
  }
  if (where != NULL)
    *where = w;
  return d;
}

void cli_pareto_compare(double miss, double density,
                        double (*rule_miss)[CLI_PARETO_MAX_SETTINGS],
                        double (*rule_density)[CLI_PARETO_MAX_SETTINGS],
                        const int *n, double vtk_shipped,
                        cli_pareto_cmp *out) {
  int r;
  out->miss = miss;
  out->density = density;
  out->best = -1;
  for (r = 0; r < RULES; r++) {
    out->at[r] = cli_pareto_density_at(rule_miss[r], rule_density[r], n[r],
                                       miss, &out->where[r]);
    if (isfinite(out->at[r]) &&
        (out->best < 0 || out->at[r] > out->at[out->best]))
      out->best = r;
  }
  out->ratio_best = out->best >= 0 && isfinite(density)
                        ? density / out->at[out->best]
                        : NAN;
  out->vtk_shipped = vtk_shipped;
  out->ratio_vtk = density / vtk_shipped; /* NaN when either is */
}

/* ---- the plan ------------------------------------------------------------ */

/* A setting as typed ("default", "none", or a number) and its value: 0
 * for "default", -1 for "none". */
typedef struct setting {
  char text[24];
  double value;
} setting;

/* What the sweep plays. */
typedef struct plan {
  setting head[MAX_SET], miss[MAX_SET];
  int nhead, nmiss;
  int plays[CTLS]; /* the controller is chosen */
  int replays;     /* per run: the longer list's length */
  int compare_at;  /* predicted's setting compared; -1: none */
  int shipped;     /* the "default" headroom's setting; -1: none */
} plan;

/* The settings of `list` for `option`: headrooms in (0, 0.9] or
 * "default", miss rates in (0, 0.5] or "none". 0 or 2 (printed). */
static int parse_settings(const char *list, const char *option,
                          int headroom, setting *out, int *n) {
  const char *p = list;
  *n = 0;
  for (;;) {
    size_t len = strcspn(p, ",");
    setting *s = &out[*n];
    if (*n == MAX_SET || len == 0 || len >= sizeof s->text) {
      fprintf(stderr, "raypace bench pacing: %s '%s': %s\n", option, list,
              *n == MAX_SET ? "more than 16 settings"
              : len == 0    ? "an empty setting"
                            : "a setting too long");
      return 2;
    }
    memcpy(s->text, p, len);
    s->text[len] = '\0';
    if (strcmp(s->text, headroom ? "default" : "none") == 0) {
      s->value = headroom ? 0.0 : -1.0;
    } else {
      /* replay's ranges for --headroom and --miss-rate. */
      cli_range r = {0.0, 0.5, CLI_OPEN_LO, 0, "of the frames"};
      const char *problem;
      char what[320], want[96];
      if (headroom)
        r.hi = 0.9, r.unit = "of the target";
      /* As typed, not as the float replay parses it to: the JSON's. */
      if ((problem = cli_number_problem(s->text, &r, &s->value)) != NULL) {
        snprintf(what, sizeof what, "%s %s:", option, list);
        cli_range_text(&r, want, sizeof want);
        return cli_bad_option("bench pacing", what, s->text, problem,
                              "must be %s, or %s", want,
                              headroom ? "default" : "none");
      }
    }
    (*n)++;
    if (p[len] == '\0')
      return 0;
    p += len + 1;
  }
}

/* The controller of sweep slot c. */
static rp_controller_kind kind_of(int c) {
  return c == PRED ? RP_CONTROL_PREDICTED : cli_pareto_rules[c];
}

/* --controllers into pl->plays; 0 or 2 (printed). */
static int parse_controllers(const char *list, plan *pl) {
  const char *p = list;
  for (;;) {
    size_t len = strcspn(p, ",");
    int c, found = -1;
    for (c = 0; c < CTLS; c++) {
      const char *name = rp_controller_name(kind_of(c));
      if (strlen(name) == len && strncmp(p, name, len) == 0)
        found = c;
    }
    if (found < 0) {
      fprintf(stderr, "raypace bench pacing: --controllers '%s': '%.*s' "
                      "is not one of last-frame, vtk, ue5, valve, "
                      "predicted\n", list, (int)len, p);
      return 2;
    }
    pl->plays[found] = 1;
    if (p[len] == '\0')
      return 0;
    p += len + 1;
  }
}

/* How many settings slot c sweeps. */
static int settings_of(const plan *pl, int c) {
  return c == PRED ? pl->nmiss : pl->nhead;
}

static const setting *setting_of(const plan *pl, int c, int i) {
  return c == PRED ? &pl->miss[i] : &pl->head[i];
}

/* 0 or 2 (printed). */
static int plan_of(const pacing_opts *o, plan *pl) {
  int c, i, rules = 0;
  memset(pl, 0, sizeof *pl);
  if (parse_settings(o->headrooms ? o->headrooms : DEFAULT_HEADROOMS,
                     "--headrooms", 1, pl->head, &pl->nhead) != 0 ||
      parse_settings(o->miss_rates ? o->miss_rates : DEFAULT_MISS_RATES,
                     "--miss-rates", 0, pl->miss, &pl->nmiss) != 0)
    return 2;
  if (o->controllers == NULL)
    for (c = 0; c < CTLS; c++)
      pl->plays[c] = 1;
  else if (parse_controllers(o->controllers, pl) != 0)
    return 2;
  for (c = 0; c < RULES; c++)
    rules += pl->plays[c];
  pl->replays = rules > 0 ? pl->nhead : 0;
  if (pl->plays[PRED] && pl->nmiss > pl->replays)
    pl->replays = pl->nmiss;
  pl->compare_at = pl->shipped = -1;
  for (i = 0; i < pl->nmiss; i++)
    if (fabs(pl->miss[i].value - CLI_PARETO_COMPARE_AT) < 1e-6)
      pl->compare_at = i;
  for (i = 0; i < pl->nhead; i++)
    if (pl->head[i].value == 0.0)
      pl->shipped = i;
  return 0;
}

/* ---- the runs ------------------------------------------------------------ */

/* A point's figures. */
enum { P_MISS, P_OVER, P_DENSITY, P_FRAMES, P_FIGURES };
typedef double point[P_FIGURES];
/* Every point of one run: [slot][setting]. */
typedef point run_points[CTLS][MAX_SET];

/* One sequence's results. */
typedef struct seq_result {
  run_points *each;   /* [run] */
  run_points median;  /* over the runs */
  cli_pareto_cmp *cmp; /* [run] */
  cli_pareto_cmp cmp_median;
} seq_result;

/* Replay i of a run of sequence `seq` into pts. 0 or the replay's exit
 * status (printed). */
static int play_replay(const pacing_opts *o, const plan *pl,
                       const char *seq, int i, run_points *pts) {
  char ctl[128] = "", *extra[5], *args[CLI_PACING_MAX_ARGS];
  cli_replay_point got[RP_CONTROL_COUNT];
  int c, k, n = 0, nextra = 0, heads = 0, pred = 0, rc;
  /* predicted first: it plays the first runtime, which the replay
   * calibrates, alone or not. */
  for (k = 0; k < CTLS; k++) {
    c = (k + PRED) % CTLS;
    if (!pl->plays[c] || i >= settings_of(pl, c))
      continue;
    snprintf(ctl + strlen(ctl), sizeof ctl - strlen(ctl), "%s%s",
             ctl[0] ? "," : "", rp_controller_name(kind_of(c)));
    heads |= c != PRED;
    pred |= c == PRED;
  }
  extra[nextra++] = "--no-noise";
  if (heads && pl->head[i].value > 0) {
    extra[nextra++] = "--headroom";
    extra[nextra++] = (char *)pl->head[i].text;
  }
  if (pred) {
    extra[nextra++] = "--miss-rate";
    extra[nextra++] = (char *)pl->miss[i].text;
  }
  n = cli_pacing_args(o, seq, ctl, extra, nextra, args);
  if ((rc = cli_replay_points(n, args, got, &k)) != 0) {
    fprintf(stderr, "raypace bench pacing: %s, replay of %s failed\n", seq,
            ctl);
    return rc;
  }
  while (k-- > 0)
    for (c = 0; c < CTLS; c++)
      if (kind_of(c) == got[k].kind) {
        double *p = (*pts)[c][i];
        p[P_MISS] = got[k].miss_rate;
        p[P_OVER] = got[k].share_over_1_2;
        p[P_DENSITY] = got[k].mean_density;
        p[P_FRAMES] = got[k].frames;
      }
  return 0;
}

/* The comparison within one run's points. */
static void compare_run(const plan *pl, run_points *pts,
                        cli_pareto_cmp *out) {
  double miss[RULES][MAX_SET], dens[RULES][MAX_SET];
  double m = NAN, d = NAN, shipped = NAN;
  int n[RULES], r, i;
  for (r = 0; r < RULES; r++) {
    n[r] = pl->plays[r] ? pl->nhead : 0;
    for (i = 0; i < n[r]; i++) {
      miss[r][i] = (*pts)[r][i][P_MISS];
      dens[r][i] = (*pts)[r][i][P_DENSITY];
    }
  }
  if (pl->plays[PRED] && pl->compare_at >= 0) {
    m = (*pts)[PRED][pl->compare_at][P_MISS];
    d = (*pts)[PRED][pl->compare_at][P_DENSITY];
  }
  if (pl->plays[VTK] && pl->shipped >= 0)
    shipped = (*pts)[VTK][pl->shipped][P_DENSITY];
  cli_pareto_compare(m, d, miss, dens, n, shipped, out);
}

/* The medians of the runs' comparisons; a rule's `where` is ABOVE if
 * any run's was (its median may be a floor), else its last run's. */
static void compare_median(const cli_pareto_cmp *cmp, int runs,
                           cli_pareto_cmp *out) {
  double v[CLI_PACING_MAX_RUNS];
  int r, i;
#define MEDIAN_OF(field)                                                   \
  do {                                                                     \
    for (i = 0; i < runs; i++)                                             \
      v[i] = cmp[i].field;                                                 \
    out->field = cli_finite_median(v, runs);                               \
  } while (0)
  MEDIAN_OF(miss);
  MEDIAN_OF(density);
  MEDIAN_OF(ratio_best);
  MEDIAN_OF(vtk_shipped);
  MEDIAN_OF(ratio_vtk);
  out->best = -1;
  for (r = 0; r < RULES; r++) {
    MEDIAN_OF(at[r]);
    out->where[r] = cmp[runs - 1].where[r];
    for (i = 0; i < runs; i++)
      if (cmp[i].where[r] == CLI_PARETO_ABOVE)
        out->where[r] = CLI_PARETO_ABOVE;
    if (isfinite(out->at[r]) &&
        (out->best < 0 || out->at[r] > out->at[out->best]))
      out->best = r;
  }
#undef MEDIAN_OF
}

/* Every run of sequence `seq`, then the medians. 0 or an exit status. */
static int play_sequence(const pacing_opts *o, const plan *pl,
                         const char *seq, seq_result *res) {
  double v[CLI_PACING_MAX_RUNS];
  int run, i, c, f, rc, runs = (int)o->runs;
  for (run = 0; run < runs; run++) {
    for (c = 0; c < CTLS; c++)
      for (i = 0; i < MAX_SET; i++)
        for (f = 0; f < P_FIGURES; f++)
          res->each[run][c][i][f] = NAN;
    for (i = 0; i < pl->replays; i++) {
      if (!o->quiet)
        fprintf(stderr, "bench pacing --pareto: %s run %d/%d, replay "
                        "%d/%d\n", seq, run + 1, runs, i + 1, pl->replays);
      if ((rc = play_replay(o, pl, seq, i, &res->each[run])) != 0)
        return rc;
    }
    compare_run(pl, &res->each[run], &res->cmp[run]);
  }
  for (c = 0; c < CTLS; c++)
    for (i = 0; i < MAX_SET; i++)
      for (f = 0; f < P_FIGURES; f++) {
        for (run = 0; run < runs; run++)
          v[run] = res->each[run][c][i][f];
        res->median[c][i][f] = cli_finite_median(v, runs);
      }
  compare_median(res->cmp, runs, &res->cmp_median);
  return 0;
}

/* ---- the table ----------------------------------------------------------- */

static void print_percent(double v) {
  if (isfinite(v))
    printf(" %6.1f%%", 100 * v);
  else
    printf(" %7s", "-");
}

static void print_points(const plan *pl, run_points *pts) {
  int c, i;
  printf("  %-11s %-8s %6s %7s %7s %8s\n", "controller", "setting",
         "frames", "miss", ">1.2x", "density");
  for (c = 0; c < CTLS; c++)
    for (i = 0; pl->plays[c] && i < settings_of(pl, c); i++) {
      const double *p = (*pts)[c][i];
      printf("  %-11s %-8s", rp_controller_name(kind_of(c)),
             setting_of(pl, c, i)->text);
      if (isfinite(p[P_FRAMES]))
        printf(" %6.0f", p[P_FRAMES]);
      else
        printf(" %6s", "-");
      print_percent(p[P_MISS]);
      print_percent(p[P_OVER]);
      if (isfinite(p[P_DENSITY]))
        printf(" %8.4f\n", p[P_DENSITY]);
      else
        printf(" %8s\n", "-");
    }
}

static void print_number(const char *fmt, double v) {
  if (isfinite(v))
    printf(fmt, v);
  else
    printf("-");
}

/* A rule's density at the compared rate: '>' marks a floor, '-' none. */
static void print_at(double v, int where) {
  if (isfinite(v))
    printf("%s%.4f", where == CLI_PARETO_ABOVE ? ">" : "", v);
  else
    printf("-");
}

static void print_compare(const char *label, const cli_pareto_cmp *x) {
  int r;
  printf("  %s: predicted", label);
  print_percent(x->miss);
  printf(" late, density ");
  print_number("%.4f", x->density);
  printf("; there");
  for (r = 0; r < RULES; r++) {
    printf(" %s ", rp_controller_name(cli_pareto_rules[r]));
    print_at(x->at[r], x->where[r]);
  }
  printf("; d/best ");
  print_number("%.3f", x->ratio_best);
  printf(" (%s), d/vtk-shipped ",
         x->best >= 0 ? rp_controller_name(cli_pareto_rules[x->best]) : "-");
  print_number("%.3f", x->ratio_vtk);
  printf(" (vtk ");
  print_number("%.4f", x->vtk_shipped);
  printf(")\n");
}

static void print_sequence(const pacing_opts *o, const plan *pl,
                           const char *seq, seq_result *res) {
  const cli_pareto_cmp *m = &res->cmp_median;
  int run;
  printf("sequence %s\n", seq);
  print_points(pl, &res->median);
  if (pl->compare_at < 0 || !pl->plays[PRED]) {
    printf("  no comparison: predicted does not play miss rate %g\n",
           CLI_PARETO_COMPARE_AT);
    return;
  }
  print_compare("compared (medians)", m);
  printf("  goals: d/best >= %g %s, d/vtk-shipped >= %g %s\n",
         CLI_GOAL_PARETO_BEST,
         m->ratio_best >= CLI_GOAL_PARETO_BEST ? "met" : "missed",
         CLI_GOAL_PARETO_VTK,
         m->ratio_vtk >= CLI_GOAL_PARETO_VTK ? "met" : "missed");
  for (run = 0; o->runs > 1 && run < (int)o->runs; run++) {
    char label[32];
    snprintf(label, sizeof label, "run %d", run + 1);
    print_compare(label, &res->cmp[run]);
  }
  fflush(stdout);
}

/* ---- JSON ---------------------------------------------------------------- */

static void add_figures(cJSON *o, const double *p) {
  cli_json_figure(o, "frames", p[P_FRAMES]);
  cli_json_figure(o, "miss_rate", p[P_MISS]);
  cli_json_figure(o, "share_over_1_2", p[P_OVER]);
  cli_json_figure(o, "mean_density", p[P_DENSITY]);
}

static const char *const where_names[] = {"inside", "above", "below",
                                          "none"};

static cJSON *json_compare(const cli_pareto_cmp *x) {
  cJSON *o = cJSON_CreateObject(), *at, *where;
  int r;
  if (o == NULL)
    return NULL;
  cli_json_figure(o, "miss_rate", x->miss);
  cli_json_figure(o, "mean_density", x->density);
  at = cJSON_AddObjectToObject(o, "at");
  where = cJSON_AddObjectToObject(o, "where");
  for (r = 0; r < RULES && at != NULL && where != NULL; r++) {
    const char *name = rp_controller_name(cli_pareto_rules[r]);
    cli_json_figure(at, name, x->at[r]);
    cJSON_AddStringToObject(where, name, where_names[x->where[r]]);
  }
  if (x->best >= 0)
    cJSON_AddStringToObject(o, "best",
                            rp_controller_name(cli_pareto_rules[x->best]));
  else
    cJSON_AddNullToObject(o, "best");
  cli_json_figure(o, "ratio_best", x->ratio_best);
  cli_json_figure(o, "vtk_shipped", x->vtk_shipped);
  cli_json_figure(o, "ratio_vtk", x->ratio_vtk);
  return o;
}

static void json_points(cJSON *a, const pacing_opts *o, const plan *pl,
                        const seq_result *res) {
  int c, i, run;
  for (c = 0; c < CTLS; c++)
    for (i = 0; pl->plays[c] && i < settings_of(pl, c); i++) {
      const setting *s = setting_of(pl, c, i);
      cJSON *p = cJSON_CreateObject(), *each;
      if (p == NULL)
        return;
      cJSON_AddItemToArray(a, p);
      cJSON_AddStringToObject(p, "controller",
                              rp_controller_name(kind_of(c)));
      cJSON_AddStringToObject(p, "setting", s->text);
      /* The value the runtime gets: "default" and "none" are null. */
      cli_json_figure(p, c == PRED ? "asked_miss_rate" : "headroom",
                 s->value > 0 ? s->value : NAN);
      add_figures(p, res->median[c][i]);
      if ((each = cJSON_AddArrayToObject(p, "each")) == NULL)
        return;
      for (run = 0; run < (int)o->runs; run++) {
        cJSON *e = cJSON_CreateObject();
        if (e == NULL)
          return;
        cJSON_AddItemToArray(each, e);
        add_figures(e, res->each[run][c][i]);
      }
    }
}

static int print_json(const pacing_opts *o, const plan *pl,
                      const char *seq, const seq_result *res) {
  cJSON *j = cJSON_CreateObject(), *cmp, *each;
  char *text = NULL;
  int run;
  if (j != NULL) {
    cJSON_AddStringToObject(j, "sequence", seq);
    cJSON_AddNumberToObject(j, "runs", o->runs);
    cJSON_AddNumberToObject(j, "replays_per_run", pl->replays);
    json_points(cJSON_AddArrayToObject(j, "points"), o, pl, res);
    cmp = cJSON_AddObjectToObject(j, "comparison");
    cli_json_figure(cmp, "compared_at", CLI_PARETO_COMPARE_AT);
    cJSON_AddItemToObject(cmp, "median", json_compare(&res->cmp_median));
    each = cJSON_AddArrayToObject(cmp, "each");
    for (run = 0; run < (int)o->runs; run++)
      cJSON_AddItemToArray(each, json_compare(&res->cmp[run]));
    text = cJSON_PrintUnformatted(j);
    cJSON_Delete(j);
  }
  if (text == NULL) {
    fprintf(stderr, "raypace bench pacing: out of memory\n");
    return 1;
  }
  printf("%s\n", text);
  free(text);
  return 0;
}

/* ---- the plot ------------------------------------------------------------ */

/* Slot c's median points of sequence s as datablock $s<s>c<c>, sorted by
 * miss rate (percent) so that each curve runs left to right. */
static void plot_data(FILE *g, const plan *pl, int s, int c,
                      run_points *med) {
  int idx[MAX_SET], n = settings_of(pl, c), i, j;
  for (i = 0; i < n; i++)
    idx[i] = i;
  for (i = 1; i < n; i++)
    for (j = i; j > 0 && (*med)[c][idx[j - 1]][P_MISS] >
                             (*med)[c][idx[j]][P_MISS]; j--) {
      int t = idx[j - 1];
      idx[j - 1] = idx[j];
      idx[j] = t;
    }
  fprintf(g, "$s%dc%d << EOD\n", s, c);
  for (i = 0; i < n; i++) {
    const double *p = (*med)[c][idx[i]];
    if (isfinite(p[P_MISS]) && isfinite(p[P_DENSITY]))
      fprintf(g, "%.6g %.6g\n", 100 * p[P_MISS], p[P_DENSITY]);
  }
  fprintf(g, "EOD\n");
}

/* One panel: a curve per controller, predicted's drawn thick; vtk as it
 * ships and predicted at the compared rate circled. */
static void plot_panel(FILE *g, const plan *pl, int s, const char *seq,
                       run_points *med) {
  int c, first = 1;
  fprintf(g, "set title ");
  cli_gnuplot_string(g, seq);
  fprintf(g, "\nplot ");
  for (c = 0; c < CTLS; c++) {
    if (!pl->plays[c])
      continue;
    fprintf(g, "%s$s%dc%d with linespoints lw %s pt 7 ps %s lc rgb '%s' "
               "title '%s'", first ? "" : ", ", s, c,
            c == PRED ? "4" : "1.5", c == PRED ? "1.4" : "1",
            cli_controller_colour(kind_of(c)),
            rp_controller_name(kind_of(c)));
    first = 0;
  }
  if (pl->plays[VTK] && pl->shipped >= 0) {
    const double *p = (*med)[VTK][pl->shipped];
    fprintf(g, ", '+' using (%.6g):(%.6g) every ::0::0 with points pt 6 "
               "ps 3 lw 2 lc rgb '%s' title 'vtk as shipped'",
            100 * p[P_MISS], p[P_DENSITY], cli_controller_colour(
                                               RP_CONTROL_VTK));
  }
  if (pl->plays[PRED] && pl->compare_at >= 0) {
    const double *p = (*med)[PRED][pl->compare_at];
    fprintf(g, ", '+' using (%.6g):(%.6g) every ::0::0 with points pt 6 "
               "ps 3 lw 2 lc rgb '%s' title 'predicted, asked %g'",
            100 * p[P_MISS], p[P_DENSITY],
            cli_controller_colour(RP_CONTROL_PREDICTED),
            CLI_PARETO_COMPARE_AT);
  }
  fprintf(g, "\n");
}

static int write_plot(const pacing_opts *o, const plan *pl,
                      seq_result *res) {
  const char *who = "raypace bench pacing";
  int cols = o->nseq > 1 ? 2 : 1, rows = (o->nseq + cols - 1) / cols;
  int s, c;
  cli_plot plot;
  FILE *g;
  if (cli_plot_open(&plot, who) != 0)
    return 1;
  g = plot.g;
  for (s = 0; s < o->nseq; s++)
    for (c = 0; c < CTLS; c++)
      if (pl->plays[c])
        plot_data(g, pl, s, c, &res[s].median);
  fprintf(g, "set terminal pngcairo size %d,%d noenhanced\nset output ",
          800 * cols, 600 * rows);
  cli_gnuplot_string(g, o->plot);
  fprintf(g, "\nset multiplot layout %d,%d title ", rows, cols);
  cli_gnuplot_string(g, o->volume);
  /* The x axis from a little under 0: the points at a miss rate of 0
   * would sit on the axis otherwise. */
  fprintf(g, "\nset grid\nset key below horizontal\n"
             "set xlabel 'measured miss rate (%% of frames over the "
             "target)'\nset ylabel 'mean density'\n"
             "set xrange [-2:*]\nset yrange [0:*]\n");
  for (s = 0; s < o->nseq; s++)
    plot_panel(g, pl, s, o->seqs[s], &res[s].median);
  fprintf(g, "unset multiplot\n");
  return cli_plot_close(&plot, who);
}

/* ---- the command --------------------------------------------------------- */

static void print_heading(const pacing_opts *o, const plan *pl) {
  int k;
  printf("bench pacing --pareto: %s, %u run%s per sequence, %d replays "
         "per run", o->volume, o->runs, o->runs == 1 ? "" : "s",
         pl->replays);
  for (k = 0; k < o->npassed; k++)
    printf("%s%s %s", k == 0 ? " (" : " ", o->passed[2 * k],
           o->passed[2 * k + 1]);
  printf("%s; medians over the runs; miss = share of frames over the "
         "target, a density '>' a floor (the rule never missed that "
         "often), '-' unknown\n", o->npassed > 0 ? ")" : "");
}

int cli_bench_pareto(const pacing_opts *o) {
  plan pl;
  seq_result *res;
  int s, rc = 0;
  if ((rc = plan_of(o, &pl)) != 0)
    return rc;
  if (o->plot != NULL && !cli_have_gnuplot()) {
    fprintf(stderr, "raypace bench pacing: --plot needs gnuplot (Debian "
                    "gnuplot-nox)\n");
    return 1;
  }
  if ((res = calloc((size_t)o->nseq, sizeof *res)) == NULL) {
    fprintf(stderr, "raypace bench pacing: out of memory\n");
    return 1;
  }
  if (!o->json)
    print_heading(o, &pl);
  for (s = 0; s < o->nseq && rc == 0; s++) {
    res[s].each = malloc(o->runs * sizeof *res[s].each);
    res[s].cmp = malloc(o->runs * sizeof *res[s].cmp);
    if (res[s].each == NULL || res[s].cmp == NULL) {
      fprintf(stderr, "raypace bench pacing: out of memory\n");
      rc = 1;
    } else if ((rc = play_sequence(o, &pl, o->seqs[s], &res[s])) == 0) {
      if (o->json)
        rc = print_json(o, &pl, o->seqs[s], &res[s]);
      else
        print_sequence(o, &pl, o->seqs[s], &res[s]);
    }
  }
  if (rc == 0 && o->plot != NULL)
    rc = write_plot(o, &pl, res);
  for (s = 0; s < o->nseq; s++) {
    free(res[s].each);
    free(res[s].cmp);
  }
  free(res);
  return rc;
}
