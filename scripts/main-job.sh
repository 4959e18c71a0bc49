#!/usr/bin/env bash
# The main job: installs what is missing, builds, starts a deepcanvas server on loopback, paints a
# scene into it from a client, renders the canvas with the Vulkan client and writes a PNG.
#
# usage: bash scripts/main-job.sh [PAINTING.apa] [--scale S] [--offset X,Y,Z] [--out FILE.png]
#                                 [--size WxH] [--port N]
# Without a painting it paints the project's own generated scene.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)

painting="" scale="" offset="" out="$root/out/deepcanvas.png" size="960x540" port=""
while [ $# -gt 0 ]; do
  case "$1" in
    -h|--help) sed -n '2,7p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    --scale) scale="$2"; shift 2 ;;
    --offset) offset="$2"; shift 2 ;;
    --out) out="$2"; shift 2 ;;
    --size) size="$2"; shift 2 ;;
    --port) port="$2"; shift 2 ;;
    -*) echo "main-job.sh: unknown option '$1' (see --help)" >&2; exit 2 ;;
    *) painting="$1"; shift ;;
  esac
done
if [ -n "$painting" ] && [ ! -f "$painting" ]; then
  echo "main-job.sh: no such painting: $painting" >&2
  exit 2
fi
case "$out" in /*) ;; *) out="$root/$out" ;; esac

bash scripts/setup.sh
source scripts/build-env.sh  # the same build/ as test.sh, through ccache
warn_if_low_disk 3 "scripts/main-job.sh"  # the server and client in build/: about 2 GB
cmake -S . -B build "${release_config[@]}" >/dev/null
cmake --build build --target deepcanvas-server deepcanvas-client
server="$root/build/server/deepcanvas-server"
client="$root/build/client/deepcanvas-client"

# A free loopback port unless one was given.
if [ -z "$port" ]; then
  port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')
fi
url="ws://127.0.0.1:$port/main"
mkdir -p "$(dirname "$out")"
log="$(dirname "$out")/server.log"

# The canvas is kept in a fresh data directory beside the picture, so every run paints the same
# scene; the server is restarted before rendering, so the picture shows the canvas as restored
# from disk.
data="$(dirname "$out")/deepcanvas-data"
rm -rf "$data"
server_pid=
start_server() {
  "$server" serve --listen "127.0.0.1:$port" --data "$data" --canvas main >>"$log" 2>&1 &
  server_pid=$!
  # Wait until the server accepts connections (it logs 'listening' once bound).
  local before=$1
  for _ in $(seq 1 300); do
    [ "$(grep -c "listening" "$log" 2>/dev/null)" -gt "$before" ] && return 0
    kill -0 "$server_pid" 2>/dev/null || { echo "main-job.sh: the server exited; its log:" >&2; cat "$log" >&2; exit 1; }
    sleep 0.1
  done
  echo "main-job.sh: the server did not start in 30 s; its log:" >&2; cat "$log" >&2; exit 1
}
stop_server() {
  if [ -n "$server_pid" ] && kill -0 "$server_pid" 2>/dev/null; then
    kill -TERM "$server_pid" 2>/dev/null || true
    wait "$server_pid" 2>/dev/null || true
  fi
}
trap stop_server EXIT
: >"$log"
start_server 0

paint_args=(paint --connect "$url" --pace fast)
if [ -n "$painting" ]; then
  paint_args+=("$painting")
  [ -n "$scale" ] && paint_args+=(--scale "$scale")
  [ -n "$offset" ] && paint_args+=(--offset "$offset")
else
  paint_args+=(--generated)
fi
echo "main-job.sh: painting through $url"
"$client" "${paint_args[@]}"

echo "main-job.sh: restarting the server (the canvas comes back from $data)"
stop_server
start_server 1
grep "canvas_restored" "$log" | tail -1

echo "main-job.sh: rendering"
"$client" render --connect "$url" --size "$size" --out "$out"

stop_server
trap - EXIT
echo "main-job.sh: wrote $out (server log: $log)"
