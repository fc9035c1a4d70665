/* raypace sequences: scripted interaction, replayed frame by frame.
 *
 * Not part of the library (README, "Headers"): the format belongs to the
 * raypace command that plays it. cli/sequence.c and cli/sequence_json.c
 * build it as the static library raypace_seq, which the command, its
 * tests and the benchmarks link; it parses with cJSON, which the library
 * itself does not need. An app scripts its interaction its own way
 * (samples/embed_uv.c).
 *
 * A sequence is a JSON document (docs/sequences.md) that says, for every
 * frame of a fixed count, where the camera is, which transfer function is
 * active, which frame-time target holds and which effects are on. Camera
 * keyframes interpolate linearly; transfer function, target and effect
 * changes are steps that hold until the next change. A replay asks for
 * the resolved state of each frame with rp_sequence_frame and renders it.
 *
 * Sequences come from a file or from the built-in set, which is written
 * in the same format and parsed by the same parser. Everything is checked
 * at load time, every transfer function included (each is built once),
 * so a loaded sequence cannot fail half-way through a replay.
 *
 * Errors: RP_EFORMAT for input that is not JSON or does not have the
 * format's shape (wrong type, missing or unknown key, frames out of
 * order), RP_ERANGE for a number outside its range, RP_ENOTFINITE for a
 * number too large for a double, RP_EINVAL for an unknown name (preset,
 * effect, projection), RP_EUNSUPPORTED for a format version other than 1,
 * RP_ENOENT / RP_EIO for files. The message
 * (rp_last_error) names the sequence, the JSON path and the bad value:
 *   sequence 'a.json': events[3].camera.azimuth: expected a number,
 *   got "abc"
 *
 * Threading: a sequence is immutable once loaded; it belongs to the thread
 * that uses its context, like every other object made from a context. */
#ifndef RAYPACE_SEQUENCE_H
#define RAYPACE_SEQUENCE_H

#include <stddef.h>
#include <stdint.h>

#include "raypace.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct rp_sequence rp_sequence;

/* A camera cut, when no keyframe marks one: from one frame to the next,
 * the view direction turns by more than RP_SEQUENCE_CUT_ANGLE_DEG, the
 * distance or the field of view changes by more than a factor of
 * RP_SEQUENCE_CUT_RATIO (either way), or the pan moves by more than
 * RP_SEQUENCE_CUT_PAN bounding radii. Smooth interaction stays well
 * under each: a fast drag at 60 Hz turns a few degrees a frame, a zoom
 * changes the distance by a few percent. */
#define RP_SEQUENCE_CUT_ANGLE_DEG 15.0
#define RP_SEQUENCE_CUT_RATIO 1.25
#define RP_SEQUENCE_CUT_PAN 0.25

/** The resolved state of one frame. Angles in degrees, lengths in
 *  bounding-sphere radii of the volume (the units of rp_camera_orbit). */
typedef struct rp_sequence_state {
  uint32_t frame;
  rp_projection projection; /* the sequence's; the same on every frame */
  /* Camera: an orbit around the volume centre (rp_camera_orbit), then
   * eye and look-at point moved together by pan[0] radii along the
   * camera's right and pan[1] along its up. */
  double azimuth_deg;
  double elevation_deg;
  double distance;
  double pan[2];
  double fov_y_deg;
  int camera_changed; /* 1 on frame 0 and when any camera value differs
                         from the previous frame's */
  int camera_cut;     /* 1 when the camera jumps rather than moves: a
                         keyframe marked "cut", or a change from the
                         previous frame beyond what smooth motion makes
                         (RP_SEQUENCE_CUT_*; docs/sequences.md); 0 on
                         frame 0, which has no frame before it */
  int tf;             /* index of the active transfer function, in
                         [0, rp_sequence_tf_count()) */
  int tf_changed;     /* 1 on frame 0 and when tf differs from the
                         previous frame's */
  /* Exactly one of the two targets is > 0; the other is 0. target_ms is
   * absolute. target_fraction is relative to the frame time without
   * adaptation (the replay measures it at the start), which makes one
   * sequence meaningful on any machine. */
  double target_ms;
  double target_fraction;
  int target_changed; /* 1 on frame 0 and when the target changes */
  uint32_t effects;   /* RP_EFFECT_* bits */
  int effects_changed; /* 1 on frame 0 and when the set changes */
} rp_sequence_state;

/** Loads a sequence: a built-in name (rp_sequence_builtin_names) or else
 *  the path of a JSON file. A built-in name wins over a file of the same
 *  name; write "./orbit" for the file.
 *  \param ctx the context that owns the sequence and records errors.
 *  \param name_or_path built-in name or file path.
 *  \param out receives the sequence; untouched on failure.
 *  \returns 0, RP_ENOENT (neither a built-in nor a file; the message
 *  lists the built-ins), RP_EIO, RP_EFORMAT, RP_ERANGE, RP_ENOTFINITE,
 *  RP_EINVAL, RP_EUNSUPPORTED or RP_ENOMEM.
 *  \threadsafety like its context.
 *  \since 0.1 */
int rp_sequence_load(rp_context *ctx, const char *name_or_path,
                     rp_sequence **out);

/** Parses a sequence from memory (`len` bytes of UTF-8 JSON; no NUL
 *  terminator needed, and none allowed inside).
 *  \param name_for_errors how messages name the document, and the
 *  sequence's name when the document has no "name"; NULL: "<memory>".
 *  \returns as rp_sequence_load, without the file errors.
 *  \threadsafety like its context.
 *  \since 0.1 */
int rp_sequence_parse(rp_context *ctx, const char *json, size_t len,
                      const char *name_for_errors,
                      rp_sequence **out);

/** Destroys a sequence; NULL is a no-op. \since 0.1 */
void rp_sequence_destroy(rp_sequence *s);

/** The built-in sequence names, NULL-terminated: "orbit", "tf-switch",
 *  "zoom-in", "mixed", "ao-tf-switch", "tf-window", "head-motion",
 *  "cut-switch", "target-steps", "effects-motion". \threadsafety any
 *  thread.
 *  \since 0.1 */
const char *const *rp_sequence_builtin_names(void);

/** One line about a built-in sequence, or NULL for an unknown name.
 *  \threadsafety any thread. \since 0.1 */
const char *rp_sequence_builtin_about(const char *name);

/** The JSON text of a built-in sequence (an example of the format), or
 *  NULL for an unknown name. \threadsafety any thread. \since 0.1 */
const char *rp_sequence_builtin_json(const char *name);

/** Number of frames; 0 for NULL. \since 0.1 */
uint32_t rp_sequence_frames(const rp_sequence *s);

/** The document's "name", else the name it was loaded under (built-in
 *  name, path, or name_for_errors). Owned by the sequence. \since 0.1 */
const char *rp_sequence_name(const rp_sequence *s);

/** The document's "about" line, "" when absent. \since 0.1 */
const char *rp_sequence_about(const rp_sequence *s);

/** The resolved state of frame `i` (0-based).
 *  \returns 0, RP_EINVAL (NULL argument) or RP_ERANGE (i >= frames).
 *  \since 0.1 */
int rp_sequence_frame(const rp_sequence *s, uint32_t i,
                      rp_sequence_state *st);

/** Number of transfer functions the sequence defines (>= 1; 0 for NULL).
 *  \since 0.1 */
int rp_sequence_tf_count(const rp_sequence *s);

/** Builds transfer function `index` (a preset or control points) as a
 *  new rp_tf on `ctx`; the caller destroys it.
 *  \returns 0, RP_EINVAL, RP_ERANGE (index out of range) or RP_ENOMEM.
 *  \since 0.1 */
int rp_sequence_tf_create(rp_context *ctx, const rp_sequence *s,
                          int index, rp_tf **out);

/** Fills in every field of `cam` for a frame's state and a volume:
 *  rp_camera_orbit with the state's azimuth, elevation and distance, then
 *  eye and centre shifted by pan times the bounding radius along the
 *  camera's right and up. The fov is the state's; an orthographic camera
 *  sees the height a perspective one would at the centre:
 *  ortho_height = 2 * distance * radius * tan(fov / 2). Up is left zero
 *  (the default, which pan does not change). NULL arguments: no-op.
 *  \since 0.1 */
void rp_sequence_camera(const rp_sequence_state *st,
                        const rp_volume *vol, rp_camera *cam);

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_SEQUENCE_H */
