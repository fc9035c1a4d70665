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
/* Parses "WxH" (each 1..16384). */
int cli_parse_size(const char *s, uint32_t *w, uint32_t *h);
/* Parses a decimal integer in [0, max] (no sign). */
int cli_parse_u32(const char *s, uint32_t max, uint32_t *out);
/* Parses n comma-separated floats, refusing values a float cannot hold. */
int cli_parse_floats(const char *s, float *out, int n);
/* Parses one float > 0: the library reads 0 as "default", so a 0 typed on
 * the command line must not silently become one. */
int cli_parse_positive(const char *s, float *out);
/* Out-of-core options (--budget-mb, --brick-size), shared by render and
 * replay: zeros mean the device's defaults. */
typedef struct cli_memory {
  uint64_t budget_bytes;
  uint32_t brick_size;
} cli_memory;
/* Parses --budget-mb (megabytes, 2^20 bytes, > 0) and --brick-size;
 * returns 0 or 1 (the caller reports the bad value). */
int cli_parse_budget_mb(const char *s, uint64_t *bytes);
/* Prints how `dev` holds its volume, when out of core, after `prefix`. */
void cli_print_bricks(const rp_device *dev, const char *prefix);

/* Opens `backend`'s device `index`, or the first backend with a device;
 * with none at all (and nothing named), the reference, saying so on
 * stderr: an app would rather get a slow image than none. `option` names
 * the command-line option in the error. Returns 0 or 1 (error printed). */
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
 * seed in 0..2^32-1, noise in [0, 1]). The message reads "raypace:
 * OPTION: ...", as cli_error's do. out[i].backend points to a static
 * string. */
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
/* Parses --window (is_width) or --level into tf; 1 when bad. */
int cli_parse_window(cli_tf *tf, int is_width, const char *s);
/* Builds the TF (a preset or a file, then the window when given); 0, or
 * 1 with the error printed. */
int cli_make_tf(rp_context *ctx, const rp_volume *vol, const cli_tf *tf,
                rp_tf **out);

#endif
