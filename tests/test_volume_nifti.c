/* NIfTI-1 and NIfTI-2 volumes: files written here with nifticlib (.nii,
 * .nii.gz, .hdr/.img pairs, both versions) and one written byte by byte
 * (big-endian, scaled), loaded and compared with the values the test
 * computed: voxels, type, spacing, range, orientation in LPS. Then
 * malformed files, each refused with its code and a message that names
 * the file and the field, and nothing printed by nifticlib. */
#include "test_util.h"

#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <nifti2_io.h>
#include <zlib.h>

#define NX 3
#define NY 2
#define NZ 4
#define NV (NX * NY * NZ)

static const uint32_t test_dims[3] = {NX, NY, NZ};

/* The rotated grid of the NRRD and MetaImage tests, in LPS: axis 0 runs
 * anterior (-y), axis 1 left (+x), axis 2 superior (+z). */
static const double turned_lps[9] = {0, -1, 0, 1, 0, 0, 0, 0, 1};
static const float turned_spacing[3] = {2.0f, 1.5f, 3.0f};

static const struct {
  int code;
  rp_voxel_type type;
} types[] = {{DT_UINT8, RP_U8},   {DT_INT8, RP_S8},     {DT_INT16, RP_S16},
             {DT_UINT16, RP_U16}, {DT_INT32, RP_S32},   {DT_UINT32, RP_U32},
             {DT_FLOAT32, RP_F32}, {DT_FLOAT64, RP_F32}};

/* Stores x as voxel i of a buffer of NIfTI type `code`. */
static void put(void *data, int code, size_t i, double x) {
  uint8_t *p = data;
  switch (code) {
  case DT_UINT8: p[i] = (uint8_t)x; break;
  case DT_INT8: { int8_t v = (int8_t)x; memcpy(p + i, &v, 1); break; }
  case DT_INT16: { int16_t v = (int16_t)x; memcpy(p + 2 * i, &v, 2); break; }
  case DT_UINT16: { uint16_t v = (uint16_t)x; memcpy(p + 2 * i, &v, 2); break; }
  case DT_INT32: { int32_t v = (int32_t)x; memcpy(p + 4 * i, &v, 4); break; }
  case DT_UINT32: { uint32_t v = (uint32_t)x; memcpy(p + 4 * i, &v, 4); break; }
  case DT_FLOAT32: { float v = (float)x; memcpy(p + 4 * i, &v, 4); break; }
  default: memcpy(p + 8 * i, &x, 8); break;
  }
}

/* A nifti_image of the pattern of `type` (nt volumes along t), stored as
 * `code`, spacing 0.5 x 2 x 1.25 and no transform. */
static nifti_image *make_image(int code, rp_voxel_type type, int64_t nt) {
  int64_t dims[8] = {nt > 1 ? 4 : 3, NX, NY, NZ, nt, 1, 1, 1};
  nifti_image *nim = nifti_make_new_nim(dims, code, 1);
  int64_t i;
  assert_non_null(nim);
  for (i = 0; i < NV * nt; i++)
    put(nim->data, code, (size_t)i, rp_test_pattern(type, (int)(i % NV)));
  nim->pixdim[1] = nim->dx = 0.5;
  nim->pixdim[2] = nim->dy = 2.0;
  nim->pixdim[3] = nim->dz = 1.25;
  nim->qform_code = nim->sform_code = 0;
  return nim;
}

/* Writes nim as tmp/<name>, NIfTI-1 (one file, or a pair for .hdr);
 * the path. Debian's nifticlib 3.0.1 writes NIfTI-2 wrongly (a single
 * file's data over its header, a pair as NIfTI-1): test_nifti2_handmade
 * writes those by hand. */
static const char *write_image(nifti_image *nim, const char *name) {
  static char path[8][1024];
  static int next;
  char *p = path[next++ % 8];
  int two = strstr(name, ".hdr") != NULL || strstr(name, ".img") != NULL;
  snprintf(p, 1024, "%s/%s", rp_test_tmp_dir(), name);
  assert_int_equal(nifti_set_filenames(nim, p, 0, 1), 0);
  nim->nifti_type = two ? NIFTI_FTYPE_NIFTI1_2 : NIFTI_FTYPE_NIFTI1_1;
  nifti_image_write(nim);
  return p;
}

static const float pix_spacing[3] = {0.5f, 2.0f, 1.25f};

static void test_nifti_types(void **state) {
  rp_context *ctx = rp_test_context();
  char name[64];
  size_t t;
  (void)state;
  for (t = 0; t < sizeof types / sizeof types[0]; t++) {
    nifti_image *nim = make_image(types[t].code, types[t].type, 1);
    rp_volume *v;
    snprintf(name, sizeof name, "nii_type%zu.nii", t);
    v = rp_test_load_ok(ctx, write_image(nim, name));
    rp_test_check_pattern(v, types[t].type, test_dims, pix_spacing);
    rp_test_expect_no_orientation(v);
    rp_volume_destroy(v);
    nifti_image_free(nim);
  }
  rp_context_destroy(ctx);
}

/* The same int16 volume in every container nifticlib writes. */
static void test_nifti_containers(void **state) {
  static const struct {
    const char *name, *load;
  } files[] = {{"nii_c1.nii.gz", "nii_c1.nii.gz"},
               {"nii_pair1.hdr", "nii_pair1.hdr"},
               {"nii_pair1b.hdr", "nii_pair1b.img"},
               {"nii_pairz.hdr.gz", "nii_pairz.hdr.gz"},
               {"nii_pairzb.hdr.gz", "nii_pairzb.img.gz"}};
  rp_context *ctx = rp_test_context();
  char path[1024];
  size_t f;
  (void)state;
  for (f = 0; f < sizeof files / sizeof files[0]; f++) {
    nifti_image *nim = make_image(DT_INT16, RP_S16, 1);
    rp_volume *v;
    write_image(nim, files[f].name);
    snprintf(path, sizeof path, "%s/%s", rp_test_tmp_dir(), files[f].load);
    v = rp_test_load_ok(ctx, path);
    rp_test_check_pattern(v, RP_S16, test_dims, pix_spacing);
    rp_volume_destroy(v);
    nifti_image_free(nim);
  }
  rp_context_destroy(ctx);
}

/* A quaternion turning 90 degrees about z: (b, c, d) = (0, 0, sin 45). */
static void set_turned_qform(nifti_image *nim) {
  nim->qform_code = NIFTI_XFORM_SCANNER_ANAT;
  nim->quatern_b = 0.0;
  nim->quatern_c = 0.0;
  nim->quatern_d = sqrt(0.5);
  nim->qfac = 1.0;
  nim->qoffset_x = 10.0;
  nim->qoffset_y = 20.0;
  nim->qoffset_z = 30.0;
  nim->pixdim[1] = nim->dx = 2.0;
  nim->pixdim[2] = nim->dy = 1.5;
  nim->pixdim[3] = nim->dz = 3.0;
}

/* An sform whose columns are (RAS) axis 0 = (0,0,-2), axis 1 = (1,0,0),
 * axis 2 = (0,0.5,0), offset (-5,6,7). */
static void set_sform(nifti_image *nim, double shear) {
  static const double m[3][4] = {
      {0, 1, 0, -5}, {0, 0, 0.5, 6}, {-2, 0, 0, 7}};
  int i, j;
  nim->sform_code = NIFTI_XFORM_ALIGNED_ANAT;
  memset(&nim->sto_xyz, 0, sizeof nim->sto_xyz);
  for (i = 0; i < 3; i++)
    for (j = 0; j < 4; j++)
      nim->sto_xyz.m[i][j] = m[i][j];
  nim->sto_xyz.m[0][2] = shear;
  nim->sto_xyz.m[3][3] = 1.0;
}

static void test_nifti_orientation(void **state) {
  /* The qform: rotation R (z, 90 degrees) times pixdim (2, 1.5, 3): RAS
   * columns (0,2,0), (-1.5,0,0), (0,0,3); in LPS the turned grid. The
   * origin (10,20,30) RAS is (-10,-20,30) LPS. */
  static const double q_origin[3] = {-10, -20, 30};
  /* The sform in LPS: (0,0,-2) -> (0,0,-1), length 2; (1,0,0) ->
   * (-1,0,0), length 1; (0,0.5,0) -> (0,-1,0), length 0.5; the origin
   * (-5,6,7) -> (5,-6,7). */
  static const double s_dir[9] = {0, 0, -1, -1, 0, 0, 0, -1, 0};
  static const double s_origin[3] = {5, -6, 7};
  static const float s_spacing[3] = {2.0f, 1.0f, 0.5f};
  rp_context *ctx = rp_test_context();
  nifti_image *nim;
  rp_volume *v;
  (void)state;
  nim = make_image(DT_UINT8, RP_U8, 1);
  set_turned_qform(nim);
  v = rp_test_load_ok(ctx, write_image(nim, "nii_q.nii"));
  rp_test_check_pattern(v, RP_U8, test_dims, turned_spacing);
  rp_test_expect_orientation(v, turned_lps, q_origin, 1e-6);
  rp_volume_destroy(v);
  /* Both: the sform wins. */
  set_sform(nim, 0.0);
  v = rp_test_load_ok(ctx, write_image(nim, "nii_qs.hdr"));
  rp_test_check_pattern(v, RP_U8, test_dims, s_spacing);
  rp_test_expect_orientation(v, s_dir, s_origin, 1e-12);
  rp_volume_destroy(v);
  /* A sheared sform falls back to the qform. */
  set_sform(nim, 0.3);
  v = rp_test_load_ok(ctx, write_image(nim, "nii_shear_q.nii"));
  rp_test_expect_orientation(v, turned_lps, q_origin, 1e-6);
  rp_volume_destroy(v);
  /* ... and without one it is refused, naming the sform. */
  nim->qform_code = 0;
  rp_test_load_fails(ctx, write_image(nim, "nii_shear.nii"), RP_ERANGE,
                     "nii_shear.nii", "sform", "orthogonal", NULL);
  /* The sform alone, no qform. */
  set_sform(nim, 0.0);
  v = rp_test_load_ok(ctx, write_image(nim, "nii_s.nii"));
  rp_test_expect_orientation(v, s_dir, s_origin, 1e-6);
  rp_volume_destroy(v);
  nifti_image_free(nim);
  rp_context_destroy(ctx);
}

/* Voxels of a loaded volume against `want`, of the expected type. */
static void expect_values(const rp_volume *v, rp_voxel_type type,
                          const double want[NV]) {
  rp_volume_info info;
  int i;
  rp_volume_get_info(v, &info);
  assert_int_equal(info.type, type);
  for (i = 0; i < NV; i++)
    if (rp_test_voxel(v, (size_t)i) != want[i])
      fail_msg("voxel %d = %.9g, want %.9g", i, rp_test_voxel(v, (size_t)i),
               want[i]);
}

/* Loads the pattern of `type` written with slope and intercept, and
 * checks the values slope * p + inter in `want_type`. */
static void scaled_case(rp_context *ctx, int code, rp_voxel_type type,
                        double slope, double inter, rp_voxel_type want_type) {
  nifti_image *nim = make_image(code, type, 1);
  double want[NV];
  rp_volume *v;
  int i, plain = slope == 0.0 || (slope == 1.0 && inter == 0.0);
  nim->scl_slope = slope;
  nim->scl_inter = inter;
  for (i = 0; i < NV; i++) {
    double x = plain ? rp_test_pattern(type, i)
                     : slope * rp_test_pattern(type, i) + inter;
    want[i] = want_type == RP_F32 ? (double)(float)x : x;
  }
  v = rp_test_load_ok(ctx, write_image(nim, "nii_scaled.nii"));
  expect_values(v, want_type, want);
  rp_volume_destroy(v);
  nifti_image_free(nim);
}

static void test_nifti_scaling(void **state) {
  rp_context *ctx = rp_test_context();
  (void)state;
  /* CT's usual: integers in, HU out, still int16. */
  scaled_case(ctx, DT_INT16, RP_S16, 2.0, -1024.0, RP_S16);
  scaled_case(ctx, DT_UINT8, RP_U8, 1.0, -100.0, RP_S16);
  /* A fraction, or results past int16: float32. */
  scaled_case(ctx, DT_INT16, RP_S16, 0.5, 0.0, RP_F32);
  scaled_case(ctx, DT_INT16, RP_S16, 100.0, 3.0, RP_F32);
  scaled_case(ctx, DT_FLOAT32, RP_F32, 4.0, 1.0, RP_F32);
  /* Slope 0, and (1, 0): no scaling, the stored type. */
  scaled_case(ctx, DT_UINT16, RP_U16, 0.0, 55.0, RP_U16);
  scaled_case(ctx, DT_UINT16, RP_U16, 1.0, 0.0, RP_U16);
  rp_context_destroy(ctx);
}

static void test_nifti_float64_and_4d(void **state) {
  rp_context *ctx = rp_test_context();
  nifti_image *nim;
  rp_volume *v;
  double bad;
  (void)state;
  nim = make_image(DT_FLOAT64, RP_F32, 1);
  bad = NAN;
  memcpy((double *)nim->data + 7, &bad, sizeof bad);
  rp_test_load_fails(ctx, write_image(nim, "nii_nan.nii"), RP_ENOTFINITE,
                     "nii_nan.nii", "voxel 7", NULL);
  ((double *)nim->data)[7] = 1e300; /* finite, but not as a float */
  rp_test_load_fails(ctx, write_image(nim, "nii_big.nii"), RP_ENOTFINITE,
                     "nii_big.nii", "voxel 7", NULL);
  nifti_image_free(nim);
  /* 4D with one volume: accepted. */
  nim = make_image(DT_UINT8, RP_U8, 1);
  nim->ndim = nim->dim[0] = 4;
  nim->nt = nim->dim[4] = 1;
  v = rp_test_load_ok(ctx, write_image(nim, "nii_4d1.nii"));
  rp_test_check_pattern(v, RP_U8, test_dims, pix_spacing);
  rp_volume_destroy(v);
  nifti_image_free(nim);
  nim = make_image(DT_UINT8, RP_U8, 2);
  rp_test_load_fails(ctx, write_image(nim, "nii_4d2.nii"),
                     RP_EUNSUPPORTED, "nii_4d2.nii", "3 x 2 x 4 x 2", NULL);
  nifti_image_free(nim);
  rp_context_destroy(ctx);
}

/* ---- A header written byte by byte ----------------------------------- */

static void put_be(uint8_t *h, size_t at, const void *v, size_t n) {
  size_t i;
  for (i = 0; i < n; i++)
    h[at + i] = ((const uint8_t *)v)[n - 1 - i];
}

static void be16(uint8_t *h, size_t at, int16_t v) { put_be(h, at, &v, 2); }
static void be32f(uint8_t *h, size_t at, float v) { put_be(h, at, &v, 4); }

/* A big-endian NIfTI-1 of the int16 pattern, scaled by (1, -1024), with
 * an sform (code 2) swapping x and y and a 3 mm z; `edit` may spoil it
 * before it is written. Returns the file's size. */
static size_t handmade(uint8_t *file, void (*edit)(uint8_t *h)) {
  static const float srow[3][4] = {
      {0, 0.8f, 0, 1}, {-0.8f, 0, 0, 2}, {0, 0, 3, 3}};
  int32_t size = 348;
  int i, j;
  memset(file, 0, 352 + NV * 2);
  put_be(file, 0, &size, 4);
  be16(file, 40, 3);
  be16(file, 42, NX);
  be16(file, 44, NY);
  be16(file, 46, NZ);
  be16(file, 70, DT_INT16);
  be16(file, 72, 16);
  for (i = 0; i < 4; i++)
    be32f(file, 76 + 4 * (size_t)i, 1.0f);
  be32f(file, 108, 352.0f);
  be32f(file, 112, 1.0f);     /* scl_slope */
  be32f(file, 116, -1024.0f); /* scl_inter */
  be16(file, 254, 2);         /* sform_code */
  for (i = 0; i < 3; i++)
    for (j = 0; j < 4; j++)
      be32f(file, 280 + 16 * (size_t)i + 4 * (size_t)j, srow[i][j]);
  memcpy(file + 344, "n+1", 4);
  for (i = 0; i < NV; i++)
    be16(file, 352 + 2 * (size_t)i, (int16_t)rp_test_pattern(RP_S16, i));
  if (edit != NULL)
    edit(file);
  return 352 + NV * 2;
}

static void test_nifti_handmade(void **state) {
  /* sform columns (RAS): (0,-0.8,0), (0.8,0,0), (0,0,3); LPS: (0,0.8,0)
   * -> (0,1,0), (-0.8,0,0) -> (-1,0,0), (0,0,1); origin (1,2,3) ->
   * (-1,-2,3). Spacing 0.8, 0.8, 3 (as floats: the file's). */
  static const double dir[9] = {0, 1, 0, -1, 0, 0, 0, 0, 1};
  static const double origin[3] = {-1, -2, 3};
  rp_context *ctx = rp_test_context();
  uint8_t file[352 + NV * 2];
  double want[NV];
  rp_volume_info info;
  rp_volume *v;
  int i;
  (void)state;
  for (i = 0; i < NV; i++)
    want[i] = rp_test_pattern(RP_S16, i) - 1024.0;
  v = rp_test_load_ok(ctx, rp_test_write_file("nii_be.nii", file,
                                              handmade(file, NULL)));
  expect_values(v, RP_S16, want);
  rp_test_expect_orientation(v, dir, origin, 1e-6);
  rp_volume_get_info(v, &info);
  assert_true(info.spacing[0] == 0.8f && info.spacing[1] == 0.8f &&
              info.spacing[2] == 3.0f);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

/* A little-endian single-file NIfTI-2 of the uint16 pattern, written by
 * offsets (nifti2.h's layout), with the turned grid as its sform in
 * doubles and nt volumes; returns the file's size. */
static size_t handmade2(uint8_t *file, int64_t nt) {
  static const double srow[3][4] = {
      {0, -1.5, 0, 10}, {2, 0, 0, 20}, {0, 0, 3, 30}};
  const int64_t dim[8] = {nt > 1 ? 4 : 3, NX, NY, NZ, nt, 1, 1, 1};
  const int32_t size = 540, sform = 1;
  const int16_t type = DT_UINT16, bits = 16;
  const int64_t offset = 544;
  const double one = 1.0;
  int i, j;
  memset(file, 0, 544 + NV * 2 * (size_t)nt);
  memcpy(file, &size, 4);
  memcpy(file + 4, "n+2\0\r\n\032\n", 8);
  memcpy(file + 12, &type, 2);
  memcpy(file + 14, &bits, 2);
  memcpy(file + 16, dim, 64);
  for (i = 0; i < 4; i++)
    memcpy(file + 104 + 8 * i, &one, 8);
  memcpy(file + 168, &offset, 8);
  memcpy(file + 348, &sform, 4);
  for (i = 0; i < 3; i++)
    for (j = 0; j < 4; j++)
      memcpy(file + 400 + 32 * i + 8 * j, &srow[i][j], 8);
  for (i = 0; i < NV * nt; i++) {
    uint16_t v = (uint16_t)rp_test_pattern(RP_U16, i % NV);
    memcpy(file + 544 + 2 * i, &v, 2);
  }
  return 544 + NV * 2 * (size_t)nt;
}

static void test_nifti2_handmade(void **state) {
  /* The sform's columns (RAS) are (0,2,0), (-1.5,0,0), (0,0,3) and its
   * offset (10,20,30): the turned grid, origin (-10,-20,30) in LPS, in
   * doubles all the way. */
  static const double origin[3] = {-10, -20, 30};
  rp_context *ctx = rp_test_context();
  uint8_t file[544 + NV * 4];
  size_t n = handmade2(file, 1);
  char path[1024];
  gzFile gz;
  rp_volume *v;
  (void)state;
  v = rp_test_load_ok(ctx, rp_test_write_file("nii2_le.nii", file, n));
  rp_test_check_pattern(v, RP_U16, test_dims, turned_spacing);
  rp_test_expect_orientation(v, turned_lps, origin, 1e-12);
  rp_volume_destroy(v);
  snprintf(path, sizeof path, "%s/nii2_le.nii.gz", rp_test_tmp_dir());
  gz = gzopen(path, "wb");
  assert_non_null(gz);
  assert_int_equal(gzwrite(gz, file, (unsigned)n), (int)n);
  assert_int_equal(gzclose(gz), Z_OK);
  v = rp_test_load_ok(ctx, path);
  rp_test_check_pattern(v, RP_U16, test_dims, turned_spacing);
  rp_volume_destroy(v);
  n = handmade2(file, 2);
  rp_test_load_fails(ctx, rp_test_write_file("nii2_4d.nii", file, n),
                     RP_EUNSUPPORTED, "nii2_4d.nii", "3 x 2 x 4 x 2", NULL);
  rp_test_load_fails(ctx, rp_test_write_file("nii2_cut.nii", file, 300),
                     RP_ETRUNC, "nii2_cut.nii", "540", NULL);
  rp_context_destroy(ctx);
}

/* ---- Malformed files --------------------------------------------------- */

static void huge_dims(uint8_t *h) {
  be16(h, 42, 30000);
  be16(h, 44, 30000);
  be16(h, 46, 30000);
}
static void zero_dim(uint8_t *h) { be16(h, 44, 0); }
static void many_dims(uint8_t *h) { be16(h, 40, 9); }
static void complex_type(uint8_t *h) { be16(h, 70, DT_COMPLEX64); }
static void far_offset(uint8_t *h) { be32f(h, 108, 1e9f); }
static void bad_size(uint8_t *h) { memset(h, 'x', 4); }

typedef struct bad_nifti {
  const char *file;
  void (*edit)(uint8_t *h);
  size_t cut; /* bytes kept; 0: all */
  int code;
  const char *field, *value;
} bad_nifti;

static const bad_nifti bad_niftis[] = {
    {"nb_huge.nii", huge_dims, 0, RP_ERANGE, "dim", "30000"},
    {"nb_zero.nii", zero_dim, 0, RP_ERANGE, "dim[2]", "at least 1"},
    {"nb_ndim.nii", many_dims, 0, RP_EFORMAT, "dim[0]", "9"},
    {"nb_type.nii", complex_type, 0, RP_EUNSUPPORTED, "datatype",
     "COMPLEX64"},
    {"nb_offset.nii", far_offset, 0, RP_ETRUNC, "vox_offset", "1000000000"},
    {"nb_size.nii", bad_size, 0, RP_EFORMAT, "sizeof_hdr", "348"},
    {"nb_data.nii", NULL, 352 + NV * 2 - 5, RP_ETRUNC, "truncated",
     "48 bytes"},
    {"nb_header.nii", NULL, 100, RP_ETRUNC, "header truncated", "100"},
};

/* Runs f with stderr going to a file; returns how many bytes it got. */
static long stderr_bytes_during(void (*f)(rp_context *), rp_context *ctx) {
  char path[1024];
  struct stat st;
  int saved, fd;
  snprintf(path, sizeof path, "%s/nii_stderr.txt", rp_test_tmp_dir());
  fflush(stderr);
  saved = dup(2);
  fd = open(path, O_WRONLY | O_CREAT | O_TRUNC, 0644);
  assert_true(saved >= 0 && fd >= 0);
  dup2(fd, 2);
  close(fd);
  f(ctx);
  fflush(stderr);
  dup2(saved, 2);
  close(saved);
  assert_int_equal(stat(path, &st), 0);
  return (long)st.st_size;
}

static void malformed_cases(rp_context *ctx) {
  uint8_t file[352 + NV * 2];
  char path[1024];
  size_t i;
  for (i = 0; i < sizeof bad_niftis / sizeof bad_niftis[0]; i++) {
    const bad_nifti *c = &bad_niftis[i];
    size_t n = handmade(file, c->edit);
    rp_test_load_fails(ctx,
                       rp_test_write_file(c->file, file,
                                          c->cut != 0 ? c->cut : n),
                       c->code, c->file, c->field, c->value, NULL);
  }
  /* A pair whose .img is gone, and garbage after a gzip header. */
  {
    nifti_image *nim = make_image(DT_UINT8, RP_U8, 1);
    write_image(nim, "nb_pair.hdr");
    nifti_image_free(nim);
    snprintf(path, sizeof path, "%s/nb_pair.img", rp_test_tmp_dir());
    assert_int_equal(unlink(path), 0);
    snprintf(path, sizeof path, "%s/nb_pair.hdr", rp_test_tmp_dir());
    rp_test_load_fails(ctx, path, RP_ENOENT, "nb_pair.hdr", "nb_pair.img",
                       NULL);
  }
  {
    static const uint8_t gz[16] = {0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 3,
                                   0xff, 0xff, 0xff, 0xff, 0xff, 0xff};
    rp_test_load_fails(ctx, rp_test_write_file("nb_gz.nii.gz", gz, 16),
                       RP_EIO, "nb_gz.nii.gz", "gzip", NULL);
  }
}

static void test_nifti_malformed(void **state) {
  rp_context *ctx = rp_test_context();
  (void)state;
  /* Our messages say it all; nifticlib must not add its own. */
  assert_int_equal(stderr_bytes_during(malformed_cases, ctx), 0);
  rp_context_destroy(ctx);
}

/* A header within the context's byte limit loads; one byte less, the
 * limit refuses it before any voxel is read. */
static void test_nifti_limit(void **state) {
  rp_context_desc desc;
  rp_context *ctx = NULL;
  nifti_image *nim = make_image(DT_FLOAT64, RP_F32, 1);
  const char *path = write_image(nim, "nii_limit.nii");
  rp_volume *v;
  (void)state;
  memset(&desc, 0, sizeof desc);
  desc.max_volume_bytes = NV * 8; /* the float64 data, read before it
                                     becomes float32 */
  assert_int_equal(rp_context_create(&desc, &ctx), 0);
  v = rp_test_load_ok(ctx, path);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
  desc.max_volume_bytes = NV * 8 - 1;
  assert_int_equal(rp_context_create(&desc, &ctx), 0);
  rp_test_load_fails(ctx, path, RP_ERANGE, "nii_limit.nii", "dim",
                     "max_volume_bytes", NULL);
  rp_context_destroy(ctx);
  nifti_image_free(nim);
}

/* A real CT (the shared headsq_ct, uint16) written with nifticlib as
 * .nii.gz, with a qform, loads voxel for voxel as the raw file does: a
 * gzip stream of many chunks, at a real size. Skipped without the shared
 * data. */
static void test_nifti_real_ct(void **state) {
  rp_context *ctx;
  rp_volume *raw, *v;
  rp_volume_info info;
  int64_t dims[8] = {3, 0, 0, 0, 1, 1, 1, 1};
  nifti_image *nim;
  char path[1024];
  size_t bytes;
  int i;
  (void)state;
  if (rp_test_data_volume("headsq_ct", path, sizeof path) == NULL)
    skip();
  ctx = rp_test_context();
  raw = rp_test_load_ok(ctx, path);
  rp_volume_get_info(raw, &info);
  assert_int_equal(info.type, RP_U16);
  for (i = 0; i < 3; i++)
    dims[i + 1] = info.dims[i];
  nim = nifti_make_new_nim(dims, DT_UINT16, 0);
  assert_non_null(nim);
  bytes = (size_t)info.dims[0] * info.dims[1] * info.dims[2] * 2;
  nim->data = malloc(bytes);
  assert_non_null(nim->data);
  memcpy(nim->data, rp_volume_data(raw), bytes);
  set_turned_qform(nim);
  v = rp_test_load_ok(ctx, write_image(nim, "nii_ct.nii.gz"));
  rp_volume_get_info(v, &info);
  assert_int_equal(info.type, RP_U16);
  for (i = 0; i < 3; i++) {
    assert_int_equal(info.dims[i], dims[i + 1]);
    assert_true(info.spacing[i] == turned_spacing[i]);
  }
  assert_memory_equal(rp_volume_data(v), rp_volume_data(raw), bytes);
  rp_volume_destroy(v);
  rp_volume_destroy(raw);
  nifti_image_free(nim);
  rp_context_destroy(ctx);
}

/* A voxel size outside RP_SPACING_MIN/MAX, from pixdim or from an sform
 * column, is refused naming the file, the field and the value; the
 * limit itself loads. */
static void test_nifti_spacing_limits(void **state) {
  rp_context *ctx = rp_test_context();
  nifti_image *nim = make_image(DT_UINT8, RP_U8, 1);
  rp_volume *v;
  rp_volume_info info;
  (void)state;
  nim->pixdim[2] = nim->dy = 1e-30;
  rp_test_load_fails(ctx, write_image(nim, "nii_tiny.nii"), RP_ERANGE,
                     "nii_tiny.nii", "pixdim", "axis 2", "1e-30",
                     "[1e-09, 1e+09]", NULL);
  nim->pixdim[2] = nim->dy = 1e-9;
  v = rp_test_load_ok(ctx, write_image(nim, "nii_edge.nii"));
  rp_volume_get_info(v, &info);
  assert_true(info.spacing[1] == RP_SPACING_MIN);
  rp_volume_destroy(v);
  nim->pixdim[2] = nim->dy = 1.0;
  nim->sform_code = NIFTI_XFORM_SCANNER_ANAT;
  memset(&nim->sto_xyz, 0, sizeof nim->sto_xyz);
  nim->sto_xyz.m[0][0] = 1e12;
  nim->sto_xyz.m[1][1] = 1.0;
  nim->sto_xyz.m[2][2] = 1.0;
  nim->sto_xyz.m[3][3] = 1.0;
  rp_test_load_fails(ctx, write_image(nim, "nii_huge.nii"), RP_ERANGE,
                     "nii_huge.nii", "sform", "column 0", "1e+12", NULL);
  nifti_image_free(nim);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_nifti_types),
      cmocka_unit_test(test_nifti_containers),
      cmocka_unit_test(test_nifti_orientation),
      cmocka_unit_test(test_nifti_scaling),
      cmocka_unit_test(test_nifti_float64_and_4d),
      cmocka_unit_test(test_nifti_handmade),
      cmocka_unit_test(test_nifti2_handmade),
      cmocka_unit_test(test_nifti_malformed),
      cmocka_unit_test(test_nifti_limit),
      cmocka_unit_test(test_nifti_spacing_limits),
      cmocka_unit_test(test_nifti_real_ct),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
