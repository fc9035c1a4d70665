#include "cli_util.h"

#include <cjson/cJSON.h>
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

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

/* The number `tok` of generator spec `spec` as field `what` in lo..hi;
 * 0, or 1 with the error printed. */
static int generator_number(const char *spec, const char *what,
                            const char *tok, uint32_t lo, uint32_t hi,
                            uint32_t *out) {
  char option[320];
  snprintf(option, sizeof option, "%s: %s", spec, what);
  return cli_parse_whole(NULL, option, tok, lo, hi, out) != 0;
}

/* A generator spec's size field, N or XxYxZ, each in 1..RP_VOLUME_MAX_DIM;
 * 0, or 1 with the error printed. */
static int generator_dims(const char *spec, const char *tok,
                          uint32_t dims[3]) {
  char buf[64], *p = buf, *x;
  int a;
  if (strchr(tok, 'x') == NULL) {
    if (generator_number(spec, "size N", tok, 1, RP_VOLUME_MAX_DIM,
                         &dims[0]) != 0)
      return 1;
    dims[1] = dims[2] = dims[0];
    return 0;
  }
  if (strlen(tok) >= sizeof buf)
    return cli_bad_option(NULL, spec, NULL, "a size too long",
                          "must be XxYxZ") != 0;
  strcpy(buf, tok);
  for (a = 0; a < 3; a++, p = x + 1) {
    static const char *const names[] = {"size X", "size Y", "size Z"};
    x = strchr(p, 'x');
    if ((x == NULL) != (a == 2)) {
      char problem[96];
      snprintf(problem, sizeof problem, "'%s', not XxYxZ", tok);
      return cli_bad_option(NULL, spec, NULL, problem, "must be three "
                            "sizes joined by x, each in 1..%u",
                            (unsigned)RP_VOLUME_MAX_DIM) != 0;
    }
    if (x != NULL)
      *x = '\0';
    if (generator_number(spec, names[a], p, 1, RP_VOLUME_MAX_DIM,
                         &dims[a]) != 0)
      return 1;
  }
  return 0;
}

/* gen:KIND[:N|:XxYxZ][:u8|u16][:SEED] into d; 0, or 1 with the error
 * printed, naming the spec and its field. */
static int parse_generator(const char *spec, rp_generate_desc *d) {
  static const char form[] = "gen:KIND[:N|:XxYxZ][:u8|u16][:SEED]";
  char buf[256], *tok, *save = NULL;
  int field = 0;
  if (strlen(spec) >= sizeof buf)
    return cli_bad_option(NULL, "generator spec", NULL, "too long",
                          "must be %s", form) != 0;
  strcpy(buf, spec + 4);
  d->dims[0] = d->dims[1] = d->dims[2] = 128;
  d->type = RP_U8;
  d->seed = 1;
  for (tok = strtok_r(buf, ":", &save); tok != NULL;
       tok = strtok_r(NULL, ":", &save), field++) {
    uint32_t seed;
    if (field == 0) {
      if (strcmp(tok, "ml") == 0 || strcmp(tok, "marschner-lobb") == 0)
        d->kind = RP_GEN_MARSCHNER_LOBB;
      else if (strcmp(tok, "phantom") == 0)
        d->kind = RP_GEN_PHANTOM;
      else if (strcmp(tok, "noise") == 0)
        d->kind = RP_GEN_NOISE;
      else if (strcmp(tok, "ct") == 0) {
        d->kind = RP_GEN_CT_HEAD;
        d->type = RP_S16;
      } else {
        char option[320];
        snprintf(option, sizeof option, "%s: generator", spec);
        return cli_bad_option(NULL, option, tok, "unknown", "must be ml, "
                              "phantom, noise or ct (%s)", form) != 0;
      }
    } else if (strcmp(tok, "u8") == 0) {
      d->type = RP_U8;
    } else if (strcmp(tok, "u16") == 0) {
      d->type = RP_U16;
    } else if (field == 1 || strchr(tok, 'x') != NULL) {
      if (generator_dims(spec, tok, d->dims) != 0)
        return 1;
    } else if (isdigit((unsigned char)tok[0]) || tok[0] == '-' ||
               tok[0] == '+') {
      if (generator_number(spec, "seed", tok, 0, UINT32_MAX, &seed) != 0)
        return 1;
      d->seed = seed;
    } else {
      char option[320];
      snprintf(option, sizeof option, "%s: field", spec);
      return cli_bad_option(NULL, option, tok, "unknown", "must be N or "
                            "XxYxZ (the size), u8, u16 or a seed (%s)",
                            form) != 0;
    }
  }
  return 0;
}

int cli_open_volume(rp_context *ctx, const char *spec, rp_volume **out) {
  rp_generate_desc d = {0};
  int err;
  if (strncmp(spec, "gen:", 4) == 0) {
    if (parse_generator(spec, &d) != 0)
      return 1;
    err = rp_volume_generate(ctx, &d, out);
  } else {
    err = rp_volume_load(ctx, spec, out);
  }
  return err != 0 ? cli_error(ctx, spec, err) : 0;
}

void cli_print_bricks(const rp_device *dev, const char *prefix) {
  rp_brick_stats st;
  if (rp_device_get_brick_stats(dev, &st) != 0 || !st.out_of_core)
    return;
  printf("%sout of core: %u bricks of %u^3 (%u visible), pool of %u, "
         "%u resident; %llu hits, %llu misses, %llu evictions; last "
         "render in %u part%s, %.2f MB uploaded in %.2f ms\n", prefix,
         st.bricks, st.brick_size, st.visible, st.slots - 1, st.resident,
         (unsigned long long)st.hits, (unsigned long long)st.misses,
         (unsigned long long)st.evictions, st.last_pieces,
         st.last_pieces == 1 ? "" : "s", st.last_upload_bytes / 1048576.0,
         st.last_upload_ns * 1e-6);
}

/* What the user typed for the device that failed with err, for the
 * message: the backend and index for a device that is not there, the
 * memory options too for any other failure. */
static void device_what(char *buf, size_t n, const char *option,
                        const char *backend, uint32_t index,
                        const cli_memory *mem, int err) {
  size_t len = 0;
  buf[0] = '\0';
  if (backend != NULL)
    len += (size_t)snprintf(buf + len, n - len, "%s %s", option, backend);
  if (index != 0 && len < n)
    len += (size_t)snprintf(buf + len, n - len, "%s--device %u",
                            len ? " " : "", index);
  if (err != RP_ENODEV && mem != NULL && mem->budget_arg != NULL &&
      len < n)
    len += (size_t)snprintf(buf + len, n - len, "%s--budget-mb %s",
                            len ? " " : "", mem->budget_arg);
  if (err != RP_ENODEV && mem != NULL && mem->brick_size != 0 && len < n)
    len += (size_t)snprintf(buf + len, n - len, "%s--brick-size %u",
                            len ? " " : "", mem->brick_size);
  if (len == 0)
    snprintf(buf, n, "device (the first with a driver)");
}

int cli_open_device(rp_context *ctx, const char *option, const char *backend,
                    uint32_t index, const cli_memory *mem, rp_device **dev) {
  rp_device_desc dd = {0};
  char what[512];
  int err;
  dd.backend = backend;
  dd.index = index;
  if (mem != NULL) {
    dd.budget_bytes = mem->budget_bytes;
    dd.brick_size = mem->brick_size;
  }
  err = rp_device_create(ctx, &dd, dev);
  if (err == RP_ENODEV && backend == NULL && index == 0) {
    fprintf(stderr, "raypace: %s; using the reference\n",
            rp_last_error(ctx));
    dd.backend = "reference";
    dd.budget_bytes = 0; /* the reference holds the whole volume */
    err = rp_device_create(ctx, &dd, dev);
  }
  if (err == 0)
    return 0;
  device_what(what, sizeof what, option, backend, index, mem, err);
  return cli_error(ctx, what, err);
}

/* The key=value fields of a device spec, in the order of this list. */
static const char *const device_keys[] = {"cu", "slow", "fail", "seed",
                                          "noise"};
#define DEVICE_KEYS (sizeof device_keys / sizeof device_keys[0])

/* Field `key` (an index into device_keys) = `v` of spec [s, s + len).
 * Points d->next at the ext struct the field sets. */
static int parse_device_field(const char *option, const char *tok,
                              size_t key, const char *v, const char *s,
                              int len, rp_device_desc *d,
                              cli_device_ext *ext) {
  static const cli_range ranges[] = {
      {1, 65536, 0, 1, "(compute units of a sub-device)"},
      {1, 10000, 0, 0, "(times slower)"},
      {0, UINT32_MAX, 0, 1, "(the render to fail at, from 1; 0: never)"},
      {0, UINT32_MAX, 0, 1, NULL},
      {0, 1, 0, 0, "(the log-normal sd of device times; 0: none)"}};
  char what[200], want[160];
  const char *problem;
  double x = 0.0;
  uint32_t u;
  if (key >= 3 && strcmp(d->backend, "test") != 0) {
    fprintf(stderr, "raypace: %s: '%s' in '%.*s' is for backend test "
                    "only\n", option, tok, len, s);
    return RP_EINVAL;
  }
  if ((problem = cli_number_problem(v, &ranges[key], &x)) != NULL) {
    snprintf(what, sizeof what, "%s %.*s: %s", option, len, s,
             device_keys[key]);
    cli_range_text(&ranges[key], want, sizeof want);
    cli_bad_option(NULL, what, v, problem, "must be %s", want);
    return RP_EINVAL;
  }
  u = (uint32_t)x;
  switch (key) {
  case 0: d->compute_units = u; break;
  case 1: ext->faults.slowdown = x; break;
  case 2: ext->faults.fail_at_render = u; break;
  case 3: ext->test.seed = u; break;
  /* On the command line 0 means no noise, not the default's. */
  default: ext->test.noise_sd = x > 0.0 ? x : -1.0; break;
  }
  if (key == 1 || key == 2)
    ext->faults.header.type = RP_EXT_FAULTS;
  else if (key >= 3)
    ext->test.header.type = RP_EXT_TEST_BACKEND;
  return 0;
}

/* Chains the ext structs a spec set onto d->next. */
static void chain_device_ext(rp_device_desc *d, cli_device_ext *ext) {
  const void *next = NULL;
  ext->faults.header.next = NULL;
  ext->test.header.next = NULL;
  if (ext->test.header.type != 0) {
    ext->test.header.next = next;
    next = &ext->test;
  }
  if (ext->faults.header.type != 0) {
    ext->faults.header.next = next;
    next = &ext->faults;
  }
  d->next = next;
}

/* One SPEC of a device list, [s, s + len). */
static int parse_device(const char *option, const char *s, size_t len,
                        rp_device_desc *d, cli_device_ext *ext) {
  static const char *const names[] = {"opencl", "vulkan", "reference",
                                      "test", "mpi"};
  char buf[128], *tok, *save = NULL;
  int field = 0, seen[DEVICE_KEYS] = {0}, err;
  size_t i, k;
  memset(d, 0, sizeof(*d));
  memset(ext, 0, sizeof(*ext));
  if (len == 0) {
    fprintf(stderr, "raypace: %s: empty device in the list\n", option);
    return RP_EINVAL;
  }
  if (len >= sizeof(buf)) {
    fprintf(stderr, "raypace: %s: device '%.*s...' is too long\n", option,
            32, s);
    return RP_EINVAL;
  }
  memcpy(buf, s, len);
  buf[len] = '\0';
  /* strtok_r would fold "::" into one separator; empty fields are
   * errors, so split by hand. */
  for (tok = buf; tok != NULL; tok = save, field++) {
    char *colon = strchr(tok, ':');
    char *eq;
    save = NULL;
    if (colon != NULL) {
      *colon = '\0';
      save = colon + 1;
    }
    eq = strchr(tok, '=');
    if (field == 0) {
      for (i = 0; i < sizeof(names) / sizeof(names[0]); i++)
        if (strcmp(tok, names[i]) == 0)
          d->backend = names[i];
      if (d->backend == NULL) {
        fprintf(stderr, "raypace: %s: backend '%s' in '%.*s' is not opencl, "
                        "vulkan, reference, test or mpi\n", option, tok,
                (int)len, s);
        return RP_EINVAL;
      }
      continue;
    }
    if (eq == NULL && field == 1) {
      if (cli_whole(tok, 0, 1024, &d->index) != 0) {
        char what[200];
        snprintf(what, sizeof what, "%s %.*s: index", option, (int)len, s);
        cli_bad_option(NULL, what, tok, "not a device index",
                       "must be a whole number in 0..1024");
        return RP_EINVAL;
      }
      continue;
    }
    for (k = 0; eq != NULL && k < DEVICE_KEYS; k++)
      if (strlen(device_keys[k]) == (size_t)(eq - tok) &&
          strncmp(tok, device_keys[k], (size_t)(eq - tok)) == 0)
        break;
    if (eq == NULL || k == DEVICE_KEYS) {
      fprintf(stderr, "raypace: %s: field '%s' in '%.*s' is not %s"
                      "cu=N, slow=S, fail=F, seed=N or noise=X\n", option,
              tok, (int)len, s, field == 1 ? "an index, " : "");
      return RP_EINVAL;
    }
    if (seen[k]++) {
      fprintf(stderr, "raypace: %s: '%.*s' is given twice in '%.*s'\n",
              option, (int)(eq - tok), tok, (int)len, s);
      return RP_EINVAL;
    }
    if ((err = parse_device_field(option, tok, k, eq + 1, s, (int)len, d,
                                  ext)) != 0)
      return err;
  }
  chain_device_ext(d, ext);
  return 0;
}

int cli_parse_devices(const char *option, const char *spec,
                      rp_device_desc *out, cli_device_ext *ext,
                      uint32_t max, uint32_t *n) {
  uint32_t count = 0;
  const char *s = spec;
  if (spec == NULL || out == NULL || ext == NULL || n == NULL)
    return RP_EINVAL;
  for (;;) {
    const char *comma = strchr(s, ',');
    size_t len = comma != NULL ? (size_t)(comma - s) : strlen(s);
    rp_device_desc d;
    cli_device_ext e;
    int err = parse_device(option, s, len, &d, &e);
    if (err != 0)
      return err;
    if (count == max) {
      fprintf(stderr, "raypace: %s: at most %u devices\n", option, max);
      return RP_EINVAL;
    }
    /* The chain points into ext[count], where the structs now live. */
    ext[count] = e;
    out[count] = d;
    chain_device_ext(&out[count], &ext[count]);
    count++;
    if (comma == NULL)
      break;
    s = comma + 1;
  }
  *n = count;
  return 0;
}

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return x < y ? -1 : x > y;
}

double cli_median(double *v, int n) {
  qsort(v, (size_t)n, sizeof *v, cmp_double);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

double cli_quantile(double *v, int n, double p) {
  double k;
  if (n <= 0)
    return NAN;
  qsort(v, (size_t)n, sizeof *v, cmp_double);
  k = ceil(p * n - 1e-9);
  return v[k < 1 ? 0 : k > n ? n - 1 : (int)k - 1];
}

/* One colour per controller, the same in every panel and plot (replay's
 * and bench pacing --pareto's): left to
 * gnuplot, a line's colour follows its place in the plot command, which
 * the target line, drawn first in the top panel only, shifted by one
 * against the bottom panel. The target is black. The colours are Okabe
 * and Ito's, told apart with the common colour-vision deficiencies, but
 * for ue5's: a dark brown, as their orange was hard to tell from
 * predicted's vermillion in thin lines. */
static const char *const controller_colours[] = {
    "#999999", /* none */
    "#56b4e9", /* last-frame */
    "#009e73", /* two-pass */
    "#d55e00", /* predicted */
    "#0072b2", /* vtk */
    "#8c510a", /* ue5 */
    "#cc79a7", /* valve */
};
_Static_assert(sizeof controller_colours / sizeof controller_colours[0] ==
                   RP_CONTROL_COUNT,
               "a colour for every controller");

const char *cli_controller_colour(rp_controller_kind kind) {
  return (unsigned)kind < RP_CONTROL_COUNT ? controller_colours[kind]
                                           : "#000000";
}

void cli_json_figure(cJSON *o, const char *name, double v) {
  if (isfinite(v))
    cJSON_AddNumberToObject(o, name, v);
  else
    cJSON_AddNullToObject(o, name);
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

int cli_plot_open(cli_plot *p, const char *who) {
  p->sigpipe = signal(SIGPIPE, SIG_IGN);
  p->g = popen("gnuplot", "w");
  if (p->g == NULL) {
    signal(SIGPIPE, p->sigpipe);
    fprintf(stderr, "%s: --plot: cannot run gnuplot\n", who);
    return 1;
  }
  return 0;
}

int cli_plot_close(cli_plot *p, const char *who) {
  int status = pclose(p->g);
  signal(SIGPIPE, p->sigpipe);
  p->g = NULL;
  if (status != 0) {
    fprintf(stderr, "%s: --plot: gnuplot failed (status %d)\n", who,
            status);
    return 1;
  }
  return 0;
}

int cli_have_gnuplot(void) {
  return system("command -v gnuplot >/dev/null 2>&1") == 0;
}

/* A bar on stderr, redrawn in place; only on a terminal, so logs and
 * pipes stay clean. */
void cli_progress(double fraction, void *user) {
  static const int width = 30;
  const char *what = user != NULL ? user : "working";
  int filled = (int)(fraction * width + 0.5), i;
  if (!isatty(fileno(stderr)))
    return;
  fprintf(stderr, "\r%s [", what);
  for (i = 0; i < width; i++)
    fputc(i < filled ? '#' : ' ', stderr);
  fprintf(stderr, "] %3d%%%s", (int)(fraction * 100.0 + 0.5),
          fraction >= 1.0 ? "\n" : "");
  fflush(stderr);
}

const char *cli_tf_name(const rp_volume *vol, const cli_tf *tf) {
  rp_volume_info info;
  if (tf->spec != NULL)
    return tf->spec;
  rp_volume_get_info(vol, &info);
  /* Signed data is CT in HU far more often than not; unsigned CT is
   * usually HU shifted by an unknown amount, where a window on [min, max]
   * is the safer guess. */
  return info.type == RP_S8 || info.type == RP_S16 || info.type == RP_S32
             ? "ct-bone"
             : "minmax-bone";
}

int cli_make_tf(rp_context *ctx, const rp_volume *vol, const cli_tf *tf,
                rp_tf **out) {
  const char *name = cli_tf_name(vol, tf);
  struct stat st;
  rp_tf *base = NULL;
  int err;
  /* A name with a '/' or '.' or one that is an existing file is a file;
   * presets are bare words. */
  if (strpbrk(name, "/.") != NULL || stat(name, &st) == 0)
    err = rp_tf_load(ctx, name, &base);
  else
    err = rp_tf_create_preset(ctx, name, &base);
  if (err != 0)
    return cli_error(ctx, "--tf", err);
  if (tf->windowed == 0) {
    *out = base;
    return 0;
  }
  if (tf->windowed != 3) {
    rp_tf_destroy(base);
    fprintf(stderr, "raypace: --window and --level go together\n");
    return 1;
  }
  err = rp_tf_window(ctx, base, tf->window, tf->level, out);
  rp_tf_destroy(base);
  return err != 0 ? cli_error(ctx, "--window/--level", err) : 0;
}

int cli_print_json(cJSON *root) {
  char *text = cJSON_Print(root);
  int ok = text != NULL;
  if (ok)
    printf("%s\n", text);
  free(text);
  cJSON_Delete(root);
  return ok ? 0 : 1;
}

int cli_write_ppm(const char *path, const uint8_t *rgba, uint32_t width,
                  uint32_t height, const float background[3]) {
  FILE *f = fopen(path, "wb");
  size_t i, n = (size_t)width * height;
  int c, ok;
  if (f == NULL) {
    fprintf(stderr, "raypace: %s: cannot write: %s\n", path,
            strerror(errno));
    return 1;
  }
  fprintf(f, "P6\n%u %u\n255\n", width, height);
  /* out = C + (1 - A) bg on the 0..255 scale, as rp_write_png. */
  for (i = 0; i < n; i++) {
    const uint8_t *px = rgba + 4 * i;
    for (c = 0; c < 3; c++) {
      double v = px[c] + (255.0 - px[3]) * background[c];
      fputc((int)floor((v > 255.0 ? 255.0 : v) + 0.5), f);
    }
  }
  ok = !ferror(f);
  ok = fclose(f) == 0 && ok;
  if (!ok) {
    fprintf(stderr, "raypace: %s: write failed: %s\n", path,
            strerror(errno));
    remove(path);
  }
  return !ok;
}
