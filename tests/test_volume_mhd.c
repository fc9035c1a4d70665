/* Orientation from NRRD's space fields, and MetaImage files (.mhd with a
 * detached data file, .mha with the data attached, raw or zlib, either
 * byte order), round trips and malformed files.
 *
 * Every expected value is worked out here: voxels from a formula encoded
 * byte by byte, orientations converted to LPS by hand in the comments. */
#include "test_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "volume_io.h"

/* 3 x 2 x 4 voxels: no two axes alike, so a swapped axis shows. */
#define NX 3
#define NY 2
#define NZ 4
#define NV (NX * NY * NZ)

static size_t type_bytes(rp_voxel_type t) {
  return t == RP_U8 || t == RP_S8 ? 1 : t == RP_U16 || t == RP_S16 ? 2 : 4;
}

/* The pattern as file bytes in the given byte order; returns the count. */
static size_t encode(rp_voxel_type t, int big, uint8_t *out) {
  size_t vs = type_bytes(t), b;
  int i;
  for (i = 0; i < NV; i++) {
    uint32_t bits;
    double x = rp_test_pattern(t, i);
    if (t == RP_F32) {
      float f = (float)x;
      memcpy(&bits, &f, 4);
    } else {
      bits = (uint32_t)(int64_t)x; /* two's complement of negatives */
    }
    for (b = 0; b < vs; b++) {
      size_t shift = big ? 8 * (vs - 1 - b) : 8 * b;
      out[(size_t)i * vs + b] = (uint8_t)(bits >> shift);
    }
  }
  return NV * vs;
}

/* Voxels, type, spacing and range of a loaded volume against the
 * pattern. */
static void check_pattern(const rp_volume *v, rp_voxel_type t,
                          const float spacing[3]) {
  static const uint32_t dims[3] = {NX, NY, NZ};
  rp_test_check_pattern(v, t, dims, spacing);
}

static const float unit[3] = {1.0f, 1.0f, 1.0f};

/* The rotated grid both the NRRD and the MetaImage tests use, in LPS:
 * axis 0 runs anterior (-y), axis 1 left (+x), axis 2 superior (+z). */
static const double turned_lps[9] = {0, -1, 0, 1, 0, 0, 0, 0, 1};
static const float turned_spacing[3] = {2.0f, 1.5f, 3.0f};

/* ---- NRRD space ---------------------------------------------------------- */

static const char *nrrd_u8(const char *name, const char *extra) {
  static char text[2048];
  uint8_t payload[NV];
  encode(RP_U8, 0, payload);
  snprintf(text, sizeof text,
           "NRRD0005\ntype: uchar\ndimension: 3\nsizes: %d %d %d\n"
           "encoding: raw\n%s\n",
           NX, NY, NZ, extra);
  return rp_test_write_with(name, text, payload, NV);
}

/* Loads an NRRD of the pattern with `extra` fields and checks voxels,
 * spacing and orientation. */
static void expect_nrrd(rp_context *ctx, const char *name, const char *extra,
                        const float spacing[3], const double direction[9],
                        const double origin[3]) {
  rp_volume *v = rp_test_load_ok(ctx, nrrd_u8(name, extra));
  check_pattern(v, RP_U8, spacing);
  rp_test_expect_orientation(v, direction, origin, 1e-12);
  rp_volume_destroy(v);
}

static void test_nrrd_space(void **state) {
  /* RAS, turned 90 degrees about the feet-head axis: axis 0 runs along
   * +A (RAS (0,2,0)), axis 1 along -R, i.e. towards the left (RAS
   * (-1.5,0,0)). LPS flips x and y: axis 0 (0,-2,0) -> unit (0,-1,0),
   * axis 1 (1.5,0,0) -> (1,0,0), axis 2 (0,0,3) -> (0,0,1); the origin
   * (10,20,30) -> (-10,-20,30). */
  static const double ras_origin[3] = {-10, -20, 30};
  /* LPS as written: nothing flips. */
  static const double lps_dir[9] = {0.6, 0.8, 0, -0.8, 0.6, 0, 0, 0, 1};
  static const double lps_origin[3] = {1.5, -2.5, 4};
  /* LAS: y flips only; the origin defaults to zero without the field. */
  static const double las_dir[9] = {1, 0, 0, 0, -1, 0, 0, 0, -1};
  static const double zero[3] = {0, 0, 0};
  static const float lps_spacing[3] = {1.0f, 1.0f, 0.5f};
  static const float las_spacing[3] = {0.5f, 0.5f, 2.0f};
  rp_context *ctx = rp_test_context();
  rp_volume_info info;
  rp_volume *v;
  (void)state;
  expect_nrrd(ctx, "sp_ras.nrrd",
              "space: right-anterior-superior\nspace directions: (0,2,0) "
              "(-1.5,0,0) (0,0,3)\nspace origin: (10,20,30)\n",
              turned_spacing, turned_lps, ras_origin);
  expect_nrrd(ctx, "sp_lps.nrrd",
              "space: LPS\nspace directions: (0.6,0.8,0) (-0.8,0.6,0) "
              "(0,0,0.5)\nspace origin: (1.5,-2.5,4)\n",
              lps_spacing, lps_dir, lps_origin);
  expect_nrrd(ctx, "sp_las.nrrd",
              "space: left-anterior-superior\nspace directions: (0.5,0,0) "
              "(0,0.5,0) (0,0,-2)\n",
              las_spacing, las_dir, zero);
  /* A frame that is not the patient's, and directions without any space:
   * spacing kept, orientation unknown. */
  v = rp_test_load_ok(ctx, nrrd_u8("sp_scanner.nrrd",
                                   "space: scanner-xyz\nspace directions: "
                                   "(0,2,0) (-1.5,0,0) (0,0,3)\n"));
  check_pattern(v, RP_U8, turned_spacing);
  rp_test_expect_no_orientation(v);
  rp_volume_destroy(v);
  v = rp_test_load_ok(ctx, nrrd_u8("sp_none.nrrd", "space directions: "
                                   "(0,2,0) (-1.5,0,0) (0,0,3)\n"));
  rp_volume_get_info(v, &info);
  assert_false(info.orientation.known);
  assert_true(info.spacing[1] == 1.5f);
  rp_volume_destroy(v);
  /* No space fields at all: unknown, the identity. */
  v = rp_test_load_ok(ctx, nrrd_u8("sp_plain.nrrd", ""));
  rp_test_expect_no_orientation(v);
  rp_volume_destroy(v);
  check_pattern(v = rp_test_load_ok(ctx, nrrd_u8("sp_dim.nrrd",
                                                 "space dimension: 3\n")),
                RP_U8, unit);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

static void test_nrrd_space_bad(void **state) {
  rp_context *ctx = rp_test_context();
  (void)state;
  rp_test_load_fails(ctx, nrrd_u8("spb_name.nrrd", "space: sideways\n"),
                     RP_EFORMAT, "spb_name.nrrd", "space", "sideways",
                     NULL);
  rp_test_load_fails(ctx, nrrd_u8("spb_time.nrrd",
                                  "space: right-anterior-superior-time\n"),
                     RP_EUNSUPPORTED, "spb_time.nrrd", "time", NULL);
  rp_test_load_fails(ctx, nrrd_u8("spb_shear.nrrd",
                                  "space: RAS\nspace directions: (1,0,0) "
                                  "(1,1,0) (0,0,1)\n"),
                     RP_ERANGE, "spb_shear.nrrd", "space directions",
                     "orthogonal", NULL);
  rp_test_load_fails(ctx, nrrd_u8("spb_comp.nrrd",
                                  "space: RAS\nspace directions: (1,0) "
                                  "(0,1) (1,1)\n"),
                     RP_EFORMAT, "spb_comp.nrrd", "space directions",
                     "components", NULL);
  rp_test_load_fails(ctx, nrrd_u8("spb_origin.nrrd",
                                  "space: RAS\nspace origin: (1,2)\n"),
                     RP_EFORMAT, "spb_origin.nrrd", "space origin", "(1,2)",
                     NULL);
  rp_test_load_fails(ctx, nrrd_u8("spb_orignan.nrrd",
                                  "space: RAS\nspace origin: (1,nan,2)\n"),
                     RP_ENOTFINITE, "spb_orignan.nrrd", "space origin",
                     NULL);
  rp_test_load_fails(ctx, nrrd_u8("spb_both.nrrd",
                                  "space: RAS\nspace dimension: 3\n"),
                     RP_EFORMAT, "spb_both.nrrd", "space dimension", NULL);
  rp_test_load_fails(ctx, nrrd_u8("spb_dim4.nrrd", "space dimension: 4\n"),
                     RP_EUNSUPPORTED, "spb_dim4.nrrd", "space dimension 4",
                     NULL);
  rp_context_destroy(ctx);
}

/* ---- MetaImage ----------------------------------------------------------- */

static const char *met_type(rp_voxel_type t) {
  switch (t) {
  case RP_U8: return "MET_UCHAR";
  case RP_S8: return "MET_CHAR";
  case RP_U16: return "MET_USHORT";
  case RP_S16: return "MET_SHORT";
  case RP_U32: return "MET_UINT";
  case RP_S32: return "MET_INT";
  default: return "MET_FLOAT";
  }
}

/* A MetaImage header for the pattern; `extra` lines go before
 * ElementDataFile, which comes last as the format wants. */
static const char *mhd_text(rp_voxel_type t, const char *extra,
                            const char *data_file) {
  static char text[2048];
  snprintf(text, sizeof text,
           "ObjectType = Image\nNDims = 3\nDimSize = %d %d %d\n"
           "ElementType = %s\n%sElementDataFile = %s\n",
           NX, NY, NZ, met_type(t), extra, data_file);
  return text;
}

static size_t zlib_bytes(const uint8_t *in, size_t n, uint8_t *out,
                         size_t cap) {
  uLongf len = (uLongf)cap;
  assert_int_equal(compress2(out, &len, in, (uLong)n, 9), Z_OK);
  return (size_t)len;
}

static void test_mhd_round_trip(void **state) {
  static const rp_voxel_type types[7] = {RP_U8,  RP_S8,  RP_U16, RP_S16,
                                         RP_U32, RP_S32, RP_F32};
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4 + 64], packed[NV * 8 + 64];
  char name[64], extra[256];
  int t, big;
  (void)state;
  for (t = 0; t < 7; t++) {
    for (big = 0; big < 2; big++) {
      size_t n = encode(types[t], big, payload), z;
      rp_volume *v;
      snprintf(extra, sizeof extra, "ElementByteOrderMSB = %s\n",
               big ? "True" : "False");
      /* .mha, data attached */
      snprintf(name, sizeof name, "mhd_%d_%d.mha", t, big);
      v = rp_test_load_ok(ctx, rp_test_write_with(name, mhd_text(types[t], extra,
                                                         "LOCAL"),
                                          payload, n));
      check_pattern(v, types[t], unit);
      rp_volume_destroy(v);
      /* .mhd naming a raw file beside it */
      snprintf(name, sizeof name, "mhd_%d_%d.raw", t, big);
      rp_test_write_file(name, payload, n);
      snprintf(extra, sizeof extra,
               "BinaryDataByteOrderMSB = %s\nElementSpacing = 0.5 2 1.25\n",
               big ? "True" : "False");
      v = rp_test_load_ok(ctx, rp_test_write_with("mhd_detached.mhd",
                                          mhd_text(types[t], extra, name),
                                          NULL, 0));
      {
        static const float sp[3] = {0.5f, 2.0f, 1.25f};
        check_pattern(v, types[t], sp);
      }
      rp_volume_destroy(v);
      /* zlib, with and without its size */
      z = zlib_bytes(payload, n, packed, sizeof packed);
      snprintf(extra, sizeof extra,
               "ElementByteOrderMSB = %s\nCompressedData = True\n"
               "CompressedDataSize = %zu\n",
               big ? "True" : "False", z);
      v = rp_test_load_ok(ctx, rp_test_write_with("mhd_z.mha",
                                          mhd_text(types[t], extra, "LOCAL"),
                                          packed, z));
      check_pattern(v, types[t], unit);
      rp_volume_destroy(v);
    }
  }
  rp_context_destroy(ctx);
}

static void test_mhd_header_size(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV + 100];
  rp_volume *v;
  (void)state;
  memset(payload, 0xab, 100);
  encode(RP_U8, 0, payload + 100);
  rp_test_write_file("mhs_skip.raw", payload, NV + 100);
  v = rp_test_load_ok(ctx, rp_test_write_with("mhs_skip.mhd",
                                      mhd_text(RP_U8, "HeaderSize = 100\n",
                                               "mhs_skip.raw"),
                                      NULL, 0));
  check_pattern(v, RP_U8, unit);
  rp_volume_destroy(v);
  /* -1: the data is the file's tail, whatever comes before it. */
  rp_test_write_file("mhs_tail.raw", payload + 37, NV + 63);
  v = rp_test_load_ok(ctx, rp_test_write_with("mhs_tail.mhd",
                                      mhd_text(RP_U8, "HeaderSize = -1\n",
                                               "mhs_tail.raw"),
                                      NULL, 0));
  check_pattern(v, RP_U8, unit);
  rp_volume_destroy(v);
  /* Without HeaderSize the leading bytes make the file too long. */
  rp_test_load_fails(ctx, rp_test_write_with("mhs_none.mhd",
                                     mhd_text(RP_U8, "", "mhs_skip.raw"),
                                     NULL, 0),
                     RP_EFORMAT, "mhs_skip.raw", "do not match", NULL);
  rp_context_destroy(ctx);
}

static void test_mhd_orientation(void **state) {
  /* ITK writes TransformMatrix in LPS, axis 0's vector first: the turned
   * grid as it is, and Offset the origin as it is. */
  static const double origin[3] = {-10, -20, 30};
  /* AnatomicalOrientation, ITK's way: each letter is where an axis comes
   * from. RAI: from the right (+x), from anterior (+y), from inferior
   * (+z): the identity. LPI: -x, -y, +z. */
  static const double identity[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  static const double lpi[9] = {-1, 0, 0, 0, -1, 0, 0, 0, 1};
  static const double zero[3] = {0, 0, 0};
  static const double offset_only[3] = {5, 6, 7};
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV];
  rp_volume *v;
  (void)state;
  encode(RP_U8, 0, payload);
  v = rp_test_load_ok(
      ctx, rp_test_write_with("mho_matrix.mha",
                      mhd_text(RP_U8,
                               "TransformMatrix = 0 -1 0 1 0 0 0 0 1\n"
                               "Offset = -10 -20 30\n"
                               "ElementSpacing = 2 1.5 3\n"
                               "AnatomicalOrientation = RAI\n",
                               "LOCAL"),
                      payload, NV));
  check_pattern(v, RP_U8, turned_spacing);
  rp_test_expect_orientation(v, turned_lps, origin, 1e-12);
  rp_volume_destroy(v);
  v = rp_test_load_ok(ctx, rp_test_write_with("mho_rai.mha",
                                      mhd_text(RP_U8,
                                               "AnatomicalOrientation = RAI\n",
                                               "LOCAL"),
                                      payload, NV));
  rp_test_expect_orientation(v, identity, zero, 0.0);
  rp_volume_destroy(v);
  v = rp_test_load_ok(ctx, rp_test_write_with("mho_lpi.mha",
                                      mhd_text(RP_U8,
                                               "Position = 5 6 7\n"
                                               "AnatomicalOrientation = LPI\n",
                                               "LOCAL"),
                                      payload, NV));
  rp_test_expect_orientation(v, lpi, offset_only, 0.0);
  rp_volume_destroy(v);
  /* "???" and an all-zero matrix say nothing. */
  v = rp_test_load_ok(ctx, rp_test_write_with("mho_unknown.mha",
                                      mhd_text(RP_U8,
                                               "TransformMatrix = 0 0 0 0 0 "
                                               "0 0 0 0\n"
                                               "AnatomicalOrientation = ???\n",
                                               "LOCAL"),
                                      payload, NV));
  rp_test_expect_no_orientation(v);
  rp_volume_destroy(v);
  rp_context_destroy(ctx);
}

/* One malformed MetaImage: header text, the pattern's uint8 bytes
 * appended (delta more or fewer; NO_DATA: none), the code and the words
 * the message must hold besides the file's name. */
#define NO_DATA 9999
typedef struct bad_mhd {
  const char *file;
  const char *text;
  int delta;
  int code;
  const char *field, *value;
} bad_mhd;

#define MHD_HEAD "ObjectType = Image\nNDims = 3\n"
#define MHD_U8 MHD_HEAD "DimSize = 3 2 4\nElementType = MET_UCHAR\n"

static const bad_mhd bad_mhds[] = {
    {"mb_short.mha", MHD_U8 "ElementDataFile = LOCAL\n", -1, RP_ETRUNC,
     "truncated", "24"},
    {"mb_long.mha", MHD_U8 "ElementDataFile = LOCAL\n", 5, RP_EFORMAT,
     "29 bytes", "3x2x4"},
    {"mb_type.mha",
     MHD_HEAD "DimSize = 3 2 4\nElementType = MET_DOUBLE\n"
              "ElementDataFile = LOCAL\n",
     0, RP_EUNSUPPORTED, "ElementType", "MET_DOUBLE"},
    {"mb_array.mha",
     MHD_HEAD "DimSize = 3 2 4\nElementType = MET_UCHAR_ARRAY\n"
              "ElementDataFile = LOCAL\n",
     0, RP_EUNSUPPORTED, "ElementType", "MET_UCHAR_ARRAY"},
    {"mb_huge.mha",
     MHD_HEAD "DimSize = 100000 100000 100000\nElementType = MET_UCHAR\n"
              "ElementDataFile = LOCAL\n",
     0, RP_ERANGE, "DimSize", "100000"},
    {"mb_zero.mha",
     MHD_HEAD "DimSize = 3 0 4\nElementType = MET_UCHAR\n"
              "ElementDataFile = LOCAL\n",
     0, RP_ERANGE, "DimSize", "3 0 4"},
    {"mb_dims2.mha",
     MHD_HEAD "DimSize = 3 2\nElementType = MET_UCHAR\n"
              "ElementDataFile = LOCAL\n",
     0, RP_EFORMAT, "DimSize", "3 2"},
    {"mb_ndims.mha",
     "NDims = 4\nDimSize = 3 2 4 1\nElementType = MET_UCHAR\n"
     "ElementDataFile = LOCAL\n",
     0, RP_EUNSUPPORTED, "NDims", "4"},
    {"mb_object.mha", "ObjectType = Tube\nNDims = 3\n", NO_DATA,
     RP_EUNSUPPORTED, "ObjectType", "Tube"},
    {"mb_nofile.mha", MHD_U8 "ElementSpacing = 1 1 1\n", NO_DATA,
     RP_EFORMAT, "missing", "ElementDataFile"},
    {"mb_notype.mha", MHD_HEAD "DimSize = 3 2 4\nElementDataFile = LOCAL\n",
     0, RP_EFORMAT, "missing", "ElementType"},
    {"mb_missing.mhd", MHD_U8 "ElementDataFile = mb_absent.raw\n", NO_DATA,
     RP_ENOENT, "data file", "mb_absent.raw"},
    {"mb_list.mhd", MHD_U8 "ElementDataFile = LIST\n", NO_DATA,
     RP_EUNSUPPORTED, "ElementDataFile", "LIST"},
    {"mb_pattern.mhd", MHD_U8 "ElementDataFile = slice%03d.raw 1 4 1\n",
     NO_DATA, RP_EUNSUPPORTED, "ElementDataFile", "slice%03d.raw"},
    {"mb_spacing.mha",
     MHD_U8 "ElementSpacing = 1 -2 1\nElementDataFile = LOCAL\n", 0,
     RP_ERANGE, "ElementSpacing", "-2"},
    {"mb_spacingnan.mha",
     MHD_U8 "ElementSpacing = 1 nan 1\nElementDataFile = LOCAL\n", 0,
     RP_ENOTFINITE, "ElementSpacing", "nan"},
    {"mb_msb.mha", MHD_U8 "ElementByteOrderMSB = maybe\n"
                   "ElementDataFile = LOCAL\n",
     0, RP_EFORMAT, "ElementByteOrderMSB", "maybe"},
    {"mb_twice.mha", MHD_U8 "ElementType = MET_UCHAR\n"
                     "ElementDataFile = LOCAL\n",
     0, RP_EFORMAT, "twice", "ElementType"},
    {"mb_noeq.mha", MHD_U8 "just words\nElementDataFile = LOCAL\n", 0,
     RP_EFORMAT, "Key = Value", "just words"},
    {"mb_shear.mha",
     MHD_U8 "TransformMatrix = 1 0 0 0.6 0.8 0 0 0 1\n"
            "ElementDataFile = LOCAL\n",
     0, RP_ERANGE, "TransformMatrix", "orthogonal"},
    {"mb_matrix8.mha",
     MHD_U8 "TransformMatrix = 1 0 0 0 1 0 0 0\nElementDataFile = LOCAL\n",
     0, RP_EFORMAT, "TransformMatrix", "9 numbers"},
    {"mb_anatomy.mha",
     MHD_U8 "AnatomicalOrientation = RAX\nElementDataFile = LOCAL\n", 0,
     RP_EFORMAT, "AnatomicalOrientation", "RAX"},
    {"mb_anatomy2.mha",
     MHD_U8 "AnatomicalOrientation = RA?\nElementDataFile = LOCAL\n", 0,
     RP_EFORMAT, "AnatomicalOrientation", "some axes"},
    {"mb_channels.mha",
     MHD_U8 "ElementNumberOfChannels = 3\nElementDataFile = LOCAL\n", 0,
     RP_EUNSUPPORTED, "ElementNumberOfChannels", "3"},
    {"mb_ascii.mha",
     MHD_U8 "BinaryData = False\nElementDataFile = LOCAL\n", 0,
     RP_EUNSUPPORTED, "BinaryData", "False"},
    {"mb_hsize.mha", MHD_U8 "HeaderSize = -2\nElementDataFile = LOCAL\n", 0,
     RP_EFORMAT, "HeaderSize", "-2"},
    {"mb_zsize.mha",
     MHD_U8 "CompressedData = True\nCompressedDataSize = 5\n"
            "ElementDataFile = LOCAL\n",
     0, RP_EFORMAT, "CompressedDataSize", "5"},
    {"mb_zraw.mha", MHD_U8 "CompressedData = True\nElementDataFile = LOCAL\n",
     0, RP_EFORMAT, "corrupt gzip", "mb_zraw.mha"},
};

static void test_mhd_malformed(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV + 8];
  size_t i;
  (void)state;
  encode(RP_U8, 0, payload);
  memset(payload + NV, 0x7f, 8);
  for (i = 0; i < sizeof bad_mhds / sizeof bad_mhds[0]; i++) {
    const bad_mhd *c = &bad_mhds[i];
    size_t n = c->delta == NO_DATA ? 0 : (size_t)(NV + c->delta);
    rp_test_load_fails(ctx, rp_test_write_with(c->file, c->text, payload, n),
                       c->code, c->file, c->field, c->value, NULL);
  }
  /* A detached file that is too short names that file. */
  rp_test_write_file("mb_cut.raw", payload, NV - 3);
  rp_test_load_fails(ctx, rp_test_write_with("mb_cut.mhd",
                                     mhd_text(RP_U8, "", "mb_cut.raw"), NULL,
                                     0),
                     RP_ETRUNC, "mb_cut.raw", "truncated", NULL);
  /* A zlib stream cut short. */
  {
    uint8_t packed[NV * 2 + 64];
    size_t z = zlib_bytes(payload, NV, packed, sizeof packed);
    rp_test_load_fails(ctx, rp_test_write_with("mb_zcut.mha",
                                       mhd_text(RP_U8,
                                                "CompressedData = True\n",
                                                "LOCAL"),
                                       packed, z - 4),
                       RP_ETRUNC, "mb_zcut.mha", "gzip", NULL);
  }
  rp_context_destroy(ctx);
}

/* The parser on memory, as the fuzz target calls it: the data offset,
 * and a header that is all there is. */
static void test_mhd_parse_memory(void **state) {
  static const char text[] = "NDims = 3\r\nDimSize = 3 2 4\r\n"
                             "ElementType = MET_SHORT\r\n"
                             "ElementDataFile = LOCAL\r\nvoxels";
  rp_context *ctx = rp_test_context();
  rp__volume_header hdr;
  size_t len = 0;
  (void)state;
  assert_int_equal(rp__mhd_parse(ctx, "m.mha", (const uint8_t *)text,
                                 sizeof text - 1, &hdr, &len),
                   0);
  assert_int_equal(len, sizeof text - 1 - strlen("voxels"));
  assert_int_equal(hdr.type, RP_S16);
  assert_int_equal(hdr.dims[2], 4);
  assert_false(hdr.orientation.known);
  assert_int_equal(rp__mhd_parse(ctx, "m.mha", (const uint8_t *)text, 10,
                                 &hdr, &len),
                   RP_EFORMAT);
  assert_non_null(strstr(rp_last_error(ctx), "DimSize"));
  assert_true(rp__looks_like_mhd("x.dat", (const uint8_t *)text, 12));
  assert_false(rp__looks_like_mhd("x.dat", (const uint8_t *)"NDimsX", 6));
  assert_true(rp__looks_like_mhd("x.MHA", (const uint8_t *)"", 0));
  rp_context_destroy(ctx);
}

/* Built without nifticlib, a NIfTI file is refused saying what to
 * install; with it, test_volume_nifti tests the loader. */
static void test_nifti_absent(void **state) {
#ifdef RP_TEST_NO_NIFTI
  rp_context *ctx = rp_test_context();
  uint8_t header[352];
  (void)state;
  memset(header, 0, sizeof header);
  rp_test_load_fails(ctx, rp_test_write_file("absent.nii", header, 352),
                     RP_EUNSUPPORTED, "absent.nii", "libnifti2-dev", NULL);
  rp_context_destroy(ctx);
#else
  (void)state;
  skip();
#endif
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_nrrd_space),
      cmocka_unit_test(test_nrrd_space_bad),
      cmocka_unit_test(test_mhd_round_trip),
      cmocka_unit_test(test_mhd_header_size),
      cmocka_unit_test(test_mhd_orientation),
      cmocka_unit_test(test_mhd_malformed),
      cmocka_unit_test(test_mhd_parse_memory),
      cmocka_unit_test(test_nifti_absent),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
