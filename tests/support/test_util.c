#include "test_util.h"

#include <dirent.h>
#include <errno.h>
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
