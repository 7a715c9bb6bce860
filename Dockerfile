# syntax=docker/dockerfile:1
#
# meshsmooth: the HTTP service in a small runtime image.
#
#   docker build -t meshsmooth .
#   docker run --rm -p 8080:8080 meshsmooth
#
# Network at build time: only crates.io, for `cargo fetch` (the Swagger UI
# assets are vendored in a crate, nothing else is downloaded). For a fully
# offline build, run `cargo vendor vendor > .cargo/config.toml` beforehand:
# the fetch step then reads the vendored sources.

FROM rust:1.95-slim-bookworm AS build
WORKDIR /src
COPY . .
# Fetch once (the only step that may touch the network), then build offline.
RUN --mount=type=cache,target=/usr/local/cargo/registry \
    cargo fetch --locked
RUN --mount=type=cache,target=/usr/local/cargo/registry \
    --mount=type=cache,target=/src/target \
    cargo build --release --locked --offline --bin meshsmooth \
    && install -D target/release/meshsmooth /out/meshsmooth

FROM debian:bookworm-slim
RUN useradd --system --uid 10001 --no-create-home --shell /usr/sbin/nologin meshsmooth
COPY --from=build /out/meshsmooth /usr/local/bin/meshsmooth
USER 10001
# Every setting is a MESHSMOOTH_* variable (see `meshsmooth serve --help`);
# in a container: listen on all interfaces, JSON logs.
ENV MESHSMOOTH_LISTEN=0.0.0.0:8080 \
    MESHSMOOTH_LOG_FORMAT=json
EXPOSE 8080
# SIGTERM starts the graceful shutdown (MESHSMOOTH_SHUTDOWN_TIMEOUT, 30 s
# by default): give the runtime at least that long before SIGKILL.
STOPSIGNAL SIGTERM
ENTRYPOINT ["meshsmooth"]
CMD ["serve"]
