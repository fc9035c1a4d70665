/* Transfer functions from text files: control points "x r g b a", one per
 * line, with optional "key: value" lines for the units, the range and the
 * reference step. A file is small and read whole; every error names the
 * file, the line and what was found there. */
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "volume_io.h"

#define RP__TF_FILE_MAX (1 << 20)
#define RP__TF_POINTS_MAX 65536

typedef struct tf_parse {
  rp_context *ctx;
  const char *path;
  int line;
  rp_tf_desc desc;
  rp_tf_point *points;
  int cap;
} tf_parse;

/* Reads up to `max` numbers separated by blanks or commas (rp__text_double:
 * '.' whatever the locale; NaN and infinities pass, for rp_tf_create to
 * refuse by point and field); returns how many, or -1 when a token is not
 * a number or there are more than `max`. */
static int numbers(char *s, double *out, int max) {
  int n = 0;
  for (;;) {
    char *tok;
    while (isspace((unsigned char)*s) || *s == ',')
      s++;
    if (*s == '\0')
      return n;
    if (n == max)
      return -1;
    tok = s;
    while (*s != '\0' && !isspace((unsigned char)*s) && *s != ',')
      s++;
    if (*s != '\0')
      *s++ = '\0';
    if (!rp__text_double(tok, &out[n]))
      return -1;
    n++;
  }
}

static int bad(tf_parse *p, int err, const char *what, const char *text) {
  return rp__fail(p->ctx, err, "%s: line %d: %s: '%s'", p->path, p->line,
                  what, text);
}

static int parse_key(tf_parse *p, const char *key, char *value) {
  double v[2];
  if (strcmp(key, "units") == 0) {
    if (strcmp(value, "data") == 0)
      p->desc.units = RP_TF_DATA;
    else if (strcmp(value, "normalised") == 0 ||
             strcmp(value, "normalized") == 0)
      p->desc.units = RP_TF_NORMALISED;
    else
      return bad(p, RP_EINVAL, "units must be 'data' or 'normalised'",
                 value);
    return 0;
  }
  if (strcmp(key, "reference_step") == 0) {
    if (numbers(value, v, 1) != 1)
      return bad(p, RP_EFORMAT, "reference_step takes one number", value);
    p->desc.reference_step = (float)v[0];
    return 0;
  }
  if (strcmp(key, "range") == 0) {
    char *rest = value + strcspn(value, " \t");
    size_t word = (size_t)(rest - value);
    if (word == 6 && strncmp(value, "minmax", 6) == 0 && *rp__text_trim(rest) == 0) {
      p->desc.range = RP_TF_RANGE_MINMAX;
      return 0;
    }
    if (numbers(rest, v, 2) != 2)
      return bad(p, RP_EFORMAT, "range is 'minmax', 'percentiles LO HI' or "
                 "'window WIDTH LEVEL'", value);
    if (word == 11 && strncmp(value, "percentiles", 11) == 0) {
      p->desc.range = RP_TF_RANGE_PERCENTILES;
      p->desc.range_lo = v[0], p->desc.range_hi = v[1];
      return 0;
    }
    if (word == 6 && strncmp(value, "window", 6) == 0) {
      if (!(v[0] > 0.0))
        return bad(p, RP_ERANGE, "the window's width must be > 0", value);
      if (!(fabs(v[1]) + v[0] / 2.0 <= 1e30)) /* rp_tf_create's bound */
        return bad(p, RP_ERANGE, "the window's ends must lie within "
                   "[-1e30, 1e30]", value);
      p->desc.range = RP_TF_RANGE_DATA;
      p->desc.range_lo = v[1] - v[0] / 2.0;
      p->desc.range_hi = v[1] + v[0] / 2.0;
      return 0;
    }
    return bad(p, RP_EFORMAT, "range is 'minmax', 'percentiles LO HI' or "
               "'window WIDTH LEVEL'", value);
  }
  return bad(p, RP_EFORMAT, "unknown key (known: units, range, "
             "reference_step)", key);
}

static int parse_point(tf_parse *p, char *text) {
  double v[5];
  if (numbers(text, v, 5) != 5)
    return bad(p, RP_EFORMAT, "a control point is five numbers 'x r g b a'",
               text);
  if (p->desc.count == RP__TF_POINTS_MAX)
    return bad(p, RP_ERANGE, "more than 65536 control points", text);
  if (p->desc.count == p->cap) {
    int cap = p->cap != 0 ? 2 * p->cap : 16;
    rp_tf_point *n = rp__malloc(p->ctx, (size_t)cap * sizeof *n);
    if (n == NULL)
      return rp__fail(p->ctx, RP_ENOMEM, "%s: out of memory", p->path);
    if (p->points != NULL)
      memcpy(n, p->points, (size_t)p->desc.count * sizeof *n);
    rp__free(p->ctx, p->points);
    p->points = n, p->cap = cap;
  }
  p->points[p->desc.count++] = (rp_tf_point){(float)v[0], (float)v[1],
                                             (float)v[2], (float)v[3],
                                             (float)v[4]};
  return 0;
}

static int parse(tf_parse *p, char *text) {
  char *line = text, *next;
  int err = 0;
  for (; line != NULL && err == 0; line = next) {
    char *colon, *s;
    next = strchr(line, '\n');
    if (next != NULL)
      *next++ = '\0';
    p->line++;
    if ((s = strchr(line, '#')) != NULL)
      *s = '\0';
    s = rp__text_trim(line);
    if (*s == '\0')
      continue;
    colon = strchr(s, ':');
    if (colon != NULL) {
      *colon = '\0';
      err = parse_key(p, rp__text_trim(s), rp__text_trim(colon + 1));
    } else {
      err = parse_point(p, s);
    }
  }
  if (err == 0 && p->desc.count == 0)
    err = rp__fail(p->ctx, RP_EFORMAT, "%s: no control points (lines 'x r "
                   "g b a')", p->path);
  return err;
}

/* The file whole, at most RP__TF_FILE_MAX bytes, into *out (the caller
 * frees it) and its length into *len. */
static int read_all(rp_context *ctx, const char *path, char **out,
                    size_t *len) {
  uint64_t size = 0;
  int rc = 0;
  FILE *f = rp__open_regular(ctx, path, NULL, &size, &rc);
  char *buf;
  if (f == NULL)
    return rc;
  if (size > RP__TF_FILE_MAX) {
    fclose(f);
    return rp__fail(ctx, RP_ERANGE, "%s: %llu bytes; a transfer function "
                    "file is at most %d", path, (unsigned long long)size,
                    RP__TF_FILE_MAX);
  }
  buf = rp__malloc(ctx, (size_t)size + 1);
  if (buf == NULL) {
    fclose(f);
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory", path);
  }
  *len = fread(buf, 1, (size_t)size, f);
  fclose(f);
  *out = buf;
  return 0;
}

int rp__tf_parse(rp_context *ctx, const char *name, const char *buf,
                 size_t len, rp_tf **out) {
  tf_parse p;
  char *text;
  int err;
  if (len > RP__TF_FILE_MAX)
    return rp__fail(ctx, RP_ERANGE, "%s: %zu bytes; a transfer function "
                    "file is at most %d", name, len, RP__TF_FILE_MAX);
  if (len > 0 && memchr(buf, '\0', len) != NULL)
    return rp__fail(ctx, RP_EFORMAT, "%s: binary data (a NUL byte); a "
                    "transfer function file is text", name);
  /* The parser cuts lines and tokens in place. */
  if ((text = rp__malloc(ctx, len + 1)) == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory", name);
  if (len > 0) /* buf may be NULL then */
    memcpy(text, buf, len);
  text[len] = '\0';
  memset(&p, 0, sizeof p);
  p.ctx = ctx, p.path = name;
  err = parse(&p, text);
  if (err == 0) {
    p.desc.points = p.points;
    err = rp_tf_create(ctx, &p.desc, out);
    if (err != 0) { /* name the file in rp_tf_create's message */
      char msg[RP__ERRMSG_MAX];
      snprintf(msg, sizeof msg, "%s", rp_last_error(ctx));
      err = rp__fail(ctx, err, "%s: %s", name, msg);
    }
  }
  rp__free(ctx, p.points);
  rp__free(ctx, text);
  return err;
}

int rp_tf_load(rp_context *ctx, const char *path, rp_tf **out) {
  char *text = NULL;
  size_t len = 0;
  int err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (path == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_tf_load: path and out are "
                    "required");
  if ((err = read_all(ctx, path, &text, &len)) != 0)
    return err;
  err = rp__tf_parse(ctx, path, text, len, out);
  rp__free(ctx, text);
  return err;
}
