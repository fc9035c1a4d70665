/* The soak (docs/soak.md): N frames through rp_runtime, in
 * sessions of a few hundred frames. Each session draws at random
 *
 * - how frames are paced, as the apps that embed the runtime do:
 *   manual (rp_runtime_step), on request on the runtime's own loop (one
 *   request at a time, each answered by exactly one frame), timer pacing
 *   on its own loop, and timer pacing on the app's loop (closed from the
 *   frame callback, as samples/embed_uv.c does);
 * - one device or two (the group path: regions split, a lost device's
 *   region re-rendered by the other), each "reference" or "test";
 * - faults (raypace_testing.h) on each device: with probability
 *   --fail-prob a failure from a random render on (possibly past the
 *   session's end), with --stall-prob a stall at a random render (one in
 *   ten of them long enough, 250-400 ms, for the group to give the
 *   device up as late), with --ao-fail-prob a failing AO job.
 *
 * Meanwhile --threads threads post events (posters.c), and every
 * --check-every frames the driver posts a scene the oracle knows and the
 * frame that includes it is compared with rp_render_reference
 * (verify.c). The run fails on any problem the callback saw, a refused
 * event, an oracle mismatch, a frame missing or repeated, or a resident
 * memory slope over the second half above --max-slope KiB per 10^4
 * frames. */
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "raypace_testing.h"
#include "soak.h"

enum { MODE_MANUAL, MODE_REQUEST, MODE_TIMER, MODE_APP_LOOP, MODE_COUNT };

typedef struct options {
  uint64_t frames, seed, rss_every;
  uint32_t threads, check_every, session_min, session_max;
  double fail_prob, stall_prob, ao_fail_prob;
  double max_slope;      /* RSS; < 0: report only */
  double max_heap_slope; /* the library's heap and malloc's live bytes */
  const char *json, *rss_csv;
} options;

typedef struct totals {
  uint64_t sessions[MODE_COUNT], devices, stall_armed, stall_reached;
  uint64_t stall_long, fail_armed, ao_fail_armed;
  soak_post_counts posts;
  double wall_s;
} totals;

/* One session's world. */
typedef struct session {
  const options *o;
  soak_verify *v;
  soak_rng *rng;
  rp_context *ctx;
  rp_runtime *rt;
  int mode;
  uint64_t frames;     /* to deliver */
  uint64_t next_check; /* delivered count at which to check next */
  /* The devices' descs and faults, kept for the session: the runtime
   * copies the descs, chain pointers included. */
  rp_device_desc dd[2];
  rp_fault_desc fd[2];
  uint32_t devices;
  uv_loop_t loop;      /* app-loop mode */
  int closing, closed;
} session;

static double now_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Waits for the callback to have delivered `want` frames, a minute at
 * most without a frame (a hang is a failure: the run stops). */
static uint64_t wait_delivered(soak_verify *v, uint64_t want) {
  uint64_t got, last;
  double since = now_s();
  uv_mutex_lock(&v->lock);
  last = v->delivered;
  while (v->delivered < want) {
    uv_cond_timedwait(&v->cv, &v->lock, 1000000000ull);
    if (v->delivered != last) {
      last = v->delivered;
      since = now_s();
    } else if (now_s() - since > 60.0) {
      fprintf(stderr, "soak: no frame for 60 s after %llu frames; "
              "hung\n", (unsigned long long)v->delivered);
      abort();
    }
  }
  got = v->delivered;
  uv_mutex_unlock(&v->lock);
  return got;
}

/* Posts the oracle's scene when a check is due (posters paused until the
 * frame that includes it is delivered). */
static void maybe_check(session *s, uint64_t delivered) {
  if (delivered < s->next_check)
    return;
  s->next_check = delivered + s->o->check_every;
  if (soak_check_begin(s->v, s->rt, s->ctx, s->rng) != 0)
    soak_posters_resume(s->v->posters, s->rt);
}

/* ---- Drivers, one per pacing mode -------------------------------------- */

static void drive_manual(session *s) {
  uint64_t i;
  for (i = 0; i < s->frames; i++) {
    uint64_t before = s->v->delivered; /* the callback runs on this thread */
    int err;
    maybe_check(s, before);
    err = rp_runtime_step(s->rt);
    uv_mutex_lock(&s->v->lock);
    if (s->v->delivered != before + 1)
      soak_bad(s->v, "rp_runtime_step returned %d after %llu frames "
               "delivered, 1 expected", err,
               (unsigned long long)(s->v->delivered - before));
    else if (err != s->v->last_status)
      soak_bad(s->v, "rp_runtime_step returned %d, its frame's status was "
               "%d", err, s->v->last_status);
    uv_mutex_unlock(&s->v->lock);
  }
}

/* One request at a time: each must be answered by exactly one frame. */
static void drive_request(session *s) {
  uint64_t i;
  for (i = 0; i < s->frames; i++) {
    uint64_t got;
    maybe_check(s, i);
    if (rp_runtime_request_frame(s->rt) != 0) {
      uv_mutex_lock(&s->v->lock);
      soak_bad(s->v, "rp_runtime_request_frame refused");
      uv_mutex_unlock(&s->v->lock);
      return;
    }
    got = wait_delivered(s->v, i + 1);
    if (got != i + 1) {
      uv_mutex_lock(&s->v->lock);
      soak_bad(s->v, "%llu requests answered by %llu frames",
               (unsigned long long)(i + 1), (unsigned long long)got);
      uv_mutex_unlock(&s->v->lock);
    }
  }
}

static void drive_timer(session *s) {
  uint64_t got = 0;
  while (got < s->frames) {
    maybe_check(s, got);
    got = wait_delivered(s->v, got + 1);
  }
}

/* App loop: the frame callback wraps the verifier's, checks from the
 * loop thread and closes the runtime after the session's frames. */
static void on_closed(void *user) { ((session *)user)->closed = 1; }

static void app_on_frame(rp_runtime *rt, const rp_frame *f, void *user) {
  session *s = user;
  uint64_t delivered;
  soak_on_frame(rt, f, s->v);
  if (s->closing)
    return;
  uv_mutex_lock(&s->v->lock);
  delivered = s->v->delivered;
  if (delivered >= s->frames)
    s->v->ending = 1;
  uv_mutex_unlock(&s->v->lock);
  if (delivered < s->frames) {
    maybe_check(s, delivered);
    return;
  }
  s->closing = 1;
  /* No poster may be inside a setter once the close callback frees the
   * runtime. */
  soak_posters_pause(s->v->posters);
  if (rp_runtime_close(rt, on_closed, s) != 0) {
    uv_mutex_lock(&s->v->lock);
    soak_bad(s->v, "rp_runtime_close refused");
    uv_mutex_unlock(&s->v->lock);
  }
}

/* ---- A session ------------------------------------------------------------ */

/* Draws each device's backend and faults. */
static uint32_t draw_devices(session *s, totals *t, rp_device_desc *dd,
                             rp_fault_desc *fd) {
  soak_rng *r = s->rng;
  uint32_t n = soak_rng_unit(r) < 0.6 ? 2 : 1, i;
  for (i = 0; i < n; i++) {
    memset(&dd[i], 0, sizeof dd[i]);
    memset(&fd[i], 0, sizeof fd[i]);
    fd[i].header.type = RP_EXT_FAULTS;
    dd[i].backend = soak_rng_unit(r) < 0.7 ? "reference" : "test";
    dd[i].next = &fd[i];
    if (soak_rng_unit(r) < s->o->fail_prob) {
      /* Up to twice the session: some are never reached. */
      fd[i].fail_at_render = soak_rng_range(r, 1, (uint32_t)(2 * s->frames));
      t->fail_armed++;
    }
    if (soak_rng_unit(r) < s->o->stall_prob) {
      int long_stall = soak_rng_range(r, 0, 9) == 0;
      fd[i].stall_at_render = soak_rng_range(r, 1, (uint32_t)s->frames);
      fd[i].stall_ms = long_stall ? soak_rng_range(r, 250, 400)
                                  : soak_rng_range(r, 2, 40);
      t->stall_armed++;
      t->stall_long += long_stall;
    }
    if (soak_rng_unit(r) < s->o->ao_fail_prob) {
      fd[i].fail_at_ao = soak_rng_range(r, 1, 40);
      t->ao_fail_armed++;
    }
  }
  t->devices += n;
  return n;
}

/* The first scene: a frame needs a volume, a TF and a camera. */
static int post_first(session *s) {
  rp_generate_desc g;
  rp_volume *vol = NULL;
  rp_camera cam = {0};
  int err;
  soak_volume_desc(0, &g);
  if ((err = rp_volume_generate(s->ctx, &g, &vol)) != 0)
    return err;
  rp_camera_orbit(&cam, s->v->vols[0], 30.0f, 20.0f, 2.2f);
  if ((err = rp_runtime_set_volume(s->rt, vol)) != 0) {
    rp_volume_destroy(vol);
    return err;
  }
  if ((err = rp_runtime_set_tf(s->rt, s->v->tfs[0])) != 0)
    return err;
  return rp_runtime_set_camera(s->rt, &cam);
}

static int open_runtime(session *s, totals *t) {
  rp_runtime_desc d = {0};
  int err;
  d.devices = s->dd;
  d.device_count = s->devices = draw_devices(s, t, s->dd, s->fd);
  d.pacing = s->mode == MODE_MANUAL    ? RP_PACE_MANUAL
             : s->mode == MODE_REQUEST ? RP_PACE_ON_REQUEST
                                       : RP_PACE_TIMER;
  d.on_frame = s->mode == MODE_APP_LOOP ? app_on_frame : soak_on_frame;
  d.user = s->mode == MODE_APP_LOOP ? (void *)s : (void *)s->v;
  d.controller = (rp_controller_kind)soak_rng_range(s->rng, 0,
                                                    RP_CONTROL_COUNT - 1);
  d.target_ms = 4.0;
  d.width = SOAK_CHECK_W;
  d.height = SOAK_CHECK_H;
  d.effects = RP_EFFECT_ERT | RP_EFFECT_SKIP;
  d.ert_seed = (uint32_t)soak_rng_next(s->rng);
  if (s->mode == MODE_APP_LOOP) {
    if (uv_loop_init(&s->loop) != 0)
      return RP_EDEVICE;
    d.loop = &s->loop;
  }
  soak_verify_session(s->v, d.device_count);
  if ((err = rp_runtime_create(s->ctx, &d, &s->rt)) != 0) {
    fprintf(stderr, "soak: rp_runtime_create: %s: %s\n", rp_strerror(err),
            rp_last_error(s->ctx));
    return err;
  }
  return 0;
}

/* Runs one session of s->frames frames; the posters are paused on
 * return. */
static int run_session(session *s, totals *t) {
  long long heap;
  uint32_t i;
  int err;
  if ((err = open_runtime(s, t)) != 0)
    return err;
  if ((err = post_first(s)) != 0) {
    fprintf(stderr, "soak: the first scene was refused: %s\n",
            rp_strerror(err));
    return err;
  }
  s->next_check = 1 + soak_rng_range(s->rng, 0, s->o->check_every);
  s->closing = s->closed = 0;
  soak_posters_resume(s->v->posters, s->rt);
  switch (s->mode) {
  case MODE_MANUAL: drive_manual(s); break;
  case MODE_REQUEST: drive_request(s); break;
  case MODE_TIMER: drive_timer(s); break;
  default:
    uv_run(&s->loop, UV_RUN_DEFAULT);
    if (!s->closed || uv_loop_close(&s->loop) != 0) {
      uv_mutex_lock(&s->v->lock);
      soak_bad(s->v, "the app's loop did not close cleanly");
      uv_mutex_unlock(&s->v->lock);
    }
    break;
  }
  if (s->mode != MODE_APP_LOOP) {
    uv_mutex_lock(&s->v->lock);
    s->v->ending = 1;
    uv_mutex_unlock(&s->v->lock);
    soak_posters_pause(s->v->posters);
    if (rp_runtime_destroy(s->rt) != 0)
      return RP_ESTATE;
  }
  s->rt = NULL;
  heap = soak_heap_bytes();
  uv_mutex_lock(&s->v->lock);
  if (s->v->heap_between_checked++ == 0)
    s->v->heap_between = heap;
  else if (heap != s->v->heap_between)
    soak_bad(s->v, "the library's heap is %lld bytes after session %llu, "
             "%lld after the first: a session left memory behind", heap,
             (unsigned long long)s->v->heap_between_checked,
             s->v->heap_between);
  uv_mutex_unlock(&s->v->lock);
  for (i = 0; i < s->devices; i++)
    if (s->fd[i].stall_at_render != 0 &&
        s->v->renders[i] >= s->fd[i].stall_at_render)
      t->stall_reached++;
  return 0;
}

/* ---- Options and the report ------------------------------------------------ */

static int parse(int argc, char **argv, options *o) {
  static const struct option opts[] = {
      {"frames", required_argument, 0, 'n'},
      {"seed", required_argument, 0, 's'},
      {"threads", required_argument, 0, 't'},
      {"check-every", required_argument, 0, 'c'},
      {"session", required_argument, 0, 'l'},
      {"fail-prob", required_argument, 0, 'f'},
      {"stall-prob", required_argument, 0, 'p'},
      {"ao-fail-prob", required_argument, 0, 'a'},
      {"rss-every", required_argument, 0, 'r'},
      {"max-slope", required_argument, 0, 'm'},
      {"max-heap-slope", required_argument, 0, 'h'},
      {"json", required_argument, 0, 'j'},
      {"rss-csv", required_argument, 0, 'k'},
      {0, 0, 0, 0}};
  int c, li = 0;
  while ((c = getopt_long(argc, argv, "", opts, &li)) != -1) {
    char *end = optarg;
    double x = c != '?' ? strtod(optarg, &end) : 0.0;
    int ok = end != optarg && (*end == '\0' || (c == 'l' && *end == ':'));
    switch (c) {
    case 'n': o->frames = (uint64_t)x; ok = ok && x >= 1 && x <= 1e9; break;
    case 's': o->seed = (uint64_t)x; ok = ok && x >= 0; break;
    case 't':
      o->threads = (uint32_t)x;
      ok = ok && x >= 0 && x <= SOAK_MAX_THREADS;
      break;
    case 'c': o->check_every = (uint32_t)x; ok = ok && x >= 1; break;
    case 'l':
      o->session_min = (uint32_t)x;
      o->session_max = *end == ':' ? (uint32_t)strtod(end + 1, &end)
                                   : o->session_min;
      ok = *end == '\0' && o->session_min >= 1 &&
           o->session_max >= o->session_min && o->session_max <= 1000000;
      break;
    case 'f': o->fail_prob = x; ok = ok && x >= 0 && x <= 1; break;
    case 'p': o->stall_prob = x; ok = ok && x >= 0 && x <= 1; break;
    case 'a': o->ao_fail_prob = x; ok = ok && x >= 0 && x <= 1; break;
    case 'r': o->rss_every = (uint64_t)x; ok = ok && x >= 1; break;
    case 'm': o->max_slope = x; break;
    case 'h': o->max_heap_slope = x; ok = ok && x >= 0; break;
    case 'j': o->json = optarg; ok = 1; break;
    case 'k': o->rss_csv = optarg; ok = 1; break;
    default: return 1;
    }
    if (!ok) {
      fprintf(stderr, "soak: bad value '%s' for --%s (see "
              "docs/soak.md)\n", optarg, opts[li].name);
      return 1;
    }
  }
  if (optind < argc) {
    fprintf(stderr, "soak: unexpected argument '%s'\n", argv[optind]);
    return 1;
  }
  if (o->rss_every == 0)
    o->rss_every = o->frames >= 800 ? o->frames / 400 : 1;
  return 0;
}

/* The memory samples, for a plot: frames delivered, resident KiB. */
static int write_rss(const char *path, const soak_verify *v) {
  FILE *f = fopen(path, "w");
  uint32_t i;
  int err = f == NULL ||
            fprintf(f, "frames,rss_kib,heap_kib,malloc_kib\n") < 0;
  for (i = 0; !err && i < v->rss_count; i++)
    err = fprintf(f, "%llu,%.0f,%.1f,%.1f\n",
                  (unsigned long long)v->rss_frames[i], v->rss_kib[i],
                  v->heap_kib[i], v->malloc_kib[i]) < 0;
  if (f != NULL && fclose(f) != 0)
    err = 1;
  if (err)
    fprintf(stderr, "soak: cannot write %s\n", path);
  return err;
}

/* The three memory series' second-half slopes, KiB per 10^4 frames. */
typedef struct slopes {
  double rss, heap, malloc_;
} slopes;

/* Prints the figures (and writes them as JSON with --json); returns 1
 * when the run failed. */
static int report(const options *o, const totals *t, const soak_verify *v,
                  int posters_failed) {
  uint32_t half = v->rss_count / 2;
  uint32_t last = v->rss_count > 0 ? v->rss_count - 1 : 0;
  slopes sl = {soak_slope(v, v->rss_kib, half) * 1e4,
               soak_slope(v, v->heap_kib, half) * 1e4,
               soak_slope(v, v->malloc_kib, half) * 1e4};
  uint64_t events = t->posts.camera + t->posts.tf + t->posts.viewport +
                    t->posts.target + t->posts.effects +
                    t->posts.controller + t->posts.density + t->posts.volume;
  int rss_over = o->max_slope >= 0.0 && sl.rss > o->max_slope;
  int heap_over = sl.heap > o->max_heap_slope ||
                  sl.malloc_ > o->max_heap_slope;
  int failed = v->bad != 0 || posters_failed || v->frames < o->frames ||
               rss_over || heap_over || v->checks == 0;
  char buf[3072];
  int n = snprintf(buf, sizeof buf,
      "{\"frames\": %llu, \"failed_frames\": %llu, \"two_pass_frames\": "
      "%llu, \"sessions\": {\"manual\": %llu, \"on_request\": %llu, "
      "\"timer\": %llu, \"app_loop\": %llu}, \"devices\": %llu,\n"
      " \"faults\": {\"fail_armed\": %llu, \"fail_render\": %llu, "
      "\"ao_fail_armed\": %llu, \"fail_ao\": %llu, \"stall_armed\": %llu, "
      "\"stall_reached\": %llu, \"stall_long_armed\": %llu, "
      "\"dropped_other\": %llu, \"dropped_unexplained\": %llu},\n"
      " \"events\": {\"total\": %llu, \"camera\": %llu, \"tf\": %llu, "
      "\"viewport\": %llu, \"target\": %llu, \"effects\": %llu, "
      "\"controller\": %llu, \"density\": %llu, \"volume\": %llu, "
      "\"refused\": %llu, \"threads\": %u},\n"
      " \"oracle\": {\"checked\": %llu, \"skipped\": %llu, \"mismatch\": "
      "%llu},\n \"wall_s\": %.1f, \"memory_samples\": %u,\n"
      " \"rss_warm_kib\": %.0f, \"rss_end_kib\": %.0f, "
      "\"rss_slope_kib_per_1e4\": %.2f, \"max_rss_slope\": %.2f,\n"
      " \"heap_warm_kib\": %.1f, \"heap_end_kib\": %.1f, "
      "\"heap_slope_kib_per_1e4\": %.2f, \"heap_between_sessions_b\": "
      "%lld,\n \"malloc_warm_kib\": %.1f, \"malloc_end_kib\": %.1f, "
      "\"malloc_slope_kib_per_1e4\": %.2f, \"max_heap_slope\": %.2f,\n"
      " \"problems\": %llu, \"first_problem\": \"%s\", \"passed\": %s}\n",
      (unsigned long long)v->frames, (unsigned long long)v->failed_frames,
      (unsigned long long)v->two_pass,
      (unsigned long long)t->sessions[MODE_MANUAL],
      (unsigned long long)t->sessions[MODE_REQUEST],
      (unsigned long long)t->sessions[MODE_TIMER],
      (unsigned long long)t->sessions[MODE_APP_LOOP],
      (unsigned long long)t->devices, (unsigned long long)t->fail_armed,
      (unsigned long long)v->fail_render,
      (unsigned long long)t->ao_fail_armed, (unsigned long long)v->fail_ao,
      (unsigned long long)t->stall_armed,
      (unsigned long long)t->stall_reached,
      (unsigned long long)t->stall_long,
      (unsigned long long)v->drops_other,
      (unsigned long long)v->drops_unexplained, (unsigned long long)events,
      (unsigned long long)t->posts.camera, (unsigned long long)t->posts.tf,
      (unsigned long long)t->posts.viewport,
      (unsigned long long)t->posts.target,
      (unsigned long long)t->posts.effects,
      (unsigned long long)t->posts.controller,
      (unsigned long long)t->posts.density,
      (unsigned long long)t->posts.volume,
      (unsigned long long)t->posts.refused, o->threads,
      (unsigned long long)v->checks, (unsigned long long)v->checks_skipped,
      (unsigned long long)v->check_mismatch, t->wall_s, v->rss_count,
      v->rss_kib[half], v->rss_kib[last], sl.rss, o->max_slope,
      v->heap_kib[half], v->heap_kib[last], sl.heap, v->heap_between,
      v->malloc_kib[half], v->malloc_kib[last], sl.malloc_,
      o->max_heap_slope, (unsigned long long)v->bad,
      strchr(v->first_error, '"') == NULL ? v->first_error : "",
      failed ? "false" : "true");
  fputs(buf, stdout);
  if (o->json != NULL) {
    FILE *f = fopen(o->json, "w");
    if (f == NULL || fwrite(buf, 1, (size_t)n, f) != (size_t)n) {
      fprintf(stderr, "soak: cannot write %s\n", o->json);
      failed = 1;
    }
    if (f != NULL)
      fclose(f);
  }
  if (o->rss_csv != NULL && write_rss(o->rss_csv, v) != 0)
    failed = 1;
  if (rss_over)
    fprintf(stderr, "soak: resident memory grows %.1f KiB per 10^4 frames "
            "over the second half; the bound is %.1f\n", sl.rss,
            o->max_slope);
  if (heap_over)
    fprintf(stderr, "soak: live memory grows over the second half: the "
            "library's heap %.1f, malloc's %.1f KiB per 10^4 frames; the "
            "bound is %.1f\n", sl.heap, sl.malloc_, o->max_heap_slope);
  if (v->checks == 0)
    fprintf(stderr, "soak: no frame was held to the oracle\n");
  printf("soak: %s\n", failed ? "FAILED" : "passed");
  return failed;
}

int main(int argc, char **argv) {
  options o = {100000, 1, 0, 4, 64, 100, 900, 0.3, 0.6, 0.1, NAN, 64.0,
               NULL, NULL};
  rp_context_desc cd = {0};
  rp_space_desc space = {0};
  soak_posters *posters = NULL;
  soak_verify v;
  soak_rng rng;
  totals t;
  session s;
  int err = 0, failed, posters_failed;
  double t0 = now_s();
  if (parse(argc, argv, &o) != 0)
    return 2;
  /* A sanitizer's allocator holds freed memory back (ASan's quarantine)
   * and keeps metadata of its own: there the resident set says little
   * about the program, and malloc's live bytes (which the sanitizer
   * counts) are held to the bound instead. */
  if (isnan(o.max_slope))
    o.max_slope = soak_sanitized() ? -1.0 : 256.0;
  memset(&t, 0, sizeof t);
  memset(&s, 0, sizeof s);
  soak_rng_seed(&rng, o.seed);
  cd.allocator = soak_heap_allocator();
  if (soak_posters_start(&posters, o.threads, o.seed, &space) != 0 ||
      soak_verify_init(&v, posters, o.rss_every, o.frames) != 0 ||
      rp_context_create(&cd, &s.ctx) != 0) {
    fprintf(stderr, "soak: out of resources at start\n");
    return 2;
  }
  s.o = &o;
  s.v = &v;
  s.rng = &rng;
  while (err == 0 && v.frames < o.frames && v.bad == 0) {
    uint64_t left = o.frames - v.frames;
    s.frames = soak_rng_range(&rng, o.session_min, o.session_max);
    if (s.frames > left)
      s.frames = left;
    s.mode = (int)soak_rng_range(&rng, 0, MODE_COUNT - 1);
    t.sessions[s.mode]++;
    err = run_session(&s, &t);
  }
  posters_failed = soak_posters_failed(posters);
  soak_posters_stop(posters, &t.posts);
  t.wall_s = now_s() - t0;
  failed = report(&o, &t, &v, posters_failed) || err != 0;
  soak_verify_free(&v);
  rp_context_destroy(s.ctx);
  return failed ? 1 : 0;
}
