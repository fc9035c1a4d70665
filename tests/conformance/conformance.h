/* Backend conformance, written once and run per backend: what its files
 * share. One binary (test_conformance.c has main), registered by ctest
 * once per backend with RP_BACKEND=reference|test|opencl|vulkan; it exits 77
 * when that backend has no device here.
 *
 * The tolerances are the contract's (backends/README.md): per image, at
 * most 0.1 % of pixels more than 2/255 off in any channel and none more
 * than 8/255; per 8x8 tile, samples within one per ray of the
 * reference's, rays hit within two, and the mean depth within 1e-3
 * relative plus one step where the rays hit agree; volume fetches held to
 * the reference's count as rp_test_check_fetches states; depth-pass
 * values and ERT terminations as tests/conformance/passes.c states; AO
 * voxels within 2/255 on >= 99.9 % of voxels and none over 8/255. */
#ifndef RP_CONFORMANCE_H
#define RP_CONFORMANCE_H

#include <stdint.h>

#include "ao.h"
#include "passes.h"
#include "raypace_ao.h"
#include "raypace_backend.h"
#include "raypace_testing.h"
#include "test_util.h"
#include "variant_cache.h"

/* The context and the device of the backend under test (main's). */
extern rp_context *ctx;
extern rp_device *dev;

/* RP_BACKEND, or "reference". */
const char *backend_name(void);

/* ---- scenes -------------------------------------------------------------- */

typedef struct scene {
  const char *name;
  rp_volume *vol;
  rp_histograms *h;
} scene;

/* A generated volume (seed 3) and its histograms. */
scene make_scene(const char *name, rp_generator kind, uint32_t x,
                 uint32_t y, uint32_t z, rp_voxel_type type);
/* `vol` (taken over) and its histograms. */
scene scene_of(const char *name, rp_volume *vol);
void drop_scene(scene *s);

/* Two dense balls in air, far apart in a volume of 8x7x6 blocks: most
 * blocks are empty (even after the occupancy's dilation), and there is an
 * empty run between the balls. */
rp_volume *sparse_volume(void);
/* A uint16 volume of at most 19 x 7 x 3 voxels, spacing (1, 0.5, 2),
 * values spread over the range: the thin and tiny cases. */
rp_volume *thin_volume(const uint32_t dims[3]);
/* Partly opaque at every value, reference step 2. */
rp_tf *solid_tf(void);

/* A scene under a transfer function, with its occupancy. */
typedef struct lit_scene {
  scene s;
  rp_tf *tf;
  rp_occupancy *occ;
} lit_scene;

/* Takes `s` and `tf` over and builds the occupancy. */
lit_scene lit(scene s, rp_tf *tf);
void unlit(lit_scene *l);

/* Uploads the scene to `d`, failing the test on an error. */
void device_scene(rp_device *d, const scene *s, const rp_tf *tf,
                  const rp_occupancy *occ);

/* ---- cameras ------------------------------------------------------------- */

enum {
  CAM_OUTSIDE,  /* perspective, from outside */
  CAM_GRAZING,  /* looking along a face: rays skim the box */
  CAM_ZOOMED,   /* a narrow field of view */
  CAM_INSIDE,   /* inside the volume */
  CAM_ORTHO,    /* orthographic, oblique */
  CAMERAS,      /* the five above are the matrices' */
  CAM_AXIS = CAMERAS, /* orthographic along x: ray components exactly 0 */
  CAM_INSIDE2,  /* inside again, from another side */
  CAM_AWAY,     /* looking away: every ray misses */
  CAM_KINDS
};
rp_camera camera(const rp_volume *vol, int kind);
const char *camera_name(int kind);

/* ---- images -------------------------------------------------------------- */

/* Accumulated over one volume's matrix, or over one image. */
typedef struct tally {
  uint64_t fetches, fetches_off; /* reference's; off beyond samples */
  uint64_t pixels, over2, compared_tiles;
  int worst;
  char worst_at[160];
} tally;

/* Adds an image's pixels to `t` and holds its tiles to the reference's
 * (failing at once: samples, rays hit, mean depth). */
void compare(tally *t, const char *what, const uint8_t *got,
             const uint8_t *want, const rp_tile_stats *gt,
             const rp_tile_stats *wt, uint32_t w, uint32_t h, float step);
/* Holds the pixels of `t` to the tolerance; prints a line unless quiet. */
void finish(const tally *t, const char *name, int quiet);

/* One render on `dev` and on the reference (rp__reference_render, with
 * `ao` when not NULL), compared into `t`; with count_fetches, the tiles'
 * fetches too. */
void check_render(tally *t, const scene *s, const rp_tf *tf,
                  const rp_occupancy *occ, const rp_ao *ao,
                  const rp_camera *cam, const rp_render_desc *d,
                  const char *what, int count_fetches);
/* check_render, copying the device's image, tiles and (with
 * count_fetches) fetches out too, where not NULL: the scaled image's
 * pixels and tile grid. */
void check_render_out(tally *t, const scene *s, const rp_tf *tf,
                      const rp_occupancy *occ, const rp_ao *ao,
                      const rp_camera *cam, const rp_render_desc *d,
                      const char *what, int count_fetches, uint8_t *rgba,
                      rp_tile_stats *tiles, uint64_t *fetches);
/* check_render of one image, held to the tolerance on its own. */
void check_image(const scene *s, const rp_tf *tf, const rp_occupancy *occ,
                 const rp_camera *cam, const rp_render_desc *d,
                 const char *what);

/* ---- the backend without its front end ----------------------------------- */

/* This backend's device 0 opened bare (rp__backend_open): its ops, as the
 * front end drives them. */
typedef struct bare {
  const rp_backend_ops *ops;
  void *impl;
  rp_caps caps;
} bare;

/* Opens it, with errors on `c`; 0, or RP_EUNSUPPORTED when this backend
 * has no ops to open (the reference renders in the front end), which the
 * caller reports and skips. */
int bare_open(rp_context *c, bare *b);
void bare_close(bare *b);
/* Uploads volume, TF and occupancy, as rp_device_set_* would. */
void bare_upload(const bare *b, const scene *s, const rp_tf *tf,
                 const rp_occupancy *occ);
/* A frame as the front end builds it: `d` resolved in place, rays at the
 * scaled size in `rg`, the kernels' form in `p`. */
void bare_frame(const scene *s, const rp_tf *tf, const rp_occupancy *occ,
                const rp_camera *cam, rp_render_desc *d, rp__raygen *rg,
                rp_frame_params *p);
/* The front end's order: the depth pass, then the raycast of the whole
 * scaled image; tiles and fetches may be NULL. */
void bare_render(const bare *b, const rp_frame_params *p, uint8_t *rgba,
                 rp_tile_stats *tiles, uint64_t *fetches);
/* The backend's kernel-variant cache figures (variant_cache.h); 0 when
 * it keeps none (then the caller says so and skips). */
int variant_stats(const bare *b, rp_variant_stats *st);

/* ---- the tests, one file per area ---------------------------------------- */

/* images.c */
void matrix_phantom_u8(void **state);
void matrix_marschner_lobb_u16(void **state);
void matrix_noise(void **state);
void matrix_float(void **state);
void matrix_ct_head_s16(void **state);
void matrix_thin_shell_u16(void **state);
void matrix_real_volumes(void **state);
void odd_viewports_and_scales(void **state);
void views_and_steps(void **state);
void scenes_from_three_cameras(void **state);
void thin_volumes(void **state);
/* jitter.c */
void jitter_seeds(void **state);
/* passes.c */
void depth_pass(void **state);
void ert_prepass(void **state);
void regions_compose(void **state);
void fetch_counts(void **state);
/* occlusion.c */
void ao_volume(void **state);
void ao_render(void **state);
void ao_state(void **state);
/* kernels.c */
void prepare_no_volume(void **state);
void prepare_builds_ahead(void **state);
void prepare_ao(void **state);
void prepare_concurrent(void **state);
void variant_cache(void **state);

#endif /* RP_CONFORMANCE_H */
