"""`sphrender submit --ray` against a real Ray cluster on this machine: a head started by the
test (`ray start --head --block`, ephemeral GCS port, its own temp dir, 2 CPUs) and stopped
after it; real `sphrender submit` driver processes; real actor worker processes, one killed
with SIGKILL mid-run. Outputs are compared byte for byte with `submit --local`."""

from __future__ import annotations

import os
import re
import secrets
import shutil
import signal
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from cli_harness import SPHRENDER, run_sphrender

pytest.importorskip("ray")

RAY = str(Path(SPHRENDER).with_name("ray"))

#: Slow enough (320x200) that a run lasts a few seconds on 2 cores, so the tests can act mid-run.
SCENE = """
[image]
width = 320
height = 200
[camera]
eye = [0.0, 2.5, 5.0]
target = [0.0, 0.5, 0.0]
[particles]
radius = 0.015
"""
#: Copies of the 8 dam-break frames under new names: a 24-frame sequence.
FRAMES = 24


def _children(pid: int) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            if ppid == pid:
                found.append(int(entry.name))
    return found


def descendants(pid: int) -> dict[int, str]:
    """pid -> command line (Ray sets worker titles: ``ray::RenderActor.render`` while busy)."""
    result: dict[int, str] = {}
    stack = _children(pid)
    while stack:
        child = stack.pop()
        try:
            result[child] = (
                (Path("/proc") / str(child) / "cmdline").read_bytes().decode(errors="replace")
            )
        except OSError:
            continue
        stack += _children(child)
    return result


class RayHead:
    """`ray start --head --block` as a child process; SIGTERM stops every process it started."""

    def __init__(self) -> None:
        # Token authentication with a token of its own (not ~/.ray/auth_token): the drivers
        # get it through the environment, as a user would export it.
        self.env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
        self.env.update(RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=secrets.token_hex(32))
        # A short path: Ray's Unix sockets live under it (108-byte limit).
        self.temp_dir = Path(tempfile.mkdtemp(prefix="sphr-ray-", dir="/tmp"))
        self.log_path = self.temp_dir / "head.log"
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen(
            [
                RAY,
                "start",
                "--head",
                "--block",
                "--port=0",
                "--num-cpus=2",
                "--num-gpus=0",
                "--include-dashboard=false",
                "--disable-usage-stats",
                "--object-store-memory=200000000",
                f"--temp-dir={self.temp_dir}",
            ],
            stdout=self._log,
            stderr=subprocess.STDOUT,
            env=self.env,
        )
        deadline = time.monotonic() + 120
        while True:
            text = self.log_path.read_text(errors="replace")
            match = re.search(r"--address='[^']*:(\d+)'", text)
            if match and "will now block" in text:
                break
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise AssertionError(f"ray head did not start:\n{text}")
            time.sleep(0.2)
        self.address = f"127.0.0.1:{match.group(1)}"

    def actor_workers(self, busy: bool = False) -> list[int]:
        title = "ray::RenderActor.render" if busy else "ray::RenderActor"
        return [pid for pid, cmd in descendants(self.proc.pid).items() if cmd.startswith(title)]

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(60)
            except subprocess.TimeoutExpired:
                for pid in descendants(self.proc.pid):
                    os.kill(pid, signal.SIGKILL)
                self.proc.kill()
                self.proc.wait(10)
        self._log.close()
        shutil.rmtree(self.temp_dir, ignore_errors=True)


@pytest.fixture(scope="module")
def ray_head() -> Iterator[RayHead]:
    head = RayHead()
    try:
        yield head
    finally:
        head.stop()


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory, dambreak: Path) -> Path:
    folder = tmp_path_factory.mktemp("sequence")
    sources = sorted((dambreak / "vtk").glob("*.vtk"))
    for index in range(FRAMES):
        shutil.copyfile(sources[index % len(sources)], folder / f"weld_{index + 1}.vtk")
    (folder / "scene.toml").write_text(SCENE)
    return folder


@pytest.fixture(scope="module")
def reference(tmp_path_factory: pytest.TempPathFactory, sequence: Path) -> Path:
    out = tmp_path_factory.mktemp("local")
    result = run_sphrender(
        "submit", str(sequence), "--scene", str(sequence / "scene.toml"), "--local", "-o", str(out)
    )
    assert result.returncode == 0, result.stderr
    return out


def ray_submit(sequence: Path, out: Path, *args: str) -> list[str]:
    return [
        SPHRENDER,
        "submit",
        str(sequence),
        "--scene",
        str(sequence / "scene.toml"),
        "-o",
        str(out),
        *args,
    ]


def assert_same_outputs(out: Path, reference: Path) -> None:
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted(p.name for p in reference.iterdir())  # no partial or stray file
    different = [n for n in names if (out / n).read_bytes() != (reference / n).read_bytes()]
    assert not different, different


def written(stderr: str) -> list[str]:
    """Outputs the progress log reports as written, in order (one line per frame)."""
    return re.findall(r"-> (\S+): ok", stderr)


def test_ray_equals_local_byte_for_byte(
    ray_head: RayHead, sequence: Path, reference: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    result = subprocess.run(
        ray_submit(sequence, out, "--ray", ray_head.address, "--ray-actors", "2"),
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
        env=ray_head.env,
    )
    assert result.returncode == 0, result.stderr
    assert f"{FRAMES} rendered, 0 skipped" in result.stderr
    assert_same_outputs(out, reference)
    assert sorted(written(result.stderr)) == sorted(p.name for p in reference.iterdir())


def wait_until(condition: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


def test_actor_killed_mid_frame_every_frame_written_once(
    ray_head: RayHead, sequence: Path, reference: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    driver = subprocess.Popen(
        ray_submit(sequence, out, "--ray", ray_head.address, "--ray-actors", "2"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ray_head.env,
    )
    try:
        wait_until(lambda: out.is_dir() and any(out.glob("*.png")), 120, "a first frame")
        busy: list[int] = []

        def an_actor_renders() -> bool:
            busy[:] = ray_head.actor_workers(busy=True)
            return bool(busy)

        wait_until(an_actor_renders, 30, "an actor rendering")
        os.kill(busy[0], signal.SIGKILL)
        killed_at = len(list(out.glob("*.png")))
        _stdout, stderr = driver.communicate(timeout=180)
    finally:
        if driver.poll() is None:
            driver.kill()
    assert killed_at < FRAMES, "the run ended before the kill"
    assert driver.returncode == 0, stderr
    assert re.search(r"ray: actor \d+ lost .*replacement started", stderr), stderr
    assert f"{FRAMES} rendered, 0 skipped" in stderr
    assert sorted(written(stderr)) == sorted(p.name for p in reference.iterdir())  # each once
    assert_same_outputs(out, reference)


def test_interrupted_ray_run_resumes_with_only_the_missing_frames(
    ray_head: RayHead, sequence: Path, reference: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    first = subprocess.Popen(
        ray_submit(sequence, out, "--ray", ray_head.address),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env=ray_head.env,
    )
    try:
        wait_until(lambda: out.is_dir() and len(list(out.glob("*.png"))) >= 3, 120, "3 frames")
        first.send_signal(signal.SIGKILL)  # as a lost login session or OOM would
        first.communicate(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
    done = {p.name for p in out.glob("*.png")}
    assert 3 <= len(done) < FRAMES
    # the killed driver's actors go with it (Ray owns them through the driver)
    wait_until(lambda: not ray_head.actor_workers(), 60, "the killed driver's actors to exit")
    second = subprocess.run(
        ray_submit(sequence, out, "--ray", ray_head.address, "--resume"),
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
        env=ray_head.env,
    )
    assert second.returncode == 0, second.stderr
    assert f"{FRAMES - len(done)} rendered, {len(done)} skipped" in second.stderr
    assert sorted(written(second.stderr)) == sorted(
        p.name for p in reference.iterdir() if p.name not in done
    )
    assert_same_outputs(out, reference)


def test_actors_that_cannot_render_the_scene_fail_at_start_in_one_line(
    ray_head: RayHead, sequence: Path, tmp_path: Path
) -> None:
    """Each actor warms up on the scene; a node missing the environment file says so."""
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE + '[environment]\nfile = "missing.exr"\n')
    command = ray_submit(sequence, tmp_path / "out", "--ray", ray_head.address)
    command[command.index("--scene") + 1] = str(scene)
    result = subprocess.run(
        command, capture_output=True, text=True, timeout=120, check=False, env=ray_head.env
    )
    assert result.returncode == 2, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("sphrender: error: --ray: no render actor could start: InputError")
    assert 'environment.file: "missing.exr" not found' in last


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("--ray", "--ray-actors", "0"), "--ray-actors: must be at least 1, got 0"),
        (("--local", "--ray-actors", "2"), "--ray-actors: only applies with --ray"),
        (("--ray=127.0.0.1:1",), "--ray: no Ray cluster reachable at 127.0.0.1:1"),
        (("--ray=not an address",), "--ray: expected auto, HOST:PORT or ray://HOST:PORT"),
    ],
)
def test_bad_ray_options_get_one_line_naming_the_option(
    sequence: Path, tmp_path: Path, args: tuple[str, ...], message: str
) -> None:
    started = time.monotonic()
    result = run_sphrender(*ray_submit(sequence, tmp_path / "out", *args)[1:], timeout=60)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], result.stderr
    assert time.monotonic() - started < 30


def test_placements_one_actor_per_gpu_else_n_per_node_sharing_its_cpus() -> None:
    from sphrender.server.cluster.ray_backend import plan_placements

    nodes = [
        {"NodeID": "gpu", "Alive": True, "Resources": {"CPU": 16.0, "GPU": 4.0}},
        {"NodeID": "cpu", "Alive": True, "Resources": {"CPU": 2.0}},
        {"NodeID": "gone", "Alive": False, "Resources": {"CPU": 64.0}},
        {"NodeID": "head", "Alive": True, "Resources": {"CPU": 0.0}},
    ]
    placements = plan_placements(nodes, actors_per_node=3)
    assert [(p.node_id, p.num_gpus, p.num_cpus) for p in placements] == [
        *[("gpu", 1, 1.0)] * 4,
        *[("cpu", 0, 0.6666)] * 3,
    ]
