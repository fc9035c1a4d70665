/* An app outside the tree: links, runs, and renders a tiny volume. */
#include <raypace.h>
#include <stdio.h>

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
