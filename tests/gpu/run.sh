#!/usr/bin/env bash
# On a machine with an NVIDIA GPU, one command: build the engine with CUDA, run the parity test
# (the CUDA backend against the CPU backend, bitwise, 1,000 substeps a scene), run it again under
# compute-sanitizer's memcheck, racecheck, initcheck and synccheck (the full run, the four at once),
# then the GPU benchmark at 128^2, 512^2 and 1024^2 with 0 and 64 rocks as JSON lines, a batch of
# 1,000 default scenes in one cs_sims_step a frame (its real-time factor, beside the cost model's
# prediction), and the CPU benchmark for comparison. The parity run ends with the batch check
# (cs_sims_step over mixed scenes, bitwise equal to each alone). Needs only nvcc, CMake and a C compiler (no Debian -dev packages, no
# network). On a machine without a usable GPU it says so and exits 77 (skipped).
#   tests/gpu/run.sh [benchmark sizes, default 128,512,1024] [rock counts, default 0,64]
# CLOTHD_GPU_SANITIZE=quick runs the sanitizers on the quick parity run instead (a tenth of the
# substeps), =off skips them; CLOTHD_GPU_BATCH=N batches N default scenes instead of 1,000, and
# CLOTHD_GPU_IM_BATCH=N N under implicit_euler instead of 200.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build="$root/build-gpu"
sizes="${1:-128,512,1024}"
rocks="${2:-0,64}"
sanitize="${CLOTHD_GPU_SANITIZE:-full}"
t_start=$(date +%s)
stamp() { echo "== $* ($(( $(date +%s) - t_start )) s)"; }

# Options for cmake, in an array that may be empty: "${a[@]}" under set -u fails before bash 4.4,
# ${a[@]+"${a[@]}"} does not.
opts=(-DCMAKE_BUILD_TYPE=Release -DCLOTHD_CUDA=ON -DCLOTHD_EMU=OFF -DBUILD_TESTING=ON)
command -v ninja >/dev/null && opts+=(-G Ninja)
gpu=0
if command -v nvidia-smi >/dev/null && nvidia-smi -L 2>/dev/null | grep -q '^GPU'; then
  gpu=1
  nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm,clocks.max.mem --format=csv || true
fi
# Only this machine's GPU architecture, where there is one and CMake can find it (3.24+): a
# shorter build. Elsewhere the default architectures (the build still works; the run skips).
cmake_minor=$(cmake --version | sed -n 's/^cmake version 3\.\([0-9]*\).*/\1/p')
if [ "$gpu" = 1 ] && [ -n "$cmake_minor" ] && [ "$cmake_minor" -ge 24 ]; then
  opts+=(-DCMAKE_CUDA_ARCHITECTURES=native)
fi

stamp "build"
cmake -S "$root" -B "$build" ${opts[@]+"${opts[@]}"} >/dev/null
cmake --build "$build" -j "$(nproc)" --target clothsim test_parity clothd-bench

# A skip (77) must not abort the script under set -e: take the status explicitly.
stamp "parity (CPU vs CUDA, bitwise, 1,000 substeps a scene)"
status=0
"$build/tests/gpu/test_parity" cuda || status=$?
if [ "$status" = 77 ]; then
  echo "tests/gpu/run.sh: skipped: no usable CUDA device (see the line above)"
  exit 77
fi
[ "$status" = 0 ] || { echo "tests/gpu/run.sh: parity FAILED"; exit "$status"; }

failed=0
sanitizer=$(command -v compute-sanitizer || ls /usr/local/cuda/bin/compute-sanitizer 2>/dev/null || true)
if [ "$sanitize" = off ]; then
  stamp "compute-sanitizer: off (CLOTHD_GPU_SANITIZE=off)"
elif [ -z "$sanitizer" ]; then
  stamp "compute-sanitizer not found: skipped"
else
  mode=()
  [ "$sanitize" = quick ] && mode=(quick)
  stamp "compute-sanitizer memcheck, racecheck, initcheck, synccheck on the $sanitize parity run, at once"
  logs="$build/sanitizer"
  mkdir -p "$logs"
  pids=()
  for tool in memcheck racecheck initcheck synccheck; do
    extra=()
    [ "$tool" = memcheck ] && extra=(--leak-check full)
    [ "$tool" = racecheck ] && extra=(--racecheck-report all)
    ( s=$(date +%s)
      rc=0
      "$sanitizer" --tool "$tool" ${extra[@]+"${extra[@]}"} --error-exitcode 3 \
        "$build/tests/gpu/test_parity" cuda ${mode[@]+"${mode[@]}"} >"$logs/$tool.log" 2>&1 || rc=$?
      echo "$tool: exit $rc in $(( $(date +%s) - s )) s" >"$logs/$tool.status"
      exit "$rc" ) &
    pids+=($!)
  done
  for pid in "${pids[@]}"; do wait "$pid" || failed=1; done
  for tool in memcheck racecheck initcheck synccheck; do
    cat "$logs/$tool.status"
    grep -E "ERROR SUMMARY|parity: |FAILED|Error|error" "$logs/$tool.log" | head -20 || true
  done
  [ "$failed" = 0 ] || echo "tests/gpu/run.sh: a sanitizer reported errors (logs in $logs)"
fi

stamp "GPU benchmark (JSON lines: measured, with the cost model and roofline predictions)"
"$build/kernels/clothd-bench" --backend cuda --json --sizes "$sizes" --rocks "$rocks" --seconds 2
stamp "a batch of 1,000 default scenes, and of 200 under implicit_euler (the model's predictions, then the measurements)"
"$build/kernels/clothd-bench" --model --json --sizes 64 --rocks 0 | tail -n 2
"$build/kernels/clothd-bench" --backend cuda --json --batch "${CLOTHD_GPU_BATCH:-1000}" --sizes 64 --read --seconds 3
"$build/kernels/clothd-bench" --backend cuda --json --batch "${CLOTHD_GPU_IM_BATCH:-200}" --sizes 64 --read --seconds 3 \
  --integrator implicit_euler
stamp "CPU benchmark on this machine, for comparison"
"$build/kernels/clothd-bench" --backend cpu --json --sizes 128 --rocks 0 --seconds 1
stamp "done"
exit "$failed"
