/* The soak (docs/soak.md): many frames through the runtime
 * an app embeds, with events posted from several threads at once and
 * device faults injected at random, checking that every frame comes out
 * once, in order and right, and that resident memory stays flat.
 *
 * soak.c drives sessions (one runtime each, a pacing mode and faulty
 * devices drawn at random); posters.c runs the threads that post events;
 * verify.c is the frame callback's side: ids, images, the oracle and the
 * memory samples. */
#ifndef RP_SOAK_H
#define RP_SOAK_H

#include <stdint.h>
#include <uv.h>

#include "raypace.h"
#include "raypace_pace.h"
#include "raypace_runtime.h"

#define SOAK_MAX_THREADS 16
#define SOAK_VOLUMES 4     /* the volumes events choose from */
#define SOAK_CHECK_W 32    /* the oracle frames' viewport */
#define SOAK_CHECK_H 32

/* A small deterministic PRNG (xorshift64*): each thread has its own. */
typedef struct soak_rng {
  uint64_t s;
} soak_rng;
void soak_rng_seed(soak_rng *r, uint64_t seed);
uint64_t soak_rng_next(soak_rng *r);
double soak_rng_unit(soak_rng *r);                 /* [0, 1) */
uint32_t soak_rng_range(soak_rng *r, uint32_t lo, uint32_t hi); /* [lo, hi] */

/* The volumes events pick from: the same desc gives the same voxels
 * (rp_volume_generate), so a poster makes a fresh one to hand over and
 * the oracle renders its own copy. */
void soak_volume_desc(uint32_t i, rp_generate_desc *g);
extern const char *const soak_tfs[];
#define SOAK_TF_COUNT 4

/* ---- Event posters (posters.c) ----------------------------------------- */

typedef struct soak_posters soak_posters;

typedef struct soak_post_counts {
  uint64_t camera, tf, viewport, target, effects, controller, density,
      volume, refused;
} soak_post_counts;

/* Starts `threads` threads, paused. `seed` seeds each one's stream. */
int soak_posters_start(soak_posters **out, uint32_t threads, uint64_t seed,
                       const rp_space_desc *space);
/* Lets them post to `rt` until soak_posters_pause. */
void soak_posters_resume(soak_posters *p, rp_runtime *rt);
/* Returns once every thread has stopped posting and waits: no call into
 * the runtime is under way on any of them. Any thread; idempotent. */
void soak_posters_pause(soak_posters *p);
/* Stops and joins the threads (paused or not); adds their counts. */
void soak_posters_stop(soak_posters *p, soak_post_counts *total);
/* 1 when a poster saw an unexpected error (its message went to
 * stderr). */
int soak_posters_failed(soak_posters *p);

/* ---- The frame side (verify.c) ----------------------------------------- */

/* Everything the frame callback checks and counts. Guarded by `lock`:
 * the callback runs on the runtime's loop thread (own loop) while the
 * driver waits on `cv`. */
typedef struct soak_verify {
  uv_mutex_t lock;
  uv_cond_t cv;
  soak_posters *posters;
  rp_context *ctx;                    /* the oracle's, callback only */
  rp_volume *vols[SOAK_VOLUMES];      /* the oracle's copies */
  rp_tf *tfs[SOAK_TF_COUNT];
  uint32_t devices;                   /* in this session */

  /* This session. */
  uint64_t next_id;      /* the frame id expected next */
  uint64_t delivered;    /* frames delivered */
  int last_status;       /* the last frame's stats.status */
  uint32_t dropped[RP_RUNTIME_MAX_DEVICES]; /* seen dropped */

  int ending;            /* the session is closing: posters stay paused */
  /* The pending oracle check: the first frame whose stats.events is at
   * least check_events renders check_* (the posters are paused until
   * that frame is delivered). */
  int check_pending;
  uint64_t check_events;
  uint32_t check_vol, check_tf;
  rp_camera check_cam;
  uint32_t check_effects;

  /* All sessions. */
  uint64_t frames, failed_frames, bad;
  uint64_t checks, checks_skipped, check_mismatch;
  /* Devices dropped, by why; unexplained: no status, no message. */
  uint64_t fail_render, fail_ao, drops_other, drops_unexplained;
  uint64_t two_pass;      /* frames of two render passes */
  uint64_t renders[RP_RUNTIME_MAX_DEVICES]; /* this session, per device */
  uint64_t rss_every;
  /* The library's heap between sessions (no runtime alive, posters
   * paused): the same bytes after every session, or something leaked. */
  long long heap_between;
  uint64_t heap_between_checked;
  uint64_t *rss_frames;   /* the samples: frames delivered, KiB */
  double *rss_kib;
  double *heap_kib;       /* the library's live heap at each sample */
  double *malloc_kib;     /* the process's malloc'd bytes live */
  uint32_t rss_count, rss_cap;
  char first_error[512];
} soak_verify;

int soak_verify_init(soak_verify *v, soak_posters *p, uint64_t rss_every,
                     uint64_t frames);
void soak_verify_free(soak_verify *v);
void soak_verify_session(soak_verify *v, uint32_t devices);
/* The runtime's frame callback; `user` is the soak_verify. */
void soak_on_frame(rp_runtime *rt, const rp_frame *f, void *user);
/* Pauses the posters and posts a scene the oracle knows (full quality,
 * SOAK_CHECK_W x SOAK_CHECK_H); the next frame that includes it is held
 * to rp_render_reference and resumes the posters. Not under v->lock.
 * Returns 0, or the error of a refused event (in v->first_error). */
int soak_check_begin(soak_verify *v, rp_runtime *rt, rp_context *ctx,
                     soak_rng *rng);
/* Resident set size now, KiB (/proc/self/statm). */
double soak_rss_kib(void);
/* The allocator every context of the soak uses (and so the runtime's):
 * malloc with a count of the bytes live, which soak_heap_kib reads. */
rp_allocator soak_heap_allocator(void);
double soak_heap_kib(void);
long long soak_heap_bytes(void);
/* Bytes live in the process's malloc, KiB: the sanitizer allocator's
 * count under ASan or TSan, glibc's (mallinfo2) otherwise. */
double soak_malloc_kib(void);
/* 1 when a sanitizer's allocator serves malloc. */
int soak_sanitized(void);
/* Least-squares slope of samples[from..count) over v->rss_frames, KiB
 * per frame. */
double soak_slope(const soak_verify *v, const double *samples,
                  uint32_t from);
/* Records the first problem (printf-style) and counts it. Under
 * v->lock. */
void soak_bad(soak_verify *v, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

#endif /* RP_SOAK_H */
