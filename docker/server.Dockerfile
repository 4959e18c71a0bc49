# deepcanvas server image. Build from the repository root:
#   docker build -f docker/server.Dockerfile -t deepcanvas-server .
# Run it with a tokens file mounted (lines '<canvas> <role> <token>', docs/operations.md#tokens):
#   docker run -p 7878:7878 -v $PWD/tokens:/run/deepcanvas/tokens:ro \
#     -v deepcanvas-data:/var/lib/deepcanvas deepcanvas-server
# Arguments after the image name are appended to `deepcanvas-server serve` (--canvas, limits).
# (Not built in CI: the CI machines have no Docker engine. tests/ops/docker_images.py runs the
# entrypoint script against the built server and checks that the runtime packages below cover
# every shared library the server links.)
FROM debian:12 AS build
WORKDIR /src
COPY . .
# The build folder lies outside /src: a build folder copied from a working tree (its
# CMakeCache.txt names another source folder) would make CMake stop.
RUN bash scripts/setup.sh \
 && cmake -S . -B /build -G Ninja -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF \
      -DDEEPCANVAS_BUILD_CLIENT=OFF -DDEEPCANVAS_BUILD_BENCH=OFF \
 && cmake --build /build --target deepcanvas-server

FROM debian:12-slim
# The shared libraries deepcanvas-server links (ldd): zstd, ISA-L, spdlog with fmt; OpenSSL for
# wss://; SQLite for the canvases (and the sqlite3 shell to inspect them); OpenVDB with what it
# links, and tinygltf (with stb), for `export` and imports.
RUN apt-get update -qq && apt-get install -y -qq --no-install-recommends \
      libzstd1 libisal2 libspdlog1.10 libfmt9 libssl3 libsqlite3-0 sqlite3 \
      libopenvdb10.0 libblosc1 libtbb12 libimath-3-1-29 liblog4cplus-2.0.5 libtinygltf2d libstb0 \
      libboost-iostreams1.74.0 libboost-iostreams1.81.0 libbz2-1.0 liblz4-1 liblzma5 \
      libsnappy1v5 \
 && rm -rf /var/lib/apt/lists/*
COPY --from=build /build/server/deepcanvas-server /usr/local/bin/deepcanvas-server
COPY docker/server-entrypoint.sh /usr/local/bin/deepcanvas-server-entrypoint
# Not root: the server needs no privilege (7878 is not a privileged port).
RUN useradd --system --no-create-home --shell /usr/sbin/nologin deepcanvas \
 && install -d -o deepcanvas -g deepcanvas /var/lib/deepcanvas
USER deepcanvas
# The canvases (serve --data): mount a volume here to keep them across containers.
VOLUME /var/lib/deepcanvas
EXPOSE 7878
# Listens on all interfaces inside the container; publish the port to choose who can reach it.
# The entrypoint takes the tokens from /run/deepcanvas/tokens (or $DEEPCANVAS_TOKENS_FILE) and
# stops with a message saying so when the file is missing.
ENTRYPOINT ["/usr/local/bin/deepcanvas-server-entrypoint"]
