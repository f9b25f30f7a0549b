"""The OpenCL context, its command queue and its built programs, owned by one thread.

Like `GLContext`, a `CLContext` records the thread that created it; `context`, `queue` and
`program` raise when called from another thread. In the service that thread is the render thread
(the same one that owns the GL context); in the CLI and the tests it is the main thread.

Device choice never prompts (pyopencl's ``create_some_context`` would ask on a terminal):

1. the ``device`` argument (configuration, ``--cl-device``), else
2. the ``PYOPENCL_CTX`` environment variable, else
3. automatic: GPUs first, then accelerators, then CPUs, in platform order; the first device that
   actually builds a small probe kernel wins.

Both explicit forms accept ``"P"`` or ``"P:D"`` (platform and device indices, as pyopencl's own
``PYOPENCL_CTX``) or a case-insensitive substring of ``"platform name / device name"``.

Why probe instead of taking the first device: a machine may list a PoCL that cannot compile for
its CPU. The PoCL wheel on PyPI (``pocl-binary-distribution`` 3.0, LLVM 14) fails with "unknown
target CPU 'generic'" on CPUs newer than LLVM 14 knows (AMD Zen 5), while Debian's
``pocl-opencl-icd`` (PoCL 3.1, LLVM 15) works there. Probing picks the one that works.

Built programs are cached per context, keyed by file name and build options, so a kernel file is
compiled once per process. PoCL additionally keeps compiled kernels on disk (``POCL_CACHE_DIR``,
default ``~/.cache/pocl/kcache``), so a second process skips LLVM entirely.
"""

from __future__ import annotations

import importlib.resources
import os
import posixpath
import re
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pyopencl as cl

#: What to install when no usable OpenCL device exists (CPU OpenCL through PoCL).
POCL_INSTALL_HINT = (
    "install a CPU OpenCL driver: `pip install 'pyopencl[pocl]'` (PoCL from PyPI), or on "
    "Debian/Ubuntu `apt-get install pocl-opencl-icd` (needed on CPUs newer than PyPI's PoCL "
    "knows, such as AMD Zen 5)"
)

_PROBE_SOURCE = "__kernel void probe(__global float *a) { a[get_global_id(0)] *= 2.0f; }"
_KERNEL_PACKAGE = "sphrender.shaders"
#: ``#include "relative/path.cl"`` on a line of its own (see `kernel_source`).
_INCLUDE_RE = re.compile(r'^\s*#\s*include\s+"(?P<path>[^"]+)"\s*$')


class CLUnavailableError(RuntimeError):
    """No usable OpenCL device: no platform, no device, or the chosen one cannot build kernels."""


class CLBuildError(RuntimeError):
    """An OpenCL program failed to build; the message names the file and holds the build log."""


@dataclass(frozen=True)
class CLDeviceInfo:
    platform_index: int
    device_index: int
    platform_name: str
    device_name: str
    device_type: str

    @property
    def label(self) -> str:
        return (
            f"{self.platform_index}:{self.device_index} {self.platform_name} / {self.device_name}"
        )


def _import_pyopencl() -> Any:
    try:
        import pyopencl
    except ImportError as exc:
        raise CLUnavailableError(
            f"pyopencl cannot be imported ({exc}); {POCL_INSTALL_HINT}"
        ) from None
    return pyopencl


def _type_name(cl_module: Any, device: Any) -> str:
    kind = int(device.type)
    if kind & cl_module.device_type.GPU:
        return "gpu"
    if kind & cl_module.device_type.ACCELERATOR:
        return "accelerator"
    if kind & cl_module.device_type.CPU:
        return "cpu"
    return "other"


def list_devices() -> list[tuple[CLDeviceInfo, Any]]:
    """Every (platform, device) pair the ICD loader reports; empty when there is no platform."""
    cl_module = _import_pyopencl()
    try:
        platforms = cl_module.get_platforms()
    except cl_module.Error:  # PLATFORM_NOT_FOUND_KHR when no ICD is installed
        return []
    found: list[tuple[CLDeviceInfo, Any]] = []
    for p_index, platform in enumerate(platforms):
        try:
            devices = platform.get_devices()
        except cl_module.Error:  # DEVICE_NOT_FOUND on a platform without devices
            continue
        for d_index, device in enumerate(devices):
            info = CLDeviceInfo(
                p_index,
                d_index,
                platform.name.strip(),
                device.name.strip(),
                _type_name(cl_module, device),
            )
            found.append((info, device))
    return found


def _select_explicit(
    choice: str, devices: list[tuple[CLDeviceInfo, Any]], source: str
) -> tuple[CLDeviceInfo, Any]:
    available = "; ".join(info.label for info, _ in devices) or "none"
    parts = choice.strip().split(":")
    if all(part.strip().isdigit() for part in parts) and len(parts) in (1, 2):
        p_index = int(parts[0])
        d_index = int(parts[1]) if len(parts) == 2 else 0
        for info, device in devices:
            if (info.platform_index, info.device_index) == (p_index, d_index):
                return info, device
    else:
        needle = choice.strip().lower()
        for info, device in devices:
            if needle in f"{info.platform_name} / {info.device_name}".lower():
                return info, device
    raise CLUnavailableError(
        f"{source} = {choice!r} matches no OpenCL device; available: {available}"
    )


def icd_load_errors() -> list[str]:
    """The OpenCL ICD files (``OCL_ICD_VENDORS``, else /etc/OpenCL/vendors) whose library does
    not load, as "file: library does not load"; the ICD loader skips them without a word, which is
    how an NVIDIA image without a GPU looks (nvidia.icd names the host driver's library)."""
    import ctypes
    from pathlib import Path

    vendors = Path(os.environ.get("OCL_ICD_VENDORS") or "/etc/OpenCL/vendors")
    files = sorted(vendors.glob("*.icd")) if vendors.is_dir() else [vendors]
    errors = []
    for icd in files:
        try:
            library = icd.read_text().strip()
        except OSError:
            continue
        try:
            ctypes.CDLL(library)
        except OSError:
            errors.append(f"{icd}: {library} does not load")
    return errors


def probe_device(cl_module: Any, device: Any) -> tuple[Any, str | None]:
    """Build and run a one-line kernel: (the context, None) when it works, else (None, why)."""
    import numpy as np

    try:
        context = cl_module.Context([device])
        program = cl_module.Program(context, _PROBE_SOURCE).build()
        queue = cl_module.CommandQueue(context)
        data = np.arange(4, dtype=np.float32)
        buffer = cl_module.Buffer(
            context,
            cl_module.mem_flags.READ_WRITE | cl_module.mem_flags.COPY_HOST_PTR,
            hostbuf=data,
        )
        program.probe(queue, (4,), None, buffer)
        cl_module.enqueue_copy(queue, data, buffer)
        queue.finish()
        buffer.release()
    except cl_module.Error as exc:
        lines = [line for line in str(exc).splitlines() if "error" in line.lower()]
        return None, lines[-1].strip() if lines else str(exc).splitlines()[0]
    if not np.array_equal(data, np.arange(4, dtype=np.float32) * 2):
        return None, "the probe kernel computed a wrong result"
    return context, None


def choose_device(device: str | None = None) -> tuple[CLDeviceInfo, Any]:
    """Pick the OpenCL device as the module docstring describes; raises `CLUnavailableError`.

    Returns the device's description and a context on it (the probe's, so it is built once)."""
    cl_module = _import_pyopencl()
    devices = list_devices()
    if not devices:
        raise CLUnavailableError(f"no OpenCL platform found; {POCL_INSTALL_HINT}")
    env_choice = os.environ.get("PYOPENCL_CTX", "").strip()
    if device is not None or env_choice:
        source = "cl_device" if device is not None else "PYOPENCL_CTX"
        info, chosen = _select_explicit(
            device if device is not None else env_choice, devices, source
        )
        context, problem = probe_device(cl_module, chosen)
        if problem is not None:
            raise CLUnavailableError(
                f"OpenCL device {info.label} ({source}) cannot build kernels: {problem}; "
                f"choose another device or {POCL_INSTALL_HINT}"
            )
        return info, context
    order = {"gpu": 0, "accelerator": 1, "cpu": 2, "other": 3}
    problems: list[str] = []
    for info, candidate in sorted(devices, key=lambda pair: order[pair[0].device_type]):
        context, problem = probe_device(cl_module, candidate)
        if problem is None:
            return info, context
        problems.append(f"{info.label}: {problem}")
    raise CLUnavailableError(
        f"no OpenCL device can build kernels ({'; '.join(problems)}); {POCL_INSTALL_HINT}"
    )


def kernel_source(name: str, _included: set[str] | None = None) -> str:
    """The text of ``shaders/<name>`` (package data), with ``#include "file.cl"`` lines replaced
    by that file's text (resolved relative to the including file's folder, each file at most
    once per program, so a kernel file can share another's helpers without a build path)."""
    included = set() if _included is None else _included
    included.add(name)
    resource = importlib.resources.files(_KERNEL_PACKAGE).joinpath(name)
    try:
        text = resource.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise CLBuildError(f"OpenCL kernel file {name} is not in {_KERNEL_PACKAGE}") from None
    lines = []
    for line in text.splitlines(keepends=True):
        match = _INCLUDE_RE.match(line)
        if match is None:
            lines.append(line)
            continue
        target = posixpath.normpath(posixpath.join(posixpath.dirname(name), match["path"]))
        if target.startswith("../"):
            raise CLBuildError(f"{name}: #include {match['path']} leaves {_KERNEL_PACKAGE}")
        if target in included:
            lines.append(f"/* {line.strip()}: already included */\n")
        else:
            lines.append(kernel_source(target, included).rstrip("\n") + "\n")
    return "".join(lines)


class CLContext:
    """An OpenCL context + in-order queue on one device, with a per-context program cache."""

    def __init__(self, device: str | None = None) -> None:
        cl_module = _import_pyopencl()
        self._cl = cl_module
        self.device_info, context = choose_device(device)
        self._context: cl.Context | None = context
        self._queue: cl.CommandQueue | None = cl_module.CommandQueue(self._context)
        self._owner = threading.get_ident()
        self._programs: dict[tuple[str, tuple[tuple[str, str], ...]], cl.Program] = {}

    @property
    def device_name(self) -> str:
        return self.device_info.device_name

    @property
    def platform_name(self) -> str:
        return self.device_info.platform_name

    def check_owner(self) -> None:
        if threading.get_ident() != self._owner:
            raise RuntimeError(
                "the OpenCL context was used from a thread that does not own it; "
                "all OpenCL work must run on the render thread"
            )

    @property
    def context(self) -> cl.Context:
        self.check_owner()
        if self._context is None:
            raise RuntimeError("the OpenCL context has been released")
        return self._context

    @property
    def queue(self) -> cl.CommandQueue:
        self.check_owner()
        if self._queue is None:
            raise RuntimeError("the OpenCL context has been released")
        return self._queue

    @property
    def built(self) -> int:
        """How many programs have been built (and are held)."""
        return len(self._programs)

    def program(self, name: str, defines: Mapping[str, int | float] | None = None) -> cl.Program:
        """The built program of ``shaders/<name>`` with ``-D`` defines; built once, then cached."""
        context = self.context
        key = (name, tuple(sorted((k, repr(v)) for k, v in (defines or {}).items())))
        program = self._programs.get(key)
        if program is None:
            options = [f"-D{k}={v}" for k, v in key[1]]
            try:
                program = self._cl.Program(context, kernel_source(name)).build(options=options)
            except self._cl.RuntimeError as exc:  # BUILD_PROGRAM_FAILURE carries the log
                raise CLBuildError(f"{name}: {exc}") from None
            self._programs[key] = program
        return program

    def release(self) -> None:
        """Drop programs, queue and context (on the owner thread); idempotent."""
        if self._context is None:
            return
        self.check_owner()
        self._programs.clear()
        if self._queue is not None:
            self._queue.finish()
        self._queue = None
        self._context = None

    def __enter__(self) -> CLContext:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
