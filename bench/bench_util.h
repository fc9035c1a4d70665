/* Timing helpers shared by the benchmark programs: clocks in seconds and
 * the median the programs report (medians over repeated runs, since the
 * machines they run on are shared and noisy). */
#ifndef RP_BENCH_UTIL_H
#define RP_BENCH_UTIL_H

#include <stdlib.h>
#include <time.h>

/* Seconds on one of clock_gettime's clocks: CLOCK_MONOTONIC for wall
 * time, CLOCK_PROCESS_CPUTIME_ID / CLOCK_THREAD_CPUTIME_ID for the work
 * itself when neighbours share the cores. */
static inline double bench_seconds(clockid_t clock) {
  struct timespec ts;
  clock_gettime(clock, &ts);
  return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static inline int bench_cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return x < y ? -1 : x > y;
}

/* Median of n values; sorts them in place. */
static inline double bench_median(double *v, int n) {
  qsort(v, (size_t)n, sizeof *v, bench_cmp_double);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

#endif /* RP_BENCH_UTIL_H */
