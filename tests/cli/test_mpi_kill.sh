#!/bin/sh
# A rank killed mid-run (raypace_mpi.h): rank 2 is started with
# RP_MPI_DIE_AT=3 and SIGKILLs itself at its third raycast; rank 0's
# test_mpi kill must see the frame re-rendered by rank 1, later frames on
# rank 1 alone, and rank 2 given up on (tests/test_mpi.c, lose_rank_2).
# usage: test_mpi_kill.sh SCRATCH_DIR LIMIT_S MPIEXEC [OPTIONS...] -- \
#          ENV TEST_MPI
# where the launcher's options hold --enable-recovery and the number-of-
# processes flag is the last of them (-n or -np).
#
# Why a script rather than the launch in ctest: after the rank's death,
# Open MPI 4.1.4 (Debian 12) sometimes never ends the job although rank 0
# has finished its tests (2 of 4 runs launched by ctest directly; 1 of 18
# runs of this script, output to files). raypace's part is over by then,
# so the verdict
# is rank 0's own: its cmocka summary and the line it prints before
# MPI_Finalize. A launcher still running LINGER_S after that line is
# ended here, and said so; a rank 0 that never gets there fails the test
# at LIMIT_S.
set -u
dir=$1; limit=$2; shift 2
mkdir -p "$dir"
mpiexec=""
while [ "$1" != "--" ]; do mpiexec="$mpiexec $1"; shift; done
shift
envp=$1; test_mpi=$2
LINGER_S=10
out="$dir/out"; err="$dir/err"
: >"$out"; : >"$err"
# Its own session, so that the launcher and every rank it started can be
# ended together; no stdin, output to files.
# Splitting the launcher's options into words is meant.
# shellcheck disable=SC2086
setsid $mpiexec 2 "$test_mpi" kill : ${mpiexec##* } 1 "$envp" \
  RP_MPI_DIE_AT=3 "$test_mpi" kill </dev/null >"$out" 2>"$err" &
pid=$!
# The whole session: the launcher's process group (setsid made it the
# leader), then any rank left outside it. (dash's kill takes no "--".)
end_job() {
  kill -TERM "-$pid" 2>/dev/null; sleep 2; kill -KILL "-$pid" 2>/dev/null
  pkill -KILL -f "$test_mpi kill" 2>/dev/null
}
waited=0; finished_at=""
while kill -0 "$pid" 2>/dev/null; do
  if [ -z "$finished_at" ] && grep -q '^test_mpi: rank 0 done' "$out"; then
    finished_at=$waited
  fi
  if [ -n "$finished_at" ] && [ $((waited - finished_at)) -ge $((LINGER_S * 2)) ]; then
    echo "note: the launcher had not ended ${LINGER_S} s after rank 0's tests;" \
      "ending it (Open MPI after a rank's death, see the script's header)"
    end_job
    break
  fi
  if [ "$waited" -ge $((limit * 2)) ]; then
    echo "FAIL: no result from rank 0 within ${limit} s"
    end_job
    cat "$out" "$err"; exit 1
  fi
  sleep 0.5; waited=$((waited + 1))
done
wait "$pid" 2>/dev/null
rc=$?
if [ -n "$finished_at" ] || grep -q '^test_mpi: rank 0 done' "$out"; then
  :
else
  echo "FAIL: rank 0 never finished (launcher exit $rc)"; cat "$out" "$err"
  exit 1
fi
if ! grep -q '^test_mpi: rank 0 done, 0 failed$' "$out" ||
    ! cat "$out" "$err" | grep -q 'PASSED.*1 test' ||
    cat "$out" "$err" | grep -q 'FAILED'; then
  echo "FAIL: rank 0's tests did not pass"; cat "$out" "$err"; exit 1
fi
grep -E 'rank 2 lost|reopening rank 2' "$out" "$err" | sed 's/^[^:]*://'
echo "a killed rank was rendered around (launcher exit $rc)"
