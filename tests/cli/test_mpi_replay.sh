#!/bin/sh
# raypace replay across MPI ranks: rank 0 plays the sequence, ranks 1 and
# 2 serve their devices as --devices mpi:0,mpi:1 (raypace_mpi.h).
# usage: test_mpi_replay.sh SCRATCH_DIR MPIEXEC [OPTIONS...] -- RAYPACE
# where the launcher's options start 3 ranks (-np 3).
# The run must exit 0 and print one JSON summary naming both ranks. Then
# every controller over a sequence with AO on one MPI device: the replay
# would give each controller a device of its own, which a rank's single
# device cannot be, so it plays them in turn (a summary each, exit 0).
set -u
dir=$1; shift
mkdir -p "$dir"
mpiexec=""
while [ "$1" != "--" ]; do mpiexec="$mpiexec $1"; shift; done
shift
rp=$1
# Splitting the launcher's options into words is meant.
# shellcheck disable=SC2086
$mpiexec "$rp" replay gen:phantom:48 --sequence orbit \
  --controller predicted --frames 30 --devices mpi:0,mpi:1 --json \
  --size 64x64 --quiet >"$dir/out" 2>"$dir/err"
rc=$?
if [ $rc -ne 0 ]; then
  echo "FAIL: mpirun replay exited $rc"; cat "$dir/out" "$dir/err"; exit 1
fi
for pat in '^{"controller":"predicted"' '"frames":30' \
    '"mpi:rank 1 ' '"mpi:rank 2 ' '"mean_imbalance":'; do
  if ! grep -q -- "$pat" "$dir/out"; then
    echo "FAIL: the output lacks '$pat'"; cat "$dir/out" "$dir/err"; exit 1
  fi
done
if [ "$(wc -l <"$dir/out")" -ne 1 ]; then
  echo "FAIL: not one line of JSON"; cat "$dir/out"; exit 1
fi
echo "replay over 3 ranks: $(cat "$dir/out")"
$mpiexec "$rp" replay gen:phantom:24 --backend mpi --device 0 \
  --sequence ao-tf-switch --frames 12 --settle 1 --size 32x32 --json \
  >"$dir/out" 2>"$dir/err"
rc=$?
if [ $rc -ne 0 ] || [ "$(grep -c '^{"controller":' "$dir/out")" -ne 7 ] ||
   ! grep -q "each plays the whole sequence in turn" "$dir/err"; then
  echo "FAIL: AO replay on one MPI device (exit $rc)"
  cat "$dir/out" "$dir/err"; exit 1
fi
echo "AO replay on one MPI device: 7 controllers, in turn"
