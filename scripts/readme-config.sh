#!/bin/sh
# docs/operating.md's "Configuration" table is clothd's own output (clothd --help-markdown, from the
# table in server/core/settings.h), between the BEGIN and END marker lines. (The name is older than
# the page: the table lived in README.md.)
#   scripts/readme-config.sh [CLOTHD]          rewrite that part of docs/operating.md
#   scripts/readme-config.sh --check [CLOTHD]  diff it, exit 1 when it differs (ctest docs.readme_config)
# CLOTHD defaults to build/server/clothd.
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
check=0
if [ "${1:-}" = "--check" ]; then
  check=1
  shift
fi
clothd=${1:-$root/build/server/clothd}
doc=$root/docs/operating.md
begin='<!-- BEGIN clothd --help-markdown (scripts/readme-config.sh writes this table) -->'
end='<!-- END clothd --help-markdown -->'
table=$(mktemp)
new=$(mktemp)
trap 'rm -f "$table" "$new"' EXIT
"$clothd" --help-markdown >"$table"
awk -v begin="$begin" -v end="$end" -v table="$table" '
  $0 == begin { print; while ((getline line < table) > 0) print line; skip = 1; found++; next }
  $0 == end { skip = 0 }
  !skip { print }
  END { if (found != 1) { print "readme-config: docs/operating.md needs exactly one line: " begin > "/dev/stderr"; exit 1 } }
' "$doc" >"$new"
if [ "$check" = 1 ]; then
  if ! diff -u "$doc" "$new"; then
    echo "docs/operating.md's configuration table differs from clothd --help-markdown: run scripts/readme-config.sh" >&2
    exit 1
  fi
else
  cat "$new" >"$doc"
fi
