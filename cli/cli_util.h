/* Helpers shared by the raypace command's subcommands. */
#ifndef RP_CLI_UTIL_H
#define RP_CLI_UTIL_H

#include <stdint.h>
#include <stdio.h>

#include "raypace.h"
#include "raypace_testing.h"

/* Opens a volume from a file path or a generator spec
 * "gen:KIND[:N|:XxYxZ][:u8|u16][:SEED]" (KIND: ml, phantom, noise; a
 * number right after KIND is the size N^3, a later one the seed; default
 * 128^3, u8, seed 1). Prints the error and returns non-zero on failure. */
int cli_open_volume(rp_context *ctx, const char *spec, rp_volume **out);
/* Out-of-core options (--budget-mb, --brick-size), shared by render and
 * replay: zeros mean the device's defaults. */
typedef struct cli_memory {
  uint64_t budget_bytes;
  uint32_t brick_size;
  const char *budget_arg; /* --budget-mb as typed; NULL: not given */
} cli_memory;

/* ---- Option values (cli_options.c) -----------------------------------
 * Every parser below checks the value against its range when the option
 * is parsed, before any work, and on a bad one prints one line in the
 * shape of cli_bad_option and returns 2 (the exit status of a usage
 * error); 0 otherwise. `cmd` is the command ("render", "bench quality")
 * and `option` what the user typed ("--fov"). */

/* Prints "raypace CMD: OPTION VALUE is PROBLEM; WANT" to stderr (WANT a
 * printf format saying what the value must be, or what to do); "raypace:
 * ..." when cmd is NULL; VALUE is left out when NULL. Returns 2. */
int cli_bad_option(const char *cmd, const char *option, const char *value,
                   const char *problem, const char *want, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 5, 6)))
#endif
    ;
/* A number's range: [lo, hi], either end open, hi = INFINITY for none;
 * `whole` for integers; `unit` printed after the range. */
#define CLI_OPEN_LO 1
#define CLI_OPEN_HI 2
typedef struct cli_range {
  double lo, hi;
  int open, whole;
  const char *unit;
} cli_range;
/* "in (0, 170] degrees", "> 0 ms", "a whole number in 1..256". */
void cli_range_text(const cli_range *r, char *buf, size_t n);
/* 1 when v is in r. */
int cli_in_range(const cli_range *r, double v);
/* What is wrong with `s` as a number in r ("not a number", "out of
 * range", ...), NULL when nothing is (its value then in *out); prints
 * nothing. */
const char *cli_number_problem(const char *s, const cli_range *r,
                               double *out);
/* A decimal number in r (no hex, nan or inf). */
int cli_parse_real(const char *cmd, const char *option, const char *s,
                   const cli_range *r, double *out);
/* The same into a float, refusing what a float cannot hold (1e-50 would
 * become 0, which the library reads as "the default"). */
int cli_parse_float(const char *cmd, const char *option, const char *s,
                    const cli_range *r, float *out);
/* A whole number in lo..hi; "-5" is out of range, never 2^32 - 5. */
int cli_parse_whole(const char *cmd, const char *option, const char *s,
                    uint32_t lo, uint32_t hi, uint32_t *out);
/* The same without a message: 0, or -1 when s is not one. */
int cli_whole(const char *s, uint32_t lo, uint32_t hi, uint32_t *out);
/* One number of a tuple: its name in messages, its range and an
 * optional hint on what to type instead. */
typedef struct cli_field {
  const char *name;
  cli_range range;
  const char *hint;
} cli_field;
/* n (<= 8) numbers joined by commas, `form` ("AZ,EL,DIST") naming them
 * in messages; a bad one is named by its field. */
int cli_parse_tuple(const char *cmd, const char *option, const char *s,
                    const char *form, const cli_field *fields, int n,
                    float *out);
/* --camera AZ,EL,DIST (rp_camera_orbit): AZ in [-360, 360] and EL in
 * [-90, 90] degrees, DIST in (0, 2 RP_CAMERA_DISTANCE_MAX] radii. */
int cli_parse_orbit(const char *cmd, const char *option, const char *s,
                    float orbit[3]);
/* "WxH": each side in 1..RP_IMAGE_MAX_DIM and W x H at most
 * RP_IMAGE_MAX_PIXELS. */
int cli_parse_size(const char *cmd, const char *option, const char *s,
                   uint32_t *w, uint32_t *h);
/* --budget-mb (megabytes, 2^20 bytes, in [0.001, 1e9]) and --brick-size
 * (a power of two in [8, 256], rp_device_desc.brick_size) into mem. */
int cli_parse_budget_mb(const char *cmd, const char *option, const char *s,
                        cli_memory *mem);
int cli_parse_brick_size(const char *cmd, const char *option, const char *s,
                         cli_memory *mem);
/* The work bound (RP_MAX_SAMPLES_PER_RAY, RP_MAX_SAMPLES_PER_FRAME) for
 * `step` (named by step_option, "--step") on vol at width x height and
 * image scale `scale` (0: 1), checked once the volume is open and
 * before any device work, naming the options rather than the library's
 * fields. */
int cli_check_work(const char *cmd, const char *step_option,
                   const rp_volume *vol, float step, uint32_t width,
                   uint32_t height, float scale);
/* A file the command will write: in an existing, writable directory,
 * not a directory itself, and (exts non-NULL: a NULL-terminated list
 * such as ".png") ending in one of exts, whatever the case. */
int cli_check_output(const char *cmd, const char *option, const char *path,
                     const char *const *exts);
/* --backend NAME: one of the backends raypace knows (whether it was
 * compiled in is rp_device_create's to say). */
int cli_check_backend(const char *cmd, const char *name);
/* Backend "mpi" device `index`, named by OPTION VALUE: refused unless
 * this process is rank 0 of an MPI job with a rank index + 1. */
int cli_check_mpi(const char *cmd, const char *option, const char *value,
                  uint32_t index);
/* The device options render and replay share (--backend, --device,
 * --devices, --budget-mb, --brick-size), pointing into each command's
 * options. */
typedef struct cli_device_opts {
  const char **backend;
  uint32_t *device;
  int *device_given;
  const char **devices_spec;
  rp_device_desc *devices; /* RP_GROUP_MAX_DEVICES of each */
  struct cli_device_ext *ext;
  uint32_t *ndevices;
  cli_memory *mem;
} cli_device_opts;
/* Points d into options struct *o, which has fields of these names
 * (render's and replay's). */
#define CLI_DEVICE_OPTS_OF(o, d)                                          \
  ((d)->backend = &(o)->backend, (d)->device = &(o)->device,             \
   (d)->device_given = &(o)->device_given,                               \
   (d)->devices_spec = &(o)->devices_spec, (d)->devices = (o)->devices,  \
   (d)->ext = (o)->device_ext, (d)->ndevices = &(o)->ndevices,           \
   (d)->mem = &(o)->mem)
/* Option c of d ('B' --backend, 'D' --device, 'L' --devices, 'M'
 * --budget-mb, 'Z' --brick-size) = arg, checked; 0 or 2 (printed). */
int cli_parse_device_option(const char *cmd, int c, const char *option,
                            const char *arg, const cli_device_opts *d);
/* Once every option is parsed: --devices excludes --backend and
 * --device, an "mpi" device needs its MPI rank, and the memory options
 * apply to every device of the list. 0 or 2 (printed). */
int cli_check_devices(const char *cmd, const cli_device_opts *d);
/* The MPI job's size as rp_mpi_init gave it (main calls this); without
 * it cli_check_mpi reads the launcher's environment. */
void cli_set_mpi_world(int size);

/* Prints how `dev` holds its volume, when out of core, after `prefix`. */
void cli_print_bricks(const rp_device *dev, const char *prefix);

/* Opens `backend`'s device `index`, or the first backend with a device;
 * with none at all (and nothing named), the reference, saying so on
 * stderr: an app would rather get a slow image than none. The error
 * names what was typed for it: `option` (the backend's option, such as
 * "--backend") and the backend, --device, and for a failure other than
 * a missing device the memory options. Returns 0 or 1 (error printed). */
int cli_open_device(rp_context *ctx, const char *option, const char *backend,
                    uint32_t index, const cli_memory *mem, rp_device **dev);
/* The extension structs a device spec may ask for (raypace_testing.h),
 * stored next to its rp_device_desc, whose `next` points into them. */
typedef struct cli_device_ext {
  rp_fault_desc faults;
  rp_test_backend_desc test;
} cli_device_ext;
/* Parses a device list "SPEC[,SPEC...]",
 * SPEC = BACKEND[:INDEX][:cu=N][:slow=S][:fail=F][:seed=N][:noise=X]
 * (BACKEND opencl, vulkan, reference, test or mpi, whose device INDEX is
 * MPI rank INDEX + 1 under mpirun; INDEX default 0; cu = compute units
 * of a sub-device, rp_device_desc.compute_units; slow =
 * rp_fault_desc.slowdown; fail = rp_fault_desc.fail_at_render; seed and
 * noise, for backend test only, rp_test_backend_desc.seed and noise_sd,
 * noise=0 meaning none) into out[0..*n), with the extension structs in
 * ext[0..*n) (out[i].next points into ext[i]; NULL when the spec asks for
 * none). At most `max`. On a bad spec prints "OPTION: ..." naming the bad
 * part to stderr and returns RP_EINVAL. INDEX, if given, comes right
 * after BACKEND; the key=value fields follow in any order, each at most
 * once (cu in 1..65536, slow in [1, 10000], fail >= 0 where 0 is never,
 * seed in 0..2^32-1, noise in [0, 1]). A bad number reads as
 * cli_bad_option's ("raypace: OPTION SPEC: KEY VALUE is out of range;
 * must be ..."), the other errors "raypace: OPTION: ...".
 * out[i].backend points to a static string. */
int cli_parse_devices(const char *option, const char *spec,
                      rp_device_desc *out, cli_device_ext *ext,
                      uint32_t max, uint32_t *n);
/* Median of n > 0 values; sorts them in place. */
double cli_median(double *v, int n);
/* The p-quantile (0 < p <= 1) of n values by nearest rank: the smallest
 * of them with at least p n values at or under it, v[ceil(p n) - 1]
 * once sorted (p n within 1e-9 of a whole number counts as that
 * number, so that 0.95 x 20 is 19). No interpolation: every quantile is
 * a frame that happened. Sorts v in place; NaN for n = 0. */
double cli_quantile(double *v, int n, double p);
/* The controller's colour in every plot ("#rrggbb"), the same whatever
 * else a plot draws; black for a kind out of range. */
const char *cli_controller_colour(rp_controller_kind kind);
/* Adds a figure to a JSON object (cJSON): null where it does not exist
 * (NaN or infinite), as JSON has no such numbers. */
struct cJSON;
void cli_json_figure(struct cJSON *o, const char *name, double v);
/* Prints `root` formatted on stdout and deletes it; 0, or 1 when it could
 * not be printed (out of memory). */
int cli_print_json(struct cJSON *root);
/* Writes s as a gnuplot single-quoted literal ('' is a quote), so that a
 * path cannot end the string or inject commands. */
void cli_gnuplot_string(FILE *g, const char *s);
/* 1 if a gnuplot command is on the PATH: checked before a long run that
 * ends in a plot. */
int cli_have_gnuplot(void);
/* A gnuplot to write commands to. SIGPIPE is ignored from open to close:
 * a gnuplot that dies early must not kill us. */
typedef struct cli_plot {
  FILE *g;
  void (*sigpipe)(int); /* the handler to put back */
} cli_plot;
/* 0, or 1 with "<who>: --plot: cannot run gnuplot" on stderr. */
int cli_plot_open(cli_plot *p, const char *who);
/* Waits for gnuplot; 0, or 1 with its status on stderr. */
int cli_plot_close(cli_plot *p, const char *who);
/* Seconds from a monotonic clock. */
double cli_now(void);
/* rp_progress_fn drawing a bar on stderr when it is a terminal; `user`
 * is the label (a string). */
void cli_progress(double fraction, void *user);
/* Writes premultiplied RGBA8 as a binary PPM (P6) composited over
 * `background` (RGB in [0, 1]) as rp_write_png composites: the same
 * pixels, in a form a script reads without a decoder. 0, or 1 with the
 * error printed naming the path. */
int cli_write_ppm(const char *path, const uint8_t *rgba, uint32_t width,
                  uint32_t height, const float background[3]);
/* Prints "raypace: <what>: <rp_strerror>: <last error>" to stderr. */
int cli_error(rp_context *ctx, const char *what, int err);

/* What --tf, --window and --level asked for. */
typedef struct cli_tf {
  const char *spec; /* a preset name or a TF file; NULL: by the volume */
  int windowed;     /* bit 0: --window given, bit 1: --level */
  double window, level;
} cli_tf;
/* The TF name to use on `vol`: spec, or ct-bone for signed (HU) data and
 * minmax-bone otherwise. */
const char *cli_tf_name(const rp_volume *vol, const cli_tf *tf);
/* Parses --window (is_width: a width > 0) or --level into tf. */
int cli_parse_window(const char *cmd, cli_tf *tf, int is_width,
                     const char *s);
/* Builds the TF (a preset or a file, then the window when given); 0, or
 * 1 with the error printed. */
int cli_make_tf(rp_context *ctx, const rp_volume *vol, const cli_tf *tf,
                rp_tf **out);

#endif
