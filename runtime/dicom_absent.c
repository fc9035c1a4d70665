/* DICOM input in a build without GDCM (volume_dicom.h): refused with a
 * message that says how to get it, so that a folder of slices never meets
 * "not a regular file". */
#include "internal.h"
#include "volume_dicom.h"

int rp__dicom_load_dir(rp_context *ctx, const char *dir, rp_volume **out) {
  (void)out;
  return rp__fail(ctx, RP_EUNSUPPORTED, "%s: a folder (a DICOM series?): "
                  "this raypace was built without GDCM (Debian "
                  "libgdcm-dev), which reads DICOM", dir);
}

int rp__dicom_load_file(rp_context *ctx, const rp__dicom_src *src,
                        rp_volume **out) {
  (void)out;
  return rp__fail(ctx, RP_EUNSUPPORTED, "%s: a DICOM file: this raypace "
                  "was built without GDCM (Debian libgdcm-dev), which "
                  "reads DICOM", src->name);
}
