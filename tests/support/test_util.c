#include "test_util.h"

#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

const char *rp_test_data_dir(void) {
  const char *dir = getenv("RP_SHARED_DATA");
  struct stat st;
  if (dir == NULL || stat(dir, &st) != 0 || !S_ISDIR(st.st_mode))
    return NULL;
  return dir;
}

const char *rp_test_data_volume(const char *name, char *buf, size_t len) {
  const char *dir = rp_test_data_dir();
  struct stat st;
  if (dir == NULL)
    return NULL;
  snprintf(buf, len, "%s/%s/%s.txt", dir, name, name);
  return stat(buf, &st) == 0 ? buf : NULL;
}

static int cmp_str(const void *a, const void *b) {
  return strcmp(*(char *const *)a, *(char *const *)b);
}

const char *const *rp_test_data_names(void) {
  static char names[64][64];
  static const char *list[65];
  int n = 0;
  const char *dir = rp_test_data_dir();
  if (dir != NULL) {
    DIR *d = opendir(dir);
    struct dirent *e;
    while (d != NULL && (e = readdir(d)) != NULL && n < 64) {
      char path[1024];
      if (e->d_name[0] == '.' || strlen(e->d_name) >= 64)
        continue;
      if (rp_test_data_volume(e->d_name, path, sizeof path) == NULL)
        continue;
      memcpy(names[n], e->d_name, strlen(e->d_name) + 1); /* < 64 */
      list[n] = names[n];
      n++;
    }
    if (d != NULL)
      closedir(d);
  }
  qsort(list, (size_t)n, sizeof list[0], cmp_str);
  list[n] = NULL;
  return list;
}

const char *rp_test_tmp_dir(void) {
  const char *dir = getenv("RP_TEST_TMP");
  if (dir == NULL || dir[0] == '\0')
    dir = "/tmp";
  if (mkdir(dir, 0777) != 0 && errno != EEXIST)
    fail_msg("cannot create %s", dir);
  return dir;
}

const char *rp_test_write_file(const char *name, const void *data,
                               size_t len) {
  static char paths[8][1024];
  static int next;
  char *path = paths[next++ % 8];
  FILE *f;
  snprintf(path, 1024, "%s/%s", rp_test_tmp_dir(), name);
  f = fopen(path, "wb");
  assert_non_null(f);
  assert_int_equal(fwrite(data, 1, len, f), len);
  assert_int_equal(fclose(f), 0);
  return path;
}

rp_context *rp_test_context(void) {
  rp_context *ctx = NULL;
  assert_int_equal(rp_context_create(NULL, &ctx), 0);
  assert_non_null(ctx);
  return ctx;
}

int rp_test_has_device(const char *backend) {
  rp_context *probe = rp_test_context();
  uint32_t n = 0;
  int have = rp_device_count(probe, backend, &n) == 0 && n > 0;
  rp_context_destroy(probe);
  return have;
}

void rp_test_check_fetches(const char *what, const rp_tile_stats *got,
                           const uint64_t *got_fetches,
                           const rp_tile_stats *want,
                           const uint64_t *want_fetches, size_t tiles,
                           uint32_t effects, uint64_t *total,
                           uint64_t *off) {
  uint64_t sum = 0, away = 0, explained = 0;
  uint64_t per = rp_test_visible_fetches(effects);
  uint64_t per_ray = (effects & RP_EFFECT_PREINT) ? 1u : 0u;
  size_t k;
  for (k = 0; k < tiles; k++) {
    uint64_t ray_f = per_ray * got[k].rays_hit;
    uint64_t f = got_fetches[k], n = got[k].samples, w = want_fetches[k];
    int64_t ds = (int64_t)got[k].samples - (int64_t)want[k].samples;
    int64_t dh = (int64_t)got[k].rays_hit - (int64_t)want[k].rays_hit;
    uint64_t slack = (1u + per) * (uint64_t)(ds < 0 ? -ds : ds) +
                     per_ray * (uint64_t)(dh < 0 ? -dh : dh);
    uint64_t d = f > w ? f - w : w - f;
    /* The per-ray fetch first (PREINT: the value before the first
     * sample), then one per sample and per_visible per visible one. */
    if (f < ray_f)
      fail_msg("%s: tile %zu: %llu fetches for %u rays that sample", what,
               k, (unsigned long long)f, got[k].rays_hit);
    f -= ray_f;
    if (f < n || f > (1u + per) * n || (per == 0 && f != n) ||
        (per != 0 && (f - n) % per != 0))
      fail_msg("%s: tile %zu: %llu fetches for %llu samples", what, k,
               (unsigned long long)f, (unsigned long long)n);
    if (d > slack + per * RP_TILE_SIZE * RP_TILE_SIZE)
      fail_msg("%s: tile %zu: %llu fetches, reference %llu (samples %u vs "
               "%u)", what, k, (unsigned long long)got_fetches[k],
               (unsigned long long)w,
               got[k].samples, want[k].samples);
  sum += w;
    away += d;
    explained += slack;
  }
  away = away > explained ? away - explained : 0;
  if (away * 1000u > sum)
    fail_msg("%s: fetches %llu off the reference's %llu beyond the sample "
             "differences; the bound is 0.1 %%", what,
             (unsigned long long)away, (unsigned long long)sum);
  *total += sum;
  *off += away;
}

unsigned rp_test_visible_fetches(uint32_t effects) {
  return ((effects & RP_EFFECT_SHADING) ? 6u : 0u) +
         ((effects & RP_EFFECT_AO) ? 1u : 0u);
}

rp_tf *rp_test_preset(rp_context *ctx, const char *name) {
  rp_tf *tf = NULL;
  assert_int_equal(rp_tf_create_preset(ctx, name, &tf), 0);
  return tf;
}

void rp_test_expect_reference(rp_context *ctx, const rp_volume *vol,
                              const rp_tf *tf, const rp_ao *ao,
                              const rp_camera *cam, uint32_t w, uint32_t h,
                              uint32_t effects, uint32_t jitter_seed,
                              const uint8_t *got) {
  rp_histograms *hist = NULL;
  rp_occupancy *occ = NULL;
  rp_render_desc rd = {0};
  uint8_t *want = malloc((size_t)w * h * 4);
  assert_non_null(want);
  assert_int_equal(rp_histograms_build(ctx, vol, &hist), 0);
  assert_int_equal(rp_occupancy_build(ctx, hist, tf, &occ), 0);
  rd.width = w;
  rd.height = h;
  rd.effects = effects | (ao != NULL ? RP_EFFECT_AO : 0u);
  rd.jitter = jitter_seed != 0 ? RP_JITTER_ON : RP_JITTER_OFF;
  rd.jitter_seed = jitter_seed;
  assert_int_equal(
      rp_render_reference(ctx, vol, tf, occ, ao, cam, &rd, want, NULL), 0);
  assert_memory_equal(got, want, (size_t)w * h * 4);
  free(want);
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(hist);
}

rp_test_scene rp_test_scene_make(rp_context *ctx, rp_generator kind,
                                 uint32_t n, uint32_t seed, const char *tf) {
  rp_test_scene s;
  rp_generate_desc g = {kind, {n, n, n}, RP_U8, seed};
  memset(&s, 0, sizeof s);
  assert_int_equal(rp_volume_generate(ctx, &g, &s.vol), 0);
  assert_int_equal(rp_histograms_build(ctx, s.vol, &s.h), 0);
  s.tf = rp_test_preset(ctx, tf);
  assert_int_equal(rp_occupancy_build(ctx, s.h, s.tf, &s.occ), 0);
  return s;
}

void rp_test_scene_drop(rp_test_scene *s) {
  rp_occupancy_destroy(s->occ);
  rp_tf_destroy(s->tf);
  rp_histograms_destroy(s->h);
  rp_volume_destroy(s->vol);
}

void rp_test_faults(rp_device_desc *d, rp_fault_desc *f) {
  f->header.type = RP_EXT_FAULTS;
  f->header.next = d->next;
  d->next = f;
}

rp_tf *rp_test_ramp_tf(rp_context *ctx, float ref_step) {
  rp_tf_point pts[4] = {{0.0f, 0.1f, 0.2f, 0.9f, 0.0f},
                        {0.35f, 0.9f, 0.6f, 0.1f, 0.0f},
                        {0.6f, 1.0f, 0.9f, 0.3f, 0.25f},
                        {1.0f, 0.9f, 0.1f, 0.1f, 0.6f}};
  rp_tf_desc d = {pts, 4, ref_step, 256, 0, 0, 0, 0};
  rp_tf *tf = NULL;
  assert_int_equal(rp_tf_create(ctx, &d, &tf), 0);
  return tf;
}

rp_volume *rp_test_generate(rp_context *ctx, rp_generator kind, uint32_t x,
                            uint32_t y, uint32_t z, rp_voxel_type type,
                            uint32_t seed) {
  rp_generate_desc d = {0};
  rp_volume *vol = NULL;
  d.kind = kind, d.dims[0] = x, d.dims[1] = y, d.dims[2] = z;
  d.type = type, d.seed = seed;
  assert_int_equal(rp_volume_generate(ctx, &d, &vol), 0);
  return vol;
}

/* A float volume of `dims` and `spacing` whose voxel (x, y, z) is
 * f(x, y, z). */
static rp_volume *float_volume(rp_context *ctx, const uint32_t dims[3],
                               const float spacing[3],
                               double (*f)(double, double, double)) {
  rp_volume_desc d = {{dims[0], dims[1], dims[2]}, RP_F32,
                      {spacing[0], spacing[1], spacing[2]}, NULL, {0}};
  float *data = malloc(sizeof(float) * dims[0] * dims[1] * dims[2]);
  rp_volume *vol = NULL;
  uint32_t x, y, z;
  assert_non_null(data);
  for (z = 0; z < dims[2]; z++)
    for (y = 0; y < dims[1]; y++)
      for (x = 0; x < dims[0]; x++)
        data[((size_t)z * dims[1] + y) * dims[0] + x] = (float)f(x, y, z);
  d.data = data;
  assert_int_equal(rp_volume_create(ctx, &d, &vol), 0);
  free(data);
  return vol;
}

static double two_blobs(double x, double y, double z) {
  double a = (x - 12.0) * (x - 12.0) + (y - 14.0) * (y - 14.0) +
             (z - 12.0) * (z - 12.0);
  double b = (x - 25.0) * (x - 25.0) + (y - 16.0) * (y - 16.0) +
             (z - 14.0) * (z - 14.0);
  return 3.0 * exp(-a / 40.0) - 2.0 * exp(-b / 25.0) + 0.01 * x - 0.5;
}

rp_volume *rp_test_float_field(rp_context *ctx) {
  static const uint32_t dims[3] = {37, 30, 26};
  static const float spacing[3] = {1.0f, 1.5f, 0.8f};
  return float_volume(ctx, dims, spacing, two_blobs);
}

static double one_blob(double x, double y, double z) {
  double dx = x - 10.0, dy = (y - 9.0) * 1.3, dz = (z - 12.0) * 0.8;
  return -3.5 + 100.0 * exp(-(dx * dx + dy * dy + dz * dz) / 40.0);
}

rp_volume *rp_test_float_blob(rp_context *ctx) {
  static const uint32_t dims[3] = {21, 18, 25};
  static const float spacing[3] = {1.0f, 1.3f, 0.8f};
  return float_volume(ctx, dims, spacing, one_blob);
}

rp_volume *rp_test_load_ok(rp_context *ctx, const char *path) {
  rp_volume *v = NULL;
  int rc = rp_volume_load(ctx, path, &v);
  if (rc != 0)
    fail_msg("%s: %s: %s", path, rp_err_name(rc), rp_last_error(ctx));
  assert_non_null(v);
  return v;
}

void rp_test_load_fails(rp_context *ctx, const char *path, int code, ...) {
  static int sentinel;
  rp_volume *v = (rp_volume *)&sentinel;
  const char *needle;
  va_list ap;
  int rc = rp_volume_load(ctx, path, &v);
  if (rc != code)
    fail_msg("%s: got %s, want %s (%s)", path, rp_err_name(rc),
             rp_err_name(code), rp_last_error(ctx));
  assert_ptr_equal(v, (rp_volume *)&sentinel);
  va_start(ap, code);
  while ((needle = va_arg(ap, const char *)) != NULL) {
    if (strstr(rp_last_error(ctx), needle) == NULL) {
      va_end(ap);
      fail_msg("%s: message '%s' does not mention '%s'", path,
               rp_last_error(ctx), needle);
    }
  }
  va_end(ap);
}

double rp_test_voxel(const rp_volume *vol, size_t i) {
  rp_volume_info info;
  const uint8_t *p = rp_volume_data(vol);
  double x;
  rp_volume_get_info(vol, &info);
  if (info.stored_type == RP_U8) {
    x = p[i];
  } else if (info.stored_type == RP_U16) {
    uint16_t u;
    memcpy(&u, p + 2 * i, 2);
    x = u;
  } else {
    float f;
    assert_int_equal(info.stored_type, RP_F32);
    memcpy(&f, p + 4 * i, 4);
    x = f;
  }
  return x + info.stored_offset;
}

void rp_test_expect_orientation(const rp_volume *vol,
                                const double direction[9],
                                const double origin[3], double tol) {
  rp_volume_info info;
  int i;
  rp_volume_get_info(vol, &info);
  assert_true(info.orientation.known);
  for (i = 0; i < 9; i++)
    if (!(fabs(info.orientation.direction[i] - direction[i]) <= tol))
      fail_msg("direction[%d] (axis %d, component %d) = %.9g, want %.9g", i,
               i / 3, i % 3, info.orientation.direction[i], direction[i]);
  for (i = 0; i < 3; i++)
    if (!(fabs(info.orientation.origin[i] - origin[i]) <= tol))
      fail_msg("origin[%d] = %.9g, want %.9g", i, info.orientation.origin[i],
               origin[i]);
}

const char *rp_test_write_with(const char *name, const char *text,
                               const void *payload, size_t n) {
  size_t t = strlen(text);
  uint8_t *buf = malloc(t + n + 1);
  const char *path;
  assert_non_null(buf);
  memcpy(buf, text, t);
  if (n > 0)
    memcpy(buf + t, payload, n);
  path = rp_test_write_file(name, buf, t + n);
  free(buf);
  return path;
}

double rp_test_pattern(rp_voxel_type t, int i) {
  switch (t) {
  case RP_U8: return i * 10 + 5;
  case RP_S8: return i * 5 - 60;
  case RP_U16: return 1000 + i * 2345;
  case RP_S16: return i * 137 - 1500;
  case RP_U32: return 100000.0 + i * 70001.0;
  case RP_S32: return i * 90001.0 - 1000000.0;
  default: return -2.5 + i * 0.75;
  }
}

void rp_test_check_pattern(const rp_volume *v, rp_voxel_type t,
                           const uint32_t dims[3], const float spacing[3]) {
  rp_volume_info info;
  double lo = INFINITY, hi = -INFINITY;
  size_t n, i;
  int a;
  rp_volume_get_info(v, &info);
  assert_int_equal(info.type, t);
  for (a = 0; a < 3; a++) {
    assert_int_equal(info.dims[a], dims[a]);
    if (info.spacing[a] != spacing[a])
      fail_msg("spacing[%d] = %.9g, want %.9g", a, (double)info.spacing[a],
               (double)spacing[a]);
  }
  n = (size_t)dims[0] * dims[1] * dims[2];
  for (i = 0; i < n; i++) {
    double want = rp_test_pattern(t, (int)i);
    if (rp_test_voxel(v, i) != want)
      fail_msg("voxel %zu = %.9g, want %.9g", i, rp_test_voxel(v, i), want);
    lo = want < lo ? want : lo;
    hi = want > hi ? want : hi;
  }
  assert_true(info.min == lo);
  assert_true(info.max == hi);
}

void rp_test_expect_no_orientation(const rp_volume *vol) {
  rp_volume_info info;
  int i;
  rp_volume_get_info(vol, &info);
  assert_false(info.orientation.known);
  for (i = 0; i < 9; i++)
    assert_true(info.orientation.direction[i] == (i % 4 == 0 ? 1.0 : 0.0));
  for (i = 0; i < 3; i++)
    assert_true(info.orientation.origin[i] == 0.0);
}
