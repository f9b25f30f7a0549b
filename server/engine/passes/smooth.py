"""Smooth pass: the splatted eye depth, filtered into a smooth surface.

Filters (`[quality] filter`): gaussian | bilateral | narrow_range (Truong & Yuksel 2018), iterated.
Kernel sigma = kernel_scale x the projected particle radius (or depth_falloff, eq 25), reach
3 sigma: every pixel out to kernel_max_px, then (separable filters, close-ups) every stride-th
out to kernel_max_px x kernel_max_stride; past that, capped. Separable filters (x y, then y x
on the next iteration, so the nonlinear filters' streaks do not pile up on one axis; the last
pass along the last axis lighter, `last_pass_sigma`, and optionally one light pass across it,
`destreak`: `separable_passes`) run on a packed copy of the image, four pixels of a row per
RGBA32F texel: pack, the 1-D passes, unpack; one fetch serves four pixels.

The narrow range averages inverse depth. Where a kernel reaches past the image's end it goes on
one-sided and fits a line through the taps inside; a 1-D pass draws that variant (IMAGE_BORDER)
only over the strips within kernel_max_px of the ends (`_axis_draws`). After the filter, the
gap pass closes the pinholes left (`GapPass.close_again`). With `normal_guide` the separable
narrow range's kernels stop at convex edges between flat faces: a smoothed pilot at
1 / GUIDE_SCALE of the image gives each pixel one-sided limits per axis, kept only on crease
lines (`SmoothPass._guide`, `shaders/smooth/guide_*.frag.glsl`).

Shaders: `shaders/smooth/smooth_depth_separable.frag.glsl` (1-D, packed; taps walked by
`common/packed_taps.glsl`; `smooth/image_border_taps.glsl` its variant at the image's ends),
`shaders/smooth/smooth_depth.frag.glsl` (2-D), `common/image_pack`
and `common/image_unpack`; uniforms shared by both in `common/depth_filter_params.glsl`.
Owns: two plain ping-pong targets and two packed ones, per image size, and the guide's seven
packed targets at its reduced size.
"""

from __future__ import annotations

import math

import moderngl

from sphrender.server.engine.geometry.screen_box import (
    ScreenBox,
    intersect,
    packed_border_split,
    packed_box,
)
from sphrender.server.engine.gpu.draw import PerSize, Target, clear_and_scissor, set_scissor
from sphrender.server.engine.gpu.uniforms import set_group, set_if_used
from sphrender.server.engine.passes.context import FULLSCREEN_VERT, PassContext
from sphrender.server.engine.passes.gaps import GapPass
from sphrender.server.scene import QualityConfig

SEPARABLE_SHADER = "smooth/smooth_depth_separable.frag.glsl"
TWO_D_SHADER = "smooth/smooth_depth.frag.glsl"
GUIDE_NORMALS_SHADER = "smooth/guide_normals.frag.glsl"
GUIDE_FLAT_SHADER = "smooth/guide_flat.frag.glsl"
GUIDE_LIMITS_SHADER = "smooth/guide_limits.frag.glsl"
GUIDE_DOWNSAMPLE_SHADER = "smooth/guide_downsample.frag.glsl"
GUIDE_RUNS_SHADER = "smooth/guide_runs.frag.glsl"
PACK_SHADER = "common/image_pack.frag.glsl"
UNPACK_SHADER = "common/image_unpack.frag.glsl"
_FILTER_DEFINES = {"gaussian": 0, "bilateral": 1, "narrow_range": 2}
_KERNEL_SIZE_DEFINES = {"projected_radius": 0, "depth_falloff": 1}

# The normal guide's rule (quality.normal_guide; SmoothPass._guide):
#: The pilot's Gaussian sigma over the splat's depth, in projected particle radii.
GUIDE_PILOT_RADII = 1.7
#: The cut's ramp: turn (degrees) past quality.normal_guide from no cut to a whole one.
GUIDE_WIDTH_DEG = 12.0
#: The turn of a sphere of this many particle radii over the distance to a tap is tolerated.
GUIDE_TURN_RADII = 11.0
#: Only convex turns are cut: the chord's angle (degrees, over the turn) behind the centre's
#: pilot tangent plane where the cut begins; whole at twice it.
GUIDE_CONVEX_DEG = 8.0
#: No cut at pixels with background within this many projected radii (a one-sided pilot).
GUIDE_RIM_RADII = 3.0
#: A tap is cut only where the pilot normals at 1, 2, 3 times this many projected radii past
#: it (away from the centre), and as far behind the centre, agree: flat faces on both sides.
GUIDE_FLAT_RADII = 2.5
#: ... within this angle, degrees.
GUIDE_FLAT_DEG = 24.0
#: A one-sided limit lies where the cut (0..1), linear between taps, first reaches this.
GUIDE_LIMIT_CUT = 0.5
#: The pilot, its normals, flags and limits at 1 / this of the image's size along each axis.
GUIDE_SCALE = 4
#: A limit is kept only on a crease line at least this many reduced pixels long, stepping at
#: most GUIDE_RUN_SHIFT reduced pixels along the pass between neighbouring lines.
GUIDE_RUN = 10
GUIDE_RUN_SHIFT = 2


class _SmoothTargets:
    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.size = size
        self.ping = [Target.float(ctx, size, 1) for _ in range(2)]
        packed_size = ((size[0] + 3) // 4, size[1])
        self.packed = [Target.float(ctx, packed_size, 4) for _ in range(2)]

    def release(self) -> None:
        for target in (*self.ping, *self.packed):
            target.release()


class _GuideTargets:
    """quality.normal_guide's seven packed targets at the guide's reduced size: the pilot's
    two passes (then its normals), the flagged normals and the limits of each axis, and the
    reduced splat."""

    def __init__(self, ctx: moderngl.Context, size: tuple[int, int]) -> None:
        self.packed = [Target.float(ctx, ((size[0] + 3) // 4, size[1]), 4) for _ in range(7)]

    def release(self) -> None:
        for target in self.packed:
            target.release()


class SmoothPass:
    def __init__(self, context: PassContext) -> None:
        self._context = context
        self._targets = PerSize(lambda size: _SmoothTargets(context.gl.ctx, size))
        # quality.normal_guide: its packed targets, per image size
        self._guide_targets = PerSize(lambda size: _GuideTargets(context.gl.ctx, size))
        self._gaps = GapPass(context)  # quality.close_gaps, before the filter (passes/gaps.py)

    def run(
        self,
        depth: moderngl.Texture,
        *,
        px_per_unit: float,
        particle_radius: float,
        quality: QualityConfig,
        box: ScreenBox | None = None,
        temperature: moderngl.Texture | None = None,
    ) -> moderngl.Texture:
        """Smooth the eye-depth image `depth`, its gaps closed first (`quality.close_gaps`)
        and the pinholes left after it (GapPass.close_again); returns the texture holding the
        result (`depth` itself for ``filter = "none"`` and no
        gaps to close; the splat's kelvin `temperature` is filled alike, in place).
        `px_per_unit`: pixels per scene unit at eye depth 1.
        With a `box` (see `screen_box`) the passes run only inside it, on targets cleared
        outside it."""
        depth = self._gaps.run(
            depth,
            px_per_unit=px_per_unit,
            particle_radius=particle_radius,
            gap_radii=quality.close_gaps,
            box=box,
            temperature=temperature,
        )
        if quality.filter == "none":
            return depth
        targets = self._targets.get(depth.size)
        defines = {
            "FILTER": _FILTER_DEFINES[quality.filter],
            "KERNEL_SIZE": _KERNEL_SIZE_DEFINES[quality.kernel_size],
        }
        uniforms = _FilterUniforms(px_per_unit, particle_radius, quality)
        if quality.separable:
            margin_px = max(quality.kernel_max_px, quality.kernel_min_px)
            smoothed = self._separable(targets, depth, defines, uniforms, quality, box, margin_px)
        else:
            smoothed = self._two_d(targets, depth, defines, uniforms, quality.iterations, box)
        if quality.close_gaps > 0.0:  # pinholes (GapPass.close_again)
            return self._gaps.close_again(smoothed, temperature)
        return smoothed

    def _two_d(
        self,
        targets: _SmoothTargets,
        depth: moderngl.Texture,
        defines: dict[str, int],
        uniforms: _FilterUniforms,
        iterations: int,
        box: ScreenBox | None,
    ) -> moderngl.Texture:
        program = self._context.programs.get(FULLSCREEN_VERT, TWO_D_SHADER, defines, {"u_depth": 0})
        uniforms.set(program)
        for target in targets.ping:
            clear_and_scissor(target.fbo, box)
        source = depth
        write_index = 0
        for _ in range(iterations):
            source.use(0)
            targets.ping[write_index].fbo.use()
            self._context.fullscreen.draw(program)
            source = targets.ping[write_index].texture
            write_index = 1 - write_index
        for target in targets.ping:
            set_scissor(target.fbo, None)
        return source

    def _separable(
        self,
        targets: _SmoothTargets,
        depth: moderngl.Texture,
        defines: dict[str, int],
        uniforms: _FilterUniforms,
        quality: QualityConfig,
        box: ScreenBox | None,
        margin_px: int,
    ) -> moderngl.Texture:
        programs, draw = self._context.programs, self._context.fullscreen.draw
        packed = targets.packed
        packed_scissor = None if box is None else packed_box(box)
        for target in packed:
            clear_and_scissor(target.fbo, packed_scissor)
        pack = programs.get(FULLSCREEN_VERT, PACK_SHADER, samplers={"u_image": 0})
        depth.use(0)
        packed[0].fbo.use()
        draw(pack)
        defines = {**defines, "CREASE_TEST": int(quality.crease_angle > 0.0)}
        samplers = None
        passes = separable_passes(quality.iterations, quality.last_pass_sigma, quality.destreak)
        if quality.normal_guide > 0.0 and quality.filter == "narrow_range":
            reach_scale = max(scale for _, scale in passes)
            guide = self._guide(depth, uniforms, quality, margin_px, reach_scale)
            defines["NORMAL_GUIDE"] = 1
            defines["GUIDE_SCALE"] = GUIDE_SCALE
            samplers = {"u_packed_depth": 0, "u_guide_limits": 1}
        draws = {
            axis: self._axis_draws(
                defines, uniforms, axis, depth.size, packed_scissor, margin_px, samplers
            )
            for axis in (0, 1)
        }
        read_index = 0
        pair_limits = pair_limits_per_pass(len(passes), quality, uniforms.particle_radius)
        crease_limits = crease_limits_per_pass(len(passes), quality)
        for (axis, sigma_scale), pair_limit, crease_limit in zip(
            passes, pair_limits, crease_limits, strict=True
        ):
            packed[read_index].texture.use(0)
            if samplers is not None:
                guide[axis].use(1)
            fbo = packed[1 - read_index].fbo
            for program, scissor in draws[axis]:
                set_if_used(program, "u_sigma_scale", sigma_scale)
                set_if_used(program, "u_nr_pair_limit", pair_limit)
                set_if_used(program, "u_crease_limit", crease_limit)
                set_scissor(fbo, scissor)
                fbo.use()
                draw(program)
            read_index = 1 - read_index
        for target in packed:
            set_scissor(target.fbo, None)
        unpack = programs.get(FULLSCREEN_VERT, UNPACK_SHADER, samplers={"u_packed": 0})
        packed[read_index].texture.use(0)
        result = targets.ping[0]
        clear_and_scissor(result.fbo, box)
        result.fbo.use()
        draw(unpack)
        set_scissor(result.fbo, None)
        return result.texture

    def _guide(
        self,
        depth: moderngl.Texture,
        uniforms: _FilterUniforms,
        quality: QualityConfig,
        margin_px: int,
        reach_scale: float,
    ) -> dict[int, moderngl.Texture]:
        """quality.normal_guide's one-sided limits for the passes along each axis, all at
        1 / GUIDE_SCALE of the image's size: the pilot and its normals (`_guide_pilot`),
        flagged where the pilot is flat past a pixel (`_guide_flags`), the rule's limits
        (`_guide_limits`), those kept on crease lines (`crease_runs`)."""
        full = depth.size
        size = (
            (full[0] + GUIDE_SCALE - 1) // GUIDE_SCALE,
            (full[1] + GUIDE_SCALE - 1) // GUIDE_SCALE,
        )
        uniforms = _FilterUniforms(
            uniforms.px_per_unit / GUIDE_SCALE, uniforms.particle_radius, quality
        )
        targets = self._guide_targets.get(size).packed
        for target in targets:
            clear_and_scissor(target.fbo, None)
        pilot, normals = self._guide_pilot(depth, targets, size, uniforms, quality, margin_px)
        flagged = self._guide_flags(pilot, normals, targets[2:4], size, uniforms)
        limits = self._guide_limits(
            pilot, flagged, targets[4:6], size, uniforms, quality, reach_scale
        )
        return self.crease_runs(limits, size)

    def crease_runs(
        self, limits: dict[int, moderngl.Texture], size: tuple[int, int]
    ) -> dict[int, moderngl.Texture]:
        """Per axis, the one-sided `limits` (packed, at the guide's reduced `size`) kept only
        on crease lines of at least GUIDE_RUN reduced pixels (guide_runs.frag.glsl), drawn into
        the guide's flag targets (free once the limits are found)."""
        draw = self._context.fullscreen.draw
        targets = self._guide_targets.get(size).packed[2:4]
        result = {}
        for axis, target in zip((0, 1), targets, strict=True):
            runs = self._context.programs.get(
                FULLSCREEN_VERT, GUIDE_RUNS_SHADER, {"AXIS": axis}, {"u_guide_limits": 0}
            )
            set_if_used(runs, "u_image_size_px", size)
            set_if_used(runs, "u_run", GUIDE_RUN)
            set_if_used(runs, "u_shift", GUIDE_RUN_SHIFT)
            limits[axis].use(0)
            target.fbo.use()
            draw(runs)
            result[axis] = target.texture
        return result

    def _guide_pilot(
        self,
        depth: moderngl.Texture,
        targets: list[Target],
        size: tuple[int, int],
        uniforms: _FilterUniforms,
        quality: QualityConfig,
        margin_px: int,
    ) -> tuple[moderngl.Texture, moderngl.Texture]:
        """The pilot (the splat `depth` reduced by guide_downsample.frag.glsl, then a Gaussian
        of sigma GUIDE_PILOT_RADII projected radii, rows then columns, background excluded) and
        its view-space normals, packed and encoded (guide_normals.frag.glsl)."""
        programs, draw = self._context.programs, self._context.fullscreen.draw
        downsample = programs.get(
            FULLSCREEN_VERT, GUIDE_DOWNSAMPLE_SHADER, {"SCALE": GUIDE_SCALE}, {"u_image": 0}
        )
        depth.use(0)
        targets[6].fbo.use()
        draw(downsample)
        defines = {"FILTER": _FILTER_DEFINES["gaussian"], "KERNEL_SIZE": 0}
        sigma_scale = GUIDE_PILOT_RADII / quality.kernel_scale
        source = targets[6].texture
        for axis, target in zip((0, 1), targets[:2], strict=True):
            source.use(0)
            for program, scissor in self._axis_draws(
                defines, uniforms, axis, size, None, margin_px
            ):
                set_if_used(program, "u_sigma_scale", sigma_scale)
                set_scissor(target.fbo, scissor)
                target.fbo.use()
                draw(program)
            set_scissor(target.fbo, None)
            source = target.texture
        normals = self._guide_program(
            GUIDE_NORMALS_SHADER, {}, {"u_packed_depth": 0}, size, uniforms
        )
        set_if_used(normals, "u_rim_radii", GUIDE_RIM_RADII)
        source.use(0)
        targets[0].fbo.use()
        draw(normals)
        return source, targets[0].texture

    def _guide_flags(
        self,
        pilot: moderngl.Texture,
        normals: moderngl.Texture,
        targets: list[Target],
        size: tuple[int, int],
        uniforms: _FilterUniforms,
    ) -> dict[int, moderngl.Texture]:
        """Per axis, the pilot's normals flagged where the pilot is flat past each pixel along
        +AXIS and along -AXIS (guide_flat.frag.glsl)."""
        draw = self._context.fullscreen.draw
        samplers = {"u_guide_normals": 0, "u_packed_depth": 1}
        flagged = {}
        normals.use(0)
        pilot.use(1)
        for axis, target in zip((0, 1), targets, strict=True):
            flat = self._guide_program(GUIDE_FLAT_SHADER, {"AXIS": axis}, samplers, size, uniforms)
            set_if_used(flat, "u_flat_radii", GUIDE_FLAT_RADII)
            set_if_used(flat, "u_flat_cos", math.cos(math.radians(GUIDE_FLAT_DEG)))
            target.fbo.use()
            draw(flat)
            flagged[axis] = target.texture
        return flagged

    def _guide_limits(
        self,
        pilot: moderngl.Texture,
        flagged: dict[int, moderngl.Texture],
        targets: list[Target],
        size: tuple[int, int],
        uniforms: _FilterUniforms,
        quality: QualityConfig,
        reach_scale: float,
    ) -> dict[int, moderngl.Texture]:
        """Per axis, the rule's one-sided limits out to `reach_scale` times the kernel's reach
        (guide_limits.frag.glsl)."""
        draw = self._context.fullscreen.draw
        samplers = {"u_guide_normals": 0, "u_packed_depth": 1}
        result = {}
        pilot.use(1)
        for axis, target in zip((0, 1), targets, strict=True):
            flagged[axis].use(0)
            limits = self._guide_program(
                GUIDE_LIMITS_SHADER, {"AXIS": axis}, samplers, size, uniforms
            )
            _set_guide_uniforms(limits, quality, uniforms.particle_radius)
            set_if_used(limits, "u_reach_radii", 3.0 * quality.kernel_scale * reach_scale)
            set_if_used(limits, "u_reach_max_px", quality.kernel_max_px // GUIDE_SCALE)
            set_if_used(limits, "u_limit_cut", GUIDE_LIMIT_CUT)
            target.fbo.use()
            draw(limits)
            result[axis] = target.texture
        return result

    def _guide_program(
        self,
        shader: str,
        defines: dict[str, int],
        samplers: dict[str, int],
        size: tuple[int, int],
        uniforms: _FilterUniforms,
    ) -> moderngl.Program:
        """A guide pass's program with the reduced image's size, scale and particle radius set."""
        program = self._context.programs.get(FULLSCREEN_VERT, shader, defines, samplers)
        set_if_used(program, "u_image_size_px", size)
        set_if_used(program, "u_px_per_unit", uniforms.px_per_unit)
        set_if_used(program, "u_particle_radius", uniforms.particle_radius)
        return program

    def _axis_draws(
        self,
        defines: dict[str, int],
        uniforms: _FilterUniforms,
        axis: int,
        image_px: tuple[int, int],
        scissor: ScreenBox | None,
        margin_px: int,
        samplers: dict[str, int] | None = None,
    ) -> list[tuple[moderngl.Program, ScreenBox | None]]:
        """The draws of one 1-D pass along `axis`, each a program and the packed texels it
        covers (`scissor`: the screen box's, None = all). A kernel goes one-sided past the
        image's ends and fits a line (shaders/smooth/image_border_taps.glsl); that variant
        covers the strips within `margin_px` (the kernel cap) of the ends, the packed walk's
        the rest, so the inside pays nothing for it."""
        programs = self._context.programs

        def program(border: int) -> moderngl.Program:
            variant = {**defines, "AXIS": axis, "IMAGE_BORDER": border}
            chosen = programs.get(
                FULLSCREEN_VERT, SEPARABLE_SHADER, variant, samplers or {"u_packed_depth": 0}
            )
            uniforms.set(chosen)
            set_if_used(chosen, "u_image_size_px", image_px)
            return chosen

        whole = scissor or (0, 0, (image_px[0] + 3) // 4, image_px[1])
        inside, strips = packed_border_split(image_px, axis, margin_px)
        parts = [(0, inside)] if inside is not None else []
        parts += [(1, strip) for strip in strips]
        clipped = [(border, intersect(box, whole)) for border, box in parts]
        return [(program(border), box) for border, box in clipped if box is not None]

    def release(self) -> None:
        self._targets.release()
        self._guide_targets.release()
        self._gaps.release()


def separable_passes(
    iterations: int, last_pass_sigma: float = 1.0, destreak: float = 0.0
) -> list[tuple[int, float]]:
    """The 1-D passes of a separable filter in order: (axis, sigma scale) each.

    The iterations alternate their order (x y, y x, ...): the nonlinear filters leave streaks
    along the axis filtered last, and alternating keeps them from piling up. A kernel is cut
    where its row (column) meets a silhouette, at a place that changes from row to row along a
    beaded rim, so even so the last pass leaves streaks along its axis near silhouettes, of an
    amplitude that grows with its sigma squared. `last_pass_sigma` < 1 shrinks that pass's
    sigma and widens the first pass along the same axis to keep the axis's total variance
    (needs two passes along it); `destreak` > 0 adds one light pass across the last (sigma
    scaled by `destreak`)."""
    passes = [
        (axis, 1.0)
        for iteration in range(iterations)
        for axis in ((0, 1) if iteration % 2 == 0 else (1, 0))
    ]
    last_axis = passes[-1][0]
    along = [i for i, (axis, _) in enumerate(passes) if axis == last_axis]
    if last_pass_sigma < 1.0 and len(along) >= 2:
        passes[along[0]] = (last_axis, math.sqrt(2.0 - last_pass_sigma**2))
        passes[along[-1]] = (last_axis, last_pass_sigma)
    if destreak > 0.0:
        passes.append((1 - last_axis, destreak))
    return passes


#: The pair limit's "off" (scene units): no pair departs this far.
PAIR_TEST_OFF = 3e38


def pair_limits_per_pass(count: int, quality: QualityConfig, particle_radius: float) -> list[float]:
    """quality.narrow_range_pairs per 1-D pass in scene units: off on the first pass, which
    sees the raw splat (its relief between particles, up to a few radii deep where a lattice
    is seen at a grazing angle, would trip the test: spatter flicker 0.65 -> 0.92 deg with it
    on every pass), and everywhere when the setting is 0."""
    limit = quality.narrow_range_pairs * particle_radius
    if limit <= 0.0:
        return [PAIR_TEST_OFF] * count
    return [PAIR_TEST_OFF] + [limit] * (count - 1)


#: The crease limit's "off" on a pass of a program that has the test.
CREASE_TEST_OFF = -1.0


def crease_limits_per_pass(count: int, quality: QualityConfig) -> list[float]:
    """tan(quality.crease_angle) per 1-D pass: off on the first pass, whose raw splat
    turns by tens of degrees between particles over runs longer than a radius where a lattice
    is seen obliquely (a ball's stair-stepped shell would keep its ripple), and everywhere when
    the setting is 0."""
    if quality.crease_angle <= 0.0:
        return [CREASE_TEST_OFF] * count
    return [CREASE_TEST_OFF] + [math.tan(math.radians(quality.crease_angle))] * (count - 1)


def _set_guide_uniforms(program: moderngl.Program, quality: QualityConfig, radius: float) -> None:
    """quality.normal_guide's rule as ramps (guide_limits.frag.glsl cut_at)."""
    low2 = math.radians(quality.normal_guide) ** 2
    high2 = math.radians(quality.normal_guide + GUIDE_WIDTH_DEG) ** 2
    scale = 1.0 / (high2 - low2)
    set_if_used(program, "u_guide_ramp", (scale, -low2 * scale))
    turn = GUIDE_TURN_RADII * radius
    set_if_used(program, "u_guide_turn2", 1.0 / turn**2)
    convex = math.radians(GUIDE_CONVEX_DEG)
    low, high = math.sin(convex), math.sin(2.0 * convex)
    set_if_used(program, "u_guide_convex", (1.0 / (high - low), -low / (high - low)))


class _FilterUniforms:
    """The uniforms of `common/depth_filter_params.glsl`, lengths in particle radii resolved;
    set on a program only when one of their inputs changed."""

    __slots__ = ("_key",)

    def __init__(self, px_per_unit: float, particle_radius: float, quality: QualityConfig) -> None:
        self._key = (px_per_unit, particle_radius, quality)

    @property
    def particle_radius(self) -> float:
        return self._key[1]

    @property
    def px_per_unit(self) -> float:
        return self._key[0]

    def set(self, program: moderngl.Program) -> None:
        # The compiler drops the uniforms a filter never reads; set_if_used skips those.
        set_group(program, "filter", self._key, self.values)

    def values(self) -> dict[str, float]:
        px_per_unit, r, quality = self._key
        return {
            "u_kernel_min_px": quality.kernel_min_px,
            "u_kernel_max_px": quality.kernel_max_px,
            "u_kernel_max_stride": quality.kernel_max_stride,
            "u_particle_radius": r,
            "u_px_per_unit": px_per_unit,
            "u_kernel_scale": quality.kernel_scale,
            "u_falloff_sigma_px": quality.falloff_sigma_px,
            "u_falloff_depth": quality.falloff_depth,
            "u_falloff_rate": quality.falloff_rate,
            "u_range_sigma": quality.bilateral_depth_sigma * r,
            "u_nr_threshold": quality.narrow_range_threshold * r,
            "u_nr_clamp": quality.narrow_range_clamp * r,
        }
