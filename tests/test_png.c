/* PNG output (rp_write_png): what a reader gets back, composited on the
 * background, worked out from the pixels written; errors that name the
 * path; and the write through a temporary beside the file, so that a
 * failed write never leaves a partial image where the old one was.
 * Moved out of test_reference.c, which tests the raycaster. */
#include "test_util.h"
#include <dirent.h>
#include <math.h>
#include <png.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>

static uint8_t *read_png_rgb(const char *path, uint32_t *w, uint32_t *h) {
  png_image img;
  uint8_t *buf;
  memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  assert_true(png_image_begin_read_from_file(&img, path));
  img.format = PNG_FORMAT_RGB;
  buf = malloc(PNG_IMAGE_SIZE(img));
  assert_non_null(buf);
  assert_true(png_image_finish_read(&img, NULL, buf, 0, NULL));
  *w = img.width;
  *h = img.height;
  return buf;
}

static void test_png_roundtrip(void **state) {
  rp_context *ctx = rp_test_context();
  const uint32_t w = 13, h = 7;
  const float bg[3] = {0.25f, 0.5f, 1.0f};
  uint8_t rgba[13 * 7 * 4];
  char path[1024];
  uint32_t rw, rh, i;
  uint8_t *back;
  int c, err;
  (void)state;
  /* Premultiplied pixels: each colour channel at most alpha. */
  for (i = 0; i < w * h; i++) {
    uint8_t a = (uint8_t)(i * 37 % 256);
    rgba[i * 4 + 3] = a;
    for (c = 0; c < 3; c++)
      rgba[i * 4 + c] = (uint8_t)(a == 0 ? 0 : (i * 11 + c * 29) % (a + 1));
  }
  snprintf(path, sizeof path, "%s/test_png_bg.png", rp_test_tmp_dir());
  assert_int_equal(rp_write_png(ctx, path, rgba, w, h, bg), 0);
  back = read_png_rgb(path, &rw, &rh);
  assert_int_equal(rw, w);
  assert_int_equal(rh, h);
  for (i = 0; i < w * h; i++)
    for (c = 0; c < 3; c++) {
      /* Dyadic backgrounds make C + (255 - A) bg exact in binary. */
      double v = rgba[i * 4 + c] + (255.0 - rgba[i * 4 + 3]) * bg[c];
      int want = (int)floor((v > 255.0 ? 255.0 : v) + 0.5);
      assert_int_equal(back[i * 3 + c], want);
    }
  free(back);

  /* No background: black, so RGB is the premultiplied colour. */
  snprintf(path, sizeof path, "%s/test_png_black.png",
           rp_test_tmp_dir());
  assert_int_equal(rp_write_png(ctx, path, rgba, w, h, NULL), 0);
  back = read_png_rgb(path, &rw, &rh);
  for (i = 0; i < w * h; i++)
    for (c = 0; c < 3; c++)
      assert_int_equal(back[i * 3 + c], rgba[i * 4 + c]);
  free(back);

  /* Errors name the path. */
  snprintf(path, sizeof path, "%s/no/such/dir/x.png", rp_test_tmp_dir());
  err = rp_write_png(ctx, path, rgba, w, h, NULL);
  assert_int_equal(err, RP_ENOENT);
  assert_non_null(strstr(rp_last_error(ctx), "no/such/dir"));
  {
    const float bad[3] = {0.0f, 1.5f, 0.0f};
    assert_int_equal(rp_write_png(ctx, "x.png", rgba, w, h, bad), RP_EINVAL);
    assert_non_null(strstr(rp_last_error(ctx), "background[1]"));
  }
  assert_int_equal(rp_write_png(ctx, NULL, rgba, w, h, NULL), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "path"));
  assert_int_equal(rp_write_png(ctx, "x.png", NULL, w, h, NULL), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "rgba"));
  assert_int_equal(rp_write_png(ctx, "x.png", rgba, 0, h, NULL), RP_EINVAL);
  assert_non_null(strstr(rp_last_error(ctx), "width"));
  assert_int_equal(rp_write_png(NULL, "x.png", rgba, w, h, NULL), RP_EINVAL);
  rp_context_destroy(ctx);
}

/* Writes a small file with the given content. */
static void put_file(const char *path, const char *text) {
  FILE *f = fopen(path, "wb");
  assert_non_null(f);
  assert_int_equal(fputs(text, f) >= 0, 1);
  assert_int_equal(fclose(f), 0);
}

/* The file holds exactly `text`. */
static void assert_file_is(const char *path, const char *text) {
  char buf[256];
  size_t n;
  FILE *f = fopen(path, "rb");
  assert_non_null(f);
  n = fread(buf, 1, sizeof buf - 1, f);
  fclose(f);
  buf[n] = '\0';
  assert_string_equal(buf, text);
}

/* Names in `dir`, other than "." and "..". */
static int count_entries(const char *dir) {
  DIR *d = opendir(dir);
  struct dirent *e;
  int n = 0;
  assert_non_null(d);
  while ((e = readdir(d)) != NULL)
    if (strcmp(e->d_name, ".") != 0 && strcmp(e->d_name, "..") != 0)
      n++;
  closedir(d);
  return n;
}

/* The image goes to a fresh temporary beside `path`: a file the caller
 * named "<path>.tmp" is never touched, and a failed write leaves `path`
 * as it was and no temporary behind. */
static void test_png_temp_file(void **state) {
  enum { W = 64, H = 64 };
  rp_context *ctx = rp_test_context();
  char dir[1024], path[1100], tmp[1200], sub[1200];
  uint8_t *rgba = malloc(W * H * 4);
  uint32_t x = 1, rw, rh, i;
  uint8_t *back;
  (void)state;
  assert_non_null(rgba);
  for (i = 0; i < W * H * 4; i++) { /* noise: hardly compresses */
    x = x * 1664525u + 1013904223u;
    rgba[i] = (uint8_t)(i % 4 == 3 ? 255 : x >> 24);
  }
  snprintf(dir, sizeof dir, "%s/png_tmp", rp_test_tmp_dir());
  mkdir(dir, 0777);
  snprintf(path, sizeof path, "%s/out.png", dir);
  snprintf(tmp, sizeof tmp, "%s/out.png.tmp", dir);
  snprintf(sub, sizeof sub, "%s/out.png/keep", dir);
  remove(sub);
  remove(path); /* a directory left by an earlier run, or a file */
  put_file(tmp, "the caller's own file");

  /* Success: the image is in place, the caller's file is intact. */
  assert_int_equal(rp_write_png(ctx, path, rgba, W, H, NULL), 0);
  assert_file_is(tmp, "the caller's own file");
  assert_int_equal(count_entries(dir), 2);
  back = read_png_rgb(path, &rw, &rh);
  assert_int_equal(rw, W);
  assert_int_equal(rh, H);
  for (i = 0; i < W * H; i++)
    assert_memory_equal(back + 3 * i, rgba + 4 * i, 3);
  free(back);

  /* Failure before any file is made: `path` is untouched. */
  put_file(path, "an older image");
  assert_int_equal(rp_write_png(ctx, path, rgba, 0, H, NULL), RP_EINVAL);
  assert_file_is(path, "an older image");
  assert_file_is(tmp, "the caller's own file");
  assert_int_equal(count_entries(dir), 2);

  /* Failure while writing (the file size limit stands in for a full
   * disk): `path` keeps its content, the temporary is gone. */
  {
    struct rlimit old, lim;
    void (*prev)(int) = signal(SIGXFSZ, SIG_IGN);
    int err;
    assert_int_equal(getrlimit(RLIMIT_FSIZE, &old), 0);
    lim = old;
    lim.rlim_cur = 1024;
    assert_int_equal(setrlimit(RLIMIT_FSIZE, &lim), 0);
    err = rp_write_png(ctx, path, rgba, W, H, NULL);
    assert_int_equal(setrlimit(RLIMIT_FSIZE, &old), 0);
    signal(SIGXFSZ, prev);
    assert_int_equal(err, RP_EIO);
    assert_non_null(strstr(rp_last_error(ctx), "out.png"));
  }
  assert_file_is(path, "an older image");
  assert_file_is(tmp, "the caller's own file");
  assert_int_equal(count_entries(dir), 2);

  /* Failure at the rename: `path` is a directory, which stays as it was
   * with its content. */
  remove(path);
  assert_int_equal(mkdir(path, 0777), 0);
  put_file(sub, "kept");
  assert_int_equal(rp_write_png(ctx, path, rgba, W, H, NULL), RP_EIO);
  assert_non_null(strstr(rp_last_error(ctx), "out.png"));
  assert_file_is(sub, "kept");
  assert_file_is(tmp, "the caller's own file");
  assert_int_equal(count_entries(dir), 2);
  remove(sub);
  remove(path);
  free(rgba);
  rp_context_destroy(ctx);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_png_roundtrip),
      cmocka_unit_test(test_png_temp_file),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
