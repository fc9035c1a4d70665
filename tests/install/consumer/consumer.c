/* An app outside the tree: links, runs, and renders a tiny volume. It
 * includes every product header and nothing else (README, "Headers"):
 * what an app embedding the runtime sets must be declared there. */
#include <raypace.h>
#include <raypace_ao.h>
#include <raypace_backend.h>
#include <raypace_mpi.h>
#include <raypace_runtime.h>
#include <stdio.h>
#include <string.h>

#if defined(RAYPACE_PACE_H) || defined(RAYPACE_BALANCE_H) ||                \
    defined(RAYPACE_GROUP_H) || defined(RAYPACE_SEQUENCE_H)
#error "a product header includes a lab header"
#endif

/* The runtime's settings, named as an app's options would name them. */
static int settings(void) {
  rp_runtime_desc d = {0};
  rp_controller_kind kind;
  rp_space space;
  d.controller = RP_CONTROL_PREDICTED;
  d.space.space = RP_SPACE_HYBRID;
  d.damping = RP_DAMP_EVEN;
  d.model.noise_ratio = 0.05;
  d.ao.directions = 8;
  d.ao_schedule.scheme = RP_AO_STATIC;
  if (rp_controller_from_name(rp_controller_name(d.controller), &kind) != 0 ||
      kind != RP_CONTROL_PREDICTED ||
      strcmp(rp_space_name(d.space.space), "hybrid") != 0 ||
      rp_space_from_name("ray", &space) != 0 || space != RP_SPACE_RAY)
    return -101;
  return 0;
}

int main(void) {
  rp_context *ctx = NULL;
  rp_volume *vol = NULL;
  rp_tf *tf = NULL;
  rp_generate_desc g = {0};
  rp_camera cam = {0};
  rp_render_desc rd = {0};
  uint8_t px[16 * 16 * 4];
  int err;
  if (rp_version() != RP_VERSION_HEX)
    return 1;
  g.kind = RP_GEN_PHANTOM;
  g.dims[0] = g.dims[1] = g.dims[2] = 16;
  rd.width = rd.height = 16;
  err = settings();
  if (err == 0)
    err = rp_context_create(NULL, &ctx);
  if (err == 0)
    err = rp_volume_generate(ctx, &g, &vol);
  if (err == 0)
    err = rp_tf_create_preset(ctx, "opaque", &tf);
  if (err == 0) {
    rp_camera_orbit(&cam, vol, 0, 0, 3);
    err = rp_render_reference(ctx, vol, tf, NULL, NULL, &cam, &rd, px, NULL);
  }
  /* The opaque TF makes the centre pixel fully opaque. */
  if (err == 0 && px[(8 * 16 + 8) * 4 + 3] != 255)
    err = -100;
  printf("consumer: %s\n", err == 0 ? "ok" : rp_strerror(err));
  rp_tf_destroy(tf);
  rp_volume_destroy(vol);
  rp_context_destroy(ctx);
  return err == 0 ? 0 : 1;
}
