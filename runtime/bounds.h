/* Checks of raypace.h's Limits (runtime/bounds.c). */
#ifndef RP_BOUNDS_H
#define RP_BOUNDS_H

#include <stdint.h>

#include "raygen.h"

/* The shortest %g form of v that reads back as the same float (is_float)
 * or double: 179.9f prints as "179.9", not "179.899994", and the float
 * just below 0.001f as "0.0009999999", not "0.001". */
const char *rp__num_text(char buf[40], double v, int is_float);

/* 0 when lo <= v <= hi; otherwise records "WHERE: FIELD is V; must be in
 * [LO, HI] UNIT (0: ZERO)" and returns RP_EINVAL (NaN included). `where` may be "" and `zero` NULL (no default); V is
 * printed in the fewest digits that read back as the same float when
 * is_float is set, so 179.9f reads "179.9". */
int rp__check_range(rp_context *ctx, const char *where, const char *field,
                    double v, int is_float, double lo, double hi,
                    const char *unit, const char *zero);

/* "512 bytes", "300.0 MiB", "6.2 GiB" (powers of 1024). */
const char *rp__bytes_text(char buf[32], uint64_t bytes);

/* The memory an allocation may take without the OOM killer or minutes of
 * swapping: MemAvailable + SwapFree, else the physical memory; 0 when
 * unknown (then nothing is refused). */
uint64_t rp__memory_available(void);

/* 0, or RP_ENOMEM with "WHAT needs 6.2 GiB (N bytes); this machine has
 * ... available" when `bytes` exceeds rp__memory_available(). Called
 * before every allocation that grows with the input (volumes, bricks,
 * images), never after. */
int rp__check_memory(rp_context *ctx, const char *what, uint64_t bytes);

/* An output image of width x height within RP_IMAGE_MAX_DIM and
 * RP_IMAGE_MAX_PIXELS (RP_EINVAL naming `field` otherwise). */
int rp__check_image_size(rp_context *ctx, const char *where,
                         const char *field, uint32_t width, uint32_t height);

/* The most lattice samples one ray through rg's volume can take at
 * `step`: the box diagonal in depth units over the step, plus one. */
double rp__ray_samples_max(const rp__raygen *rg, double step);

/* The work bound: RP_EINVAL with the counts when a ray may take more than
 * RP_MAX_SAMPLES_PER_RAY samples at `step`, or rg's width x height rays
 * more than RP_MAX_SAMPLES_PER_FRAME. rg->width/height are the scaled
 * image's. */
int rp__check_work(rp_context *ctx, const char *where, const rp__raygen *rg,
                   double step);

#endif /* RP_BOUNDS_H */
