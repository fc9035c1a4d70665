/* runtime/krls.c against dlib's krls, the implementation the paper used.
 * dlib's kernel is radial_basis_kernel, exp(-gamma * |a - b|^2), plus a
 * constant 0.01 that its krls adds inside (an implicit intercept), so our
 * model runs with bias = 0.01. Same gamma, tolerance and sample stream.
 *
 * Asserted: the two take the same ALD decisions (same dictionary size) and
 * predict alike, over 2000 random points, to 1e-7 relative to the
 * largest prediction, while neither dictionary fills up,
 * and with full dictionaries when ours evicts the oldest element as dlib
 * does (both then marginalise it the same way). With the default policy
 * (least recently used) a full dictionary holds other elements than
 * dlib's, so that case is reported, not asserted. */
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

#include <dlib/svm.h>

extern "C" {
#include "krls.h"
}

namespace {

const int LRU = RP__KRLS_EVICT_LRU, OLDEST = RP__KRLS_EVICT_OLDEST;

typedef dlib::matrix<double, 0, 1> sample;
typedef dlib::radial_basis_kernel<sample> rbf;

unsigned long long rng = 1;

double urand() {
  rng ^= rng >> 12;
  rng ^= rng << 25;
  rng ^= rng >> 27;
  return (double)((rng * 0x2545F4914F6CDD1DULL) >> 11) * 0x1p-53;
}

double target(const double *x, int dim) {
  double s = 1.0 + 0.4 * std::sin(3.0 * x[0]) * std::cos(2.0 * x[dim > 1]);
  for (int i = 2; i < dim; i++)
    s += 0.1 * x[i] * x[i];
  return s;
}

struct result {
  unsigned long dlib_size;
  int our_size;
  double max_abs, max_rel;
};

result run_case(rp_context *ctx, int dim, double gamma, double tol,
                int max_dict, int samples, int evict) {
  dlib::krls<rbf> ref(rbf(gamma), tol, (unsigned long)max_dict);
  rp__krls_desc d = {};
  rp__krls *m = NULL;
  result r = {0, 0, 0, 0};
  d.dim = dim;
  d.gamma = gamma;
  d.nu = tol;
  d.max_dict = max_dict;
  d.bias = 0.01;
  d.evict = evict;
  if (rp__krls_create(ctx, &d, &m) != 0) {
    std::fprintf(stderr, "create: %s\n", rp_last_error(ctx));
    std::exit(1);
  }
  std::vector<double> x((size_t)dim);
  sample s((long)dim);
  for (int i = 0; i < samples; i++) {
    for (int j = 0; j < dim; j++)
      s(j) = x[(size_t)j] = urand();
    double y = target(x.data(), dim) * (1.0 + 0.01 * (urand() - 0.5));
    ref.train(s, y);
    if (rp__krls_update(m, x.data(), y) != 0) {
      std::fprintf(stderr, "update: %s\n", rp_last_error(ctx));
      std::exit(1);
    }
  }
  rp__krls_stats st;
  rp__krls_get_stats(m, &st);
  r.dlib_size = ref.dictionary_size();
  r.our_size = st.size;
  double scale = 0;
  for (int p = 0; p < 2000; p++) {
    for (int j = 0; j < dim; j++)
      s(j) = x[(size_t)j] = urand();
    double a = ref(s), b = rp__krls_predict(m, x.data());
    r.max_abs = std::fmax(r.max_abs, std::fabs(a - b));
    scale = std::fmax(scale, std::fabs(a));
  }
  r.max_rel = r.max_abs / scale;
  rp__krls_destroy(m);
  return r;
}

} /* namespace */

int main() {
  static const struct {
    int dim;
    double gamma, tol;
    int max_dict, samples, evict;
  } cases[] = {
      {2, 4.0, 1e-3, 256, 2000, LRU},    {3, 2.0, 1e-4, 256, 2000, LRU},
      {7, 0.3, 1e-3, 256, 1000, LRU},    {7, 0.3, 6e-3, 256, 2000, LRU},
      {1, 30.0, 1e-5, 256, 1000, LRU},   {5, 1.0, 1e-2, 256, 3000, LRU},
      {7, 1.0, 1e-3, 16, 2000, LRU},     {7, 1.0, 1e-3, 16, 2000, OLDEST},
      {3, 4.0, 1e-3, 8, 2000, OLDEST},
  };
  rp_context *ctx = NULL;
  int failed = 0;
  if (rp_context_create(NULL, &ctx) != 0)
    return 1;
  for (const auto &c : cases) {
    rng = 1000 + (unsigned long long)c.dim;
    result r = run_case(ctx, c.dim, c.gamma, c.tol, c.max_dict, c.samples,
                        c.evict);
    bool full = r.our_size == c.max_dict;
    /* Round-off differs (dlib's products, our rebuilds, neither exact)
     * and is amplified by cond(K~): test_krls holds ours to 1e-7 of the
     * direct solve, and dlib is asked the same. */
    const double bound = 1e-7;
    bool asserted = !full || c.evict == OLDEST;
    bool ok = !asserted || ((long)r.dlib_size == r.our_size &&
                            r.max_rel < bound);
    std::printf("dlib krls: dim %d gamma %g tol %g max_dict %d, %d "
                "samples%s: dictionary dlib %lu ours %d, max abs diff "
                "%.2e, rel %.2e (bound %.0e)%s\n",
                c.dim, c.gamma, c.tol, c.max_dict, c.samples,
                c.evict == OLDEST ? ", oldest evicted" : "", r.dlib_size,
                r.our_size, r.max_abs, r.max_rel, bound,
                !asserted ? ": full, policies differ, not asserted"
                          : ok ? "" : "  FAIL");
    failed += !ok;
  }
  rp_context_destroy(ctx);
  return failed != 0;
}
