/* DICOM files for the tests, written with GDCM (dicom_writer.cpp): one
 * image per call, each tag present only when the desc says so. */
#ifndef RP_TEST_DICOM_WRITER_H
#define RP_TEST_DICOM_WRITER_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

enum dicom_encoding {
  DICOM_EXPLICIT = 0, /* explicit VR little endian, uncompressed */
  DICOM_IMPLICIT,     /* implicit VR little endian */
  DICOM_RLE,          /* RLE lossless */
  DICOM_JPEG_LS       /* JPEG-LS lossless */
};

typedef struct dicom_slice_desc {
  const char *path;
  const char *series_uid;   /* NULL: no SeriesInstanceUID */
  int instance_number;      /* 0: none */
  uint16_t rows, cols;
  uint32_t frames;          /* 0 or 1: a single frame */
  int bits_allocated, bits_stored, pixel_rep;
  const void *pixels;       /* rows x cols x frames values, host order */
  int has_position, has_orientation, has_rescale;
  double position[3], orientation[6];
  double pixel_spacing[2];  /* rows, columns; 0: no PixelSpacing */
  double slice_thickness;   /* 0: none */
  double spacing_between;   /* SpacingBetweenSlices; 0: none */
  double slope, intercept;
  enum dicom_encoding encoding;
} dicom_slice_desc;

/* 0, or -1 when GDCM could not write the file. */
int dicom_write(const dicom_slice_desc *d);

#ifdef __cplusplus
}
#endif

#endif
