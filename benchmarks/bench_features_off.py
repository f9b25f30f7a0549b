"""Frame time of scenes that use none of the optional features (shadows, heat tint, molten,
solids, finish, glare, motion blur), in whatever checkout runs it: run it under two checkouts'
venvs alternately and compare (benchmarks/STUDIES.md, "Features off").

    .venv/bin/python benchmarks/bench_features_off.py 10   # frames per case after 3 warm-ups
"""

import json
import sys
import time

import numpy as np

from sphrender.core.frame import make_frame
from sphrender.server.content.demo import weld_bead_positions, weld_temperatures
from sphrender.server.engine.gpu.gl_context import GLContext
from sphrender.server.engine.renderer import SurfaceRenderer
from sphrender.server.scene import scene_from_dict

rng = np.random.default_rng(3)
ball = rng.normal(size=(100_000, 3))
ball /= np.linalg.norm(ball, axis=1, keepdims=True)
ball *= rng.uniform(0, 1, (100_000, 1)) ** (1 / 3) * 0.5
weld = weld_bead_positions()
cases = {
    "ball100k_1280x720": (
        make_frame(ball),
        {
            "image": {"width": 1280, "height": 720},
            "camera": {"eye": [0, 0.4, 1.6]},
            "particles": {"radius": 0.006},
        },
    ),
    "weld_temps_960x540": (
        make_frame(weld, temperatures=weld_temperatures(weld)),
        {
            "image": {"width": 960, "height": 540},
            "camera": {"eye": [-30, 26, 48], "target": [3, 0, 0], "near": 1.0},
            "particles": {"radius": 0.4},
            "material": {"preset": "stainless_steel", "roughness": 0.45},
            "output": {"exposure": 1.5, "tone_mapper": "aces"},
        },
    ),
}
out = {}
with GLContext() as gl:
    r = SurfaceRenderer(gl)
    for name, (frame, sd) in cases.items():
        scene = scene_from_dict(sd)
        for _ in range(3):
            r.render(frame, scene)
        times = []
        for _ in range(int(sys.argv[1])):
            t = time.perf_counter()
            r.render(frame, scene)
            times.append((time.perf_counter() - t) * 1e3)
        out[name] = (float(np.min(times)), float(np.median(times)))
    r.release()
print(json.dumps(out))
