# Multi-stage build: one builder for the workspace, then one slim runtime stage per binary.
#   docker build --target service -t tessera-service .
#   docker build --target worker  -t tessera-worker  .
FROM rust:1-bookworm AS builder
WORKDIR /src
COPY . .
RUN cargo build --release --locked -p tessera-service -p tessera-worker -p tessera-tracer \
    && cp target/release/tessera-service target/release/tessera-worker \
          target/release/tessera-render /usr/local/bin/

FROM debian:bookworm-slim AS worker
RUN useradd --system --uid 10001 tessera
COPY --from=builder /usr/local/bin/tessera-worker /usr/local/bin/tessera-render /usr/local/bin/
USER tessera
ENTRYPOINT ["tessera-worker"]

FROM debian:bookworm-slim AS service
RUN useradd --system --uid 10001 tessera && mkdir /data && chown tessera /data
COPY --from=builder /usr/local/bin/tessera-service /usr/local/bin/
USER tessera
VOLUME /data
EXPOSE 8080
ENV TESSERA_LISTEN=0.0.0.0:8080 \
    TESSERA_DATABASE=sqlite:///data/tessera.db \
    TESSERA_OPEN_SUBMIT=true
ENTRYPOINT ["tessera-service"]
