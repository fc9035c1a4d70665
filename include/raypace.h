/* Product tier (README, "Headers"): the interface an app is supported on.
 *
 * raypace: volume raycasting held at a fixed frame rate.
 *
 * Conventions used throughout this header:
 * - Every object is an opaque handle made by rp_X_create (or a loader) and
 *   released by rp_X_destroy; destroy accepts NULL.
 * - Descriptor structs are zero-initialised by the caller; a zero field
 *   means "use the default" named in its comment.
 * - Functions return 0 on success or a negative RP_E* code. When a call
 *   that has a context fails, rp_last_error(ctx) says what was wrong
 *   (file, field, value). A failed call leaves its outputs untouched and
 *   never frees or modifies the caller's data.
 * - Thread safety: a context and every object made from it may be used by
 *   one thread at a time. Different contexts are independent.
 */
#ifndef RAYPACE_H
#define RAYPACE_H

#include <stddef.h>
#include <stdint.h>

#include "raypace_version.h"

#ifdef __cplusplus
extern "C" {
#endif

#if defined(_WIN32) && defined(RP_SHARED_BUILD)
#define RP_API __declspec(dllexport)
#elif defined(__GNUC__)
#define RP_API __attribute__((visibility("default")))
#else
#define RP_API
#endif

/* ---- Errors ------------------------------------------------------------ */

/* XX(name, value, message). Values are stable across releases. */
#define RP_ERRNO_MAP(XX)                                                      \
  XX(EINVAL, -1, "invalid argument")                                          \
  XX(ENOMEM, -2, "out of memory")                                             \
  XX(ENOENT, -3, "no such file")                                              \
  XX(EIO, -4, "input/output error")                                           \
  XX(EFORMAT, -5, "malformed input")                                          \
  XX(ETRUNC, -6, "data truncated")                                            \
  XX(ERANGE, -7, "value out of range")                                        \
  XX(EUNSUPPORTED, -8, "unsupported type, encoding or feature")               \
  XX(ENOTFINITE, -9, "value is NaN or infinite")                              \
  XX(EBUSY, -10, "resource busy")                                             \
  XX(ENODEV, -11, "no usable device")                                         \
  XX(EDEVICE, -12, "device failure")                                          \
  XX(EBUILD, -13, "kernel build failed")                                      \
  XX(ETIMEDOUT, -14, "deadline exceeded")                                     \
  XX(ESTATE, -15, "call not valid in this state")

typedef enum rp_errno {
#define RP__ERRNO_ENUM(name, val, msg) RP_##name = (val),
  RP_ERRNO_MAP(RP__ERRNO_ENUM)
#undef RP__ERRNO_ENUM
  RP_OK = 0
} rp_errno;

/** Returns a static message for an error code ("unknown error" otherwise).
 *  \threadsafety any thread. \since 0.1 */
RP_API const char *rp_strerror(int err);
/** Returns the code's name without prefix ("EINVAL"), or "UNKNOWN".
 *  \threadsafety any thread. \since 0.1 */
RP_API const char *rp_err_name(int err);
/** Returns RP_VERSION_HEX of the library actually linked. \since 0.1 */
RP_API unsigned rp_version(void);
/** Returns "MAJOR.MINOR.PATCH". \since 0.1 */
RP_API const char *rp_version_string(void);

/* ---- Context ----------------------------------------------------------- */

typedef struct rp_context rp_context;

/** Memory hooks. Both NULL: the C library's malloc and free. */
typedef struct rp_allocator {
  void *(*alloc)(size_t size, void *user);
  void (*free)(void *ptr, void *user);
  void *user;
} rp_allocator;

typedef enum rp_log_level {
  RP_LOG_ERROR = 1,
  RP_LOG_WARN = 2,
  RP_LOG_INFO = 3,
  RP_LOG_DEBUG = 4
} rp_log_level;

/** Log sink. The library prints nothing unless one is set. */
typedef void (*rp_logger)(const char *tag, int level, int item_id,
                          const char *msg, int line, void *user);

typedef struct rp_context_desc {
  rp_allocator allocator; /* zero: malloc/free */
  rp_logger logger;       /* NULL: silent */
  void *logger_user;
  int threads;             /* worker threads for the CPU passes on volume
                              load and TF change (histograms, AO,
                              bricks); 0: all cores; at most 256 are
                              used. The per-frame probe runs on the
                              calling thread. */
  uint64_t max_volume_bytes; /* largest volume a loader accepts;
                                0: 16 GiB */
} rp_context_desc;

/** Creates a context. `desc` may be NULL (all defaults).
 *  \returns 0 or RP_EINVAL / RP_ENOMEM. \since 0.1 */
RP_API int rp_context_create(const rp_context_desc *desc, rp_context **out);
/** Destroys a context; NULL is a no-op. Objects made from it must be
 *  destroyed first. \since 0.1 */
RP_API void rp_context_destroy(rp_context *ctx);
/** The message of the last failed call on this context ("" if none).
 *  Valid until the next call on the context. \since 0.1 */
RP_API const char *rp_last_error(const rp_context *ctx);

/* ---- Limits ------------------------------------------------------------- */

/* The range of every numeric parameter (docs/parameters.md has the table,
 * with the file fields and CLI options that map to each). Each bound is
 * checked where the value enters the library, and a value outside it is
 * refused with RP_EINVAL (a render desc or camera field) or RP_ERANGE (a
 * volume's, a file's or a runtime desc's) and a message naming the
 * field, the value and the range. The bounds are far beyond
 * any legitimate use; they exist so that every call ends in bounded time
 * and memory whatever it is given. Ranges are inclusive. */

/** Ray step (rp_render_desc.step, rp_space_desc's steps,
 *  rp_tf_desc.reference_step), in voxels of the finest spacing. Below
 *  1/1000 of a voxel an image no longer changes (trilinear data is
 *  linear between voxels) while a ray of a 512^3 volume takes close to
 *  10^6 samples; above 10^4 every ray of any volume under 10^4 voxels
 *  across takes one sample at its entry. \since 0.12 */
#define RP_STEP_MIN 1e-3f
#define RP_STEP_MAX 1e4f
/** Voxel spacing (rp_volume_desc.spacing and every file's spacing), in
 *  the file's own length unit (mm for CT and MRI: 0.1 to 5 in practice).
 *  10^-9 holds nanometre voxels given in metres, 10^9 anything in any
 *  unit; within it the box's extent and its square stay normal floats
 *  (the 1e-30 and 1e30 did not). The ratio between axes is not
 *  limited here: a ray's work is (RP_MAX_SAMPLES_PER_RAY). \since 0.12 */
#define RP_SPACING_MIN 1e-9f
#define RP_SPACING_MAX 1e9f
/** Voxels along one axis of a volume (rp_volume_desc.dims, files).
 *  2^16: voxel positions stay exact in a float's 24 bits with room for
 *  sub-voxel steps, and a garbled header is refused by its size before
 *  its byte count (rp_context_desc.max_volume_bytes). \since 0.12 */
#define RP_VOLUME_MAX_DIM 65536u
/** Perspective field of view (rp_camera.fov_y_deg), degrees, vertical.
 *  Past 170 the frustum's edge is 11x its centre's width and a volume
 *  in view shrinks to a few pixels (at 179.9 to none: a black image);
 *  below 0.01 degrees the view is narrower than a float camera aims.
 *  \since 0.12 */
#define RP_FOV_MIN_DEG 0.01f
#define RP_FOV_MAX_DEG 170.0f
/** Orthographic view height (rp_camera.ortho_height) as a multiple of
 *  the volume's bounding diameter: past these a view holds a millionth
 *  of a voxel or shows the volume as under one pixel. \since 0.12 */
#define RP_ORTHO_HEIGHT_MIN 1e-6
#define RP_ORTHO_HEIGHT_MAX 1e4
/** How far the eye (rp_camera.eye; rp_camera_orbit's and
 *  rp_camera_view's distance, which are in radii, twice this unit) may
 *  be from the volume's centre, in bounding diameters. Farther, a
 *  perspective volume is under a pixel at any fov in range, and depths
 *  along a ray lose the precision a step needs. \since 0.12 */
#define RP_CAMERA_DISTANCE_MAX 1e4
/** Image scale (rp_render_desc.image_scale, rp_space_desc.min_scale):
 *  rays per output pixel along each axis. Below 1/100 a 512-pixel image
 *  is raycast at 5 pixels, and at 1e-9 at one: nothing a user would
 *  recognise. \since 0.12 */
#define RP_SCALE_MIN 0.01f
#define RP_SCALE_MAX 1.0f
/** Output image size (rp_render_desc.width/height, rp_runtime_desc's
 *  viewport), pixels. 16384 is the largest 2D image most GPUs hold; the
 *  pixel bound (8192 x 8192, 256 MiB of RGBA8) keeps a frame's buffers
 *  (scaled image, output, tile stats) near 1 GiB. Larger prints are
 *  rendered as tiles. \since 0.12 */
#define RP_IMAGE_MAX_DIM 16384u
#define RP_IMAGE_MAX_PIXELS (1u << 26)
/** Early-ray-termination threshold (rp_render_desc.ert_threshold):
 *  accumulated opacity at which a ray stops. Under 0.01 a ray stops at
 *  its first faint sample and the image is its transparent hull.
 *  \since 0.12 */
#define RP_ERT_THRESHOLD_MIN 0.01f
#define RP_ERT_THRESHOLD_MAX 1.0f
/** The work bound. A render is refused up front (RP_EINVAL, the message
 *  giving the count and the limit) when one ray may take more samples
 *  than RP_MAX_SAMPLES_PER_RAY: floor(D / s) + 1, D the volume's box
 *  diagonal in voxels of its finest spacing and s the step, or 8 (the
 *  ERT pre-pass's) when the step is coarser; or the frame more than
 *  RP_MAX_SAMPLES_PER_FRAME: the scaled image's rays times
 *  floor(D / step) + 1. So a volume whose spacings differ by 10^9 is
 *  refused here. A frame takes at most minutes on a GPU, never unbounded
 *  time. The reference's and
 *  the OpenCL kernel's ray loops also stop at RP_MAX_SAMPLES_PER_RAY.
 *  2^24 samples is a 2^16-voxel axis at step 1/256; 2^38 is an 8192^2
 *  image of a 1024^3 volume at step 1/2. \since 0.12 */
#define RP_MAX_SAMPLES_PER_RAY (1u << 24)
#define RP_MAX_SAMPLES_PER_FRAME (1ull << 38)

/* ---- Volumes ----------------------------------------------------------- */

typedef enum rp_voxel_type {
  RP_U8 = 1,
  RP_U16 = 2,
  RP_F32 = 3,
  RP_S8 = 4,  /* signed types and 32-bit integers: \since 0.11 */
  RP_S16 = 5, /* CT in Hounsfield units is usually stored so */
  RP_U32 = 6,
  RP_S32 = 7
} rp_voxel_type;

/** Where a volume lies in the patient (or world) frame, when its file
 *  says so. Patient space is DICOM's LPS: +x towards the patient's left,
 *  +y posterior, +z superior, in millimetres. Column j of `direction`
 *  (direction[3 * j + 0..2]) is the unit vector along which voxel index j
 *  grows; the columns are orthonormal (a mirrored grid has determinant
 *  -1). `origin` is the patient position of voxel (0, 0, 0)'s centre.
 *  \since 0.11 */
typedef struct rp_orientation {
  int known;           /* 0: the file said nothing; direction is then the
                          identity and origin zero */
  double direction[9];
  double origin[3];
} rp_orientation;

typedef struct rp_volume rp_volume;

typedef struct rp_volume_desc {
  uint32_t dims[3];      /* voxels along x, y, z; each in
                            [1, RP_VOLUME_MAX_DIM] */
  rp_voxel_type type;    /* required */
  float spacing[3];      /* voxel size, in [RP_SPACING_MIN,
                            RP_SPACING_MAX]; 0: 1.0 */
  const void *data;      /* x fastest, native endianness; copied */
  rp_orientation orientation; /* all zero: not known. \since 0.11 */
} rp_volume_desc;

/** Creates a volume from memory (the voxels are copied; the caller keeps
 *  its buffer). Float volumes must hold no NaN or infinity. RP_ERANGE
 *  for dims or a spacing outside the Limits; RP_ENOMEM, saying how much
 *  was asked, for more bytes than the machine has available (\since
 *  0.12), before anything is allocated. \since 0.1 */
RP_API int rp_volume_create(rp_context *ctx, const rp_volume_desc *desc,
                            rp_volume **out);

/** Loads a volume from a file: NRRD (.nrrd/.nhdr; raw or gzip encoding),
 *  NIfTI-1 and NIfTI-2 (.nii, .nii.gz, .hdr/.img pairs; \since 0.11;
 *  RP_EUNSUPPORTED when built without nifticlib), MetaImage (.mhd with a
 *  data file, .mha with the data attached; raw or zlib; \since 0.11), a
 *  raypace sidecar (.txt with "key: value" lines naming a raw file), or a
 *  .raw file whose name ends in _XxYxZ_TYPE (e.g. head_64x64x93_uint16).
 *  The orientation (rp_volume_info.orientation, in LPS) is set when the
 *  file gives it: NRRD "space" (RAS, LAS, LPS) with "space directions"
 *  and "space origin"; NIfTI's sform, else its qform (RAS+ turned into
 *  LPS); MetaImage's TransformMatrix and Offset, else its
 *  AnatomicalOrientation. NIfTI's scl_slope/scl_inter are applied:
 *  integer data with integer scaling that fits stays int16, anything else
 *  becomes float32 (so does float64 data). Messages name the file, the
 *  field and the value at fault.
 *
 *  DICOM (\since 0.11; builds with GDCM): `path` may be a folder holding
 *  one series of slice files, or one DICOM file (a slice, or a
 *  multi-frame image). In a folder, files that are not DICOM images
 *  (no "DICM" at byte 128, or no Rows/Columns: a DICOMDIR, a report, a
 *  README) and sub-folders are skipped; hidden files are not read.
 *  - One series only: a folder with several SeriesInstanceUIDs is
 *    refused, the message listing each UID and its file count.
 *  - Slices are ordered by their position along the slice normal
 *    (ImagePositionPatient . (row x column cosines)), not by file name
 *    or InstanceNumber. Refused, naming the files and the tag: mixed
 *    ImageOrientationPatient, Rows/Columns, BitsAllocated or
 *    PixelRepresentation; duplicate positions; a step off the median
 *    step by more than 5 % (a missing slice); slices off the normal
 *    line (gantry tilt); a file of the series without an image, or cut
 *    short (RP_ETRUNC).
 *  - Spacing: PixelSpacing (x = between columns, y = between rows) and
 *    the measured mean step; a lone slice takes SpacingBetweenSlices,
 *    else SliceThickness, else 1.
 *  - Values are in data units: stored x RescaleSlope + RescaleIntercept
 *    (HU for CT), after masking to BitsStored (sign-extended when
 *    PixelRepresentation is 1). The type is RP_S16 when every slope is
 *    1, every intercept an integer and every value fits int16; else
 *    RP_F32.
 *  - Orientation: direction columns are the row cosines, the column
 *    cosines and the slice normal (the order slices were stacked in);
 *    origin is the first slice's ImagePositionPatient.
 *  - Classes read: CT, MR, PET, NM, their enhanced and legacy-converted
 *    forms, grey secondary capture; others are refused (RP_EUNSUPPORTED),
 *    as are colour and palette images.
 *  - Each file's structure is checked before GDCM reads it (element
 *    lengths, nesting, tag order, VRs against the dictionary; RLE frames
 *    decoded dry): Debian's GDCM aborts on some malformed files.
 *  max_volume_bytes is checked before anything is allocated.
 *  \returns 0, RP_ENOENT, RP_EIO, RP_EFORMAT, RP_ETRUNC, RP_ERANGE,
 *  RP_EUNSUPPORTED (also: DICOM in a build without GDCM),
 *  RP_ENOTFINITE or RP_ENOMEM. \since 0.1 */
RP_API int rp_volume_load(rp_context *ctx, const char *path,
                          rp_volume **out);

typedef enum rp_generator {
  RP_GEN_MARSCHNER_LOBB = 1, /* analytic test signal, f_M = 6, alpha = .25 */
  RP_GEN_PHANTOM = 2,        /* CT-like: empty air, soft shell, dense core */
  RP_GEN_NOISE = 3,          /* white noise: worst case for every skip */
  /* A CT head in Hounsfield units (int16; RP_S16 or 0 only), in patient
   * orientation (voxel axes along LPS): air, skin, fat, skull, brain,
   * ventricles, eyes, a nose pointing anterior, the cervical spine and a
   * contrast-filled vessel. \since 0.11 */
  RP_GEN_CT_HEAD = 4
} rp_generator;

typedef struct rp_generate_desc {
  rp_generator kind;  /* required */
  uint32_t dims[3];   /* required, each >= 1 */
  rp_voxel_type type; /* RP_U8 or RP_U16; 0: RP_U8 (RP_GEN_CT_HEAD: int16) */
  uint64_t seed;      /* for RP_GEN_NOISE */
} rp_generate_desc;

/** Generates a synthetic volume; the same desc gives the same voxels.
 *  \since 0.1 */
RP_API int rp_volume_generate(rp_context *ctx, const rp_generate_desc *desc,
                              rp_volume **out);
RP_API void rp_volume_destroy(rp_volume *vol);

typedef struct rp_volume_info {
  uint32_t dims[3];
  rp_voxel_type type;
  float spacing[3];
  double min, max;       /* data range over all voxels */
  uint32_t blocks[3];    /* 16^3 blocks per axis (edge blocks partial) */
  rp_orientation orientation; /* \since 0.11 */
  /* How rp_volume_data's voxels are stored: a data value is the stored
   * value plus stored_offset. int8 and int16 are stored as uint8 and
   * uint16 offset by 128 and 32768; 32-bit integers as float32 (exact up
   * to 2^24 in magnitude). \since 0.11 */
  rp_voxel_type stored_type;
  double stored_offset;
} rp_volume_info;

RP_API void rp_volume_get_info(const rp_volume *vol, rp_volume_info *info);
/** The voxels as stored (rp_volume_info.stored_type: the type given for
 *  uint8, uint16 and float32), x fastest; owned by the volume. */
RP_API const void *rp_volume_data(const rp_volume *vol);
/** Name of a voxel type ("uint8", "int8", "uint16", "int16", "uint32",
 *  "int32", "float32"; "unknown" for any other value). */
RP_API const char *rp_voxel_type_name(rp_voxel_type type);

/* ---- Transfer functions ------------------------------------------------ */

typedef struct rp_tf rp_tf;

/** One control point. `x` is the position: in [0, 1] over the TF's range
 *  (rp_tf_desc.range; by default the volume's data range [min, max]), or
 *  a data value (HU for CT) within [-1e30, 1e30] when rp_tf_desc.units
 *  is RP_TF_DATA. Colour
 *  and alpha in [0, 1]. Alpha is the opacity of one reference step
 *  (rp_tf_desc.reference_step). */
typedef struct rp_tf_point {
  float x, r, g, b, a;
} rp_tf_point;

/** What a control point's x is. \since 0.11 */
typedef enum rp_tf_units {
  RP_TF_NORMALISED = 0, /* x in [0, 1] over the range (rp_tf_range) */
  RP_TF_DATA = 1        /* x in the volume's own values (HU for CT) */
} rp_tf_units;

/** Where a normalised TF's [0, 1] lies on a volume's values. Values
 *  below the range take the first point's colour, above it the last's.
 *  \since 0.11 */
typedef enum rp_tf_range {
  /* [min, max] of the volume: one outlier voxel moves every position */
  RP_TF_RANGE_MINMAX = 0,
  /* [range_lo, range_hi] percentiles of the volume's voxels, in [0, 100]:
   * robust to outliers (a metal filling, a hot pixel) */
  RP_TF_RANGE_PERCENTILES = 1,
  /* [range_lo, range_hi] in data units: a window (width hi - lo, level
   * their mean), the same on every volume */
  RP_TF_RANGE_DATA = 2
} rp_tf_range;

typedef struct rp_tf_desc {
  const rp_tf_point *points; /* strictly increasing x; at least one */
  int count;
  float reference_step;      /* Delta_0 in voxels, in [RP_STEP_MIN,
                                RP_STEP_MAX]; 0: 1.0 */
  int lut_size;              /* entries; 0: 1024 (min 2, max 65536) */
  /* \since 0.11. With RP_TF_DATA the range is the points' own span in
   * data units and `range` must be RP_TF_RANGE_MINMAX (0). */
  rp_tf_units units;
  rp_tf_range range;
  double range_lo, range_hi; /* for PERCENTILES and DATA: lo < hi; DATA
                                within [-1e30, 1e30] (\since 0.11) */
} rp_tf_desc;

/** Builds a transfer function. Piecewise linear between points, constant
 *  outside them. NaN, infinities, normalised values outside [0, 1] and
 *  unordered or repeated x are rejected with RP_ENOTFINITE / RP_ERANGE /
 *  RP_EINVAL and a message naming the point and field. \since 0.1 */
RP_API int rp_tf_create(rp_context *ctx, const rp_tf_desc *desc,
                        rp_tf **out);
/** Builds a named preset. CT presets are placed in Hounsfield units on
 *  their usual clinical windows (width/level): "ct-bone" (2000/500),
 *  "ct-soft" (400/40), "ct-lung" (1500/-600), "ct-angio" (700/250). "mri"
 *  spans the 1st to the 99.5th percentile of the volume's voxels. The
 *  others span the volume's [min, max]: "transparent" (all alpha 0),
 *  "opaque" (alpha 1 everywhere), "minmax-bone" and "minmax-soft" (the
 *  ct-bone and ct-soft of 0.10 and before, for CT data not in HU), "ramp",
 *  "nearly-transparent".
 *  \returns RP_EINVAL with the list of names for an unknown name. */
RP_API int rp_tf_create_preset(rp_context *ctx, const char *name,
                               rp_tf **out);
/** A copy of `src` whose [0, 1] spans the window [level - width / 2,
 *  level + width / 2] in data units (HU for CT): how a radiologist's
 *  window/level is applied to any TF. width must be > 0, both finite and
 *  the window's ends within [-1e30, 1e30] (RP_ERANGE / RP_ENOTFINITE
 *  naming the value otherwise). \since 0.11 */
RP_API int rp_tf_window(rp_context *ctx, const rp_tf *src, double width,
                        double level, rp_tf **out);
/** The data values [*lo, *hi] over which tf's LUT lies on `vol`: values
 *  below *lo take the LUT's first entry, above *hi its last. \since 0.11 */
RP_API void rp_tf_data_range(const rp_tf *tf, const rp_volume *vol,
                             double *lo, double *hi);
/** Loads a transfer function from a text file: one control point per line
 *  as "x r g b a", and optional lines "units: data" (x in data units) or
 *  "units: normalised", "range: minmax", "range: percentiles LO HI",
 *  "range: window WIDTH LEVEL", "reference_step: S"; '#' starts a
 *  comment. Errors name the file, the line and the field. \since 0.11 */
RP_API int rp_tf_load(rp_context *ctx, const char *path, rp_tf **out);
/** The preset names, NULL-terminated. */
RP_API const char *const *rp_tf_preset_names(void);
RP_API void rp_tf_destroy(rp_tf *tf);
RP_API float rp_tf_reference_step(const rp_tf *tf);
/** The lookup table: lut_size RGBA entries (floats, straight colour); entry
 *  i is the TF at x = i / (lut_size - 1). The TF used everywhere (render,
 *  H-alpha, occupancy) is this table read with linear interpolation. */
RP_API const float *rp_tf_lut(const rp_tf *tf, int *lut_size);

/** Opacity correction: the opacity of a step `step` for a sample whose
 *  opacity over the reference step `ref_step` is `alpha`:
 *  1 - (1 - alpha)^(step / ref_step), evaluated in double as
 *  -expm1((step / ref_step) * log1p(-alpha)) so that tiny and huge ratios
 *  keep full relative precision: the result is within one float ulp of the
 *  exact value. alpha <= 0 gives 0 and alpha >= 1 gives 1 at any step.
 *  step and ref_step must be positive and finite (NaN otherwise). */
RP_API float rp_opacity_correct(float alpha, float step, float ref_step);

/* ---- Histograms and occupancy ------------------------------------------ */

#define RP_BLOCK_SIZE 16
#define RP_DENSITY_BINS 64
#define RP_OPACITY_BINS 16

typedef struct rp_histograms rp_histograms;

/** Builds the per-block density histograms H of a volume (16^3 blocks, x
 *  fastest, 64 bins over [min, max]) on ctx's worker threads. */
RP_API int rp_histograms_build(rp_context *ctx, const rp_volume *vol,
                               rp_histograms **out);
RP_API void rp_histograms_destroy(rp_histograms *h);
/** Number of blocks and a pointer to block `b`'s 64 counts. */
RP_API uint32_t rp_histograms_block_count(const rp_histograms *h);
RP_API const uint32_t *rp_histograms_block(const rp_histograms *h,
                                           uint32_t b);
/** The bin a value falls in (the rule H uses; DESIGN section 2). */
RP_API int rp_histograms_bin_of(const rp_histograms *h, double value);

/** Derived data for one transfer function: opacity histograms H-alpha (16
 *  bytes per block) and the occupancy grid used for empty-space skipping.
 */
typedef struct rp_occupancy rp_occupancy;

/** Builds H-alpha and the occupancy grid of `tf` from `h`. The occupancy
 *  keeps a pointer to `h` (every TF update re-reads it): `h` must outlive
 *  it. \since 0.1 */
RP_API int rp_occupancy_build(rp_context *ctx, const rp_histograms *h,
                              const rp_tf *tf, rp_occupancy **out);
/** Recomputes in place for a new transfer function (no allocation). */
RP_API int rp_occupancy_update(rp_occupancy *occ, const rp_tf *tf);
RP_API void rp_occupancy_destroy(rp_occupancy *occ);
/** 16 bytes per block: fraction of the block's voxels in each opacity bin,
 *  x255, a non-empty bin never rounded to 0. Opacity bin 0 holds exactly
 *  the voxels of zero opacity; bin j >= 1 holds (j-1)/15 < a <= j/15. */
RP_API const uint8_t *rp_occupancy_alpha_hist(const rp_occupancy *occ);
/** One byte per block: 1 if a ray may see non-zero opacity inside it. */
RP_API const uint8_t *rp_occupancy_grid(const rp_occupancy *occ);
RP_API uint32_t rp_occupancy_empty_blocks(const rp_occupancy *occ);

/** An ambient-occlusion volume (raypace_ao.h). */
typedef struct rp_ao rp_ao;

/* ---- Cameras, render settings, images ---------------------------------- */

typedef enum rp_projection {
  RP_PERSPECTIVE = 0,
  RP_ORTHOGRAPHIC = 1
} rp_projection;

/** A camera in world space. World space is the volume's voxel grid scaled
 *  by its spacing, centred on the origin. */
typedef struct rp_camera {
  rp_projection projection;
  float eye[3];
  float center[3];
  float up[3];         /* zero: +y (or +z when looking along y) */
  float fov_y_deg;     /* perspective vertical field of view, in
                          [RP_FOV_MIN_DEG, RP_FOV_MAX_DEG]; 0: 40 */
  float ortho_height;  /* orthographic view height; 0: bounding diameter;
                          else within RP_ORTHO_HEIGHT_MIN/MAX diameters.
                          The eye lies within RP_CAMERA_DISTANCE_MAX
                          diameters of the volume's centre. */
} rp_camera;

/** Anatomical views: where the eye is, seen from the patient. \since 0.11 */
typedef enum rp_view {
  RP_VIEW_ANTERIOR = 1, /* from the front, superior up */
  RP_VIEW_POSTERIOR,    /* from behind, superior up */
  RP_VIEW_LEFT,         /* from the patient's left, superior up */
  RP_VIEW_RIGHT,        /* from the patient's right, superior up */
  RP_VIEW_SUPERIOR,     /* from above, anterior up */
  RP_VIEW_INFERIOR      /* from below, anterior up */
} rp_view;

/** Points `cam` at the volume centre from an anatomical direction, at a
 *  distance in bounding-sphere radii as rp_camera_orbit, using the
 *  volume's orientation (rp_volume_info.orientation; when not known the
 *  voxel axes are taken as LPS: +x left, +y posterior, +z superior). An
 *  anterior view shows the patient's left on the image's right, as a
 *  radiologist expects. Keeps projection and fov. \returns 0, or
 *  RP_EINVAL for an unknown view or a NULL argument. \since 0.11 */
RP_API int rp_camera_view(rp_camera *cam, const rp_volume *vol,
                          rp_view view, float distance);
/** The view's name ("anterior", ...), NULL for an unknown value; and the
 *  view of a name (0 for an unknown one). \since 0.11 */
RP_API const char *rp_view_name(rp_view view);
RP_API rp_view rp_view_from_name(const char *name);

/** Points `cam` at the volume centre from azimuth/elevation (degrees) and
 *  a distance in bounding-sphere radii (1.0 touches the sphere; below 1
 *  may put the eye inside the volume). Keeps projection and fov. Up is
 *  the way elevation rises (+y at elevation 0), so that elevation +-90
 *  continues the views beside it (0.12; before, the default up's switch
 *  to +z rolled the pole's view). */
RP_API void rp_camera_orbit(rp_camera *cam, const rp_volume *vol,
                            float azimuth_deg, float elevation_deg,
                            float distance);

enum {
  RP_EFFECT_SHADING = 1u << 0, /* gradient (central differences) shading */
  RP_EFFECT_ERT = 1u << 1,     /* early ray termination */
  RP_EFFECT_SKIP = 1u << 2,    /* empty-space skipping from occupancy */
  RP_EFFECT_AO = 1u << 3,      /* ambient occlusion fetch (M7) */
  /** Pre-integrated classification (Engel, Kraus and Ertl 2001;
   *  docs/sampling.md): each sample stands for the segment from the
   *  previous lattice sample, over which the value is taken to run
   *  linearly, and takes the TF's extinction integrated over the values
   *  it crosses, so a coarse step keeps thin, steep features. One more
   *  volume fetch per ray. \since 0.11 */
  RP_EFFECT_PREINT = 1u << 4
};

/** Ray-start jitter (rp_render_desc.jitter, DESIGN section 14). Each
 *  ray's samples lie at s + (j + i) * step, i = 0, 1, ..., with s where
 *  it enters the volume (or the eye, inside it) and j in [0, 1) a hash
 *  of its pixel and a seed (rp_jitter_offset): every backend takes the
 *  same samples, and the rings a common lattice leaves on surfaces
 *  become fine noise that averages out over seeds. \since 0.11 */
typedef enum rp_jitter {
  RP_JITTER_DEFAULT = 0, /* on */
  RP_JITTER_ON = 1,
  RP_JITTER_OFF = 2,     /* j = 0: the lattice of 0.10 and before */
  /* On, with the same seed in every frame of a runtime (a render desc
   * takes it as RP_JITTER_ON): a frame then costs the same whenever it
   * is rendered, which replaying a frame to measure it needs. */
  RP_JITTER_FIXED = 3
} rp_jitter;

typedef struct rp_render_desc {
  uint32_t width, height;  /* output pixels; required; each at most
                              RP_IMAGE_MAX_DIM, width x height at most
                              RP_IMAGE_MAX_PIXELS */
  float step;              /* Delta in voxels (finest spacing), in
                              [RP_STEP_MIN, RP_STEP_MAX]; 0: 1.0 */
  uint32_t effects;        /* RP_EFFECT_* bits; 0: none */
  float ert_threshold;     /* accumulated alpha to stop at, in
                              [RP_ERT_THRESHOLD_MIN, 1]; 0: 0.99 */
  float image_scale;       /* rays per output pixel along each axis, in
                              [RP_SCALE_MIN, 1]; 0: 1. Rays form a
                              scaled image of
                              rp_scaled_size() pixels over the same
                              frustum; the output is upscaled from it. */
  rp_jitter jitter;        /* 0: on. \since 0.11 */
  uint32_t jitter_seed;    /* the hash's seed; 0: RP_JITTER_SEED.
                              \since 0.11 */
} rp_render_desc;

/** The jitter seed a zero rp_render_desc.jitter_seed stands for.
 *  \since 0.11 */
#define RP_JITTER_SEED 0x2545f491u

/** The jitter of the ray through pixel (x, y) of the (scaled) image under
 *  `seed` (used as given, 0 included), as a fraction of a step in [0, 1):
 *  (h >> 8) * 2^-24 of the 32-bit hash h = m(seed ^ m(x ^ m(y +
 *  0x632be5ab))), with m the integer mix of the ERT stream
 *  (backends/README.md). Exact in float; every backend computes the same
 *  bits. \threadsafety any thread. \since 0.11 */
RP_API float rp_jitter_offset(uint32_t x, uint32_t y, uint32_t seed);

/** The seed frame `frame` of a sequence renders with when its jitter seed
 *  is `seed` (0: RP_JITTER_SEED): a hash of both, never 0, so that
 *  consecutive frames have unrelated jitter. \threadsafety any thread.
 *  \since 0.11 */
RP_API uint32_t rp_jitter_frame_seed(uint32_t seed, uint64_t frame);

/** Size of the image actually raycast at desc->image_scale:
 *  max(1, floor(width * scale + 0.5)) and the same for height. */
RP_API void rp_scaled_size(const rp_render_desc *desc, uint32_t *width,
                           uint32_t *height);

/** A rectangle of the (scaled) image, [x0, x1) x [y0, y1). */
typedef struct rp_region {
  uint32_t x0, y0, x1, y1;
} rp_region;

#define RP_TILE_SIZE 8

/** Per 8x8-pixel tile: the truth training and accuracy reports need. */
typedef struct rp_tile_stats {
  uint32_t samples;    /* samples taken (TF lookups) by the tile's rays */
  uint32_t rays_hit;   /* rays that took at least one sample */
  float mean_depth;    /* mean over those rays of the depth of their last
                          sample (termination or exit), in voxels of the
                          finest spacing from the eye; 0 if none */
} rp_tile_stats;

/** Number of tiles along x and y for an image. */
RP_API void rp_tile_grid(uint32_t width, uint32_t height, uint32_t *tiles_x,
                         uint32_t *tiles_y);

/** The scalar reference raycaster: the oracle backends are held to.
 *  Writes the scaled image's RGBA8 pixels (rp_scaled_size(); the full
 *  width x height at scale 1; premultiplied alpha, rows top to bottom) to
 *  `rgba` and, if `tiles` is not NULL, its tiles_x*tiles_y stats.
 *  `occ` is required when RP_EFFECT_SKIP is set and must have been built
 *  for `tf` on this volume; `ao` (raypace_ao.h) likewise with
 *  RP_EFFECT_AO. Single-threaded on purpose: obviously correct
 *  first. \since 0.1 */
RP_API int rp_render_reference(rp_context *ctx, const rp_volume *vol,
                               const rp_tf *tf, const rp_occupancy *occ,
                               const rp_ao *ao, const rp_camera *cam,
                               const rp_render_desc *desc, uint8_t *rgba,
                               rp_tile_stats *tiles);

/* ---- Devices ------------------------------------------------------------ */

/** A device's features and limits, filled in by its backend. */
typedef struct rp_caps {
  char backend[32];          /* "opencl", "vulkan", "reference" */
  char device[128];          /* the driver's device name */
  uint32_t effects;          /* RP_EFFECT_* bits it can render */
  uint32_t voxel_types;      /* bit (1 << rp_voxel_type) per type */
  uint64_t global_mem_bytes;
  uint64_t max_alloc_bytes;  /* largest single buffer */
  uint32_t compute_units;
  int sub_device;            /* 1 if a partition of a larger device */
} rp_caps;

typedef struct rp_device rp_device;

typedef struct rp_device_desc {
  /* "opencl", "vulkan", "reference", "test" or "mpi" (another MPI
   * rank's device, raypace_mpi.h). NULL: the RP_BACKEND environment
   * variable if set, else the first compiled-in backend with a device
   * ("reference", "test" and "mpi" only when named: the slow scalar
   * oracle, the deterministic test device of raypace_testing.h, and a
   * device elsewhere). */
  const char *backend;
  uint32_t index;            /* device within the backend */
  /* 0: the whole device; n: a sub-device of n compute units (OpenCL:
   * clCreateSubDevices CL_DEVICE_PARTITION_EQUALLY, the first partition).
   * Backends that cannot partition refuse it with RP_EUNSUPPORTED; more
   * than the device has is RP_ERANGE. */
  uint32_t compute_units;
  /* Out-of-core volumes (DESIGN section 9, docs/out_of_core.md): the
   * device memory a volume may take, in bytes. A volume that fits is
   * uploaded whole. A larger one stays in host memory as bricks of
   * brick_size^3 voxels (plus a one-voxel border), and the device keeps a
   * pool of as many bricks as the budget holds, loading on each render
   * only the visible bricks its region's frustum touches and replacing
   * the least recently used; a region whose bricks do not fit is cut into
   * parts, and a tile into depth slabs. The image is the in-core image.
   * 0: the device's largest buffer (rp_caps.max_alloc_bytes). Not for the
   * reference and test devices, which always hold the whole volume. */
  uint64_t budget_bytes;
  /* A brick's edge in voxels: a power of two in [8, 256]. 0: 16. */
  uint32_t brick_size;
  /* Extension structs from raypace_testing.h (the testing tier: fault
   * injection, the test backend's parameters), each beginning with
   * rp_ext_header {type, next}; read only during rp_device_create.
   * NULL: none. */
  const void *next;
} rp_device_desc;

/** Where a device of several (a device group, raypace_group.h; the
 *  runtime's devices, rp_device_frame) stands after a frame. A stall is
 *  not a failure: a device given up on at its deadline comes back on
 *  probation once its late work ends; one that fails is re-created after
 *  a back-off, and stays out only after failing again and again.
 *  \since 0.12 */
typedef enum rp_device_state {
  /* Rendering its full share, in proportion to its rate. */
  RP_DEVICE_ACTIVE = 0,
  /* Back after running late or being re-created: its share is at most
   * RP_GROUP_PROBATION_SHARE until it has been on time for
   * RP_GROUP_PROBATION_FRAMES frames in a row. */
  RP_DEVICE_PROBATION = 1,
  /* Given up on at its deadline and still busy with that work: no share
   * until it ends (then probation, or a failure if the work failed). */
  RP_DEVICE_LATE = 2,
  /* Failed (RP_EDEVICE): re-created, its volume, TF and AO uploaded
   * again, after a back-off of RP_GROUP_RETRY_FRAMES << (failures - 1)
   * frames. */
  RP_DEVICE_RETRY = 3,
  /* Failed RP_GROUP_MAX_FAILURES times in a row (a failed re-creation
   * counts): out for good. */
  RP_DEVICE_OUT = 4
} rp_device_state;

/* The rules the states above follow. \since 0.12 */
#define RP_GROUP_PROBATION_SHARE 0.1 /* at most this share on probation */
#define RP_GROUP_PROBATION_FRAMES 3  /* on time this many frames: back */
#define RP_GROUP_RETRY_FRAMES 2      /* the first back-off, in frames */
#define RP_GROUP_MAX_FAILURES 3      /* failures in a row: out for good */

/** How a device holds its volume (rp_device_get_brick_stats). Counters
 *  run from the last rp_device_set_volume; the last_ fields are of the
 *  last render. */
typedef struct rp_brick_stats {
  int out_of_core;          /* 0: the whole volume is on the device */
  uint32_t brick_size;
  uint32_t bricks;          /* in the volume */
  uint32_t visible;         /* of those, not empty under the current TF */
  uint32_t slots;           /* bricks the pool holds (slot 0 reserved) */
  uint32_t resident;
  uint64_t hits, misses, evictions;
  uint64_t uploaded_bytes, upload_ns;
  uint32_t last_pieces;     /* parts the last render's region was cut into
                               so that each part's bricks fit the pool */
  uint32_t last_slabs;      /* of those, depth slabs: passes over a tile
                               whose bricks do not fit at once */
  uint64_t last_upload_bytes, last_upload_ns;
} rp_brick_stats;

/** The compiled-in backends, NULL-terminated. */
RP_API const char *const *rp_backend_names(void);
/** Devices a backend can open here (0 when its driver is missing).
 *  \returns 0, or RP_EINVAL for an unknown backend name. */
RP_API int rp_device_count(rp_context *ctx, const char *backend,
                           uint32_t *count);
/** Opens a device. RP_ENODEV when no backend has one (the message lists
 *  what was tried); RP_EUNSUPPORTED or RP_ERANGE for a compute_units the
 *  device cannot be partitioned into; RP_EINVAL (or RP_ERANGE,
 *  RP_ENOTFINITE for a bad value) for an extension chain (desc->next)
 *  raypace_testing.h does not describe. \since 0.1 */
RP_API int rp_device_create(rp_context *ctx, const rp_device_desc *desc,
                            rp_device **out);
RP_API void rp_device_destroy(rp_device *dev);
RP_API void rp_device_get_caps(const rp_device *dev, rp_caps *caps);
/** Uploads a volume (native voxel type). The device keeps its own copy;
 *  the volume may be destroyed afterwards. */
RP_API int rp_device_set_volume(rp_device *dev, const rp_volume *vol);
/** Uploads a transfer function with the occupancy built for it (for the
 *  current volume): LUT, H-alpha and the occupancy grid. */
RP_API int rp_device_set_tf(rp_device *dev, const rp_tf *tf,
                            const rp_occupancy *occ);
/** Depth pass: per ray of the scaled image, D_front and D_back (2 floats,
 *  voxel units; +inf/-inf where no occupied block is met). `front_back`
 *  may be NULL: the result also stays on the device for rendering. */
RP_API int rp_device_depth_pass(rp_device *dev, const rp_camera *cam,
                                const rp_render_desc *desc,
                                float *front_back);
/** ERT pre-pass: per pre-pass ray (one per 4x4 scaled pixels, grid
 *  ceil(w/4) x ceil(h/4)), the estimated termination depth or +inf.
 *  Deterministic for (seed, frame). */
RP_API int rp_device_ert_prepass(rp_device *dev, const rp_camera *cam,
                                 const rp_render_desc *desc, uint32_t seed,
                                 uint32_t frame, float *d_ert);
/** Raycasts `region` of the scaled image (NULL: all of it) into `rgba`
 *  (scaled width x height RGBA8, only the region's pixels written) and
 *  the region's tiles into `tiles` (may be NULL). Runs the depth pass
 *  first unless the last one was for the same camera and settings.
 *  Region corners must lie on the 8x8 tile grid or the image edge. */
RP_API int rp_device_render(rp_device *dev, const rp_camera *cam,
                            const rp_render_desc *desc,
                            const rp_region *region, uint8_t *rgba,
                            rp_tile_stats *tiles);
/** Forgets the depth pass the device keeps between renders, so that the
 *  next rp_device_render runs its own. For a benchmark that renders for
 *  several clients in turn and times each render whole. NULL is a no-op.
 *  \since 0.2 */
RP_API void rp_device_forget_depth(rp_device *dev);
/** Device time of the last operation in nanoseconds (0 if unknown). */
RP_API uint64_t rp_device_last_time_ns(const rp_device *dev);
/** Builds ahead the kernel variants a render with `effects` may use on
 *  the volume uploaded now (any step and image size; with RP_EFFECT_AO
 *  also rp_device_compute_ao's), so that the first use does not wait
 *  for a build (on PoCL one takes about a second cold, tens of
 *  milliseconds from its disk cache). 0 when they are built, or when
 *  the backend builds on first use only (the reference device and
 *  MPI). RP_ESTATE before a volume was uploaded;
 *  RP_EBUILD, RP_ENOMEM or RP_EDEVICE when a build fails.
 *  \threadsafety the exception to the one-thread rule: another thread
 *  may call it while `dev` renders, uploads or computes AO, provided
 *  `ctx` (where errors go) is that thread's own and `dev` is not
 *  destroyed meanwhile. \since 0.2 */
RP_API int rp_device_prepare(rp_device *dev, rp_context *ctx,
                             uint32_t effects);
/** What rendering a region would upload to an out-of-core device first:
 *  the visible bricks its frustum touches (`bricks`), the bricks the
 *  render would load (`loads`: it follows the render's own plan on a copy
 *  of the pool's state, so when the bricks do not fit the pool at once
 *  and the region is cut into parts and depth slabs, a brick two parts
 *  load counts twice), their bytes, and the time that takes at the device's measured
 *  upload rate (a nominal 2 GB/s until it has uploaded a megabyte). All
 *  zero in core. */
typedef struct rp_upload_estimate {
  uint32_t bricks, loads;
  uint64_t bytes;
  double ms;
} rp_upload_estimate;
/** The estimate for `region` (NULL: the whole scaled image) of a render
 *  with `cam` and `desc`; changes nothing on the device. */
RP_API int rp_device_upload_estimate(rp_device *dev, const rp_camera *cam,
                                     const rp_render_desc *desc,
                                     const rp_region *region,
                                     rp_upload_estimate *out);
/** How the device holds its volume: in core, or as bricks (counters of
 *  hits, misses and evictions of its pool). RP_EINVAL for NULL. */
RP_API int rp_device_get_brick_stats(const rp_device *dev,
                                     rp_brick_stats *out);

/** Resamples an RGBA8 premultiplied image bilinearly to another size
 *  (pixel centres aligned, edges clamped): how an image rendered at a
 *  scale < 1 becomes the output. Equal sizes copy. \since 0.1 */
RP_API void rp_image_upscale(const uint8_t *src, uint32_t src_w,
                             uint32_t src_h, uint8_t *dst, uint32_t dst_w,
                             uint32_t dst_h);

/** How far an image is from a reference (seed 000 Table 4). */
typedef struct rp_image_metrics {
  double mse;  /* mean squared error, 0..255 units, over R, G and B */
  double psnr; /* 10 log10(255^2 / mse) dB; +inf when mse is 0 */
  double ssim; /* mean structural similarity of the luma, in [-1, 1] */
} rp_image_metrics;

/** Compares two RGBA8 premultiplied images of the same size as they are
 *  seen composited over black, i.e. their premultiplied R, G and B; alpha
 *  is not compared.
 *  - MSE: the mean of (a - b)^2 over every pixel's R, G and B.
 *  - PSNR: 10 log10(255^2 / MSE); +INFINITY for identical colours.
 *  - SSIM (Wang et al. 2004) on the luma Y = 0.299 R + 0.587 G + 0.114 B
 *    (unrounded): per window, (2 mu_a mu_b + C1)(2 cov_ab + C2) /
 *    ((mu_a^2 + mu_b^2 + C1)(var_a + var_b + C2)), C1 = (0.01 * 255)^2,
 *    C2 = (0.03 * 255)^2, moments weighted by an 11x11 Gaussian window
 *    (sigma 1.5, weights summing to 1; population variances); the mean
 *    over every window lying wholly inside the image ("valid" region, no
 *    padding). Along an axis shorter than 11 pixels the window spans the
 *    whole axis: the same Gaussian sampled at those pixels' offsets from
 *    their middle and renormalised (a 1x1 image is one window of one
 *    pixel, where SSIM reduces to its luminance term).
 *  Scratch memory (ctx's allocator): two rows of luma and 11 rows of
 *  window sums, 5 doubles per column.
 *  \returns 0, RP_EINVAL (a NULL pointer, a zero size), RP_ERANGE (a size
 *  whose byte count overflows), RP_ENOMEM. \since 0.1 */
RP_API int rp_image_compare(rp_context *ctx, const uint8_t *a,
                            const uint8_t *b, uint32_t width,
                            uint32_t height, rp_image_metrics *out);

/** Writes RGBA8 premultiplied pixels as an 8-bit RGB PNG composited over
 *  `background` (RGB in [0, 1]; NULL: black). */
RP_API int rp_write_png(rp_context *ctx, const char *path,
                        const uint8_t *rgba, uint32_t width,
                        uint32_t height, const float *background);

/* ---- Pacing settings -------------------------------------------------- */

/* What an app chooses for the runtime (rp_runtime_desc,
 * raypace_runtime.h): where quality is traded for time, which rule picks
 * each frame's density, the cost model's knobs and how device shares
 * move. The machinery behind them (the density mapping, the tuner, the
 * controller objects, the cost model, the balancer) is the lab tier:
 * raypace_pace.h and raypace_balance.h. */

/** Where quality is traded for time. Density rho = scale^2 * base_step /
 *  step: 1 is the base step at full resolution; frame time is close to
 *  linear in it (rays x samples per ray). Above 1 (min_step under
 *  base_step), only the step refines: the image is never rendered above
 *  the output's resolution, and pure image space stops at 1. */
typedef enum rp_space {
  RP_SPACE_RAY = 0,    /* step changes, full resolution */
  RP_SPACE_IMAGE = 1,  /* image scale changes (upscaled to the output) */
  RP_SPACE_HYBRID = 2  /* both */
} rp_space;

/** Bounds of the tuning spaces; zero fields take the defaults. The steps
 *  lie in [RP_STEP_MIN, RP_STEP_MAX] and min_scale at or above
 *  RP_SCALE_MIN (rp_runtime_create refuses others with RP_ERANGE). */
typedef struct rp_space_desc {
  rp_space space;
  float base_step;   /* step at rho = 1, voxels; 0: 1.0 */
  float max_step;    /* coarsest step; 0: 16 * base_step */
  float min_scale;   /* smallest image scale; 0: 0.125 */
  float min_step;    /* finest step; 0 (or above base_step): base_step,
                        no density above 1. The cost model's step
                        feature stops at 1/8 voxel (S' does not).
                        \since 0.2 */
} rp_space_desc;

/** "ray", "image", "hybrid"; and the reverse (RP_EINVAL if unknown).
 *  \since 0.1 */
RP_API const char *rp_space_name(rp_space space);
RP_API int rp_space_from_name(const char *name, rp_space *out);

/** The rules; runtime/control.c states each one exactly and cites its
 *  source. Every rule decides at rp_controller_begin_frame from the
 *  frames before and this frame's target, and never emits NaN or a rho
 *  outside [rho_min, rho_max]. */
typedef enum rp_controller_kind {
  RP_CONTROL_NONE = 0,       /* rho_start every frame */
  RP_CONTROL_LAST_FRAME = 1, /* rho_last * target / t_last, damped */
  RP_CONTROL_TWO_PASS = 2,   /* pass at rho_last / 4; if under half the
                                target, extrapolate to the rest and
                                render again */
  RP_CONTROL_PREDICTED = 3,  /* ours: rp_tune on the caller's model,
                                aimed at target e^-m, m the margin
                                that keeps a share miss_rate of frames
                                late (learned online); no rise after a
                                frame that took over 1.5x its
                                prediction; a damped rise lifted at
                                half the target (lift 0.5) after one
                                within 1.2x of it, on a scene still
                                priced within 1.2x */
  RP_CONTROL_VTK = 4,        /* isd' = isd sqrt(t_last f / target),
                                isd in [1, 10], rho = 1 / isd^2 */
  RP_CONTROL_UE5 = 5,        /* UE5 dynamic resolution, rho = s^2 */
  RP_CONTROL_VALVE = 6,      /* Valve's adaptive quality: a ladder of
                                15 % fill-rate steps */
  RP_CONTROL_COUNT = 7
} rp_controller_kind;

/** "none", "last-frame", "two-pass", "predicted", "vtk", "ue5", "valve"
 *  ("unknown" out of range); from_name is its reverse (RP_EINVAL if
 *  unknown). \since 0.1 */
RP_API const char *rp_controller_name(rp_controller_kind kind);
RP_API int rp_controller_from_name(const char *name,
                                   rp_controller_kind *out);

/** The cost model's knobs (DESIGN section 5, raypace_pace.h); zero
 *  fields take the defaults. */
typedef struct rp_cost_model_desc {
  double gamma;      /* KRLS RBF width on features in [0, 1]; 0: 2 */
  double nu;         /* ALD tolerance; 0: 1e-3 */
  int max_dict;      /* dictionary bound; 0: 32 */
  double forget;     /* KRLS forgetting factor; 0: 0.995 */
  double clip;       /* KRLS residual clamp; 0: 4 */
  double sigma0_ns;  /* cost per fetch before any training; 0: 5 */
  /* KRLS prior on a new dictionary element: the timing noise's variance
   * over that of what the model learns (runtime/krls.h), so that one
   * noisy frame is not taken as the cost of every view beside it.
   * 0: 0.05; negative: none (each new element takes its frame's value).
   * \since 0.2 */
  double noise_ratio;
} rp_cost_model_desc;

/** How the devices' shares move from frame to frame (DESIGN section 7,
 *  rp_balance_damp in raypace_balance.h). */
typedef enum rp_damping {
  /* Ours (default): exponential smoothing toward the previous frame's
   * shares, w = (1 - lambda) w_prev + lambda w_new. Converges to w_new
   * when it holds still: the error shrinks by (1 - lambda) per frame. */
  RP_DAMP_SMOOTH = 0,
  /* The paper's: a mix with the even split, w = (1 - zeta) / n +
   * zeta w_new. Needs no history, but never reaches w_new: a device's
   * share stays within [(1 - zeta) / n, (1 - zeta) / n + zeta]. */
  RP_DAMP_EVEN = 1
} rp_damping;

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_H */
