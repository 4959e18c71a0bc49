# deepcanvas server image. Build from the repository root:
#   docker build -f docker/server.Dockerfile -t deepcanvas-server .
# (Not built in CI: the CI machines have no Docker engine.)
FROM debian:12 AS build
WORKDIR /src
COPY . .
RUN bash scripts/setup.sh \
 && cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DBUILD_TESTING=OFF \
      -DDEEPCANVAS_BUILD_CLIENT=OFF -DDEEPCANVAS_BUILD_BENCH=OFF \
 && cmake --build build --target deepcanvas-server

FROM debian:12-slim
RUN apt-get update -qq && apt-get install -y -qq --no-install-recommends libzstd1 \
 && rm -rf /var/lib/apt/lists/*
COPY --from=build /src/build/server/deepcanvas-server /usr/local/bin/deepcanvas-server
EXPOSE 7878
# Listens on all interfaces inside the container; publish the port to choose who can reach it.
# A non-loopback address requires access tokens, so run it with a tokens file mounted:
#   docker run -p 7878:7878 -v $PWD/tokens:/tokens:ro deepcanvas-server --tokens /tokens
ENTRYPOINT ["deepcanvas-server", "serve", "--listen", "0.0.0.0:7878"]
