#!/usr/bin/env bash
# The Debian packages clothd builds and tests with, in one place: scripts/setup.sh installs them
# for a user, .ci/run (through scripts/test.sh) for CI, docker/Dockerfile (setup.sh --build-only)
# the build half in the image's build stage.
CLOTHD_APT_BUILD=(
  gcc make cmake pkg-config   # the build
  libmicrohttpd-dev libjansson-dev   # clothd's HTTP server and JSON
  libwebsockets-dev libmeshoptimizer-dev   # clothd's stream
  libzstd-dev                 # the stream's delta encoding
  nodejs                      # npm, for the viewer's packages (web/package-lock.json)
)
CLOTHD_APT_TEST=(
  libcmocka-dev               # C unit and physics tests
  g++                         # the emulated-CUDA tests: backend_cuda.cu compiled for the CPU (tests/emu)
  clang                       # libFuzzer and the fuzz targets' sanitizers (scripts/fuzz.sh)
  lld                         # wasm-ld: clients/js/src/delta-wasm.mjs checked against its source (scripts/build-wasm.sh)
  chromium chromium-driver    # the viewer's end-to-end tests (headless, driven by playwright-core)
  strace                      # the crash-safe save test sees the system calls of a save
  wrk                         # the soak test's API load (tests/server/soak.mjs) and bench/http.sh
  prometheus                  # promtool checks a /metrics scrape (tests/server/metrics.test.mjs)
  python3-pytest python3-websocket python3-numpy   # the Python client's tests (clients/python): its
  python3-setuptools python3-pip                   # stream, numpy frames, and pip installing it offline
  python3-mypy                # the Python client's type hints, mypy --strict (ctest clients.python_types)
  python3-websockets          # the Python client's asyncio stream (clothd.aio) and its tests
)                             # (nodejs, above: the integration tests, node's test runner and fetch)
CLOTHD_APT_PACKAGES=("${CLOTHD_APT_BUILD[@]}" "${CLOTHD_APT_TEST[@]}")
# npm: Debian's nodejs needs the npm package, NodeSource's nodejs bundles npm (and would conflict
# with Debian's). Installed only when the command is missing.
CLOTHD_APT_IF_NO_NPM=(npm)
