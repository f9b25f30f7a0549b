"""Rendering beyond one machine: `ray_backend.py` spreads a sequence over a Ray cluster
(`sphrender submit --ray`). Imported only when asked for, so Ray stays an optional extra."""
