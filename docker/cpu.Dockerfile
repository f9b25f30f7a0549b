# sphrender on a machine without a GPU: Mesa llvmpipe (EGL) for GL, Debian's PoCL for OpenCL.
# Build from the repository root:
#   docker build -f docker/cpu.Dockerfile -t sphrender-cpu .
#   docker run --rm -p 127.0.0.1:8080:8080 -e SPHRENDER_TOKEN=... sphrender-cpu
# The packages are the README's for rendering, deploy/apt/render.txt. Not built by CI (its
# machines have no Docker engine); docker/check-images.sh runs these steps in a chroot instead
# and renders in it (docker/README.md).
FROM debian:bookworm-slim

# The README's package list for rendering (deploy/apt/README.md says what each package is for);
# pyopencl's wheel brings its own OpenCL ICD loader, which reads /etc/OpenCL/vendors/pocl.icd.
WORKDIR /opt/sphrender
COPY deploy/apt deploy/apt
RUN apt-get update \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
        $(cat deploy/apt/render.txt) \
    && rm -rf /var/lib/apt/lists/*

COPY pyproject.toml README.md ./
COPY server server
COPY client client
COPY shaders shaders
COPY configs configs
RUN python3 -m venv /opt/venv && /opt/venv/bin/pip install --no-cache-dir . \
    && useradd --system --home /var/lib/sphrender --create-home sphrender

USER sphrender
ENV PATH=/opt/venv/bin:$PATH
EXPOSE 8080 8081
# Inside a container the service must listen beyond loopback; it refuses to without a token, so
# pass SPHRENDER_TOKEN (or use --allow-remote-without-token on a private network only).
CMD ["sphrender", "serve", "--host", "0.0.0.0", "--port", "8080", "--stream-port", "8081"]
