/* Interaction sequences: the built-ins keep their promises, interpolation
 * and steps resolve to values worked out by hand, every malformed
 * document fails with its code and a message naming where, files load,
 * and the camera helper places eye and pan as documented. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "raypace_sequence.h"
#include "test_util.h"

#define PI 3.14159265358979323846

static rp_sequence *parse_ok(rp_context *ctx, const char *json) {
  rp_sequence *s = NULL;
  int err = rp_sequence_parse(ctx, json, strlen(json), "t.json", &s);
  if (err != 0)
    fail_msg("parse failed (%s): %s", rp_err_name(err), rp_last_error(ctx));
  assert_non_null(s);
  return s;
}

static rp_sequence_state frame_of(const rp_sequence *s, uint32_t i) {
  rp_sequence_state st;
  memset(&st, 0xab, sizeof st);
  assert_int_equal(rp_sequence_frame(s, i, &st), 0);
  assert_int_equal(st.frame, i);
  return st;
}

/* Mean alpha over the LUT: how much a TF lets a ray through. */
static double tf_mean_alpha(rp_context *ctx, const rp_sequence *s, int i) {
  rp_tf *tf = NULL;
  const float *lut;
  double sum = 0;
  int n = 0, k;
  assert_int_equal(rp_sequence_tf_create(ctx, s, i, &tf), 0);
  lut = rp_tf_lut(tf, &n);
  assert_true(n >= 2);
  for (k = 0; k < n; k++)
    sum += lut[4 * k + 3];
  rp_tf_destroy(tf);
  return sum / n;
}

/* ---- built-ins ----------------------------------------------------------- */

static void builtins_load_and_resolve(void **state) {
  rp_context *ctx = rp_test_context();
  const char *const *names = rp_sequence_builtin_names();
  int count = 0, i;
  (void)state;
  for (; *names != NULL; names++, count++) {
    rp_sequence *s = NULL;
    rp_sequence_state st;
    uint32_t f, n;
    assert_int_equal(rp_sequence_load(ctx, *names, &s), 0);
    n = rp_sequence_frames(s);
    assert_true(n >= 120 && n <= 200);
    assert_string_equal(rp_sequence_name(s), *names);
    assert_non_null(rp_sequence_builtin_about(*names));
    assert_string_equal(rp_sequence_about(s),
                        rp_sequence_builtin_about(*names));
    assert_non_null(rp_sequence_builtin_json(*names));
    assert_true(rp_sequence_tf_count(s) >= 1);
    for (i = 0; i < rp_sequence_tf_count(s); i++) {
      rp_tf *tf = NULL;
      assert_int_equal(rp_sequence_tf_create(ctx, s, i, &tf), 0);
      rp_tf_destroy(tf);
    }
    st = frame_of(s, 0);
    assert_true(st.camera_changed && st.tf_changed && st.target_changed &&
                st.effects_changed);
    for (f = 0; f < n; f++) {
      st = frame_of(s, f);
      /* Built-ins must mean the same on any machine. */
      assert_true(st.target_fraction > 0 && st.target_fraction <= 1);
      assert_true(st.target_ms == 0);
      assert_true(st.effects & RP_EFFECT_ERT);
      assert_true(st.tf >= 0 && st.tf < rp_sequence_tf_count(s));
      assert_true(st.distance > 0 && st.fov_y_deg > 0 &&
                  st.fov_y_deg < 180);
      assert_int_equal(st.projection, RP_PERSPECTIVE);
    }
    assert_int_equal(rp_sequence_frame(s, n, &st), RP_ERANGE);
    assert_non_null(strstr(rp_last_error(ctx), "does not exist"));
    rp_sequence_destroy(s);
  }
  assert_true(count >= 4);
  assert_null(rp_sequence_builtin_about("no-such"));
  assert_null(rp_sequence_builtin_json("no-such"));
  rp_context_destroy(ctx);
}

static void builtin_orbit_turns_full_circle(void **state) {
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  rp_sequence_state st, last;
  uint32_t f, n;
  (void)state;
  assert_int_equal(rp_sequence_load(ctx, "orbit", &s), 0);
  n = rp_sequence_frames(s);
  last = frame_of(s, 0);
  for (f = 1; f < n; f++) {
    st = frame_of(s, f);
    assert_true(st.azimuth_deg > last.azimuth_deg);
    assert_true(st.camera_changed);
    assert_false(st.tf_changed || st.target_changed || st.effects_changed);
    assert_int_equal(st.tf, 0);
    last = st;
  }
  /* One more step of the same size would close the circle. */
  st = frame_of(s, n - 1);
  assert_true(fabs(st.azimuth_deg + 360.0 / n - 360.0) < 1e-9);
  assert_int_equal(rp_sequence_tf_count(s), 1);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

static void builtin_tf_switch_alternates(void **state) {
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  rp_sequence_state st, prev;
  uint32_t f, n, last_switch = 0;
  int switches = 0, transparent = 0, opaque = 0;
  (void)state;
  assert_int_equal(rp_sequence_load(ctx, "tf-switch", &s), 0);
  n = rp_sequence_frames(s);
  prev = frame_of(s, 0);
  for (f = 0; f < n; f++) {
    double a;
    st = frame_of(s, f);
    a = tf_mean_alpha(ctx, s, st.tf);
    /* Every frame shows one of the two extremes. */
    assert_true(a < 0.05 || a > 0.9);
    transparent += a < 0.05;
    opaque += a > 0.9;
    if (f > 0) {
      assert_false(st.camera_changed);
      assert_int_equal(st.tf_changed, st.tf != prev.tf);
      if (st.tf_changed) {
        double pa = tf_mean_alpha(ctx, s, prev.tf);
        /* Abrupt: straight from one extreme to the other. */
        assert_true((a < 0.05 && pa > 0.9) || (a > 0.9 && pa < 0.05));
        assert_true(f - last_switch <= 30);
        last_switch = f;
        switches++;
      }
    }
    prev = st;
  }
  assert_true(switches >= 6);
  assert_true(transparent >= (int)n / 3 && opaque >= (int)n / 3);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

/* The eye of the last zoom-in frame is inside `vol`'s box and the first
 * one outside its bounding sphere. */
static void check_zoom_eye(const rp_sequence *s, const rp_volume *vol,
                           const char *what) {
  rp_volume_info info;
  rp_sequence_state st;
  rp_camera cam;
  double half[3], r2 = 0, e2 = 0;
  int a;
  rp_volume_get_info(vol, &info);
  for (a = 0; a < 3; a++) {
    half[a] = 0.5 * info.dims[a] * info.spacing[a];
    r2 += half[a] * half[a];
  }
  st = frame_of(s, 0);
  rp_sequence_camera(&st, vol, &cam);
  for (a = 0; a < 3; a++)
    e2 += (double)cam.eye[a] * cam.eye[a];
  assert_true(e2 > 9 * r2);
  st = frame_of(s, rp_sequence_frames(s) - 1);
  rp_sequence_camera(&st, vol, &cam);
  for (a = 0; a < 3; a++) {
    if (!(fabs(cam.eye[a]) < half[a]))
      fail_msg("%s: eye[%d] = %g is outside the box (half size %g)", what,
               a, (double)cam.eye[a], half[a]);
  }
}

static void builtin_zoom_in_ends_inside(void **state) {
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  rp_sequence_state st, prev;
  rp_generate_desc g = {0};
  rp_volume *vol = NULL;
  const char *const *names;
  uint32_t f, n;
  int real = 0;
  (void)state;
  assert_int_equal(rp_sequence_load(ctx, "zoom-in", &s), 0);
  n = rp_sequence_frames(s);
  prev = frame_of(s, 0);
  assert_true(prev.distance >= 3.5);
  for (f = 1; f < n; f++) {
    st = frame_of(s, f);
    assert_true(st.distance <= prev.distance);
    prev = st;
  }
  assert_true(prev.distance < 1.0);

  /* A cube, then a box half as deep as wide (the flattest real data sets
   * are about that flat). */
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = 32;
  assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
  check_zoom_eye(s, vol, "phantom 32^3");
  rp_volume_destroy(vol);
  g.dims[2] = 16;
  assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
  check_zoom_eye(s, vol, "phantom 32x32x16");
  rp_volume_destroy(vol);

  /* The real data sets, whatever their shape and spacing. */
  for (names = rp_test_data_names(); *names != NULL; names++) {
    char path[1024];
    vol = NULL;
    assert_non_null(rp_test_data_volume(*names, path, sizeof path));
    assert_int_equal(rp_volume_load(ctx, path, &vol), 0);
    check_zoom_eye(s, vol, *names);
    rp_volume_destroy(vol);
    real++;
  }
  print_message("zoom-in: eye inside the box on %d real volumes\n", real);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

static void builtin_mixed_changes_everything(void **state) {
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  rp_sequence_state st;
  uint32_t f, n;
  int tf = 0, target = 0, fx = 0, shading = 0, panned = 0, moved = 0;
  double az_lo = 1e9, az_hi = -1e9;
  (void)state;
  assert_int_equal(rp_sequence_load(ctx, "mixed", &s), 0);
  n = rp_sequence_frames(s);
  for (f = 1; f < n; f++) {
    st = frame_of(s, f);
    tf += st.tf_changed;
    target += st.target_changed;
    fx += st.effects_changed;
    shading += (st.effects & RP_EFFECT_SHADING) != 0;
    panned += st.pan[0] != 0 || st.pan[1] != 0;
    moved += st.camera_changed;
    az_lo = fmin(az_lo, st.azimuth_deg);
    az_hi = fmax(az_hi, st.azimuth_deg);
  }
  assert_true(tf >= 3);
  assert_true(target >= 1);
  assert_true(fx >= 2);
  assert_true(shading > 0 && shading < (int)n - 1); /* on, then off */
  assert_true(panned > 0);
  assert_true(moved > (int)n / 2);
  assert_true(az_hi - az_lo >= 180);
  /* Both a nearly transparent and an opaque TF take part. */
  assert_true(tf_mean_alpha(ctx, s, 2) > 0.9);
  assert_true(tf_mean_alpha(ctx, s, 3) < 0.05);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

/* tf-window: TF k, from frame 5k, is a tent over [0.03k, 0.03k + 0.13]
 * peaking at 0.8; worked out here at three frames and compared with
 * every LUT entry (entry i sits at x = i / (n - 1)). */
static void check_window(rp_context *ctx, const rp_sequence *s,
                         uint32_t frame, int want_tf, double lo) {
  rp_sequence_state st = frame_of(s, frame);
  double hi = lo + 0.13, mid = lo + 0.065, worst = 0.0;
  const float *lut;
  rp_tf *tf = NULL;
  int n = 0, i, inside = 0;
  assert_int_equal(st.tf, want_tf);
  assert_int_equal(rp_sequence_tf_create(ctx, s, st.tf, &tf), 0);
  lut = rp_tf_lut(tf, &n);
  for (i = 0; i < n; i++) {
    double x = (double)i / (n - 1);
    double want = x <= lo || x >= hi ? 0.0
                                     : 0.8 * (1.0 - fabs(x - mid) / 0.065);
    worst = fmax(worst, fabs(lut[4 * i + 3] - want));
    inside += lut[4 * i + 3] > 0.0f;
  }
  if (worst > 1e-4)
    fail_msg("frame %u: alpha off the window [%g, %g] by %g", frame, lo,
             hi, worst);
  /* The window is 0.13 of the range: about that share of the entries. */
  assert_true(abs(inside - (int)(0.13 * (n - 1))) <= 2);
  rp_tf_destroy(tf);
}

static void builtin_tf_window_slides(void **state) {
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  rp_sequence_state st;
  uint32_t f;
  (void)state;
  assert_int_equal(rp_sequence_load(ctx, "tf-window", &s), 0);
  assert_int_equal(rp_sequence_frames(s), 150);
  assert_int_equal(rp_sequence_tf_count(s), 30);
  for (f = 1; f < 150; f++) {
    st = frame_of(s, f);
    assert_int_equal(st.tf, (int)(f / 5));
    assert_int_equal(st.tf_changed, f % 5 == 0);
    /* An orbit of 1 degree a frame: motion, never a cut. */
    assert_true(fabs(st.azimuth_deg - f) < 1e-9);
    assert_true(st.camera_changed && !st.camera_cut);
    assert_false(st.effects_changed || st.target_changed);
  }
  check_window(ctx, s, 0, 0, 0.0);
  check_window(ctx, s, 77, 15, 0.45);
  check_window(ctx, s, 149, 29, 0.87);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

static void builtin_head_motion_jitters_while_approaching(void **state) {
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  rp_sequence_state st, prev;
  uint32_t f;
  int turns = 0;
  (void)state;
  assert_int_equal(rp_sequence_load(ctx, "head-motion", &s), 0);
  assert_int_equal(rp_sequence_frames(s), 121);
  /* Frame 6, halfway between the keys of frames 4 (azimuth 33,
   * elevation 22, distance 3.34) and 8 (27, 20, 3.28). */
  st = frame_of(s, 6);
  assert_true(fabs(st.azimuth_deg - 30.0) < 1e-9);
  assert_true(fabs(st.elevation_deg - 21.0) < 1e-9);
  assert_true(fabs(st.distance - 3.31) < 1e-9);
  st = frame_of(s, 120);
  assert_true(st.azimuth_deg == 27.0 && st.elevation_deg == 20.0 &&
              st.distance == 1.6);
  prev = frame_of(s, 0);
  for (f = 1; f < 121; f++) {
    st = frame_of(s, f);
    assert_true(st.camera_changed && !st.camera_cut);
    assert_false(st.tf_changed || st.effects_changed || st.target_changed);
    assert_true(st.azimuth_deg >= 27.0 && st.azimuth_deg <= 33.0);
    assert_true(st.elevation_deg >= 18.0 && st.elevation_deg <= 22.0);
    assert_true(st.distance < prev.distance);
    /* The azimuth turns back every 4 frames. */
    if (f >= 2) {
      rp_sequence_state pp = frame_of(s, f - 2);
      turns += (st.azimuth_deg - prev.azimuth_deg) *
                   (prev.azimuth_deg - pp.azimuth_deg) < 0;
    }
    prev = st;
  }
  assert_int_equal(turns, 120 / 4 - 1);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

/* A copy of `src` without any `what`. */
static char *without(const char *src, const char *what) {
  size_t n = strlen(what);
  char *out = malloc(strlen(src) + 1), *d = out;
  assert_non_null(out);
  while (*src != '\0') {
    if (strncmp(src, what, n) == 0)
      src += n;
    else
      *d++ = *src++;
  }
  *d = '\0';
  return out;
}

static void check_cut_switch(const rp_sequence *s) {
  rp_sequence_state st;
  uint32_t f;
  int cuts = 0;
  assert_int_equal(rp_sequence_frames(s), 150);
  for (f = 1; f < 150; f++) {
    st = frame_of(s, f);
    assert_int_equal(st.camera_cut, f % 30 == 0);
    assert_int_equal(st.tf_changed, f % 30 == 0);
    assert_true(st.camera_changed);
    cuts += st.camera_cut && st.tf_changed;
  }
  assert_int_equal(cuts, 4);
  /* Half-way through the second shot: 0.5 degrees a frame from 120. */
  st = frame_of(s, 45);
  assert_true(fabs(st.azimuth_deg - 127.5) < 1e-9);
  assert_true(st.elevation_deg == 35.0 && st.distance == 1.6);
  st = frame_of(s, 60);
  assert_true(st.azimuth_deg == 250.0 && st.tf == 2);
}

/* Each cut is marked, and each also jumps far enough for the rule alone
 * (RP_SEQUENCE_CUT_*): without the marks, the same frames are cuts. */
static void builtin_cut_switch_cuts_with_switches(void **state) {
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  char *unmarked = without(rp_sequence_builtin_json("cut-switch"),
                           ",\n                \"cut\": true");
  (void)state;
  assert_null(strstr(unmarked, "cut\""));
  assert_int_equal(rp_sequence_load(ctx, "cut-switch", &s), 0);
  check_cut_switch(s);
  rp_sequence_destroy(s);
  s = parse_ok(ctx, unmarked);
  check_cut_switch(s);
  rp_sequence_destroy(s);
  free(unmarked);
  rp_context_destroy(ctx);
}

static void builtin_target_steps_steps(void **state) {
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  rp_sequence_state st;
  uint32_t f;
  (void)state;
  assert_int_equal(rp_sequence_load(ctx, "target-steps", &s), 0);
  assert_int_equal(rp_sequence_frames(s), 150);
  for (f = 1; f < 150; f++) {
    st = frame_of(s, f);
    assert_true(st.target_fraction == (f < 50 ? 0.5 : f < 100 ? 0.2 : 0.8));
    assert_int_equal(st.target_changed, f == 50 || f == 100);
    assert_true(fabs(st.azimuth_deg - f) < 1e-9 && !st.camera_cut);
    assert_false(st.tf_changed || st.effects_changed);
  }
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

static void builtin_effects_motion_toggles(void **state) {
  static const uint32_t plain = RP_EFFECT_ERT | RP_EFFECT_SKIP;
  static const uint32_t want[6] = {
      plain, plain | RP_EFFECT_SHADING, plain,
      plain | RP_EFFECT_SHADING | RP_EFFECT_AO, plain | RP_EFFECT_SHADING,
      plain};
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  rp_sequence_state st;
  uint32_t f;
  (void)state;
  assert_int_equal(rp_sequence_load(ctx, "effects-motion", &s), 0);
  assert_int_equal(rp_sequence_frames(s), 150);
  for (f = 1; f < 150; f++) {
    st = frame_of(s, f);
    assert_int_equal(st.effects, want[f / 25]);
    assert_int_equal(st.effects_changed, f % 25 == 0);
    /* Mid-motion: the camera moves on every frame, a toggle's too. */
    assert_true(st.camera_changed && !st.camera_cut);
    assert_true(fabs(st.distance - (3.0 - 1.2 * f / 149.0)) < 1e-9);
    assert_false(st.tf_changed || st.target_changed);
  }
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

/* ---- resolution ---------------------------------------------------------- */

static void camera_interpolates_linearly(void **state) {
  static const char doc[] =
      "{\"frames\": 30, \"tfs\": [\"ramp\"], \"events\": [\n"
      " {\"frame\": 4, \"camera\": {\"azimuth\": 10, \"elevation\": 0,\n"
      "  \"distance\": 2, \"pan\": [0, 0], \"fov\": 40}},\n"
      " {\"frame\": 14, \"camera\": {\"azimuth\": 100, \"elevation\": 30,\n"
      "  \"distance\": 1, \"pan\": [0.5, -0.25], \"fov\": 60}},\n"
      " {\"frame\": 20, \"camera\": {}},\n"
      " {\"frame\": 24, \"camera\": {\"distance\": 3}}]}";
  rp_context *ctx = rp_test_context();
  rp_sequence *s = parse_ok(ctx, doc);
  rp_sequence_state st;
  uint32_t f;
  (void)state;
  /* Before the first keyframe the camera holds it. */
  for (f = 0; f <= 4; f++) {
    st = frame_of(s, f);
    assert_true(st.azimuth_deg == 10 && st.elevation_deg == 0 &&
                st.distance == 2 && st.fov_y_deg == 40);
    assert_int_equal(st.camera_changed, f == 0);
  }
  /* Midway (frame 9): every value halfway, by hand. */
  st = frame_of(s, 9);
  assert_float_equal(st.azimuth_deg, 55, 1e-12);
  assert_float_equal(st.elevation_deg, 15, 1e-12);
  assert_float_equal(st.distance, 1.5, 1e-12);
  assert_float_equal(st.pan[0], 0.25, 1e-12);
  assert_float_equal(st.pan[1], -0.125, 1e-12);
  assert_float_equal(st.fov_y_deg, 50, 1e-12);
  assert_true(st.camera_changed);
  /* Frame 6 is 2/10 of the way: 10 + 0.2 * 90 = 28, and so on. */
  st = frame_of(s, 6);
  assert_float_equal(st.azimuth_deg, 28, 1e-12);
  assert_float_equal(st.elevation_deg, 6, 1e-12);
  assert_float_equal(st.distance, 1.8, 1e-12);
  assert_float_equal(st.pan[0], 0.1, 1e-12);
  assert_float_equal(st.pan[1], -0.05, 1e-12);
  assert_float_equal(st.fov_y_deg, 44, 1e-12);
  /* Keyframes are hit exactly, and {} repeats the previous one: a hold
   * that reports no change. */
  for (f = 14; f <= 20; f++) {
    st = frame_of(s, f);
    assert_true(st.azimuth_deg == 100 && st.elevation_deg == 30 &&
                st.distance == 1 && st.pan[0] == 0.5 &&
                st.pan[1] == -0.25 && st.fov_y_deg == 60);
    assert_int_equal(st.camera_changed, f == 14);
  }
  /* A key that gives only distance keeps the other values. */
  st = frame_of(s, 22);
  assert_float_equal(st.distance, 2, 1e-12);
  assert_true(st.azimuth_deg == 100 && st.fov_y_deg == 60);
  /* After the last keyframe the camera holds. */
  for (f = 24; f < 30; f++) {
    st = frame_of(s, f);
    assert_true(st.distance == 3 && st.azimuth_deg == 100);
    assert_int_equal(st.camera_changed, f == 24);
  }
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

/* Each limit of the cut rule met just under and just over, one value at
 * a time on consecutive frames; then marked cuts: a small move marked is
 * a cut, a mark that moves nothing is none, and a mark holds the camera
 * until its frame. */
static void camera_cuts_by_rule_and_by_mark(void **state) {
  static const char doc[] =
      "{\"frames\": 20, \"tfs\": [\"ramp\"], \"events\": [\n"
      " {\"frame\": 0, \"camera\": {\"azimuth\": 0, \"elevation\": 0,\n"
      "  \"distance\": 2, \"fov\": 40, \"pan\": [0, 0]}},\n"
      " {\"frame\": 1, \"camera\": {\"azimuth\": 14}},\n"
      " {\"frame\": 2, \"camera\": {\"azimuth\": 30}},\n"
      " {\"frame\": 3, \"camera\": {\"distance\": 2.4}},\n"
      " {\"frame\": 4, \"camera\": {\"distance\": 3.12}},\n"
      " {\"frame\": 5, \"camera\": {\"fov\": 48}},\n"
      " {\"frame\": 6, \"camera\": {\"fov\": 62.4}},\n"
      " {\"frame\": 7, \"camera\": {\"pan\": [0.2, 0]}},\n"
      " {\"frame\": 8, \"camera\": {\"pan\": [0.2, 0.3]}},\n"
      " {\"frame\": 9, \"camera\": {\"elevation\": 90}},\n"
      " {\"frame\": 10, \"camera\": {\"azimuth\": 210}},\n"
      " {\"frame\": 11, \"camera\": {\"elevation\": 85}},\n"
      " {\"frame\": 12, \"camera\": {\"elevation\": 80, \"cut\": true}},\n"
      " {\"frame\": 13, \"camera\": {\"cut\": true}},\n"
      " {\"frame\": 19, \"camera\": {\"azimuth\": 250, \"cut\": true}}]}";
  /* 14 degrees, 16; distance x1.2, x1.3; fov x1.2, x1.3; pan 0.2, 0.3;
   * 90 degrees up; azimuth turned at the pole (the same view); 5 degrees
   * down; 5 more, marked; a mark that moves nothing; the hold; the jump
   * the last mark makes. */
  static const int changed[20] = {1, 1, 1, 1, 1, 1, 1, 1, 1, 1,
                                  1, 1, 1, 0, 0, 0, 0, 0, 0, 1};
  static const int cut[20] = {0, 0, 1, 0, 1, 0, 1, 0, 1, 1,
                              0, 0, 1, 0, 0, 0, 0, 0, 0, 1};
  rp_context *ctx = rp_test_context();
  rp_sequence *s = parse_ok(ctx, doc);
  rp_sequence_state st;
  uint32_t f;
  (void)state;
  for (f = 1; f < 20; f++) {
    st = frame_of(s, f);
    if (st.camera_changed != changed[f] || st.camera_cut != cut[f])
      fail_msg("frame %u: changed %d cut %d; want %d and %d", f,
               st.camera_changed, st.camera_cut, changed[f], cut[f]);
  }
  st = frame_of(s, 0);
  assert_true(st.camera_changed && !st.camera_cut);
  st = frame_of(s, 18);
  assert_true(st.azimuth_deg == 210.0 && st.elevation_deg == 80.0);
  st = frame_of(s, 19);
  assert_true(st.azimuth_deg == 250.0);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

static void azimuth_is_taken_as_written(void **state) {
  static const char doc[] =
      "{\"frames\": 5, \"tfs\": [\"ramp\"], \"events\": [\n"
      " {\"frame\": 0, \"camera\": {\"azimuth\": 350}},\n"
      " {\"frame\": 4, \"camera\": {\"azimuth\": 10}}]}";
  static const char doc2[] =
      "{\"frames\": 5, \"tfs\": [\"ramp\"], \"events\": [\n"
      " {\"frame\": 0, \"camera\": {\"azimuth\": 350}},\n"
      " {\"frame\": 4, \"camera\": {\"azimuth\": 370}}]}";
  rp_context *ctx = rp_test_context();
  rp_sequence *s = parse_ok(ctx, doc);
  (void)state;
  /* 350 -> 10 goes the long way round, through 180... */
  assert_float_equal(frame_of(s, 2).azimuth_deg, 180, 1e-12);
  rp_sequence_destroy(s);
  /* ...and 350 -> 370 the short way, through 360. */
  s = parse_ok(ctx, doc2);
  assert_float_equal(frame_of(s, 2).azimuth_deg, 360, 1e-12);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

static void steps_hold_until_the_next_change(void **state) {
  static const char doc[] =
      "{\"frames\": 12, \"tfs\": [\"ramp\", \"opaque\"], \"events\": [\n"
      " {\"frame\": 3, \"target_ms\": 20},\n"
      " {\"frame\": 4, \"effects\": [\"shading\", \"skip\"]},\n"
      " {\"frame\": 5, \"tf\": 1},\n"
      " {\"frame\": 6, \"tf\": 1, \"effects\": [\"skip\", \"shading\"]},\n"
      " {\"frame\": 7, \"target_fraction\": 0.25},\n"
      " {\"frame\": 8, \"effects\": []},\n"
      " {\"frame\": 9, \"tf\": 0, \"effects\": [\"ao\", \"ert\"]},\n"
      " {\"frame\": 11, \"effects\": [\"ert\", \"preint\"]}]}";
  /* By hand: tf, target_ms, target_fraction, effects and the three
   * change flags per frame. Before a track's first change: tf 0,
   * fraction 0.5, no effects; the camera has the defaults. */
  static const struct {
    int tf;
    double ms, frac;
    uint32_t fx;
    int tfc, tc, fc;
  } want[12] = {
      {0, 0, 0.5, 0, 1, 1, 1},
      {0, 0, 0.5, 0, 0, 0, 0},
      {0, 0, 0.5, 0, 0, 0, 0},
      {0, 20, 0, 0, 0, 1, 0},
      {0, 20, 0, RP_EFFECT_SHADING | RP_EFFECT_SKIP, 0, 0, 1},
      {1, 20, 0, RP_EFFECT_SHADING | RP_EFFECT_SKIP, 1, 0, 0},
      /* Restating the same values is no change. */
      {1, 20, 0, RP_EFFECT_SHADING | RP_EFFECT_SKIP, 0, 0, 0},
      {1, 0, 0.25, RP_EFFECT_SHADING | RP_EFFECT_SKIP, 0, 1, 0},
      {1, 0, 0.25, 0, 0, 0, 1},
      {0, 0, 0.25, RP_EFFECT_AO | RP_EFFECT_ERT, 1, 0, 1},
      {0, 0, 0.25, RP_EFFECT_AO | RP_EFFECT_ERT, 0, 0, 0},
      {0, 0, 0.25, RP_EFFECT_ERT | RP_EFFECT_PREINT, 0, 0, 1},
  };
  rp_context *ctx = rp_test_context();
  rp_sequence *s = parse_ok(ctx, doc);
  uint32_t f;
  (void)state;
  assert_int_equal(rp_sequence_tf_count(s), 2);
  for (f = 0; f < 12; f++) {
    rp_sequence_state st = frame_of(s, f);
    assert_int_equal(st.tf, want[f].tf);
    assert_true(st.target_ms == want[f].ms);
    assert_true(st.target_fraction == want[f].frac);
    assert_int_equal(st.effects, want[f].fx);
    assert_int_equal(st.tf_changed, want[f].tfc);
    assert_int_equal(st.target_changed, want[f].tc);
    assert_int_equal(st.effects_changed, want[f].fc);
    assert_int_equal(st.camera_changed, f == 0);
    assert_true(st.azimuth_deg == 0 && st.elevation_deg == 0 &&
                st.distance == 3 && st.fov_y_deg == 40 && st.pan[0] == 0 &&
                st.pan[1] == 0);
  }
  /* Any order of queries gives the same answers. */
  assert_int_equal(frame_of(s, 7).tf, 1);
  assert_int_equal(frame_of(s, 2).tf, 0);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

static void control_points_and_projection(void **state) {
  static const char doc[] =
      "{\"frames\": 3, \"projection\": \"orthographic\",\n"
      " \"name\": \"cp\", \"about\": \"control points\",\n"
      " \"tfs\": [{\"points\": [[0, 0, 0, 0, 0], [1, 1, 0.5, 0, 0.5]],\n"
      "           \"reference_step\": 2, \"lut_size\": 3,\n"
      "           \"comment\": \"a red ramp\"},\n"
      "          {\"preset\": \"opaque\"}],\n"
      " \"events\": [{\"frame\": 0, \"tf\": 1}]}";
  rp_context *ctx = rp_test_context();
  rp_sequence *s = parse_ok(ctx, doc);
  rp_tf *tf = NULL;
  const float *lut;
  int n = 0;
  (void)state;
  assert_string_equal(rp_sequence_name(s), "cp");
  assert_string_equal(rp_sequence_about(s), "control points");
  assert_int_equal(frame_of(s, 0).projection, RP_ORTHOGRAPHIC);
  assert_int_equal(rp_sequence_tf_create(ctx, s, 0, &tf), 0);
  lut = rp_tf_lut(tf, &n);
  assert_int_equal(n, 3);
  assert_float_equal(rp_tf_reference_step(tf), 2, 0);
  /* The middle entry is halfway along the ramp. */
  assert_float_equal(lut[4 + 0], 0.5, 1e-7);
  assert_float_equal(lut[4 + 1], 0.25, 1e-7);
  assert_float_equal(lut[4 + 3], 0.25, 1e-7);
  rp_tf_destroy(tf);
  tf = NULL;
  assert_true(tf_mean_alpha(ctx, s, 1) > 0.99);
  assert_int_equal(rp_sequence_tf_create(ctx, s, 2, &tf), RP_ERANGE);
  assert_int_equal(rp_sequence_tf_create(ctx, s, -1, &tf), RP_ERANGE);
  assert_null(tf);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

/* ---- the camera helper --------------------------------------------------- */

static void camera_helper_orbits_and_pans(void **state) {
  rp_context *ctx = rp_test_context();
  rp_generate_desc g = {0};
  rp_volume *vol = NULL;
  rp_volume_info info;
  rp_sequence_state st;
  rp_camera cam, ref = {0};
  rp_render_desc rd = {0};
  rp_tf *tf = NULL;
  uint8_t px[16 * 16 * 4];
  double R;
  int a;
  (void)state;
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = 16, g.dims[1] = 24, g.dims[2] = 32;
  assert_int_equal(rp_volume_generate(ctx, &g, &vol), 0);
  rp_volume_get_info(vol, &info);
  R = 0.5 * sqrt(16.0 * 16 + 24 * 24 + 32 * 32);
  assert_int_equal(rp_tf_create_preset(ctx, "opaque", &tf), 0);
  rd.width = rd.height = 16;

  memset(&st, 0, sizeof st);
  st.projection = RP_PERSPECTIVE;
  st.azimuth_deg = 30, st.elevation_deg = 20, st.distance = 2.5;
  st.fov_y_deg = 35;
  memset(&cam, 0x7f, sizeof cam); /* every field must be written */
  rp_sequence_camera(&st, vol, &cam);
  rp_camera_orbit(&ref, vol, 30, 20, 2.5f);
  for (a = 0; a < 3; a++) {
    assert_true(cam.eye[a] == ref.eye[a]);
    assert_true(cam.center[a] == 0 && cam.up[a] == ref.up[a]);
  }
  assert_float_equal(cam.fov_y_deg, 35, 0);
  assert_float_equal(cam.ortho_height, 0, 0);
  assert_int_equal(rp_render_reference(ctx, vol, tf, NULL, NULL, &cam, &rd, px,
                                       NULL), 0);

  /* Azimuth 0: right is +x, up is +y; pan moves both points. */
  st.azimuth_deg = 0, st.elevation_deg = 0, st.distance = 2;
  st.pan[0] = 0.5, st.pan[1] = 0.25;
  rp_sequence_camera(&st, vol, &cam);
  assert_float_equal(cam.eye[0], 0.5 * R, 1e-4);
  assert_float_equal(cam.eye[1], 0.25 * R, 1e-4);
  assert_float_equal(cam.eye[2], 2 * R, 1e-4);
  assert_float_equal(cam.center[0], 0.5 * R, 1e-4);
  assert_float_equal(cam.center[1], 0.25 * R, 1e-4);
  assert_float_equal(cam.center[2], 0, 1e-4);
  /* Azimuth 90 looks down -x: right is -z. */
  st.azimuth_deg = 90, st.pan[1] = 0;
  rp_sequence_camera(&st, vol, &cam);
  assert_float_equal(cam.eye[0], 2 * R, 1e-4);
  assert_float_equal(cam.eye[2], -0.5 * R, 1e-4);
  assert_float_equal(cam.center[2], -0.5 * R, 1e-4);
  assert_float_equal(cam.center[0], 0, 1e-4);
  assert_int_equal(rp_render_reference(ctx, vol, tf, NULL, NULL, &cam, &rd, px,
                                       NULL), 0);
  /* Straight down: the default up becomes +z; pan stays a valid
   * camera, moved by pan * R perpendicular to the view. */
  st.elevation_deg = 90, st.pan[0] = 1;
  rp_sequence_camera(&st, vol, &cam);
  assert_float_equal(cam.center[1], 0, 1e-4);
  assert_float_equal(hypot(cam.center[0], cam.center[2]), R, 1e-3);
  assert_int_equal(rp_render_reference(ctx, vol, tf, NULL, NULL, &cam, &rd, px,
                                       NULL), 0);
  /* Orthographic: the height a perspective camera sees at the centre. */
  st.projection = RP_ORTHOGRAPHIC;
  st.elevation_deg = 0, st.pan[0] = 0, st.fov_y_deg = 40;
  rp_sequence_camera(&st, vol, &cam);
  assert_int_equal(cam.projection, RP_ORTHOGRAPHIC);
  assert_float_equal(cam.ortho_height, 2 * 2 * R * tan(20 * PI / 180),
                     1e-3);
  assert_int_equal(rp_render_reference(ctx, vol, tf, NULL, NULL, &cam, &rd, px,
                                       NULL), 0);
  rp_sequence_camera(NULL, vol, &cam); /* no-ops */
  rp_sequence_camera(&st, NULL, &cam);
  rp_sequence_camera(&st, vol, NULL);
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* ---- malformed documents ------------------------------------------------- */

#define DOC(events)                                                           \
  "{\"frames\": 10, \"tfs\": [\"ramp\", \"opaque\"], \"events\": [" events "]}"
#define TOP(top) "{" top "}"
#define EV0 "{\"frame\": 0, \"tf\": 0}"

typedef struct bad_case {
  const char *json;
  int err;
  const char *msg; /* a substring of rp_last_error */
} bad_case;

static const bad_case bad_cases[] = {
    /* Not JSON, or not an object. */
    {"{", RP_EFORMAT, "not valid JSON: unexpected end of input"},
    {"{\n  \"frames\": 10,\n  oops\n}", RP_EFORMAT,
     "not valid JSON at line 3, column 3 (near 'oops')"},
    {DOC(EV0) " trailing", RP_EFORMAT, "not valid JSON at line 1"},
    {"[1, 2]", RP_EFORMAT, "expected an object at the top level, got an "
     "array"},
    /* Top level. */
    {TOP("\"tfs\": [\"ramp\"], \"events\": [" EV0 "]"), RP_EFORMAT,
     "missing required key \"frames\""},
    {TOP("\"frames\": 0, \"tfs\": [\"ramp\"], \"events\": [" EV0 "]"),
     RP_ERANGE, "frames: 0 is outside [1, 10000000] (an empty sequence)"},
    {TOP("\"frames\": 1.5, \"tfs\": [\"ramp\"], \"events\": [" EV0 "]"),
     RP_EFORMAT, "frames: expected an integer, got 1.5"},
    {TOP("\"frames\": \"10\", \"tfs\": [\"ramp\"], \"events\": [" EV0 "]"),
     RP_EFORMAT, "frames: expected an integer, got \"10\""},
    {TOP("\"frames\": 10, \"frame\": 3, \"tfs\": [\"ramp\"], "
         "\"events\": [" EV0 "]"),
     RP_EFORMAT, "unknown key \"frame\" (known: version, name"},
    {TOP("\"frames\": 10, \"frames\": 12, \"tfs\": [\"ramp\"], "
         "\"events\": [" EV0 "]"),
     RP_EFORMAT, "key \"frames\" appears twice"},
    {TOP("\"version\": 2, \"frames\": 10, \"tfs\": [\"ramp\"], "
         "\"events\": [" EV0 "]"),
     RP_EUNSUPPORTED, "version: 2 is not supported"},
    {TOP("\"frames\": 10, \"projection\": \"fisheye\", \"tfs\": [\"ramp\"],"
         " \"events\": [" EV0 "]"),
     RP_EINVAL, "projection: unknown projection \"fisheye\" (known: "
     "perspective, orthographic)"},
    {TOP("\"frames\": 10, \"events\": [" EV0 "]"), RP_EFORMAT,
     "missing required key \"tfs\""},
    {TOP("\"frames\": 10, \"tfs\": [\"ramp\"]"), RP_EFORMAT,
     "missing required key \"events\""},
    /* Transfer functions. */
    {TOP("\"frames\": 10, \"tfs\": [], \"events\": [" EV0 "]"), RP_EFORMAT,
     "tfs: empty; at least one transfer function is needed"},
    {TOP("\"frames\": 10, \"tfs\": [\"minmax-bones\"], \"events\": [" EV0 "]"),
     RP_EINVAL, "tfs[0]: unknown transfer function preset \"minmax-bones\" "
     "(known: transparent, opaque, ct-bone, ct-soft, ct-lung, ct-angio, "
     "mri, minmax-bone, minmax-soft, ramp, nearly-transparent)"},
    {TOP("\"frames\": 10, \"tfs\": [\"ramp\", {\"points\": [[0.5, 0, 0, 0, "
         "0], [0.25, 1, 1, 1, 1]]}], \"events\": [" EV0 "]"),
     RP_EINVAL, "tfs[1]: transfer function: point 1 field 'x'"},
    {TOP("\"frames\": 10, \"tfs\": [{\"points\": [[0, 0, 0, 0, 1.5]]}], "
         "\"events\": [" EV0 "]"),
     RP_ERANGE, "tfs[0]: transfer function: point 0 field 'a': value 1.5 "
     "is outside [0, 1]"},
    {TOP("\"frames\": 10, \"tfs\": [{\"points\": [[0, 0, 0, 0]]}], "
         "\"events\": [" EV0 "]"),
     RP_EFORMAT, "tfs[0].points[0]: expected an array of 5 numbers"},
    {TOP("\"frames\": 10, \"tfs\": [{\"points\": [[0, 0, 0, 0, 1e300]]}], "
         "\"events\": [" EV0 "]"),
     RP_ERANGE, "tfs[0].points[0][4]: 1e+300 is outside [0, 1]"},
    {TOP("\"frames\": 10, \"tfs\": [{\"points\": [[0, 0, 0, 0, 0]], "
         "\"lut_size\": 1}], \"events\": [" EV0 "]"),
     RP_ERANGE, "tfs[0].lut_size: 1 is outside [2, 65536]"},
    {TOP("\"frames\": 10, \"tfs\": [{\"preset\": \"ramp\", \"lut_size\": "
         "64}], \"events\": [" EV0 "]"),
     RP_EFORMAT, "tfs[0]: \"reference_step\" and \"lut_size\" apply to "
     "\"points\" only"},
    {TOP("\"frames\": 10, \"tfs\": [3], \"events\": [" EV0 "]"), RP_EFORMAT,
     "tfs[0]: expected a preset name or an object, got 3"},
    /* Events and frames. */
    {DOC(""), RP_EFORMAT, "events: empty; a sequence needs at least one "
     "event"},
    {DOC("{\"tf\": 0}"), RP_EFORMAT, "events[0]: missing required key "
     "\"frame\""},
    {DOC("{\"frame\": -1, \"tf\": 0}"), RP_ERANGE,
     "events[0].frame: frame -1 is negative"},
    {DOC("{\"frame\": 2.5, \"tf\": 0}"), RP_EFORMAT,
     "events[0].frame: expected an integer, got 2.5"},
    {DOC("{\"frame\": 5, \"tf\": 0}, {\"frame\": 3, \"tf\": 1}"),
     RP_EFORMAT, "events[1].frame: frame 3 does not come after "
     "events[0].frame 5"},
    {DOC("{\"frame\": 5, \"tf\": 0}, {\"frame\": 5, \"tf\": 1}"),
     RP_EFORMAT, "events[1].frame: frame 5 does not come after"},
    {DOC(EV0 ", {\"frame\": 10, \"tf\": 1}"), RP_ERANGE,
     "events[1].frame: frame 10 is beyond the last frame 9 "
     "(\"frames\": 10)"},
    {DOC("{\"frame\": 0}"), RP_EFORMAT, "events[0]: changes nothing"},
    {DOC("{\"frame\": 0, \"tf\": 0, \"effect\": []}"), RP_EFORMAT,
     "events[0]: unknown key \"effect\""},
    {DOC("{\"frame\": 0, \"tf\": 2}"), RP_ERANGE,
     "events[0].tf: index 2 is out of range (\"tfs\" has 2: 0 to 1)"},
    {DOC("{\"frame\": 0, \"tf\": \"opaque\"}"), RP_EFORMAT,
     "events[0].tf: expected an integer, got \"opaque\""},
    /* Camera. */
    {DOC(EV0 ", {\"frame\": 1, \"camera\": {}}, {\"frame\": 2, \"camera\": "
             "{}}, {\"frame\": 3, \"camera\": {\"azimuth\": \"abc\"}}"),
     RP_EFORMAT, "sequence 't.json': events[3].camera.azimuth: expected a "
     "number, got \"abc\""},
    {DOC("{\"frame\": 0, \"camera\": {\"distance\": 1e999}}"),
     RP_ENOTFINITE, "events[0].camera.distance: the number is too large "
     "for a double (it reads as inf)"},
    {DOC("{\"frame\": 0, \"camera\": {\"azimuth\": -1e999}}"),
     RP_ENOTFINITE, "events[0].camera.azimuth: the number is too large "
     "for a double (it reads as -inf)"},
    {DOC("{\"frame\": 0, \"camera\": {\"distance\": 0}}"), RP_ERANGE,
     "events[0].camera.distance: 0 is outside [0.0001, 10000] (bounding "
     "radii; must be > 0)"},
    {DOC("{\"frame\": 0, \"camera\": {\"distance\": -2}}"), RP_ERANGE,
     "events[0].camera.distance: -2 is outside"},
    {DOC("{\"frame\": 0, \"camera\": {\"fov\": 180}}"), RP_ERANGE,
     "events[0].camera.fov: 180 is outside [0.01, 170]"},
    {DOC("{\"frame\": 0, \"camera\": {\"fov\": 0}}"), RP_ERANGE,
     "events[0].camera.fov: 0 is outside [0.01, 170]"},
    {DOC("{\"frame\": 0, \"camera\": {\"elevation\": 91}}"), RP_ERANGE,
     "events[0].camera.elevation: 91 is outside [-90, 90]"},
    {DOC("{\"frame\": 0, \"camera\": {\"azimut\": 10}}"), RP_EFORMAT,
     "events[0].camera: unknown key \"azimut\" (known: azimuth, elevation,"
     " distance, pan, fov, cut, comment)"},
    {DOC(EV0 ", {\"frame\": 3, \"camera\": {\"cut\": 1}}"), RP_EFORMAT,
     "events[1].camera.cut: expected true or false, got 1"},
    {DOC("{\"frame\": 0, \"tf\": 0}, {\"frame\": 3, \"camera\": "
         "{\"azimuth\": 90, \"cut\": true}}"),
     RP_EFORMAT, "events[1].camera.cut: a cut needs an earlier camera "
     "keyframe to cut from"},
    {DOC("{\"frame\": 0, \"camera\": {\"pan\": [1]}}"), RP_EFORMAT,
     "events[0].camera.pan: expected an array of 2 numbers [right, up], "
     "got an array"},
    {DOC("{\"frame\": 0, \"camera\": {\"pan\": [1, null]}}"), RP_EFORMAT,
     "events[0].camera.pan[1]: expected a number, got null"},
    {DOC("{\"frame\": 0, \"camera\": [0, 0, 3]}"), RP_EFORMAT,
     "events[0].camera: expected a camera object, got an array"},
    /* Targets and effects. */
    {DOC("{\"frame\": 0, \"target_ms\": 0}"), RP_ERANGE,
     "events[0].target_ms: 0 is outside (0, 60000] (milliseconds)"},
    {DOC("{\"frame\": 0, \"target_fraction\": -0.5}"), RP_ERANGE,
     "events[0].target_fraction: -0.5 is outside (0, 100]"},
    {DOC("{\"frame\": 0, \"target_ms\": 10, \"target_fraction\": 0.5}"),
     RP_EFORMAT, "events[0]: give \"target_ms\" or \"target_fraction\", "
     "not both"},
    {DOC("{\"frame\": 0, \"effects\": [\"ert\", \"shadow\"]}"), RP_EINVAL,
     "events[0].effects[1]: unknown effect \"shadow\" (known: shading, "
     "ert, skip, ao, preint)"},
    {DOC("{\"frame\": 0, \"effects\": \"ert\"}"), RP_EFORMAT,
     "events[0].effects: expected an array of effect names, got \"ert\""},
    {DOC("{\"frame\": 0, \"effects\": [\"ert\", \"ert\"]}"), RP_EFORMAT,
     "events[0].effects[1]: effect \"ert\" is listed twice"},
};

static void malformed_documents_fail_clearly(void **state) {
  rp_context *ctx = rp_test_context();
  size_t i;
  (void)state;
  for (i = 0; i < sizeof bad_cases / sizeof bad_cases[0]; i++) {
    const bad_case *c = &bad_cases[i];
    rp_sequence *s = (rp_sequence *)&i; /* a failure leaves it untouched */
    int err = rp_sequence_parse(ctx, c->json, strlen(c->json), "t.json",
                                &s);
    if (err != c->err || strstr(rp_last_error(ctx), c->msg) == NULL)
      fail_msg("case %zu: got %s \"%s\"; want %s containing \"%s\"\n"
               "document: %s", i, rp_err_name(err), rp_last_error(ctx),
               rp_err_name(c->err), c->msg, c->json);
    assert_ptr_equal(s, (rp_sequence *)&i);
    /* Every message says which document. */
    assert_non_null(strstr(rp_last_error(ctx), "sequence 't.json': "));
  }
  print_message("%zu malformed documents rejected\n", i);
  rp_context_destroy(ctx);
}

static void odd_bytes_fail_clearly(void **state) {
  static const char nul[] = "{\"frames\": 1}\0 {}";
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  (void)state;
  assert_int_equal(rp_sequence_parse(ctx, nul, sizeof nul - 1, "n", &s),
                   RP_EFORMAT);
  assert_non_null(strstr(rp_last_error(ctx), "NUL byte at offset 13"));
  assert_int_equal(rp_sequence_parse(ctx, "", 0, "e", &s), RP_EFORMAT);
  assert_non_null(strstr(rp_last_error(ctx), "sequence 'e': empty"));
  /* The length bounds the text: a valid prefix parses. */
  {
    static const char doc[] = DOC(EV0) "garbage";
    assert_int_equal(rp_sequence_parse(ctx, doc, sizeof doc - 1 - 7, NULL,
                                       &s), 0);
    assert_string_equal(rp_sequence_name(s), "<memory>");
    rp_sequence_destroy(s);
    s = NULL;
  }
  /* A byte order mark is skipped. */
  {
    static const char doc[] = "\xef\xbb\xbf" DOC(EV0);
    assert_int_equal(rp_sequence_parse(ctx, doc, sizeof doc - 1, "b", &s),
                     0);
    rp_sequence_destroy(s);
  }
  rp_context_destroy(ctx);
}

static void bad_arguments(void **state) {
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  rp_sequence_state st;
  rp_tf *tf = NULL;
  (void)state;
  assert_int_equal(rp_sequence_load(NULL, "orbit", &s), RP_EINVAL);
  assert_int_equal(rp_sequence_load(ctx, NULL, &s), RP_EINVAL);
  assert_int_equal(rp_sequence_load(ctx, "orbit", NULL), RP_EINVAL);
  assert_int_equal(rp_sequence_load(ctx, "", &s), RP_EINVAL);
  assert_int_equal(rp_sequence_parse(NULL, "{}", 2, NULL, &s), RP_EINVAL);
  assert_int_equal(rp_sequence_parse(ctx, NULL, 2, NULL, &s), RP_EINVAL);
  assert_int_equal(rp_sequence_parse(ctx, "{}", 2, NULL, NULL), RP_EINVAL);
  assert_null(s);
  assert_int_equal(rp_sequence_frame(NULL, 0, &st), RP_EINVAL);
  assert_int_equal(rp_sequence_frames(NULL), 0);
  assert_int_equal(rp_sequence_tf_count(NULL), 0);
  assert_null(rp_sequence_name(NULL));
  assert_int_equal(rp_sequence_tf_create(ctx, NULL, 0, &tf), RP_EINVAL);
  assert_int_equal(rp_sequence_load(ctx, "orbit", &s), 0);
  assert_int_equal(rp_sequence_frame(s, 0, NULL), RP_EINVAL);
  assert_int_equal(rp_sequence_tf_create(NULL, s, 0, &tf), RP_EINVAL);
  assert_int_equal(rp_sequence_tf_create(ctx, s, 0, NULL), RP_EINVAL);
  assert_null(tf);
  rp_sequence_destroy(s);
  rp_sequence_destroy(NULL);
  rp_context_destroy(ctx);
}

/* ---- files --------------------------------------------------------------- */

static void file_round_trip(void **state) {
  static const char doc[] =
      "{\n  \"frames\": 8,\n  \"tfs\": [\"mri\"],\n  \"events\": [\n"
      "    {\"frame\": 0, \"camera\": {\"azimuth\": 0}, \"target_ms\": 16},\n"
      "    {\"frame\": 7, \"camera\": {\"azimuth\": 70}}\n  ]\n}\n";
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL, *m = NULL;
  const char *path = rp_test_write_file("seq_round_trip.json", doc,
                                        sizeof doc - 1);
  uint32_t f;
  (void)state;
  assert_int_equal(rp_sequence_load(ctx, path, &s), 0);
  assert_string_equal(rp_sequence_name(s), path); /* no "name" given */
  assert_string_equal(rp_sequence_about(s), "");
  m = parse_ok(ctx, doc);
  assert_int_equal(rp_sequence_frames(s), 8);
  for (f = 0; f < 8; f++) {
    rp_sequence_state a = frame_of(s, f), b = frame_of(m, f);
    assert_memory_equal(&a, &b, sizeof a);
    assert_float_equal(a.azimuth_deg, 10.0 * f, 1e-12);
    assert_true(a.target_ms == 16 && a.target_fraction == 0);
  }
  rp_sequence_destroy(m);
  rp_sequence_destroy(s);
  rp_context_destroy(ctx);
}

static void file_errors(void **state) {
  static const char notjson[] = "{\"frames\": 8,\n \"tfs\": [ramp]}\n";
  rp_context *ctx = rp_test_context();
  rp_sequence *s = NULL;
  char missing[1024];
  const char *path;
  (void)state;
  snprintf(missing, sizeof missing, "%s/no_such_sequence.json",
           rp_test_tmp_dir());
  assert_int_equal(rp_sequence_load(ctx, missing, &s), RP_ENOENT);
  assert_non_null(strstr(rp_last_error(ctx), "no_such_sequence.json': no "
                                             "such file, and not a built-in "
                                             "sequence (built-ins: orbit, "
                                             "tf-switch, zoom-in, mixed, "
                                             "ao-tf-switch, tf-window, "
                                             "head-motion, cut-switch, "
                                             "target-steps, "
                                             "effects-motion)"));
  /* A near miss of a built-in name is a missing file too. */
  assert_int_equal(rp_sequence_load(ctx, "orbits", &s), RP_ENOENT);
  assert_int_equal(rp_sequence_load(ctx, rp_test_tmp_dir(), &s), RP_EIO);
  assert_non_null(strstr(rp_last_error(ctx), "not a regular file"));
  path = rp_test_write_file("seq_not_json.json", notjson,
                            sizeof notjson - 1);
  assert_int_equal(rp_sequence_load(ctx, path, &s), RP_EFORMAT);
  assert_non_null(strstr(rp_last_error(ctx), "seq_not_json.json': not "
                                             "valid JSON at line 2, column "
                                             "10 (near 'ramp]}')"));
  path = rp_test_write_file("seq_empty.json", "", 0);
  assert_int_equal(rp_sequence_load(ctx, path, &s), RP_EFORMAT);
  assert_non_null(strstr(rp_last_error(ctx), "empty document"));
  assert_null(s);
  rp_context_destroy(ctx);
}

/* ---- allocation failures ------------------------------------------------- */

typedef struct counting {
  long fail_at; /* the allocation that fails (1-based); 0: none */
  long calls;
  long live;
} counting;

static void *counting_alloc(size_t size, void *user) {
  counting *c = user;
  void *p;
  if (++c->calls == c->fail_at)
    return NULL;
  p = malloc(size);
  if (p != NULL)
    c->live++;
  return p;
}

static void counting_free(void *ptr, void *user) {
  counting *c = user;
  c->live--;
  free(ptr);
}

static void allocation_failures_are_clean(void **state) {
  static const char doc[] =
      "{\"frames\": 20, \"name\": \"n\", \"about\": \"a\",\n"
      " \"tfs\": [\"ramp\", {\"points\": [[0, 0, 0, 0, 0], [1, 1, 1, 1, 1]]}"
      "],\n \"events\": [{\"frame\": 0, \"tf\": 1, \"camera\": {}},\n"
      "  {\"frame\": 5, \"effects\": [\"ert\"], \"target_ms\": 3}]}";
  counting c = {0, 0, 0};
  rp_context_desc d = {0};
  rp_context *ctx = NULL;
  long n;
  int ok = 0;
  (void)state;
  d.allocator.alloc = counting_alloc;
  d.allocator.free = counting_free;
  d.allocator.user = &c;
  assert_int_equal(rp_context_create(&d, &ctx), 0);
  for (n = 1; n < 1000 && !ok; n++) {
    rp_sequence *s = NULL;
    long before = c.live;
    int err;
    c.calls = 0;
    c.fail_at = n;
    err = rp_sequence_parse(ctx, doc, sizeof doc - 1, "oom", &s);
    if (err == 0) {
      ok = 1;
      rp_sequence_destroy(s);
    } else {
      assert_int_equal(err, RP_ENOMEM);
      assert_null(s);
    }
    assert_int_equal(c.live, before); /* nothing leaked either way */
  }
  assert_true(ok && n > 5);
  c.fail_at = 0;
  rp_context_destroy(ctx);
  assert_int_equal(c.live, 0);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(builtins_load_and_resolve),
      cmocka_unit_test(builtin_orbit_turns_full_circle),
      cmocka_unit_test(builtin_tf_switch_alternates),
      cmocka_unit_test(builtin_zoom_in_ends_inside),
      cmocka_unit_test(builtin_mixed_changes_everything),
      cmocka_unit_test(builtin_tf_window_slides),
      cmocka_unit_test(builtin_head_motion_jitters_while_approaching),
      cmocka_unit_test(builtin_cut_switch_cuts_with_switches),
      cmocka_unit_test(builtin_target_steps_steps),
      cmocka_unit_test(builtin_effects_motion_toggles),
      cmocka_unit_test(camera_cuts_by_rule_and_by_mark),
      cmocka_unit_test(camera_interpolates_linearly),
      cmocka_unit_test(azimuth_is_taken_as_written),
      cmocka_unit_test(steps_hold_until_the_next_change),
      cmocka_unit_test(control_points_and_projection),
      cmocka_unit_test(camera_helper_orbits_and_pans),
      cmocka_unit_test(malformed_documents_fail_clearly),
      cmocka_unit_test(odd_bytes_fail_clearly),
      cmocka_unit_test(bad_arguments),
      cmocka_unit_test(file_round_trip),
      cmocka_unit_test(file_errors),
      cmocka_unit_test(allocation_failures_are_clean),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
