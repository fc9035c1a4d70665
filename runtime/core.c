/* Context, errors, version, allocation and the CPU worker pool. */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "internal.h"

/* rp__parallel_for keeps its workers on the stack. */
#define RP__MAX_THREADS 256

#define RP__VERSION_STR2(a, b, c) #a "." #b "." #c
#define RP__VERSION_STR(a, b, c) RP__VERSION_STR2(a, b, c)

const char *rp_strerror(int err) {
  switch (err) {
#define RP__STRERROR(name, val, msg)                                          \
  case RP_##name: return msg;
    RP_ERRNO_MAP(RP__STRERROR)
#undef RP__STRERROR
  case RP_OK: return "success";
  default: return "unknown error";
  }
}

const char *rp_err_name(int err) {
  switch (err) {
#define RP__ERRNAME(name, val, msg)                                           \
  case RP_##name: return #name;
    RP_ERRNO_MAP(RP__ERRNAME)
#undef RP__ERRNAME
  case RP_OK: return "OK";
  default: return "UNKNOWN";
  }
}

unsigned rp_version(void) { return RP_VERSION_HEX; }

const char *rp_version_string(void) {
  return RP__VERSION_STR(RP_VERSION_MAJOR, RP_VERSION_MINOR,
                         RP_VERSION_PATCH);
}

static void *default_alloc(size_t size, void *user) {
  (void)user;
  return malloc(size);
}

static void default_free(void *ptr, void *user) {
  (void)user;
  free(ptr);
}

/* The one place that turns zero fields into defaults (STYLE rule 3). */
static rp_context_desc context_defaults(const rp_context_desc *in) {
  rp_context_desc d;
  if (in != NULL)
    d = *in;
  else
    memset(&d, 0, sizeof d);
  if (d.allocator.alloc == NULL || d.allocator.free == NULL) {
    d.allocator.alloc = default_alloc;
    d.allocator.free = default_free;
    d.allocator.user = NULL;
  }
  if (d.threads <= 0) {
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    d.threads = n > 0 ? (int)(n > RP__MAX_THREADS ? RP__MAX_THREADS : n) : 1;
  }
  if (d.threads > RP__MAX_THREADS)
    d.threads = RP__MAX_THREADS;
  if (d.max_volume_bytes == 0)
    d.max_volume_bytes = (uint64_t)16 << 30;
  return d;
}

int rp_context_create(const rp_context_desc *desc, rp_context **out) {
  rp_context_desc d;
  rp_context *ctx;
  if (out == NULL)
    return RP_EINVAL;
  if (desc != NULL && (desc->allocator.alloc == NULL) !=
                          (desc->allocator.free == NULL))
    return RP_EINVAL; /* half an allocator would free with the wrong one */
  d = context_defaults(desc);
  ctx = d.allocator.alloc(sizeof *ctx, d.allocator.user);
  if (ctx == NULL)
    return RP_ENOMEM;
  memset(ctx, 0, sizeof *ctx);
  ctx->desc = d;
  *out = ctx;
  return 0;
}

void rp_context_destroy(rp_context *ctx) {
  rp_allocator a;
  if (ctx == NULL)
    return;
  a = ctx->desc.allocator;
#ifndef NDEBUG
  memset(ctx, 0xdd, sizeof *ctx); /* poison: use after destroy shows */
#endif
  a.free(ctx, a.user);
}

const char *rp_last_error(const rp_context *ctx) {
  return ctx != NULL ? ctx->last_error : "no context";
}

void *rp__malloc(rp_context *ctx, size_t size) {
  if (size == 0)
    size = 1;
  return ctx->desc.allocator.alloc(size, ctx->desc.allocator.user);
}

void *rp__calloc(rp_context *ctx, size_t count, size_t size) {
  void *p;
  if (size != 0 && count > SIZE_MAX / size)
    return NULL;
  p = rp__malloc(ctx, count * size);
  if (p != NULL)
    memset(p, 0, count * size);
  return p;
}

void rp__free(rp_context *ctx, void *ptr) {
  if (ptr != NULL)
    ctx->desc.allocator.free(ptr, ctx->desc.allocator.user);
}

int rp__fail(rp_context *ctx, int err, const char *fmt, ...) {
  va_list ap;
  if (ctx == NULL)
    return err;
  va_start(ap, fmt);
  vsnprintf(ctx->last_error, sizeof ctx->last_error, fmt, ap);
  va_end(ap);
  if (ctx->desc.logger != NULL)
    ctx->desc.logger("raypace", RP_LOG_ERROR, err, ctx->last_error, 0,
                     ctx->desc.logger_user);
  return err;
}

void rp__clear_error(rp_context *ctx) {
  if (ctx != NULL)
    ctx->last_error[0] = '\0';
}

uint64_t rp__next_id(void) {
  static atomic_uint_fast64_t next = 1;
  return atomic_fetch_add(&next, 1);
}

uint64_t rp__now_ns(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

double rp__now_ms(void) { return (double)rp__now_ns() * 1e-6; }

int rp__thread_count(const rp_context *ctx) { return ctx->desc.threads; }

typedef struct worker {
  pthread_t thread;
  uint32_t begin, end;
  void (*fn)(uint32_t, uint32_t, void *);
  void *user;
} worker;

static void *worker_main(void *arg) {
  worker *w = arg;
  w->fn(w->begin, w->end, w->user);
  return NULL;
}

/* Threads are started per call: the CPU passes that use this run on volume
 * load and TF change, never per frame, so a pool would buy nothing here.
 * The calling thread takes the first range itself. */
int rp__parallel_for(const rp_context *ctx, uint32_t n,
                     void (*fn)(uint32_t, uint32_t, void *), void *user) {
  worker ws[RP__MAX_THREADS];
  uint32_t t, threads = (uint32_t)rp__thread_count(ctx), started = 0;
  int err = 0;
  if (threads > n)
    threads = n;
  if (threads <= 1) {
    if (n > 0)
      fn(0, n, user);
    return 0;
  }
  for (t = 0; t < threads; t++) {
    ws[t].begin = (uint32_t)((uint64_t)n * t / threads);
    ws[t].end = (uint32_t)((uint64_t)n * (t + 1) / threads);
    ws[t].fn = fn;
    ws[t].user = user;
  }
  for (t = 1; t < threads; t++) {
    if (pthread_create(&ws[t].thread, NULL, worker_main, &ws[t]) != 0)
      break;
    started = t;
  }
  /* Ranges whose thread could not start run here, so the work is done
   * either way; the caller sees no difference but time. */
  for (t = started + 1; t < threads; t++)
    fn(ws[t].begin, ws[t].end, user);
  fn(ws[0].begin, ws[0].end, user);
  for (t = 1; t <= started; t++)
    pthread_join(ws[t].thread, NULL);
  return err;
}

#if defined(__SANITIZE_ADDRESS__)
#define RP_UNDER_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define RP_UNDER_ASAN 1
#endif
#endif

#ifdef RP_UNDER_ASAN
#include <sanitizer/lsan_interface.h>
void rp__driver_setup_begin(void) { __lsan_disable(); }
void rp__driver_setup_end(void) { __lsan_enable(); }
#else
void rp__driver_setup_begin(void) {}
void rp__driver_setup_end(void) {}
#endif
