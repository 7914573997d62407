#!/usr/bin/env bash
# The Debian packages clothd builds and tests with, in one place: scripts/setup.sh installs them
# for a user, .ci/run for CI.
CLOTHD_APT_PACKAGES=(
  gcc make cmake pkg-config   # the build
  libcmocka-dev               # C unit and physics tests
  libmicrohttpd-dev libjansson-dev   # clothd's HTTP server and JSON
  nodejs                      # integration tests (node's test runner and fetch)
)
