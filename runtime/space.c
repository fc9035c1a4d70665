/* Sampling density and the three tuning spaces (DESIGN section 6).
 *
 * Density rho = scale^2 * base_step / step: rays per output pixel times
 * samples per voxel of depth, relative to the base step at full size.
 * Frame time is close to linear in it, which is what lets the tuner
 * extrapolate.
 * Each space turns a rho into a (step, scale) pair:
 * - ray: scale 1, step = base_step / rho;
 * - image: step = base_step, scale = sqrt(rho);
 * - hybrid: the reduction -ln(rho) split evenly between the two factors
 *   (scale^2 and base_step / step each take half of it), and when one
 *   factor reaches its bound the other takes the rest. An even split in
 *   the logarithm degrades both the same relative amount: seed 000 §7.6
 *   finds that neither pure space wins everywhere (under-sampling along
 *   rays shows on thin structures, image scaling blurs edges).
 * Above 1 (a min_step under base_step), ray and hybrid space refine the
 * step alone, down to min_step: a scale above 1 would render more rays
 * than the output has pixels, which the upscale cannot use. A frame
 * whose TF leaves budget over at the base step (an opaque TF ends its
 * rays early) then spends it on samples between voxels, which brings
 * the image closer to the fine reference (raypace bench quality). */
#include <math.h>
#include <string.h>

#include "bounds.h"
#include "internal.h"
#include "raypace_pace.h"

/* The bounds with their defaults filled in: the one place that knows
 * them. A max_step below base_step or a min_scale above 1 is clamped
 * rather than refused (mapping must not fail inside a frame); zero,
 * negative or NaN fields take the defaults. */
static rp_space_desc space_defaults(const rp_space_desc *in) {
  rp_space_desc d = {0};
  if (in != NULL)
    d = *in;
  if (!(d.base_step > 0.0f) || !isfinite(d.base_step))
    d.base_step = 1.0f;
  if (!(d.max_step > 0.0f) || !isfinite(d.max_step))
    d.max_step = 16.0f * d.base_step;
  if (d.max_step < d.base_step)
    d.max_step = d.base_step;
  if (d.min_scale > 1.0f)
    d.min_scale = 1.0f;
  if (!(d.min_scale > 0.0f))
    d.min_scale = 0.125f;
  if (!(d.min_step > 0.0f) || !isfinite(d.min_step) ||
      d.min_step > d.base_step || d.space == RP_SPACE_IMAGE)
    d.min_step = d.base_step;
  /* Within raypace.h's limits, so that no density maps to a render the
   * device refuses (rp__space_check refuses such a desc up front where
   * a caller gives one). */
  d.base_step = fminf(fmaxf(d.base_step, RP_STEP_MIN), RP_STEP_MAX);
  d.max_step = fminf(fmaxf(d.max_step, d.base_step), RP_STEP_MAX);
  d.min_step = fminf(fmaxf(d.min_step, RP_STEP_MIN), d.base_step);
  d.min_scale = fmaxf(d.min_scale, RP_SCALE_MIN);
  return d;
}

int rp__space_check(rp_context *ctx, const char *fn, const char *field,
                    const rp_space_desc *d) {
  static const char *const names[3] = {"base_step", "max_step", "min_step"};
  const float steps[3] = {d->base_step, d->max_step, d->min_step};
  char num[40];
  int i;
  for (i = 0; i < 3; i++)
    if (steps[i] != 0.0f &&
        !(steps[i] >= RP_STEP_MIN && steps[i] <= RP_STEP_MAX))
      return rp__fail(ctx, RP_ERANGE, "%s: %s.%s is %s; must be in [%g, "
                      "%g] voxels (0: the default)", fn, field, names[i],
                      rp__num_text(num, steps[i], 1), RP_STEP_MIN,
                      RP_STEP_MAX);
  if (d->min_scale != 0.0f && !(d->min_scale >= RP_SCALE_MIN))
    return rp__fail(ctx, RP_ERANGE, "%s: %s.min_scale is %s; must be at "
                    "least %g (above 1 means 1; 0: 0.125)", fn, field,
                    rp__num_text(num, d->min_scale, 1), RP_SCALE_MIN);
  return 0;
}

/* The largest reduction -ln(rho) each factor can take. */
static void reductions(const rp_space_desc *d, double *ray, double *image) {
  *ray = d->space == RP_SPACE_IMAGE ? 0.0
                                    : log((double)d->max_step /
                                          (double)d->base_step);
  *image = d->space == RP_SPACE_RAY ? 0.0 : -2.0 * log((double)d->min_scale);
}

double rp_space_min_density(const rp_space_desc *in) {
  rp_space_desc d = space_defaults(in);
  double ray, image;
  reductions(&d, &ray, &image);
  return exp(-(ray + image));
}

double rp_space_max_density(const rp_space_desc *in) {
  rp_space_desc d = space_defaults(in);
  return (double)d.base_step / (double)d.min_step;
}

void rp_space_map(const rp_space_desc *in, double rho, float *step,
                  float *scale) {
  rp_space_desc d = space_defaults(in);
  double ray_max, image_max, h, ray, image;
  if (rho > 1.0) {
    /* Finer than the base step; NaN does not get here. */
    double top = (double)d.base_step / (double)d.min_step;
    *scale = 1.0f;
    *step = rho >= top ? d.min_step
                       : fminf(fmaxf((float)((double)d.base_step / rho),
                                     d.min_step),
                               d.base_step);
    return;
  }
  reductions(&d, &ray_max, &image_max);
  /* NaN and rho = 1 give the base step at full resolution: never a NaN
   * step. */
  h = !(rho < 1.0) ? 0.0 : rho > 0.0 ? -log(rho) : INFINITY;
  if (h > ray_max + image_max)
    h = ray_max + image_max;
  /* One rule for every space: a pure space has no room in the other
   * factor (reductions() gives it 0), so the even split hands it all to
   * the factor that has. */
  ray = 0.5 * h;
  image = 0.5 * h;
  if (ray > ray_max) {
    image += ray - ray_max;
    ray = ray_max;
  } else if (image > image_max) {
    ray += image - image_max;
    image = image_max;
  }
  /* The bounds hold exactly, not just up to exp/log rounding. */
  *step = ray <= 0.0         ? d.base_step
          : ray >= ray_max   ? d.max_step
                             : fminf((float)((double)d.base_step * exp(ray)),
                                     d.max_step);
  *scale = image <= 0.0        ? 1.0f
           : image >= image_max ? d.min_scale
                                : fmaxf((float)exp(-0.5 * image),
                                        d.min_scale);
}

static const char *const space_names[] = {"ray", "image", "hybrid"};

const char *rp_space_name(rp_space space) {
  return (unsigned)space < 3 ? space_names[space] : "unknown";
}

int rp_space_from_name(const char *name, rp_space *out) {
  int i;
  for (i = 0; name != NULL && out != NULL && i < 3; i++) {
    if (strcmp(name, space_names[i]) == 0) {
      *out = (rp_space)i;
      return 0;
    }
  }
  return rp__fail(NULL, RP_EINVAL,
                  "unknown tuning space '%s' (ray, image, hybrid)",
                  name != NULL ? name : "(null)");
}
