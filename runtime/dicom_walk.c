/* A walk over a DICOM file's elements before GDCM reads it
 * (volume_dicom.h, rp__dicom_walk).
 *
 * Why: Debian's GDCM is built with its assertions on, and some malformed
 * files (a data set cut short in the middle, for one) end in abort()
 * inside it rather than in an error. GDCM also accepts PixelData cut
 * short, reading the missing bytes as zeros: a silent wrong image. This
 * walk checks only structure: every element's length fits in what
 * encloses it, sequences and items nest and close, explicit VRs are VRs,
 * and the data set ends where the file does. It decodes no value beyond
 * the transfer syntax; GDCM does the rest. RLE pixel data (whose GDCM
 * decoder asserts that each frame decodes to its size) is decoded dry:
 * every segment must give exactly Rows x Columns bytes. */
#include <errno.h>
#include <fcntl.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include "internal.h"
#include "volume_dicom.h"

/* Nested sequences deeper than this are refused (real files nest a few
 * levels), so that a crafted file cannot exhaust the stack. */
#define MAX_DEPTH 16
#define UNDEFINED 0xffffffffu

enum { CODEC_NONE, CODEC_JPEG, CODEC_J2K };

typedef struct walk {
  rp_context *ctx;
  const char *name;
  const uint8_t *p;
  size_t len;
  int implicit, big_endian, rle;
  int codec; /* CODEC_*: the compressed pixel data's frame headers */
  /* Top-level image tags, for the RLE check; 0: absent. */
  uint32_t rows, cols, bits, samples, frames;
  uint32_t rle_frames; /* frames checked */
} walk;

static uint32_t u16(const walk *w, size_t at) {
  const uint8_t *b = w->p + at;
  return w->big_endian ? (uint32_t)b[0] << 8 | b[1]
                       : (uint32_t)b[1] << 8 | b[0];
}

static uint32_t u32(const walk *w, size_t at) {
  return w->big_endian ? u16(w, at) << 16 | u16(w, at + 2)
                       : u16(w, at + 2) << 16 | u16(w, at);
}

/* VRs with a 4-byte length (after two reserved bytes) in explicit VR. */
static int long_vr(const uint8_t *vr) {
  static const char *const names[] = {"OB", "OD", "OF", "OL", "OV", "OW",
                                      "SQ", "SV", "UC", "UN", "UR", "UT",
                                      "UV"};
  size_t i;
  for (i = 0; i < sizeof names / sizeof names[0]; i++)
    if (memcmp(vr, names[i], 2) == 0)
      return 1;
  return 0;
}

static int known_vr(const uint8_t *vr) {
  static const char *const names[] = {"AE", "AS", "AT", "CS", "DA", "DS",
                                      "DT", "FL", "FD", "IS", "LO", "LT",
                                      "PN", "SH", "SL", "SS", "ST", "TM",
                                      "UI", "UL", "US"};
  size_t i;
  if (long_vr(vr))
    return 1;
  for (i = 0; i < sizeof names / sizeof names[0]; i++)
    if (memcmp(vr, names[i], 2) == 0)
      return 1;
  return 0;
}

static int cut(walk *w, uint32_t group, uint32_t element, size_t at,
               uint64_t need, size_t end) {
  return rp__fail(w->ctx, RP_ETRUNC, "%s: element (%04X,%04X) at byte %zu "
                  "needs %llu bytes, %zu are left: the file is cut short "
                  "or malformed", w->name, group, element, at,
                  (unsigned long long)need, end - at);
}

static int walk_set(walk *w, size_t *pos, size_t end, int depth,
                    int in_item);

static uint32_t le32(const uint8_t *b) {
  return (uint32_t)b[3] << 24 | (uint32_t)b[2] << 16 | (uint32_t)b[1] << 8 |
         b[0];
}

/* One PackBits segment of an RLE frame, from `p` up to `limit`: must give
 * exactly `want` bytes. Returns the bytes left after it, or -1. */
static long rle_segment(const uint8_t *p, size_t at, size_t limit,
                        uint64_t want) {
  uint64_t got = 0;
  while (got < want) {
    int8_t n;
    if (at >= limit)
      return -1;
    n = (int8_t)p[at++];
    if (n >= 0) {
      if ((size_t)n + 1 > limit - at)
        return -1;
      at += (size_t)n + 1;
      got += (uint64_t)n + 1;
    } else if (n != -128) {
      if (at >= limit)
        return -1;
      at++;
      got += (uint64_t)(1 - n);
    }
  }
  return got == want ? (long)(limit - at) : -1;
}

/* An RLE frame (a fragment after the offset table): a 64-byte header
 * (segment count, 15 offsets), one segment per byte of a pixel. */
static int rle_frame(walk *w, size_t at, uint32_t len) {
  const uint8_t *f = w->p + at;
  uint32_t segments, want_segments, i;
  uint64_t plane = (uint64_t)w->rows * w->cols;
  want_segments = w->bits / 8 * w->samples;
  if (w->rows == 0 || w->cols == 0 || w->bits % 8 != 0 ||
      want_segments == 0 || want_segments > 15)
    return rp__fail(w->ctx, RP_EFORMAT, "%s: RLE pixel data without "
                    "valid Rows, Columns, BitsAllocated and SamplesPerPixel "
                    "before it", w->name);
  if (len < 64 || (segments = le32(f)) != want_segments)
    return rp__fail(w->ctx, RP_EFORMAT, "%s: RLE frame %u: %u segments, "
                    "BitsAllocated / 8 x SamplesPerPixel = %u", w->name,
                    w->rle_frames, len < 64 ? 0 : le32(f), want_segments);
  for (i = 0; i < segments; i++) {
    uint32_t start = le32(f + 4 + 4 * i);
    uint32_t limit = i + 1 < segments ? le32(f + 8 + 4 * i) : len;
    long left;
    if ((i == 0 && start != 64) || start >= limit || limit > len ||
        (left = rle_segment(f, start, limit, plane)) < 0 ||
        (i + 1 < segments && left > 2))
      return rp__fail(w->ctx, RP_EFORMAT, "%s: RLE frame %u, segment %u "
                      "(bytes %u to %u) does not decode to Rows x Columns "
                      "= %llu bytes: malformed RLE data", w->name,
                      w->rle_frames, i, start, limit,
                      (unsigned long long)plane);
  }
  w->rle_frames++;
  return 0;
}

static uint32_t be16(const uint8_t *b) { return (uint32_t)b[0] << 8 | b[1]; }

static uint32_t be32(const uint8_t *b) {
  return be16(b) << 16 | be16(b + 2);
}

/* The size a JPEG or JPEG-LS frame header (SOFn, SOF55) gives, from the
 * markers before the scan; 0 when none is found. */
static int jpeg_size(const uint8_t *f, size_t len, uint32_t *width,
                     uint32_t *height, uint32_t *components) {
  size_t at = 2; /* after SOI */
  while (at + 4 <= len && f[at] == 0xff) {
    uint8_t m = f[at + 1];
    uint32_t seg = be16(f + at + 2);
    if (m == 0xda)
      return 0; /* the scan, and no frame header before it */
    if (((m >= 0xc0 && m <= 0xcf && m != 0xc4 && m != 0xc8 &&
          m != 0xcc) || m == 0xf7) && seg >= 8 && at + 2 + seg <= len) {
      *height = be16(f + at + 5);
      *width = be16(f + at + 7);
      *components = f[at + 9];
      return 1;
    }
    at += 2 + seg;
  }
  return 0;
}

/* The size a JPEG 2000 codestream's SIZ marker gives; 0 when absent. */
static int j2k_size(const uint8_t *f, size_t len, uint32_t *width,
                    uint32_t *height, uint32_t *components) {
  size_t at;
  for (at = 0; at + 42 <= len && at < 512; at++)
    if (f[at] == 0xff && f[at + 1] == 0x4f && f[at + 2] == 0xff &&
        f[at + 3] == 0x51) {
      const uint8_t *siz = f + at + 4;
      *width = be32(siz + 4) - be32(siz + 12);
      *height = be32(siz + 8) - be32(siz + 16);
      *components = be16(siz + 36);
      return 1;
    }
  return 0;
}

/* A fragment of JPEG-family pixel data: one that starts a frame (SOI, or
 * a JPEG 2000 box or codestream) must say the image's size, since GDCM
 * asserts that a codec gives it at least the bytes the image needs. */
static int codec_fragment(walk *w, size_t at, uint32_t len) {
  const uint8_t *f = w->p + at;
  uint32_t width = 0, height = 0, components = 0;
  int found;
  if (w->codec == CODEC_JPEG) {
    if (len < 2 || f[0] != 0xff || f[1] != 0xd8)
      return 0; /* a frame's continuation */
    found = jpeg_size(f, len, &width, &height, &components);
  } else {
    found = j2k_size(f, len, &width, &height, &components);
    if (!found && !(len >= 12 && memcmp(f + 4, "jP  ", 4) == 0))
      return 0; /* a continuation */
  }
  if (!found || width != w->cols || height != w->rows ||
      components != (w->samples ? w->samples : 1))
    return rp__fail(w->ctx, RP_EFORMAT, "%s: compressed frame at byte %zu: "
                    "%s%ux%u with %u components, the image is Columns %u x "
                    "Rows %u", w->name, at, found ? "" : "no frame header; ",
                    width, height, components, w->cols, w->rows);
  return 0;
}

/* Top-level values the RLE check needs: US tags and NumberOfFrames. */
static void note_image_tag(walk *w, uint32_t g, uint32_t e, size_t at,
                           uint32_t len) {
  uint32_t *us = NULL;
  if (g != 0x0028)
    return;
  if (e == 0x0010)
    us = &w->rows;
  else if (e == 0x0011)
    us = &w->cols;
  else if (e == 0x0100)
    us = &w->bits;
  else if (e == 0x0002)
    us = &w->samples;
  if (us != NULL && len == 2)
    *us = u16(w, at);
  if (e == 0x0008) {
    uint32_t v = 0, i;
    for (i = 0; i < len && v < 100000000u; i++) {
      uint8_t c = w->p[at + i];
      if (c >= '0' && c <= '9')
        v = v * 10 + (uint32_t)(c - '0');
      else if (c != ' ' && c != '+')
        break;
    }
    w->frames = v;
  }
}

/* The items of a sequence (or the fragments of encapsulated pixel data,
 * `fragments`), from *pos: up to `end` for a defined length, else to the
 * sequence delimiter. */
static int walk_items(walk *w, size_t *pos, size_t end, int undefined,
                      int fragments, int depth) {
  uint32_t index = 0;
  while (undefined || *pos < end) {
    uint32_t g, e, len;
    size_t at = *pos;
    if (end - at < 8)
      return cut(w, 0xfffe, 0xe000, at, 8, end);
    g = u16(w, at), e = u16(w, at + 2), len = u32(w, at + 4);
    *pos = at + 8;
    if (g == 0xfffe && (e == 0xe0dd || e == 0xe00d) && len != 0)
      return rp__fail(w->ctx, RP_EFORMAT, "%s: a delimiter (FFFE,%04X) at "
                      "byte %zu with length %u (a delimiter has none)",
                      w->name, e, at, len);
    if (g == 0xfffe && e == 0xe0dd && undefined) {
      uint32_t frames = w->frames ? w->frames : 1;
      if (fragments && w->rle && w->rle_frames != frames)
        return rp__fail(w->ctx, RP_EFORMAT, "%s: %u RLE frames, "
                        "NumberOfFrames (0028,0008) says %u", w->name,
                        w->rle_frames, frames);
      return 0;
    }
    if (g != 0xfffe || e != 0xe000)
      return rp__fail(w->ctx, RP_EFORMAT, "%s: (%04X,%04X) at byte %zu "
                      "where a sequence item (FFFE,E000) belongs", w->name,
                      g, e, at);
    if (len == UNDEFINED) {
      int rc;
      if (fragments)
        return rp__fail(w->ctx, RP_EFORMAT, "%s: a pixel data fragment at "
                        "byte %zu has no length", w->name, at);
      if ((rc = walk_set(w, pos, end, depth + 1, 1)) != 0)
        return rc;
      continue;
    }
    if (len > end - *pos)
      return cut(w, g, e, at, (uint64_t)len + 8, end);
    if (!fragments) {
      size_t item_end = *pos + len;
      int rc = walk_set(w, pos, item_end, depth + 1, 0);
      if (rc != 0)
        return rc;
    } else if (index > 0 && (w->rle || w->codec != CODEC_NONE)) {
      /* Item 0 is the offset table. */
      int rc = w->rle ? rle_frame(w, *pos, len)
                      : codec_fragment(w, *pos, len);
      if (rc != 0)
        return rc;
    }
    index++;
    *pos = at + 8 + len;
  }
  return 0;
}

/* Elements from *pos to `end`; in an item of undefined length, up to its
 * delimiter (FFFE,E00D). */
static int walk_set(walk *w, size_t *pos, size_t end, int depth,
                    int in_item) {
  uint32_t last = 0;
  int first = 1;
  if (depth > MAX_DEPTH)
    return rp__fail(w->ctx, RP_EFORMAT, "%s: sequences nested deeper than "
                    "%d levels at byte %zu", w->name, MAX_DEPTH, *pos);
  while (*pos < end) {
    size_t at = *pos, head = 8;
    uint32_t g, e, len;
    int sequence;
    if (end - at < 8)
      return cut(w, 0, 0, at, 8, end);
    g = u16(w, at), e = u16(w, at + 2);
    if (g == 0xfffe && e == 0xe00d && in_item) {
      if (u32(w, at + 4) != 0)
        return rp__fail(w->ctx, RP_EFORMAT, "%s: a delimiter (FFFE,E00D) "
                        "at byte %zu with a length (a delimiter has none)",
                        w->name, at);
      *pos = at + 8;
      return 0;
    }
    /* Items and delimiters belong in sequences only: GDCM asserts on
     * one among a data set's elements. */
    if (g == 0xfffe)
      return rp__fail(w->ctx, RP_EFORMAT, "%s: (FFFE,%04X) at byte %zu "
                      "outside a sequence", w->name, e, at);
    /* Tags ascend in a data set; GDCM re-reads a file that breaks the
     * order in other encodings, where lengths mean other things. */
    if (!first && (g << 16 | e) <= last)
      return rp__fail(w->ctx, RP_EFORMAT, "%s: element (%04X,%04X) at byte "
                      "%zu after (%04X,%04X): tags out of order", w->name, g,
                      e, at, last >> 16, last & 0xffff);
    last = g << 16 | e;
    first = 0;
    if (w->implicit) {
      len = u32(w, at + 4);
      sequence = len == UNDEFINED;
    } else {
      const uint8_t *vr = w->p + at + 4;
      if (!known_vr(vr))
        return rp__fail(w->ctx, RP_EFORMAT, "%s: element (%04X,%04X) at "
                        "byte %zu has no valid VR (bytes 0x%02X 0x%02X)",
                        w->name, g, e, at, vr[0], vr[1]);
      if (long_vr(vr)) {
        if (end - at < 12)
          return cut(w, g, e, at, 12, end);
        len = u32(w, at + 8);
        head = 12;
      } else {
        len = u16(w, at + 6);
      }
      sequence = memcmp(vr, "SQ", 2) == 0 ||
                 (len == UNDEFINED && memcmp(vr, "UN", 2) == 0);
      /* GDCM asserts PixelData is neither a sequence nor UN. */
      if (g == 0x7fe0 && e == 0x0010 && memcmp(vr, "OB", 2) != 0 &&
          memcmp(vr, "OW", 2) != 0)
        return rp__fail(w->ctx, RP_EFORMAT, "%s: PixelData (7FE0,0010) at "
                        "byte %zu has VR %.2s, not OB or OW", w->name, at,
                        (const char *)vr);
    }
    *pos = at + head;
    if (g == 0x7fe0 && e == 0x0010 && len == UNDEFINED) {
      int rc = walk_items(w, pos, end, 1, 1, depth);
      if (rc != 0)
        return rc;
      continue;
    }
    if (len == UNDEFINED && !sequence)
      return rp__fail(w->ctx, RP_EFORMAT, "%s: element (%04X,%04X) at byte "
                      "%zu has an undefined length", w->name, g, e, at);
    if (len != UNDEFINED && len > end - *pos)
      return cut(w, g, e, at, (uint64_t)len + head, end);
    if (depth == 0 && len != UNDEFINED)
      note_image_tag(w, g, e, *pos, len);
    if (sequence && (!w->implicit || len == UNDEFINED)) {
      size_t seq_end = len == UNDEFINED ? end : *pos + len;
      /* An explicit UN of undefined length holds implicit VR items
       * (CP 246), and GDCM reads them so. */
      int was_implicit = w->implicit, rc;
      if (!w->implicit && memcmp(w->p + at + 4, "UN", 2) == 0)
        w->implicit = 1;
      rc = walk_items(w, pos, seq_end, len == UNDEFINED, 0, depth);
      w->implicit = was_implicit;
      if (rc != 0)
        return rc;
      if (len != UNDEFINED)
        *pos = seq_end;
      continue;
    }
    *pos += len;
  }
  if (in_item)
    return cut(w, 0xfffe, 0xe00d, *pos, 8, end);
  return 0;
}

/* The file meta group (explicit VR little endian, group 0002) from
 * *pos; sets the data set's transfer syntax. Its elements must end
 * exactly where its group length (0002,0000), when present, says: GDCM
 * asserts on a meta group that runs over it. */
static int walk_meta(walk *w, size_t *pos) {
  char ts[68] = "";
  size_t meta_end = w->len;
  int counted = 0;
  while (*pos < meta_end && w->len - *pos >= 8 && (counted || *pos == 132)) {
    size_t at = *pos;
    const uint8_t *vr = w->p + at + 4;
    uint32_t len, group = u16(w, at), element = u16(w, at + 2);
    size_t head = 8;
    if (group != 0x0002 || !known_vr(vr) || memcmp(vr, "SQ", 2) == 0 ||
        (at == 132 && (element != 0 || memcmp(vr, "UL", 2) != 0)))
      return rp__fail(w->ctx, RP_EFORMAT, "%s: meta element (%04X,%04X) at "
                      "byte %zu: the meta group is group 0002, starts with "
                      "its length (0002,0000) UL and holds no sequence",
                      w->name, group, element, at);
    if (long_vr(vr)) {
      if (meta_end - at < 12)
        return cut(w, 2, element, at, 12, meta_end);
      len = u32(w, at + 8), head = 12;
    } else {
      len = u16(w, at + 6);
    }
    if (len > meta_end - at - head)
      return cut(w, 2, element, at, (uint64_t)len + head, meta_end);
    if (element == 0x0000 && at == 132 && len == 4 && !counted) {
      uint64_t group_end = (uint64_t)at + head + len + u32(w, at + head);
      if (group_end > w->len)
        return cut(w, 2, 0, at, group_end - at, w->len);
      meta_end = (size_t)group_end;
      counted = 1;
    }
    if (element == 0x0010 && len < sizeof ts) {
      size_t n = len;
      memcpy(ts, w->p + at + head, n);
      ts[n] = '\0';
      while (n > 0 && (ts[n - 1] == '\0' || ts[n - 1] == ' '))
        ts[--n] = '\0';
    }
    *pos = at + head + len;
  }
  if (!counted || *pos != meta_end)
    return rp__fail(w->ctx, RP_EFORMAT, "%s: the meta group ends at byte "
                    "%zu, its length (0002,0000) says %zu", w->name, *pos,
                    counted ? meta_end : 0);
  /* GDCM reads on while it finds group 0002, and asserts when the file
   * ends where it looks for a tag. */
  if (w->len - *pos < 8 || u16(w, *pos) == 0x0002)
    return rp__fail(w->ctx, RP_EFORMAT, "%s: %s after the meta group "
                    "(byte %zu)", w->name,
                    w->len - *pos < 8 ? "no data set" : "a group 0002 element",
                    *pos);
  if (strcmp(ts, "1.2.840.10008.1.2") == 0)
    w->implicit = 1;
  else if (strcmp(ts, "1.2.840.10008.1.2.2") == 0)
    w->big_endian = 1;
  else if (strcmp(ts, "1.2.840.10008.1.2.5") == 0)
    w->rle = 1;
  else if (strncmp(ts, "1.2.840.10008.1.2.4.", 20) == 0 &&
           strlen(ts) == 22 && ts[20] == '9')
    w->codec = CODEC_J2K; /* .90 to .93, JPEG 2000 */
  else if (strncmp(ts, "1.2.840.10008.1.2.4.", 20) == 0 &&
           strlen(ts) == 22 && ts[20] >= '5' && ts[20] <= '8')
    w->codec = CODEC_JPEG; /* JPEG .50 to .70, JPEG-LS .80 and .81 */
  else if (strcmp(ts, "1.2.840.10008.1.2.1.99") == 0)
    return rp__fail(w->ctx, RP_EUNSUPPORTED, "%s: TransferSyntaxUID "
                    "(0002,0010) '%s' (deflated) is not supported", w->name,
                    ts);
  return 0;
}

int rp__dicom_walk(rp_context *ctx, const char *name, const uint8_t *p,
                   size_t len) {
  walk w;
  memset(&w, 0, sizeof w);
  w.ctx = ctx, w.name = name, w.p = p, w.len = len;
  size_t pos = 132;
  int rc;
  if (len < 132 || memcmp(p + 128, "DICM", 4) != 0)
    return 1;
  if ((rc = walk_meta(&w, &pos)) != 0)
    return rc;
  return walk_set(&w, &pos, len, 0, 0);
}

int rp__dicom_walk_src(rp_context *ctx, const rp__dicom_src *src) {
  struct stat st;
  void *map;
  int fd, rc, err;
  if (src->mem != NULL)
    return rp__dicom_walk(ctx, src->name, src->mem, src->len);
  if ((fd = open(src->name, O_RDONLY | O_CLOEXEC)) < 0) {
    err = errno;
    return rp__fail(ctx, err == ENOENT ? RP_ENOENT : RP_EIO,
                    "%s: cannot open: %s", src->name, strerror(err));
  }
  if (fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    close(fd);
    return rp__fail(ctx, RP_EIO, "%s: not a regular file", src->name);
  }
  if (st.st_size < 132) {
    close(fd);
    return 1; /* too short for the magic */
  }
  map = mmap(NULL, (size_t)st.st_size, PROT_READ, MAP_PRIVATE, fd, 0);
  err = errno;
  close(fd);
  if (map == MAP_FAILED)
    return rp__fail(ctx, RP_EIO, "%s: cannot map: %s", src->name,
                    strerror(err));
  rc = rp__dicom_walk(ctx, src->name, map, (size_t)st.st_size);
  munmap(map, (size_t)st.st_size);
  return rc;
}
