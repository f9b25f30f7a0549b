"""`sphrender bench`: speed against error on reference scenes, peers side by side.

`scenes` builds the reference scenes and their ground truth (analytic surfaces, or a pysplashsurf
mesh rendered with the same camera), `metrics` compares a render against that truth, `sweep`
times quality settings on the engine, `peers` runs the tools a user would otherwise pick on the
same particles, camera and resolution, and `report` writes the table, the Markdown report and the
Pareto plot. Nothing here runs in CI except `sphrender bench --quick` (one smoke test).
"""
