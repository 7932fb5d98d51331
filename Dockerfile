# Multi-stage build: one builder for the workspace, then one slim runtime stage per binary.
#   docker build --target service -t tessera-service .
#   docker build --target worker  -t tessera-worker  .
# How to run them: docs/OPERATIONS.md, "Docker". Checked without an engine by scripts/docker-emulate.py.

FROM rust:1-bookworm AS builder
WORKDIR /src
# The whole workspace (.dockerignore keeps target/ and .git out): Cargo reads every member's
# manifest even for -p, and the service embeds migrations/ and its page at compile time.
COPY . .
RUN cargo build --release --locked -p tessera-service -p tessera-worker -p tessera-render \
    && cp target/release/tessera-service target/release/tessera-worker \
          target/release/tessera-render /usr/local/bin/

# The binaries need only libc, libm and libgcc_s (SQLite is compiled in; no TLS: workers
# talk plain HTTP), all in bookworm-slim.
FROM debian:bookworm-slim AS worker
RUN useradd --uid 10001 --user-group --no-create-home --shell /usr/sbin/nologin tessera
COPY --from=builder /usr/local/bin/tessera-worker /usr/local/bin/tessera-render /usr/local/bin/
# Numeric, so that Kubernetes' runAsNonRoot can see it is not root.
USER 10001:10001
# `docker stop` kills after 10 s: give held tiles back before that rather than leaving them
# to lease expiry (TESSERA_GRACE_SECS; raise it together with `docker stop -t`).
ENV TESSERA_GRACE_SECS=8
ENTRYPOINT ["tessera-worker"]

# Last, so that a plain `docker build .` builds the service.
FROM debian:bookworm-slim AS service
RUN useradd --uid 10001 --user-group --no-create-home --shell /usr/sbin/nologin tessera \
    && mkdir /data && chown 10001:10001 /data
COPY --from=builder /usr/local/bin/tessera-service /usr/local/bin/
USER 10001:10001
VOLUME /data
EXPOSE 8080
# Listening on all of the container's interfaces is beyond loopback, so the service refuses
# to start until `docker run` says who may submit: -e TESSERA_SUBMIT_TOKEN=... or, said out
# loud, -e TESSERA_OPEN_SUBMIT=true (docs/OPERATIONS.md, "Docker"). Its local workers give held tiles
# back before `docker stop`'s kill, as the worker image's do (TESSERA_GRACE_SECS).
ENV TESSERA_LISTEN=0.0.0.0:8080 \
    TESSERA_DATABASE=sqlite:///data/tessera.db \
    TESSERA_GRACE_SECS=8
ENTRYPOINT ["tessera-service"]
