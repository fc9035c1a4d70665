/* DICOM through rp_volume_load: series written here with GDCM's writer
 * (support/dicom_writer.cpp) with known voxels, an oblique orientation and
 * file names unrelated to position, then loaded and held to the values
 * the test computes itself: data units (stored x slope + intercept), the
 * voxel type the rules give, spacing, orientation and origin. Then the
 * folders a loader must refuse, each with a message naming the file and
 * the tag. */
#include <dirent.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "dicom_writer.h"
#include "test_util.h"

#define MAX_SLICES 16

typedef struct series {
  uint16_t rows, cols;
  uint32_t n;             /* slices */
  double angle_a, angle_b; /* orientation: Rx(b) Rz(a) */
  double origin[3];       /* position of the slice nearest -normal */
  double step;            /* mm between slices along the normal */
  double ps[2];           /* PixelSpacing: rows, columns */
  int bits_stored, pixel_rep;
  int has_rescale;
  double slope, intercept;
  int32_t base, range;    /* stored values: base + (hash % range) */
  const char *uid;
  enum dicom_encoding enc;
} series;

static void frame_of(const series *s, double r[3], double c[3],
                     double n[3]) {
  double ca = cos(s->angle_a), sa = sin(s->angle_a);
  double cb = cos(s->angle_b), sb = sin(s->angle_b);
  r[0] = ca, r[1] = sa * cb, r[2] = sa * sb;
  c[0] = -sa, c[1] = ca * cb, c[2] = ca * sb;
  n[0] = 0, n[1] = -sb, n[2] = cb;
}

static int32_t stored_at(const series *s, uint32_t x, uint32_t y,
                         uint32_t k) {
  uint32_t h = x * 37u + y * 101u + k * 211u + 7u;
  return s->base + (int32_t)(h % (uint32_t)s->range);
}

/* A folder under the test's scratch folder, emptied. */
static const char *fresh_dir(const char *name) {
  static char path[4][512];
  static int turn;
  char *p = path[turn++ % 4];
  DIR *d;
  struct dirent *e;
  snprintf(p, 512, "%s/dicom_%s", rp_test_tmp_dir(), name);
  mkdir(p, 0755);
  if ((d = opendir(p)) != NULL) {
    while ((e = readdir(d)) != NULL) {
      char f[1024];
      if (e->d_name[0] == '.')
        continue;
      snprintf(f, sizeof f, "%s/%s", p, e->d_name);
      unlink(f);
    }
    closedir(d);
  }
  return p;
}

/* File name of slice k: a permutation of position order (5 is prime to
 * every n used here), so that name order is not position order. */
static void slice_name(char *buf, size_t len, const char *dir,
                       const series *s, uint32_t k) {
  snprintf(buf, len, "%s/IM%04u", dir, (k * 5u + 3u) % s->n);
}

static void slice_desc(const series *s, uint32_t k, const char *path,
                       uint16_t *pix, dicom_slice_desc *d) {
  double r[3], c[3], n[3];
  uint32_t x, y;
  int i;
  frame_of(s, r, c, n);
  memset(d, 0, sizeof *d);
  d->path = path;
  d->series_uid = s->uid;
  d->instance_number = (int)((k * 5u + 3u) % s->n) + 1;
  d->rows = s->rows, d->cols = s->cols;
  d->bits_allocated = 16;
  d->bits_stored = s->bits_stored;
  d->pixel_rep = s->pixel_rep;
  for (y = 0; y < s->rows; y++)
    for (x = 0; x < s->cols; x++)
      pix[y * s->cols + x] = (uint16_t)stored_at(s, x, y, k);
  d->pixels = pix;
  d->has_position = d->has_orientation = 1;
  for (i = 0; i < 3; i++) {
    d->position[i] = s->origin[i] + s->step * k * n[i];
    d->orientation[i] = r[i];
    d->orientation[3 + i] = c[i];
  }
  d->pixel_spacing[0] = s->ps[0], d->pixel_spacing[1] = s->ps[1];
  d->has_rescale = s->has_rescale;
  d->slope = s->slope, d->intercept = s->intercept;
  d->encoding = s->enc;
}

static void write_series(const series *s, const char *dir) {
  uint16_t pix[64 * 64];
  uint32_t k;
  assert_true((size_t)s->rows * s->cols <= 64 * 64);
  for (k = 0; k < s->n; k++) {
    char path[600];
    dicom_slice_desc d;
    slice_name(path, sizeof path, dir, s, k);
    slice_desc(s, k, path, pix, &d);
    assert_int_equal(dicom_write(&d), 0);
  }
}

static series oblique_ct(void) {
  series s;
  memset(&s, 0, sizeof s);
  s.rows = 4, s.cols = 5, s.n = 6;
  s.angle_a = 0.3, s.angle_b = -0.45;
  s.origin[0] = -120.5, s.origin[1] = 33.25, s.origin[2] = 410.0;
  s.step = 1.25;
  s.ps[0] = 0.7, s.ps[1] = 0.5;
  s.bits_stored = 12, s.pixel_rep = 0;
  s.has_rescale = 1, s.slope = 1.0, s.intercept = -1024.0;
  s.base = 0, s.range = 4096;
  s.uid = "1.2.826.0.1.3680043.10.1234.77";
  return s;
}

/* Loads `path`, failing the test with the loader's message if it fails. */
static rp_volume *load_ok(rp_context *ctx, const char *path) {
  rp_volume *vol = NULL;
  if (rp_volume_load(ctx, path, &vol) != 0)
    fail_msg("%s: %s", path, rp_last_error(ctx));
  return vol;
}

/* A voxel in data units, from the volume's stored voxels. */
static double voxel(const rp_volume *vol, const rp_volume_info *info,
                    size_t i) {
  const void *p = rp_volume_data(vol);
  switch (info->stored_type) {
  case RP_U8: return ((const uint8_t *)p)[i] + info->stored_offset;
  case RP_U16: return ((const uint16_t *)p)[i] + info->stored_offset;
  default: return ((const float *)p)[i] + info->stored_offset;
  }
}

/* The volume against the series: sizes, spacing, orientation, origin and
 * every voxel, stored x slope + intercept (`mask` applied to the stored
 * value first). */
static void expect_series(const rp_volume *vol, const series *s,
                          rp_voxel_type type, int32_t mask) {
  rp_volume_info info;
  double r[3], c[3], n[3], lo = INFINITY, hi = -INFINITY;
  uint32_t x, y, k;
  int i;
  rp_volume_get_info(vol, &info);
  frame_of(s, r, c, n);
  assert_int_equal(info.dims[0], s->cols);
  assert_int_equal(info.dims[1], s->rows);
  assert_int_equal(info.dims[2], s->n);
  assert_int_equal(info.type, type);
  assert_float_equal(info.spacing[0], s->ps[1], 1e-6);
  assert_float_equal(info.spacing[1], s->ps[0], 1e-6);
  assert_float_equal(info.spacing[2], s->step, 1e-5);
  assert_true(info.orientation.known);
  for (i = 0; i < 3; i++) {
    assert_float_equal(info.orientation.direction[i], r[i], 1e-8);
    assert_float_equal(info.orientation.direction[3 + i], c[i], 1e-8);
    assert_float_equal(info.orientation.direction[6 + i], n[i], 1e-8);
    assert_float_equal(info.orientation.origin[i], s->origin[i], 1e-6);
  }
  for (k = 0; k < s->n; k++)
    for (y = 0; y < s->rows; y++)
      for (x = 0; x < s->cols; x++) {
        size_t at = ((size_t)k * s->rows + y) * s->cols + x;
        int32_t v = stored_at(s, x, y, k) & mask;
        double want = v * s->slope + s->intercept;
        double got = voxel(vol, &info, at);
        if (fabs(got - want) > 1e-6 * fabs(want) + 1e-9)
          fail_msg("voxel (%u, %u, %u): %g, want %g", x, y, k, got, want);
        lo = fmin(lo, want), hi = fmax(hi, want);
      }
  assert_float_equal(info.min, lo, 1e-6 * fabs(lo));
  assert_float_equal(info.max, hi, 1e-6 * fabs(hi) + 1e-9);
}

/* Unsigned 12-bit CT with intercept -1024: int16 HU, negative values
 * kept; the files are named and numbered out of position order. The
 * pixel words carry an overlay bit above BitsStored, which is masked. */
static void test_oblique_ct_int16(void **state) {
  rp_context *ctx = rp_test_context();
  series s = oblique_ct();
  const char *dir = fresh_dir("oblique");
  rp_volume *vol = NULL;
  (void)state;
  s.base = 0x8000; /* bit 15: not part of the 12 stored bits */
  write_series(&s, dir);
  vol = load_ok(ctx, dir);
  expect_series(vol, &s, RP_S16, 0x0fff);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* Signed 16-bit pixels, slope 0.5 and a fractional intercept, implicit
 * VR: float32 data units. */
static void test_signed_rescaled_float(void **state) {
  rp_context *ctx = rp_test_context();
  series s = oblique_ct();
  const char *dir = fresh_dir("float");
  rp_volume *vol = NULL;
  (void)state;
  s.bits_stored = 16, s.pixel_rep = 1;
  s.slope = 0.5, s.intercept = -1000.25;
  s.base = -2000, s.range = 5000;
  s.enc = DICOM_IMPLICIT;
  s.angle_a = 2.0, s.angle_b = 1.1; /* normal with -y: reversed order */
  write_series(&s, dir);
  vol = load_ok(ctx, dir);
  expect_series(vol, &s, RP_F32, -1);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* Slope 1, intercept 0, but stored values beyond int16 from the fourth
 * slice on: the loader starts in int16 and widens to float32 midway,
 * exactly. The pixel data is RLE-compressed. */
static void test_widens_to_float_rle(void **state) {
  rp_context *ctx = rp_test_context();
  series s = oblique_ct();
  const char *dir = fresh_dir("widen");
  rp_volume *vol = NULL;
  (void)state;
  s.bits_stored = 16;
  s.has_rescale = 0, s.slope = 1.0, s.intercept = 0.0;
  s.range = 30000;
  s.enc = DICOM_RLE;
  write_series(&s, dir);
  {
    /* Slice 3 (in position order) gets values up to about 33500. */
    uint16_t pix[64 * 64];
    char path[600];
    dicom_slice_desc d;
    uint32_t i;
    slice_name(path, sizeof path, dir, &s, 3);
    slice_desc(&s, 3, path, pix, &d);
    for (i = 0; i < (uint32_t)s.rows * s.cols; i++)
      pix[i] = (uint16_t)(pix[i] + 32000);
    assert_int_equal(dicom_write(&d), 0);
    vol = load_ok(ctx, dir);
    {
      rp_volume_info info;
      rp_volume_get_info(vol, &info);
      assert_int_equal(info.type, RP_F32);
      for (i = 0; i < (uint32_t)s.rows * s.cols * s.n; i++) {
        uint32_t k = i / ((uint32_t)s.rows * s.cols);
        uint32_t x = i % s.cols, y = (i / s.cols) % s.rows;
        double want = stored_at(&s, x, y, k) + (k == 3 ? 32000 : 0);
        assert_float_equal(voxel(vol, &info, i), want, 0.0);
      }
    }
  }
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* A folder with a file that is not DICOM (a README) and a sub-folder:
 * both are skipped, as rp_volume_load documents. */
static void test_non_dicom_skipped(void **state) {
  rp_context *ctx = rp_test_context();
  series s = oblique_ct();
  const char *dir = fresh_dir("readme");
  char path[600];
  rp_volume *vol = NULL;
  FILE *f;
  (void)state;
  write_series(&s, dir);
  snprintf(path, sizeof path, "%s/README.txt", dir);
  assert_non_null(f = fopen(path, "w"));
  fputs("scanner export, see the PDF\n", f);
  fclose(f);
  snprintf(path, sizeof path, "%s/sub", dir);
  mkdir(path, 0755);
  vol = load_ok(ctx, dir);
  expect_series(vol, &s, RP_S16, -1);
  rp_volume_destroy(vol);
  rmdir(path);
  rp_context_destroy(ctx);
}

/* One slice file, JPEG-LS compressed, loaded on its own: its thickness
 * is the third spacing, its position the origin. */
static void test_single_file(void **state) {
  rp_context *ctx = rp_test_context();
  series s = oblique_ct();
  const char *dir = fresh_dir("single");
  uint16_t pix[64 * 64];
  char path[600];
  dicom_slice_desc d;
  rp_volume *vol = NULL;
  (void)state;
  s.n = 1, s.step = 2.5, s.enc = DICOM_JPEG_LS;
  snprintf(path, sizeof path, "%s/one.dcm", dir);
  slice_desc(&s, 0, path, pix, &d);
  d.slice_thickness = 2.5;
  assert_int_equal(dicom_write(&d), 0);
  vol = load_ok(ctx, path);
  expect_series(vol, &s, RP_S16, -1);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* A multi-frame file (legacy: one ImagePositionPatient for the first
 * frame, SpacingBetweenSlices for the step), loaded on its own. */
static void test_multiframe(void **state) {
  rp_context *ctx = rp_test_context();
  series s = oblique_ct();
  const char *dir = fresh_dir("multiframe");
  uint16_t pix[3 * 64], plane[64];
  char path[600];
  dicom_slice_desc d;
  rp_volume *vol;
  uint32_t k;
  (void)state;
  s.n = 3, s.step = 1.5;
  snprintf(path, sizeof path, "%s/mf.dcm", dir);
  for (k = 0; k < s.n; k++) {
    slice_desc(&s, k, path, plane, &d);
    memcpy(pix + k * 20, plane, 20 * sizeof *plane);
  }
  slice_desc(&s, 0, path, plane, &d);
  d.pixels = pix;
  d.frames = s.n;
  d.spacing_between = s.step;
  assert_int_equal(dicom_write(&d), 0);
  vol = load_ok(ctx, path);
  expect_series(vol, &s, RP_S16, -1);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

/* Loads `dir`, which must fail with `err` and a message holding each of
 * the NULL-ended `parts`. */
static void expect_refused(rp_context *ctx, const char *dir, int err,
                           const char *const *parts) {
  rp_volume *vol = NULL;
  const char *msg;
  int rc = rp_volume_load(ctx, dir, &vol);
  if (rc != err)
    fail_msg("%s: %d (%s), want %d", dir, rc, rp_last_error(ctx), err);
  assert_null(vol);
  msg = rp_last_error(ctx);
  for (; *parts != NULL; parts++)
    if (strstr(msg, *parts) == NULL)
      fail_msg("message '%s' lacks '%s'", msg, *parts);
}

static void test_mixed_series(void **state) {
  rp_context *ctx = rp_test_context();
  series a = oblique_ct(), b = oblique_ct();
  const char *dir = fresh_dir("mixed");
  const char *parts[] = {"2 series", "SeriesInstanceUID (0020,000E)",
                         "1.2.826.0.1.3680043.10.1234.77' (6 files)",
                         "1.2.826.0.1.3680043.10.1234.78' (3 files)", NULL};
  (void)state;
  write_series(&a, dir);
  /* b's files are named IM0006.. so that they do not overwrite a's. */
  b.uid = "1.2.826.0.1.3680043.10.1234.78";
  b.n = 3;
  {
    uint16_t pix[64 * 64];
    uint32_t k;
    for (k = 0; k < b.n; k++) {
      char path[600];
      dicom_slice_desc d;
      snprintf(path, sizeof path, "%s/IM%04u", dir, 6 + k);
      slice_desc(&b, k, path, pix, &d);
      assert_int_equal(dicom_write(&d), 0);
    }
  }
  expect_refused(ctx, dir, RP_EFORMAT, parts);
  rp_context_destroy(ctx);
}

/* Slice 3 of 7 removed: the gap between slices 2 and 4 is twice the
 * step, and the message names the two files around it. */
static void test_missing_slice(void **state) {
  rp_context *ctx = rp_test_context();
  series s = oblique_ct();
  const char *dir = fresh_dir("gap");
  char before[600], after[600], gone[600];
  const char *parts[] = {"uneven slice spacing", before, after, "2.5 mm",
                         "1.25 mm", NULL};
  (void)state;
  s.n = 7;
  write_series(&s, dir);
  slice_name(gone, sizeof gone, dir, &s, 3);
  slice_name(before, sizeof before, dir, &s, 2);
  slice_name(after, sizeof after, dir, &s, 4);
  assert_int_equal(unlink(gone), 0);
  expect_refused(ctx, dir, RP_EFORMAT, parts);
  rp_context_destroy(ctx);
}

/* Rewrites slice k of a written series with a change made by `edit`. */
static void rewrite(const series *s, const char *dir, uint32_t k,
                    void (*edit)(dicom_slice_desc *d), char *path,
                    size_t len) {
  uint16_t pix[64 * 64];
  dicom_slice_desc d;
  slice_name(path, len, dir, s, k);
  slice_desc(s, k, path, pix, &d);
  edit(&d);
  assert_int_equal(dicom_write(&d), 0);
}

static void edit_size(dicom_slice_desc *d) {
  d->rows = 5, d->cols = 4; /* same pixel count, other shape */
}

static void edit_same_position(dicom_slice_desc *d) {
  double r[3], c[3], n[3];
  series s = oblique_ct();
  int i;
  frame_of(&s, r, c, n);
  for (i = 0; i < 3; i++) /* slice 1's position */
    d->position[i] = s.origin[i] + s.step * n[i];
}

static void edit_orientation(dicom_slice_desc *d) {
  d->orientation[0] = 1, d->orientation[1] = 0, d->orientation[2] = 0;
  d->orientation[3] = 0, d->orientation[4] = 1, d->orientation[5] = 0;
}

static void edit_no_position(dicom_slice_desc *d) {
  d->has_position = 0;
}

static void test_refused_edits(void **state) {
  static const struct {
    const char *name;
    void (*edit)(dicom_slice_desc *d);
    const char *part;
  } cases[] = {
      {"size", edit_size, "Rows (0028,0010) x Columns (0028,0011) 5 x 4"},
      {"dup", edit_same_position, "duplicate slices"},
      {"orient", edit_orientation, "mixed orientations"},
      {"nopos", edit_no_position, "no ImagePositionPatient (0020,0032)"}};
  size_t i;
  (void)state;
  for (i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    rp_context *ctx = rp_test_context();
    series s = oblique_ct();
    const char *dir = fresh_dir(cases[i].name);
    char path[600];
    const char *parts[] = {path, cases[i].part, NULL};
    write_series(&s, dir);
    rewrite(&s, dir, 2, cases[i].edit, path, sizeof path);
    expect_refused(ctx, dir, RP_EFORMAT, parts);
    rp_context_destroy(ctx);
  }
}

/* A slice cut short: in its pixel data (which GDCM alone would accept,
 * zero-filled), in an element of its data set (where Debian's GDCM would
 * abort on an assertion), and in its meta header. Each is refused with
 * the file named; never skipped, which would hide a slice. Cut between
 * two elements before Rows, the file is still DICOM of the series but
 * without an image: refused too. */
/* The byte where PhotometricInterpretation
 * (0028,0004) begins in an explicit VR little endian file: an element
 * boundary before Rows. */
static long boundary_before_rows(const char *path) {
  static const uint8_t tag[] = {0x28, 0x00, 0x04, 0x00, 'C', 'S'};
  uint8_t buf[4096];
  size_t n, i;
  FILE *f = fopen(path, "rb");
  assert_non_null(f);
  n = fread(buf, 1, sizeof buf, f);
  fclose(f);
  for (i = 132; i + sizeof tag <= n; i++)
    if (memcmp(buf + i, tag, sizeof tag) == 0)
      return (long)i;
  fail_msg("%s: no (0028,0004)", path);
  return 0;
}

static void test_truncated(void **state) {
  static const long keep[] = {-20, -1, 505, 200, 0};
  static const char *const name[] = {"trunc_20", "trunc_1", "trunc_set",
                                     "trunc_meta", "trunc_boundary"};
  size_t i;
  (void)state;
  for (i = 0; i < 5; i++) {
    rp_context *ctx = rp_test_context();
    series s = oblique_ct();
    const char *dir = fresh_dir(name[i]);
    char path[600];
    const char *parts[] = {path, "cut short", NULL};
    struct stat st;
    long at;
    write_series(&s, dir);
    slice_name(path, sizeof path, dir, &s, 0);
    assert_int_equal(stat(path, &st), 0);
    at = keep[i] < 0 ? st.st_size + keep[i] : keep[i];
    if (keep[i] == 0)
      at = boundary_before_rows(path);
    assert_int_equal(truncate(path, at), 0);
    expect_refused(ctx, dir, keep[i] == 0 ? RP_EFORMAT : RP_ETRUNC, parts);
    rp_context_destroy(ctx);
  }
}

/* A corrupt RLE frame header (3 segments for 16-bit pixels): refused
 * with a message, where GDCM's RLE decoder alone would abort on an
 * assertion. */
static void test_corrupt_rle(void **state) {
  static const uint8_t header[] = {2, 0, 0, 0, 64, 0, 0, 0};
  rp_context *ctx = rp_test_context();
  series s = oblique_ct();
  const char *dir = fresh_dir("bad_rle");
  char path[600];
  const char *parts[] = {path, "RLE frame 0", "3 segments", NULL};
  uint8_t buf[4096];
  size_t n, i;
  FILE *f;
  (void)state;
  s.enc = DICOM_RLE;
  write_series(&s, dir);
  slice_name(path, sizeof path, dir, &s, 4);
  assert_non_null(f = fopen(path, "r+b"));
  n = fread(buf, 1, sizeof buf, f);
  for (i = 132; i + sizeof header <= n; i++)
    if (memcmp(buf + i, header, sizeof header) == 0)
      break;
  assert_true(i + sizeof header <= n);
  buf[i] = 3;
  assert_int_equal(fseek(f, 0, SEEK_SET), 0);
  assert_int_equal(fwrite(buf, 1, n, f), n);
  fclose(f);
  expect_refused(ctx, dir, RP_EFORMAT, parts);
  rp_context_destroy(ctx);
}

static void test_empty_and_foreign(void **state) {
  rp_context *ctx = rp_test_context();
  const char *dir = fresh_dir("empty");
  const char *parts[] = {dir, "no DICOM image", "0 files", NULL};
  const char *parts2[] = {dir, "no DICOM image", "1 files", NULL};
  char path[600];
  FILE *f;
  (void)state;
  expect_refused(ctx, dir, RP_EFORMAT, parts);
  snprintf(path, sizeof path, "%s/notes.txt", dir);
  assert_non_null(f = fopen(path, "w"));
  fputs("hello\n", f);
  fclose(f);
  expect_refused(ctx, dir, RP_EFORMAT, parts2);
  rp_context_destroy(ctx);
}

/* The volume's size is checked against max_volume_bytes before anything
 * is allocated. */
static void test_volume_limit(void **state) {
  rp_context *ctx = NULL;
  rp_context_desc desc;
  series s = oblique_ct();
  const char *dir = fresh_dir("limit");
  const char *parts[] = {dir, "max_volume_bytes", NULL};
  (void)state;
  memset(&desc, 0, sizeof desc);
  desc.max_volume_bytes = 200; /* 5 x 4 x 6 int16 = 240 bytes */
  assert_int_equal(rp_context_create(&desc, &ctx), 0);
  write_series(&s, dir);
  expect_refused(ctx, dir, RP_ERANGE, parts);
  rp_context_destroy(ctx);
}

/* PixelSpacing outside RP_SPACING_MIN/MAX is refused before any pixel is
 * read, naming the folder, the tag, the value and the range; the limit
 * itself loads. */
static void test_spacing_limits(void **state) {
  rp_context *ctx = rp_test_context();
  series s = oblique_ct();
  const char *dir = fresh_dir("spacing");
  const char *parts[] = {dir, "PixelSpacing (0028,0030) between columns",
                         "is 1e-12", "[1e-09, 1e+09]", NULL};
  rp_volume *vol;
  rp_volume_info info;
  (void)state;
  s.ps[1] = 1e-12;
  write_series(&s, dir);
  expect_refused(ctx, dir, RP_ERANGE, parts);
  s.ps[1] = 1e-9;
  dir = fresh_dir("spacing_edge");
  write_series(&s, dir);
  vol = load_ok(ctx, dir);
  rp_volume_get_info(vol, &info);
  assert_true(info.spacing[0] == RP_SPACING_MIN);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_oblique_ct_int16),
      cmocka_unit_test(test_signed_rescaled_float),
      cmocka_unit_test(test_widens_to_float_rle),
      cmocka_unit_test(test_non_dicom_skipped),
      cmocka_unit_test(test_single_file),
      cmocka_unit_test(test_multiframe),
      cmocka_unit_test(test_mixed_series),
      cmocka_unit_test(test_missing_slice),
      cmocka_unit_test(test_refused_edits),
      cmocka_unit_test(test_truncated),
      cmocka_unit_test(test_corrupt_rle),
      cmocka_unit_test(test_empty_and_foreign),
      cmocka_unit_test(test_volume_limit),
      cmocka_unit_test(test_spacing_limits),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
