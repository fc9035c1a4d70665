/* Volume payloads: raw or gzip (or zlib) data, either endianness, from
 * memory or from an open file, into a new volume (volume_io.h says how the
 * loader's parts fit together).
 *
 * Policy decisions (tests/test_volume_io.c holds us to them):
 * - Data must fill the file exactly: fewer bytes than the sizes need is
 *   RP_ETRUNC, more is RP_EFORMAT. The only way to ignore leading bytes is
 *   NRRD's "byte skip" (-1: the payload is the file's last bytes) and
 *   "line skip". For gzip the stream must end with the data, and nothing
 *   may follow it; "line skip" counts lines of the file before the
 *   stream, "byte skip" bytes of the inflated data (as teem reads them),
 *   and -1 is for raw data only. */
#define ZLIB_CONST
#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <string.h>
#include <sys/types.h>
#include <zlib.h>

#include "volume_io.h"

/* Read and inflate granularity. */
#define CHUNK ((size_t)64 << 10)

/* Calls to inflate() made by this thread, which only tests read: they hold
 * the decoder to a bounded number of calls per inflated byte. Thread-local,
 * so that concurrent loads do not race on it. */
extern _Thread_local unsigned long rp__inflate_calls;
_Thread_local unsigned long rp__inflate_calls;


/* A header handed to rp__volume_decode: its struct's own field names. */
static const rp__header_fields memory_fields_named = {"field 'dims'",
                                                      "field 'spacing'"};

/* ---- Reading the source ------------------------------------------------ */

/* Reads up to n bytes; *got < n only at the end of the data. */
static int src_read(rp_context *ctx, const char *name, rp__volume_source *s,
                    void *dst, size_t n, size_t *got) {
  if (n > s->left)
    n = (size_t)s->left;
  if (s->fp == NULL) {
    /* An empty memory source may be NULL, which memcpy must not see. */
    if (n > 0) {
      memcpy(dst, s->mem, n);
      s->mem += n;
    }
    *got = n;
  } else {
    *got = fread(dst, 1, n, s->fp);
    if (*got < n && ferror(s->fp))
      return rp__fail(ctx, RP_EIO, "%s: read error: %s", name,
                      strerror(errno));
    if (*got < n) {
      s->left = 0; /* shrank since fstat: report as truncated */
      return 0;
    }
  }
  s->left -= *got;
  return 0;
}

static int src_skip(rp_context *ctx, const char *name, rp__volume_source *s,
                    uint64_t n) {
  if (s->fp == NULL) {
    s->mem += n;
  } else if (n > 0) {
    /* n <= left <= the file size, which fits off_t. */
    if (fseeko(s->fp, (off_t)n, SEEK_CUR) != 0)
      return rp__fail(ctx, RP_EIO, "%s: seek error: %s", name,
                      strerror(errno));
  }
  s->left -= n;
  return 0;
}

/* Consumes `lines` lines, each up to and including its '\n'. */
static int src_skip_lines(rp_context *ctx, const char *name,
                          rp__volume_source *s, uint64_t lines) {
  uint64_t done;
  for (done = 0; done < lines; done++) {
    if (s->fp == NULL) {
      const uint8_t *nl = NULL;
      if (s->left > 0)
        nl = memchr(s->mem, '\n', s->left > SIZE_MAX ? SIZE_MAX
                                                     : (size_t)s->left);
      if (nl == NULL)
        break;
      src_skip(ctx, name, s, (uint64_t)(nl - s->mem) + 1);
    } else {
      int c = 0;
      while (s->left > 0 && (c = getc(s->fp)) != EOF) {
        s->left--;
        if (c == '\n')
          break;
      }
      if (c == EOF && ferror(s->fp))
        return rp__fail(ctx, RP_EIO, "%s: read error: %s", name,
                        strerror(errno));
      if (c != '\n')
        break;
    }
  }
  if (done < lines)
    return rp__fail(ctx, RP_ETRUNC,
                    "%s: line skip %llu goes past the end of the data (%llu "
                    "lines)",
                    name, (unsigned long long)lines,
                    (unsigned long long)done);
  return 0;
}

static int decode_raw(rp_context *ctx, const char *name,
                      const rp__volume_header *hdr, rp__volume_source *src,
                      size_t bytes, uint8_t **out) {
  char dt[96];
  uint8_t *data;
  size_t got;
  int rc;
  if (hdr->skip_to_end) {
    if (src->left < bytes)
      return rp__fail(ctx, RP_ETRUNC,
                      "%s: data truncated: %s needs %zu bytes, %llu present",
                      name, rp__volume_dims_text(dt, hdr), bytes,
                      (unsigned long long)src->left);
    if ((rc = src_skip(ctx, name, src, src->left - bytes)) != 0)
      return rc;
  } else {
    if (hdr->byte_skip > src->left)
      return rp__fail(ctx, RP_ETRUNC,
                      "%s: byte skip %llu goes past the end of the data (%llu "
                      "bytes)",
                      name, (unsigned long long)hdr->byte_skip,
                      (unsigned long long)src->left);
    if ((rc = src_skip(ctx, name, src, hdr->byte_skip)) != 0)
      return rc;
    if (src->left < bytes)
      return rp__fail(ctx, RP_ETRUNC,
                      "%s: data truncated: %s needs %zu bytes, %llu present",
                      name, rp__volume_dims_text(dt, hdr), bytes,
                      (unsigned long long)src->left);
    if (src->left > bytes)
      return rp__fail(ctx, RP_EFORMAT,
                      "%s: %llu bytes of data, but %s needs %zu: the sizes "
                      "do not match the data",
                      name, (unsigned long long)src->left,
                      rp__volume_dims_text(dt, hdr), bytes);
  }
  data = rp__malloc(ctx, bytes);
  if (data == NULL)
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory for %zu bytes", name,
                    bytes);
  if ((rc = src_read(ctx, name, src, data, bytes, &got)) != 0 ||
      got < bytes) {
    rp__free(ctx, data);
    return rc != 0 ? rc
                   : rp__fail(ctx, RP_ETRUNC,
                              "%s: data truncated: read %zu of %zu bytes",
                              name, got, bytes);
  }
  *out = data;
  return 0;
}

/* zlib allocates through the context's allocator too. */
static voidpf z_alloc(voidpf opaque, uInt items, uInt size) {
  if (size != 0 && items > SIZE_MAX / size)
    return Z_NULL;
  return rp__malloc((rp_context *)opaque, (size_t)items * size);
}

static void z_free(voidpf opaque, voidpf ptr) {
  rp__free((rp_context *)opaque, ptr);
}

/* One gzip decode's state, from the first buffer to the last byte. It
 * holds the z_stream, which zlib points back to: it stays where it was
 * made. */
typedef struct gz_decoder {
  rp_context *ctx;
  const char *name;
  rp__volume_source *src;
  z_stream zs;
  int inited; /* inflateInit2 succeeded: inflateEnd is due */
  int in_end; /* the source is used up */
  uint8_t *in;     /* input read from a file (NULL for memory) */
  uint8_t *data;   /* the output: cap bytes, `have` of them inflated */
  uint8_t *window; /* wcap bytes for the byte skip; NULL: `data` is it */
  uint8_t spill[64]; /* where bytes past the data land, to be refused */
  uint64_t skip;     /* inflated bytes still to discard */
  size_t bytes, cap, wcap, have;
} gz_decoder;

/* Where the next inflated bytes go (gz_target). */
enum { GZ_SKIP, GZ_FILL, GZ_SPILL, GZ_GROW };

/* The first output buffer, the input buffer, the window, then zlib. */
static int gz_start(gz_decoder *gz) {
  rp_context *ctx = gz->ctx;
  int zrc;
  gz->zs.zalloc = z_alloc;
  gz->zs.zfree = z_free;
  gz->zs.opaque = ctx;
  gz->cap = gz->bytes < CHUNK ? gz->bytes : CHUNK;
  gz->data = rp__malloc(ctx, gz->cap);
  if (gz->src->fp != NULL)
    gz->in = rp__malloc(ctx, CHUNK);
  /* The output buffer serves as the window when it is as large. */
  gz->wcap = gz->skip < CHUNK ? (size_t)gz->skip : CHUNK;
  if (gz->wcap > gz->cap)
    gz->window = rp__malloc(ctx, gz->wcap);
  else
    gz->wcap = gz->cap;
  if (gz->data == NULL || (gz->src->fp != NULL && gz->in == NULL) ||
      (gz->wcap > gz->cap && gz->window == NULL))
    return rp__fail(ctx, RP_ENOMEM, "%s: out of memory", gz->name);
  /* 15 + 32: largest window, and accept either a gzip or a zlib header. */
  zrc = inflateInit2(&gz->zs, 15 + 32);
  if (zrc != Z_OK)
    return rp__fail(ctx, zrc == Z_MEM_ERROR ? RP_ENOMEM : RP_EIO,
                    "%s: cannot start zlib (%d)", gz->name, zrc);
  gz->inited = 1;
  return 0;
}

/* Hands zlib more input once it has used up what it had: all of a memory
 * source at once, a file CHUNK bytes at a time. */
static int gz_refill(gz_decoder *gz) {
  rp__volume_source *src = gz->src;
  if (gz->zs.avail_in > 0 || gz->in_end)
    return 0;
  if (src->fp == NULL) {
    size_t n = src->left > UINT_MAX ? UINT_MAX : (size_t)src->left;
    gz->zs.next_in = src->mem;
    gz->zs.avail_in = (uInt)n;
    src_skip(gz->ctx, gz->name, src, n);
  } else {
    size_t got;
    int rc = src_read(gz->ctx, gz->name, src, gz->in, CHUNK, &got);
    if (rc != 0)
      return rc;
    gz->zs.next_in = gz->in;
    gz->zs.avail_in = (uInt)got;
  }
  gz->in_end = src->left == 0;
  return 0;
}

/* Points zlib's output where the next inflated bytes belong: the window
 * while bytes are skipped, then the data; once all the data is in, the
 * spill, where any byte is one too many. GZ_GROW: the data buffer is full
 * and the data is not, so it must grow first. */
static int gz_target(gz_decoder *gz) {
  z_stream *zs = &gz->zs;
  if (gz->skip > 0) {
    zs->next_out = gz->window != NULL ? gz->window : gz->data;
    zs->avail_out = (uInt)(gz->skip < gz->wcap ? gz->skip : gz->wcap);
    return GZ_SKIP;
  }
  if (gz->have < gz->cap) {
    size_t room = gz->cap - gz->have;
    zs->next_out = gz->data + gz->have;
    zs->avail_out = (uInt)(room > UINT_MAX ? UINT_MAX : room);
    return GZ_FILL;
  }
  if (gz->cap < gz->bytes)
    return GZ_GROW;
  zs->next_out = gz->spill;
  zs->avail_out = sizeof gz->spill;
  return GZ_SPILL;
}

/* Doubles the data buffer, capped at the data's size. */
static int gz_grow(gz_decoder *gz) {
  size_t ncap = gz->cap > gz->bytes / 2 ? gz->bytes : gz->cap * 2;
  uint8_t *grown = rp__malloc(gz->ctx, ncap);
  if (grown == NULL)
    return rp__fail(gz->ctx, RP_ENOMEM, "%s: out of memory for %zu bytes",
                    gz->name, ncap);
  memcpy(grown, gz->data, gz->have);
  rp__free(gz->ctx, gz->data);
  gz->data = grown;
  gz->cap = ncap;
  return 0;
}

/* One step of the stream: input, output, one inflate() call, and what it
 * did. Returns 1 to go on, 0 at the end of the stream, or an error. */
static int gz_step(gz_decoder *gz) {
  z_stream *zs = &gz->zs;
  uInt before;
  int mode, rc, zrc;
  if ((rc = gz_refill(gz)) != 0)
    return rc;
  mode = gz_target(gz);
  if (mode == GZ_GROW)
    return (rc = gz_grow(gz)) != 0 ? rc : 1;
  before = zs->avail_out;
  zrc = inflate(zs, Z_NO_FLUSH);
  rp__inflate_calls++;
  if (mode == GZ_SKIP)
    gz->skip -= before - zs->avail_out;
  else if (mode == GZ_FILL)
    gz->have += before - zs->avail_out;
  else if (zs->avail_out != before)
    return rp__fail(gz->ctx, RP_EFORMAT,
                    "%s: gzip data holds more than the %zu bytes the sizes "
                    "need",
                    gz->name, gz->bytes);
  if (zrc == Z_STREAM_END)
    return 0;
  if (zrc == Z_OK)
    return 1;
  if (zrc == Z_BUF_ERROR && zs->avail_in == 0) {
    /* No progress possible: the output always has room, so the input
     * ran out; refill, or the stream was cut short. */
    if (!gz->in_end)
      return 1;
    return rp__fail(gz->ctx, RP_ETRUNC,
                    "%s: gzip data truncated after %zu of %zu bytes",
                    gz->name, gz->have, gz->bytes);
  }
  return zrc == Z_MEM_ERROR
             ? rp__fail(gz->ctx, RP_ENOMEM, "%s: out of memory in zlib",
                        gz->name)
             : rp__fail(gz->ctx, RP_EFORMAT, "%s: corrupt gzip data (%s)",
                        gz->name,
                        zs->msg != NULL ? zs->msg : "unknown zlib error");
}

/* At the end of the stream: all the data came, and nothing follows. */
static int gz_check_end(const gz_decoder *gz) {
  if (gz->skip > 0 || gz->have < gz->bytes)
    return rp__fail(gz->ctx, RP_ETRUNC,
                    "%s: gzip data ends after %zu of %zu bytes", gz->name,
                    gz->have, gz->bytes);
  if (gz->zs.avail_in > 0 || gz->src->left > 0)
    return rp__fail(gz->ctx, RP_EFORMAT,
                    "%s: %llu bytes follow the end of the gzip stream",
                    gz->name,
                    (unsigned long long)(gz->zs.avail_in + gz->src->left));
  return 0;
}

/* Inflates a gzip or zlib stream into exactly `bytes` bytes. The output
 * grows as data arrives (doubling, capped at `bytes`): a small file that
 * claims huge sizes runs out of input and fails with RP_ETRUNC long before
 * it could make us allocate what it claims. The byte skip is inflated into
 * a window of up to CHUNK bytes of its own: the output buffer of a tiny
 * volume would take one inflate call per skipped byte. */
static int decode_gzip(rp_context *ctx, const char *name,
                       const rp__volume_header *hdr, rp__volume_source *src,
                       size_t bytes, uint8_t **out) {
  gz_decoder gz;
  int rc;
  memset(&gz, 0, sizeof gz);
  gz.ctx = ctx;
  gz.name = name;
  gz.src = src;
  gz.skip = hdr->byte_skip;
  gz.bytes = bytes;
  if ((rc = gz_start(&gz)) == 0) {
    do
      rc = gz_step(&gz);
    while (rc > 0);
    if (rc == 0)
      rc = gz_check_end(&gz);
  }
  if (gz.inited)
    inflateEnd(&gz.zs);
  rp__free(ctx, gz.window);
  rp__free(ctx, gz.in);
  if (rc != 0) {
    rp__free(ctx, gz.data);
    return rc;
  }
  *out = gz.data;
  return 0;
}

static int host_is_big_endian(void) {
  const uint16_t one = 1;
  uint8_t first;
  memcpy(&first, &one, 1);
  return first == 0;
}

static void swap_bytes(uint8_t *p, size_t count, size_t size) {
  size_t i;
  uint8_t t;
  for (i = 0; i < count; i++, p += size) {
    if (size == 2) {
      t = p[0], p[0] = p[1], p[1] = t;
    } else if (size == 4) {
      t = p[0], p[0] = p[3], p[3] = t;
      t = p[1], p[1] = p[2], p[2] = t;
    }
  }
}

int rp__volume_decode_source(rp_context *ctx, const char *name,
                             const rp__volume_header *hdr,
                             rp__volume_source *src, size_t bytes,
                             rp_volume **out) {
  uint8_t *data = NULL;
  uint32_t dims[3];
  rp_volume *vol = NULL;
  rp_orientation orient;
  size_t vs = rp__voxel_size(hdr->type);
  int rc;

  /* Checked before the voxels are read: a header no parser produced (the
   * fuzz targets hand such headers over) must not cost a decode first. */
  if ((rc = rp__orientation_check(ctx, name, &hdr->orientation, &orient)) !=
      0)
    return rc;
  if ((rc = src_skip_lines(ctx, name, src, hdr->line_skip)) != 0)
    return rc;
  if (hdr->payload_bytes != 0 && src->left != hdr->payload_bytes)
    return rp__fail(ctx, src->left < hdr->payload_bytes ? RP_ETRUNC
                                                        : RP_EFORMAT,
                    "%s: CompressedDataSize %llu disagrees with the %llu "
                    "bytes of data present",
                    name, (unsigned long long)hdr->payload_bytes,
                    (unsigned long long)src->left);
  rc = hdr->gzip ? decode_gzip(ctx, name, hdr, src, bytes, &data)
                 : decode_raw(ctx, name, hdr, src, bytes, &data);
  if (rc != 0 || data == NULL) /* data is set exactly when rc is 0 */
    return rc != 0 ? rc : RP_ENOMEM;
  if (vs > 1 && (hdr->big_endian != 0) != host_is_big_endian())
    swap_bytes(data, bytes / vs, vs);
  dims[0] = (uint32_t)hdr->dims[0];
  dims[1] = (uint32_t)hdr->dims[1];
  dims[2] = (uint32_t)hdr->dims[2];
  rc = rp__volume_adopt(ctx, dims, hdr->type, hdr->spacing, data, &vol);
  if (rc != 0) {
    /* The message is about the voxels; say which file they came from. */
    char msg[RP__ERRMSG_MAX];
    snprintf(msg, sizeof msg, "%s", rp_last_error(ctx));
    return rp__fail(ctx, rc, "%s: %s", name, msg);
  }
  vol->orientation = orient;
  *out = vol;
  return 0;
}

int rp__volume_decode(rp_context *ctx, const char *name,
                      const rp__volume_header *hdr, const uint8_t *payload,
                      size_t len, rp_volume **out) {
  rp__volume_source src;
  size_t bytes = 0;
  int rc;
  if (ctx == NULL)
    return RP_EINVAL;
  if (name == NULL)
    name = "(memory)";
  if (hdr == NULL || out == NULL || (payload == NULL && len > 0))
    return rp__fail(ctx, RP_EINVAL, "%s: rp__volume_decode: NULL argument",
                    name);
  if ((rc = rp__volume_header_check(ctx, name, &memory_fields_named, hdr,
                                    &bytes)) != 0)
    return rc;
  if (hdr->skip_to_end && hdr->gzip)
    return rp__fail(ctx, RP_EUNSUPPORTED,
                    "%s: byte skip -1 needs raw encoding, not gzip", name);
  src.fp = NULL;
  src.mem = payload;
  src.left = len;
  return rp__volume_decode_source(ctx, name, hdr, &src, bytes, out);
}
