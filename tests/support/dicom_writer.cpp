/* Writes DICOM files for the tests with GDCM's writer (dicom_writer.h):
 * the data set is built tag by tag, so that a test says exactly what a
 * file holds, malformed geometry included. */
#include <cstdio>
#include <cstring>
#include <exception>
#include <string>

#include <gdcmDataSet.h>
#include <gdcmFile.h>
#include <gdcmImageChangeTransferSyntax.h>
#include <gdcmImageReader.h>
#include <gdcmImageWriter.h>
#include <gdcmTag.h>
#include <gdcmTransferSyntax.h>
#include <gdcmWriter.h>

#include "dicom_writer.h"

namespace {

void put(gdcm::DataSet &ds, uint16_t g, uint16_t e, gdcm::VR vr,
         std::string value, char pad = ' ') {
  if (value.size() % 2)
    value += pad;
  gdcm::DataElement de(gdcm::Tag(g, e));
  de.SetVR(vr);
  de.SetByteValue(value.data(), (uint32_t)value.size());
  ds.Insert(de);
}

void put_us(gdcm::DataSet &ds, uint16_t g, uint16_t e, uint16_t v) {
  gdcm::DataElement de(gdcm::Tag(g, e));
  de.SetVR(gdcm::VR::US);
  de.SetByteValue(reinterpret_cast<const char *>(&v), 2);
  ds.Insert(de);
}

std::string numbers(const double *v, int n) {
  std::string s;
  char buf[64];
  for (int i = 0; i < n; i++) {
    std::snprintf(buf, sizeof buf, "%s%.10g", i ? "\\" : "", v[i]);
    s += buf;
  }
  return s;
}

/* Re-encodes a written file's pixel data in another transfer syntax. */
bool recompress(const char *path, const gdcm::TransferSyntax &ts) {
  gdcm::ImageReader reader;
  reader.SetFileName(path);
  if (!reader.Read())
    return false;
  gdcm::ImageChangeTransferSyntax change;
  change.SetTransferSyntax(ts);
  change.SetInput(reader.GetImage());
  if (!change.Change())
    return false;
  gdcm::ImageWriter writer;
  writer.SetFileName(path);
  writer.SetFile(reader.GetFile());
  writer.SetImage(change.GetOutput());
  return writer.Write();
}

int write(const dicom_slice_desc *d) {
  gdcm::Writer writer;
  gdcm::File &file = writer.GetFile();
  gdcm::DataSet &ds = file.GetDataSet();
  size_t bytes = (size_t)d->rows * d->cols * (d->frames ? d->frames : 1) *
                 (size_t)(d->bits_allocated / 8);
  char uid[64];
  static unsigned serial;
  std::snprintf(uid, sizeof uid, "1.2.826.0.1.3680043.10.1234.%u",
                ++serial);
  put(ds, 0x0008, 0x0016, gdcm::VR::UI, "1.2.840.10008.5.1.4.1.1.2", 0);
  put(ds, 0x0008, 0x0018, gdcm::VR::UI, uid, 0);
  put(ds, 0x0008, 0x0060, gdcm::VR::CS, "CT");
  if (d->series_uid != nullptr)
    put(ds, 0x0020, 0x000e, gdcm::VR::UI, d->series_uid, 0);
  if (d->instance_number > 0)
    put(ds, 0x0020, 0x0013, gdcm::VR::IS,
        std::to_string(d->instance_number));
  if (d->has_position)
    put(ds, 0x0020, 0x0032, gdcm::VR::DS, numbers(d->position, 3));
  if (d->has_orientation)
    put(ds, 0x0020, 0x0037, gdcm::VR::DS, numbers(d->orientation, 6));
  if (d->pixel_spacing[0] > 0)
    put(ds, 0x0028, 0x0030, gdcm::VR::DS, numbers(d->pixel_spacing, 2));
  if (d->slice_thickness > 0)
    put(ds, 0x0018, 0x0050, gdcm::VR::DS,
        numbers(&d->slice_thickness, 1));
  if (d->spacing_between > 0)
    put(ds, 0x0018, 0x0088, gdcm::VR::DS,
        numbers(&d->spacing_between, 1));
  if (d->has_rescale) {
    put(ds, 0x0028, 0x1053, gdcm::VR::DS, numbers(&d->slope, 1));
    put(ds, 0x0028, 0x1052, gdcm::VR::DS, numbers(&d->intercept, 1));
  }
  if (d->frames > 1)
    put(ds, 0x0028, 0x0008, gdcm::VR::IS, std::to_string(d->frames));
  put_us(ds, 0x0028, 0x0002, 1);
  put(ds, 0x0028, 0x0004, gdcm::VR::CS, "MONOCHROME2");
  put_us(ds, 0x0028, 0x0010, d->rows);
  put_us(ds, 0x0028, 0x0011, d->cols);
  put_us(ds, 0x0028, 0x0100, (uint16_t)d->bits_allocated);
  put_us(ds, 0x0028, 0x0101, (uint16_t)d->bits_stored);
  put_us(ds, 0x0028, 0x0102, (uint16_t)(d->bits_stored - 1));
  put_us(ds, 0x0028, 0x0103, (uint16_t)d->pixel_rep);
  gdcm::DataElement pixels(gdcm::Tag(0x7fe0, 0x0010));
  pixels.SetVR(d->bits_allocated == 8 ? gdcm::VR::OB : gdcm::VR::OW);
  pixels.SetByteValue(static_cast<const char *>(d->pixels),
                      (uint32_t)bytes);
  ds.Insert(pixels);
  file.GetHeader().SetDataSetTransferSyntax(
      d->encoding == DICOM_IMPLICIT
          ? gdcm::TransferSyntax::ImplicitVRLittleEndian
          : gdcm::TransferSyntax::ExplicitVRLittleEndian);
  writer.SetFileName(d->path);
  if (!writer.Write())
    return -1;
  if (d->encoding == DICOM_RLE &&
      !recompress(d->path, gdcm::TransferSyntax::RLELossless))
    return -1;
  if (d->encoding == DICOM_JPEG_LS &&
      !recompress(d->path, gdcm::TransferSyntax::JPEGLSLossless))
    return -1;
  return 0;
}

} // namespace

extern "C" int dicom_write(const dicom_slice_desc *d) {
  try {
    return write(d);
  } catch (...) {
    return -1;
  }
}
