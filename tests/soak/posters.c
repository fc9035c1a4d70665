/* The soak's event threads: each posts a random stream of events (camera,
 * TF, viewport, target, effects, controller, density, now and then a new
 * volume) to the runtime, at a few hundred per second, as a UI thread, a
 * network thread and a tracker would at once. A pause is a handshake, so
 * that the driver knows no thread is inside a runtime call when it posts
 * an oracle scene or destroys the runtime (the runtime's memory is gone
 * after destroy: rp_runtime_set_* must not be running then). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "soak.h"

typedef struct poster {
  soak_posters *p;
  uv_thread_t thread;
  uint32_t index;
  soak_rng rng;
  rp_context *ctx; /* its own: a context is one thread's */
  rp_tf *tfs[SOAK_TF_COUNT];
  rp_volume *orbit; /* volume 0: what cameras orbit */
  soak_post_counts n;
} poster;

struct soak_posters {
  uv_mutex_t lock;
  uv_cond_t cv;
  rp_runtime *rt;       /* NULL while paused */
  uint32_t count, parked, stop, failed;
  rp_space_desc space;
  poster threads[SOAK_MAX_THREADS];
};

/* ---- The PRNG and the shared scene choices -------------------------------- */

void soak_rng_seed(soak_rng *r, uint64_t seed) {
  r->s = seed * 0x9e3779b97f4a7c15ull + 0x2545f4914f6cdd1dull;
  if (r->s == 0)
    r->s = 1;
}

uint64_t soak_rng_next(soak_rng *r) {
  r->s ^= r->s >> 12;
  r->s ^= r->s << 25;
  r->s ^= r->s >> 27;
  return r->s * 0x2545f4914f6cdd1dull;
}

double soak_rng_unit(soak_rng *r) {
  return (double)(soak_rng_next(r) >> 11) * (1.0 / 9007199254740992.0);
}

uint32_t soak_rng_range(soak_rng *r, uint32_t lo, uint32_t hi) {
  return lo + (uint32_t)(soak_rng_next(r) % ((uint64_t)hi - lo + 1));
}

const char *const soak_tfs[SOAK_TF_COUNT] = {"minmax-bone", "minmax-soft",
                                             "opaque", "nearly-transparent"};

/* Small volumes, so that frames are cheap; sizes differ so that a volume
 * change resizes what the runtime derives from it. */
void soak_volume_desc(uint32_t i, rp_generate_desc *g) {
  static const rp_generator kinds[SOAK_VOLUMES] = {
      RP_GEN_PHANTOM, RP_GEN_MARSCHNER_LOBB, RP_GEN_PHANTOM, RP_GEN_NOISE};
  static const uint32_t dims[SOAK_VOLUMES][3] = {
      {24, 24, 24}, {20, 20, 20}, {28, 20, 16}, {16, 16, 16}};
  memset(g, 0, sizeof *g);
  g->kind = kinds[i % SOAK_VOLUMES];
  memcpy(g->dims, dims[i % SOAK_VOLUMES], sizeof g->dims);
  g->seed = 7 + i;
}

/* ---- One event ------------------------------------------------------------ */

/* Effects drawn at random; AO (computed over several frames, freed when
 * turned off) in one draw in eight. */
static uint32_t random_effects(soak_rng *r) {
  uint32_t e = (uint32_t)(soak_rng_next(r) >> 20) &
               (RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP |
                RP_EFFECT_PREINT);
  if (soak_rng_range(r, 0, 7) == 0)
    e |= RP_EFFECT_AO;
  return e;
}

/* A new volume to hand over; NULL when it could not be made. */
static rp_volume *new_volume(poster *t) {
  rp_generate_desc g;
  rp_volume *vol = NULL;
  soak_volume_desc(soak_rng_range(&t->rng, 0, SOAK_VOLUMES - 1), &g);
  if (rp_volume_generate(t->ctx, &g, &vol) != 0)
    return NULL;
  return vol;
}

/* Posts one event drawn at random; returns the runtime's answer. Every
 * value is one the runtime must take: a refusal is a failure of the
 * soak. */
static int post_one(poster *t, rp_runtime *rt, const rp_space_desc *space) {
  soak_rng *r = &t->rng;
  uint32_t k = soak_rng_range(r, 0, 99);
  if (k < 35) { /* the camera, most often: a user orbiting */
    rp_camera cam = {0};
    cam.fov_y_deg = 30.0f + 30.0f * (float)soak_rng_unit(r);
    if (soak_rng_range(r, 0, 9) == 0)
      cam.projection = RP_ORTHOGRAPHIC;
    /* Around volume 0, the others' boxes are about as large. */
    rp_camera_orbit(&cam, t->orbit, (float)(360.0 * soak_rng_unit(r)),
                    (float)(170.0 * soak_rng_unit(r) - 85.0),
                    1.5f + 2.0f * (float)soak_rng_unit(r));
    t->n.camera++;
    return rp_runtime_set_camera(rt, &cam);
  }
  if (k < 50) {
    t->n.tf++;
    return rp_runtime_set_tf(rt, t->tfs[soak_rng_range(r, 0,
                                                      SOAK_TF_COUNT - 1)]);
  }
  if (k < 60) {
    t->n.viewport++;
    return rp_runtime_set_viewport(rt, soak_rng_range(r, 8, 40),
                                   soak_rng_range(r, 8, 40));
  }
  if (k < 70) {
    t->n.target++;
    return rp_runtime_set_target(rt, 0.5 + 7.5 * soak_rng_unit(r));
  }
  if (k < 80) {
    t->n.effects++;
    return rp_runtime_set_effects(rt, random_effects(r));
  }
  if (k < 87) {
    t->n.controller++;
    return rp_runtime_set_controller(
        rt, (rp_controller_kind)soak_rng_range(r, 0, RP_CONTROL_COUNT - 1));
  }
  if (k < 97) {
    double lo = rp_space_min_density(space), hi = rp_space_max_density(space);
    t->n.density++;
    return rp_runtime_set_density(rt, lo + (hi - lo) * soak_rng_unit(r));
  }
  {
    rp_volume *vol = new_volume(t);
    int err;
    if (vol == NULL)
      return RP_ENOMEM;
    t->n.volume++;
    if ((err = rp_runtime_set_volume(rt, vol)) != 0)
      rp_volume_destroy(vol); /* refused: still ours */
    return err;
  }
}

/* ---- The threads ---------------------------------------------------------- */

static void sleep_us(uint32_t us) {
  struct timespec ts = {0, (long)us * 1000L};
  nanosleep(&ts, NULL);
}

static void poster_main(void *arg) {
  poster *t = arg;
  soak_posters *p = t->p;
  for (;;) {
    rp_runtime *rt;
    int err;
    uv_mutex_lock(&p->lock);
    while (p->rt == NULL && !p->stop) {
      p->parked++;
      uv_cond_broadcast(&p->cv);
      uv_cond_wait(&p->cv, &p->lock);
      p->parked--;
    }
    rt = p->rt;
    uv_mutex_unlock(&p->lock);
    if (rt == NULL)
      break; /* stopped */
    /* Out of the lock: the threads post at the same time. The driver's
     * pause waits for this call to return before it touches rt. */
    err = post_one(t, rt, &p->space);
    if (err != 0) {
      uv_mutex_lock(&p->lock);
      t->n.refused++;
      if (!p->failed)
        fprintf(stderr, "soak: poster %u: an event was refused: %s: %s\n",
                t->index, rp_strerror(err), rp_last_error(t->ctx));
      p->failed = 1;
      uv_mutex_unlock(&p->lock);
    }
    sleep_us(soak_rng_range(&t->rng, 200, 1800));
  }
  uv_mutex_lock(&p->lock);
  p->parked++;
  uv_cond_broadcast(&p->cv);
  uv_mutex_unlock(&p->lock);
}

static void poster_free(poster *t) {
  uint32_t i;
  for (i = 0; i < SOAK_TF_COUNT; i++)
    rp_tf_destroy(t->tfs[i]);
  rp_volume_destroy(t->orbit);
  rp_context_destroy(t->ctx);
}

static int poster_init(poster *t, soak_posters *p, uint32_t index,
                       uint64_t seed) {
  rp_context_desc cd = {0};
  rp_generate_desc g;
  uint32_t i;
  memset(t, 0, sizeof *t);
  t->p = p;
  t->index = index;
  soak_rng_seed(&t->rng, seed * 1000003u + index);
  cd.allocator = soak_heap_allocator();
  if (rp_context_create(&cd, &t->ctx) != 0)
    return RP_ENOMEM;
  soak_volume_desc(0, &g);
  if (rp_volume_generate(t->ctx, &g, &t->orbit) != 0)
    return RP_ENOMEM;
  for (i = 0; i < SOAK_TF_COUNT; i++)
    if (rp_tf_create_preset(t->ctx, soak_tfs[i], &t->tfs[i]) != 0)
      return RP_EINVAL;
  return 0;
}

int soak_posters_start(soak_posters **out, uint32_t threads, uint64_t seed,
                       const rp_space_desc *space) {
  soak_posters *p = calloc(1, sizeof *p);
  uint32_t i;
  if (p == NULL || threads > SOAK_MAX_THREADS) {
    free(p);
    return RP_EINVAL;
  }
  uv_mutex_init(&p->lock);
  uv_cond_init(&p->cv);
  p->space = *space;
  for (i = 0; i < threads; i++) {
    if (poster_init(&p->threads[i], p, i, seed) != 0 ||
        uv_thread_create(&p->threads[i].thread, poster_main,
                         &p->threads[i]) != 0) {
      poster_free(&p->threads[i]);
      break;
    }
    p->count++;
  }
  *out = p;
  if (p->count < threads) {
    soak_posters_stop(p, NULL);
    *out = NULL;
    return RP_ENOMEM;
  }
  soak_posters_pause(p);
  return 0;
}

void soak_posters_resume(soak_posters *p, rp_runtime *rt) {
  uv_mutex_lock(&p->lock);
  p->rt = rt;
  uv_cond_broadcast(&p->cv);
  uv_mutex_unlock(&p->lock);
}

void soak_posters_pause(soak_posters *p) {
  uv_mutex_lock(&p->lock);
  p->rt = NULL;
  while (p->parked < p->count)
    uv_cond_wait(&p->cv, &p->lock);
  uv_mutex_unlock(&p->lock);
}

int soak_posters_failed(soak_posters *p) {
  int failed;
  uv_mutex_lock(&p->lock);
  failed = (int)p->failed;
  uv_mutex_unlock(&p->lock);
  return failed;
}

void soak_posters_stop(soak_posters *p, soak_post_counts *total) {
  uint32_t i;
  if (p == NULL)
    return;
  uv_mutex_lock(&p->lock);
  p->rt = NULL;
  p->stop = 1;
  uv_cond_broadcast(&p->cv);
  uv_mutex_unlock(&p->lock);
  for (i = 0; i < p->count; i++) {
    poster *t = &p->threads[i];
    uv_thread_join(&t->thread);
    if (total != NULL) {
#define ADD(f) total->f += t->n.f
      ADD(camera); ADD(tf); ADD(viewport); ADD(target); ADD(effects);
      ADD(controller); ADD(density); ADD(volume); ADD(refused);
#undef ADD
    }
    poster_free(t);
  }
  uv_cond_destroy(&p->cv);
  uv_mutex_destroy(&p->lock);
  free(p);
}
