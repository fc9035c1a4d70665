/* DICOM images, read through GDCM. Two parts:
 * - volume_dicom.cpp, a thin C++ shim (the only file that sees GDCM): it
 *   reads one file's header into an rp__dicom_meta and decodes its pixel
 *   data into plain integers. GDCM throws C++ exceptions; the shim catches
 *   all of them, so nothing crosses into C.
 * - volume_dicom.c: everything else, in C: a folder's files, series,
 *   slice order, geometry checks, the rescale to data units (HU for CT)
 *   and the volume.
 * Built without GDCM, dicom_absent.c refuses DICOM input with a message.
 * This header is C and C++: the shim includes it. */
#ifndef RP_VOLUME_DICOM_H
#define RP_VOLUME_DICOM_H

#include <stddef.h>
#include <stdint.h>

#include "raypace.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Where a DICOM file's bytes are: a path, or memory (the fuzz target). */
typedef struct rp__dicom_src {
  const char *name; /* the path, or a name for messages */
  const uint8_t *mem; /* NULL: read the file at `name` */
  size_t len;
} rp__dicom_src;

/* What the loader needs of one file's header. Tags that are absent keep
 * the defaults rp__dicom_meta_read sets (has_* 0, slope 1, intercept 0). */
typedef struct rp__dicom_meta {
  char series_uid[68];       /* (0020,000E); "" when absent */
  uint32_t rows, cols;       /* (0028,0010), (0028,0011) */
  uint32_t frames;           /* (0028,0008); 1 when absent */
  int bits_allocated;        /* (0028,0100) */
  int bits_stored;           /* (0028,0101) */
  int high_bit;              /* (0028,0102) */
  int pixel_rep;             /* (0028,0103): 0 unsigned, 1 signed */
  int samples;               /* (0028,0002); 1 when absent */
  char photometric[20];      /* (0028,0004), trimmed; "" when absent */
  int has_position, has_orientation, has_pixel_spacing;
  double position[3];        /* (0020,0032) ImagePositionPatient */
  double orientation[6];     /* (0020,0037) row, then column cosines */
  double pixel_spacing[2];   /* (0028,0030): between rows, between cols */
  double slope, intercept;   /* (0028,1053), (0028,1052) */
  double slice_step;         /* a multi-frame's or a lone slice's step:
                                (0018,0088), else (0018,0050); 0: none */
} rp__dicom_meta;

/* Reads the header of one file, after rp__dicom_walk_src. Returns 0 for
 * a DICOM image (it has Rows and Columns), 1 for a file without DICOM's
 * magic or without an image (nothing recorded, so a folder may skip it;
 * series_uid is filled for a DICOM file without an image),
 * or a negative error naming the file and the tag: a file with the magic
 * that cannot be read is an error, never skipped. */
int rp__dicom_meta_read(rp_context *ctx, const rp__dicom_src *src,
                        rp__dicom_meta *m);

/* After rp__dicom_meta_read on the same file (which checks what GDCM's
 * image reader would assert on): walks, reads the whole file and decodes its pixel data (any transfer syntax
 * GDCM reads: implicit/explicit VR, JPEG, JPEG-LS, JPEG 2000, RLE) into
 * `dst`, `count` stored values, x fastest, then rows, then frames: each
 * value sign-extended or masked to BitsStored. The file must still match
 * `m` (sizes, frames, pixel format). */
int rp__dicom_pixels_read(rp_context *ctx, const rp__dicom_src *src,
                          const rp__dicom_meta *m, int32_t *dst,
                          size_t count);

/* ---- dicom_walk.c ------------------------------------------------------ */

/* Checks a file's structure before GDCM reads it (dicom_walk.c says
 * why): 0 when every element fits and nests, 1 when it lacks DICOM's
 * magic ("DICM" at byte 128; nothing recorded), or a negative error
 * naming the file, the element and the byte. */
int rp__dicom_walk(rp_context *ctx, const char *name, const uint8_t *p,
                   size_t len);
/* The same on a source: memory, or the file mapped for reading. */
int rp__dicom_walk_src(rp_context *ctx, const rp__dicom_src *src);

/* ---- volume_dicom.c (dicom_absent.c without GDCM) ----------------------- */

/* A folder of slice files (one series), as rp_volume_load documents. */
int rp__dicom_load_dir(rp_context *ctx, const char *dir, rp_volume **out);
/* One DICOM file: a single slice or a multi-frame image. */
int rp__dicom_load_file(rp_context *ctx, const rp__dicom_src *src,
                        rp_volume **out);

#ifdef __cplusplus
}
#endif

#endif /* RP_VOLUME_DICOM_H */
