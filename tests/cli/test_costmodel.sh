#!/bin/sh
# raypace replay --trace and bench_costmodel together: the trace holds
# everything the runtime's cost model learned from, so a fresh model fed
# the trace with the same settings must predict every frame exactly as the
# runtime's did (the CSV's pass_predicted_ms). Then the refusals.
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
# One row per frame the model learned from: the warm-up's (frame -1),
# then 62 frames of one pass each (settle included, frames 0..61).
[ "$(awk -F, '$1 == "predicted" && $2 >= 0' "$dir/t.csv" | wc -l)" -eq 62 ] ||
  fail "trace rows: $(grep -c '^predicted,' "$dir/t.csv")"

if ! "$bench" --trace "$dir/t.csv" --ratios 0.05 --skip 0 \
    --rows "$dir/rows.csv" >"$dir/out" 2>&1; then
  fail "bench_costmodel"; cat "$dir/out"
fi
grep -q '^predicted ' "$dir/out" || { fail "bench table"; cat "$dir/out"; }
# The trace's row for CSV frame f is the one whose frame is f + 2 (the
# settle frames come first); bench_costmodel numbers the rows it fed
# from 0. The replay's pass_predicted_ms is the model's t' alone.
col=$(head -1 "$dir/r.csv" | tr ',' '\n' | grep -nx pass_predicted_ms |
      cut -d: -f1)
bad=$(awk -F, -v c="$col" '
  FILENAME == ARGV[1] { if (FNR > 1 && $1 == "predicted") {
                          if ($2 >= 0) row[$2] = n; n++ } next }
  FILENAME == ARGV[2] { if (FNR > 1) p[$3] = $9; next }
  FNR > 1 { r = row[$2 + 2]; d = p[r] - $c; if (d < 0) d = -d; k++
            if (!(($2 + 2) in row) || !(r in p) || d > 2e-4) { bad++
              print "frame " $2 ": replay " $c ", bench " p[r] > "/dev/stderr" } }
  END { print (k == 60 ? bad + 0 : "rows " k) }' \
  "$dir/t.csv" "$dir/rows.csv" "$dir/r.csv")
[ -n "$col" ] && [ "$bad" = "0" ] ||
  fail "predictions differ from the replay's: $bad"

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
  awk -F, 'BEGIN { OFS = "," } { $22 = $22 + 0.5; print }'; } >"$dir/bad.csv"
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
