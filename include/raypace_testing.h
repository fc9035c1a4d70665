/* Lab tier (README, "Headers"): public for research use, and may change
 * between minor versions.
 *
 * raypace testing: what a test, a benchmark or a lab experiment asks of a
 * device, never what a product ships with.
 *
 * A product opens its devices with rp_device_desc (raypace.h) alone. A
 * test that needs a device to misbehave on purpose (slower, lost, stalled)
 * or a device whose timing is a formula rather than a measurement chains
 * the extension structs below onto rp_device_desc.next, Vulkan's pNext
 * way: each begins with an rp_ext_header naming its type and the next
 * struct (NULL ends the chain). rp_device_create reads the chain and
 * nothing keeps a pointer into it afterwards. A chain with an unknown
 * type or a type given twice (as a chain that loops back does) is
 * refused with RP_EINVAL and a message naming it.
 *
 *   rp_fault_desc faults = {{RP_EXT_FAULTS, NULL}, 4.0, 0, 0, 0, 0.0};
 *   rp_device_desc dd = {0};
 *   dd.backend = "opencl";
 *   dd.next = &faults;       // an OpenCL device four times slower
 *
 * Thread safety: as rp_device_create (the thread that owns the context).
 */
#ifndef RAYPACE_TESTING_H
#define RAYPACE_TESTING_H

#include <stdint.h>

#include "raypace.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The extension struct types. Values are stable across releases. */
typedef enum rp_ext_type {
  RP_EXT_FAULTS = 1,       /* rp_fault_desc */
  RP_EXT_TEST_BACKEND = 2  /* rp_test_backend_desc */
} rp_ext_type;

/* First member of every extension struct. */
typedef struct rp_ext_header {
  rp_ext_type type;
  const void *next; /* the next extension struct, or NULL */
} rp_ext_header;

/** Fault injection around any backend (runtime/faults.c wraps the
 *  device's backend in one that forwards every operation and adds the
 *  faults). A zero field injects nothing.
 *
 *  - slowdown: every operation that reports a device time (uploads,
 *    depth pass, ERT pre-pass, raycast, AO) takes `slowdown` times as
 *    long: the wrapper waits (slowdown - 1) times the operation's device
 *    time after it and reports the stretched time, so a real backend
 *    becomes a device that much slower, reproducibly. On a backend that
 *    keeps its own simulated clock (the "test" backend) the wait is on
 *    that clock, not in wall time. 0 or 1: none; otherwise finite and in
 *    (1, 10000].
 *  - fail_at_render: the fail_at_render-th rp_device_render (counting
 *    from 1) and every one after it fail with RP_EDEVICE, as a device
 *    that is lost mid-session does. An out-of-core render, which the
 *    backend sees as several raycasts (parts, depth slabs), counts once.
 *    0: never.
 *  - fail_at_ao: the same for AO jobs (rp_device_compute_ao). 0: never.
 *  - stall_at_render, stall_ms: the stall_at_render-th render (counting
 *    from 1, as fail_at_render) takes stall_ms longer, in wall time (or
 *    the backend's own clock) and in the time reported, as a thread
 *    descheduled on a shared machine does. 0: never; stall_ms finite and
 *    in [0, 60000].
 *  \since 0.3 */
typedef struct rp_fault_desc {
  rp_ext_header header; /* type RP_EXT_FAULTS */
  double slowdown;
  uint32_t fail_at_render;
  uint32_t fail_at_ao;
  uint32_t stall_at_render;
  double stall_ms;
} rp_fault_desc;

/** Parameters of backend "test", the deterministic test device: it
 *  renders exactly what backend "reference" renders (the scalar oracle,
 *  so images are rp_render_reference's bit for bit) and reports as its
 *  device time a formula of the work each operation really did, times a
 *  seeded noise factor, without sleeping and without reading any clock:
 *
 *    raycast        launch_ns + ray_ns * rays + fetch_ns * fetches
 *                   (rays: the region's pixels; fetches: the volume
 *                   fetches its rays took, as rp_tile_stats' counting
 *                   variant reports them)
 *    depth pass     launch_ns + depth_ray_ns * rays (the scaled image's)
 *    ERT pre-pass   launch_ns + depth_ray_ns * rays (the pre-pass grid's)
 *    compute_ao     launch_ns + ao_voxel_ns * voxels (of the job's box)
 *    uploads        ns_per_byte * bytes (volume, LUT, occupancy with its
 *                   H-alpha, AO volume)
 *
 *  each times exp(noise_sd * z), z ~ N(0, 1), and rounded to whole ns.
 *  The k-th timed operation of a device draws the k-th z of the stream
 *  `seed` names, so the same operations give the same times on every run
 *  and machine (with the same C math library). The device keeps a
 *  simulated clock that starts at 0 and advances by each operation's
 *  time (rp_backend_ops.clock_ns).
 *
 *  A zero field takes its default; a negative field asks for exactly 0
 *  (no noise, a free operation). Defaults, chosen so that a 64x64 frame
 *  of a 64^3 volume takes on the order of a millisecond: noise_sd 0.02,
 *  launch_ns 20000, ray_ns 50, fetch_ns 2, depth_ray_ns 5, ns_per_byte
 *  0.5 (2 GB/s), ao_voxel_ns 100. Each must be finite; noise_sd at most
 *  1, launch_ns at most 1e9, the others at most 1e6. seed: any value, 0
 *  included.
 *  \since 0.3 */
typedef struct rp_test_backend_desc {
  rp_ext_header header; /* type RP_EXT_TEST_BACKEND */
  uint64_t seed;
  double noise_sd;
  double launch_ns;
  double ray_ns;
  double fetch_ns;
  double depth_ray_ns;
  double ns_per_byte;
  double ao_voxel_ns;
} rp_test_backend_desc;

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_TESTING_H */
