"""The shared libraries a headless EGL context loads, and the Debian package behind each one.

glcontext (moderngl's loader) dlopens two libraries: the EGL dispatcher and a GL library whose
symbols it resolves (falling back to ``eglGetProcAddress``). Left alone it asks
``ctypes.util.find_library("GL")``, which finds only ``libGL.so.1`` (package ``libgl1``, which
also brings GLX) and otherwise tries the development name ``libGL.so`` that no runtime package
provides: "libGL.so not loaded". GLVND's ``libOpenGL.so.0`` (``libopengl0``: GL without GLX)
serves EGL just as well, so `resolve_libraries` hands glcontext whichever of the two loads.

Behind the EGL dispatcher (GLVND's ``libEGL.so.1``) sit the vendor libraries named by JSON files
in ``egl_vendor.d``: Mesa's ``libEGL_mesa.so.0`` (``libegl-mesa0``), whose CPU renderer llvmpipe
is the DRI driver ``swrast_dri.so`` (``libgl1-mesa-dri``), or NVIDIA's ``libEGL_nvidia.so.0``,
which the NVIDIA Container Toolkit mounts from the host driver. `diagnose` checks each link and
says which one is missing and what provides it.

Standard library only, so it runs before anything is installed: ``python3
server/engine/gpu/gl_libraries.py`` prints the Debian packages Mesa's CPU rendering still lacks, one
a line, and exits 1 if there are any (``.ci/run`` uses it).
"""

from __future__ import annotations

import ctypes
import json
import os
import platform
import sys
import sysconfig
from dataclasses import dataclass
from pathlib import Path

#: Mesa llvmpipe through EGL on Debian/Ubuntu: the smallest set that renders, found on a clean
#: Debian 12 root (docker/check-images.sh). libgbm1 and the rest come as dependencies.
MESA_PACKAGES = ("libegl1", "libegl-mesa0", "libgl1-mesa-dri", "libopengl0")

EGL_LIBRARY = "libEGL.so.1"
#: GL libraries glcontext can resolve GL symbols from, in order of preference (libGL.so.1 is what
#: glcontext picks by itself; libOpenGL.so.0 is the same GLVND dispatch without GLX).
GL_LIBRARIES = ("libGL.so.1", "libOpenGL.so.0")
MESA_EGL_VENDOR = "libEGL_mesa.so.0"
LLVMPIPE_DRIVER = "swrast_dri.so"

#: The Debian package that provides each library, keyed by the name up to ".so".
PACKAGE_OF = {
    "libEGL": "libegl1",
    "libGL": "libgl1",
    "libOpenGL": "libopengl0",
    "libEGL_mesa": "libegl-mesa0",
    "swrast_dri": "libgl1-mesa-dri",
}

#: What an NVIDIA container needs for the host driver's EGL library to be mounted.
NVIDIA_HINT = (
    "no NVIDIA GPU driver is here (no GPU, or a container started without the NVIDIA Container "
    "Toolkit: docker run --gpus all, NVIDIA_DRIVER_CAPABILITIES including graphics)"
)

_DEFAULT_VENDOR_DIRS = ("/etc/glvnd/egl_vendor.d", "/usr/share/glvnd/egl_vendor.d")


def package_for(library: str) -> str | None:
    """The Debian package that provides `library` (a name or a path), if it is one we know."""
    return PACKAGE_OF.get(Path(library).name.split(".so")[0])


def load_error(library: str) -> str | None:
    """None when `library` loads (dlopen), else the loader's message."""
    try:
        ctypes.CDLL(library)
    except OSError as exc:
        return str(exc)
    return None


def resolve_libraries() -> tuple[str, str]:
    """(EGL library, GL library) to hand glcontext. Its environment overrides win, as in
    glcontext itself; otherwise the first GL library that loads (or the first, so that the error
    names it)."""
    egl = os.environ.get("GLCONTEXT_LINUX_LIBEGL") or EGL_LIBRARY
    gl = os.environ.get("GLCONTEXT_LINUX_LIBGL") or next(
        (name for name in GL_LIBRARIES if load_error(name) is None), GL_LIBRARIES[0]
    )
    return egl, gl


@dataclass(frozen=True)
class EGLVendor:
    config: Path  #: the egl_vendor.d JSON file
    library: str  #: the vendor library it names
    error: str | None  #: why that library does not load; None when it does


def egl_vendors() -> list[EGLVendor]:
    """The EGL vendors GLVND would consider, with the same search as GLVND's: the files in
    ``__EGL_VENDOR_LIBRARY_FILENAMES``, else the folders in ``__EGL_VENDOR_LIBRARY_DIRS``, else
    /etc/glvnd/egl_vendor.d and /usr/share/glvnd/egl_vendor.d."""
    if files := os.environ.get("__EGL_VENDOR_LIBRARY_FILENAMES"):
        configs = [Path(name) for name in files.split(":") if name]
    else:
        dirs = os.environ.get("__EGL_VENDOR_LIBRARY_DIRS")
        folders = [Path(d) for d in (dirs.split(":") if dirs else _DEFAULT_VENDOR_DIRS) if d]
        configs = sorted(
            (path for folder in folders if folder.is_dir() for path in folder.glob("*.json")),
            key=lambda path: path.name,
        )
    vendors = []
    for config in configs:
        try:
            library = str(json.loads(config.read_text())["ICD"]["library_path"])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        vendors.append(EGLVendor(config, library, load_error(library)))
    return vendors


def dri_driver_dirs() -> list[Path]:
    """Where Mesa looks for DRI drivers: ``LIBGL_DRIVERS_PATH``, else the distribution's."""
    if paths := os.environ.get("LIBGL_DRIVERS_PATH"):
        return [Path(p) for p in paths.split(":") if p]
    # Debian's multiarch folder; a Python built elsewhere (pyenv, uv) may not know it.
    multiarch = sysconfig.get_config_var("MULTIARCH") or f"{platform.machine()}-linux-gnu"
    return [Path("/usr/lib") / multiarch / "dri", Path("/usr/lib64/dri"), Path("/usr/lib/dri")]


def has_llvmpipe_driver() -> bool:
    return any((folder / LLVMPIPE_DRIVER).is_file() for folder in dri_driver_dirs())


@dataclass(frozen=True)
class Problem:
    text: str  #: one clause naming the library that is missing
    package: str | None  #: the Debian package that provides it


def _unloadable(library: str, error: str) -> Problem:
    reason = "not found" if "No such file" in error else error
    return Problem(f"{library} does not load ({reason})", package_for(library))


def diagnose(egl: str, gl: str) -> list[Problem]:
    """Every missing link between glcontext and a renderer, given the EGL and GL libraries it
    was told to load; empty when all of them load (the failure is then the driver's own)."""
    problems = []
    if error := load_error(egl):
        problems.append(_unloadable(egl, error))
    if error := load_error(gl):
        if os.environ.get("GLCONTEXT_LINUX_LIBGL"):
            problems.append(_unloadable(gl, error))
        else:
            names = " nor ".join(GL_LIBRARIES)
            problems.append(Problem(f"no GL library loads (neither {names})", "libopengl0"))
    vendors = egl_vendors()
    working = [vendor for vendor in vendors if vendor.error is None]
    for vendor in vendors:
        if vendor.error is not None:
            hint = f": {NVIDIA_HINT}" if "nvidia" in vendor.library.lower() else ""
            problems.append(
                Problem(f"{vendor.library} (named by {vendor.config}) does not load{hint}", None)
            )
    if not working:
        problems.append(
            Problem(f"no EGL vendor loads (Mesa's, for the CPU: {MESA_EGL_VENDOR})", "libegl-mesa0")
        )
    mesa = any(Path(vendor.library).name == MESA_EGL_VENDOR for vendor in working)
    if (mesa or not working) and not has_llvmpipe_driver():
        folders = ", ".join(str(folder) for folder in dri_driver_dirs())
        problems.append(
            Problem(
                f"Mesa's CPU driver {LLVMPIPE_DRIVER} is in none of {folders}", "libgl1-mesa-dri"
            )
        )
    return problems


def failure_message(error: str, egl: str, gl: str) -> str:
    """One line: what glcontext said, what is missing and which packages provide it."""
    problems = diagnose(egl, gl)
    head = f"cannot create a headless OpenGL context through EGL ({error})"
    if not problems:
        return (
            f"{head}; {egl} and {gl} load and an EGL vendor loads, so the driver refused "
            f"(for Mesa's CPU renderer on Debian/Ubuntu: apt-get install {' '.join(MESA_PACKAGES)})"
        )
    packages = list(dict.fromkeys(p.package for p in problems if p.package is not None))
    install = f". On Debian/Ubuntu: apt-get install {' '.join(packages)}" if packages else ""
    return f"{head}: {'; '.join(p.text for p in problems)}{install}"


def missing_mesa_packages() -> list[str]:
    """The MESA_PACKAGES whose library does not load (or, for the driver, is not there)."""
    missing = []
    if load_error(EGL_LIBRARY):
        missing.append("libegl1")
    if all(load_error(name) for name in GL_LIBRARIES):
        missing.append("libopengl0")
    if load_error(MESA_EGL_VENDOR):
        missing.append("libegl-mesa0")
    if not has_llvmpipe_driver():
        missing.append("libgl1-mesa-dri")
    return missing


def main() -> int:
    missing = missing_mesa_packages()
    for package in missing:
        print(package)
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
