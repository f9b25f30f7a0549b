"""The screen rectangle that holds every splatted fragment.

The passes after the splat touch only pixels with a surface (or their direct neighbours), so
running them inside this box, on targets cleared outside it, gives the same image while
skipping the background: with a ball filling a quarter of a 1280x720 image that is 3/4 of the
fragments of every full-screen pass.
"""

from __future__ import annotations

from sphrender.server.engine.geometry import occlusion
from sphrender.server.engine.geometry.camera import Camera

ScreenBox = tuple[int, int, int, int]  # x, y (GL window coordinates, bottom-left), width, height


def screen_box(
    bounds: occlusion.SphereBounds, camera: Camera, margin_px: int = 2
) -> ScreenBox | None:
    """A pixel rectangle holding every splatted fragment (the union of the spheres' silhouette
    rectangles, see `occlusion.sphere_bounds`, plus `margin_px`), or None (whole image) when a
    sphere reaches the eye plane."""
    if bounds.valid.size == 0 or not bounds.valid.all():
        return None
    return clip_box(
        int(bounds.x0.min()),
        int(bounds.x1.max()),
        int(bounds.y0.min()),
        int(bounds.y1.max()),
        camera,
        margin_px,
    )


def clip_box(x0: int, x1: int, y0: int, y1: int, camera: Camera, margin_px: int = 2) -> ScreenBox:
    """The inclusive pixel rectangle x0..x1, y0..y1 grown by `margin_px` and clipped to the
    image (the device prepare reduces the rectangles on the GPU and calls this)."""
    width, height = camera.width, camera.height
    x0 = min(max(int(x0) - margin_px, 0), width)
    x1 = min(max(int(x1) + 1 + margin_px, 0), width)
    y0 = min(max(int(y0) - margin_px, 0), height)
    y1 = min(max(int(y1) + 1 + margin_px, 0), height)
    if x1 <= x0 or y1 <= y0:
        return (0, 0, 1, 1)  # nothing on screen: a token box keeps the passes trivial
    return (x0, y0, x1 - x0, y1 - y0)


def packed_box(box: ScreenBox) -> ScreenBox:
    """`box` in the texels of a packed image (four pixels per texel along x)."""
    x, y, width, height = box
    first = x // 4
    return (first, y, (x + width + 3) // 4 - first, height)


def intersect(a: ScreenBox, b: ScreenBox) -> ScreenBox | None:
    """The overlap of two boxes, None when they do not overlap."""
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[0] + a[2], b[0] + b[2]), min(a[1] + a[3], b[1] + b[3])
    return (x0, y0, x1 - x0, y1 - y0) if x1 > x0 and y1 > y0 else None


def packed_border_split(
    image_px: tuple[int, int], axis: int, margin_px: int
) -> tuple[ScreenBox | None, list[ScreenBox]]:
    """A packed image (four pixels per texel along x) of `image_px` = (width, height) pixels cut
    along `axis` (0: x, 1: y) into the texels all of whose pixels lie more than `margin_px`
    pixels inside both ends of that axis (None if there are none) and the 1-2 strips of texels
    at the ends that hold the rest: where a 1-D kernel at most `margin_px` long may reach past
    the image."""
    width, height = image_px
    texels = ((width + 3) // 4, height)
    if axis == 0:
        # texel x holds pixels 4x .. 4x + 3
        lo, hi, end = (margin_px + 3) // 4, (width - 4 - margin_px) // 4 + 1, texels[0]
    else:
        lo, hi, end = margin_px, height - margin_px, height

    def span(a: int, b: int) -> ScreenBox:
        return (a, 0, b - a, texels[1]) if axis == 0 else (0, a, texels[0], b - a)

    if lo >= hi:
        return None, [span(0, end)]
    return span(lo, hi), [span(a, b) for a, b in ((0, lo), (hi, end)) if b > a]
