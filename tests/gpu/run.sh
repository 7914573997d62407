#!/usr/bin/env bash
# On a machine with an NVIDIA GPU: build the engine with CUDA, run the parity test, run it again
# under compute-sanitizer (memcheck and racecheck), then the GPU benchmark. Needs only nvcc,
# CMake, a C compiler (and ninja if present): no Debian -dev packages, no network.
#   tests/gpu/run.sh [benchmark sizes, default 128,256,512,1024]
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
build="$root/build-gpu"
sizes="${1:-128,256,512,1024}"
gen=()
command -v ninja >/dev/null && gen=(-G Ninja)
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv || true

echo "== build"
cmake -S "$root" -B "$build" "${gen[@]}" -DCMAKE_BUILD_TYPE=Release -DCLOTHD_CUDA=ON >/dev/null
cmake --build "$build" -j "$(nproc)" --target clothsim test_parity clothd-bench

echo "== parity (CPU vs CUDA, 1000 substeps per scene)"
"$build/tests/gpu/test_parity" cuda

sanitizer=$(command -v compute-sanitizer || ls /usr/local/cuda/bin/compute-sanitizer 2>/dev/null || true)
if [ -n "$sanitizer" ]; then
  for tool in memcheck racecheck; do
    echo "== compute-sanitizer --tool $tool (100 substeps per scene)"
    "$sanitizer" --tool "$tool" --error-exitcode 3 "$build/tests/gpu/test_parity" cuda quick
  done
else
  echo "== compute-sanitizer not found: skipped"
fi

echo "== benchmark"
"$build/kernels/clothd-bench" --backend cuda --json --sizes "$sizes"
echo "== CPU benchmark on this machine, for comparison"
"$build/kernels/clothd-bench" --backend cpu --json --sizes 128 --seconds 1
