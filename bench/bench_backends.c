/* M2 benchmark: device backends against the scalar reference.
 *
 *   bench_backends [--quick] [--runs N] [--data DIR] [--backend NAME]
 *                  [--device I] [--cold] [--device-only]
 *
 * Per data set (bonsai, engine), image size (512^2, 1024^2) and effect
 * set: raycast samples per second from the device's own timer, the depth
 * pass and the ERT pre-pass as a fraction of one raycast, and the scalar
 * reference's samples per second on the same frame: on one thread, and
 * with its tile rows dealt out in turn to one thread per online CPU (a
 * plain multithreaded C loop over the cores the device also runs on). Kernel
 * build cost: the first frame of an effect set against the same frame
 * again, on a fresh device. --cold points POCL_CACHE_DIR at a new empty
 * directory first, so that the first frame pays PoCL's full compile.
 * Medians over N runs (default 7). Besides device time, samples per
 * CPU-second of the whole process: on a shared machine wall time also
 * measures the neighbours, and two idle cores give at most twice the
 * per-CPU-second figure. --quick shrinks everything so that the test
 * suite can check the program still runs; --device-only leaves out the
 * scalar reference, which takes most of a full run's time. */
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "bench_util.h"
#include "raypace.h"

#define MAX_RUNS 64

static double now(void) { return bench_seconds(CLOCK_MONOTONIC); }

/* CPU time of the whole process (PoCL's worker threads included): on a
 * shared machine it measures the work where wall time measures the
 * neighbours too. */
static double cpu_now(void) {
  return bench_seconds(CLOCK_PROCESS_CPUTIME_ID);
}

static void die(rp_context *ctx, const char *what, int err) {
  fprintf(stderr, "bench_backends: %s: %s: %s\n", what, rp_strerror(err),
          rp_last_error(ctx));
  exit(1);
}

typedef struct scene {
  const char *name;
  rp_volume *vol;
  rp_tf *tf;
  rp_histograms *h; /* the occupancy points into it */
  rp_occupancy *occ;
  rp_camera cam;
} scene;

typedef struct options {
  const char *backend;
  uint32_t device;
  int runs, quick;
  int device_only; /* no scalar reference rows: device figures in seconds */
} options;

static const struct {
  uint32_t effects;
  const char *name;
} effect_sets[] = {
    {0, "none"},
    {RP_EFFECT_ERT | RP_EFFECT_SKIP, "ert+skip"},
    {RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP, "shade+ert+skip"},
};

static uint64_t total_samples(const rp_tile_stats *tiles, size_t n) {
  uint64_t s = 0;
  size_t i;
  for (i = 0; i < n; i++)
    s += tiles[i].samples;
  return s;
}

static rp_device *open_device(rp_context *ctx, const options *o) {
  rp_device_desc dd = {0};
  rp_device *dev = NULL;
  int err;
  dd.backend = o->backend;
  dd.index = o->device;
  if ((err = rp_device_create(ctx, &dd, &dev)) != 0)
    die(ctx, "device", err);
  return dev;
}

static void upload(rp_context *ctx, rp_device *dev, const scene *s) {
  int err;
  if ((err = rp_device_set_volume(dev, s->vol)) != 0 ||
      (err = rp_device_set_tf(dev, s->tf, s->occ)) != 0)
    die(ctx, "upload", err);
}

/* One band of the multithreaded reference. Each band has a context of
 * its own: a context and every object made from it may be used by one
 * thread at a time (raypace.h). */
typedef struct ref_band {
  rp_context *ctx;
  rp_device *dev;
  const rp_camera *cam;
  const rp_render_desc *desc;
  uint32_t first, stride, rows; /* tile rows first, first + stride, ... */
  uint32_t w, h;                /* the scaled image */
  uint8_t *rgba;        /* the whole scaled image; the band writes its rows */
  rp_tile_stats *tiles; /* the whole tile grid, likewise */
  pthread_t thread;
  int err; /* die() exits: called from several threads at once it races */
} ref_band;

static void *ref_band_main(void *arg) {
  ref_band *b = arg;
  uint32_t t;
  for (t = b->first; t < b->rows && b->err == 0; t += b->stride) {
    rp_region region;
    region.x0 = 0;
    region.x1 = b->w;
    region.y0 = t * RP_TILE_SIZE;
    /* The last row ends at the image edge, off the grid if need be. */
    region.y1 = (t + 1) * RP_TILE_SIZE < b->h ? (t + 1) * RP_TILE_SIZE
                                                : b->h;
    b->err = rp_device_render(b->dev, b->cam, b->desc, &region, b->rgba,
                              b->tiles);
  }
  return NULL;
}

/* The reference raycaster on one thread per online CPU, thread i taking
 * tile rows i, i + n, i + 2n, ... (regions must lie on the tile grid).
 * Interleaved, not in bands: samples crowd where the volume is, and on
 * bonsai at 512^2 two halves of the image held 17.0 M and 9.3 M
 * samples, so the slower half set the time. Median wall and process
 * CPU seconds of a frame over `runs`, threads and all; returns the
 * number of threads. Leaves the frame in rgba and tiles. */
static int reference_threads(rp_context *ctx, const scene *s,
                             const rp_render_desc *d, int runs,
                             uint8_t *rgba, rp_tile_stats *tiles,
                             size_t ntiles, double *wall, double *cpu) {
  long ncpu = sysconf(_SC_NPROCESSORS_ONLN);
  double tw[MAX_RUNS], tc[MAX_RUNS];
  uint32_t w, h, tx, ty;
  ref_band *b;
  int n, i, r, err;
  rp_scaled_size(d, &w, &h);
  rp_tile_grid(w, h, &tx, &ty);
  /* A thread with no tile row would idle: no more threads than rows. */
  n = ncpu < 1 ? 1 : ncpu > (long)ty ? (int)ty : (int)ncpu;
  if ((b = calloc((size_t)n, sizeof *b)) == NULL)
    die(ctx, "malloc", RP_ENOMEM);
  /* Devices and uploads outside the timed region: each keeps a copy. */
  for (i = 0; i < n; i++) {
    rp_device_desc dd = {0};
    dd.backend = "reference";
    if ((err = rp_context_create(NULL, &b[i].ctx)) != 0)
      die(ctx, "context", err);
    if ((err = rp_device_create(b[i].ctx, &dd, &b[i].dev)) != 0)
      die(b[i].ctx, "reference device", err);
    upload(b[i].ctx, b[i].dev, s);
    b[i].cam = &s->cam;
    b[i].desc = d;
    b[i].first = (uint32_t)i;
    b[i].stride = (uint32_t)n;
    b[i].rows = ty;
    b[i].w = w;
    b[i].h = h;
    b[i].rgba = rgba;
    b[i].tiles = tiles;
  }
  for (r = 0; r < runs; r++) {
    int started;
    /* Stale counts would hide a band that rendered nothing. */
    memset(tiles, 0, ntiles * sizeof *tiles);
    tw[r] = now();
    tc[r] = cpu_now();
    for (i = 0; i < n; i++)
      b[i].err = 0;
    for (started = 0; started < n; started++)
      if (pthread_create(&b[started].thread, NULL, ref_band_main,
                         &b[started]) != 0)
        break;
    for (i = 0; i < started; i++)
      pthread_join(b[i].thread, NULL);
    tw[r] = now() - tw[r];
    tc[r] = cpu_now() - tc[r];
    if (started < n)
      die(ctx, "pthread_create", RP_ENOMEM);
    for (i = 0; i < n; i++)
      if (b[i].err != 0)
        die(b[i].ctx, "reference band", b[i].err);
  }
  for (i = 0; i < n; i++) {
    rp_device_destroy(b[i].dev);
    rp_context_destroy(b[i].ctx);
  }
  free(b);
  *wall = bench_median(tw, runs);
  *cpu = bench_median(tc, runs);
  return n;
}

/* One image size and effect set on one scene. */
static void bench_frame(rp_context *ctx, rp_device *dev, const scene *s,
                        uint32_t size, uint32_t effects, const char *ename,
                        const options *o, int with_reference) {
  rp_render_desc d = {0};
  uint32_t tx, ty;
  size_t npx = (size_t)size * size, ntiles;
  uint8_t *rgba = malloc(npx * 4);
  float *d_ert = malloc(npx * sizeof *d_ert); /* more than enough */
  rp_tile_stats *tiles;
  double ray[MAX_RUNS], dep[MAX_RUNS], ert[MAX_RUNS], cpu[MAX_RUNS];
  double ray_s, dep_s, ert_s, cpu_s;
  uint64_t samples;
  int r, err;
  d.width = d.height = size;
  d.effects = effects;
  rp_tile_grid(size, size, &tx, &ty);
  ntiles = (size_t)tx * ty;
  tiles = malloc(ntiles * sizeof *tiles);
  if (rgba == NULL || tiles == NULL || d_ert == NULL)
    die(ctx, "malloc", RP_ENOMEM);
  /* Once untimed: builds the kernels for this effect set. */
  if ((err = rp_device_render(dev, &s->cam, &d, NULL, rgba, tiles)) != 0)
    die(ctx, "render", err);
  samples = total_samples(tiles, ntiles);
  for (r = 0; r < o->runs; r++) {
    if ((err = rp_device_depth_pass(dev, &s->cam, &d, NULL)) != 0)
      die(ctx, "depth pass", err);
    dep[r] = rp_device_last_time_ns(dev) * 1e-9;
    if ((err = rp_device_ert_prepass(dev, &s->cam, &d, 1u, (uint32_t)r,
                                     d_ert)) != 0)
      die(ctx, "ERT pre-pass", err);
    ert[r] = rp_device_last_time_ns(dev) * 1e-9;
    cpu[r] = cpu_now();
    if ((err = rp_device_render(dev, &s->cam, &d, NULL, rgba, tiles)) != 0)
      die(ctx, "render", err);
    cpu[r] = cpu_now() - cpu[r];
    ray[r] = rp_device_last_time_ns(dev) * 1e-9;
  }
  ray_s = bench_median(ray, o->runs);
  dep_s = bench_median(dep, o->runs);
  ert_s = bench_median(ert, o->runs);
  cpu_s = bench_median(cpu, o->runs);
  printf("%-8s %4u^2 %-15s raycast %8.2f ms %7.1f M samples/s  "
         "%6.1f M/cpu-s  depth %5.2f %%  ert %5.2f %%  (%.1f M samples)\n",
         s->name, (unsigned)size, ename, ray_s * 1e3,
         ray_s > 0 ? samples / ray_s / 1e6 : 0.0,
         cpu_s > 0 ? samples / cpu_s / 1e6 : 0.0,
         ray_s > 0 ? 100.0 * dep_s / ray_s : 0.0,
         ray_s > 0 ? 100.0 * ert_s / ray_s : 0.0, samples / 1e6);
  if (with_reference) {
    double t0 = now(), c0 = cpu_now(), t, c;
    uint64_t one, all;
    int nt;
    if ((err = rp_render_reference(ctx, s->vol, s->tf, s->occ, NULL, &s->cam, &d,
                                   rgba, tiles)) != 0)
      die(ctx, "reference", err);
    t = now() - t0;
    c = cpu_now() - c0;
    one = total_samples(tiles, ntiles);
    printf("%-8s %4u^2 %-15s reference %8.2f ms %7.1f M samples/s  "
           "%6.1f M/cpu-s (1 thread): device %.1fx (%.1fx per cpu-s)\n",
           s->name, (unsigned)size, ename, t * 1e3, one / t / 1e6,
           one / c / 1e6, ray_s > 0 ? t / ray_s : 0.0,
           cpu_s > 0 ? c / cpu_s : 0.0);
    /* As many runs as the one-thread figure above has: one. */
    nt = reference_threads(ctx, s, &d, 1, rgba, tiles, ntiles, &t, &c);
    all = total_samples(tiles, ntiles);
    printf("%-8s %4u^2 %-15s reference %8.2f ms %7.1f M samples/s  "
           "%6.1f M/cpu-s (%d thread%s): device %.1fx (%.1fx per cpu-s)\n",
           s->name, (unsigned)size, ename, t * 1e3,
           t > 0 ? all / t / 1e6 : 0.0, c > 0 ? all / c / 1e6 : 0.0, nt,
           nt == 1 ? "" : "s", ray_s > 0 ? t / ray_s : 0.0,
           cpu_s > 0 ? c / cpu_s : 0.0);
    /* The bands must add up to the same frame, or the figure compares
     * different work. */
    if (all != one)
      printf("%-8s %4u^2 %-15s warning: %d-thread reference took %llu "
             "samples, one thread %llu\n",
             s->name, (unsigned)size, ename, nt, (unsigned long long)all,
             (unsigned long long)one);
  }
  free(d_ert);
  free(tiles);
  free(rgba);
}

/* First frame of each effect set on a fresh device against the second. */
static void bench_builds(rp_context *ctx, const scene *s, const options *o) {
  rp_render_desc d = {0};
  uint32_t size = o->quick ? 16 : 64;
  uint8_t *rgba = malloc((size_t)size * size * 4);
  size_t i;
  int err;
  rp_device *dev = open_device(ctx, o);
  if (rgba == NULL)
    die(ctx, "malloc", RP_ENOMEM);
  upload(ctx, dev, s);
  d.width = d.height = size;
  for (i = 0; i < sizeof effect_sets / sizeof effect_sets[0]; i++) {
    double t0, first, again;
    d.effects = effect_sets[i].effects;
    t0 = now();
    if ((err = rp_device_render(dev, &s->cam, &d, NULL, rgba, NULL)) != 0)
      die(ctx, "render", err);
    first = now() - t0;
    t0 = now();
    if ((err = rp_device_render(dev, &s->cam, &d, NULL, rgba, NULL)) != 0)
      die(ctx, "render", err);
    again = now() - t0;
    printf("build    %-15s first frame %8.1f ms, again %6.2f ms: "
           "build + compile %8.1f ms\n",
           effect_sets[i].name, first * 1e3, again * 1e3,
           (first - again) * 1e3);
  }
  rp_device_destroy(dev);
  free(rgba);
}

static int load_scene(rp_context *ctx, const char *data, const char *name,
                      scene *s) {
  char path[1024];
  int err;
  memset(s, 0, sizeof *s);
  s->name = name;
  if (data == NULL)
    return 0;
  snprintf(path, sizeof path, "%s/%s/%s.txt", data, name, name);
  if (rp_volume_load(ctx, path, &s->vol) != 0)
    return 0;
  if ((err = rp_tf_create_preset(ctx, "minmax-bone", &s->tf)) != 0 ||
      (err = rp_histograms_build(ctx, s->vol, &s->h)) != 0 ||
      (err = rp_occupancy_build(ctx, s->h, s->tf, &s->occ)) != 0)
    die(ctx, name, err);
  rp_camera_orbit(&s->cam, s->vol, 30.0f, 20.0f, 1.6f);
  return 1;
}

static void free_scene(scene *s) {
  rp_occupancy_destroy(s->occ);
  rp_histograms_destroy(s->h);
  rp_tf_destroy(s->tf);
  rp_volume_destroy(s->vol);
}

int main(int argc, char **argv) {
  static const char *const names[] = {"bonsai", "engine"};
  const char *data = getenv("RP_SHARED_DATA");
  options o = {NULL, 0, 7, 0, 0};
  rp_context *ctx = NULL;
  int cold = 0, i, err, built = 0;
  size_t k, e;
  for (i = 1; i < argc; i++) {
    if (strcmp(argv[i], "--quick") == 0)
      o.quick = 1;
    else if (strcmp(argv[i], "--runs") == 0 && i + 1 < argc)
      o.runs = atoi(argv[++i]);
    else if (strcmp(argv[i], "--data") == 0 && i + 1 < argc)
      data = argv[++i];
    else if (strcmp(argv[i], "--backend") == 0 && i + 1 < argc)
      o.backend = argv[++i];
    else if (strcmp(argv[i], "--device") == 0 && i + 1 < argc)
      o.device = (uint32_t)atoi(argv[++i]);
    else if (strcmp(argv[i], "--cold") == 0)
      cold = 1;
    else if (strcmp(argv[i], "--device-only") == 0)
      o.device_only = 1;
    else {
      fprintf(stderr, "usage: bench_backends [--quick] [--runs N] "
                      "[--data DIR] [--backend NAME] [--device I] "
                      "[--cold] [--device-only]\n");
      return 2;
    }
  }
  if (o.runs < 1 || o.runs > MAX_RUNS)
    o.runs = 7;
  if (o.quick)
    o.runs = 1;
  if (cold) {
    /* Before the first OpenCL call, which is when PoCL reads it. */
    static char dir[] = "/tmp/rp_bench_pocl_XXXXXX";
    if (mkdtemp(dir) == NULL || setenv("POCL_CACHE_DIR", dir, 1) != 0) {
      perror("bench_backends: --cold");
      return 1;
    }
  }
  if ((err = rp_context_create(NULL, &ctx)) != 0)
    die(NULL, "context", err);
  {
    rp_device_desc dd = {0};
    rp_device *dev = NULL;
    rp_caps caps;
    dd.backend = o.backend;
    dd.index = o.device;
    /* No device here: skipped (77), as the test suite counts it. */
    if ((err = rp_device_create(ctx, &dd, &dev)) == RP_ENODEV) {
      printf("bench_backends: %s; skipped\n", rp_last_error(ctx));
      rp_context_destroy(ctx);
      return 77;
    }
    if (err != 0)
      die(ctx, "device", err);
    rp_device_get_caps(dev, &caps);
    printf("device: %s '%s', %u compute units%s\n", caps.backend,
           caps.device, (unsigned)caps.compute_units,
           caps.sub_device ? " (sub-device)" : "");
    rp_device_destroy(dev);
  }
  if (o.quick) {
    /* No data needed: a small generated volume, one frame. */
    scene s = {"phantom", NULL, NULL, NULL, NULL, {0}};
    rp_generate_desc g = {RP_GEN_PHANTOM, {40, 40, 40}, RP_U8, 0};
    rp_device *dev;
    if ((err = rp_volume_generate(ctx, &g, &s.vol)) != 0 ||
        (err = rp_tf_create_preset(ctx, "minmax-bone", &s.tf)) != 0 ||
        (err = rp_histograms_build(ctx, s.vol, &s.h)) != 0 ||
        (err = rp_occupancy_build(ctx, s.h, s.tf, &s.occ)) != 0)
      die(ctx, "phantom", err);
    rp_camera_orbit(&s.cam, s.vol, 30.0f, 20.0f, 1.6f);
    bench_builds(ctx, &s, &o);
    dev = open_device(ctx, &o);
    upload(ctx, dev, &s);
    bench_frame(ctx, dev, &s, 32, RP_EFFECT_SHADING, "shading", &o, 1);
    rp_device_destroy(dev);
    free_scene(&s);
    rp_context_destroy(ctx);
    return 0;
  }
  for (k = 0; k < sizeof names / sizeof names[0]; k++) {
    scene s;
    rp_device *dev;
    if (!load_scene(ctx, data, names[k], &s)) {
      printf("%s: not found under %s; skipped\n", names[k],
             data != NULL ? data : "(RP_SHARED_DATA unset)");
      continue;
    }
    if (!built) {
      bench_builds(ctx, &s, &o);
      built = 1;
    }
    dev = open_device(ctx, &o);
    upload(ctx, dev, &s);
    for (e = 0; e < sizeof effect_sets / sizeof effect_sets[0]; e++) {
      bench_frame(ctx, dev, &s, 512, effect_sets[e].effects,
                  effect_sets[e].name, &o, !o.device_only);
      bench_frame(ctx, dev, &s, 1024, effect_sets[e].effects,
                  effect_sets[e].name, &o, 0);
    }
    rp_device_destroy(dev);
    free_scene(&s);
  }
  rp_context_destroy(ctx);
  return 0;
}
