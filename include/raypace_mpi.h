/* Product tier (README, "Headers"): the interface an app is supported on.
 *
 * raypace across machines: devices on other MPI ranks (DESIGN section 9,
 * milestone M8).
 *
 * Started under an MPI launcher (mpirun -np N app ...), rank 0 runs the
 * application as usual and ranks 1 .. N-1 serve their local device to it:
 *
 *   int rank, size;
 *   rp_mpi_init(&argc, &argv, &rank, &size);
 *   if (rank > 0) {
 *     rc = rp_mpi_serve(ctx, NULL);  // until rank 0 says shut down
 *   } else {
 *     ... open devices "mpi" 0 .. size-2, alone or in a device group ...
 *   }
 *   rp_mpi_finalize();
 *
 * On rank 0, backend "mpi" has one device per server rank: device i is
 * rank i + 1. Each is a proxy: every backend operation (uploads, depth
 * pass, raycast of a region, AO, bricks) is sent to its rank, run there
 * on the rank's local device, and answered with the status, the error
 * message, the device time and the outputs (the region's pixels and tile
 * stats). So a device group whose devices are ranks splits each frame
 * across machines by the per-rank cost models, and re-renders the region
 * of a rank that fails or runs late on the others (raypace_group.h).
 * Backend "mpi" is never chosen by default: it is opened only by name.
 *
 * Faults. A rank that does not answer is given up on, its operation fails
 * with RP_EDEVICE and a message naming the rank, and raypace never waits
 * on it again (nor at rp_mpi_finalize):
 * - no reply RP_MPI_TIMEOUT_MS after the request (environment, read when
 *   the device is opened; default 60000: a CPU device's first kernel
 *   builds take tens of seconds on a loaded machine);
 * - no sign of life for RP_MPI_SILENCE_MS (default 2000): a server sends
 *   a heartbeat every 100 ms while it works on a request, so a rank that
 *   died is found within that time whatever the operation.
 * A device group also drops a rank still rendering past its deadline
 * (rp_group_desc.deadline_factor), in the same frame.
 * Open MPI aborts the whole job when a rank dies unless it is started
 * with `mpirun --enable-recovery`; with it, rank 0 and the other ranks
 * carry on and rp_mpi_finalize returns normally. Rank 0 itself cannot be
 * lost.
 *
 * Every rank must run the same build of raypace on the same kind of
 * machine: operations travel as raw structs (checked when a device is
 * opened: RP_BACKEND_ABI and struct sizes).
 *
 * Threading: the MPI calls raypace makes are short non-blocking ones
 * under one lock, so MPI_THREAD_SERIALIZED is enough (raypace asks for
 * MPI_THREAD_MULTIPLE); proxies of different ranks are used from
 * different threads at once (a device group's workers). */
#ifndef RAYPACE_MPI_H
#define RAYPACE_MPI_H

#include "raypace.h"

#ifdef __cplusplus
extern "C" {
#endif

/** Initialises MPI when this process was started by an MPI launcher
 *  (Open MPI's OMPI_COMM_WORLD_SIZE, or PMI_SIZE / PMIX_RANK in the
 *  environment) and raypace was built with MPI; otherwise does nothing
 *  and reports rank 0 of 1, so one binary runs with and without mpirun.
 *  If the application has initialised MPI itself, it is used as it is.
 *  Collective: every rank calls it. `argc` and `argv` may be NULL;
 *  `rank` and `size` may be NULL.
 *  \returns 0, RP_EDEVICE (MPI failed to start: the message is on stderr,
 *  as there is no context yet), RP_EUNSUPPORTED (MPI gives less than
 *  MPI_THREAD_SERIALIZED). \since 0.2 */
RP_API int rp_mpi_init(int *argc, char ***argv, int *rank, int *size);

/** Serves this rank's local device to rank 0 until rank 0 shuts the
 *  servers down (rp_mpi_finalize on rank 0); for ranks >= 1. The device is
 *  device RP_MPI_DEVICE (environment; default 0) of `backend`, NULL: the
 *  RP_BACKEND environment variable if set, else the first compiled-in
 *  backend with that device, as rp_device_create chooses ("reference" and
 *  "mpi" cannot be served). A machine with several devices runs one rank
 *  per device, each with its own RP_MPI_DEVICE (an MPMD launch: `mpirun
 *  -np 2 app : -np 1 env RP_MPI_DEVICE=1 app` serves devices 0 and 1 of
 *  one machine from ranks 1 and 2). It is opened when rank 0 first opens
 *  this rank, and kept between rank 0's sessions; when it cannot be
 *  opened, the server still runs and answers every open with the error.
 *  Testing knobs (environment): RP_MPI_DIE_AT=N kills this rank (SIGKILL)
 *  at its N-th raycast; RP_MPI_STALL_AT=N makes its N-th raycast take
 *  RP_MPI_STALL_MS (default 5000) longer.
 *  \returns 0 after a shutdown, RP_ESTATE (MPI not initialised by
 *  rp_mpi_init, or rank 0), RP_EINVAL (RP_MPI_DEVICE or a testing knob
 *  is not a whole number),
 *  RP_EUNSUPPORTED (built without MPI), RP_EDEVICE (MPI failed: the
 *  message says how). \since 0.2 */
RP_API int rp_mpi_serve(rp_context *ctx, const char *backend);

/** On rank 0, tells every server rank to shut down (without waiting on a
 *  rank that was given up on); then, on every rank, finalises MPI if
 *  rp_mpi_init initialised it. Call it last, after every "mpi" device is
 *  destroyed. A no-op without MPI. \since 0.2 */
RP_API void rp_mpi_finalize(void);

#ifdef __cplusplus
}
#endif
#endif /* RAYPACE_MPI_H */
