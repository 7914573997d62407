#!/usr/bin/env bash
# The main job: installs what is missing, builds, and starts clothd on its default scene (the
# viewer at http://127.0.0.1:8080/, assembled in build/web - clothd prints a "viewer: URL" line;
# the API at http://127.0.0.1:8080/v1).
# Extra arguments go to clothd, e.g. scripts/run.sh --port 9000 --backend cpu. Ctrl-C stops it
# (and saves --state-file if set).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
"$root/scripts/setup.sh"
"$root/scripts/build.sh"
cd "$root"
exec "$root/build/server/clothd" "$@"
