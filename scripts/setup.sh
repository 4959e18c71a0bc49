#!/usr/bin/env bash
# Installs every Debian package deepcanvas needs to build, test and run.
# Idempotent and non-interactive: packages already installed are skipped, and apt is only
# touched when something is missing. Nothing is fetched from anywhere but Debian's archive.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config git ca-certificates
  # Boost with Asio/Beast: 1.81 where it exists (Debian 12), 1.74 as the fallback below.
  libboost1.81-dev libboost-iostreams1.81-dev
  # Command lines (CLI11) and logs (spdlog).
  libcli11-dev libspdlog-dev
  libglm-dev libzstd-dev libisal-dev nlohmann-json3-dev libpng-dev zlib1g-dev
  # TLS for wss:// (Beast's ssl_stream over OpenSSL); openssl makes the tests' certificates.
  libssl-dev openssl
  # Vulkan: loader + headers, lavapipe (software device), glslang for shaders at build time.
  libvulkan-dev mesa-vulkan-drivers glslang-tools vulkan-tools
  # Tests and benchmarks.
  libgtest-dev libgmock-dev libbenchmark-dev
  # The peer we measure against and export to; glTF meshes (tinygltf); ffmpeg makes time-lapse
  # videos from the PNG frames.
  libopenvdb-dev libtbb-dev libopenvdb-tools libtinygltf-dev ffmpeg
  # libFuzzer for the protocol decoders.
  clang libclang-rt-14-dev
  # Third-party WebSocket client used by the protocol conformance test.
  python3 python3-websockets zstd
  # The /metrics test parses the exposition with the reference Prometheus parser.
  python3-prometheus-client
  # Durable canvases: one SQLite database per canvas; sqlite3 is the operator's inspection shell.
  libsqlite3-dev sqlite3
  # The studio window: GLFW, Dear ImGui (with its GLFW and Vulkan backends); its tests run it
  # in a real X server (Xvfb), drive it with xdotool and read the screen back with xwd.
  libglfw3-dev libimgui-dev xvfb xdotool x11-apps
  # The headset client: the OpenXR loader (a runtime comes with the headset; tests use the
  # headless Monado runtime in ../shared/tools/openxr).
  libopenxr-dev libopenxr-loader1
  # Compiler cache: repeated builds of the test command (scripts/test.sh) reuse objects.
  ccache
)

if [ "$(id -u)" -ne 0 ]; then
  SUDO=sudo
else
  SUDO=
fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all ${#packages[@]} packages already installed"
  exit 0
fi

echo "setup: installing ${#missing[@]} missing package(s): ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
if ! $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"; then
  # Boost 1.81 is not in every release; fall back to the default Boost (1.74 on older Debian).
  fallback=()
  for p in "${missing[@]}"; do
    [ "$p" = libboost1.81-dev ] && p=libboost-dev
    [ "$p" = libboost-iostreams1.81-dev ] && p=libboost-iostreams-dev
    fallback+=("$p")
  done
  $SUDO apt-get install -y -qq --no-install-recommends "${fallback[@]}"
fi
echo "setup: done"
