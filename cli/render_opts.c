/* raypace render's options: usage, parsing and every check that can be
 * made before the volume is opened (DESIGN: bad input gives a clear
 * error naming what the user typed). The ranges are the library's
 * (include/raypace.h, docs/parameters.md) where it has one. */
#include "render_opts.h"

#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>

#define CMD "render"

static void usage(FILE *f) {
  const char *const *p;
  fprintf(f,
          "usage: raypace render VOLUME -o OUT.png|OUT.ppm [options]\n\n"
          "  -o FILE               the image: PNG, or binary PPM (P6) for a\n"
          "                        name ending in .ppm\n"
          "  --tf PRESET|FILE      transfer function: a preset (below) or a\n"
          "                        file of 'x r g b a' lines (rp_tf_load);\n"
          "                        default ct-bone for signed (HU) data,\n"
          "                        else minmax-bone\n"
          "  --window W --level L  place the TF on [L - W/2, L + W/2] in\n"
          "                        data units (HU for CT); W > 0\n"
          "  --view NAME           anterior, posterior, left, right,\n"
          "                        superior or inferior (superior up; the\n"
          "                        default, anterior, for a volume whose\n"
          "                        file gives its orientation)\n"
          "  --camera AZ,EL,DIST   orbit: azimuth in [-360, 360] and\n"
          "                        elevation in [-90, 90] degrees, distance\n"
          "                        from the centre in (0, %g] bounding\n"
          "                        radii (default 30,20,2.5)\n"
          "  --ortho               orthographic projection\n"
          "  --fov DEG             vertical field of view in [%g, %g]\n"
          "                        (default 40)\n"
          "  --size WxH            image size, each side 1..%u, at most %u\n"
          "                        pixels (default 512x512)\n"
          "  --step D              sample step in voxels, in [%g, %g]\n"
          "                        (default 1)\n",
          2.0 * RP_CAMERA_DISTANCE_MAX, (double)RP_FOV_MIN_DEG,
          (double)RP_FOV_MAX_DEG, (unsigned)RP_IMAGE_MAX_DIM,
          (unsigned)RP_IMAGE_MAX_PIXELS, (double)RP_STEP_MIN,
          (double)RP_STEP_MAX);
  fprintf(f,
          "  --no-shading          no gradient shading (on by default)\n"
          "  --shading             accepted for older scripts\n"
          "  --ao                  ambient occlusion (computed first, on the\n"
          "                        rendering device(s), with a progress bar)\n"
          "  --ao-scheme NAME      with --devices: dynamic (default), static\n"
          "                        or naive\n"
          "  --no-ert              no early ray termination\n"
          "  --no-skip             no empty-space skipping\n"
          "  --preint              pre-integrated classification: each\n"
          "                        sample takes the segment from the one\n"
          "                        before, so a coarse --step keeps thin,\n"
          "                        steep features (docs/sampling.md)\n"
          "  --ert-threshold A     stop rays at this opacity, in [%g, %g]\n"
          "                        (default 0.99)\n"
          "  --no-jitter           no per-pixel jitter of the ray starts\n"
          "                        (every ray's samples on one lattice from\n"
          "                        the box entry: rings on surfaces)\n"
          "  --seed N              jitter seed, 1 to 4294967295 (default:\n"
          "                        the library's)\n"
          "  --background R,G,B    image background, each in [0, 1]\n"
          "                        (default 0,0,0)\n"
          "  --backend NAME        opencl, vulkan, reference (the scalar\n"
          "                        oracle), test (the reference's image, a\n"
          "                        device time from a formula: testing) or\n"
          "                        mpi (under mpirun: device N is rank\n"
          "                        N + 1's); default: the first with a\n"
          "                        device (never reference, test or mpi)\n"
          "  --device N            device index within the backend, 0..1024"
          "\n                        (default 0)\n"
          "  --scale S             image scale in [%g, %g]: rays per output\n"
          "                        pixel per axis (default 1)\n",
          (double)RP_ERT_THRESHOLD_MIN, (double)RP_ERT_THRESHOLD_MAX,
          (double)RP_SCALE_MIN, (double)RP_SCALE_MAX);
  fprintf(f,
          "  --devices LIST        render on several devices at once, the\n"
          "                        image split by predicted cost (not with\n"
          "                        --backend/--device); LIST is SPEC[,SPEC.."
          ".],\n"
          "                        SPEC BACKEND[:INDEX][:cu=N][:slow=S]"
          "[:fail=F]\n"
          "                        [:seed=N][:noise=X]:\n"
          "                        cu a sub-device of N compute units (the\n"
          "                        first part of an equal split: two cu=1\n"
          "                        share one core; opencl:1 and opencl:2\n"
          "                        are PoCL's two one-core parts), slow a\n"
          "                        device S times slower, fail the render "
          "it\n"
          "                        fails at (testing device loss), seed\n"
          "                        and noise the test backend's noise\n"
          "                        (0: none; default 0.02); mpi:I is\n"
          "                        MPI rank I + 1 under mpirun (rank 0 runs\n"
          "                        the command, the others serve devices)\n"
          "  --overlay-split       with --devices: tint each device's region"
          "\n"
          "                        in its own colour, 1-pixel borders\n"
          "  --warmup N            render N frames first, 0..10000 (with\n"
          "                        --devices: the devices' costs are learned"
          "\n"
          "                        from them, so the shares follow their\n"
          "                        speeds; default 0)\n"
          "  --budget-mb MB        device memory the volume may take, in\n"
          "                        [0.001, 1e9]; a larger volume is rendered"
          "\n"
          "                        out of core, from bricks (default: the\n"
          "                        device's largest buffer)\n"
          "  --brick-size N        out-of-core brick edge in voxels, a power"
          "\n"
          "                        of two in [8, 256] (default 16)\n"
          "  --json                print a JSON summary on stdout\n\n"
          "presets:");
  for (p = rp_tf_preset_names(); *p != NULL; p++)
    fprintf(f, " %s", *p);
  fprintf(f, "\n");
}

static const struct option opts[] = {
    {"tf", required_argument, 0, 't'},
    {"window", required_argument, 0, 'W'},
    {"level", required_argument, 0, 'l'},
    {"view", required_argument, 0, 'v'},
    {"no-shading", no_argument, 0, 'n'},
    {"camera", required_argument, 0, 'c'},
    {"ortho", no_argument, 0, 'O'},
    {"fov", required_argument, 0, 'f'},
    {"size", required_argument, 0, 's'},
    {"step", required_argument, 0, 'd'},
    {"shading", no_argument, 0, 'S'},
    {"ao", no_argument, 0, 'A'},
    {"ao-scheme", required_argument, 0, 'C'},
    {"no-ert", no_argument, 0, 'E'},
    {"no-skip", no_argument, 0, 'K'},
    {"preint", no_argument, 0, 'P'},
    {"ert-threshold", required_argument, 0, 'a'},
    {"no-jitter", no_argument, 0, 'J'},
    {"seed", required_argument, 0, 'N'},
    {"background", required_argument, 0, 'b'},
    {"backend", required_argument, 0, 'B'},
    {"device", required_argument, 0, 'D'},
    {"scale", required_argument, 0, 'x'},
    {"devices", required_argument, 0, 'L'},
    {"overlay-split", no_argument, 0, 'V'},
    {"warmup", required_argument, 0, 'w'},
    {"json", no_argument, 0, 'j'},
    {"budget-mb", required_argument, 0, 'M'},
    {"brick-size", required_argument, 0, 'Z'},
    {"output", required_argument, 0, 'o'},
    {"help", no_argument, 0, 'h'},
    {0, 0, 0, 0}};

/* The library's ranges for the render desc's and camera's numbers. */
static const cli_range fov_range = {RP_FOV_MIN_DEG, RP_FOV_MAX_DEG, 0, 0,
                                    "degrees"};
static const cli_range step_range = {RP_STEP_MIN, RP_STEP_MAX, 0, 0,
                                     "voxels"};
static const cli_range scale_range = {RP_SCALE_MIN, RP_SCALE_MAX, 0, 0,
                                      "rays per pixel per axis"};
static const cli_range ert_range = {RP_ERT_THRESHOLD_MIN,
                                    RP_ERT_THRESHOLD_MAX, 0, 0, "opacity"};
static const cli_field background_fields[3] = {
    {"R", {0.0, 1.0, 0, 0, NULL}, NULL},
    {"G", {0.0, 1.0, 0, 0, NULL}, NULL},
    {"B", {0.0, 1.0, 0, 0, NULL}, NULL}};

/* A name from a list of `n`: its index, or -1 (printed). */
static int pick_name(const char *option, const char *arg,
                     const char *const *names, int n, const char *what,
                     const char *want) {
  int i;
  for (i = 0; i < n; i++)
    if (strcmp(arg, names[i]) == 0)
      return i;
  cli_bad_option(CMD, option, arg, what, "must be %s", want);
  return -1;
}

/* An option that takes a value: parsed and checked into o; 0 or 2. */
static int parse_value(int c, const char *option, const char *arg,
                       render_opts *o) {
  static const char *const schemes[] = {"dynamic", "static", "naive"};
  static const rp_ao_scheme scheme_of[] = {RP_AO_DYNAMIC, RP_AO_STATIC,
                                           RP_AO_STATIC_NAIVE};
  int k;
  switch (c) {
  case 't': o->tfo.spec = arg; return 0;
  case 'W':
  case 'l': return cli_parse_window(CMD, &o->tfo, c == 'W', arg);
  case 'v':
    o->view = arg;
    return rp_view_from_name(arg) == 0
               ? cli_bad_option(CMD, option, arg, "not a view", "must be "
                                "anterior, posterior, left, right, "
                                "superior or inferior")
               : 0;
  case 'c':
    o->orbit_given = 1;
    return cli_parse_orbit(CMD, option, arg, o->orbit);
  case 'f': return cli_parse_float(CMD, option, arg, &fov_range, &o->fov);
  case 's': return cli_parse_size(CMD, option, arg, &o->width, &o->height);
  case 'd':
    return cli_parse_float(CMD, option, arg, &step_range, &o->step);
  case 'C':
    if ((k = pick_name(option, arg, schemes, 3, "not an AO scheme",
                       "dynamic, static or naive")) < 0)
      return 2;
    o->ao_scheme = scheme_of[k];
    return 0;
  case 'a':
    return cli_parse_float(CMD, option, arg, &ert_range, &o->ert_threshold);
  case 'N': return cli_parse_whole(CMD, option, arg, 1, UINT32_MAX, &o->seed);
  case 'b':
    return cli_parse_tuple(CMD, option, arg, "R,G,B", background_fields, 3,
                           o->background);
  case 'x':
    return cli_parse_float(CMD, option, arg, &scale_range, &o->scale);
  case 'w': return cli_parse_whole(CMD, option, arg, 0, 10000, &o->warmup);
  case 'o': o->out = arg; return 0;
  default: {
    cli_device_opts d;
    CLI_DEVICE_OPTS_OF(o, &d);
    return cli_parse_device_option(CMD, c, option, arg, &d);
  }
  }
}

/* The options' combinations, the output and the devices named; 0 or 2
 * (printed). */
static int check_render(render_opts *o) {
  static const char *const exts[] = {".png", ".ppm", NULL};
  cli_device_opts d;
  CLI_DEVICE_OPTS_OF(o, &d);
  if (cli_check_devices(CMD, &d) != 0)
    return 2;
  if (o->view != NULL && o->orbit_given) {
    fprintf(stderr, "raypace render: --view excludes --camera\n");
    return 2;
  }
  if (o->overlay && o->devices_spec == NULL) {
    fprintf(stderr, "raypace render: --overlay-split needs --devices\n");
    return 2;
  }
  if (o->out != NULL && cli_check_output(CMD, "-o", o->out, exts) != 0)
    return 2;
  o->ppm = o->out != NULL && strlen(o->out) > 4 &&
           strcasecmp(o->out + strlen(o->out) - 4, ".ppm") == 0;
  return 0;
}

int cli_parse_render(int argc, char **argv, render_opts *o) {
  int c, li = 0;
  memset(o, 0, sizeof *o);
  o->orbit[0] = 30, o->orbit[1] = 20, o->orbit[2] = 2.5f;
  o->width = o->height = 512;
  o->ert = o->skip = 1;
  o->shading = 1;
  optind = 1;
  while ((c = getopt_long(argc, argv, "ho:", opts, &li)) != -1) {
    char option[40];
    switch (c) {
    case 'n': o->shading = 0; break;
    case 'O': o->ortho = 1; break;
    case 'S': o->shading = 1; break;
    case 'A': o->ao = 1; break;
    case 'E': o->ert = 0; break;
    case 'K': o->skip = 0; break;
    case 'P': o->preint = 1; break;
    case 'J': o->no_jitter = 1; break;
    case 'V': o->overlay = 1; break;
    case 'j': o->json = 1; break;
    case 'h': usage(stdout); return 1;
    case '?': usage(stderr); return 2;
    default:
      snprintf(option, sizeof option, "%s", "-o");
      if (c != 'o')
        snprintf(option, sizeof option, "--%s", opts[li].name);
      if (parse_value(c, option, optarg, o) != 0)
        return 2;
    }
  }
  if (check_render(o) != 0)
    return 2;
  if (optind + 1 != argc || o->out == NULL) {
    usage(stderr);
    return 2;
  }
  o->volume = argv[optind];
  return 0;
}
