#!/bin/sh
# Entrypoint of the server image (docker/server.Dockerfile): serve on every interface with the
# access tokens from a mounted file, so that the image starts (a non-loopback address without
# --tokens is refused by the server) and no token is baked into the image or its command line.
#
#   DEEPCANVAS_TOKENS_FILE  the tokens file (default /run/deepcanvas/tokens): lines
#                           '<canvas> <role> <token>', see docs/operations.md#tokens
#   DEEPCANVAS_LISTEN       the address (default 0.0.0.0:7878)
#   DEEPCANVAS_DATA         the data directory (default /var/lib/deepcanvas, the image's
#                           volume): the canvases, kept across restarts; --in-memory keeps none
# Arguments are appended to `deepcanvas-server serve` (e.g. --canvas NAME, --max-cells N).
# tests/ops/docker_images.py runs this script outside docker against the built server.
set -eu

tokens="${DEEPCANVAS_TOKENS_FILE:-/run/deepcanvas/tokens}"
listen="${DEEPCANVAS_LISTEN:-0.0.0.0:7878}"
data="${DEEPCANVAS_DATA:-/var/lib/deepcanvas}"

if [ ! -e "$tokens" ]; then
  cat >&2 <<MSG
deepcanvas-server image: no tokens file at $tokens.
The server listens on $listen, which needs access tokens. Mount a file of lines
'<canvas> <role> <token>' (role painter or viewer) there, for example
  docker run -p 7878:7878 -v \$PWD/tokens:/run/deepcanvas/tokens:ro deepcanvas-server
or set DEEPCANVAS_TOKENS_FILE to where it is mounted.
MSG
  exit 2
fi
if [ ! -f "$tokens" ] || [ ! -r "$tokens" ]; then
  echo "deepcanvas-server image: tokens file $tokens is not a readable file" \
    "(the server runs as user $(id -un 2>/dev/null || id -u))" >&2
  exit 2
fi

# exec: the server is the container's main process and gets SIGTERM from `docker stop` itself.
for arg in "$@"; do
  case "$arg" in --in-memory|--data|--data=*) exec deepcanvas-server serve --listen "$listen" --tokens "$tokens" "$@" ;; esac
done
exec deepcanvas-server serve --listen "$listen" --tokens "$tokens" --data "$data" "$@"
