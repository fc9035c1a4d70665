/* libFuzzer target: a NIfTI file. nifticlib reads files only, so each
 * input is written to one scratch file of this process (.nii) and goes
 * through rp_volume_load, our header check, nifticlib's header reader and
 * our voxel reader together. Besides the sanitizers it checks the
 * loader's contract: a failure is a negative code with a message that
 * leaves *out alone; a success has a range and a valid orientation. */
#include <stdio.h>
#include <unistd.h>

#include "fuzz_common.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static const char *scratch_path(void) {
  static char path[256];
  if (path[0] == '\0') {
    const char *dir = getenv("TMPDIR");
    snprintf(path, sizeof path, "%s/rp_fuzz_nifti_%ld.nii",
             dir != NULL && dir[0] != '\0' ? dir : "/tmp", (long)getpid());
  }
  return path;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static int sentinel;
  rp_context *ctx = fuzz_context();
  rp_volume *vol = (rp_volume *)&sentinel;
  rp_volume_info info;
  const char *path = scratch_path();
  FILE *f = fopen(path, "wb");
  int rc;
  if (f == NULL || fwrite(data, 1, size, f) != size || fclose(f) != 0)
    abort();
  rp__clear_error(ctx);
  rc = rp_volume_load(ctx, path, &vol);
  unlink(path);
  if (!fuzz_loaded(ctx, rc, vol, &sentinel))
    return 0;
  rp_volume_get_info(vol, &info);
  if (!(info.min <= info.max) || fuzz_orientation_bad(&info.orientation))
    abort();
  rp_volume_destroy(vol);
  return 0;
}
