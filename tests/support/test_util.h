/* Helpers shared by the cmocka tests. */
#ifndef RP_TEST_UTIL_H
#define RP_TEST_UTIL_H

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "raypace.h"
#include "raypace_testing.h"

/* The shared data folder (RP_SHARED_DATA), or NULL when it is absent: tests
 * that need real volumes call skip() then. */
const char *rp_test_data_dir(void);
/* Path of a shared volume's sidecar "<dir>/<name>/<name>.txt" in `buf`;
 * returns NULL when the folder or the file is absent. */
const char *rp_test_data_volume(const char *name, char *buf, size_t len);
/* The data set names in the shared folder (sidecar present), NULL-ended;
 * empty when absent. Static storage. */
const char *const *rp_test_data_names(void);
/* A scratch directory for files a test writes (created if missing). */
const char *rp_test_tmp_dir(void);
/* Writes `len` bytes to tmp/<name>, returns the full path (static buffer
 * rotated over 8 calls). */
const char *rp_test_write_file(const char *name, const void *data,
                               size_t len);
/* A context with defaults; asserts on failure. */
rp_context *rp_test_context(void);
/* Whether `backend` has a device here: the tests that need one skip
 * otherwise. */
int rp_test_has_device(const char *backend);
/* A transfer-function preset; asserts on failure. */
rp_tf *rp_test_preset(rp_context *ctx, const char *name);
/* A half-transparent ramp of 256 entries whose alpha is given per
 * `ref_step` voxels, so that a step other than ref_step exercises the
 * opacity correction; asserts on failure. */
rp_tf *rp_test_ramp_tf(rp_context *ctx, float ref_step);
/* A generated volume; asserts on failure. */
rp_volume *rp_test_generate(rp_context *ctx, rp_generator kind, uint32_t x,
                            uint32_t y, uint32_t z, rp_voxel_type type,
                            uint32_t seed);
/* A smooth float field with negative values and anisotropic spacing
 * (1, 1.5, 0.8): two blobs of opposite sign over a gentle slope,
 * 37x30x26. */
rp_volume *rp_test_float_field(rp_context *ctx);
/* A float blob, 21x18x25 with spacing (1, 1.3, 0.8), from -3.5 in the
 * corners to 96.5 at the centre: gradients and lighting vary
 * everywhere. */
rp_volume *rp_test_float_blob(rp_context *ctx);

/* Holds a device's per-tile volume fetches (its counting variant) to the
 * reference's (rp__reference_render), failing the test with `what` and
 * the tile otherwise. per_visible = rp_test_visible_fetches(effects) is
 * the fetches each sample with opacity above 0 adds: 6 with shading, 1
 * with AO, 7 with both, 0 with neither; with RP_EFFECT_PREINT each ray
 * that samples adds one more (rays_hit per tile), taken off first.
 * - structure: one fetch per sample, per_visible more per visible one,
 *   so samples <= fetches <= (1 + per_visible) samples and the excess is
 *   a multiple of per_visible;
 * - per tile: within (1 + per_visible) per sample the tile's sample count
 *   differs from the reference's by (a tile's samples are within one per
 *   ray), plus per_visible per ray (a sample whose opacity is 0 in float
 *   and not in double);
 * - per frame: within 0.1 % of the reference's fetches beyond what the
 *   sample differences explain.
 * Adds the reference's fetches to *total and the excess to *off. */
void rp_test_check_fetches(const char *what, const rp_tile_stats *got,
                           const uint64_t *got_fetches,
                           const rp_tile_stats *want,
                           const uint64_t *want_fetches, size_t tiles,
                           uint32_t effects, uint64_t *total,
                           uint64_t *off);

/* Asserts that `got` (w x h RGBA8) is, bit for bit, the reference
 * raycaster's image of `vol` under `tf` from `cam` with `effects` at full
 * quality, with `ao` (RP_EFFECT_AO added) or without (NULL), its rays
 * jittered with `jitter_seed` (the frame's rp_frame_stats.jitter_seed; 0:
 * jitter off): the oracle outside the runtime that runtime tests hold
 * frames to. */
void rp_test_expect_reference(rp_context *ctx, const rp_volume *vol,
                              const rp_tf *tf, const rp_ao *ao,
                              const rp_camera *cam, uint32_t w, uint32_t h,
                              uint32_t effects, uint32_t jitter_seed,
                              const uint8_t *got);

/* The per_visible of rp_test_check_fetches for an effects set. */
unsigned rp_test_visible_fetches(uint32_t effects);

/* A generated uint8 volume of n^3 voxels with its histograms, a preset
 * TF and the occupancy built for them (each call asserts success). */
typedef struct rp_test_scene {
  rp_volume *vol;
  rp_histograms *h;
  rp_tf *tf;
  rp_occupancy *occ;
} rp_test_scene;
rp_test_scene rp_test_scene_make(rp_context *ctx, rp_generator kind,
                                 uint32_t n, uint32_t seed, const char *tf);
void rp_test_scene_drop(rp_test_scene *s);

/* Gives the device `d` will open the faults in `f` (raypace_testing.h):
 * sets f's header and chains f onto d->next. */
void rp_test_faults(rp_device_desc *d, rp_fault_desc *f);

/* ---- Volume files ------------------------------------------------------ */

/* Writes `text` then `n` payload bytes into tmp/<name>; the path as
 * rp_test_write_file gives it. */
const char *rp_test_write_with(const char *name, const char *text,
                               const void *payload, size_t n);
/* Voxel i of a test pattern in each type, negative where signed, every
 * value exact in the type (float32 included). */
double rp_test_pattern(rp_voxel_type t, int i);
/* Asserts that `v` holds rp_test_pattern(t, i) at every voxel i, with
 * these dims and spacing, type t, and the pattern's range. */
void rp_test_check_pattern(const rp_volume *v, rp_voxel_type t,
                           const uint32_t dims[3], const float spacing[3]);
/* Loads `path`, failing the test with the loader's message otherwise. */
rp_volume *rp_test_load_ok(rp_context *ctx, const char *path);
/* The load fails with `code`, leaves *out alone, and the message names
 * every one of the NULL-ended strings after `code` (the file, the field,
 * the value). */
void rp_test_load_fails(rp_context *ctx, const char *path, int code, ...);
/* Voxel i of `vol` in data units (the stored value plus its offset). */
double rp_test_voxel(const rp_volume *vol, size_t i);
/* Asserts the volume's orientation is known and matches `direction`
 * (columns: axis j's unit vector at 3 j) and `origin` within `tol`. */
void rp_test_expect_orientation(const rp_volume *vol,
                                const double direction[9],
                                const double origin[3], double tol);
/* Asserts the volume's orientation is not known: the identity, origin
 * zero. */
void rp_test_expect_no_orientation(const rp_volume *vol);

#endif
