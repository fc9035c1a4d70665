/* Cameras: orbit placement, validation, and one ray per pixel.
 *
 * The spaces and formulas are stated once, in raygen.h; backends receive
 * an rp__raygen rather than re-deriving the basis, so that a camera the
 * reference accepts is a camera every backend sees the same way. */
#include <math.h>
#include <string.h>

#include "bounds.h"
#include "passes.h"
#include "raygen.h"

#define RP__PI 3.14159265358979323846
#define RP__DEFAULT_FOV_DEG 40.0

static double dot3(const double a[3], const double b[3]) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static void cross3(const double a[3], const double b[3], double out[3]) {
  double c[3];
  c[0] = a[1] * b[2] - a[2] * b[1];
  c[1] = a[2] * b[0] - a[0] * b[2];
  c[2] = a[0] * b[1] - a[1] * b[0];
  out[0] = c[0];
  out[1] = c[1];
  out[2] = c[2];
}

/* Scales v to unit length; returns 0 when v is zero. Dividing by the
 * largest component first keeps tiny and huge vectors from underflowing
 * or overflowing in the squares. */
static int normalize3(double v[3]) {
  double m = fabs(v[0]), len;
  int a;
  if (fabs(v[1]) > m)
    m = fabs(v[1]);
  if (fabs(v[2]) > m)
    m = fabs(v[2]);
  if (m == 0.0)
    return 0;
  for (a = 0; a < 3; a++)
    v[a] /= m;
  len = sqrt(dot3(v, v));
  for (a = 0; a < 3; a++)
    v[a] /= len;
  return 1;
}

static int parallel(const double a[3], const double b[3]) {
  double c[3];
  cross3(a, b, c);
  return sqrt(dot3(c, c)) <= RP__PARALLEL_EPS;
}

/* Length of the box diagonal: the bounding sphere's diameter. */
static double box_diameter(const rp_volume *vol) {
  double d2 = 0.0;
  int a;
  for (a = 0; a < 3; a++) {
    double e = (double)vol->dims[a] * vol->spacing[a];
    d2 += e * e;
  }
  return sqrt(d2);
}

void rp_camera_orbit(rp_camera *cam, const rp_volume *vol, float azimuth_deg,
                     float elevation_deg, float distance) {
  double az, el, d;
  int a;
  if (cam == NULL || vol == NULL)
    return;
  az = azimuth_deg * (RP__PI / 180.0);
  el = elevation_deg * (RP__PI / 180.0);
  d = 0.5 * box_diameter(vol) * distance;
  /* Azimuth 0, elevation 0 is on +z looking down -z with +y up;
   * azimuth turns toward +x, elevation toward +y. */
  cam->eye[0] = (float)(d * cos(el) * sin(az));
  cam->eye[1] = (float)(d * sin(el));
  cam->eye[2] = (float)(d * cos(el) * cos(az));
  /* Up is the way elevation rises (d eye / d el): +y at elevation 0,
   * the default's projection of +y anywhere off the poles, and at the
   * poles the limit of the views beside them, so that elevation 90 is
   * the 89.9 view, not that view turned by the default's switch to +z. */
  cam->up[0] = (float)(-sin(el) * sin(az));
  cam->up[1] = (float)cos(el);
  cam->up[2] = (float)(-sin(el) * cos(az));
  for (a = 0; a < 3; a++)
    cam->center[a] = 0.0f;
}

/* Eye direction and up of each view in patient space (LPS). */
static const struct {
  const char *name;
  double eye[3], up[3];
} views[] = {
    {"anterior", {0, -1, 0}, {0, 0, 1}},  {"posterior", {0, 1, 0}, {0, 0, 1}},
    {"left", {1, 0, 0}, {0, 0, 1}},       {"right", {-1, 0, 0}, {0, 0, 1}},
    {"superior", {0, 0, 1}, {0, -1, 0}}, {"inferior", {0, 0, -1}, {0, -1, 0}},
};
#define N_VIEWS (int)(sizeof views / sizeof views[0])

const char *rp_view_name(rp_view view) {
  return view >= 1 && (int)view <= N_VIEWS ? views[view - 1].name : NULL;
}

rp_view rp_view_from_name(const char *name) {
  int i;
  for (i = 0; name != NULL && i < N_VIEWS; i++)
    if (strcmp(views[i].name, name) == 0)
      return (rp_view)(i + 1);
  return (rp_view)0;
}

int rp_camera_view(rp_camera *cam, const rp_volume *vol, rp_view view,
                   float distance) {
  const double *D;
  double d;
  int a;
  if (cam == NULL || vol == NULL || rp_view_name(view) == NULL)
    return RP_EINVAL;
  /* World axes are the voxel axes (scaled by the spacing), and column j of
   * the direction matrix is voxel axis j in LPS: a patient-space vector v
   * is D^T v in world space. */
  D = vol->orientation.direction;
  d = 0.5 * box_diameter(vol) * distance;
  for (a = 0; a < 3; a++) {
    const double *c = &D[3 * a];
    const double *e = views[view - 1].eye, *u = views[view - 1].up;
    cam->eye[a] = (float)(d * (c[0] * e[0] + c[1] * e[1] + c[2] * e[2]));
    cam->up[a] = (float)(c[0] * u[0] + c[1] * u[1] + c[2] * u[2]);
    cam->center[a] = 0.0f;
  }
  return 0;
}

static int check_vec(rp_context *ctx, const char *field, const float v[3]) {
  int a;
  for (a = 0; a < 3; a++)
    if (!isfinite(v[a]))
      return rp__fail(ctx, RP_EINVAL, "camera: rp_camera.%s[%d] is %g; "
                      "must be finite", field, a, (double)v[a]);
  return 0;
}

/* The camera with its zero fov replaced by the default. Two defaults are
 * left for rp__raygen_init: a zero up depends on the view direction, and
 * a zero ortho_height is the box diagonal, kept in double rather than
 * rounded into the float field. */
static rp_camera camera_defaults(const rp_camera *in) {
  rp_camera c = *in;
  if (c.fov_y_deg == 0.0f)
    c.fov_y_deg = RP__DEFAULT_FOV_DEG;
  return c;
}

static int check_camera(rp_context *ctx, const rp_camera *cam) {
  int err;
  if (cam->projection != RP_PERSPECTIVE && cam->projection != RP_ORTHOGRAPHIC)
    return rp__fail(ctx, RP_EINVAL, "camera: rp_camera.projection is %d; "
                    "must be RP_PERSPECTIVE or RP_ORTHOGRAPHIC",
                    (int)cam->projection);
  if ((err = check_vec(ctx, "eye", cam->eye)) != 0 ||
      (err = check_vec(ctx, "center", cam->center)) != 0 ||
      (err = check_vec(ctx, "up", cam->up)) != 0)
    return err;
  /* Both fields are checked whatever the projection: a camera switched
   * between projections carries both, and garbage in either is a bug.
   * ortho_height's upper bound depends on the volume (raygen_init). */
  if ((err = rp__check_range(ctx, "camera", "rp_camera.fov_y_deg",
                             cam->fov_y_deg, 1, RP_FOV_MIN_DEG,
                             RP_FOV_MAX_DEG, "degrees", "40")) != 0)
    return err;
  if (!(cam->ortho_height >= 0.0f) || !isfinite(cam->ortho_height))
    return rp__fail(ctx, RP_EINVAL, "camera: rp_camera.ortho_height is %g; "
                    "must be finite and > 0 (0: bounding diameter)",
                    (double)cam->ortho_height);
  return 0;
}

/* The bounds that depend on the volume: the eye within
 * RP_CAMERA_DISTANCE_MAX diameters of its centre (the world origin), and
 * a set ortho_height within [RP_ORTHO_HEIGHT_MIN, RP_ORTHO_HEIGHT_MAX]
 * diameters. */
static int check_camera_scale(rp_context *ctx, const rp_camera *cam,
                              const rp_volume *vol) {
  double diam = box_diameter(vol), e[3], dist;
  int a;
  for (a = 0; a < 3; a++)
    e[a] = cam->eye[a];
  dist = sqrt(dot3(e, e)) / diam;
  if (!(dist <= RP_CAMERA_DISTANCE_MAX))
    return rp__fail(ctx, RP_EINVAL, "camera: rp_camera.eye is (%g, %g, %g), "
                    "%g bounding diameters (%g world units) from the "
                    "volume's centre; must be within %g "
                    "(RP_CAMERA_DISTANCE_MAX)", e[0], e[1], e[2], dist,
                    diam, RP_CAMERA_DISTANCE_MAX);
  if (cam->ortho_height != 0.0f) {
    double h = cam->ortho_height / diam;
    char num[40];
    if (!(h >= RP_ORTHO_HEIGHT_MIN && h <= RP_ORTHO_HEIGHT_MAX))
      return rp__fail(ctx, RP_EINVAL, "camera: rp_camera.ortho_height is "
                      "%s, %g bounding diameters (%g world units); must be "
                      "in [%g, %g] diameters (0: one)",
                      rp__num_text(num, cam->ortho_height, 1), h, diam,
                      RP_ORTHO_HEIGHT_MIN, RP_ORTHO_HEIGHT_MAX);
  }
  return 0;
}

int rp__camera_check(rp_context *ctx, const rp_camera *cam) {
  rp_camera c = camera_defaults(cam);
  int err = check_camera(ctx, &c);
  if (err == 0 && c.eye[0] == c.center[0] && c.eye[1] == c.center[1] &&
      c.eye[2] == c.center[2])
    return rp__fail(ctx, RP_EINVAL, "camera: rp_camera.center equals "
                    "rp_camera.eye");
  return err;
}

int rp__raygen_init(rp_context *ctx, const rp_camera *cam_in,
                    const rp_volume *vol, uint32_t width, uint32_t height,
                    rp__raygen *rg) {
  rp_camera c = camera_defaults(cam_in);
  const rp_camera *cam = &c;
  double up[3], aspect;
  int a, err;
  if ((err = check_camera(ctx, cam)) != 0 ||
      (err = check_camera_scale(ctx, cam, vol)) != 0)
    return err;
  for (a = 0; a < 3; a++) {
    rg->eye[a] = cam->eye[a];
    /* The difference of two floats is exact in double, so eye and
     * center may be arbitrarily close without losing the direction. */
    rg->f[a] = (double)cam->center[a] - (double)cam->eye[a];
    up[a] = cam->up[a];
  }
  if (!normalize3(rg->f))
    return rp__fail(ctx, RP_EINVAL, "camera: rp_camera.center equals "
                    "rp_camera.eye; the view direction is undefined");
  if (!normalize3(up)) {
    up[0] = 0.0;
    up[1] = 1.0;
    up[2] = 0.0;
    if (parallel(rg->f, up)) {
      up[1] = 0.0;
      up[2] = 1.0;
    }
  } else if (parallel(rg->f, up)) {
    return rp__fail(ctx, RP_EINVAL, "camera: rp_camera.up is parallel to "
                    "the view direction (center - eye)");
  }
  cross3(rg->f, up, rg->r);
  normalize3(rg->r);
  cross3(rg->r, rg->f, rg->u);

  rg->ortho = cam->projection == RP_ORTHOGRAPHIC;
  rg->width = width;
  rg->height = height;
  aspect = (double)width / (double)height;
  if (rg->ortho && cam->ortho_height == 0.0f)
    rg->half_h = 0.5 * box_diameter(vol);
  else if (rg->ortho)
    rg->half_h = 0.5 * cam->ortho_height;
  else
    rg->half_h = tan(0.5 * cam->fov_y_deg * (RP__PI / 180.0));
  rg->half_w = rg->half_h * aspect;

  rg->min_spacing = vol->spacing[0];
  for (a = 0; a < 3; a++) {
    rg->dims[a] = vol->dims[a];
    rg->spacing[a] = vol->spacing[a];
    if (rg->spacing[a] < rg->min_spacing)
      rg->min_spacing = rg->spacing[a];
  }
  return 0;
}

/* Slab method in voxel space, where the box is [-0.5, dims - 0.5]. An axis
 * the ray does not move along constrains nothing when the origin lies in
 * its slab (boundary included) and misses otherwise; testing it apart
 * avoids the 0 * inf = NaN of the division form. */
static void clip(const rp__raygen *rg, rp__ray *ray) {
  double t0 = -INFINITY, t1 = INFINITY;
  int a;
  ray->hit = 0;
  for (a = 0; a < 3; a++) {
    double lo = -0.5, hi = rg->dims[a] - 0.5, ta, tb;
    if (ray->dp[a] == 0.0) {
      if (ray->p0[a] < lo || ray->p0[a] > hi)
        return;
      continue;
    }
    ta = (lo - ray->p0[a]) / ray->dp[a];
    tb = (hi - ray->p0[a]) / ray->dp[a];
    if (ta > tb) {
      double tmp = ta;
      ta = tb;
      tb = tmp;
    }
    if (ta > t0)
      t0 = ta;
    if (tb < t1)
      t1 = tb;
  }
  /* A unit direction has a component of at least 1/sqrt(3), so t0 and t1
   * are finite here. A box entirely behind the origin is a miss. */
  if (!(t0 <= t1) || t1 < 0.0)
    return;
  ray->t0 = t0;
  ray->t1 = t1;
  ray->s = t0 > 0.0 ? t0 : 0.0;
  ray->hit = 1;
}

float rp_jitter_offset(uint32_t x, uint32_t y, uint32_t seed) {
  uint32_t h = rp__ert_mix(seed ^ rp__ert_mix(x ^ rp__ert_mix(y +
                                                            0x632be5abu)));
  /* 24 bits, so that the float is exact and below 1. */
  return (float)(h >> 8) * (1.0f / 16777216.0f);
}

uint32_t rp_jitter_frame_seed(uint32_t seed, uint64_t frame) {
  uint32_t base = seed != 0 ? seed : RP_JITTER_SEED;
  uint32_t h = rp__ert_mix(base ^ rp__ert_mix((uint32_t)frame ^
                                              rp__ert_mix((uint32_t)(
                                                  frame >> 32) +
                                                          0x85157af5u)));
  return h != 0 ? h : RP_JITTER_SEED;
}

void rp__ray_jitter(rp__ray *ray, double offset, double step) {
  if (!ray->hit)
    return;
  ray->s += offset * step;
  if (!(ray->s <= ray->t1))
    ray->hit = 0;
}

void rp__raygen_ray(const rp__raygen *rg, uint32_t x, uint32_t y,
                    rp__ray *ray) {
  rp__raygen_ray_at(rg, (double)x + 0.5, (double)y + 0.5, ray);
}

void rp__raygen_ray_at(const rp__raygen *rg, double px, double py,
                       rp__ray *ray) {
  double nu = 2.0 * px / rg->width - 1.0;
  double nv = 1.0 - 2.0 * py / rg->height;
  double su = nu * rg->half_w, sv = nv * rg->half_h;
  int a;
  for (a = 0; a < 3; a++) {
    if (rg->ortho) {
      ray->org[a] = rg->eye[a] + su * rg->r[a] + sv * rg->u[a];
      ray->dir[a] = rg->f[a];
    } else {
      ray->org[a] = rg->eye[a];
      ray->dir[a] = rg->f[a] + su * rg->r[a] + sv * rg->u[a];
    }
  }
  if (!rg->ortho)
    normalize3(ray->dir);
  for (a = 0; a < 3; a++) {
    ray->p0[a] = ray->org[a] / rg->spacing[a] + 0.5 * rg->dims[a] - 0.5;
    ray->dp[a] = ray->dir[a] * (rg->min_spacing / rg->spacing[a]);
  }
  clip(rg, ray);
}

uint64_t rp__lattice_count(double s, double t1, double step) {
  /* The work bound: no ray takes more (rp__check_work refuses a frame
   * that could ask for more; this keeps every ray loop finite even so). */
  const uint64_t cap = RP_MAX_SAMPLES_PER_RAY;
  double est = floor((t1 - s) / step);
  uint64_t k;
  if (!(est >= 0.0))
    est = 0.0;
  if (est >= (double)cap)
    return cap;
  /* The quotient is only an estimate: the definition is the predicate
   * s + i*step <= t1 on the positions as computed, which is monotone in
   * i, so nudge k to the last i that satisfies it. Both walks end within
   * the cap. */
  k = (uint64_t)est;
  while (k > 0 && s + (double)k * step > t1)
    k--;
  while (k + 1 < cap && s + (double)(k + 1) * step <= t1)
    k++;
  return k + 1;
}

/* The float form of the frame every backend receives (raypace_backend.h):
 * the camera resolved here, plus the volume's grid and the TF's range. */
int rp__frame_params(rp_context *ctx, const rp_volume *shape,
                     const rp_occupancy *occ, const rp_camera *cam,
                     const rp_render_desc *d, float ref_step,
                     uint32_t lut_size, const double tf_span[2],
                     rp__raygen *rg, rp_frame_params *p) {
  int err, a;
  if ((err = rp__raygen_init(ctx, cam, shape, d->width, d->height, rg)) != 0)
    return err;
  rp_scaled_size(d, &rg->width, &rg->height);
  if ((err = rp__check_work(ctx, "render", rg, d->step)) != 0)
    return err;
  memset(p, 0, sizeof *p);
  for (a = 0; a < 3; a++) {
    p->eye[a] = (float)rg->eye[a];
    p->f[a] = (float)rg->f[a];
    p->r[a] = (float)rg->r[a];
    p->u[a] = (float)rg->u[a];
    p->dims[a] = (float)rg->dims[a];
    p->inv_spacing[a] = (float)(1.0 / rg->spacing[a]);
    p->idims[a] = shape->dims[a];
    p->blocks[a] = rp__blocks_along(shape->dims[a]);
    p->occupied_lo[a] = occ != NULL ? occ->box_lo[a] : 0u;
    p->occupied_end[a] = occ != NULL ? occ->box_end[a] : p->blocks[a];
  }
  p->half_w = (float)rg->half_w;
  p->half_h = (float)rg->half_h;
  p->ortho = rg->ortho;
  p->width = rg->width;
  p->height = rg->height;
  p->min_spacing = (float)rg->min_spacing;
  p->step = d->step;
  p->ref_step = ref_step;
  p->ert_threshold = d->ert_threshold;
  p->effects = d->effects;
  p->value_min = (float)tf_span[0];
  p->value_max = (float)tf_span[1];
  p->lut_size = lut_size;
  p->jitter = d->jitter != RP_JITTER_OFF;
  p->jitter_seed = p->jitter ? d->jitter_seed : 0u;
  return 0;
}
