/* raypace bench quality: what accuracy costs in time (DESIGN section 10,
 * seed 000 Table 4 and section 7.6).
 *
 * One fine reference image (step 0.1 voxel, full resolution), then for
 * each tuning space (ray, image, hybrid) a sweep of sampling densities
 * rho: each rho is mapped to a (step, image scale) by rp_space_map, the
 * frame rendered, upscaled to the output size, timed and compared with the
 * reference (MSE, PSNR, SSIM by rp_image_compare). Then, at a few equal
 * time budgets, the quality each space reaches: the sweep interpolated
 * between the two points whose times bracket the budget.
 *
 * A frame's time is wall time (monotonic clock) of the depth pass, the
 * raycast and the upscale, as in interaction where the camera moves every
 * frame: the device would otherwise reuse the depth pass of the previous
 * identical frame. Each setting renders one untimed frame first (kernel
 * and buffer warm-up); the median of the timed frames is reported. */
#include <cjson/cJSON.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_quality.h"
#include "cli_util.h"
#include "commands.h"
#include "raypace.h"
#include "raypace_pace.h"

#define SPACES 3
#define BUDGETS 3
#define MAX_DENSITIES 9
#define MAX_RUNS 1000

/* A log grid, each point about 1/sqrt(2) of the one before. */
static const double full_grid[MAX_DENSITIES] = {1,     0.7,   0.5,
                                                0.35,  0.25,  0.18,
                                                0.125, 0.09,  0.0625};
static const double quick_grid[] = {1, 0.5, 0.25, 0.125};
/* Budgets as fractions of the time of the rho = 1 frame. */
static const double budget_fractions[BUDGETS] = {0.25, 0.5, 0.75};
static const rp_space spaces[SPACES] = {RP_SPACE_RAY, RP_SPACE_IMAGE,
                                        RP_SPACE_HYBRID};

typedef struct sweep_point {
  rp_space space;
  double rho;
  float step, scale;
  uint32_t sw, sh; /* rays actually cast: rp_scaled_size */
  double ms;
  rp_image_metrics m;
} sweep_point;

typedef struct budget_point {
  double ms;
  int reached; /* 0: no two sweep points bracket the budget */
  double rho;
  rp_image_metrics m;
} budget_point;

static void usage_quality(FILE *f) {
  fprintf(f,
          "usage: raypace bench quality VOLUME [options]\n\n"
          "Renders a fine reference, then sweeps the sampling density rho\n"
          "in ray space (step), image space (image scale) and hybrid (both)"
          "\nand reports time against MSE, PSNR and SSIM, and the quality\n"
          "each space reaches at equal time budgets.\n\n"
          "  --tf PRESET|FILE      transfer function: a preset or a file of\n"
          "                        'x r g b a' lines (default minmax-bone)\n"
          "  --camera AZ,EL,DIST   orbit, as in raypace render (default "
          "30,20,2.5)\n"
          "  --size WxH            output size, as in raypace render "
          "(default\n                        512x512)\n"
          "  --backend NAME        opencl, vulkan or reference; default: the"
          "\n                        first with a device\n"
          "  --device N            device index within the backend, 0..1024\n"
          "  --ref-backend NAME    render the reference on another backend\n"
          "                        (e.g. reference); default: the same device"
          "\n"
          "  --runs N              timed frames per setting, median reported"
          "\n                        1..1000 (default 5)\n"
          "  --ref-step D          reference step in voxels, in [0.001,\n"
          "                        10000] (default 0.1; 0.05 with "
          "--sampling)\n"
          "  --base-step D         step at rho = 1, in [0.001, 10000] "
          "(default 1)\n"
          "  --shading             gradient shading\n"
          "  --csv FILE            write the sweep as CSV\n"
          "  --plot FILE           PNG of PSNR over time, one line per space"
          "\n                        (needs gnuplot)\n"
          "  --json                one JSON object on stdout\n"
          "  --quick               128x128, 4 densities, 1 run: a smoke test"
          "\n"
          "  --sampling            instead of the sweep: plain, jittered\n"
          "                        ray starts, pre-integrated and both at\n"
          "                        steps 4, 2, 1, 0.5 and 0.25 (and the\n"
          "                        mean of --frames jittered frames); the\n"
          "                        reference is neither jittered nor\n"
          "                        pre-integrated\n"
          "  --frames N            jittered frames averaged, 1..256 (default "
          "8)\n");
}

#define CMD "bench quality"

/* An option of bench quality that takes a value, checked into o; 0 or
 * 2 (printed). */
static int quality_value(int c, const char *option, const char *arg,
                         quality_opts *o) {
  static const cli_range step = {RP_STEP_MIN, RP_STEP_MAX, 0, 0, "voxels"};
  uint32_t v = 0;
  switch (c) {
  case 'c': return cli_parse_orbit(CMD, option, arg, o->orbit);
  case 's': return cli_parse_size(CMD, option, arg, &o->width, &o->height);
  case 'B': o->backend = arg; return cli_check_backend(CMD, arg);
  case 'R':
    o->ref_backend = arg;
    return cli_check_backend(CMD, arg);
  case 'D': return cli_parse_whole(CMD, option, arg, 0, 1024, &o->device);
  case 'n':
    if (cli_parse_whole(CMD, option, arg, 1, MAX_RUNS, &v) != 0)
      return 2;
    o->runs = (int)v;
    return 0;
  case 'r': return cli_parse_float(CMD, option, arg, &step, &o->ref_step);
  case 'b': return cli_parse_float(CMD, option, arg, &step, &o->base_step);
  default: return cli_parse_whole(CMD, option, arg, 1, 256, &o->frames);
  }
}

/* The files bench quality writes and its MPI devices; 0 or 2 (printed). */
static int quality_files(const quality_opts *o) {
  static const char *const png[] = {".png", NULL};
  if (o->csv != NULL && cli_check_output(CMD, "--csv", o->csv, NULL) != 0)
    return 2;
  if (o->backend != NULL && strcmp(o->backend, "mpi") == 0 &&
      cli_check_mpi(CMD, "--backend", "mpi", o->device) != 0)
    return 2;
  if (o->ref_backend != NULL && strcmp(o->ref_backend, "mpi") == 0 &&
      cli_check_mpi(CMD, "--ref-backend", "mpi", 0) != 0)
    return 2;
  if (o->plot != NULL && cli_check_output(CMD, "--plot", o->plot, png) != 0)
    return 2;
  return 0;
}

static int parse_quality(int argc, char **argv, quality_opts *o) {
  static const struct option opts[] = {
      {"tf", required_argument, 0, 't'},
      {"camera", required_argument, 0, 'c'},
      {"size", required_argument, 0, 's'},
      {"backend", required_argument, 0, 'B'},
      {"device", required_argument, 0, 'D'},
      {"ref-backend", required_argument, 0, 'R'},
      {"runs", required_argument, 0, 'n'},
      {"ref-step", required_argument, 0, 'r'},
      {"base-step", required_argument, 0, 'b'},
      {"shading", no_argument, 0, 'S'},
      {"csv", required_argument, 0, 'C'},
      {"plot", required_argument, 0, 'P'},
      {"json", no_argument, 0, 'j'},
      {"quick", no_argument, 0, 'q'},
      {"sampling", no_argument, 0, 'J'},
      {"frames", required_argument, 0, 'F'},
      {"help", no_argument, 0, 'h'},
      {0, 0, 0, 0}};
  int c, li = 0, have_size = 0, have_runs = 0, have_ref_step = 0;
  memset(o, 0, sizeof *o);
  o->tf = "minmax-bone";
  o->orbit[0] = 30, o->orbit[1] = 20, o->orbit[2] = 2.5f;
  o->width = o->height = 512;
  o->runs = 5;
  o->ref_step = 0.1f;
  o->base_step = 1.0f;
  o->frames = 8;
  optind = 1;
  while ((c = getopt_long(argc, argv, "h", opts, &li)) != -1) {
    char option[40];
    snprintf(option, sizeof option, "--%s", opts[li].name);
    switch (c) {
    case 't': o->tf = optarg; break;
    case 'S': o->shading = 1; break;
    case 'C': o->csv = optarg; break;
    case 'P': o->plot = optarg; break;
    case 'j': o->json = 1; break;
    case 'q': o->quick = 1; break;
    case 'J': o->sampling = 1; break;
    case 'h': usage_quality(stdout); return 1;
    case '?': usage_quality(stderr); return 2;
    default:
      if (quality_value(c, option, optarg, o) != 0)
        return 2;
      have_size |= c == 's';
      have_runs |= c == 'n';
      have_ref_step |= c == 'r';
    }
  }
  if (quality_files(o) != 0)
    return 2;
  if (optind + 1 != argc) {
    usage_quality(stderr);
    return 2;
  }
  if (o->sampling && !have_ref_step)
    o->ref_step = 0.05f;
  if (o->quick) {
    if (!have_size)
      o->width = o->height = 128;
    if (!have_runs)
      o->runs = 1;
  }
  o->volume = argv[optind];
  return 0;
}

static int upload(bench *b, rp_device *dev) {
  int err;
  if ((err = rp_device_set_volume(dev, b->vol)) != 0 ||
      (err = rp_device_set_tf(dev, b->tf, b->occ)) != 0)
    return cli_error(b->ctx, "upload", err);
  return 0;
}

int bench_measure(bench *b, rp_device *dev, float step, float scale,
                  int runs, uint32_t *sw, uint32_t *sh, double *ms) {
  rp_render_desc rd = b->rd;
  int i, err, frames = runs > 0 ? runs + 1 : 1;
  rd.step = step;
  rd.image_scale = scale;
  rp_scaled_size(&rd, sw, sh);
  for (i = 0; i < frames; i++) {
    double t0 = cli_now();
    if ((err = rp_device_depth_pass(dev, &b->cam, &rd, NULL)) != 0 ||
        (err = rp_device_render(dev, &b->cam, &rd, NULL, b->scaled,
                                NULL)) != 0)
      return cli_error(b->ctx, "render", err);
    rp_image_upscale(b->scaled, *sw, *sh, b->out, rd.width, rd.height);
    b->times[i] = (cli_now() - t0) * 1e3;
  }
  if (runs == 0) {
    *ms = b->times[0];
    return 0;
  }
  *ms = cli_median(b->times + 1, runs);
  return 0;
}

static double lerp(double a, double b, double u) { return a + u * (b - a); }

/* The quality a space's sweep (n points, rho falling) reaches in `ms`:
 * linear in time between the first neighbours whose times bracket it,
 * rho in log. A budget above the rho = 1 time gets rho = 1 (the densest
 * setting: controllers never go above it); one below every point of the
 * sweep is not reached. */
static budget_point at_budget(const sweep_point *p, int n, double ms) {
  budget_point r;
  int i;
  memset(&r, 0, sizeof r);
  r.ms = ms;
  if (ms >= p[0].ms) {
    r.reached = 1;
    r.rho = p[0].rho;
    r.m = p[0].m;
    return r;
  }
  for (i = 0; i + 1 < n; i++) {
    const sweep_point *hi = &p[i], *lo = &p[i + 1];
    double u;
    if (!(hi->ms >= ms && ms >= lo->ms))
      continue;
    u = hi->ms > lo->ms ? (ms - lo->ms) / (hi->ms - lo->ms) : 1.0;
    r.reached = 1;
    r.rho = exp(lerp(log(lo->rho), log(hi->rho), u));
    r.m.mse = lerp(lo->m.mse, hi->m.mse, u);
    r.m.ssim = lerp(lo->m.ssim, hi->m.ssim, u);
    /* PSNR in dB like the other two, unless an end is exact (+inf). */
    if (isinf(lo->m.psnr) || isinf(hi->m.psnr))
      r.m.psnr = r.m.mse > 0 ? 10 * log10(255.0 * 255.0 / r.m.mse)
                             : INFINITY;
    else
      r.m.psnr = lerp(lo->m.psnr, hi->m.psnr, u);
    return r;
  }
  return r;
}

static void print_row(const sweep_point *p) {
  printf("%-7s %7.4f %6.3f %6.3f %5ux%-5u %9.2f %10.3f %7.2f %7.4f\n",
         rp_space_name(p->space), p->rho, p->step, p->scale, p->sw, p->sh,
         p->ms, p->m.mse, p->m.psnr, p->m.ssim);
}

static void print_budgets(budget_point b[BUDGETS][SPACES], double t1) {
  int i, s;
  printf("\nat equal budgets (share of the rho = 1 frame, %.2f ms; "
         "interpolated\nbetween the bracketing sweep points):\n", t1);
  printf("%-15s %-7s %7s %10s %7s %7s\n", "budget", "space", "rho", "MSE",
         "PSNR", "SSIM");
  for (i = 0; i < BUDGETS; i++)
    for (s = 0; s < SPACES; s++) {
      char label[32];
      const budget_point *p = &b[i][s];
      snprintf(label, sizeof label, "%3.0f%% %.2f ms",
               100 * budget_fractions[i], p->ms);
      if (p->reached)
        printf("%-15s %-7s %7.4f %10.3f %7.2f %7.4f\n", label,
               rp_space_name(spaces[s]), p->rho, p->m.mse, p->m.psnr,
               p->m.ssim);
      else
        printf("%-15s %-7s %7s %10s %7s %7s\n", label,
               rp_space_name(spaces[s]), "-", "-", "-", "-");
    }
}

static int write_csv(FILE *f, const char *path, const sweep_point *p,
                     int n) {
  int i;
  fprintf(f, "space,rho,step,scale,rays_x,rays_y,ms,mse,psnr,ssim\n");
  for (i = 0; i < n; i++)
    fprintf(f, "%s,%.6g,%.6g,%.6g,%u,%u,%.6f,%.6f,%.6f,%.6f\n",
            rp_space_name(p[i].space), p[i].rho, p[i].step, p[i].scale,
            p[i].sw, p[i].sh, p[i].ms, p[i].m.mse, p[i].m.psnr,
            p[i].m.ssim);
  if (fclose(f) != 0) {
    fprintf(stderr, "raypace bench: %s: write failed\n", path);
    return 1;
  }
  return 0;
}

/* PSNR over time, one line per space, through gnuplot: pngcairo where it
 * is built in, else the plain png terminal. */
int bench_plot_open(cli_plot *plot, const char *path, const char *title) {
  FILE *g;
  if (cli_plot_open(plot, "raypace bench") != 0)
    return 1;
  g = plot->g;
  fprintf(g, "if (strstrt(GPVAL_TERMINALS, 'pngcairo') > 0) "
             "{ set terminal pngcairo size 960,640 } "
             "else { set terminal png size 960,640 }\n"
             "set termoption noenhanced\nset output ");
  cli_gnuplot_string(g, path);
  fprintf(g, "\nset title ");
  cli_gnuplot_string(g, title);
  fprintf(g, "\nset xlabel 'frame time, median (ms)'\n"
             "set ylabel 'PSNR (dB)'\nset grid\nset key bottom right\n");
  return 0;
}

static int write_plot(const quality_opts *o, const char *device,
                      const sweep_point *p, int per_space) {
  cli_plot plot;
  FILE *g;
  char title[512];
  int s, i;
  snprintf(title, sizeof title,
           "%s, %ux%u, %s: PSNR against a step %g reference", o->volume,
           o->width, o->height, device, o->ref_step);
  if (bench_plot_open(&plot, o->plot, title) != 0)
    return 1;
  g = plot.g;
  for (s = 0; s < SPACES; s++) {
    fprintf(g, "$%s << EOD\n", rp_space_name(spaces[s]));
    for (i = 0; i < per_space; i++) {
      const sweep_point *q = &p[s * per_space + i];
      if (isfinite(q->m.psnr))
        fprintf(g, "%.6f %.6f\n", q->ms, q->m.psnr);
    }
    fprintf(g, "EOD\n");
  }
  fprintf(g, "plot ");
  for (s = 0; s < SPACES; s++)
    fprintf(g, "%s$%s using 1:2 with linespoints pt 7 title '%s space'",
            s ? ", " : "", rp_space_name(spaces[s]),
            rp_space_name(spaces[s]));
  fprintf(g, "\n");
  return cli_plot_close(&plot, "raypace bench");
}

void bench_json_metrics(cJSON *o, const rp_image_metrics *m) {
  cJSON_AddNumberToObject(o, "mse", m->mse);
  /* JSON has no infinity: identical images give psnr null. */
  if (isfinite(m->psnr))
    cJSON_AddNumberToObject(o, "psnr", m->psnr);
  else
    cJSON_AddNullToObject(o, "psnr");
  cJSON_AddNumberToObject(o, "ssim", m->ssim);
}

/* A float setting as the decimal it was typed or mapped as: 0.1f printed
 * as a double would read 0.10000000149011612. */
static double decimal(float v) {
  char buf[32];
  snprintf(buf, sizeof buf, "%.7g", v);
  return strtod(buf, NULL);
}

static int print_json(const quality_opts *o, const rp_caps *caps,
                      const char *ref_backend, double ref_ms,
                      const sweep_point *p, int n,
                      budget_point b[BUDGETS][SPACES], double t1) {
  cJSON *root = cJSON_CreateObject(), *sw, *bu;
  int i, s;
  cJSON_AddStringToObject(root, "volume", o->volume);
  cJSON_AddStringToObject(root, "backend", caps->backend);
  cJSON_AddStringToObject(root, "device", caps->device);
  cJSON_AddNumberToObject(root, "width", o->width);
  cJSON_AddNumberToObject(root, "height", o->height);
  cJSON_AddStringToObject(root, "tf", o->tf);
  cJSON_AddBoolToObject(root, "shading", o->shading);
  cJSON_AddNumberToObject(root, "runs", o->runs);
  cJSON_AddNumberToObject(root, "base_step", decimal(o->base_step));
  cJSON_AddNumberToObject(root, "ref_step", decimal(o->ref_step));
  cJSON_AddStringToObject(root, "ref_backend", ref_backend);
  cJSON_AddNumberToObject(root, "ref_ms", ref_ms);
  cJSON_AddNumberToObject(root, "full_density_ms", t1);
  sw = cJSON_AddArrayToObject(root, "sweep");
  for (i = 0; i < n; i++) {
    cJSON *e = cJSON_CreateObject();
    cJSON_AddStringToObject(e, "space", rp_space_name(p[i].space));
    cJSON_AddNumberToObject(e, "rho", p[i].rho);
    cJSON_AddNumberToObject(e, "step", decimal(p[i].step));
    cJSON_AddNumberToObject(e, "scale", decimal(p[i].scale));
    cJSON_AddNumberToObject(e, "rays_x", p[i].sw);
    cJSON_AddNumberToObject(e, "rays_y", p[i].sh);
    cJSON_AddNumberToObject(e, "ms", p[i].ms);
    bench_json_metrics(e, &p[i].m);
    cJSON_AddItemToArray(sw, e);
  }
  bu = cJSON_AddArrayToObject(root, "budgets");
  for (i = 0; i < BUDGETS; i++)
    for (s = 0; s < SPACES; s++) {
      cJSON *e = cJSON_CreateObject();
      cJSON_AddNumberToObject(e, "fraction", budget_fractions[i]);
      cJSON_AddNumberToObject(e, "budget_ms", b[i][s].ms);
      cJSON_AddStringToObject(e, "space", rp_space_name(spaces[s]));
      cJSON_AddBoolToObject(e, "reached", b[i][s].reached);
      if (b[i][s].reached) {
        cJSON_AddNumberToObject(e, "rho", b[i][s].rho);
        bench_json_metrics(e, &b[i][s].m);
      }
      cJSON_AddItemToArray(bu, e);
    }
  if (o->csv != NULL)
    cJSON_AddStringToObject(root, "csv", o->csv);
  if (o->plot != NULL)
    cJSON_AddStringToObject(root, "plot", o->plot);
  return cli_print_json(root);
}

/* Every density of the grid in every space: its median time over the
 * runs, and its image against the reference. */
static int sweep(bench *b, rp_device *dev, const quality_opts *o,
                 const double *grid, int per_space, const uint8_t *ref,
                 sweep_point *pts) {
  int i, s, err;
  /* Densities outermost, so that a slow drift of the machine (a neighbour
   * starting a build) shifts every space alike rather than one. */
  for (i = 0; i < per_space; i++)
    for (s = 0; s < SPACES; s++) {
      rp_space_desc sd = {0};
      sweep_point *p = &pts[s * per_space + i];
      sd.space = spaces[s];
      sd.base_step = o->base_step;
      p->space = spaces[s];
      p->rho = grid[i];
      rp_space_map(&sd, p->rho, &p->step, &p->scale);
      if (bench_measure(b, dev, p->step, p->scale, o->runs, &p->sw, &p->sh,
                  &p->ms) != 0)
        return 1;
      if ((err = rp_image_compare(b->ctx, b->out, ref, o->width, o->height,
                                  &p->m)) != 0)
        return cli_error(b->ctx, "compare", err);
    }
  return 0;
}

/* The best image each space gives within each budget; returns the
 * budgets' base, the frame at rho = 1: the same setting in every space,
 * so the median of its three measurements. */
static double budgets_of(const sweep_point *pts, int per_space,
                         budget_point budgets[BUDGETS][SPACES]) {
  double t1s[SPACES], t1;
  int i, s;
  for (s = 0; s < SPACES; s++)
    t1s[s] = pts[s * per_space].ms;
  t1 = cli_median(t1s, SPACES);
  for (i = 0; i < BUDGETS; i++)
    for (s = 0; s < SPACES; s++)
      budgets[i][s] = at_budget(&pts[s * per_space], per_space,
                                budget_fractions[i] * t1);
  return t1;
}

/* The table or JSON, then --csv (closing *csv) and --plot. */
static int report_quality(const quality_opts *o, const rp_caps *caps,
                          const char *ref_backend, double ref_ms,
                          const sweep_point *pts, int per_space,
                          budget_point budgets[BUDGETS][SPACES], double t1,
                          FILE **csv) {
  int n = SPACES * per_space, rc = 0;
  if (o->json)
    rc = print_json(o, caps, ref_backend, ref_ms, pts, n, budgets, t1);
  else
    print_budgets(budgets, t1);
  if (*csv != NULL) {
    FILE *f = *csv;
    *csv = NULL;
    if (write_csv(f, o->csv, pts, n) != 0)
      rc = 1;
    else if (!o->json)
      printf("\nwrote %s\n", o->csv);
  }
  if (o->plot != NULL) {
    if (write_plot(o, caps->backend, pts, per_space) != 0)
      rc = 1;
    else if (!o->json)
      printf("wrote %s\n", o->plot);
  }
  return rc;
}

/* The bench's context, volume, TF, occupancy and devices (the measured
 * one, and the reference's when --ref-backend names another), each
 * uploaded. What it made is the caller's to free, failed or not. */
static int open_quality(bench *b, const quality_opts *o, rp_histograms **h,
                        rp_device **dev, rp_device **ref_dev, rp_caps *caps,
                        rp_caps *ref_caps) {
  int err;
  if ((err = rp_context_create(NULL, &b->ctx)) != 0) {
    cli_error(b->ctx, "context", err);
    return 1;
  }
  /* The reference's step is the finest the bench renders. */
  if (cli_open_volume(b->ctx, o->volume, &b->vol) != 0 ||
      cli_check_work(CMD, "--ref-step", b->vol, o->ref_step, o->width,
                     o->height, 1.0f) != 0)
    return 1;
  {
    /* A preset or a TF file, as render takes them. */
    cli_tf spec = {o->tf, 0, 0.0, 0.0};
    if (cli_make_tf(b->ctx, b->vol, &spec, &b->tf) != 0)
      return 1;
  }
  if ((err = rp_histograms_build(b->ctx, b->vol, h)) != 0 ||
      (err = rp_occupancy_build(b->ctx, *h, b->tf, &b->occ)) != 0) {
    cli_error(b->ctx, "occupancy", err);
    return 1;
  }
  if (cli_open_device(b->ctx, "--backend", o->backend, o->device, NULL,
                      dev) != 0 ||
      upload(b, *dev) != 0)
    return 1;
  rp_device_get_caps(*dev, caps);
  *ref_caps = *caps;
  if (o->ref_backend != NULL) {
    if (cli_open_device(b->ctx, "--ref-backend", o->ref_backend, 0, NULL,
                        ref_dev) != 0 ||
        upload(b, *ref_dev) != 0)
      return 1;
    rp_device_get_caps(*ref_dev, ref_caps);
  }
  return 0;
}

static int bench_quality(int argc, char **argv) {
  quality_opts o;
  bench b;
  rp_histograms *h = NULL;
  rp_device *dev = NULL, *ref_dev = NULL;
  rp_caps caps, ref_caps;
  FILE *csv = NULL;
  sweep_point pts[SPACES * MAX_DENSITIES];
  budget_point budgets[BUDGETS][SPACES];
  const double *grid;
  uint8_t *ref = NULL;
  uint32_t sw, sh;
  double ref_ms = 0, t1;
  int per_space, n, i, rc;
  if ((rc = parse_quality(argc, argv, &o)) != 0)
    return rc == 1 ? 0 : rc;
  rc = 1;
  memset(&b, 0, sizeof b);
  grid = o.quick ? quick_grid : full_grid;
  per_space = o.quick ? (int)(sizeof quick_grid / sizeof quick_grid[0])
                      : MAX_DENSITIES;
  /* Before the minutes of rendering, not after them. */
  if (o.plot != NULL && !cli_have_gnuplot()) {
    fprintf(stderr, "raypace bench: --plot needs gnuplot, which is not "
                    "installed (Debian: gnuplot-nox)\n");
    return 1;
  }
  /* --sampling writes its own CSV (bench_sampling.c). */
  if (o.csv != NULL && !o.sampling && (csv = fopen(o.csv, "w")) == NULL) {
    fprintf(stderr, "raypace bench: --csv: cannot write %s\n", o.csv);
    return 1;
  }
  if (open_quality(&b, &o, &h, &dev, &ref_dev, &caps, &ref_caps) != 0)
    goto out;
  b.cam.projection = RP_PERSPECTIVE;
  rp_camera_orbit(&b.cam, b.vol, o.orbit[0], o.orbit[1], o.orbit[2]);
  b.rd.width = o.width;
  b.rd.height = o.height;
  b.rd.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP |
                 (o.shading ? RP_EFFECT_SHADING : 0);
  b.scaled = malloc((size_t)o.width * o.height * 4);
  b.out = malloc((size_t)o.width * o.height * 4);
  ref = malloc((size_t)o.width * o.height * 4);
  b.times = malloc(((size_t)o.runs + 1) * sizeof *b.times);
  if (b.scaled == NULL || b.out == NULL || ref == NULL || b.times == NULL) {
    fprintf(stderr, "raypace bench: out of memory\n");
    goto out;
  }
  /* The reference is never jittered: at its fine step the lattice's
   * rings are below a byte, and its image is then one image, not one of
   * many. The sweep renders as the product does, jittered. */
  b.rd.jitter = RP_JITTER_OFF;
  if (bench_measure(&b, ref_dev != NULL ? ref_dev : dev, o.ref_step, 1.0f,
                    0, &sw, &sh, &ref_ms) != 0)
    goto out;
  b.rd.jitter = RP_JITTER_DEFAULT;
  memcpy(ref, b.out, (size_t)o.width * o.height * 4);
  if (o.sampling) {
    rc = bench_sampling(&b, dev, &o, &caps, ref_caps.backend, ref_ms, ref);
    goto out;
  }
  if (!o.json) {
    printf("%s, %ux%u, tf %s%s, on %s '%s', median of %d\n", o.volume,
           o.width, o.height, o.tf, o.shading ? ", shading" : "",
           caps.backend, caps.device, o.runs);
    printf("reference: step %g, scale 1, on %s: %.2f ms (one cold frame)"
           "\n\n",
           o.ref_step, ref_caps.backend, ref_ms);
    printf("%-7s %7s %6s %6s %11s %9s %10s %7s %7s\n", "space", "rho",
           "step", "scale", "rays", "ms", "MSE", "PSNR", "SSIM");
  }
  if (sweep(&b, dev, &o, grid, per_space, ref, pts) != 0)
    goto out;
  n = SPACES * per_space;
  if (!o.json)
    for (i = 0; i < n; i++)
      print_row(&pts[i]);
  t1 = budgets_of(pts, per_space, budgets);
  rc = report_quality(&o, &caps, ref_caps.backend, ref_ms, pts, per_space,
                      budgets, t1, &csv);
out:
  if (csv != NULL)
    fclose(csv);
  free(ref);
  free(b.scaled);
  free(b.out);
  free(b.times);
  rp_device_destroy(ref_dev);
  rp_device_destroy(dev);
  rp_occupancy_destroy(b.occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(b.tf);
  rp_volume_destroy(b.vol);
  rp_context_destroy(b.ctx);
  return rc;
}

static void usage_bench(FILE *f) {
  fprintf(f, "usage: raypace bench BENCHMARK [options]\n\n"
             "benchmarks:\n"
             "  quality VOLUME   time against image quality (MSE, PSNR,\n"
             "                   SSIM) over step and image scale\n"
             "  overhead VOLUME  what each stage of a runtime frame costs\n"
             "                   (H build, uploads, probe, predict, ...)\n"
             "  pacing VOLUME    the frame-time goals (replay of every\n"
             "                   controller), medians over repeated runs\n"
             "Run 'raypace bench BENCHMARK --help' for its options.\n");
}

int cli_cmd_bench(int argc, char **argv) {
  if (argc < 2) {
    usage_bench(stderr);
    return 2;
  }
  if (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) {
    usage_bench(stdout);
    return 0;
  }
  if (strcmp(argv[1], "quality") == 0)
    return bench_quality(argc - 1, argv + 1);
  if (strcmp(argv[1], "overhead") == 0)
    return cli_cmd_bench_overhead(argc - 1, argv + 1);
  if (strcmp(argv[1], "pacing") == 0)
    return cli_cmd_bench_pacing(argc - 1, argv + 1);
  fprintf(stderr, "raypace bench: unknown benchmark '%s' (known: quality, "
                  "overhead, pacing)\n", argv[1]);
  return 2;
}
