#include "cli_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

int cli_error(rp_context *ctx, const char *what, int err) {
  const char *detail = rp_last_error(ctx);
  fprintf(stderr, "raypace: %s: %s%s%s\n", what, rp_strerror(err),
          detail[0] ? ": " : "", detail);
  return 1;
}

double cli_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

int cli_parse_size(const char *s, uint32_t *w, uint32_t *h) {
  unsigned long a, b;
  char *end;
  a = strtoul(s, &end, 10);
  if (end == s || (*end != 'x' && *end != 'X'))
    return -1;
  s = end + 1;
  b = strtoul(s, &end, 10);
  if (end == s || *end != '\0' || a < 1 || b < 1 || a > 16384 || b > 16384)
    return -1;
  *w = (uint32_t)a;
  *h = (uint32_t)b;
  return 0;
}

int cli_parse_u32(const char *s, uint32_t max, uint32_t *out) {
  char *end;
  unsigned long v = strtoul(s, &end, 10);
  if (end == s || *end != '\0' || v > max || s[0] == '-')
    return -1;
  *out = (uint32_t)v;
  return 0;
}

int cli_parse_floats(const char *s, float *out, int n) {
  int i;
  for (i = 0; i < n; i++) {
    char *end;
    double v = strtod(s, &end);
    /* Checked after the cast too: 1e-50 would become 0 (which the library
     * reads as "default") and 1e39 infinity. */
    if (end == s || !isfinite(v) || !isfinite((float)v) ||
        (v != 0.0 && (float)v == 0.0f))
      return -1;
    out[i] = (float)v;
    s = end;
    if (i + 1 < n) {
      if (*s != ',')
        return -1;
      s++;
    }
  }
  return *s == '\0' ? 0 : -1;
}

int cli_parse_positive(const char *s, float *out) {
  float v;
  if (cli_parse_floats(s, &v, 1) != 0 || !(v > 0.0f))
    return -1;
  *out = v;
  return 0;
}

static int parse_generator(rp_context *ctx, const char *spec,
                           rp_volume **out) {
  rp_generate_desc d = {0};
  char buf[256], *tok, *save = NULL;
  int field = 0, err;
  if (strlen(spec) >= sizeof buf) {
    fprintf(stderr, "raypace: generator spec too long\n");
    return 1;
  }
  strcpy(buf, spec + 4);
  d.dims[0] = d.dims[1] = d.dims[2] = 128;
  d.type = RP_U8;
  d.seed = 1;
  for (tok = strtok_r(buf, ":", &save); tok != NULL;
       tok = strtok_r(NULL, ":", &save), field++) {
    unsigned x, y, z;
    char extra;
    if (field == 0) {
      if (strcmp(tok, "ml") == 0 || strcmp(tok, "marschner-lobb") == 0)
        d.kind = RP_GEN_MARSCHNER_LOBB;
      else if (strcmp(tok, "phantom") == 0)
        d.kind = RP_GEN_PHANTOM;
      else if (strcmp(tok, "noise") == 0)
        d.kind = RP_GEN_NOISE;
      else {
        fprintf(stderr, "raypace: generator '%s' is unknown (ml, phantom, "
                        "noise)\n", tok);
        return 1;
      }
    } else if (sscanf(tok, "%ux%ux%u%c", &x, &y, &z, &extra) == 3) {
      d.dims[0] = x, d.dims[1] = y, d.dims[2] = z;
    } else if (sscanf(tok, "%u%c", &x, &extra) == 1 && field == 1) {
      d.dims[0] = d.dims[1] = d.dims[2] = x;
    } else if (strcmp(tok, "u8") == 0) {
      d.type = RP_U8;
    } else if (strcmp(tok, "u16") == 0) {
      d.type = RP_U16;
    } else if (sscanf(tok, "%u%c", &x, &extra) == 1) {
      d.seed = x;
    } else {
      fprintf(stderr, "raypace: generator field '%s' is not XxYxZ, u8, "
                      "u16 or a seed\n", tok);
      return 1;
    }
  }
  err = rp_volume_generate(ctx, &d, out);
  return err != 0 ? cli_error(ctx, spec, err) : 0;
}

int cli_open_volume(rp_context *ctx, const char *spec, rp_volume **out) {
  int err;
  if (strncmp(spec, "gen:", 4) == 0)
    return parse_generator(ctx, spec, out);
  err = rp_volume_load(ctx, spec, out);
  return err != 0 ? cli_error(ctx, spec, err) : 0;
}

int cli_open_device(rp_context *ctx, const char *option, const char *backend,
                    uint32_t index, rp_device **dev) {
  rp_device_desc dd = {0};
  int err;
  dd.backend = backend;
  dd.index = index;
  err = rp_device_create(ctx, &dd, dev);
  if (err == RP_ENODEV && backend == NULL && index == 0) {
    fprintf(stderr, "raypace: %s; using the reference\n",
            rp_last_error(ctx));
    dd.backend = "reference";
    err = rp_device_create(ctx, &dd, dev);
  }
  return err != 0 ? cli_error(ctx, option, err) : 0;
}

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return x < y ? -1 : x > y;
}

double cli_median(double *v, int n) {
  qsort(v, (size_t)n, sizeof *v, cmp_double);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

void cli_gnuplot_string(FILE *g, const char *s) {
  fputc('\'', g);
  for (; *s != '\0'; s++) {
    if (*s == '\'')
      fputc('\'', g);
    fputc(*s, g);
  }
  fputc('\'', g);
}

int cli_have_gnuplot(void) {
  return system("command -v gnuplot >/dev/null 2>&1") == 0;
}
