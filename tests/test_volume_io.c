/* Volume loaders: NRRD (attached, detached, raw, gzip, both endians), the
 * sidecar format, NAME_XxYxZ_TYPE.raw, every malformed input we promise to
 * reject, allocation failures, and the real volumes of the shared folder.
 *
 * Expected voxels are the values the tests themselves encode, byte by byte
 * (and compress with zlib's deflate), never the loader's own decoding. */
#include "test_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include <zlib.h>

#include "internal.h"

/* The test volume: 3 x 2 x 4 voxels, no two axes alike, so that a swapped
 * axis or a wrong stride shows. */
#define NX 3
#define NY 2
#define NZ 4
#define NV (NX * NY * NZ)

static const uint32_t test_dims[3] = {NX, NY, NZ};
static const float unit_spacing[3] = {1.0f, 1.0f, 1.0f};

static uint8_t u8_value(int i) { return (uint8_t)(i * 10 + 5); }
static uint16_t u16_value(int i) { return (uint16_t)(1000 + i * 2345); }
static float f32_value(int i) { return -2.5f + (float)i * 0.75f; }

/* The native-endian voxels that a load must produce. */
static const void *expected_voxels(rp_voxel_type type) {
  static uint8_t u8[NV];
  static uint16_t u16[NV];
  static float f32[NV];
  int i;
  for (i = 0; i < NV; i++) {
    u8[i] = u8_value(i);
    u16[i] = u16_value(i);
    f32[i] = f32_value(i);
  }
  return type == RP_U8 ? (const void *)u8
                       : type == RP_U16 ? (const void *)u16
                                        : (const void *)f32;
}

static size_t voxel_bytes(rp_voxel_type type) {
  return type == RP_U8 ? 1 : type == RP_U16 ? 2 : 4;
}

/* The voxels as file bytes in the given byte order; returns the count. */
static size_t encode(rp_voxel_type type, int big, uint8_t *out) {
  int i, b;
  size_t vs = voxel_bytes(type);
  for (i = 0; i < NV; i++) {
    uint32_t bits;
    if (type == RP_U8) {
      bits = u8_value(i);
    } else if (type == RP_U16) {
      bits = u16_value(i);
    } else {
      float f = f32_value(i);
      memcpy(&bits, &f, 4);
    }
    for (b = 0; b < (int)vs; b++) {
      int shift = big ? 8 * ((int)vs - 1 - b) : 8 * b;
      out[(size_t)i * vs + (size_t)b] = (uint8_t)(bits >> shift);
    }
  }
  return (size_t)NV * vs;
}

/* Compresses with deflate: a gzip wrapper, or a zlib one if `zlib`. */
static size_t deflate_bytes(const uint8_t *in, size_t n, uint8_t *out,
                            size_t cap, int zlib) {
  z_stream zs;
  memset(&zs, 0, sizeof zs);
  assert_int_equal(deflateInit2(&zs, 9, Z_DEFLATED, zlib ? 15 : 15 + 16, 8,
                                Z_DEFAULT_STRATEGY),
                   Z_OK);
  zs.next_in = (Bytef *)(uintptr_t)in;
  zs.avail_in = (uInt)n;
  zs.next_out = out;
  zs.avail_out = (uInt)cap;
  assert_int_equal(deflate(&zs, Z_FINISH), Z_STREAM_END);
  assert_int_equal(deflateEnd(&zs), Z_OK);
  return cap - zs.avail_out;
}

static const char *write_text(const char *name, const char *text) {
  return rp_test_write_file(name, text, strlen(text));
}

/* Header lines for the test volume; `extra` goes before the blank line. */
static const char *nrrd_header(const char *type, const char *endian,
                               const char *encoding, const char *extra) {
  static char buf[2048];
  snprintf(buf, sizeof buf,
           "NRRD0004\n# written by test_volume_io\ntype: %s\n"
           "dimension: 3\nsizes: %d %d %d\n%s%s%sencoding: %s\n%s\n",
           type, NX, NY, NZ, endian != NULL ? "endian: " : "",
           endian != NULL ? endian : "", endian != NULL ? "\n" : "", encoding,
           extra != NULL ? extra : "");
  return buf;
}

static const char *nrrd_type(rp_voxel_type type) {
  return type == RP_U8 ? "uchar" : type == RP_U16 ? "ushort" : "float";
}

static rp_volume *load_ok(rp_context *ctx, const char *path) {
  return rp_test_load_ok(ctx, path);
}

/* The load fails with `code`, leaves *out alone, and the message names
 * `needle`. */
static void load_fails(rp_context *ctx, const char *path, int code,
                       const char *needle) {
  rp_test_load_fails(ctx, path, code, needle, NULL);
}

static void check_volume(const rp_volume *v, rp_voxel_type type,
                         const float spacing[3]) {
  rp_volume_info info;
  const void *want = expected_voxels(type);
  double lo = INFINITY, hi = -INFINITY;
  int i;
  rp_volume_get_info(v, &info);
  for (i = 0; i < 3; i++) {
    assert_int_equal(info.dims[i], test_dims[i]);
    if (info.spacing[i] != spacing[i])
      fail_msg("spacing[%d] = %.9g, want %.9g", i, (double)info.spacing[i],
               (double)spacing[i]);
  }
  assert_int_equal(info.type, type);
  assert_memory_equal(rp_volume_data(v), want, NV * voxel_bytes(type));
  for (i = 0; i < NV; i++) {
    double x = type == RP_U8    ? u8_value(i)
               : type == RP_U16 ? u16_value(i)
                                : (double)f32_value(i);
    lo = x < lo ? x : lo;
    hi = x > hi ? x : hi;
  }
  assert_true(info.min == lo);
  assert_true(info.max == hi);
}

static void load_and_check(rp_context *ctx, const char *path,
                           rp_voxel_type type, const float spacing[3]) {
  rp_volume *v = load_ok(ctx, path);
  check_volume(v, type, spacing);
  rp_volume_destroy(v);
}

static const rp_voxel_type all_types[3] = {RP_U8, RP_U16, RP_F32};

/* ---- NRRD round trips ---------------------------------------------------- */

static void test_nrrd_raw_attached(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4];
  int t, big;
  (void)state;
  for (t = 0; t < 3; t++) {
    for (big = 0; big < 2; big++) {
      size_t n = encode(all_types[t], big, payload);
      const char *hdr = nrrd_header(nrrd_type(all_types[t]),
                                    big ? "big" : "little", "raw", NULL);
      load_and_check(ctx, rp_test_write_with("raw_attached.nrrd", hdr, payload, n),
                     all_types[t], unit_spacing);
    }
  }
  /* uint8 needs no endian field. */
  encode(RP_U8, 0, payload);
  load_and_check(ctx,
                 rp_test_write_with("u8_noendian.nrrd",
                            nrrd_header("uchar", NULL, "raw", NULL), payload,
                            NV),
                 RP_U8, unit_spacing);
  rp_context_destroy(ctx);
}

static void test_nrrd_gzip_attached(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4], packed[1024];
  int t, big, zlib;
  (void)state;
  for (t = 0; t < 3; t++) {
    for (big = 0; big < 2; big++) {
      for (zlib = 0; zlib < 2; zlib++) {
        size_t n = encode(all_types[t], big, payload);
        size_t z = deflate_bytes(payload, n, packed, sizeof packed, zlib);
        const char *hdr =
            nrrd_header(nrrd_type(all_types[t]), big ? "big" : "little",
                        zlib ? "gz" : "gzip", NULL);
        load_and_check(ctx, rp_test_write_with("gz_attached.nrrd", hdr, packed, z),
                       all_types[t], unit_spacing);
      }
    }
  }
  rp_context_destroy(ctx);
}

/* Larger than the loader's read and output chunks (64 kB): pseudo-random
 * uint16 voxels hardly compress, so the gzip file spans several reads and
 * the output buffer grows several times. */
static void test_nrrd_gzip_large(void **state) {
  enum { L = 64 * 64 * 64 };
  rp_context *ctx = rp_test_context();
  uint16_t *want = malloc(L * 2);
  uint8_t *bytes = malloc(L * 2);
  size_t cap = L * 2 + 4096, z;
  uint8_t *packed = malloc(cap);
  uint32_t x = 12345;
  rp_volume_info info;
  rp_volume *v;
  int i;
  (void)state;
  assert_non_null(want);
  assert_non_null(bytes);
  assert_non_null(packed);
  for (i = 0; i < L; i++) {
    x = x * 1664525u + 1013904223u;
    want[i] = (uint16_t)(x >> 16);
    bytes[2 * i] = (uint8_t)(want[i] >> 8); /* big endian */
    bytes[2 * i + 1] = (uint8_t)want[i];
  }
  z = deflate_bytes(bytes, L * 2, packed, cap, 0);
  assert_true(z > 3 * 65536);
  v = load_ok(ctx, rp_test_write_with("large.nrrd",
                              "NRRD0004\ntype: uint16\ndimension: 3\n"
                              "sizes: 64 64 64\nendian: big\n"
                              "encoding: gzip\n\n",
                              packed, z));
  rp_volume_get_info(v, &info);
  assert_int_equal(info.dims[0] * info.dims[1] * info.dims[2], L);
  assert_memory_equal(rp_volume_data(v), want, L * 2);
  rp_volume_destroy(v);
  free(packed);
  free(bytes);
  free(want);
  rp_context_destroy(ctx);
}

static void test_nrrd_detached(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4], packed[1024];
  char dir[1024], hdr[1024], extra[1200];
  size_t n, z;
  (void)state;
  n = encode(RP_U16, 1, payload);
  rp_test_write_file("det_u16.raw", payload, n);
  load_and_check(ctx,
                 write_text("det.nhdr",
                            nrrd_header("ushort", "big", "raw",
                                        "data file: det_u16.raw\n")),
                 RP_U16, unit_spacing);
  /* The older spelling, a "./" prefix, and no blank line at the end. */
  snprintf(hdr, sizeof hdr,
           "NRRD0001\ntype: unsigned short\ndimension: 3\nsizes: 3 2 4\n"
           "endian: big\nencoding: raw\ndatafile: ./det_u16.raw");
  load_and_check(ctx, write_text("det_old.nhdr", hdr), RP_U16, unit_spacing);
  /* An absolute path. */
  snprintf(extra, sizeof extra, "data file: %s/det_u16.raw\n",
           rp_test_tmp_dir());
  load_and_check(ctx,
                 write_text("det_abs.nhdr",
                            nrrd_header("ushort", "big", "raw", extra)),
                 RP_U16, unit_spacing);
  /* Relative to the header's folder, not to the working directory. */
  snprintf(dir, sizeof dir, "%s/det_sub", rp_test_tmp_dir());
  mkdir(dir, 0777);
  n = encode(RP_F32, 0, payload);
  z = deflate_bytes(payload, n, packed, sizeof packed, 0);
  rp_test_write_file("det_sub/data.raw.gz", packed, z);
  load_and_check(ctx,
                 write_text("det_sub/vol.nhdr",
                            nrrd_header("float", "little", "gzip",
                                        "data file: data.raw.gz\n")),
                 RP_F32, unit_spacing);
  rp_context_destroy(ctx);
}

static void test_nrrd_skips(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4], file[512], packed[1024];
  const char junk[] = "0123456789abc"; /* 13 bytes, no newline */
  const char lines[] = "first line\nsecond line\n";
  size_t n;
  (void)state;
  n = encode(RP_U16, 0, payload);

  /* byte skip, detached: 13 junk bytes before the data. */
  memcpy(file, junk, 13);
  memcpy(file + 13, payload, n);
  rp_test_write_file("skip_data.raw", file, 13 + n);
  load_and_check(ctx,
                 write_text("skip13.nhdr",
                            nrrd_header("ushort", "little", "raw",
                                        "data file: skip_data.raw\n"
                                        "byte skip: 13\n")),
                 RP_U16, unit_spacing);
  /* byte skip -1: the data is the file's tail, whatever comes first. */
  load_and_check(ctx,
                 write_text("skipend.nhdr",
                            nrrd_header("ushort", "little", "raw",
                                        "data file: skip_data.raw\n"
                                        "byte skip: -1\n")),
                 RP_U16, unit_spacing);
  /* Both, attached: bytes counted from the end of the header. */
  load_and_check(ctx,
                 rp_test_write_with("skip_att.nrrd",
                            nrrd_header("ushort", "little", "raw",
                                        "byte skip: 13\n"),
                            file, 13 + n),
                 RP_U16, unit_spacing);
  load_and_check(ctx,
                 rp_test_write_with("skipend_att.nrrd",
                            nrrd_header("ushort", "little", "raw",
                                        "byte skip: -1\n"),
                            file, 13 + n),
                 RP_U16, unit_spacing);

  /* line skip, then byte skip. */
  memcpy(file, lines, sizeof lines - 1);
  memcpy(file + sizeof lines - 1, junk, 5);
  memcpy(file + sizeof lines - 1 + 5, payload, n);
  rp_test_write_file("lines_data.raw", file, sizeof lines - 1 + 5 + n);
  load_and_check(ctx,
                 write_text("lines.nhdr",
                            nrrd_header("ushort", "little", "raw",
                                        "data file: lines_data.raw\n"
                                        "line skip: 2\nbyte skip: 5\n")),
                 RP_U16, unit_spacing);

  /* gzip: line skip before the stream, byte skip inside the inflated
   * data (as teem reads it). */
  memcpy(file, junk, 7);
  memcpy(file + 7, payload, n);
  n = deflate_bytes(file, 7 + n, packed, sizeof packed, 0);
  memcpy(file, lines, sizeof lines - 1);
  memcpy(file + sizeof lines - 1, packed, n);
  rp_test_write_file("lines_data.gz", file, sizeof lines - 1 + n);
  load_and_check(ctx,
                 write_text("lines_gz.nhdr",
                            nrrd_header("ushort", "little", "gzip",
                                        "data file: lines_data.gz\n"
                                        "line skip: 2\nbyte skip: 7\n")),
                 RP_U16, unit_spacing);
  rp_context_destroy(ctx);
}

static void test_nrrd_spacing(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV];
  const float want[3] = {0.5f, 2.0f, 3.25f};
  const float norms[3] = {5.0f, 2.0f, 0.1f};
  (void)state;
  encode(RP_U8, 0, payload);
  load_and_check(ctx,
                 rp_test_write_with("spacings.nrrd",
                            nrrd_header("uchar", NULL, "raw",
                                        "spacings: 0.5 2 3.25\n"),
                            payload, NV),
                 RP_U8, want);
  load_and_check(ctx,
                 rp_test_write_with("directions.nrrd",
                            nrrd_header("uchar", NULL, "raw",
                                        "space: right-anterior-superior\n"
                                        "space directions: (0.5,0,0) "
                                        "(0,2,0) (0,0,3.25)\n"
                                        "space origin: (1,2,3)\n"),
                            payload, NV),
                 RP_U8, want);
  /* Oblique axes: the spacing is each vector's length. */
  load_and_check(ctx,
                 rp_test_write_with("oblique.nrrd",
                            nrrd_header("uchar", NULL, "raw",
                                        "space directions: (3, 4, 0) "
                                        "(0,0,-2)  ( 0.1 ,0,0)\n"),
                            payload, NV),
                 RP_U8, norms);
  rp_context_destroy(ctx);
}

/* What NRRD allows and the loader must pass over: comments, key/value
 * pairs, fields it does not use, CRLF line ends, type aliases, every
 * version of the magic. */
static void test_nrrd_tolerance(void **state) {
  static const char *const u8_names[] = {"uchar", "unsigned char", "uint8",
                                         "uint8_t", "UCHAR"};
  static const char *const u16_names[] = {"ushort", "unsigned short",
                                          "unsigned short int", "uint16",
                                          "uint16_t"};
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 2];
  char hdr[1024];
  size_t i;
  (void)state;
  encode(RP_U8, 0, payload);
  for (i = 0; i < 5; i++) {
    snprintf(hdr, sizeof hdr,
             "NRRD000%d\r\n# comment: with a colon\r\ncontent: a:=b c\r\n"
             "type: %s\r\ndimension: 3\r\nsizes: 3 2 4\r\n"
             "kinds: domain domain domain\r\ncenters: cell cell cell\r\n"
             "labels: \"x\" \"y\" \"z\"\r\nmy key:=my value\r\n"
             "units: \"mm\" \"mm\" \"mm\"\r\nold min: 0\r\n"
             "type:=short\r\nsizes:=1 1\r\n"
             "some future field: 1 2 3\r\nencoding: raw\r\n\r\n",
             (int)i + 1, u8_names[i]);
    load_and_check(ctx, rp_test_write_with("tolerant.nrrd", hdr, payload, NV),
                   RP_U8, unit_spacing);
  }
  encode(RP_U16, 0, payload);
  for (i = 0; i < 5; i++)
    load_and_check(ctx,
                   rp_test_write_with("alias16.nrrd",
                              nrrd_header(u16_names[i], "little", "raw",
                                          NULL),
                              payload, NV * 2),
                   RP_U16, unit_spacing);
  rp_context_destroy(ctx);
}

/* ---- Sidecar and named raw ----------------------------------------------- */

static void test_sidecar(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4];
  const float sp[3] = {3.2f, 3.2f, 1.5f};
  size_t n;
  (void)state;
  n = encode(RP_U16, 0, payload);
  rp_test_write_file("sc_u16.raw", payload, n);
  load_and_check(ctx,
                 write_text("sc_u16.txt",
                            "file: sc_u16.raw\ndims: 3 2 4\ntype: uint16\n"
                            "endian: little\n"
                            "order: x fastest, then y, then z\n"
                            "spacing: 3.2 3.2 1.5\nbytes: 48\nmin: 1000\n"
                            "source: made by the test\n"),
                 RP_U16, sp);
  /* Defaults: spacing 1, little endian; comments and blank lines. */
  load_and_check(ctx,
                 write_text("sc_min.txt", "# minimal\n\ntype: uint16\n"
                                          "dims: 3 2 4\nfile: sc_u16.raw\n"),
                 RP_U16, unit_spacing);
  n = encode(RP_F32, 1, payload);
  rp_test_write_file("sc_f32be.raw", payload, n);
  load_and_check(ctx,
                 write_text("sc_f32be.txt",
                            "file: sc_f32be.raw\ndims: 3 2 4\n"
                            "type: float32\nendian: big\nbytes: 96\n"),
                 RP_F32, unit_spacing);
  n = encode(RP_U8, 0, payload);
  rp_test_write_file("sc_u8.raw", payload, n);
  load_and_check(ctx,
                 write_text("sc_u8.txt", "file: sc_u8.raw\r\ndims: 3 2 4\r\n"
                                         "type: uint8\r\n"),
                 RP_U8, unit_spacing);
  rp_context_destroy(ctx);
}

static void test_named_raw(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4];
  char name[64];
  int t;
  (void)state;
  for (t = 0; t < 3; t++) {
    size_t n = encode(all_types[t], 0, payload);
    snprintf(name, sizeof name, "my_vol_%dx%dx%d_%s.raw", NX, NY, NZ,
             rp_voxel_type_name(all_types[t]));
    load_and_check(ctx, rp_test_write_file(name, payload, n), all_types[t],
                   unit_spacing);
  }
  /* The name decides before the content: voxels that happen to begin with
   * the bytes "NRRD" are still voxels. */
  {
    static const uint8_t magic[8] = {'N', 'R', 'R', 'D', '0', '0', '0', '4'};
    rp_volume *v;
    encode(RP_U8, 0, payload);
    memcpy(payload, magic, sizeof magic);
    v = load_ok(ctx, rp_test_write_file("magic_3x2x4_uint8.raw", payload,
                                        NV));
    assert_memory_equal(rp_volume_data(v), payload, NV);
    rp_volume_destroy(v);
  }
  rp_context_destroy(ctx);
}

/* ---- The memory interface ------------------------------------------------ */

/* A heap copy of exactly n bytes, without a terminating NUL, so that a
 * parser reading past the end trips the address sanitizer. */
static uint8_t *exact_copy(const void *src, size_t n) {
  uint8_t *p = malloc(n > 0 ? n : 1);
  assert_non_null(p);
  memcpy(p, src, n);
  return p;
}

static void test_parsers_on_memory(void **state) {
  rp_context *ctx = rp_test_context();
  const char *text =
      "NRRD0005\ntype: float\ndimension: 3\nsizes: 7 8 9\nendian: big\n"
      "encoding: gzip\nspacings: 1 2 4\nbyte skip: 3\n\nDATA";
  const char *detached =
      "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 1 1 2\nencoding: raw\n"
      "data file: elsewhere.raw\nline skip: 4";
  const char *sidecar = "file: x.raw\ndims: 5 6 7\ntype: uint16\n"
                        "endian: big\nspacing: 1 1 0.25";
  rp__volume_header h;
  size_t hl = 0;
  uint8_t *buf;
  (void)state;

  buf = exact_copy(text, strlen(text));
  assert_int_equal(rp__nrrd_parse(ctx, "mem", buf, strlen(text), &h, &hl),
                   0);
  assert_int_equal(hl, strlen(text) - 4);
  assert_int_equal(h.dims[0], 7);
  assert_int_equal(h.dims[1], 8);
  assert_int_equal(h.dims[2], 9);
  assert_int_equal(h.type, RP_F32);
  assert_true(h.big_endian && h.gzip && !h.skip_to_end);
  assert_int_equal(h.byte_skip, 3);
  assert_true(h.spacing[0] == 1.0f && h.spacing[1] == 2.0f &&
              h.spacing[2] == 4.0f);
  assert_string_equal(h.data_file, "");
  free(buf);

  /* A header ending at the end of the buffer, without a newline. */
  buf = exact_copy(detached, strlen(detached));
  assert_int_equal(
      rp__nrrd_parse(ctx, "mem", buf, strlen(detached), &h, &hl), 0);
  assert_int_equal(hl, strlen(detached));
  assert_string_equal(h.data_file, "elsewhere.raw");
  assert_int_equal(h.line_skip, 4);
  free(buf);

  /* Every prefix of a valid header is handled without reading past it. */
  for (hl = 0; hl < strlen(text); hl++) {
    size_t end;
    buf = exact_copy(text, hl);
    (void)rp__nrrd_parse(ctx, "prefix", buf, hl, &h, &end);
    free(buf);
  }

  buf = exact_copy(sidecar, strlen(sidecar));
  assert_int_equal(rp__sidecar_parse(ctx, "mem", buf, strlen(sidecar), &h),
                   0);
  assert_string_equal(h.data_file, "x.raw");
  assert_int_equal(h.dims[0] * h.dims[1] * h.dims[2], 210);
  assert_int_equal(h.type, RP_U16);
  assert_true(h.big_endian);
  assert_true(h.spacing[2] == 0.25f);
  free(buf);
  rp_context_destroy(ctx);
}

static void test_decode_on_memory(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4], file[512], packed[1024];
  rp__volume_header h;
  rp_volume *v = NULL;
  size_t n, z;
  uint8_t *buf;
  (void)state;
  memset(&h, 0, sizeof h);
  h.dims[0] = NX, h.dims[1] = NY, h.dims[2] = NZ;
  h.type = RP_F32;
  h.spacing[0] = h.spacing[1] = h.spacing[2] = 1.0f;
  h.big_endian = 1;
  h.gzip = 1;
  h.line_skip = 1;
  h.byte_skip = 2;
  n = encode(RP_F32, 1, payload);
  memcpy(file, "xy", 2);
  memcpy(file + 2, payload, n);
  z = deflate_bytes(file, n + 2, packed, sizeof packed, 0);
  memcpy(file, "skip me\n", 8);
  memcpy(file + 8, packed, z);
  buf = exact_copy(file, 8 + z);
  assert_int_equal(rp__volume_decode(ctx, "mem", &h, buf, 8 + z, &v), 0);
  check_volume(v, RP_F32, unit_spacing);
  rp_volume_destroy(v);
  /* Every truncation fails cleanly. */
  for (n = 0; n < 8 + z; n++) {
    v = NULL;
    assert_int_not_equal(rp__volume_decode(ctx, "mem", &h, buf, n, &v), 0);
    assert_null(v);
  }
  free(buf);

  /* A byte skip larger than the decoder's output chunk. */
  {
    const size_t skip = 200000;
    uint8_t *big = calloc(1, skip + NV * 4);
    size_t cap = skip + 4096;
    uint8_t *zbig = malloc(cap);
    assert_non_null(big);
    assert_non_null(zbig);
    memcpy(big + skip, payload, NV * 4);
    z = deflate_bytes(big, skip + NV * 4, zbig, cap, 1);
    h.line_skip = 0;
    h.byte_skip = skip;
    assert_int_equal(rp__volume_decode(ctx, "mem", &h, zbig, z, &v), 0);
    check_volume(v, RP_F32, unit_spacing);
    rp_volume_destroy(v);
    free(zbig);
    free(big);
  }

  /* A header no parser made: the message names the bad spacing axis. */
  h.spacing[1] = -2.0f;
  v = NULL;
  assert_int_equal(rp__volume_decode(ctx, "mem", &h, payload, 0, &v),
                   RP_ERANGE);
  assert_null(v);
  assert_non_null(strstr(rp_last_error(ctx), "field 'spacing': axis 1"));
  rp_context_destroy(ctx);
}

/* Calls to inflate() made by this thread, counted by volume_io.c. */
extern _Thread_local unsigned long rp__inflate_calls;

/* A large inflated byte skip before a tiny payload is discarded through a
 * fixed 64 kB window, not through the payload's one byte: 8 MiB of skipped
 * zeros take a few hundred inflate calls, not eight million. */
static void test_gzip_big_skip(void **state) {
  const size_t skip = (size_t)8 << 20, cap = (size_t)1 << 20;
  rp_context *ctx = rp_test_context();
  uint8_t *plain = calloc(1, skip + 1);
  uint8_t *packed = malloc(cap);
  rp_volume_info info;
  rp_volume *v;
  size_t z;
  (void)state;
  assert_non_null(plain);
  assert_non_null(packed);
  plain[skip] = 42;
  z = deflate_bytes(plain, skip + 1, packed, cap, 0);
  rp__inflate_calls = 0;
  v = load_ok(ctx, rp_test_write_with("bigskip.nrrd",
                              "NRRD0004\ntype: uchar\ndimension: 3\n"
                              "sizes: 1 1 1\nencoding: gzip\n"
                              "byte skip: 8388608\n\n",
                              packed, z));
  rp_volume_get_info(v, &info);
  assert_int_equal(info.dims[0] * info.dims[1] * info.dims[2], 1);
  assert_int_equal(((const uint8_t *)rp_volume_data(v))[0], 42);
  rp_volume_destroy(v);
  if (rp__inflate_calls > 1024)
    fail_msg("%lu inflate calls for an 8 MiB skip", rp__inflate_calls);
  /* The same from memory. */
  {
    rp__volume_header h;
    memset(&h, 0, sizeof h);
    h.dims[0] = h.dims[1] = h.dims[2] = 1;
    h.type = RP_U8;
    h.spacing[0] = h.spacing[1] = h.spacing[2] = 1.0f;
    h.gzip = 1;
    h.byte_skip = skip;
    rp__inflate_calls = 0;
    v = NULL;
    assert_int_equal(rp__volume_decode(ctx, "mem", &h, packed, z, &v), 0);
    assert_int_equal(((const uint8_t *)rp_volume_data(v))[0], 42);
    rp_volume_destroy(v);
    assert_true(rp__inflate_calls <= 1024);
    /* A skip past the end of the inflated data is still truncation. */
    h.byte_skip = skip + 1;
    assert_int_equal(rp__volume_decode(ctx, "mem", &h, packed, z, &v),
                     RP_ETRUNC);
  }
  free(packed);
  free(plain);
  rp_context_destroy(ctx);
}

/* ---- Malformed input ----------------------------------------------------- */

#define NO_DATA 1000 /* bad_case.delta: write the text alone */

typedef struct bad_case {
  const char *file;   /* name under the tmp folder */
  const char *text;   /* the file's text */
  int delta;          /* append the 24-byte uint8 payload, this many bytes
                         longer (> 0) or shorter (< 0); NO_DATA: none */
  int code;
  const char *needle; /* the message must mention it */
} bad_case;

#define HDR_START "NRRD0004\ntype: uchar\ndimension: 3\n"
#define HDR_U8 HDR_START "sizes: 3 2 4\nencoding: raw\n"

static const bad_case bad_cases[] = {
    /* NRRD: magic and lines */
    {"magic.nrrd", "NRRD000X\n" HDR_U8 "\n", 0, RP_EFORMAT, "magic"},
    {"version.nrrd", "NRRD0009\ntype: uchar\n\n", 0, RP_EUNSUPPORTED,
     "NRRD0009"},
    {"nocolon.nrrd", HDR_U8 "this line has no colon\n\n", 0, RP_EFORMAT,
     "this line has no colon"},
    {"blankish.nrrd", HDR_U8 "   \n\n", 0, RP_EFORMAT, "line 6"},
    {"twice.nrrd", HDR_U8 "type: uchar\n\n", 0, RP_EFORMAT, "'type'"},
    /* NRRD: required fields */
    {"notype.nrrd", "NRRD0004\ndimension: 3\nsizes: 3 2 4\nencoding: raw\n\n",
     0, RP_EFORMAT, "'type'"},
    {"nodim.nrrd", "NRRD0004\ntype: uchar\nsizes: 3 2 4\nencoding: raw\n\n",
     0, RP_EFORMAT, "'dimension'"},
    {"nosizes.nrrd", HDR_START "encoding: raw\n\n", 0, RP_EFORMAT,
     "'sizes'"},
    {"noenc.nrrd", HDR_START "sizes: 3 2 4\n\n", 0, RP_EFORMAT,
     "'encoding'"},
    {"noendian.nrrd",
     "NRRD0004\ntype: ushort\ndimension: 3\nsizes: 3 2 4\nencoding: raw\n\n",
     NO_DATA, RP_EFORMAT, "'endian'"},
    /* NRRD: values */
    {"sizesx.nrrd", HDR_START "sizes: 3 x 4\nencoding: raw\n\n", 0,
     RP_EFORMAT, "sizes '3 x 4'"},
    {"sizes2.nrrd", HDR_START "sizes: 3 8\nencoding: raw\n\n", 0, RP_EFORMAT,
     "sizes"},
    {"sizes4.nrrd", HDR_START "sizes: 3 2 4 1\nencoding: raw\n\n", 0,
     RP_EFORMAT, "sizes"},
    {"sizesneg.nrrd", HDR_START "sizes: 3 -2 4\nencoding: raw\n\n", 0,
     RP_EFORMAT, "sizes"},
    {"sizesbig.nrrd",
     HDR_START "sizes: 3 2 99999999999999999999999\nencoding: raw\n\n", 0,
     RP_EFORMAT, "sizes"},
    {"sizes0.nrrd", HDR_START "sizes: 3 0 4\nencoding: raw\n\n", 0,
     RP_ERANGE, "sizes"},
    {"overflow.nrrd",
     HDR_START "sizes: 4294967295 4294967295 4294967295\nencoding: raw\n\n",
     0, RP_ERANGE, "overflow.nrrd: field 'sizes'"},
    {"axis32.nrrd", HDR_START "sizes: 4294967296 1 1\nencoding: raw\n\n", 0,
     RP_ERANGE, "axis32.nrrd: field 'sizes'"},
    {"dim2.nrrd", "NRRD0004\ntype: uchar\ndimension: 2\n\n", 0,
     RP_EUNSUPPORTED, "dimension 2"},
    {"dimx.nrrd", "NRRD0004\ntype: uchar\ndimension: three\n\n", 0,
     RP_EFORMAT, "dimension 'three'"},
    {"llong.nrrd", "NRRD0004\ntype: long long\n\n", 0, RP_EUNSUPPORTED,
     "'long long'"},
    {"double.nrrd", "NRRD0004\ntype: double\n\n", 0, RP_EUNSUPPORTED,
     "'double'"},
    {"block.nrrd", "NRRD0004\ntype: block\n\n", 0, RP_EUNSUPPORTED,
     "'block'"},
    {"ascii.nrrd", HDR_START "sizes: 3 2 4\nencoding: ascii\n\n", NO_DATA,
     RP_EUNSUPPORTED, "'ascii'"},
    {"bzip2.nrrd", HDR_START "sizes: 3 2 4\nencoding: bzip2\n\n", 0,
     RP_EUNSUPPORTED, "'bzip2'"},
    {"hex.nrrd", HDR_START "sizes: 3 2 4\nencoding: hex\n\n", 0,
     RP_EUNSUPPORTED, "'hex'"},
    {"endian.nrrd", HDR_U8 "endian: middle\n\n", 0, RP_EFORMAT, "'middle'"},
    {"spnan.nrrd", HDR_U8 "spacings: 1 nan 1\n\n", 0, RP_ENOTFINITE,
     "field 'spacings': axis 1"},
    {"spinf.nrrd", HDR_U8 "spacings: 1 1e999 1\n\n", 0, RP_ENOTFINITE,
     "spacings"},
    {"sp0.nrrd", HDR_U8 "spacings: 1 0 1\n\n", 0, RP_ERANGE, "spacings"},
    {"spneg.nrrd", HDR_U8 "spacings: 1 -2 1\n\n", 0, RP_ERANGE,
     "field 'spacings': axis 1 value '-2'"},
    {"sptiny.nrrd", HDR_U8 "spacings: 1 1e-300 1\n\n", 0, RP_ERANGE,
     "spacings"},
    {"sp2.nrrd", HDR_U8 "spacings: 1 2\n\n", 0, RP_EFORMAT, "spacings"},
    {"spword.nrrd", HDR_U8 "spacings: 1 abc 1\n\n", 0, RP_EFORMAT,
     "spacings"},
    {"spcomma.nrrd", HDR_U8 "spacings: 1 1,5 1\n\n", 0, RP_EFORMAT,
     "spacings"},
    {"dirnone.nrrd", HDR_U8 "space directions: (1,0,0) none (0,0,1)\n\n", 0,
     RP_EFORMAT, "space directions"},
    {"dirzero.nrrd",
     HDR_U8 "space directions: (1,0,0) (0,0,0) (0,0,1)\n\n", 0, RP_ERANGE,
     "field 'space directions': axis 1"},
    {"dirlen.nrrd", HDR_U8 "space directions: (1,0,0) (0,1) (0,0,1)\n\n",
     0, RP_EFORMAT, "space directions"},
    {"dirnan.nrrd",
     HDR_U8 "space directions: (1,0,0) (0,nan,0) (0,0,1)\n\n", 0,
     RP_ENOTFINITE, "space directions"},
    {"dirfour.nrrd",
     HDR_U8 "space directions: (1,0,0) (0,1,0) (0,0,1) (1,1,1)\n\n", 0,
     RP_EFORMAT, "space directions"},
    {"dirparen.nrrd", HDR_U8 "space directions: (1,0,0) (0,1,0) (0,0,1\n\n",
     0, RP_EFORMAT, "space directions"},
    {"both.nrrd",
     HDR_U8 "spacings: 1 1 1\nspace directions: (1,0,0) (0,1,0) (0,0,1)\n\n",
     0, RP_EFORMAT, "spacings"},
    {"list.nhdr", HDR_U8 "data file: LIST\n", NO_DATA, RP_EUNSUPPORTED,
     "LIST"},
    {"fmt.nhdr", HDR_U8 "data file: slice%03d.raw 1 4 1\n", NO_DATA,
     RP_EUNSUPPORTED, "slice%03d.raw"},
    {"nodata.nhdr", HDR_U8 "data file: missing_data.raw\n", NO_DATA,
     RP_ENOENT, "missing_data.raw"},
    {"bskip.nrrd", HDR_U8 "byte skip: -2\n\n", 0, RP_ERANGE, "byte skip"},
    {"bskipx.nrrd", HDR_U8 "byte skip: 1.5\n\n", 0, RP_EFORMAT,
     "byte skip"},
    {"bskipfar.nrrd", HDR_U8 "byte skip: 100\n\n", 0, RP_ETRUNC,
     "byte skip"},
    {"bskipgz.nrrd",
     HDR_START "sizes: 3 2 4\nencoding: gzip\nbyte skip: -1\n\n", 0,
     RP_EUNSUPPORTED, "byte skip"},
    {"bskipend.nrrd", HDR_U8 "byte skip: -1\n\n", -1, RP_ETRUNC,
     "bskipend.nrrd"},
    {"lskip.nrrd", HDR_U8 "line skip: -1\n\n", 0, RP_ERANGE, "line skip"},
    {"lskipfar.nrrd", HDR_U8 "line skip: 3\n\n", 0, RP_ETRUNC, "line skip"},
    /* NRRD: data size */
    {"short_data.nrrd", HDR_U8 "\n", -1, RP_ETRUNC, "short_data.nrrd"},
    {"long_data.nrrd", HDR_U8 "\n", 1, RP_EFORMAT, "long_data.nrrd"},
    {"no_data.nrrd", HDR_U8, NO_DATA, RP_ETRUNC, "no_data.nrrd"},
    {"empty_line.nrrd", HDR_U8 "\n", NO_DATA, RP_ETRUNC, "empty_line.nrrd"},
    /* Sidecar */
    {"sc_nofile.txt", "dims: 3 2 4\ntype: uint8\n", NO_DATA, RP_EFORMAT,
     "'file'"},
    {"sc_nodims.txt", "file: sc_bad.raw\ntype: uint8\n", NO_DATA,
     RP_EFORMAT, "'dims'"},
    {"sc_dimsx.txt", "file: sc_bad.raw\ntype: uint8\ndims:\n", NO_DATA,
     RP_EFORMAT, "dims ''"},
    {"sc_notype.txt", "file: sc_bad.raw\ndims: 3 2 4\n", NO_DATA, RP_EFORMAT,
     "'type'"},
    {"sc_type.txt", "file: sc_bad.raw\ndims: 3 2 4\ntype: int64\n", NO_DATA,
     RP_EUNSUPPORTED, "'int64'"},
    {"sc_bytes.txt", "file: sc_bad.raw\ndims: 3 2 4\ntype: uint8\nbytes: 25\n",
     NO_DATA, RP_EFORMAT, "bytes 25"},
    {"sc_bytesx.txt",
     "file: sc_bad.raw\ndims: 3 2 4\ntype: uint8\nbytes: many\n", NO_DATA,
     RP_EFORMAT, "bytes 'many'"},
    {"sc_dims2.txt", "file: sc_bad.raw\ndims: 3 2\ntype: uint8\n", NO_DATA,
     RP_EFORMAT, "dims '3 2'"},
    {"sc_dims0.txt", "file: sc_bad.raw\ndims: 3 2 0\ntype: uint8\n", NO_DATA,
     RP_ERANGE, "dims"},
    {"sc_twice.txt", "file: sc_bad.raw\ndims: 3 2 4\ndims: 3 2 4\n", NO_DATA,
     RP_EFORMAT, "'dims'"},
    {"sc_endian.txt",
     "file: sc_bad.raw\ndims: 3 2 4\ntype: uint8\nendian: pdp\n", NO_DATA,
     RP_EFORMAT, "'pdp'"},
    {"sc_spacing.txt",
     "file: sc_bad.raw\ndims: 3 2 4\ntype: uint8\nspacing: 1 -1 1\n",
     NO_DATA, RP_ERANGE, "field 'spacing': axis 1 value '-1'"},
    {"sc_overflow.txt",
     "file: sc_bad.raw\ndims: 4294967295 4294967295 4294967295\n"
     "type: uint8\n", NO_DATA, RP_ERANGE, "sc_overflow.txt: field 'dims'"},
    {"sc_axis32.txt", "file: sc_bad.raw\ndims: 4294967296 1 1\ntype: uint8\n",
     NO_DATA, RP_ERANGE, "sc_axis32.txt: field 'dims'"},
    {"sc_line.txt", "file: sc_bad.raw\ndims: 3 2 4\nnot a key value\n",
     NO_DATA, RP_EFORMAT, "not a key value"},
    {"sc_missing.txt", "file: sc_none.raw\ndims: 3 2 4\ntype: uint8\n",
     NO_DATA, RP_ENOENT, "sc_none.raw"},
    {"sc_short.txt", "file: sc_short.raw\ndims: 3 2 4\ntype: uint8\n",
     NO_DATA, RP_ETRUNC, "sc_short.raw"},
    {"sc_long.txt", "file: sc_long.raw\ndims: 3 2 4\ntype: uint8\n", NO_DATA,
     RP_EFORMAT, "sc_long.raw"},
    {"sc_dir.txt", "file: .\ndims: 3 2 4\ntype: uint8\n", NO_DATA, RP_EIO,
     "regular"},
    /* Named raw and unknown files */
    {"pat_3x2x4_uint8.raw", "", -1, RP_ETRUNC, "pat_3x2x4_uint8.raw"},
    {"pat2_3x2x4_uint8.raw", "", 1, RP_EFORMAT, "pat2_3x2x4_uint8.raw"},
    {"pat_3x2x4_int64.raw", "", 0, RP_EUNSUPPORTED, "'int64'"},
    {"pat_3x0x4_uint8.raw", "", 0, RP_ERANGE, "pat_3x0x4_uint8.raw"},
    {"pat_4294967296x1x1_uint8.raw", "", 0, RP_ERANGE,
     "dims in the file name"},
    {"weird.raw", "", 0, RP_EFORMAT, "NAME_XxYxZ_TYPE.raw"},
    {"pat_3x2_uint8.raw", "", 0, RP_EFORMAT, "NAME_XxYxZ_TYPE.raw"},
    {"garbage.bin", "hello: world\n", 0, RP_EFORMAT, "NRRD"},
    {"empty.nrrd", "", NO_DATA, RP_EFORMAT, "empty.nrrd"},
    {"nrrd_only.nrrd", "NRRD", NO_DATA, RP_EFORMAT, "magic"},
};

/* Signed and 32-bit integer voxels, in NRRD (big-endian, by the type names
 * NRRD gives them), in a sidecar and in a named raw file: the values come
 * back as data values (stored + stored_offset), the range is that of the
 * values written, worked out here from the same formula. */
static int32_t signed_value(int i, rp_voxel_type type) {
  int32_t v = (int32_t)((i * 7919) % 4096) - 1024; /* [-1024, 3071] */
  if (type == RP_S8)
    return v % 128;
  if (type == RP_S32)
    return v * 100000; /* beyond int16, within float's 2^24 */
  if (type == RP_U32)
    return (v + 1024) * 4096;
  return v;
}

static void signed_case(rp_context *ctx, rp_voxel_type type,
                        const char *nrrd_name, const char *plain) {
  size_t vs = type == RP_S8 ? 1 : type == RP_S16 ? 2 : 4;
  uint8_t *le = malloc(NV * vs), *be = malloc(NV * vs);
  double lo = INFINITY, hi = -INFINITY;
  char name[64], text[512];
  const char *paths[3];
  int i, k, b;
  assert_non_null(le), assert_non_null(be);
  for (i = 0; i < NV; i++) {
    uint32_t u = (uint32_t)signed_value(i, type);
    for (b = 0; b < (int)vs; b++) {
      le[i * vs + b] = (uint8_t)(u >> (8 * b));
      be[i * vs + b] = (uint8_t)(u >> (8 * (vs - 1 - b)));
    }
    lo = fmin(lo, signed_value(i, type));
    hi = fmax(hi, signed_value(i, type));
  }
  snprintf(name, sizeof name, "signed_%s.nrrd", plain);
  paths[0] = strdup(rp_test_write_with(name, nrrd_header(nrrd_name, "big", "raw",
                                                 NULL), be, NV * vs));
  snprintf(name, sizeof name, "signed_%s.raw", plain);
  rp_test_write_file(name, le, NV * vs);
  snprintf(text, sizeof text, "file: signed_%s.raw\ndims: %d %d %d\n"
           "type: %s\nendian: little\n", plain, NX, NY, NZ, plain);
  snprintf(name, sizeof name, "signed_%s.txt", plain);
  paths[1] = strdup(write_text(name, text));
  snprintf(name, sizeof name, "signed_%dx%dx%d_%s.raw", NX, NY, NZ, plain);
  paths[2] = strdup(rp_test_write_file(name, le, NV * vs));
  for (k = 0; k < 3; k++) {
    rp_volume *v = load_ok(ctx, paths[k]);
    rp_volume_info info;
    const void *d = rp_volume_data(v);
    rp_volume_get_info(v, &info);
    assert_int_equal(info.type, type);
    if (info.min != lo || info.max != hi)
      fail_msg("%s: range [%g, %g], want [%g, %g]", paths[k], info.min,
               info.max, lo, hi);
    for (i = 0; i < NV; i++) {
      double got = info.stored_type == RP_U8 ? ((const uint8_t *)d)[i]
                   : info.stored_type == RP_U16
                       ? ((const uint16_t *)d)[i]
                       : (double)((const float *)d)[i];
      if (got + info.stored_offset != signed_value(i, type))
        fail_msg("%s: voxel %d is %g, want %d", paths[k], i,
                 got + info.stored_offset, signed_value(i, type));
    }
    rp_volume_destroy(v);
    free((void *)paths[k]);
  }
  free(le), free(be);
}

static void test_signed_types(void **state) {
  rp_context *ctx = rp_test_context();
  (void)state;
  signed_case(ctx, RP_S8, "signed char", "int8");
  signed_case(ctx, RP_S16, "short", "int16");
  signed_case(ctx, RP_S32, "int", "int32");
  signed_case(ctx, RP_U32, "unsigned int", "uint32");
  assert_string_equal(rp_voxel_type_name(RP_S16), "int16");
  assert_string_equal(rp_voxel_type_name((rp_voxel_type)99), "unknown");
  rp_context_destroy(ctx);
}

static void test_malformed(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV + 8];
  size_t i;
  (void)state;
  encode(RP_U8, 0, payload);
  memset(payload + NV, 0x7f, 8);
  rp_test_write_file("sc_bad.raw", payload, NV);
  rp_test_write_file("sc_short.raw", payload, NV - 1);
  rp_test_write_file("sc_long.raw", payload, NV + 1);
  for (i = 0; i < sizeof bad_cases / sizeof bad_cases[0]; i++) {
    const bad_case *c = &bad_cases[i];
    size_t n = c->delta == NO_DATA ? 0 : (size_t)(NV + c->delta);
    load_fails(ctx, rp_test_write_with(c->file, c->text, payload, n), c->code,
               c->needle);
  }
  rp_context_destroy(ctx);
}

static void test_missing_and_unreadable(void **state) {
  rp_context *ctx = rp_test_context();
  rp_volume *v = NULL;
  char path[1024];
  (void)state;
  snprintf(path, sizeof path, "%s/does_not_exist.nrrd", rp_test_tmp_dir());
  load_fails(ctx, path, RP_ENOENT, "does_not_exist.nrrd");
  snprintf(path, sizeof path, "%s/no_dir/x_1x1x1_uint8.raw",
           rp_test_tmp_dir());
  load_fails(ctx, path, RP_ENOENT, "no_dir");
  /* A folder is a DICOM series (test_dicom.c): an empty one holds no
   * image, or the build has no GDCM; the message names the folder. */
  snprintf(path, sizeof path, "%s/empty_folder", rp_test_tmp_dir());
  mkdir(path, 0755);
  {
    int rc = rp_volume_load(ctx, path, &v);
    assert_true(rc == RP_EFORMAT || rc == RP_EUNSUPPORTED);
    assert_non_null(strstr(rp_last_error(ctx), "empty_folder"));
    assert_null(v);
  }
  snprintf(path, sizeof path, "%s/no_dir/x_1x1x1_uint8.raw",
           rp_test_tmp_dir());
  assert_int_equal(rp_volume_load(NULL, path, &v), RP_EINVAL);
  assert_int_equal(rp_volume_load(ctx, NULL, &v), RP_EINVAL);
  assert_int_equal(rp_volume_load(ctx, path, NULL), RP_EINVAL);
  assert_null(v);
  rp_context_destroy(ctx);
}

/* A FIFO (or any file that is not regular) is refused by its type before
 * it is opened: opening a FIFO for reading blocks until a writer comes.
 * The alarm turns a hang into a failure. */
static void test_not_regular(void **state) {
  static const char *const names[] = {"fifo.nrrd", "fifo_3x2x4_uint8.raw",
                                      "fifo_data.raw"};
  rp_context *ctx = rp_test_context();
  char path[1024];
  size_t i;
  (void)state;
  alarm(20);
  for (i = 0; i < sizeof names / sizeof names[0]; i++) {
    snprintf(path, sizeof path, "%s/%s", rp_test_tmp_dir(), names[i]);
    unlink(path);
    assert_int_equal(mkfifo(path, 0600), 0);
  }
  snprintf(path, sizeof path, "%s/fifo.nrrd", rp_test_tmp_dir());
  load_fails(ctx, path, RP_EIO, "not a regular file");
  load_fails(ctx, path, RP_EIO, "fifo.nrrd");
  snprintf(path, sizeof path, "%s/fifo_3x2x4_uint8.raw", rp_test_tmp_dir());
  load_fails(ctx, path, RP_EIO, "fifo_3x2x4_uint8.raw: not a regular file");
  /* Data files named by a detached header or a sidecar. */
  load_fails(ctx,
             write_text("fifo.nhdr",
                        nrrd_header("uchar", NULL, "raw",
                                    "data file: fifo_data.raw\n")),
             RP_EIO, "fifo_data.raw: not a regular file");
  load_fails(ctx,
             write_text("fifo.txt", "file: fifo_data.raw\ndims: 3 2 4\n"
                                    "type: uint8\n"),
             RP_EIO, "fifo_data.raw: not a regular file");
  alarm(0);
  for (i = 0; i < sizeof names / sizeof names[0]; i++) {
    snprintf(path, sizeof path, "%s/%s", rp_test_tmp_dir(), names[i]);
    unlink(path);
  }
  rp_context_destroy(ctx);
}

/* Header lines that are too long or hold a NUL byte. */
static void test_bad_lines(void **state) {
  rp_context *ctx = rp_test_context();
  size_t n = strlen(HDR_U8);
  char *buf = malloc(n + 6000);
  (void)state;
  assert_non_null(buf);
  memcpy(buf, HDR_U8, n);
  buf[n] = '#';
  memset(buf + n + 1, 'a', 5000);
  memcpy(buf + n + 5001, "\n\n", 2);
  load_fails(ctx, rp_test_write_file("longline.nrrd", buf, n + 5003),
             RP_EFORMAT, "longer than");
  memcpy(buf + n, "content: a\0b\n\n", 14);
  load_fails(ctx, rp_test_write_file("nul.nrrd", buf, n + 14), RP_EFORMAT,
             "NUL");
  memcpy(buf, "file: a.raw\ndims: 1 1 1\ntype: uint8\nx\0y\n", 40);
  load_fails(ctx, rp_test_write_file("nul.txt", buf, 40), RP_EFORMAT,
             "NUL");
  free(buf);
  rp_context_destroy(ctx);
}

static void test_not_finite_data(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4], packed[1024];
  const float bad[2] = {NAN, INFINITY};
  int k;
  size_t z;
  (void)state;
  for (k = 0; k < 2; k++) {
    uint32_t bits;
    int b;
    encode(RP_F32, 0, payload);
    memcpy(&bits, &bad[k], 4);
    for (b = 0; b < 4; b++) /* voxel (1, 0, 1), little endian */
      payload[4 * 7 + b] = (uint8_t)(bits >> (8 * b));
    load_fails(ctx,
               rp_test_write_with("nan.nrrd",
                          nrrd_header("float", "little", "raw", NULL),
                          payload, NV * 4),
               RP_ENOTFINITE, "nan.nrrd");
    z = deflate_bytes(payload, NV * 4, packed, sizeof packed, 0);
    load_fails(ctx,
               rp_test_write_with("nan_gz.nrrd",
                          nrrd_header("float", "little", "gzip", NULL),
                          packed, z),
               RP_ENOTFINITE, "not finite");
  }
  rp_context_destroy(ctx);
}

static void test_bad_gzip(void **state) {
  rp_context *ctx = rp_test_context();
  uint8_t payload[NV * 4 + 16], packed[1024], copy[1024];
  const char *hdr = nrrd_header("ushort", "little", "gzip", NULL);
  size_t n = encode(RP_U16, 0, payload), z;
  (void)state;
  z = deflate_bytes(payload, n, packed, sizeof packed, 0);
  /* A gzip member is at least 18 bytes; saying so also tells the compiler
   * that z - 8 below cannot wrap. */
  if (z < 18)
    abort();
  /* Cut short: inside the deflate data, and just before the trailer. */
  load_fails(ctx, rp_test_write_with("gz_cut.nrrd", hdr, packed, z / 2), RP_ETRUNC,
             "gz_cut.nrrd");
  load_fails(ctx, rp_test_write_with("gz_cut8.nrrd", hdr, packed, z - 8), RP_ETRUNC,
             "gz_cut8.nrrd");
  load_fails(ctx, rp_test_write_with("gz_cut1.nrrd", hdr, packed, z - 1), RP_ETRUNC,
             "gz_cut1.nrrd");
  /* A wrong CRC and a wrong magic are corruption. */
  memcpy(copy, packed, z);
  copy[z - 8] ^= 0x55;
  load_fails(ctx, rp_test_write_with("gz_crc.nrrd", hdr, copy, z), RP_EFORMAT,
             "corrupt");
  memcpy(copy, packed, z);
  copy[0] ^= 0xff;
  load_fails(ctx, rp_test_write_with("gz_magic.nrrd", hdr, copy, z), RP_EFORMAT,
             "corrupt");
  /* Trailing bytes after the stream. */
  memcpy(copy, packed, z);
  memcpy(copy + z, "tail", 4);
  load_fails(ctx, rp_test_write_with("gz_tail.nrrd", hdr, copy, z + 4), RP_EFORMAT,
             "follow");
  /* A complete stream with too few or too many bytes. */
  z = deflate_bytes(payload, n - 2, packed, sizeof packed, 0);
  load_fails(ctx, rp_test_write_with("gz_less.nrrd", hdr, packed, z), RP_ETRUNC,
             "gz_less.nrrd");
  memset(payload + n, 0, 16);
  z = deflate_bytes(payload, n + 2, packed, sizeof packed, 0);
  load_fails(ctx, rp_test_write_with("gz_more.nrrd", hdr, packed, z), RP_EFORMAT,
             "more than");
  rp_context_destroy(ctx);
}

/* ---- Limits and allocation ----------------------------------------------- */

/* An allocator that counts, tracks the peak of live bytes and can fail
 * the nth allocation. */
typedef struct counting {
  long fail_at; /* -1: never */
  long calls;
  long live;
  size_t bytes, peak;
} counting;

static void *count_alloc(size_t size, void *user) {
  counting *c = user;
  unsigned char *p;
  if (c->fail_at >= 0 && c->calls++ == c->fail_at)
    return NULL;
  p = malloc(size + 16);
  if (p == NULL)
    return NULL;
  memcpy(p, &size, sizeof size);
  c->live++;
  c->bytes += size;
  if (c->bytes > c->peak)
    c->peak = c->bytes;
  return p + 16;
}

static void count_free(void *ptr, void *user) {
  counting *c = user;
  unsigned char *p = (unsigned char *)ptr - 16;
  size_t size;
  memcpy(&size, p, sizeof size);
  c->live--;
  c->bytes -= size;
  free(p);
}

static rp_context *counting_context(counting *c, uint64_t max_bytes) {
  rp_context_desc d;
  rp_context *ctx = NULL;
  memset(&d, 0, sizeof d);
  memset(c, 0, sizeof *c);
  c->fail_at = -1;
  d.allocator.alloc = count_alloc;
  d.allocator.free = count_free;
  d.allocator.user = c;
  d.max_volume_bytes = max_bytes;
  assert_int_equal(rp_context_create(&d, &ctx), 0);
  return ctx;
}

/* A tiny file that claims a huge volume fails on the missing data before
 * anything near the claimed size is allocated. */
static void test_huge_claims(void **state) {
  counting c;
  rp_context *ctx = counting_context(&c, 0);
  uint8_t payload[NV], packed[256];
  const char *raw_hdr = "NRRD0004\ntype: uchar\ndimension: 3\n"
                        "sizes: 2000 2000 1000\nencoding: raw\n\n";
  const char *gz_hdr = "NRRD0004\ntype: uchar\ndimension: 3\n"
                       "sizes: 2000 2000 1000\nencoding: gzip\n\n";
  size_t z, base;
  (void)state;
  encode(RP_U8, 0, payload);
  z = deflate_bytes(payload, NV, packed, sizeof packed, 0);
  base = c.bytes;
  c.peak = base;
  load_fails(ctx, rp_test_write_with("huge_raw.nrrd", raw_hdr, payload, NV),
             RP_ETRUNC, "huge_raw.nrrd");
  assert_true(c.peak - base < ((size_t)1 << 20));
  c.peak = base;
  load_fails(ctx, rp_test_write_with("huge_gz.nrrd", gz_hdr, packed, z), RP_ETRUNC,
             "huge_gz.nrrd");
  assert_true(c.peak - base < ((size_t)1 << 20));
  /* 300 kB of zeros in a few hundred bytes of gzip, claiming 100 MB: the
   * output grows with the data, it is not sized from the claim. */
  {
    const size_t n = 300000;
    uint8_t *zeros = calloc(1, n);
    uint8_t *zz = malloc(n);
    assert_non_null(zeros);
    assert_non_null(zz);
    z = deflate_bytes(zeros, n, zz, n, 0);
    c.peak = base;
    load_fails(ctx,
               rp_test_write_with("huge_zeros.nrrd",
                          "NRRD0004\ntype: uchar\ndimension: 3\n"
                          "sizes: 1000 1000 100\nencoding: gzip\n\n",
                          zz, z),
               RP_ETRUNC, "huge_zeros.nrrd");
    assert_true(c.peak - base < ((size_t)2 << 20));
    free(zz);
    free(zeros);
  }
  assert_int_equal(c.live, 1); /* the context */
  rp_context_destroy(ctx);

  /* max_volume_bytes bounds what a loader accepts. */
  ctx = counting_context(&c, 23);
  load_fails(ctx,
             rp_test_write_with("limit.nrrd", nrrd_header("uchar", NULL, "raw", NULL),
                        payload, NV),
             RP_ERANGE, "limit.nrrd: field 'sizes'");
  rp_test_write_file("limit.raw", payload, NV);
  load_fails(ctx,
             write_text("limit.txt",
                        "file: limit.raw\ndims: 3 2 4\ntype: uint8\n"),
             RP_ERANGE, "limit.txt: field 'dims'");
  rp_context_destroy(ctx);
}

/* Failing each allocation in turn: RP_ENOMEM, *out untouched, no leak. */
static void oom_loop(const char *path) {
  static int sentinel;
  counting c;
  rp_context *ctx = counting_context(&c, 0);
  long n;
  for (n = 0;; n++) {
    rp_volume *v = (rp_volume *)&sentinel;
    int rc;
    c.fail_at = n;
    c.calls = 0;
    rc = rp_volume_load(ctx, path, &v);
    if (rc == 0) {
      rp_volume_destroy(v);
      break;
    }
    if (rc != RP_ENOMEM)
      fail_msg("%s, allocation %ld failing: %s (%s)", path, n,
               rp_err_name(rc), rp_last_error(ctx));
    assert_ptr_equal(v, (rp_volume *)&sentinel);
    assert_int_equal(c.live, 1);
  }
  assert_true(n >= 2);
  assert_int_equal(c.live, 1);
  rp_context_destroy(ctx);
}

static void test_out_of_memory(void **state) {
  uint8_t payload[NV * 4], packed[1024];
  size_t n, z;
  (void)state;
  n = encode(RP_U16, 1, payload);
  z = deflate_bytes(payload, n, packed, sizeof packed, 0);
  oom_loop(rp_test_write_with("oom_gz.nrrd",
                      nrrd_header("ushort", "big", "gzip", NULL), packed,
                      z));
  oom_loop(rp_test_write_with("oom_raw.nrrd",
                      nrrd_header("ushort", "big", "raw", NULL), payload,
                      n));
  /* A byte skip larger than the output: the skip window of its own. */
  {
    const size_t skip = 100000;
    uint8_t *plain = calloc(1, skip + n);
    uint8_t *zz = malloc(skip + n);
    assert_non_null(plain);
    assert_non_null(zz);
    memcpy(plain + skip, payload, n);
    z = deflate_bytes(plain, skip + n, zz, skip + n, 0);
    oom_loop(rp_test_write_with("oom_skip.nrrd",
                        nrrd_header("ushort", "big", "gzip",
                                    "byte skip: 100000\n"),
                        zz, z));
    free(zz);
    free(plain);
  }
  rp_test_write_file("oom_data.raw", payload, n);
  oom_loop(write_text("oom.txt", "file: oom_data.raw\ndims: 3 2 4\n"
                                 "type: uint16\nendian: big\n"));
  oom_loop(write_text("oom.nhdr",
                      nrrd_header("ushort", "big", "raw",
                                  "data file: oom_data.raw\n")));
}

/* ---- Real data ----------------------------------------------------------- */

/* The sidecar's own statement of a key's value, read independently of the
 * loader. */
static int sidecar_value(const char *path, const char *key, char *out,
                         size_t cap) {
  char line[4096];
  size_t k = strlen(key);
  FILE *f = fopen(path, "r");
  int found = 0;
  assert_non_null(f);
  while (!found && fgets(line, sizeof line, f) != NULL) {
    if (strncmp(line, key, k) == 0 && line[k] == ':') {
      snprintf(out, cap, "%s", line + k + 1);
      out[strcspn(out, "\r\n")] = '\0';
      found = 1;
    }
  }
  fclose(f);
  return found;
}

static double voxel_mean(const rp_volume *v) {
  rp_volume_info info;
  size_t i, n;
  const void *data = rp_volume_data(v);
  double sum = 0.0;
  rp_volume_get_info(v, &info);
  n = (size_t)info.dims[0] * info.dims[1] * info.dims[2];
  if (info.type == RP_U8) {
    uint64_t s = 0;
    for (i = 0; i < n; i++)
      s += ((const uint8_t *)data)[i];
    sum = (double)s;
  } else if (info.type == RP_U16) {
    uint64_t s = 0;
    for (i = 0; i < n; i++)
      s += ((const uint16_t *)data)[i];
    sum = (double)s;
  } else {
    for (i = 0; i < n; i++)
      sum += ((const float *)data)[i];
  }
  return sum / (double)n;
}

static void test_real_data(void **state) {
  const char *const *names = rp_test_data_names();
  rp_context *ctx;
  struct timespec t0, t1;
  double secs;
  size_t total = 0;
  int count = 0;
  (void)state;
  if (names[0] == NULL)
    skip();
  ctx = rp_test_context();
  clock_gettime(CLOCK_MONOTONIC, &t0);
  for (; *names != NULL; names++) {
    char path[1024], val[256], type[64];
    unsigned d[3];
    double lo, hi, mean;
    rp_volume_info info;
    rp_volume *v;
    assert_non_null(rp_test_data_volume(*names, path, sizeof path));
    v = load_ok(ctx, path);
    rp_volume_get_info(v, &info);
    assert_true(sidecar_value(path, "dims", val, sizeof val));
    assert_int_equal(sscanf(val, "%u %u %u", &d[0], &d[1], &d[2]), 3);
    assert_true(sidecar_value(path, "type", val, sizeof val));
    assert_int_equal(sscanf(val, "%63s", type), 1);
    assert_true(sidecar_value(path, "min", val, sizeof val));
    lo = atof(val);
    assert_true(sidecar_value(path, "max", val, sizeof val));
    hi = atof(val);
    assert_true(sidecar_value(path, "mean", val, sizeof val));
    mean = atof(val);
    assert_int_equal(info.dims[0], d[0]);
    assert_int_equal(info.dims[1], d[1]);
    assert_int_equal(info.dims[2], d[2]);
    assert_string_equal(rp_voxel_type_name(info.type), type);
    if (info.min != lo || info.max != hi)
      fail_msg("%s: range [%g, %g], sidecar says [%g, %g]", *names,
               info.min, info.max, lo, hi);
    if (fabs(voxel_mean(v) - mean) > 0.001)
      fail_msg("%s: mean %.6f, sidecar says %.3f", *names, voxel_mean(v),
               mean);
    total += (size_t)d[0] * d[1] * d[2] * voxel_bytes(info.type);
    count++;
    rp_volume_destroy(v);
  }
  clock_gettime(CLOCK_MONOTONIC, &t1);
  secs = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec -
                                                           t0.tv_nsec);
  print_message("loaded %d volumes, %.1f MB, in %.2f s (with checks)\n",
                count, (double)total / 1e6, secs);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_nrrd_raw_attached),
      cmocka_unit_test(test_nrrd_gzip_attached),
      cmocka_unit_test(test_nrrd_gzip_large),
      cmocka_unit_test(test_nrrd_detached),
      cmocka_unit_test(test_nrrd_skips),
      cmocka_unit_test(test_nrrd_spacing),
      cmocka_unit_test(test_nrrd_tolerance),
      cmocka_unit_test(test_sidecar),
      cmocka_unit_test(test_named_raw),
      cmocka_unit_test(test_parsers_on_memory),
      cmocka_unit_test(test_decode_on_memory),
      cmocka_unit_test(test_gzip_big_skip),
      cmocka_unit_test(test_signed_types),
      cmocka_unit_test(test_malformed),
      cmocka_unit_test(test_missing_and_unreadable),
      cmocka_unit_test(test_not_regular),
      cmocka_unit_test(test_bad_lines),
      cmocka_unit_test(test_not_finite_data),
      cmocka_unit_test(test_bad_gzip),
      cmocka_unit_test(test_huge_claims),
      cmocka_unit_test(test_out_of_memory),
      cmocka_unit_test(test_real_data),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
