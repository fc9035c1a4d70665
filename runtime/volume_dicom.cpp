/* The GDCM shim (volume_dicom.h): one DICOM file's header, and its pixel
 * data decoded. GDCM is used rather than a parser of our own because real
 * series come in many transfer syntaxes (implicit and explicit VR, either
 * byte order) and with compressed pixel data (JPEG lossless and lossy,
 * JPEG-LS, JPEG 2000, RLE), each a codec of its own.
 *
 * Every entry point catches every exception: GDCM throws on malformed
 * input and std::vector throws bad_alloc, and neither may unwind into C.
 * Values the loader relies on are read from the tags' text here, so that
 * a message can name the tag and the value the file holds. */
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <gdcmDataSet.h>
#include <gdcmDicts.h>
#include <gdcmGlobal.h>
#include <gdcmImage.h>
#include <gdcmImageHelper.h>
#include <gdcmImageReader.h>
#include <gdcmReader.h>
#include <gdcmSequenceOfItems.h>
#include <gdcmTag.h>
#include <gdcmTrace.h>
#include <gdcmTransferSyntax.h>

#include "volume_dicom.h"

extern "C" int rp__fail(rp_context *ctx, int err, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

namespace {

const gdcm::Tag kPixelData(0x7fe0, 0x0010);

/* The input as a stream: a file, or a copy of the memory. */
struct Input {
  std::ifstream file;
  std::istringstream mem;
  std::istream *stream = nullptr;

  explicit Input(const rp__dicom_src *src) {
    if (src->mem != nullptr) {
      mem.str(std::string(reinterpret_cast<const char *>(src->mem),
                          src->len));
      stream = &mem;
    } else {
      file.open(src->name, std::ios::binary);
      if (file.is_open())
        stream = &file;
    }
  }
};

/* A tag's value for a message: at most 40 characters, unprintable bytes
 * as '?'. */
std::string shown(const gdcm::ByteValue *bv) {
  std::string s;
  size_t len = bv->GetLength(), n = len < 40 ? len : 40;
  for (size_t i = 0; i < n; i++) {
    char c = bv->GetPointer()[i];
    s += c >= 32 && c < 127 ? c : '?';
  }
  if (len > 40)
    s += "...";
  return s;
}

const gdcm::ByteValue *value_of(const gdcm::DataSet &ds, uint16_t group,
                                uint16_t element) {
  gdcm::Tag tag(group, element);
  if (!ds.FindDataElement(tag))
    return nullptr;
  const gdcm::ByteValue *bv = ds.GetDataElement(tag).GetByteValue();
  return bv != nullptr && bv->GetLength() > 0 && bv->GetPointer() != nullptr
             ? bv
             : nullptr;
}

/* An unsigned short (US): 0 absent, 1 read, or an error. GDCM hands
 * binary values over in the host's byte order. */
int read_us(rp_context *ctx, const char *name, const gdcm::DataSet &ds,
            uint16_t group, uint16_t element, const char *what,
            uint32_t *out) {
  const gdcm::ByteValue *bv = value_of(ds, group, element);
  uint16_t v;
  if (bv == nullptr)
    return 0;
  if (bv->GetLength() != 2)
    return rp__fail(ctx, RP_EFORMAT, "%s: %s (%04X,%04X): %u bytes, an "
                    "unsigned short has 2", name, what, group, element,
                    (unsigned)bv->GetLength());
  std::memcpy(&v, bv->GetPointer(), 2);
  *out = v;
  return 1;
}

/* `n` decimal or integer strings separated by '\': 0 absent, 1 read, or
 * an error naming the tag and its value. */
int read_numbers(rp_context *ctx, const char *name, const gdcm::DataSet &ds,
                 uint16_t group, uint16_t element, const char *what,
                 double *out, int n) {
  const gdcm::ByteValue *bv = value_of(ds, group, element);
  if (bv == nullptr)
    return 0;
  std::string text(bv->GetPointer(), bv->GetLength());
  while (!text.empty() && text.back() == '\0')
    text.pop_back(); /* padding some writers use instead of a space */
  const char *p = text.c_str();
  int got = 0;
  /* Decimal and integer strings only (no "0x1", "inf" or "nan", which
   * strtod takes and GDCM's own parser reads otherwise). */
  if (text.find_first_not_of("0123456789+-.eE \\") != std::string::npos)
    got = n + 1;
  while (got <= n) {
    char *end = nullptr;
    double v;
    while (*p == ' ')
      p++;
    errno = 0;
    v = std::strtod(p, &end);
    if (end == p || errno != 0 || !std::isfinite(v) || got == n)
      break;
    out[got++] = v;
    p = end;
    while (*p == ' ')
      p++;
    if (*p == '\\') {
      p++;
      continue;
    }
    if (*p == '\0' && got == n && p == text.c_str() + text.size())
      return 1;
    break;
  }
  return rp__fail(ctx, RP_EFORMAT, "%s: %s (%04X,%04X): value '%s' is not "
                  "%d finite number%s separated by '\\'", name, what, group,
                  element, shown(bv).c_str(), n, n > 1 ? "s" : "");
}

/* A short text value (a UID or a code string) without its padding. */
void read_text(const gdcm::DataSet &ds, uint16_t group, uint16_t element,
               char *out, size_t cap) {
  const gdcm::ByteValue *bv = value_of(ds, group, element);
  size_t n = 0;
  if (bv != nullptr) {
    /* Values are padded with a NUL or a space to an even length. */
    for (n = 0; n < bv->GetLength() && n + 1 < cap; n++) {
      char c = bv->GetPointer()[n];
      if (c == '\0' || c == ' ')
        break;
      out[n] = c >= 32 && c < 127 ? c : '?';
    }
  }
  out[n] = '\0';
}

/* An enhanced multi-frame image (CT, MR, ...) keeps its geometry and
 * rescale in functional group sequences, where GDCM's helpers know to
 * look. A legacy multi-frame keeps them at the top level, read already
 * (the step from SpacingBetweenSlices, else SliceThickness). */
void multiframe_geometry(const gdcm::File &file, rp__dicom_meta *m) {
  const gdcm::DataSet &ds = file.GetDataSet();
  if (!ds.FindDataElement(gdcm::Tag(0x5200, 0x9229)) &&
      !ds.FindDataElement(gdcm::Tag(0x5200, 0x9230)))
    return;
  std::vector<double> origin = gdcm::ImageHelper::GetOriginValue(file);
  std::vector<double> cosines =
      gdcm::ImageHelper::GetDirectionCosinesValue(file);
  std::vector<double> spacing = gdcm::ImageHelper::GetSpacingValue(file);
  std::vector<double> rescale =
      gdcm::ImageHelper::GetRescaleInterceptSlopeValue(file);
  if (origin.size() == 3 && cosines.size() == 6) {
    for (int i = 0; i < 3; i++)
      m->position[i] = origin[i];
    for (int i = 0; i < 6; i++)
      m->orientation[i] = cosines[i];
    m->has_position = m->has_orientation = 1;
  }
  if (spacing.size() >= 3) {
    /* GDCM orders spacing x, y, z; PixelSpacing is rows, then columns. */
    m->pixel_spacing[0] = spacing[1];
    m->pixel_spacing[1] = spacing[0];
    m->has_pixel_spacing = 1;
    m->slice_step = spacing[2];
  }
  if (rescale.size() == 2) {
    m->intercept = rescale[0];
    m->slope = rescale[1];
  }
}

/* GDCM's typed attributes assert that an element's VR is the one its
 * dictionary gives, and its image reader reads many tags through them:
 * a file that gives a public tag another VR (or a binary value whose
 * length is not a whole number of values) is refused before that.
 * Nested data sets are checked too (enhanced images keep their geometry
 * in sequences). */
int vrs_ok(rp_context *ctx, const char *name, const gdcm::DataSet &ds,
           int depth) {
  const gdcm::Dicts &dicts = gdcm::Global::GetInstance().GetDicts();
  for (auto it = ds.Begin(); it != ds.End(); ++it) {
    const gdcm::DataElement &de = *it;
    const gdcm::Tag &tag = de.GetTag();
    gdcm::VR vr = de.GetVR();
    if (tag.IsPrivate() || tag.GetGroup() == 0xfffe)
      continue;
    gdcm::VR want = dicts.GetDictEntry(tag).GetVR();
    if (vr != gdcm::VR::INVALID && want != gdcm::VR::INVALID &&
        want != gdcm::VR::UN && !want.Compatible(vr))
      return rp__fail(ctx, RP_EFORMAT, "%s: (%04X,%04X) has VR %s, the "
                      "dictionary says %s", name, tag.GetGroup(),
                      tag.GetElement(), gdcm::VR::GetVRString(vr),
                      gdcm::VR::GetVRString(want));
    gdcm::VR as = vr != gdcm::VR::INVALID ? vr : want;
    const gdcm::ByteValue *bv = de.GetByteValue();
    static const gdcm::VR::VRType fixed[] = {
        gdcm::VR::AT, gdcm::VR::FL, gdcm::VR::FD, gdcm::VR::SL,
        gdcm::VR::SS, gdcm::VR::UL, gdcm::VR::US};
    for (gdcm::VR::VRType f : fixed)
      if (as == f && bv != nullptr &&
          bv->GetLength() % gdcm::VR(f).GetSize() != 0)
        return rp__fail(ctx, RP_EFORMAT, "%s: (%04X,%04X) %s holds %u "
                        "bytes, not whole values of %u", name,
                        tag.GetGroup(), tag.GetElement(),
                        gdcm::VR::GetVRString(f), (unsigned)bv->GetLength(),
                        gdcm::VR(f).GetSize());
    const gdcm::SequenceOfItems *sq =
        de.IsEmpty() ? nullptr
                     : dynamic_cast<const gdcm::SequenceOfItems *>(
                           &de.GetValue());
    if (sq != nullptr && depth < 16)
      for (gdcm::SequenceOfItems::SizeType i = 1;
           i <= sq->GetNumberOfItems(); i++) {
        int rc = vrs_ok(ctx, name, sq->GetItem(i).GetNestedDataSet(),
                        depth + 1);
        if (rc != 0)
          return rc;
      }
  }
  return 0;
}

/* The image storage classes read as volumes. GDCM's image reader takes
 * modality-specific paths by SOP class (RT dose scaling, palettes, ...),
 * some of which assert on malformed values; these are the classes of
 * grey volumes, and the ones tested. */
const char *const kVolumeClasses[] = {
    "1.2.840.10008.5.1.4.1.1.2",     /* CT */
    "1.2.840.10008.5.1.4.1.1.2.1",   /* Enhanced CT */
    "1.2.840.10008.5.1.4.1.1.2.2",   /* Legacy Converted Enhanced CT */
    "1.2.840.10008.5.1.4.1.1.4",     /* MR */
    "1.2.840.10008.5.1.4.1.1.4.1",   /* Enhanced MR */
    "1.2.840.10008.5.1.4.1.1.4.4",   /* Legacy Converted Enhanced MR */
    "1.2.840.10008.5.1.4.1.1.128",   /* PET */
    "1.2.840.10008.5.1.4.1.1.128.1", /* Legacy Converted Enhanced PET */
    "1.2.840.10008.5.1.4.1.1.130",   /* Enhanced PET */
    "1.2.840.10008.5.1.4.1.1.20",    /* NM */
    "1.2.840.10008.5.1.4.1.1.7",     /* Secondary Capture */
    "1.2.840.10008.5.1.4.1.1.7.2",   /* Multi-frame Grayscale Byte SC */
    "1.2.840.10008.5.1.4.1.1.7.3"};  /* Multi-frame Grayscale Word SC */

/* SOPClassUID (0008,0016) and the meta header's MediaStorageSOPClassUID
 * (0002,0002), which GDCM prefers, must both name a volume class. */
int sop_class_ok(rp_context *ctx, const char *name, const gdcm::File &file) {
  char sop[68], media[68];
  read_text(file.GetDataSet(), 0x0008, 0x0016, sop, sizeof sop);
  read_text(file.GetHeader(), 0x0002, 0x0002, media, sizeof media);
  const char *uids[] = {sop, media};
  for (const char *uid : uids) {
    bool known = false;
    for (const char *c : kVolumeClasses)
      known = known || std::strcmp(uid, c) == 0;
    if (!known && (uid == sop || uid[0] != '\0'))
      return rp__fail(ctx, RP_EUNSUPPORTED, "%s: %s '%s' is not a volume "
                      "class raypace reads (CT, MR, PET, NM, their enhanced "
                      "forms, grey secondary capture)", name,
                      uid == sop ? "SOPClassUID (0008,0016)"
                                 : "MediaStorageSOPClassUID (0002,0002)",
                      uid);
  }
  return 0;
}

/* The tags of a header that has been read. */
int meta_from(rp_context *ctx, const char *name, const gdcm::File &file,
              rp__dicom_meta *m) {
  const gdcm::DataSet &ds = file.GetDataSet();
  uint32_t v = 0;
  double frames = 1, step = 0;
  int rc;
  int has_rows, has_step = 0;
  read_text(ds, 0x0020, 0x000e, m->series_uid, sizeof m->series_uid);
  if ((has_rows = read_us(ctx, name, ds, 0x0028, 0x0010, "Rows",
                          &m->rows)) < 0 ||
      (rc = read_us(ctx, name, ds, 0x0028, 0x0011, "Columns",
                    &m->cols)) < 0)
    return has_rows < 0 ? has_rows : rc;
  if (has_rows == 0 || rc == 0)
    return 1; /* not an image */
  struct {
    uint16_t element;
    const char *what;
    int *out;
  } us[] = {{0x0100, "BitsAllocated", &m->bits_allocated},
            {0x0101, "BitsStored", &m->bits_stored},
            {0x0102, "HighBit", &m->high_bit},
            {0x0103, "PixelRepresentation", &m->pixel_rep},
            {0x0002, "SamplesPerPixel", &m->samples}};
  for (auto &u : us) {
    if ((rc = read_us(ctx, name, ds, 0x0028, u.element, u.what, &v)) < 0)
      return rc;
    if (rc == 1)
      *u.out = (int)v;
  }
  read_text(ds, 0x0028, 0x0004, m->photometric, sizeof m->photometric);
  struct {
    uint16_t group, element;
    const char *what;
    double *out;
    int n;
    int *has;
  } ds_tags[] = {
      {0x0028, 0x0008, "NumberOfFrames", &frames, 1, nullptr},
      {0x0020, 0x0032, "ImagePositionPatient", m->position, 3,
       &m->has_position},
      {0x0020, 0x0037, "ImageOrientationPatient", m->orientation, 6,
       &m->has_orientation},
      {0x0028, 0x0030, "PixelSpacing", m->pixel_spacing, 2,
       &m->has_pixel_spacing},
      {0x0028, 0x1053, "RescaleSlope", &m->slope, 1, nullptr},
      {0x0028, 0x1052, "RescaleIntercept", &m->intercept, 1, nullptr},
      /* A lone slice's thickness: SpacingBetweenSlices, else
       * SliceThickness (read second, only when the first is absent). */
      {0x0018, 0x0088, "SpacingBetweenSlices", &step, 1, &has_step},
      {0x0018, 0x0050, "SliceThickness", &step, 1, &has_step}};
  for (auto &t : ds_tags) {
    if (t.element == 0x0050 && has_step)
      continue;
    if ((rc = read_numbers(ctx, name, ds, t.group, t.element, t.what, t.out,
                           t.n)) < 0)
      return rc;
    if (t.has != nullptr)
      *t.has = rc;
  }
  /* GDCM reads a slope of 0 where only the intercept is given, and
   * asserts on it. */
  if (ds.FindDataElement(gdcm::Tag(0x0028, 0x1052)) !=
      ds.FindDataElement(gdcm::Tag(0x0028, 0x1053)))
    return rp__fail(ctx, RP_EFORMAT, "%s: RescaleIntercept (0028,1052) "
                    "and RescaleSlope (0028,1053) come together; the file "
                    "has one of them", name);
  if (frames < 1 || frames > 4294967295.0 || frames != std::floor(frames))
    return rp__fail(ctx, RP_EFORMAT, "%s: NumberOfFrames (0028,0008): "
                    "value %g is not a count of frames", name, frames);
  m->frames = (uint32_t)frames;
  m->slice_step = step > 0 ? step : 0;
  if (m->frames > 1)
    multiframe_geometry(file, m);
  return 0;
}

void meta_defaults(rp__dicom_meta *m) {
  std::memset(m, 0, sizeof *m);
  m->frames = 1;
  m->samples = 1;
  m->slope = 1.0;
}

int meta_read(rp_context *ctx, const rp__dicom_src *src, rp__dicom_meta *m) {
  Input in(src);
  gdcm::Reader reader;
  if (in.stream == nullptr)
    return rp__fail(ctx, RP_EIO, "%s: cannot open: %s", src->name,
                    std::strerror(errno));
  reader.SetStream(*in.stream);
  /* The header: the pixel data is decoded later, slices in order. */
  if (!reader.ReadUpToTag(kPixelData, std::set<gdcm::Tag>{kPixelData}))
    return rp__fail(ctx, RP_EFORMAT, "%s: GDCM cannot read the header "
                    "(malformed)", src->name);
  int rc = meta_from(ctx, src->name, reader.GetFile(), m);
  if (rc == 0)
    rc = vrs_ok(ctx, src->name, reader.GetFile().GetDataSet(), 0);
  if (rc == 0)
    rc = sop_class_ok(ctx, src->name, reader.GetFile());
  return rc;
}

/* Stored values to int32: masked to BitsStored, sign-extended when
 * signed. Bits above the stored ones may hold overlays in old files. */
template <typename T>
void widen(const char *buf, size_t count, int bits, bool is_signed,
           int32_t *dst) {
  const uint64_t mask = bits >= 32 ? 0xffffffffull : (1ull << bits) - 1;
  const uint64_t sign = 1ull << (bits - 1);
  for (size_t i = 0; i < count; i++) {
    T raw;
    std::memcpy(&raw, buf + i * sizeof raw, sizeof raw);
    uint64_t u = (uint64_t)raw & mask;
    int64_t s = is_signed && (u & sign) ? (int64_t)u - (int64_t)(mask + 1)
                                        : (int64_t)u;
    dst[i] = (int32_t)s;
  }
}

/* The header's pixel format, checked before GDCM's image reader sees it:
 * GDCM asserts on some values (SamplesPerPixel above 4, for one). */
int format_ok(rp_context *ctx, const char *name, const rp__dicom_meta *m) {
  int alloc = m->bits_allocated, stored = m->bits_stored;
  if (m->photometric[0] != '\0' &&
      std::strcmp(m->photometric, "MONOCHROME1") != 0 &&
      std::strcmp(m->photometric, "MONOCHROME2") != 0)
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: PhotometricInterpretation "
                    "(0028,0004) '%s': only grey images (MONOCHROME1/2) "
                    "make a volume", name, m->photometric);
  if (m->samples != 1)
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: SamplesPerPixel (0028,0002) "
                    "%d: only grey images (one sample) make a volume", name,
                    m->samples);
  if ((alloc != 8 && alloc != 16 && alloc != 32) || stored < 1 ||
      stored > alloc || m->high_bit != stored - 1 ||
      (m->pixel_rep != 0 && m->pixel_rep != 1) ||
      (alloc == 32 && stored == 32 && m->pixel_rep == 0))
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: BitsAllocated (0028,0100) "
                    "%d, BitsStored (0028,0101) %d, HighBit (0028,0102) %d, "
                    "PixelRepresentation (0028,0103) %d: not a supported "
                    "integer pixel format", name, alloc, stored, m->high_bit,
                    m->pixel_rep);
  return 0;
}

int pixels_read(rp_context *ctx, const rp__dicom_src *src,
                const rp__dicom_meta *m, int32_t *dst, size_t count) {
  Input in(src);
  gdcm::ImageReader reader;
  const char *name = src->name;
  int rc;
  if ((rc = format_ok(ctx, name, m)) != 0)
    return rc;
  if (in.stream == nullptr)
    return rp__fail(ctx, RP_EIO, "%s: cannot open: %s", name,
                    std::strerror(errno));
  reader.SetStream(*in.stream);
  if (!reader.Read())
    return rp__fail(ctx, RP_EFORMAT, "%s: GDCM cannot read the image "
                    "(truncated, malformed, or no PixelData (7FE0,0010))",
                    name);
  const gdcm::Image &img = reader.GetImage();
  unsigned ndim = img.GetNumberOfDimensions();
  uint64_t cols = img.GetDimension(0), rows = img.GetDimension(1);
  uint64_t frames = ndim > 2 ? img.GetDimension(2) : 1;
  if (cols != m->cols || rows != m->rows || frames != m->frames ||
      cols * rows * frames != count)
    return rp__fail(ctx, RP_EFORMAT, "%s: the image is %llux%llux%llu, its "
                    "header said Columns %u, Rows %u, NumberOfFrames %u",
                    name, (unsigned long long)cols, (unsigned long long)rows,
                    (unsigned long long)frames, m->cols, m->rows, m->frames);
  const gdcm::PixelFormat &pf = img.GetPixelFormat();
  gdcm::PhotometricInterpretation pi = img.GetPhotometricInterpretation();
  if (pf.GetSamplesPerPixel() != 1 ||
      (pi != gdcm::PhotometricInterpretation::MONOCHROME1 &&
       pi != gdcm::PhotometricInterpretation::MONOCHROME2))
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: SamplesPerPixel (0028,0002) "
                    "%u, PhotometricInterpretation (0028,0004) '%s': only "
                    "grey images (MONOCHROME1/2, one sample) make a volume",
                    name, (unsigned)pf.GetSamplesPerPixel(),
                    gdcm::PhotometricInterpretation::GetPIString(pi));
  int alloc = pf.GetBitsAllocated(), stored = pf.GetBitsStored();
  bool is_signed = pf.GetPixelRepresentation() == 1;
  if ((alloc != 8 && alloc != 16 && alloc != 32) || stored < 1 ||
      stored > alloc || pf.GetHighBit() != stored - 1 ||
      (alloc == 32 && stored == 32 && !is_signed))
    return rp__fail(ctx, RP_EUNSUPPORTED, "%s: BitsAllocated (0028,0100) "
                    "%d, BitsStored (0028,0101) %d, HighBit (0028,0102) %d, "
                    "PixelRepresentation (0028,0103) %d: not a supported "
                    "integer pixel format", name, alloc, stored,
                    (int)pf.GetHighBit(), is_signed ? 1 : 0);
  size_t bytes = count * (size_t)(alloc / 8);
  if (img.GetBufferLength() != bytes)
    return rp__fail(ctx, RP_EFORMAT, "%s: pixel data of %lu bytes, %zu "
                    "expected", name, img.GetBufferLength(), bytes);
  /* Native pixel data shorter than the image: GDCM would copy the
   * image's length out of the shorter value. */
  const gdcm::DataElement &pd = img.GetDataElement();
  const gdcm::ByteValue *native = pd.GetByteValue();
  if (native != nullptr && native->GetLength() < bytes)
    return rp__fail(ctx, RP_ETRUNC, "%s: PixelData (7FE0,0010) holds %u "
                    "bytes, Columns x Rows x NumberOfFrames x "
                    "BitsAllocated/8 = %zu", name,
                    (unsigned)native->GetLength(), bytes);
  if (native == nullptr && pd.GetSequenceOfFragments() == nullptr)
    return rp__fail(ctx, RP_EFORMAT, "%s: no PixelData (7FE0,0010)", name);
  std::vector<char> buf(bytes);
  if (!img.GetBuffer(buf.data()))
    return rp__fail(ctx, RP_EFORMAT, "%s: PixelData (7FE0,0010) cannot be "
                    "decoded (truncated or corrupt; transfer syntax %s)",
                    name, gdcm::TransferSyntax::GetTSString(
                              img.GetTransferSyntax()));
  if (alloc == 8)
    widen<uint8_t>(buf.data(), count, stored, is_signed, dst);
  else if (alloc == 16)
    widen<uint16_t>(buf.data(), count, stored, is_signed, dst);
  else
    widen<uint32_t>(buf.data(), count, stored, is_signed, dst);
  return 0;
}

/* GDCM reports warnings and errors on std::cerr, and the library prints
 * nothing (the caller reads rp_last_error): its output is off while the
 * shim runs, and put back as it was afterwards. GDCM's switches are
 * global, so two threads loading DICOM at once may leave them off. */
struct Quiet {
  bool warning = gdcm::Trace::GetWarningFlag();
  bool error = gdcm::Trace::GetErrorFlag();
  bool debug = gdcm::Trace::GetDebugFlag();
  Quiet() {
    gdcm::Trace::SetWarning(false);
    gdcm::Trace::SetError(false);
    gdcm::Trace::SetDebug(false);
  }
  ~Quiet() {
    gdcm::Trace::SetWarning(warning);
    gdcm::Trace::SetError(error);
    gdcm::Trace::SetDebug(debug);
  }
};

} // namespace

extern "C" int rp__dicom_meta_read(rp_context *ctx, const rp__dicom_src *src,
                                   rp__dicom_meta *m) {
  Quiet quiet;
  int rc;
  meta_defaults(m);
  /* GDCM sees only files whose structure holds (dicom_walk.c). */
  if ((rc = rp__dicom_walk_src(ctx, src)) != 0)
    return rc;
  try {
    return meta_read(ctx, src, m);
  } catch (const std::bad_alloc &) {
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory reading the DICOM "
                    "header", src->name);
  } catch (const std::exception &e) {
    return rp__fail(ctx, RP_EFORMAT, "%s: malformed DICOM header: %s",
                    src->name, e.what());
  } catch (...) {
    return rp__fail(ctx, RP_EFORMAT, "%s: malformed DICOM header",
                    src->name);
  }
}

extern "C" int rp__dicom_pixels_read(rp_context *ctx,
                                     const rp__dicom_src *src,
                                     const rp__dicom_meta *m, int32_t *dst,
                                     size_t count) {
  Quiet quiet;
  int rc = rp__dicom_walk_src(ctx, src);
  if (rc != 0)
    return rc > 0 ? rp__fail(ctx, RP_EFORMAT, "%s: no longer a DICOM "
                             "file", src->name)
                  : rc;
  try {
    return pixels_read(ctx, src, m, dst, count);
  } catch (const std::bad_alloc &) {
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory decoding the pixel "
                    "data", src->name);
  } catch (const std::exception &e) {
    return rp__fail(ctx, RP_EFORMAT, "%s: malformed pixel data: %s",
                    src->name, e.what());
  } catch (...) {
    return rp__fail(ctx, RP_EFORMAT, "%s: malformed pixel data", src->name);
  }
}
