"""Mutation check: plant small, plausible bugs one at a time and see whether the tests that
claim to guard against them fail. Not part of CI (it runs selected tests once per mutation).

    .venv/bin/python tools/mutation_check.py            # every mutation, then the score
    .venv/bin/python tools/mutation_check.py --list     # the table, nothing run
    .venv/bin/python tools/mutation_check.py -k resume  # mutations whose name contains "resume"

Every planted bug is one row of `MUTATIONS`: the file (relative to the repository root), the
exact text to replace (it must occur exactly once, or the script stops before running anything:
a stale path or text is an error, never a silently "caught" mutation), its replacement, the
tests expected to catch it (pytest node ids) and what the bug is.

Safety: the working tree is never modified. The script copies the tree (tracked files plus
untracked files that git does not ignore, i.e. what `git status` shows) into a temporary
directory, builds the import layout `sphrender/{core,server,client,shaders,configs}` there as
symlinks into the copy, and runs pytest from the copy with that layout first on PYTHONPATH.
The package is installed editable from the working tree, but setuptools' editable finder sits
after the normal path finder on `sys.meta_path`, so the copy wins; the script checks this
before anything else (every package must import from the copy, also in a child process as the
console script `sphrender` runs) and stops otherwise. Child processes the tests start
(`sphrender serve`, `sphrender submit`) inherit PYTHONPATH and so run the copy too. Each
mutation is applied to the copy's file and the original bytes are written back (and compared)
before the next one; the copy is deleted at the end.

Rows are real bugs, not equivalent mutants: a change that cannot alter behaviour is no test of
anything (one tried and dropped: not converting big-endian arrays in `readers._native`, which
`make_frame` converts to native float anyway).

Outcome per mutation: pytest exit status 1 (tests failed) = caught, 0 = survived; anything else
(collection error, unknown node id, timeout) is an error of the check itself and is reported
as such, never counted as caught. Before the mutations the union of all named tests runs on the
unmutated copy and must pass, so that a "caught" means the bug was seen, not that the test was
already failing.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE_FOLDERS = ("core", "server", "client", "shaders", "configs")
#: Caught share the check aims at (the issue's Done-when).
TARGET_SCORE = 0.9
TIMEOUT_S = 900


@dataclass(frozen=True)
class Mutation:
    name: str
    path: str  # relative to the repository root
    old: str  # must occur exactly once in the file
    new: str
    tests: tuple[str, ...]  # pytest node ids (relative to the repository root)
    description: str


# fmt: off
MUTATIONS: tuple[Mutation, ...] = (
    # -- the six the issue found, and their neighbours --------------------------------------
    Mutation(
        name="diffuse-ibl-without-1/pi",
        path="shaders/shade/shade_pbr.frag.glsl",
        old="diffuse_ibl = (1.0 - specular_albedo) * u_diffuse_albedo * irradiance * (1.0 / PI);",
        new="diffuse_ibl = (1.0 - specular_albedo) * u_diffuse_albedo * irradiance;",
        tests=(
            "tests/test_shading_mitsuba.py::test_dielectric_and_partly_metallic_spheres_under_the_workshop_match_mitsuba",
        ),
        description="the diffuse environment term E_sh(n) c_diff without its 1/pi",
    ),
    Mutation(
        name="prefiltered-level-from-roughness-squared",
        path="shaders/shade/shade_pbr.frag.glsl",
        old="float lod = clamp(u_roughness, 0.0, 1.0) * u_prefiltered_max_lod;",
        new="float lod = clamp(u_roughness * u_roughness, 0.0, 1.0) * u_prefiltered_max_lod;",
        tests=(
            "tests/test_shading_mitsuba.py::test_dielectric_and_partly_metallic_spheres_under_the_workshop_match_mitsuba",
        ),
        description="prefiltered environment level looked up at roughness^2, not roughness",
    ),
    Mutation(
        name="temperatures-of-the-first-k-after-culling",
        path="server/engine/geometry/prepare.py",
        old="np.ascontiguousarray(frame.temperatures[keep], dtype=np.float32)",
        new="np.ascontiguousarray(frame.temperatures[: int(keep.sum())], dtype=np.float32)",
        tests=(
            "tests/test_shading_emission.py::test_each_pixel_shows_the_temperature_of_its_front_particle",
        ),
        description="prepare_particles keeps the first k temperatures, not the visible particles'",
    ),
    Mutation(
        name="temperatures-not-subset-by-surface-only-splatting",
        path="server/engine/sph/frame.py",
        old="temperatures=None if out.temperatures is None else out.temperatures[keep],",
        new="temperatures=None if out.temperatures is None else out.temperatures[: keep.sum()],",
        tests=(
            "tests/test_shading_emission.py::test_each_pixel_shows_the_temperature_of_its_front_particle",
        ),
        description="surface-only splatting keeps the first k temperatures, not the splatted ones",
    ),
    Mutation(
        name="occlusion-second-pass-takes-temperatures-in-upload-order",
        path="shaders/common/splat_particles.glsl",
        old="return u_has_temperature ? splat_temperatures[particle] : 0.0;",
        new="return u_has_temperature ? splat_temperatures[uint(gl_VertexID) >> 2] : 0.0;",
        tests=(
            "tests/test_shading_emission.py::test_each_pixel_shows_the_temperature_of_its_front_particle",
        ),
        description="the occlusion-culled draws upload temperatures by quad slot, not by particle",
    ),
    Mutation(
        name="resume-skips-any-existing-output",
        path="client/submit.py",
        old="if resume and is_complete_image(job.output):",
        new="if resume and job.output.exists():",
        tests=(
            "tests/test_submit.py::test_resume_renders_again_what_is_damaged_under_its_final_name",
        ),
        description="--resume skips every existing output, complete or not",
    ),
    Mutation(
        name="normals-from-the-forward-difference",
        path="shaders/normals/surface_normals.frag.glsl",
        old="if (has_plus && (!has_minus || abs(z_plus - zc) <= abs(zc - z_minus))) {",
        new="if (has_plus) {",
        tests=("tests/test_normals_stencil.py::test_normals_match_numpy_reference",),
        description="hard normal_rules: always the forward difference, not the smaller step's",
    ),
    Mutation(
        name="normals-weighted-towards-the-steeper-side",
        path="shaders/normals/surface_normals.frag.glsl",
        old="(step_minus * plus + step_plus * minus) / total",
        new="(step_plus * plus + step_minus * minus) / total",
        tests=(
            "tests/test_engine_groundtruth.py::test_normals_beside_a_nearer_surface_come_from_their_own_surface",
            "tests/test_normals_stencil.py::test_normals_match_numpy_reference",
        ),
        description="smooth normal_rules: each 1-pixel difference weighted by its own step",
    ),
    Mutation(
        name="normals-smooth-rules-switch-again",
        path="shaders/normals/surface_normals.frag.glsl",
        old="u_smooth_rules ? 1.0 - smoothstep(0.0, 2.0, kink) : hard",
        new="hard",
        tests=(
            "tests/test_normals_stencil.py::test_smooth_rules_leave_no_switch_for_a_small_move_to_flip",
        ),
        description="smooth normal_rules: the wide stencil cut at the kink limit as the hard ones",
    ),
    Mutation(
        name="gaussian-weight-with-1/sigma^2",
        path="shaders/common/gaussian_steps.glsl",
        old="vec4 q = exp(-1.0 / (2.0 * sigma * sigma));",
        new="vec4 q = exp(-1.0 / (sigma * sigma));",
        tests=("tests/test_engine_groundtruth.py::test_default_quality_on_90k_ball_meets_issue_bounds",),
        description="separable Gaussian weights exp(-k^2 / sigma^2) instead of / (2 sigma^2)",
    ),
    # -- shaders (GLSL) ------------------------------------------------------------------------
    Mutation(
        name="schlick-exponent-4",
        path="shaders/common/brdf.glsl",
        old="return f0 + (1.0 - f0) * pow5(clamp(1.0 - cos_theta, 0.0, 1.0));",
        new="return f0 + (1.0 - f0) * pow(clamp(1.0 - cos_theta, 0.0, 1.0), 4.0);",
        tests=("tests/test_shading_brdf.py",),
        description="Schlick's Fresnel with (1 - v.h)^4 instead of ^5",
    ),
    Mutation(
        name="alpha-is-roughness",
        path="shaders/common/brdf.glsl",
        old="    float r = clamp(roughness, MIN_ROUGHNESS, 1.0);\n    return r * r;",
        new="    float r = clamp(roughness, MIN_ROUGHNESS, 1.0);\n    return r;",
        tests=("tests/test_shading_brdf.py",),
        description="GGX alpha = roughness instead of roughness^2",
    ),
    Mutation(
        name="sh9-l22-with-c3",
        path="shaders/common/sh9.glsl",
        old="return c1 * sh[8] * (x * x - y * y)",
        new="return c3 * sh[8] * (x * x - y * y)",
        tests=(
            "tests/test_shading_ibl.py::test_sh_irradiance_in_the_shader_matches_brute_force",
        ),
        description="the SH9 L22 (x^2 - y^2) term with c3 (the common bug) instead of c1",
    ),
    Mutation(
        name="equirect-mirrored",
        path="shaders/common/equirect.glsl",
        old="return vec2(atan(d.x, -d.z) * (0.5 / 3.14159265358979),",
        new="return vec2(atan(d.x, d.z) * (0.5 / 3.14159265358979),",
        tests=(
            "tests/test_shading_mitsuba.py::test_dielectric_and_partly_metallic_spheres_under_the_workshop_match_mitsuba",
        ),
        description="environment lookup u = atan2(x, z): the environment turned by 180 degrees",
    ),
    Mutation(
        name="narrow-range-keeps-the-unmatched-mirror-sample",
        path="shaders/smooth/smooth_depth_separable.frag.glsl",
        old="both(both(in_reach, both(valid_a, valid_b)), pair_kept(za, zb));",
        new="both(both(in_reach, valid_a), pair_kept(za, zb));",
        tests=("tests/test_filters.py",),
        description="narrow range: a dropped sample's mirror sample is still averaged",
    ),
    Mutation(
        name="narrow-range-pairs-never-dropped",
        path="shaders/smooth/smooth_depth_separable.frag.glsl",
        old="    return lessThanEqual(abs(mid) * g_center * g_center, vec4(u_nr_pair_limit));",
        new="    return bvec4(true);",
        tests=(
            "tests/test_filters.py::test_pair_test_keeps_a_filament_in_front_of_a_surface_and_leaves_the_slope",
        ),
        description="quality.narrow_range_pairs: the pair test keeps every pair",
    ),
    Mutation(
        name="frame-densities-always-trusted",
        path="server/engine/sph/frame_densities.py",
        old="    if not FIT_RANGE[0] <= ratio <= FIT_RANGE[1]:",
        new="    if False:",
        tests=(
            "tests/test_surfaces.py::test_densities_in_other_units_are_replaced_by_computed_ones",
            "tests/test_sph_cli.py::test_densities_in_other_units_are_computed_instead",
        ),
        description="a frame's densities in other units are used as they come",
    ),
    Mutation(
        name="constant-densities-trusted",
        path="server/engine/sph/frame_densities.py",
        old="    if smallest == largest and frame.count > 1:",
        new="    if False:",
        tests=(
            "tests/test_surfaces.py::test_one_density_for_every_particle_is_replaced_by_computed_ones",
            "tests/test_frame_densities.py::test_one_density_for_every_particle_tells_nothing",
        ),
        description="a frame with one density for every particle splits no droplet",
    ),
    Mutation(
        name="celsius-not-noted",
        path="server/engine/input_notes.py",
        old="    if coldest >= COLDEST_KELVIN:",
        new="    if True:",
        tests=(
            "tests/test_shading_emission.py::test_temperatures_in_celsius_render_as_sent_with_a_note",
        ),
        description="temperatures in degrees Celsius pass without a note",
    ),
    Mutation(
        name="out-of-view-not-noted",
        path="server/engine/input_notes.py",
        old="        if not visible and frame.count:",
        new="        if False:",
        tests=("tests/test_device_prepare.py::test_nothing_to_draw",),
        description="a frame none of whose particles is in view comes back blank without a word",
    ),
    Mutation(
        name="input-notes-not-passed-on",
        path="server/engine/renderer.py",
        old="        stats.notes.extend(outcome.notes)",
        new="        pass",
        tests=(
            "tests/test_surfaces.py::test_densities_in_other_units_are_replaced_by_computed_ones",
            "tests/test_service_stream.py::test_densities_in_other_units_are_rendered_with_a_note",
        ),
        description="what the SPH stage changed about a frame's input is not told to the client",
    ),
    Mutation(
        name="narrow-range-pairs-on-the-first-pass",
        path="server/engine/passes/smooth.py",
        old="    return [PAIR_TEST_OFF] + [limit] * (count - 1)",
        new="    return [limit] * count",
        tests=(
            "tests/test_filters.py::test_pair_test_keeps_a_filament_in_front_of_a_surface_and_leaves_the_slope",
        ),
        description="the pair test on the first pass too, which sees the raw splat",
    ),
    Mutation(
        name="splat-back-surface",
        path="shaders/splat/splat_sphere.frag.glsl",
        old="float t = along - sqrt(discriminant);",
        new="float t = along + sqrt(discriminant);",
        tests=(
            "tests/test_engine_groundtruth.py::test_one_particle_is_an_exact_sphere_without_filter",
        ),
        description="the impostor's depth from the far intersection of the ray and the sphere",
    ),
    Mutation(
        name="emission-without-its-angular-shape",
        path="shaders/shade/shade_pbr.frag.glsl",
        old="vec3 emissivity = u_emissivity * (1.0 - pow5(1.0 - nv));",
        new="vec3 emissivity = u_emissivity;",
        tests=(
            "tests/test_shading_emission.py::test_shader_emission_is_one_minus_fresnel_times_planck",
        ),
        description="hot-metal emission without (1 - F(n.v)): as bright at grazing angles",
    ),
    # -- OpenCL (shaders/sph.cl) ---------------------------------------------------------------
    Mutation(
        name="sph-gradient-sign",
        path="shaders/sph/sph.cl",
        old="gradient -= (volume * spline_dw_over_q(q)) * d;",
        new="gradient += (volume * spline_dw_over_q(q)) * d;",
        tests=("tests/test_sph.py",),
        description="colour-field gradient with grad W(x_j - x_i): the normals point inwards",
    ),
    Mutation(
        name="sph-kernel-normalisation-1/pi",
        path="shaders/sph/sph.cl",
        old="#define SIGMA_3D 2.546479089470325f /* 8 / pi */",
        new="#define SIGMA_3D 0.3183098861837907f /* 8 / pi */",
        tests=("tests/test_sph.py",),
        description="cubic spline normalised with 1 / (pi h^3) (support radius taken for h/2)",
    ),
    Mutation(
        name="sph-surface-test-as-printed",
        path="shaders/sph/sph.cl",
        old="const uchar surface = length(gradient) > threshold ? 1 : 0;",
        new="const uchar surface = length(gradient) < threshold ? 1 : 0;",
        tests=("tests/test_sph.py",),
        description="eq 28 as misprinted in the thesis, |n| < t",
    ),
    Mutation(
        name="sph-spline-derivative-without-1/q",
        path="shaders/sph/sph.cl",
        old="return -6.0f * t * t / q;",
        new="return -6.0f * t * t;",
        tests=("tests/test_sph.py",),
        description="(dW/dq) / q of the outer spline branch without its 1 / q",
    ),
    # -- Python engine --------------------------------------------------------------------------
    Mutation(
        name="near-plane-culls-straddling-spheres",
        path="server/engine/geometry/camera.py",
        old="keep = depth + r > self.near",
        new="keep = depth - r > self.near",
        tests=("tests/test_engine_hard_cases.py",),
        description="near-plane culling drops spheres that cross the near plane",
    ),
    Mutation(
        name="float32-before-the-eye-subtraction",
        path="server/engine/geometry/camera.py",
        old="offset = positions - self.eye",
        new=(
            "offset = (positions.astype(np.float32) - self.eye.astype(np.float32))"
            ".astype(np.float64)"
        ),
        tests=(
            "tests/test_engine_groundtruth.py::test_ball_renders_identically_after_translation",
        ),
        description="positions rounded to float32 before subtracting the eye (1e5 loses 1e-2)",
    ),
    Mutation(
        name="adaptive-radius-deficit-not-squared",
        path="server/engine/sph/radii.py",
        old="radius = body * (1.0 - deficit**2 / decline)",
        new="radius = body * (1.0 - deficit / decline)",
        tests=("tests/test_sph.py::test_adaptive_radius",),
        description="eq 29 with a linear density deficit instead of its square",
    ),
    # -- encoders, wire protocol, service, client ----------------------------------------------
    Mutation(
        name="exr-channels-bgr",
        path="server/output/encoders.py",
        old='for index, name in enumerate("RGB"):',
        new='for index, name in enumerate("BGR"):',
        tests=("tests/test_encoders.py",),
        description="EXR colour planes written under each other's names (B as R)",
    ),
    Mutation(
        name="png-alpha-unpremultiplied-by-the-writer",
        path="server/output/encoders.py",
        old='spec.attribute("oiio:UnassociatedAlpha", 1)',
        new='spec.attribute("oiio:UnassociatedAlpha", 0)',
        tests=("tests/test_encoders.py",),
        description="PNG written as associated alpha: OpenImageIO divides straight RGB by alpha",
    ),
    Mutation(
        name="protocol-trailing-payload-accepted",
        path="core/protocol.py",
        old="    if offset != payload_length:",
        new="    if offset > payload_length:",
        tests=("tests/test_protocol.py",),
        description="a FRAME payload longer than its arrays declare is accepted",
    ),
    Mutation(
        name="scheduler-serves-the-first-session-again",
        path="server/service/render/scheduler.py",
        old=(
            "                    del self._queues[key]\n"
            "                    if queue:\n"
            "                        self._queues[key] = queue"
        ),
        new="                    if not queue:\n                        del self._queues[key]",
        tests=("tests/test_service_units.py",),
        description="take() leaves a served session first in line: no round robin",
    ),
    Mutation(
        name="png-check-ignores-crc",
        path="core/image_check.py",
        old="if zlib.crc32(kind + body) & 0xFFFFFFFF != crc:",
        new="if first and zlib.crc32(kind + body) & 0xFFFFFFFF != crc:",
        tests=(
            "tests/test_submit.py::test_resume_renders_again_what_is_damaged_under_its_final_name",
            "tests/test_submit.py::test_image_checks_detect_truncation",
        ),
        description="the PNG completeness check verifies only the IHDR chunk's CRC",
    ),
    Mutation(
        name="exr-check-accepts-offsets-into-the-header",
        path="core/image_check.py",
        old="if any(not (pos + 8 * chunks <= o < len(data)) for o in offsets):",
        new="if any(not (o < len(data)) for o in offsets):",
        tests=(
            "tests/test_submit.py::test_resume_renders_again_what_is_damaged_under_its_final_name",
        ),
        description="the EXR check accepts chunk offsets that point before the data (zeroed table)",
    ),
    Mutation(
        name="bgeo-floats-read-little-endian",
        path="core/readers.py",
        old='_BGEO_TYPES: dict[int, str] = {0: ">f4", 1: ">i4", 4: ">i4", 5: ">f4"}',
        new='_BGEO_TYPES: dict[int, str] = {0: "<f4", 1: ">i4", 4: ">i4", 5: ">f4"}',
        tests=("tests/test_readers.py",),
        description="BGEO float attributes (density) decoded little-endian",
    ),
    # -- real splashy surfaces: droplets, anti-aliasing, ellipsoids ----------------------------
    Mutation(
        name="droplet-threshold-inverted",
        path="server/engine/sph/droplets.py",
        old="return np.asarray(frame.densities) < below",
        new="return np.asarray(frame.densities) >= below",
        tests=("tests/test_surfaces.py::test_exact_droplets_from_client_densities_need_no_sph_pass",),
        description="the dense particles are taken for droplets and the droplets smoothed",
    ),
    Mutation(
        name="edge-coverage-sides-swapped",
        path="shaders/common/edge_coverage.glsl",
        old="return s >= 0.0 ? share : 1.0 - share;",
        new="return s >= 0.0 ? 1.0 - share : share;",
        tests=("tests/test_surfaces.py::test_alpha_is_sub_pixel_coverage_on_every_edge",),
        description="a pixel's coverage counted on the outer side of the silhouette",
    ),
    Mutation(
        name="interior-junctions-left-translucent",
        path="shaders/shade/shade_pbr.frag.glsl",
        old="coverage < 1.0 && !next_to_background(pixel, size)",
        new="coverage < 0.0 && !next_to_background(pixel, size)",
        tests=(
            "tests/test_surfaces.py::test_alpha_is_sub_pixel_coverage_on_every_edge",
            "tests/test_gaps.py::test_thin_sheet_coverage_never_reduced",
        ),
        description="alpha < 1 inside a surface (the coverage pass writes only the rim band)",
    ),
    Mutation(
        name="ellipsoid-back-surface",
        path="shaders/splat/splat_ellipsoid.frag.glsl",
        old="    float t = along - sqrt((1.0 - miss2) / dd);",
        new="    float t = along + sqrt((1.0 - miss2) / dd);",
        tests=("tests/test_surfaces.py::test_ray_ellipsoid_depth_matches_the_analytic_ellipsoid",),
        description="the ellipsoid impostor shows its back surface",
    ),
    Mutation(
        name="last-pass-sigma-first-not-widened",
        path="server/engine/passes/smooth.py",
        old="        passes[along[0]] = (last_axis, math.sqrt(2.0 - last_pass_sigma**2))\n",
        new="",
        tests=("tests/test_filters.py::test_filter_matches_numpy_reference[narrow-range-separable]",),
        description="the last pass shrinks, the first along its axis does not widen",
    ),
    Mutation(
        name="last-pass-sigma-ignored",
        path="server/engine/passes/smooth.py",
        old="        passes[along[-1]] = (last_axis, last_pass_sigma)\n",
        new="",
        tests=(
            "tests/test_surfaces.py::"
            "test_last_pass_sigma_and_destreak_make_a_spheres_rim_isotropic_again",
        ),
        description="the last pass keeps its full sigma (the first still widens)",
    ),
    Mutation(
        name="destreak-at-full-sigma",
        path="shaders/smooth/smooth_depth_separable.frag.glsl",
        old="    sigma *= u_sigma_scale;\n",
        new="",
        tests=(
            "tests/test_filters.py::test_filter_matches_numpy_reference[narrow-range-destreak]",
            "tests/test_filters.py::test_filter_matches_numpy_reference[gaussian-destreak]",
        ),
        description="the destreak pass smooths with the full kernel, not a light one",
    ),
    Mutation(
        name="destreak-along-the-last-axis",
        path="server/engine/passes/smooth.py",
        old="passes.append((1 - last_axis, destreak))",
        new="passes.append((last_axis, destreak))",
        tests=(
            "tests/test_surfaces.py::"
            "test_last_pass_sigma_and_destreak_make_a_spheres_rim_isotropic_again",
        ),
        description="the destreak pass runs along the streaks instead of across them",
    ),
    Mutation(
        name="droplet-densities-computed-ignored",
        path="server/engine/sph/droplets.py",
        old='if frame.densities is not None and scene.quality.droplet_densities == "frame":',
        new="if frame.densities is not None:",
        tests=("tests/test_surfaces.py::test_computed_droplet_densities_ignore_the_frames",),
        description='droplet_densities = "computed" still trusts the frame\'s densities',
    ),
    Mutation(
        name="droplet-densities-over-the-splat-subset",
        path="server/engine/sph/frame.py",
        old=(
            "droplets, lone_skipped = self._with_lone(droplets, frame, scene, computed)\n"
            "                if computed is not None and computed.splat_keep is not None:\n"
            "                    droplets = droplets[computed.splat_keep]"
        ),
        new="droplets = droplet_mask(drawn, scene, self.engine)",
        tests=(
            "tests/test_surfaces.py::"
            "test_computed_droplet_densities_count_the_whole_frame_under_surface_only",
        ),
        description="the droplet split's own densities come from the surface-only subset",
    ),
    Mutation(
        name="droplet-densities-second-pass",
        path="server/engine/sph/droplets.py",
        old="if computed is not None and computed.density_computed:",
        new="if computed is not None and not computed.density_computed:",
        tests=("tests/test_surfaces.py::test_computed_droplet_densities_reuse_the_sph_stages_pass",),
        description="the split repeats the density pass the SPH stage already ran",
    ),
    Mutation(
        name="normals-across-discontinuities",
        path="shaders/normals/surface_normals.frag.glsl",
        old="    bool has_plus = z_plus > 0.0 && abs(z_plus - zc) <= jump;",
        new="    bool has_plus = z_plus > 0.0;",
        tests=(
            "tests/test_surfaces.py::test_normals_of_a_one_pixel_droplet_are_not_differenced_into_the_pool",
        ),
        description="a normal differenced into a farther surface across a depth step",
    ),
    # -- issue 12b: the wide normal stencil and the surface bench's metrics ----------------
    Mutation(
        name="normal-stencil-no-kink-test",
        path="shaders/normals/surface_normals.frag.glsl",
        old="u_smooth_rules ? 1.0 - smoothstep(0.0, 2.0, kink) : hard",
        new="1.0",
        tests=(
            "tests/test_normals_stencil.py::test_normals_match_numpy_reference",
            "tests/test_normals_stencil.py::test_wide_stencil_on_a_sphere_stays_within_the_chord_bound",
        ),
        description="the wide central difference taken across a kink (crease, rim)",
    ),
    Mutation(
        name="droplets-rims-of-the-bulk",
        path="shaders/field/field_normals.glsl",
        old="bool on_bulk = u_droplets && texelFetch(u_bulk_depth, p, 0).r == zc;",
        new="bool on_bulk = false;",
        tests=("tests/test_field_normals.py::test_a_droplet_in_front_of_the_bulk_is_no_rim_of_it",),
        description="an exact droplet in front of the bulk taken as a rim of it (a ring around it)",
    ),
    Mutation(
        name="lone-particles-never-added",
        path="server/engine/sph/frame.py",
        old="return (droplets if lone is None else droplets | lone), None",
        new="return droplets, None",
        tests=(
            "tests/test_surfaces.py::"
            "test_lone_particles_are_droplets_whatever_the_frames_densities_say",
        ),
        description="the particles alone in the frame not split off when its densities say bulk",
    ),
    Mutation(
        name="lone-threshold-at-the-pair",
        path="server/engine/sph/droplets.py",
        old="below = quality.droplet_lone_density * scene.sph.rest_density",
        new="below = 0.4 * scene.sph.rest_density",
        tests=(
            "tests/test_surfaces.py::"
            "test_lone_particles_are_droplets_whatever_the_frames_densities_say",
        ),
        description="the lone rule's threshold ignored (a touching pair taken as lone)",
    ),
    Mutation(
        name="below-overflow-list-ignored",
        path="shaders/sph/density_below.cl",
        old="    if (sum < limit && full) {",
        new="    if (sum < limit && full && false) {",
        tests=(
            "tests/test_sph_density_below.py::test_a_full_bucket_is_answered_exactly",
            "tests/test_sph_density_below.py::test_crowded_buckets_are_read_from_the_overflow_list",
        ),
        description="the particles past a full bucket's slots never counted",
    ),
    Mutation(
        name="below-limit-inverted",
        path="shaders/sph/density_below.cl",
        old="    out[i] = sum >= limit ? BELOW_NOT : BELOW_YES;",
        new="    out[i] = sum >= limit ? BELOW_YES : BELOW_NOT;",
        tests=(
            "tests/test_surfaces.py::test_exact_droplets_are_the_unfiltered_spheres_over_the_smoothed_pool",
        ),
        description="the positions' own densities: the dense particles taken for droplets",
    ),
    Mutation(
        name="below-shared-bucket-counted-twice",
        path="shaders/sph/density_below.cl",
        old="                if (again)\n                    continue;",
        new=(
            "                if (again && dx == 0 && dy == 0 && dz == 0)\n"
            "                    continue;"
        ),
        tests=("tests/test_sph_density_below.py::test_a_bucket_two_cells_share_is_counted_once",),
        description="a bucket two cells of the walk share summed twice (the own cell's excepted)",
    ),
    Mutation(
        name="below-self-counted",
        path="shaders/sph/density_below.cl",
        old="if (r2 < h * h && j != i)",
        new="if (r2 < h * h)",
        tests=("tests/test_sph_density_below.py::test_small_frames",),
        description="a particle's own weight added again when its bucket lists it",
    ),
    Mutation(
        name="droplets-flag-never-set",
        path="server/engine/passes/field_normals.py",
        old='set_if_used(shader, "u_droplets", bulk is not depth)',
        new='set_if_used(shader, "u_droplets", False)',
        tests=("tests/test_field_normals.py::test_a_droplet_leaves_no_ring_on_the_pool_behind_it",),
        description="the listing never told that droplets were drawn over the bulk",
    ),
    Mutation(
        name="bulk-depth-not-passed-on",
        path="server/engine/renderer.py",
        old="bulk=surface.bulk_depth,",
        new="bulk=None,",
        tests=("tests/test_field_normals.py::test_a_droplet_leaves_no_ring_on_the_pool_behind_it",),
        description="the normals pass not given the bulk's depth under the droplets",
    ),
    Mutation(
        name="field-rims-cut-at-the-jump",
        path="shaders/field/field_normals.glsl",
        old="#define FIELD_RIM_FEATHER 2.0",
        new="#define FIELD_RIM_FEATHER 1.001",
        tests=("tests/test_field_normals.py::test_a_depth_step_turns_into_a_rim_smoothly",),
        description="a depth step is a full rim just past the jump (no feather): rims switch",
    ),
    Mutation(
        name="normal-stencil-one-sided-scale",
        path="shaders/normals/surface_normals.frag.glsl",
        old="int s = u_stencil_radii > 0.0",
        new="int s = u_stencil_radii < 0.0",
        tests=("tests/test_normals_stencil.py::test_wide_stencil_averages_ripple_on_a_plane",),
        description="the normal_stencil setting ignored (always the 1-pixel difference)",
    ),
    Mutation(
        name="shift-tolerant-band-ignores-truth-coverage",
        path="server/bench/surface_quality.py",
        old="angle = np.where(hit[window], np.degrees(np.arccos(cos)), np.inf)",
        new="angle = np.degrees(np.arccos(cos))",
        tests=(
            "tests/test_surface_metrics.py::test_shift_tolerance_forgives_a_one_pixel_rim_and_nothing_else",
        ),
        description="the tolerant band matching a render normal with the truth's background",
    ),
    Mutation(
        name="surface-front-ties-dominate",
        path="server/bench/surface_bench.py",
        old="return all(x <= y for x, y in pairs) and any(x < y for x, y in pairs)",
        new="return all(x <= y for x, y in pairs)",
        tests=("tests/test_surface_metrics.py::test_surface_front_keeps_rows_not_beaten_on_every_column",),
        description="a row equal on every column counted as beaten (the front empties)",
    ),
    Mutation(
        name="coverage-ids-past-the-quads",
        path="server/engine/passes/splat.py",
        old="        self.buffers.ensure_quads(2 * count)\n",
        new="",
        tests=("tests/test_device_prepare.py::test_sparse_cloud_matches_the_host_prepare",),
        description="the host culling's coverage rows drawn past the quad index buffer",
    ),
    Mutation(
        name="device-prepare-float-subtraction",
        path="shaders/splat/particles_to_view.comp.glsl",
        old="dvec3 v = u_rotation * (world - u_eye);",
        new="dvec3 v = dvec3(mat3(u_rotation) * (vec3(world) - vec3(u_eye)));",
        tests=("tests/test_device_prepare.py::test_ball_with_temperatures_matches_the_host_prepare",),
        description="the device prepare subtracting the eye in float32 (1e5 coordinates break)",
    ),
    Mutation(
        name="device-culling-drops-visible",
        path="shaders/splat/occlusion_cull.comp.glsl",
        old="bool hidden = largest >= 0.0 && near > largest;",
        new="bool hidden = largest >= 0.0 && near > 0.5 * largest;",
        tests=("tests/test_device_prepare.py::test_dense_wall_behind_spatter",),
        description="the device occlusion test culling particles in front of the front layer",
    ),
    Mutation(
        name="display-pass-fused-rounding",
        path="shaders/display/display_codes.frag.glsl",
        old="    while (code < 255u && pattern >= thresholds[code]) ++code;\n",
        new="",
        tests=("tests/test_display_pass.py::test_hard_values_get_the_cpu_codes",),
        description="the display pass trusting the GPU's pow without the CPU's thresholds",
    ),
    Mutation(
        name="storage-binding-not-renewed-on-growth",
        path="server/engine/passes/splat_buffers.py",
        old="            buffer.orphan(max(nbytes, buffer.size * 2))\n            # A storage",
        new=(
            "            buffer.orphan(max(nbytes, buffer.size * 2))\n"
            "            return\n            # A storage"
        ),
        tests=("tests/test_device_prepare.py::test_buffers_grown_between_frames",),
        description="a grown storage buffer read through its binding of the old size",
    ),
    Mutation(
        name="display-binds-without-claiming",
        path="server/engine/passes/display.py",
        old="        if self._context.gl.claim_storage_bindings(self):\n",
        new="        if True:\n",
        tests=("tests/test_gl_state_caches.py::test_frames_keep_their_image_between_display_passes_and_other_renderers",),
        description="the display pass takes binding 0 and the next frame's splat keeps its claim",
    ),
    Mutation(
        name="pyramid-counts-missing-pixels",
        path="shaders/splat/depth_pyramid.comp.glsl",
        old="const float NONE = -1.0;",
        new="const float NONE = 1.0 / 0.0;",
        tests=("tests/test_depth_pyramid.py",),
        description="pixels past the box's odd edge count as background (+inf) in the maxima",
    ),
    Mutation(
        name="uniform-group-ignores-member-writes",
        path="server/engine/gpu/uniforms.py",
        old="    cache[name] = value\n    _forget_groups_with(cache, name)",
        new="    cache[name] = value",
        tests=("tests/test_gl_state_caches.py::test_a_member_written_elsewhere_makes_its_group_rebuild",),
        description="a group skips over a member value another path changed",
    ),
    Mutation(
        name="gaps-background-needs-one-direction",
        path="shaders/gaps/close_gaps.frag.glsl",
        old="int need = zc > 0.0 ? 1 : 2;",
        new="int need = 1;",
        tests=("tests/test_gaps.py::test_notch_along_a_silhouette_stays_open",),
        description="the gap pass filling notches along a silhouette (one enclosing direction)",
    ),
    Mutation(
        name="gaps-walk-climbs-slopes",
        path="shaders/gaps/close_gaps.frag.glsl",
        old="if (previous <= 0.0 || zk < previous - u_edge_jump) {",
        new="if (true) {",
        tests=("tests/test_gaps.py::test_crease_is_no_gap",),
        description="the gap walk taking a slope up its own surface for a nearer one",
    ),
    Mutation(
        name="gaps-cold-fill",
        path="shaders/gaps/close_gaps.frag.glsl",
        old="float ta = texelFetch(u_temperature, fill_a, 0).r;",
        new="float ta = 0.0;",
        tests=("tests/test_gaps.py::test_kelvin_filled_like_the_depth",),
        description="the gap pass leaving closed gaps half cold in the kelvin image",
    ),
    Mutation(
        name="silhouette-border-is-edge",
        path="shaders/silhouette/silhouette_normals.frag.glsl",
        old="        return -1.0;\n    }\n    return texelFetch(u_normal_depth, p, 0).w;",
        new="        return 0.0;\n    }\n    return texelFetch(u_normal_depth, p, 0).w;",
        tests=("tests/test_silhouette.py::test_surface_filling_the_image_is_untouched",),
        description="the silhouette pass taking the image border for a silhouette",
    ),
    Mutation(
        name="silhouette-droplets-not-spared",
        path="shaders/silhouette/silhouette_normals.frag.glsl",
        old="* edge_like;",
        new=";",
        tests=("tests/test_silhouette.py::test_exact_spheres_barely_change",),
        description="the silhouette pass turning droplets smaller than its window",
    ),
    Mutation(
        name="shade-neighbour-window-empty",
        path="server/engine/passes/shade.py",
        old='"u_neighbour_reach": 1,',
        new='"u_neighbour_reach": 0,',
        tests=("tests/test_surfaces.py::test_alpha_is_sub_pixel_coverage_on_every_edge",),
        description="the shade pass's anti-aliasing windows shrunk to the pixel itself",
    ),
    Mutation(
        name="field-first-ring-too-far",
        path="shaders/field/field_normals.glsl",
        old="            int dm = max(gx + gy, 1);",
        new="            int dm = max(gx + gy, 1) + 1;",
        tests=("tests/test_field_normals.py::test_matches_the_numpy_reference",),
        description="the rim search starting a ring past the first that a tile allows",
    ),
    Mutation(
        name="field-tile-test-farther-only",
        path="shaders/field/field_list.comp.glsl",
        old="                if (e.r - own.g > jump || own.r - e.g > jump) {",
        new="                if (e.r - own.g > jump) {",
        tests=(
            "tests/test_field_normals.py::test_rims_of_a_nearer_sheet_over_a_wall_filling_the_image",
        ),
        description="the listing skipping tiles whose rim is a nearer surface",
    ),
    Mutation(
        name="field-list-half-the-tile",
        path="shaders/field/field_list.comp.glsl",
        old="int((i >> 2) & 3u)",
        new="int((i >> 2) & 1u)",
        tests=("tests/test_field_normals.py::test_matches_the_numpy_reference",),
        description="the listing covering only two rows of each listed tile",
    ),
    Mutation(
        name="field-list-partial-tiles-dropped",
        path="server/engine/passes/field_normals.py",
        old="    x1 = min(-(-(x + width) // 4), tiles[0])",
        new="    x1 = min((x + width) // 4, tiles[0])",
        tests=("tests/test_field_normals.py::test_matches_the_reference_on_images_of_partial_tiles",),
        description="the listing leaving out the partial tiles at an image's far side",
    ),
    Mutation(
        name="field-grid-atomic-order",
        path="shaders/field/field_grid.comp.glsl",
        old="                sorted_centres[first + below] = s;",
        new="                sorted_centres[first + entry.y] = s;",
        tests=("tests/test_field_normals.py::test_the_same_frame_gives_the_same_normals_bit_for_bit",),
        description="the field grid keeping its atomics' order within a bucket (normals vary)",
    ),
    Mutation(
        name="field-rows-overlap",
        path="shaders/common/field_grid.glsl",
        old="#define FIELD_HASH_Y 19349663u",
        new="#define FIELD_HASH_Y 1u",
        tests=("tests/test_field_normals.py::test_matches_the_numpy_reference",),
        description="field grid rows of one window sharing buckets (centres counted twice)",
    ),
    Mutation(
        name="field-row-wrap-dropped",
        path="shaders/field/field_normals.glsl",
        old="add_centres(starts[0], starts[last - buckets], x, h, outward, scale);",
        new="",
        tests=("tests/test_field_normals.py::test_rows_wrapping_at_the_tables_end",),
        description="a row of cells that wraps at the table's end losing its part past it",
    ),
    Mutation(
        name="field-cull-middle-block-only",
        path="shaders/field/field_grid.comp.glsl",
        old="return (rim_blocks[middle.y * u_rim_blocks.x + middle.x] & 2u) != 0u;",
        new="return (rim_blocks[middle.y * u_rim_blocks.x + middle.x] & 1u) != 0u;",
        tests=("tests/test_field_normals.py::test_matches_the_numpy_reference",),
        description="the field grid dropping particles whose support reaches a listed block",
    ),
    Mutation(
        name="field-blend-last-group-dropped",
        path="shaders/field/field_blend.comp.glsl",
        old="uint needed = (rim_count + uint(FIELD_GROUP) - 1u) / uint(FIELD_GROUP);",
        new="uint needed = rim_count / uint(FIELD_GROUP);",
        tests=("tests/test_field_normals.py::test_matches_the_numpy_reference",),
        description="field normals' blend dispatched without the list's last, partial group",
    ),
    Mutation(
        name="field-blend-rows-overlap",
        path="shaders/field/field_blend.comp.glsl",
        old="uint i = gl_WorkGroupID.y * u_groups_x * uint(FIELD_GROUP) + gl_GlobalInvocationID.x;",
        new="uint i = gl_WorkGroupID.y * u_groups_x + gl_GlobalInvocationID.x;",
        tests=("tests/test_field_normals.py::test_blend_dispatch_in_rows",),
        description="the blend's rows of work groups indexing the list as if one group long",
    ),
    Mutation(
        name="field-scan-inclusive",
        path="shaders/field/field_grid.comp.glsl",
        old="            buckets[b] = running;\n            running += count;",
        new="            running += count;\n            buckets[b] = running;",
        tests=("tests/test_field_normals.py::test_matches_the_numpy_reference",),
        description="the field grid's bucket starts one bucket late (inclusive prefix sum)",
    ),
    Mutation(
        name="field-cells-skipped",
        path="shaders/field/field_normals.glsl",
        old="float chord = sqrt(h * h - row2);",
        new="float chord = 0.5 * sqrt(h * h - row2);",
        tests=("tests/test_field_normals.py::test_matches_the_numpy_reference",),
        description="field normals scanning rows of cells shorter than the support's chord",
    ),
    Mutation(
        name="field-faces-away",
        path="shaders/field/field_normals.glsl",
        old="    if (away > 0.0) {\n        n_field = normalize(n_field - 2.0 * away * ray);",
        new="    if (away > 1.0) {\n        n_field = normalize(n_field - 2.0 * away * ray);",
        tests=("tests/test_field_normals.py::test_matches_the_numpy_reference",),
        description="field normals left facing away from the eye",
    ),
    Mutation(
        name="field-culled-counted",
        path="shaders/field/field_grid.comp.glsl",
        old="if (s.w != 0.0 && (!u_cull || near_a_rim(s.xyz))) {",
        new="if (!u_cull || near_a_rim(s.xyz)) {",
        tests=("tests/test_field_normals.py::test_host_and_device_prepare_agree",),
        description="the field grid sorting the particles the device prepare culled",
    ),
    Mutation(
        name="field-host-droplets-missing",
        path="server/engine/passes/prepare_stage.py",
        old="            prepared.center_radius,\n        )",
        new="            bulk.center_radius,\n        )",
        tests=("tests/test_field_normals.py::test_host_and_device_prepare_agree",),
        description="the field grid without the host prepare's droplets",
    ),
    Mutation(
        name="field-rim-jump-4r-only",
        path="shaders/field/field_normals.glsl",
        old="float jump = max(u_edge_jump, footprint_jump * float(d));",
        new="float jump = u_edge_jump;",
        tests=("tests/test_field_normals.py::test_a_grazing_surface_far_away_is_no_rim",),
        description="field normals taking a grazing surface's per-pixel steps for rims",
    ),
    Mutation(
        name="field-rim-jump-not-summed",
        path="shaders/field/field_normals.glsl",
        old="float jump = max(u_edge_jump, footprint_jump * float(d));",
        new="float jump = max(u_edge_jump, footprint_jump);",
        tests=("tests/test_field_normals.py::test_a_grazing_surface_far_away_is_no_rim",),
        description="field normals comparing a pixel d away with one pixel's step allowance",
    ),
    Mutation(
        name="host-culling-drops-rim-coverage",
        path="server/engine/passes/splat.py",
        old="edge = ids[~np.isfinite(largest[ids])].astype(np.uint32)",
        new="edge = ids[~np.isfinite(table.largest(bounds.grown(-1), ids))].astype(np.uint32)",
        tests=("tests/test_occlusion.py",),
        description="coverage left out for particles whose rectangle's rim touches background",
    ),
    Mutation(
        name="device-culling-drops-rim-coverage",
        path="shaders/splat/occlusion_cull.comp.glsl",
        old="covered(rect, u_coverage_need)",
        new="covered(rect, u_coverage_need - 1)",
        tests=("tests/test_device_prepare.py",),
        description="the device culling's coverage left out where a rectangle's rim is open",
    ),
    Mutation(
        name="coverage-band-without-the-outside",
        path="shaders/splat/coverage_band.frag.glsl",
        old="gl_FragDepth = band ? 1.0 : 0.0;",
        new="gl_FragDepth = band && surface ? 1.0 : 0.0;",
        tests=("tests/test_surfaces.py::test_alpha_is_sub_pixel_coverage_on_every_edge",),
        description="no coverage drawn just outside the silhouettes (no anti-aliased fringe)",
    ),
    Mutation(
        name="gap-tiles-miss-near-jumps",
        path="shaders/gaps/gap_tiles.frag.glsl",
        old="jump = jump || zn <= 0.0 || zq < zn - u_edge_jump;",
        new="jump = jump || zn <= 0.0 || zq < zn - 3.0 * u_edge_jump;",
        tests=("tests/test_gaps.py",),
        description="the gap tiles skipping pixels a walk could stop on (gaps before a surface)",
    ),
    Mutation(
        name="gap-tiles-skip-farther-surfaces",
        path="shaders/gaps/close_gaps.frag.glsl",
        old="    if (!nearer(tile.g, zc)) {",
        new="    if (!nearer(tile.g, zc) || zc > 0.0) {",
        tests=("tests/test_gaps.py",),
        description="the gap pass leaving gaps over a farther surface open",
    ),
    Mutation(
        name="gap-walks-wrong-quadrant",
        path="shaders/gaps/close_gaps.frag.glsl",
        old="        nearer(diagonals.b, zc) && nearer(diagonals.a, zc));",
        new="        nearer(diagonals.r, zc) && nearer(diagonals.g, zc));",
        tests=("tests/test_gaps.py::test_enclosed_along_one_direction_alone",),
        description="the gap pass bounding the (1, -1) walks by the (1, 1) diagonal's quadrants",
    ),
    Mutation(
        name="gap-quadrant-from-the-wrong-side",
        path="shaders/gaps/gap_dilate.frag.glsl",
        old="out_diagonals = written(vec4(positive.a, negative.b, negative.a, positive.b));",
        new="out_diagonals = written(vec4(negative.a, negative.b, negative.a, positive.b));",
        tests=("tests/test_gaps.py::test_enclosed_along_one_direction_alone",),
        description="the gap tiles' x+ y+ quadrant taken from below the tile's row",
    ),
    Mutation(
        name="closed-gaps-keep-sphere-alpha",
        path="shaders/shade/shade_pbr.frag.glsl",
        old="    } else if (normal_depth.w > 0.0 && coverage < 0.5) {",
        new="    } else if (normal_depth.w > 0.0 && coverage < -0.5) {",
        tests=("tests/test_gaps.py::test_thin_sheet_coverage_never_reduced",),
        description="closed gaps left with the spheres' coverage (surface pixels with alpha 0)",
    ),
    Mutation(
        name="gap-tile-flag-at-nearest-depth",
        path="shaders/gaps/gap_dilate.frag.glsl",
        old="may_close(tile.g, out_axes, out_diagonals, depths.b, 1)",
        new="may_close(tile.g, out_axes, out_diagonals, tile.r, 1)",
        tests=("tests/test_gaps.py",),
        description="the close pass skipping tiles whose farther pixels could close",
    ),
    Mutation(
        name="gap-tile-flag-forgets-background",
        path="shaders/gaps/gap_dilate.frag.glsl",
        old="(depths.a > 0.0 && may_close(tile.g, out_axes, out_diagonals, 0.0, 2))",
        new="(depths.a > 1.0 && may_close(tile.g, out_axes, out_diagonals, 0.0, 2))",
        tests=("tests/test_gaps.py",),
        description="the close pass skipping tiles whose background pixels could close",
    ),
    Mutation(
        name="gap-points-clipped-at-the-far-edge",
        path="shaders/gaps/close_tiles.vert.glsl",
        old="vec2 center = min(vec2(tile) * 4.0 + 2.0, u_image_size - 1.5);",
        new="vec2 center = vec2(tile) * 4.0 + 2.0;",
        tests=("tests/test_gaps.py::test_image_sizes_off_the_tile_grid",),
        description="the close pass skipping the partial tiles of images off the 4-px grid",
    ),
    Mutation(
        name="depth-aov-zero-background",
        path="shaders/readback/depth_aov.frag.glsl",
        old="depth > 0.0 ? depth :",
        new="depth >= 0.0 ? depth :",
        tests=("tests/test_readback.py",),
        description="the Z AOV keeping the target's 0 where there is no surface (contract: +inf)",
    ),
    Mutation(
        name="depth-aov-box-columns-only",
        path="server/engine/passes/readback.py",
        old="(0, box[1], width, box[3])",
        new="box",
        tests=("tests/test_readback.py",),
        description="the Z copy drawn only in the box's columns while the box's full rows are read",
    ),
    Mutation(
        name="edge-on-rim-turned-to-the-camera",
        path="shaders/normals/surface_normals.frag.glsl",
        old="    if (near_plus && !near_minus) {",
        new="    if (false) {",
        tests=("tests/test_normals_stencil.py",),
        description="a pixel with one nearer neighbour and no same-surface one assumed flat",
    ),
    Mutation(
        name="second-context-on-owner-thread-allowed",
        path="server/engine/gpu/gl_context.py",
        old="        if live is not None and live._ctx is not None:",
        new="        if False:",
        tests=("tests/test_engine_hard_cases.py",),
        description="a second GL context made on a thread that owns one (it takes over the first)",
    ),
    Mutation(
        name="rasteriser-threads-left-preempting",
        path="server/engine/gpu/rasteriser_threads.py",
        old="os.sched_setscheduler(tid, os.SCHED_BATCH, os.sched_param(0))",
        new="os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))",
        tests=("tests/test_rasteriser_threads.py",),
        description="llvmpipe's workers counted as switched but left under the default policy",
    ),
    Mutation(
        name="samplers-not-bound-at-build",
        path="server/engine/gpu/programs.py",
        old="            _bind_samplers(program, samplers)\n",
        new="",
        tests=("tests/test_programs.py", "tests/test_gaps.py"),
        description="the sampler units passed to ProgramCache.get never set (all left at unit 0)",
    ),
    Mutation(
        name="smooth-border-fit-dropped",
        path="shaders/smooth/image_border_taps.glsl",
        old="    bvec4 one_sided = notEqual(g_k_sum, vec4(0.0));",
        new="    bvec4 one_sided = bvec4(false);",
        tests=(
            "tests/test_filters.py::test_filter_matches_numpy_reference",
            "tests/test_filters.py::test_narrow_range_keeps_a_plane_in_perspective_up_to_the_image_edges",
        ),
        description="the 1-D passes' kernel one-sided at an image end without the line fit",
    ),
    Mutation(
        name="smooth-border-strips-plain",
        path="server/engine/passes/smooth.py",
        old="        parts += [(1, strip) for strip in strips]",
        new="        parts += [(0, strip) for strip in strips]",
        tests=(
            "tests/test_engine_groundtruth.py::test_slab_filling_the_image_is_as_smooth_at_the_image_edges_as_inside",
        ),
        description="the strips at the image's ends drawn with the packed walk (taps dropped)",
    ),
    Mutation(
        name="smooth-border-strip-too-narrow",
        path="server/engine/geometry/screen_box.py",
        old="lo, hi, end = (margin_px + 3) // 4, (width - 4 - margin_px) // 4 + 1, texels[0]",
        new="lo, hi, end = margin_px // 4, (width - 4 - margin_px) // 4 + 1, texels[0]",
        tests=(
            "tests/test_filters.py::test_border_split_gives_every_texel_near_an_image_end_to_the_border_variant",
            "tests/test_filters.py::test_packed_filters_with_wide_and_capped_kernels",
        ),
        description="the left strip one texel short when kernel_max_px is no multiple of 4",
    ),
    Mutation(
        name="smooth-centre-as-depth",
        path="shaders/smooth/smooth_depth_separable.frag.glsl",
        old="    g_sum = inverse_depth(z);",
        new="    g_sum = zc;",
        tests=("tests/test_filters.py::test_filter_matches_numpy_reference",),
        description="the narrow range's centre sample summed as depth among inverse depths",
    ),
    Mutation(
        name="smooth-2d-border-fit-dropped",
        path="shaders/smooth/smooth_depth.frag.glsl",
        old="    return clamp(mean - dot(slope, o_mean), v_min, v_max);",
        new="    return mean;",
        tests=(
            "tests/test_filters.py::test_filter_matches_numpy_reference",
            "tests/test_filters.py::test_narrow_range_keeps_a_plane_in_perspective_up_to_the_image_edges",
        ),
        description="the 2-D kernels one-sided at an image end without the plane fit",
    ),

    Mutation(
        name="smooth-border-pair-sum-reordered",
        path="shaders/smooth/image_border_taps.glsl",
        old="    g_sum += mix(wa * ua + wb * ub, w * (ua + ub), pair);",
        new="    g_sum += wa * ua + wb * ub;",
        tests=(
            "tests/test_filters.py::"
            "test_border_variant_gives_the_packed_walks_result_bit_for_bit_inside",
        ),
        description="the border variant summing a pair in another order (a seam at its strips)",
    ),
    Mutation(
        name="smooth-border-gaussian-fit-dropped",
        path="shaders/smooth/image_border_taps.glsl",
        old="    bvec4 one_sided = g_crossed;",
        new="    bvec4 one_sided = bvec4(false);",
        tests=(
            "tests/test_filters.py::test_filter_matches_numpy_reference",
            "tests/test_engine_groundtruth.py::"
            "test_slab_filling_the_image_is_as_smooth_at_the_image_edges_as_inside",
        ),
        description="the Gaussian's one-sided mean at an image end kept (no line fit)",
    ),
    Mutation(
        name="temperature-border-fit-dropped",
        path="shaders/temperature/smooth_temperature.frag.glsl",
        old="                              g_t_min - span, g_t_max + span, g_crossed);",
        new="                              g_t_min - span, g_t_max + span, bvec4(false));",
        tests=("tests/test_filters.py::test_temperature_blur_matches_numpy_reference",),
        description="the temperature blur's one-sided mean at an image end kept (no line fit)",
    ),
    Mutation(
        name="spread-weight-dropped",
        path="shaders/common/gaussian_steps.glsl",
        old="    g_gaussian_weight = stride * exp(-last * last * inv_two_sigma2);",
        new="    g_gaussian_weight = exp(-last * last * inv_two_sigma2);",
        tests=("tests/test_filters.py::test_packed_filters_with_wide_and_capped_kernels",),
        description="a spread tap weighted as one pixel, not the stride it stands for",
    ),
    Mutation(
        name="spread-room-limit-dropped",
        path="shaders/smooth/smooth_depth_separable.frag.glsl",
        old="    limit = min(limit, max(vec4(cap), min(room_ahead, room_behind)));",
        new="    limit = limit;",
        tests=("tests/test_filters.py::test_packed_filters_with_wide_and_capped_kernels",),
        description="spread taps reaching past the image's ends (read there as background)",
    ),
    Mutation(
        name="spread-stride-from-largest-lane",
        path="shaders/smooth/smooth_depth_separable.frag.glsl",
        old="min(min(smallest.x, smallest.y), min(smallest.z, smallest.w))",
        new="max(max(smallest.x, smallest.y), max(smallest.z, smallest.w))",
        tests=("tests/test_filters.py::test_packed_filters_with_wide_and_capped_kernels",),
        description="a texel's tap spacing from its longest kernel, not its shortest",
    ),
    Mutation(
        name="spread-overlaps-row-texels",
        path="shaders/smooth/smooth_depth_separable.frag.glsl",
        old="    int dense_end = AXIS == 0 ? (dense + 3) / 4 * 4 : dense;",
        new="    int dense_end = dense;",
        tests=("tests/test_filters.py::test_packed_filters_with_wide_and_capped_kernels",),
        description="spread taps starting inside the row walk's last texel (taps counted twice)",
    ),
    Mutation(
        name="spread-row-window-skips",
        path="shaders/common/packed_taps.glsl",
        old="            ahead_next = fetch_packed(image, texel + ivec2(s + 1, 0));",
        new="            ahead_next = fetch_packed(image, texel + ivec2(s + 2, 0));",
        tests=("tests/test_filters.py::test_packed_filters_with_wide_and_capped_kernels",),
        description="the spread row walk's window one texel off ahead",
    ),
    Mutation(
        name="spread-taps-off",
        path="shaders/smooth/smooth_depth_separable.frag.glsl",
        old="    vec4 limit = vec4(cap * float(u_kernel_max_stride));",
        new="    vec4 limit = vec4(cap);",
        tests=(
            "tests/test_engine_groundtruth.py::test_spread_taps_keep_a_close_up_as_smooth_as_the_full_kernel",
        ),
        description="kernel_max_stride ignored: a hard cap on close-ups (the lattice's ripple)",
    ),
    Mutation(
        name="shader-include-note-a-directive",
        path="server/engine/gpu/shader_loader.py",
        old="""                note = f'// "{target}" skipped: included above'""",
        new="""                note = f'// #include "{target}" skipped: included above'""",
        tests=("tests/test_shader_loader.py::test_diamond_include_included_once",),
        description="a skipped include's note read by moderngl as a directive (which it fails)",
    ),
    Mutation(
        name="sph-ranks-atomic-order",
        path="server/engine/sph/engine.py",
        old="""        self._run("stable_rank", n, bucket, starts, slots, u32(n), rank)""",
        new="""        pass""",
        tests=("tests/test_sph.py::test_the_same_frame_gives_the_same_bits",),
        description="the counting sort's ranks left in atomic order (run-to-run last bits)",
    ),
    Mutation(
        name="gaps-pinholes-left",
        path="server/engine/passes/smooth.py",
        old="            return self._gaps.close_again(smoothed, temperature)",
        new="            return smoothed",
        tests=("tests/test_gaps.py::test_pinholes_through_a_lattice_plate_are_closed",),
        description="no second close after the smoothing: a lattice plate's pinholes stay open",
    ),
    Mutation(
        name="gaps-pinholes-cold",
        path="server/engine/passes/gaps.py",
        old="self._close(program, targets, depth, tile_box, temperature, targets.again())",
        new="self._close(program, targets, depth, tile_box, None, targets.again())",
        tests=("tests/test_gaps.py::test_pinholes_through_a_lattice_plate_are_closed",),
        description="pinholes closed in depth but left at 0 K in the kelvin the blur reads",
    ),
)
# fmt: on


def check_table(mutations: Sequence[Mutation], root: Path) -> list[str]:
    """Every problem with the table against the files under `root` (empty = usable)."""
    problems = []
    names = [m.name for m in mutations]
    for name in sorted({n for n in names if names.count(n) > 1}):
        problems.append(f"duplicate mutation name {name!r}")
    for m in mutations:
        path = root / m.path
        if not path.is_file():
            problems.append(f"{m.name}: {m.path} does not exist")
            continue
        count = path.read_text(encoding="utf-8").count(m.old)
        if count != 1:
            problems.append(f"{m.name}: the old text occurs {count} times in {m.path}, not once")
        if m.old == m.new:
            problems.append(f"{m.name}: old and new text are the same")
        if not m.tests:
            problems.append(f"{m.name}: no tests named")
        for test in m.tests:
            test_file = root / test.split("::", 1)[0]
            if not test_file.is_file():
                problems.append(f"{m.name}: test file {test_file.relative_to(root)} not found")
    return problems


def tree_files(repo: Path) -> list[str]:
    """Tracked files and untracked files git does not ignore (the working tree as git sees it)."""
    listed = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=repo,
        capture_output=True,
        check=True,
    ).stdout.decode()
    return [name for name in listed.split("\0") if name and (repo / name).is_file()]


@contextmanager
def copied_tree(repo: Path = REPO) -> Iterator[tuple[Path, dict[str, str]]]:
    """A temporary copy of the tree and the environment that imports `sphrender` from it."""
    with tempfile.TemporaryDirectory(prefix="sphrender-mutation-") as tmp:
        # Nested one level deeper so nothing named `shared` sits beside the copy: tests that
        # still needed ../shared would fail here instead of passing on the workplace's data.
        tree = Path(tmp) / "checkout" / "sphrender"
        for name in tree_files(repo):
            target = tree / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(repo / name, target)
        layout = Path(tmp) / "layout" / "sphrender"
        layout.mkdir(parents=True)
        for folder in PACKAGE_FOLDERS:
            (layout / folder).symlink_to(tree / folder, target_is_directory=True)
        env = {
            **os.environ,
            "PYTHONPATH": os.pathsep.join(
                [str(layout.parent), *filter(None, [os.environ.get("PYTHONPATH")])]
            ),
            "PYTHONDONTWRITEBYTECODE": "1",
        }
        check_imports_from(tree, env)
        yield tree, env


def check_imports_from(tree: Path, env: dict[str, str]) -> None:
    """Stop unless a child interpreter with `env` imports every package from `tree`."""
    probe = (
        "import importlib.resources, sphrender.server.engine.renderer as r, "
        "sphrender.client.submit as s, sphrender.server.cli as c;"
        "print(r.__file__); print(s.__file__); print(c.__file__);"
        "print(importlib.resources.files('sphrender.shaders').joinpath('sph.cl'));"
        "print(importlib.resources.files('sphrender.configs').joinpath('demo.toml'))"
    )
    result = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if result.returncode != 0:
        raise SystemExit(f"the copied tree does not import:\n{result.stderr}")
    for line in result.stdout.split():
        resolved = Path(line).resolve()
        if not resolved.is_relative_to(tree.resolve()):
            raise SystemExit(f"the copy is not what runs: {line} resolves outside {tree}")


def run_pytest(
    tree: Path, env: dict[str, str], tests: Sequence[str], *, stop_first: bool
) -> tuple[int, float, str]:
    """(exit status, seconds, the first failed test or the last lines of output); status -1 =
    timed out."""
    command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--no-header"]
    command += ["-x"] if stop_first else []
    start = time.monotonic()
    try:
        result = subprocess.run(
            [*command, *tests],
            cwd=tree,
            env=env,
            capture_output=True,
            text=True,
            timeout=TIMEOUT_S,
            check=False,
        )
    except subprocess.TimeoutExpired:
        return -1, time.monotonic() - start, "timed out"
    lines = (result.stdout + result.stderr).strip().splitlines()
    failed = [line.split(" ", 1)[1] for line in lines if line.startswith(("FAILED ", "ERROR "))]
    detail = failed[0] if failed else "\n".join(lines[-6:])
    return result.returncode, time.monotonic() - start, detail


@contextmanager
def planted(tree: Path, mutation: Mutation) -> Iterator[None]:
    path = tree / mutation.path
    original = path.read_bytes()
    text = original.decode("utf-8")
    if text.count(mutation.old) != 1:
        raise SystemExit(f"{mutation.name}: old text not found exactly once in {mutation.path}")
    path.write_bytes(text.replace(mutation.old, mutation.new, 1).encode("utf-8"))
    try:
        yield
    finally:
        path.write_bytes(original)
        if path.read_bytes() != original:
            raise SystemExit(f"could not restore {path}")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--list", action="store_true", help="print the table and exit")
    parser.add_argument("-k", dest="select", help="only mutations whose name contains this")
    parser.add_argument(
        "--skip-baseline", action="store_true", help="do not run the tests unmutated first"
    )
    args = parser.parse_args(argv)
    mutations = [m for m in MUTATIONS if not args.select or args.select in m.name]
    problems = check_table(MUTATIONS, REPO)
    if problems:
        print("The mutation table does not match the tree:", *problems, sep="\n  ")
        return 2
    if args.list:
        for m in mutations:
            print(f"{m.name}\n  {m.path}: {m.description}\n  guarded by: {', '.join(m.tests)}")
        return 0
    if not mutations:
        print("no mutation selected")
        return 2
    with copied_tree() as (tree, env):
        if not args.skip_baseline:
            union = list(dict.fromkeys(t for m in mutations for t in m.tests))
            status, seconds, tail = run_pytest(tree, env, union, stop_first=False)
            print(f"baseline: {len(union)} tests unmutated, exit {status} in {seconds:.0f} s")
            if status != 0:
                print(tail)
                print("the named tests must pass on the unmutated tree; stopping")
                return 2
        rows: list[tuple[Mutation, str, float, str]] = []
        for m in mutations:
            with planted(tree, m):
                status, seconds, detail = run_pytest(tree, env, m.tests, stop_first=True)
            outcome = {0: "SURVIVED", 1: "caught"}.get(status, f"ERROR (exit {status})")
            by = detail.split(" - ", 1)[0].split("::", 1)[-1] if status == 1 else ""
            rows.append((m, outcome, seconds, by))
            print(f"{outcome:>16}  {m.name}  ({seconds:.0f} s)  {by}", flush=True)
            if status not in (0, 1):
                print(detail)
    caught = sum(outcome == "caught" for _, outcome, _, _ in rows)
    errors = [m.name for m, outcome, _, _ in rows if outcome.startswith("ERROR")]
    print()
    print("| mutation | file | outcome | first failing test | seconds |\n|---|---|---|---|---|")
    for m, outcome, seconds, by in rows:
        print(f"| {m.name} | {m.path} | {outcome} | {by} | {seconds:.0f} |")
    score = caught / len(rows)
    print(f"\nscore: {caught} / {len(rows)} caught = {score:.0%} (target {TARGET_SCORE:.0%})")
    if errors:
        print("errors (not counted as caught):", ", ".join(errors))
        return 2
    return 0 if score >= TARGET_SCORE else 1


if __name__ == "__main__":
    sys.exit(main())
