#!/usr/bin/env bash
# Installs what this machine lacks to build and test clothd (Debian 12 / Ubuntu 22.04+):
# the apt packages of scripts/deps.sh (with sudo when not root), then the npm packages of the
# lock files (npm ci). Quiet when nothing is missing.
#   scripts/setup.sh               everything, to build and to test
#   scripts/setup.sh --build-only  what building clothd and its viewer needs (docker/Dockerfile)
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
source "$here/deps.sh"
packages=("${CLOTHD_APT_PACKAGES[@]}")
npm_dirs=("$here/.." "$here/../web")
case "${1:-}" in
  "") ;;
  --build-only) packages=("${CLOTHD_APT_BUILD[@]}"); npm_dirs=("$here/../web") ;;
  *) echo "usage: scripts/setup.sh [--build-only]" >&2; exit 2 ;;
esac

sudo=""
if [ "$(id -u)" -ne 0 ]; then sudo="sudo"; fi
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
updated=0
if ((${#missing[@]})); then
  echo "setup: installing ${missing[*]}" >&2
  $sudo apt-get update -qq
  updated=1
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${missing[@]}" >/dev/null
fi
if ! command -v npm >/dev/null; then
  echo "setup: installing ${CLOTHD_APT_IF_NO_NPM[*]}" >&2
  ((updated)) || $sudo apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq "${CLOTHD_APT_IF_NO_NPM[@]}" >/dev/null
fi

# npm packages from the lock files (the test tools at the root, the viewer's in web/), when
# they are missing or older than the lock.
for dir in "${npm_dirs[@]}"; do
  if [ -f "$dir/package-lock.json" ] && { [ ! -f "$dir/node_modules/.package-lock.json" ] ||
      [ "$dir/package-lock.json" -nt "$dir/node_modules/.package-lock.json" ]; }; then
    echo "setup: npm ci in $(cd "$dir" && pwd)" >&2
    (cd "$dir" && npm ci --no-audit --no-fund --loglevel=error >/dev/null)
  fi
done
