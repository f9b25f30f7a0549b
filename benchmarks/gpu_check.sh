#!/usr/bin/env bash
# GPU check (issue "GPU-ready frame"): one script for an NVIDIA machine, well under 10 minutes.
#
#   benchmarks/gpu_check.sh            # from the repository root or anywhere
#
# 1. Makes the EGL/GL vendor libraries reachable: the NVIDIA driver's libEGL_nvidia.so.0 behind
#    GLVND's libEGL.so.1. Containers started with the NVIDIA Container Toolkit mount the driver
#    library but not always its GLVND vendor file; the script writes one when it is missing and
#    installs GLVND (libegl1 libopengl0) with apt-get when that is possible.
# 2. Installs the project into .venv (reuses one that is there and works; offline machines need
#    it prepared beforehand).
# 3. Prints the GL renderer and the OpenCL devices (`sphrender info`), renders the demo and the
#    bench headline scene (a ~100k-particle ball at 1280x720), and prints the stage times and the
#    host work per frame at 100k/720p and 1M/1080p for both prepare paths
#    (benchmarks/bench_host.py): on a GPU the host column is the frame time's floor; what
#    the service's true stage times (a finish per stage) cost against none; and the frame time
#    of each preset, and of balanced without its field normals (~14 ms on llvmpipe), against
#    the pre-issue-12 default (benchmarks/bench_frame_ratio.py); and the field normals'
#    gradient per invocation (the blend's way) against tiles in shared memory
#    (benchmarks/bench_field_gradient.py: 2.9-3.8x slower on llvmpipe, the usual remedy on GPUs);
#    the same frame ratio on frames that carry densities (balanced's lone droplets ask the GPU's
#    OpenCL which particles are alone); and SphEngine.density_below against the density pass
#    on the GPU's OpenCL, with the particles whose answers differ (must be 0).
#
# Nothing else depends on this script; CI never runs it.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)
section() { printf '\n== %s (%ds)\n' "$1" "$(($(date +%s) - start))"; }

section "GPU"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null \
    || echo "nvidia-smi: not available"

section "EGL vendor libraries"
nvidia_egl=$(ldconfig -p 2>/dev/null | awk '/libEGL_nvidia\.so\.0/ {print $NF; exit}')
if [ -z "$nvidia_egl" ]; then
    nvidia_egl=$(find /usr/lib /usr/lib64 /usr/local/nvidia -name 'libEGL_nvidia.so.0' 2>/dev/null | head -1 || true)
fi
echo "libEGL_nvidia.so.0: ${nvidia_egl:-not found (GL will fall back to Mesa if present)}"
if ! ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1 '; then
    echo "GLVND's libEGL.so.1 is missing; trying apt-get install libegl1 libopengl0"
    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
        --no-install-recommends libegl1 libopengl0) || echo "apt-get failed (offline?)"
fi
if [ -n "$nvidia_egl" ]; then
    vendor_dirs="/usr/share/glvnd/egl_vendor.d /etc/glvnd/egl_vendor.d"
    # shellcheck disable=SC2086  # two directories
    if ! grep -qs libEGL_nvidia $(for d in $vendor_dirs; do echo "$d"/*.json; done); then
        vendor_file=$(mktemp -d)/10_nvidia.json
        printf '{"file_format_version": "1.0.0", "ICD": {"library_path": "%s"}}\n' \
            "$nvidia_egl" >"$vendor_file"
        export __EGL_VENDOR_LIBRARY_FILENAMES="$vendor_file"
        echo "wrote $vendor_file (no GLVND vendor file named the NVIDIA library)"
    fi
fi

section "install"
if ! { [ -x .venv/bin/sphrender ] && .venv/bin/python -c 'import sphrender' 2>/dev/null; }; then
    python3 -m venv .venv
    .venv/bin/pip install -q .
fi

section "GL renderer and OpenCL devices"
.venv/bin/sphrender info

section "demo"
.venv/bin/sphrender demo -o "${TMPDIR:-/tmp}/sphrender-gpu-check-demo.png" -v

section "host work and stage times (ms; host = wall - time inside GL/CL calls)"
timeout 420 .venv/bin/python benchmarks/bench_host.py --frames 5 --sizes 100k,1m,4k \
    --prepare host,device,auto --stage-timing-cost

section "frame time per setting against the pre-issue-12 default (field normals: their GPU cost)"
timeout 180 .venv/bin/python benchmarks/bench_frame_ratio.py --cycles 8

section "the same on frames that carry densities (balanced's lone droplets: density_below)"
timeout 120 .venv/bin/python benchmarks/bench_frame_ratio.py --cycles 8 --densities

section "densities below a limit (density_below) against the density pass, answers compared"
timeout 120 .venv/bin/python benchmarks/bench_sph.py --below --sizes 100000 1000000

section "field gradient: per invocation against tiles in shared memory"
timeout 120 .venv/bin/python benchmarks/bench_field_gradient.py

section "done"
