# deepcanvas headless client image (lavapipe, no display). Build from the repository root:
#   docker build -f docker/client.Dockerfile -t deepcanvas-client .
# (Not built in CI: the CI machines have no Docker engine.)
FROM debian:12 AS build
WORKDIR /src
COPY . .
RUN bash scripts/setup.sh \
 && cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF \
      -DDEEPCANVAS_BUILD_BENCH=OFF \
 && cmake --build build --target deepcanvas-client

FROM debian:12-slim
RUN apt-get update -qq && apt-get install -y -qq --no-install-recommends \
      libzstd1 libpng16-16 libvulkan1 mesa-vulkan-drivers \
 && rm -rf /var/lib/apt/lists/*
COPY --from=build /src/build/client/deepcanvas-client /usr/local/bin/deepcanvas-client
ENTRYPOINT ["deepcanvas-client"]
