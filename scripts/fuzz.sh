#!/usr/bin/env bash
# Builds the libFuzzer targets of fuzz/ in build-fuzz (clang, ASan + UBSan) and runs each for
# SECONDS (default 60), as many at once as there are cores, from its committed corpus, copied to
# build-fuzz/work so that a run adds nothing to the repository. Exits non-zero when any target
# crashes, leaks or hangs, after naming the input that did it (libFuzzer's crash-/leak-/timeout- file) and how to rerun it.
#
#   scripts/fuzz.sh [SECONDS] [TARGET...]     TARGET: request snapshot config stream_msg recording
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
seconds=${1:-60}
shift || true
targets=("$@")
((${#targets[@]})) || targets=(request snapshot config stream_msg recording)
if ! [[ $seconds =~ ^[0-9]+$ ]] || ((seconds < 1)); then
  echo "usage: scripts/fuzz.sh [SECONDS] [TARGET...]" >&2
  exit 2
fi
if ! command -v clang >/dev/null; then
  echo "fuzz: needs clang with libFuzzer (apt install clang)" >&2
  exit 1
fi

build="$root/build-fuzz"
mkdir -p "$build"
# libFuzzer's runtime is a package of its own on Debian (libclang-rt-14-dev, which clang
# recommends): said plainly rather than as a link error.
probe="$build/probe"
if ! printf 'int LLVMFuzzerTestOneInput(const char *d, unsigned long n) { return (void)d, (void)n, 0; }\n' |
    clang -x c -fsanitize=fuzzer,address,undefined -o "$probe" - >/dev/null 2>&1; then
  echo "fuzz: clang cannot link libFuzzer (Debian: apt install libclang-rt-14-dev)" >&2
  exit 1
fi
rm -f "$probe"
cmake -S "$root" -B "$build" -DCMAKE_C_COMPILER=clang -DCMAKE_BUILD_TYPE=Debug -DCLOTHD_FUZZ=ON \
  -DBUILD_TESTING=OFF >/dev/null
cmake --build "$build" -j "$(nproc)" --target fuzz >/dev/null

# Undefined behaviour and memory errors stop a run and leave the input (libFuzzer's default for
# ASan; UBSan's via -fno-sanitize-recover). Leaks too: libFuzzer checks each input for them.
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:symbolize=1}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-halt_on_error=1:abort_on_error=1:print_stacktrace=1}"

# Each target runs alone in its process: as many at once as there are cores, then each is
# reported in order.
run_target() {
  local t=$1 bin="$build/fuzz/fuzz_$1" work="$build/work/$1" rc=0
  (cd "$work" && "$bin" -max_total_time="$seconds" -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
    -dict="$root/fuzz/json.dict" -artifact_prefix="$work/found/" corpus >"$work/log" 2>&1) || rc=$?
  echo "$rc" >"$work/rc"
}
for t in "${targets[@]}"; do
  bin="$build/fuzz/fuzz_$t"
  if [ ! -x "$bin" ] || [ ! -d "$root/fuzz/corpus/$t" ]; then
    echo "fuzz: no target '$t' (request snapshot config stream_msg recording)" >&2
    exit 2
  fi
  work="$build/work/$t"
  rm -rf "$work"
  mkdir -p "$work/corpus" "$work/found"
  cp "$root/fuzz/corpus/$t"/* "$work/corpus/"
  # Snapshots of this build's parameter table, whatever the committed seeds were made with.
  if [ "$t" = snapshot ]; then "$build/fuzz/snapshot_seeds" "$work/corpus" 2>/dev/null || true; fi
done
cores=$(nproc)
running=0
for t in "${targets[@]}"; do
  run_target "$t" &
  running=$((running + 1))
  if ((running >= cores)); then
    wait -n || true
    running=$((running - 1))
  fi
done
wait

failed=()
for t in "${targets[@]}"; do
  bin="$build/fuzz/fuzz_$t"
  work="$build/work/$t"
  rc=$(cat "$work/rc")
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$work/log")
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$work/log")
  last=$(grep -E '^#[0-9]+' "$work/log" | tail -1 || true)
  cov=$(sed -n 's/.* cov: \([0-9]*\).*/\1/p' <<<"$last")
  ft=$(sed -n 's/.* ft: \([0-9]*\).*/\1/p' <<<"$last")
  corp=$(sed -n 's/.* corp: \([0-9]*\)\/.*/\1/p' <<<"$last")
  if ((rc == 0)); then
    printf 'fuzz %-10s %4ss  %9s runs (%s/s)  coverage %s edges, %s features  corpus %s  ok\n' "$t" "$seconds" \
      "${execs:-?}" "${rate:-?}" "${cov:-?}" "${ft:-?}" "${corp:-?}"
  else
    found=$(ls "$work/found" 2>/dev/null | head -1)
    echo "fuzz $t: FAILED (exit $rc) after ${execs:-?} runs; the log is $work/log" >&2
    grep -m1 -E 'ERROR: |runtime error: |fuzz: |SUMMARY: ' "$work/log" >&2 || tail -20 "$work/log" >&2
    if [ -n "$found" ]; then
      echo "fuzz $t: the input is $work/found/$found; rerun it with" >&2
      echo "  ASAN_OPTIONS=fast_unwind_on_malloc=0 $bin $work/found/$found" >&2
    fi
    failed+=("$t")
  fi
done
if ((${#failed[@]})); then
  echo "fuzz: ${failed[*]} failed" >&2
  exit 1
fi
