/* The bounds of raypace.h's Limits section that take more than one
 * comparison: the one message form every range check uses, the memory
 * the machine can hold, and the work a frame may ask for.
 *
 * The memory check exists because an allocation the machine cannot hold
 * does not fail on Linux: malloc succeeds (overcommit) and the OOM killer
 * ends the process later, or the machine swaps for minutes. Refusing
 * before the allocation, with the size asked for, is the only place the
 * user still gets a message. */
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "bounds.h"

const char *rp__num_text(char buf[40], double v, int is_float) {
  int p;
  for (p = 6; p <= 17; p++) { /* %g's 6 digits, more if needed */
    double back;
    snprintf(buf, 40, "%.*g", p, v);
    back = strtod(buf, NULL);
    if (is_float ? (float)back == (float)v : back == v)
      break;
  }
  return buf;
}

int rp__check_range(rp_context *ctx, const char *where, const char *field,
                    double v, int is_float, double lo, double hi,
                    const char *unit, const char *zero) {
  char num[40];
  if (v >= lo && v <= hi)
    return 0;
  return rp__fail(ctx, RP_EINVAL, "%s%s%s is %s; must be in [%g, %g]%s%s%s%s%s", where,
                  where[0] != '\0' ? ": " : "", field,
                  rp__num_text(num, v, is_float), lo, hi,
                  unit[0] != '\0' ? " " : "", unit,
                  zero != NULL ? " (0: " : "", zero != NULL ? zero : "",
                  zero != NULL ? ")" : "");
}

const char *rp__bytes_text(char buf[32], uint64_t bytes) {
  const double kib = 1024.0, mib = kib * 1024.0, gib = mib * 1024.0,
               tib = gib * 1024.0;
  double b = (double)bytes;
  if (b >= tib)
    snprintf(buf, 32, "%.1f TiB", b / tib);
  else if (b >= gib)
    snprintf(buf, 32, "%.1f GiB", b / gib);
  else if (b >= mib)
    snprintf(buf, 32, "%.1f MiB", b / mib);
  else
    snprintf(buf, 32, "%llu bytes", (unsigned long long)bytes);
  return buf;
}

/* MemAvailable plus SwapFree from /proc/meminfo (what Linux can still
 * give without killing anything), in bytes; 0 when it cannot be read. */
static uint64_t meminfo_available(void) {
  FILE *f = fopen("/proc/meminfo", "r");
  char line[128];
  unsigned long long avail = 0, swap = 0, kb;
  int have = 0;
  if (f == NULL)
    return 0;
  while (fgets(line, sizeof line, f) != NULL) {
    if (sscanf(line, "MemAvailable: %llu kB", &kb) == 1)
      avail = kb, have = 1;
    else if (sscanf(line, "SwapFree: %llu kB", &kb) == 1)
      swap = kb;
  }
  fclose(f);
  return have ? (avail + swap) * 1024ull : 0;
}

uint64_t rp__memory_available(void) {
  uint64_t m = meminfo_available();
#if defined(_SC_PHYS_PAGES) && defined(_SC_PAGESIZE)
  if (m == 0) {
    long pages = sysconf(_SC_PHYS_PAGES), size = sysconf(_SC_PAGESIZE);
    if (pages > 0 && size > 0)
      m = (uint64_t)pages * (uint64_t)size;
  }
#endif
  return m;
}

int rp__check_memory(rp_context *ctx, const char *what, uint64_t bytes) {
  uint64_t avail = rp__memory_available();
  char asked[32], have[32];
  if (avail == 0 || bytes <= avail)
    return 0;
  return rp__fail(ctx, RP_ENOMEM, "%s needs %s (%llu bytes); this machine "
                  "has %s of memory available", what,
                  rp__bytes_text(asked, bytes), (unsigned long long)bytes,
                  rp__bytes_text(have, avail));
}

int rp__check_image_size(rp_context *ctx, const char *where,
                         const char *field, uint32_t width,
                         uint32_t height) {
  uint64_t pixels = (uint64_t)width * height;
  if (width == 0 || height == 0 || width > RP_IMAGE_MAX_DIM ||
      height > RP_IMAGE_MAX_DIM)
    return rp__fail(ctx, RP_EINVAL, "%s: %s is %ux%u; each must be in "
                    "[1, %u] pixels", where, field, (unsigned)width,
                    (unsigned)height, RP_IMAGE_MAX_DIM);
  if (pixels > RP_IMAGE_MAX_PIXELS)
    return rp__fail(ctx, RP_EINVAL, "%s: %s is %ux%u, %llu pixels; at "
                    "most %u (RP_IMAGE_MAX_PIXELS, e.g. 8192x8192): "
                    "render a larger image as tiles", where, field,
                    (unsigned)width, (unsigned)height,
                    (unsigned long long)pixels, RP_IMAGE_MAX_PIXELS);
  return 0;
}

double rp__ray_samples_max(const rp__raygen *rg, double step) {
  double d2 = 0.0;
  int a;
  /* The longest chord of the box, in depth units (voxels of the finest
   * spacing): no ray inside it is longer. */
  for (a = 0; a < 3; a++) {
    double e = rg->dims[a] * rg->spacing[a] / rg->min_spacing;
    d2 += e * e;
  }
  return floor(sqrt(d2) / step) + 1.0;
}

int rp__check_work(rp_context *ctx, const char *where, const rp__raygen *rg,
                   double step) {
  double per_ray = rp__ray_samples_max(rg, step);
  double rays = (double)rg->width * rg->height;
  if (!(per_ray <= (double)RP_MAX_SAMPLES_PER_RAY))
    return rp__fail(ctx, RP_EINVAL, "%s: a ray may take %.4g samples (the "
                    "volume's diagonal, %.4g voxels of its finest spacing "
                    "%g, over step %g); at most %u "
                    "(RP_MAX_SAMPLES_PER_RAY): use a coarser step, or a "
                    "volume whose spacings differ less", where, per_ray,
                    (per_ray - 1.0) * step, rg->min_spacing, step,
                    RP_MAX_SAMPLES_PER_RAY);
  if (!(per_ray * rays <= (double)RP_MAX_SAMPLES_PER_FRAME))
    return rp__fail(ctx, RP_EINVAL, "%s: the frame may take %.4g samples "
                    "(%ux%u rays of up to %.4g each at step %g); at most "
                    "%.4g (RP_MAX_SAMPLES_PER_FRAME): use a coarser step "
                    "or a smaller image", where, per_ray * rays,
                    (unsigned)rg->width, (unsigned)rg->height, per_ray,
                    step, (double)RP_MAX_SAMPLES_PER_FRAME);
  return 0;
}
