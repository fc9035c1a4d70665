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
 * the transfer syntax; GDCM does the rest. */
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

typedef struct walk {
  rp_context *ctx;
  const char *name;
  const uint8_t *p;
  size_t len;
  int implicit, big_endian;
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

/* The items of a sequence (or the fragments of encapsulated pixel data,
 * `fragments`), from *pos: up to `end` for a defined length, else to the
 * sequence delimiter. */
static int walk_items(walk *w, size_t *pos, size_t end, int undefined,
                      int fragments, int depth) {
  while (undefined || *pos < end) {
    uint32_t g, e, len;
    size_t at = *pos;
    if (end - at < 8)
      return cut(w, 0xfffe, 0xe000, at, 8, end);
    g = u16(w, at), e = u16(w, at + 2), len = u32(w, at + 4);
    *pos = at + 8;
    if (g == 0xfffe && e == 0xe0dd && undefined)
      return 0;
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
    }
    *pos = at + 8 + len;
  }
  return 0;
}

/* Elements from *pos to `end`; in an item of undefined length, up to its
 * delimiter (FFFE,E00D). */
static int walk_set(walk *w, size_t *pos, size_t end, int depth,
                    int in_item) {
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
      *pos = at + 8;
      return 0;
    }
    if (w->implicit || g == 0xfffe) {
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
    if (sequence && (!w->implicit || len == UNDEFINED)) {
      size_t seq_end = len == UNDEFINED ? end : *pos + len;
      int rc = walk_items(w, pos, seq_end, len == UNDEFINED, 0, depth);
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
 * *pos; sets the data set's transfer syntax. */
static int walk_meta(walk *w, size_t *pos) {
  char ts[68] = "";
  while (w->len - *pos >= 8 && u16(w, *pos) == 0x0002) {
    size_t at = *pos;
    const uint8_t *vr = w->p + at + 4;
    uint32_t len, element = u16(w, at + 2);
    size_t head = 8;
    if (!known_vr(vr))
      return rp__fail(w->ctx, RP_EFORMAT, "%s: meta element (0002,%04X) "
                      "has no valid VR", w->name, element);
    if (long_vr(vr)) {
      if (w->len - at < 12)
        return cut(w, 2, element, at, 12, w->len);
      len = u32(w, at + 8), head = 12;
    } else {
      len = u16(w, at + 6);
    }
    if (len > w->len - at - head)
      return cut(w, 2, element, at, (uint64_t)len + head, w->len);
    if (element == 0x0010 && len < sizeof ts) {
      size_t n = len;
      memcpy(ts, w->p + at + head, n);
      ts[n] = '\0';
      while (n > 0 && (ts[n - 1] == '\0' || ts[n - 1] == ' '))
        ts[--n] = '\0';
    }
    *pos = at + head + len;
  }
  if (strcmp(ts, "1.2.840.10008.1.2") == 0)
    w->implicit = 1;
  else if (strcmp(ts, "1.2.840.10008.1.2.2") == 0)
    w->big_endian = 1;
  else if (strcmp(ts, "1.2.840.10008.1.2.1.99") == 0)
    return rp__fail(w->ctx, RP_EUNSUPPORTED, "%s: TransferSyntaxUID "
                    "(0002,0010) '%s' (deflated) is not supported", w->name,
                    ts);
  return 0;
}

int rp__dicom_walk(rp_context *ctx, const char *name, const uint8_t *p,
                   size_t len) {
  walk w = {ctx, name, p, len, 0, 0};
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
