/* Interaction sequences: the JSON format of docs/sequences.md, parsed
 * with cJSON into the tracks of cli/sequence_internal.h and checked
 * completely at load time.
 *
 * cJSON allocates its parse tree through its own hooks, which are global
 * to the process; the tree lives only inside rp_sequence_parse. What the
 * sequence keeps goes through the context's allocator. */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cjson/cJSON.h>

#include "internal.h"
#include "sequence_internal.h"

#define RP__SEQ_MAX_FRAMES 10000000u /* about 46 hours at 60 Hz */
#define RP__SEQ_MAX_TFS 256
#define RP__SEQ_MAX_FILE ((size_t)64 << 20)
#define RP__SEQ_LIMIT 1e6 /* bound on angles */
/* Bound on distances and pans, in bounding radii: with both at it the eye
 * is sqrt(3) 1e4 radii from the volume, within the library's
 * RP_CAMERA_DISTANCE_MAX (1e4 diameters), so that no keyframe that parses
 * puts the eye where the library refuses it. (An orthographic view's
 * height, distance x tan(fov / 2) diameters, may still fall outside
 * RP_ORTHO_HEIGHT_MIN/MAX at the extremes; that frame fails, saying so.) */
#define RP__SEQ_MAX_RADII 1e4
#define RP__SEQ_MIN_DISTANCE 1e-4
#define RP__SEQ_PATH_MAX 160

/* ---- Messages ------------------------------------------------------------ */

typedef struct parser {
  rp_context *ctx;
  const char *name; /* how messages name the document */
  rp_sequence *s;
} parser;

static int fail(parser *p, int err, const char *path, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;

static int fail(parser *p, int err, const char *path, const char *fmt,
                ...) {
  char msg[RP__ERRMSG_MAX];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof msg, fmt, ap);
  va_end(ap);
  if (path == NULL || path[0] == '\0')
    return rp__fail(p->ctx, err, "sequence '%s': %s", p->name, msg);
  return rp__fail(p->ctx, err, "sequence '%s': %s: %s", p->name, path, msg);
}

/* Copies at most `max` bytes of user text for a message, control bytes
 * replaced by '?', "..." appended when cut. A cut never splits a UTF-8
 * sequence. */
static void sanitize(const char *src, size_t max, char *dst, size_t n) {
  size_t len = strlen(src), i, k = 0, take = len;
  if (take > max) {
    take = max;
    while (take > 0 && ((unsigned char)src[take] & 0xc0) == 0x80)
      take--;
  }
  for (i = 0; i < take && k + 4 < n; i++) {
    unsigned char c = (unsigned char)src[i];
    dst[k++] = c < 0x20 || c == 0x7f ? '?' : (char)c;
  }
  if (take < len && k + 4 < n) {
    memcpy(dst + k, "...", 3);
    k += 3;
  }
  dst[k] = '\0';
}

/* A JSON value as a message shows it: "abc" (quoted), 1.5, true, null, an
 * array, an object. */
static void describe(const cJSON *v, char *buf, size_t n) {
  char text[96];
  if (v == NULL) {
    snprintf(buf, n, "nothing");
  } else if (cJSON_IsString(v)) {
    sanitize(v->valuestring, 40, text, sizeof text);
    snprintf(buf, n, "\"%s\"", text);
  } else if (cJSON_IsNumber(v)) {
    snprintf(buf, n, "%.10g", v->valuedouble);
  } else if (cJSON_IsBool(v)) {
    snprintf(buf, n, "%s", cJSON_IsTrue(v) ? "true" : "false");
  } else if (cJSON_IsNull(v)) {
    snprintf(buf, n, "null");
  } else if (cJSON_IsArray(v)) {
    snprintf(buf, n, "an array");
  } else if (cJSON_IsObject(v)) {
    snprintf(buf, n, "an object");
  } else {
    snprintf(buf, n, "an invalid value");
  }
}

static int wrong_type(parser *p, const char *path, const char *expected,
                      const cJSON *v) {
  char got[128];
  describe(v, got, sizeof got);
  return fail(p, RP_EFORMAT, path, "expected %s, got %s", expected, got);
}

/* ---- Typed access -------------------------------------------------------- */

/* Rejects keys not in `known` (typos would otherwise be ignored silently)
 * and keys given twice (cJSON keeps both; only the first would count). */
static int check_keys(parser *p, const cJSON *obj, const char *path,
                      const char *const *known) {
  const cJSON *c;
  uint32_t seen = 0;
  cJSON_ArrayForEach(c, obj) {
    char key[96], list[256] = "";
    size_t used = 0;
    int i, found = -1;
    for (i = 0; known[i] != NULL; i++)
      if (strcmp(known[i], c->string) == 0)
        found = i;
    if (found >= 0 && (seen & (1u << found)) == 0) {
      seen |= 1u << found;
      continue;
    }
    sanitize(c->string, 40, key, sizeof key);
    if (found >= 0)
      return fail(p, RP_EFORMAT, path, "key \"%s\" appears twice", key);
    for (i = 0; known[i] != NULL && used < sizeof list; i++) {
      int w = snprintf(list + used, sizeof list - used, "%s%s",
                       i > 0 ? ", " : "", known[i]);
      if (w < 0)
        break;
      used += (size_t)w;
    }
    return fail(p, RP_EFORMAT, path, "unknown key \"%s\" (known: %s)", key,
                list);
  }
  return 0;
}

/* JSON paths for messages ("events[3].camera.azimuth"). The format nests
 * four levels at most, far below the buffer; a cut path would still be
 * a readable message. */
static void child_path(char *buf, const char *path, const char *key) {
  int w = path[0] == '\0' ? snprintf(buf, RP__SEQ_PATH_MAX, "%s", key)
                          : snprintf(buf, RP__SEQ_PATH_MAX, "%s.%s", path,
                                     key);
  if (w < 0)
    buf[0] = '\0';
}

static void index_path(char *buf, const char *path, size_t i) {
  if (snprintf(buf, RP__SEQ_PATH_MAX, "%s[%zu]", path, i) < 0)
    buf[0] = '\0';
}

static int want_number(parser *p, const cJSON *v, const char *path,
                       double *out) {
  if (!cJSON_IsNumber(v))
    return wrong_type(p, path, "a number", v);
  /* JSON has no NaN or infinity, but cJSON turns a literal too large for
   * a double (1e999) into one. */
  if (!isfinite(v->valuedouble))
    return fail(p, RP_ENOTFINITE, path, "the number is too large for a "
                "double (it reads as %s)",
                v->valuedouble > 0 ? "inf" : "-inf");
  *out = v->valuedouble;
  return 0;
}

static int want_integer(parser *p, const cJSON *v, const char *path,
                        double *out) {
  int err;
  if (!cJSON_IsNumber(v))
    return wrong_type(p, path, "an integer", v);
  if ((err = want_number(p, v, path, out)) != 0)
    return err;
  if (*out != floor(*out))
    return wrong_type(p, path, "an integer", v);
  return 0;
}

static int want_range(parser *p, const cJSON *v, const char *path,
                      double lo, double hi, const char *meaning,
                      double *out) {
  int err;
  if ((err = want_number(p, v, path, out)) != 0)
    return err;
  if (!(*out >= lo && *out <= hi))
    return fail(p, RP_ERANGE, path, "%.10g is outside [%g, %g] (%s)", *out,
                lo, hi, meaning);
  return 0;
}

/* A string copied to the context's allocator. */
static int want_string(parser *p, const cJSON *v, const char *path,
                       char **out) {
  size_t len;
  if (!cJSON_IsString(v))
    return wrong_type(p, path, "a string", v);
  len = strlen(v->valuestring);
  *out = rp__malloc(p->ctx, len + 1);
  if (*out == NULL)
    return fail(p, RP_ENOMEM, path, "out of memory");
  memcpy(*out, v->valuestring, len + 1);
  return 0;
}

/* ---- Transfer functions -------------------------------------------------- */

static int parse_preset(parser *p, const cJSON *v, const char *path,
                        seq_tf *tf) {
  const char *const *names = rp_tf_preset_names();
  char list[256] = "", got[128];
  size_t used = 0;
  int i;
  if (!cJSON_IsString(v))
    return wrong_type(p, path, "a preset name (a string)", v);
  for (i = 0; names[i] != NULL; i++)
    if (strcmp(names[i], v->valuestring) == 0)
      return want_string(p, v, path, &tf->preset);
  for (i = 0; names[i] != NULL && used < sizeof list; i++) {
    int w = snprintf(list + used, sizeof list - used, "%s%s",
                     i > 0 ? ", " : "", names[i]);
    if (w < 0)
      break;
    used += (size_t)w;
  }
  describe(v, got, sizeof got);
  return fail(p, RP_EINVAL, path, "unknown transfer function preset %s "
              "(known: %s)", got, list);
}

/* "points": [[x, r, g, b, a], ...]. Types and finiteness are checked here
 * with the JSON path; ranges and order are rp_tf_create's to judge. */
static int parse_points(parser *p, const cJSON *v, const char *path,
                        seq_tf *tf) {
  const cJSON *pt;
  char pp[RP__SEQ_PATH_MAX], cp[RP__SEQ_PATH_MAX];
  int n, i = 0, err;
  if (!cJSON_IsArray(v))
    return wrong_type(p, path, "an array of [x, r, g, b, a] points", v);
  n = cJSON_GetArraySize(v);
  if (n < 1)
    return fail(p, RP_EFORMAT, path, "empty; at least one point is "
                "needed");
  tf->points = rp__calloc(p->ctx, (size_t)n, sizeof *tf->points);
  if (tf->points == NULL)
    return fail(p, RP_ENOMEM, path, "out of memory");
  cJSON_ArrayForEach(pt, v) {
    const cJSON *c;
    float v5[5] = {0.0f, 0.0f, 0.0f, 0.0f, 0.0f};
    int k = 0;
    index_path(pp, path, (size_t)i);
    if (!cJSON_IsArray(pt) || cJSON_GetArraySize(pt) != 5)
      return wrong_type(p, pp, "an array of 5 numbers [x, r, g, b, a]",
                        pt);
    cJSON_ArrayForEach(c, pt) {
      double d = 0.0;
      index_path(cp, pp, (size_t)k);
      if ((err = want_number(p, c, cp, &d)) != 0)
        return err;
      /* rp_tf_create judges ranges, but a value beyond float's range
       * would become inf on the way there and be misreported. */
      if (fabs(d) > 1e30)
        return fail(p, RP_ERANGE, cp, "%.10g is outside [0, 1]", d);
      v5[k++] = (float)d;
    }
    tf->points[i].x = v5[0];
    tf->points[i].r = v5[1];
    tf->points[i].g = v5[2];
    tf->points[i].b = v5[3];
    tf->points[i].a = v5[4];
    i++;
  }
  tf->count = n;
  return 0;
}

static int build_tf(rp_context *ctx, const seq_tf *t, rp_tf **out) {
  rp_tf_desc d = {0};
  if (t->preset != NULL)
    return rp_tf_create_preset(ctx, t->preset, out);
  d.points = t->points;
  d.count = t->count;
  d.reference_step = t->reference_step;
  d.lut_size = t->lut_size;
  return rp_tf_create(ctx, &d, out);
}

int rp_sequence_tf_create(rp_context *ctx, const rp_sequence *s, int index,
                          rp_tf **out) {
  if (ctx == NULL)
    return RP_EINVAL;
  if (s == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_sequence_tf_create: s and out are "
                    "required");
  if (index < 0 || index >= s->tf_count)
    return rp__fail(ctx, RP_ERANGE, "sequence '%s': transfer function %d "
                    "does not exist (it has %d)", s->name, index,
                    s->tf_count);
  return build_tf(ctx, &s->tfs[index], out);
}

static int parse_tf(parser *p, const cJSON *v, const char *path,
                    seq_tf *tf) {
  static const char *const keys[] = {"preset", "points", "reference_step",
                                     "lut_size", "comment", NULL};
  const cJSON *preset, *points, *step, *lut;
  char cp[RP__SEQ_PATH_MAX];
  double d = 0.0;
  int err;
  if (cJSON_IsString(v))
    return parse_preset(p, v, path, tf);
  if (!cJSON_IsObject(v))
    return wrong_type(p, path, "a preset name or an object", v);
  if ((err = check_keys(p, v, path, keys)) != 0)
    return err;
  preset = cJSON_GetObjectItemCaseSensitive(v, "preset");
  points = cJSON_GetObjectItemCaseSensitive(v, "points");
  step = cJSON_GetObjectItemCaseSensitive(v, "reference_step");
  lut = cJSON_GetObjectItemCaseSensitive(v, "lut_size");
  if ((preset == NULL) == (points == NULL))
    return fail(p, RP_EFORMAT, path, "give exactly one of \"preset\" and "
                "\"points\"");
  if (preset != NULL) {
    if (step != NULL || lut != NULL)
      return fail(p, RP_EFORMAT, path, "\"reference_step\" and "
                  "\"lut_size\" apply to \"points\" only");
    child_path(cp, path, "preset");
    return parse_preset(p, preset, cp, tf);
  }
  child_path(cp, path, "points");
  if ((err = parse_points(p, points, cp, tf)) != 0)
    return err;
  if (step != NULL) {
    child_path(cp, path, "reference_step");
    if ((err = want_range(p, step, cp, RP_STEP_MIN, RP_STEP_MAX, "voxels",
                          &d)) != 0)
      return err;
    tf->reference_step = (float)d;
  }
  if (lut != NULL) {
    child_path(cp, path, "lut_size");
    if ((err = want_integer(p, lut, cp, &d)) != 0)
      return err;
    if (!(d >= 2 && d <= 65536))
      return fail(p, RP_ERANGE, cp, "%.10g is outside [2, 65536] (lookup "
                  "table entries)", d);
    tf->lut_size = (int)d;
  }
  return 0;
}

static int parse_tfs(parser *p, const cJSON *v) {
  rp_sequence *s = p->s;
  const cJSON *e;
  char path[RP__SEQ_PATH_MAX];
  int n, i = 0, err;
  if (!cJSON_IsArray(v))
    return wrong_type(p, "tfs", "an array of transfer functions", v);
  n = cJSON_GetArraySize(v);
  if (n < 1)
    return fail(p, RP_EFORMAT, "tfs", "empty; at least one transfer "
                "function is needed");
  if (n > RP__SEQ_MAX_TFS)
    return fail(p, RP_ERANGE, "tfs", "%d transfer functions; at most %d",
                n, RP__SEQ_MAX_TFS);
  s->tfs = rp__calloc(p->ctx, (size_t)n, sizeof *s->tfs);
  if (s->tfs == NULL)
    return fail(p, RP_ENOMEM, "tfs", "out of memory");
  s->tf_count = n;
  cJSON_ArrayForEach(e, v) {
    rp_tf *tf = NULL;
    index_path(path, "tfs", (size_t)i);
    if ((err = parse_tf(p, e, path, &s->tfs[i])) != 0)
      return err;
    /* Built once so that a replay cannot fail on it later; its own
     * message says which point and field, ours where it is. */
    err = build_tf(p->ctx, &s->tfs[i], &tf);
    rp_tf_destroy(tf);
    if (err != 0) {
      char inner[RP__ERRMSG_MAX];
      snprintf(inner, sizeof inner, "%s", rp_last_error(p->ctx));
      return fail(p, err, path, "%s", inner);
    }
    i++;
  }
  return 0;
}

/* ---- Events -------------------------------------------------------------- */

static const struct {
  const char *name;
  uint32_t bit;
} effect_names[] = {
    {"shading", RP_EFFECT_SHADING},
    {"ert", RP_EFFECT_ERT},
    {"skip", RP_EFFECT_SKIP},
    {"ao", RP_EFFECT_AO},
    {"preint", RP_EFFECT_PREINT},
};

#define RP__SEQ_EFFECTS (sizeof effect_names / sizeof effect_names[0])

static int parse_effects(parser *p, const cJSON *v, const char *path,
                         uint32_t *out) {
  const cJSON *e;
  char ep[RP__SEQ_PATH_MAX], got[128];
  size_t i = 0, k;
  *out = 0;
  if (!cJSON_IsArray(v))
    return wrong_type(p, path, "an array of effect names", v);
  cJSON_ArrayForEach(e, v) {
    index_path(ep, path, i++);
    if (!cJSON_IsString(e))
      return wrong_type(p, ep, "an effect name (a string)", e);
    for (k = 0; k < RP__SEQ_EFFECTS; k++)
      if (strcmp(effect_names[k].name, e->valuestring) == 0)
        break;
    describe(e, got, sizeof got);
    if (k == RP__SEQ_EFFECTS)
      return fail(p, RP_EINVAL, ep, "unknown effect %s (known: shading, "
                  "ert, skip, ao, preint)", got);
    if (*out & effect_names[k].bit)
      return fail(p, RP_EFORMAT, ep, "effect %s is listed twice", got);
    *out |= effect_names[k].bit;
  }
  return 0;
}

/* A camera keyframe: the fields given override `prev` (the previous
 * keyframe, or the defaults for the first). */
static int parse_camera(parser *p, const cJSON *v, const char *path,
                        const seq_key *prev, seq_key *key) {
  static const char *const keys[] = {"azimuth", "elevation", "distance",
                                     "pan", "fov", "cut", "comment", NULL};
  const cJSON *c;
  char cp[RP__SEQ_PATH_MAX], ip[RP__SEQ_PATH_MAX];
  int err;
  if (!cJSON_IsObject(v))
    return wrong_type(p, path, "a camera object", v);
  if ((err = check_keys(p, v, path, keys)) != 0)
    return err;
  *key = *prev;
  key->cut = 0;
  if ((c = cJSON_GetObjectItemCaseSensitive(v, "cut")) != NULL) {
    child_path(cp, path, "cut");
    if (!cJSON_IsBool(c))
      return wrong_type(p, cp, "true or false", c);
    /* A cut jumps from the previous keyframe; before the first one the
     * camera already holds still at it. */
    if (cJSON_IsTrue(c) && p->s->key_count == 0)
      return fail(p, RP_EFORMAT, cp, "a cut needs an earlier camera "
                  "keyframe to cut from");
    key->cut = cJSON_IsTrue(c);
  }
  if ((c = cJSON_GetObjectItemCaseSensitive(v, "azimuth")) != NULL) {
    child_path(cp, path, "azimuth");
    if ((err = want_range(p, c, cp, -RP__SEQ_LIMIT, RP__SEQ_LIMIT,
                          "degrees", &key->az)) != 0)
      return err;
  }
  if ((c = cJSON_GetObjectItemCaseSensitive(v, "elevation")) != NULL) {
    child_path(cp, path, "elevation");
    if ((err = want_range(p, c, cp, -90, 90, "degrees", &key->el)) != 0)
      return err;
  }
  if ((c = cJSON_GetObjectItemCaseSensitive(v, "distance")) != NULL) {
    child_path(cp, path, "distance");
    if ((err = want_range(p, c, cp, RP__SEQ_MIN_DISTANCE, RP__SEQ_MAX_RADII,
                          "bounding radii; must be > 0", &key->dist)) != 0)
      return err;
  }
  if ((c = cJSON_GetObjectItemCaseSensitive(v, "fov")) != NULL) {
    child_path(cp, path, "fov");
    if ((err = want_range(p, c, cp, RP_FOV_MIN_DEG, RP_FOV_MAX_DEG,
                          "vertical field of view, degrees; "
                          "RP_FOV_MIN_DEG/MAX_DEG", &key->fov)) != 0)
      return err;
  }
  if ((c = cJSON_GetObjectItemCaseSensitive(v, "pan")) != NULL) {
    const cJSON *e;
    int i = 0;
    child_path(cp, path, "pan");
    if (!cJSON_IsArray(c) || cJSON_GetArraySize(c) != 2)
      return wrong_type(p, cp, "an array of 2 numbers [right, up]", c);
    cJSON_ArrayForEach(e, c) {
      index_path(ip, cp, (size_t)i);
      if ((err = want_range(p, e, ip, -RP__SEQ_MAX_RADII, RP__SEQ_MAX_RADII,
                            "bounding radii", &key->pan[i])) != 0)
        return err;
      i++;
    }
  }
  return 0;
}

static int parse_target(parser *p, const cJSON *ms, const cJSON *frac,
                        const char *path, seq_step *st) {
  char cp[RP__SEQ_PATH_MAX];
  double *dst = ms != NULL ? &st->target_ms : &st->target_fraction;
  int err;
  if (ms != NULL && frac != NULL)
    return fail(p, RP_EFORMAT, path, "give \"target_ms\" or "
                "\"target_fraction\", not both");
  child_path(cp, path, ms != NULL ? "target_ms" : "target_fraction");
  if ((err = want_number(p, ms != NULL ? ms : frac, cp, dst)) != 0)
    return err;
  /* The runtime's target range (rp_runtime_desc.target_ms), and the
   * replay's --target-fraction's. */
  if (!(*dst > 0.0 && *dst <= (ms != NULL ? 60000.0 : 100.0)))
    return fail(p, RP_ERANGE, cp, "%.10g is outside (0, %g] (%s)", *dst,
                ms != NULL ? 60000.0 : 100.0,
                ms != NULL ? "milliseconds"
                           : "fraction of the no-adaptation frame time");
  return 0;
}

static int parse_frame(parser *p, const cJSON *v, const char *path,
                       int64_t prev, size_t prev_index, uint32_t *out) {
  char cp[RP__SEQ_PATH_MAX];
  double d = 0.0;
  int err;
  if (v == NULL)
    return fail(p, RP_EFORMAT, path, "missing required key \"frame\"");
  child_path(cp, path, "frame");
  if ((err = want_integer(p, v, cp, &d)) != 0)
    return err;
  if (d < 0)
    return fail(p, RP_ERANGE, cp, "frame %.10g is negative", d);
  if (d >= p->s->frames)
    return fail(p, RP_ERANGE, cp, "frame %.10g is beyond the last frame %u "
                "(\"frames\": %u)", d, p->s->frames - 1, p->s->frames);
  if ((int64_t)d <= prev)
    return fail(p, RP_EFORMAT, cp, "frame %.10g does not come after "
                "events[%zu].frame %lld (events must be in strictly "
                "increasing frame order)", d, prev_index, (long long)prev);
  *out = (uint32_t)d;
  return 0;
}

static int parse_events(parser *p, const cJSON *v) {
  static const char *const keys[] = {"frame", "camera", "tf", "target_ms",
                                     "target_fraction", "effects",
                                     "comment", NULL};
  rp_sequence *s = p->s;
  const cJSON *e;
  char path[RP__SEQ_PATH_MAX], cp[RP__SEQ_PATH_MAX];
  seq_key defaults = {0};
  int64_t prev = -1;
  size_t n, i = 0;
  int err;
  if (!cJSON_IsArray(v))
    return wrong_type(p, "events", "an array of events", v);
  n = (size_t)cJSON_GetArraySize(v);
  if (n == 0)
    return fail(p, RP_EFORMAT, "events", "empty; a sequence needs at "
                "least one event");
  s->keys = rp__calloc(p->ctx, n, sizeof *s->keys);
  s->tf_steps = rp__calloc(p->ctx, n, sizeof *s->tf_steps);
  s->target_steps = rp__calloc(p->ctx, n, sizeof *s->target_steps);
  s->effect_steps = rp__calloc(p->ctx, n, sizeof *s->effect_steps);
  if (s->keys == NULL || s->tf_steps == NULL || s->target_steps == NULL ||
      s->effect_steps == NULL)
    return fail(p, RP_ENOMEM, "events", "out of memory");
  defaults.dist = RP__SEQ_DEFAULT_DISTANCE;
  defaults.fov = RP__SEQ_DEFAULT_FOV;
  cJSON_ArrayForEach(e, v) {
    const cJSON *cam, *tf, *ms, *frac, *fx;
    uint32_t frame = 0;
    index_path(path, "events", i);
    if (!cJSON_IsObject(e))
      return wrong_type(p, path, "an event object", e);
    if ((err = check_keys(p, e, path, keys)) != 0 ||
        (err = parse_frame(p, cJSON_GetObjectItemCaseSensitive(e, "frame"),
                           path, prev, i > 0 ? i - 1 : 0, &frame)) != 0)
      return err;
    prev = frame;
    cam = cJSON_GetObjectItemCaseSensitive(e, "camera");
    tf = cJSON_GetObjectItemCaseSensitive(e, "tf");
    ms = cJSON_GetObjectItemCaseSensitive(e, "target_ms");
    frac = cJSON_GetObjectItemCaseSensitive(e, "target_fraction");
    fx = cJSON_GetObjectItemCaseSensitive(e, "effects");
    if (cam == NULL && tf == NULL && ms == NULL && frac == NULL &&
        fx == NULL)
      return fail(p, RP_EFORMAT, path, "changes nothing (give \"camera\", "
                  "\"tf\", \"target_ms\", \"target_fraction\" or "
                  "\"effects\")");
    if (cam != NULL) {
      seq_key *k = &s->keys[s->key_count];
      const seq_key *before =
          s->key_count > 0 ? &s->keys[s->key_count - 1] : &defaults;
      child_path(cp, path, "camera");
      if ((err = parse_camera(p, cam, cp, before, k)) != 0)
        return err;
      k->frame = frame;
      s->key_count++;
    }
    if (tf != NULL) {
      double d = 0.0;
      seq_step *st = &s->tf_steps[s->tf_step_count];
      child_path(cp, path, "tf");
      if ((err = want_integer(p, tf, cp, &d)) != 0)
        return err;
      if (!(d >= 0 && d < s->tf_count))
        return fail(p, RP_ERANGE, cp, "index %.10g is out of range (\"tfs\" "
                    "has %d: 0 to %d)", d, s->tf_count, s->tf_count - 1);
      st->frame = frame;
      st->tf = (int)d;
      s->tf_step_count++;
    }
    if (ms != NULL || frac != NULL) {
      seq_step *st = &s->target_steps[s->target_step_count];
      if ((err = parse_target(p, ms, frac, path, st)) != 0)
        return err;
      st->frame = frame;
      s->target_step_count++;
    }
    if (fx != NULL) {
      seq_step *st = &s->effect_steps[s->effect_step_count];
      child_path(cp, path, "effects");
      if ((err = parse_effects(p, fx, cp, &st->effects)) != 0)
        return err;
      st->frame = frame;
      s->effect_step_count++;
    }
    i++;
  }
  return 0;
}

/* ---- Document ------------------------------------------------------------ */

static int parse_document(parser *p, const cJSON *root) {
  static const char *const keys[] = {"version", "name", "about", "frames",
                                     "projection", "tfs", "events",
                                     "comment", NULL};
  rp_sequence *s = p->s;
  const cJSON *v;
  double d = 0.0;
  int err;
  if (!cJSON_IsObject(root))
    return wrong_type(p, "", "an object at the top level", root);
  if ((err = check_keys(p, root, "", keys)) != 0)
    return err;
  if ((v = cJSON_GetObjectItemCaseSensitive(root, "version")) != NULL) {
    if ((err = want_integer(p, v, "version", &d)) != 0)
      return err;
    if (d != 1)
      return fail(p, RP_EUNSUPPORTED, "version", "%.10g is not supported "
                  "(raypace reads version 1)", d);
  }
  if ((v = cJSON_GetObjectItemCaseSensitive(root, "name")) != NULL &&
      (err = want_string(p, v, "name", &s->name)) != 0)
    return err;
  if ((v = cJSON_GetObjectItemCaseSensitive(root, "about")) != NULL &&
      (err = want_string(p, v, "about", &s->about)) != 0)
    return err;
  if ((v = cJSON_GetObjectItemCaseSensitive(root, "frames")) == NULL)
    return fail(p, RP_EFORMAT, "", "missing required key \"frames\" (the "
                "number of frames)");
  if ((err = want_integer(p, v, "frames", &d)) != 0)
    return err;
  if (!(d >= 1 && d <= RP__SEQ_MAX_FRAMES))
    return fail(p, RP_ERANGE, "frames", "%.10g is outside [1, %u]%s", d,
                RP__SEQ_MAX_FRAMES, d < 1 ? " (an empty sequence)" : "");
  s->frames = (uint32_t)d;
  s->projection = RP_PERSPECTIVE;
  if ((v = cJSON_GetObjectItemCaseSensitive(root, "projection")) != NULL) {
    char got[128];
    if (!cJSON_IsString(v))
      return wrong_type(p, "projection", "a string", v);
    describe(v, got, sizeof got);
    if (strcmp(v->valuestring, "orthographic") == 0)
      s->projection = RP_ORTHOGRAPHIC;
    else if (strcmp(v->valuestring, "perspective") != 0)
      return fail(p, RP_EINVAL, "projection", "unknown projection %s "
                  "(known: perspective, orthographic)", got);
  }
  if ((v = cJSON_GetObjectItemCaseSensitive(root, "tfs")) == NULL)
    return fail(p, RP_EFORMAT, "", "missing required key \"tfs\" (the "
                "transfer functions)");
  if ((err = parse_tfs(p, v)) != 0)
    return err;
  if ((v = cJSON_GetObjectItemCaseSensitive(root, "events")) == NULL)
    return fail(p, RP_EFORMAT, "", "missing required key \"events\"");
  return parse_events(p, v);
}

static void sequence_free(rp_sequence *s) {
  int i;
  if (s == NULL)
    return;
  for (i = 0; s->tfs != NULL && i < s->tf_count; i++) {
    rp__free(s->ctx, s->tfs[i].preset);
    rp__free(s->ctx, s->tfs[i].points);
  }
  rp__free(s->ctx, s->tfs);
  rp__free(s->ctx, s->keys);
  rp__free(s->ctx, s->tf_steps);
  rp__free(s->ctx, s->target_steps);
  rp__free(s->ctx, s->effect_steps);
  rp__free(s->ctx, s->name);
  rp__free(s->ctx, s->about);
  rp__free(s->ctx, s);
}

void rp_sequence_destroy(rp_sequence *s) { sequence_free(s); }

/* Line and column (1-based, bytes) of offset `off` in `text`. */
static void line_col(const char *text, size_t off, size_t *line,
                     size_t *col) {
  size_t i;
  *line = 1;
  *col = 1;
  for (i = 0; i < off; i++) {
    if (text[i] == '\n') {
      (*line)++;
      *col = 1;
    } else {
      (*col)++;
    }
  }
}

static int not_json(parser *p, const char *text, size_t len,
                    const char *end) {
  size_t off = end != NULL && end >= text ? (size_t)(end - text) : len;
  size_t line, col;
  char raw[26] = "", near[96];
  size_t k = 0;
  if (off > len)
    off = len;
  line_col(text, off, &line, &col);
  if (off >= len)
    return fail(p, RP_EFORMAT, NULL, "not valid JSON: unexpected end of "
                "input at line %zu, column %zu", line, col);
  /* cJSON reports some errors one byte into the bad token (a bare word
   * where a key belongs): back up to the token's start, so that the
   * column points at it. */
  while (off > 0 && strchr(" \t\r\n{}[],:\"", text[off - 1]) == NULL) {
    off--;
    col--;
  }
  /* Show the rest of the line only. */
  while (k + 1 < sizeof raw && text[off + k] != '\0' &&
         text[off + k] != '\n' && text[off + k] != '\r')
    k++;
  memcpy(raw, text + off, k);
  raw[k] = '\0';
  sanitize(raw, 24, near, sizeof near);
  return fail(p, RP_EFORMAT, NULL, "not valid JSON at line %zu, column %zu "
              "(near '%s')", line, col, near);
}

int rp_sequence_parse(rp_context *ctx, const char *json, size_t len,
                      const char *name_for_errors, rp_sequence **out) {
  parser p;
  rp_sequence *s;
  cJSON *root;
  const char *end = NULL, *text;
  char *copy;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  p.ctx = ctx;
  p.name = name_for_errors != NULL ? name_for_errors : "<memory>";
  p.s = NULL;
  if (json == NULL || out == NULL)
    return fail(&p, RP_EINVAL, NULL, "rp_sequence_parse: json and out are "
                "required");
  if (len == 0)
    return fail(&p, RP_EFORMAT, NULL, "empty document");
  if (memchr(json, '\0', len) != NULL)
    return fail(&p, RP_EFORMAT, NULL, "NUL byte at offset %zu (not JSON "
                "text)", (size_t)((const char *)memchr(json, '\0', len) -
                                  json));
  /* cJSON wants the terminator inside the length to reject trailing
   * garbage; the caller's buffer need not have one. */
  copy = rp__malloc(ctx, len + 1);
  if (copy == NULL)
    return fail(&p, RP_ENOMEM, NULL, "out of memory");
  memcpy(copy, json, len);
  copy[len] = '\0';
  text = copy;
  if (len >= 3 && memcmp(text, "\xef\xbb\xbf", 3) == 0)
    text += 3; /* a UTF-8 byte order mark, as some editors write */
  root = cJSON_ParseWithLengthOpts(text, len + 1 - (size_t)(text - copy),
                                   &end, 1);
  if (root == NULL) {
    err = not_json(&p, text, len - (size_t)(text - copy), end);
    rp__free(ctx, copy);
    return err;
  }
  rp__free(ctx, copy);
  s = rp__calloc(ctx, 1, sizeof *s);
  if (s == NULL) {
    cJSON_Delete(root);
    return fail(&p, RP_ENOMEM, NULL, "out of memory");
  }
  s->ctx = ctx;
  p.s = s;
  err = parse_document(&p, root);
  cJSON_Delete(root);
  if (err == 0 && s->name == NULL) {
    size_t n = strlen(p.name);
    s->name = rp__malloc(ctx, n + 1);
    if (s->name == NULL)
      err = fail(&p, RP_ENOMEM, NULL, "out of memory");
    else
      memcpy(s->name, p.name, n + 1);
  }
  if (err == 0 && s->about == NULL) {
    s->about = rp__calloc(ctx, 1, 1);
    if (s->about == NULL)
      err = fail(&p, RP_ENOMEM, NULL, "out of memory");
  }
  if (err != 0) {
    sequence_free(s);
    return err;
  }
  *out = s;
  return 0;
}

/* ---- Files --------------------------------------------------------------- */

static int builtin_list(char *buf, size_t n) {
  const char *const *names = rp_sequence_builtin_names();
  size_t i, used = 0;
  buf[0] = '\0';
  for (i = 0; names[i] != NULL && used < n; i++) {
    int w = snprintf(buf + used, n - used, "%s%s", i > 0 ? ", " : "",
                     names[i]);
    if (w < 0)
      return -1;
    used += (size_t)w;
  }
  return 0;
}

/* Reads a whole regular file. A FIFO would block in open() and a device
 * may act on being opened, so the type is checked first, and again on
 * the descriptor in case the path changed in between. */
static int read_file(parser *p, const char *path, char **buf, size_t *len) {
  struct stat st;
  size_t got = 0, size;
  char *data;
  int fd, err;
  if (stat(path, &st) != 0) {
    char list[256];
    err = errno;
    if (err != ENOENT && err != ENOTDIR)
      return fail(p, RP_EIO, NULL, "cannot stat: %s", strerror(err));
    builtin_list(list, sizeof list);
    return fail(p, RP_ENOENT, NULL, "no such file, and not a built-in "
                "sequence (built-ins: %s)", list);
  }
  if (!S_ISREG(st.st_mode))
    return fail(p, RP_EIO, NULL, "not a regular file");
  fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    err = errno;
    return fail(p, err == ENOENT ? RP_ENOENT : RP_EIO, NULL,
                "cannot open: %s", strerror(err));
  }
  if (fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    close(fd);
    return fail(p, RP_EIO, NULL, "not a regular file");
  }
  if ((uint64_t)st.st_size > RP__SEQ_MAX_FILE) {
    close(fd);
    return fail(p, RP_ERANGE, NULL, "the file has %lld bytes; sequences "
                "are limited to %zu", (long long)st.st_size,
                RP__SEQ_MAX_FILE);
  }
  size = (size_t)st.st_size;
  data = rp__malloc(p->ctx, size + 1);
  if (data == NULL) {
    close(fd);
    return fail(p, RP_ENOMEM, NULL, "out of memory");
  }
  while (got < size) {
    ssize_t r = read(fd, data + got, size - got);
    if (r < 0 && errno == EINTR)
      continue;
    if (r < 0) {
      err = errno;
      close(fd);
      rp__free(p->ctx, data);
      return fail(p, RP_EIO, NULL, "read failed: %s", strerror(err));
    }
    if (r == 0)
      break; /* the file shrank: parse what is there */
    got += (size_t)r;
  }
  close(fd);
  *buf = data;
  *len = got;
  return 0;
}

int rp_sequence_load(rp_context *ctx, const char *name_or_path,
                     rp_sequence **out) {
  const char *json = rp_sequence_builtin_json(name_or_path);
  parser p;
  char *buf = NULL;
  size_t len = 0;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (name_or_path == NULL || out == NULL || name_or_path[0] == '\0')
    return rp__fail(ctx, RP_EINVAL, "rp_sequence_load: a built-in name or "
                    "a path, and out, are required");
  if (json != NULL)
    return rp_sequence_parse(ctx, json, strlen(json), name_or_path, out);
  p.ctx = ctx;
  p.name = name_or_path;
  p.s = NULL;
  if ((err = read_file(&p, name_or_path, &buf, &len)) != 0)
    return err;
  err = rp_sequence_parse(ctx, buf, len, name_or_path, out);
  rp__free(ctx, buf);
  return err;
}

