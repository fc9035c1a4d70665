/* The raypace command: inspect volumes and render them.
 *
 * JSON output (--json) is the stable interface later tools and tests read;
 * fields are only ever added. */
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
#include "raypace_mpi.h"
#include "raypace_pace.h"

static void usage_main(FILE *f) {
  fprintf(f,
          "usage: raypace COMMAND [options]\n\n"
          "commands:\n"
          "  info VOLUME     dimensions, type, range, blocks, empty space\n"
          "  render VOLUME   render one image to PNG\n"
          "  replay VOLUME   play an interaction sequence under frame-time\n"
          "                  controllers; per-frame CSV, plot, summary\n"
          "  bench quality VOLUME\n"
          "                  image quality (PSNR, SSIM) against time over\n"
          "                  step and image scale\n"
          "  bench overhead VOLUME\n"
          "                  each runtime stage's share of the frame time\n"
          "  bench pacing VOLUME\n"
          "                  the frame-time goals over every controller,\n"
          "                  medians over repeated replays\n"
          "  version         print the library version\n\n"
          "VOLUME is a file (.nrrd, .nhdr, sidecar .txt, NAME_XxYxZ_TYPE.raw)"
          "\nor a generated volume gen:KIND[:N|:XxYxZ][:u8|u16][:SEED]: KIND"
          "\nis ml, phantom or noise; a number right after KIND is the size"
          "\n(N^3), a later one the seed (default 128^3, u8, seed 1).\n"
          "Run 'raypace COMMAND --help' for a command's options.\n");
}

static void usage_info(FILE *f) {
  fprintf(f,
          "usage: raypace info VOLUME [--tf PRESET] [--histograms] [--json]"
          "\n\n"
          "  --tf PRESET    count empty blocks under this transfer function\n"
          "                 (default ct-bone)\n"
          "  --histograms   also print per-block density histograms H (64\n"
          "                 bins) and opacity histograms H-alpha (16 bytes)\n"
          "  --json         one JSON object on stdout\n");
}

static void usage_render(FILE *f) {
  const char *const *p;
  fprintf(f,
          "usage: raypace render VOLUME -o OUT.png [options]\n\n"
          "  --tf PRESET           transfer function (default ct-bone)\n"
          "  --camera AZ,EL,DIST   orbit: azimuth and elevation in degrees,\n"
          "                        distance in bounding radii (default "
          "30,20,2.5)\n"
          "  --ortho               orthographic projection\n"
          "  --fov DEG             vertical field of view (default 40)\n"
          "  --size WxH            image size (default 512x512)\n"
          "  --step D              sample step in voxels (default 1)\n"
          "  --shading             gradient shading\n"
          "  --ao                  ambient occlusion (computed first, on the\n"
          "                        rendering device(s), with a progress bar)\n"
          "  --ao-scheme NAME      with --devices: dynamic (default), static\n"
          "                        or naive\n"
          "  --no-ert              no early ray termination\n"
          "  --no-skip             no empty-space skipping\n"
          "  --ert-threshold A     stop rays at this opacity (default 0.99)"
          "\n"
          "  --background R,G,B    PNG background in [0,1] (default 0,0,0)\n"
          "  --backend NAME        opencl, vulkan, reference (the scalar\n"
          "                        oracle), test (the reference's image, a\n"
          "                        device time from a formula: testing) or\n"
          "                        mpi (under mpirun: device N is rank\n"
          "                        N + 1's); default: the first with a\n"
          "                        device (never reference, test or mpi)\n"
          "  --device N            device index within the backend (default "
          "0)\n"
          "  --scale S             image scale in (0, 1]: rays per output\n"
          "                        pixel per axis (default 1)\n"
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
          "  --warmup N            render N frames first (with --devices: "
          "the\n"
          "                        devices' costs are learned from them, so"
          "\n"
          "                        the shares follow their speeds; default "
          "0)\n"
          "  --budget-mb MB        device memory the volume may take; a\n"
          "                        larger volume is rendered out of core,\n"
          "                        from bricks (default: the device's "
          "largest\n"
          "                        buffer)\n"
          "  --brick-size N        out-of-core brick edge in voxels, a power"
          "\n"
          "                        of two in [8, 256] (default 16)\n"
          "  --json                print a JSON summary on stdout\n\n"
          "presets:");
  for (p = rp_tf_preset_names(); *p != NULL; p++)
    fprintf(f, " %s", *p);
  fprintf(f, "\n");
}

static cJSON *json_u32s(const uint32_t *v, int n) {
  cJSON *a = cJSON_CreateArray();
  int i;
  for (i = 0; i < n; i++)
    cJSON_AddItemToArray(a, cJSON_CreateNumber(v[i]));
  return a;
}

static int print_json(cJSON *root) {
  char *s = cJSON_Print(root);
  int ok = s != NULL;
  if (ok)
    printf("%s\n", s);
  free(s);
  cJSON_Delete(root);
  return ok ? 0 : 1;
}

static int cmd_info(int argc, char **argv) {
  static const struct option opts[] = {{"tf", required_argument, 0, 't'},
                                       {"histograms", no_argument, 0, 'H'},
                                       {"json", no_argument, 0, 'j'},
                                       {"help", no_argument, 0, 'h'},
                                       {0, 0, 0, 0}};
  const char *tf_name = "ct-bone";
  int json = 0, hist = 0, c, err, rc = 1;
  rp_context *ctx = NULL;
  rp_volume *vol = NULL;
  rp_tf *tf = NULL;
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  rp_volume_info in;
  uint32_t nb, b;
  double t0, t_h, t_occ;
  while ((c = getopt_long(argc, argv, "h", opts, NULL)) != -1) {
    switch (c) {
    case 't': tf_name = optarg; break;
    case 'H': hist = 1; break;
    case 'j': json = 1; break;
    case 'h': usage_info(stdout); return 0;
    default: usage_info(stderr); return 2;
    }
  }
  if (optind + 1 != argc) {
    usage_info(stderr);
    return 2;
  }
  if ((err = rp_context_create(NULL, &ctx)) != 0)
    return cli_error(ctx, "context", err);
  if (cli_open_volume(ctx, argv[optind], &vol) != 0)
    goto out;
  if ((err = rp_tf_create_preset(ctx, tf_name, &tf)) != 0) {
    cli_error(ctx, "--tf", err);
    goto out;
  }
  t0 = cli_now();
  if ((err = rp_histograms_build(ctx, vol, &h)) != 0) {
    cli_error(ctx, "histograms", err);
    goto out;
  }
  t_h = cli_now() - t0;
  t0 = cli_now();
  if ((err = rp_occupancy_build(ctx, h, tf, &occ)) != 0) {
    cli_error(ctx, "occupancy", err);
    goto out;
  }
  t_occ = cli_now() - t0;
  rp_volume_get_info(vol, &in);
  nb = rp_histograms_block_count(h);
  if (json) {
    cJSON *root = cJSON_CreateObject();
    uint32_t dims[3] = {in.dims[0], in.dims[1], in.dims[2]};
    cJSON_AddStringToObject(root, "volume", argv[optind]);
    cJSON_AddItemToObject(root, "dims", json_u32s(dims, 3));
    cJSON_AddStringToObject(root, "type", rp_voxel_type_name(in.type));
    cJSON_AddItemToObject(root, "spacing",
                          cJSON_CreateFloatArray(in.spacing, 3));
    cJSON_AddNumberToObject(root, "min", in.min);
    cJSON_AddNumberToObject(root, "max", in.max);
    cJSON_AddItemToObject(root, "blocks", json_u32s(in.blocks, 3));
    cJSON_AddNumberToObject(root, "block_count", nb);
    cJSON_AddStringToObject(root, "tf", tf_name);
    cJSON_AddNumberToObject(root, "empty_blocks",
                            rp_occupancy_empty_blocks(occ));
    cJSON_AddNumberToObject(root, "empty_fraction",
                            (double)rp_occupancy_empty_blocks(occ) / nb);
    cJSON_AddNumberToObject(root, "histogram_ms", t_h * 1e3);
    cJSON_AddNumberToObject(root, "occupancy_ms", t_occ * 1e3);
    if (hist) {
      cJSON *hd = cJSON_AddArrayToObject(root, "density_histograms");
      cJSON *ha = cJSON_AddArrayToObject(root, "opacity_histograms");
      const uint8_t *a = rp_occupancy_alpha_hist(occ);
      for (b = 0; b < nb; b++) {
        uint32_t op[RP_OPACITY_BINS];
        int j;
        cJSON_AddItemToArray(hd, json_u32s(rp_histograms_block(h, b),
                                           RP_DENSITY_BINS));
        for (j = 0; j < RP_OPACITY_BINS; j++)
          op[j] = a[b * RP_OPACITY_BINS + j];
        cJSON_AddItemToArray(ha, json_u32s(op, RP_OPACITY_BINS));
      }
    }
    rc = print_json(root);
    goto out;
  }
  printf("volume:        %s\n", argv[optind]);
  printf("dims:          %u x %u x %u\n", in.dims[0], in.dims[1], in.dims[2]);
  printf("type:          %s\n", rp_voxel_type_name(in.type));
  printf("spacing:       %g %g %g\n", in.spacing[0], in.spacing[1],
         in.spacing[2]);
  printf("range:         %g .. %g\n", in.min, in.max);
  printf("blocks:        %u x %u x %u = %u (16^3)\n", in.blocks[0],
         in.blocks[1], in.blocks[2], nb);
  printf("empty blocks:  %u (%.1f %%) under TF '%s'\n",
         rp_occupancy_empty_blocks(occ),
         100.0 * rp_occupancy_empty_blocks(occ) / nb, tf_name);
  printf("timing:        H %.2f ms, H-alpha + occupancy %.2f ms\n",
         t_h * 1e3, t_occ * 1e3);
  if (hist) {
    const uint8_t *a = rp_occupancy_alpha_hist(occ);
    for (b = 0; b < nb; b++) {
      const uint32_t *hb = rp_histograms_block(h, b);
      int j;
      printf("block %u H:", b);
      for (j = 0; j < RP_DENSITY_BINS; j++)
        printf(" %u", hb[j]);
      printf("\nblock %u H-alpha:", b);
      for (j = 0; j < RP_OPACITY_BINS; j++)
        printf(" %u", a[b * RP_OPACITY_BINS + j]);
      printf("\n");
    }
  }
  rc = 0;
out:
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
  return rc;
}

typedef struct render_opts {
  const char *volume, *out, *tf, *backend;
  float orbit[3], background[3], fov, step, ert_threshold, scale;
  uint32_t device;
  uint32_t width, height;
  int ortho, shading, ert, skip, json, ao;
  int device_given, overlay;
  rp_ao_scheme ao_scheme;
  uint32_t warmup;
  const char *devices_spec;
  rp_device_desc devices[RP_GROUP_MAX_DEVICES];
  cli_device_ext device_ext[RP_GROUP_MAX_DEVICES]; /* devices[i].next */
  uint32_t ndevices;
  cli_memory mem;
} render_opts;

static int parse_render(int argc, char **argv, render_opts *o) {
  static const struct option opts[] = {
      {"tf", required_argument, 0, 't'},
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
      {"ert-threshold", required_argument, 0, 'a'},
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
  int c, li = 0;
  memset(o, 0, sizeof *o);
  o->tf = "ct-bone";
  o->backend = NULL;
  o->orbit[0] = 30, o->orbit[1] = 20, o->orbit[2] = 2.5f;
  o->width = o->height = 512;
  o->ert = o->skip = 1;
  optind = 1;
  while ((c = getopt_long(argc, argv, "ho:", opts, &li)) != -1) {
    int bad = 0;
    switch (c) {
    case 't': o->tf = optarg; break;
    case 'c': bad = cli_parse_floats(optarg, o->orbit, 3); break;
    case 'O': o->ortho = 1; break;
    case 'f': bad = cli_parse_positive(optarg, &o->fov); break;
    case 's': bad = cli_parse_size(optarg, &o->width, &o->height); break;
    case 'd': bad = cli_parse_positive(optarg, &o->step); break;
    case 'S': o->shading = 1; break;
    case 'A': o->ao = 1; break;
    case 'C':
      if (strcmp(optarg, "dynamic") == 0)
        o->ao_scheme = RP_AO_DYNAMIC;
      else if (strcmp(optarg, "static") == 0)
        o->ao_scheme = RP_AO_STATIC;
      else if (strcmp(optarg, "naive") == 0)
        o->ao_scheme = RP_AO_STATIC_NAIVE;
      else
        bad = 1;
      break;
    case 'E': o->ert = 0; break;
    case 'K': o->skip = 0; break;
    case 'a': bad = cli_parse_positive(optarg, &o->ert_threshold); break;
    case 'b': bad = cli_parse_floats(optarg, o->background, 3); break;
    case 'B':
      o->backend = optarg;
      o->device_given = 1;
      break;
    case 'D':
      bad = cli_parse_u32(optarg, 1024, &o->device);
      o->device_given = 1;
      break;
    case 'x':
      bad = cli_parse_positive(optarg, &o->scale) || o->scale > 1.0f;
      break;
    case 'L':
      /* The parser names the bad part itself. */
      if (cli_parse_devices("--devices", optarg, o->devices, o->device_ext,
                            RP_GROUP_MAX_DEVICES, &o->ndevices) != 0)
        return 2;
      o->devices_spec = optarg;
      break;
    case 'V': o->overlay = 1; break;
    case 'w': bad = cli_parse_u32(optarg, 10000, &o->warmup); break;
    case 'j': o->json = 1; break;
    case 'M': bad = cli_parse_budget_mb(optarg, &o->mem.budget_bytes); break;
    case 'Z': bad = cli_parse_u32(optarg, 256, &o->mem.brick_size); break;
    case 'o': o->out = optarg; break;
    case 'h': usage_render(stdout); return 1;
    default: usage_render(stderr); return 2;
    }
    if (bad) {
      fprintf(stderr, "raypace render: bad value '%s' for --%s\n", optarg,
              opts[li].name);
      return 2;
    }
  }
  if (o->devices_spec != NULL && o->device_given) {
    fprintf(stderr, "raypace render: --devices excludes --backend and "
                    "--device\n");
    return 2;
  }
  for (c = 0; c < (int)o->ndevices; c++) {
    o->devices[c].budget_bytes = o->mem.budget_bytes;
    o->devices[c].brick_size = o->mem.brick_size;
  }
  if (o->overlay && o->devices_spec == NULL) {
    fprintf(stderr, "raypace render: --overlay-split needs --devices\n");
    return 2;
  }
  if (optind + 1 != argc || o->out == NULL) {
    usage_render(stderr);
    return 2;
  }
  o->volume = argv[optind];
  return 0;
}

/* ---- render --devices ---------------------------------------------------- */

/* One colour per device (RGB), as distinct as eight can be. */
static const uint8_t device_colours[RP_GROUP_MAX_DEVICES][3] = {
    {230, 25, 75},  {60, 180, 75},  {0, 130, 200}, {255, 225, 25},
    {240, 50, 230}, {70, 240, 240}, {245, 130, 48}, {145, 30, 180}};

/* A region of the scaled image (sw x sh) in output pixels (w x h): each
 * edge mapped by the same monotone function, so that regions that were
 * disjoint and covered the scaled image still do in the output. */
static rp_region region_to_output(const rp_region *r, uint32_t sw,
                                  uint32_t sh, uint32_t w, uint32_t h) {
  rp_region o;
  o.x0 = (uint32_t)((uint64_t)r->x0 * w / sw);
  o.x1 = (uint32_t)((uint64_t)r->x1 * w / sw);
  o.y0 = (uint32_t)((uint64_t)r->y0 * h / sh);
  o.y1 = (uint32_t)((uint64_t)r->y1 * h / sh);
  return o;
}

/* Tints region r of a premultiplied RGBA image 40 % toward `rgb` (as it
 * will be seen composited over the background: colour and alpha move
 * together) and draws its 1-pixel border in `rgb`. A region that was
 * lost (re-rendered by the other devices) is hatched as well. */
static void overlay_region(uint8_t *img, uint32_t w, const rp_region *r,
                           const uint8_t rgb[3], int lost) {
  uint32_t x, y;
  for (y = r->y0; y < r->y1; y++) {
    for (x = r->x0; x < r->x1; x++) {
      uint8_t *p = img + ((size_t)y * w + x) * 4;
      int edge = x == r->x0 || y == r->y0 || x + 1 == r->x1 ||
                 y + 1 == r->y1;
      int hatch = lost && (x + y) % 6 == 0;
      int c;
      for (c = 0; c < 3; c++)
        p[c] = edge || hatch ? rgb[c]
                             : (uint8_t)((3 * p[c] + 2 * rgb[c] + 2) / 5);
      p[3] = edge || hatch ? 255 : (uint8_t)((3 * p[3] + 2 * 255 + 2) / 5);
    }
  }
}

/* What became of each device over every frame the command rendered. */
typedef struct device_fate {
  int status, late;
  char why[256];
} device_fate;

static cJSON *json_region(const rp_region *r) {
  uint32_t v[4];
  v[0] = r->x0, v[1] = r->y0, v[2] = r->x1, v[3] = r->y1;
  return json_u32s(v, 4);
}

static void json_ms(cJSON *o, const char *name, double v) {
  if (isfinite(v))
    cJSON_AddNumberToObject(o, name, v);
  else
    cJSON_AddNullToObject(o, name);
}

static cJSON *json_group(const render_opts *o, const rp_group_report *rep,
                         const device_fate *fate, uint32_t sw,
                         uint32_t sh) {
  cJSON *a = cJSON_CreateArray();
  uint32_t i;
  for (i = 0; i < rep->count; i++) {
    const rp_group_device *d = &rep->devices[i];
    cJSON *e = cJSON_CreateObject();
    rp_region out = region_to_output(&d->region, sw, sh, o->width,
                                     o->height);
    cJSON_AddStringToObject(e, "name", d->name);
    cJSON_AddStringToObject(e, "backend", o->devices[i].backend);
    cJSON_AddNumberToObject(e, "index", o->devices[i].index);
    cJSON_AddNumberToObject(e, "share", d->share);
    cJSON_AddNumberToObject(e, "cost_share", d->cost_share);
    cJSON_AddItemToObject(e, "region", json_region(&d->region));
    cJSON_AddItemToObject(e, "output_region", json_region(&out));
    json_ms(e, "predicted_ms", d->predicted_ms);
    cJSON_AddNumberToObject(e, "depth_ms", d->depth_ms);
    cJSON_AddNumberToObject(e, "raycast_ms", d->raycast_ms);
    cJSON_AddNumberToObject(e, "busy_ms", d->busy_ms);
    cJSON_AddNumberToObject(e, "samples", (double)d->samples);
    cJSON_AddNumberToObject(e, "strips", d->strips);
    cJSON_AddNumberToObject(e, "strip_cost_share", d->strip_cost_share);
    cJSON_AddStringToObject(e, "status",
                            fate[i].status ? rp_err_name(fate[i].status)
                                           : "ok");
    cJSON_AddBoolToObject(e, "lost", fate[i].status != 0);
    cJSON_AddBoolToObject(e, "late", fate[i].late);
    if (fate[i].status != 0)
      cJSON_AddStringToObject(e, "error", fate[i].why);
    cJSON_AddItemToArray(a, e);
  }
  return a;
}

/* The tail's strips: the device that took each (-1: none finished it,
 * re-rendered with the lost regions), in scaled and output pixels. */
static cJSON *json_strips(const render_opts *o, const rp_group_report *rep,
                          uint32_t sw, uint32_t sh) {
  cJSON *a = cJSON_CreateArray();
  uint32_t i;
  for (i = 0; i < rep->strip_count; i++) {
    cJSON *e = cJSON_CreateObject();
    rp_region out = region_to_output(&rep->strips[i], sw, sh, o->width,
                                     o->height);
    cJSON_AddNumberToObject(e, "device", rep->strip_device[i] < rep->count
                                             ? (double)rep->strip_device[i]
                                             : -1.0);
    cJSON_AddItemToObject(e, "region", json_region(&rep->strips[i]));
    cJSON_AddItemToObject(e, "output_region", json_region(&out));
    cJSON_AddItemToArray(a, e);
  }
  return a;
}

static void print_group(const render_opts *o, const rp_group_report *rep,
                        const device_fate *fate) {
  uint32_t i;
  for (i = 0; i < rep->count; i++) {
    const rp_group_device *d = &rep->devices[i];
    printf("  device %u %s: share %.3f", i, d->name, d->share);
    if (d->region.x0 < d->region.x1 && d->region.y0 < d->region.y1)
      printf(", region %u,%u-%u,%u", d->region.x0, d->region.y0,
             d->region.x1, d->region.y1);
    else
      printf(", no region");
    if (d->strips > 0)
      printf(", %u tail strips (%.3f of the cost)", d->strips,
             d->strip_cost_share);
    printf(", raycast %.2f ms, busy %.2f ms, %llu samples, ", d->raycast_ms,
           d->busy_ms, (unsigned long long)d->samples);
    if (fate[i].status == 0)
      printf("ok\n");
    else
      printf("LOST (%s%s%s%s); the others re-rendered its region\n",
             rp_err_name(fate[i].status), fate[i].late ? ", late" : "",
             fate[i].why[0] ? ": " : "", fate[i].why);
  }
  printf("  imbalance %.3f, %u of %u devices alive", rep->imbalance,
         rep->alive, rep->count);
  if (rep->lost > 0)
    printf(", re-render %.2f ms", rep->rerender_ms);
  printf("%s\n", o->overlay ? ", regions tinted (--overlay-split)" : "");
}

/* Renders `rd` through a device group into `out` (output size): the
 * probe first (its tile costs guide the split), --warmup frames each
 * followed by training, then the frame kept. */
static int render_group(rp_context *ctx, const render_opts *o,
                        const rp_volume *vol, const rp_tf *tf,
                        const rp_occupancy *occ, const rp_camera *cam,
                        const rp_render_desc *rd) {
  rp_group_desc gd = {0};
  rp_device_group *g = NULL;
  rp_frame_probe *probe = NULL;
  rp_group_report rep;
  device_fate fate[RP_GROUP_MAX_DEVICES];
  uint8_t *rgba = NULL, *out = NULL;
  rp_tile_stats *tiles = NULL;
  uint32_t sw, sh, tx, ty, t, i, frame;
  uint64_t samples = 0, rays = 0;
  double t0, t_render = 0, depth_sum = 0;
  float step = rd->step > 0 ? rd->step : 1.0f;
  float scale = rd->image_scale > 0 ? rd->image_scale : 1.0f;
  int err, rc = 1;
  memset(fate, 0, sizeof fate);
  gd.devices = o->devices;
  gd.count = o->ndevices;
  if ((err = rp_device_group_create(ctx, &gd, &g)) != 0)
    return cli_error(ctx, "--devices", err);
  if ((err = rp_device_group_set_volume(g, vol)) != 0 ||
      (err = rp_device_group_set_tf(g, tf, occ)) != 0) {
    cli_error(ctx, "upload", err);
    goto out;
  }
  if (o->ao) {
    rp_ao_plan *plan = NULL;
    rp_ao *ao = NULL;
    rp_ao_schedule sc = {0};
    sc.scheme = o->ao_scheme;
    sc.progress = cli_progress;
    sc.user = "ambient occlusion";
    if ((err = rp_ao_plan_create(ctx, vol, tf, NULL, &plan)) == 0 &&
        (err = rp_device_group_compute_ao(g, plan, &sc, &ao, NULL)) == 0)
      err = rp_device_group_set_ao(g, ao);
    rp_ao_destroy(ao);
    rp_ao_plan_destroy(plan);
    if (err != 0) {
      cli_error(ctx, "--ao", err);
      goto out;
    }
  }
  rp_scaled_size(rd, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  rgba = malloc((size_t)sw * sh * 4);
  out = malloc((size_t)o->width * o->height * 4);
  tiles = malloc((size_t)tx * ty * sizeof *tiles);
  probe = malloc(sizeof *probe);
  if (rgba == NULL || out == NULL || tiles == NULL || probe == NULL) {
    fprintf(stderr, "raypace render: out of memory\n");
    goto out;
  }
  if ((err = rp_frame_probe_compute(ctx, vol, tf, occ, cam, rd, 1, 0,
                                    probe)) != 0) {
    cli_error(ctx, "probe", err);
    goto out;
  }
  for (frame = 0; frame <= o->warmup; frame++) {
    t0 = cli_now();
    err = rp_device_group_render(g, cam, rd, probe, rgba, tiles, &rep);
    if (err == 0)
      rp_image_upscale(rgba, sw, sh, out, o->width, o->height);
    t_render = cli_now() - t0;
    if (err != 0) {
      cli_error(ctx, "render", err);
      goto out;
    }
    for (i = 0; i < rep.count; i++) {
      const rp_group_device *d = &rep.devices[i];
      if (d->status == 0 || fate[i].status != 0)
        continue;
      fate[i].status = d->status;
      fate[i].late = d->late;
      snprintf(fate[i].why, sizeof fate[i].why, "%s", d->error);
    }
    if (frame < o->warmup &&
        (err = rp_device_group_train(g, probe, step, scale,
                                     t_render * 1e3)) != 0) {
      cli_error(ctx, "train", err);
      goto out;
    }
  }
  if (o->overlay) {
    for (i = 0; i < rep.count; i++) {
      rp_region r = region_to_output(&rep.devices[i].region, sw, sh,
                                     o->width, o->height);
      overlay_region(out, o->width, &r, device_colours[i],
                     rep.devices[i].status != 0);
    }
    /* The tail's strips in the colour of the device that took each. */
    for (i = 0; i < rep.strip_count; i++)
      if (rep.strip_device[i] < rep.count) {
        rp_region r = region_to_output(&rep.strips[i], sw, sh, o->width,
                                       o->height);
        overlay_region(out, o->width, &r,
                       device_colours[rep.strip_device[i]], 0);
      }
  }
  if ((err = rp_write_png(ctx, o->out, out, o->width, o->height,
                          o->background)) != 0) {
    cli_error(ctx, o->out, err);
    goto out;
  }
  for (t = 0; t < tx * ty; t++) {
    samples += tiles[t].samples;
    rays += tiles[t].rays_hit;
    depth_sum += (double)tiles[t].mean_depth * tiles[t].rays_hit;
  }
  if (o->json) {
    cJSON *root = cJSON_CreateObject();
    double device_ms = 0;
    for (i = 0; i < rep.count; i++)
      device_ms = fmax(device_ms, rep.devices[i].raycast_ms);
    cJSON_AddStringToObject(root, "output", o->out);
    cJSON_AddStringToObject(root, "backend", "group");
    cJSON_AddStringToObject(root, "device", o->devices_spec);
    cJSON_AddNumberToObject(root, "width", o->width);
    cJSON_AddNumberToObject(root, "height", o->height);
    cJSON_AddNumberToObject(root, "scaled_width", sw);
    cJSON_AddNumberToObject(root, "scaled_height", sh);
    cJSON_AddStringToObject(root, "tf", o->tf);
    cJSON_AddNumberToObject(root, "samples", (double)samples);
    cJSON_AddNumberToObject(root, "rays_hit", (double)rays);
    cJSON_AddNumberToObject(root, "mean_depth",
                            rays ? depth_sum / rays : 0.0);
    cJSON_AddNumberToObject(root, "render_ms", t_render * 1e3);
    cJSON_AddNumberToObject(root, "device_ms", device_ms);
    cJSON_AddNumberToObject(root, "samples_per_s",
                            t_render > 0 ? samples / t_render : 0.0);
    cJSON_AddNumberToObject(root, "warmup", o->warmup);
    cJSON_AddNumberToObject(root, "probe_ms", probe->probe_ms);
    cJSON_AddNumberToObject(root, "group_render_ms", rep.render_ms);
    cJSON_AddNumberToObject(root, "rerender_ms", rep.rerender_ms);
    cJSON_AddNumberToObject(root, "imbalance", rep.imbalance);
    cJSON_AddNumberToObject(root, "devices_alive", rep.alive);
    cJSON_AddBoolToObject(root, "overlay_split", o->overlay);
    cJSON_AddItemToObject(root, "devices",
                          json_group(o, &rep, fate, sw, sh));
    cJSON_AddItemToObject(root, "strips", json_strips(o, &rep, sw, sh));
    rc = print_json(root);
  } else {
    printf("wrote %s (%ux%u on %u devices, %llu samples, %.1f ms, %.2f M "
           "samples/s)\n", o->out, o->width, o->height, rep.count,
           (unsigned long long)samples, t_render * 1e3,
           t_render > 0 ? samples / t_render / 1e6 : 0.0);
    print_group(o, &rep, fate);
    rc = 0;
  }
out:
  free(probe);
  free(rgba);
  free(out);
  free(tiles);
  rp_device_group_destroy(g);
  return rc;
}

/* How the device held the volume, when out of core. */
static void add_bricks_json(cJSON *root, const rp_device *dev) {
  rp_brick_stats st;
  cJSON *b;
  if (rp_device_get_brick_stats(dev, &st) != 0 || !st.out_of_core)
    return;
  b = cJSON_AddObjectToObject(root, "out_of_core");
  cJSON_AddNumberToObject(b, "brick_size", st.brick_size);
  cJSON_AddNumberToObject(b, "bricks", st.bricks);
  cJSON_AddNumberToObject(b, "visible", st.visible);
  cJSON_AddNumberToObject(b, "pool", st.slots - 1);
  cJSON_AddNumberToObject(b, "resident", st.resident);
  cJSON_AddNumberToObject(b, "hits", (double)st.hits);
  cJSON_AddNumberToObject(b, "misses", (double)st.misses);
  cJSON_AddNumberToObject(b, "evictions", (double)st.evictions);
  cJSON_AddNumberToObject(b, "parts", st.last_pieces);
  cJSON_AddNumberToObject(b, "upload_bytes", (double)st.last_upload_bytes);
  cJSON_AddNumberToObject(b, "upload_ms", st.last_upload_ns * 1e-6);
}

static int cmd_render(int argc, char **argv) {
  render_opts o;
  rp_context *ctx = NULL;
  rp_volume *vol = NULL;
  rp_tf *tf = NULL;
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  rp_device *dev = NULL;
  rp_caps caps;
  rp_camera cam = {0};
  rp_render_desc rd = {0};
  rp_ao *ao = NULL;
  uint8_t *rgba = NULL, *out = NULL;
  rp_tile_stats *tiles = NULL;
  uint32_t tx, ty, t, sw, sh;
  uint64_t samples = 0, rays = 0;
  double t0, t_render, depth_sum = 0, ao_ms = 0;
  int err, rc = 1;
  if ((rc = parse_render(argc, argv, &o)) != 0)
    return rc == 1 ? 0 : rc;
  rc = 1;
  if ((err = rp_context_create(NULL, &ctx)) != 0)
    return cli_error(ctx, "context", err);
  if (cli_open_volume(ctx, o.volume, &vol) != 0)
    goto out;
  if ((err = rp_tf_create_preset(ctx, o.tf, &tf)) != 0) {
    cli_error(ctx, "--tf", err);
    goto out;
  }
  if ((err = rp_histograms_build(ctx, vol, &h)) != 0 ||
      (err = rp_occupancy_build(ctx, h, tf, &occ)) != 0) {
    cli_error(ctx, "occupancy", err);
    goto out;
  }
  cam.projection = o.ortho ? RP_ORTHOGRAPHIC : RP_PERSPECTIVE;
  cam.fov_y_deg = o.fov;
  rp_camera_orbit(&cam, vol, o.orbit[0], o.orbit[1], o.orbit[2]);
  rd.width = o.width;
  rd.height = o.height;
  rd.step = o.step;
  rd.ert_threshold = o.ert_threshold;
  rd.image_scale = o.scale;
  rd.effects = (o.shading ? RP_EFFECT_SHADING : 0) |
               (o.ert ? RP_EFFECT_ERT : 0) | (o.skip ? RP_EFFECT_SKIP : 0) |
               (o.ao ? RP_EFFECT_AO : 0);
  if (o.ndevices > 0) {
    rc = render_group(ctx, &o, vol, tf, occ, &cam, &rd);
    goto out;
  }
  if (cli_open_device(ctx, "--backend", o.backend, o.device, &o.mem,
                      &dev) != 0)
    goto out;
  rp_device_get_caps(dev, &caps);
  if ((err = rp_device_set_volume(dev, vol)) != 0 ||
      (err = rp_device_set_tf(dev, tf, occ)) != 0) {
    cli_error(ctx, "upload", err);
    goto out;
  }
  if (o.ao) {
    rp_ao_plan *plan = NULL;
    rp_ao_schedule sc = {0};
    sc.progress = cli_progress;
    sc.user = "ambient occlusion";
    t0 = cli_now();
    if ((err = rp_ao_plan_create(ctx, vol, tf, NULL, &plan)) == 0 &&
        (err = rp_ao_compute(ctx, &dev, 1, plan, &sc, &ao, NULL)) == 0)
      err = rp_device_set_ao(dev, ao);
    ao_ms = (cli_now() - t0) * 1e3;
    rp_ao_plan_destroy(plan);
    if (err != 0) {
      cli_error(ctx, "--ao", err);
      goto out;
    }
  }
  rp_scaled_size(&rd, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  rgba = malloc((size_t)sw * sh * 4);
  out = malloc((size_t)o.width * o.height * 4);
  tiles = malloc((size_t)tx * ty * sizeof *tiles);
  if (rgba == NULL || out == NULL || tiles == NULL) {
    fprintf(stderr, "raypace render: out of memory\n");
    goto out;
  }
  for (t = 0; t < o.warmup; t++)
    if ((err = rp_device_render(dev, &cam, &rd, NULL, rgba, tiles)) != 0) {
      cli_error(ctx, "render", err);
      goto out;
    }
  t0 = cli_now();
  err = rp_device_render(dev, &cam, &rd, NULL, rgba, tiles);
  t_render = cli_now() - t0;
  if (err != 0) {
    cli_error(ctx, "render", err);
    goto out;
  }
  rp_image_upscale(rgba, sw, sh, out, o.width, o.height);
  if ((err = rp_write_png(ctx, o.out, out, o.width, o.height,
                          o.background)) != 0) {
    cli_error(ctx, o.out, err);
    goto out;
  }
  for (t = 0; t < tx * ty; t++) {
    samples += tiles[t].samples;
    rays += tiles[t].rays_hit;
    depth_sum += (double)tiles[t].mean_depth * tiles[t].rays_hit;
  }
  if (o.json) {
    cJSON *root = cJSON_CreateObject();
    cJSON_AddStringToObject(root, "output", o.out);
    cJSON_AddStringToObject(root, "backend", caps.backend);
    cJSON_AddStringToObject(root, "device", caps.device);
    cJSON_AddNumberToObject(root, "width", o.width);
    cJSON_AddNumberToObject(root, "height", o.height);
    cJSON_AddNumberToObject(root, "scaled_width", sw);
    cJSON_AddNumberToObject(root, "scaled_height", sh);
    cJSON_AddStringToObject(root, "tf", o.tf);
    cJSON_AddNumberToObject(root, "samples", (double)samples);
    cJSON_AddNumberToObject(root, "rays_hit", (double)rays);
    cJSON_AddNumberToObject(root, "mean_depth",
                            rays ? depth_sum / rays : 0.0);
    cJSON_AddNumberToObject(root, "render_ms", t_render * 1e3);
    cJSON_AddNumberToObject(root, "device_ms",
                            rp_device_last_time_ns(dev) * 1e-6);
    cJSON_AddBoolToObject(root, "ao", o.ao);
    cJSON_AddNumberToObject(root, "ao_ms", ao_ms);
    cJSON_AddNumberToObject(root, "samples_per_s",
                            t_render > 0 ? samples / t_render : 0.0);
    add_bricks_json(root, dev);
    rc = print_json(root);
  } else {
    printf("wrote %s (%ux%u on %s '%s', %llu samples, %.1f ms, %.2f M "
           "samples/s)\n", o.out, o.width, o.height, caps.backend,
           caps.device, (unsigned long long)samples, t_render * 1e3,
           t_render > 0 ? samples / t_render / 1e6 : 0.0);
    cli_print_bricks(dev, "  ");
    rc = 0;
  }
out:
  free(rgba);
  free(out);
  free(tiles);
  rp_ao_destroy(ao);
  rp_device_destroy(dev);
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
  return rc;
}

static int run_command(int argc, char **argv) {
  if (argc < 2) {
    usage_main(stderr);
    return 2;
  }
  if (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0 ||
      strcmp(argv[1], "help") == 0) {
    usage_main(stdout);
    return 0;
  }
  if (strcmp(argv[1], "version") == 0 || strcmp(argv[1], "--version") == 0) {
    printf("raypace %s\n", rp_version_string());
    return 0;
  }
  if (strcmp(argv[1], "info") == 0)
    return cmd_info(argc - 1, argv + 1);
  if (strcmp(argv[1], "render") == 0)
    return cmd_render(argc - 1, argv + 1);
  if (strcmp(argv[1], "replay") == 0)
    return cli_cmd_replay(argc - 1, argv + 1);
  if (strcmp(argv[1], "bench") == 0)
    return cli_cmd_bench(argc - 1, argv + 1);
  fprintf(stderr, "raypace: unknown command '%s'\n\n", argv[1]);
  usage_main(stderr);
  return 2;
}

/* A server rank of an MPI job: this rank's device (RP_BACKEND, else the
 * first with a device) for rank 0's "mpi" devices, until rank 0 ends. */
static int serve(int rank) {
  rp_context *ctx = NULL;
  char what[32];
  int err;
  if ((err = rp_context_create(NULL, &ctx)) != 0)
    return cli_error(ctx, "context", err);
  err = rp_mpi_serve(ctx, NULL);
  snprintf(what, sizeof what, "rank %d", rank);
  if (err != 0)
    cli_error(ctx, what, err);
  rp_context_destroy(ctx);
  return err != 0;
}

/* Under mpirun (raypace_mpi.h) rank 0 runs the command and ranks 1 and
 * up serve it their devices as backend "mpi"; started any other way,
 * rp_mpi_init does nothing and this is one process. */
int main(int argc, char **argv) {
  int rank = 0, rc;
  if (rp_mpi_init(&argc, &argv, &rank, NULL) != 0) {
    rp_mpi_finalize();
    return 1;
  }
  rc = rank > 0 ? serve(rank) : run_command(argc, argv);
  rp_mpi_finalize();
  return rc;
}
