#!/usr/bin/env bash
# The Debian packages clothd builds and tests with, in one place: scripts/setup.sh installs them
# for a user, .ci/run for CI.
CLOTHD_APT_PACKAGES=(
  gcc make cmake pkg-config   # the build
  libcmocka-dev               # C unit and physics tests
  libmicrohttpd-dev libjansson-dev   # clothd's HTTP server and JSON
  libwebsockets-dev libmeshoptimizer-dev   # clothd's stream
  nodejs                      # integration tests (node's test runner and fetch)
  chromium chromium-driver    # the viewer's end-to-end tests (headless, driven by playwright-core)
  strace                      # the crash-safe save test sees the system calls of a save
  wrk                         # the soak test's API load (tests/server/soak.mjs) and scripts/bench-http.sh
)
# npm: Debian's nodejs needs the npm package, NodeSource's nodejs bundles npm (and would conflict
# with Debian's). Installed only when the command is missing.
CLOTHD_APT_IF_NO_NPM=(npm)
