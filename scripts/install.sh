#!/usr/bin/env bash
# Installs a built clothd into PREFIX (scripts/build.sh builds it first):
#   PREFIX/bin/clothd            the daemon
#   PREFIX/bin/clothd-serve      scripts/serve.sh: how a container or a service starts it
#   PREFIX/bin/clothctl          the command-line client
#   PREFIX/share/clothd/web/     the viewer (clothd-serve passes it as --web-root)
#   PREFIX/share/clothd/runtime-packages
#                                the Debian packages that hold the libraries clothd loads, one a
#                                line: what a machine without the -dev packages installs to run it
# usage: scripts/install.sh PREFIX    (the build directory: $CLOTHD_BUILD_DIR, default build/)
# docker/Dockerfile runs it in its build stage; tests/deploy/install.test.mjs runs it here into a
# temporary PREFIX and starts the installed daemon.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
if [ $# -ne 1 ] || [ -z "$1" ]; then
  echo "usage: scripts/install.sh PREFIX" >&2
  exit 2
fi
prefix=$1
build=${CLOTHD_BUILD_DIR:-$root/build}
if [ ! -x "$build/server/clothd" ]; then
  echo "install: no clothd in $build/server (run scripts/build.sh first)" >&2
  exit 1
fi
if [ ! -f "$build/web/index.html" ]; then
  echo "install: the viewer was not assembled in $build/web (scripts/setup.sh, then scripts/build.sh)" >&2
  exit 1
fi
cmake --install "$build" --prefix "$prefix" >/dev/null
if [ ! -x "$prefix/bin/clothd" ] || [ ! -x "$prefix/bin/clothd-serve" ]; then
  echo "install: cmake --install put no clothd in $prefix/bin ($build predates the install rules: scripts/build.sh)" >&2
  exit 1
fi
prefix=$(cd "$prefix" && pwd)

# The packages of the shared libraries the installed binary resolves to. ldd prints /lib paths
# that dpkg may know as /usr/lib (merged /usr) or the other way round: both are asked.
list="$prefix/share/clothd/runtime-packages"
mkdir -p "$(dirname "$list")"
ldd "$prefix/bin/clothd" | awk '$2 == "=>" && $3 ~ /^\// {print $3}' | while read -r lib; do
  for path in "$lib" "/usr$lib" "${lib#/usr}" "$(readlink -f "$lib")"; do
    if owner=$(dpkg-query -S "$path" 2>/dev/null); then
      echo "${owner%%:*}"
      break
    fi
  done
done | sort -u >"$list.tmp"
if [ ! -s "$list.tmp" ]; then
  rm -f "$list.tmp"
  echo "install: no Debian package owns the libraries of $prefix/bin/clothd (dpkg-query -S)" >&2
  exit 1
fi
mv "$list.tmp" "$list"
echo "install: clothd in $prefix/bin, the viewer in $prefix/share/clothd/web" >&2
