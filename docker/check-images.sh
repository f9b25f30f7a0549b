#!/usr/bin/env bash
# The check_* functions run through "check_$check" and the cleanup through a trap; dpkg-query's
# ${Field} formats are literal.
# shellcheck disable=SC2317,SC2016
# Check the container images and the README's install line without a Docker engine: build a
# minimal Debian root (mmdebstrap --variant=minbase, what debian:bookworm-slim is built from), run
# a Dockerfile's steps or the README's commands in it through chroot (/proc, /sys and /dev
# mounted), render in it, and compare the demo with this machine's. Not part of CI: it takes
# minutes, needs root and the network (a Debian mirror, PyPI).
#
#   docker/check-images.sh                   # every check: readme readme-tests cpu nvidia minimal
#   docker/check-images.sh cpu nvidia        # some of them
#
# readme        the README's first command (its apt-get line, then set up + demo) in a copy of
#               this working tree, as root
# readme-tests  the same, then the README's second command (its apt-get line, then set up +
#               pytest) with pytest given only the tests that need system tools: the viewer in
#               Chromium, replicas behind HAProxy, the C client (the full suite takes too long)
# cpu      docker/cpu.Dockerfile's steps; as its user: sphrender info, demo, sph and an SPH render
# nvidia   docker/nvidia.Dockerfile's steps; as its user: sphrender info must report that there
#          is no GPU (this machine need not have one; with one, nothing is mounted anyway)
# minimal  deploy/apt/render.txt's GL packages each left out in turn (and libgl1 for libopengl0):
#          which ones the demo needs
#
# Needs: root, mmdebstrap (apt-get install mmdebstrap), about 3 GB under ${TMPDIR:-/var/tmp},
# and the README's test set-up (.venv) here for the reference demo and the pixel comparison.
# The host's pip settings that reach PyPI (PIP_INDEX_URL, proxies, its CA bundle) are carried
# into the root for the build steps only. Mounts live in a private mount namespace and a trap
# unmounts them and removes every root, also on failure or Ctrl-C.
set -euo pipefail

REPO=$(cd "$(dirname "$0")/.." && pwd)
CHECKS=("$@")
[ ${#CHECKS[@]} -gt 0 ] || CHECKS=(readme readme-tests cpu nvidia minimal)
for check in "${CHECKS[@]}"; do
    case $check in readme | readme-tests | cpu | nvidia | minimal) ;; *)
        echo "usage: $0 [readme] [readme-tests] [cpu] [nvidia] [minimal]" >&2
        exit 2
        ;;
    esac
done
[ "$(id -u)" -eq 0 ] || { echo "check-images: needs root (chroot, mount)" >&2; exit 2; }
command -v mmdebstrap >/dev/null \
    || { echo "check-images: needs mmdebstrap: apt-get install mmdebstrap" >&2; exit 2; }
HOST_VENV=$REPO/.venv/bin
[ -x "$HOST_VENV/sphrender" ] || {
    echo "check-images: needs the README's test set-up in $REPO/.venv (the reference demo)" >&2
    exit 2
}

# A private mount namespace: whatever is mounted below disappears with this process, whatever
# happens to it; the trap still unmounts and removes everything in order.
if [ -z "${CHECK_IMAGES_NAMESPACE:-}" ] && unshare --mount --propagation private true 2>/dev/null
then
    CHECK_IMAGES_NAMESPACE=1 exec unshare --mount --propagation private bash "$0" "${CHECKS[@]}"
fi

START=$SECONDS
WORK=$(mktemp -d "${TMPDIR:-/var/tmp}/check-images.XXXXXX")
ROOTS=()
RESULTS=()
FAILED=0
DEFAULT_PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
CHROOT_IMAGE=(python3 "$REPO/docker/chroot_image.py")

log() { printf '[%4ds] %s\n' $((SECONDS - START)) "$*"; }
result() { RESULTS+=("$*"); log "RESULT $*"; }
fail() { FAILED=1; result "FAIL $*"; }

mounts_under() { findmnt -rn -o TARGET | grep -F "$1/" | sort -r || true; }

unmount_root() {
    local root=$1 target
    for target in $(mounts_under "$root"); do
        umount "$target" 2>/dev/null || umount -l "$target"
    done
    if [ -n "$(mounts_under "$root")" ]; then
        echo "check-images: still mounted under $root; not removing it" >&2
        return 1
    fi
}

drop_root() {
    unmount_root "$1" && rm -rf --one-file-system "$1"
}

cleanup() {
    local status=$? root
    for root in "${ROOTS[@]}"; do
        [ -d "$root" ] && { drop_root "$root" || status=1; }
    done
    if [ -z "$(mounts_under "$WORK")" ]; then rm -rf --one-file-system "$WORK"; else status=1; fi
    exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT TERM HUP

# The host's way to PyPI, for build steps only (a minimal root has no CA bundle; pip's own
# certifi does not know a local proxy's CA).
NET_ENV=()
for var in http_proxy https_proxy no_proxy HTTP_PROXY HTTPS_PROXY NO_PROXY \
    PIP_INDEX_URL PIP_EXTRA_INDEX_URL PIP_TRUSTED_HOST PIP_DEFAULT_TIMEOUT; do
    [ -z "${!var:-}" ] || NET_ENV+=("$var=${!var}")
done
HOST_CA=${PIP_CERT:-${SSL_CERT_FILE:-/etc/ssl/certs/ca-certificates.crt}}
[ -f "$HOST_CA" ] && NET_ENV+=(PIP_CERT=/run/check-images/ca.pem)

# A fresh root from the base tarball, with what docker run provides: /proc, /sys (PoCL reads
# the CPU topology there), /dev, resolv.conf and hosts; plus the host's CA bundle for pip.
new_root() {
    local root=$WORK/$1 tarball=${2:-$WORK/base.tar}
    ROOTS+=("$root")
    mkdir "$root"
    tar -C "$root" -xpf "$tarball"
    mount -t proc proc "$root/proc"
    for dir in sys dev; do
        mount --rbind "/$dir" "$root/$dir"
        mount --make-rslave "$root/$dir"
    done
    cp /etc/resolv.conf /etc/hosts "$root/etc/"
    if [ -f "$HOST_CA" ]; then
        mkdir -p "$root/run/check-images"
        cp "$HOST_CA" "$root/run/check-images/ca.pem"
    fi
}

# A shell command in the root as root, with the build network settings.
as_root() {
    local root=$1
    shift
    chroot "$root" /usr/bin/env -i "PATH=$DEFAULT_PATH" HOME=/root "${NET_ENV[@]}" \
        /bin/sh -c "$*"
}

copy_worktree() {  # the tracked and untracked (not ignored) files: a clone plus its edits
    mkdir -p "$1"
    git -C "$REPO" ls-files -z --cached --others --exclude-standard \
        | tar -C "$REPO" --null --ignore-failed-read -T - -cf - 2>/dev/null | tar -C "$1" -xf -
}

installed() { chroot "$1" dpkg-query -W -f '${Package}\n' | sort; }
mesa_version() { chroot "$1" dpkg-query -W -f '${Version}' libgl1-mesa-dri 2>/dev/null; }
manual() { chroot "$1" apt-mark showmanual | sort; }

# "byte-identical" or the pixel difference, against this machine's demo: NAME ROOT PNG.
compare_demo() {
    local name=$1 root=$2 png=$3
    local versions
    versions="Mesa $(mesa_version "$root" || true) there, $(dpkg-query -W \
        -f '${Version}' libgl1-mesa-dri 2>/dev/null || echo unknown) here"
    if cmp -s "$png" "$WORK/host-demo.png"; then
        result "$name: demo.png byte-identical to this machine's" \
            "($(sha256sum <"$png" | cut -c1-16); $versions)"
        return
    fi
    local diff
    diff=$("$HOST_VENV/python" - "$WORK/host-demo.png" "$png" <<'EOF'
import sys

import numpy as np
import OpenImageIO as oiio


def read(path):
    image = oiio.ImageInput.open(path)
    if image is None:
        sys.exit(f"cannot read {path}: {oiio.geterror()}")
    pixels = np.asarray(image.read_image(), dtype=np.float64)
    image.close()
    return pixels


host, other = read(sys.argv[1]), read(sys.argv[2])
if host.shape != other.shape:
    sys.exit(f"shapes differ: {host.shape} here, {other.shape} there")
delta = np.abs(host - other) * 255
changed = int((delta.max(axis=-1) > 0).sum())
print(f"{changed} of {host.shape[0] * host.shape[1]} pixels differ, max {delta.max():.0f}/255")
EOF
) || diff="cannot compare: $diff"
    fail "$name: demo.png differs from this machine's: $diff ($versions)"
}

# Line $2 of the README's ```sh block $1: block 1 sets up and renders the demo, block 2 sets up
# and runs the tests; line 1 of each is its apt-get line.
readme_line() {
    awk -v block="$1" -v line="$2" '/^```sh$/ {n++; inside=1; i=0; next} /^```$/ {inside=0}
        inside && n == block && ++i == line {print; exit}' "$REPO/README.md"
}

# What a fresh machine has that minbase lacks: sudo, for the README's "sudo apt-get". The package
# lists are dropped again, so the README's own "apt-get update" is what fetches them.
prepare_readme_root() {
    as_root "$1" "apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
        --no-install-recommends sudo && rm -rf /var/lib/apt/lists/*"
}

# A README line as root in /root/sphrender, its output in $WORK/NAME.log: ROOT NAME LINE.
run_readme_line() {
    local root=$1 name=$2 line=$3 t=$SECONDS
    log "$name: $line"
    if as_root "$root" "export DEBIAN_FRONTEND=noninteractive; cd /root/sphrender && $line" \
        >"$WORK/$name.log" 2>&1; then
        log "$name: done in $((SECONDS - t)) s"
    else
        tail -20 "$WORK/$name.log"
        fail "$name: failed after $((SECONDS - t)) s: $line"
        return 1
    fi
}

# The README's first command on a fresh root; with "tests", then its second one, pytest given
# only the tests that need Chromium, HAProxy and gcc.
check_readme() {
    local name=readme${1:+-$1} root before
    root=$WORK/$name
    new_root "$name"
    prepare_readme_root "$root" >"$WORK/$name-sudo.log" 2>&1 \
        || { tail -5 "$WORK/$name-sudo.log"; fail "$name: installing sudo failed"; return; }
    copy_worktree "$root/root/sphrender"
    before=$(installed "$root" | wc -l)
    run_readme_line "$root" "$name-apt" "$(readme_line 1 1)" || return 0
    log "$name: $(($(installed "$root" | wc -l) - before)) packages installed over minbase + sudo"
    run_readme_line "$root" "$name-demo" "$(readme_line 1 2)" || return 0
    compare_demo "$name" "$root" "$root/root/sphrender/demo.png"
    if [ "${1:-}" = tests ]; then
        before=$(installed "$root" | wc -l)
        run_readme_line "$root" "$name-apt2" "$(readme_line 2 1)" || return 0
        log "$name: $(($(installed "$root" | wc -l) - before)) more packages for the tests"
        local tests="tests/test_viewer.py tests/test_replicas_haproxy.py tests/test_c_client.py"
        if run_readme_line "$root" "$name-pytest" "$(readme_line 2 2) -p no:cacheprovider $tests"
        then
            local summary
            summary=$(grep -E '^=+ .* in [0-9.]+s' "$WORK/$name-pytest.log" | tail -1 | tr -d '=')
            case $summary in
            *skipped* | *failed* | *error*) fail "$name: pytest:$summary ($tests)" ;;
            *) result "$name: pytest:$summary ($tests)" ;;
            esac
        fi
    fi
    drop_root "$root"
}

check_readme-tests() { check_readme tests; }

# The Dockerfile's steps, then the package list they brought.
build_image() {
    local name=$1 dockerfile=$2 root=$WORK/$1 before_all before_manual
    new_root "$name"
    before_all=$(installed "$root")
    before_manual=$(manual "$root")
    local env_args=()
    for pair in "${NET_ENV[@]}"; do env_args+=(--env "$pair"); done
    log "$name: running $(basename "$dockerfile")'s steps"
    if ! "${CHROOT_IMAGE[@]}" build "$dockerfile" "$root" --context "$REPO" "${env_args[@]}" \
        >"$WORK/$name-build.log" 2>&1; then
        tail -15 "$WORK/$name-build.log"
        fail "$name: the Dockerfile's steps failed"
        return 1
    fi
    rm -rf "$root/run/check-images"  # the image keeps no trace of the build network
    local requested added size
    requested=$(comm -13 <(echo "$before_manual") <(manual "$root") | tr '\n' ' ')
    added=$(comm -13 <(echo "$before_all") <(installed "$root") | wc -l)
    size=$(du -sh --one-file-system "$root" | cut -f1)
    result "$name: apt installs ${requested% } ($added packages over minbase; root $size)"
}

in_image() {  # a shell command as `docker run IMAGE sh -c` would run it
    local dockerfile=$1 root=$2
    shift 2
    "${CHROOT_IMAGE[@]}" exec "$dockerfile" "$root" -- "$@"
}

# A jittered lattice ball (particle radius 1 cm, 15 cm across), its scene and a summary of
# what `sphrender sph` computed, run with the image's python (its venv's numpy).
BALL_PY='import numpy as np
r = 0.01
axis = np.arange(-0.15, 0.15 + 1e-9, 2 * r)
grid = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
ball = grid[np.linalg.norm(grid, axis=1) <= 0.15]
ball += np.random.default_rng(1).normal(0.0, 0.1 * r, ball.shape)
np.savez("/tmp/check/ball.npz", positions=ball)'
SPH_SCENE='[image]
width = 160
height = 120
[camera]
eye = [0.0, 0.1, 0.6]
target = [0.0, 0.0, 0.0]
[particles]
radius = 0.01
[sph]
adaptive_radius = true'
SPH_SUMMARY='import numpy as np
a = np.load("/tmp/check/ball-sph.npz")
density, surface = a["density"], a["surface"]
print(f"{len(density)} particles, {int(surface.sum())} on the surface, "
      f"median density {np.median(density):.0f}")'

check_cpu() {
    local dockerfile=$REPO/docker/cpu.Dockerfile root=$WORK/cpu out
    build_image cpu "$dockerfile" || return 0
    mkdir -p "$root/tmp/check" && chmod 1777 "$root/tmp/check"
    printf '%s\n' "$SPH_SCENE" >"$root/tmp/check/sph.toml"
    printf '%s\n' "$BALL_PY" >"$root/tmp/check/ball.py"
    printf '%s\n' "$SPH_SUMMARY" >"$root/tmp/check/summary.py"
    if out=$(in_image "$dockerfile" "$root" sphrender info 2>&1); then
        result "cpu: sphrender info: $(echo "$out" | tr -d '\n' | tr -s ' ')"
    else
        fail "cpu: sphrender info failed: $out"
    fi
    local t=$SECONDS
    if out=$(in_image "$dockerfile" "$root" sphrender demo -o /tmp/check/demo.png 2>&1); then
        log "cpu: demo rendered in $((SECONDS - t)) s"
        compare_demo cpu "$root" "$root/tmp/check/demo.png"
    else
        fail "cpu: sphrender demo failed: $out"
    fi
    t=$SECONDS
    if out=$(in_image "$dockerfile" "$root" python3 /tmp/check/ball.py 2>&1) \
        && in_image "$dockerfile" "$root" sphrender sph /tmp/check/ball.npz \
            --scene /tmp/check/sph.toml -o /tmp/check/ball-sph.npz >/dev/null 2>&1 \
        && summary=$(in_image "$dockerfile" "$root" python3 /tmp/check/summary.py 2>&1) \
        && in_image "$dockerfile" "$root" sphrender render /tmp/check/ball.npz \
            --scene /tmp/check/sph.toml -o /tmp/check/ball.png >/dev/null 2>&1 \
        && [ -s "$root/tmp/check/ball.png" ]; then
        result "cpu: sphrender sph on a generated ball: $summary; rendered with adaptive radii" \
            "(ball.png $(stat -c %s "$root/tmp/check/ball.png") bytes) in $((SECONDS - t)) s"
    else
        fail "cpu: sphrender sph / render on a generated ball failed: ${summary:-$out}"
    fi
    drop_root "$root"
}

check_nvidia() {
    local dockerfile=$REPO/docker/nvidia.Dockerfile root=$WORK/nvidia out status=0
    build_image nvidia "$dockerfile" || return 0
    local vendor=$root/usr/share/glvnd/egl_vendor.d/10_nvidia.json icd=$root/etc/OpenCL/vendors/nvidia.icd
    if grep -q '"libEGL_nvidia.so.0"' "$vendor" && [ "$(cat "$icd")" = libnvidia-opencl.so.1 ]; then
        result "nvidia: 10_nvidia.json names libEGL_nvidia.so.0, nvidia.icd libnvidia-opencl.so.1"
    else
        fail "nvidia: the GLVND vendor file or the OpenCL ICD file is missing or wrong"
    fi
    if [ -n "$(find "$root/usr/lib" -name swrast_dri.so -print -quit)" ]; then
        fail "nvidia: Mesa's llvmpipe is installed (the image must not fall back to the CPU)"
    fi
    out=$(in_image "$dockerfile" "$root" sphrender info 2>/dev/null) || status=$?
    if [ "$status" -eq 3 ] && echo "$out" | grep -q 'libEGL_nvidia.so.0.*no NVIDIA GPU' \
        && echo "$out" | grep -q 'nvidia.icd: libnvidia-opencl.so.1 does not load'; then
        result "nvidia: sphrender info exits 3 without a GPU: $(echo "$out" | tr -d '\n' | tr -s ' ')"
    else
        fail "nvidia: sphrender info (exit $status) does not report the missing GPU: $out"
    fi
    drop_root "$root"
}

check_minimal() {
    local gl_packages=() package
    while read -r package; do
        case $package in python3 | python3-venv | pocl-opencl-icd) ;; *) gl_packages+=("$package") ;;
        esac
    done <"$REPO/deploy/apt/render.txt"
    local root=$WORK/prepared
    new_root prepared
    log "minimal: preparing a root with python3, python3-venv and sphrender, no GL"
    if ! as_root "$root" "apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install \
            -y -qq --no-install-recommends python3 python3-venv" >"$WORK/minimal.log" 2>&1; then
        tail -5 "$WORK/minimal.log"
        fail "minimal: installing python3 failed"
        return 0
    fi
    copy_worktree "$root/opt/sphrender"
    if ! as_root "$root" "python3 -m venv /opt/venv && /opt/venv/bin/pip install -q \
            /opt/sphrender" >>"$WORK/minimal.log" 2>&1; then
        tail -5 "$WORK/minimal.log"
        fail "minimal: pip install failed"
        return 0
    fi
    unmount_root "$root"
    tar -C "$root" --one-file-system -cf "$WORK/prepared.tar" .
    drop_root "$root"
    local variants=() set out other
    for package in "${gl_packages[@]}" libopengl0; do
        set=""
        for other in "${gl_packages[@]}"; do
            [ "$other" = "$package" ] || set+="$other "
        done
        variants+=("without $package|$set")
    done
    # the last one again with libgl1 in place of libopengl0
    variants[-1]="libgl1 instead of libopengl0|${set}libgl1"
    local index=0 variant
    for variant in "${variants[@]}"; do
        index=$((index + 1))
        set=${variant#*|}
        new_root "variant$index" "$WORK/prepared.tar"
        root=$WORK/variant$index
        as_root "$root" "DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
            --no-install-recommends $set" >>"$WORK/minimal.log" 2>&1 || true
        local present=""
        for package in "${gl_packages[@]}" libgl1; do
            chroot "$root" dpkg-query -W -f '${Status}' "$package" 2>/dev/null \
                | grep -q 'ok installed' && present+="$package "
        done
        if out=$(as_root "$root" "cd /tmp && /opt/venv/bin/sphrender demo -o demo.png" 2>&1); then
            result "minimal: ${variant%%|*}: renders (installed: ${present% })"
        else
            result "minimal: ${variant%%|*}: fails: $(echo "$out" | grep 'sphrender: error' \
                | cut -c1-300)"
        fi
        drop_root "$root"
    done
}

SUITE=$("${CHROOT_IMAGE[@]}" suite "$REPO/docker/cpu.Dockerfile")
[ "$("${CHROOT_IMAGE[@]}" suite "$REPO/docker/nvidia.Dockerfile")" = "$SUITE" ] \
    || { echo "check-images: the Dockerfiles name different suites" >&2; exit 2; }
log "host: reference demo with $HOST_VENV/sphrender"
"$HOST_VENV/sphrender" demo -o "$WORK/host-demo.png" >/dev/null
log "base: mmdebstrap --variant=minbase $SUITE"
mmdebstrap --quiet --variant=minbase "$SUITE" "$WORK/base.tar" ${MIRROR:+"$MIRROR"}
BASE_PACKAGES=$(tar -xOf "$WORK/base.tar" ./var/lib/dpkg/status | grep -c '^Package:')
result "base: minbase $SUITE, $BASE_PACKAGES packages, built in $((SECONDS - START)) s"

for check in "${CHECKS[@]}"; do
    t=$SECONDS
    "check_$check"
    log "$check: done in $((SECONDS - t)) s"
done

echo
echo "check-images summary ($((SECONDS - START)) s):"
printf '  %s\n' "${RESULTS[@]}"
[ $FAILED -eq 0 ] && echo "check-images: PASS" || echo "check-images: FAIL"
exit $FAILED
