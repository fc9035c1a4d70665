/* bench_ao: seed 004's Table 1 on this machine's devices, and what AO
 * costs a frame.
 *
 * Per volume (the ../shared/data sets named, or generated ones), AO with
 * the default desc (L = 8, M = 16, R = 8, a = 1) under a TF preset:
 *   1 device, unbricked     (the reference time; speedups are against it)
 *   1 device, bricked
 *   N devices, static naive, unbricked
 *   N devices, static naive, bricked
 *   N devices, static balanced, bricked
 *   N devices, dynamic, bricked
 * each as the median total wall time over --runs, with the devices'
 * (t_min, t_max) compute times of the median run, as the seed's table
 * prints them. Then one frame's raycast with and without AO at 512^2
 * (median of 9 renders on each device, each variant built first). The
 * last row is static with the speeds the dynamic row measured (full
 * bricks per ms per device): what a second TF change would get from
 * rp_device_group_compute_ao.
 *
 * Device sets (--set):
 *   cl2      PoCL's two 1-compute-unit sub-devices (OpenCL devices 1, 2)
 *   cl-vk    PoCL device 1 and lavapipe (set LP_NUM_THREADS=1)
 *   cl-slow  as cl2, the second slowed 3x (rp_fault_desc.slowdown)
 *
 * With --sweep, what AO accuracy costs: time and error of L in {4, 8,
 * 16, 32} directions and M in {4, 8, 16} samples against L = 64, M = 32.
 *
 * usage: bench_ao [--set cl2|cl-vk|cl-slow] [--runs N] [--tf PRESET]
 *                 [--sweep] [VOLUME ...]   (default: bonsai engine headsq_ct from
 *                 $RP_SHARED_DATA, else a generated 128^3 phantom) */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_util.h"
#include "raypace.h"
#include "raypace_ao.h"
#include "raypace_testing.h"

#define MAX_RUNS 15
/* Frames are short and noisy next to AO computations: more of them. */
#define FRAME_RUNS 9

typedef struct device_set {
  rp_context *ctx[2];
  rp_device *dev[2];
  uint32_t n;
} device_set;

/* The second device of set cl-slow: three times slower. */
static const rp_fault_desc slowed_3x = {{RP_EXT_FAULTS, NULL}, 3.0, 0, 0, 0,
                                        0.0};

static int open_set(const char *set, device_set *ds) {
  rp_device_desc dd[2];
  uint32_t i;
  memset(ds, 0, sizeof *ds);
  memset(dd, 0, sizeof dd);
  ds->n = 2;
  if (strcmp(set, "cl2") == 0 || strcmp(set, "cl-slow") == 0) {
    dd[0].backend = dd[1].backend = "opencl";
    dd[0].index = 1;
    dd[1].index = 2;
    if (strcmp(set, "cl-slow") == 0)
      dd[1].next = &slowed_3x;
  } else if (strcmp(set, "cl-vk") == 0) {
    dd[0].backend = "opencl";
    dd[0].index = 1;
    dd[1].backend = "vulkan";
  } else {
    fprintf(stderr, "bench_ao: unknown set '%s'\n", set);
    return 2;
  }
  for (i = 0; i < 2; i++) {
    int err;
    if ((err = rp_context_create(NULL, &ds->ctx[i])) != 0 ||
        (err = rp_device_create(ds->ctx[i], &dd[i], &ds->dev[i])) != 0) {
      fprintf(stderr, "bench_ao: device %u: %s\n", i,
              ds->ctx[i] != NULL ? rp_last_error(ds->ctx[i]) : "context");
      return 1;
    }
  }
  return 0;
}

static void close_set(device_set *ds) {
  uint32_t i;
  for (i = 0; i < 2; i++) {
    rp_device_destroy(ds->dev[i]);
    rp_context_destroy(ds->ctx[i]);
  }
}

typedef struct row {
  const char *name;
  uint32_t devices;
  int unbricked;
  rp_ao_scheme scheme;
  int speeds; /* static with the speeds the dynamic row measured */
} row;

static const row rows[] = {
    {"1 device, unbricked", 1, 1, RP_AO_STATIC_NAIVE, 0},
    {"1 device, bricked", 1, 0, RP_AO_STATIC_NAIVE, 0},
    {"static naive, unbricked", 2, 1, RP_AO_STATIC_NAIVE, 0},
    {"static naive, bricked", 2, 0, RP_AO_STATIC_NAIVE, 0},
    {"static balanced, bricked", 2, 0, RP_AO_STATIC, 0},
    {"dynamic, bricked", 2, 0, RP_AO_DYNAMIC, 0},
    {"static by speed, bricked", 2, 0, RP_AO_STATIC, 1},
};

/* What the effect costs a frame on device i: 512^2, shaded, ERT and
 * skipping, with and without AO; each variant built before timing. */
static int frame_cost(rp_context *ctx, const rp_volume *vol, const rp_tf *tf,
                      device_set *ds, uint32_t i) {
  rp_ao_plan *plan = NULL;
  rp_ao *ao = NULL;
  rp_camera cam = {0};
  rp_render_desc d = {512, 512, 1.0f, 0, 0, 0, RP_JITTER_DEFAULT, 0};
  uint8_t *rgba = malloc(512 * 512 * 4);
  double t[2][FRAME_RUNS];
  rp_caps caps;
  int k, e, err = RP_ENOMEM;
  if (rgba == NULL ||
      (err = rp_ao_plan_create(ctx, vol, tf, NULL, &plan)) != 0 ||
      (err = rp_ao_compute(ctx, &ds->dev[i], 1, plan, NULL, &ao, NULL)) !=
          0 ||
      (err = rp_device_set_ao(ds->dev[i], ao)) != 0) {
    fprintf(stderr, "bench_ao: frame: %s\n", rp_last_error(ctx));
  } else {
    rp_camera_orbit(&cam, vol, 30.0f, 20.0f, 2.0f);
    for (e = 0; e < 2 && err == 0; e++) {
      d.effects = RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP |
                  (e ? RP_EFFECT_AO : 0u);
      err = rp_device_render(ds->dev[i], &cam, &d, NULL, rgba, NULL);
      for (k = 0; k < FRAME_RUNS && err == 0; k++) {
        err = rp_device_render(ds->dev[i], &cam, &d, NULL, rgba, NULL);
        t[e][k] = rp_device_last_time_ns(ds->dev[i]) * 1e-6;
      }
    }
    if (err != 0) {
      fprintf(stderr, "bench_ao: render: %s\n", rp_last_error(ds->ctx[i]));
    } else {
      double off = bench_median(t[0], FRAME_RUNS);
      double on = bench_median(t[1], FRAME_RUNS);
      rp_device_get_caps(ds->dev[i], &caps);
      printf("  frame 512^2 shaded on %s, median of %d: AO off %.1f ms, "
             "on %.1f ms (x%.3f)\n", caps.backend, FRAME_RUNS, off, on,
             on / off);
    }
  }
  free(rgba);
  rp_ao_plan_destroy(plan);
  rp_ao_destroy(ao);
  rp_device_set_ao(ds->dev[i], NULL);
  return err != 0;
}

/* AO over the set (dynamic, bricked) of `desc` into *out, timed. */
static int timed_ao(rp_context *ctx, const rp_volume *vol, const rp_tf *tf,
                    device_set *ds, const rp_ao_desc *desc, rp_ao **out,
                    double *ms) {
  rp_ao_plan *plan = NULL;
  double t0 = bench_seconds(CLOCK_MONOTONIC);
  int err = rp_ao_plan_create(ctx, vol, tf, desc, &plan);
  if (err == 0)
    err = rp_ao_compute(ctx, ds->dev, ds->n, plan, NULL, out, NULL);
  *ms = (bench_seconds(CLOCK_MONOTONIC) - t0) * 1e3;
  rp_ao_plan_destroy(plan);
  if (err != 0)
    fprintf(stderr, "bench_ao: AO L=%u M=%u: %s\n", desc->directions,
            desc->samples, rp_last_error(ctx));
  return err;
}

/* What AO accuracy costs in time: directions L and samples M against a
 * fine AO (L = 64, M = 32), both over the set, the error taken over the
 * voxels the fine AO computed (full bricks), in 1/255 units. */
static int accuracy_sweep(rp_context *ctx, const rp_volume *vol,
                          const rp_tf *tf, device_set *ds) {
  static const uint32_t Ls[] = {4, 8, 16, 32}, Ms[] = {4, 8, 16};
  rp_ao_desc fine = {64, 32, 0, 0, 0};
  rp_ao *ref = NULL;
  const uint8_t *r;
  uint32_t dims[3];
  size_t n, li, mi;
  double ms;
  if (timed_ao(ctx, vol, tf, ds, &fine, &ref, &ms) != 0)
    return 1;
  r = rp_ao_data(ref, dims);
  n = (size_t)dims[0] * dims[1] * dims[2];
  printf("  accuracy: fine AO (L 64, M 32) took %.0f ms\n", ms);
  printf("  %4s %4s %10s %10s %8s\n", "L", "M", "ms", "RMSE/255",
         "max/255");
  for (li = 0; li < sizeof Ls / sizeof Ls[0]; li++)
    for (mi = 0; mi < sizeof Ms / sizeof Ms[0]; mi++) {
      rp_ao_desc d = {0};
      rp_ao *ao = NULL;
      const uint8_t *a;
      double sq = 0.0;
      size_t i, counted = 0;
      int worst = 0;
      d.directions = Ls[li];
      d.samples = Ms[mi];
      if (timed_ao(ctx, vol, tf, ds, &d, &ao, &ms) != 0) {
        rp_ao_destroy(ref);
        return 1;
      }
      a = rp_ao_data(ao, NULL);
      /* Voxels the fine AO left at 255 are those of empty bricks, the
       * same under any L and M: they would only dilute the error. */
      for (i = 0; i < n; i++) {
        int e = abs((int)a[i] - (int)r[i]);
        if (r[i] == 255 && a[i] == 255)
          continue;
        sq += (double)e * e;
        worst = e > worst ? e : worst;
        counted++;
      }
      printf("  %4u %4u %10.1f %10.2f %8d\n", Ls[li], Ms[mi], ms,
             counted > 0 ? sqrt(sq / (double)counted) : 0.0, worst);
      rp_ao_destroy(ao);
    }
  rp_ao_destroy(ref);
  return 0;
}

static int bench_volume(rp_context *ctx, const char *spec, const char *path,
                        const char *set, const char *tf_name, int runs,
                        int sweep) {
  rp_volume *vol = NULL;
  rp_tf *tf = NULL;
  rp_histograms *h = NULL;
  rp_occupancy *occ = NULL;
  device_set ds;
  double ref_ms = 0.0, speed[RP_AO_MAX_DEVICES] = {0};
  size_t r;
  uint32_t i;
  int err, rc = 1;
  rp_volume_info info;
  memset(&ds, 0, sizeof ds);
  if (path != NULL)
    err = rp_volume_load(ctx, path, &vol);
  else {
    rp_generate_desc g = {RP_GEN_PHANTOM, {128, 128, 128}, RP_U8, 1};
    err = rp_volume_generate(ctx, &g, &vol);
  }
  if (err != 0 || (err = rp_tf_create_preset(ctx, tf_name, &tf)) != 0 ||
      (err = rp_histograms_build(ctx, vol, &h)) != 0 ||
      (err = rp_occupancy_build(ctx, h, tf, &occ)) != 0) {
    fprintf(stderr, "bench_ao: %s: %s\n", spec, rp_last_error(ctx));
    goto out;
  }
  if ((rc = open_set(set, &ds)) != 0)
    goto out;
  rc = 1;
  for (i = 0; i < ds.n; i++)
    if ((err = rp_device_set_volume(ds.dev[i], vol)) != 0 ||
        (err = rp_device_set_tf(ds.dev[i], tf, occ)) != 0) {
      fprintf(stderr, "bench_ao: upload: %s\n", rp_last_error(ds.ctx[i]));
      goto out;
    }
  rp_volume_get_info(vol, &info);
  printf("\n%s (%ux%ux%u), tf %s, set %s, median of %d\n", spec,
         info.dims[0], info.dims[1], info.dims[2], tf_name, set, runs);
  printf("  %-26s %10s %18s %8s %7s\n", "", "total ms", "(t_min, t_max)",
         "speedup", "bricks");
  for (r = 0; r < sizeof rows / sizeof rows[0]; r++) {
    rp_ao_desc desc = {0};
    rp_ao_plan *plan = NULL;
    rp_ao_schedule sc = {0};
    double total[MAX_RUNS], tmin[MAX_RUNS], tmax[MAX_RUNS], med;
    uint64_t computed = 0, bricks = 0;
    int k, pick = 0;
    desc.unbricked = rows[r].unbricked;
    sc.scheme = rows[r].scheme;
    if (rows[r].speeds)
      memcpy(sc.speed, speed, sizeof speed);
    for (k = 0; k < runs; k++) {
      rp_ao_report rep;
      rp_ao *ao = NULL;
      double t0 = bench_seconds(CLOCK_MONOTONIC);
      /* The plan (brick mask) is part of what a TF change costs. */
      if ((err = rp_ao_plan_create(ctx, vol, tf, &desc, &plan)) != 0 ||
          (err = rp_ao_compute(ctx, ds.dev, rows[r].devices, plan, &sc, &ao,
                               &rep)) != 0) {
        fprintf(stderr, "bench_ao: %s: %s\n", rows[r].name,
                rp_last_error(ctx));
        rp_ao_plan_destroy(plan);
        goto out;
      }
      total[k] = (bench_seconds(CLOCK_MONOTONIC) - t0) * 1e3;
      tmin[k] = rep.min_ms;
      tmax[k] = rep.max_ms;
      if (rows[r].scheme == RP_AO_DYNAMIC && rows[r].devices == 2)
        for (i = 0; i < 2; i++)
          speed[i] = rep.devices[i].busy_ms > 0.0
                         ? (double)rep.devices[i].full_bricks /
                               rep.devices[i].busy_ms
                         : 0.0;
      rp_ao_bricks(ao, &computed, &bricks);
      rp_ao_destroy(ao);
      rp_ao_plan_destroy(plan);
      plan = NULL;
    }
    {
      double sorted[MAX_RUNS];
      memcpy(sorted, total, sizeof(double) * (size_t)runs);
      med = bench_median(sorted, runs);
      for (k = 0; k < runs; k++)
        if (total[k] == med)
          pick = k;
    }
    if (r == 0)
      ref_ms = med;
    printf("  %-26s %10.1f (%7.1f, %7.1f) %8.2f %6.1f%%\n", rows[r].name,
           med, tmin[pick], tmax[pick], ref_ms / med,
           bricks > 0 ? 100.0 * (double)computed / (double)bricks : 0.0);
  }
  for (i = 0; i < ds.n; i++)
    if ((rc = frame_cost(ctx, vol, tf, &ds, i)) != 0)
      goto out;
  if (sweep && (rc = accuracy_sweep(ctx, vol, tf, &ds)) != 0)
    goto out;
  rc = 0;
out:
  close_set(&ds);
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(h);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  return rc;
}

int main(int argc, char **argv) {
  static const char *defaults[] = {"bonsai", "engine", "headsq_ct"};
  const char *set = "cl2", *tf = "minmax-bone", *names[16];
  const char *data = getenv("RP_SHARED_DATA");
  int runs = 3, n = 0, i, rc = 0, sweep = 0;
  rp_context *ctx = NULL;
  /* A run takes minutes: show each row as it is measured. */
  setvbuf(stdout, NULL, _IOLBF, 0);
  for (i = 1; i < argc; i++) {
    if (strcmp(argv[i], "--set") == 0 && i + 1 < argc)
      set = argv[++i];
    else if (strcmp(argv[i], "--tf") == 0 && i + 1 < argc)
      tf = argv[++i];
    else if (strcmp(argv[i], "--sweep") == 0)
      sweep = 1;
    else if (strcmp(argv[i], "--runs") == 0 && i + 1 < argc)
      runs = atoi(argv[++i]);
    else if (argv[i][0] == '-') {
      fprintf(stderr, "usage: bench_ao [--set cl2|cl-vk|cl-slow] "
              "[--runs N] [--tf PRESET] [--sweep] [VOLUME ...]\n");
      return 2;
    } else if (n < 16)
      names[n++] = argv[i];
  }
  if (runs < 1 || runs > MAX_RUNS) {
    fprintf(stderr, "bench_ao: --runs must be in [1, %d]\n", MAX_RUNS);
    return 2;
  }
  if (rp_context_create(NULL, &ctx) != 0)
    return 1;
  if (n == 0 && data != NULL)
    for (i = 0; i < 3; i++)
      names[n++] = defaults[i];
  if (n == 0)
    rc = bench_volume(ctx, "generated phantom 128^3", NULL, set, tf, runs,
                      sweep);
  for (i = 0; i < n && rc == 0; i++) {
    char path[1024];
    snprintf(path, sizeof path, "%s/%s/%s.txt", data != NULL ? data : ".",
             names[i], names[i]);
    rc = bench_volume(ctx, names[i], path, set, tf, runs, sweep);
  }
  rp_context_destroy(ctx);
  return rc;
}
