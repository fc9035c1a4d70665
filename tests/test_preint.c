/* Pre-integrated classification (RP_EFFECT_PREINT, runtime/preint.c) in
 * the reference, against values worked out here: on a field that rises
 * linearly along the ray the segments' opacity is the analytic integral
 * of the TF's extinction at any step; a thin, steep feature that a
 * coarse lattice misses on most rays is seen on every ray; the table the
 * backends upload against its trapezoid sums; and PREINT off leaves the
 * plain classification as it was. The device backends are held to the
 * reference in tests/conformance/images.c. */
#include "test_util.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

#include "internal.h"
#include "raypace_backend.h"

/* A ramp of 64 voxels along x (value = voxel x, 4 x 4 across) seen along
 * -x: every ray runs through values 63 .. 0 linearly, clamped beyond. */
#define RAMP 64
#define PX 8

typedef struct ramp {
  rp_context *ctx;
  rp_volume *vol;
  rp_tf *tf;
  rp_camera cam;
} ramp;

/* The TF: lut_size entries, white, alpha[j] at x = j / (lut_size - 1). */
static ramp ramp_open(const double *alpha, int lut_size) {
  rp_volume_desc vd = {{RAMP, 4, 4}, RP_F32, {1, 1, 1}, NULL, {0}};
  rp_tf_point p[256];
  rp_tf_desc td = {p, 0, 1.0f, 0, 0, 0, 0, 0};
  float data[RAMP * 16];
  ramp r;
  int i;
  memset(&r, 0, sizeof r);
  r.ctx = rp_test_context();
  for (i = 0; i < RAMP * 16; i++)
    data[i] = (float)(i % RAMP);
  vd.data = data;
  assert_int_equal(rp_volume_create(r.ctx, &vd, &r.vol), 0);
  assert_true(lut_size <= 256);
  for (i = 0; i < lut_size; i++) {
    p[i].x = (float)i / (float)(lut_size - 1);
    p[i].r = p[i].g = p[i].b = 1.0f;
    p[i].a = (float)alpha[i];
  }
  td.count = lut_size;
  td.lut_size = lut_size;
  assert_int_equal(rp_tf_create(r.ctx, &td, &r.tf), 0);
  r.cam.projection = RP_ORTHOGRAPHIC;
  r.cam.eye[0] = 100.0f;
  r.cam.ortho_height = 2.0f;
  return r;
}

static void ramp_close(ramp *r) {
  rp_tf_destroy(r->tf);
  rp_volume_destroy(r->vol);
  rp_context_destroy(r->ctx);
}

static void ramp_render(const ramp *r, float step, uint32_t effects,
                        rp_jitter jitter, uint8_t *rgba) {
  rp_render_desc d = {0};
  d.width = d.height = PX;
  d.step = step;
  d.effects = effects;
  d.jitter = jitter;
  if (rp_render_reference(r->ctx, r->vol, r->tf, NULL, NULL, &r->cam, &d,
                          rgba, NULL) != 0)
    fail_msg("render: %s", rp_last_error(r->ctx));
}

/* The extinction per voxel rises as k (v - 8) from value 8 to 40 and
 * drops to 0 at 41; 0 elsewhere. It is linear between the LUT's entries
 * (one per value), so along the ramp the optical depth is the area under
 * it, 32 * 32k / 2 + 32k / 2 = 528k, and a ray's opacity is
 * 1 - exp(-528k) whatever the lattice: every segment with extinction lies
 * where the field is linear (the clamped ends have none). k = 2 / 528.
 * The plain classification samples points: at a step of 4 from the box
 * entry (63.5) its samples sit at 39.5, 35.5, ..., 11.5, summing 560k,
 * and it reads 1 - exp(-560k) = 4 bytes too much. */
static void test_linear_ramp(void **state) {
  static const float steps[] = {0.5f, 2.0f, 4.0f};
  double alpha[RAMP], k = 2.0 / 528.0, exact = 1.0 - exp(-2.0);
  uint8_t rgba[PX * PX * 4];
  ramp r;
  int i, s, j;
  (void)state;
  for (i = 0; i < RAMP; i++)
    alpha[i] = i >= 8 && i <= 40 ? 1.0 - exp(-k * (i - 8)) : 0.0;
  r = ramp_open(alpha, RAMP);
  for (s = 0; s < 3; s++)
    for (j = 0; j < 2; j++) {
      ramp_render(&r, steps[s], RP_EFFECT_PREINT,
                  j ? RP_JITTER_ON : RP_JITTER_OFF, rgba);
      for (i = 0; i < PX * PX; i++) {
        double a = rgba[4 * i + 3] / 255.0;
        if (fabs(a - exact) > 0.5 / 255.0 + 1e-6)
          fail_msg("step %g jitter %d ray %d: opacity %.5f, analytic %.5f",
                   (double)steps[s], j, i, a, exact);
        /* White emission: colour equals opacity. */
        assert_int_equal(rgba[4 * i], rgba[4 * i + 3]);
      }
    }
  ramp_render(&r, 4.0f, 0, RP_JITTER_OFF, rgba);
  {
    double plain = rgba[3] / 255.0, want = 1.0 - exp(-560.0 * k);
    print_message("ramp opacity: analytic %.5f, plain at step 4 %.5f\n",
                  exact, plain);
    /* The alpha interpolation of the plain LUT differs from tau's by
     * well under a byte here. */
    assert_true(fabs(plain - want) < 1.0 / 255.0);
    assert_true(fabs(plain - exact) > 3.0 / 255.0);
  }
  ramp_close(&r);
}

/* A spike: one LUT entry of 256 over values 0..63 has alpha 0.99, its
 * neighbours 0, so the extinction is a triangle of half-width h = 63/255
 * voxel around value 84h = 20.75 and height tau = -ln(0.01). Every ray
 * crosses it: pre-integrated, each ray's opacity is 1 - exp(-tau h) =
 * 0.68 at any step. At a
 * step of 4, jittered, a plain sample lands inside the 2h = 0.49 voxel
 * wide spike on a share 2h / 4 = 12 % of rays (64 rays: at most 20 %
 * allowed, about 2.5 standard deviations); the rest show nothing. */
static void test_thin_feature(void **state) {
  double alpha[256], tau = -log(0.01), h = 63.0 / 255.0;
  double exact = 1.0 - exp(-tau * h);
  uint8_t rgba[PX * PX * 4];
  int i, seen = 0;
  ramp r;
  (void)state;
  for (i = 0; i < 256; i++)
    alpha[i] = i == 84 ? 0.99 : 0.0;
  r = ramp_open(alpha, 256);
  ramp_render(&r, 4.0f, RP_EFFECT_PREINT, RP_JITTER_ON, rgba);
  for (i = 0; i < PX * PX; i++)
    if (fabs(rgba[4 * i + 3] / 255.0 - exact) > 0.5 / 255.0 + 1e-6)
      fail_msg("ray %d: opacity %u/255, want %.5f", i, rgba[4 * i + 3],
               exact);
  ramp_render(&r, 4.0f, 0, RP_JITTER_ON, rgba);
  for (i = 0; i < PX * PX; i++)
    seen += rgba[4 * i + 3] > 0;
  print_message("spike: pre-integrated %.3f on every ray; plain sees it "
                "on %d of %d rays\n", exact, seen, PX * PX);
  assert_true(seen <= PX * PX / 5);
  ramp_close(&r);
}

/* The table against its definition, summed here in another order: entry
 * i's integral is the sum of trapezoids of (tau, tau c) below it. */
static void test_table(void **state) {
  float lut[4 * 5] = {0, 0, 0, 0,      1, 0, 0, 0.5f, 0, 1, 0, 1,
                      0, 0, 1, 0.25f, 1, 1, 1, 0};
  float out[8 * 5];
  double tau[5], cum = 0.0, cum_r = 0.0;
  int i;
  (void)state;
  rp__preint_table(lut, 5, out);
  for (i = 0; i < 5; i++) {
    double a = lut[4 * i + 3] > RP_PREINT_ALPHA_MAX ? RP_PREINT_ALPHA_MAX
                                                    : lut[4 * i + 3];
    tau[i] = -log(1.0 - a);
  }
  for (i = 0; i < 5; i++) {
    if (i > 0) {
      cum += (tau[i - 1] + tau[i]) / 2.0;
      cum_r += (tau[i - 1] * lut[4 * (i - 1)] + tau[i] * lut[4 * i]) / 2.0;
    }
    assert_float_equal(out[8 * i], tau[i], 1e-6 * (1.0 + tau[i]));
    assert_float_equal(out[8 * i + 1], tau[i] * lut[4 * i], 1e-6 * 14.0);
    assert_float_equal(out[8 * i + 4], cum, 1e-6 * (1.0 + cum));
    assert_float_equal(out[8 * i + 5], cum_r, 1e-6 * (1.0 + cum_r));
  }
  /* The opaque entry is clamped, not infinite. */
  assert_true(isfinite(out[8 * 2]) && out[8 * 2] > 13.0f);
}

/* A constant field: every segment has one value, and its mean is the
 * model at that value; with an entry's alpha at a node that is the
 * plain opacity correction of that alpha. */
static void test_constant(void **state) {
  double alpha[RAMP], mean[4], rgba[4];
  ramp r;
  int i;
  (void)state;
  for (i = 0; i < RAMP; i++)
    alpha[i] = 0.02 * (i % 7);
  r = ramp_open(alpha, RAMP);
  for (i = 0; i < RAMP; i++) {
    double x = i / (double)(RAMP - 1);
    rp__preint_mean(r.tf, x, x, mean);
    rp__preint_classify(mean, 2.5, rgba);
    assert_float_equal(rgba[3],
                       rp_opacity_correct((float)alpha[i], 2.5f, 1.0f),
                       1e-6);
  }
  /* Either order, the same mean. */
  {
    double m2[4];
    rp__preint_mean(r.tf, 0.1, 0.7, mean);
    rp__preint_mean(r.tf, 0.7, 0.1, m2);
    for (i = 0; i < 4; i++)
      assert_float_equal(mean[i], m2[i], 1e-12);
  }
  ramp_close(&r);
}

int main(void) {
  const struct CMUnitTest tests[] = {
      cmocka_unit_test(test_linear_ramp),
      cmocka_unit_test(test_thin_feature),
      cmocka_unit_test(test_table),
      cmocka_unit_test(test_constant),
  };
  return cmocka_run_group_tests(tests, NULL, NULL);
}
