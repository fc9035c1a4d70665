/* raypace_mpi.h in a build without MPI (RP_WITH_MPI off): one process,
 * rank 0 of 1, whatever launched it, so an application written for both
 * runs unchanged; there is nothing to serve. The MPI build's versions are
 * in backends/mpi. */
#include "internal.h"
#include "raypace_mpi.h"

int rp_mpi_init(int *argc, char ***argv, int *rank, int *size) {
  (void)argc;
  (void)argv;
  if (rank != NULL)
    *rank = 0;
  if (size != NULL)
    *size = 1;
  return 0;
}

int rp_mpi_serve(rp_context *ctx, const char *backend) {
  (void)backend;
  if (ctx == NULL)
    return RP_EINVAL;
  return rp__fail(ctx, RP_EUNSUPPORTED, "rp_mpi_serve: raypace was built "
                  "without MPI (RP_WITH_MPI off)");
}

void rp_mpi_finalize(void) {}
