#!/bin/sh
# Runs libFuzzer targets over their seed corpora. Builds nothing: build the
# targets first (CC=clang cmake -DRP_FUZZ=ON ...; cmake --build ...).
#
#   fuzz/run_corpus.sh BUILD/fuzz/fuzz_nrrd BUILD/fuzz/fuzz_sidecar
#
# Each binary fuzz_NAME runs once over every file in fuzz/corpus/NAME and
# fails on the first crash, leak or sanitizer report. With FUZZ_SECONDS=N
# set, each then fuzzes for N more seconds; new inputs and any crash file go
# to a scratch folder (FUZZ_OUT, default a mktemp folder), never into the
# checked-in corpus or the current directory. To keep what a long run
# found, add only the inputs that reach new edges, the named seeds kept:
#   fuzz_NAME -merge=1 -use_counters=0 fuzz/corpus/NAME SCRATCH/NAME/new
set -eu

here=$(cd "$(dirname "$0")" && pwd)
if [ $# -eq 0 ]; then
  echo "usage: $0 FUZZ_BINARY..." >&2
  exit 2
fi

status=0
for bin in "$@"; do
  name=$(basename "$bin")
  name=${name#fuzz_}
  corpus="$here/corpus/$name"
  if [ ! -x "$bin" ] || [ ! -d "$corpus" ]; then
    echo "$0: $bin: not an executable, or no corpus at $corpus" >&2
    status=1
    continue
  fi
  # GDCM's codecs leak on malformed input (gdcm_lsan.supp says which);
  # a caller's own LSAN_OPTIONS win.
  if [ "$name" = dicom ] && [ -z "${LSAN_OPTIONS:-}" ]; then
    LSAN_OPTIONS="suppressions=$here/gdcm_lsan.supp:print_suppressions=0"
    export LSAN_OPTIONS
  fi
  echo "== $bin over $corpus"
  # Passing the files (not the folder) runs each one exactly once.
  if ! "$bin" "$corpus"/*; then
    echo "FAILED: $bin on its corpus" >&2
    status=1
    continue
  fi
  if [ -n "${FUZZ_SECONDS:-}" ]; then
    out=${FUZZ_OUT:-$(mktemp -d "${TMPDIR:-/tmp}/rp_fuzz.XXXXXX")}
    mkdir -p "$out/$name/new"
    echo "== $bin for $FUZZ_SECONDS s (scratch: $out/$name)"
    # One process (no -jobs): -jobs writes fuzz-N.log into the current
    # directory.
    # fuzz/NAME.dict, where there is one: the format's keywords.
    dict=""
    [ -f "$here/$name.dict" ] && dict="-dict=$here/$name.dict"
    # shellcheck disable=SC2086
    if ! "$bin" -max_total_time="$FUZZ_SECONDS" -print_final_stats=1 \
        -artifact_prefix="$out/$name/" $dict \
        "$out/$name/new" "$corpus"; then
      echo "FAILED: $bin found a crash; see $out/$name" >&2
      status=1
    fi
  fi
done
exit $status
