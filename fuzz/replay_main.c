/* A main for the fuzz targets without libFuzzer: runs
 * LLVMFuzzerTestOneInput once on each file named on the command line, as
 * libFuzzer does when given files. The test builds link the targets with
 * it, so that `./dev.sh test` replays every corpus under the build's own
 * sanitizers (gcc's ASan and UBSan in build-asan) without a second,
 * clang-instrumented copy of the library; `./dev.sh fuzz` builds the real
 * fuzzers. */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* The whole file in a buffer of exactly its size (so that ASan sees a
 * read past the input), or NULL with *size 0 for an empty file. */
static int read_all(const char *path, uint8_t **out, size_t *size) {
  FILE *f = fopen(path, "rb");
  long n;
  *out = NULL;
  *size = 0;
  if (f == NULL)
    return -1;
  if (fseek(f, 0, SEEK_END) != 0 || (n = ftell(f)) < 0 ||
      fseek(f, 0, SEEK_SET) != 0) {
    fclose(f);
    return -1;
  }
  if (n > 0) {
    if ((*out = malloc((size_t)n)) == NULL ||
        fread(*out, 1, (size_t)n, f) != (size_t)n) {
      free(*out);
      *out = NULL;
      fclose(f);
      return -1;
    }
    *size = (size_t)n;
  }
  fclose(f);
  return 0;
}

int main(int argc, char **argv) {
  int i;
  if (argc < 2) {
    fprintf(stderr, "usage: %s INPUT...\n", argv[0]);
    return 2;
  }
  for (i = 1; i < argc; i++) {
    uint8_t *data;
    size_t size;
    if (read_all(argv[i], &data, &size) != 0) {
      fprintf(stderr, "%s: cannot read %s\n", argv[0], argv[i]);
      return 1;
    }
    LLVMFuzzerTestOneInput(data, size);
    free(data);
  }
  printf("%s: %d inputs replayed\n", argv[0], argc - 1);
  return 0;
}
