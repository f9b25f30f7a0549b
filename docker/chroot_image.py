"""Run a Dockerfile's steps in a chroot, for checking an image on a machine without a Docker engine.

`docker/check-images.sh` builds a minimal Debian root (mmdebstrap) and mounts /proc, /sys and
/dev in it; this module does what ``docker build`` and ``docker run`` would do inside that root,
for the small part of the Dockerfile language the images here use:

* ``FROM debian:SUITE`` / ``debian:SUITE-slim``: only tells which suite the root must be
  (``suite`` prints it); the root itself comes from the caller.
* ``RUN`` (shell form): ``/bin/sh -c`` in the root, as the current ``USER``, in the current
  ``WORKDIR``, with Docker's default PATH, HOME and the ``ENV`` values.
* ``ENV``, ``WORKDIR``, ``USER``, ``COPY`` (from the build context, owned by root as Docker
  does), with ``$VAR`` / ``${VAR}`` expansion; ``EXPOSE``, ``CMD``, ``ENTRYPOINT`` and
  ``LABEL`` are skipped (they do not change the file system).

Anything else is an error, so a Dockerfile that outgrows this fails the check instead of being
half-run. Standard library only; run as root::

    python3 docker/chroot_image.py suite docker/cpu.Dockerfile
    python3 docker/chroot_image.py build docker/cpu.Dockerfile ROOT --context . --env K=V
    python3 docker/chroot_image.py exec docker/cpu.Dockerfile ROOT -- 'sphrender info'
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

#: Docker's PATH when the image sets none.
DEFAULT_PATH = "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin"
IGNORED = {"EXPOSE", "CMD", "ENTRYPOINT", "LABEL"}


class DockerfileError(ValueError):
    """A Dockerfile instruction this runner does not support (or a malformed one)."""


@dataclass(frozen=True)
class Instruction:
    keyword: str
    argument: str
    line: int


def parse(text: str) -> list[Instruction]:
    """Instructions with continuation lines joined and comment lines dropped, as Docker does."""
    instructions: list[Instruction] = []
    pending: list[str] = []
    start = 0
    for number, raw in enumerate(text.splitlines(), 1):
        stripped = raw.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if not pending:
            start = number
        if stripped.endswith("\\"):
            pending.append(stripped[:-1].strip())
            continue
        pending.append(stripped)
        keyword, _, argument = " ".join(pending).partition(" ")
        instructions.append(Instruction(keyword.upper(), argument.strip(), start))
        pending = []
    if pending:
        raise DockerfileError(f"line {start}: continuation runs past the end of the file")
    return instructions


def expand(value: str, env: dict[str, str]) -> str:
    """Docker's ``$VAR`` and ``${VAR}`` substitution (unset = empty)."""
    return re.sub(r"\$(?:\{(\w+)\}|(\w+))", lambda m: env.get(m.group(1) or m.group(2), ""), value)


def suite(instructions: list[Instruction]) -> str:
    """The Debian suite named by the FROM line: ``debian:bookworm-slim`` -> ``bookworm``."""
    froms = [i for i in instructions if i.keyword == "FROM"]
    if len(froms) != 1:
        raise DockerfileError("exactly one FROM is supported")
    image = r"(?:docker\.io/)?(?:library/)?debian:([a-z]+)(?:-slim)?"
    match = re.fullmatch(image, froms[0].argument)
    if match is None:
        raise DockerfileError(
            f"line {froms[0].line}: FROM {froms[0].argument}: only debian:SUITE[-slim] images "
            "can be rebuilt with mmdebstrap"
        )
    return match.group(1)


@dataclass
class Image:
    """The state a Dockerfile builds up: environment, working directory and user."""

    root: Path
    env: dict[str, str] = field(default_factory=lambda: {"PATH": DEFAULT_PATH})
    workdir: str = "/"
    user: str = "root"

    def passwd(self) -> tuple[int, int, str]:
        """(uid, gid, home) of `user`, from the root's /etc/passwd."""
        name = self.user.split(":")[0]
        for line in (self.root / "etc/passwd").read_text().splitlines():
            fields = line.split(":")
            if fields[0] == name or fields[2] == name:
                return int(fields[2]), int(fields[3]), fields[5]
        raise DockerfileError(f"USER {self.user}: no such user in the image")

    def run(self, command: str, extra_env: dict[str, str] | None = None) -> int:
        """``/bin/sh -c command`` in the root, as ``docker run`` / ``RUN`` would."""
        uid, gid, home = self.passwd()
        env = {"HOME": home, **self.env, **(extra_env or {})}
        args = ["chroot", f"--userspec={uid}:{gid}", str(self.root), "/usr/bin/env", "-i"]
        args += [f"{key}={value}" for key, value in env.items()]
        args += ["/bin/sh", "-c", f"cd {shlex.quote(self.workdir)} && {command}"]
        return subprocess.run(args, check=False).returncode

    def copy(self, sources: list[str], destination: str, context: Path) -> None:
        """COPY from the build context: a folder's contents, or files, owned by root."""
        target = Path(self.root, self.workdir.lstrip("/"), destination)
        if destination.startswith("/"):
            target = Path(self.root, destination.lstrip("/"))
        into_folder = destination.endswith("/") or len(sources) > 1
        for source in sources:
            origin = (context / source).resolve()
            if context.resolve() not in (origin, *origin.parents):
                raise DockerfileError(f"COPY {source}: outside the build context")
            if origin.is_dir():
                shutil.copytree(origin, target, symlinks=True, dirs_exist_ok=True)
                _chown_root(target)
            else:
                path = target / origin.name if into_folder else target
                path.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(origin, path)
                os.chown(path, 0, 0)


def _chown_root(folder: Path) -> None:
    os.chown(folder, 0, 0, follow_symlinks=False)
    for parent, dirs, files in os.walk(folder):
        for name in dirs + files:
            os.chown(Path(parent, name), 0, 0, follow_symlinks=False)


def _env_pairs(argument: str) -> list[tuple[str, str]]:
    words = shlex.split(argument)
    if words and "=" not in words[0]:  # legacy form: ENV KEY value with spaces
        return [(words[0], " ".join(words[1:]))]
    pairs = []
    for word in words:
        key, sep, value = word.partition("=")
        if not sep:
            raise DockerfileError(f"ENV {argument}: expected KEY=VALUE")
        pairs.append((key, value))
    return pairs


def build(
    instructions: list[Instruction],
    root: Path,
    context: Path,
    extra_env: dict[str, str] | None = None,
    execute: bool = True,
) -> Image:
    """Apply every instruction to `root` (with ``execute=False`` only track the final state)."""
    suite(instructions)
    image = Image(root)
    for step in instructions:
        keyword, argument = step.keyword, step.argument
        if keyword in ("FROM", *IGNORED):
            continue
        if keyword == "ENV":
            for key, value in _env_pairs(argument):
                image.env[key] = expand(value, image.env)
        elif keyword == "WORKDIR":
            workdir = expand(argument, image.env)
            image.workdir = str(Path(image.workdir, workdir))
            if execute:
                Path(root, image.workdir.lstrip("/")).mkdir(parents=True, exist_ok=True)
        elif keyword == "USER":
            image.user = expand(argument, image.env)
        elif keyword == "COPY":
            words = [expand(word, image.env) for word in shlex.split(argument)]
            if len(words) < 2 or words[0].startswith("--") or argument.startswith("["):
                raise DockerfileError(f"line {step.line}: COPY {argument}: unsupported form")
            if execute:
                image.copy(words[:-1], words[-1], context)
        elif keyword == "RUN":
            if argument.startswith("["):
                raise DockerfileError(f"line {step.line}: RUN in exec form is not supported")
            if execute:
                print(f"chroot_image: line {step.line}: RUN {argument[:100]}", flush=True)
                if (status := image.run(argument, extra_env)) != 0:
                    raise SystemExit(f"chroot_image: line {step.line}: RUN exited {status}")
        else:
            raise DockerfileError(f"line {step.line}: {keyword} is not supported")
    return image


def _key_values(pairs: list[str]) -> dict[str, str]:
    values = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise SystemExit(f"chroot_image: --env {pair}: expected KEY=VALUE")
        values[key] = value
    return values


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    suite_parser = commands.add_parser("suite", help="print the Debian suite of FROM")
    suite_parser.add_argument("dockerfile", type=Path)
    build_parser = commands.add_parser("build", help="run the Dockerfile's steps in ROOT")
    build_parser.add_argument("dockerfile", type=Path)
    build_parser.add_argument("root", type=Path)
    build_parser.add_argument("--context", type=Path, default=Path("."))
    build_parser.add_argument(
        "--env", action="append", default=[], help="KEY=VALUE for RUN only (build network)"
    )
    exec_parser = commands.add_parser("exec", help="run a command as the image would")
    exec_parser.add_argument("dockerfile", type=Path)
    exec_parser.add_argument("root", type=Path)
    exec_parser.add_argument("shell_command", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    try:
        instructions = parse(args.dockerfile.read_text())
        if args.command == "suite":
            print(suite(instructions))
            return 0
        if args.command == "build":
            build(instructions, args.root, args.context, _key_values(args.env))
            return 0
        image = build(instructions, args.root, Path("."), execute=False)
        words = args.shell_command[1:] if args.shell_command[:1] == ["--"] else args.shell_command
        return image.run(" ".join(words) or "true")
    except DockerfileError as exc:
        print(f"chroot_image: {args.dockerfile}: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
