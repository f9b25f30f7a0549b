"""`sphrender submit --ray`: a sequence rendered by a pool of Ray actors.

Each actor (`RenderActor`) is one Ray worker process that owns one GL context (and, when the
scene needs SPH, one CL context) for its whole life: the contexts, compiled programs, render
targets and IBL tables are built once per actor, never per frame. Where a node has GPUs there is
one actor per GPU (``num_gpus=1``; Ray sets ``CUDA_VISIBLE_DEVICES`` and the actor opens the EGL
device of its GPU); nodes without GPUs get ``actors_per_node`` actors sharing the node's CPUs.

`RayFrameRenderer` is a `FrameRenderer` (``client/submit.py``), so ``run_submission`` keeps
doing what it does for ``--server``: ``--resume``, the progress bar, the summary, exit status 4,
the atomic writes. Its worker threads (``capacity`` of them: actors x frames in flight per
actor) each read one input once, `ray.put` the `ParticleFrame` into the object store and hand
the reference to an idle actor slot; the encoded image comes back through the object store and
the *driver* writes it. Outputs are written by the driver, not by the actors, because

* a frame is then written exactly once, by one process, after its image is complete: an actor
  that dies mid-frame (or after rendering, before answering) has written nothing, and its frame
  is retried on another actor from the same object reference, not re-read from disk;
* the cluster needs no shared file system for outputs, and ``--resume`` inspects the
  directory the user named, on the machine they ran the command on.

Bounded work and backpressure: a thread blocks until an actor slot is free, so at most
``capacity`` frames are in the driver's memory and in the object store at once, whatever the
length of the sequence. With two frames in flight per actor, one renders while the next one's
particles are already on the actor's node.

An actor that dies (process killed, node lost, render stuck past ``frame_timeout_s``) is
replaced by a new actor with the same placement (a bounded number of times), and every frame it
held is retried on another actor. A frame on which ``max_losses_per_frame`` actors died fails
(it is reported, the rest still render) instead of killing actors forever.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import queue
import re
import socket
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import ray
import ray.exceptions
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from sphrender.client.submit import FrameFailed, TransientError
from sphrender.core.errors import InputError
from sphrender.core.frame import ParticleFrame, make_frame
from sphrender.server.engine.gpu.gl_context import GLUnavailableError
from sphrender.server.output.local import ImageFormat, LocalFrameRenderer
from sphrender.server.scene import Scene

log = logging.getLogger("sphrender.ray")

#: Object store of the throwaway local instance ``--ray`` starts without an address: frames in
#: flight are bounded, so a small store is plenty (Ray's default is 30 % of the machine's memory).
LOCAL_OBJECT_STORE_BYTES = 512 << 20
#: How long an address's TCP port may take to accept, before ray.init is even tried (ray.init
#: itself waits minutes for an unreachable head and then exits the process).
CONNECT_CHECK_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class RayOptions:
    #: None: $RAY_ADDRESS, else a new local Ray instance for this run. Otherwise ``auto`` (the
    #: cluster `ray start` runs on this machine), ``HOST:PORT`` (a head's GCS port) or
    #: ``ray://HOST:PORT`` (Ray Client; needs ``ray[client]``).
    address: str | None = None
    #: actors on each node without GPUs (nodes with GPUs get one per GPU)
    actors_per_node: int = 1
    #: frames queued on one actor at once (one rendering, the rest waiting on its node)
    in_flight_per_actor: int = 2
    #: how long the actors may take to start (scheduling + GL context)
    start_timeout_s: float = 120.0
    #: a frame taking longer counts as a lost actor (killed, replaced, frame retried)
    frame_timeout_s: float = 300.0
    max_losses_per_frame: int = 3


class RenderActor:
    """Runs inside a Ray worker process: one `LocalFrameRenderer` (GL context, and a CL
    context on first SPH need) for the actor's life. Ray runs a synchronous actor's constructor
    and methods on one thread, the GL owner; `GLContext.check_owner` would say otherwise."""

    def __init__(
        self, scene: Scene, fmt: ImageFormat, environment_dirs: Sequence[str], gpu: bool
    ) -> None:
        self._args = (scene, fmt, [Path(d) for d in environment_dirs])
        self._gpu = gpu
        self._device = 0
        self._renderer = self._open(egl_devices(gpu))
        # Warm up as the service does: one particle at the camera target compiles every program
        # and builds every target and lighting table the scene uses, so the first frame is not
        # slow, and a node that cannot render the scene (an environment file missing there)
        # fails here, at start, with the reason.
        camera, radius = scene.camera.target, scene.particles.radius
        warm = make_frame(
            np.array([camera], dtype=np.float64), radii=np.array([radius], np.float32)
        )
        self._renderer.render(warm)

    def _open(self, devices: Sequence[int]) -> LocalFrameRenderer:
        """The first EGL device that gives a hardware renderer (on a GPU actor), else the last
        one tried: which index is this actor's GPU depends on the driver (see egl_devices)."""
        scene, fmt, dirs = self._args
        for index, device in enumerate(devices):
            last = index == len(devices) - 1
            try:
                renderer = LocalFrameRenderer(scene, fmt, dirs, device_index=device)
            except GLUnavailableError:
                if last:
                    raise
                continue
            self._device = device
            software = any(n in renderer.gl_renderer for n in ("llvmpipe", "softpipe"))
            if not (self._gpu and software) or last:
                return renderer
            renderer.close()
        raise AssertionError("no EGL device to try")

    def ready(self) -> dict[str, Any]:
        return {
            "pid": os.getpid(),
            "node": ray.get_runtime_context().get_node_id(),
            "gl_renderer": self._renderer.gl_renderer,
            "egl_device": self._device,
        }

    def render(self, frame: ParticleFrame) -> tuple[str, bytes, str]:
        """("image", bytes, "") | ("input", message, field) | ("failed", message, "")."""
        try:
            return "image", self._renderer.render(frame), ""
        except InputError as exc:
            return "input", exc.message.encode(), exc.field
        except Exception as exc:  # a GL/driver error: start from a fresh context, as the service
            message = f"{type(exc).__name__}: {exc}"
            try:
                self._renderer.close()
            finally:
                self._renderer = self._open([self._device])
            return "failed", message.encode(), ""


def egl_devices(gpu: bool) -> list[int]:
    """EGL device indices for this actor to try, best first: $SPHRENDER_EGL_DEVICE alone when
    set; for a GPU actor its Ray GPU id (the physical index, which is the EGL index when EGL
    lists the GPUs in PCI order and ignores CUDA_VISIBLE_DEVICES), then 0 (where the driver
    shows only the visible GPU); otherwise 0."""
    explicit = os.environ.get("SPHRENDER_EGL_DEVICE")
    if explicit:
        return [int(explicit)]
    ids = ray.get_gpu_ids() if gpu else []
    first = int(ids[0]) if ids else 0
    return [first, 0] if first else [0]


@dataclass(frozen=True)
class _Placement:
    node_id: str
    num_cpus: float
    num_gpus: int


@dataclass(eq=False)
class _Actor:
    number: int
    placement: _Placement
    handle: Any
    alive: bool = True


_ERROR_LINE = re.compile(r"^\s*(?:\w+\.)*(\w+(?:Error|Exception)\b.*)$")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def one_line(exc: BaseException) -> str:
    """Ray's errors carry whole tracebacks; the line that says what went wrong (the last
    ``SomeError: ...`` line, without its module path), else the first line."""
    text = _ANSI.sub("", str(exc)).strip()
    errors = [m.group(1) for line in text.splitlines() if (m := _ERROR_LINE.match(line))]
    line = errors[-1] if errors else (text.splitlines() or [type(exc).__name__])[0]
    return line if len(line) <= 300 else line[:297] + "..."


def connect(address: str | None) -> None:
    """ray.init for `address` (see `RayOptions.address`); bad or unreachable addresses are an
    `InputError` naming --ray, within seconds."""
    if ray.is_initialized():
        return
    target = address or os.environ.get("RAY_ADDRESS") or None
    quiet: dict[str, Any] = {"log_to_driver": False, "logging_level": logging.WARNING}
    if target is None:
        ray.init(
            address="local",
            include_dashboard=False,
            object_store_memory=LOCAL_OBJECT_STORE_BYTES,
            **quiet,
        )
        return
    if Path(target).exists():
        raise InputError(
            "--ray",
            f"{target!r} is a file or directory, not a Ray address (put --ray after the inputs, "
            "or write --ray=ADDRESS)",
        )
    if target != "auto" and not target.startswith("ray://"):
        host, sep, port = target.rpartition(":")
        if not sep or not host or not port.isdigit():
            raise InputError(
                "--ray", f"expected auto, HOST:PORT or ray://HOST:PORT, got {target!r}"
            )
        try:
            socket.create_connection((host, int(port)), timeout=CONNECT_CHECK_TIMEOUT_S).close()
        except OSError as exc:
            reason = exc.strerror or type(exc).__name__
            raise InputError("--ray", f"no Ray cluster reachable at {target} ({reason})") from None
    # Ray's C++ client logs every failed attempt to stderr; the error below says it once.
    os.environ.setdefault("RAY_BACKEND_LOG_LEVEL", "error")
    try:
        ray.init(address=target, **quiet)
    except (ConnectionError, ValueError, RuntimeError, SystemExit) as exc:
        hint = ""
        if os.environ.get("RAY_AUTH_MODE") != "token":
            hint = (
                " (a cluster with token authentication needs RAY_AUTH_MODE=token and its "
                "token in RAY_AUTH_TOKEN or ~/.ray/auth_token)"
            )
        raise InputError("--ray", f"cannot connect to {target}: {one_line(exc)}{hint}") from None


def plan_placements(nodes: Sequence[dict[str, Any]], actors_per_node: int) -> list[_Placement]:
    """One actor per GPU on nodes with GPUs, `actors_per_node` on the others (sharing the
    node's CPUs, so Ray never leaves one waiting for a CPU)."""
    placements: list[_Placement] = []
    for node in nodes:
        if not node.get("Alive"):
            continue
        resources = node.get("Resources", {})
        gpus = int(resources.get("GPU", 0))
        cpus = float(resources.get("CPU", 0))
        if not gpus and not cpus:
            continue  # e.g. a head started with --num-cpus=0 to keep work off it
        count = gpus if gpus else actors_per_node
        # rounded down to Ray's resource precision, so the shares never add up to more
        share = math.floor((min(1.0, cpus / count) if gpus else cpus / count) * 1e4) / 1e4
        placements += [_Placement(node["NodeID"], share, 1 if gpus else 0)] * count
    return placements


class RayFrameRenderer:
    """A thread-safe `FrameRenderer` over a pool of `RenderActor`s (module docstring)."""

    def __init__(
        self,
        scene: Scene,
        fmt: ImageFormat,
        environment_dirs: Sequence[str | Path] = (),
        options: RayOptions | None = None,
    ) -> None:
        self.options = options or RayOptions()
        if self.options.actors_per_node < 1:
            raise InputError(
                "--ray-actors", f"must be at least 1, got {self.options.actors_per_node}"
            )
        self.format = fmt
        self._actor_args = (scene, fmt, [str(Path(d).resolve()) for d in environment_dirs])
        self._lock = threading.Lock()
        self._idle: queue.Queue[_Actor] = queue.Queue()
        self._actors: list[_Actor] = []
        self._started = 0
        self.actors_lost = 0
        connect(self.options.address)
        try:
            self._start_pool()
        except BaseException:
            self.close()
            raise

    # -- the pool -------------------------------------------------------------------------------

    def _spawn(self, placement: _Placement) -> _Actor:
        self._started += 1
        remote = ray.remote(RenderActor).options(
            num_cpus=placement.num_cpus,
            num_gpus=placement.num_gpus,
            max_restarts=0,
            max_task_retries=0,
            # soft: a replacement goes elsewhere when its node is gone
            scheduling_strategy=NodeAffinitySchedulingStrategy(placement.node_id, soft=True),
        )
        handle = remote.remote(*self._actor_args, placement.num_gpus > 0)
        return _Actor(self._started, placement, handle)

    def _start_pool(self) -> None:
        placements = plan_placements(ray.nodes(), self.options.actors_per_node)
        if not placements:
            raise InputError("--ray", "the Ray cluster has no live node")
        actors = [self._spawn(p) for p in placements]
        pending = {actor.handle.ready.remote(): actor for actor in actors}
        ready, late = ray.wait(
            list(pending), num_returns=len(pending), timeout=self.options.start_timeout_s
        )
        errors: list[str] = []
        for ref in ready:
            actor = pending[ref]
            try:
                info = ray.get(ref)
            except ray.exceptions.RayError as exc:
                errors.append(one_line(exc))
                continue
            log.info(
                "ray actor %d: node %s pid %d, GL %s (EGL device %d)",
                actor.number,
                info["node"][:12],
                info["pid"],
                info["gl_renderer"],
                info["egl_device"],
            )
            self._add(actor)
        for ref in late:
            ray.kill(pending[ref].handle, no_restart=True)
        if late:
            errors.append(
                f"{len(late)} actor(s) not started within {self.options.start_timeout_s:.0f} s "
                "(does the cluster have the CPUs/GPUs they ask for?)"
            )
        if not self._actors:
            raise InputError("--ray", f"no render actor could start: {errors[0]}")
        for error in errors:
            log.warning("ray: an actor did not start: %s", error)
        self._replacements_left = max(4, 2 * len(placements))

    def _add(self, actor: _Actor) -> None:
        self._actors.append(actor)
        for _ in range(self.options.in_flight_per_actor):
            self._idle.put(actor)

    @property
    def actor_count(self) -> int:
        with self._lock:
            return sum(actor.alive for actor in self._actors)

    @property
    def capacity(self) -> int:
        """Frames worth keeping in flight: what `run_submission`'s concurrency should be."""
        return self.actor_count * self.options.in_flight_per_actor

    def _acquire(self) -> _Actor:
        while True:
            try:
                actor = self._idle.get(timeout=0.5)
            except queue.Empty:
                if self.actor_count == 0:
                    raise FrameFailed(
                        f"no render actor left ({self.actors_lost} lost, no replacement left)"
                    ) from None
                continue
            if actor.alive:
                return actor

    def _lose(self, actor: _Actor, reason: str) -> None:
        """Retire a dead (or stuck) actor and start its replacement, once per actor."""
        with self._lock:
            if not actor.alive:
                return
            actor.alive = False
            self.actors_lost += 1
            with contextlib.suppress(Exception):  # already gone
                ray.kill(actor.handle, no_restart=True)
            replaced = self._replacements_left > 0
            if replaced:
                self._replacements_left -= 1
                self._add(self._spawn(actor.placement))
        log.warning(
            "ray: actor %d lost (%s); its frames are retried on other actors%s",
            actor.number,
            reason,
            "; replacement started" if replaced else "; no replacement left",
        )

    # -- FrameRenderer --------------------------------------------------------------------------

    def render(self, frame: ParticleFrame) -> bytes:
        particles = ray.put(frame)  # once per frame: every retry below reuses this reference
        losses: list[str] = []
        while True:
            actor = self._acquire()
            try:
                status, payload, field = ray.get(
                    actor.handle.render.remote(particles), timeout=self.options.frame_timeout_s
                )
            except (ray.exceptions.RayActorError, ray.exceptions.GetTimeoutError) as exc:
                reason = (
                    f"no answer within {self.options.frame_timeout_s:.0f} s"
                    if isinstance(exc, ray.exceptions.GetTimeoutError)
                    else one_line(exc)
                )
                self._lose(actor, reason)
                losses.append(reason)
                if len(losses) >= self.options.max_losses_per_frame:
                    raise FrameFailed(
                        f"{len(losses)} render actors were lost on this frame (last: {reason})"
                    ) from None
                continue
            except ray.exceptions.RayError as exc:
                self._idle.put(actor)
                raise TransientError(one_line(exc)) from None
            self._idle.put(actor)
            if status == "image":
                return payload
            if status == "input":
                raise InputError(field, payload.decode())
            raise TransientError(f"render failed on a Ray actor: {payload.decode()}")

    def close(self) -> None:
        """Stop the actors and disconnect (a local instance started for this run stops too)."""
        with self._lock:
            for actor in self._actors:
                if actor.alive:
                    actor.alive = False
                    with contextlib.suppress(Exception):
                        ray.kill(actor.handle, no_restart=True)
        if ray.is_initialized():
            ray.shutdown()
