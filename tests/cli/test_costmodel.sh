#!/bin/sh
# raypace replay --trace and bench_costmodel together: the trace holds
# everything the replay's cost model learned from, so a fresh model fed
# the trace with the same settings must predict every frame exactly as the
# replay's did (its CSV, to the CSV's 4 decimals). Then the refusals.
# usage: test_costmodel.sh RAYPACE BENCH_COSTMODEL SCRATCH_DIR
set -u
rp=$1
bench=$2
dir=$3
mkdir -p "$dir"
fails=0

fail() { echo "FAIL: $*"; fails=$((fails + 1)); }

# The mixed sequence: TF switches, a zoom, shading toggled, a new target.
if ! "$rp" replay gen:phantom:24 --backend reference --sequence mixed \
    --frames 60 --settle 2 --size 32x32 --quiet --controller predicted \
    --csv "$dir/r.csv" --trace "$dir/t.csv" >"$dir/out" 2>&1; then
  fail "replay --trace"; cat "$dir/out"
fi
[ "$(head -1 "$dir/t.csv" | cut -d, -f1-3)" = "controller,frame,width" ] ||
  fail "trace header: $(head -1 "$dir/t.csv")"
# One row per pass: 62 frames of one pass each (settle included).
[ "$(grep -c '^predicted,' "$dir/t.csv")" -eq 62 ] ||
  fail "trace rows: $(grep -c '^predicted,' "$dir/t.csv")"

if ! "$bench" --trace "$dir/t.csv" --ratios 0.05 --skip 0 \
    --rows "$dir/rows.csv" >"$dir/out" 2>&1; then
  fail "bench_costmodel"; cat "$dir/out"
fi
grep -q '^predicted ' "$dir/out" || { fail "bench table"; cat "$dir/out"; }
# CSV frame f is trace row f + 2 (the settle frames come first); the
# replay's prediction adds the predicted brick uploads (column 20), which
# the cost model does not price.
bad=$(awk -F, 'NR == FNR { if (FNR > 1) p[$3] = $9; next }
  FNR > 1 { r = $2 + 2; d = p[r] - ($5 - $20); if (d < 0) d = -d;
            n++; if (!(r in p) || d > 2e-4) { bad++; print "frame " $2 ": replay " $5 ", bench " p[r] > "/dev/stderr" } }
  END { print (n == 60 ? bad + 0 : "rows " n) }' "$dir/rows.csv" "$dir/r.csv")
[ "$bad" = "0" ] || fail "predictions differ from the replay's: $bad"

# Refusals: a clear message, never a crash.
if "$bench" --trace "$dir/none.csv" >"$dir/out" 2>&1 ||
   ! grep -q "cannot open" "$dir/out"; then fail "missing file"; fi
head -1 "$dir/t.csv" | sed 's/,samples,/,sample_count,/' >"$dir/bad.csv"
if "$bench" --trace "$dir/bad.csv" >"$dir/out" 2>&1 ||
   ! grep -q "no column 'samples'" "$dir/out"; then fail "column"; fi
{ head -1 "$dir/t.csv"; sed -n 2p "$dir/t.csv" | sed 's/,[^,]*$/,nan/'; } \
  >"$dir/bad.csv"
if "$bench" --trace "$dir/bad.csv" >"$dir/out" 2>&1 ||
   ! grep -q "'frame_ms' = 'nan' is out of range" "$dir/out"; then fail "nan"; fi
{ head -1 "$dir/t.csv"; sed -n 2p "$dir/t.csv" |
  awk -F, 'BEGIN { OFS = "," } { $21 = $21 + 0.5; print }'; } >"$dir/bad.csv"
if "$bench" --trace "$dir/bad.csv" >"$dir/out" 2>&1 ||
   ! grep -q "'samples' = '.*' is out of range" "$dir/out"; then
  fail "fractional samples"; fi
{ head -1 "$dir/t.csv"; sed -n 2p "$dir/t.csv" | tr -d '\n';
  head -c 5000 /dev/zero | tr '\0' 1; echo; } >"$dir/bad.csv"
if "$bench" --trace "$dir/bad.csv" >"$dir/out" 2>&1 ||
   ! grep -q "line over" "$dir/out"; then fail "long line"; fi
if "$bench" --trace "$dir/t.csv" --ratios 0.05,-1 >"$dir/out" 2>&1 ||
   ! grep -q "ratios" "$dir/out"; then fail "bad --ratios"; fi
if "$rp" replay gen:ml:8 --devices reference,reference --trace "$dir/x" \
    >"$dir/out" 2>&1 || ! grep -q "not with --devices" "$dir/out"; then
  fail "--trace with --devices"; fi

[ $fails -eq 0 ] && echo "test_costmodel: all checks passed"
exit $((fails > 0))
