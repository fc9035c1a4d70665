/* DICOM series and files into volumes (volume_dicom.h): the folder's
 * files, one series, slices ordered by position, the geometry checked,
 * pixel values rescaled to data units (HU for CT).
 *
 * Slices are ordered by their position along the slice normal (the cross
 * product of ImageOrientationPatient's row and column cosines), never by
 * file name or InstanceNumber: both are often unrelated to where a slice
 * lies. A grid the renderer cannot show truthfully (mixed orientation,
 * duplicate positions, uneven gaps, a gantry tilt) is refused with the
 * slices named, rather than shown stretched or sheared. */
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "internal.h"
#include "volume_dicom.h"

/* Cosines are written with a few digits; 1e-4 still tells orientations
 * apart that differ by 0.006 degrees. */
#define COSINE_TOL 1e-4
/* A step may differ from the series' median step by this fraction: a
 * missing slice doubles a step, while positions rounded to 0.01 mm move a
 * 0.5 mm step by 2 %. */
#define STEP_TOL 0.05
/* Positions closer than this along the normal (mm) are one position. */
#define SAME_POSITION_MM 1e-3
/* Most series UIDs listed in the message about a mixed folder. */
#define UIDS_SHOWN 8

typedef struct slice {
  char *path;
  rp__dicom_meta m;
  double along; /* position along the slice normal */
} slice;

typedef struct slice_list {
  slice *s;
  size_t n, cap;
} slice_list;

static void slices_free(rp_context *ctx, slice_list *l) {
  size_t i;
  for (i = 0; i < l->n; i++)
    rp__free(ctx, l->s[i].path);
  rp__free(ctx, l->s);
  l->s = NULL;
  l->n = l->cap = 0;
}

static int slices_push(rp_context *ctx, slice_list *l, const char *path,
                       const rp__dicom_meta *m) {
  size_t len = strlen(path);
  if (l->n == l->cap) {
    size_t cap = l->cap ? 2 * l->cap : 64;
    slice *s = rp__malloc(ctx, cap * sizeof *s);
    if (s == NULL)
      return rp__fail(ctx, RP_ENOMEM, "%s: out of memory", path);
    if (l->n > 0)
      memcpy(s, l->s, l->n * sizeof *s);
    rp__free(ctx, l->s);
    l->s = s;
    l->cap = cap;
  }
  l->s[l->n].path = rp__malloc(ctx, len + 1);
  if (l->s[l->n].path == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory", path);
  memcpy(l->s[l->n].path, path, len + 1);
  l->s[l->n].m = *m;
  l->s[l->n].along = 0;
  l->n++;
  return 0;
}

static double dot3(const double *a, const double *b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/* The slice normal of ImageOrientationPatient: row x column cosines. */
static void normal_of(const double *o, double n[3]) {
  n[0] = o[1] * o[5] - o[2] * o[4];
  n[1] = o[2] * o[3] - o[0] * o[5];
  n[2] = o[0] * o[4] - o[1] * o[3];
}

static int orientation_ok(rp_context *ctx, const char *path,
                          const double *o) {
  double r = sqrt(dot3(o, o)), c = sqrt(dot3(o + 3, o + 3));
  double d = dot3(o, o + 3);
  if (fabs(r - 1.0) > 1e-3 || fabs(c - 1.0) > 1e-3 || fabs(d) > 1e-3)
    return rp__fail(ctx, RP_EFORMAT, "%s: ImageOrientationPatient "
                    "(0020,0037): row and column cosines of lengths %g and "
                    "%g with dot product %g are not two orthogonal unit "
                    "vectors", path, r, c, d);
  return 0;
}

static int by_along(const void *a, const void *b) {
  double x = ((const slice *)a)->along, y = ((const slice *)b)->along;
  return x < y ? -1 : x > y;
}

static int by_step(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return x < y ? -1 : x > y;
}

/* What every slice of a stack must share with the first one. */
static int check_same(rp_context *ctx, const slice *first,
                      const slice *s) {
  const rp__dicom_meta *a = &first->m, *b = &s->m;
  int i;
  if (a->rows != b->rows || a->cols != b->cols)
    return rp__fail(ctx, RP_EFORMAT, "%s: Rows (0028,0010) x Columns "
                    "(0028,0011) %u x %u, but %s has %u x %u: slices of "
                    "one volume have one size", s->path, b->rows, b->cols,
                    first->path, a->rows, a->cols);
  if (a->bits_allocated != b->bits_allocated ||
      a->pixel_rep != b->pixel_rep || a->samples != b->samples)
    return rp__fail(ctx, RP_EFORMAT, "%s: BitsAllocated (0028,0100) %d, "
                    "PixelRepresentation (0028,0103) %d, SamplesPerPixel "
                    "(0028,0002) %d, but %s has %d, %d, %d", s->path,
                    b->bits_allocated, b->pixel_rep, b->samples, first->path,
                    a->bits_allocated, a->pixel_rep, a->samples);
  if (b->frames != 1)
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: NumberOfFrames (0028,0008) "
                    "%u in a folder of slices: load a multi-frame file on "
                    "its own", s->path, b->frames);
  if (first == s)
    return 0;
  if (!b->has_position || !b->has_orientation || !a->has_orientation)
    return rp__fail(ctx, RP_EFORMAT, "%s: no %s: slices cannot be put in "
                    "order without it", !a->has_orientation ? first->path
                                                            : s->path,
                    !b->has_position ? "ImagePositionPatient (0020,0032)"
                                     : "ImageOrientationPatient (0020,0037)");
  for (i = 0; i < 6; i++)
    if (fabs(a->orientation[i] - b->orientation[i]) > COSINE_TOL)
      return rp__fail(ctx, RP_EFORMAT, "%s: ImageOrientationPatient "
                      "(0020,0037) %g\\%g\\%g\\%g\\%g\\%g differs from %s's "
                      "%g\\%g\\%g\\%g\\%g\\%g: mixed orientations are not "
                      "one volume", s->path, b->orientation[0],
                      b->orientation[1], b->orientation[2], b->orientation[3],
                      b->orientation[4], b->orientation[5], first->path,
                      a->orientation[0], a->orientation[1], a->orientation[2],
                      a->orientation[3], a->orientation[4],
                      a->orientation[5]);
  for (i = 0; i < 2 && a->has_pixel_spacing; i++)
    if (!b->has_pixel_spacing ||
        fabs(a->pixel_spacing[i] - b->pixel_spacing[i]) >
            1e-4 * a->pixel_spacing[i])
      return rp__fail(ctx, RP_EFORMAT, "%s: PixelSpacing (0028,0030) "
                      "differs from %s's %g\\%g", s->path, first->path,
                      a->pixel_spacing[0], a->pixel_spacing[1]);
  return 0;
}

/* The gaps between sorted slices: no duplicate, none off the median by
 * more than STEP_TOL, no slice off the normal line through the first (a
 * gantry tilt shears the grid). *step is the mean step. */
static int check_gaps(rp_context *ctx, const char *dir, const slice *s,
                      size_t n, double min_pixel, double *step) {
  double *steps = rp__malloc(ctx, (n - 1) * sizeof *steps);
  double median, normal[3];
  size_t i;
  int rc = 0;
  if (steps == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory", dir);
  normal_of(s[0].m.orientation, normal);
  for (i = 0; i + 1 < n && rc == 0; i++) {
    steps[i] = s[i + 1].along - s[i].along;
    if (steps[i] < SAME_POSITION_MM)
      rc = rp__fail(ctx, RP_EFORMAT, "%s: %s and %s lie at the same "
                    "position (ImagePositionPatient (0020,0032) along the "
                    "normal: %.4f mm): duplicate slices", dir, s[i].path,
                    s[i + 1].path, s[i].along);
  }
  for (i = 1; i < n && rc == 0; i++) {
    double d[3], along, off;
    int k;
    for (k = 0; k < 3; k++)
      d[k] = s[i].m.position[k] - s[0].m.position[k];
    along = dot3(d, normal);
    for (k = 0; k < 3; k++)
      d[k] -= along * normal[k];
    off = sqrt(dot3(d, d));
    if (off > 0.01 * min_pixel + 1e-3)
      rc = rp__fail(ctx, RP_EUNSUPPORTED, "%s: %s lies %.4g mm off the "
                    "line through %s along the slice normal "
                    "(ImagePositionPatient (0020,0032)): a tilted gantry "
                    "makes a sheared grid, which is not supported", dir,
                    s[i].path, off, s[0].path);
  }
  if (rc != 0) {
    rp__free(ctx, steps);
    return rc;
  }
  qsort(steps, n - 1, sizeof *steps, by_step);
  median = steps[(n - 1) / 2];
  rp__free(ctx, steps);
  for (i = 0; i + 1 < n; i++) {
    double gap = s[i + 1].along - s[i].along;
    if (fabs(gap - median) > STEP_TOL * median)
      return rp__fail(ctx, RP_EFORMAT, "%s: uneven slice spacing: %s and "
                      "%s (slices %zu and %zu in position order) are %.4g "
                      "mm apart along the normal, the series' median step "
                      "is %.4g mm: a missing or extra slice?", dir,
                      s[i].path, s[i + 1].path, i, i + 1, gap, median);
  }
  *step = (s[n - 1].along - s[0].along) / (double)(n - 1);
  return 0;
}

/* Lists the series of a folder that holds more than one. */
static int mixed_series(rp_context *ctx, const char *dir,
                        const slice_list *l) {
  char text[1024];
  size_t used = 0, shown = 0, i, j, total = 0;
  text[0] = '\0';
  for (i = 0; i < l->n; i++) {
    size_t count = 0;
    for (j = 0; j < i; j++)
      if (strcmp(l->s[j].m.series_uid, l->s[i].m.series_uid) == 0)
        break;
    if (j < i)
      continue; /* listed already */
    total++;
    for (j = i; j < l->n; j++)
      count += strcmp(l->s[j].m.series_uid, l->s[i].m.series_uid) == 0;
    if (shown < UIDS_SHOWN && used < sizeof text) {
      int w = snprintf(text + used, sizeof text - used, "%s'%s' (%zu files)",
                       shown ? ", " : "",
                       l->s[i].m.series_uid[0] ? l->s[i].m.series_uid
                                               : "(none)",
                       count);
      used += w > 0 ? (size_t)w : 0;
      shown++;
    }
  }
  return rp__fail(ctx, RP_EFORMAT, "%s: %zu series (SeriesInstanceUID "
                  "(0020,000E)) in one folder: %s%s; put each series in a "
                  "folder of its own", dir, total, text,
                  shown < total ? ", ..." : "");
}

/* ---- pixels: stored values to data units --------------------------- */

typedef struct stack {
  uint32_t dims[3];
  size_t plane;        /* voxels per file: rows x columns x frames */
  rp_voxel_type type;  /* RP_S16 while every value fits, then RP_F32 */
  void *data;
  int32_t *raw;        /* one file's stored values */
} stack;

static int rescale_ok(rp_context *ctx, const slice *s) {
  if (!isfinite(s->m.slope) || s->m.slope == 0.0)
    return rp__fail(ctx, RP_EFORMAT, "%s: RescaleSlope (0028,1053): value "
                    "%g (a slope is finite and not 0)", s->path, s->m.slope);
  if (!isfinite(s->m.intercept) || fabs(s->m.intercept) > 1e30)
    return rp__fail(ctx, RP_EFORMAT, "%s: RescaleIntercept (0028,1052): "
                    "value %g is out of range", s->path, s->m.intercept);
  return 0;
}

/* int16 data becomes float32 (exact), when a value does not fit int16;
 * `done` voxels have been written. */
static int widen_to_float(rp_context *ctx, const char *what, stack *st,
                          size_t done) {
  uint64_t d64[3] = {st->dims[0], st->dims[1], st->dims[2]};
  size_t voxels = 0, bytes = 0, i;
  const int16_t *src = st->data;
  float *dst;
  int rc = rp__volume_size(ctx, what, "Rows x Columns x slices", d64,
                           RP_F32, &voxels, &bytes);
  if (rc != 0)
    return rc;
  if ((dst = rp__malloc(ctx, bytes)) == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: cannot allocate %zu bytes", what,
                    bytes);
  for (i = 0; i < done; i++)
    dst[i] = src[i];
  rp__free(ctx, st->data);
  st->data = dst;
  st->type = RP_F32;
  return 0;
}

/* One file's stored values into the stack at voxel `at`, in data units:
 * value = stored x slope + intercept. */
static int put_plane(rp_context *ctx, const char *what, stack *st,
                     const slice *s, size_t at) {
  const int32_t *raw = st->raw;
  size_t i;
  int rc;
  if (st->type == RP_S16) {
    int16_t *dst = (int16_t *)st->data + at;
    int exact = s->m.slope == 1.0 && s->m.intercept == floor(s->m.intercept);
    int64_t b = (int64_t)s->m.intercept;
    for (i = 0; exact && i < st->plane; i++) {
      int64_t v = (int64_t)raw[i] + b;
      if (v < INT16_MIN || v > INT16_MAX)
        break;
      dst[i] = (int16_t)v;
    }
    if (exact && i == st->plane)
      return 0;
    if ((rc = widen_to_float(ctx, what, st, at)) != 0)
      return rc;
  }
  {
    float *dst = (float *)st->data + at;
    for (i = 0; i < st->plane; i++)
      dst[i] = (float)((double)raw[i] * s->m.slope + s->m.intercept);
  }
  return 0;
}

/* Reads every file of the sorted stack into a new volume. */
static int read_stack(rp_context *ctx, const char *what, const slice *s,
                      size_t n, const rp__dicom_src *one, stack *st) {
  uint64_t d64[3] = {st->dims[0], st->dims[1], st->dims[2]};
  uint64_t p64[3] = {st->dims[0], st->dims[1], s[0].m.frames};
  size_t voxels = 0, bytes = 0, plane_bytes = 0, k;
  int rc;
  /* Both buffers are checked against max_volume_bytes before either is
   * allocated: the volume (int16 at first) and one file's values. */
  if ((rc = rp__volume_size(ctx, what, "Rows x Columns x slices", d64,
                            RP_S16, &voxels, &bytes)) != 0 ||
      (rc = rp__volume_size(ctx, what, "Rows x Columns x NumberOfFrames",
                            p64, RP_S32, &st->plane, &plane_bytes)) != 0)
    return rc;
  st->type = RP_S16;
  st->data = rp__malloc(ctx, bytes);
  st->raw = rp__malloc(ctx, plane_bytes);
  if (st->data == NULL || st->raw == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: cannot allocate %zu bytes", what,
                    bytes + plane_bytes);
  for (k = 0; k < n; k++) {
    rp__dicom_src src = {s[k].path, NULL, 0};
    if ((rc = rescale_ok(ctx, &s[k])) != 0 ||
        (rc = rp__dicom_pixels_read(ctx, one != NULL ? one : &src, &s[k].m,
                                    st->raw, st->plane)) != 0 ||
        (rc = put_plane(ctx, what, st, &s[k], k * st->plane)) != 0)
      return rc;
  }
  return 0;
}

/* The spacings within RP_SPACING_MIN/MAX, each named by the tag it came
 * from, before any pixel data is read. */
static int check_spacings(rp_context *ctx, const char *what,
                          const rp__dicom_meta *m, double step) {
  static const char *const tags[2] = {
      "PixelSpacing (0028,0030) between columns",
      "PixelSpacing (0028,0030) between rows"};
  int a, rc;
  for (a = 0; a < 2 && m->has_pixel_spacing; a++)
    if ((rc = rp__spacing_check(ctx, what, tags[a], -1,
                                m->pixel_spacing[1 - a])) != 0)
      return rc;
  return rp__spacing_check(ctx, what, "the slice step (ImagePositionPatient "
                           "along the normal; one slice: "
                           "SpacingBetweenSlices or SliceThickness)", -1,
                           step);
}

/* The volume of a sorted stack: n slices (or one multi-frame file, then
 * `one` is its source), the step between slices along the normal. */
static int make_volume(rp_context *ctx, const char *what, const slice *s,
                       size_t n, double step, const rp__dicom_src *one,
                       rp_volume **out) {
  const rp__dicom_meta *m = &s[0].m;
  stack st;
  float spacing[3] = {1.0f, 1.0f, (float)step};
  rp_orientation o;
  int rc;
  memset(&st, 0, sizeof st);
  memset(&o, 0, sizeof o);
  st.dims[0] = m->cols;
  st.dims[1] = m->rows;
  st.dims[2] = (uint32_t)n * m->frames;
  if (m->has_pixel_spacing) {
    /* PixelSpacing is the distance between rows (y), then columns (x). */
    spacing[0] = (float)m->pixel_spacing[1];
    spacing[1] = (float)m->pixel_spacing[0];
  }
  if (m->has_position && m->has_orientation) {
    double normal[3];
    int i;
    normal_of(m->orientation, normal);
    o.known = 1;
    for (i = 0; i < 3; i++) {
      o.direction[i] = m->orientation[i];
      o.direction[3 + i] = m->orientation[3 + i];
      o.direction[6 + i] = normal[i];
      o.origin[i] = m->position[i];
    }
  }
  if ((rc = check_spacings(ctx, what, m, step)) != 0)
    return rc;
  rc = read_stack(ctx, what, s, n, one, &st);
  rp__free(ctx, st.raw);
  if (rc != 0) {
    rp__free(ctx, st.data);
    return rc;
  }
  if ((rc = rp__orientation_check(ctx, what, &o, &o)) != 0) {
    rp__free(ctx, st.data);
    return rc;
  }
  if ((rc = rp__volume_adopt(ctx, st.dims, st.type, spacing, st.data,
                             out)) == 0)
    (*out)->orientation = o;
  return rc;
}

/* One series' slices, in any order, into a volume. */
static int load_series(rp_context *ctx, const char *dir, slice_list *l,
                       rp_volume **out) {
  double normal[3], step = 1.0, min_pixel = 1.0;
  size_t i;
  int rc;
  if (l->n == 0)
    return rp__fail(ctx, RP_EFORMAT, "%s: no slices", dir);
  /* Slice 0 is held to the others (its position too) from slice 1 on. */
  for (i = l->n > 1 ? 1 : 0; i < l->n; i++)
    if ((rc = check_same(ctx, &l->s[0], &l->s[i])) != 0)
      return rc;
  if (l->n > 1 && !l->s[0].m.has_position)
    return rp__fail(ctx, RP_EFORMAT, "%s: no ImagePositionPatient "
                    "(0020,0032): slices cannot be put in order without it",
                    l->s[0].path);
  if (l->s[0].m.has_orientation &&
      (rc = orientation_ok(ctx, l->s[0].path, l->s[0].m.orientation)) != 0)
    return rc;
  normal_of(l->s[0].m.orientation, normal);
  for (i = 0; i < l->n; i++)
    l->s[i].along = dot3(l->s[i].m.position, normal);
  qsort(l->s, l->n, sizeof *l->s, by_along);
  if (l->s[0].m.has_pixel_spacing)
    min_pixel = fmin(l->s[0].m.pixel_spacing[0], l->s[0].m.pixel_spacing[1]);
  if (l->n > 1 &&
      (rc = check_gaps(ctx, dir, l->s, l->n, min_pixel, &step)) != 0)
    return rc;
  if (l->n == 1 && l->s[0].m.slice_step > 0)
    step = l->s[0].m.slice_step;
  return make_volume(ctx, dir, l->s, l->n, step, NULL, out);
}

static int by_name(const void *a, const void *b) {
  return strcmp(*(char *const *)a, *(char *const *)b);
}

/* The regular files of a folder, sorted by name (so that messages and
 * the "first" file do not depend on the file system's order). */
static int list_files(rp_context *ctx, const char *dir, char ***names,
                      size_t *count) {
  DIR *d = opendir(dir);
  struct dirent *e;
  size_t n = 0, cap = 0, dlen = strlen(dir);
  char **v = NULL;
  int rc = 0;
  if (d == NULL)
    return rp__fail(ctx, errno == ENOENT ? RP_ENOENT : RP_EIO,
                    "%s: cannot open the folder: %s", dir, strerror(errno));
  while (rc == 0 && (e = readdir(d)) != NULL) {
    struct stat st;
    char *p;
    size_t len = strlen(e->d_name);
    if (e->d_name[0] == '.')
      continue; /* ".", "..", and hidden files */
    if ((p = rp__malloc(ctx, dlen + len + 2)) == NULL) {
      rc = rp__fail(ctx, RP_ENOMEM, "%s: out of memory", dir);
      break;
    }
    memcpy(p, dir, dlen);
    p[dlen] = '/';
    memcpy(p + dlen + 1, e->d_name, len + 1);
    if (stat(p, &st) != 0 || !S_ISREG(st.st_mode)) {
      rp__free(ctx, p); /* sub-folders and devices are not slices */
      continue;
    }
    if (n == cap) {
      char **w = rp__malloc(ctx, (cap ? 2 * cap : 64) * sizeof *w);
      if (w == NULL) {
        rp__free(ctx, p);
        rc = rp__fail(ctx, RP_ENOMEM, "%s: out of memory", dir);
        break;
      }
      if (n > 0)
        memcpy(w, v, n * sizeof *w);
      rp__free(ctx, v);
      v = w;
      cap = cap ? 2 * cap : 64;
    }
    v[n++] = p;
  }
  closedir(d);
  if (rc == 0 && n > 1)
    qsort(v, n, sizeof *v, by_name);
  *names = v;
  *count = n;
  return rc;
}

/* A DICOM file without an image is skipped (a DICOMDIR, a report), but
 * not one of the series being loaded: that is a slice cut short. */
static int imageless_in_series(rp_context *ctx, const slice_list *l,
                               const slice_list *other) {
  size_t i;
  for (i = 0; l->n > 0 && i < other->n; i++)
    if (strcmp(other->s[i].m.series_uid, l->s[0].m.series_uid) == 0)
      return rp__fail(ctx, RP_EFORMAT, "%s: a file of the series '%s' "
                      "without an image (no Rows (0028,0010) or Columns "
                      "(0028,0011)): a slice cut short?", other->s[i].path,
                      other->s[i].m.series_uid);
  return 0;
}

int rp__dicom_load_dir(rp_context *ctx, const char *dir, rp_volume **out) {
  char **names = NULL;
  size_t n = 0, i;
  slice_list l = {NULL, 0, 0}, other = {NULL, 0, 0};
  int rc = list_files(ctx, dir, &names, &n);
  for (i = 0; rc == 0 && i < n; i++) {
    rp__dicom_src src = {names[i], NULL, 0};
    rp__dicom_meta m;
    rc = rp__dicom_meta_read(ctx, &src, &m);
    if (rc == 0)
      rc = slices_push(ctx, &l, names[i], &m);
    else if (rc == 1) /* not a DICOM image: skipped */
      rc = m.series_uid[0] ? slices_push(ctx, &other, names[i], &m) : 0;
  }
  if (rc == 0 && l.n == 0)
    rc = rp__fail(ctx, RP_EFORMAT, "%s: no DICOM image in the folder (%zu "
                  "files looked at; files that are not DICOM images are "
                  "skipped)", dir, n);
  for (i = 1; rc == 0 && i < l.n; i++)
    if (strcmp(l.s[i].m.series_uid, l.s[0].m.series_uid) != 0)
      rc = mixed_series(ctx, dir, &l);
  if (rc == 0)
    rc = imageless_in_series(ctx, &l, &other);
  if (rc == 0)
    rc = load_series(ctx, dir, &l, out);
  slices_free(ctx, &l);
  slices_free(ctx, &other);
  for (i = 0; i < n; i++)
    rp__free(ctx, names[i]);
  rp__free(ctx, names);
  return rc;
}

int rp__dicom_load_file(rp_context *ctx, const rp__dicom_src *src,
                        rp_volume **out) {
  slice s;
  double step;
  int rc = rp__dicom_meta_read(ctx, src, &s.m);
  if (rc == 1)
    return rp__fail(ctx, RP_EFORMAT, "%s: not a DICOM image (no Rows "
                    "(0028,0010) and Columns (0028,0011))", src->name);
  if (rc != 0)
    return rc;
  if (s.m.has_orientation &&
      (rc = orientation_ok(ctx, src->name, s.m.orientation)) != 0)
    return rc;
  s.path = (char *)src->name;
  s.along = 0;
  step = s.m.slice_step > 0 ? s.m.slice_step : 1.0;
  return make_volume(ctx, src->name, &s, 1, step, src, out);
}
