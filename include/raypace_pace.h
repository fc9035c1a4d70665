/* Lab tier (README, "Headers"): public for research use, and may change
 * between minor versions. An app embedding the runtime needs none of it:
 * every setting it makes is declared in the product headers.
 *
 * raypace pacing: hold a frame-time target (DESIGN sections 5 and 6).
 *
 * Three parts, usable on their own:
 * - sampling density and the tuning spaces: one number rho (1: the base
 *   step at full size; above 1 only with a min_step under the base step)
 *   that frame time is (nearly) linear in, and its mapping to a step and
 *   an image scale in ray, image or hybrid space;
 * - the cost model: a probe of the frame (the depth pass and ERT
 *   pre-pass, summarised) and t' = sigma * k * S' + c0, sigma learned per
 *   device by KRLS;
 * - the tuner (Eq. 2) and the controllers that choose rho each frame:
 *   none, last-frame, two-pass, predicted (ours) and three reactive rules
 *   from well-known systems, all behind one interface.
 *
 * Threading: every object here belongs to one thread at a time. */
#ifndef RAYPACE_PACE_H
#define RAYPACE_PACE_H

#include <stdint.h>

#include "raypace.h"

#ifdef __cplusplus
extern "C" {
#endif

/* ---- Sampling density and tuning spaces -------------------------------- */

/* rp_space, rp_space_desc and their names are in raypace.h (the runtime's
 * settings); the mapping is here. */

/** The step and image scale that give density rho in d's space (rho
 *  clamped to [rp_space_min_density(d), rp_space_max_density(d)]).
 *  \since 0.1 */
RP_API void rp_space_map(const rp_space_desc *d, double rho, float *step,
                         float *scale);
/** The smallest density d's space can reach. \since 0.1 */
RP_API double rp_space_min_density(const rp_space_desc *d);
/** The largest: base_step / min_step in ray and hybrid space, 1 in image
 *  space. \since 0.2 */
RP_API double rp_space_max_density(const rp_space_desc *d);

/* ---- Tuner: Eq. 2 ------------------------------------------------------- */

/** Predicted frame time in ms at density rho (the cost model, or any
 *  model a caller supplies). May return NaN/inf for "unknown". */
typedef double (*rp_predict_fn)(void *user, double rho);

/** Zero fields take the defaults; negative or non-finite ones are
 *  refused. */
typedef struct rp_tune_desc {
  double target_ms;   /* required, > 0 */
  double rho_prev;    /* last frame's density: the damping reference and
                         the search's start; 0: no damping, start at
                         rho_max (first frame) */
  double rho_min;     /* 0: 1e-3; 0 < rho_min <= rho_max */
  double rho_max;     /* 0: 1; rp_space_max_density() for the space */
  double raise_limit; /* largest rise of rho per frame, >= 1;
                         0: 1 / 0.8 */
  int max_iters;      /* predictions per frame; 0: 8 */
  double tolerance;   /* accept t' in [target (1 - tolerance), target];
                         in (0, 1); 0: 0.01 */
  double max_time_us; /* checked before each prediction after the
                         first (CLOCK_MONOTONIC), so a call overruns it
                         by at most one prediction; 0: 200 */
  double lift;        /* share of the target under which a rise the
                         damping held back is taken at once (below);
                         in (0, 1); 0: 0.25. \since 0.2 */
} rp_tune_desc;

typedef struct rp_tune_result {
  double rho;          /* the density to render at */
  double predicted_ms; /* t'(rho); NaN when no valid prediction was made
                          at rho */
  int iters;           /* predictions made */
  int limited;         /* 1 if rho was cut by raise_limit, rho_min or
                          rho_max, or no density met the target */
} rp_tune_result;

/** Eq. 2 (DESIGN section 6): the largest density whose predicted time
 *  meets the target. Clamps: rho stays in [rho_min, ub] with
 *  ub = min(rho_max, max(rho_min, rho_prev * raise_limit)) (rho_prev
 *  > 0): a rise is damped, a fall is not, and rho_min wins over the
 *  damping. When the damping alone held rho back at a density predicted
 *  at `lift` of the target or less (a quarter by default), rho rises at
 *  once to the largest density predicted at `lift` of the target,
 *  searched between the two the same way, rho_max first (at a quarter,
 *  a 4x error of the model would be needed to overshoot; a switch to a
 *  cheap TF then gets the finest image at once); these predictions
 *  count against max_iters and max_time_us. Predictions
 *  that are NaN, infinite or <= 0 count as unknown.
 *  The result is the largest rho seen with t' <= target. If none was
 *  seen and t'(rho_min) > target, no density meets the target: the
 *  largest rho up to ub predicted within 10 % of t'(rho_min), searched
 *  the same way from the call's predictions so far, then ub (where
 *  fixed costs dominate, a far finer image costs little more than
 *  rho_min's); rho_min itself when that rho is under twice rho_min or
 *  the budget is spent (\since 0.2; before, rho_min). Otherwise (the
 *  budget ran out first) Eq. 2's unverified step down from the
 *  smallest rho tried. A
 *  model that predicts nothing valid leaves rho at rho_prev (or rho_max
 *  on the first frame). Never NaN. No context: errors carry no message.
 *  \returns 0; RP_EINVAL (NULL argument, field out of range) or
 *  RP_ENOTFINITE for a bad desc. \since 0.1 */
RP_API int rp_tune(const rp_tune_desc *d, rp_predict_fn predict,
                   void *user, rp_tune_result *out);

/* ---- Controllers -------------------------------------------------------- */

/* rp_controller_kind and its names are in raypace.h (the runtime's
 * setting); the controller objects are here. */

typedef struct rp_controller rp_controller;

/** Zero fields take the defaults. */
typedef struct rp_controller_desc {
  rp_controller_kind kind;
  double rho_min;     /* 0: 1e-3; 0 < rho_min <= rho_max */
  double rho_max;     /* 0: 1; rp_space_max_density() for the space */
  double rho_start;   /* the density before the first frame, in
                         [rho_min, rho_max]; 0: 1 clamped to them. NONE
                         renders it
                         every frame; LAST_FRAME, VTK and UE5 render it on
                         the first frame, VALVE its highest ladder level
                         not above it; PREDICTED uses it as the first
                         frame's damping reference; TWO_PASS's first pass
                         renders at a quarter of it */
  double raise_limit; /* largest rise per frame, >= 1, for LAST_FRAME and
                         PREDICTED; 0: 1 / 0.8 */
  double vtk_f;       /* VTK's time factor f, > 0; 0: VTK's own choice,
                         1.66 for targets under 1000 ms, else 1 (see
                         runtime/control.c) */
  double tune_time_us; /* PREDICTED: the tuner's wall-clock budget per
                          frame (rp_tune_desc.max_time_us), >= 0; 0: its
                          default, 200 */
  /* PREDICTED: the share of frames allowed over their target (DESIGN
   * section 12). The controller aims each frame at target * exp(-m),
   * m the (1 - a) quantile of its recent log residuals ln(t / t'), and
   * moves a after every frame toward the asked rate (adaptive conformal
   * inference): runtime/control.c states the rule. In (0, 0.5];
   * 0: 0.05; negative: no margin, the frame aimed at the target itself
   * (the rule before 0.3). \since 0.3 */
  double miss_rate;
  /* The reactive rules: the share of the target kept free, in [0, 0.9]:
   * LAST_FRAME, TWO_PASS and VTK aim at (1 - headroom) of it (VTK
   * with its factor on top), UE5 takes it for its targeted headroom,
   * VALVE scales its thresholds (70, 85, 90 %) by (1 - headroom). 0: each
   * rule's own (UE5's 10 %, none for the others). What buys a reactive
   * rule fewer late frames, for comparing rules at equal miss rates
   * (raypace bench pacing --pareto). \since 0.3 */
  double headroom;
} rp_controller_desc;

/** `ctx` is kept: failed calls on the controller leave their message in
 *  rp_last_error(ctx). `desc` may be NULL (all defaults).
 *  \returns 0, RP_EINVAL, RP_ENOTFINITE or RP_ENOMEM. \since 0.1 */
RP_API int rp_controller_create(rp_context *ctx,
                                const rp_controller_desc *desc,
                                rp_controller **out);
/** NULL is a no-op. \since 0.1 */
RP_API void rp_controller_destroy(rp_controller *c);
/** Forgets the history and closes an open frame; keeps the desc.
 *  \since 0.1 */
RP_API void rp_controller_reset(rp_controller *c);

/** Before a frame: the density of its first render pass. `predict` is
 *  required by RP_CONTROL_PREDICTED (RP_EINVAL without) and ignored by
 *  the others. \returns 0, RP_EINVAL (target <= 0, a frame already begun
 *  and not ended), RP_ENOTFINITE (target NaN or infinite); a failed call
 *  changes nothing. \since 0.1 */
RP_API int rp_controller_begin_frame(rp_controller *c, double target_ms,
                                     rp_predict_fn predict, void *user,
                                     double *rho);
/** PREDICTED: the log-margin m of the open frame, or of the last one
 *  when none is open (its first pass was aimed at target * exp(-m));
 *  0 for the other kinds, with no margin, and before the first frame.
 *  \since 0.3 */
RP_API double rp_controller_margin(const rp_controller *c);
/** PREDICTED: how new the coming frame is to the cost model, in [0, 1]
 *  (rp_cost_estimate.novelty at the last density), before its
 *  rp_controller_begin_frame. The contract keeps the residuals of novel
 *  frames (over 0.5) apart from the others' and holds each group to the
 *  miss rate on its own: a model wrong on a new scene then widens the
 *  margin of the next new scene, not of every frame. Out of range or
 *  NaN is taken as 1; never set, every frame counts as familiar. Other
 *  kinds ignore it. \since 0.3 */
RP_API void rp_controller_set_novelty(rp_controller *c, double novelty);
/** After each render pass of the frame, its measured time (ms, >= 0 and
 *  finite, else RP_ERANGE/RP_ENOTFINITE with the frame still open and
 *  nothing learned). Sets *again to 1 and *rho to the next pass's density
 *  when the frame renders again (two-pass), else *again = 0 and *rho to
 *  the frame's final density: the frame is over and its time (the sum of
 *  its passes) is what the controller learns from. RP_EINVAL without an
 *  open frame. \since 0.1 */
RP_API int rp_controller_end_pass(rp_controller *c, double pass_ms,
                                  int *again, double *rho);

/* ---- Cost model (DESIGN section 5) -------------------------------------- */

/** What the depth pass and ERT pre-pass say about a frame, summarised for
 *  the cost model. It does not depend on the step or the image scale:
 *  one probe per camera / transfer function / effect set serves every
 *  density the tuner tries. Probe rays are the ERT pre-pass grid of the
 *  output image (one ray per 4x4 output pixels), subsampled to at most
 *  1024 rays (a 128x128 output traces them all). The runtime's own
 *  probes trace fewer, down to 128, where 2 % of the frame's target pays
 *  for no more (docs/pacing.md, "Prediction's own cost"). */
/** The most rays a probe traces. */
#define RP_PROBE_MAX_RAYS 1024

typedef struct rp_frame_probe {
  uint32_t width, height;  /* output size */
  uint32_t effects;        /* RP_EFFECT_* the frame renders with */
  uint32_t rays;           /* probe rays traced: the ERT pre-pass grid,
                              or, past 1024 rays, the regular subgrid of
                              every n-th ray per axis that fits 1024 */
  uint32_t rays_hit;       /* probe rays with a non-empty sampled span */
  uint32_t rays_ended;     /* of those, rays the ERT pre-pass ends */
  uint32_t jitter;         /* 1: the frame jitters its ray starts
                              (rp_jitter): a ray ERT does not end takes
                              half a sample less on average than on a
                              lattice that starts at its span. \since
                              0.11 */
  double depth_sum;        /* sum over probe rays of the sampled span L,
                              voxels: from D_front to D'_ERT (ERT on) or
                              D_back */
  double depth_max;        /* largest L */
  double ert_cut;          /* share of the span that ERT removes, [0, 1]
                              (0 with ERT off) */
  /* With RP_EFFECT_SHADING or RP_EFFECT_AO (0 otherwise): the samples
   * expected to show (opacity above 0), the only ones the raycast shades
   * and reads AO for. lit_span: sum
   * over probe rays of L times the share of voxels that show in the
   * blocks along L (rp_occupancy); lit_ends: of the samples the lattice
   * adds to L / h (1/2 a ray, 0 with jitter; 1 a ray ERT ends), those
   * that show, the
   * sample ERT ends a ray on always. At step h the shaded share is
   * (lit_span / h + lit_ends) / (depth_sum / h + those samples). */
  double lit_span, lit_ends;
  double view[3];          /* unit view direction, volume axes */
  double pixels_per_voxel; /* splatted voxel size at scale 1: output
                              pixels one voxel spans at the volume centre */
  double diagonal;         /* the volume's diagonal, voxels */
  double probe_ms;         /* wall time the probe took */
  /* Each probe ray's sampled span L (voxels, 0 for a ray that misses or
   * meets nothing), row by row: map_width x map_height rays, ray (i, j)
   * at output pixel (i * map_stride + 2, j * map_stride + 2). What a
   * device group predicts each tile's cost from. */
  uint32_t map_width, map_height, map_stride;
  float span[RP_PROBE_MAX_RAYS];
} rp_frame_probe;

/** Runs the depth pass and ERT pre-pass on the host for `cam` and
 *  `desc` (width, height, effects and ert_threshold are used; step and
 *  image_scale are not) and summarises them. `occ` must be built for
 *  `tf` on `vol`. (seed, frame) seed the ERT pre-pass as on a device.
 *  \returns 0, RP_EINVAL (a NULL argument, a bad desc, an occupancy of
 *  another TF or volume), RP_ENOMEM. \since 0.1 */
RP_API int rp_frame_probe_compute(rp_context *ctx, const rp_volume *vol,
                                  const rp_tf *tf, const rp_occupancy *occ,
                                  const rp_camera *cam,
                                  const rp_render_desc *desc, uint32_t seed,
                                  uint32_t frame, rp_frame_probe *out);

/** The most volume fetches a sample takes with an effect set:
 *  1 + 6 * shading + 1 * AO. Only samples with opacity above 0 take the
 *  shading and AO fetches; the cost model's k (rp_cost_estimate.fetches)
 *  takes the probe's share of them. RP_EFFECT_PREINT adds one fetch per
 *  ray that samples, not per sample: k adds the probe's rays over its
 *  samples (since 0.11). \since 0.1 */
RP_API uint32_t rp_fetches_per_sample(uint32_t effects);

#define RP_COST_FEATURES 8

/* rp_cost_model_desc is in raypace.h (the runtime's setting). */
typedef struct rp_cost_model rp_cost_model;

typedef struct rp_cost_estimate {
  double samples;        /* S', from the probe */
  double sample_ratio;   /* kappa: learned S_measured / S' */
  double fetches;        /* k */
  double sigma_ns;       /* predicted cost per fetch */
  double launch_ms;      /* the raycast's own cost outside its fetches:
                            a cost per ray a times the rays at this
                            scale */
  double c0_ms;          /* per-frame fixed cost outside the raycast */
  double ms;             /* t' = (a + sigma * k * kappa * S' + c0) * Q */
  double features[RP_COST_FEATURES]; /* in [0, 1] */
  /* Q: the recent frames' agreed bias on frames whose time the fetches
   * hardly set (runtime/predict.c), in [1/4, 4]; mostly 1. \since 0.2 */
  double frame_factor;
  /* How new this point is to the model, in [0, 1]: the share of the
   * kernel's prior variance its learned points leave unexplained at
   * these features (KRLS's predictive variance, noise aside; the larger
   * of sigma's and kappa's): about 0 on a scene it has learned, 1 on
   * one far from all (a new TF, a cut, a zoom never seen) and before it
   * learned anything. \since 0.3 */
  double novelty;
} rp_cost_estimate;

/** A cost model for one device. \returns 0, RP_EINVAL / RP_ENOTFINITE
 *  naming a bad desc field, RP_ENOMEM. \since 0.1 */
RP_API int rp_cost_model_create(rp_context *ctx,
                                const rp_cost_model_desc *desc,
                                rp_cost_model **out);
/** NULL is a no-op. \since 0.1 */
RP_API void rp_cost_model_destroy(rp_cost_model *m);
/** Forgets everything learned. \since 0.1 */
RP_API void rp_cost_model_reset(rp_cost_model *m);
/** The predicted cost of rendering the probed frame at (step, scale).
 *  Const: valid calls may run concurrently (a failing one records its
 *  message in the context). \since 0.1 */
RP_API int rp_cost_predict(const rp_cost_model *m, const rp_frame_probe *p,
                           float step, float scale, rp_cost_estimate *out);
/** Learns from a rendered frame: its measured sample count (the tiles'
 *  sum), the raycast's own time and the whole frame's time (ms).
 *  \returns RP_ENOTFINITE / RP_ERANGE for NaN, inf, negative or
 *  overflowing figures (the model is unchanged). \since 0.1 */
RP_API int rp_cost_train(rp_cost_model *m, const rp_frame_probe *p,
                         float step, float scale, uint64_t samples,
                         double raycast_ms, double frame_ms);

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_PACE_H */
