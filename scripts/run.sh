#!/usr/bin/env bash
# The main job: installs what is missing, builds, and runs the physics core on its default scene
# sizes with the benchmark (until the daemon exists), printing vertex-substeps per second.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
"$root/scripts/setup.sh"
"$root/scripts/build.sh"
exec "$root/build/kernels/clothd-bench" "$@"
