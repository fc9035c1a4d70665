/* libFuzzer target: a sequence document (docs/sequences.md) in memory
 * through rp_sequence_parse, the raypace command's parser (cli/, built
 * into this target). A sequence that loads promises that no frame can
 * fail later: every frame resolves, to a state within the format's
 * ranges, and its camera is finite. Frames are sampled (a sequence may
 * have ten million): the first ones, the last, and each side of every
 * change, where interpolation and steps switch. */
#include "fuzz_common.h"
#include "sequence_internal.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static int finite3(const float v[3]) {
  return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

/* Frame i (if it exists) against what a loaded sequence promises. */
static void check_frame(const rp_sequence *s, int64_t i) {
  rp_sequence_state st;
  rp_camera cam;
  if (i < 0 || i >= (int64_t)rp_sequence_frames(s))
    return;
  if (rp_sequence_frame(s, (uint32_t)i, &st) != 0 ||
      st.frame != (uint32_t)i || st.tf < 0 ||
      st.tf >= rp_sequence_tf_count(s) ||
      (st.target_ms > 0.0) == (st.target_fraction > 0.0) ||
      st.target_ms < 0.0 || st.target_fraction < 0.0 ||
      !isfinite(st.target_ms) || !isfinite(st.target_fraction) ||
      !isfinite(st.azimuth_deg) || !isfinite(st.elevation_deg) ||
      !(st.distance > 0.0) || !isfinite(st.distance) ||
      !isfinite(st.pan[0]) || !isfinite(st.pan[1]) ||
      !(st.fov_y_deg > 0.0 && st.fov_y_deg < 180.0))
    abort();
  rp_sequence_camera(&st, fuzz_volume(), &cam);
  if (!finite3(cam.eye) || !finite3(cam.center) || !finite3(cam.up) ||
      !isfinite(cam.fov_y_deg) || !isfinite(cam.ortho_height))
    abort();
}

/* Each side of the changes on one track (`n` entries of `stride` bytes
 * whose first field is the frame). */
static void check_track(const rp_sequence *s, const void *track, size_t n,
                        size_t stride) {
  size_t k;
  for (k = 0; k < n && k < 256; k++) {
    uint32_t f;
    memcpy(&f, (const char *)track + k * stride, sizeof f);
    check_frame(s, (int64_t)f - 1);
    check_frame(s, f);
    check_frame(s, (int64_t)f + 1);
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  rp_context *ctx = fuzz_context();
  static int sentinel;
  rp_sequence *s = (rp_sequence *)&sentinel;
  int64_t i;

  rp__clear_error(ctx);
  if (!fuzz_loaded(ctx, rp_sequence_parse(ctx, (const char *)data, size,
                                          "fuzz.json", &s),
                   s, &sentinel))
    return 0;
  if (rp_sequence_frames(s) < 1 || rp_sequence_tf_count(s) < 1 ||
      rp_sequence_name(s) == NULL || rp_sequence_about(s) == NULL)
    abort();
  for (i = 0; i < 16; i++)
    check_frame(s, i);
  check_frame(s, (int64_t)rp_sequence_frames(s) - 1);
  check_track(s, s->keys, s->key_count, sizeof *s->keys);
  check_track(s, s->tf_steps, s->tf_step_count, sizeof *s->tf_steps);
  check_track(s, s->target_steps, s->target_step_count,
              sizeof *s->target_steps);
  check_track(s, s->effect_steps, s->effect_step_count,
              sizeof *s->effect_steps);
  rp_sequence_destroy(s);
  return 0;
}
