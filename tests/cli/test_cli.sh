#!/bin/sh
# The raypace command end to end: help, JSON fields, PNG output, errors.
# usage: test_cli.sh RAYPACE_BINARY SCRATCH_DIR
set -u
rp=$1
dir=$2
mkdir -p "$dir"
fails=0
pass=0

check() { # check NAME COMMAND...: the command must succeed
  name=$1; shift
  if "$@" >"$dir/out" 2>"$dir/err"; then pass=$((pass + 1)); else
    echo "FAIL: $name"; cat "$dir/out" "$dir/err"; fails=$((fails + 1)); fi
}
refuse() { # refuse NAME PATTERN COMMAND...: must fail and say PATTERN
  name=$1; pat=$2; shift 2
  if "$@" >"$dir/out" 2>"$dir/err"; then
    echo "FAIL: $name succeeded"; fails=$((fails + 1))
  elif grep -q -- "$pat" "$dir/err"; then pass=$((pass + 1)); else
    echo "FAIL: $name: stderr lacks '$pat'"; cat "$dir/err"
    fails=$((fails + 1)); fi
}
has() { # has NAME PATTERN: the last output contains PATTERN
  if grep -q -- "$2" "$dir/out"; then pass=$((pass + 1)); else
    echo "FAIL: $1: output lacks '$2'"; cat "$dir/out"; fails=$((fails + 1))
  fi
}

check "help" "$rp" --help; has "help" "render VOLUME"
check "info help" "$rp" info --help; has "info help" "--histograms"
check "render help" "$rp" render --help; has "render help" "nearly-transparent"
check "version" "$rp" version; has "version" "raypace 0."

# A 40x36x20 phantom: 3x3x2 = 18 blocks of 16^3.
check "info json" "$rp" info gen:phantom:40x36x20 --json
has "info dims" '"dims":	\[40, 36, 20\]'
has "info blocks" '"block_count":	18'
has "info type" '"type":	"uint8"'
check "info hist" "$rp" info gen:noise:16x16x16:u16 --json --histograms
has "info hist H" '"density_histograms"'
has "info hist Ha" '"opacity_histograms"'
# White noise over 64 bins, 4096 voxels: the bins are all non-empty.
check "info text" "$rp" info gen:ml:33 --tf transparent
has "transparent empties all" "empty blocks:  27 (100.0 %)"

check "render" "$rp" render gen:phantom:48 --size 40x30 --shading \
  -o "$dir/a.png" --json
has "render json output" "\"output\":	\"$dir/a.png\""
has "render json size" '"width":	40'
if [ "$(head -c 8 "$dir/a.png" | od -An -tx1 | tr -d ' \n')" = \
     "89504e470d0a1a0a" ]; then pass=$((pass + 1)); else
  echo "FAIL: a.png is not a PNG"; fails=$((fails + 1)); fi
check "render ortho" "$rp" render gen:ml:20 --ortho --camera 0,90,2 \
  --size 9x7 --no-ert --no-skip -o "$dir/b.png"
has "render text" "wrote $dir/b.png"

# Ray-start jitter: a seed gives the same image every time, another seed
# or --no-jitter another image (a PNG holds the pixels and nothing that
# varies from run to run).
jr() { # jr OUT ARGS...: the reference's render of a small phantom
  out=$1; shift
  "$rp" render gen:phantom:32 --size 24x24 --backend reference \
    --step 2 -o "$dir/$out" "$@"
}
check "jitter seed 5" jr j5.png --seed 5
check "jitter seed 5 again" jr j5b.png --seed 5
check "jitter seed 6" jr j6.png --seed 6
check "no jitter" jr j0.png --no-jitter
check "no jitter, a seed" jr j0b.png --no-jitter --seed 9
if cmp -s "$dir/j5.png" "$dir/j5b.png" &&
   ! cmp -s "$dir/j5.png" "$dir/j6.png" &&
   ! cmp -s "$dir/j5.png" "$dir/j0.png" &&
   cmp -s "$dir/j0.png" "$dir/j0b.png"; then pass=$((pass + 1)); else
  echo "FAIL: jitter images (same seed equal, others differ)"
  fails=$((fails + 1)); fi
refuse "seed 0" "--seed 0 is out of range; must be a whole number in 1..4294967295" "$rp" render gen:ml:8 --seed 0 \
  -o "$dir/c.png"
refuse "seed -1" "--seed -1 is out of range" "$rp" render gen:ml:8 \
  --seed -1 -o "$dir/c.png"

# Data units: the CT head is int16 HU with its orientation; its default
# TF is ct-bone on [-500, 1500] HU; a window moves it; a TF file in HU.
check "ct info" "$rp" info gen:ct:24
has "ct type" "type:          int16"
has "ct orientation" "orientation:   L P S"
has "ct default tf" "under TF 'ct-bone'"
has "ct tf range" "tf range:      -500 .. 1500"
check "ct window" "$rp" info gen:ct:24 --window 400 --level 40
has "ct window range" "tf range:      -160 .. 240"
check "mri percentiles" "$rp" info gen:ct:24 --tf mri --json
has "mri json range" '"tf_range":'
printf 'units: data\n-100 0 0 0 0\n700 1 1 1 1\n' >"$dir/hu.tf"
check "tf file" "$rp" info gen:ct:24 --tf "$dir/hu.tf"
has "tf file range" "tf range:      -100 .. 700"
printf '0 0 0 0 0\n1 1 1\n' >"$dir/bad.tf"
refuse "bad tf file" "bad.tf: line 2" "$rp" info gen:ct:24 \
  --tf "$dir/bad.tf"
refuse "window without level" "go together" "$rp" info gen:ct:24 \
  --window 400
refuse "zero window" "raypace info: --window 0 is out of range; must be > 0 data units" "$rp" info gen:ct:24 \
  --window 0 --level 40
check "ct views" "$rp" render gen:ct:24 --size 16x16 --view left \
  --no-shading -o "$dir/v.png"
refuse "bad view" "--view up is not a view; must be anterior," "$rp" render gen:ct:24 \
  --view up -o "$dir/v.png"
refuse "view and camera" "--view excludes --camera" "$rp" render \
  gen:ct:24 --view left --camera 0,0,2 -o "$dir/v.png"

refuse "missing file" "no such file" "$rp" info "$dir/does-not-exist.nrrd"
refuse "bad preset" "known: transparent" "$rp" render gen:ml:8 --tf nope \
  -o "$dir/c.png"
refuse "bad size" "--size 0x5 is out of range; must be WxH, width and height each in 1..16384" "$rp" render gen:ml:8 --size 0x5 \
  -o "$dir/c.png"
refuse "bad generator" "unknown" "$rp" info gen:cube
refuse "zero step" "--step 0 is out of range; must be in \[0.001, 10000\] voxels" "$rp" render gen:ml:8 --step 0 \
  -o "$dir/c.png"
refuse "underflowing step" "--step 1e-50 is out of range" "$rp" render gen:ml:8 \
  --step 1e-50 -o "$dir/c.png"
refuse "overflowing fov" "--fov 1e39 is out of range" "$rp" render gen:ml:8 \
  --fov 1e39 -o "$dir/c.png"
refuse "unknown backend" "--backend warp is not a backend; must be opencl," "$rp" render gen:ml:8 \
  --backend warp -o "$dir/c.png"
refuse "no such device" "has one device" "$rp" render gen:ml:8 \
  --backend reference --device 3 -o "$dir/c.png"
refuse "scale above one" "--scale 1.5 is out of range; must be in \[0.01, 1\]" "$rp" render gen:ml:8 \
  --scale 1.5 -o "$dir/c.png"

# Every option's value is checked when parsed, before any work: the
# volume here does not exist, so a message about the option (and not
# "no such file") shows the check came first. Each names the option,
# the value as typed, and the range or form it must have.
nv="$dir/none.nrrd"
rr() { # rr NAME PATTERN ARGS...: render of the missing volume refused
  name=$1; pat=$2; shift 2
  refuse "$name" "$pat" "$rp" render "$nv" -o "$dir/c.png" "$@"
}
rr "fov range" "raypace render: --fov 179.9 is out of range; must be in \[0.01, 170\] degrees" --fov 179.9
rr "fov text" "--fov wide is not a number; must be in \[0.01, 170\]" \
  --fov wide
rr "ert range" "--ert-threshold 2 is out of range; must be in \[0.01, 1\]" \
  --ert-threshold 2
rr "step tiny" "--step 1e-9 is out of range; must be in \[0.001, 10000\] voxels" --step 1e-9
rr "scale tiny" "--scale 1e-9 is out of range; must be in \[0.01, 1\]" \
  --scale 1e-9
rr "brick size" "--brick-size 7 is out of range; must be 8, 16, 32, 64, 128 or 256" --brick-size 7
rr "brick size odd" "--brick-size 24 is not a power of two" --brick-size 24
rr "budget" "--budget-mb 0 is out of range; must be in \[0.001, 1e+09\]" \
  --budget-mb 0
rr "device range" "--device 2000 is out of range; must be a whole number in 0..1024" --device 2000
rr "background" "--background 2,0,0: R 2 is out of range; must be in \[0, 1\]" --background 2,0,0
rr "background form" "--background 1,1 is not R,G,B; must be 3 numbers" \
  --background 1,1
rr "size form" "--size 512 is not WxH; must be WxH, width and height each in 1..16384" --size 512
rr "size negative" "--size -5x5 is out of range; must be WxH" --size -5x5
rr "size pixels" "--size 16384x16384 is 268435456 pixels, over the limit; must be WxH, width and height each in 1..16384 and at most 67108864 pixels" --size 16384x16384
rr "camera behind" "--camera 0,0,-1: DIST -1 is out of range; must be in (0, 20000\] bounding radii; .*add 180 to AZ" --camera 0,0,-1
rr "camera pole" "--camera 0,100,2: EL 100 is out of range; must be in \[-90, 90\] degrees" --camera 0,100,2
rr "seed text" "--seed 1.5 is not a whole number; must be a whole number in 1..4294967295" --seed 1.5
rr "warmup" "--warmup 1e9 is out of range; must be a whole number in 0..10000" --warmup 1e9
rr "window" "--window nan is not a number; must be > 0 data units" \
  --window nan --level 0
rr "ao scheme" "--ao-scheme lazy is not an AO scheme; must be dynamic, static or naive" --ao-scheme lazy
refuse "output jpg" "-o $dir/x.jpg is a .jpg file; must end in .png or .ppm" \
  "$rp" render "$nv" -o "$dir/x.jpg"
refuse "output no dir" "-o $dir/no/x.png is in no directory; '$dir/no' does not exist" "$rp" render "$nv" -o "$dir/no/x.png"
refuse "output a dir" "-o $dir is a directory" "$rp" render "$nv" -o "$dir"
if [ ! -e "$dir/x.jpg" ]; then pass=$((pass + 1)); else
  echo "FAIL: output jpg: a file was written"; fails=$((fails + 1)); fi
# Each range's ends are accepted, by the option and by the library
# after it (the float limits such as 1e-3f are checked as the floats the
# values become).
for a in "--fov 0.01" "--fov 170" "--step 0.001" "--step 10000" \
    "--scale 0.01" "--ert-threshold 0.01" "--ert-threshold 1" \
    "--camera -360,-90,20000" "--camera 360,90,0.0001" "--size 16384x1" \
    "--background 0,0.5,1" "--seed 4294967295" "--warmup 0" \
    "--size 1x16384 --scale 1"; do
  # shellcheck disable=SC2086
  check "range end $a" "$rp" render gen:ml:8 --backend reference \
    --size 8x8 $a -o "$dir/e.png"
done
# The work bound, once the volume is open and before any device work:
# named by the step's option, with the counts and the limit.
refuse "work bound" "raypace render: --step 0.001 is too fine for this volume (8x8x8) at 8192x8192 rays: the frame may take .* samples, at most .* (RP_MAX_SAMPLES_PER_FRAME); use a coarser --step, or a smaller --size or --scale" "$rp" render gen:ml:8 --size 8192x8192 \
  --step 0.001 -o "$dir/c.png"
refuse "work bound replay" "raypace replay: --min-step 0.001 is too fine" \
  "$rp" replay gen:ml:8 --size 8192x8192 --min-step 0.001
refuse "work bound bench" "raypace bench quality: --ref-step 0.001 is too fine" "$rp" bench quality gen:ml:8 --size 8192x8192 --ref-step 0.001
# The device's errors name the options that chose it, not --backend.
refuse "device missing" "raypace: --backend reference --device 7: no usable device" "$rp" render gen:ml:8 --size 8x8 --backend reference \
  --device 7 -o "$dir/c.png"
# Backend mpi outside an MPI job: the launcher is missing, not a driver.
refuse "mpi without mpirun" "--backend mpi is a device on another MPI rank, and this process was not started by an MPI launcher; start it as 'mpirun -np N raypace render" env -u OMPI_COMM_WORLD_SIZE -u PMI_SIZE -u PMIX_SIZE \
  "$rp" render "$nv" --backend mpi -o "$dir/c.png"
refuse "mpi devices without mpirun" "--devices reference,mpi:0 is a device on another MPI rank" env -u OMPI_COMM_WORLD_SIZE -u PMI_SIZE \
  -u PMIX_SIZE "$rp" replay "$nv" --devices reference,mpi:0
# Generated volumes: sizes and seeds as typed, never 2^32 - 5.
refuse "gen negative" "gen:phantom:-5: size N -5 is out of range; must be a whole number in 1..65536" "$rp" info gen:phantom:-5
refuse "gen axis" "gen:ml:8x0x8: size Y 0 is out of range" "$rp" info \
  gen:ml:8x0x8
refuse "gen seed" "gen:noise:8:-1: seed -1 is out of range" "$rp" info \
  gen:noise:8:-1
if grep -q 4294967291 "$dir/err"; then
  echo "FAIL: gen seed: a negative number wrapped"; fails=$((fails + 1))
else pass=$((pass + 1)); fi
refuse "gen kind" "gen:cube: generator cube is unknown; must be ml, phantom, noise or ct" "$rp" info gen:cube
# replay: --frames 0 is refused (it used to play every frame).
rq() { # rq NAME PATTERN ARGS...: replay of the missing volume refused
  name=$1; pat=$2; shift 2
  refuse "$name" "$pat" "$rp" replay "$nv" "$@"
}
rq "replay frames 0" "raypace replay: --frames 0 is out of range; must be a whole number in 1..10000000" --frames 0
rq "replay target" "--target-ms 0 is out of range; must be in (0, 60000\] ms" --target-ms 0
rq "replay fraction" "--target-fraction 101 is out of range; must be in (0, 100\]" --target-fraction 101
rq "replay miss rate" "--miss-rate 0.7 is out of range; must be in (0, 0.5\] of the frames, or none" --miss-rate 0.7
rq "replay headroom" "--headroom 1 is out of range; must be in (0, 0.9\]" \
  --headroom 1
rq "replay base step" "--base-step 1e-9 is out of range; must be in \[0.001, 10000\] voxels" --base-step 1e-9
rq "replay settle" "--settle -1 is out of range; must be a whole number in 0..100000" --settle -1
rq "replay seed" "--seed 4294967296 is out of range" --seed 4294967296
rq "replay size" "--size 9000x9000 is 81000000 pixels, over the limit" \
  --size 9000x9000
rq "replay brick" "--brick-size 7 is out of range; must be 8, 16" \
  --brick-size 7
# --plot to a bad path names the plot, not a CSV never asked for.
rq "replay plot path" "--plot $dir/no/p.png is in no directory" \
  --plot "$dir/no/p.png"
if grep -q "\.csv" "$dir/err"; then
  echo "FAIL: replay plot path: names a CSV"; fails=$((fails + 1))
else pass=$((pass + 1)); fi
rq "replay plot form" "--plot $dir/p.svg is a .svg file; must end in .png" \
  --plot "$dir/p.svg"
rq "replay csv path" "--csv $dir/no/r.csv is in no directory" \
  --csv "$dir/no/r.csv"
refuse "bench quality plot" "raypace bench quality: --plot $dir/no/q.png is in no directory" "$rp" bench quality "$nv" --plot "$dir/no/q.png"
refuse "bench quality step" "raypace bench quality: --ref-step 0 is out of range" "$rp" bench quality "$nv" --ref-step 0
refuse "bench quality camera" "raypace bench quality: --camera 0,0,0: DIST 0 is out of range" "$rp" bench quality "$nv" --camera 0,0,0
refuse "bench overhead target" "raypace bench overhead: --target-ms -5 is out of range; must be in (0, 60000\] ms" "$rp" bench overhead "$nv" \
  --target-ms -5
refuse "bench overhead frames" "raypace bench overhead: --frames 0 is out of range; must be a whole number in 1..10000" "$rp" bench overhead "$nv" \
  --frames 0
# bench pacing checks the options it passes on before its first replay,
# in its own name.
refuse "bench pacing passed" "raypace bench pacing: --frames 0 is out of range" "$rp" bench pacing "$nv" --frames 0
refuse "bench pacing fov" "raypace bench pacing: --base-step 0 is out of range" "$rp" bench pacing "$nv" --base-step 0

# A camera and its mirror: an 8^3 volume opaque only at x = 6 and 7.
# From azimuth 0 (the eye on +z looking down -z, +y up) +x is on the
# image's right; from azimuth 180 on its left; from 90 (eye on +x) the
# marker faces the eye, left and right alike. The PPM's bytes are read
# directly: the sum of R+G+B over each half.
mk="$dir/marker_8x8x8_uint8.raw"
: >"$mk"
i=0
while [ $i -lt 64 ]; do
  printf '\000\000\000\000\000\000\377\377' >>"$mk"; i=$((i + 1)); done
halves() { # halves FILE: "LEFT RIGHT" sums of a 16x8 binary PPM
  tail -c $((16 * 8 * 3)) "$1" | od -An -v -tu1 -w3 |
    awk '{ s = $1 + $2 + $3; if ((NR - 1) % 16 < 8) l += s; else r += s }
         END { print l + 0, r + 0 }'
}
for az in 0 180 90; do
  check "marker $az" "$rp" render "$mk" --backend reference --size 16x8 \
    --camera $az,0,2.5 --no-jitter --tf minmax-bone -o "$dir/m$az.ppm"
done
if [ "$(head -c 2 "$dir/m0.ppm")" = P6 ] &&
   halves "$dir/m0.ppm" | awk '{ exit !($1 == 0 && $2 > 0) }' &&
   halves "$dir/m180.ppm" | awk '{ exit !($1 > 0 && $2 == 0) }' &&
   halves "$dir/m90.ppm" | awk '{ exit !($1 > 0 && $1 == $2) }'; then
  pass=$((pass + 1)); else
  echo "FAIL: marker sides (left right): az 0 $(halves "$dir/m0.ppm")," \
    "180 $(halves "$dir/m180.ppm"), 90 $(halves "$dir/m90.ppm")"
  fails=$((fails + 1)); fi

check "reference backend" "$rp" render gen:phantom:32 --backend reference \
  --size 40x30 --scale 0.5 -o "$dir/d.png" --json
has "reference backend named" '"backend":	"reference"'
has "scaled width" '"scaled_width":	20'
has "scaled height" '"scaled_height":	15'
has "output width" '"width":	40'
refuse "unwritable png" "$dir/no/such/dir/x.png" "$rp" render gen:ml:8 \
  --size 4x4 -o "$dir/no/such/dir/x.png"
refuse "unknown command" "unknown command" "$rp" frobnicate

# bench quality: a smoke test of the sweep, its JSON and its refusals.
check "bench quality" "$rp" bench quality gen:ml:32 --quick --json \
  --csv "$dir/q.csv"
has "bench psnr" '"psnr":	'
has "bench ssim" '"ssim":	'
has "bench budgets" '"budgets":'
if [ "$(head -1 "$dir/q.csv")" = \
     "space,rho,step,scale,rays_x,rays_y,ms,mse,psnr,ssim" ] &&
   [ "$(wc -l <"$dir/q.csv")" -eq 13 ]; then pass=$((pass + 1)); else
  echo "FAIL: bench csv"; cat "$dir/q.csv"; fails=$((fails + 1)); fi
# --sampling: plain, jittered, pre-integrated, both and the mean of
# jittered frames at steps 4 and 2 (--quick). The mean of 8 jittered
# frames is nearer the reference than one at each step: its noise
# averages out. Under a TF that is opaque only on a thin value interval
# (an iso-surface of the smooth Marschner-Lobb field) a step of 4 misses
# most of the surface, and pre-integration keeps it: its error is under
# half the plain one's (measured about a third).
check "bench sampling" "$rp" bench quality gen:phantom:32 --quick \
  --sampling --size 48x48 --shading --backend reference --csv "$dir/s.csv"
has "bench sampling table" "jittered-mean"
has "bench sampling preint" "jittered-preint"
if [ "$(head -1 "$dir/s.csv")" = "sampling,step,ms,mse,psnr,ssim" ] &&
   [ "$(wc -l <"$dir/s.csv")" -eq 11 ] &&
   awk -F, 'NR > 1 { mse[$1 "@" $2] = $4 }
     END { exit !(mse["jittered-mean@4"] < mse["jittered@4"] &&
                  mse["jittered-mean@2"] < mse["jittered@2"]) }' \
     "$dir/s.csv"; then pass=$((pass + 1)); else
  echo "FAIL: bench sampling csv"; cat "$dir/s.csv"; fails=$((fails + 1)); fi
printf '0.47 1 1 1 0\n0.48 1 0.85 0.6 0.8\n0.49 1 1 1 0\n' >"$dir/iso.tf"
check "bench sampling iso" "$rp" bench quality gen:ml:32 --quick \
  --sampling --size 32x32 --backend reference --tf "$dir/iso.tf" \
  --csv "$dir/p.csv"
if awk -F, 'NR > 1 { mse[$1 "@" $2] = $4 }
     END { exit !(mse["preint@4"] * 2 < mse["plain@4"]) }' "$dir/p.csv"
then pass=$((pass + 1)); else
  echo "FAIL: bench preint iso"; cat "$dir/p.csv"; fails=$((fails + 1)); fi
refuse "bench bad frames" "bench quality: --frames 0 is out of range; must be a whole number in 1..256" "$rp" bench quality \
  gen:ml:8 --quick --sampling --frames 0
check "bench help" "$rp" bench quality --help; has "bench help" "--ref-step"
refuse "bench bad runs" "bench quality: --runs 0 is out of range" "$rp" bench quality \
  gen:ml:8 --quick --runs 0
refuse "bench bad option" "unrecognized option" "$rp" bench quality \
  gen:ml:8 --quick --frobnicate
refuse "bench unknown" "unknown benchmark 'speed'" "$rp" bench speed
if command -v gnuplot >/dev/null 2>&1; then
  check "bench plot" "$rp" bench quality gen:ml:32 --quick \
    --plot "$dir/q.png"
  if [ -s "$dir/q.png" ] && [ "$(head -c 8 "$dir/q.png" | od -An -tx1 |
       tr -d ' \n')" = "89504e470d0a1a0a" ]; then pass=$((pass + 1)); else
    echo "FAIL: bench plot is not a PNG"; fails=$((fails + 1)); fi
fi

# replay: every controller over a short sequence on the scalar reference
# (no driver needed), its JSON, CSV and refusals.
check "replay list" "$rp" replay --list
has "replay list sequences" "tf-switch"
has "replay list controllers" "predicted"
check "replay all" "$rp" replay gen:phantom:24 --backend reference \
  --sequence tf-switch --frames 24 --settle 2 --size 32x32 --json --quiet \
  --csv "$dir/r.csv" --noise-csv "$dir/n.csv"
for c in none last-frame two-pass predicted vtk ue5 valve; do
  has "replay json $c" "\"controller\":\"$c\""
done
has "replay rmse" '"target_rmse_ms":'
has "replay switch overshoot" '"switch_overshoot":'
has "replay sigma" '"sigma_error_after_30":null'
if [ "$(head -1 "$dir/r.csv" | cut -d, -f1-5)" = \
     "controller,frame,target_ms,measured_ms,predicted_ms" ] &&
   [ "$(wc -l <"$dir/r.csv")" -eq $((7 * 24 + 1)) ]; then
  pass=$((pass + 1)); else
  echo "FAIL: replay csv"; head -3 "$dir/r.csv"; fails=$((fails + 1)); fi
# The still frame's noise figures, worked out again from its times: the
# switch at frame 20 starts a second segment. sd is about each segment's
# median (the middle pair's mean for an even count), sd_last against the
# frame before; a segment's first frame is not scored (22 of 24 are).
noise_of() { # noise_of FIELD: that field of the first JSON line's "noise"
  head -1 "$dir/out" |
    sed -n "s/.*\"noise\":{.*\"$1\":\([-0-9.e+]*\).*/\1/p"
}
if awk -F, -v sd="$(noise_of sd)" -v sl="$(noise_of sd_last)" '
  FNR == 1 { next }
  NR == FNR {  # first pass: the times of each segment, kept sorted
    n = ++cnt[$2]; i = n
    while (i > 1 && v[$2, i - 1] > $4 + 0) { v[$2, i] = v[$2, i - 1]; i-- }
    v[$2, i] = $4 + 0
    next
  }
  {            # second pass, in frame order
    if (!($2 in med)) {
      n = cnt[$2]
      med[$2] = n % 2 ? v[$2, (n + 1) / 2] \
                      : (v[$2, n / 2] + v[$2, n / 2 + 1]) / 2
      segs++
    } else {
      d = log($4 / med[$2]); se += d * d
      d = log($4 / last); se_last += d * d; k++
    }
    last = $4
  }
  function near(a, b) { return b > 0 && a / b > 0.999 && a / b < 1.001 }
  END { exit !(segs == 2 && k == 22 && near(sqrt(se / k), sd) &&
               near(sqrt(se_last / k), sl)) }' "$dir/n.csv" "$dir/n.csv"
then pass=$((pass + 1)); else
  echo "FAIL: replay noise (sd $(noise_of sd), sd_last $(noise_of sd_last))"
  cat "$dir/n.csv"; fails=$((fails + 1)); fi
refuse "replay noise csv" "needs the still frame" "$rp" replay gen:ml:8 \
  --backend reference --no-noise --noise-csv "$dir/x.csv"
# AO in steps: frames before the switch at 40 render with AO; the switch
# starts a new AO run, the frames during it render without AO, and one
# before frame 50 renders with it again (24^3: eight 16^3 jobs at most,
# at least one per frame). All seven controllers, frame by frame in
# turn, each on a device of its own: each sees the same, none another's
# run.
check "replay ao" "$rp" replay gen:phantom:24 --backend reference \
  --sequence ao-tf-switch --frames 50 --settle 2 --size 32x32 \
  --quiet --csv "$dir/ao.csv"
ao_col=$(head -1 "$dir/ao.csv" | tr ',' '\n' | grep -nx ao | cut -d: -f1)
ao_of() { awk -F, -v c="$ao_col" -v f="$1" '$2 == f { printf "%s", $c }' \
  "$dir/ao.csv"; }
if [ -n "$ao_col" ] && [ "$(ao_of 39)" = 1111111 ] &&
   [ "$(ao_of 40)" = 0000000 ] && [ "$(ao_of 49)" = 1111111 ]; then
  pass=$((pass + 1)); else
  echo "FAIL: replay ao (frames 39/40/49: $(ao_of 39)/$(ao_of 40)/$(ao_of 49))"
  fails=$((fails + 1)); fi
# Each controller's run is its own: every one renders at least two frames
# of 40..49 without AO (here seven; one run shared by all seven would be
# done within the first two rounds, one frame each for most).
short=$(awk -F, -v c="$ao_col" 'NR > 1 && $2 >= 40 && $2 < 50 {
          n[$1] += ($c == 0) } END { for (k in n) if (n[k] < 2) print k }' \
        "$dir/ao.csv")
if [ -n "$ao_col" ] && [ -z "$short" ]; then pass=$((pass + 1)); else
  echo "FAIL: replay ao runs (under two frames without AO: $short)"
  fails=$((fails + 1)); fi
# Back to the first TF while the second's AO is still being computed: the
# devices still hold the first's AO, so that frame renders with it, and
# the abandoned run is never stepped against the wrong TF.
cat >"$dir/back.json" <<'EOF'
{"frames": 8, "tfs": ["minmax-soft", "minmax-bone"],
 "events": [{"frame": 0, "camera": {"azimuth": 30, "distance": 2.5},
             "tf": 0, "target_fraction": 0.5,
             "effects": ["shading", "ao", "ert", "skip"]},
            {"frame": 4, "tf": 1}, {"frame": 5, "tf": 0}]}
EOF
check "replay ao back" "$rp" replay gen:phantom:24 --backend reference \
  --sequence "$dir/back.json" --settle 2 --size 32x32 \
  --quiet --csv "$dir/ao.csv"
if [ "$(ao_of 3)" = 1111111 ] && [ "$(ao_of 4)" = 0000000 ] &&
   [ "$(ao_of 5)" = 1111111 ]; then pass=$((pass + 1)); else
  echo "FAIL: replay ao back (frames 3/4/5: $(ao_of 3)/$(ao_of 4)/$(ao_of 5))"
  fails=$((fails + 1)); fi
check "replay table" "$rp" replay gen:ml:16 --backend reference \
  --sequence orbit --frames 4 --settle 1 --size 16x16 --controller vtk \
  --target-ms 5 --space ray --quiet
has "replay table header" "rmse_ms"
# One controller: the goal line has no reactive rule to compare with and
# says so, rather than print a ratio of NaN.
check "replay one controller" "$rp" replay gen:ml:16 --backend reference \
  --sequence orbit --frames 4 --settle 1 --size 16x16 \
  --controller predicted --target-ms 5 --quiet
has "replay goals alone" "no reactive controller played"
if grep -qi "nan" "$dir/out"; then
  echo "FAIL: replay one controller prints a NaN"; cat "$dir/out"
  fails=$((fails + 1)); else pass=$((pass + 1)); fi
# Per event class: cut-switch cuts the camera and switches the TF on
# frames 30 and 60; each event's class holds its frame and the two after
# it, smooth the other 58 of 64. The classes of the CSV's last column,
# counted here, and the predicted controller's smooth p95 (nearest rank:
# the ceil(0.95 n)-th of its t/target sorted) against the JSON's.
check "replay classes" "$rp" replay gen:ml:16 --backend reference \
  --sequence cut-switch --frames 64 --settle 1 --size 16x16 --json --quiet \
  --csv "$dir/cl.csv"
class_of() { # class_of CLASS FIELD: predicted's figure for that class
  grep '"controller":"predicted"' "$dir/out" |
    sed -n "s/.*\"$1\":{[^}]*\"$2\":\([-0-9.e+]*\).*/\1/p"
}
if [ "$(head -1 "$dir/cl.csv" | cut -d, -f16)" = tf_switch ] &&
   [ "$(head -1 "$dir/cl.csv" | awk -F, '{ print $(NF - 1) "," $NF }')" = \
     "events,classes" ] &&
   [ "$(awk -F, '$1 == "vtk" && ($2 == 30 || $2 == 60) { print $(NF - 1) }' \
       "$dir/cl.csv" | sort -u)" = "tf_switch+camera_cut" ] &&
   [ "$(awk -F, '$1 == "vtk" && $2 == 32 { print $(NF - 1) "/" $NF }' \
       "$dir/cl.csv")" = "none/tf_switch+camera_cut" ] &&
   [ "$(awk -F, '$1 == "predicted" && $NF == "smooth"' "$dir/cl.csv" |
       wc -l)" -eq 58 ] && [ "$(class_of smooth frames)" = 58 ] &&
   [ "$(class_of tf_switch frames)" = 6 ] &&
   [ "$(class_of camera_cut frames)" = 6 ] &&
   [ "$(class_of effect_toggle frames)" = 0 ] &&
   grep -q '"effect_toggle":{"frames":0,"miss_rate":null' "$dir/out"; then
  pass=$((pass + 1)); else
  echo "FAIL: replay classes"; head -1 "$dir/cl.csv"; cat "$dir/out"
  fails=$((fails + 1)); fi
p95=$(awk -F, '$1 == "predicted" && $NF == "smooth" { print $4 / $3 }' \
        "$dir/cl.csv" | sort -g |
      awk '{ v[NR] = $1 } END { k = int(0.95 * NR); if (k < 0.95 * NR) k++
                                print v[k] }')
if awk -v a="$p95" -v b="$(class_of smooth p95)" \
     'BEGIN { exit !(b > 0 && a / b > 0.99 && a / b < 1.01) }'; then
  pass=$((pass + 1)); else
  echo "FAIL: replay classes p95: $p95 from the CSV, $(class_of smooth p95)"
  fails=$((fails + 1)); fi
# --split on the deterministic test device. Without timing noise
# (noise=0) the same frame costs the same whatever ran
# before it, so context, switching and noise are 0 and the whole pass
# error is the model's. With a log-normal noise of 0.1, the repeats'
# spread (noise_rms) is that noise on the settled time: within 0.6x and
# 1.2x of 0.1 x rms(split_ms / target) worked out from the CSV (the
# depth pass's own draw dilutes it, a sample sd of 5 runs short).
split_of() { # split_of FIELD: the error split's figure
  sed -n "s/.*\"error_split\":{[^}]*\"$1\":\([-0-9.e+]*\).*/\1/p" \
    "$dir/out"
}
check "replay split exact" "$rp" replay gen:ml:32 --devices test:noise=0 \
  --sequence mixed --frames 60 --size 32x32 --controller predicted \
  --split 3 --json --quiet
if awk -v c="$(split_of context_rms)" -v s="$(split_of switch_rms)" \
     -v n="$(split_of noise_rms)" -v m="$(split_of model_rms)" \
     -v p="$(split_of pass_rms)" -v f="$(split_of frames)" \
     'BEGIN { exit !(f > 40 && p > 0.001 && c < 1e-9 && s < 1e-9 &&
                     n < 1e-9 && (m - p) ^ 2 < 1e-18) }'; then
  pass=$((pass + 1)); else
  echo "FAIL: replay split exact"; cat "$dir/out"; fails=$((fails + 1)); fi
check "replay split noise" "$rp" replay gen:ml:32 --devices test:noise=0.1 \
  --sequence mixed --frames 60 --size 32x32 --controller predicted \
  --split 5 --json --quiet --csv "$dir/split.csv"
want=$(awk -F, 'NR == 1 { for (i = 1; i <= NF; i++) col[$i] = i }
                NR > 1 && $col["split_ms"] != "nan" {
                  q += ($col["split_ms"] / $col["target_ms"]) ^ 2; n++ }
                END { print 0.1 * sqrt(q / n) }' "$dir/split.csv")
if awk -v a="$(split_of noise_rms)" -v b="$want" \
     'BEGIN { exit !(b > 0 && a / b > 0.6 && a / b < 1.2) }'; then
  pass=$((pass + 1)); else
  echo "FAIL: replay split noise: $(split_of noise_rms), want ~$want"
  fails=$((fails + 1)); fi
refuse "replay split needs predicted" "does not play it" "$rp" replay \
  gen:ml:16 --backend reference --controller vtk --split 3
refuse "replay split repeats" "--split 1 is out of range; must be a whole number in 2..50" "$rp" replay \
  gen:ml:16 --backend reference --split 1
# bench pacing: each sequence's median is the middle of its three runs'
# figures, picked here from the JSON by awk for two of them.
check "bench pacing json" "$rp" bench pacing gen:ml:16 --backend reference \
  --sequences orbit,tf-switch --runs 3 --frames 6 --settle 1 --size 16x16 \
  --json --quiet
if [ "$(grep -c '"runs":3,' "$dir/out")" = 2 ]; then pass=$((pass + 1))
else echo "FAIL: bench pacing: not two sequences of 3 runs"; cat "$dir/out"
  fails=$((fails + 1)); fi
for field in ratio_reachable density_vs_two_pass late; do
  bad=$(awk -v f="\"$field\":" '{
    n = 0; s = $0
    while ((i = index(s, f)) > 0) {
      s = substr(s, i + length(f)); v[n++] = s + 0 }
    # v[0] the median, v[1..3] the runs: the median of three is the one
    # neither under nor over both others.
    m = v[1]
    if ((v[2] - v[1]) * (v[2] - v[3]) <= 0) m = v[2]
    if ((v[3] - v[1]) * (v[3] - v[2]) <= 0) m = v[3]
    if (n != 4 || v[0] != m) print NR ": " n " values, median " v[0] " not " m
  }' "$dir/out")
  if [ -z "$bad" ]; then pass=$((pass + 1)); else
    echo "FAIL: bench pacing median of $field: $bad"; fails=$((fails + 1)); fi
done
check "bench pacing table" "$rp" bench pacing gen:ml:16 --backend reference \
  --sequences orbit --runs 2 --frames 4 --settle 1 --size 16x16 --quiet
has "bench pacing met" "  met [R.][O.][D.][L.][M.][T.][E.]$"
has "bench pacing each run" "^orbit #2 "
refuse "bench pacing runs" "--runs 0 is out of range; must be a whole number in 1.." "$rp" bench pacing \
  gen:ml:8 --runs 0
refuse "bench pacing sequence" "no-such-seq" "$rp" bench pacing gen:ml:8 \
  --backend reference --sequences no-such-seq --runs 1 --quiet
# A volume named like an option reaches replay as a volume, not as one
# of its options (replay's --help would end the run with no figures).
refuse "bench pacing volume" "no such file" "$rp" bench pacing \
  --backend reference --sequences orbit --runs 1 --frames 2 --quiet \
  -- --help
refuse "replay controller" "unknown controller 'pid'" "$rp" replay \
  gen:ml:8 --controller pid
# bench pacing --pareto on the deterministic test device: every point is
# the replay of its setting, so the point of a controller that plays
# first in its replays (predicted; vtk when it plays alone) holds the
# very figures a plain replay of that controller and setting gives
# (here each of the two compared has a miss rate, share over 1.2x and
# density that differ, so that no figure can stand in for another).
pareto="gen:ml:24 --backend test --size 48x48 --frames 30 --settle 2"
check "pareto json" "$rp" bench pacing $pareto --sequences orbit --runs 1 \
  --pareto --headrooms default,0.3 --miss-rates 0.05,0.2 --json --quiet
cp "$dir/out" "$dir/pareto.json"
# The first number after "NAME": in stdin (the line's first such field).
json_num() { awk -v f="\"$1\":" '{ i = index($0, f)
  if (i > 0) { print substr($0, i + length(f)) + 0; exit } }'; }
# The figures of one point: controller $1 at setting $2, in file $3.
point_of() { sed -n "s/.*\"controller\":\"$1\",\"setting\":\"$2\",\
\([^[]*\)\"each\".*/\1/p" "$3"; }
if [ "$(grep -o '"controller":"[a-z0-9-]*","setting"' \
        "$dir/pareto.json" | sort | uniq -c | awk '$1 == 2' | wc -l)" = 5 ] \
   && [ "$(grep -o '"frames":30,' "$dir/pareto.json" | wc -l)" = 20 ] \
   && grep -q '"replays_per_run":2,' "$dir/pareto.json" \
   && grep -q '"compared_at":0.05,' "$dir/pareto.json"; then
  pass=$((pass + 1)); else
  echo "FAIL: pareto json: not 5 controllers x 2 settings of 30 frames"
  cat "$dir/pareto.json"; fails=$((fails + 1)); fi
same_point() { # same_point NAME CONTROLLER SETTING PARETO_JSON REPLAY_JSON
  for f in miss_rate share_over_1_2 mean_density; do
    a=$(point_of "$2" "$3" "$4" | json_num $f)
    b=$(json_num $f <"$5")
    if [ -n "$a" ] && [ "$a" = "$b" ]; then pass=$((pass + 1)); else
      echo "FAIL: $1: $f $a in the sweep, $b in the replay"
      fails=$((fails + 1)); fi
  done
}
check "pareto replay predicted" "$rp" replay $pareto --sequence orbit \
  --controller predicted --miss-rate 0.2 --json --quiet
same_point "pareto predicted 0.2" predicted 0.2 "$dir/pareto.json" \
  "$dir/out"
check "pareto vtk" "$rp" bench pacing $pareto --sequences orbit --runs 1 \
  --pareto --controllers vtk --headrooms 0.3,default --json --quiet
cp "$dir/out" "$dir/pareto-vtk.json"
has "pareto vtk alone" '"replays_per_run":2,"points":\[{"controller":"vtk"'
check "pareto replay vtk" "$rp" replay $pareto --sequence orbit \
  --controller vtk --json --quiet
same_point "pareto vtk default" vtk default "$dir/pareto-vtk.json" \
  "$dir/out"
check "pareto table" "$rp" bench pacing $pareto --sequences orbit \
  --runs 2 --pareto --headrooms default,0.3 --miss-rates 0.05 --quiet
has "pareto table point" "^  vtk         0.3 *30 "
has "pareto table compared" "^  compared (medians): predicted"
has "pareto table run" "^  run 2: predicted"
has "pareto table goals" "^  goals: d/best >= 1.3 "
if command -v gnuplot >/dev/null 2>&1; then
  check "pareto plot" "$rp" bench pacing $pareto --runs 1 \
    --sequences orbit,cut-switch --pareto --headrooms default,0.3 \
    --miss-rates 0.05,0.2 --quiet --plot "$dir/pareto.png"
  if [ "$(head -c 8 "$dir/pareto.png" | od -An -tx1 | tr -d ' \n')" = \
       "89504e470d0a1a0a" ]; then pass=$((pass + 1)); else
    echo "FAIL: pareto.png is not a PNG"; fails=$((fails + 1)); fi
fi
refuse "pareto headroom range" "--headrooms 0.1,0.95: 0.95 is out of range; must be in (0, 0.9\] of the target, or default" "$rp" \
  bench pacing gen:ml:8 --pareto --headrooms 0.1,0.95
refuse "pareto miss range" "--miss-rates 0.05,some: some is not a number; must be in (0, 0.5\] of the frames, or none" "$rp" \
  bench pacing gen:ml:8 --pareto --miss-rates 0.05,some
refuse "pareto swept" "--pareto sweeps --headroom itself" "$rp" \
  bench pacing gen:ml:8 --pareto --headroom 0.1
refuse "pareto alone" "--headrooms needs --pareto" "$rp" bench pacing \
  gen:ml:8 --headrooms 0.1
refuse "pareto controllers" "'two-pass' is not one of" "$rp" bench pacing \
  gen:ml:8 --pareto --controllers vtk,two-pass
refuse "replay controller twice" "names 'vtk' twice" "$rp" replay \
  gen:ml:8 --controller vtk,predicted,vtk
refuse "replay sequence" "no-such-seq" "$rp" replay gen:ml:8 \
  --backend reference --sequence no-such-seq
refuse "replay targets" "exclude each other" "$rp" replay gen:ml:8 \
  --target-ms 5 --target-fraction 0.5
refuse "replay space" "--space diagonal is not a space; must be ray, image or hybrid" "$rp" replay \
  gen:ml:8 --space diagonal
refuse "replay min step" "--min-step 2 is over the base step; must be at most --base-step (1)" "$rp" replay gen:ml:8 \
  --min-step 2
# A budget far above any frame's cost, --min-step a quarter of the base
# step: the predicted controller ends at the finest step (density 4),
# NONE stays at the base step.
check "replay min step" "$rp" replay gen:ml:16 --backend reference \
  --sequence orbit --frames 6 --settle 2 --size 16x16 --target-ms 1000 \
  --min-step 0.25 --quiet --csv "$dir/ms.csv"
last_of() { awk -F, -v c="$1" '$1 == c && $2 == 5 { print $8 "/" $9 }' \
  "$dir/ms.csv"; }
if [ "$(last_of predicted)" = "4/0.25" ] &&
   [ "$(last_of none)" = "1/1" ]; then pass=$((pass + 1)); else
  echo "FAIL: replay min step (predicted $(last_of predicted), none" \
    "$(last_of none))"; fails=$((fails + 1)); fi
if command -v gnuplot >/dev/null 2>&1; then
  check "replay plot" "$rp" replay gen:ml:16 --backend reference \
    --sequence zoom-in --frames 6 --settle 1 --size 16x16 --quiet \
    --plot "$dir/r.png"
  if [ -s "$dir/r.png" ] && [ ! -e "$dir/r.png.csv" ]; then
    pass=$((pass + 1)); else
    echo "FAIL: replay plot"; fails=$((fails + 1)); fi
fi

# bench overhead: a stage runs as often as its event is posted: H per
# volume load (2), the probe per camera (every frame), predict per frame.
check "bench overhead" "$rp" bench overhead gen:phantom:32 --frames 12 \
  --loads 2 --size 64x64 --backend reference
has "overhead H" 'H build  *volume  *2 '
has "overhead probe" 'probe (host depth + ERT)  *camera  *12 '
has "overhead predict" 'predict  *frame  *12 '
has "overhead share" 'per-frame prediction work'
check "bench overhead json" "$rp" bench overhead gen:ml:16 --frames 4 \
  --loads 1 --size 32x32 --backend reference --json
has "overhead json" '"stage":	"train"'
refuse "bench overhead loads" "--loads 3 is more than --frames; must be at most --frames (2)" "$rp" bench overhead gen:ml:8 \
  --frames 2 --loads 3 --backend reference

# Device groups (--devices): the list's parser, then renders and a replay.
# The reference needs no driver; OpenCL parts skip without a device.
regions_ok() { # regions_ok W H NAME [KEY]: the JSON's KEYs (default
  # region: the devices' and the tail strips') are disjoint, lie in the
  # WxH image and cover it; two or more
  if grep -F "\"${4:-region}\":" "$dir/out" | tr -d '[],' |
     awk -v W="$1" -v H="$2" '
    { n = NR; x0[n] = $2; y0[n] = $3; x1[n] = $4; y1[n] = $5 }
    END {
      a = 0
      for (i = 1; i <= n; i++) {
        if (x0[i] > x1[i] || y0[i] > y1[i] || x1[i] > W || y1[i] > H)
          exit 1
        a += (x1[i] - x0[i]) * (y1[i] - y0[i])
        for (j = 1; j < i; j++)
          if (x0[i] < x1[j] && x0[j] < x1[i] && y0[i] < y1[j] &&
              y0[j] < y1[i] && x0[i] < x1[i] && y0[i] < y1[i] &&
              x0[j] < x1[j] && y0[j] < y1[j])
            exit 1
      }
      exit !(n >= 2 && a == W * H)
    }'; then pass=$((pass + 1)); else
    echo "FAIL: $3: regions not a partition of ${1}x$2"; cat "$dir/out"
    fails=$((fails + 1)); fi
}
is_png() { # is_png NAME FILE
  if [ -s "$2" ] && [ "$(head -c 8 "$2" | od -An -tx1 | tr -d ' \n')" = \
       "89504e470d0a1a0a" ]; then pass=$((pass + 1)); else
    echo "FAIL: $1: $2 is not a PNG"; fails=$((fails + 1)); fi
}
g="$dir/g.png"
refuse "devices backend" "backend 'cuda' in 'cuda'" "$rp" render gen:ml:8 \
  --devices cuda -o "$g"
refuse "devices index" "raypace: --devices opencl:x: index x is not a device index; must be a whole number in 0..1024" "$rp" render \
  gen:ml:8 --devices reference,opencl:x -o "$g"
refuse "devices cu" "--devices opencl:0:cu=0: cu 0 is out of range; must be a whole number in 1..65536 (compute units" "$rp" render gen:ml:8 \
  --devices opencl:0:cu=0 -o "$g"
refuse "devices slow" "--devices reference:0:slow=0.5: slow 0.5 is out of range; must be in \[1, 10000\]" "$rp" render gen:ml:8 \
  --devices reference:0:slow=0.5 -o "$g"
refuse "devices slow nan" "reference:slow=nan: slow nan is not a number" "$rp" render gen:ml:8 \
  --devices reference:slow=nan -o "$g"
refuse "devices fail" "reference:fail=-1: fail -1 is out of range; must be a whole number in 0..4294967295" "$rp" render gen:ml:8 \
  --devices reference:fail=-1 -o "$g"
refuse "devices empty" "empty device" "$rp" render gen:ml:8 \
  --devices reference,,reference -o "$g"
refuse "devices trailing" "empty device" "$rp" render gen:ml:8 \
  --devices reference, -o "$g"
refuse "devices twice" "'cu' is given twice" "$rp" render gen:ml:8 \
  --devices opencl:0:cu=2:cu=3 -o "$g"
refuse "devices field" "field 'bogus=1' in 'reference:0:bogus=1'" "$rp" \
  render gen:ml:8 --devices reference:0:bogus=1 -o "$g"
refuse "devices late index" "field '1' in 'opencl:cu=2:1'" "$rp" render \
  gen:ml:8 --devices opencl:cu=2:1 -o "$g"
refuse "devices too many" "at most 8 devices" "$rp" render gen:ml:8 \
  --devices reference,reference,reference,reference,reference,reference,\
reference,reference,reference -o "$g"
refuse "devices and backend" "excludes --backend" "$rp" render gen:ml:8 \
  --devices reference --backend reference -o "$g"
refuse "devices and device" "excludes --backend" "$rp" render gen:ml:8 \
  --device 0 --devices reference -o "$g"
refuse "overlay alone" "needs --devices" "$rp" render gen:ml:8 \
  --overlay-split -o "$g"
refuse "replay devices and backend" "excludes --backend" "$rp" replay \
  gen:ml:8 --backend reference --devices reference
refuse "replay devices" "backend 'gpu'" "$rp" replay gen:ml:8 \
  --devices gpu
refuse "devices cu on reference" "device 1" "$rp" render gen:ml:8 \
  --size 8x8 --devices reference,reference:0:cu=2 -o "$g"

# Accepted lists on the reference: every field, one losing its device.
check "group reference" "$rp" render gen:phantom:32 --size 40x24 \
  --devices reference:0:slow=1.5:fail=0,reference --overlay-split --json \
  -o "$g"
has "group reference devices" '"devices":'
has "group reference backend" '"backend":	"group"'
regions_ok 40 24 "group reference"
is_png "group reference png" "$g"
check "group reference lost" "$rp" render gen:phantom:32 --size 32x32 \
  --devices reference:fail=1,reference,reference --warmup 2 -o "$g"
has "group reference lost line" "device 0 .*LOST (EDEVICE"
has "group reference alive" "of 3 devices alive"
check "warmup one device" "$rp" render gen:ml:16 --size 16x16 --warmup 2 \
  --backend reference -o "$g"
check "group scaled" "$rp" render gen:phantom:32 --size 50x30 --scale 0.5 \
  --devices reference,reference --json -o "$g"
regions_ok 25 15 "group scaled"
regions_ok 50 30 "group scaled output" output_region

# The deterministic test device: named only, the reference's image byte
# for byte, in a group and in replay too; its options in device specs.
check "test backend" "$rp" render gen:phantom:32 --backend test \
  --size 40x30 --shading --json -o "$dir/t.png"
has "test backend named" '"backend":	"test"'
check "test backend reference" "$rp" render gen:phantom:32 \
  --backend reference --size 40x30 --shading -o "$dir/r.png"
if cmp -s "$dir/t.png" "$dir/r.png"; then pass=$((pass + 1)); else
  echo "FAIL: test backend: its PNG is not the reference's"
  fails=$((fails + 1)); fi
check "test devices" "$rp" render gen:phantom:32 --size 40x24 \
  --devices test:0:seed=7:noise=0,test:slow=2:noise=0.1 --json -o "$g"
regions_ok 40 24 "test devices"
refuse "seed on reference" "'seed=1' in 'reference:seed=1' is for backend" \
  "$rp" render gen:ml:8 --devices reference:seed=1 -o "$g"
refuse "test noise range" "--devices test:noise=2: noise 2 is out of range; must be in \[0, 1\]" "$rp" render \
  gen:ml:8 --devices test:noise=2 -o "$g"
check "replay test" "$rp" replay gen:phantom:24 --backend test \
  --sequence tf-switch --frames 12 --settle 2 --size 32x32 --json --quiet \
  --controller predicted
has "replay test controller" '"controller":"predicted"'
check "replay test devices" "$rp" replay gen:phantom:24 \
  --devices test:0:seed=1,test:0:seed=2 --sequence tf-switch --frames 8 \
  --settle 2 --size 32x32 --quiet --controller predicted

if "$rp" render gen:ml:8 --size 8x8 --backend opencl -o "$g" \
    >/dev/null 2>&1; then
  check "group opencl overlay" "$rp" render gen:phantom:64 --size 64x64 \
    --devices opencl:0,opencl:0 --overlay-split --json -o "$g"
  is_png "group opencl png" "$g"
  regions_ok 64 64 "group opencl overlay"
  has "group opencl status" '"status":	"ok"'
  check "group opencl fail" "$rp" render gen:phantom:64 --size 64x64 \
    --devices opencl:0,opencl:0:fail=1 --json -o "$g"
  is_png "group opencl fail png" "$g"
  has "group opencl lost" '"lost":	true'
  has "group opencl lost status" '"status":	"EDEVICE"'
  has "group opencl alive" '"devices_alive":	1'
  check "group opencl fail text" "$rp" render gen:phantom:64 \
    --size 64x64 --devices opencl:0:fail=1,opencl:0 -o "$g"
  has "group opencl fail text" "device 0 .*LOST (EDEVICE"
  # Out of core: a 96^3 phantom (864 KB) through a pool of 0.2 MB renders
  # the PNG the whole volume gives, byte for byte.
  check "render in core" "$rp" render gen:phantom:96 --size 160x120 \
    --shading --backend opencl -o "$dir/ic.png"
  check "render out of core" "$rp" render gen:phantom:96 --size 160x120 \
    --shading --backend opencl --budget-mb 0.2 --brick-size 8 --json \
    -o "$dir/oc.png"
  has "out of core json" '"out_of_core":'
  has "out of core parts" '"parts":'
  if cmp -s "$dir/ic.png" "$dir/oc.png"; then pass=$((pass + 1)); else
    echo "FAIL: out-of-core PNG differs from in-core"; fails=$((fails + 1))
  fi
  check "render out of core text" "$rp" render gen:phantom:96 \
    --size 160x120 --backend opencl --budget-mb 0.2 -o "$dir/oc.png"
  has "out of core text" "out of core: .* bricks of 16^3"
  refuse "budget too small" "at least 2" "$rp" render gen:phantom:96 \
    --size 16x16 --backend opencl --budget-mb 0.001 -o "$dir/oc.png"
  refuse "bad brick size" "--brick-size 12 is not a power of two; must be 8, 16," "$rp" render gen:phantom:96 \
    --size 16x16 --backend opencl --budget-mb 0.2 --brick-size 12 \
    -o "$dir/oc.png"
  check "replay out of core" "$rp" replay gen:phantom:64 --backend opencl \
    --budget-mb 0.2 --brick-size 8 --sequence orbit --frames 6 --settle 1 \
    --size 64x64 --controller predicted --quiet --csv "$dir/oc.csv"
  if head -1 "$dir/oc.csv" |
     grep -q "upload_ms,upload_predicted_ms,pass_predicted_ms,render_ms,\
margin,novelty,split_first_ms,split_ms,split_sd_ms,events,classes$"
  then pass=$((pass + 1)); else
    echo "FAIL: replay csv lacks upload columns"; head -1 "$dir/oc.csv"
    fails=$((fails + 1)); fi
else
  echo "SKIP: no OpenCL device: group renders on opencl"
fi

check "replay devices" "$rp" replay gen:phantom:24 --devices \
  reference,reference:0:slow=2 --sequence orbit --frames 6 --settle 1 \
  --size 32x32 --controller predicted --json --quiet --csv "$dir/d.csv"
has "replay devices imbalance" '"mean_imbalance":'
has "replay devices alive" '"devices_alive":'
cols="tf_switch,dev0_share,dev0_busy_ms,dev0_raycast_ms,dev0_samples"
cols="$cols,dev1_share,dev1_busy_ms,dev1_raycast_ms,dev1_samples,imbalance"
cols="$cols,ao_ms,ao,upload_ms,upload_predicted_ms"
cols="$cols,dev0_tail_share,dev1_tail_share,pass_predicted_ms,render_ms"
cols="$cols,margin,novelty,split_first_ms,split_ms,split_sd_ms,events,classes"
# The shares sum to 1. The default tail (the fewest bottom tile rows
# holding 0.15 of the cost, never every row) is cut when the scaled
# image, rp_scaled_size of the 32x32 output at the row's scale, has two
# tile rows or more, and went to the two devices whole: a positive share
# then, none otherwise.
if [ "$(head -1 "$dir/d.csv" | cut -d, -f16-)" = "$cols" ] &&
   [ "$(wc -l <"$dir/d.csv")" -eq 7 ] &&
   [ "$(awk -F, 'NR > 1 && ($17 + $21 - 1)^2 > 1e-8 { n++ }
                 NR > 1 { sh = int(32 * $10 + 0.5); t = $30 + $31 }
                 NR > 1 && sh >= 9 && !(t > 0 && t < 1) { n++ }
                 NR > 1 && sh < 9 && t != 0 { n++ }
                 END { print n + 0 }' \
       "$dir/d.csv")" -eq 0 ]; then
  pass=$((pass + 1)); else
  echo "FAIL: replay devices csv"; cat "$dir/d.csv"; fails=$((fails + 1))
fi
check "replay devices table" "$rp" replay gen:ml:16 --devices \
  reference,reference:0:fail=3 --sequence orbit --frames 4 --settle 1 \
  --size 16x16 --controller vtk --quiet
has "replay devices table" "imbal  alive"
if command -v gnuplot >/dev/null 2>&1; then
  check "replay devices plot" "$rp" replay gen:ml:16 --devices \
    reference,reference --sequence orbit --frames 6 --settle 1 \
    --size 16x16 --quiet \
    --plot "$dir/dp.png"
  is_png "replay devices plot" "$dir/dp-devices.png"
fi

if [ -n "${RP_SHARED_DATA:-}" ] && [ -f "$RP_SHARED_DATA/bonsai/bonsai.txt" ]
then
  check "bonsai info" "$rp" info "$RP_SHARED_DATA/bonsai/bonsai.txt" --json
  has "bonsai dims" '"dims":	\[256, 256, 256\]'
  has "bonsai max" '"max":	255'
fi

echo "$pass passed, $fails failed"
[ "$fails" -eq 0 ]
