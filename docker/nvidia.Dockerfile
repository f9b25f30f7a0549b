# sphrender on an NVIDIA GPU: the host driver's EGL (OpenGL) and OpenCL, which the NVIDIA
# Container Toolkit mounts into the container. Build from the repository root:
#   docker build -f docker/nvidia.Dockerfile -t sphrender-nvidia .
#   docker run --rm --gpus all -p 127.0.0.1:8080:8080 -e SPHRENDER_TOKEN=... sphrender-nvidia
# No Mesa llvmpipe on purpose: without a GPU this image says so (`sphrender info`) instead of
# rendering far slower on the CPU. docker/check-images.sh checks its steps in a chroot, without
# a GPU (docker/README.md says what that covers).
FROM debian:bookworm-slim

# What the toolkit mounts from the host driver: graphics = EGL/OpenGL (libEGL_nvidia.so.0 and
# the libraries behind it), compute = CUDA and OpenCL (libnvidia-opencl.so.1).
ENV NVIDIA_VISIBLE_DEVICES=all \
    NVIDIA_DRIVER_CAPABILITIES=graphics,compute

# GLVND's EGL and GL dispatch from Debian, deploy/apt/nvidia.txt (libegl1 brings Mesa's EGL
# vendor as a dependency; it finds no driver here, and 10_nvidia.json sorts first), plus the two
# files the loaders look for: the GLVND vendor entry for NVIDIA's EGL and the OpenCL ICD entry
# for NVIDIA's OpenCL (older toolkits mount neither; newer ones mount the same content over them).
WORKDIR /opt/sphrender
COPY deploy/apt deploy/apt
RUN apt-get update \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
        $(cat deploy/apt/nvidia.txt) \
    && rm -rf /var/lib/apt/lists/* \
    && mkdir -p /usr/share/glvnd/egl_vendor.d /etc/OpenCL/vendors \
    && printf '{"file_format_version": "1.0.0", "ICD": {"library_path": "libEGL_nvidia.so.0"}}\n' \
        > /usr/share/glvnd/egl_vendor.d/10_nvidia.json \
    && echo libnvidia-opencl.so.1 > /etc/OpenCL/vendors/nvidia.icd

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
# As in cpu.Dockerfile: beyond loopback the service needs SPHRENDER_TOKEN.
CMD ["sphrender", "serve", "--host", "0.0.0.0", "--port", "8080", "--stream-port", "8081"]
