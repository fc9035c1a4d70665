/* raypace render's options: what they hold once parsed and checked
 * (render_opts.c). */
#ifndef RP_CLI_RENDER_OPTS_H
#define RP_CLI_RENDER_OPTS_H

#include "cli_util.h"
#include "raypace_ao.h"
#include "raypace_group.h"

typedef struct render_opts {
  const char *volume, *out, *tf, *backend; /* tf: set with the volume */
  int ppm; /* -o names a .ppm: written as binary PPM, else PNG */
  cli_tf tfo;
  const char *view; /* an rp_view name; NULL: anterior for a volume whose
                       orientation is known, else the orbit */
  int orbit_given;
  float orbit[3], background[3], fov, step, ert_threshold, scale;
  uint32_t device;
  uint32_t width, height;
  int ortho, shading, ert, skip, json, ao, no_jitter, preint;
  uint32_t seed;
  int device_given, overlay;
  rp_ao_scheme ao_scheme;
  uint32_t warmup;
  const char *devices_spec;
  rp_device_desc devices[RP_GROUP_MAX_DEVICES];
  cli_device_ext device_ext[RP_GROUP_MAX_DEVICES]; /* devices[i].next */
  uint32_t ndevices;
  cli_memory mem;
} render_opts;

/* Parses and checks `raypace render`'s options (argv[0] = "render"):
 * every value against its range, every combination, the output's
 * directory and form, before any work. 0; 1 after --help (printed on
 * stdout); 2 for a bad option (printed: the option, the value and what
 * it must be). */
int cli_parse_render(int argc, char **argv, render_opts *o);

#endif
