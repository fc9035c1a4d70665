/* The arithmetic of a group's split (shares.h). */
#include <math.h>
#include <string.h>

#include "passes.h"
#include "raypace_balance.h"
#include "shares.h"

void rp__rate_add(rp__split_model *m, double measured) {
  double v[RP__RATE_FRAMES], t;
  uint32_t i, j;
  m->rates[m->next_rate] = measured;
  m->next_rate = (m->next_rate + 1) % RP__RATE_FRAMES;
  if (m->n_rates < RP__RATE_FRAMES)
    m->n_rates++;
  memcpy(v, m->rates, m->n_rates * sizeof *v);
  for (i = 1; i < m->n_rates; i++) /* insertion sort of at most three */
    for (j = i; j > 0 && v[j - 1] > v[j]; j--)
      t = v[j], v[j] = v[j - 1], v[j - 1] = t;
  m->rate = v[(m->n_rates - 1) / 2];
}

void rp__split_learn(rp__split_model *m, const rp__split_sample *s,
                     double total_cost, int frame_depth) {
  double ran, measured;
  if (!s->rendered || !(s->cost > 0.0)) {
    if (m->rate > 0.0)
      m->depth_freq += RP__DEPTH_FREQ_GAIN * ((double)frame_depth -
                                              m->depth_freq);
    return;
  }
  ran = s->depth_passes > 0;
  if (ran)
    m->depth_est = s->depth_ms;
  m->depth_freq = m->rate > 0.0
                      ? m->depth_freq + RP__DEPTH_FREQ_GAIN *
                                            (ran - m->depth_freq)
                      : ran;
  measured = fmax(s->busy_ms - s->depth_ms, 1e-6) / s->cost;
  if (m->rate > 0.0 && s->cost < RP__MIN_RATE_FRACTION * total_cost &&
      !(measured < m->rate))
    return;
  rp__rate_add(m, measured);
}

/* The split's sigma (the rate) is per unit of the split's own cost, not
 * the paper's cost per sample from the device's KRLS model: the split
 * divides predicted tile cost, so a cost map that is off by a factor for
 * a whole view is off the same way for every device and cancels; and the
 * depth pass, which every device runs over the whole image whatever its
 * share, is a fixed cost the paper's shares cannot express. The KRLS
 * models still predict the frame's time (rp__predict_frame). */
int rp__frame_shares(const rp_group_desc *d,
                     const rp__split_model *const *dev, uint32_t count,
                     const double *prev, double cost, double *shares) {
  double var[RP_GROUP_MAX_DEVICES], fixed[RP_GROUP_MAX_DEVICES];
  double target[RP_GROUP_MAX_DEVICES], last[RP_GROUP_MAX_DEVICES];
  double psum = 0.0;
  uint32_t idx[RP_GROUP_MAX_DEVICES], n = 0, i;
  int err;
  for (i = 0; i < count; i++) {
    const rp__split_model *m = dev[i];
    shares[i] = 0.0;
    if (m == NULL)
      continue;
    idx[n] = i;
    if (d->share_mode == RP_SHARES_FIXED) {
      target[n] = d->fixed_shares[i];
    } else {
      var[n] = m->rate > 0.0 && cost > 0.0 ? m->rate * cost : NAN;
      fixed[n] = m->depth_freq * m->depth_est;
    }
    last[n] = prev != NULL ? prev[i] : 0.0;
    psum += last[n];
    n++;
  }
  if (n == 0)
    return RP_ENODEV;
  if (d->share_mode == RP_SHARES_FIXED) {
    double sum = 0.0;
    for (i = 0; i < n; i++)
      sum += target[i];
    if (!(sum > 0.0)) /* the live devices all had share 0: even */
      for (i = 0; i < n; i++)
        target[i] = 1.0;
    if ((err = rp_balance_damp(RP_DAMP_SMOOTH, 1.0, NULL, target, n,
                               target)) != 0)
      return err;
  } else {
    if ((err = rp_balance_shares_fixed(var, fixed, n, target)) != 0)
      return err;
    if ((err = rp_balance_damp(d->damping, d->damp_rate,
                               psum > 0.0 ? last : NULL, target, n,
                               target)) != 0)
      return err;
  }
  for (i = 0; i < n; i++)
    shares[idx[i]] = target[i];
  return 0;
}

void rp__device_cost_split(rp__device_cost *c) {
  /* t' = (a R + c0 + variable) * Q: Q scales the fixed part too. */
  c->fixed = c->e.c0_ms * c->e.frame_factor;
  c->var = c->e.ms - c->fixed;
  c->ok = isfinite(c->var) && c->var > 0.0 && isfinite(c->fixed);
}

double rp__predict_frame(const rp__device_cost *c, const double *shares,
                         uint32_t count, double tiles, int *fastest) {
  double worst = -INFINITY, best = INFINITY;
  uint32_t i;
  *fastest = -1;
  for (i = 0; i < count; i++) {
    double t;
    if (!c[i].ok)
      continue;
    /* A device whose share buys less than half a tile gets an empty
     * region (rp_balancer_split) and pays nothing. */
    t = shares[i] * tiles >= 0.5 ? c[i].fixed + shares[i] * c[i].var : 0.0;
    if (t > worst)
      worst = t;
    if (c[i].var < best) {
      best = c[i].var;
      *fastest = (int)i;
    }
  }
  return *fastest >= 0 ? worst : NAN;
}

int rp__region_empty(const rp_region *r) {
  return r->x0 >= r->x1 || r->y0 >= r->y1;
}

double rp__region_cost(const float *cost, uint32_t tx, const rp_region *t) {
  double sum = 0.0;
  uint32_t x, y;
  for (y = t->y0; y < t->y1; y++)
    for (x = t->x0; x < t->x1; x++)
      sum += cost[(size_t)y * tx + x];
  return sum;
}

uint32_t rp__tail_cut(const float *cost, uint32_t tx, uint32_t ty,
                      double fraction, uint32_t n, double total,
                      rp_region *strips) {
  uint32_t rows = 0, k = 0, x, x0 = 0, y;
  double band = 0.0, acc = 0.0;
  if (ty < 2 || !(total > 0.0))
    return 0;
  while (rows < ty - 1 && band < fraction * total) {
    rows++;
    for (x = 0; x < tx; x++)
      band += cost[(size_t)(ty - rows) * tx + x];
  }
  if (!(band > 0.0))
    return 0;
  if (n > tx)
    n = tx;
  if (n > RP_GROUP_MAX_STRIPS)
    n = RP_GROUP_MAX_STRIPS;
  for (x = 0; x < tx && k + 1 < n; x++) {
    for (y = ty - rows; y < ty; y++)
      acc += cost[(size_t)y * tx + x];
    /* Close strip k at its share of the band, if the strips after it
     * still get a column each, and when they need every column left. */
    if ((acc >= band * (double)(k + 1) / (double)n &&
         tx - (x + 1) >= n - 1 - k) ||
        tx - (x + 1) == n - 1 - k) {
      rp_region r = {x0, ty - rows, x + 1, ty};
      strips[k++] = r;
      x0 = x + 1;
    }
  }
  {
    rp_region r = {x0, ty - rows, tx, ty};
    strips[k++] = r;
  }
  return k;
}

int rp_probe_tile_costs(const rp_frame_probe *p, const rp_render_desc *desc,
                        float *cost) {
  uint32_t sw, sh, tx, ty, x, y;
  double step, sx, sy;
  if (p == NULL || desc == NULL || cost == NULL || desc->width == 0 ||
      desc->height == 0)
    return RP_EINVAL;
  step = rp__render_desc_defaults(desc).step;
  if (!isfinite(step))
    return RP_ENOTFINITE;
  if (!(step > 0.0))
    return RP_ERANGE;
  rp_scaled_size(desc, &sw, &sh);
  rp_tile_grid(sw, sh, &tx, &ty);
  /* Scaled pixel -> output pixel. */
  sx = (double)desc->width / sw;
  sy = (double)desc->height / sh;
  for (y = 0; y < ty; y++) {
    uint32_t y0 = y * RP_TILE_SIZE;
    uint32_t y1 = y0 + RP_TILE_SIZE < sh ? y0 + RP_TILE_SIZE : sh;
    double oy = 0.5 * (y0 + y1) * sy;
    for (x = 0; x < tx; x++) {
      uint32_t x0 = x * RP_TILE_SIZE;
      uint32_t x1 = x0 + RP_TILE_SIZE < sw ? x0 + RP_TILE_SIZE : sw;
      double ox = 0.5 * (x0 + x1) * sx, span = 0.0;
      if (p->map_width > 0 && p->map_height > 0 && p->map_stride > 0 &&
          (size_t)p->map_width * p->map_height <= RP_PROBE_MAX_RAYS) {
        /* The probe ray nearest the tile's centre. */
        double fi = floor((ox - 2.0) / p->map_stride + 0.5);
        double fj = floor((oy - 2.0) / p->map_stride + 0.5);
        uint32_t i = fi <= 0.0 ? 0
                     : fi >= p->map_width - 1 ? p->map_width - 1
                                              : (uint32_t)fi;
        uint32_t j = fj <= 0.0 ? 0
                     : fj >= p->map_height - 1 ? p->map_height - 1
                                               : (uint32_t)fj;
        span = p->span[(size_t)j * p->map_width + i];
        if (!(span >= 0.0) || !isfinite(span))
          span = 0.0;
      }
      cost[(size_t)y * tx + x] =
          (float)((double)(x1 - x0) * (y1 - y0) * (1.0 + span / step));
    }
  }
  return 0;
}
