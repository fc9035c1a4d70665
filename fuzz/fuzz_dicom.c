/* libFuzzer target: one DICOM file in memory, through the GDCM shim and
 * the same assembly a file on disk gets (rp__dicom_load_file: header,
 * geometry, pixel data, rescale). Besides the sanitizers, it checks the
 * loaders' contract: a failure is a negative code with a message and
 * leaves *out untouched; a success is a volume of the header's size, in
 * int16 or float32 data units. */
#include "fuzz_common.h"
#include "volume_dicom.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  static int sentinel;
  rp_context *ctx = fuzz_context();
  rp__dicom_src src = {"fuzz.dcm", data, size};
  rp__dicom_meta meta;
  rp_volume *vol = (rp_volume *)&sentinel;
  rp_volume_info info;
  int rc;

  rp__clear_error(ctx);
  rc = rp__dicom_meta_read(ctx, &src, &meta);
  if (rc == 1)
    return 0; /* not DICOM: nothing recorded, nothing to check */
  if (!fuzz_parsed(ctx, rc))
    return 0;
  rp__clear_error(ctx);
  rc = rp__dicom_load_file(ctx, &src, &vol);
  if (!fuzz_loaded(ctx, rc, vol, &sentinel))
    return 0;
  rp_volume_get_info(vol, &info);
  if (info.dims[0] != meta.cols || info.dims[1] != meta.rows ||
      info.dims[2] != meta.frames ||
      (info.type != RP_S16 && info.type != RP_F32) ||
      !(info.min <= info.max))
    abort();
  rp_volume_destroy(vol);
  return 0;
}
