#!/usr/bin/env bash
# GET /v1/sim (or $BENCH_PATH: /livez, /readyz, ...) under wrk while clothd runs a 128 x 128 cloth on the CPU backend, in two runs:
# saturating (as many requests as the machine answers) and paced at about 10,000 requests per
# second ($BENCH_ARGS replaces the cloth's flags, e.g. BENCH_ARGS="--integrator implicit_euler" for
# the default scene under it). Prints requests per second, latency percentiles and the sim's real-time factor before
# and during each run. It is a benchmark, not a test.
#   bench/http.sh [seconds per run, default 10]
# Needs wrk (apt install wrk).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
secs=${1:-10}
path=${BENCH_PATH:-/v1/sim}
bin="$root/build/server/clothd"
[ -x "$bin" ] || "$root/scripts/build.sh" >/dev/null
command -v wrk >/dev/null || { echo "bench/http.sh: wrk is missing (apt install wrk)" >&2; exit 2; }
work=$(mktemp -d)
"$bin" --port 0 --stream-port 0 --backend cpu ${BENCH_ARGS:---nx 128 --ny 128 --auto-drop-interval 1} --web-root /nonexistent 2>"$work/log" &
pid=$!
trap 'kill $pid 2>/dev/null; rm -rf "$work"' EXIT
for _ in $(seq 100); do grep -q "listening on" "$work/log" && break; sleep 0.1; done
url=$(grep -o 'http://[0-9.]*:[0-9]*' "$work/log" | head -1)
field() { curl -s "$url/v1/sim" | grep -o "\"$1\":[0-9.e+-]*" | head -1 | cut -d: -f2; }
# Each connection waits 2.4 ms after each answer: 32 connections ask about 10,000 times a second.
cat > "$work/paced.lua" <<'LUA'
function delay() return 2.4 end
LUA
run() { # name, wrk options...
  local name=$1
  shift
  wrk -t2 -c32 -d"${secs}s" --latency "$@" "$url$path" > "$work/wrk" &
  local w=$! samples=()
  for _ in $(seq $((secs - 1))); do sleep 1; samples+=("$(field realtime_factor)"); done
  wait $w
  echo "== GET $path, $name: $(grep Requests/sec "$work/wrk" | tr -s ' ')"
  grep -E "Non-2xx" "$work/wrk" | sed 's/^ */   /' || true
  grep -E "^ +(50|90|99)%" "$work/wrk" | tr -s ' ' | sed 's/^/   latency p/'
  echo "   real-time factor during the run (1 s samples): ${samples[*]}"
}
sleep 3
echo "clothd ${BENCH_ARGS:-128x128}, CPU backend, $(field substeps) substeps per frame; real-time factor idle: $(field realtime_factor)"
run "saturating"
sleep 2
run "paced at ~10k requests/s" -s "$work/paced.lua"
