"""The scene's surface-quality sections: `[quality]` (depth smoothing, anti-aliasing, culling)
and `[sph]` (the OpenCL SPH quantities). Part of the scene schema (`schema.py` re-exports them):
every field typed and documented here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from sphrender.server.scene.fields import spec

FilterName = Literal["narrow_range", "bilateral", "gaussian", "none"]


@dataclass(frozen=True)
class QualityConfig:
    """Depth smoothing, anti-aliasing and the speed/error trade-offs of the surface."""

    filter: FilterName = spec(
        "narrow_range",
        "depth smoothing filter: narrow_range (Truong & Yuksel 2018; averages inverse depth, so "
        "a plane in perspective stays a plane), bilateral (eq 22-24), gaussian (eq 17-21) or "
        "none. Where a kernel reaches past the image's end it goes on one-sided and returns "
        "the intercept of a line fit through the taps inside (the image's edge is no "
        "silhouette)",
    )
    separable: bool = spec(True, "filter rows then columns (1-D kernels) instead of one 2-D kernel")
    iterations: int = spec(2, "how many times the whole filter is applied", low=1, high=16)
    last_pass_sigma: float = spec(
        0.7,
        "separable filters with two or more passes along the axis filtered last (iterations "
        ">= 2): that axis's last pass smooths with sigma x this, its first with sigma x "
        "sqrt(2 - this^2), so the axis's smoothing (the sum of the passes' variances) stays. "
        "The last pass's kernels are cut where rows meet a silhouette, at places that change "
        "from row to row along a beaded rim: the streaks it leaves scale with its sigma "
        "squared. Less of it trades them for those the other axis's passes leave, which the "
        "lighter last pass smooths less. balanced 0.7, best 0.5 (with destreak), at no cost. "
        "Near rims, angle between vertically / horizontally adjacent normals at 1, 0.7 and "
        "0.5 (the 2-D filter's): dam-break frame 5 close-up 2.11 / 1.77, 2.01 / 1.77, "
        "1.97 / 1.80 (1.81 / 1.69); the demo 1.91 / 0.94, 1.82 / 0.99, 1.77 / 1.05 (1.65 / "
        "0.92). A 4k ball's rim rows/columns ratio 1.45, 1.25, 1.11 (the sphere's 0.99). "
        "1: equal passes",
        low=0.0,
        high=1.0,
        low_open=True,
        unit="fraction of the kernel's sigma",
    )
    destreak: float = spec(
        0.0,
        "separable filters: after the iterations one more 1-D pass across the axis filtered "
        "last, sigma = destreak x the kernel's. Each row's kernel is cut where its row meets "
        "a silhouette, at a place that changes from row to row along a beaded rim, so the "
        "last pass leaves streaks along its axis near silhouettes on close-ups; a light pass "
        "across them takes what last_pass_sigma leaves (0.25 over balanced's last_pass_sigma "
        "0.7: dam-break frame 5 close-up, angle between vertically / horizontally adjacent "
        "normals near rims 2.01 / 1.77 -> 1.84 / 1.75 deg, the 2-D filter's 1.81 / 1.69; a "
        "4k ball's rim rows/columns ratio 1.25 -> 0.99, the sphere's 0.99). best: 0.25; "
        "balanced and fast: 0 (+2.4-4 ms on the 100k ball at 1280x720 on llvmpipe). 0: off",
        low=0.0,
        high=1.0,
        unit="fraction of the kernel's sigma",
    )
    kernel_size: Literal["projected_radius", "eq25"] = spec(
        "projected_radius",
        "how the kernel follows depth: projected_radius (sigma = kernel_scale * r_px(z)) or "
        "eq25 (the thesis's linear decline: eq25_sigma_px up to eq25_threshold, then minus "
        "eq25_decline px per unit)",
    )
    kernel_scale: float = spec(
        2.0,
        "Gaussian sigma in projected particle radii (sigma_px = kernel_scale * r_px(z)); the "
        "kernel reaches 3 sigma",
        low=0.0,
        high=16.0,
        low_open=True,
        unit="projected particle radii",
    )
    kernel_max_px: int = spec(
        64,
        "the kernel takes every pixel out to this radius; past it only spread taps "
        "(kernel_max_stride), and where those end the kernel does, with sigma shrunk to keep "
        "3 sigma inside. A cap below 3 kernel_scale projected radii leaves per-particle ripple "
        "on close-ups, which flickers (spatter pool, up to ~20 px per radius, hard cap: 0.79 "
        "deg at 64, 0.69 at 96, 0.66 at 128)",
        low=1,
        high=128,
        unit="px",
    )
    kernel_max_stride: int = spec(
        3,
        "close-ups, separable filters: a kernel whose 3 sigma lies past kernel_max_px goes on "
        "beyond it with every stride-th pixel, stride = ceil(3 sigma / kernel_max_px) up to "
        "this, so sigma stays kernel_scale projected radii out to kernel_max_px x stride for "
        "fewer than 2 kernel_max_px taps (never past the image's ends). 1: a hard cap (the 2-D "
        "filter's always)",
        low=1,
        high=4,
    )
    kernel_min_px: int = spec(
        1, "smallest kernel radius in pixels (eq 25's ks_min)", low=0, high=64, unit="px"
    )
    eq25_sigma_px: float = spec(
        6.0,
        "eq 25: sigma in pixels up to the threshold distance",
        low=0.0,
        low_open=True,
        unit="px",
    )
    eq25_threshold: float = spec(
        1.0,
        "eq 25: eye depth (scene units) beyond which the kernel shrinks",
        low=0.0,
        unit="scene units",
    )
    eq25_decline: float = spec(
        2.0,
        "eq 25: k, kernel radius lost per scene unit beyond the threshold (px)",
        low=0.0,
        unit="px per scene unit",
    )
    bilateral_depth_sigma: float = spec(
        6.0,
        "bilateral range sigma in particle radii (eq 24); smaller keeps the per-particle bumps",
        low=0.0,
        low_open=True,
        unit="particle radii",
    )
    narrow_range_threshold: float = spec(
        10.0,
        "narrow-range lambda: samples more than lambda*r behind the accepted range are "
        "dropped with their mirror sample, samples more than lambda*r in front are clamped "
        "(narrow_range_clamp); the range starts at the centre +-lambda*r and grows around "
        "every accepted sample. 10: the published default. Measured at 960x540 on balanced: "
        "lambda 6 keeps blobs of a few particles 6-10 r in front of a surface apart from it "
        "(the splashy dam-break frames 9-15: mean normal error 0.3-0.7 deg lower, silhouette "
        "band 0.2-0.6 deg lower) but cuts the kernel at the grazing rim of a smooth body, "
        "whose splat steps by more than 6 r per pixel there (the 90k lattice ball at 1280x720 "
        "1.48 / 3.72 -> 1.54 / 3.90 deg; lambda 4: 1.84 / 4.68) and flickers a little more "
        "(dam break 0.957 -> 0.968 deg)",
        low=0.0,
        low_open=True,
        unit="particle radii",
    )
    narrow_range_clamp: float = spec(
        1.0,
        "narrow-range mu: nearer samples are clamped to z - mu*r",
        low=0.0,
        low_open=True,
        unit="particle radii",
    )
    narrow_range_pairs: float = spec(
        4.0,
        "separable narrow_range: a mirrored tap pair whose midpoint departs from the centre "
        "by more than this many particle radii (in inverse depth, so the pairs of a plane "
        "seen in perspective never depart, whatever its slope or the kernel's length) is "
        "dropped, from the second 1-D pass on (the first sees the raw splat, whose relief "
        "between particles would trip it). It tells a step from a slope, which lambda alone "
        "cannot: a blob of a few particles 4-10 r in front of a surface keeps its depth "
        "instead of melting into it, where the grazing rim of a smooth body (whose pairs "
        "depart little) keeps its kernel. Measured at 960x540, balanced, the dam break's "
        "eight frames against pysplashsurf: 1-px tolerant silhouette band 8.32 -> 8.10 deg on "
        "frame 5, 9.23 -> 8.00 on frame 9, mean error 0.1-1.4 deg lower on every frame; the "
        "90k lattice ball and the spatter unchanged, dam-break flicker 0.957 -> 0.981 deg. "
        "4: the edge jump of the normals pass. 0: off (the fast preset)",
        low=0.0,
        unit="particle radii",
    )
    keep_features: Literal["none", "truncate", "blend", "both"] = spec(
        "none",
        "keep features smaller than the kernel (droplets, thin edges; separable narrow_range "
        "only): truncate (the kernel ends at the first sample pair it rejects, so it never "
        "reaches across a discontinuity), blend (the result moves back towards the unfiltered "
        "depth by the weight share of rejected samples, as NVIDIA FleX does), both, or none. "
        "Experimental: on the reference scenes neither beat none (exact_droplets is what keeps "
        "droplets round)",
    )
    normal_stencil: float = spec(
        1.0,
        "normals from a central difference over +-normal_stencil projected particle radii "
        "(at least 1 pixel, at most normal_stencil_max_px) where the stencil stays on one "
        "surface without a kink, else the 1-pixel one-sided difference; averages the ripple "
        "the smoothing leaves, which a 1-pixel difference turns into flicker. 0: always the "
        "1-pixel one-sided difference",
        low=0.0,
        high=4.0,
    )
    normal_stencil_max_px: int = spec(
        2,
        "cap on the normal_stencil half-width in pixels (a central difference over +-s pixels "
        "of a sphere of R_px pixels is off by ~ (s / R_px)^2 near its rim: small droplets want "
        "a narrow stencil, a rippled bulk a wide one)",
        low=1,
        high=16,
    )
    normal_rules: Literal["smooth", "hard"] = spec(
        "smooth",
        "how the normals pass picks between its differences: smooth: the wide stencil's weight "
        "falls smoothly with its kink test (1/2 at the kink limit) and the two 1-pixel "
        "one-sided differences are weighted by the other side's squared depth step, so a "
        "particle's small move changes the normals a little (dam break at 960x540, flicker "
        "0.973 -> 0.959 deg; 1-pixel difference alone 2.11 -> 1.92); hard: the switches of the "
        "pre-issue-12 renderer (the kink test cuts, the smaller one-sided step wins), kept for "
        "the bench's baseline",
    )
    antialias: bool = spec(
        True,
        "silhouette anti-aliasing: alpha is each edge pixel's sub-pixel coverage (analytic, from "
        "the ray's angular distance to the sphere's silhouette) and the pixels just outside a "
        "silhouette show the surface next to them; off: alpha is 1 where a pixel centre hits",
    )
    exact_droplets: bool = spec(
        True,
        "droplets (particles whose kernel density is below droplet_density * sph.rest_density: "
        "isolated particles and pairs) are not smoothed: they are splatted "
        "as exact spheres over the smoothed surface, so a kernel wider than a droplet neither "
        "flattens it nor blends it into the pool behind. Uses the frame's densities (the "
        "client's, or those an [sph] feature computed; see droplet_densities); frames without "
        "them are split only with droplet_density_pass",
    )
    droplet_densities: Literal["frame", "computed"] = spec(
        "frame",
        "which densities exact_droplets compares with droplet_density: the frame's (as above), "
        "or always the frame's own positions' (OpenCL, the cost of droplet_density_pass). "
        "For simulators whose densities count what the frame does not "
        "hold: SPlisHSPlasH's include its walls (not exported), so in its dam break's frame 9 "
        "half of the particles with no neighbour within 4 r carry 0.45-1.0 rest, all about 2 r "
        "from a wall, and are smoothed instead of drawn as droplets",
    )
    droplet_density_pass: bool = spec(
        False,
        "exact_droplets on frames that carry no densities: find the particles whose own "
        "density, from the positions, is below droplet_density (OpenCL, sph/density_below.py; "
        "each particle's sum stops once it passes the limit: the sweep's SPH stage in best "
        "29.9 -> 10.5 ms on the 90k ball at 1280x720, 14.4 -> 3.6 ms on a dam-break frame, "
        "against the density pass it replaced, on a 2-core CPU); off: such frames render "
        "without the droplet split",
    )
    droplet_density: float = spec(
        0.45,
        "exact_droplets: the density, as a fraction of sph.rest_density, below which a "
        "particle is a droplet (cubic spline, support 4 r, measured: a lone particle 0.32, a "
        "pair 0.40, the inside of a one-particle filament 0.48, the outer particles of a "
        "jittered lattice ball >= 0.47, a slab's corner 0.61, edge 0.72, face 0.85)",
        low=0.0,
        high=1.0,
        unit="fraction of sph.rest_density",
    )
    droplet_lone_density: float = spec(
        0.36,
        "exact_droplets on frames whose own densities are used (droplet_densities = frame): "
        "also a droplet, whatever its density there, is a particle whose density computed "
        "from the frame's positions (OpenCL) is below this fraction of sph.rest_density: "
        "alone in the frame (cubic spline, support 4 r: a lone particle 0.318, one neighbour "
        "3 r away 0.328, a touching pair 2 r apart 0.398; 0.36 lies midway). A simulator's "
        "densities can count what the frame does not hold: SPlisHSPlasH's count its walls, so "
        "a lone particle near one reads 0.45-1.0 rest and was smoothed into a lens. Dam break "
        "at 960x540, frames 5-15: lone droplets 0.97 / 6.86 / 5.07 / 3.65 / 4.37 / 2.99 -> "
        "0.97 / 5.42 / 2.64 / 2.56 / 2.43 / 2.55 deg, tolerant band 8.13 / 7.74 / 7.93 / 8.01 "
        "/ 8.90 / 9.18 -> 8.07 / 7.67 / 7.88 / 7.93 / 8.76 / 9.13 deg, flicker 0.980 / 1.298 / "
        "1.101 / 0.879 / 0.830 / 0.873 -> 0.967 / 1.258 / 1.095 / 0.887 / 0.845 / 0.856 deg "
        "(0.33: frame 13's band 8.85, 0.38: its flicker 0.840, frame 9's 1.156). Cost, on "
        "frames with densities only: no density pass, each particle's sum stops once it passes "
        "the limit (sph/density_below.py): the dam break's 32k at 960x540 nothing measurable "
        "on llvmpipe + PoCL, a 100k ball at 1280x720 +0.04-0.09x of the pre-issue frame. "
        "balanced and best: 0.36, fast: 0. 0: off (the frame's densities alone); without "
        "OpenCL the frame's alone, with a note",
        low=0.0,
        high=1.0,
        unit="fraction of sph.rest_density",
    )
    close_gaps: float = spec(
        2.0,
        "close the gaps a sparse sheet or spray leaves between its splatted particles, before "
        "the smoothing (passes/gaps.py): a background pixel enclosed in two of four directions, "
        "or a pixel of a farther surface enclosed in one, by a nearer surface on both sides at "
        "most close_gaps particle radii apart (on screen, projected at their depth, and in "
        "depth) takes the depth interpolated between them; depths only get nearer (no hole "
        "opens), a notch along a silhouette stays open, particles farther apart stay apart; "
        "at most 16 pixels; after the smoothing the same rule once more on background pixels "
        "within 8 pixels (pinholes: a view along a lattice's channels sees through its "
        "layers); runs with the smoothing (not with filter none). 0: off (the fast preset; on "
        "llvmpipe the passes cost ~7-10 % of a 100k-particle 1280x720 frame)",
        low=0.0,
        high=8.0,
        unit="particle radii",
    )
    silhouette_normals: float = spec(
        0.0,
        "turn the normals near a silhouette towards the silhouette's outward direction "
        "(passes/silhouette.py): direction and distance to the rim from coverage moments "
        "over a Gaussian window of half this reach (at most 3 px sigma), blended in by the "
        "distance to the rim (full on it, none from this many projected particle radii "
        "inside); removes the sideways flips of a beaded rim without moving it. 0: off",
        low=0.0,
        high=8.0,
        unit="particle radii",
    )
    field_normals: float = spec(
        2.0,
        "take the normals within this many projected particle radii (at most 5 pixels) of a "
        "rim (background, or a depth step the normals pass does not difference across) "
        "towards the normal of the particles' smoothed field, -grad phi of phi = sum W(|x - "
        "x_j|, field_normals_support) at the pixel's own surface point "
        "(passes/field_normals.py): smooth rims where the particles leave beads, rounded edges "
        "round a sheet's holes, exact droplet spheres; blended in by the distance to the rim, "
        "depth unchanged. An exact droplet is no rim of the surface behind it (no ring "
        "around it on a pool). Builds a particle grid on the device each frame (on llvmpipe ~15 ms "
        "of a 100k-particle 1280x720 frame; balanced and best: 2, fast: off). 0: off",
        low=0.0,
        high=8.0,
        unit="particle radii",
    )
    field_normals_support: float = spec(
        5.0,
        "field_normals: the cubic spline's support, in particle radii (the SPH passes use 4: "
        "5 smooths the rim's beads more; dam break against splashsurf, 1-px tolerant band "
        "10.3 deg at 4, 8.5 at 5, 9.5 at 5.5; lone droplets near a pool lean towards it)",
        low=1.0,
        high=16.0,
        unit="particle radii",
    )
    occlusion_culling: bool = spec(
        True,
        "splat the front layer first and skip particles hidden behind it (exact: the depth "
        "image is unchanged; off only to measure it)",
    )


@dataclass(frozen=True)
class SphConfig:
    """SPH quantities computed on OpenCL (thesis section 3.3.4). The pass runs only when a
    feature below asks for it; kernel, support and mass are pinned so results compare with
    other SPH tools (cubic spline, support 4 r, m = rest_density (2 r)^3, as splashsurf)."""

    rest_density: float = spec(
        1000.0,
        "rest density rho_0 (kg/m^3 in SI scenes: water 1000, molten steel ~7000), the units "
        "of the frames' densities: a frame whose densities peak outside 0.5-1.5 x rho_0 "
        "(another fluid, rho / rho_0, g/cm^3), or are one value for every particle, gets "
        "densities computed from its positions instead, with a warning and a note on its answer",
        low=0.0,
        low_open=True,
        unit="mass per scene unit^3",
    )
    support_radius: float | None = spec(
        None,
        "kernel support h (W = 0 beyond); absent = 4 * particles.radius",
        low=0.0,
        low_open=True,
        unit="scene units",
    )
    mass: float | None = spec(
        None,
        "particle mass m; absent = rest_density * (2 * particles.radius)^3",
        low=0.0,
        low_open=True,
        unit="mass units",
    )
    surface_threshold: float = spec(
        0.5,
        "eq 28 (corrected): a particle is on the surface where |n| > t, with t = "
        "surface_threshold / support_radius (|n| h is about 1 on a flat surface, 0 inside)",
        low=0.0,
        low_open=True,
        unit="1 / support_radius",
    )
    adaptive_radius: bool = spec(
        False,
        "eq 29: particles less dense than the surface average shrink toward min_radius "
        "(thins splashes and droplets)",
    )
    min_radius: float = spec(
        0.5,
        "eq 29 r_min as a fraction of the particle's radius",
        low=0.0,
        high=1.0,
        low_open=True,
        unit="fraction of the particle radius",
    )
    radius_decline: float = spec(
        0.25,
        "eq 29 k, dimensionless: r = r_body (1 - ((d_surface - d) / d_surface)^2 / "
        "radius_decline), i.e. the thesis's k = radius_decline * d_surface^2 / r_body",
        low=0.0,
        low_open=True,
    )
    surface_only: bool = spec(
        False,
        "splat only surface particles, sparse ones and a safety layer; hidden interior "
        "particles are skipped",
    )
    safety_layer: float = spec(
        0.9,
        "surface_only: also splat particles within safety_layer * support_radius of a "
        "surface or sparse particle (0.9 reaches all 26 lattice neighbours at spacing 2 r = "
        "h / 2, at sqrt(3) h / 2; less opens holes between the outer particles)",
        low=0.0,
        high=1.0,
        unit="support radii",
    )
    sparse_density: float = spec(
        0.75,
        "surface_only: a particle whose kernel density (eq 2 from positions) is below "
        "sparse_density * rest_density is sparse (droplet, thin sheet) and always splatted",
        low=0.0,
        high=1.0,
        unit="fraction of sph.rest_density",
    )
    anisotropy: bool = spec(
        False,
        "anisotropic particles (Yu & Turk 2013): each particle becomes an ellipsoid of its "
        "sphere's volume, stretched along its neighbourhood's principal axes (flat on flat "
        "surfaces, long along filaments), at a smoothed centre; particles with few neighbours "
        "stay spheres of their radius at their position",
    )
    anisotropy_radius: float = spec(
        1.5,
        "anisotropy: neighbourhood radius R as a multiple of support_radius (weights 1 - "
        "(d/R)^3); 1.5 = 6 r gives ~107 neighbours inside a jittered lattice of spacing 2 r "
        "and ~63 on its surface (1.0 gives ~29 and ~19: at or below min_neighbours)",
        low=0.25,
        high=4.0,
        unit="support radii",
    )
    anisotropy_max_ratio: float = spec(
        4.0,
        "anisotropy: k_r, largest ratio of the longest to the shortest axis (the covariance's "
        "eigenvalues are clamped to >= largest / k_r; axes follow the eigenvalues, as Yu & Turk)",
        low=1.0,
        high=32.0,
    )
    anisotropy_min_neighbours: int = spec(
        25,
        "anisotropy: N_eps, particles with fewer neighbours within R stay exact spheres "
        "(droplets do not shrink or move); above it anisotropy and smoothing ramp in over "
        "N_eps / 2 more neighbours, so shapes change continuously between frames",
        low=1,
        high=10000,
        unit="particles",
    )
    anisotropy_smoothing: float = spec(
        0.5,
        "anisotropy: lambda, centres move to (1 - lambda) x + lambda (weighted neighbourhood "
        "mean), ramped like the shape; Yu & Turk use 0.9-1, which also pulls the surface "
        "inwards by lambda * ~0.25 R (up to 0.4 R)",
        low=0.0,
        high=1.0,
    )
