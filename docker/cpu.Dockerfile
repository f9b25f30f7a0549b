# sphrender on a machine without a GPU: Mesa llvmpipe (EGL) for GL, Debian's PoCL for OpenCL.
# Build from the repository root:
#   docker build -f docker/cpu.Dockerfile -t sphrender-cpu .
#   docker run --rm -p 127.0.0.1:8080:8080 -e SPHRENDER_TOKEN=... sphrender-cpu
# The packages are the README's (the smallest set that renders, found on a clean Debian 12 root)
# plus Debian's PoCL. Not built by CI (its machines have no Docker engine); docker/check-images.sh
# runs these steps in a chroot instead and renders in it (docker/README.md).
FROM debian:bookworm-slim

# libopengl0 is the GL library glcontext resolves GL calls from (libgl1 would do too, with GLX);
# pyopencl's wheel brings its own OpenCL ICD loader, which reads /etc/OpenCL/vendors/pocl.icd.
RUN apt-get update \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
        python3 python3-venv \
        libegl1 libegl-mesa0 libgl1-mesa-dri libopengl0 \
        pocl-opencl-icd \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/sphrender
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
