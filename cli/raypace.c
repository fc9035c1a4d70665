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
#include "render_opts.h"
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
          "VOLUME is a file (.nrrd, .nhdr, .nii, .nii.gz, .hdr/.img, .mhd,"
          "\n.mha, sidecar .txt, NAME_XxYxZ_TYPE.raw) or a generated volume"
          "\ngen:KIND[:N|:XxYxZ][:u8|u16][:SEED]: KIND is ml, phantom or"
          "\nnoise; a number right after KIND is the size"
          "\n(N^3), a later one the seed (default 128^3, u8, seed 1).\n"
          "Run 'raypace COMMAND --help' for a command's options.\n");
}

static void usage_info(FILE *f) {
  fprintf(f,
          "usage: raypace info VOLUME [--tf PRESET] [--histograms] [--json]"
          "\n\n"
          "  --tf PRESET|FILE  count empty blocks under this transfer\n"
          "                 function (default ct-bone for signed data, else\n"
          "                 minmax-bone)\n"
          "  --window W --level L  place the TF on [L - W/2, L + W/2] in\n"
          "                 data units (HU for CT)\n"
          "  --histograms   also print per-block density histograms H (64\n"
          "                 bins) and opacity histograms H-alpha (16 bytes)\n"
          "  --json         one JSON object on stdout\n");
}

static cJSON *json_u32s(const uint32_t *v, int n) {
  cJSON *a = cJSON_CreateArray();
  int i;
  for (i = 0; i < n; i++)
    cJSON_AddItemToArray(a, cJSON_CreateNumber(v[i]));
  return a;
}


/* What info and render both build: a context, the volume, a TF, the
 * density histograms and the occupancy under the TF. */
typedef struct scene {
  rp_context *ctx;
  rp_volume *vol;
  rp_tf *tf;
  rp_histograms *h;
  rp_occupancy *occ;
  double histogram_s, occupancy_s; /* how long H and the occupancy took */
} scene;

/* The context and the volume of `sc`; 0, or 1 with the error printed.
 * scene_close frees what was made, either way. */
static int scene_load(scene *sc, const char *volume) {
  int err;
  memset(sc, 0, sizeof *sc);
  if ((err = rp_context_create(NULL, &sc->ctx)) != 0)
    return cli_error(sc->ctx, "context", err);
  return cli_open_volume(sc->ctx, volume, &sc->vol);
}

/* The rest of `sc` on its volume: the TF, H and the occupancy; 0, or 1
 * with the error printed. `h_what` names a failure to build H in the
 * message (the commands have always named it differently). */
static int scene_build(scene *sc, const cli_tf *tf, const char *h_what) {
  double t0;
  int err;
  if (cli_make_tf(sc->ctx, sc->vol, tf, &sc->tf) != 0)
    return 1;
  t0 = cli_now();
  if ((err = rp_histograms_build(sc->ctx, sc->vol, &sc->h)) != 0)
    return cli_error(sc->ctx, h_what, err);
  sc->histogram_s = cli_now() - t0;
  t0 = cli_now();
  if ((err = rp_occupancy_build(sc->ctx, sc->h, sc->tf, &sc->occ)) != 0)
    return cli_error(sc->ctx, "occupancy", err);
  sc->occupancy_s = cli_now() - t0;
  return 0;
}

static void scene_close(scene *sc) {
  rp_occupancy_destroy(sc->occ);
  rp_histograms_destroy(sc->h);
  rp_tf_destroy(sc->tf);
  rp_volume_destroy(sc->vol);
  rp_context_destroy(sc->ctx);
}

/* ---- info ---------------------------------------------------------------- */

typedef struct info_opts {
  const char *volume, *tf; /* tf: the name used, set once the volume is */
  cli_tf tfo;
  int json, hist;
} info_opts;

/* 0, or 1 after --help, or 2 (usage printed). */
static int parse_info(int argc, char **argv, info_opts *o) {
  static const struct option opts[] = {{"tf", required_argument, 0, 't'},
                                       {"window", required_argument, 0, 'W'},
                                       {"level", required_argument, 0, 'l'},
                                       {"histograms", no_argument, 0, 'H'},
                                       {"json", no_argument, 0, 'j'},
                                       {"help", no_argument, 0, 'h'},
                                       {0, 0, 0, 0}};
  int c, li = 0;
  memset(o, 0, sizeof *o);
  while ((c = getopt_long(argc, argv, "h", opts, &li)) != -1) {
    switch (c) {
    case 't': o->tfo.spec = optarg; break;
    case 'W':
    case 'l':
      if (cli_parse_window("info", &o->tfo, c == 'W', optarg) != 0)
        return 2;
      break;
    case 'H': o->hist = 1; break;
    case 'j': o->json = 1; break;
    case 'h': usage_info(stdout); return 1;
    default: usage_info(stderr); return 2;
    }
  }
  if (optind + 1 != argc) {
    usage_info(stderr);
    return 2;
  }
  o->volume = argv[optind];
  return 0;
}

static int info_json(const info_opts *o, const scene *sc) {
  cJSON *root = cJSON_CreateObject();
  rp_volume_info in;
  uint32_t nb = rp_histograms_block_count(sc->h), b;
  rp_volume_get_info(sc->vol, &in);
  cJSON_AddStringToObject(root, "volume", o->volume);
  cJSON_AddItemToObject(root, "dims", json_u32s(in.dims, 3));
  cJSON_AddStringToObject(root, "type", rp_voxel_type_name(in.type));
  cJSON_AddItemToObject(root, "spacing",
                        cJSON_CreateFloatArray(in.spacing, 3));
  cJSON_AddNumberToObject(root, "min", in.min);
  cJSON_AddNumberToObject(root, "max", in.max);
  if (in.orientation.known) {
    cJSON *or = cJSON_AddObjectToObject(root, "orientation");
    cJSON_AddItemToObject(or, "direction",
                          cJSON_CreateDoubleArray(in.orientation.direction,
                                                  9));
    cJSON_AddItemToObject(or, "origin",
                          cJSON_CreateDoubleArray(in.orientation.origin, 3));
  }
  cJSON_AddItemToObject(root, "blocks", json_u32s(in.blocks, 3));
  cJSON_AddNumberToObject(root, "block_count", nb);
  cJSON_AddStringToObject(root, "tf", o->tf);
  {
    double lo, hi;
    rp_tf_data_range(sc->tf, sc->vol, &lo, &hi);
    cJSON_AddItemToObject(root, "tf_range",
                          cJSON_CreateDoubleArray((double[]){lo, hi}, 2));
  }
  cJSON_AddNumberToObject(root, "empty_blocks",
                          rp_occupancy_empty_blocks(sc->occ));
  cJSON_AddNumberToObject(root, "empty_fraction",
                          (double)rp_occupancy_empty_blocks(sc->occ) / nb);
  cJSON_AddNumberToObject(root, "histogram_ms", sc->histogram_s * 1e3);
  cJSON_AddNumberToObject(root, "occupancy_ms", sc->occupancy_s * 1e3);
  if (o->hist) {
    cJSON *hd = cJSON_AddArrayToObject(root, "density_histograms");
    cJSON *ha = cJSON_AddArrayToObject(root, "opacity_histograms");
    const uint8_t *a = rp_occupancy_alpha_hist(sc->occ);
    for (b = 0; b < nb; b++) {
      uint32_t op[RP_OPACITY_BINS];
      int j;
      cJSON_AddItemToArray(hd, json_u32s(rp_histograms_block(sc->h, b),
                                         RP_DENSITY_BINS));
      for (j = 0; j < RP_OPACITY_BINS; j++)
        op[j] = a[b * RP_OPACITY_BINS + j];
      cJSON_AddItemToArray(ha, json_u32s(op, RP_OPACITY_BINS));
    }
  }
  return cli_print_json(root);
}

static int info_text(const info_opts *o, const scene *sc) {
  rp_volume_info in;
  uint32_t nb = rp_histograms_block_count(sc->h), b;
  rp_volume_get_info(sc->vol, &in);
  printf("volume:        %s\n", o->volume);
  printf("dims:          %u x %u x %u\n", in.dims[0], in.dims[1], in.dims[2]);
  printf("type:          %s\n", rp_voxel_type_name(in.type));
  printf("spacing:       %g %g %g\n", in.spacing[0], in.spacing[1],
         in.spacing[2]);
  if (in.orientation.known) {
    const double *d = in.orientation.direction;
    /* Each voxel axis by the patient direction it is nearest to. */
    static const char *const pos[3] = {"L", "P", "S"}, *neg[3] = {"R", "A",
                                                                  "I"};
    int a, c;
    printf("orientation:   ");
    for (a = 0; a < 3; a++) {
      int best = 0;
      for (c = 1; c < 3; c++)
        if (fabs(d[3 * a + c]) > fabs(d[3 * a + best]))
          best = c;
      printf("%s%s", a ? " " : "", d[3 * a + best] > 0 ? pos[best]
                                                      : neg[best]);
    }
    printf(" (voxel x, y, z towards; LPS origin %g %g %g)\n",
           in.orientation.origin[0], in.orientation.origin[1],
           in.orientation.origin[2]);
  } else {
    printf("orientation:   not given by the file\n");
  }
  printf("range:         %g .. %g\n", in.min, in.max);
  printf("blocks:        %u x %u x %u = %u (16^3)\n", in.blocks[0],
         in.blocks[1], in.blocks[2], nb);
  printf("empty blocks:  %u (%.1f %%) under TF '%s'\n",
         rp_occupancy_empty_blocks(sc->occ),
         100.0 * rp_occupancy_empty_blocks(sc->occ) / nb, o->tf);
  {
    double lo, hi;
    rp_tf_data_range(sc->tf, sc->vol, &lo, &hi);
    printf("tf range:      %g .. %g (data units)\n", lo, hi);
  }
  printf("timing:        H %.2f ms, H-alpha + occupancy %.2f ms\n",
         sc->histogram_s * 1e3, sc->occupancy_s * 1e3);
  if (o->hist) {
    const uint8_t *a = rp_occupancy_alpha_hist(sc->occ);
    for (b = 0; b < nb; b++) {
      const uint32_t *hb = rp_histograms_block(sc->h, b);
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
  return 0;
}

static int cmd_info(int argc, char **argv) {
  info_opts o;
  scene sc;
  int rc;
  if ((rc = parse_info(argc, argv, &o)) != 0)
    return rc == 1 ? 0 : rc;
  if ((rc = scene_load(&sc, o.volume)) == 0 &&
      (rc = scene_build(&sc, &o.tfo, "histograms")) == 0) {
    o.tf = cli_tf_name(sc.vol, &o.tfo);
    rc = o.json ? info_json(&o, &sc) : info_text(&o, &sc);
  }
  scene_close(&sc);
  return rc;
}

/* ---- render -------------------------------------------------------------- */


/* The camera and render desc the options ask for. */
static void render_setup(const render_opts *o, const rp_volume *vol,
                         rp_camera *cam, rp_render_desc *rd) {
  rp_volume_info info;
  rp_volume_get_info(vol, &info);
  memset(cam, 0, sizeof *cam);
  memset(rd, 0, sizeof *rd);
  cam->projection = o->ortho ? RP_ORTHOGRAPHIC : RP_PERSPECTIVE;
  cam->fov_y_deg = o->fov;
  if (o->view != NULL || (!o->orbit_given && info.orientation.known))
    (void)rp_camera_view(cam, vol,
                         o->view != NULL ? rp_view_from_name(o->view)
                                         : RP_VIEW_ANTERIOR,
                         2.0f); /* closer than the orbit: a head fills it */
  else
    rp_camera_orbit(cam, vol, o->orbit[0], o->orbit[1], o->orbit[2]);
  rd->width = o->width;
  rd->height = o->height;
  rd->step = o->step;
  rd->ert_threshold = o->ert_threshold;
  rd->image_scale = o->scale;
  rd->jitter = o->no_jitter ? RP_JITTER_OFF : RP_JITTER_ON;
  rd->jitter_seed = o->seed;
  rd->effects = (o->shading ? RP_EFFECT_SHADING : 0) |
                (o->ert ? RP_EFFECT_ERT : 0) |
                (o->skip ? RP_EFFECT_SKIP : 0) | (o->ao ? RP_EFFECT_AO : 0) |
                (o->preint ? RP_EFFECT_PREINT : 0);
}

static int out_of_memory(void) {
  fprintf(stderr, "raypace render: out of memory\n");
  return 1;
}

/* A frame's images and tile statistics: rendered at the scaled size
 * (sw x sh, tx x ty tiles), kept at the output size. */
typedef struct frame_buffers {
  uint32_t sw, sh, tx, ty;
  uint8_t *rgba, *out;
  rp_tile_stats *tiles;
} frame_buffers;

/* 0, or 1 with the error printed; buffers_free frees them either way. */
static int buffers_alloc(frame_buffers *fb, const render_opts *o,
                         const rp_render_desc *rd) {
  rp_scaled_size(rd, &fb->sw, &fb->sh);
  rp_tile_grid(fb->sw, fb->sh, &fb->tx, &fb->ty);
  fb->rgba = malloc((size_t)fb->sw * fb->sh * 4);
  fb->out = malloc((size_t)o->width * o->height * 4);
  fb->tiles = malloc((size_t)fb->tx * fb->ty * sizeof *fb->tiles);
  if (fb->rgba == NULL || fb->out == NULL || fb->tiles == NULL)
    return out_of_memory();
  return 0;
}

static void buffers_free(frame_buffers *fb) {
  free(fb->rgba);
  free(fb->out);
  free(fb->tiles);
}

/* What a frame's tiles add up to. */
typedef struct frame_totals {
  uint64_t samples, rays;
  double depth_sum; /* mean depth times rays, summed */
} frame_totals;

static frame_totals sum_tiles(const frame_buffers *fb) {
  frame_totals ft = {0, 0, 0};
  uint32_t t;
  for (t = 0; t < fb->tx * fb->ty; t++) {
    ft.samples += fb->tiles[t].samples;
    ft.rays += fb->tiles[t].rays_hit;
    ft.depth_sum += (double)fb->tiles[t].mean_depth * fb->tiles[t].rays_hit;
  }
  return ft;
}

/* Writes the output image to the PNG the options name; 0, or 1 with the
 * error printed. */
static int write_output(rp_context *ctx, const render_opts *o,
                        const frame_buffers *fb) {
  int err;
  if (o->ppm)
    return cli_write_ppm(o->out, fb->out, o->width, o->height,
                         o->background);
  err = rp_write_png(ctx, o->out, fb->out, o->width, o->height,
                     o->background);
  return err != 0 ? cli_error(ctx, o->out, err) : 0;
}

/* The JSON summary's fields that one device and a group share, in the
 * order both have always printed them; each adds its own after them. */
static cJSON *json_render(const render_opts *o, const char *backend,
                          const char *device, const frame_buffers *fb,
                          const frame_totals *ft, double t_render,
                          double device_ms) {
  cJSON *root = cJSON_CreateObject();
  cJSON_AddStringToObject(root, "output", o->out);
  cJSON_AddStringToObject(root, "backend", backend);
  cJSON_AddStringToObject(root, "device", device);
  cJSON_AddNumberToObject(root, "width", o->width);
  cJSON_AddNumberToObject(root, "height", o->height);
  cJSON_AddNumberToObject(root, "scaled_width", fb->sw);
  cJSON_AddNumberToObject(root, "scaled_height", fb->sh);
  cJSON_AddStringToObject(root, "tf", o->tf);
  cJSON_AddNumberToObject(root, "samples", (double)ft->samples);
  cJSON_AddNumberToObject(root, "rays_hit", (double)ft->rays);
  cJSON_AddNumberToObject(root, "mean_depth",
                          ft->rays ? ft->depth_sum / ft->rays : 0.0);
  cJSON_AddNumberToObject(root, "render_ms", t_render * 1e3);
  cJSON_AddNumberToObject(root, "device_ms", device_ms);
  return root;
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

/* One render through a device group, from set-up to report. What became
 * of each device (render_group's `fate`) is kept apart: with both in one
 * struct, GCC's -Wrestrict takes the copy of a device's error from the
 * report for a copy that may overlap. */
typedef struct group_run {
  rp_device_group *g;
  rp_frame_probe *probe;
  frame_buffers fb;
  rp_group_report rep; /* the kept frame's */
  double t_render;     /* the kept frame's wall time, seconds */
} group_run;

/* The group, the volume and TF on it, and AO on its devices when asked;
 * 0, or 1 with the error printed. */
static int group_setup(const scene *sc, const render_opts *o,
                       group_run *run) {
  rp_group_desc gd = {0};
  int err;
  gd.devices = o->devices;
  gd.count = o->ndevices;
  if ((err = rp_device_group_create(sc->ctx, &gd, &run->g)) != 0)
    return cli_error(sc->ctx, "--devices", err);
  if ((err = rp_device_group_set_volume(run->g, sc->vol)) != 0 ||
      (err = rp_device_group_set_tf(run->g, sc->tf, sc->occ)) != 0)
    return cli_error(sc->ctx, "upload", err);
  if (o->ao) {
    rp_ao_plan *plan = NULL;
    rp_ao *ao = NULL;
    rp_ao_schedule sched = {0};
    sched.scheme = o->ao_scheme;
    sched.progress = cli_progress;
    sched.user = "ambient occlusion";
    if ((err = rp_ao_plan_create(sc->ctx, sc->vol, sc->tf, NULL, &plan)) ==
            0 &&
        (err = rp_device_group_compute_ao(run->g, plan, &sched, &ao,
                                          NULL)) == 0)
      err = rp_device_group_set_ao(run->g, ao);
    rp_ao_destroy(ao);
    rp_ao_plan_destroy(plan);
    if (err != 0)
      return cli_error(sc->ctx, "--ao", err);
  }
  return 0;
}

/* The probe first (its tile costs guide the split), --warmup frames each
 * followed by training, then the frame kept. A device lost in any frame
 * keeps its first loss in fate[]. 0, or 1 with the error printed. */
static int group_frames(const scene *sc, const render_opts *o,
                        const rp_camera *cam, const rp_render_desc *rd,
                        group_run *run, device_fate *fate) {
  frame_buffers *fb = &run->fb;
  float step = rd->step > 0 ? rd->step : 1.0f;
  float scale = rd->image_scale > 0 ? rd->image_scale : 1.0f;
  uint32_t frame, i;
  double t0;
  int err;
  if ((err = rp_frame_probe_compute(sc->ctx, sc->vol, sc->tf, sc->occ, cam,
                                    rd, 1, 0, run->probe)) != 0)
    return cli_error(sc->ctx, "probe", err);
  for (frame = 0; frame <= o->warmup; frame++) {
    t0 = cli_now();
    err = rp_device_group_render(run->g, cam, rd, run->probe, fb->rgba,
                                 fb->tiles, &run->rep);
    if (err == 0)
      rp_image_upscale(fb->rgba, fb->sw, fb->sh, fb->out, o->width,
                       o->height);
    run->t_render = cli_now() - t0;
    if (err != 0)
      return cli_error(sc->ctx, "render", err);
    for (i = 0; i < run->rep.count; i++) {
      const rp_group_device *d = &run->rep.devices[i];
      device_fate *f = &fate[i];
      if (d->status == 0 || f->status != 0)
        continue;
      f->status = d->status;
      f->late = d->late;
      snprintf(f->why, sizeof f->why, "%s", d->error);
    }
    if (frame < o->warmup &&
        (err = rp_device_group_train(run->g, run->probe, step, scale,
                                     run->t_render * 1e3)) != 0)
      return cli_error(sc->ctx, "train", err);
  }
  return 0;
}

/* --overlay-split: each device's region tinted in its colour (hatched if
 * it was lost), then the tail's strips in the colour of the device that
 * took each. */
static void group_overlay(const render_opts *o, group_run *run) {
  const rp_group_report *rep = &run->rep;
  frame_buffers *fb = &run->fb;
  uint32_t i;
  for (i = 0; i < rep->count; i++) {
    rp_region r = region_to_output(&rep->devices[i].region, fb->sw, fb->sh,
                                   o->width, o->height);
    overlay_region(fb->out, o->width, &r, device_colours[i],
                   rep->devices[i].status != 0);
  }
  for (i = 0; i < rep->strip_count; i++)
    if (rep->strip_device[i] < rep->count) {
      rp_region r = region_to_output(&rep->strips[i], fb->sw, fb->sh,
                                     o->width, o->height);
      overlay_region(fb->out, o->width, &r,
                     device_colours[rep->strip_device[i]], 0);
    }
}

/* The summary on stdout: JSON with --json, else text. */
static int group_report(const render_opts *o, const group_run *run,
                        const device_fate *fate) {
  const rp_group_report *rep = &run->rep;
  frame_totals ft = sum_tiles(&run->fb);
  double t_render = run->t_render;
  if (o->json) {
    double device_ms = 0;
    cJSON *root;
    uint32_t i;
    for (i = 0; i < rep->count; i++)
      device_ms = fmax(device_ms, rep->devices[i].raycast_ms);
    root = json_render(o, "group", o->devices_spec, &run->fb, &ft,
                       t_render, device_ms);
    cJSON_AddNumberToObject(root, "samples_per_s",
                            t_render > 0 ? ft.samples / t_render : 0.0);
    cJSON_AddNumberToObject(root, "warmup", o->warmup);
    cJSON_AddNumberToObject(root, "probe_ms", run->probe->probe_ms);
    cJSON_AddNumberToObject(root, "group_render_ms", rep->render_ms);
    cJSON_AddNumberToObject(root, "rerender_ms", rep->rerender_ms);
    cJSON_AddNumberToObject(root, "imbalance", rep->imbalance);
    cJSON_AddNumberToObject(root, "devices_alive", rep->alive);
    cJSON_AddBoolToObject(root, "overlay_split", o->overlay);
    cJSON_AddItemToObject(root, "devices",
                          json_group(o, rep, fate, run->fb.sw, run->fb.sh));
    cJSON_AddItemToObject(root, "strips",
                          json_strips(o, rep, run->fb.sw, run->fb.sh));
    return cli_print_json(root);
  }
  printf("wrote %s (%ux%u on %u devices, %llu samples, %.1f ms, %.2f M "
         "samples/s)\n", o->out, o->width, o->height, rep->count,
         (unsigned long long)ft.samples, t_render * 1e3,
         t_render > 0 ? ft.samples / t_render / 1e6 : 0.0);
  print_group(o, rep, fate);
  return 0;
}

/* Renders `rd` through a device group into o->out (output size). */
static int render_group(const scene *sc, const render_opts *o,
                        const rp_camera *cam, const rp_render_desc *rd) {
  group_run run;
  device_fate fate[RP_GROUP_MAX_DEVICES];
  int rc = 1;
  memset(&run, 0, sizeof run);
  memset(fate, 0, sizeof fate);
  if (group_setup(sc, o, &run) != 0 || buffers_alloc(&run.fb, o, rd) != 0)
    goto out;
  if ((run.probe = malloc(sizeof *run.probe)) == NULL) {
    out_of_memory();
    goto out;
  }
  if (group_frames(sc, o, cam, rd, &run, fate) != 0)
    goto out;
  if (o->overlay)
    group_overlay(o, &run);
  if (write_output(sc->ctx, o, &run.fb) != 0)
    goto out;
  rc = group_report(o, &run, fate);
out:
  free(run.probe);
  buffers_free(&run.fb);
  rp_device_group_destroy(run.g);
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

/* The device, the volume and TF on it, and AO on it when asked (*ao_ms:
 * how long AO took); 0, or 1 with the error printed. */
static int single_setup(const scene *sc, const render_opts *o,
                        rp_device **dev, rp_caps *caps, rp_ao **ao,
                        double *ao_ms) {
  int err;
  if (cli_open_device(sc->ctx, "--backend", o->backend, o->device, &o->mem,
                      dev) != 0)
    return 1;
  rp_device_get_caps(*dev, caps);
  if ((err = rp_device_set_volume(*dev, sc->vol)) != 0 ||
      (err = rp_device_set_tf(*dev, sc->tf, sc->occ)) != 0)
    return cli_error(sc->ctx, "upload", err);
  if (o->ao) {
    rp_ao_plan *plan = NULL;
    rp_ao_schedule sched = {0};
    double t0;
    sched.progress = cli_progress;
    sched.user = "ambient occlusion";
    t0 = cli_now();
    if ((err = rp_ao_plan_create(sc->ctx, sc->vol, sc->tf, NULL, &plan)) ==
            0 &&
        (err = rp_ao_compute(sc->ctx, dev, 1, plan, &sched, ao, NULL)) == 0)
      err = rp_device_set_ao(*dev, *ao);
    *ao_ms = (cli_now() - t0) * 1e3;
    rp_ao_plan_destroy(plan);
    if (err != 0)
      return cli_error(sc->ctx, "--ao", err);
  }
  return 0;
}

/* The summary on stdout: JSON with --json, else text. */
static int single_report(const render_opts *o, const rp_device *dev,
                         const rp_caps *caps, const frame_buffers *fb,
                         double t_render, double ao_ms) {
  frame_totals ft = sum_tiles(fb);
  if (o->json) {
    cJSON *root = json_render(o, caps->backend, caps->device, fb, &ft,
                              t_render, rp_device_last_time_ns(dev) * 1e-6);
    cJSON_AddBoolToObject(root, "ao", o->ao);
    cJSON_AddNumberToObject(root, "ao_ms", ao_ms);
    cJSON_AddNumberToObject(root, "samples_per_s",
                            t_render > 0 ? ft.samples / t_render : 0.0);
    add_bricks_json(root, dev);
    return cli_print_json(root);
  }
  printf("wrote %s (%ux%u on %s '%s', %llu samples, %.1f ms, %.2f M "
         "samples/s)\n", o->out, o->width, o->height, caps->backend,
         caps->device, (unsigned long long)ft.samples, t_render * 1e3,
         t_render > 0 ? ft.samples / t_render / 1e6 : 0.0);
  cli_print_bricks(dev, "  ");
  return 0;
}

/* Renders `rd` on one device into o->out: --warmup frames first, then the
 * frame kept and timed. */
static int render_single(const scene *sc, const render_opts *o,
                         const rp_camera *cam, const rp_render_desc *rd) {
  rp_device *dev = NULL;
  rp_caps caps;
  rp_ao *ao = NULL;
  frame_buffers fb;
  double t0, t_render, ao_ms = 0;
  uint32_t frame;
  int err, rc = 1;
  memset(&fb, 0, sizeof fb);
  if (single_setup(sc, o, &dev, &caps, &ao, &ao_ms) != 0 ||
      buffers_alloc(&fb, o, rd) != 0)
    goto out;
  for (frame = 0; frame < o->warmup; frame++)
    if ((err = rp_device_render(dev, cam, rd, NULL, fb.rgba, fb.tiles)) !=
        0) {
      cli_error(sc->ctx, "render", err);
      goto out;
    }
  t0 = cli_now();
  err = rp_device_render(dev, cam, rd, NULL, fb.rgba, fb.tiles);
  t_render = cli_now() - t0;
  if (err != 0) {
    cli_error(sc->ctx, "render", err);
    goto out;
  }
  rp_image_upscale(fb.rgba, fb.sw, fb.sh, fb.out, o->width, o->height);
  if (write_output(sc->ctx, o, &fb) != 0)
    goto out;
  rc = single_report(o, dev, &caps, &fb, t_render, ao_ms);
out:
  buffers_free(&fb);
  rp_ao_destroy(ao);
  rp_device_destroy(dev);
  return rc;
}

static int cmd_render(int argc, char **argv) {
  render_opts o;
  scene sc;
  rp_camera cam;
  rp_render_desc rd;
  int rc;
  if ((rc = cli_parse_render(argc, argv, &o)) != 0)
    return rc == 1 ? 0 : rc;
  /* The work bound is checked on the volume, before any other work. */
  if ((rc = scene_load(&sc, o.volume)) == 0 &&
      (rc = cli_check_work("render", "--step", sc.vol,
                           o.step > 0 ? o.step : 1.0f, o.width, o.height,
                           o.scale)) == 0 &&
      (rc = scene_build(&sc, &o.tfo, "occupancy")) == 0) {
    o.tf = cli_tf_name(sc.vol, &o.tfo);
    render_setup(&o, sc.vol, &cam, &rd);
    rc = o.ndevices > 0 ? render_group(&sc, &o, &cam, &rd)
                        : render_single(&sc, &o, &cam, &rd);
  }
  scene_close(&sc);
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
  int rank = 0, size = 1, rc;
  if (rp_mpi_init(&argc, &argv, &rank, &size) != 0) {
    rp_mpi_finalize();
    return 1;
  }
  cli_set_mpi_world(size);
  rc = rank > 0 ? serve(rank) : run_command(argc, argv);
  rp_mpi_finalize();
  return rc;
}
