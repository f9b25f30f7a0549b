"""The "Wire" section of REPORT.md: the compact encoding's measurements (wire.py, wire_link.py)
as tables, with the issue's targets and whether they are met."""

from __future__ import annotations

import os
from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from benchmarks.studies.wire import (
    DAM_RADIUS,
    FRACTIONS,
    SPATTER_RADIUS,
    CodecRow,
    ServiceDecode,
    _best_ms,
    codec_rows,
    dam_sequence,
    image_change,
    peer_rows,
    service_decode,
    spatter_sequence,
    truth_change,
)
from sphrender.core.compact_encoder import CompactEncoder

if TYPE_CHECKING:
    from benchmarks.studies.wire_link import LinkRow

HEADING = "## Wire: the compact frame encoding"
#: Before this heading when the report has no Wire section yet.
_BEFORE = "## Scaling"
DAM_CAMERA = {"eye": [0.0, 2.5, 5.0], "target": [0.0, 0.5, 0.0], "fov_y": 45.0}
SPATTER_CAMERA = {"eye": [0.5, 0.6, 1.2], "target": [0.0, 0.1, 0.0], "fov_y": 40.0}
MBIT = 1e6


def _r(fraction: float) -> str:
    return f"r/{round(1 / fraction)}" if fraction else "lossless f32"


def wire_section(*, quick: bool, link: bool, log: Callable[[str], None]) -> list[str]:
    dam = dam_sequence(3)
    if dam is None:
        log("wire: skipped (../shared/data not found)")
        return []
    repeats = 1 if quick else 3
    lines = [HEADING, "", _INTRO.format(cpus=os.cpu_count()), ""]
    log("wire: codec at 100k")
    rows = list(codec_rows("dam break", dam, DAM_RADIUS, FRACTIONS, repeats))
    rows += codec_rows("dam break, in order", dam, DAM_RADIUS, (0.01,), repeats, reorder=False)
    spatter = spatter_sequence(100_000)
    rows += codec_rows("spatter", spatter, SPATTER_RADIUS, FRACTIONS, repeats)
    if not quick:
        log("wire: codec at 1M")
        big = dam_sequence(31)
        assert big is not None
        rows += codec_rows("dam break", big[:4], DAM_RADIUS, (0.01,), 1)
        rows += codec_rows("dam break, in order", big[:4], DAM_RADIUS, (0.01,), 1, reorder=False)
        del big
        rows += codec_rows("spatter", spatter_sequence(1_000_000, 4), SPATTER_RADIUS, (0.01,), 1)
    lines += _codec_table(rows)
    log("wire: decode as the service runs it")
    service = [service_decode(3, len(dam), 0.01)]
    if not quick:
        service.append(service_decode(31, 4, 0.01))
    lines += _service_table(service)
    log("wire: peers")
    lines += _peer_table(dam[4]["positions"], rows)
    log("wire: image change")
    image_lines, normals_verdict = _image_table(dam, spatter)
    lines += image_lines
    if link:
        log("wire: rate-limited link")
        lines += _link_table(dam)
    lines += ["", *_verdicts(rows, service), *normals_verdict, ""]
    return lines


_INTRO = (
    "`benchmarks/bench_wire.py` (studies/wire.py, wire_link.py), on this machine's {cpus} CPU "
    "cores, shared (timings: the best of 3 repeats, median over a sequence's frames). Positions "
    "within the bound b (max |decoded - sent| <= b, measured below in radii), densities within "
    "0.05 kg/m³, temperatures within 0.05 K (the client's defaults). Positions go out order-free "
    "(`predict: cells`) or, where smaller, predicted from the frame before; the first frame "
    "stands alone. "
    "Dam break: the real frames (0.2 s apart), copies side by side, each a different frame "
    "turned by 1-4° (no copy repeats another's numbers); temperatures synthetic. Spatter: a "
    "pool with a slow wave and 5 % droplets in flight, 30 frames a second. A 1M dam-break frame "
    "holds every frame of the data set about 4 times, the early ones (still in the initial "
    "lattice's order, cheap) included; a 100k frame holds three neighbouring frames. Rows "
    '"in order": the encoder told to keep the particles\' order (`reorder=False`: every frame '
    "predicted particle to particle or from the frame before, as before order-free positions)."
)


def _codec_table(rows: list[CodecRow]) -> list[str]:
    lines = [
        "| sequence | particles | bound | positions B/particle | frame B/particle | first "
        "frame B/particle | encode ms | decode ms | decode ms per 100k | decode CPU ms per 100k "
        "| max error (r) |",
        "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        per = row.decode_ms * 100_000 / row.particles
        per_cpu = row.decode_cpu_ms * 100_000 / row.particles
        lines.append(
            f"| {row.sequence} | {row.particles:,} | {_r(row.fraction)} | "
            f"{row.positions_bpp:.2f} | {row.frame_bpp:.2f} | {row.first_bpp:.2f} | "
            f"{row.encode_ms:.1f} | {row.decode_ms:.1f} | {per:.1f} | {per_cpu:.1f} | "
            f"{row.max_error_r:.4f} |"
        )
    return [*lines, ""]


def _service_table(rows: list[ServiceDecode]) -> list[str]:
    lines = [
        "The same decodes in a process set up as the service (server/service/heap.py: every "
        "block from 128 KiB in a mapping of its own, so that resident memory stays flat): what "
        "a decode returns (the arrays, and the integers kept for the next frame) faults its "
        "pages in, ~2.4 us each on this VM; its temporaries come from a pool "
        "(core/scratch.py). Dam break, r/100, in a session:",
        "",
        "| particles | decode CPU ms per 100k | page faults a frame |",
        "|---:|---:|---:|",
    ]
    for row in rows:
        per = row.cpu_ms * 100_000 / row.particles
        lines.append(f"| {row.particles:,} | {per:.1f} | {row.faults:,} |")
    return [*lines, ""]


def _peer_table(positions: object, rows: list[CodecRow]) -> list[str]:
    pos = np.asarray(positions)
    peers = peer_rows(pos, DAM_RADIUS, FRACTIONS)
    lines = [
        f"Peers on the positions of one dam-break frame ({len(pos):,} particles, frame 9 and its "
        "neighbours), beside this encoding's (one frame alone, and in a session):",
        "",
        "| coder | bound | positions B/particle | max error (r) | encode ms | decode ms |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for fraction in FRACTIONS:
        ms, (_header, payload) = _best_ms(partial(_alone, fraction * DAM_RADIUS, pos))
        alone = len(payload) / len(pos)
        lines.append(f"| compact, this frame alone | {_r(fraction)} | {alone:.2f} | ≤ {fraction:g} "
                     f"| {ms:.1f} | |")  # fmt: skip
        ours = next(r for r in rows if r.fraction == fraction and r.particles == len(pos))
        lines.append(
            f"| compact, in a session | {_r(fraction)} | {ours.positions_bpp:.2f} | "
            f"{ours.max_error_r:.4f} | {ours.encode_ms:.1f} | {ours.decode_ms:.1f} |"
        )
    for peer in sorted(peers, key=lambda p: (p.fraction, p.peer)):
        lines.append(
            f"| {peer.peer} | {_r(peer.fraction)} | {peer.positions_bpp:.2f} | "
            f"{peer.max_error_r:.4f} | {peer.encode_ms:.1f} | {peer.decode_ms:.1f} |"
        )
    return [*lines, ""]


def _alone(error: float, positions: np.ndarray) -> tuple[dict, bytes]:
    """One frame with a fresh encoder (nothing to predict it from)."""
    return CompactEncoder(position_error=error).encode(0, {"positions": positions})


def _image_table(dam: list[dict], spatter: list[dict]) -> tuple[list[str], list[str]]:
    """The table, and the verdict on the normals' line (dam break at r/100)."""
    lines = [
        "Image change against float32 input (the float64 positions rounded to float32, as "
        "today's float32 path sends them), preset balanced, 256x160: normal change over the "
        "pixels both cover, and coverage (alpha) change; beside it, the dam break's reference "
        "surface's own normal change (splashsurf's reconstruction of the decoded positions "
        "against the float32 input's, rasterised with the same camera; studies/wire_normals.py):",
        "",
        "| sequence | bound | normal change mean° | p99° | alpha change mean | pixels with "
        "alpha change > 1/255 | reference surface's own change mean° |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    one = [{k: v[: len(v) // 3] for k, v in f.items()} for f in dam]
    truth = truth_change(one[len(one) // 2], DAM_RADIUS, DAM_CAMERA, FRACTIONS)
    own = {fraction: f"{mean:.3f}" for fraction, (mean, _p99) in zip(FRACTIONS, truth, strict=True)}
    verdict = []
    for name, frames, radius, camera in (
        ("dam break (one copy)", one, DAM_RADIUS, DAM_CAMERA),
        ("spatter", spatter, SPATTER_RADIUS, SPATTER_CAMERA),
    ):
        for fraction, mean, p99, alpha, changed in image_change(frames, radius, camera, FRACTIONS):
            reference = own[fraction] if frames is one else ""
            lines.append(
                f"| {name} | {_r(fraction)} | {mean:.3f} | {p99:.2f} | {alpha:.5f} | "
                f"{100 * changed:.2f} % | {reference} |"
            )
            if frames is one and fraction == 0.01:
                verdict.append(
                    f"* rendered normals change <= 0.1° mean against float32 input (dam break, "
                    f"r/100): {'met' if mean <= 0.1 else 'not met'} ({mean:.3f}°; the "
                    f"reference surface itself changes {own[fraction]}° at r/100)"
                )
    return [*lines, ""], verdict


def _link_table(dam: list[dict]) -> list[str]:
    from benchmarks.studies.wire_link import run_link

    base = {"image": {"width": 64, "height": 40}, "particles": {"radius": DAM_RADIUS}}
    scenes = {
        "dam break, 64x40": {**base, "camera": DAM_CAMERA},
        "camera turned away": {**base, "camera": {**DAM_CAMERA, "target": [0.0, 2.5, 10.0]}},
    }
    links = {"100 Mbit/s": 100 * MBIT, "1 Gbit/s": 1000 * MBIT}
    rows = list(run_link(dam, scenes, links))
    lines = [
        f"End to end over a token-bucket relay on loopback ({len(dam[0]['positions']):,} "
        f"particles with densities and temperatures, {len(dam)} frames pipelined, queue mode):",
        "",
        "| scene | link | encoding | bytes a frame | link alone, frames/s | render ms a frame | "
        "render alone, frames/s | frames/s | × float64 raw |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows:
        ceiling = links[row.link] / 8 / row.bytes_per_frame
        base_fps = next(
            r.fps for r in rows
            if (r.scene, r.link, r.encoding) == (row.scene, row.link, "float64 raw")
        )  # fmt: skip
        lines.append(
            f"| {row.scene} | {row.link} | {row.encoding} | {row.bytes_per_frame:,.0f} | "
            f"{ceiling:.1f} | {row.server_ms:.1f} | {1000 / row.server_ms:.1f} | {row.fps:.2f} | "
            f"{row.fps / base_fps:.2f} |"
        )
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    lines += [
        "",
        f'"link alone": the link\'s rate over the frame\'s bytes; "render ms a frame": the '
        "median of the answers' stage timings in the render process, summed (the renderer's "
        "stages and the image encoding; in the same run, so they include what the client's "
        'encoding takes from the shared cores): "render alone", its inverse, is a ceiling no '
        "encoding on the wire can lift. Load average after the runs: "
        f"{load} on {os.cpu_count()} cores: the client's encoding, the server's decoding and the "
        "render compete for them, so where frames/s stays below the link's figure the CPU, "
        "not the link, is the limit.",
        "",
        _fps_verdict(rows),
    ]
    return [*lines, ""]


def _fps_verdict(rows: list[LinkRow]) -> str:
    """The 100 Mbit/s line for the dam break: the best compact ratio, and where the render
    alone leaves any encoding (its ceiling over float64 raw's frames/s)."""
    dam = {r.encoding: r for r in rows if r.scene == "dam break, 64x40" and r.link == "100 Mbit/s"}
    raw = dam["float64 raw"].fps
    best = max((r for name, r in dam.items() if "compact" in name), key=lambda r: r.fps)
    ceiling = max(1000 / r.server_ms for name, r in dam.items() if "compact" in name) / raw
    return (
        f"* >= 5x float64 raw's frames/s at 100 Mbit/s (dam break): "
        f"{'met' if best.fps >= 5 * raw else 'not met'} ({best.fps / raw:.2f}x, {best.encoding}; "
        f"the render alone allows {ceiling:.2f}x on this machine)"
    )


def _verdicts(rows: list[CodecRow], service: list[ServiceDecode]) -> list[str]:
    dam = [r for r in rows if r.sequence == "dam break" and r.fraction == 0.01]
    per100k = max(r.decode_ms * 100_000 / r.particles for r in dam)
    cpu100k = max(r.decode_cpu_ms * 100_000 / r.particles for r in dam)
    in_service = max(r.cpu_ms * 100_000 / r.particles for r in service)
    return [
        f"* positions <= 3 B/particle at r/100 on dam-break frames in a session: "
        f"{'met' if all(r.positions_bpp <= 3 for r in dam) else 'not met'} "
        f"({', '.join(f'{r.positions_bpp:.2f}' for r in dam)})",
        f"* whole frame <= 5 B/particle: "
        f"{'met' if all(r.frame_bpp <= 5 for r in dam) else 'not met'} "
        f"({', '.join(f'{r.frame_bpp:.2f}' for r in dam)})",
        f"* decode <= 2 ms per 100k particles: "
        f"{'met' if max(cpu100k, in_service) <= 2 else 'not met'} (worst {in_service:.1f} ms "
        f"of CPU time as the service decodes; {cpu100k:.1f} ms of CPU time, {per100k:.1f} ms "
        f"of wall time in this process)",
    ]


def splice_section(report: str, lines: list[str]) -> str:
    """`report` with its Wire section replaced by `lines` (or inserted before Scaling)."""
    text = "\n".join(lines).rstrip("\n") + "\n\n"
    if HEADING in report:
        head, rest = report.split(HEADING, 1)
        tail = rest.split("\n## ", 1)
        return head + text + ("## " + tail[1] if len(tail) == 2 else "")
    if _BEFORE in report:
        head, rest = report.split(_BEFORE, 1)
        return head + text + _BEFORE + rest
    return report.rstrip("\n") + "\n\n" + text
