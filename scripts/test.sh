#!/usr/bin/env bash
# The test command: installs what is missing, builds, runs ctest.
#   1. release build (warnings as errors) + every test except labels soak and fuzz
#   2. ASan+UBSan build + the unit, integration and GPU tests (leak checks on; GPU on lavapipe)
#   3. clang libFuzzer build + a short bounded run of each fuzzer (label fuzz)
#   4. (--tsan only) ThreadSanitizer build + the tests of the threaded code (server, client
#      library, streaming GPU replica); lavapipe's own threads are suppressed (tests/sanitizers)
# Options: --no-asan, --no-fuzz skip stages 2 / 3; --soak also runs label soak in stage 1;
#          --tsan adds stage 4 (about 6 more minutes on 2 cores, so not in the default run).
# Paintings: tests read DEEPCANVAS_PAINTINGS, by default ../shared/data/apainter beside the
# checkout when it is there; tests that need paintings are skipped, saying so, without them.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${DEEPCANVAS_PAINTINGS:-}" ] && [ -d ../shared/data/apainter ]; then
  export DEEPCANVAS_PAINTINGS="$(cd ../shared/data/apainter && pwd)"
fi

asan=1 fuzz=1 soak=0 tsan=0
for arg in "$@"; do
  case "$arg" in
    --no-asan) asan=0 ;;
    --no-fuzz) fuzz=0 ;;
    --soak) soak=1 ;;
    --tsan) tsan=1 ;;
    -h|--help) sed -n '2,11p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "test.sh: unknown option '$arg' (see --help)" >&2; exit 2 ;;
  esac
done

bash scripts/setup.sh
jobs=$(nproc)
source scripts/build-env.sh  # launcher (ccache) and release_config
# Measured in a fresh clone: build/ 6.4 GB, build-asan/ 6.9 GB, build-fuzz/ 0.1 GB; build-tsan/
# (six test programs) estimated at 3 GB.
need_gb=7
[ "$asan" = 1 ] && need_gb=$((need_gb + 7))
[ "$tsan" = 1 ] && need_gb=$((need_gb + 3))
warn_if_low_disk "$need_gb" "scripts/test.sh"
start=$(date +%s)
stage() { echo; echo "=== $* ($(( $(date +%s) - start ))s)"; }

stage "release build"
cmake -S . -B build "${release_config[@]}" >/dev/null
cmake --build build -j "$jobs"
stage "ctest (release)"
exclude="fuzz|soak"
[ "$soak" = 1 ] && exclude="fuzz"
ctest --test-dir build -LE "$exclude" --output-on-failure -j "$jobs"

if [ "$asan" = 1 ]; then
  stage "ASan+UBSan build"
  cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=Debug -DDEEPCANVAS_ASAN=ON \
    -DDEEPCANVAS_BUILD_BENCH=OFF "${launcher[@]}" >/dev/null
  cmake --build build-asan -j "$jobs"
  stage "ctest (ASan+UBSan, labels unit, integration and gpu)"
  ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
    ctest --test-dir build-asan -L "unit|integration|gpu" --output-on-failure -j "$jobs"
fi

if [ "$fuzz" = 1 ]; then
  stage "libFuzzer build (clang)"
  CC=clang CXX=clang++ cmake -S . -B build-fuzz -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DDEEPCANVAS_FUZZ=ON -DDEEPCANVAS_BUILD_CLIENT=OFF -DDEEPCANVAS_BUILD_BENCH=OFF "${launcher[@]}" >/dev/null
  cmake --build build-fuzz -j "$jobs" --target fuzzers
  stage "ctest (label fuzz, short bounded runs)"
  ctest --test-dir build-fuzz -L fuzz --output-on-failure
fi
if [ "$tsan" = 1 ]; then
  stage "ThreadSanitizer build"
  cmake -S . -B build-tsan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DDEEPCANVAS_TSAN=ON \
    -DDEEPCANVAS_BUILD_BENCH=OFF "${launcher[@]}" >/dev/null
  cmake --build build-tsan -j "$jobs" --target server_test server_net_test client_core_test streaming_gpu_test \
    storage_test durable_canvas_test
  stage "ctest (ThreadSanitizer: server, sessions, storage, client library, streaming replica)"
  TSAN_OPTIONS="halt_on_error=1 suppressions=$PWD/tests/sanitizers/tsan.supp" \
    ctest --test-dir build-tsan \
    -R "^(server_test|server_net_test|client_core_test|streaming_gpu_test|storage_test|durable_canvas_test)$" \
    --output-on-failure
fi
stage "all stages passed"
