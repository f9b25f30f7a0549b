#!/usr/bin/env python3
"""Write an HAProxy configuration for N `sphrender serve` replicas from haproxy.cfg.template.

    python3 deploy/haproxy/render_config.py \\
        --replica r1=10.0.0.11:8080:8081 --replica r2=10.0.0.12:8080:8081 \\
        --http-bind :8080 --stream-bind :8081 > /etc/haproxy/haproxy.cfg

Each ``--replica NAME=HOST:HTTP_PORT:STREAM_PORT`` is one server in both backends (the stream
backend checks health on the replica's HTTP port). Standard library only.
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

TEMPLATE = Path(__file__).with_name("haproxy.cfg.template")
_BLOCK = re.compile(r"^[ \t]*# >>> per replica\n(.*?)^[ \t]*# <<< per replica\n", re.M | re.S)


@dataclass(frozen=True)
class Replica:
    name: str
    host: str
    http_port: int
    stream_port: int


def parse_replica(text: str) -> Replica:
    match = re.fullmatch(r"([A-Za-z0-9_.-]+)=([^\s:]+|\[[0-9a-fA-F:]+\]):(\d+):(\d+)", text)
    if not match:
        raise ValueError(f"expected NAME=HOST:HTTP_PORT:STREAM_PORT, got {text!r}")
    name, host, http_port, stream_port = match.groups()
    return Replica(name, host, int(http_port), int(stream_port))


def render(
    replicas: Sequence[Replica],
    *,
    http_bind: str,
    stream_bind: str,
    check_interval_ms: int = 500,
    fall: int = 2,
    rise: int = 2,
    global_extra: Sequence[str] = (),
    template: str | None = None,
) -> str:
    """The configuration text; `global_extra` lines go into the ``global`` section (e.g. a
    ``stats socket``)."""
    if not replicas:
        raise ValueError("at least one replica is needed")
    text = TEMPLATE.read_text() if template is None else template

    def expand(block: re.Match[str]) -> str:
        return "".join(
            block.group(1).format(
                name=r.name, host=r.host, http_port=r.http_port, stream_port=r.stream_port
            )
            for r in replicas
        )

    text = _BLOCK.sub(expand, text)
    return text.format(
        http_bind=http_bind,
        stream_bind=stream_bind,
        check_interval_ms=check_interval_ms,
        fall=fall,
        rise=rise,
        global_extra="\n".join(f"    {line}" for line in global_extra),
    )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--replica",
        action="append",
        required=True,
        metavar="NAME=HOST:HTTP_PORT:STREAM_PORT",
        help="one replica (repeat for each)",
    )
    parser.add_argument("--http-bind", default=":8080", help="HAProxy's HTTP address")
    parser.add_argument("--stream-bind", default=":8081", help="HAProxy's stream address")
    parser.add_argument("--check-interval-ms", type=int, default=500)
    parser.add_argument("--fall", type=int, default=2, help="failed checks before DOWN")
    parser.add_argument("--rise", type=int, default=2, help="passed checks before UP")
    args = parser.parse_args(argv)
    try:
        replicas = [parse_replica(text) for text in args.replica]
    except ValueError as exc:
        parser.error(f"--replica: {exc}")
    sys.stdout.write(
        render(
            replicas,
            http_bind=args.http_bind,
            stream_bind=args.stream_bind,
            check_interval_ms=args.check_interval_ms,
            fall=args.fall,
            rise=args.rise,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
