/* What the device front end (backend.c) builds a device from besides a
 * driver's bootstrap: the host backends that run inside the library (the
 * scalar reference, ref_backend.c; the deterministic test device,
 * test_backend.c), the frame they receive, and the fault wrapper that can
 * sit around any backend (faults.c). Not part of the public API. */
#ifndef RP_DEVICE_H
#define RP_DEVICE_H

#include <stdint.h>

#include "raygen.h"
#include "raypace_backend.h"
#include "raypace_testing.h"

/* ---- The host frame --------------------------------------------------- */

/* The frame as the front end hands it to every backend: a pointer to `p`.
 * A GPU backend reads rp_frame_params alone (the plain float block its
 * kernels copy by value). A host backend, which only the front end in
 * this process ever calls (rp__backend_open refuses one), also reads the
 * camera the params were made from in double, beside them: its image is
 * then rp_render_reference's bit for bit, where the float camera would
 * move rays by an ulp. Every front-end path that calls a frame op (depth
 * pass, ERT pre-pass, raycast, an out-of-core part) passes &frame.p. */
typedef struct rp__host_frame {
  rp_frame_params p; /* first, so that &frame.p is the frame */
  const rp__raygen *rg;
} rp__host_frame;

/* The host frame a frame op's `p` belongs to. */
static inline const rp__host_frame *rp__host_frame_of(
    const rp_frame_params *p) {
  return (const rp__host_frame *)(const void *)p;
}

/* ---- Host backends ---------------------------------------------------- */

/* A backend that runs on the host, opened only by name. Unlike a driver's
 * bootstrap, create receives the whole desc: a host backend refuses what
 * it cannot honour (a memory budget, a device index or compute units
 * other than its one thread) and reads its own extension struct. */
typedef struct rp__host_backend {
  const char *name;
  int (*create)(rp_context *ctx, const rp_device_desc *desc,
                const rp_backend_ops **ops, void **impl, rp_caps *caps);
} rp__host_backend;

extern const rp__host_backend rp__ref_backend;  /* "reference" */
extern const rp__host_backend rp__test_backend; /* "test" */

/* The reference backend's ops and a bare impl of it, which the test
 * backend renders with; rp__ref_check refuses, for host backend `name`,
 * a desc with a budget, an index other than 0 or compute units. */
extern const rp_backend_ops rp__ref_ops;
int rp__ref_open(rp_context *ctx, void **impl);
void rp__ref_caps(rp_caps *caps);
int rp__ref_check(rp_context *ctx, const char *name,
                  const rp_device_desc *desc);

/* ---- The extension chain (device_ext.c) ------------------------------ */

/* Checks the chain of a desc opening backend `name` (NULL: the first
 * with a device): every struct of a known type, each type once (so the
 * chain ends: one that loops repeats a struct), the test backend's
 * parameters only for it, and the faults valid. *faults: the fault desc,
 * or NULL. */
int rp__ext_check(rp_context *ctx, const void *next, const char *name,
                  const rp_fault_desc **faults);
/* The extension struct of `type` in a checked chain, or NULL. */
const rp_ext_header *rp__ext_find(const void *next, rp_ext_type type);

/* ---- Fault injection (faults.c) --------------------------------------- */

typedef struct rp__faults rp__faults;

/* Validates an rp_fault_desc (message names rp_device_create, the field
 * and its value). */
int rp__faults_check(rp_context *ctx, const rp_fault_desc *fd);
/* Wraps the backend (*ops, *impl), whose device is described by `caps`,
 * in one that injects fd's faults: on success *ops and *impl are the
 * wrapper's, which owns the inner backend from then on (its destroy
 * destroys both), and *out is the wrapper for the calls below. On
 * failure nothing changes. */
int rp__faults_wrap(rp_context *ctx, const rp_fault_desc *fd,
                    const rp_caps *caps, const rp_backend_ops **ops,
                    void **impl, rp__faults **out);
/* A front-end render begins: counts it and, from fail_at_render on,
 * refuses it (RP_EDEVICE, "injected"). However many raycasts the render
 * then takes (out-of-core parts and slabs), it is one render. NULL: 0. */
int rp__faults_render_begin(rp__faults *f);
/* The render that began last ended well: the stall injected into it, in
 * ns, already waited (0 when none), which the front end adds to the
 * render's reported time. NULL: 0. */
uint64_t rp__faults_render_end(rp__faults *f);
/* rp__device_set_slowdown's work: checked as rp__faults_check does. */
int rp__faults_set_slowdown(rp__faults *f, double slowdown);

#endif /* RP_DEVICE_H */
