/* PNG output through libpng.
 *
 * The image goes to a temporary file beside `path` and is renamed over it
 * only once it is complete, so that a failed write (full disk, libpng
 * error) leaves an existing file as it was, as the API promises for every
 * output. The temporary gets a fresh name from mkstemp: a fixed name such
 * as "<path>.tmp" would clobber a file of the caller's and race with a
 * second writer of the same path. */
#include <errno.h>
#include <math.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "internal.h"

/* libpng reports errors through a callback that must not return; the
 * message is kept here for rp__fail, then png_longjmp unwinds. */
typedef struct png_error_box {
  char msg[256];
} png_error_box;

static void on_png_error(png_structp png, png_const_charp msg) {
  png_error_box *box = png_get_error_ptr(png);
  snprintf(box->msg, sizeof box->msg, "%s", msg != NULL ? msg : "?");
  png_longjmp(png, 1);
}

/* The library prints nothing; warnings carry nothing a caller can act on
 * that the error path does not already cover. */
static void on_png_warning(png_structp png, png_const_charp msg) {
  (void)png;
  (void)msg;
}

static void write_image(png_structp png, png_infop info, const uint8_t *rgb,
                        uint32_t width, uint32_t height) {
  uint32_t y;
  png_set_IHDR(png, info, width, height, 8, PNG_COLOR_TYPE_RGB,
               PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  for (y = 0; y < height; y++)
    png_write_row(png, rgb + (size_t)y * width * 3);
  png_write_end(png, NULL);
}

/* The setjmp lives in a function whose locals never change after it, so
 * nothing is left indeterminate by the longjmp (and -Wclobbered stays
 * quiet). */
static int guarded_write(png_structp png, png_infop info, FILE *f,
                         const uint8_t *rgb, uint32_t width,
                         uint32_t height) {
  if (setjmp(png_jmpbuf(png)))
    return -1;
  png_init_io(png, f);
#ifdef PNG_SET_USER_LIMITS_SUPPORTED
  /* The default write limit is 10^6 pixels a side; PNG allows 2^31-1. */
  png_set_user_limits(png, PNG_UINT_31_MAX, PNG_UINT_31_MAX);
#endif
  write_image(png, info, rgb, width, height);
  return 0;
}

/* `tmp` holds the mkstemp template "<path>.XXXXXX" and receives the
 * name. Every failure after mkstemp unlinks the temporary. */
static int write_file(rp_context *ctx, const char *path, char *tmp,
                      const uint8_t *rgb, uint32_t width, uint32_t height) {
  png_error_box box = {{0}};
  png_structp png;
  png_infop info = NULL;
  FILE *f;
  int fd, failed;
  fd = mkstemp(tmp);
  if (fd < 0) {
    int e = errno;
    return rp__fail(ctx, e == ENOENT || e == ENOTDIR ? RP_ENOENT : RP_EIO,
                    "png: cannot create a temporary file beside %s: %s",
                    path, strerror(e));
  }
  /* mkstemp makes the file 0600; an image is for others to read too, as
   * fopen would have made it under the usual umask. */
  if (fchmod(fd, 0644) != 0 || (f = fdopen(fd, "wb")) == NULL) {
    int e = errno;
    close(fd);
    unlink(tmp);
    return rp__fail(ctx, e == ENOMEM ? RP_ENOMEM : RP_EIO,
                    "png: cannot prepare %s: %s", tmp, strerror(e));
  }
  png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &box, on_png_error,
                                on_png_warning);
  if (png != NULL)
    info = png_create_info_struct(png);
  if (png == NULL || info == NULL) {
    png_destroy_write_struct(&png, &info);
    fclose(f);
    unlink(tmp);
    return rp__fail(ctx, RP_ENOMEM, "png: %s: libpng could not allocate "
                    "its state", path);
  }
  failed = guarded_write(png, info, f, rgb, width, height);
  png_destroy_write_struct(&png, &info);
  /* fclose flushes: a full disk often shows only here. */
  if (fclose(f) != 0 && !failed) {
    snprintf(box.msg, sizeof box.msg, "%s", strerror(errno));
    failed = 1;
  }
  if (!failed && rename(tmp, path) != 0) {
    snprintf(box.msg, sizeof box.msg, "cannot replace it: %s",
             strerror(errno));
    failed = 1;
  }
  if (failed) {
    unlink(tmp);
    return rp__fail(ctx, RP_EIO, "png: writing %s failed: %s", path,
                    box.msg);
  }
  return 0;
}

int rp__png_write_rgb(rp_context *ctx, const char *path, const uint8_t *rgb,
                      uint32_t width, uint32_t height) {
  size_t len;
  char *tmp;
  int err;
  if (width == 0 || height == 0 || width > PNG_UINT_31_MAX ||
      height > PNG_UINT_31_MAX)
    return rp__fail(ctx, RP_ERANGE, "png: %s: %ux%u is outside PNG's "
                    "1..2^31-1 pixels a side", path, (unsigned)width,
                    (unsigned)height);
  /* In the same directory, so that the rename stays on one file system
   * and is atomic. */
  len = strlen(path);
  tmp = rp__malloc(ctx, len + sizeof ".XXXXXX");
  if (tmp == NULL)
    return rp__fail(ctx, RP_ENOMEM, "png: %s: out of memory", path);
  memcpy(tmp, path, len);
  memcpy(tmp + len, ".XXXXXX", sizeof ".XXXXXX");
  err = write_file(ctx, path, tmp, rgb, width, height);
  rp__free(ctx, tmp);
  return err;
}

int rp_write_png(rp_context *ctx, const char *path, const uint8_t *rgba,
                 uint32_t width, uint32_t height, const float *background) {
  double bg[3] = {0.0, 0.0, 0.0};
  uint64_t pixels;
  uint8_t *rgb;
  size_t i, n;
  int c, err;
  if (ctx == NULL)
    return RP_EINVAL;
  if (path == NULL || path[0] == '\0' || rgba == NULL)
    return rp__fail(ctx, RP_EINVAL, "rp_write_png: %s is NULL or empty",
                    rgba == NULL ? "rgba" : "path");
  if (width == 0 || height == 0)
    return rp__fail(ctx, RP_EINVAL, "rp_write_png: %s: width and height "
                    "must be >= 1 (got %ux%u)", path, (unsigned)width,
                    (unsigned)height);
  if (background != NULL) {
    for (c = 0; c < 3; c++) {
      if (!(background[c] >= 0.0f && background[c] <= 1.0f))
        return rp__fail(ctx, RP_EINVAL, "rp_write_png: %s: background[%d] "
                        "is %g; must be in [0, 1]", path, c,
                        (double)background[c]);
      bg[c] = background[c];
    }
  }
  pixels = (uint64_t)width * height;
  if (pixels > SIZE_MAX / 4)
    return rp__fail(ctx, RP_EINVAL, "rp_write_png: %s: %ux%u pixels "
                    "overflow size_t", path, (unsigned)width,
                    (unsigned)height);
  n = (size_t)pixels;
  rgb = rp__malloc(ctx, n * 3);
  if (rgb == NULL)
    return rp__fail(ctx, RP_ENOMEM, "rp_write_png: %s: no memory for "
                    "%ux%u pixels", path, (unsigned)width,
                    (unsigned)height);
  /* out = C + (1 - A) bg, worked on the 0..255 scale (C + (255 - A) bg)
   * so that dyadic backgrounds such as 0.5 give exact results rather
   * than values a rounding away from a tie. */
  for (i = 0; i < n; i++) {
    const uint8_t *px = rgba + 4 * i;
    for (c = 0; c < 3; c++) {
      double v = px[c] + (255.0 - px[3]) * bg[c];
      if (v > 255.0)
        v = 255.0;
      rgb[3 * i + c] = (uint8_t)floor(v + 0.5);
    }
  }
  err = rp__png_write_rgb(ctx, path, rgb, width, height);
  rp__free(ctx, rgb);
  return err;
}
