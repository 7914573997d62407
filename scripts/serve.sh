#!/bin/sh
# clothd-serve: starts an installed clothd (scripts/install.sh PREFIX puts this file in
# PREFIX/bin/clothd-serve) the way a container, a systemd service or a Kubernetes pod runs it.
# Arguments go on to clothd. It decides only what clothd cannot know about where it runs:
#
# - The token: CLOTHD_TOKEN_FILE when set (a missing file then stops the start, in clothd); else
#   the first that exists of $CREDENTIALS_DIRECTORY/token (systemd's LoadCredential) and
#   $CLOTHD_SECRETS_DIR/clothd_token (default /run/secrets: Docker and Compose secrets, a
#   Kubernetes Secret mounted there). The view token likewise: .../view_token, .../clothd_view_token.
# - The address: with a token, 0.0.0.0 (the token guards it); without one, 127.0.0.1 - reachable
#   only from inside the container or host, and it says so. CLOTHD_LISTEN or --listen overrides
#   this, and clothd itself refuses an address beyond loopback without a token.
# - The state file: CLOTHD_STATE_FILE, default state.bin in $STATE_DIRECTORY (systemd's
#   StateDirectory) or /var/lib/clothd; its directory must exist and be writable.
# - The viewer: CLOTHD_WEB_ROOT, default PREFIX/share/clothd/web.
#
# Every other setting comes as usual from CLOTHD_* variables, a config file or flags
# (clothd --help). `clothd-serve --explain` prints what it would run, and runs nothing.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
bin=$here/clothd
explain=0
if [ "${1:-}" = "--explain" ]; then
  explain=1
  shift
fi
say() { echo "clothd-serve: $*" >&2; }

secrets=${CLOTHD_SECRETS_DIR:-/run/secrets}
unset CLOTHD_SECRETS_DIR # not a clothd setting: clothd would warn about it
first_file() {
  for f in "$@"; do
    if [ -n "$f" ] && [ -f "$f" ]; then
      echo "$f"
      return 0
    fi
  done
  return 0
}
creds=${CREDENTIALS_DIRECTORY:-}
token_paths="${creds:+$creds/token }$secrets/clothd_token"
view_token_paths="${creds:+$creds/view_token }$secrets/clothd_view_token"
if [ -z "${CLOTHD_TOKEN_FILE:-}" ]; then
  # shellcheck disable=SC2086 # the paths hold no spaces
  CLOTHD_TOKEN_FILE=$(first_file $token_paths)
fi
if [ -z "${CLOTHD_VIEW_TOKEN_FILE:-}" ]; then
  # shellcheck disable=SC2086
  CLOTHD_VIEW_TOKEN_FILE=$(first_file $view_token_paths)
fi
if [ -z "${CLOTHD_LISTEN:-}" ]; then
  if [ -n "$CLOTHD_TOKEN_FILE" ]; then
    CLOTHD_LISTEN=0.0.0.0
  else
    CLOTHD_LISTEN=127.0.0.1
    say "no token (CLOTHD_TOKEN_FILE, or a file at: $token_paths): listening on 127.0.0.1" \
      "only, which nothing outside this container or host can reach; give a token to listen on 0.0.0.0"
  fi
fi
if [ -z "${CLOTHD_STATE_FILE:-}" ]; then
  CLOTHD_STATE_FILE=${STATE_DIRECTORY:-/var/lib/clothd}/state.bin
fi
: "${CLOTHD_WEB_ROOT:=$(cd "$here/.." && pwd)/share/clothd/web}"
export CLOTHD_TOKEN_FILE CLOTHD_VIEW_TOKEN_FILE CLOTHD_LISTEN CLOTHD_STATE_FILE CLOTHD_WEB_ROOT

if [ "$explain" = 1 ]; then
  echo "# token looked for in: $token_paths"
  echo "# view token looked for in: $view_token_paths"
  env | grep '^CLOTHD_' | sort
  echo "exec $bin $*"
  exit 0
fi
state_dir=$(dirname "$CLOTHD_STATE_FILE")
if [ ! -d "$state_dir" ] || [ ! -w "$state_dir" ]; then
  say "the state directory $state_dir does not exist or is not writable by $(id -un 2>/dev/null || id -u)" \
    "(a volume at /var/lib/clothd, systemd's StateDirectory=, or CLOTHD_STATE_FILE elsewhere)"
  exit 1
fi
exec "$bin" "$@"
