# deepcanvas headless client image (lavapipe, no display). Build from the repository root:
#   docker build -f docker/client.Dockerfile -t deepcanvas-client .
# (Not built in CI: the CI machines have no Docker engine. tests/ops/docker_images.py checks
# that the runtime packages below cover every shared library the client links.)
FROM debian:12 AS build
WORKDIR /src
COPY . .
# The build folder lies outside /src: a build folder copied from a working tree (its
# CMakeCache.txt names another source folder) would make CMake stop.
RUN bash scripts/setup.sh \
 && cmake -S . -B /build -G Ninja -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF \
      -DDEEPCANVAS_BUILD_BENCH=OFF \
 && cmake --build /build --target deepcanvas-client

FROM debian:12-slim
# The shared libraries deepcanvas-client links (ldd): zstd, ISA-L, spdlog with fmt, libpng, the
# Vulkan loader; OpenSSL and the CA store for wss://; lavapipe (mesa-vulkan-drivers), the CPU
# Vulkan device; GLFW with Xlib and stb (ImGui's fonts) for the studio window, which this
# headless image does not open but the binary links; the OpenXR loader (with jsoncpp) for the
# headset client, likewise linked (a headset's runtime is not in this image). It runs as root so that it can write
# images to a mounted folder.
RUN apt-get update -qq && apt-get install -y -qq --no-install-recommends \
      libzstd1 libisal2 libspdlog1.10 libfmt9 libpng16-16 libvulkan1 libssl3 \
      libglfw3 libstb0 libx11-6 libxcb1 libxau6 libxdmcp6 libbsd0 libmd0 \
      libopenxr-loader1 libjsoncpp25 \
      mesa-vulkan-drivers ca-certificates \
 && rm -rf /var/lib/apt/lists/*
COPY --from=build /build/client/deepcanvas-client /usr/local/bin/deepcanvas-client
# Arguments after the image name are the client's command, e.g. `render --connect ws://…`;
# the token comes from --token or $DEEPCANVAS_TOKEN.
ENTRYPOINT ["deepcanvas-client"]
