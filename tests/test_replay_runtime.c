/* Replay and the runtime an app embeds decide every frame alike.
 *
 * `raypace replay` is a driver of rp_runtime (cli/replay.c): if it ever
 * decided a frame differently from the runtime an app embeds -- its own
 * copy of a constant, an event posted that an app would not post, a
 * warm-up that differs from the one it documents -- every figure it
 * reports would be about something other than the library. Here the
 * same sequence plays twice on the deterministic test device (its times
 * are a formula of the work plus seeded noise, on a clock of its own, so
 * a frame's decisions do not depend on this machine):
 * - through `raypace replay --csv`, run in this process;
 * - through an rp_runtime on this test's own libuv loop, paced on
 *   request as an app embeds it, given the events replay's header
 *   documents (warm-up under the controller none at the largest target,
 *   every effect set until it renders, three frames measuring the frame
 *   without adaptation, then the first target, the controller, the
 *   settle frames and the sequence).
 * Every recorded frame's density, step, scale, render passes, and its
 * measured and predicted times must be the same, printed alike. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <uv.h>

#include "commands.h"
#include "raypace_runtime.h"
#include "raypace_sequence.h"
#include "test_util.h"

#define VOLUME "gen:phantom:48"
#define SEQUENCE "mixed"
#define FRAMES 120
#define SETTLE 4
#define SIZE 64
#define FRACTION 0.5
#define WARM_TARGET_MS 60000.0
#define CALIBRATE_FRAMES 3
#define MAX_ROWS FRAMES

/* A frame's decisions and times, as replay's CSV prints them. */
typedef struct decision {
  char density[32], step[32], scale[32];
  int passes;
  char measured[32], predicted[32];
} decision;

static void print_decision(decision *d, const rp_frame_stats *st) {
  snprintf(d->density, sizeof d->density, "%.9g", st->rho);
  snprintf(d->step, sizeof d->step, "%.9g", (double)st->step);
  snprintf(d->scale, sizeof d->scale, "%.9g", (double)st->scale);
  d->passes = (int)st->passes;
  snprintf(d->measured, sizeof d->measured, "%.4f", st->measured_ms);
  snprintf(d->predicted, sizeof d->predicted, "%.4f", st->predicted_ms);
}

/* ---- The runtime as an app embeds it ------------------------------------- */

typedef struct app {
  uv_loop_t loop;
  rp_runtime *rt;
  int frames;
  rp_frame_stats last;
} app;

static void on_frame(rp_runtime *rt, const rp_frame *f, void *user) {
  app *a = user;
  (void)rt;
  a->last = *f->stats;
  a->frames++;
}

static void frame(app *a) {
  int n = a->frames;
  assert_int_equal(rp_runtime_request_frame(a->rt), 0);
  while (a->frames == n)
    uv_run(&a->loop, UV_RUN_ONCE);
  assert_int_equal(a->last.status, 0);
}

typedef struct posted {
  int tf;
  rp_camera cam;
  uint32_t effects;
  double target;
} posted;

/* What frame f changes, posted as an app posts changes. */
static void post(app *a, posted *p, rp_tf *const *tfs,
                 const rp_sequence_state *st, const rp_camera *cam,
                 double target) {
  if (st->tf != p->tf) {
    assert_int_equal(rp_runtime_set_tf(a->rt, tfs[st->tf]), 0);
    p->tf = st->tf;
  }
  if (memcmp(cam, &p->cam, sizeof *cam) != 0) {
    assert_int_equal(rp_runtime_set_camera(a->rt, cam), 0);
    p->cam = *cam;
  }
  if (st->effects != p->effects) {
    assert_int_equal(rp_runtime_set_effects(a->rt, st->effects), 0);
    p->effects = st->effects;
  }
  if (target > 0.0 && target != p->target) {
    assert_int_equal(rp_runtime_set_target(a->rt, target), 0);
    p->target = target;
  }
}

static void set_effects_until_shown(app *a, posted *p, uint32_t effects) {
  int n;
  assert_int_equal(rp_runtime_set_effects(a->rt, effects), 0);
  p->effects = effects;
  for (n = 0; n < 100; n++) {
    frame(a);
    if (a->last.effects == effects)
      return;
  }
  fail_msg("effects 0x%x never rendered", effects);
}

static int cmp_double(const void *x, const void *y) {
  double a = *(const double *)x, b = *(const double *)y;
  return (a > b) - (a < b);
}

/* Plays the sequence on an app-embedded runtime; fills out[0..FRAMES). */
static void play_embedded(rp_context *ctx, decision *out) {
  app a;
  rp_runtime_desc d = {0};
  rp_sequence *seq = NULL;
  rp_sequence_state st, first;
  rp_volume *vol = NULL, *mine = NULL;
  rp_tf *tfs[8] = {0};
  rp_generate_desc g = {0};
  posted p;
  rp_camera cam;
  uint32_t sets[32], nsets = 0, i, k;
  double t[CALIBRATE_FRAMES], full_ms, target0;
  int ntf, n;
  memset(&a, 0, sizeof a);
  memset(&p, 0, sizeof p);
  p.tf = -1;
  assert_int_equal(rp_sequence_load(ctx, SEQUENCE, &seq), 0);
  ntf = rp_sequence_tf_count(seq);
  assert_true(ntf <= 8);
  for (n = 0; n < ntf; n++)
    assert_int_equal(rp_sequence_tf_create(ctx, seq, n, &tfs[n]), 0);
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = 48;
  g.seed = 1;
  assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
  assert_int_equal(rp_volume_generate(ctx, &g, &mine), 0);
  assert_int_equal(uv_loop_init(&a.loop), 0);
  d.loop = &a.loop;
  d.pacing = RP_PACE_ON_REQUEST;
  d.on_frame = on_frame;
  d.user = &a;
  d.device.backend = "test";
  d.controller = RP_CONTROL_NONE;
  d.target_ms = WARM_TARGET_MS;
  d.width = d.height = SIZE;
  d.space.space = RP_SPACE_HYBRID;
  d.space.base_step = 1.0f;
  d.ert_seed = 1;
  d.jitter = RP_JITTER_FIXED; /* as replay's runtimes (cli/replay.c) */
  assert_int_equal(rp_runtime_create(ctx, &d, &a.rt), 0);
  assert_int_equal(rp_runtime_set_volume(a.rt, mine), 0);
  /* Warm-up: the first frame's TF, camera and effects, then every other
   * effect set in the order it first appears, the first frame's last. */
  assert_int_equal(rp_sequence_frame(seq, 0, &first), 0);
  rp_sequence_camera(&first, vol, &cam);
  post(&a, &p, tfs, &first, &cam, 0.0);
  for (i = 1; i < FRAMES; i++) {
    assert_int_equal(rp_sequence_frame(seq, i, &st), 0);
    for (k = 0; k < nsets && sets[k] != st.effects; k++)
      ;
    if (k == nsets && st.effects != first.effects)
      sets[nsets++] = st.effects;
  }
  sets[nsets++] = first.effects;
  for (k = 0; k < nsets; k++) {
    assert_false(sets[k] & RP_EFFECT_AO); /* AO steps run on wall time */
    set_effects_until_shown(&a, &p, sets[k]);
  }
  /* The frame without adaptation, and the targets from it. */
  for (n = 0; n < CALIBRATE_FRAMES; n++) {
    frame(&a);
    t[n] = a.last.measured_ms;
  }
  qsort(t, CALIBRATE_FRAMES, sizeof t[0], cmp_double);
  full_ms = t[CALIBRATE_FRAMES / 2];
  target0 = first.target_ms > 0 ? first.target_ms
                                : first.target_fraction * full_ms;
  for (i = 0; i < SETTLE + FRAMES; i++) {
    uint32_t f = i < SETTLE ? 0 : i - SETTLE;
    double seq_t;
    assert_int_equal(rp_sequence_frame(seq, f, &st), 0);
    rp_sequence_camera(&st, vol, &cam);
    seq_t = st.target_ms > 0 ? st.target_ms : st.target_fraction * full_ms;
    post(&a, &p, tfs, &st, &cam, FRACTION * full_ms * seq_t / target0);
    if (i == 0)
      assert_int_equal(
          rp_runtime_set_controller(a.rt, RP_CONTROL_PREDICTED), 0);
    frame(&a);
    if (i >= SETTLE)
      print_decision(&out[f], &a.last);
  }
  assert_int_equal(rp_runtime_close(a.rt, NULL, NULL), 0);
  while (uv_run(&a.loop, UV_RUN_ONCE) != 0)
    ;
  assert_int_equal(uv_loop_close(&a.loop), 0);
  for (n = 0; n < ntf; n++)
    rp_tf_destroy(tfs[n]);
  rp_volume_destroy(vol);
  rp_sequence_destroy(seq);
}

/* ---- Replay --------------------------------------------------------------- */

/* Column `name`'s index in a CSV header line, or -1. */
static int column(const char *header, const char *name) {
  char buf[4096], *tok, *save = NULL;
  int i = 0;
  snprintf(buf, sizeof buf, "%s", header);
  buf[strcspn(buf, "\r\n")] = '\0';
  for (tok = strtok_r(buf, ",", &save); tok != NULL;
       tok = strtok_r(NULL, ",", &save), i++)
    if (strcmp(tok, name) == 0)
      return i;
  return -1;
}

static void field(const char *line, int col, char *out, size_t len) {
  const char *s = line;
  size_t n;
  int i;
  for (i = 0; i < col; i++) {
    s = strchr(s, ',');
    assert_non_null(s);
    s++;
  }
  n = strcspn(s, ",\r\n");
  assert_true(n < len);
  memcpy(out, s, n);
  out[n] = '\0';
}

/* Runs `raypace replay` on the same sequence; fills out[0..FRAMES). */
static void play_replay(decision *out) {
  char csv[1024], frames[16], settle[16], size[32], fraction[16];
  char line[4096], passes[16], frame_no[16];
  char *argv[32];
  int argc = 0, c[8], n = 0;
  FILE *f;
  snprintf(csv, sizeof csv, "%s/replay_runtime.csv", rp_test_tmp_dir());
  snprintf(frames, sizeof frames, "%d", FRAMES);
  snprintf(settle, sizeof settle, "%d", SETTLE);
  snprintf(size, sizeof size, "%dx%d", SIZE, SIZE);
  snprintf(fraction, sizeof fraction, "%g", FRACTION);
  argv[argc++] = "replay";
  argv[argc++] = "--backend";
  argv[argc++] = "test";
  argv[argc++] = "--sequence";
  argv[argc++] = SEQUENCE;
  argv[argc++] = "--controller";
  argv[argc++] = "predicted";
  argv[argc++] = "--frames";
  argv[argc++] = frames;
  argv[argc++] = "--settle";
  argv[argc++] = settle;
  argv[argc++] = "--size";
  argv[argc++] = size;
  argv[argc++] = "--target-fraction";
  argv[argc++] = fraction;
  argv[argc++] = "--quiet";
  argv[argc++] = "--json";
  argv[argc++] = "--csv";
  argv[argc++] = csv;
  argv[argc++] = VOLUME;
  argv[argc] = NULL;
  assert_int_equal(cli_cmd_replay(argc, argv), 0);
  f = fopen(csv, "r");
  assert_non_null(f);
  assert_non_null(fgets(line, sizeof line, f));
  c[0] = column(line, "frame");
  c[1] = column(line, "density");
  c[2] = column(line, "step");
  c[3] = column(line, "scale");
  c[4] = column(line, "passes");
  c[5] = column(line, "measured_ms");
  c[6] = column(line, "predicted_ms");
  for (n = 0; n < 7; n++)
    assert_true(c[n] >= 0);
  for (n = 0; fgets(line, sizeof line, f) != NULL; n++) {
    decision *d;
    assert_true(n < FRAMES);
    field(line, c[0], frame_no, sizeof frame_no);
    assert_int_equal(atoi(frame_no), n);
    d = &out[n];
    field(line, c[1], d->density, sizeof d->density);
    field(line, c[2], d->step, sizeof d->step);
    field(line, c[3], d->scale, sizeof d->scale);
    field(line, c[4], passes, sizeof passes);
    d->passes = atoi(passes);
    field(line, c[5], d->measured, sizeof d->measured);
    field(line, c[6], d->predicted, sizeof d->predicted);
  }
  assert_int_equal(n, FRAMES);
  fclose(f);
}

static void test_replay_decides_as_runtime(void **state) {
  rp_context *ctx = rp_test_context();
  decision *a = calloc(MAX_ROWS, sizeof *a), *b = calloc(MAX_ROWS, sizeof *b);
  int i, changes = 0, bad = 0;
  (void)state;
  assert_non_null(a);
  assert_non_null(b);
  play_replay(a);
  play_embedded(ctx, b);
  for (i = 0; i < FRAMES; i++) {
    if (strcmp(a[i].density, b[i].density) != 0 ||
        strcmp(a[i].step, b[i].step) != 0 ||
        strcmp(a[i].scale, b[i].scale) != 0 || a[i].passes != b[i].passes ||
        strcmp(a[i].measured, b[i].measured) != 0 ||
        strcmp(a[i].predicted, b[i].predicted) != 0) {
      if (bad++ < 5)
        print_message("frame %d: replay %s/%s/%s %d %s %s, runtime "
                      "%s/%s/%s %d %s %s\n", i, a[i].density, a[i].step,
                      a[i].scale, a[i].passes, a[i].measured,
                      a[i].predicted, b[i].density, b[i].step, b[i].scale,
                      b[i].passes, b[i].measured, b[i].predicted);
    }
    changes += i > 0 && strcmp(a[i].density, a[i - 1].density) != 0;
  }
  /* The controller had decisions to make: a sequence it rendered at one
   * density would compare nothing. */
  print_message("%d frames, %d density changes, %d differ\n", FRAMES,
                changes, bad);
  assert_true(changes >= FRAMES / 4);
  assert_int_equal(bad, 0);
  free(a);
  free(b);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_replay_decides_as_runtime),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
