/* Volume files: rp_volume_load opens a file, tells its format apart and
 * hands header and payload to the parsers and the decoder (volume_io.h
 * says how the loader's parts fit together).
 *
 * The formats are told apart in this order: a .raw file by its name (its
 * bytes can be anything, "NRRD" included); NRRD by its magic "NRRD" at
 * byte 0; NIfTI by its name or magic (volume_nifti.c); MetaImage by its
 * name or first key (volume_mhd.c); a sidecar by at least two of the
 * lines "file:", "dims:" and "type:". Only regular files are opened: a
 * FIFO would block. A folder is a DICOM series, and a file with DICOM's
 * magic ("DICM" at byte 128) one DICOM image (volume_dicom.c). */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

#include "volume_dicom.h"
#include "volume_io.h"

/* Bytes read from the start of a file to recognise it; an NRRD header or a
 * sidecar must fit in them. */
#define HEAD_MAX ((size_t)1 << 20)

static int no_such_file(rp_context *ctx, const char *path,
                        const char *owner) {
  return owner != NULL
             ? rp__fail(ctx, RP_ENOENT, "%s: data file %s: no such file",
                        owner, path)
             : rp__fail(ctx, RP_ENOENT, "%s: no such file", path);
}

static int not_regular(rp_context *ctx, const char *path,
                       const char *owner) {
  return owner != NULL
             ? rp__fail(ctx, RP_EIO, "%s: data file %s: not a regular file",
                        owner, path)
             : rp__fail(ctx, RP_EIO, "%s: not a regular file", path);
}

/* rp__open_regular (volume_io.h). A FIFO
 * blocks in open() until a writer comes, and opening a device may act on
 * it, so the path's type is checked before it is opened; the open itself
 * does not block either, and the type is checked again on the descriptor,
 * in case the path changed in between. */
FILE *rp__open_regular(rp_context *ctx, const char *path, const char *owner,
                       uint64_t *size, int *rc) {
  struct stat st;
  FILE *f = NULL;
  int fd, flags, err;
  if (stat(path, &st) != 0) {
    err = errno;
    *rc = err == ENOENT || err == ENOTDIR
              ? no_such_file(ctx, path, owner)
              : rp__fail(ctx, RP_EIO, "%s: cannot stat: %s", path,
                         strerror(err));
    return NULL;
  }
  if (!S_ISREG(st.st_mode)) {
    *rc = not_regular(ctx, path, owner);
    return NULL;
  }
  fd = open(path, O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    err = errno;
    *rc = err == ENOENT || err == ENOTDIR
              ? no_such_file(ctx, path, owner)
              : rp__fail(ctx, RP_EIO, "%s: cannot open: %s", path,
                         strerror(err));
    return NULL;
  }
  if (fstat(fd, &st) != 0) {
    err = errno;
    close(fd);
    *rc = rp__fail(ctx, RP_EIO, "%s: cannot stat: %s", path, strerror(err));
    return NULL;
  }
  if (!S_ISREG(st.st_mode)) {
    close(fd);
    *rc = not_regular(ctx, path, owner);
    return NULL;
  }
  /* Reads block as usual from here on. */
  flags = fcntl(fd, F_GETFL);
  if (flags != -1 && fcntl(fd, F_SETFL, flags & ~O_NONBLOCK) != -1)
    f = fdopen(fd, "rb");
  if (f == NULL) {
    err = errno;
    close(fd);
    *rc = rp__fail(ctx, err == ENOMEM ? RP_ENOMEM : RP_EIO,
                   "%s: cannot open: %s", path, strerror(err));
    return NULL;
  }
  *size = (uint64_t)st.st_size;
  return f;
}

/* The file `file` names relative to the directory of `header`, in memory
 * from rp__malloc; NULL when out of memory (recorded). Absolute names are
 * kept as they are. */
static char *resolve(rp_context *ctx, const char *header, const char *file) {
  const char *slash = strrchr(header, '/');
  size_t dir = file[0] == '/' || slash == NULL
                   ? 0
                   : (size_t)(slash - header) + 1;
  size_t n = strlen(file);
  char *p = rp__malloc(ctx, dir + n + 1);
  if (p == NULL) {
    rp__fail(ctx, RP_ENOMEM, "%s: out of memory", header);
    return NULL;
  }
  memcpy(p, header, dir);
  memcpy(p + dir, file, n + 1);
  return p;
}

/* Decodes the payload of `fp`, from byte `offset` to its end. */
static int decode_file(rp_context *ctx, const char *name,
                       const rp__header_fields *fields,
                       const rp__volume_header *hdr, FILE *fp, uint64_t size,
                       uint64_t offset, rp_volume **out) {
  rp__volume_source src;
  size_t bytes = 0;
  int rc;
  if ((rc = rp__volume_header_check(ctx, name, fields, hdr, &bytes)) != 0)
    return rc;
  if (offset > size || fseeko(fp, (off_t)offset, SEEK_SET) != 0)
    return rp__fail(ctx, RP_EIO, "%s: seek error", name);
  src.fp = fp;
  src.mem = NULL;
  src.left = size - offset;
  return rp__volume_decode_source(ctx, name, hdr, &src, bytes, out);
}

/* The payload of a header that names a data file. */
static int decode_data_file(rp_context *ctx, const char *path,
                            const rp__header_fields *fields,
                            const rp__volume_header *hdr, rp_volume **out) {
  char *data_path = resolve(ctx, path, hdr->data_file);
  FILE *fp;
  uint64_t size = 0;
  int rc = RP_ENOMEM;
  if (data_path == NULL)
    return rc;
  fp = rp__open_regular(ctx, data_path, path, &size, &rc);
  if (fp != NULL) {
    rc = decode_file(ctx, data_path, fields, hdr, fp, size, 0, out);
    fclose(fp);
  }
  rp__free(ctx, data_path);
  return rc;
}

/* An NRRD header must end within the bytes read: at an empty line, or at
 * the end of a file that fits in them. */
static int has_blank_line(const uint8_t *buf, size_t len) {
  size_t pos = 0;
  while (pos < len) {
    const uint8_t *nl = memchr(buf + pos, '\n', len - pos);
    size_t end;
    if (nl == NULL)
      return 0;
    end = (size_t)(nl - buf);
    if (end == pos || (end == pos + 1 && buf[pos] == '\r'))
      return 1;
    pos = end + 1;
  }
  return 0;
}

static int load_nrrd(rp_context *ctx, const char *path, FILE *fp,
                     uint64_t size, const uint8_t *head, size_t head_len,
                     rp_volume **out) {
  rp__volume_header hdr;
  size_t header_len = 0;
  int rc;
  rp__volume_header_init(&hdr);
  if (head_len < size && !has_blank_line(head, head_len))
    return rp__fail(ctx, RP_EFORMAT,
                    "%s: NRRD header does not end (empty line) within its "
                    "first %zu bytes",
                    path, HEAD_MAX);
  rc = rp__nrrd_parse(ctx, path, head, head_len, &hdr, &header_len);
  if (rc != 0)
    return rc;
  if (hdr.data_file[0] != '\0')
    return decode_data_file(ctx, path, &rp__nrrd_fields_named, &hdr, out);
  return decode_file(ctx, path, &rp__nrrd_fields_named, &hdr, fp, size,
                     header_len, out);
}

/* MetaImage: LOCAL data follows the header; otherwise it names a file. */
static int load_mhd(rp_context *ctx, const char *path, FILE *fp,
                    uint64_t size, const uint8_t *head, size_t head_len,
                    rp_volume **out) {
  rp__volume_header hdr;
  size_t header_len = 0;
  int rc = rp__mhd_parse(ctx, path, head, head_len, &hdr, &header_len);
  if (rc != 0)
    return rc;
  if (hdr.data_file[0] != '\0')
    return decode_data_file(ctx, path, &rp__mhd_fields_named, &hdr, out);
  return decode_file(ctx, path, &rp__mhd_fields_named, &hdr, fp, size,
                     header_len, out);
}

int rp_volume_load(rp_context *ctx, const char *path, rp_volume **out) {
  rp__volume_header hdr;
  struct stat st;
  uint8_t *head = NULL;
  size_t head_len, got;
  uint64_t size = 0;
  FILE *fp = NULL;
  int rc;

  if (ctx == NULL)
    return RP_EINVAL;
  if (path == NULL || out == NULL)
    return rp__fail(ctx, RP_EINVAL,
                    "rp_volume_load: path and out must not be NULL");
  rp__volume_header_init(&hdr);
  if (stat(path, &st) == 0 && S_ISDIR(st.st_mode))
    return rp__dicom_load_dir(ctx, path, out);
  if ((fp = rp__open_regular(ctx, path, NULL, &size, &rc)) == NULL)
    return rc;
  /* A .raw file by its name first: its content is voxels only, and voxels
   * may begin with any bytes, "NRRD" included. Then the first bytes
   * decide: NRRD by its magic, a sidecar by its keys. */
  rc = rp__raw_name_parse(ctx, path, &hdr);
  if (rc <= 0) {
    if (rc == 0)
      rc = decode_file(ctx, path, &rp__raw_fields_named, &hdr, fp, size, 0,
                       out);
    goto done;
  }
  head_len = size < HEAD_MAX ? (size_t)size : HEAD_MAX;
  head = rp__malloc(ctx, head_len > 0 ? head_len : 1);
  if (head == NULL) {
    rc = rp__fail(ctx, RP_ENOMEM, "%s: out of memory", path);
    goto done;
  }
  got = fread(head, 1, head_len, fp);
  if (got < head_len) {
    rc = rp__fail(ctx, RP_EIO, "%s: read error: %s", path,
                  ferror(fp) ? strerror(errno) : "file shrank");
    goto done;
  }
  if (head_len >= 4 && memcmp(head, "NRRD", 4) == 0) {
    rc = load_nrrd(ctx, path, fp, size, head, head_len, out);
  } else if (head_len >= 132 && memcmp(head + 128, "DICM", 4) == 0) {
    rp__dicom_src src = {path, NULL, 0};
    rc = rp__dicom_load_file(ctx, &src, out);
  } else if (rp__looks_like_nifti(path, head, head_len)) {
    rc = rp__nifti_load(ctx, path, out);
  } else if (rp__looks_like_mhd(path, head, head_len)) {
    rc = load_mhd(ctx, path, fp, size, head, head_len, out);
  } else if (rp__looks_like_sidecar(head, head_len)) {
    if (size > HEAD_MAX)
      rc = rp__fail(ctx, RP_EFORMAT,
                    "%s: too large for a sidecar (%llu bytes)", path,
                    (unsigned long long)size);
    else if ((rc = rp__sidecar_parse(ctx, path, head, head_len, &hdr)) == 0)
      rc = decode_data_file(ctx, path, &rp__sidecar_fields_named, &hdr, out);
  } else {
    rc = rp__fail(ctx, RP_EFORMAT,
                  "%s: not a volume file; accepted: NRRD (starts with "
                  "NRRD000N), NIfTI (.nii, .nii.gz, .hdr/.img), MetaImage "
                  "(.mhd, .mha), DICOM (DICM at byte 128; or a folder of "
                  "slices), a sidecar (lines 'file:', 'dims:', 'type:') "
                  "or NAME_XxYxZ_TYPE.raw (TYPE uint8, int8, uint16, "
                  "int16, uint32, int32, float32)",
                  path);
  }
done:
  rp__free(ctx, head);
  fclose(fp);
  return rc;
}
