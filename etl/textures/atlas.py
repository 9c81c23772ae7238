"""Multi-resolution texture atlases: the thesis' resolution rule, bounded atlas pages, resampling, encoding.

Pure: arrays in, arrays/bytes out; no database. The textures stage asks for one texture per chart (a wall, a
roof face, an xatlas chart layout), sized by ``texture_size`` for the distance its tile is viewed from, and
``pack`` places them on pages of at most ``page_size`` texels a side; the exporter maps each chart's local
coordinates into its page rectangle with ``page_uv``.

Design choices:
  * **Resolution rule** (thesis 4.3.1): a surface of extent e metres seen from distance >= d through a vertical
    field of view fov on a screen H pixels high covers at most e / (2 d tan(fov/2)) * H pixels; it gets that
    many texels divided by the pixel-per-texel ratio, so it is never magnified. Not rounded to a power of two:
    textures share a page, mipmaps are made per page, and rounding each chart up would waste up to 4x texels.
  * **Repeated textures are baked** (option a): a request says how often its image repeats across the chart,
    and the repeats are drawn into the chart at the chart's own resolution. The chart costs its screen-space
    size, never its repeat count (thesis 5.2.1: "it is not relevant for the required texture space whether a
    triangle contains 100 repetitions of a tile texture or a single one"). glTF has no per-rectangle wrap
    inside an atlas, and splitting faces at every repeat (option b) would multiply triangles by the repeat
    count, so baking it is; procedural textures are mostly rendered straight at the chart size anyway.
  * **Bounded pages**: nothing is ever larger than ``page_size`` (512 by default as in the thesis, at most
    4096); a texture that would not fit is shrunk to fit and flagged ``scaled``; more pages when needed. Each
    page is then cropped to the area in use, rounded up to a multiple of 4 texels (block-compressed formats
    need that, and two 2x reductions stay exact), or to a power of two a side (``pot``, what the textures stage
    uses: KTX2 carries a full mip chain). Each chart sits in a gutter of ``padding`` texels filled
    with its own edge texels, so bilinear filtering and the first log2(padding) mip levels never bleed in
    a neighbour's colour.
  * **Two packers with one output**: ``shelf`` (heights descending, best-fitting open shelf on any page,
    else a new shelf, else a new page) and ``xatlas`` (xatlas' chart packer fed one quad per texture through
    ``Atlas.add_uv_mesh``, rotation off), so they can be compared on utilization and time. On rectangles the
    shelf packer wins both (benchmarks/atlas_compare.py, 1000 charts of 200 buildings, 2-texel gutters:
    91.6 % vs 84.9 % at 100 m, 87.8 % vs 78.5 % at 200 m, in 0.01 s vs 2-3 s), so it is the default;
    xatlas is for irregular charts, which reach this module already laid out (textures.chart_uvs).
  * **Gamma-correct resampling**: sRGB texels are converted to linear light, resized with a proper filter by
    OpenImageIO (``lanczos3`` by default), and converted back, so a downsampled brick wall keeps its brightness.

UV convention of the outputs (glTF): (0, 0) is the top-left corner of a page's first texel row, v grows down.
"""

from __future__ import annotations

import functools
import math
import os
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from types import ModuleType
from typing import overload

import numpy as np

from core.camera import pixels_per_metre
from etl.textures import xatlas_run

PAGE_SIZE = 512  # the thesis' choice (4.3.1: "W = H = 512 is the most appropriate choice")
MAX_PAGE_SIZE = 4096
PACKERS = ("shelf", "xatlas")
FILTER = "lanczos3"


@functools.cache
def openimageio() -> ModuleType:
    """The OpenImageIO module, single-threaded: citylod parallelises across processes, and OIIO's own thread
    pool is one more place a process can hang on its way out (its shutdown can deadlock, OIIO issue #3851)."""
    import OpenImageIO as oiio

    oiio.attribute("threads", 1)
    return oiio


# --- resolution rule -----------------------------------------------------------------------------------------


def texels_per_metre(
    view_distance_m: float | np.ndarray, fov_y_rad: float, screen_height_px: float, px_per_texel: float = 1.0
) -> float | np.ndarray:
    """Texels per metre that avoid magnification for a surface seen from at least ``view_distance_m``."""
    d = np.asarray(view_distance_m, dtype=np.float64)
    if np.any(d <= 0) or not 0 < fov_y_rad < math.pi or screen_height_px <= 0 or px_per_texel <= 0:
        raise ValueError("need distance > 0, 0 < fov < pi, screen height > 0 and px_per_texel > 0")
    rho = pixels_per_metre(d, fov_y_rad, screen_height_px) / px_per_texel
    return float(rho) if np.ndim(rho) == 0 else rho


def texture_size(
    extent_m: float | np.ndarray,
    view_distance_m: float | np.ndarray,
    fov_y_rad: float,
    screen_height_px: float,
    px_per_texel: float = 1.0,
) -> int | np.ndarray:
    """Texels along an extent of ``extent_m`` metres: its projected size in pixels at the distance, rounded up
    (at least 1). Vectorised over extents and distances."""
    return texels(extent_m, texels_per_metre(view_distance_m, fov_y_rad, screen_height_px, px_per_texel))


@overload
def texels(extent_m: float, rho: float) -> int: ...
@overload
def texels(extent_m: np.ndarray, rho: float | np.ndarray) -> np.ndarray: ...
@overload
def texels(extent_m: float | np.ndarray, rho: float | np.ndarray) -> int | np.ndarray: ...
def texels(extent_m: float | np.ndarray, rho: float | np.ndarray) -> int | np.ndarray:
    """Texels along an extent of ``extent_m`` metres at ``rho`` texels per metre: rounded up, at least 1."""
    px = np.asarray(extent_m, dtype=np.float64) * rho
    # a hair below the exact product so a float error never adds a whole texel (e.g. 10 m * 12.8/m)
    n = np.maximum(np.ceil(px - 1e-9), 1).astype(np.int64)
    return int(n) if n.ndim == 0 else n


# --- resampling ----------------------------------------------------------------------------------------------


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """float32 linear light in 0..1 of 8-bit sRGB values (the exact sRGB curve, not a 2.2 power)."""
    c = np.asarray(x).astype(np.float32) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
    """uint8 sRGB of linear light (clipped to 0..1)."""
    c = np.clip(c, 0.0, 1.0)
    s = np.where(c <= 0.0031308, c * 12.92, 1.055 * np.power(c, 1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def resize(pixels: np.ndarray, width: int, height: int, filter: str = FILTER) -> np.ndarray:
    """(height, width, c) uint8: ``pixels`` (h, w, c) uint8 sRGB (alpha, if any, linear) resampled by
    OpenImageIO in linear light with ``filter`` (any OIIO filter name: lanczos3, blackman-harris, box, ...)."""
    oiio = openimageio()

    src = np.asarray(pixels)
    if src.ndim == 2:
        src = src[:, :, None]
    if src.dtype != np.uint8:
        raise ValueError("resize expects uint8 pixels")
    width, height = int(width), int(height)
    if width < 1 or height < 1:
        raise ValueError("target size must be at least 1 x 1")
    if (src.shape[1], src.shape[0]) == (width, height):
        return src.copy()
    nc = src.shape[2]
    lin = srgb_to_linear(src)
    if nc in (2, 4):  # alpha is not gamma-encoded
        lin[:, :, -1] = src[:, :, -1] / np.float32(255.0)
    out = oiio.ImageBufAlgo.resize(
        oiio.ImageBuf(np.ascontiguousarray(lin)), filtername=filter, roi=oiio.ROI(0, width, 0, height, 0, 1, 0, nc)
    )
    if out.has_error:
        raise RuntimeError(f"OpenImageIO resize failed: {out.geterror()}")
    res = out.get_pixels(oiio.FLOAT).reshape(height, width, nc)
    srgb = linear_to_srgb(res)
    if nc in (2, 4):
        srgb[:, :, -1] = np.round(np.clip(res[:, :, -1], 0, 1) * 255).astype(np.uint8)
    return srgb


def downsample(page: np.ndarray, factor: float = 2.0, filter: str = FILTER) -> np.ndarray:
    """``page`` shrunk by ``factor`` (each side round(side / factor), at least 1) for a coarser tile level."""
    if factor < 1:
        raise ValueError("factor must be >= 1")
    h, w = page.shape[:2]
    return resize(page, max(1, round(w / factor)), max(1, round(h / factor)), filter)


def mipmaps(page: np.ndarray, filter: str = FILTER, min_size: int = 1) -> list[np.ndarray]:
    """The mip chain of a page: level 0 is the page, each next level halves both sides (floor, at least 1)
    until both are <= min_size. For KTX2 (which stores levels); PNG/WebP/JPEG leave mipmaps to the GPU."""
    levels = [np.asarray(page)]
    while max(levels[-1].shape[:2]) > min_size:
        h, w = levels[-1].shape[:2]
        levels.append(resize(levels[-1], max(1, w // 2), max(1, h // 2), filter))
    return levels


# --- packing -------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TextureRequest:
    """One chart's texture. ``size`` = (width, height) in texels from the resolution rule. Pixels come from
    ``generator(width, height)`` (procedural: rendered straight at the size) or from ``image`` (h, w, 3|4)
    uint8, repeated ``repeat`` = (across, down) times (fractions allowed) and resampled to the size."""

    size: tuple[int, int]
    image: np.ndarray | None = None
    generator: Callable[[int, int], np.ndarray] | None = None
    repeat: tuple[float, float] = (1.0, 1.0)
    key: object = None  # the caller's id (building, wall, chart), passed through untouched


@dataclass(frozen=True)
class Layout:
    """Where each texture goes: content texel box (x, y, x + w, y + h) on page ``page``. Geometry only."""

    page: np.ndarray  # (k,) int64
    x: np.ndarray  # (k,) int64 content origin (left), texels
    y: np.ndarray  # (k,) int64 content origin (top), texels
    w: np.ndarray  # (k,) int64 content width (the requested one unless scaled)
    h: np.ndarray  # (k,) int64
    scaled: np.ndarray  # (k,) bool: shrunk to fit on a page
    page_dims: np.ndarray  # (pages, 2) int64 (width, height) of each page after cropping
    padding: int
    packer: str
    seconds: float  # time spent placing (the packer alone)

    @property
    def n_pages(self) -> int:
        return len(self.page_dims)

    @property
    def utilization(self) -> np.ndarray:
        """(pages,) fraction of each page's texels covered by content (gutters and free space excluded)."""
        used = np.bincount(self.page, weights=self.w * self.h, minlength=self.n_pages)
        area = self.page_dims[:, 0] * self.page_dims[:, 1]
        return used / np.maximum(area, 1)

    @property
    def total_utilization(self) -> float:
        area = float((self.page_dims[:, 0] * self.page_dims[:, 1]).sum())
        return float((self.w * self.h).sum()) / area if area else 0.0

    @property
    def rects(self) -> np.ndarray:
        """(k, 4) float64 (u0, v0, u1, v1): each content box in its page's normalised UV (v down)."""
        dims = self.page_dims[self.page].astype(np.float64)
        return np.column_stack(
            [self.x / dims[:, 0], self.y / dims[:, 1], (self.x + self.w) / dims[:, 0], (self.y + self.h) / dims[:, 1]]
        )


@dataclass(frozen=True)
class Atlas:
    """A packed atlas: pages of pixels plus the layout (per request: page, UV rectangle, texel box)."""

    pages: list[np.ndarray]  # (H, W, 4) uint8 each, H, W <= page_size
    layout: Layout
    keys: list[object] = field(default_factory=list)
    seconds: float = 0.0  # packing plus drawing

    @property
    def page(self) -> np.ndarray:
        return self.layout.page

    @property
    def rects(self) -> np.ndarray:
        return self.layout.rects

    @property
    def utilization(self) -> np.ndarray:
        return self.layout.utilization

    @property
    def scaled(self) -> np.ndarray:
        return self.layout.scaled


def _check_page_size(page_size: int, padding: int) -> None:
    if not 16 <= page_size <= MAX_PAGE_SIZE or page_size % 4:
        raise ValueError(f"page_size must be a multiple of 4 in 16..{MAX_PAGE_SIZE}, got {page_size}")
    if padding < 0 or 2 * padding >= page_size:
        raise ValueError("padding must be >= 0 and leave room on the page")


def fit_sizes(sizes: np.ndarray, page_size: int, padding: int) -> tuple[np.ndarray, np.ndarray]:
    """(fitted (k, 2) int64, scaled (k,) bool): sizes shrunk (aspect kept) so size + 2 * padding <= page_size."""
    s = np.asarray(sizes, dtype=np.int64).reshape(-1, 2)
    if np.any(s < 1):
        raise ValueError("texture sizes must be at least 1 x 1")
    room = page_size - 2 * padding
    f = np.minimum(1.0, room / s.max(axis=1))
    fitted = np.where((f < 1)[:, None], np.maximum(np.floor(s * f[:, None]), 1), s).astype(np.int64)
    return np.minimum(fitted, room), f < 1


def _crop(
    page: np.ndarray, right: np.ndarray, bottom: np.ndarray, n_pages: int, page_size: int, pot: bool
) -> np.ndarray:
    """(pages, 2) page sizes: the used area rounded up to a multiple of 4 (or a power of two), <= page_size."""
    used = np.zeros((n_pages, 2), dtype=np.int64)
    np.maximum.at(used[:, 0], page, right)
    np.maximum.at(used[:, 1], page, bottom)
    dims = 2 ** np.ceil(np.log2(np.maximum(used, 1))).astype(np.int64) if pot else -(-used // 4) * 4
    return np.minimum(np.maximum(dims, 4), page_size)


def _shelf(slots: np.ndarray, page_size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shelf packing of (k, 2) slot sizes: tallest first; each slot goes on the open shelf (any page) it fits
    with the least height to spare, else on a new shelf under the last one of the first page with room."""
    k = len(slots)
    order = np.lexsort((-slots[:, 0], -slots[:, 1]))
    page = np.zeros(k, dtype=np.int64)
    x = np.zeros(k, dtype=np.int64)
    y = np.zeros(k, dtype=np.int64)
    cap = 64
    sh_page = np.zeros(cap, np.int64)
    sh_y = np.zeros(cap, np.int64)
    sh_h = np.zeros(cap, np.int64)
    sh_x = np.zeros(cap, np.int64)  # width already used on the shelf
    n = 0
    page_top: list[int] = []  # first free row of each page
    for i in order:
        w, h = int(slots[i, 0]), int(slots[i, 1])
        fits = np.flatnonzero((sh_h[:n] >= h) & (sh_x[:n] + w <= page_size))
        if fits.size:
            s = int(fits[np.argmin(sh_h[fits])])  # heights only shrink, so the least spare height wins
        else:
            p = next((j for j, top in enumerate(page_top) if top + h <= page_size), len(page_top))
            if p == len(page_top):
                page_top.append(0)
            if n == cap:
                cap *= 2
                sh_page, sh_y, sh_h, sh_x = (np.resize(a, cap) for a in (sh_page, sh_y, sh_h, sh_x))
            s = n
            n += 1
            sh_page[s], sh_y[s], sh_h[s], sh_x[s] = p, page_top[p], h, 0
            page_top[p] += h
        page[i], x[i], y[i] = sh_page[s], sh_x[s], sh_y[s]
        sh_x[s] += w
    return page, x, y


def _xatlas(slots: np.ndarray, page_size: int, brute_force: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """xatlas' packer on one quad per slot (uv mesh charts in texel units, one texel per unit).

    xatlas puts a chart's corner on a texel centre (x + 0.5) and reserves every texel the chart touches, i.e.
    one more than its extent (measured here); quads of (w - 1, h - 1) therefore reserve exactly w x h texels
    starting at floor(corner)."""
    import xatlas

    k = len(slots)
    # xatlas widens charts narrower than 1 to 1 (then reserving 2 texels): a 1-texel slot costs 2 here
    ext = np.maximum(slots - 1, 1).astype(np.float32)
    # islands on a grid (xatlas finds charts by connectivity; the gaps keep them apart, the grid keeps the
    # coordinates small enough to be exact in float32)
    cols = math.ceil(math.sqrt(k))
    cell = float(ext.max()) + 2.0
    i = np.arange(k)
    corner = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float32)
    uv = corner[None] * ext[:, None, :]
    uv[:, :, 0] += ((i % cols) * cell)[:, None]
    uv[:, :, 1] += ((i // cols) * cell)[:, None]
    base = 4 * np.arange(k, dtype=np.uint32)[:, None]
    idx = np.concatenate([base + np.array([0, 1, 2], np.uint32), base + np.array([0, 2, 3], np.uint32)], axis=1)
    po = xatlas.PackOptions()
    po.resolution = page_size
    po.texels_per_unit = 1.0
    po.padding = 0  # gutters are part of the slots
    po.bilinear = False
    po.blockAlign = False
    po.rotate_charts = False  # a rotated chart would need rotated texels and UVs
    po.rotate_charts_to_axis = False
    po.bruteForce = brute_force

    def read(atlas: xatlas.Atlas) -> tuple:
        if atlas.width > page_size or atlas.height > page_size:
            raise RuntimeError(f"xatlas made a {atlas.width}x{atlas.height} page for page_size {page_size}")
        vmap, _, out_uv = atlas.get_mesh(0)
        return vmap, out_uv, atlas.get_mesh_vertex_assignment(0)[0], atlas.width, atlas.height

    vmap, out_uv, at, width, height = xatlas_run.generate(
        lambda atlas: atlas.add_uv_mesh(
            np.ascontiguousarray(uv.reshape(-1, 2)), np.ascontiguousarray(idx.reshape(-1, 3))
        ),
        read,
        pack_options=po,
    )
    req = vmap.astype(np.int64) // 4
    px = out_uv.astype(np.float64) * np.array([width, height])
    lo = np.full((k, 2), np.inf)
    hi = np.full((k, 2), -np.inf)
    np.minimum.at(lo, req, px)
    np.maximum.at(hi, req, px)
    if np.any(np.abs((hi - lo) - ext) > 1e-3):
        raise RuntimeError("xatlas changed a chart's extent (rotation or scaling)")
    page = np.zeros(k, dtype=np.int64)
    page[req] = at
    org = np.floor(lo + 1e-6).astype(np.int64)
    return page, org[:, 0], org[:, 1]


def layout(
    sizes: np.ndarray | Sequence[tuple[int, int]],
    page_size: int = PAGE_SIZE,
    packer: str = "shelf",
    padding: int = 2,
    brute_force: bool = False,
    pot: bool = False,
) -> Layout:
    """Place textures of ``sizes`` (k, 2) = (width, height) texels on pages of at most page_size a side.
    ``pot``: crop pages to the next power of two a side (KTX2 mip chains halve each side exactly; CesiumJS
    resizes a mipmapped NPOT WebP page to the next power of two itself). The shelf packer fills a page's width
    first, so only its height rounds up: on Liechtenstein 1.04x the texels of multiple-of-4 crops (a repack
    into the smallest power-of-two rectangle that holds a page's charts gained nothing there, measured)."""
    _check_page_size(page_size, padding)
    if pot and page_size & (page_size - 1):
        raise ValueError(f"page_size must be a power of two for power-of-two pages, got {page_size}")
    if packer not in PACKERS:
        raise ValueError(f"unknown packer {packer!r} ({' or '.join(PACKERS)})")
    fitted, scaled = fit_sizes(np.asarray(sizes).reshape(-1, 2), page_size, padding)
    k = len(fitted)
    if k == 0:
        z = np.zeros(0, np.int64)
        return Layout(z, z, z, z, z, np.zeros(0, bool), np.zeros((0, 2), np.int64), padding, packer, 0.0)
    slots = fitted + 2 * padding
    t0 = time.perf_counter()
    if packer == "shelf":
        page, sx, sy = _shelf(slots, page_size)
    else:
        page, sx, sy = _xatlas(slots, page_size, brute_force)
    seconds = time.perf_counter() - t0
    # pages renumbered in order of first use, so page 0 always exists and none is empty
    _, page = np.unique(page, return_inverse=True)
    n_pages = int(page.max()) + 1
    if np.any(sx < 0) or np.any(sy < 0) or np.any(sx + slots[:, 0] > page_size) or np.any(sy + slots[:, 1] > page_size):
        raise RuntimeError(f"{packer} placed a texture outside its page")
    dims = _crop(page, sx + slots[:, 0], sy + slots[:, 1], n_pages, page_size, pot)
    return Layout(
        page=page,
        x=sx + padding,
        y=sy + padding,
        w=fitted[:, 0],
        h=fitted[:, 1],
        scaled=scaled,
        page_dims=dims,
        padding=padding,
        packer=packer,
        seconds=seconds,
    )


def _rgba(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.dtype != np.uint8:
        raise ValueError("texture pixels must be uint8")
    c = img.shape[2]
    if c == 4:
        return img
    if c == 3:
        return np.concatenate([img, np.full(img.shape[:2] + (1,), 255, np.uint8)], axis=2)
    if c == 1:
        return np.concatenate([np.repeat(img, 3, axis=2), np.full(img.shape[:2] + (1,), 255, np.uint8)], axis=2)
    raise ValueError(f"cannot use {c}-channel pixels")


def bake_repeat(
    image: np.ndarray, repeat: tuple[float, float], width: int, height: int, filter: str = FILTER
) -> np.ndarray:
    """(height, width, c): ``image`` repeated (across, down) times (fractions crop the last copy) and resampled
    to the chart size. The tile is first shrunk to about twice its final per-repeat size, so a texture
    repeated 500 times never builds a 500-copy intermediate: the cost follows the chart, not the repeats."""
    img = np.asarray(image)
    ru, rv = float(repeat[0]), float(repeat[1])
    if ru <= 0 or rv <= 0:
        raise ValueError("repeat counts must be > 0")
    th, tw = img.shape[:2]
    want_w = max(1, min(tw, math.ceil(2 * width / ru)))
    want_h = max(1, min(th, math.ceil(2 * height / rv)))
    if (want_w, want_h) != (tw, th):
        img = resize(img, want_w, want_h, filter)
        th, tw = want_h, want_w
    full_w = max(1, round(ru * tw))
    full_h = max(1, round(rv * th))
    tiled = np.tile(img, (math.ceil(full_h / th), math.ceil(full_w / tw)) + (1,) * (img.ndim - 2))
    return resize(tiled[:full_h, :full_w], width, height, filter)


def _content(req: TextureRequest, w: int, h: int, filter: str) -> np.ndarray:
    if req.generator is not None:
        img = np.asarray(req.generator(w, h))
        if img.shape[:2] != (h, w):  # a generator that ignores the size still gets resampled to it
            img = resize(img, w, h, filter)
    elif req.image is not None:
        img = (
            bake_repeat(req.image, req.repeat, w, h, filter)
            if req.repeat != (1.0, 1.0)
            else resize(req.image, w, h, filter)
        )
    else:
        raise ValueError("a texture request needs an image or a generator")
    return _rgba(img)


def pack(
    requests: Sequence[TextureRequest],
    page_size: int = PAGE_SIZE,
    packer: str = "shelf",
    padding: int = 2,
    brute_force: bool = False,
    filter: str = FILTER,
    pot: bool = False,
) -> Atlas:
    """Pack the requests onto pages (see the module doc). Each request is drawn once at its placed size
    (shrunk if it had to be: ``layout.scaled``), its gutter filled with its edge texels; unused texels get the
    mean colour of the page's content so coarse mip levels do not darken towards black."""
    t0 = time.perf_counter()
    lay = layout([r.size for r in requests], page_size, packer, padding, brute_force, pot)
    pages = [np.zeros((int(h), int(w), 4), np.uint8) for w, h in lay.page_dims]
    used = [np.zeros((int(h), int(w)), bool) for w, h in lay.page_dims]
    p = padding
    for i, req in enumerate(requests):
        w, h = int(lay.w[i]), int(lay.h[i])
        img = _content(req, w, h, filter)
        if p:
            img = np.pad(img, ((p, p), (p, p), (0, 0)), mode="edge")
        x0, y0 = int(lay.x[i]) - p, int(lay.y[i]) - p
        pages[lay.page[i]][y0 : y0 + h + 2 * p, x0 : x0 + w + 2 * p] = img
        used[lay.page[i]][y0 : y0 + h + 2 * p, x0 : x0 + w + 2 * p] = True
    for pg, u in zip(pages, used, strict=True):
        if not u.all():
            pg[~u] = np.round(pg[u].reshape(-1, 4).mean(axis=0)).astype(np.uint8)
    return Atlas(pages=pages, layout=lay, keys=[r.key for r in requests], seconds=time.perf_counter() - t0)


def page_uv(local: np.ndarray, rect: np.ndarray) -> np.ndarray:
    """(n, 2) float32 page UVs of chart-local coordinates ``local`` (n, 2) in [0, 1] (0, 0 = the texture's
    top-left corner), with ``rect`` (4,) or (n, 4) = (u0, v0, u1, v1) of the chart on its page."""
    loc = np.asarray(local, dtype=np.float64).reshape(-1, 2)
    r = np.broadcast_to(np.asarray(rect, dtype=np.float64), (len(loc), 4))
    return np.column_stack(
        [r[:, 0] + loc[:, 0] * (r[:, 2] - r[:, 0]), r[:, 1] + loc[:, 1] * (r[:, 3] - r[:, 1])]
    ).astype(np.float32)


def metric_to_local(uv_m: np.ndarray, origin_m: np.ndarray, size_m: np.ndarray) -> np.ndarray:
    """Chart-local [0, 1] coordinates of metric UVs (u along, v up; metres) for a chart spanning origin_m ..
    origin_m + size_m (broadcast per vertex). v is flipped: image rows run top-down, metres bottom-up."""
    uv = np.asarray(uv_m, dtype=np.float64).reshape(-1, 2)
    o = np.asarray(origin_m, dtype=np.float64)
    s = np.asarray(size_m, dtype=np.float64)
    loc = (uv - o) / s
    return np.column_stack([loc[:, 0], 1.0 - loc[:, 1]])


# --- encoding ------------------------------------------------------------------------------------------------

MIME = {"ktx2": "image/ktx2", "webp": "image/webp", "png": "image/png", "jpeg": "image/jpeg"}
_EXT = {"ktx2": "ktx2", "webp": "webp", "png": "png", "jpeg": "jpg"}


def writable_formats() -> list[str]:
    """Which of ktx2, webp, png, jpeg this OpenImageIO build can write (pip wheel 3.2.2: no KTX2 writer)."""
    oiio = openimageio()

    out = []
    for fmt in ("ktx2", "webp", "png", "jpeg"):
        o = oiio.ImageOutput.create("x." + _EXT[fmt])
        if o is not None:
            out.append(fmt)
    oiio.geterror()  # drop the "could not find a format writer" message
    return out


def encode_image(pixels: np.ndarray, fmt: str = "auto", quality: int = 90, method: int = 4) -> tuple[bytes, str]:
    """(bytes, mime type) of an (h, w, 1|3|4) uint8 image. fmt: ktx2, webp, png, jpeg, or auto (the first of
    ktx2, webp, png that can be written). webp/jpeg are lossy at ``quality``; an opaque alpha channel is
    dropped (JPEG has none, and OIIO's WebP writer would treat it as premultiplied). ``method``: libwebp's
    effort 0 (fast) .. 6."""
    oiio = openimageio()

    if fmt == "auto":
        fmt = next(f for f in writable_formats() if f != "jpeg")
    if fmt not in MIME:
        raise ValueError(f"unknown image format {fmt!r}")
    img = np.asarray(pixels)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.dtype != np.uint8:
        raise ValueError("encode_image expects uint8 pixels")
    if img.shape[2] in (2, 4) and (fmt == "jpeg" or np.all(img[:, :, -1] == 255)):
        img = img[:, :, :-1]
    img = np.ascontiguousarray(img)
    h, w, c = img.shape
    with tempfile.TemporaryDirectory(prefix="citylod-img-") as tmp:
        path = os.path.join(tmp, "page." + _EXT[fmt])
        out = oiio.ImageOutput.create(path)
        if out is None:
            oiio.geterror()
            raise RuntimeError(f"this OpenImageIO build has no {fmt} writer (it writes: {writable_formats()})")
        spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
        if fmt == "webp":
            spec.attribute("compression", f"webp:{quality}")
            spec.attribute("oiio:UnassociatedAlpha", 1)
            # 4 (the default) is libwebp's own default effort; OIIO's 6 is 4x slower for 4 % fewer bytes on pages
            spec.attribute("webp:method", int(method))
        elif fmt == "jpeg":
            spec.attribute("compression", f"jpeg:{quality}")
        if not out.open(path, spec) or not out.write_image(img) or not out.close():
            raise RuntimeError(f"writing {fmt} failed: {out.geterror()}")
        with open(path, "rb") as f:
            return f.read(), MIME[fmt]


def decode_image(data: bytes, fmt: str) -> np.ndarray:
    """(h, w, c) uint8 pixels of encoded image bytes (OpenImageIO reads files, so through a temp file)."""
    oiio = openimageio()

    with tempfile.TemporaryDirectory(prefix="citylod-img-") as tmp:
        path = os.path.join(tmp, "page." + _EXT[fmt])
        with open(path, "wb") as f:
            f.write(data)
        buf = oiio.ImageBuf(path)
        px = buf.get_pixels(oiio.UINT8)
        if buf.has_error:
            raise RuntimeError(f"decoding {fmt} failed: {buf.geterror()}")
        return np.asarray(px).reshape(buf.spec().height, buf.spec().width, buf.spec().nchannels)
