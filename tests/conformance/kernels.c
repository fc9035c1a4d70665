/* Kernels built ahead (rp_backend_ops.prepare) and the kernel-variant
 * cache every backend keeps (backends/variant_cache.h), driven through
 * the backend's ops as the front end drives them, so that what was built
 * can be counted. The reference renders in the front end: it has no ops
 * to open and builds nothing, which these tests say before they skip
 * (prepare_no_volume still holds its front end to the contract). */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "conformance.h"

#define SEK (RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP)

/* Opens the backend bare, or says why not and skips: it has no ops to
 * open, or builds no kernels (no prepare, no variant cache). */
static void open_or_skip(bare *b) {
  rp_variant_stats st;
  if (bare_open(ctx, b) == RP_EUNSUPPORTED) {
    print_message("%s: %s: skipped\n", backend_name(), rp_last_error(ctx));
    skip();
  }
  if (b->ops->prepare == NULL || !variant_stats(b, &st)) {
    print_message("%s builds no kernel variants: skipped\n",
                  backend_name());
    bare_close(b);
    skip();
  }
}

static rp_variant_stats stats_of(const bare *b) {
  rp_variant_stats st;
  if (!variant_stats(b, &st))
    fail_msg("%s keeps no kernel-variant cache to read", backend_name());
  return st;
}

/* A frame of `l` on `b`: rendered (depth pass, raycast), and held to
 * the reference by the tolerance (counting: its fetches too). `ao`, when
 * not NULL, is the AO volume the device holds. Returns the image
 * (malloc) when `keep`, else NULL. */
static uint8_t *bare_check(const bare *b, const lit_scene *l,
                           const rp_ao *ao, int cam_kind, uint32_t size,
                           float step, uint32_t effects, int count,
                           int keep) {
  rp_camera cam = camera(l->s.vol, cam_kind);
  rp_render_desc d = {0};
  rp__raygen rg;
  rp_frame_params p;
  rp_region all;
  rp_volume ao_view;
  uint32_t tx, ty;
  uint8_t *got, *want;
  rp_tile_stats *gt, *wt;
  uint64_t *gf, *wf, total = 0, off = 0;
  tally t = {0};
  char what[128];
  d.width = d.height = size, d.step = step, d.effects = effects;
  bare_frame(&l->s, l->tf, l->occ, &cam, &d, &rg, &p);
  rp_tile_grid(p.width, p.height, &tx, &ty);
  got = malloc((size_t)p.width * p.height * 4);
  want = malloc((size_t)p.width * p.height * 4);
  gt = malloc((size_t)tx * ty * sizeof *gt);
  wt = malloc((size_t)tx * ty * sizeof *wt);
  gf = malloc((size_t)tx * ty * sizeof *gf);
  wf = malloc((size_t)tx * ty * sizeof *wf);
  assert_true(got && want && gt && wt && gf && wf);
  bare_render(b, &p, got, gt, count ? gf : NULL);
  all.x0 = all.y0 = 0, all.x1 = p.width, all.y1 = p.height;
  if (ao != NULL)
    rp__ao_view(ao, &ao_view);
  rp__reference_render(l->s.vol, l->tf,
                       (effects & RP_EFFECT_SKIP) ? l->occ->grid : NULL,
                       l->s.h->blocks, ao != NULL ? &ao_view : NULL, &rg, &d,
                       &all, want, wt, wf);
  snprintf(what, sizeof what, "%s effects 0x%x step %g%s", l->s.name,
           effects, (double)step, count ? " counting" : "");
  compare(&t, what, got, want, gt, wt, p.width, p.height, p.step);
  finish(&t, what, 1);
  if (count)
    rp_test_check_fetches(what, gt, gf, wt, wf, (size_t)tx * ty,
                          effects, &total, &off);
  free(want), free(gt), free(wt), free(gf), free(wf);
  if (keep)
    return got;
  free(got);
  return NULL;
}

/* ---- prepare ------------------------------------------------------------- */

/* Before any volume prepare is RP_ESTATE, said in the caller's context
 * and not in the device's: through the ops and through
 * rp_device_prepare, which passes the call on, context and all; once a
 * volume is there, it succeeds. A device that builds nothing ahead (the
 * reference) succeeds at once, and says so. */
void prepare_no_volume(void **state) {
  rp_context *dctx = rp_test_context(), *ctx2 = rp_test_context();
  rp_context *ctx3 = rp_test_context();
  rp_device_desc dd = {0};
  rp_device *d = NULL;
  rp_generate_desc g = {RP_GEN_PHANTOM, {32, 32, 32}, RP_U8, 3};
  rp_volume *vol = NULL;
  rp_variant_stats st;
  char before[512];
  bare b;
  (void)state;
  if (bare_open(dctx, &b) != 0) {
    print_message("%s: no ops to open bare: %s\n", backend_name(),
                  rp_last_error(dctx));
  } else if (b.ops->prepare == NULL || !variant_stats(&b, &st)) {
    print_message("%s: no prepare op\n", backend_name());
    bare_close(&b);
  } else {
    snprintf(before, sizeof before, "%s", rp_last_error(dctx));
    assert_int_equal(b.ops->prepare(b.impl, ctx2, RP_EFFECT_SKIP),
                     RP_ESTATE);
    assert_non_null(strstr(rp_last_error(ctx2), "volume"));
    assert_string_equal(rp_last_error(dctx), before);
    st = stats_of(&b);
    assert_int_equal(st.builds, 0);
    assert_int_equal(st.count, 0);
    bare_close(&b);
  }
  dd.backend = backend_name();
  assert_int_equal(rp_device_create(dctx, &dd, &d), 0);
  snprintf(before, sizeof before, "%s", rp_last_error(dctx));
  if (rp__device_builds_ahead(d)) {
    assert_int_equal(rp_device_prepare(d, ctx3, RP_EFFECT_SKIP), RP_ESTATE);
    assert_non_null(strstr(rp_last_error(ctx3), "volume"));
    assert_string_equal(rp_last_error(dctx), before);
  } else {
    print_message("%s: builds no kernels ahead: prepare succeeds at once\n",
                  backend_name());
    assert_int_equal(rp_device_prepare(d, ctx3, RP_EFFECT_SKIP), 0);
  }
  assert_int_equal(rp_volume_generate(dctx, &g, &vol), 0);
  assert_int_equal(rp_device_set_volume(d, vol), 0);
  assert_int_equal(rp_device_prepare(d, ctx3, RP_EFFECT_SKIP), 0);
  rp_volume_destroy(vol);
  rp_device_destroy(d);
  rp_context_destroy(dctx);
  rp_context_destroy(ctx2);
  rp_context_destroy(ctx3);
}

/* A 32^3 phantom under a ramp of reference step 1: step 1 needs no
 * opacity correction, 0.6 does (a kernel may be specialised for it). */
static lit_scene prepare_scene(void) {
  return lit(make_scene("phantom 32^3", RP_GEN_PHANTOM, 32, 32, 32, RP_U8),
             rp_test_ramp_tf(ctx, 1.0f));
}

/* prepare, with errors on a context of its own, builds what the frames
 * of its effect set use, at either step kind; a second prepare finds
 * them; the frames then build nothing (each finds its two kernels, the
 * depth pass's and the raycast's) and render what a device without
 * prepare renders, which did need kernels of its own for the first
 * (for the second too where the step kind is a variant of its own:
 * test_vk_backend.c holds Vulkan to that). */
void prepare_builds_ahead(void **state) {
  static const float steps[2] = {1.0f, 0.6f};
  static const int cams[2] = {CAM_OUTSIDE, CAM_INSIDE2};
  rp_context *ctx2;
  bare prep, plain;
  lit_scene l;
  rp_variant_stats st, p0, q0;
  int i;
  (void)state;
  open_or_skip(&prep);
  open_or_skip(&plain);
  ctx2 = rp_test_context();
  l = prepare_scene();
  bare_upload(&prep, &l.s, l.tf, l.occ);
  bare_upload(&plain, &l.s, l.tf, l.occ);
  assert_int_equal(prep.ops->prepare(prep.impl, ctx2, SEK), 0);
  p0 = stats_of(&prep);
  assert_true(p0.builds > 0 && p0.count == p0.builds);
  assert_int_equal(prep.ops->prepare(prep.impl, ctx2, SEK), 0);
  st = stats_of(&prep);
  assert_int_equal(st.builds, p0.builds);
  for (i = 0; i < 2; i++) {
    uint8_t *a, *b;
    p0 = stats_of(&prep);
    q0 = stats_of(&plain);
    a = bare_check(&prep, &l, NULL, cams[i], 64, steps[i], SEK, 0, 1);
    b = bare_check(&plain, &l, NULL, cams[i], 64, steps[i], SEK, 0, 1);
    st = stats_of(&prep);
    assert_int_equal(st.builds, p0.builds);
    assert_int_equal(st.hits, p0.hits + 2);
    st = stats_of(&plain);
    assert_true(i == 0 ? st.builds > q0.builds : st.builds >= q0.builds);
    assert_memory_equal(a, b, 64 * 64 * 4);
    free(a);
    free(b);
  }
  bare_close(&prep);
  bare_close(&plain);
  rp_context_destroy(ctx2);
  unlit(&l);
}

/* With AO, prepare also builds compute_ao's kernel: the AO volume's
 * computation and the frames that read it, at either step kind, build
 * nothing. */
void prepare_ao(void **state) {
  static const float steps[2] = {1.0f, 0.6f};
  static const int cams[2] = {CAM_OUTSIDE, CAM_INSIDE2};
  rp_context *ctx2;
  lit_scene l;
  const uint32_t lo[3] = {0, 0, 0};
  rp_ao_desc ad = {0};
  rp_ao_plan *plan = NULL;
  rp_ao_job job;
  rp_variant_stats built, st;
  uint8_t *ao;
  int n = 0, i;
  bare b;
  (void)state;
  open_or_skip(&b);
  ctx2 = rp_test_context();
  l = prepare_scene();
  ao = malloc(l.s.vol->voxel_count);
  assert_non_null(ao);
  bare_upload(&b, &l.s, l.tf, l.occ);
  assert_int_equal(b.ops->prepare(b.impl, ctx2, SEK | RP_EFFECT_AO), 0);
  built = stats_of(&b);
  assert_int_equal(rp_ao_plan_create(ctx, l.s.vol, l.tf, &ad, &plan), 0);
  rp_tf_lut(l.tf, &n);
  rp__ao_job(plan, lo, l.s.vol->dims, rp_tf_reference_step(l.tf),
             l.s.vol->min, l.s.vol->max, (uint32_t)n, &job);
  assert_int_equal(b.ops->compute_ao(b.impl, &job, ao), 0);
  assert_int_equal(b.ops->upload_ao(b.impl, ao), 0);
  for (i = 0; i < 2; i++) {
    rp_camera cam = camera(l.s.vol, cams[i]);
    rp_render_desc d = {0};
    rp__raygen rg;
    rp_frame_params p;
    uint8_t img[64 * 64 * 4];
    d.width = d.height = 64, d.step = steps[i];
    d.effects = SEK | RP_EFFECT_AO;
    bare_frame(&l.s, l.tf, l.occ, &cam, &d, &rg, &p);
    bare_render(&b, &p, img, NULL, NULL);
  }
  st = stats_of(&b);
  assert_int_equal(st.builds, built.builds);
  rp_ao_plan_destroy(plan);
  free(ao);
  bare_close(&b);
  rp_context_destroy(ctx2);
  unlit(&l);
}

typedef struct prepare_job {
  const bare *b;
  rp_context *ctx;
  uint32_t effects;
  int rc;
  atomic_int done;
} prepare_job;

static void *prepare_main(void *arg) {
  prepare_job *j = arg;
  j->rc = j->b->ops->prepare(j->b->impl, j->ctx, j->effects);
  atomic_store(&j->done, 1);
  return NULL;
}

/* prepare on a second thread while this one renders another effect set
 * on the same device, at changing steps and cameras (both build into
 * one table): the prepared set's frame then builds nothing, finds its
 * two kernels, and gives a fresh device's image and tiles bit for bit. */
void prepare_concurrent(void **state) {
  static const int cams[3] = {CAM_OUTSIDE, CAM_INSIDE2, CAM_AXIS};
  rp_context *ctx2;
  lit_scene l;
  rp_camera cam;
  rp_render_desc d = {0};
  rp__raygen rg;
  rp_frame_params p;
  rp_variant_stats before, st;
  uint8_t a[64 * 64 * 4], c[64 * 64 * 4];
  rp_tile_stats ta[8 * 8], tc[8 * 8];
  prepare_job job;
  pthread_t thread;
  bare b, fresh;
  int renders;
  (void)state;
  open_or_skip(&b);
  ctx2 = rp_test_context();
  l = prepare_scene();
  cam = camera(l.s.vol, CAM_OUTSIDE);
  bare_upload(&b, &l.s, l.tf, l.occ);
  job.b = &b, job.ctx = ctx2, job.effects = SEK, job.rc = -1;
  atomic_init(&job.done, 0);
  assert_int_equal(pthread_create(&thread, NULL, prepare_main, &job), 0);
  /* A few frames at least, and on for as long as prepare builds; each
   * camera change runs a depth pass too. */
  for (renders = 0;
       renders < 4 || (!atomic_load(&job.done) && renders < 200);
       renders++) {
    rp_camera other = camera(l.s.vol, cams[renders % 3]);
    rp_render_desc od = {0};
    od.width = od.height = 64, od.effects = RP_EFFECT_ERT;
    od.step = renders % 2 ? 0.6f : 1.0f;
    bare_frame(&l.s, l.tf, l.occ, &other, &od, &rg, &p);
    bare_render(&b, &p, a, NULL, NULL);
  }
  assert_int_equal(pthread_join(thread, NULL), 0);
  assert_int_equal(job.rc, 0);
  d.width = d.height = 64, d.step = 0.6f, d.effects = SEK;
  bare_frame(&l.s, l.tf, l.occ, &cam, &d, &rg, &p);
  before = stats_of(&b);
  bare_render(&b, &p, a, ta, NULL);
  st = stats_of(&b);
  assert_int_equal(st.builds, before.builds);
  assert_int_equal(st.hits, before.hits + 2);
  open_or_skip(&fresh);
  bare_upload(&fresh, &l.s, l.tf, l.occ);
  bare_render(&fresh, &p, c, tc, NULL);
  assert_memory_equal(a, c, sizeof a);
  assert_memory_equal(ta, tc, sizeof ta);
  bare_close(&fresh);
  bare_close(&b);
  rp_context_destroy(ctx2);
  unlit(&l);
}

/* ---- the variant cache --------------------------------------------------- */

/* The table's figures add up, and it never holds more than the bound. */
static rp_variant_stats check_table(const bare *b) {
  rp_variant_stats st = stats_of(b);
  assert_true(st.count <= RP_VARIANT_CACHE_SIZE);
  assert_int_equal(st.count, st.builds - st.dropped - st.evictions);
  return st;
}

/* One variant per key: a frame builds its depth pass's and its
 * raycast's; the same frame again builds nothing and finds both; another
 * effect set, the counting variant and AO each are another raycast (the
 * depth pass is keyed by skipping alone). */
static void one_variant_per_key(const lit_scene *l, const rp_ao *ao) {
  rp_variant_stats st;
  bare b;
  open_or_skip(&b);
  st = check_table(&b);
  assert_int_equal(st.builds, 0);
  bare_upload(&b, &l->s, l->tf, l->occ);
  bare_check(&b, l, NULL, CAM_OUTSIDE, 32, 1.0f, RP_EFFECT_ERT, 0, 0);
  st = check_table(&b);
  assert_int_equal(st.builds, 2);
  assert_int_equal(st.hits, 0);
  bare_check(&b, l, NULL, CAM_OUTSIDE, 32, 1.0f, RP_EFFECT_ERT, 0, 0);
  st = check_table(&b);
  assert_int_equal(st.builds, 2);
  assert_int_equal(st.hits, 2);
  bare_check(&b, l, NULL, CAM_OUTSIDE, 32, 1.0f, RP_EFFECT_SKIP, 0, 0);
  assert_int_equal(check_table(&b).builds, 4);
  bare_check(&b, l, NULL, CAM_OUTSIDE, 32, 1.0f, RP_EFFECT_ERT, 1, 0);
  assert_int_equal(check_table(&b).builds, 5);
  assert_int_equal(b.ops->upload_ao(b.impl, rp_ao_data(ao, NULL)), 0);
  bare_check(&b, l, ao, CAM_OUTSIDE, 32, 1.0f,
             RP_EFFECT_ERT | RP_EFFECT_AO, 0, 0);
  st = check_table(&b);
  assert_int_equal(st.builds, 6);
  assert_int_equal(st.count, 6);
  assert_int_equal(st.dropped + st.evictions, 0);
  bare_close(&b);
}

/* The effect sets of the variant sweep: the matrices' (images.c), so
 * that a driver's disk cache already holds what they compile to. */
static const uint32_t sweep_sets[] = {
    0, RP_EFFECT_SHADING, RP_EFFECT_ERT, RP_EFFECT_SKIP, SEK,
    SEK | RP_EFFECT_AO};
#define SWEEP_SETS (sizeof sweep_sets / sizeof sweep_sets[0])

/* Scene `l` (with its AO volume) uploaded to `b`. */
static void upload_lit(const bare *b, const lit_scene *l, const rp_ao *ao) {
  bare_upload(b, &l->s, l->tf, l->occ);
  assert_int_equal(b->ops->upload_ao(b->impl, rp_ao_data(ao, NULL)), 0);
}

/* More variants than the bound: three voxel types, six effect sets,
 * counting and not, each frame right, the table never over the bound;
 * the 36 raycasts and 2 depth passes are all built once, and the 6 past
 * the bound each replaced the least recently used entry (the depth
 * passes, used by every frame, stay). So the latest frames' variants are
 * still there, and the first frame's was replaced: it builds again. A
 * prepare on the full table builds but keeps nothing (it never evicts)
 * and succeeds; the frame then builds for itself, replacing an entry. */
void variant_cache(void **state) {
  rp_context *ctx2;
  lit_scene ls[3];
  rp_ao *aos[3];
  rp_variant_stats st, before;
  const rp_ao_desc small = {6, 4, 4.0f, 1.0f, 0};
  uint32_t built = 0;
  size_t e;
  int v, c;
  bare b;
  (void)state;
  /* Skipped before anything is made, when there is nothing to count. */
  open_or_skip(&b);
  bare_close(&b);
  ctx2 = rp_test_context();
  ls[0] = lit(make_scene("phantom 32^3 u8", RP_GEN_PHANTOM, 32, 32, 32,
                         RP_U8),
              rp_test_ramp_tf(ctx, 1.0f));
  ls[1] = lit(make_scene("Marschner-Lobb 24^3 u16", RP_GEN_MARSCHNER_LOBB,
                         24, 24, 24, RP_U16),
              rp_test_ramp_tf(ctx, 1.0f));
  ls[2] = lit(scene_of("float blob", rp_test_float_blob(ctx)),
              rp_test_ramp_tf(ctx, 1.0f));
  for (v = 0; v < 3; v++)
    assert_int_equal(rp_ao_compute_reference(ctx, ls[v].s.vol, ls[v].tf,
                                             &small, NULL, NULL, &aos[v]),
                     0);
  one_variant_per_key(&ls[0], aos[0]);
  open_or_skip(&b);
  for (v = 0; v < 3; v++) {
    upload_lit(&b, &ls[v], aos[v]);
    for (e = 0; e < SWEEP_SETS; e++)
      for (c = 0; c < 2; c++) {
        bare_check(&b, &ls[v], aos[v], CAM_OUTSIDE, 32, 1.0f,
                   sweep_sets[e], c, 0);
        check_table(&b);
      }
  }
  st = check_table(&b);
  print_message("%s: %u variants built, %u held (bound %d), %u evicted\n",
                backend_name(), st.builds, st.count, RP_VARIANT_CACHE_SIZE,
                st.evictions);
  assert_int_equal(st.builds, 2 + 3 * SWEEP_SETS * 2);
  assert_int_equal(st.count, RP_VARIANT_CACHE_SIZE);
  assert_int_equal(st.evictions, st.builds - RP_VARIANT_CACHE_SIZE);
  assert_int_equal(st.dropped, 0);
  /* The last four frames, latest first: all there. */
  for (c = 0; c < 4; c++)
    bare_check(&b, &ls[2], aos[2], CAM_OUTSIDE, 32, 1.0f,
               sweep_sets[SWEEP_SETS - 1 - (size_t)c / 2], 1 - c % 2, 0);
  assert_int_equal(check_table(&b).builds, st.builds);
  /* The first: replaced, so built again, replacing another. */
  upload_lit(&b, &ls[0], aos[0]);
  bare_check(&b, &ls[0], aos[0], CAM_OUTSIDE, 32, 1.0f, sweep_sets[0], 0,
             0);
  before = check_table(&b);
  assert_int_equal(before.builds, st.builds + 1);
  assert_int_equal(before.evictions, st.evictions + 1);
  /* The u8 volume's skipping raycast was replaced by then (the seventh
   * raycast built): prepare builds it, finds no free entry, drops it. */
  assert_int_equal(b.ops->prepare(b.impl, ctx2, RP_EFFECT_SKIP), 0);
  st = check_table(&b);
  built = st.builds - before.builds;
  assert_true(built >= 1);
  assert_int_equal(st.dropped - before.dropped, built);
  assert_int_equal(st.count, RP_VARIANT_CACHE_SIZE);
  assert_int_equal(st.evictions, before.evictions);
  bare_check(&b, &ls[0], aos[0], CAM_OUTSIDE, 32, 1.0f, RP_EFFECT_SKIP, 0,
             0);
  before = st;
  st = check_table(&b);
  assert_int_equal(st.builds, before.builds + 1);
  assert_int_equal(st.evictions, before.evictions + 1);
  bare_close(&b);
  for (v = 0; v < 3; v++) {
    rp_ao_destroy(aos[v]);
    unlit(&ls[v]);
  }
  rp_context_destroy(ctx2);
}
