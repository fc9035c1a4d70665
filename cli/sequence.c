/* Interaction sequences, the raypace command's (docs/sequences.md): the
 * built-in sequences, and what a parsed sequence says about each frame.
 * A frame's state is a binary search in each track, so a replay may ask
 * for frames in any order at no cost per frame beyond that. The format
 * and its parser are cli/sequence_json.c. */
#include <math.h>
#include <string.h>

#include "raygen.h" /* RP__PARALLEL_EPS: the camera basis is raygen's */
#include "sequence_internal.h"

#define RP__SEQ_PI 3.14159265358979323846

/* ---- Built-in sequences -------------------------------------------------- */

/* Written in the file format and parsed by the same parser, so each is
 * also an example of it. Targets are fractions of the no-adaptation frame
 * time: they mean the same on any machine. */

static const char builtin_orbit[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"orbit\",\n"
    "  \"about\": \"slow full orbit (2 degrees a frame) at a fixed "
    "transfer function: the steady case\",\n"
    "  \"frames\": 180,\n"
    "  \"tfs\": [\"ct-bone\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 0, \"elevation\": 20, "
    "\"distance\": 2.5},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 179, \"camera\": {\"azimuth\": 358}}\n"
    "  ]\n"
    "}\n";

static const char builtin_tf_switch[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"tf-switch\",\n"
    "  \"about\": \"still camera, abrupt switches between a nearly "
    "transparent and an opaque transfer function every 20 frames\",\n"
    "  \"frames\": 160,\n"
    "  \"tfs\": [\"nearly-transparent\", \"opaque\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"comment\": \"the hard case for controllers that react to the "
    "last frame: its cost says nothing about the next one\",\n"
    "     \"camera\": {\"azimuth\": 30, \"elevation\": 20, "
    "\"distance\": 2.5},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 20, \"tf\": 1},\n"
    "    {\"frame\": 40, \"tf\": 0},\n"
    "    {\"frame\": 60, \"tf\": 1},\n"
    "    {\"frame\": 80, \"tf\": 0},\n"
    "    {\"frame\": 100, \"tf\": 1},\n"
    "    {\"frame\": 120, \"tf\": 0},\n"
    "    {\"frame\": 140, \"tf\": 1}\n"
    "  ]\n"
    "}\n";

static const char builtin_zoom_in[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"zoom-in\",\n"
    "  \"about\": \"zoom from far outside (4 radii) to inside the volume "
    "(0.3 radii), then hold\",\n"
    "  \"frames\": 150,\n"
    "  \"tfs\": [\"ct-bone\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 30, \"elevation\": 15, "
    "\"distance\": 4},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 15, \"camera\": {}},\n"
    "    {\"frame\": 135, \"camera\": {\"distance\": 0.3}}\n"
    "  ]\n"
    "}\n";

static const char builtin_mixed[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"mixed\",\n"
    "  \"about\": \"orbit with zoom and pan, transfer function switches, "
    "a tighter target and shading toggled on and off\",\n"
    "  \"frames\": 200,\n"
    "  \"tfs\": [\"ct-bone\", \"ct-soft\", \"opaque\", "
    "\"nearly-transparent\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 0, \"elevation\": 10, \"distance\": 3,\n"
    "                \"pan\": [0, 0], \"fov\": 40},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 40, \"tf\": 1},\n"
    "    {\"frame\": 60, \"effects\": [\"shading\", \"ert\", \"skip\"]},\n"
    "    {\"frame\": 80,\n"
    "     \"camera\": {\"azimuth\": 120, \"elevation\": 35, "
    "\"distance\": 1.8,\n"
    "                \"pan\": [0.2, -0.1]}},\n"
    "    {\"frame\": 100, \"tf\": 2, \"target_fraction\": 0.3},\n"
    "    {\"frame\": 120, \"tf\": 3},\n"
    "    {\"frame\": 140, \"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 160, \"tf\": 0,\n"
    "     \"camera\": {\"azimuth\": 200, \"elevation\": 10, "
    "\"distance\": 2.5,\n"
    "                \"pan\": [0, 0]}},\n"
    "    {\"frame\": 199, \"camera\": {\"azimuth\": 240, \"fov\": 30}}\n"
    "  ]\n"
    "}\n";

static const char builtin_ao_tf_switch[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"ao-tf-switch\",\n"
    "  \"about\": \"still camera with shading and ambient occlusion, "
    "switching between soft tissue and bone every 40 frames: each switch "
    "recomputes the AO volume\",\n"
    "  \"frames\": 160,\n"
    "  \"tfs\": [\"ct-soft\", \"ct-bone\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 30, \"elevation\": 20, "
    "\"distance\": 2.5},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"shading\", \"ao\", \"ert\", \"skip\"]},\n"
    "    {\"frame\": 40, \"tf\": 1},\n"
    "    {\"frame\": 80, \"tf\": 0},\n"
    "    {\"frame\": 120, \"tf\": 1}\n"
    "  ]\n"
    "}\n";

typedef struct builtin {
  const char *name;
  const char *about; /* equal to the document's "about" (tested) */
  const char *json;
} builtin;

static const builtin builtins[] = {
    {"orbit",
     "slow full orbit (2 degrees a frame) at a fixed transfer function: "
     "the steady case",
     builtin_orbit},
    {"tf-switch",
     "still camera, abrupt switches between a nearly transparent and an "
     "opaque transfer function every 20 frames",
     builtin_tf_switch},
    {"zoom-in",
     "zoom from far outside (4 radii) to inside the volume (0.3 radii), "
     "then hold",
     builtin_zoom_in},
    {"mixed",
     "orbit with zoom and pan, transfer function switches, a tighter "
     "target and shading toggled on and off",
     builtin_mixed},
    {"ao-tf-switch",
     "still camera with shading and ambient occlusion, switching between "
     "soft tissue and bone every 40 frames: each switch recomputes the AO "
     "volume",
     builtin_ao_tf_switch},
};

#define RP__SEQ_BUILTINS (sizeof builtins / sizeof builtins[0])

const char *const *rp_sequence_builtin_names(void) {
  static const char *const names[] = {"orbit", "tf-switch", "zoom-in",
                                      "mixed", "ao-tf-switch", NULL};
  return names;
}

static const builtin *find_builtin(const char *name) {
  size_t i;
  if (name == NULL)
    return NULL;
  for (i = 0; i < RP__SEQ_BUILTINS; i++)
    if (strcmp(builtins[i].name, name) == 0)
      return &builtins[i];
  return NULL;
}

const char *rp_sequence_builtin_about(const char *name) {
  const builtin *b = find_builtin(name);
  return b != NULL ? b->about : NULL;
}

const char *rp_sequence_builtin_json(const char *name) {
  const builtin *b = find_builtin(name);
  return b != NULL ? b->json : NULL;
}


/* ---- Queries ------------------------------------------------------------- */

uint32_t rp_sequence_frames(const rp_sequence *s) {
  return s != NULL ? s->frames : 0;
}

const char *rp_sequence_name(const rp_sequence *s) {
  return s != NULL ? s->name : NULL;
}

const char *rp_sequence_about(const rp_sequence *s) {
  return s != NULL ? s->about : NULL;
}

int rp_sequence_tf_count(const rp_sequence *s) {
  return s != NULL ? s->tf_count : 0;
}

/* Index of the last entry whose frame is <= i, or -1 when none is. The
 * entries are sorted by frame, which is their first member. */
static long find_last(const void *base, size_t n, size_t stride,
                      uint32_t i) {
  size_t lo = 0, hi = n;
  while (lo < hi) {
    size_t mid = lo + (hi - lo) / 2;
    uint32_t f;
    memcpy(&f, (const char *)base + mid * stride, sizeof f);
    if (f <= i)
      lo = mid + 1;
    else
      hi = mid;
  }
  return (long)lo - 1;
}

/* Exact at both ends, and a held value stays bit-identical between the
 * keys, so a hold never reports a camera change. */
static double lerp(double a, double b, double t) {
  return a == b ? a : (1.0 - t) * a + t * b;
}

static void resolve(const rp_sequence *s, uint32_t i, rp_sequence_state *st) {
  long k;
  memset(st, 0, sizeof *st);
  st->frame = i;
  st->projection = s->projection;

  st->distance = RP__SEQ_DEFAULT_DISTANCE;
  st->fov_y_deg = RP__SEQ_DEFAULT_FOV;
  if (s->key_count > 0) {
    const seq_key *a, *b;
    double t = 0.0;
    k = find_last(s->keys, s->key_count, sizeof *s->keys, i);
    /* Before the first keyframe and after the last the camera holds. */
    if (k < 0)
      a = b = &s->keys[0];
    else if ((size_t)k + 1 >= s->key_count)
      a = b = &s->keys[k];
    else {
      a = &s->keys[k];
      b = &s->keys[k + 1];
      t = (double)(i - a->frame) / (double)(b->frame - a->frame);
    }
    st->azimuth_deg = lerp(a->az, b->az, t);
    st->elevation_deg = lerp(a->el, b->el, t);
    st->distance = lerp(a->dist, b->dist, t);
    st->pan[0] = lerp(a->pan[0], b->pan[0], t);
    st->pan[1] = lerp(a->pan[1], b->pan[1], t);
    st->fov_y_deg = lerp(a->fov, b->fov, t);
  }

  k = find_last(s->tf_steps, s->tf_step_count, sizeof *s->tf_steps, i);
  st->tf = k >= 0 ? s->tf_steps[k].tf : 0;

  k = find_last(s->target_steps, s->target_step_count,
                sizeof *s->target_steps, i);
  if (k >= 0) {
    st->target_ms = s->target_steps[k].target_ms;
    st->target_fraction = s->target_steps[k].target_fraction;
  } else {
    st->target_fraction = RP__SEQ_DEFAULT_FRACTION;
  }

  k = find_last(s->effect_steps, s->effect_step_count,
                sizeof *s->effect_steps, i);
  st->effects = k >= 0 ? s->effect_steps[k].effects : 0;
}

int rp_sequence_frame(const rp_sequence *s, uint32_t i,
                      rp_sequence_state *st) {
  rp_sequence_state cur, prev;
  if (s == NULL || st == NULL)
    return s != NULL ? rp__fail(s->ctx, RP_EINVAL, "rp_sequence_frame: st "
                                "is required")
                     : RP_EINVAL;
  if (i >= s->frames)
    return rp__fail(s->ctx, RP_ERANGE, "sequence '%s': frame %u does not "
                    "exist (frames 0 to %u)", s->name, i, s->frames - 1);
  resolve(s, i, &cur);
  if (i == 0) {
    cur.camera_changed = cur.tf_changed = 1;
    cur.target_changed = cur.effects_changed = 1;
  } else {
    resolve(s, i - 1, &prev);
    cur.camera_changed = cur.azimuth_deg != prev.azimuth_deg ||
                         cur.elevation_deg != prev.elevation_deg ||
                         cur.distance != prev.distance ||
                         cur.pan[0] != prev.pan[0] ||
                         cur.pan[1] != prev.pan[1] ||
                         cur.fov_y_deg != prev.fov_y_deg;
    cur.tf_changed = cur.tf != prev.tf;
    cur.target_changed = cur.target_ms != prev.target_ms ||
                         cur.target_fraction != prev.target_fraction;
    cur.effects_changed = cur.effects != prev.effects;
  }
  *st = cur;
  return 0;
}

/* ---- Cameras ------------------------------------------------------------- */

static double norm3(const double v[3]) {
  return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

static void cross(const double a[3], const double b[3], double out[3]) {
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

void rp_sequence_camera(const rp_sequence_state *st, const rp_volume *vol,
                        rp_camera *cam) {
  double radius = 0.0, f[3], up[3] = {0.0, 1.0, 0.0}, r[3], u[3], len;
  rp_volume_info info;
  int a;
  if (st == NULL || vol == NULL || cam == NULL)
    return;
  rp_volume_get_info(vol, &info);
  memset(cam, 0, sizeof *cam);
  cam->projection = st->projection;
  cam->fov_y_deg = (float)st->fov_y_deg;
  rp_camera_orbit(cam, vol, (float)st->azimuth_deg,
                  (float)st->elevation_deg, (float)st->distance);
  for (a = 0; a < 3; a++) {
    double e = (double)info.dims[a] * info.spacing[a];
    radius += e * e;
  }
  radius = 0.5 * sqrt(radius); /* as rp_camera_orbit measures it */
  if (st->projection == RP_ORTHOGRAPHIC)
    cam->ortho_height = (float)(2.0 * st->distance * radius *
                                tan(0.5 * st->fov_y_deg * RP__SEQ_PI /
                                    180.0));
  if (st->pan[0] == 0.0 && st->pan[1] == 0.0)
    return;
  /* The basis rp__raygen_init builds for a zero up: right = f x up,
   * up' = right x f, with up = +y, or +z when f is parallel to y. Pan
   * moves eye and centre together, so f and this basis do not change. */
  for (a = 0; a < 3; a++)
    f[a] = -(double)cam->eye[a];
  len = norm3(f);
  if (len == 0.0) {
    f[0] = f[1] = 0.0;
    f[2] = -1.0;
  } else {
    for (a = 0; a < 3; a++)
      f[a] /= len;
  }
  cross(f, up, r);
  if (norm3(r) <= RP__PARALLEL_EPS) {
    up[1] = 0.0;
    up[2] = 1.0;
    cross(f, up, r);
  }
  len = norm3(r);
  for (a = 0; a < 3; a++)
    r[a] /= len;
  cross(r, f, u);
  for (a = 0; a < 3; a++) {
    double shift = (st->pan[0] * r[a] + st->pan[1] * u[a]) * radius;
    cam->eye[a] = (float)(cam->eye[a] + shift);
    cam->center[a] = (float)shift;
  }
}
