/* KRLS benchmark: one training update and one prediction at dim 7 (the
 * cost model's features), with the dictionary held at 8, 16 and 32.
 *
 *   bench_krls [--quick] [--runs N]
 *
 * Each run times 10^4 operations in this thread's CPU time; printed is
 * the median over N runs (default 7) of the time per operation (and the
 * fastest run's, a hint of the figure on an idle machine), and the ratio
 * of the paper's figures (seed 000, Table 3: 0.015 ms per training, 0.001
 * ms per prediction, maxima on a desktop CPU) to it. Two kinds of update:
 * "ALD", a sample the dictionary already explains (the common case once
 * a view has been seen), and "novel", a sample that evicts an element and
 * enters the dictionary (the most expensive path). --quick shrinks
 * everything so that the test suite can check the program still works. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "bench_util.h"
#include "krls.h"

#define DIM 7
#define PAPER_TRAIN_NS 15000.0
#define PAPER_PREDICT_NS 1000.0

/* This thread's CPU time: the machines this runs on are shared, and time
 * spent descheduled is not the model's. */
static double now(void) { return bench_seconds(CLOCK_THREAD_CPUTIME_ID); }

static unsigned long long rng = 88172645463325252ULL;

static double urand(void) {
  rng ^= rng << 13;
  rng ^= rng >> 7;
  rng ^= rng << 17;
  return (double)(rng >> 11) * 0x1p-53;
}

static void die(rp_context *ctx, const char *what) {
  fprintf(stderr, "bench_krls: %s: %s\n", what, rp_last_error(ctx));
  exit(1);
}

/* A model with max_dict = size, gamma 3, filled by novel samples. */
static rp__krls *filled(rp_context *ctx, int size, double nu) {
  rp__krls_desc d = {0};
  rp__krls *m = NULL;
  rp__krls_stats st;
  double x[DIM];
  int j, guard = 0;
  d.dim = DIM;
  d.gamma = 3.0;
  d.nu = nu;
  d.max_dict = size;
  if (rp__krls_create(ctx, &d, &m) != 0)
    die(ctx, "create");
  do {
    for (j = 0; j < DIM; j++)
      x[j] = urand();
    if (rp__krls_update(m, x, 1.0 + urand()) != 0)
      die(ctx, "update");
    rp__krls_get_stats(m, &st);
  } while (st.size < size && ++guard < 100000);
  return m;
}

/* Median ns per operation (and the fastest run's in *best). kind: 0 ALD
 * update, 1 novel update, 2 predict. xs holds ops samples. */
static double time_ops(rp_context *ctx, int size, int kind, int runs,
                       int ops, double *xs, double *ys, double *best) {
  double t[64] = {0};
  volatile double sink = 0;
  int r, i, j;
  for (r = 0; r < runs; r++) {
    rp__krls *m = filled(ctx, size, kind == 1 ? 0.1 : 1e-3);
    double t0;
    for (i = 0; i < ops; i++) {
      double *x = xs + (size_t)i * DIM;
      if (kind == 0) {
        /* Near a dictionary element: ALD, delta ~ 1e-12. */
        rp__krls_point(m, i % size, x);
        for (j = 0; j < DIM; j++)
          x[j] += 1e-6 * (urand() - 0.5);
      } else {
        for (j = 0; j < DIM; j++)
          x[j] = urand();
      }
      ys[i] = 1.0 + urand();
    }
    t0 = now();
    if (kind == 2) {
      double s = 0;
      for (i = 0; i < ops; i++)
        s += rp__krls_predict(m, xs + (size_t)i * DIM);
      sink = s;
    } else {
      for (i = 0; i < ops; i++)
        if (rp__krls_update(m, xs + (size_t)i * DIM, ys[i]) != 0)
          die(ctx, "update");
    }
    t[r] = (now() - t0) / ops * 1e9;
    if (kind != 2) {
      rp__krls_stats st;
      rp__krls_get_stats(m, &st);
      /* At most 1% of the "novel" stream may land near an element. */
      if (st.size != size || (kind == 0 && st.grown != (uint64_t)size) ||
          (kind == 1 && st.evicted < (uint64_t)ops - ops / 100)) {
        fprintf(stderr, "bench_krls: the stream did not stay %s\n",
                kind ? "novel" : "ALD");
        exit(1);
      }
    }
    rp__krls_destroy(m);
  }
  (void)sink;
  *best = t[0];
  for (r = 1; r < runs; r++)
    *best = t[r] < *best ? t[r] : *best;
  return bench_median(t, runs);
}

int main(int argc, char **argv) {
  static const int sizes[] = {8, 16, 32};
  static const char *const names[] = {"update ALD  ", "update novel",
                                      "predict     "};
  rp_context *ctx = NULL;
  int runs = 7, ops = 10000, i, s, k;
  double *xs, *ys;
  for (i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--quick")) {
      runs = 1;
      ops = 1000;
    } else if (!strcmp(argv[i], "--runs") && i + 1 < argc) {
      runs = atoi(argv[++i]);
      if (runs < 1 || runs > 64) {
        fprintf(stderr, "bench_krls: --runs 1..64\n");
        return 2;
      }
    } else {
      fprintf(stderr, "usage: bench_krls [--quick] [--runs N]\n");
      return 2;
    }
  }
  if (rp_context_create(NULL, &ctx) != 0)
    return 1;
  xs = malloc(sizeof(double) * (size_t)ops * DIM);
  ys = malloc(sizeof(double) * (size_t)ops);
  if (!xs || !ys)
    return 1;
  printf("KRLS, dim %d: median over %d runs of %d operations\n", DIM, runs,
         ops);
  for (s = 0; s < 3; s++)
    for (k = 0; k < 3; k++) {
      double best, ns = time_ops(ctx, sizes[s], k, runs, ops, xs, ys,
                                 &best);
      double paper = k == 2 ? PAPER_PREDICT_NS : PAPER_TRAIN_NS;
      printf("dictionary %2d  %s median %8.1f ns (best run %8.1f)   "
             "paper %6.0f ns: %5.1fx faster\n", sizes[s], names[k], ns,
             best, paper, paper / ns);
    }
  free(xs);
  free(ys);
  rp_context_destroy(ctx);
  return 0;
}
