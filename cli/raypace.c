/* The raypace command: inspect volumes and render them.
 *
 * JSON output (--json) is the stable interface later tools and tests read;
 * fields are only ever added. */
#include <cjson/cJSON.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli_util.h"
#include "commands.h"
#include "raypace.h"

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
          "  --no-ert              no early ray termination\n"
          "  --no-skip             no empty-space skipping\n"
          "  --ert-threshold A     stop rays at this opacity (default 0.99)"
          "\n"
          "  --background R,G,B    PNG background in [0,1] (default 0,0,0)\n"
          "  --backend NAME        opencl, vulkan or reference (the scalar\n"
          "                        oracle); default: the first with a device\n"
          "  --device N            device index within the backend (default "
          "0)\n"
          "  --scale S             image scale in (0, 1]: rays per output\n"
          "                        pixel per axis (default 1)\n"
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
  int ortho, shading, ert, skip, json;
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
      {"no-ert", no_argument, 0, 'E'},
      {"no-skip", no_argument, 0, 'K'},
      {"ert-threshold", required_argument, 0, 'a'},
      {"background", required_argument, 0, 'b'},
      {"backend", required_argument, 0, 'B'},
      {"device", required_argument, 0, 'D'},
      {"scale", required_argument, 0, 'x'},
      {"json", no_argument, 0, 'j'},
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
    case 'E': o->ert = 0; break;
    case 'K': o->skip = 0; break;
    case 'a': bad = cli_parse_positive(optarg, &o->ert_threshold); break;
    case 'b': bad = cli_parse_floats(optarg, o->background, 3); break;
    case 'B': o->backend = optarg; break;
    case 'D': bad = cli_parse_u32(optarg, 1024, &o->device); break;
    case 'x':
      bad = cli_parse_positive(optarg, &o->scale) || o->scale > 1.0f;
      break;
    case 'j': o->json = 1; break;
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
  if (optind + 1 != argc || o->out == NULL) {
    usage_render(stderr);
    return 2;
  }
  o->volume = argv[optind];
  return 0;
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
  uint8_t *rgba = NULL, *out = NULL;
  rp_tile_stats *tiles = NULL;
  uint32_t tx, ty, t, sw, sh;
  uint64_t samples = 0, rays = 0;
  double t0, t_render, depth_sum = 0;
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
  if (cli_open_device(ctx, "--backend", o.backend, o.device, &dev) != 0)
    goto out;
  rp_device_get_caps(dev, &caps);
  if ((err = rp_device_set_volume(dev, vol)) != 0 ||
      (err = rp_device_set_tf(dev, tf, occ)) != 0) {
    cli_error(ctx, "upload", err);
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
               (o.ert ? RP_EFFECT_ERT : 0) | (o.skip ? RP_EFFECT_SKIP : 0);
  rp_scaled_size(&rd, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  rgba = malloc((size_t)sw * sh * 4);
  out = malloc((size_t)o.width * o.height * 4);
  tiles = malloc((size_t)tx * ty * sizeof *tiles);
  if (rgba == NULL || out == NULL || tiles == NULL) {
    fprintf(stderr, "raypace render: out of memory\n");
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
    cJSON_AddNumberToObject(root, "samples_per_s",
                            t_render > 0 ? samples / t_render : 0.0);
    rc = print_json(root);
  } else {
    printf("wrote %s (%ux%u on %s '%s', %llu samples, %.1f ms, %.2f M "
           "samples/s)\n", o.out, o.width, o.height, caps.backend,
           caps.device, (unsigned long long)samples, t_render * 1e3,
           t_render > 0 ? samples / t_render / 1e6 : 0.0);
    rc = 0;
  }
out:
  free(rgba);
  free(out);
  free(tiles);
  rp_device_destroy(dev);
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
  return rc;
}

int main(int argc, char **argv) {
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
