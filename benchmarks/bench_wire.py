"""The compact frame encoding's bench: bytes a particle, encode and decode time, image change,
peers at the same error bound and end-to-end frames per second over a rate-limited link
(benchmarks/studies/wire.py, wire_link.py). Prints the section and writes it into REPORT.md
(replacing its "Wire" section; benchmarks/bench_report.py includes the same section).

    .venv/bin/python benchmarks/bench_wire.py [--quick] [--no-link] [--no-write]

Needs ../shared/data (the dam break) and the `bench` extra (blosc2, DracoPy, zfpy, scipy).
About 3-4 minutes on 2 CPU cores.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import repo_path  # noqa: F401

from benchmarks.studies.wire_report import splice_section, wire_section

REPORT = Path(__file__).resolve().parent / "REPORT.md"


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="100k only, one repeat")
    parser.add_argument("--no-link", action="store_true", help="skip the rate-limited link")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args()
    lines = wire_section(quick=args.quick, link=not args.no_link, log=print)
    print("\n".join(lines))
    if not args.no_write:
        REPORT.write_text(splice_section(REPORT.read_text(), lines))
        print(f"written into {REPORT}")


if __name__ == "__main__":
    main()
