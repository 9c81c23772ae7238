"""Texturing one tile: charts of its meshes, the atlas pages holding their textures, a UV per triangle corner.

Pure (arrays in, arrays out; no database): the textures stage (etl/textures/stage.py) feeds it the meshes of
one tile as api.buildings_for_tile gives them and stores what comes out. It connects the procedural textures
(etl/textures/procedural.py) and the atlas (etl/textures/atlas.py):

* **Charts.** Triangles are sorted by their semantics (core/semantics.py) and orientation:
  - walls: one planar chart per feature and wall plane (textures.planar_charts: u metres along the wall, v
    metres up from its bottom), textured with the facade (building:material, building:colour) and its
    openings. Openings are the LOD3 window/door panels themselves: a panel stands FacadeParams.depth out of
    its wall, so it is matched to the wall chart of the same feature whose plane lies that far behind it; the
    panel is painted into that chart and its own triangles take UVs projected onto it, so the LOD3 boxes and
    the painted windows are the same rectangles. A LOD2 feature has no panels: it takes those of its LOD3
    mesh (the caller passes them, or the chart cache holds them from the leaves). Simplified solids and blocks
    get facade.py's layout on each wall (storeys from building:levels, windows from the wall length).
  - roofs: planar charts per roof face (u along the eaves, v up the slope; flat roofs aligned with the
    feature's longest wall, so a rotated building does not waste half its chart), roof:material and
    roof:colour. A roof of more than ``xatlas_min_planes`` faces (domes, onions, round and decimated roofs)
    gets xatlas charts on one metric sheet (textures.chart_uvs).
  - everything else (ground caps, panels without a wall, degenerate triangles) and every chart smaller than
    ``min_chart_texels`` takes a flat colour from the tile's *palette* (one small chart of flat texels): a
    procedural texture's mean is its tagged colour, which is all a chart of a few texels can show, and
    tiny charts would otherwise cost more gutter than texels.
* **Resolution.** Every chart of the tile gets ``rho`` texels per metre (the stage derives it from the
  distance the tile is seen from: atlas.texels_per_metre). Wall and roof patterns are functions of metric
  coordinates, box-filtered analytically (textures.py), so a chart rendered at a coarser level is the
  average of the fine one, not an aliased sample of it.
* **Pages.** atlas.layout places the charts (shelf packer by default) on pages of at most ``page_size``
  texels a side; the pages are then rendered here in one vectorised pass each: every texel of every chart
  of the page as one array, the wall/roof patterns evaluated per (material, colour) group and the openings per
  (opening, texel) pair. Per-chart calls of textures.facade_texture cost ~1 ms each in numpy overhead, the
  pass ~0.1 µs a texel. Gutters repeat each chart's edge texels; unused texels take the page's mean colour.
* **Cache.** A ``ChartCache`` shared by a LOD2 tile and the leaves below it keeps each leaf chart's
  pixels and openings: the same wall at the same resolution is copied, not rendered again; a larger cached
  chart is downsampled with OpenImageIO in linear light (atlas.resize).

Everything is deterministic: same meshes and tags, same pixels (seeds from the building's key, never from
Python's salted hash).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field

import numpy as np

from core.semantics import SEM_DOOR, SEM_ROOF, SEM_UNKNOWN, SEM_WALL, SEM_WINDOW
from etl.geom.facade import FacadeParams
from etl.textures import atlas as A
from etl.textures import procedural as T

KIND_WALL, KIND_ROOF, KIND_SHEET, KIND_PALETTE = 0, 1, 2, 3
OPENING_DEPTH = FacadeParams().depth  # LOD3 panels stand this far out of their wall
PATTERN_SHIFT_M = 9.0  # per-building pattern offsets are multiples of this (divides the common periods)


def _halfway(a: T.RGB, b: T.RGB) -> T.RGB:
    """The sRGB colour halfway between ``a`` and ``b``, rounded (a pane's mean: its glass runs from a to b)."""
    r, g, bl = (int(round((x + y) / 2)) for x, y in zip(a, b, strict=True))
    return (r, g, bl)


_WINDOW_RGB = _halfway(T._GLASS_LOW, T._GLASS_HIGH)
_DOOR_RGB = T._DOOR


@dataclass(frozen=True)
class Params:
    page_size: int = A.PAGE_SIZE
    padding: int = 2  # gutter texels around each chart
    packer: str = "shelf"
    min_chart_texels: int = 16  # smaller charts (or thinner than 2 texels) become flat palette colours
    xatlas_min_planes: int = 24  # roofs with more planar faces than this get xatlas charts
    palette_width: int = 16  # palette chart width in texels (rows added as needed)
    pot: bool = True  # pages cropped to powers of two a side (KTX2 mip chains; the WebP pages share the layout)


@dataclass(frozen=True)
class Style:
    """What a feature looks like: canonical materials and sRGB colours (textures.wall_material, parse_rgb)."""

    key: int  # identity of the building across levels (seeds the patterns, keys the cache)
    wall_material: str
    wall_rgb: tuple[int, int, int]
    roof_material: str
    roof_rgb: tuple[int, int, int]
    levels: float = math.nan  # building:levels; NaN = untagged (storeys from the wall height)
    generic_openings: bool = False  # windows by facade.py's rules on each wall (no LOD3 panels to follow)

    @classmethod
    def from_tags(
        cls,
        key: int,
        building_material: str | None,
        building_colour: str | None,
        roof_material: str | None,
        roof_colour: str | None,
        levels: float | None,
        generic_openings: bool = False,
    ) -> Style:
        wall = T.material_and_colour("wall", building_material, building_colour)
        roof = T.material_and_colour("roof", roof_material, roof_colour)
        return cls(key, *wall, *roof, math.nan if levels is None else float(levels), generic_openings)


@dataclass
class ChartCache:
    """Chart pixels and wall openings of the tiles already textured, for the tiles above them (one LOD2 tile
    and its leaves share one). Keys: (building key, chart kind, plane key, size in cm)."""

    pixels: dict[tuple, np.ndarray] = field(default_factory=dict)
    openings: dict[tuple, np.ndarray] = field(default_factory=dict)  # plane key -> (k, 5) s0 s1 z0 z1 kind
    buildings: set[int] = field(default_factory=set)  # building keys whose openings are known


@dataclass(frozen=True)
class TileTexture:
    pages: list[np.ndarray]  # (H, W, 3) uint8 sRGB each
    layout: A.Layout  # one request per chart; the palette is the last request when there is one
    chart_kind: np.ndarray  # (k,) int8 KIND_* per request
    tri_page: np.ndarray  # (m,) int16 page of each triangle
    tri_uv: np.ndarray  # (m, 3, 2) float32 page UV per corner, glTF convention ((0, 0) top left, v down)
    stats: dict[str, int] = field(default_factory=dict)

    def page_rects(self, page: int) -> np.ndarray:
        """(k, 4) int32 content boxes (x, y, w, h) in texels of the charts on ``page``."""
        lay = self.layout
        on = lay.page == page
        return np.column_stack([lay.x[on], lay.y[on], lay.w[on], lay.h[on]]).astype(np.int32)


# --- charts ---------------------------------------------------------------------------------------------------


@dataclass
class _Charts:
    """Planar charts of one kind: per triangle its chart and metric uv (from the chart's lower-left corner)."""

    chart: np.ndarray  # (t,) chart of each triangle
    uv: np.ndarray  # (t, 3, 2)
    size: np.ndarray  # (c, 2) metres
    origin: np.ndarray  # (c, 2) corner in the plane frame
    du: np.ndarray  # (c, 3)
    dv: np.ndarray  # (c, 3)
    group: np.ndarray  # (c,) feature
    key: np.ndarray  # (c, 5) plane key of the chart (its first triangle's)
    off: np.ndarray  # (c,) plane offset along the chart's normal (m)


def _planar(tri: np.ndarray, group: np.ndarray, align: dict[int, np.ndarray] | None = None) -> _Charts:
    """textures.planar_charts (horizontal charts turned to ``align[group]``), with plane keys and offsets."""
    pc = T.planar_charts(tri, group, align)
    f = pc.first
    return _Charts(
        pc.chart,
        pc.uv,
        pc.size,
        pc.origin,
        pc.du,
        pc.dv,
        pc.group,
        T.plane_keys(tri[f], group[f]),
        (pc.normal * tri[f, 0]).sum(axis=1),
    )


def _cache_keys(style_keys: list[int], kind: int, plane_keys: np.ndarray, size_m: np.ndarray) -> list[tuple]:
    """(building key, kind, plane key..., size in cm...) per chart: what identifies a chart across levels."""
    rest = np.column_stack([plane_keys[:, 1:], np.round(size_m * 100)]).astype(np.int64).tolist()
    return [(k, kind, *r) for k, r in zip(style_keys, rest, strict=True)]


def _unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    u, inv = np.unique(a, axis=0, return_inverse=True)
    return u, inv.reshape(-1)


# --- rendering ------------------------------------------------------------------------------------------------


class _Flat:
    """The texel field of textures.py (_Field) for a flat list of texels of many charts: per-texel metric
    coordinates and texel sizes; no tiling (charts are rendered whole)."""

    span = None

    def __init__(self, u: np.ndarray, v: np.ndarray, tu: np.ndarray, tv: np.ndarray):
        self.u, self.v, self.tu, self.tv = u, v, tu, tv
        self.t = np.sqrt(tu * tv)
        self.shape = u.shape

    def period(self, p: float, axis: int, group: int = 1) -> float:
        return p

    def wrap(self, i: np.ndarray, p: float, axis: int) -> np.ndarray:
        return i


def _cover(x: np.ndarray, t: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Fraction of each texel [x - t/2, x + t/2] inside [lo, hi] (per pair)."""
    return np.clip(np.minimum(x + t / 2, hi) - np.maximum(x - t / 2, lo), 0.0, None) / t


def _paint_openings(
    lin: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    tu: np.ndarray,
    tv: np.ndarray,
    tex: np.ndarray,
    op: np.ndarray,
    dark: np.ndarray,
    n: int,
) -> None:
    """textures._paint_openings for (texel, opening) pairs: ``tex`` the texel of each pair, ``op`` (pairs, 5)
    its opening (s0, s1, z0, z1, kind), ``dark`` (pairs,) whether its wall has dark frames. In place."""
    if len(tex) == 0:
        return
    s, z, ts, tz = u[tex], v[tex], tu[tex], tv[tex]
    s0, s1, z0, z1 = op[:, 0], op[:, 1], op[:, 2], op[:, 3]
    win = op[:, 4] == SEM_WINDOW
    fz = np.minimum(T.FRAME_WIDTH, 0.25 * (z1 - z0))
    fs = np.minimum(T.FRAME_WIDTH, 0.25 * (s1 - s0))
    cu_o, cv_o = _cover(s, ts, s0, s1), _cover(z, tz, z0, z1)
    cu_i, cv_i = _cover(s, ts, s0 + fs, s1 - fs), _cover(z, tz, z0 + fz, z1 - fz)
    mid = (s0 + s1) / 2
    cu_m = _cover(s, ts, mid - T.BAR_WIDTH / 2, mid + T.BAR_WIDTH / 2)
    zt = z0 + 0.7 * (z1 - z0)
    cv_t = _cover(z, tz, zt - T.BAR_WIDTH / 2, zt + T.BAR_WIDTH / 2)
    inner = cv_i * cu_i
    g = np.clip((z - z0) / (z1 - z0), 0, 1)

    def acc(w: np.ndarray) -> np.ndarray:
        return np.bincount(tex, weights=w, minlength=n)

    outer = acc(cv_o * cu_o)
    inner_w = acc(np.where(win, inner, 0.0))
    inner_d = acc(np.where(win, 0.0, inner))
    bars = acc(np.where(win, cv_i * cu_m + cv_t * cu_i - cv_t * cu_m, 0.0))
    gnum = acc(np.where(win, inner * g, 0.0))
    dark_t = acc(dark.astype(np.float64)) > 0  # per texel: all pairs of a texel share its wall
    at = np.flatnonzero(outer > 0)
    outer, inner_w, inner_d, bars, gnum = (x[at] for x in (outer, inner_w, inner_d, bars, gnum))
    glass = np.clip(inner_w - bars, 0, 1)
    frame = np.clip(outer - glass - inner_d, 0, 1)
    grad = gnum / np.maximum(inner_w, 1e-9)
    low, high = T._lin(T._GLASS_LOW), T._lin(T._GLASS_HIGH)
    frame_c = np.where(dark_t[at][:, None], T._lin(T._FRAME_DARK), T._lin(T._FRAME_LIGHT))
    lin[at] = (
        lin[at] * np.clip(1 - outer, 0, 1)[:, None]
        + frame_c * frame[:, None]
        + (low + (high - low) * grad[:, None]) * glass[:, None]
        + T._lin(_DOOR_RGB) * inner_d[:, None]
    )


@dataclass
class _Requests:
    kind: np.ndarray  # (k,) KIND_*
    style: np.ndarray  # (k,) feature index (-1 for the palette)
    size_m: np.ndarray  # (k, 2)
    openings: list[np.ndarray]  # per request (q, 5) s0 s1 z0 z1 kind (walls), else empty
    inset: np.ndarray  # (k, 2) 0.5 where the chart's edge texels are centred on its edges, else 0
    group: np.ndarray  # (k,) pattern group (kind, material, colour) of each request, -1 for the palette
    groups: list[tuple[str, str, tuple[int, int, int]]]  # the groups' (kind, material, colour)
    shift: np.ndarray  # (k,) metres added to u of the pattern (per building, a multiple of PATTERN_SHIFT_M)
    dark: np.ndarray  # (k,) the wall's window frames are dark


def _requests(
    kinds: np.ndarray,
    style: np.ndarray,
    size_m: np.ndarray,
    openings: list[np.ndarray],
    inset: np.ndarray,
    styles: list[Style],
) -> _Requests:
    keys: dict[tuple, int] = {}
    group = np.full(len(kinds), -1, np.int64)
    shift = np.zeros(len(kinds))
    dark = np.zeros(len(kinds), bool)
    offsets = [PATTERN_SHIFT_M * (zlib.crc32(str(s.key).encode()) % 97) for s in styles]
    for j, (k, f) in enumerate(zip(kinds.tolist(), style.tolist(), strict=True)):
        if k == KIND_PALETTE:
            continue
        s = styles[f]
        key = ("wall", s.wall_material, s.wall_rgb) if k == KIND_WALL else ("roof", s.roof_material, s.roof_rgb)
        group[j] = keys.setdefault(key, len(keys))
        shift[j] = offsets[f]
        dark[j] = s.wall_material in T._DARK_FRAMES
    return _Requests(kinds, style, size_m, openings, inset, group, list(keys), shift, dark)


def _insets(lay: A.Layout, kinds: np.ndarray) -> np.ndarray:
    """(k, 2) texel offsets o of the charts: a chart of w texels spans texel coordinates o .. w - o. Without
    gutters (padding 0) the outermost texel centres sit on the chart's edges (o = 0.5), so bilinear filtering
    never reads a neighbour's texel at full resolution (the edge texels straddle the edges by half a texel)."""
    o = np.zeros((len(kinds), 2))
    if lay.padding == 0:
        o[:, 0] = np.where(lay.w >= 2, 0.5, 0.0)
        o[:, 1] = np.where(lay.h >= 2, 0.5, 0.0)
        o[kinds == KIND_PALETTE] = 0.0  # palette UVs are texel centres already
    return o


_SRGB_LUT_SIZE = 1 << 14
_SRGB_LUT = A.linear_to_srgb((np.arange(_SRGB_LUT_SIZE) + 0.5) / _SRGB_LUT_SIZE)


def _to_srgb(lin: np.ndarray) -> np.ndarray:
    """atlas.linear_to_srgb through a 16k-entry table (within one level of it; 4x faster)."""
    i = (np.clip(lin, 0.0, 1.0) * _SRGB_LUT_SIZE).astype(np.int32)
    return _SRGB_LUT[np.minimum(i, _SRGB_LUT_SIZE - 1)]


@dataclass
class _PageCharts:
    """The charts of one page in the order of its flat texel list: the rendered ones first (grouped by pattern,
    so each group's texels are one contiguous slice), then the copies and the palette."""

    order: np.ndarray  # (c,) request of each chart
    rendered: int  # how many of the first charts are rendered
    w: np.ndarray  # (c,) texels
    h: np.ndarray  # (c,) texels
    starts: np.ndarray  # (c + 1,) first texel of each chart in the flat list, then their total

    @property
    def n_texels(self) -> int:
        """Texels of all the page's charts."""
        return int(self.starts[-1])

    @property
    def n_rendered(self) -> int:
        """Texels of the rendered charts (the first ones of the flat list)."""
        return int(self.starts[self.rendered])


@dataclass
class _PageTexels:
    """Metric coordinates and texel sizes of every rendered texel of a page, chart by chart, and the texel boxes
    of the walls' openings (per opening: its rectangle, its chart, its columns c0..c1 and rows j0..j1)."""

    u: np.ndarray  # metres along the chart (openings)
    up: np.ndarray  # the same shifted per building (patterns)
    v: np.ndarray
    tu: np.ndarray
    tv: np.ndarray
    ops: list[np.ndarray] = field(default_factory=list)
    idx: list[np.ndarray] = field(default_factory=list)
    c0: list[np.ndarray] = field(default_factory=list)
    c1: list[np.ndarray] = field(default_factory=list)
    j0: list[np.ndarray] = field(default_factory=list)
    j1: list[np.ndarray] = field(default_factory=list)


def _page_charts(lay: A.Layout, p: int, req: _Requests, given: dict[int, np.ndarray]) -> _PageCharts:
    """The charts on page ``p``, those to render (not in ``given``, not the palette) first, grouped by pattern."""
    on = np.flatnonzero(lay.page == p)
    render = np.array([j not in given and req.kind[j] != KIND_PALETTE for j in on.tolist()], bool)
    R = np.concatenate([on[render][np.argsort(req.group[on[render]], kind="stable")], on[~render]])
    w, h = lay.w[R], lay.h[R]
    area = w * h
    starts = np.concatenate([[0], np.cumsum(area)])
    return _PageCharts(R, int(render.sum()), w, h, starts)


def _fill_copies(out: np.ndarray, pc: _PageCharts, given: dict[int, np.ndarray], palette: np.ndarray) -> None:
    """The texels of the charts not rendered: the given pixels copied, the palette's flat colours. In place."""
    starts = pc.starts
    area = pc.w * pc.h
    for i in range(pc.rendered, len(pc.order)):  # copies and the palette
        j = int(pc.order[i])
        if j in given:
            out[starts[i] : starts[i + 1]] = given[j].reshape(-1, 3)
        else:
            out[starts[i] : starts[i + 1]] = palette[np.minimum(np.arange(area[i]), len(palette) - 1)]


def _page_texels(pc: _PageCharts, req: _Requests) -> _PageTexels:
    """The metric coordinates and texel sizes of every texel of the rendered charts (broadcast rows and columns),
    and the texel boxes of the walls' openings: every (opening, texel) pair is painted later."""
    n_render = pc.n_rendered
    tx = _PageTexels(np.empty(n_render), np.empty(n_render), np.empty(n_render), np.empty(n_render), np.empty(n_render))
    u, up, v, tu, tv = tx.u, tx.up, tx.v, tx.tu, tx.tv
    R, w, h, starts = pc.order, pc.w, pc.h, pc.starts
    for i in range(pc.rendered):
        j = int(R[i])
        wi, hi = int(w[i]), int(h[i])
        (W_m, H_m), (ox, oy) = req.size_m[j], req.inset[j]
        ts, tz = W_m / (wi - 2 * ox), H_m / (hi - 2 * oy)
        sl = slice(int(starts[i]), int(starts[i + 1]))
        uc = (np.arange(wi) + 0.5 - ox) * ts
        u[sl].reshape(hi, wi)[:] = uc
        up[sl].reshape(hi, wi)[:] = uc + req.shift[j]
        v[sl].reshape(hi, wi)[:] = (H_m - (np.arange(hi) + 0.5 - oy) * tz)[:, None]
        tu[sl] = ts
        tv[sl] = tz
        o = req.openings[j]
        if req.kind[j] == KIND_WALL and len(o):
            tx.ops.append(o)
            tx.idx.append(np.full(len(o), i))
            # texel k covers [(k - inset) t, (k + 1 - inset) t]
            tx.c0.append(np.clip(np.floor(o[:, 0] / ts + ox), 0, wi))
            tx.c1.append(np.clip(np.ceil(o[:, 1] / ts + ox), 0, wi))
            tx.j0.append(np.clip(np.floor((H_m - o[:, 3]) / tz + oy), 0, hi))
            tx.j1.append(np.clip(np.ceil((H_m - o[:, 2]) / tz + oy), 0, hi))
    return tx


def _paint_patterns(lin: np.ndarray, pc: _PageCharts, tx: _PageTexels, req: _Requests) -> None:
    """The wall and roof patterns of the rendered texels, one pass per (kind, material, colour): textures.py's own
    pattern functions on flat arrays. In place."""
    starts = pc.starts
    g_of = req.group[pc.order[: pc.rendered]]
    cuts = np.searchsorted(g_of, np.arange(len(req.groups) + 1))
    for g, (what, material, rgb) in enumerate(req.groups):
        if cuts[g] == cuts[g + 1]:
            continue
        sl = slice(int(starts[cuts[g]]), int(starts[cuts[g + 1]]))
        fld = _Flat(tx.up[sl], tx.v[sl], tx.tu[sl], tx.tv[sl])
        pattern = T._wall_pattern if what == "wall" else T._roof_pattern
        lin[sl] = pattern(material, T._lin(rgb), fld, T._seed(what, material, rgb, 0))


def _paint_page_openings(lin: np.ndarray, pc: _PageCharts, tx: _PageTexels, req: _Requests) -> None:
    """The openings over the patterns: every (opening, texel) pair of the walls' opening boxes. In place."""
    if not tx.ops:
        return
    R, w, starts = pc.order, pc.w, pc.starts
    op = np.concatenate(tx.ops)
    oi = np.concatenate(tx.idx)
    col0, row0 = np.concatenate(tx.c0).astype(np.int64), np.concatenate(tx.j0).astype(np.int64)
    nc = np.maximum(np.concatenate(tx.c1).astype(np.int64) - col0, 0)
    nrow = np.maximum(np.concatenate(tx.j1).astype(np.int64) - row0, 0)
    cnt = nc * nrow
    oo = np.repeat(np.arange(len(op)), cnt)
    kk = np.arange(int(cnt.sum())) - np.repeat(np.concatenate([[0], np.cumsum(cnt)[:-1]]), cnt)
    ncp = np.maximum(nc[oo], 1)
    tex = starts[oi[oo]] + (row0[oo] + kk // ncp) * w[oi[oo]] + col0[oo] + kk % ncp
    _paint_openings(lin, tx.u, tx.v, tx.tu, tx.tv, tex, op[oo], req.dark[R[oi[oo]]], pc.n_rendered)


def _compose_page(lay: A.Layout, p: int, pc: _PageCharts, out: np.ndarray) -> np.ndarray:
    """The page: the mean colour where no chart is (coarse mip levels do not darken towards black), each chart
    pasted, its gutter repeating its edge texels (slices per chart: cheaper than one gather over the page)."""
    R, w, h, starts = pc.order, pc.w, pc.h, pc.starts
    W, H = (int(d) for d in lay.page_dims[p])
    page = np.empty((H, W, 3), np.uint8)
    page[:] = np.round(out.mean(axis=0)).astype(np.uint8) if pc.n_texels else 0
    pad = lay.padding
    xs, ys = lay.x[R].tolist(), lay.y[R].tolist()
    for i in range(len(R)):
        x, y, wi, hi = xs[i], ys[i], int(w[i]), int(h[i])
        page[y : y + hi, x : x + wi] = out[starts[i] : starts[i + 1]].reshape(hi, wi, 3)
        if pad:
            page[y - pad : y, x : x + wi] = page[y, x : x + wi]
            page[y + hi : y + hi + pad, x : x + wi] = page[y + hi - 1, x : x + wi]
            page[y - pad : y + hi + pad, x - pad : x] = page[y - pad : y + hi + pad, x : x + 1]
            page[y - pad : y + hi + pad, x + wi : x + wi + pad] = page[y - pad : y + hi + pad, x + wi - 1 : x + wi]
    return page


def _render_page(
    lay: A.Layout, p: int, req: _Requests, palette: np.ndarray, given: dict[int, np.ndarray]
) -> np.ndarray:
    """(H, W, 3) uint8 page ``p``: its charts rendered (or copied from ``given``: request -> (h, w, 3) pixels),
    gutters repeating their edges, the rest in the page's mean colour."""
    pc = _page_charts(lay, p, req, given)
    out = np.zeros((pc.n_texels, 3), np.uint8)
    _fill_copies(out, pc, given, palette)
    if pc.n_rendered:
        tx = _page_texels(pc, req)
        lin = np.empty((pc.n_rendered, 3), np.float64)
        _paint_patterns(lin, pc, tx, req)
        _paint_page_openings(lin, pc, tx, req)
        out[: pc.n_rendered] = _to_srgb(lin)
    return _compose_page(lay, p, pc, out)


# --- the tile ---------------------------------------------------------------------------------------------------


def _checked(
    triangles: np.ndarray, feature: np.ndarray, semantics: np.ndarray, styles: list[Style], rho: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tile's triangles (m, 3, 3), features (m,) and semantics (m,) as arrays; an error where they do not
    fit together or ``rho`` is no density."""
    tri = np.asarray(triangles, np.float64).reshape(-1, 3, 3)
    feat = np.asarray(feature, np.int64).reshape(-1)
    sem = np.asarray(semantics, np.uint8).reshape(-1)
    m = len(tri)
    if not (len(feat) == len(sem) == m):
        raise ValueError("triangles, feature and semantics must have the same length")
    if m and (feat.min() < 0 or feat.max() >= len(styles)):
        raise ValueError("feature index out of range of styles")
    if not math.isfinite(rho) or rho <= 0:
        raise ValueError("rho (texels per metre) must be finite and > 0")
    if not np.isfinite(tri).all():
        raise ValueError("non-finite coordinates")
    return tri, feat, sem


@dataclass
class _Kinds:
    """What each triangle of the tile is (else it takes a flat colour): (m,) bool masks."""

    wall: np.ndarray
    roof: np.ndarray
    panel: np.ndarray  # a LOD3 window or door panel


def _kinds(tri: np.ndarray, sem: np.ndarray) -> _Kinds:
    """Walls, roofs and panels by semantics; SEM_UNKNOWN (and walls facing up) by orientation; degenerate
    triangles are none of them."""
    cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    a2 = np.linalg.norm(cr, axis=1)
    nz = cr[:, 2] / np.maximum(a2, 1e-300)
    good = a2 > 1e-9
    unknown = sem == SEM_UNKNOWN
    is_panel = good & ((sem == SEM_WINDOW) | (sem == SEM_DOOR))
    is_wall = good & ((sem == SEM_WALL) | unknown) & (np.abs(nz) < 0.5)
    is_roof = good & ~is_wall & ~is_panel & ((sem == SEM_ROOF) | ((sem == SEM_WALL) | unknown) & (nz >= 0.5))
    return _Kinds(is_wall, is_roof, is_panel)


@dataclass
class _Palette:
    """The tile's flat colours (sRGB -> index, in order of first use) and the colour of every triangle (used
    where it ends up without a chart)."""

    colours: dict[tuple[int, int, int], int]
    of_triangle: np.ndarray  # (m,) index into ``colours``


def _palette(styles: list[Style], feat: np.ndarray, sem: np.ndarray, kinds: _Kinds) -> _Palette:
    """Every triangle's flat colour: its feature's roof or wall colour, the glass or door colour of panels."""
    pal_colours: dict[tuple[int, int, int], int] = {}

    def colour_index(rgb: tuple[int, int, int]) -> int:
        r, g, b = (int(c) for c in rgb)
        return pal_colours.setdefault((r, g, b), len(pal_colours))

    m = len(feat)
    wall_col = np.array([colour_index(s.wall_rgb) for s in styles] or [0])
    roof_col = np.array([colour_index(s.roof_rgb) for s in styles] or [0])
    tri_pal = np.where(kinds.roof, roof_col[feat] if m else 0, wall_col[feat] if m else 0)
    if kinds.panel.any():
        tri_pal[kinds.panel & (sem == SEM_WINDOW)] = colour_index(_WINDOW_RGB)
        tri_pal[kinds.panel & (sem == SEM_DOOR)] = colour_index(_DOOR_RGB)
    return _Palette(pal_colours, tri_pal)


@dataclass
class _TileCharts:
    """The tile's planar wall charts, planar roof charts and xatlas roof sheets, with the triangles of each."""

    iw: np.ndarray  # triangles of the walls
    wc: _Charts
    ir: np.ndarray  # triangles of the planar roofs
    rc: _Charts
    sheets: list[tuple[int, np.ndarray, T.XatlasCharts]]  # (feature, its roof triangles, their xatlas charts)


def _roof_align(wc: _Charts) -> dict[int, np.ndarray]:
    """Per feature, the direction of its longest wall: its flat roof charts are turned to it."""
    align: dict[int, np.ndarray] = {}
    if len(wc.size):
        longest = np.lexsort((-wc.size[:, 0], wc.group))
        first = np.concatenate([[True], wc.group[longest][1:] != wc.group[longest][:-1]])
        align = {int(wc.group[c]): wc.du[c] for c in longest[first]}
    return align


def _sheets(
    tri: np.ndarray, feat: np.ndarray, ir: np.ndarray, sheet_feats: list[int], rho: float, params: Params
) -> tuple[list[tuple[int, np.ndarray, T.XatlasCharts]], np.ndarray]:
    """xatlas charts of the roofs of ``sheet_feats`` and which roof triangles (of ``ir``) they took: a feature
    whose xatlas run fails keeps its planar charts."""
    sheets: list[tuple[int, np.ndarray, T.XatlasCharts]] = []
    on_sheet = np.isin(feat[ir], sheet_feats)
    for f in sheet_feats:
        idx = ir[feat[ir] == f]
        pts, inv = np.unique(tri[idx].reshape(-1, 3), axis=0, return_inverse=True)
        try:
            xc = T.chart_uvs(pts, inv.reshape(-1, 3), texels_per_metre=rho, padding=params.padding or 1)
        except (RuntimeError, ValueError):
            on_sheet[feat[ir] == f] = False  # xatlas failed: keep the planar charts
            continue
        sheets.append((f, idx, xc))
    return sheets, on_sheet


def _charts(
    tri: np.ndarray, feat: np.ndarray, kinds: _Kinds, styles: list[Style], rho: float, params: Params
) -> _TileCharts:
    """Walls: planar charts per (feature, plane); roofs: planar unless a feature's roof has too many planes
    (then xatlas)."""
    iw = np.flatnonzero(kinds.wall)
    wc = _planar(tri[iw], feat[iw])
    ir = np.flatnonzero(kinds.roof)
    align = _roof_align(wc)
    rc = _planar(tri[ir], feat[ir], align)
    sheet_feats: list[int] = []
    if len(rc.size):
        planes = np.bincount(rc.group, minlength=len(styles))
        sheet_feats = np.flatnonzero(planes > params.xatlas_min_planes).tolist()
    sheets: list[tuple[int, np.ndarray, T.XatlasCharts]] = []
    if sheet_feats:
        sheets, on_sheet = _sheets(tri, feat, ir, sheet_feats, rho, params)
        if on_sheet.any():
            ir = ir[~on_sheet]
            rc = _planar(tri[ir], feat[ir], align)
    return _TileCharts(iw, wc, ir, rc, sheets)


class _WallFrames:
    """The tile's wall charts as the hosts of LOD3 panels: which wall chart a panel lies on, and where."""

    def __init__(self, wc: _Charts):
        self.wc = wc
        self.plane_key = {(int(wc.group[c]), *(int(v) for v in wc.key[c, 1:])): c for c in range(len(wc.size))}

    def host(self, ptri: np.ndarray, pfeat: np.ndarray) -> np.ndarray:
        """Wall chart behind each panel triangle (-1: none): the same feature and normal, OPENING_DEPTH behind
        (the plane key's 1 cm rounding is allowed one step either way)."""
        out = np.full(len(ptri), -1, np.int64)
        if not len(ptri) or not self.plane_key:
            return out
        keys = T.plane_keys(ptri, pfeat, OPENING_DEPTH)
        uk, inv = _unique_rows(keys)
        found = np.full(len(uk), -1, np.int64)
        for j, kk in enumerate(uk.tolist()):
            for d in (0, -1, 1):
                c = self.plane_key.get((kk[0], kk[1], kk[2], kk[3], kk[4] + d))
                if c is not None:
                    found[j] = c
                    break
        return found[inv]

    def uv(self, ptri: np.ndarray, chart: np.ndarray) -> np.ndarray:
        """(k, 3, 2) metric (s, z) of triangle corners in their host wall chart's frame."""
        wc = self.wc
        pu = (ptri * wc.du[chart][:, None, :]).sum(-1) - wc.origin[chart][:, None, 0]
        pv = (ptri * wc.dv[chart][:, None, :]).sum(-1) - wc.origin[chart][:, None, 1]
        return np.stack([pu, pv], axis=-1)

    @staticmethod
    def rects(puv: np.ndarray, chart: np.ndarray, psem: np.ndarray) -> np.ndarray:
        """(k, 6) chart, s0, s1, z0, z1, kind: each panel's rectangle; the two triangles of a panel give the
        same one."""
        r = np.column_stack(
            [chart, puv[..., 0].min(1), puv[..., 0].max(1), puv[..., 1].min(1), puv[..., 1].max(1), psem]
        )
        return np.unique(np.round(r, 6), axis=0)


@dataclass
class _WallOpenings:
    """The openings of every wall chart, in its own metric frame (s along the wall from its start, z up from its
    bottom), and where the tile's own LOD3 panels lie on the wall charts."""

    per_chart: list[np.ndarray]  # (q, 5) s0 s1 z0 z1 kind of each wall chart
    keys: list[tuple]  # cache key of each wall chart (empty without a cache)
    panels: np.ndarray  # triangles of the panels
    host: np.ndarray  # wall chart of each panel triangle (-1: none)
    uv: np.ndarray  # (panels, 3, 2) metric (s, z) of the panel triangles in their host's frame


def _own_panels(
    tri: np.ndarray, feat: np.ndarray, sem: np.ndarray, ip: np.ndarray, frames: _WallFrames, stats: dict[str, int]
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """(host, uv, rectangles) of the tile's own panel triangles ``ip``: the wall chart each lies on, its corners
    in that chart's frame, and the rectangles they make (_WallFrames.rects)."""
    found_rects: list[np.ndarray] = []
    panel_host = np.full(len(ip), -1, np.int64)
    panel_uv = np.zeros((len(ip), 3, 2))
    if len(ip):
        panel_host = frames.host(tri[ip], feat[ip])
        ok = panel_host >= 0
        if ok.any():
            panel_uv[ok] = frames.uv(tri[ip[ok]], panel_host[ok])
            found_rects.append(frames.rects(panel_uv[ok], panel_host[ok], sem[ip[ok]]))
            stats["panels_mapped"] = int(ok.sum())
    return panel_host, panel_uv, found_rects


def _given_panels(
    opening_triangles: tuple[np.ndarray, np.ndarray, np.ndarray] | None, frames: _WallFrames
) -> list[np.ndarray]:
    """The rectangles the caller's LOD3 window/door panels (of LOD2 features) make on the wall charts."""
    if opening_triangles is None or not len(opening_triangles[0]):
        return []
    otri = np.asarray(opening_triangles[0], np.float64).reshape(-1, 3, 3)
    ofeat = np.asarray(opening_triangles[1], np.int64)
    osem = np.asarray(opening_triangles[2], np.uint8)
    keep = (osem == SEM_WINDOW) | (osem == SEM_DOOR)
    hc = frames.host(otri[keep], ofeat[keep])
    if (hc >= 0).any():
        return [frames.rects(frames.uv(otri[keep][hc >= 0], hc[hc >= 0]), hc[hc >= 0], osem[keep][hc >= 0])]
    return []


def _place_rects(found_rects: list[np.ndarray], wopen: list[np.ndarray]) -> np.ndarray:
    """Each wall chart's rectangles of ``found_rects`` as its openings (sorted by chart, z0, s0; in place); (nw,)
    whether a chart got any."""
    nw = len(wopen)
    has_found = np.zeros(nw, bool)
    if found_rects:
        allr = np.concatenate(found_rects)
        allr = allr[np.lexsort((allr[:, 1], allr[:, 3], allr[:, 0]))]
        cuts = np.searchsorted(allr[:, 0], np.arange(nw + 1))
        for c in np.flatnonzero(np.diff(cuts)).tolist():
            wopen[c] = allr[cuts[c] : cuts[c + 1], 1:]
            has_found[c] = True
    return has_found


def _cached_openings(cache: ChartCache, wkeys: list[tuple], wopen: list[np.ndarray], has_found: np.ndarray) -> None:
    """Walls of LOD2 features without panels: the openings the leaves below found on the same wall. In place."""
    for c in np.flatnonzero(~has_found).tolist():
        o = cache.openings.get(wkeys[c][:-2])
        if o is not None:
            wopen[c] = o
            has_found[c] = True


def _generic_openings(wc: _Charts, styles: list[Style], wopen: list[np.ndarray], has_found: np.ndarray) -> None:
    """Simplified solids and blocks: facade.py's layout on each wall as a free-standing wall. In place."""
    gen = np.array([styles[g].generic_openings for g in wc.group.tolist()], bool) & ~has_found
    if gen.any():
        gi = np.flatnonzero(gen)
        n = len(gi)
        lv = np.array([styles[g].levels for g in wc.group[gi].tolist()])
        op = T.wall_openings(
            np.zeros((n, 2)),
            np.column_stack([wc.size[gi, 0], np.zeros(n)]),
            np.arange(n),
            0.0,
            wc.size[gi, 1],
            lv,
            False,
            True,
        )
        cuts = np.searchsorted(op.wall, np.arange(n + 1))
        for j in np.flatnonzero(np.diff(cuts)).tolist():
            lo, hi = cuts[j], cuts[j + 1]
            wopen[gi[j]] = np.column_stack([op.s0[lo:hi], op.s1[lo:hi], op.z0[lo:hi], op.z1[lo:hi], op.kind[lo:hi]])


def _wall_openings(
    tri: np.ndarray,
    feat: np.ndarray,
    sem: np.ndarray,
    kinds: _Kinds,
    wc: _Charts,
    styles: list[Style],
    opening_triangles: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    cache: ChartCache | None,
    stats: dict[str, int],
) -> _WallOpenings:
    """The openings of every wall chart: its own LOD3 panels and the caller's, else those the cache holds for the
    wall, else (simplified solids and blocks) facade.py's layout."""
    wopen: list[np.ndarray] = [np.zeros((0, 5))] * len(wc.size)
    frames = _WallFrames(wc)
    ip = np.flatnonzero(kinds.panel)
    panel_host, panel_uv, found_rects = _own_panels(tri, feat, sem, ip, frames, stats)
    found_rects += _given_panels(opening_triangles, frames)
    has_found = _place_rects(found_rects, wopen)
    wkeys = (
        _cache_keys([styles[g].key for g in wc.group.tolist()], KIND_WALL, wc.key, wc.size) if cache is not None else []
    )
    if cache is not None:
        _cached_openings(cache, wkeys, wopen, has_found)
    _generic_openings(wc, styles, wopen, has_found)
    return _WallOpenings(wopen, wkeys, ip, panel_host, panel_uv)


@dataclass
class _StripLayout:
    """The wall charts chained into strips (_strips): each strip's charts and size, each chart's strip and the
    metres from its strip's start to its own."""

    members: list[list[int]]
    of: np.ndarray  # (nw,) strip of each wall chart
    u_off: np.ndarray  # (nw,)
    size: np.ndarray  # (ns, 2) metres


def _strip_layout(wc: _Charts, params: Params, rho: float) -> _StripLayout:
    """Strips: the walls of a feature chained end to start (same bottom) into one chart each, u running on
    around the corners, so neighbouring walls need no gutter between them."""
    nw = len(wc.size)
    room = (params.page_size - 2 * params.padding) / rho  # metres that fit across a page
    strips = _strips(wc, feat_of_chart=wc.group, room_m=room)
    ns = len(strips)
    strip_of = np.zeros(nw, np.int64)
    u_off = np.zeros(nw)
    strip_size = np.zeros((ns, 2))
    for s, members in enumerate(strips):
        mem = np.asarray(members)
        strip_of[mem] = s
        u_off[mem] = np.concatenate([[0.0], np.cumsum(wc.size[mem, 0])[:-1]])
        strip_size[s] = (wc.size[mem, 0].sum(), wc.size[mem, 1].max())
    return _StripLayout(strips, strip_of, u_off, strip_size)


@dataclass
class _Planned:
    """The tile's chart requests before the layout (strips, roof charts, sheets, then the palette): per request
    its kind, size, feature, openings, cache key, texels and (strips) wall charts."""

    kinds: np.ndarray  # (k,) int8 KIND_*
    size_m: np.ndarray  # (k, 2)
    style: np.ndarray  # (k,) feature (-1: the palette)
    openings: list[np.ndarray]  # (q, 5) s0 s1 z0 z1 kind, in the strip's frame
    ckeys: list[tuple | None]  # chart cache key (None: not cached)
    px: np.ndarray  # (k, 2) texels
    members: list[list[int]]  # wall charts of a strip, else empty


def _planned(
    ch: _TileCharts, walls: _WallOpenings, st: _StripLayout, styles: list[Style], cache: ChartCache | None, rho: float
) -> _Planned:
    """Requests: strips (with their walls' openings, shifted along the strip), roof charts, sheets."""
    wc, rc, sheets = ch.wc, ch.rc, ch.sheets
    strips, wopen, wkeys = st.members, walls.per_chart, walls.keys
    ns, nr = len(strips), len(rc.size)
    kinds = np.concatenate([np.full(ns, KIND_WALL), np.full(nr, KIND_ROOF), np.full(len(sheets), KIND_SHEET)]).astype(
        np.int8
    )
    size_m = np.concatenate([st.size, rc.size, np.array([x.size_m for _, _, x in sheets]).reshape(-1, 2)])
    req_style = np.concatenate(
        [
            wc.group[[s[0] for s in strips]] if ns else np.zeros(0, np.int64),
            rc.group,
            np.array([f for f, _, _ in sheets], np.int64),
        ]
    ).astype(np.int64)
    req_open: list[np.ndarray] = []
    ckeys: list[tuple | None] = []
    for members in strips:
        ops = [wopen[c] + np.array([st.u_off[c], st.u_off[c], 0, 0, 0]) for c in members if len(wopen[c])]
        req_open.append(np.concatenate(ops) if ops else np.zeros((0, 5)))
        ckeys.append((wkeys[members[0]][0], KIND_WALL, tuple(wkeys[c][2:] for c in members)) if wkeys else None)
    req_open += [np.zeros((0, 5))] * (nr + len(sheets))
    ckeys += (
        _cache_keys([styles[g].key for g in rc.group.tolist()], KIND_ROOF, rc.key, rc.size)
        if cache is not None
        else [None] * nr
    )
    ckeys += [None] * len(sheets)
    px = A.texels(size_m, rho)
    return _Planned(kinds, size_m, req_style, req_open, ckeys, px, strips + [[]] * (nr + len(sheets)))


def _to_local(uv: np.ndarray, size: np.ndarray) -> np.ndarray:
    """Chart-local coordinates ([0, 1], y down) of metric uv in charts of ``size`` metres."""
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero-extent chart's NaNs are zeroed below
        return np.stack([uv[..., 0] / size[:, None, 0], 1 - uv[..., 1] / size[:, None, 1]], axis=-1)


def _triangle_charts(m: int, ch: _TileCharts, walls: _WallOpenings, st: _StripLayout) -> tuple[np.ndarray, np.ndarray]:
    """(request, chart-local coordinates) of every triangle: (m,) -1 where none (the palette's), (m, 3, 2) in
    [0, 1], image orientation (y down)."""
    wc, rc, iw, ir = ch.wc, ch.rc, ch.iw, ch.ir
    ns, nr = len(st.members), len(rc.size)
    tri_chart = np.full(m, -1, np.int64)
    tri_local = np.zeros((m, 3, 2))
    if len(wc.size):
        w_uv = wc.uv + np.stack([st.u_off[wc.chart], np.zeros(len(iw))], axis=-1)[:, None, :]
        tri_chart[iw] = st.of[wc.chart]
        tri_local[iw] = _to_local(w_uv, st.size[st.of[wc.chart]])
        ok = walls.host >= 0
        if ok.any():
            hc = walls.host[ok]
            p_uv = walls.uv[ok] + np.stack([st.u_off[hc], np.zeros(len(hc))], axis=-1)[:, None, :]
            tri_chart[walls.panels[ok]] = st.of[hc]
            tri_local[walls.panels[ok]] = _to_local(p_uv, st.size[st.of[hc]])
    tri_chart[ir] = ns + rc.chart
    tri_local[ir] = _to_local(rc.uv, rc.size[rc.chart])
    for j, (_, idx, xc) in enumerate(ch.sheets):
        tri_chart[idx] = ns + nr + j
        tri_local[idx] = xc.local[xc.faces]
    return tri_chart, np.nan_to_num(np.clip(tri_local, 0.0, 1.0))  # zero-extent charts (e.g. 0 m high)


def _drop_tiny(
    pl: _Planned, tri_chart: np.ndarray, ns: int, params: Params, stats: dict[str, int]
) -> tuple[_Planned, np.ndarray]:
    """Tiny charts: their triangles take the flat colour instead; only the charts in use kept, renumbered (the
    requests kept, and every triangle's request: -1 for the palette)."""
    px = pl.px
    tiny = (px.prod(axis=1) < params.min_chart_texels) | (px.min(axis=1, initial=2) < 2)
    stats["openings"] = sum(len(pl.openings[i]) for i in range(ns) if not tiny[i])
    if len(tiny):
        tri_chart[(tri_chart >= 0) & tiny[np.maximum(tri_chart, 0)]] = -1
    keep_req = ~tiny
    used = np.zeros(len(keep_req), bool)
    used[tri_chart[tri_chart >= 0]] = True
    keep_req &= used
    new_id = np.full(len(keep_req), -1, np.int64)
    new_id[keep_req] = np.arange(int(keep_req.sum()))
    if len(new_id):
        tri_chart = np.where(tri_chart >= 0, new_id[np.maximum(tri_chart, 0)], -1)
    old_ids = np.flatnonzero(keep_req).tolist()
    stats["flat"] = int(tiny.sum())
    kept = _Planned(
        pl.kinds[keep_req],
        pl.size_m[keep_req],
        pl.style[keep_req],
        [pl.openings[i] for i in old_ids],
        [pl.ckeys[i] for i in old_ids],
        px[keep_req],
        [pl.members[i] for i in old_ids],
    )
    return kept, tri_chart


def _add_palette(
    pl: _Planned, pal: _Palette, tri_chart: np.ndarray, tri_local: np.ndarray, params: Params
) -> np.ndarray:
    """The palette: the flat colours of every triangle without a chart, as one more request (``pl``,
    ``tri_chart`` and ``tri_local`` in place); its (n, 3) uint8 colours."""
    flat = tri_chart < 0
    palette = np.zeros((0, 3), np.uint8)
    if flat.any():
        pal_used = np.unique(pal.of_triangle[flat])
        palette = np.array(list(pal.colours), np.uint8).reshape(-1, 3)[pal_used]
        pw = min(len(palette), params.palette_width)
        ph = -(-len(palette) // pw)
        pl.kinds = np.append(pl.kinds, np.int8(KIND_PALETTE))
        pl.size_m = np.vstack([pl.size_m, [[pw, ph]]]).astype(np.float64)
        pl.style = np.append(pl.style, -1)
        pl.px = np.vstack([pl.px, [[pw, ph]]]).astype(np.int64)
        pl.openings.append(np.zeros((0, 5)))
        pl.ckeys.append(None)
        pl.members.append([])
        slot = np.searchsorted(pal_used, pal.of_triangle[flat])
        tri_chart[flat] = len(pl.kinds) - 1
        tri_local[flat] = np.stack([((slot % pw) + 0.5) / pw, ((slot // pw) + 0.5) / ph], axis=-1)[:, None, :]
    return palette


def _from_cache(
    cache: ChartCache | None, ckeys: list[tuple | None], lay: A.Layout, stats: dict[str, int]
) -> dict[int, np.ndarray]:
    """Cached pixels (request -> (h, w, 3)): the same size copied, larger downsampled (OpenImageIO, linear
    light); the others are rendered."""
    given: dict[int, np.ndarray] = {}
    if cache is not None:
        for j, key in enumerate(ckeys):
            img = cache.pixels.get(key) if key is not None else None
            if img is None:
                continue
            w, h = int(lay.w[j]), int(lay.h[j])
            if img.shape[:2] == (h, w):
                given[j] = img
                stats["copied"] += 1
            elif img.shape[0] >= h and img.shape[1] >= w:
                given[j] = A.resize(img, w, h)
                stats["resized"] += 1
    return given


def _page_uvs(lay: A.Layout, ins: np.ndarray, tri_chart: np.ndarray, tri_local: np.ndarray) -> np.ndarray:
    """(m, 3, 2) float32 page UVs per corner, glTF convention: the chart-local coordinates in the chart's box."""
    m = len(tri_chart)
    dims = lay.page_dims[lay.page[tri_chart]].astype(np.float64)  # (m, 2)
    o = ins[tri_chart]
    uv = np.empty((m, 3, 2), np.float32)
    uv[..., 0] = (
        lay.x[tri_chart, None] + o[:, None, 0] + tri_local[..., 0] * (lay.w[tri_chart, None] - 2 * o[:, None, 0])
    ) / dims[:, None, 0]
    uv[..., 1] = (
        lay.y[tri_chart, None] + o[:, None, 1] + tri_local[..., 1] * (lay.h[tri_chart, None] - 2 * o[:, None, 1])
    ) / dims[:, None, 1]
    return uv


def _store(
    cache: ChartCache,
    ckeys: list[tuple | None],
    lay: A.Layout,
    pages: list[np.ndarray],
    members_of: list[list[int]],
    walls: _WallOpenings,
    styles: list[Style],
    feat: np.ndarray,
) -> None:
    """This tile's chart pixels and wall openings into ``cache``, for the tiles above it (a leaf's)."""
    for j, key in enumerate(ckeys):
        if key is None:
            continue
        x, y, w, h = (int(t) for t in (lay.x[j], lay.y[j], lay.w[j], lay.h[j]))
        cache.pixels[key] = pages[lay.page[j]][y : y + h, x : x + w].copy()
        for c in members_of[j]:
            if len(walls.per_chart[c]):
                cache.openings[walls.keys[c][:-2]] = walls.per_chart[c]
    cache.buildings.update(styles[f].key for f in np.unique(feat).tolist())


def texture_tile(
    triangles: np.ndarray,
    feature: np.ndarray,
    semantics: np.ndarray,
    styles: list[Style],
    rho: float,
    params: Params = Params(),  # noqa: B008 -- frozen
    opening_triangles: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    cache: ChartCache | None = None,
    store: bool = False,
) -> TileTexture:
    """Charts, pages and per-corner UVs for one tile.

    triangles (m, 3, 3) in a metric CRS with z up (the working CRS), ``feature`` (m,) index into ``styles``,
    ``semantics`` (m,) core/semantics.py codes (SEM_UNKNOWN: by orientation). ``opening_triangles`` =
    (triangles, feature, semantics) of LOD3 window/door panels for features whose own mesh has none (LOD2).
    ``cache``: reuse chart pixels and openings found there; ``store``: add this tile's to it (leaves)."""
    tri, feat, sem = _checked(triangles, feature, semantics, styles, rho)
    m = len(tri)
    stats = dict.fromkeys(
        (
            "charts",
            "wall_charts",
            "roof_charts",
            "sheets",
            "flat",
            "panels_mapped",
            "openings",
            "copied",
            "resized",
            "rendered_texels",
            "content_texels",
            "scaled",
        ),
        0,
    )
    kinds = _kinds(tri, sem)
    pal = _palette(styles, feat, sem, kinds)
    ch = _charts(tri, feat, kinds, styles, rho, params)
    walls = _wall_openings(tri, feat, sem, kinds, ch.wc, styles, opening_triangles, cache, stats)
    st = _strip_layout(ch.wc, params, rho)
    pl = _planned(ch, walls, st, styles, cache, rho)
    tri_chart, tri_local = _triangle_charts(m, ch, walls, st)
    pl, tri_chart = _drop_tiny(pl, tri_chart, len(st.members), params, stats)
    palette = _add_palette(pl, pal, tri_chart, tri_local, params)
    kinds_of = pl.kinds
    if not len(kinds_of):
        lay = A.layout(np.zeros((0, 2), np.int64), params.page_size, params.packer, params.padding, pot=params.pot)
        return TileTexture([], lay, kinds_of, np.full(m, -1, np.int16), np.zeros((m, 3, 2), np.float32), stats)
    lay = A.layout(pl.px, params.page_size, params.packer, params.padding, pot=params.pot)
    ins = _insets(lay, kinds_of)
    req = _requests(kinds_of, pl.style, pl.size_m, pl.openings, ins, styles)
    # pixels differ with the inset: it is part of the cache key
    ckeys = [None if k is None else (*k, bool(ins[j].any())) for j, k in enumerate(pl.ckeys)]
    given = _from_cache(cache, ckeys, lay, stats)
    pages = [_render_page(lay, p, req, palette, given) for p in range(lay.n_pages)]
    uv = _page_uvs(lay, ins, tri_chart, tri_local)
    content = lay.w * lay.h
    stats.update(
        charts=len(kinds_of),
        wall_charts=int((kinds_of == KIND_WALL).sum()),
        walls=len(ch.wc.size),
        roof_charts=int((kinds_of == KIND_ROOF).sum()),
        sheets=int((kinds_of == KIND_SHEET).sum()),
        content_texels=int(content.sum()),
        scaled=int(lay.scaled.sum()),
        rendered_texels=int(content.sum() - sum(content[j] for j in given)),
    )
    if cache is not None and store:
        _store(cache, ckeys, lay, pages, pl.members, walls, styles, feat)
    return TileTexture(pages, lay, kinds_of, lay.page[tri_chart].astype(np.int16), uv, stats)


def _strip_links(wc: _Charts, feat_of_chart: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(next, previous) wall chart of each (-1: none): c is followed by the vertical chart of the same feature
    whose bottom start is c's bottom end (1 cm), with the same bottom; a chart two charts both point to keeps one
    predecessor (the other's chain ends there; ``previous`` is as found, before that cut)."""
    nw = len(wc.size)
    vertical = np.abs(wc.dv[:, 2]) > 1 - 1e-9
    # bottom corners in the plane: (u, v = z) -> world xy = u du + off n (du, n horizontal for vertical walls)
    n = np.cross(wc.du, wc.dv)
    z0 = wc.origin[:, 1]
    a_xy = wc.du[:, :2] * wc.origin[:, :1] + n[:, :2] * wc.off[:, None]
    b_xy = wc.du[:, :2] * (wc.origin[:, :1] + wc.size[:, :1]) + n[:, :2] * wc.off[:, None]

    # corners and bottoms on a 1 cm grid, per feature
    ka = np.column_stack([feat_of_chart, np.round(a_xy * 100), np.round(z0 * 100)]).astype(np.int64)
    kb = np.column_stack([feat_of_chart, np.round(b_xy * 100), np.round(z0 * 100)]).astype(np.int64)
    vert = np.flatnonzero(vertical).tolist()
    starts: dict[tuple, int] = {}
    for c, k in zip(vert, map(tuple, ka[vert].tolist()), strict=True):
        starts.setdefault(k, c)
    nxt = np.full(nw, -1, np.int64)
    for c, k in zip(vert, map(tuple, kb[vert].tolist()), strict=True):
        d = starts.get(k)
        if d is not None and d != c:
            nxt[c] = d
    prev = np.full(nw, -1, np.int64)
    has = nxt >= 0
    prev[nxt[has]] = np.flatnonzero(has)
    # a chart two charts both point to keeps one predecessor: the other's chain ends there
    for c in np.flatnonzero(has).tolist():
        if prev[nxt[c]] != c:
            nxt[c] = -1
    return nxt, prev


def _chains(nxt: np.ndarray, prev: np.ndarray) -> list[list[int]]:
    """The charts followed along ``nxt``: open chains from their first chart, then rings cut at their lowest."""
    nw = len(nxt)
    seen = np.zeros(nw, bool)
    chains: list[list[int]] = []

    def walk(c: int) -> None:
        chain = []
        while c >= 0 and not seen[c]:
            seen[c] = True
            chain.append(c)
            c = int(nxt[c])
        chains.append(chain)

    for c in range(nw):  # open chains from their first chart
        if not seen[c] and prev[c] < 0:
            walk(c)
    for c in range(nw):  # rings, cut at their lowest chart
        if not seen[c]:
            walk(c)
    return chains


def _cut_strips(chains: list[list[int]], size: np.ndarray, room_m: float) -> list[list[int]]:
    """The chains cut where a strip would exceed ``room_m`` metres, sorted by their first chart."""
    out: list[list[int]] = []
    for chain in chains:
        cur: list[int] = []
        length = 0.0
        for c in chain:
            w = float(size[c, 0])
            if cur and length + w > room_m:
                out.append(cur)
                cur, length = [], 0.0
            cur.append(c)
            length += w
        out.append(cur)
    return sorted(out, key=lambda s: s[0])


def _strips(wc: _Charts, feat_of_chart: np.ndarray, room_m: float) -> list[list[int]]:
    """Wall charts chained into strips: chart c is followed by the chart of the same feature whose bottom
    start is c's bottom end (1 cm), both vertical with the same bottom; rings are cut at their lowest chart;
    a strip is cut where it would exceed ``room_m`` (a page). Every chart is in exactly one strip, in order."""
    if not len(wc.size):
        return []
    nxt, prev = _strip_links(wc, feat_of_chart)
    return _cut_strips(_chains(nxt, prev), wc.size, room_m)
