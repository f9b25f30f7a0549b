"""The scene's surface-quality sections: `[quality]` (depth smoothing, anti-aliasing, droplets,
rims) and `[sph]` (the OpenCL SPH quantities). Part of the scene schema (`schema.py` re-exports
them): every field typed and documented here. Each doc says what the field does and which quality
presets (`configs/quality-*.toml`) set it, or when a user would change it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from sphrender.server.scene.fields import (
    MAX_DENSITY,
    MAX_LENGTH,
    MIN_DENSITY,
    MIN_LENGTH,
    bench_spec,
    spec,
)

FilterName = Literal["narrow_range", "bilateral", "gaussian", "none"]
QualityPreset = Literal["fast", "balanced", "best"]


@dataclass(frozen=True)
class QualityConfig:
    """Depth smoothing, anti-aliasing and the speed/error trade-offs of the surface."""

    preset: QualityPreset = spec(
        "balanced",
        "speed/error preset the scene's own keys are laid over (they win): fast, balanced (the "
        "built-in defaults) or best, i.e. [quality], [shading], [sph] of "
        "configs/quality-NAME.toml. No preset sets it; pick one here as with the CLI's --quality",
    )
    filter: FilterName = spec(
        "narrow_range",
        "depth smoothing filter: narrow_range (Truong & Yuksel 2018; a plane in perspective stays "
        "a plane), bilateral (thesis eq 22-24), gaussian (thesis eq 17-21) or none. "
        "Presets: narrow_range in all",
    )
    separable: bool = spec(
        True,
        "filter rows then columns (1-D kernels) instead of one 2-D kernel. Presets: true in all",
    )
    iterations: int = spec(
        2,
        "how many times the whole filter is applied; more smooths more, at proportional cost. "
        "Presets: fast 1, balanced 2, best 3",
        low=1,
        high=16,
    )
    last_pass_sigma: float = spec(
        0.7,
        "separable, iterations >= 2: the last pass along the axis filtered last smooths with "
        "sigma x this, the first with sigma x sqrt(2 - this^2) (same total); less leaves fewer "
        "streaks near rims. 1: equal passes. Presets: fast 1, balanced 0.7, best 0.5",
        low=0.0,
        high=1.0,
        low_open=True,
        unit="fraction of the kernel's sigma",
    )
    destreak: float = spec(
        0.0,
        "separable: one more 1-D pass across the axis filtered last, sigma = destreak x the "
        "kernel's; takes the streaks the last pass leaves along rims on close-ups. 0: off. "
        "Presets: fast 0, balanced 0, best 0.25",
        low=0.0,
        high=1.0,
        unit="fraction of the kernel's sigma",
    )
    kernel_size: Literal["projected_radius", "depth_falloff"] = spec(
        "projected_radius",
        "how the kernel follows depth: projected_radius (sigma = kernel_scale projected particle "
        "radii) or depth_falloff (falloff_sigma_px, shrinking past falloff_depth; thesis eq 25). "
        "No preset sets it; depth_falloff gives the thesis's fixed-pixel kernel",
    )
    kernel_scale: float = spec(
        2.0,
        "Gaussian sigma in projected particle radii (the kernel reaches 3 sigma); more smooths "
        "more. Presets: 2 in all",
        low=0.0,
        high=16.0,
        low_open=True,
        unit="projected particle radii",
    )
    kernel_max_px: int = spec(
        64,
        "the kernel takes every pixel out to this radius, past it only spread taps "
        "(kernel_max_stride); below 3 kernel_scale projected radii close-ups keep per-particle "
        "ripple. Presets: fast 32, balanced 64, best 96",
        low=1,
        high=128,
        unit="px",
    )
    kernel_max_stride: int = spec(
        3,
        "separable, close-ups: past kernel_max_px the kernel goes on with every stride-th pixel "
        "(stride up to this), keeping its sigma out to kernel_max_px x stride. 1: a hard cap. "
        "Presets: fast 1, balanced 3, best 2",
        low=1,
        high=4,
    )
    kernel_min_px: int = spec(
        1,
        "smallest kernel radius (thesis eq 25's ks_min). No preset sets it; raise it to smooth "
        "far, small particles more",
        low=0,
        high=64,
        unit="px",
    )
    falloff_sigma_px: float = spec(
        6.0,
        "kernel_size = depth_falloff: sigma up to falloff_depth (thesis eq 25). No preset sets "
        "it; set it with depth_falloff",
        low=0.0,
        low_open=True,
        unit="px",
    )
    falloff_depth: float = spec(
        1.0,
        "kernel_size = depth_falloff: eye depth beyond which the kernel shrinks (thesis eq 25's "
        "threshold). No preset sets it; set it with depth_falloff",
        low=0.0,
        unit="scene units",
    )
    falloff_rate: float = spec(
        2.0,
        "kernel_size = depth_falloff: kernel radius lost per scene unit beyond falloff_depth "
        "(thesis eq 25's k). No preset sets it; set it with depth_falloff",
        low=0.0,
        unit="px per scene unit",
    )
    bilateral_depth_sigma: float = spec(
        6.0,
        "filter = bilateral: range sigma (thesis eq 24); smaller keeps the per-particle bumps. "
        "No preset sets it; tune it with the bilateral filter",
        low=0.0,
        low_open=True,
        unit="particle radii",
    )
    narrow_range_threshold: float = spec(
        10.0,
        "narrow_range lambda: samples more than lambda r behind the accepted range are dropped "
        "with their mirror, those in front clamped (narrow_range_clamp); 10 is the published "
        "value. No preset sets it; lower keeps small blobs apart from a surface behind them",
        low=0.0,
        low_open=True,
        unit="particle radii",
    )
    narrow_range_clamp: float = spec(
        1.0,
        "narrow_range mu: nearer samples are clamped to z - mu r. No preset sets it; the "
        "published value, rarely changed",
        low=0.0,
        low_open=True,
        unit="particle radii",
    )
    narrow_range_pairs: float = spec(
        4.0,
        "separable narrow_range, from the second pass on: a mirrored tap pair whose midpoint "
        "(inverse depth) departs from the centre by more than this is dropped, so small blobs "
        "keep their depth in front of a surface. 0: off. Presets: fast 0, balanced 4, best 4",
        low=0.0,
        unit="particle radii",
    )
    crease_angle: float = spec(
        0.0,
        "separable narrow_range: a kernel stops where the surface turns by more than this over "
        "a projected radius of taps, keeping faces flat up to an edge; 0: off. No preset sets "
        "it; about 30 for box-like fluid bodies or fluid in a container (streaks rippled beads)",
        low=0.0,
        high=90.0,
        unit="degrees",
    )
    normal_guide: float = spec(
        8.0,
        "separable narrow_range: a kernel stops at a convex edge where a smoothed copy of the "
        "surface turns by more than this between two flat faces (boxes, plates, fluid against a "
        "wall keep their edges); 0: off. Presets: fast 0, balanced 8, best 8",
        low=0.0,
        high=90.0,
        unit="degrees",
    )
    normal_stencil: float = spec(
        1.0,
        "normals from a central difference over +-this many projected radii (1 px to "
        "normal_stencil_max_px) where it stays on one surface, else a 1-pixel difference; "
        "averages ripple that would flicker. 0: 1-pixel only. Presets: fast 0, balanced 1, best 1",
        low=0.0,
        high=4.0,
    )
    normal_stencil_max_px: int = spec(
        2,
        "cap on normal_stencil's half-width: small droplets want a narrow stencil, a rippled "
        "bulk a wide one. Presets: balanced 2, best 2",
        low=1,
        high=16,
        unit="px",
    )
    normal_rules: Literal["smooth", "hard"] = bench_spec(
        "smooth",
        "how the normals pass picks between its differences: smooth weights, or the hard "
        "switches of the benchmark's baseline",
    )
    antialias: bool = spec(
        True,
        "silhouette anti-aliasing: an edge pixel's alpha is its analytic sub-pixel coverage and "
        "pixels just outside a silhouette show the surface next to them; off: alpha 1 where a "
        "pixel centre hits. Presets: fast off, balanced and best on",
    )
    exact_droplets: bool = spec(
        True,
        "droplets (density below droplet_density x sph.rest_density) are drawn as exact spheres "
        "over the smoothed surface instead of being smoothed into it; needs densities "
        "(droplet_densities, droplet_density_pass). Presets: fast off, balanced and best on",
    )
    droplet_densities: Literal["frame", "computed"] = spec(
        "frame",
        "which densities exact_droplets reads: the frame's, or computed from its positions "
        "(OpenCL). No preset sets it; computed when the simulator's densities count what the "
        "frame lacks (walls)",
    )
    droplet_density_pass: bool = spec(
        False,
        "exact_droplets on frames without densities: compute each particle's density from the "
        "positions (OpenCL); off: such frames get no droplet split. Presets: best on, fast and "
        "balanced off",
    )
    droplet_density: float = spec(
        0.45,
        "exact_droplets: density below which a particle is a droplet (cubic spline, support "
        "4 r: a lone particle 0.32, a pair 0.40, a filament 0.48). No preset sets it; raise it "
        "to draw thin filaments as droplets",
        low=0.0,
        high=1.0,
        unit="fraction of sph.rest_density",
    )
    droplet_lone_density: float = spec(
        0.36,
        "exact_droplets on frames with densities: a particle whose density from the positions "
        "(OpenCL) is below this is a droplet whatever the frame says (a lone particle 0.32, a "
        "touching pair 0.40). 0: off. Presets: fast 0, balanced 0.36, best 0.36",
        low=0.0,
        high=1.0,
        unit="fraction of sph.rest_density",
    )
    close_gaps: float = spec(
        2.0,
        "close the gaps a sparse sheet or spray leaves between its particles: an enclosed pixel "
        "whose neighbours lie at most this far apart takes their interpolated depth, before "
        "and (pinholes) after the smoothing. 0: off. Presets: fast 0, balanced 2, best 2",
        low=0.0,
        high=8.0,
        unit="particle radii",
    )
    silhouette_normals: float = spec(
        0.0,
        "turn the normals within this many projected radii of a silhouette towards its outward "
        "direction, from coverage moments; removes a beaded rim's sideways flips. 0: off. No "
        "preset sets it; an alternative to field_normals on rims",
        low=0.0,
        high=8.0,
        unit="particle radii",
    )
    field_normals: float = spec(
        2.0,
        "normals within this many projected radii (at most 5 px) of a rim come from the "
        "particles' smoothed field (-grad phi), blended by the distance to the rim: smooth rims, "
        "round droplets. 0: off. Presets: fast 0, balanced 2, best 2",
        low=0.0,
        high=8.0,
        unit="particle radii",
    )
    field_normals_support: float = spec(
        5.0,
        "field_normals: the field's cubic-spline support; more smooths a rim's beads more, less "
        "keeps lone droplets from leaning towards a pool. No preset sets it; lower it for spray "
        "near a pool",
        low=1.0,
        high=16.0,
        unit="particle radii",
    )
    occlusion_culling: bool = bench_spec(
        True,
        "splat the front layer first and skip the particles hidden behind it (the depth image "
        "is unchanged); off measures what it saves",
    )


@dataclass(frozen=True)
class SphConfig:
    """SPH quantities computed on OpenCL (thesis section 3.3.4). The pass runs only when a
    feature below asks for it; kernel, support and mass are pinned so results compare with
    other SPH tools (cubic spline, support 4 r, m = rest_density (2 r)^3, as splashsurf)."""

    rest_density: float = spec(
        1000.0,
        "rest density rho_0 in the frames' density units (water 1000, molten steel ~7000 "
        "kg/m^3); frames whose densities peak outside 0.5-1.5 rho_0 get densities from their "
        "positions, with a note. No preset sets it; set it to your fluid's",
        low=MIN_DENSITY,
        high=MAX_DENSITY,
        unit="mass per scene unit^3",
    )
    support_radius: float | None = spec(
        None,
        "kernel support h (W = 0 beyond); absent = 4 x particles.radius. No preset sets it; set "
        "it to your simulator's h",
        low=MIN_LENGTH,
        high=MAX_LENGTH,
        unit="scene units",
    )
    mass: float | None = spec(
        None,
        "particle mass; absent = rest_density (2 particles.radius)^3. No preset sets it; set it "
        "to your simulator's mass",
        low=0.0,
        low_open=True,
        unit="mass units",
    )
    surface_threshold: float = spec(
        0.5,
        "a particle is on the surface where |n| > this / support_radius (thesis eq 28, "
        "corrected; |n| h is about 1 on a flat surface, 0 inside). No preset sets it; lower it "
        "to mark more particles as surface",
        low=0.0,
        low_open=True,
        unit="1 / support_radius",
    )
    adaptive_radius: bool = spec(
        False,
        "particles less dense than the surface average shrink toward min_radius (thesis eq 29); "
        "thins splashes and droplets. No preset sets it; turn it on for spray",
    )
    min_radius: float = spec(
        0.5,
        "adaptive_radius: the smallest radius (thesis eq 29's r_min). No preset sets it; set it "
        "with adaptive_radius",
        low=0.0,
        high=1.0,
        low_open=True,
        unit="fraction of the particle radius",
    )
    radius_decline: float = spec(
        0.25,
        "adaptive_radius: r = r_body (1 - ((d_surface - d) / d_surface)^2 / radius_decline), "
        "thesis eq 29's k made dimensionless; smaller shrinks faster. No preset sets it; set it "
        "with adaptive_radius",
        low=0.0,
        low_open=True,
    )
    surface_only: bool = spec(
        False,
        "splat only surface particles, sparse ones and a safety layer; hidden interior "
        "particles are skipped (faster for large bodies). Presets: off in all",
    )
    safety_layer: float = spec(
        0.9,
        "surface_only: also splat particles within this many support radii of a surface or "
        "sparse particle (0.9 reaches all lattice neighbours; less opens holes). No preset sets "
        "it; raise it if holes appear",
        low=0.0,
        high=1.0,
        unit="support radii",
    )
    sparse_density: float = spec(
        0.75,
        "surface_only: a particle whose density from the positions is below this is sparse "
        "(droplet, thin sheet) and always splatted. No preset sets it; raise it if thin sheets "
        "lose particles",
        low=0.0,
        high=1.0,
        unit="fraction of sph.rest_density",
    )
    anisotropy: bool = spec(
        False,
        "anisotropic particles (Yu & Turk 2013): ellipsoids of each sphere's volume along its "
        "neighbourhood's principal axes; particles with few neighbours stay spheres. No preset "
        "sets it; turn it on for flatter sheets and less flicker",
    )
    anisotropy_radius: float = spec(
        1.5,
        "anisotropy: neighbourhood radius R (weights 1 - (d/R)^3); 1.5 = 6 r. No preset sets "
        "it; lower it for thinner features, at or above 1.0 to keep enough neighbours",
        low=0.25,
        high=4.0,
        unit="support radii",
    )
    anisotropy_max_ratio: float = spec(
        4.0,
        "anisotropy: k_r, largest ratio of an ellipsoid's longest to shortest axis. No preset "
        "sets it; lower it for rounder particles",
        low=1.0,
        high=32.0,
    )
    anisotropy_min_neighbours: int = spec(
        25,
        "anisotropy: N_eps, particles with fewer neighbours within R stay spheres; shape ramps "
        "in over N_eps / 2 more, so it changes continuously between frames. No preset sets it; "
        "set it with anisotropy",
        low=1,
        high=10000,
        unit="particles",
    )
    anisotropy_smoothing: float = spec(
        0.5,
        "anisotropy: lambda, centres move to (1 - lambda) x + lambda (neighbourhood mean); Yu & "
        "Turk use 0.9-1, which pulls the surface inwards. No preset sets it; set it with "
        "anisotropy",
        low=0.0,
        high=1.0,
    )
