/* Images against rp_render_reference, the scalar oracle, over a matrix
 * of volumes, transfer functions, effects, cameras, viewports, image
 * scales and steps (steps other than the TF's own exercise the opacity
 * correction), with conformance.h's tolerance. */
#include <stdio.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "conformance.h"

static const char *const tfs[] = {"minmax-bone", "transparent", "opaque",
                                  "nearly-transparent", "mri"};
#define TFS 5
/* AO appears twice, with every other effect, pre-integration off and
 * on: each set is a kernel variant to build per voxel type, and AO alone
 * (without shading) is held to the reference in occlusion.c. */
static const uint32_t effect_sets[] = {
    0, RP_EFFECT_SHADING, RP_EFFECT_ERT, RP_EFFECT_SKIP,
    RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP,
    RP_EFFECT_PREINT,
    RP_EFFECT_PREINT | RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP,
    RP_EFFECT_AO | RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP,
    RP_EFFECT_AO | RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP |
        RP_EFFECT_PREINT};
#define EFFECT_SETS 9
#define EFFECT_SETS_NO_AO 7 /* the first seven */

/* AO settings small enough for the reference to compute per TF. */
static const rp_ao_desc conformance_ao = {6, 4, 4.0f, 1.0f, 0};

/* The device's AO of the scene under `tf` against the reference's, by
 * the contract's tolerance (backends/README.md): within 2/255 on at
 * least 99.9 % of voxels, none over 8/255. Returns the reference's, the
 * one both sides then render with, so that image differences are the
 * raycast's alone. */
static rp_ao *check_ao(const scene *s, const rp_tf *tf) {
  rp_ao_plan *plan = NULL;
  rp_ao *want = NULL, *got = NULL;
  const uint8_t *a, *b;
  size_t n = s->vol->voxel_count, i, over2 = 0;
  int worst = 0;
  assert_int_equal(rp_ao_compute_reference(ctx, s->vol, tf, &conformance_ao,
                                           NULL, NULL, &want),
                   0);
  assert_int_equal(rp_ao_plan_create(ctx, s->vol, tf, &conformance_ao,
                                     &plan),
                   0);
  if (rp_ao_compute(ctx, &dev, 1, plan, NULL, &got, NULL) != 0)
    fail_msg("%s: AO on %s: %s", s->name, backend_name(),
             rp_last_error(ctx));
  a = rp_ao_data(got, NULL);
  b = rp_ao_data(want, NULL);
  for (i = 0; i < n; i++) {
    int d = abs((int)a[i] - (int)b[i]);
    over2 += d > 2;
    worst = d > worst ? d : worst;
  }
  if (worst > 8 || over2 * 1000 > n)
    fail_msg("%s: AO: worst %d/255, %zu of %zu voxels over 2/255", s->name,
             worst, over2, n);
  rp_ao_destroy(got);
  rp_ao_plan_destroy(plan);
  if (rp_device_set_ao(dev, want) != 0)
    fail_msg("%s: set_ao: %s", s->name, rp_last_error(ctx));
  return want;
}

/* The device's AO of the box [lo, end) against the reference's voxels,
 * for volumes too large for the reference to compute whole per TF. */
static void check_ao_box(const scene *s, const rp_tf *tf) {
  rp_ao_plan *plan = NULL;
  uint32_t lo[3], end[3], a;
  size_t n, i, over2 = 0;
  uint8_t *got, *want;
  int worst = 0;
  for (a = 0; a < 3; a++) {
    uint32_t d = s->vol->dims[a], len = d < 24 ? d : 24;
    lo[a] = (d - len) / 2;
    end[a] = lo[a] + len;
  }
  n = (size_t)(end[0] - lo[0]) * (end[1] - lo[1]) * (end[2] - lo[2]);
  got = malloc(n);
  want = malloc(n);
  assert_true(got && want);
  assert_int_equal(rp_ao_plan_create(ctx, s->vol, tf, &conformance_ao,
                                     &plan),
                   0);
  if (rp_device_compute_ao(dev, plan, lo, end, got) != 0)
    fail_msg("%s: AO on %s: %s", s->name, backend_name(),
             rp_last_error(ctx));
  rp__ao_reference_box(s->vol, tf, plan, lo, end, lo[2], end[2], want);
  for (i = 0; i < n; i++) {
    int d = abs((int)got[i] - (int)want[i]);
    over2 += d > 2;
    worst = d > worst ? d : worst;
  }
  if (worst > 8 || over2 * 1000 > n)
    fail_msg("%s: AO box: worst %d/255, %zu of %zu voxels over 2/255",
             s->name, worst, over2, n);
  free(got);
  free(want);
  rp_ao_plan_destroy(plan);
}

/* with_ao: 1 the AO volume compared and the AO effect sets rendered; 0
 * only a central box of AO compared (large volumes). */
static void run_matrix_of(scene *s, const char *const *names, int ntfs,
                          uint32_t w, uint32_t h, int full, int with_ao) {
  tally t = {0};
  int ti, e, c;
  rp_ao *ao = NULL;
  assert_int_equal(rp_device_set_volume(dev, s->vol), 0);
  for (ti = 0; ti < ntfs; ti++) {
    rp_tf *tf = NULL;
    rp_occupancy *occ = NULL;
    assert_int_equal(rp_tf_create_preset(ctx, names[ti], &tf), 0);
    assert_int_equal(rp_occupancy_build(ctx, s->h, tf, &occ), 0);
    if (rp_device_set_tf(dev, tf, occ) != 0)
      fail_msg("set_tf: %s", rp_last_error(ctx));
    if (with_ao)
      ao = check_ao(s, tf);
    else
      check_ao_box(s, tf);
    for (e = 0; e < (with_ao ? EFFECT_SETS : EFFECT_SETS_NO_AO); e++) {
      for (c = 0; c < CAMERAS; c++) {
        rp_camera cam = camera(s->vol, c);
        rp_render_desc d = {0};
        char what[160];
        /* The full cross product on the first TF; the others with every
         * effect set from two cameras, which is where they differ. */
        if (!full && c > 1)
          continue;
        if (ti > 0 && c != 0 && c != 3)
          continue;
        d.width = w, d.height = h, d.effects = effect_sets[e];
        snprintf(what, sizeof what, "%s tf %s effects 0x%x camera %s",
                 s->name, names[ti], effect_sets[e], camera_name(c));
        check_render(&t, s, tf, occ, ao, &cam, &d, what, c == 0);
      }
    }
    rp_ao_destroy(ao);
    ao = NULL;
    rp_occupancy_destroy(occ);
    rp_tf_destroy(tf);
  }
  assert_int_equal(rp_device_set_ao(dev, NULL), 0);
  finish(&t, s->name, 0);
}

static void run_matrix(scene *s, uint32_t w, uint32_t h, int full,
                       int with_ao) {
  run_matrix_of(s, tfs, TFS, w, h, full, with_ao);
}

/* A thin spherical shell (4 voxels thick, 12-bit values with
 * partial-volume edges; air around it: with an opaque box face, jittered
 * rays that clip a corner by less than a step take one sample or none
 * depending on float against double rounding, docs/sampling.md) in an odd-sized uint16 grid with anisotropic
 * spacing: thin features under steep presets are where float rounding of
 * positions and values shows first. */
void matrix_thin_shell_u16(void **state) {
  static const char *const names[] = {"minmax-bone", "opaque", "ramp",
                                      "ct-bone"};
  const uint32_t nx = 45, ny = 39, nz = 51;
  rp_volume_desc d = {{nx, ny, nz}, RP_U16, {1.0f, 1.25f, 0.8f}, NULL,
                      {0}};
  uint16_t *vox = malloc((size_t)nx * ny * nz * 2);
  rp_volume *vol = NULL;
  uint32_t x, y, z;
  scene s;
  (void)state;
  assert_non_null(vox);
  for (z = 0; z < nz; z++)
    for (y = 0; y < ny; y++)
      for (x = 0; x < nx; x++) {
        double dx = (x - 22.0) * 1.0, dy = (y - 19.0) * 1.25;
        double dz = (z - 25.0) * 0.8;
        double r = sqrt(dx * dx + dy * dy + dz * dz);
        /* the data's maximum over a 2-voxel plateau, 1-voxel edges */
        double e = fmin(1.0, 2.0 - fabs(r - 16.0));
        vox[((size_t)z * ny + y) * nx + x] =
            (uint16_t)(e > 0.0 ? 1024.0 + 3000.0 * e : 0.0);
      }
  d.data = vox;
  assert_int_equal(rp_volume_create(ctx, &d, &vol), 0);
  free(vox);
  s = scene_of("thin shell 45x39x51 u16", vol);
  run_matrix_of(&s, names, 4, 24, 20, 1, 0);
  run_matrix_of(&s, names, 4, 96, 80, 0, 0);
  drop_scene(&s);
}

/* Signed data: the CT head in HU, int16, on an odd grid, under the HU
 * presets (windows in data units, stored values offset by 32768) and the
 * percentile-placed mri preset. */
void matrix_ct_head_s16(void **state) {
  static const char *const hu[] = {"ct-bone", "ct-soft", "ct-lung",
                                   "ct-angio", "mri"};
  scene s = make_scene("CT head 37x41x31 int16", RP_GEN_CT_HEAD, 37, 41, 31,
                       RP_S16);
  (void)state;
  run_matrix_of(&s, hu, 5, 24, 20, 1, 1);
  /* Larger images from two cameras: where one rare mismatch shows. */
  run_matrix_of(&s, hu, 5, 96, 80, 0, 0);
  drop_scene(&s);
}

void matrix_phantom_u8(void **state) {
  scene s = make_scene("phantom 48^3 u8", RP_GEN_PHANTOM, 48, 48, 48, RP_U8);
  (void)state;
  run_matrix(&s, 32, 24, 1, 1);
  drop_scene(&s);
}

void matrix_marschner_lobb_u16(void **state) {
  scene s = make_scene("Marschner-Lobb 41x37x29 u16", RP_GEN_MARSCHNER_LOBB,
                       41, 37, 29, RP_U16);
  (void)state;
  run_matrix(&s, 24, 20, 1, 1);
  drop_scene(&s);
}

void matrix_noise(void **state) {
  scene s = make_scene("noise 23x17x30 u8", RP_GEN_NOISE, 23, 17, 30, RP_U8);
  (void)state;
  run_matrix(&s, 20, 16, 0, 1);
  drop_scene(&s);
}

/* Float voxels: Marschner-Lobb rescaled to [-3, 5]. */
void matrix_float(void **state) {
  scene s = make_scene("ML 33x20x26 float", RP_GEN_MARSCHNER_LOBB, 33, 20,
                       26, RP_U16);
  rp_volume_desc d = {0};
  rp_volume *fv = NULL;
  size_t i, n = (size_t)33 * 20 * 26;
  float *vox = malloc(n * sizeof *vox);
  const uint16_t *src = rp_volume_data(s.vol);
  (void)state;
  assert_non_null(vox);
  for (i = 0; i < n; i++)
    vox[i] = -3.0f + 8.0f * src[i] / 65535.0f;
  d.dims[0] = 33, d.dims[1] = 20, d.dims[2] = 26, d.type = RP_F32;
  d.data = vox;
  d.spacing[0] = 1.0f, d.spacing[1] = 1.5f, d.spacing[2] = 0.75f;
  assert_int_equal(rp_volume_create(ctx, &d, &fv), 0);
  free(vox);
  drop_scene(&s);
  s.vol = fv;
  assert_int_equal(rp_histograms_build(ctx, fv, &s.h), 0);
  run_matrix(&s, 24, 18, 0, 1);
  drop_scene(&s);
}

/* 1x1, 7x513 and a 0.5 image scale, every effect set, three steps. */
void odd_viewports_and_scales(void **state) {
  static const uint32_t sizes[][2] = {{1, 1}, {7, 513}, {40, 30}, {9, 2}};
  static const float scales[] = {1.0f, 1.0f, 0.5f, 1.0f};
  static const float steps[] = {0.0f, 0.37f, 2.6f};
  scene s = make_scene("phantom 40x33x21", RP_GEN_PHANTOM, 40, 33, 21, RP_U8);
  rp_tf *tf = NULL;
  rp_occupancy *occ = NULL;
  tally t = {0};
  size_t v;
  int e, c;
  (void)state;
  assert_int_equal(rp_device_set_volume(dev, s.vol), 0);
  assert_int_equal(rp_tf_create_preset(ctx, "minmax-soft", &tf), 0);
  assert_int_equal(rp_occupancy_build(ctx, s.h, tf, &occ), 0);
  assert_int_equal(rp_device_set_tf(dev, tf, occ), 0);
  for (v = 0; v < sizeof sizes / sizeof sizes[0]; v++)
    for (e = 0; e < EFFECT_SETS_NO_AO; e++)
      for (c = 0; c < CAMERAS; c += 2) {
        rp_camera cam = camera(s.vol, c);
        rp_render_desc d = {0};
        char what[160];
        d.width = sizes[v][0], d.height = sizes[v][1];
        d.image_scale = scales[v];
        d.effects = effect_sets[e];
        /* Steps other than the TF's reference step exercise opacity
         * correction; 0 is the default (1). */
        d.step = steps[(v + (uint32_t)e) % 3];
        snprintf(what, sizeof what, "%ux%u scale %g step %g effects 0x%x "
                 "camera %s", d.width, d.height, (double)d.image_scale,
                 (double)d.step, d.effects, camera_name(c));
        check_render(&t, &s, tf, occ, NULL, &cam, &d, what, 1);
      }
  finish(&t, "odd viewports", 0);
  rp_occupancy_destroy(occ);
  rp_tf_destroy(tf);
  drop_scene(&s);
}

/* Real volumes when ../shared/data is there: 8 and 16 bit, anisotropic. */
void matrix_real_volumes(void **state) {
  static const char *const names[] = {"bonsai", "headsq_ct",
                                      "vx_smallhead_ct"};
  size_t i;
  int any = 0;
  (void)state;
  for (i = 0; i < sizeof names / sizeof names[0]; i++) {
    char path[1024];
    scene s = {names[i], NULL, NULL};
    if (rp_test_data_volume(names[i], path, sizeof path) == NULL)
      continue;
    any = 1;
    if (rp_volume_load(ctx, path, &s.vol) != 0)
      fail_msg("%s: %s", path, rp_last_error(ctx));
    assert_int_equal(rp_histograms_build(ctx, s.vol, &s.h), 0);
    run_matrix(&s, 24, 24, 0, 0);
    drop_scene(&s);
  }
  if (!any)
    skip();
}

/* lit(s, tf), uploaded to the device. */
static lit_scene light(scene s, rp_tf *tf) {
  lit_scene l = lit(s, tf);
  device_scene(dev, &l.s, l.tf, l.occ);
  return l;
}

/* Views held to the tolerance image by image, not per volume: four voxel
 * types and layouts (8 and 16 bit, a float blob with anisotropic
 * spacing), four effect sets, three cameras, and views from one pixel to
 * one odd column, at half scale, at steps other than the TF's; then odd
 * viewports and a half-scale image whose rays cover the output frustum,
 * from outside and from inside. */
void views_and_steps(void **state) {
  static const uint32_t effects[] = {
      0, RP_EFFECT_SHADING, RP_EFFECT_ERT | RP_EFFECT_SKIP,
      RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP};
  static const int cams[] = {CAM_OUTSIDE, CAM_INSIDE, CAM_ORTHO};
  static const struct {
    uint32_t w, h;
    float scale, step;
  } views[] = {{40, 30, 0, 0},   {1, 1, 0, 0},      {7, 513, 0, 0.5f},
               {64, 48, 0.5f, 0}, {33, 17, 0, 0.3f}, {24, 24, 0, 2.7f},
               /* odd viewports: */
               {1, 1, 0, 1.0f},   {7, 513, 0, 1.0f}, {7, 513, 0, 0.5f},
               {96, 64, 0.5f, 1.0f}, {90, 61, 0.5f, 1.0f}};
  static const uint32_t odd_effects[] = {
      RP_EFFECT_SHADING | RP_EFFECT_SKIP,
      RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP, 0,
      RP_EFFECT_ERT | RP_EFFECT_SKIP, RP_EFFECT_SHADING};
  lit_scene l;
  int si, e, c, v, renders = 0;
  (void)state;
  for (si = 0; si < 4; si++) {
    l = si == 0 ? light(make_scene("phantom 48^3 u8", RP_GEN_PHANTOM, 48,
                                   48, 48, RP_U8),
                        rp_test_preset(ctx, "minmax-bone"))
        : si == 1 ? light(make_scene("Marschner-Lobb 41x37x29 u16",
                                     RP_GEN_MARSCHNER_LOBB, 41, 37, 29,
                                     RP_U16),
                          rp_test_preset(ctx, "mri"))
        : si == 2 ? light(make_scene("noise 23x17x30 u8", RP_GEN_NOISE, 23,
                                     17, 30, RP_U8),
                          rp_test_preset(ctx, "nearly-transparent"))
                  : light(scene_of("float blob", rp_test_float_blob(ctx)),
                          rp_test_preset(ctx, "minmax-soft"));
    for (e = 0; e < 4; e++)
      for (c = 0; c < 3; c++)
        for (v = 0; v < 6; v++) {
          rp_camera cam = camera(l.s.vol, cams[c]);
          rp_render_desc d = {0};
          char what[160];
          /* Every view from outside; one more from each other camera. */
          if (c > 0 && v != (c + e + si) % 6)
            continue;
          d.width = views[v].w, d.height = views[v].h;
          d.image_scale = views[v].scale;
          d.step = views[v].step;
          d.effects = effects[e];
          snprintf(what, sizeof what, "%s effects 0x%x camera %s view "
                   "%ux%u scale %g step %g", l.s.name, effects[e],
                   camera_name(cams[c]), d.width, d.height,
                   (double)d.image_scale, (double)d.step);
          check_image(&l.s, l.tf, l.occ, &cam, &d, what);
          renders++;
        }
    unlit(&l);
  }
  l = light(make_scene("phantom 48^3 u8", RP_GEN_PHANTOM, 48, 48, 48, RP_U8),
            rp_test_preset(ctx, "minmax-soft"));
  for (v = 6; v < 11; v++) {
    rp_camera cam =
        camera(l.s.vol, (v - 6) % 2 ? CAM_INSIDE2 : CAM_OUTSIDE);
    rp_render_desc d = {0};
    char what[160];
    d.width = views[v].w, d.height = views[v].h;
    d.image_scale = views[v].scale;
    d.step = views[v].step;
    d.effects = odd_effects[v - 6];
    snprintf(what, sizeof what, "odd viewport %ux%u scale %g effects 0x%x",
             d.width, d.height, (double)d.image_scale, d.effects);
    check_image(&l.s, l.tf, l.occ, &cam, &d, what);
    renders++;
  }
  unlit(&l);
  print_message("%s: %d views, each within the tolerance\n", backend_name(),
                renders);
}

/* Five scenes from outside, from inside and along an axis (rays with
 * exactly zero components), every effect set but AO, image by image:
 * the phantom, two balls in air (skipping has empty blocks and an empty
 * run between them to skip), Marschner-Lobb and a float field with
 * negative values under a ramp (the float one at step 0.7 against a
 * reference step of 2: the correction is live), and noise. */
void scenes_from_three_cameras(void **state) {
  static const int cams[] = {CAM_OUTSIDE, CAM_INSIDE2, CAM_AXIS};
  static const float steps[] = {1.0f, 1.0f, 1.0f, 0.7f, 1.0f};
  int si, c, e;
  (void)state;
  for (si = 0; si < 5; si++) {
    lit_scene l =
        si == 0 ? light(make_scene("phantom u8", RP_GEN_PHANTOM, 48, 48, 48,
                                   RP_U8),
                        rp_test_preset(ctx, "minmax-soft"))
        : si == 1 ? light(scene_of("sparse u8", sparse_volume()),
                          rp_test_ramp_tf(ctx, 1.0f))
        : si == 2 ? light(make_scene("Marschner-Lobb u16",
                                     RP_GEN_MARSCHNER_LOBB, 41, 37, 29,
                                     RP_U16),
                          rp_test_ramp_tf(ctx, 1.0f))
        : si == 3 ? light(scene_of("float32", rp_test_float_field(ctx)),
                          rp_test_ramp_tf(ctx, 2.0f))
                  : light(make_scene("noise u8", RP_GEN_NOISE, 40, 40, 40,
                                     RP_U8),
                          rp_test_preset(ctx, "mri"));
    if (si == 1)
      assert_true(rp_occupancy_empty_blocks(l.occ) > 100);
    for (c = 0; c < 3; c++)
      for (e = 0; e < EFFECT_SETS_NO_AO; e++) {
        rp_camera cam = camera(l.s.vol, cams[c]);
        rp_render_desc d = {0};
        char what[160];
        d.width = 48, d.height = 40;
        d.step = steps[si];
        d.effects = effect_sets[e];
        snprintf(what, sizeof what, "%s camera %s effects 0x%x step %g",
                 l.s.name, camera_name(cams[c]), d.effects,
                 (double)d.step);
        check_image(&l.s, l.tf, l.occ, &cam, &d, what);
      }
    unlit(&l);
  }
}

/* Volumes one voxel thick along some axes, and one of a single voxel:
 * every neighbour a kernel's layout stores is clamped, and the block
 * grid is one block. Opaque at every value (a single-valued volume sits
 * at x = 0), at a quarter step. */
void thin_volumes(void **state) {
  static const uint32_t dims[3][3] = {{1, 1, 1}, {1, 7, 3}, {19, 1, 2}};
  static const int cams[] = {CAM_OUTSIDE, CAM_INSIDE2, CAM_AXIS};
  int v, c;
  (void)state;
  for (v = 0; v < 3; v++) {
    lit_scene l = light(scene_of("thin volume", thin_volume(dims[v])),
                        solid_tf());
    for (c = 0; c < 3; c++) {
      rp_camera cam = camera(l.s.vol, cams[c]);
      rp_render_desc d = {0};
      char what[160];
      d.width = 24, d.height = 20, d.step = 0.25f;
      d.effects = RP_EFFECT_SHADING | RP_EFFECT_SKIP | RP_EFFECT_ERT;
      snprintf(what, sizeof what, "thin volume %ux%ux%u camera %s",
               dims[v][0], dims[v][1], dims[v][2], camera_name(cams[c]));
      check_image(&l.s, l.tf, l.occ, &cam, &d, what);
    }
    unlit(&l);
  }
}
