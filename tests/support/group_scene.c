#include "group_scene.h"

#include <string.h>

void rp_group_scene_make(rp_group_scene *s, uint32_t w, uint32_t h,
                        uint32_t effects) {
  rp_generate_desc g = {0};
  memset(s, 0, sizeof *s);
  s->ctx = rp_test_context();
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = 48;
  g.seed = 7;
  assert_int_equal(rp_volume_generate(s->ctx, &g, &s->vol), 0);
  assert_int_equal(rp_histograms_build(s->ctx, s->vol, &s->h), 0);
  assert_int_equal(rp_tf_create_preset(s->ctx, "minmax-bone", &s->tf), 0);
  assert_int_equal(rp_occupancy_build(s->ctx, s->h, s->tf, &s->occ), 0);
  rp_camera_orbit(&s->cam, s->vol, 30.0f, 20.0f, 2.0f);
  s->desc.width = w;
  s->desc.height = h;
  s->desc.effects = effects;
  assert_int_equal(rp_frame_probe_compute(s->ctx, s->vol, s->tf, s->occ,
                                          &s->cam, &s->desc, 1, 0,
                                          &s->probe),
                   0);
}

void rp_group_scene_free(rp_group_scene *s) {
  rp_occupancy_destroy(s->occ);
  rp_tf_destroy(s->tf);
  rp_histograms_destroy(s->h);
  rp_volume_destroy(s->vol);
  rp_context_destroy(s->ctx);
}

void rp_group_scene_alone(rp_group_scene *s, const char *backend,
                         uint8_t *rgba, rp_tile_stats *tiles) {
  rp_device_desc dd = {0};
  rp_device *dev = NULL;
  dd.backend = backend;
  assert_int_equal(rp_device_create(s->ctx, &dd, &dev), 0);
  assert_int_equal(rp_device_set_volume(dev, s->vol), 0);
  assert_int_equal(rp_device_set_tf(dev, s->tf, s->occ), 0);
  assert_int_equal(rp_device_render(dev, &s->cam, &s->desc, NULL, rgba,
                                    tiles),
                   0);
  rp_device_destroy(dev);
}

int rp_group_scene_frame(rp_device_group *g, rp_group_scene *s, uint8_t *rgba,
                        rp_tile_stats *tiles, rp_group_report *rep) {
  int err = rp_device_group_render(g, &s->cam, &s->desc, &s->probe, rgba,
                                   tiles, rep);
  if (err == 0)
    assert_int_equal(rp_device_group_train(g, &s->probe, 1.0f, 1.0f,
                                           rep->render_ms),
                     0);
  return err;
}
