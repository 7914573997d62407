#!/usr/bin/env bash
# Runs every test: installs what is missing, builds, then ctest (unit, physics, server and viewer
# tests); then the same suite again on a build with AddressSanitizer and UndefinedBehaviorSanitizer
# (build-asan), where any report fails the test that saw it; then each fuzz target for 10 s
# (scripts/fuzz.sh; CLOTHD_FUZZ_SECONDS to change it). CLOTHD_TEST_QUICK=1 stops after the first
# ctest, for quick runs while working: CI runs everything.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
jobs=$(nproc)
"$root/scripts/setup.sh"
"$root/scripts/build.sh"
# Benchmarks (label bench: they print figures, speed is not pass/fail) are left out; ctest -L bench.
(cd "$root/build" && ctest --output-on-failure -j "$jobs" -LE bench)
if [ "${CLOTHD_TEST_QUICK:-0}" = 1 ]; then
  echo "test: CLOTHD_TEST_QUICK=1: the sanitized suite and the fuzz targets were not run" >&2
  exit 0
fi

# The sanitized build, C only: nvcc's device code is not instrumented, and the CUDA runtime's
# address-space reservations and allocations at start clash with ASan's shadow memory and
# LeakSanitizer; the CUDA backend is tested where a GPU is (tests/gpu).
echo "test: the suite under AddressSanitizer and UndefinedBehaviorSanitizer (build-asan)" >&2
cmake -S "$root" -B "$root/build-asan" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCLOTHD_SANITIZE=ON -DCLOTHD_CUDA=OFF \
  >/dev/null
cmake --build "$root/build-asan" -j "$jobs"
# A report stops the process: a C test fails on its exit status, a node test on the report in
# clothd's stderr (tests/server/harness.mjs), leaks included.
export ASAN_OPTIONS="detect_leaks=1:halt_on_error=1:detect_stack_use_after_return=1:strict_string_checks=1:check_initialization_order=1:strict_init_order=1"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1"
# Left out there, to keep the whole command under 20 minutes: emu.datapath and emu.cost count the
# bytes and launches of the same emulated kernels emu.parity and emu.batch run under the
# sanitizers; deploy.* checks install scripts and manifests; web.look, web.shadow and web.capture
# check what the page draws, web.export_usd, web.export_mcap and clients.js_export what the
# JavaScript exporters write (the daemon's side of them is the server tests'); emu.batch batches
# the same emulated kernels emu.parity runs (the batch's host code is the normal build's);
# gpu.parity_self runs the CPU backend against itself on two threads, where emu.parity runs it
# on every scene (thread counts are the normal build's to compare). The viewer's walks through
# the page (web.e2e, web.playback, web.scenes, web.remote: each alone, one core idle) and the
# clients' packaging, types and numpy-less rerun check code that is not clothd's: the daemon's
# side of each is the server tests' (web.crosssite and clients.python still run here).
asan_skip='^(emu\.(datapath|cost|batch)|gpu\.parity_self|deploy\..*|web\.(look|shadow|capture|export_usd|export_mcap|e2e|playback|scenes|remote)|clients\.(js_export|js_package|python_types|python_nonumpy))$'
(cd "$root/build-asan" && ctest --output-on-failure -j "$jobs" -E "$asan_skip" -LE bench)
unset ASAN_OPTIONS UBSAN_OPTIONS

echo "test: fuzz targets, ${CLOTHD_FUZZ_SECONDS:-10} s each (build-fuzz)" >&2
"$root/scripts/fuzz.sh" "${CLOTHD_FUZZ_SECONDS:-10}"
