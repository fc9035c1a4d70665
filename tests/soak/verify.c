/* The soak's frame side: what the frame callback holds every frame to
 * (its id is the one expected next, its counters agree, a delivered image
 * is premultiplied RGBA of the viewport, a failed frame has none and says
 * why), the oracle check of a sample of frames against
 * rp_render_reference, the devices' drops by cause, and the resident
 * memory samples with their least-squares slope. */
#include <stdalign.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <malloc.h>
#include <string.h>
#include <unistd.h>

#include "soak.h"

void soak_bad(soak_verify *v, const char *fmt, ...) {
  va_list ap;
  if (v->bad++ == 0) {
    va_start(ap, fmt);
    vsnprintf(v->first_error, sizeof v->first_error, fmt, ap);
    va_end(ap);
    fprintf(stderr, "soak: %s\n", v->first_error);
  }
}

double soak_rss_kib(void) {
  unsigned long size = 0, resident = 0;
  FILE *f = fopen("/proc/self/statm", "r");
  if (f == NULL)
    return 0.0;
  if (fscanf(f, "%lu %lu", &size, &resident) != 2)
    resident = 0;
  fclose(f);
  return (double)resident * (double)sysconf(_SC_PAGESIZE) / 1024.0;
}

/* Under a sanitizer its allocator serves malloc and knows what is live;
 * without one, glibc's counts do. Weak: absent without a sanitizer. */
extern size_t __sanitizer_get_current_allocated_bytes(void)
    __attribute__((weak));

int soak_sanitized(void) {
  return __sanitizer_get_current_allocated_bytes != NULL;
}

double soak_malloc_kib(void) {
  if (__sanitizer_get_current_allocated_bytes != NULL)
    return (double)__sanitizer_get_current_allocated_bytes() / 1024.0;
  return (double)mallinfo2().uordblks / 1024.0;
}

/* The live bytes, counted in a header before each block (the free hook
 * is not told the size). */
static atomic_llong heap_live;
#define HEAP_HEADER alignof(max_align_t)

static void *heap_alloc(size_t size, void *user) {
  unsigned char *p = malloc(HEAP_HEADER + size);
  (void)user;
  if (p == NULL)
    return NULL;
  memcpy(p, &size, sizeof size);
  atomic_fetch_add(&heap_live, (long long)size);
  return p + HEAP_HEADER;
}

static void heap_free(void *ptr, void *user) {
  unsigned char *p = ptr;
  size_t size;
  (void)user;
  if (p == NULL)
    return;
  p -= HEAP_HEADER;
  memcpy(&size, p, sizeof size);
  atomic_fetch_sub(&heap_live, (long long)size);
  free(p);
}

rp_allocator soak_heap_allocator(void) {
  rp_allocator a = {heap_alloc, heap_free, NULL};
  return a;
}

long long soak_heap_bytes(void) { return atomic_load(&heap_live); }

double soak_heap_kib(void) { return (double)soak_heap_bytes() / 1024.0; }

double soak_slope(const soak_verify *v, const double *samples,
                  uint32_t from) {
  double n = 0, sx = 0, sy = 0, sxx = 0, sxy = 0, den;
  uint32_t i;
  for (i = from; i < v->rss_count; i++) {
    double x = (double)v->rss_frames[i], y = samples[i];
    n += 1;
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
  }
  den = n * sxx - sx * sx;
  return n >= 2 && den > 0.0 ? (n * sxy - sx * sy) / den : 0.0;
}

int soak_verify_init(soak_verify *v, soak_posters *p, uint64_t rss_every,
                     uint64_t frames) {
  rp_context_desc cd = {0};
  uint32_t i;
  memset(v, 0, sizeof *v);
  cd.allocator = soak_heap_allocator();
  if (uv_mutex_init(&v->lock) != 0 || uv_cond_init(&v->cv) != 0)
    return RP_EDEVICE;
  v->posters = p;
  v->rss_every = rss_every;
  v->rss_cap = (uint32_t)(frames / rss_every + 16);
  v->rss_frames = calloc(v->rss_cap, sizeof *v->rss_frames);
  v->rss_kib = calloc(v->rss_cap, sizeof *v->rss_kib);
  v->heap_kib = calloc(v->rss_cap, sizeof *v->heap_kib);
  v->malloc_kib = calloc(v->rss_cap, sizeof *v->malloc_kib);
  if (v->rss_frames == NULL || v->rss_kib == NULL || v->heap_kib == NULL ||
      v->malloc_kib == NULL ||
      rp_context_create(&cd, &v->ctx) != 0)
    return RP_ENOMEM;
  for (i = 0; i < SOAK_VOLUMES; i++) {
    rp_generate_desc g;
    soak_volume_desc(i, &g);
    if (rp_volume_generate(v->ctx, &g, &v->vols[i]) != 0)
      return RP_ENOMEM;
  }
  for (i = 0; i < SOAK_TF_COUNT; i++)
    if (rp_tf_create_preset(v->ctx, soak_tfs[i], &v->tfs[i]) != 0)
      return RP_EINVAL;
  return 0;
}

void soak_verify_free(soak_verify *v) {
  uint32_t i;
  for (i = 0; i < SOAK_VOLUMES; i++)
    rp_volume_destroy(v->vols[i]);
  for (i = 0; i < SOAK_TF_COUNT; i++)
    rp_tf_destroy(v->tfs[i]);
  rp_context_destroy(v->ctx);
  free(v->rss_frames);
  free(v->rss_kib);
  free(v->heap_kib);
  free(v->malloc_kib);
  uv_cond_destroy(&v->cv);
  uv_mutex_destroy(&v->lock);
}

void soak_verify_session(soak_verify *v, uint32_t devices) {
  uv_mutex_lock(&v->lock);
  v->devices = devices;
  v->next_id = 0;
  v->delivered = 0;
  v->ending = 0;
  v->check_pending = 0;
  memset(v->dropped, 0, sizeof v->dropped);
  memset(v->renders, 0, sizeof v->renders);
  uv_mutex_unlock(&v->lock);
}

/* ---- The oracle ------------------------------------------------------------ */

int soak_check_begin(soak_verify *v, rp_runtime *rt, rp_context *ctx,
                     soak_rng *rng) {
  uint32_t vi = soak_rng_range(rng, 0, SOAK_VOLUMES - 1);
  uint32_t ti = soak_rng_range(rng, 0, SOAK_TF_COUNT - 1);
  uint32_t effects = (uint32_t)(soak_rng_next(rng) >> 20) &
                     (RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP |
                      RP_EFFECT_PREINT);
  rp_runtime_counters c;
  rp_generate_desc g;
  rp_volume *vol = NULL;
  rp_camera cam = {0};
  int err;
  soak_posters_pause(v->posters);
  soak_volume_desc(vi, &g);
  if ((err = rp_volume_generate(ctx, &g, &vol)) != 0)
    return err;
  rp_camera_orbit(&cam, v->vols[vi], (float)(360.0 * soak_rng_unit(rng)),
                  (float)(120.0 * soak_rng_unit(rng) - 60.0), 2.2f);
  /* The runtime takes the volume; the oracle renders its own copy. Full
   * quality: the "none" controller at density 1. */
  if ((err = rp_runtime_set_volume(rt, vol)) != 0)
    rp_volume_destroy(vol);
  if (err == 0)
    err = rp_runtime_set_tf(rt, v->tfs[ti]);
  if (err == 0)
    err = rp_runtime_set_camera(rt, &cam);
  if (err == 0)
    err = rp_runtime_set_viewport(rt, SOAK_CHECK_W, SOAK_CHECK_H);
  if (err == 0)
    err = rp_runtime_set_effects(rt, effects);
  if (err == 0)
    err = rp_runtime_set_controller(rt, RP_CONTROL_NONE);
  if (err == 0)
    err = rp_runtime_set_density(rt, 1.0);
  rp_runtime_get_counters(rt, &c);
  uv_mutex_lock(&v->lock);
  if (err != 0) {
    soak_bad(v, "an oracle scene's event was refused: %s",
             rp_strerror(err));
  } else {
    v->check_pending = 1;
    v->check_events = c.events;
    v->check_vol = vi;
    v->check_tf = ti;
    v->check_cam = cam;
    v->check_effects = effects;
  }
  uv_mutex_unlock(&v->lock);
  return err;
}

/* The frame that includes the oracle scene against rp_render_reference.
 * Under v->lock. */
static void check_frame(soak_verify *v, const rp_frame *f) {
  const rp_frame_stats *st = f->stats;
  const rp_volume *vol = v->vols[v->check_vol];
  const rp_tf *tf = v->tfs[v->check_tf];
  rp_histograms *hist = NULL;
  rp_occupancy *occ = NULL;
  rp_render_desc rd = {0};
  uint8_t want[SOAK_CHECK_W * SOAK_CHECK_H * 4];
  uint32_t i, diff = 0;
  if (st->status != 0 || st->effects != v->check_effects ||
      st->scale != 1.0f) {
    /* Every device lost, or a frame the oracle cannot render alike. */
    v->checks_skipped++;
    return;
  }
  if (f->width != SOAK_CHECK_W || f->height != SOAK_CHECK_H) {
    soak_bad(v, "frame %llu: %ux%u, the oracle scene asked for %ux%u",
             (unsigned long long)st->frame, f->width, f->height,
             SOAK_CHECK_W, SOAK_CHECK_H);
    return;
  }
  rd.width = SOAK_CHECK_W;
  rd.height = SOAK_CHECK_H;
  rd.step = st->step;
  rd.effects = st->effects;
  rd.jitter = st->jitter_seed != 0 ? RP_JITTER_ON : RP_JITTER_OFF;
  rd.jitter_seed = st->jitter_seed;
  if (rp_histograms_build(v->ctx, vol, &hist) != 0 ||
      rp_occupancy_build(v->ctx, hist, tf, &occ) != 0 ||
      rp_render_reference(v->ctx, vol, tf, occ, NULL, &v->check_cam, &rd,
                          want, NULL) != 0) {
    soak_bad(v, "the oracle failed: %s", rp_last_error(v->ctx));
  } else {
    for (i = 0; i < sizeof want; i++)
      diff += want[i] != f->rgba[i];
    v->checks++;
    if (diff != 0) {
      v->check_mismatch++;
      soak_bad(v, "frame %llu: %u of %u bytes differ from "
               "rp_render_reference (volume %u, TF %s, effects 0x%x, "
               "step %g, %u device(s))", (unsigned long long)st->frame,
               diff, (unsigned)sizeof want, v->check_vol,
               soak_tfs[v->check_tf], st->effects, (double)st->step,
               v->devices);
    }
  }
  rp_occupancy_destroy(occ);
  rp_histograms_destroy(hist);
}

/* ---- Every frame ------------------------------------------------------------ */

/* A delivered image: present exactly when the frame succeeded, of the
 * viewport a poster or the oracle asked for, premultiplied. */
static void check_image(soak_verify *v, const rp_frame *f) {
  const rp_frame_stats *st = f->stats;
  uint64_t i, n;
  if (st->status != 0) {
    v->failed_frames++;
    if (f->rgba != NULL || st->error[0] == '\0')
      soak_bad(v, "frame %llu failed (%s) %s", (unsigned long long)st->frame,
               rp_strerror(st->status),
               f->rgba != NULL ? "but has an image" : "without a message");
    return;
  }
  if (f->rgba == NULL || f->width < 8 || f->width > 40 || f->height < 8 ||
      f->height > 40) {
    soak_bad(v, "frame %llu: image %p of %ux%u", (unsigned long long)st->frame,
             (const void *)f->rgba, f->width, f->height);
    return;
  }
  n = (uint64_t)f->width * f->height;
  for (i = 0; i < n; i++) {
    const uint8_t *p = f->rgba + 4 * i;
    if (p[0] > p[3] || p[1] > p[3] || p[2] > p[3]) {
      soak_bad(v, "frame %llu: pixel %llu (%u %u %u %u) is not "
               "premultiplied", (unsigned long long)st->frame,
               (unsigned long long)i, p[0], p[1], p[2], p[3]);
      return;
    }
  }
}

/* Devices dropped this frame, by cause: the injected failures say so in
 * their message (runtime/faults.c); a device lost in an AO job is said
 * to be in the next frame's report ("lost in an ambient-occlusion job":
 * the AO report has a status per device but no message). A device
 * dropped with neither status nor message is a problem. Renders are
 * counted per device to tell which armed stalls were reached. */
static void count_devices(soak_verify *v, const rp_frame_stats *st) {
  uint32_t i;
  if (st->device_count != v->devices)
    soak_bad(v, "frame %llu: %u devices, the session opened %u",
             (unsigned long long)st->frame, st->device_count, v->devices);
  for (i = 0; i < st->device_count && i < RP_RUNTIME_MAX_DEVICES; i++) {
    const rp_device_frame *d = &st->devices[i];
    if (!d->dropped && d->busy_ms > 0.0)
      v->renders[i] += st->passes;
    if (!d->dropped || v->dropped[i])
      continue;
    v->dropped[i] = 1;
    if (strstr(d->error, "injected at render") != NULL)
      v->fail_render++;
    else if (strstr(d->error, "injected at AO") != NULL ||
             strstr(d->error, "ambient-occlusion job") != NULL)
      v->fail_ao++;
    else if (d->status == 0 && d->error[0] == '\0' &&
             d->state != RP_DEVICE_LATE) {
      v->drops_unexplained++;
      soak_bad(v, "frame %llu: device %u dropped with no status and no "
               "message (state %d, %u failures)",
               (unsigned long long)st->frame, i, (int)d->state,
               d->failures);
    }
    else
      v->drops_other++;
  }
}

void soak_on_frame(rp_runtime *rt, const rp_frame *f, void *user) {
  soak_verify *v = user;
  const rp_frame_stats *st = f->stats;
  uv_mutex_lock(&v->lock);
  if (st->frame != v->next_id)
    soak_bad(v, "frame %llu delivered where frame %llu was due: %s",
             (unsigned long long)st->frame, (unsigned long long)v->next_id,
             st->frame > v->next_id ? "frames missing" : "delivered twice");
  if (st->counters.frames != st->frame + 1)
    soak_bad(v, "frame %llu: counters.frames %llu",
             (unsigned long long)st->frame,
             (unsigned long long)st->counters.frames);
  v->next_id = st->frame + 1;
  v->last_status = st->status;
  v->delivered++;
  v->frames++;
  v->two_pass += st->passes > 1;
  check_image(v, f);
  count_devices(v, st);
  if (v->check_pending && st->events >= v->check_events) {
    v->check_pending = 0;
    check_frame(v, f);
    if (!v->ending)
      soak_posters_resume(v->posters, rt);
  }
  if (v->frames % v->rss_every == 0 && v->rss_count < v->rss_cap) {
    v->rss_frames[v->rss_count] = v->frames;
    v->heap_kib[v->rss_count] = soak_heap_kib();
    v->malloc_kib[v->rss_count] = soak_malloc_kib();
    v->rss_kib[v->rss_count++] = soak_rss_kib();
  }
  uv_cond_broadcast(&v->cv);
  uv_mutex_unlock(&v->lock);
}
