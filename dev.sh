#!/bin/sh
# Set-up, build and run on Debian 12.
#   ./dev.sh demo   install what is missing, build, render the demo image
#   ./dev.sh test   install what is missing, build, run every test: the
#                   plain build, then AddressSanitizer + UBSan (each
#                   fuzz target replays its seed corpus in both),
#                   ThreadSanitizer, clang's static analyzer; it ends
#                   with one line that counts what passed, failed and
#                   was skipped over every stage
#   ./dev.sh fuzz [SECONDS]
#                   build the libFuzzer targets with clang and fuzz each
#                   for SECONDS (default 60) from its corpus
#   ./dev.sh soak   install what is missing, then the soak (docs/soak.md):
#                   10^5 frames under AddressSanitizer + UBSan, 10^4 under
#                   ThreadSanitizer (SOAK_FRAMES / SOAK_TSAN_FRAMES)
set -eu
cd "$(dirname "$0")"
mode=${1:-}
case "$mode" in demo|test|fuzz|soak) ;; *)
  echo "usage: ./dev.sh demo|test|fuzz [SECONDS]|soak" >&2; exit 2;; esac

PKGS="cmake make gcc clang libclang-rt-14-dev pkg-config zlib1g-dev
libpng-dev libcjson-dev libuv1-dev libcmocka-dev ocl-icd-opencl-dev
opencl-headers pocl-opencl-icd libvulkan-dev mesa-vulkan-drivers glslc
g++ libdlib-dev libjpeg-dev libblas-dev liblapack-dev gnuplot-nox
libopenmpi-dev openmpi-bin libnifti2-dev libgdcm-dev"
missing=""
for p in $PKGS; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "ok installed" ||
    missing="$missing $p"
done
if [ -n "$missing" ]; then
  echo "installing:$missing"
  sudo=""
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null 2>&1 || {
      echo "dev.sh: not root and no sudo: install as root:$missing" >&2
      exit 1
    }
    sudo=sudo
  fi
  $sudo apt-get update -qq
  # env, because sudo resets the environment; splitting the list is meant.
  # shellcheck disable=SC2086
  $sudo env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
    --no-install-recommends $missing
fi

jobs=$(nproc 2>/dev/null || echo 2)
build() { # build DIR [cmake args...]
  dir=$1; shift
  cmake -S . -B "$dir" "$@" >/dev/null
  cmake --build "$dir" -j "$jobs"
}

if [ "$mode" = demo ]; then
  build build -DCMAKE_BUILD_TYPE=Release
  mkdir -p out
  # A generated CT head in HU under the bone window, from the front.
  ./build/raypace render gen:ct:160 --tf ct-bone --size 512x512 \
    -o out/demo.png
  echo "demo image: $(pwd)/out/demo.png"
  exit 0
fi

if [ "$mode" = fuzz ]; then
  CC=clang CXX=clang++ build build-fuzz -DRP_FUZZ=ON -DRP_BUILD_TESTS=OFF \
    -DRP_BUILD_CLI=OFF -DRP_BUILD_SAMPLES=OFF -DRP_BUILD_BENCH=OFF
  FUZZ_SECONDS=${2:-60} sh fuzz/run_corpus.sh build-fuzz/fuzz/fuzz_*
  exit $?
fi

if [ "$mode" = soak ]; then
  # Build dirs of its own: RP_SOAK registers the soak with ctest, which
  # the default suite's dirs must not. A small ASan quarantine, so that
  # resident memory settles within the warm-up (the default 256 MB takes
  # most of the run to fill and reads as growth).
  build build-soak-asan -DRP_ASAN=ON -DRP_UBSAN=ON -DRP_SOAK=ON \
    -DRP_SOAK_FRAMES="${SOAK_FRAMES:-100000}" -DRP_BUILD_CLI=OFF \
    -DRP_BUILD_SAMPLES=OFF -DRP_BUILD_BENCH=OFF
  ASAN_OPTIONS=detect_leaks=1:intercept_tls_get_addr=0:quarantine_size_mb=16 \
    UBSAN_OPTIONS=print_stacktrace=1 \
    LSAN_OPTIONS="suppressions=$(pwd)/tests/lsan.supp:print_suppressions=0" \
    ctest --test-dir build-soak-asan -L soak --output-on-failure
  build build-soak-tsan -DRP_TSAN=ON -DRP_SOAK=ON \
    -DRP_SOAK_FRAMES="${SOAK_TSAN_FRAMES:-10000}" -DRP_BUILD_CLI=OFF \
    -DRP_BUILD_SAMPLES=OFF -DRP_BUILD_BENCH=OFF
  TSAN_OPTIONS=halt_on_error=1 \
    ctest --test-dir build-soak-tsan -L soak --output-on-failure
  echo "soak figures: build-soak-asan/tests/soak/soak.json," \
    "build-soak-tsan/tests/soak/soak.json"
  exit 0
fi

# Every stage runs even when an earlier one failed, so that one run
# shows every failure; the last line counts them over all stages and the
# exit status is non-zero when anything failed.
passed=0 failed=0 skipped=0 broken=""
logdir=$(mktemp -d)
trap 'rm -rf "$logdir"' EXIT
stage() { # stage NAME BUILD-DIR [ctest args...]: run and count one ctest stage
  name=$1 dir=$2; shift 2
  log="$logdir/$name"
  { ctest --test-dir "$dir" -j "$jobs" --output-on-failure \
      --no-tests=error "$@"
    echo $? >"$log.rc"; } 2>&1 | tee "$log"
  # A test's own line: "12/54 Test #12: test_x ....   Passed  0.1 sec".
  lines=$(grep -E '^ *[0-9]+/[0-9]+ Test +#[0-9]+: ' "$log" || true)
  p=$(printf '%s\n' "$lines" | grep -c ' Passed ' || true)
  s=$(printf '%s\n' "$lines" | grep -c 'Skipped' || true)
  n=$(printf '%s\n' "$lines" | grep -c 'Test' || true)
  f=$((n - p - s))
  # ctest failing with no test line failing (no tests found, a crash of
  # ctest itself) still fails the stage.
  if [ "$(cat "$log.rc")" -ne 0 ] && [ "$f" -eq 0 ]; then f=1; fi
  passed=$((passed + p)) failed=$((failed + f)) skipped=$((skipped + s))
  [ "$f" -eq 0 ] || broken="$broken $name"
  echo "dev.sh: $name: $p passed, $f failed, $s skipped"
}
try_build() { # try_build NAME DIR [cmake args...]: a build that fails counts
  name=$1; shift
  if build "$@"; then return 0; fi
  failed=$((failed + 1)) broken="$broken $name(build)"
  return 1
}

# The demo's configuration (Release, -O3): GCC's -O3 warnings differ
# from -O2's, and under -Werror a warning only -O3 raises once broke
# './dev.sh demo' while every test passed.
if try_build plain build -DCMAKE_BUILD_TYPE=Release; then
  stage plain build
fi
# intercept_tls_get_addr=0: up to GCC 13 the sanitizer runtime's
# __tls_get_addr interceptor can take a malloc'd dynamic TLS block for a
# pre-2.25 glibc header and make LeakSanitizer's tracer crash at exit
# ("Tracer caught signal 11", no leak reported; seen once here in
# test_cl_backend, whose PoCL libraries use dynamic TLS).
# The sanitizer stages reuse the plain stage's compiled kernels (see
# RP_TEST_CACHE_DIR in tests/CMakeLists.txt).
cache="-DRP_TEST_CACHE_DIR=$(pwd)/build"
if try_build asan build-asan -DRP_ASAN=ON -DRP_UBSAN=ON -DRP_BUILD_CLI=ON \
  "$cache"; then
  ASAN_OPTIONS=detect_leaks=1:intercept_tls_get_addr=0 \
    UBSAN_OPTIONS=print_stacktrace=1 \
    LSAN_OPTIONS="suppressions=$(pwd)/tests/lsan.supp:print_suppressions=0" \
    stage asan+ubsan build-asan -E test_install_consumer
fi
# ThreadSanitizer over the tests that run worker threads.
if try_build tsan build-tsan -DRP_TSAN=ON -DRP_BUILD_CLI=OFF \
  -DRP_BUILD_SAMPLES=OFF -DRP_BUILD_BENCH=OFF "$cache"; then
  stage tsan build-tsan \
    -R "test_core|test_histogram|test_runtime|test_group|test_ao"
fi

# clang --analyze: any report fails the run.
# The NIfTI loader's real path too, not only the refusal built without
# nifticlib (libnifti2-dev).
nifti=""
if [ -f /usr/include/nifti/nifti2_io.h ]; then
  nifti="-DRP_WITH_NIFTI=1 -isystem /usr/include/nifti"
fi
# One clang per file, $jobs at a time (75 s of CPU one after another),
# each into a file of its own so that reports do not interleave.
mkdir -p "$logdir/analyze"
# shellcheck disable=SC2016
printf '%s\n' runtime/*.c cli/*.c | RP_NIFTI="$nifti" xargs -P "$jobs" -I{} \
  sh -c 'f=$1; out="$2/$(echo "$f" | tr / _).txt"
    # shellcheck disable=SC2086
    clang --analyze -std=c11 -D_POSIX_C_SOURCE=200809L -Iinclude \
      -Iruntime $RP_NIFTI "$f" -o /dev/null >"$out" 2>&1 || true' \
  sh {} "$logdir/analyze"
report=$(cat "$logdir"/analyze/*.txt)
if printf '%s' "$report" | grep -qE "warning:|error:"; then
  printf '%s\n' "$report"
  echo "clang --analyze: reports above"
  failed=$((failed + 1)) broken="$broken analyzer"
else
  echo "clang --analyze: no reports"
  passed=$((passed + 1))
fi

echo "dev.sh test: $passed passed, $failed failed, $skipped skipped" \
  "(stages plain, asan+ubsan, tsan, analyzer)"
if [ -n "$broken" ]; then
  echo "dev.sh test: failed in:$broken" >&2
  exit 1
fi
