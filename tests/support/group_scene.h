/* The scene the device-group tests render (test_group.c,
 * test_group_probation.c): a 48^3 phantom with the minmax-bone preset
 * seen from one camera, its probe, and the oracle every group image is
 * held to, byte for byte: one device rendering the whole frame alone (a
 * region's pixels depend only on its rays). */
#ifndef RP_GROUP_SCENE_H
#define RP_GROUP_SCENE_H

#include "raypace_group.h"
#include "test_util.h"

typedef struct rp_group_scene {
  rp_context *ctx;
  rp_volume *vol;
  rp_histograms *h;
  rp_tf *tf;
  rp_occupancy *occ;
  rp_camera cam;
  rp_render_desc desc;
  rp_frame_probe probe;
} rp_group_scene;

/* The scene at w x h with `effects`; asserts on failure. */
void rp_group_scene_make(rp_group_scene *s, uint32_t w, uint32_t h,
                        uint32_t effects);
void rp_group_scene_free(rp_group_scene *s);
/* The whole frame on one device of `backend`: the oracle. */
void rp_group_scene_alone(rp_group_scene *s, const char *backend,
                         uint8_t *rgba, rp_tile_stats *tiles);
/* Renders a frame with the group and trains it as an app would; the
 * render's status. */
int rp_group_scene_frame(rp_device_group *g, rp_group_scene *s, uint8_t *rgba,
                        rp_tile_stats *tiles, rp_group_report *rep);

#endif /* RP_GROUP_SCENE_H */
