"""Large temporaries reused between frames (core/scratch.py) and the compact decoder's use of
them: what a decode returns never shares memory with the pool, and under the service's malloc
settings a decode faults in little more than the pages of what it returns."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from sphrender.core.compact import CompactDecoder
from sphrender.core.compact_encoder import CompactEncoder
from sphrender.core.scratch import MIN_POOLED_BYTES, ScratchPool


def test_a_lease_returns_its_buffers_and_the_next_lease_reuses_them() -> None:
    pool = ScratchPool(max_bytes=8 << 20)
    with pool.lease() as lease:
        first = lease.array((1000, 100), np.float64)
        first[...] = 1.0
        small = lease.array(10, np.int32)  # below the pooled size: plain numpy
    assert pool.pooled_bytes == first.nbytes and small.base is None
    with pool.lease() as lease:
        again = lease.array(50_000, np.int64)  # fits the buffer returned above
        assert np.shares_memory(again, first) and again.dtype == np.int64
        assert pool.pooled_bytes == 0
        other = lease.array(MIN_POOLED_BYTES, np.uint8)  # none free: a new buffer
        assert not np.shares_memory(other, first)
    assert pool.pooled_bytes == first.nbytes + other.nbytes


def test_the_pool_keeps_at_most_its_bytes_dropping_the_largest() -> None:
    pool = ScratchPool(max_bytes=3 << 20)
    with pool.lease() as lease:
        for size in (1 << 20, 2 << 20, 3 << 20):
            lease.array(size, np.uint8)
    assert pool.pooled_bytes == 3 << 20  # 1 + 2 MiB kept, the 3 MiB one dropped


def _frames(n: int) -> list[dict[str, np.ndarray]]:
    rng = np.random.default_rng(7)
    positions = rng.uniform(0.0, 1.0, (n, 3))
    frames: list[dict[str, np.ndarray]] = []
    for step in range(3):
        positions = positions + rng.normal(0.0, 1e-3, (n, 3))
        densities = (1000 + rng.normal(0, 5, n)).astype(np.float32)
        kelvin = (1500 + 100 * positions[:, 1] + step).astype(np.float32)
        frames.append({"positions": positions, "densities": densities, "temperatures": kelvin})
    return frames


def test_what_a_decode_returns_outlives_the_next_decodes() -> None:
    """Frames decoded one after another (the later ones predicted from the held one): each
    result is unchanged after the decodes that reuse the pool's buffers, and equals a decode by
    a fresh decoder of the same messages."""
    encoder = CompactEncoder(position_error=1e-4)
    messages = [encoder.encode(i, frame) for i, frame in enumerate(_frames(40_000))]
    decoder = CompactDecoder()
    results = [decoder.decode(h, p, max_particles=10**6) for h, p in messages]
    copies = [{k: v.copy() for k, v in r.items()} for r in results]
    stir = CompactDecoder()
    for header, payload in messages * 2:  # reuse the pool's buffers
        stir.decode(header, payload, max_particles=10**6)
    for result, kept in zip(results, copies, strict=True):
        assert all(np.array_equal(result[k], kept[k]) for k in kept)
    again = CompactDecoder()
    for (header, payload), kept in zip(messages, copies, strict=True):
        fresh = again.decode(header, payload, max_particles=10**6)
        assert all(np.array_equal(fresh[k], kept[k]) for k in kept)


def test_sessions_decoding_in_turn_keep_their_own_base() -> None:
    """Two sessions' frames predicted from their own previous frames, decoded alternately (the
    pool serving both, each holding its base's buffers between frames), give what each session
    decoded alone gives."""
    sessions = []
    for seed in (1, 2):
        frames = _frames(30_000)
        for frame in frames:
            frame["positions"] = frame["positions"] + seed
        encoder = CompactEncoder(position_error=1e-4)
        sessions.append([encoder.encode(i, frame) for i, frame in enumerate(frames)])
    predicted = [spec["predict"] for h, _ in sessions[0][1:] for spec in h["arrays"]]
    assert "frame" in predicted or "motion" in predicted  # the case the held buffers serve
    alone = []
    for messages in sessions:
        decoder = CompactDecoder()
        alone.append([decoder.decode(h, p, max_particles=10**6) for h, p in messages])
    decoders = [CompactDecoder(), CompactDecoder()]
    for i in range(len(sessions[0])):
        for s, (decoder, messages) in enumerate(zip(decoders, sessions, strict=True)):
            header, payload = messages[i]
            arrays = decoder.decode(header, payload, max_particles=10**6)
            assert all(np.array_equal(arrays[k], alone[s][i][k]) for k in arrays)


#: A session's decodes of one 100k-particle frame in a process with the service's malloc
#: settings; the minor page faults per decode after the first three (which fill the pool).
FAULTS = """
import json, resource, sys
import numpy as np
from sphrender.server.service.heap import configure_malloc
assert configure_malloc()
sys.path.insert(0, sys.argv[1])
from test_scratch import _frames
from sphrender.core.compact import CompactDecoder
from sphrender.core.compact_encoder import CompactEncoder
header, payload = CompactEncoder(position_error=1e-4).encode(0, _frames(100_000)[0])
decoder = CompactDecoder()  # a session's: it holds the last frame's integers
for _ in range(3):
    decoder.decode(header, payload, max_particles=10**6)
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(10):
    arrays = decoder.decode(header, payload, max_particles=10**6)
    del arrays
faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 10
print(json.dumps({"faults": faults}))
"""


def test_a_decode_in_the_service_faults_in_about_what_it_returns() -> None:
    """The service maps every block from 128 KiB on its own (server/service/heap.py), so each
    fresh array faults its pages in. This 100k-particle frame returns positions (float64, 24
    B/particle), densities and temperatures (float32, 4 + 4): 32 B a particle, 782 pages. The
    integers it keeps for the next frame (20 B a particle) and its temporaries (the inflated
    sections, byte planes, cell numbers, residuals, running sums and float64 products: about
    as much again) come from the pool, the kept ones given back when the next frame has
    replaced them; allocated afresh they took some 2,000 faults more (488 for the kept ones
    alone). Bound: the returned pages plus 10 %."""
    done = subprocess.run(
        [sys.executable, "-c", FAULTS, str(Path(__file__).parent)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    faults = json.loads(done.stdout)["faults"]
    assert faults < 1.10 * 32 * 100_000 / 4096, faults
