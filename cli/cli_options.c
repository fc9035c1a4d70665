/* Command-line values: every number an option takes is parsed here and
 * checked against its range before the command does any work, and a bad
 * one is reported in one shape (cli_bad_option) that names the option,
 * the value as typed, what is wrong with it and what it must be. */
#include "cli_util.h"
#include "raypace_group.h"

#include <ctype.h>
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

int cli_bad_option(const char *cmd, const char *option, const char *value,
                   const char *problem, const char *want, ...) {
  va_list ap;
  fprintf(stderr, "raypace%s%s: %s", cmd != NULL ? " " : "",
          cmd != NULL ? cmd : "", option);
  if (value != NULL)
    fprintf(stderr, value[0] != '\0' ? " %s" : " ''", value);
  fprintf(stderr, " is %s; ", problem);
  va_start(ap, want);
  vfprintf(stderr, want, ap);
  va_end(ap);
  fputc('\n', stderr);
  return 2;
}

void cli_range_text(const cli_range *r, char *buf, size_t n) {
  const char *unit = r->unit != NULL ? r->unit : "";
  const char *sep = r->unit != NULL ? " " : "";
  if (isinf(r->lo) && isinf(r->hi))
    snprintf(buf, n, "a finite number%s%s", sep, unit);
  else if (r->whole)
    snprintf(buf, n, "a whole number in %.17g..%.17g%s%s", r->lo, r->hi,
             sep, unit);
  else if (isinf(r->hi))
    snprintf(buf, n, "%s %g%s%s", r->open & CLI_OPEN_LO ? ">" : ">=",
             r->lo, sep, unit);
  else
    snprintf(buf, n, "in %c%g, %g%c%s%s", r->open & CLI_OPEN_LO ? '(' : '[',
             r->lo, r->hi, r->open & CLI_OPEN_HI ? ')' : ']', sep, unit);
}

int cli_in_range(const cli_range *r, double v) {
  if (!(r->open & CLI_OPEN_LO ? v > r->lo : v >= r->lo))
    return 0;
  if (!(r->open & CLI_OPEN_HI ? v < r->hi : v <= r->hi))
    return 0;
  return !r->whole || v == floor(v);
}

const char *cli_number_problem(const char *s, const cli_range *r,
                               double *out) {
  char *end;
  double v = 0.0;
  /* strtod skips leading space and reads "nan" and hex: none of which a
   * user means as a value. */
  if (s[0] == '\0' || isspace((unsigned char)s[0]) ||
      strpbrk(s, "xXnN") != NULL)
    return "not a number";
  errno = 0;
  v = strtod(s, &end);
  if (end == s || *end != '\0')
    return "not a number";
  *out = v;
  if (!isfinite(v))
    return "out of range";
  if (r->whole && v != floor(v))
    return "not a whole number";
  return cli_in_range(r, v) ? NULL : "out of range";
}

int cli_whole(const char *s, uint32_t lo, uint32_t hi, uint32_t *out) {
  cli_range r = {0};
  double v = 0.0;
  r.lo = lo, r.hi = hi, r.whole = 1;
  if (cli_number_problem(s, &r, &v) != NULL)
    return -1;
  *out = (uint32_t)v;
  return 0;
}

int cli_parse_real(const char *cmd, const char *option, const char *s,
                   const cli_range *r, double *out) {
  char want[160];
  double v = 0.0;
  const char *problem = cli_number_problem(s, r, &v);
  if (problem == NULL) {
    *out = v;
    return 0;
  }
  cli_range_text(r, want, sizeof want);
  return cli_bad_option(cmd, option, s, problem, "must be %s", want);
}

/* What is wrong with `s` as a float in r: the range is checked on the
 * float the value becomes, as the library checks it (the float limits,
 * such as RP_STEP_MIN = 1e-3f, are not the decimal numbers they print
 * as), and a value a float cannot hold is refused (1e-50 would become
 * 0, which the library reads as "the default"). */
static const char *float_problem(const char *s, const cli_range *r,
                                 float *out) {
  cli_range any = *r;
  double v = 0.0;
  const char *problem;
  any.lo = -INFINITY, any.hi = INFINITY, any.open = 0;
  if ((problem = cli_number_problem(s, &any, &v)) != NULL)
    return problem;
  if (!isfinite((float)v) || (v != 0.0 && (float)v == 0.0f))
    return "out of range";
  if (!cli_in_range(r, (double)(float)v))
    return "out of range";
  *out = (float)v;
  return NULL;
}

int cli_parse_float(const char *cmd, const char *option, const char *s,
                    const cli_range *r, float *out) {
  char want[160];
  const char *problem = float_problem(s, r, out);
  if (problem == NULL)
    return 0;
  cli_range_text(r, want, sizeof want);
  return cli_bad_option(cmd, option, s, problem, "must be %s", want);
}

int cli_parse_whole(const char *cmd, const char *option, const char *s,
                    uint32_t lo, uint32_t hi, uint32_t *out) {
  cli_range r = {0};
  double v = 0.0;
  r.lo = lo, r.hi = hi, r.whole = 1;
  if (cli_parse_real(cmd, option, s, &r, &v) != 0)
    return 2;
  *out = (uint32_t)v;
  return 0;
}

int cli_parse_tuple(const char *cmd, const char *option, const char *s,
                    const char *form, const cli_field *fields, int n,
                    float *out) {
  char buf[256], *p = buf, what[320], want[240], problem[96];
  float v[8];
  int i;
  if (n > 8 || strlen(s) >= sizeof buf)
    return cli_bad_option(cmd, option, s, "too long", "must be %s", form);
  strcpy(buf, s);
  for (i = 0; i < n; i++) {
    const cli_range *r = &fields[i].range;
    char *comma = strchr(p, ',');
    const char *bad;
    if ((comma == NULL) != (i == n - 1)) {
      snprintf(problem, sizeof problem, "not %s", form);
      return cli_bad_option(cmd, option, s, problem, "must be %d numbers "
                            "joined by commas", n);
    }
    if (comma != NULL)
      *comma = '\0';
    if ((bad = float_problem(p, r, &v[i])) != NULL) {
      snprintf(what, sizeof what, "%s %s: %s", option, s, fields[i].name);
      cli_range_text(r, want, sizeof want);
      return cli_bad_option(cmd, what, p, bad, "must be %s%s%s", want,
                            fields[i].hint != NULL ? "; " : "",
                            fields[i].hint != NULL ? fields[i].hint : "");
    }
    p = comma + 1;
  }
  memcpy(out, v, (size_t)n * sizeof *out);
  return 0;
}

int cli_parse_orbit(const char *cmd, const char *option, const char *s,
                    float orbit[3]) {
  /* Elevation stops at the poles: past one, the same eye is azimuth +
   * 180 at 180 - EL. The distance is positive: a negative one puts the
   * eye on the far side, which reads as a mirrored view of the side the
   * angles name. */
  static const cli_field fields[3] = {
      {"AZ", {-360.0, 360.0, 0, 0, "degrees"}, NULL},
      {"EL", {-90.0, 90.0, 0, 0, "degrees"},
       "past a pole, add 180 to AZ instead"},
      {"DIST", {0.0, 2.0 * RP_CAMERA_DISTANCE_MAX, CLI_OPEN_LO, 0,
                "bounding radii"},
       "the eye's distance from the centre (1 touches the bounding "
       "sphere); for the view from the other side add 180 to AZ"}};
  return cli_parse_tuple(cmd, option, s, "AZ,EL,DIST", fields, 3, orbit);
}

/* One side of WxH: a decimal whole number, the sign kept so that "-5" is
 * out of range rather than 4294967291. */
static int size_side(const char *s, char **end, long long *v) {
  if (!isdigit((unsigned char)s[0]) && s[0] != '-' && s[0] != '+')
    return -1;
  errno = 0;
  *v = strtoll(s, end, 10);
  if (*end == s)
    return -1;
  if (errno == ERANGE)
    *v = s[0] == '-' ? -1 : LLONG_MAX;
  return 0;
}

int cli_parse_size(const char *cmd, const char *option, const char *s,
                   uint32_t *w, uint32_t *h) {
  static const char want[] =
      "must be WxH, width and height each in 1..%u and at most %u pixels "
      "(e.g. 512x512)";
  long long a, b;
  char *end;
  if (size_side(s, &end, &a) != 0 || (*end != 'x' && *end != 'X') ||
      size_side(end + 1, &end, &b) != 0 || *end != '\0')
    return cli_bad_option(cmd, option, s, "not WxH", want,
                          (unsigned)RP_IMAGE_MAX_DIM,
                          (unsigned)RP_IMAGE_MAX_PIXELS);
  if (a < 1 || b < 1 || a > RP_IMAGE_MAX_DIM || b > RP_IMAGE_MAX_DIM)
    return cli_bad_option(cmd, option, s, "out of range", want,
                          (unsigned)RP_IMAGE_MAX_DIM,
                          (unsigned)RP_IMAGE_MAX_PIXELS);
  if ((unsigned long long)a * (unsigned long long)b > RP_IMAGE_MAX_PIXELS) {
    char problem[64];
    snprintf(problem, sizeof problem, "%llu pixels, over the limit",
             (unsigned long long)a * (unsigned long long)b);
    return cli_bad_option(cmd, option, s, problem, want,
                          (unsigned)RP_IMAGE_MAX_DIM,
                          (unsigned)RP_IMAGE_MAX_PIXELS);
  }
  *w = (uint32_t)a;
  *h = (uint32_t)b;
  return 0;
}

int cli_parse_budget_mb(const char *cmd, const char *option, const char *s,
                        cli_memory *mem) {
  /* Up to a petabyte: beyond any device, and exact in a double. The
   * floor, one 8^3 brick's bytes, keeps a budget from rounding to 0
   * (which the library reads as "the device's largest buffer"). */
  cli_range r = {0};
  double mb = 0.0;
  r.lo = 1e-3, r.hi = 1e9, r.unit = "MB (2^20 bytes)";
  if (cli_parse_real(cmd, option, s, &r, &mb) != 0)
    return 2;
  mem->budget_bytes = (uint64_t)(mb * 1048576.0);
  mem->budget_arg = s;
  return 0;
}

int cli_parse_brick_size(const char *cmd, const char *option, const char *s,
                         cli_memory *mem) {
  /* rp_device_desc.brick_size: a power of two in [8, 256]. */
  uint32_t v = 0;
  const char *problem = NULL;
  if (cli_whole(s, 0, UINT32_MAX, &v) != 0)
    problem = "not a whole number";
  else if (v < 8 || v > 256)
    problem = "out of range";
  else if ((v & (v - 1)) != 0)
    problem = "not a power of two";
  if (problem != NULL)
    return cli_bad_option(cmd, option, s, problem, "must be 8, 16, 32, 64, "
                          "128 or 256 (voxels along a brick's edge)");
  mem->brick_size = v;
  return 0;
}

int cli_parse_window(const char *cmd, cli_tf *tf, int is_width,
                     const char *s) {
  /* A window is a width in data units (> 0); a level any data value
   * (rp_tf_window judges the two together). */
  cli_range r = {0};
  double v = 0.0;
  r.lo = is_width ? 0.0 : -INFINITY, r.hi = INFINITY, r.unit = "data units";
  r.open = is_width ? CLI_OPEN_LO : 0;
  if (cli_parse_real(cmd, is_width ? "--window" : "--level", s, &r, &v) !=
      0)
    return 2;
  if (is_width)
    tf->window = v, tf->windowed |= 1;
  else
    tf->level = v, tf->windowed |= 2;
  return 0;
}

/* ---- The work bound -------------------------------------------------- */

int cli_check_work(const char *cmd, const char *step_option,
                   const rp_volume *vol, float step, uint32_t width,
                   uint32_t height, float scale) {
  rp_volume_info in;
  rp_render_desc rd = {0};
  char problem[320], value[32];
  double d2 = 0.0, finest = INFINITY, per_ray, frame;
  uint32_t sw, sh;
  int a;
  rp_volume_get_info(vol, &in);
  for (a = 0; a < 3; a++) {
    double e = (double)in.dims[a] * in.spacing[a];
    d2 += e * e;
    finest = fmin(finest, in.spacing[a]);
  }
  /* As the library counts (RP_MAX_SAMPLES_PER_RAY): the box diagonal in
   * voxels of the finest spacing over the step. */
  per_ray = sqrt(d2) / finest / step + 1.0;
  rd.width = width, rd.height = height, rd.image_scale = scale;
  rp_scaled_size(&rd, &sw, &sh);
  frame = per_ray * sw * sh;
  snprintf(value, sizeof value, "%g", (double)step);
  if (per_ray > (double)RP_MAX_SAMPLES_PER_RAY) {
    snprintf(problem, sizeof problem, "too fine for this volume (%ux%ux%u,"
             " a diagonal of %.4g voxels of its finest spacing): a ray may "
             "take %.4g samples, at most %u (RP_MAX_SAMPLES_PER_RAY)",
             in.dims[0], in.dims[1], in.dims[2], sqrt(d2) / finest,
             per_ray, (unsigned)RP_MAX_SAMPLES_PER_RAY);
    return cli_bad_option(cmd, step_option, value, problem, "use a "
                          "coarser %s", step_option);
  }
  if (frame > (double)RP_MAX_SAMPLES_PER_FRAME) {
    snprintf(problem, sizeof problem, "too fine for this volume (%ux%ux%u)"
             " at %ux%u rays: the frame may take %.4g samples, at most "
             "%.4g (RP_MAX_SAMPLES_PER_FRAME)", in.dims[0], in.dims[1],
             in.dims[2], sw, sh, frame, (double)RP_MAX_SAMPLES_PER_FRAME);
    return cli_bad_option(cmd, step_option, value, problem, "use a "
                          "coarser %s, or a smaller --size or --scale",
                          step_option);
  }
  return 0;
}

/* ---- Files written --------------------------------------------------- */

/* 1 when `path` ends in `ext` (".png"), whatever its case. */
static int has_ext(const char *path, const char *ext) {
  size_t n = strlen(path), k = strlen(ext);
  return n > k && strcasecmp(path + n - k, ext) == 0;
}

int cli_check_output(const char *cmd, const char *option, const char *path,
                     const char *const *exts) {
  char dir[4096];
  const char *slash = strrchr(path, '/');
  struct stat st;
  if (path[0] == '\0')
    return cli_bad_option(cmd, option, path, "empty", "must name a file");
  if (stat(path, &st) == 0 && S_ISDIR(st.st_mode))
    return cli_bad_option(cmd, option, path, "a directory",
                          "must name a file in it");
  if (exts != NULL) {
    const char *const *e;
    const char *dot = strrchr(path, '.');
    char forms[64] = "";
    for (e = exts; *e != NULL; e++) {
      if (has_ext(path, *e))
        break;
      snprintf(forms + strlen(forms), sizeof forms - strlen(forms), "%s%s",
               e == exts ? "" : e[1] == NULL ? " or " : ", ", *e);
    }
    if (*e == NULL) {
      char problem[96];
      if (dot == NULL || (slash != NULL && dot < slash))
        snprintf(problem, sizeof problem, "without an extension");
      else
        snprintf(problem, sizeof problem, "a %.32s file", dot);
      return cli_bad_option(cmd, option, path, problem,
                            "must end in %s, the forms written", forms);
    }
  }
  if (slash == NULL)
    snprintf(dir, sizeof dir, ".");
  else if (slash == path)
    snprintf(dir, sizeof dir, "/");
  else
    snprintf(dir, sizeof dir, "%.*s", (int)(slash - path), path);
  if (stat(dir, &st) != 0 || !S_ISDIR(st.st_mode))
    return cli_bad_option(cmd, option, path, "in no directory",
                          "'%s' does not exist: create it first or name "
                          "another", dir);
  if (access(dir, W_OK) != 0)
    return cli_bad_option(cmd, option, path, "not writable",
                          "cannot write in '%s'", dir);
  return 0;
}

/* ---- Backends -------------------------------------------------------- */

static int mpi_world = 0; /* 0: not told (the environment says) */

void cli_set_mpi_world(int size) { mpi_world = size; }

/* The size of the MPI job this process is rank 0 of: what rp_mpi_init
 * said, else what the launcher's environment says (Open MPI, PMI,
 * PMIx); 1 when started without one. */
static int mpi_world_size(int *launched) {
  static const char *const vars[] = {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE",
                                     "PMIX_SIZE"};
  size_t i;
  *launched = 0;
  for (i = 0; i < sizeof vars / sizeof vars[0]; i++)
    if (getenv(vars[i]) != NULL)
      *launched = 1;
  if (mpi_world > 0)
    return mpi_world;
  for (i = 0; i < sizeof vars / sizeof vars[0]; i++) {
    const char *v = getenv(vars[i]);
    if (v != NULL && atoi(v) > 0)
      return atoi(v);
  }
  return 1;
}

int cli_check_mpi(const char *cmd, const char *option, const char *value,
                  uint32_t index) {
  int launched, size = mpi_world_size(&launched);
  if (size <= 1 && !launched)
    return cli_bad_option(
        cmd, option, value, "a device on another MPI rank, and this "
        "process was not started by an MPI launcher",
        "start it as 'mpirun -np N raypace %s ...' (device I is rank "
        "I + 1's), or name a local backend", cmd);
  if (size <= 1)
    return cli_bad_option(
        cmd, option, value, "a device on another MPI rank, and this "
        "process is an MPI job of one rank (or raypace was built without "
        "MPI: RP_WITH_MPI)", "start it with 2 or more ranks (mpirun -np "
        "N: device I is rank I + 1's)");
  if (index + 1 >= (uint32_t)size)
    return cli_bad_option(
        cmd, option, value, "past the job's server ranks", "must be in "
        "0..%d: device I is rank I + 1's, and the job has %d ranks",
        size - 2, size);
  return 0;
}

int cli_check_backend(const char *cmd, const char *name) {
  static const char *const names[] = {"opencl", "vulkan", "reference",
                                      "test", "mpi"};
  size_t i;
  for (i = 0; i < sizeof names / sizeof names[0]; i++)
    if (strcmp(name, names[i]) == 0)
      return 0;
  return cli_bad_option(cmd, "--backend", name, "not a backend",
                        "must be opencl, vulkan, reference, test or mpi");
}

int cli_parse_device_option(const char *cmd, int c, const char *option,
                            const char *arg, const cli_device_opts *d) {
  switch (c) {
  case 'B':
    *d->backend = arg;
    *d->device_given = 1;
    return cli_check_backend(cmd, arg);
  case 'D':
    *d->device_given = 1;
    return cli_parse_whole(cmd, option, arg, 0, 1024, d->device);
  case 'L':
    *d->devices_spec = arg;
    /* The list's parser names the bad part itself. */
    return cli_parse_devices("--devices", arg, d->devices, d->ext,
                             RP_GROUP_MAX_DEVICES, d->ndevices) != 0
               ? 2
               : 0;
  case 'M': return cli_parse_budget_mb(cmd, option, arg, d->mem);
  default: return cli_parse_brick_size(cmd, option, arg, d->mem);
  }
}

int cli_check_devices(const char *cmd, const cli_device_opts *d) {
  uint32_t i;
  if (*d->devices_spec != NULL && *d->device_given) {
    fprintf(stderr, "raypace %s: --devices excludes --backend and "
                    "--device\n", cmd);
    return 2;
  }
  if (*d->backend != NULL && strcmp(*d->backend, "mpi") == 0 &&
      cli_check_mpi(cmd, "--backend", "mpi", *d->device) != 0)
    return 2;
  for (i = 0; i < *d->ndevices; i++) {
    d->devices[i].budget_bytes = d->mem->budget_bytes;
    d->devices[i].brick_size = d->mem->brick_size;
    if (strcmp(d->devices[i].backend, "mpi") == 0 &&
        cli_check_mpi(cmd, "--devices", *d->devices_spec,
                      d->devices[i].index) != 0)
      return 2;
  }
  return 0;
}
