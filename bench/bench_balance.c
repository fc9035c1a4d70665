/* bench_balance: M6's goals. Plays an interaction sequence (orbit, TF
 * switches, zoom: built-in "mixed") on a pair of devices and reports, per
 * way of splitting the frame:
 *   - the balance deviation (seed 001 section 6): per frame (max - min) /
 *     mean of the devices' busy times, averaged over the frames;
 *   - the frame's render time (wall, the group's whole render), median
 *     and 95th percentile, against each device alone.
 *
 * Ways of splitting, every one on the same frames:
 *   tail    ours, the default: shares from each device's measured cost
 *           per unit of predicted tile cost, damped toward last frame's
 *           (lambda 0.5), and 0.15 of the predicted cost held back in
 *           strips that whichever device is done first takes
 *           (rp_group_desc.tail_fraction);
 *   smooth  the same shares, every pixel split in advance (no tail);
 *   even    the same shares damped the paper's way, mixed with the even
 *           split (zeta 0.5);
 *   static  fixed shares from each device's average frame time alone over
 *           the whole sequence (seed 000's "static distribution, based on
 *           empirically determined average sample costs"), split by the
 *           predicted tile costs;
 *   static-area  the same fixed shares, split by tile count (a static
 *           split that ignores where the work is).
 * Pass 1 renders each device alone (for the static shares and the
 * "best single device" figure); pass 2 renders every way, interleaved per
 * frame so that the machine's noise falls on all of them alike.
 *
 * Pairs (--pair):
 *   cl-vk    a 1-compute-unit PoCL sub-device and lavapipe with
 *            LP_NUM_THREADS=1: two different one-core devices;
 *   cl-slow  PoCL's two 1-compute-unit sub-devices (OpenCL devices 1
 *            and 2), the second slowed 3x (rp_fault_desc.slowdown).
 * The step stays at 1 voxel (no tuning): what is measured is the split. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bench_util.h"
#include "raypace.h"
#include "raypace_group.h"
#include "raypace_sequence.h"
#include "raypace_testing.h"

#define MAX_FRAMES 2048
#define SETTLE 5 /* frames left out of the averages: first-frame builds */

enum { WAY_TAIL, WAY_SMOOTH, WAY_EVEN, WAY_STATIC, WAY_AREA, WAYS };
static const char *const way_names[WAYS] = {"tail", "smooth", "even",
                                            "static", "static-area"};
#define NO_TAIL -1.0

typedef struct opts {
  const char *volume, *pair, *sequence, *csv;
  uint32_t size, frames;
  double tail;          /* the tail way's rp_group_desc fields: 0, the */
  uint32_t tail_strips; /* defaults */
} opts;

typedef struct scene {
  rp_context *ctx;
  rp_volume *vol;
  rp_histograms *h;
  rp_occupancy *occ;
  rp_tf **tfs;
  int tf_count, tf_active;
  rp_sequence *seq;
} scene;

static int usage(void) {
  fprintf(stderr,
          "usage: bench_balance [--volume PATH|phantom] [--pair cl-vk|cl-slow]"
          "\n                     [--size N] [--frames N] [--sequence S] "
          "[--csv FILE]\n                     [--tail F] [--tail-strips N]\n");
  return 2;
}

static int parse(int argc, char **argv, opts *o) {
  int i;
  o->volume = "phantom";
  o->pair = "cl-vk";
  o->sequence = "mixed";
  o->csv = NULL;
  o->size = 512;
  o->frames = 0;
  o->tail = 0.0;
  o->tail_strips = 0;
  for (i = 1; i < argc; i++) {
    const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
    if (v == NULL)
      return usage();
    if (strcmp(a, "--volume") == 0)
      o->volume = v;
    else if (strcmp(a, "--pair") == 0)
      o->pair = v;
    else if (strcmp(a, "--sequence") == 0)
      o->sequence = v;
    else if (strcmp(a, "--csv") == 0)
      o->csv = v;
    else if (strcmp(a, "--size") == 0)
      o->size = (uint32_t)strtoul(v, NULL, 10);
    else if (strcmp(a, "--frames") == 0)
      o->frames = (uint32_t)strtoul(v, NULL, 10);
    else if (strcmp(a, "--tail") == 0)
      o->tail = strtod(v, NULL);
    else if (strcmp(a, "--tail-strips") == 0)
      o->tail_strips = (uint32_t)strtoul(v, NULL, 10);
    else
      return usage();
    i++;
  }
  if (o->size < 8 || o->size > 4096)
    return usage();
  return 0;
}

static int fail(rp_context *ctx, const char *what, int err) {
  fprintf(stderr, "bench_balance: %s: %s (%s)\n", what, rp_last_error(ctx),
          rp_err_name(err));
  return 1;
}

static int open_scene(const opts *o, scene *s) {
  int err, i;
  memset(s, 0, sizeof *s);
  if ((err = rp_context_create(NULL, &s->ctx)) != 0)
    return 1;
  if (strcmp(o->volume, "phantom") == 0) {
    rp_generate_desc g = {0};
    g.kind = RP_GEN_PHANTOM;
    g.dims[0] = g.dims[1] = g.dims[2] = 256;
    g.seed = 1;
    err = rp_volume_generate(s->ctx, &g, &s->vol);
  } else {
    err = rp_volume_load(s->ctx, o->volume, &s->vol);
  }
  if (err != 0)
    return fail(s->ctx, o->volume, err);
  if ((err = rp_histograms_build(s->ctx, s->vol, &s->h)) != 0)
    return fail(s->ctx, "histograms", err);
  if ((err = rp_sequence_load(s->ctx, o->sequence, &s->seq)) != 0)
    return fail(s->ctx, o->sequence, err);
  s->tf_count = rp_sequence_tf_count(s->seq);
  s->tfs = calloc((size_t)s->tf_count, sizeof *s->tfs);
  if (s->tfs == NULL)
    return 1;
  for (i = 0; i < s->tf_count; i++)
    if ((err = rp_sequence_tf_create(s->ctx, s->seq, i, &s->tfs[i])) != 0)
      return fail(s->ctx, "transfer function", err);
  s->tf_active = -1;
  return 0;
}

static void close_scene(scene *s) {
  int i;
  for (i = 0; i < s->tf_count && s->tfs != NULL; i++)
    rp_tf_destroy(s->tfs[i]);
  free(s->tfs);
  rp_sequence_destroy(s->seq);
  rp_occupancy_destroy(s->occ);
  rp_histograms_destroy(s->h);
  rp_volume_destroy(s->vol);
  rp_context_destroy(s->ctx);
}

/* The second device of pair cl-slow: three times slower. */
static const rp_fault_desc slowed_3x = {{RP_EXT_FAULTS, NULL}, 3.0, 0, 0, 0,
                                        0.0};

/* The pair's device descriptions. */
static int pair_devices(const char *pair, rp_device_desc *dd) {
  memset(dd, 0, 2 * sizeof *dd);
  dd[0].backend = "opencl";
  dd[0].compute_units = 1;
  if (strcmp(pair, "cl-vk") == 0) {
    /* lavapipe reads it when its instance is made: before any device. */
    setenv("LP_NUM_THREADS", "1", 0);
    dd[1].backend = "vulkan";
  } else if (strcmp(pair, "cl-slow") == 0) {
    /* The enumerated one-core parts 1 and 2 (cl_device.c): two
     * compute_units = 1 devices would both open part 0 of their split,
     * and PoCL runs two part 0s on the same core, one after the other
     * (measured: 20 + 23 ms of kernel in 43 ms of wall time each). */
    dd[0].compute_units = 0;
    dd[0].index = 1;
    dd[1].backend = "opencl";
    dd[1].index = 2;
    dd[1].next = &slowed_3x;
  } else {
    return 1;
  }
  return 0;
}

static int make_group(scene *s, const rp_device_desc *dd, uint32_t n,
                      rp_share_mode mode, rp_damping damping,
                      const double *fixed, int by_count, double tail,
                      uint32_t tail_strips, rp_device_group **g) {
  rp_group_desc gd = {0};
  int err;
  gd.devices = dd;
  gd.count = n;
  gd.share_mode = mode;
  gd.damping = damping;
  gd.fixed_shares = fixed;
  gd.split_by_count = by_count;
  gd.tail_fraction = tail;
  gd.tail_strips = tail_strips;
  gd.deadline_factor = -1.0; /* a slow frame is not a lost device here */
  if ((err = rp_device_group_create(s->ctx, &gd, g)) != 0)
    return fail(s->ctx, "device group", err);
  if ((err = rp_device_group_set_volume(*g, s->vol)) != 0)
    return fail(s->ctx, "volume upload", err);
  return 0;
}

/* The sequence's state for frame f: the camera, TF and effects, with the
 * occupancy rebuilt (and uploaded to every group) on a TF change. */
static int frame_scene(scene *s, uint32_t f, rp_device_group **groups,
                       int ngroups, rp_camera *cam, rp_render_desc *d,
                       rp_frame_probe *probe, uint32_t size) {
  rp_sequence_state st;
  int err, i;
  if ((err = rp_sequence_frame(s->seq, f, &st)) != 0)
    return fail(s->ctx, "sequence", err);
  if (st.tf != s->tf_active) {
    err = s->occ == NULL
              ? rp_occupancy_build(s->ctx, s->h, s->tfs[st.tf], &s->occ)
              : rp_occupancy_update(s->occ, s->tfs[st.tf]);
    if (err != 0)
      return fail(s->ctx, "occupancy", err);
    for (i = 0; i < ngroups; i++)
      if ((err = rp_device_group_set_tf(groups[i], s->tfs[st.tf],
                                        s->occ)) != 0)
        return fail(s->ctx, "TF upload", err);
    s->tf_active = st.tf;
  }
  rp_sequence_camera(&st, s->vol, cam);
  memset(d, 0, sizeof *d);
  d->width = d->height = size;
  d->step = 1.0f;
  /* Shading and AO stay off: the pair must render the same image. */
  d->effects = st.effects & (RP_EFFECT_ERT | RP_EFFECT_SKIP);
  if ((err = rp_frame_probe_compute(s->ctx, s->vol, s->tfs[st.tf], s->occ,
                                    cam, d, 1, f, probe)) != 0)
    return fail(s->ctx, "probe", err);
  return 0;
}

static int render(scene *s, rp_device_group *g, const rp_camera *cam,
                  const rp_render_desc *d, const rp_frame_probe *p,
                  uint8_t *img, rp_group_report *rep) {
  int err = rp_device_group_render(g, cam, d, p, img, NULL, rep);
  if (err != 0)
    return fail(s->ctx, "render", err);
  if ((err = rp_device_group_train(g, p, d->step, 1.0f, rep->render_ms)) !=
      0)
    return fail(s->ctx, "train", err);
  return 0;
}

static double mean_of(const double *v, uint32_t n) {
  double sum = 0.0;
  uint32_t i;
  for (i = 0; i < n; i++)
    sum += v[i];
  return n > 0 ? sum / n : NAN;
}

static double pct(double *v, uint32_t n, double q) {
  qsort(v, n, sizeof *v, bench_cmp_double);
  return v[(uint32_t)floor(q * (n - 1) + 0.5)];
}

int main(int argc, char **argv) {
  opts o;
  scene s;
  rp_device_desc dd[2];
  rp_device_group *single[2] = {NULL, NULL}, *ways[WAYS] = {0};
  rp_group_report rep;
  rp_camera cam;
  rp_render_desc d;
  rp_frame_probe *probe = malloc(sizeof *probe);
  static double alone[2][MAX_FRAMES], t[WAYS][MAX_FRAMES],
      imb[WAYS][MAX_FRAMES], sh[WAYS][MAX_FRAMES], busy[WAYS][2][MAX_FRAMES],
      depth[WAYS][2][MAX_FRAMES];
  double fixed[2], avg[2], buf[MAX_FRAMES];
  uint8_t *img;
  uint32_t f, n, i, k;
  FILE *csv = NULL;
  int rc = 1;
  if (probe == NULL || parse(argc, argv, &o) != 0)
    return 2;
  if (pair_devices(o.pair, dd) != 0)
    return usage();
  if (open_scene(&o, &s) != 0)
    return 1;
  n = rp_sequence_frames(s.seq);
  if (o.frames > 0 && o.frames < n)
    n = o.frames;
  if (n > MAX_FRAMES)
    n = MAX_FRAMES;
  if (n <= SETTLE) {
    fprintf(stderr, "bench_balance: need more than %d frames\n", SETTLE);
    return 2;
  }
  img = malloc((size_t)o.size * o.size * 4);
  if (img == NULL)
    return 1;

  /* Pass 1: each device alone. */
  for (i = 0; i < 2; i++)
    if (make_group(&s, &dd[i], 1, RP_SHARES_DYNAMIC, RP_DAMP_SMOOTH, NULL, 0,
                   NO_TAIL, 0, &single[i]) != 0)
      goto out;
  {
    rp_caps c0, c1;
    rp_device_group_get_caps(single[0], 0, &c0);
    rp_device_group_get_caps(single[1], 0, &c1);
    printf("pair %s: [0] %s:%s (%u CU)  [1] %s:%s (%u CU)%s\n", o.pair,
           c0.backend, c0.device, c0.compute_units, c1.backend, c1.device,
           c1.compute_units, dd[1].next != NULL ? ", slowed 3x" : "");
    printf("volume %s, %ux%u, sequence %s, %u frames (first %d left out)\n",
           o.volume, o.size, o.size, o.sequence, n, SETTLE);
  }
  for (f = 0; f < n; f++) {
    if (frame_scene(&s, f, single, 2, &cam, &d, probe, o.size) != 0)
      goto out;
    for (i = 0; i < 2; i++) {
      if (render(&s, single[i], &cam, &d, probe, img, &rep) != 0)
        goto out;
      alone[i][f] = rep.render_ms;
    }
  }
  for (i = 0; i < 2; i++) {
    avg[i] = mean_of(alone[i] + SETTLE, n - SETTLE);
    rp_device_group_destroy(single[i]);
    single[i] = NULL;
  }
  /* Static shares by the average cost: w_i proportional to 1 / t_i. */
  fixed[0] = 1.0 / avg[0];
  fixed[1] = 1.0 / avg[1];

  /* Pass 2: every way, interleaved. */
  s.tf_active = -1;
  if (make_group(&s, dd, 2, RP_SHARES_DYNAMIC, RP_DAMP_SMOOTH, NULL, 0,
                 NO_TAIL, 0, &ways[WAY_SMOOTH]) != 0 ||
      make_group(&s, dd, 2, RP_SHARES_DYNAMIC, RP_DAMP_SMOOTH, NULL, 0,
                 o.tail, o.tail_strips, &ways[WAY_TAIL]) != 0 ||
      make_group(&s, dd, 2, RP_SHARES_DYNAMIC, RP_DAMP_EVEN, NULL, 0,
                 NO_TAIL, 0, &ways[WAY_EVEN]) != 0 ||
      make_group(&s, dd, 2, RP_SHARES_FIXED, RP_DAMP_SMOOTH, fixed, 0,
                 NO_TAIL, 0, &ways[WAY_STATIC]) != 0 ||
      make_group(&s, dd, 2, RP_SHARES_FIXED, RP_DAMP_SMOOTH, fixed, 1,
                 NO_TAIL, 0, &ways[WAY_AREA]) != 0)
    goto out;
  if (o.csv != NULL && (csv = fopen(o.csv, "w")) == NULL) {
    fprintf(stderr, "bench_balance: cannot write %s\n", o.csv);
    goto out;
  }
  if (csv != NULL) {
    fprintf(csv, "frame,alone0_ms,alone1_ms");
    for (k = 0; k < WAYS; k++)
      fprintf(csv, ",%s_ms,%s_imbalance,%s_share0,%s_busy0_ms,%s_busy1_ms,"
              "%s_depth0_ms,%s_depth1_ms", way_names[k], way_names[k],
              way_names[k], way_names[k], way_names[k], way_names[k],
              way_names[k]);
    fprintf(csv, "\n");
  }
  for (f = 0; f < n; f++) {
    if (frame_scene(&s, f, ways, WAYS, &cam, &d, probe, o.size) != 0)
      goto out;
    for (k = 0; k < WAYS; k++) {
      if (render(&s, ways[k], &cam, &d, probe, img, &rep) != 0)
        goto out;
      t[k][f] = rep.render_ms;
      imb[k][f] = rep.imbalance;
      sh[k][f] = rep.devices[0].share;
      busy[k][0][f] = rep.devices[0].busy_ms;
      busy[k][1][f] = rep.devices[1].busy_ms;
      depth[k][0][f] = rep.devices[0].depth_ms;
      depth[k][1][f] = rep.devices[1].depth_ms;
    }
    if (csv != NULL) {
      fprintf(csv, "%u,%.3f,%.3f", f, alone[0][f], alone[1][f]);
      for (k = 0; k < WAYS; k++)
        fprintf(csv, ",%.3f,%.4f,%.4f,%.3f,%.3f,%.3f,%.3f", t[k][f],
                imb[k][f], sh[k][f], busy[k][0][f], busy[k][1][f],
                depth[k][0][f], depth[k][1][f]);
      fprintf(csv, "\n");
    }
  }

  printf("\nalone: device 0 mean %.2f ms, device 1 mean %.2f ms "
         "(static shares %.3f / %.3f)\n", avg[0], avg[1],
         fixed[0] / (fixed[0] + fixed[1]), fixed[1] / (fixed[0] + fixed[1]));
  {
    double best = avg[0] < avg[1] ? avg[0] : avg[1];
    uint32_t b = avg[0] < avg[1] ? 0 : 1;
    double med_best;
    memcpy(buf, alone[b] + SETTLE, (n - SETTLE) * sizeof *buf);
    med_best = bench_median(buf, (int)(n - SETTLE));
    printf("best single device: [%u], median %.2f ms (mean %.2f)\n\n", b,
           med_best, best);
    printf("%-12s %10s %10s %10s %10s %12s %10s\n", "way", "imbalance",
           "median", "frame med", "frame p95", "vs single", "share0");
    for (k = 0; k < WAYS; k++) {
      double mi = mean_of(imb[k] + SETTLE, n - SETTLE), md, fm, f95, s0;
      memcpy(buf, imb[k] + SETTLE, (n - SETTLE) * sizeof *buf);
      md = bench_median(buf, (int)(n - SETTLE));
      memcpy(buf, t[k] + SETTLE, (n - SETTLE) * sizeof *buf);
      fm = bench_median(buf, (int)(n - SETTLE));
      f95 = pct(buf, n - SETTLE, 0.95);
      s0 = mean_of(sh[k] + SETTLE, n - SETTLE);
      printf("%-12s %10.3f %10.3f %10.2f %10.2f %12.3f %10.3f\n",
             way_names[k], mi, md, fm, f95, fm / med_best, s0);
    }
    printf("\ntail vs static: balance deviation %.0f %% lower\n",
           100.0 * (1.0 - mean_of(imb[WAY_TAIL] + SETTLE, n - SETTLE) /
                              mean_of(imb[WAY_STATIC] + SETTLE, n - SETTLE)));
    printf("smooth vs static: balance deviation %.0f %% lower; vs "
           "static-area %.0f %% lower\n",
           100.0 * (1.0 - mean_of(imb[WAY_SMOOTH] + SETTLE, n - SETTLE) /
                              mean_of(imb[WAY_STATIC] + SETTLE, n - SETTLE)),
           100.0 * (1.0 - mean_of(imb[WAY_SMOOTH] + SETTLE, n - SETTLE) /
                              mean_of(imb[WAY_AREA] + SETTLE, n - SETTLE)));
  }
  rc = 0;
out:
  if (csv != NULL)
    fclose(csv);
  for (i = 0; i < 2; i++)
    rp_device_group_destroy(single[i]);
  for (k = 0; k < WAYS; k++)
    rp_device_group_destroy(ways[k]);
  free(img);
  free(probe);
  close_scene(&s);
  return rc;
}
