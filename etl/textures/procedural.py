"""Procedural facade and roof textures from OSM tags, and the metric UVs that place them. Pure numpy (xatlas for
curved surfaces); no database, no randomness that is not derived from the inputs.

Textures are *functions of metric surface coordinates*: u metres along a wall (from its start a) or along a
roof's eaves, v metres up the wall (from its bottom) or up the slope. An image is those functions sampled at
its texel centres, so a pattern has the same physical size on every wall, a chart of any size or resolution
shows the same bricks at the same places, and two walls rendered at different densities agree where they
overlap. Every feature is box-filtered analytically over the texel (stripes and rectangles by their exact
coverage, per-unit colour variation and noise damped by how many units a texel averages), so a coarse chart
is the average of a fine one rather than an aliased sample of it, without supersampling. Colours are mixed
in linear light, and joints are balanced so that a surface's mean colour is the tagged colour: what a
building looks like from afar is what the mapper wrote.

* walls: ``building:material`` picks one of ``WALL_MATERIALS`` (brick, plaster, concrete, glass, wood, stone,
  metal, default), ``building:colour`` the colour (else the material's own). Windows and doors are drawn
  exactly where etl/geom/facade.py puts the LOD3 openings: ``wall_openings`` runs facade.py's own layout on
  the walls and ``facade_texture`` paints those rectangles, so LOD2 textures and LOD3 boxes line up
  (storeys from building:levels, window columns from the wall length, the door on the longest ground wall).
* roofs: ``roof:material`` picks one of ``ROOF_MATERIALS`` (roof_tiles, metal, slate, concrete, gravel,
  grass, default), ``roof:colour`` the colour; tile rows run along the eaves (u) and step up the slope (v).
* ``facade_tile`` is a single tileable bay x storey (for "one repeated texture per building" renderers and the
  baseline the atlas is measured against); its pattern periods are snapped to divide the tile so it repeats
  without seams.
* UVs: ``wall_uvs`` (walls with known a, b, z_bottom), ``planar_charts`` (any planar faces: one chart per
  plane and group, u horizontal, v up the plane), ``chart_uvs`` (curved surfaces: xatlas charts, metric).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, replace
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from core.semantics import SEM_DOOR, SEM_WINDOW
from etl.geom.facade import FacadeParams, door_walls, facades
from etl.geom.tags import ParseError, parse_colour
from etl.textures import xatlas_run
from etl.textures.atlas import linear_to_srgb, srgb_to_linear, texels

RGB = tuple[int, int, int]

WALL_MATERIALS = ("brick", "plaster", "concrete", "glass", "wood", "stone", "metal", "default")
ROOF_MATERIALS = ("roof_tiles", "metal", "slate", "concrete", "gravel", "grass", "default")

# OSM values (taginfo's common ones and spellings) -> the pattern drawn. Unknown values draw "default".
WALL_ALIASES = {
    **{m: m for m in WALL_MATERIALS},
    "bricks": "brick", "clinker": "brick", "brick_block": "brick",
    "stucco": "plaster", "render": "plaster", "rendered": "plaster", "mud": "plaster", "adobe": "plaster",
    "loam": "plaster", "clay": "plaster", "lime": "plaster",
    "reinforced_concrete": "concrete", "cement_block": "concrete", "cement": "concrete", "block": "concrete",
    "concrete_block": "concrete", "panel": "concrete", "prefabricated": "concrete", "plastic": "concrete",
    "mirror": "glass", "glass_facade": "glass", "curtain_wall": "glass",
    "timber": "wood", "timber_framing": "wood", "wooden": "wood", "log": "wood", "bamboo": "wood",
    "sandstone": "stone", "limestone": "stone", "granite": "stone", "marble": "stone", "masonry": "stone",
    "rock": "stone", "tuff": "stone", "basalt": "stone", "stone_block": "stone",
    "steel": "metal", "aluminium": "metal", "aluminum": "metal", "metal_plates": "metal", "copper": "metal",
    "tin": "metal", "zinc": "metal", "iron": "metal", "corrugated_iron": "metal", "sheet_metal": "metal",
}  # fmt: skip
ROOF_ALIASES = {
    **{m: m for m in ROOF_MATERIALS},
    "tiles": "roof_tiles", "tile": "roof_tiles", "clay_tiles": "roof_tiles", "clay": "roof_tiles",
    "ceramic": "roof_tiles", "concrete_tiles": "roof_tiles", "bricks": "roof_tiles",
    "metal_sheet": "metal", "tin": "metal", "copper": "metal", "zinc": "metal", "steel": "metal",
    "aluminium": "metal", "aluminum": "metal", "lead": "metal", "corrugated_iron": "metal", "sheet_metal": "metal",
    "stone": "slate", "stone_slabs": "slate", "slates": "slate",
    "cement": "concrete", "reinforced_concrete": "concrete",
    "pebblestone": "gravel", "pebbles": "gravel", "shingle": "gravel",
    "plants": "grass", "green": "grass", "vegetation": "grass", "sod": "grass", "turf": "grass",
}  # fmt: skip

# sRGB colours when building:colour / roof:colour is missing
WALL_COLOURS: dict[str, RGB] = {
    "brick": (156, 82, 62), "plaster": (226, 214, 190), "concrete": (170, 168, 160), "glass": (112, 144, 166),
    "wood": (140, 100, 66), "stone": (190, 178, 155), "metal": (160, 166, 172), "default": (214, 205, 188),
}  # fmt: skip
ROOF_COLOURS: dict[str, RGB] = {
    "roof_tiles": (160, 72, 50), "metal": (110, 118, 124), "slate": (80, 84, 92), "concrete": (150, 148, 142),
    "gravel": (150, 144, 134), "grass": (96, 128, 62), "default": (95, 90, 88),
}  # fmt: skip

_MORTAR = (196, 190, 178)
_FRAME_LIGHT = (232, 232, 226)
_FRAME_DARK = (62, 64, 68)
_GLASS_LOW = (34, 48, 62)  # bottom of a pane
_GLASS_HIGH = (118, 142, 166)  # top of a pane: sky reflection
_DOOR = (92, 62, 42)
_DARK_FRAMES = {"glass", "metal", "concrete"}
FRAME_WIDTH = 0.06  # m, window/door frame
BAR_WIDTH = 0.05  # m, mullion and transom


def wall_material(value: str | None) -> str:
    """The wall pattern for a building:material value (raw or canonical); unknown or missing -> default."""
    return WALL_ALIASES.get((value or "").strip().lower().replace(" ", "_"), "default")


def roof_material(value: str | None) -> str:
    """The roof pattern for a roof:material value (raw or canonical); unknown or missing -> default."""
    return ROOF_ALIASES.get((value or "").strip().lower().replace(" ", "_"), "default")


def parse_rgb(value: str | RGB | None, default: RGB) -> RGB:
    """sRGB of a colour tag (name, #rgb, #rrggbb, as etl.geom.tags.parse_colour reads them) or of an (r, g, b)
    tuple; ``default`` when missing or unreadable."""
    if value is None:
        return default
    if not isinstance(value, str):
        r, g, b = (int(c) for c in value)
        return (r, g, b)
    try:
        h = parse_colour(value)
    except ParseError:
        return default
    return (int(h[1:3], 16), int(h[3:5], 16), int(h[5:7], 16))


def material_and_colour(kind: str, material: str | None, colour: str | RGB | None) -> tuple[str, RGB]:
    """(pattern, sRGB) of a wall or roof from its raw material and colour tags (building:material and
    building:colour, or roof:material and roof:colour); untagged colours are the material's own."""
    if kind == "wall":
        mat = wall_material(material)
        return mat, parse_rgb(colour, WALL_COLOURS[mat])
    mat = roof_material(material)
    return mat, parse_rgb(colour, ROOF_COLOURS[mat])


def _lin(c: RGB) -> np.ndarray:
    return srgb_to_linear(np.asarray(c, dtype=np.uint8))


def _seed(*parts: object) -> int:
    # crc32, not hash(): Python salts str hashes per process, and the pixels must not change between runs
    return zlib.crc32("|".join(map(str, parts)).encode())


_HX, _HY = np.uint32(0x8DA6B343), np.uint32(0xD8163841)


def _u32(i: np.ndarray | int) -> np.ndarray:
    return (np.asarray(i, dtype=np.int64) & 0xFFFFFFFF).astype(np.uint32)


def _mix(h: np.ndarray) -> np.ndarray:
    """The hash's finaliser (in place on a fresh uint32 array) -> uniform [0, 1)."""
    with np.errstate(over="ignore"):
        h ^= h >> np.uint32(16)
        h *= np.uint32(0x7FEB352D)
        h ^= h >> np.uint32(15)
        h *= np.uint32(0x846CA68B)
        h ^= h >> np.uint32(16)
    return (h >> np.uint32(8)).astype(np.float64) / float(1 << 24)


def _hash(ix: np.ndarray | int, iy: np.ndarray | int, seed: int) -> np.ndarray:
    """Uniform [0, 1) per integer lattice point (a 32-bit integer hash; wraps negative indices)."""
    with np.errstate(over="ignore"):
        return _mix((_u32(ix) * _HX) ^ (_u32(iy) * _HY) ^ np.uint32(seed & 0xFFFFFFFF))


class _Field:
    """Texel centres of an image of width x height texels covering [u0, u0 + w_m] x [v0, v0 + h_m] metres
    (row 0 at the top), their sizes, and for a tile the span every pattern period must divide."""

    def __init__(self, u0: float, v0: float, w_m: float, h_m: float, width: int, height: int, tile: bool):
        if w_m <= 0 or h_m <= 0 or width < 1 or height < 1:
            raise ValueError("a texture needs a positive extent and at least 1 x 1 texels")
        self.tu = w_m / width
        self.tv = h_m / height
        self.t = math.sqrt(self.tu * self.tv)
        self.u = (u0 + (np.arange(width) + 0.5) * self.tu)[None, :]  # (1, W)
        self.v = (v0 + h_m - (np.arange(height) + 0.5) * self.tv)[:, None]  # (H, 1)
        self.shape = (height, width)
        self.span = (w_m, h_m) if tile else None

    def period(self, p: float, axis: int, group: int = 1) -> float:
        """p, or for a tile the nearest period of which a whole number of groups fills the span."""
        if self.span is None:
            return p
        n = max(1, round(self.span[axis] / (p * group)))
        return self.span[axis] / (n * group)

    def wrap(self, i: np.ndarray, p: float, axis: int) -> np.ndarray:
        """Unit indices, repeating with the tile so per-unit colours match across its edges."""
        if self.span is None:
            return i
        return np.mod(i, max(1, round(self.span[axis] / p)))


class _TexelField(Protocol):
    """What the pattern functions read of their texels: _Field's (one image; texel sizes are floats) or
    texturing._Flat's (a flat list of texels of many charts; per-texel sizes)."""

    @property
    def u(self) -> np.ndarray: ...
    @property
    def v(self) -> np.ndarray: ...
    @property
    def tu(self) -> float | np.ndarray: ...
    @property
    def tv(self) -> float | np.ndarray: ...
    @property
    def t(self) -> float | np.ndarray: ...
    @property
    def shape(self) -> tuple[int, ...]: ...
    def period(self, p: float, axis: int, group: int = 1) -> float: ...
    def wrap(self, i: np.ndarray, p: float, axis: int) -> np.ndarray: ...


def _stripes(
    x: np.ndarray, t: float | np.ndarray, period: float, width: float, offset: float | np.ndarray = 0.0
) -> np.ndarray:
    """Exact fraction of each texel [x - t/2, x + t/2] covered by stripes [k period + offset, ... + width)."""

    def cum(y: np.ndarray) -> np.ndarray:
        y = y - offset
        k = np.floor(y / period)
        return k * width + np.clip(y - k * period, 0.0, width)

    return (cum(x + t / 2) - cum(x - t / 2)) / t


def _saw(x: np.ndarray, t: float | np.ndarray, period: float) -> np.ndarray:
    """Box-filtered sawtooth frac(x / period) (0 at a period's start, 1 at its end; mean 0.5)."""

    def cum(y: np.ndarray) -> np.ndarray:
        s = y / period
        f = s - np.floor(s)
        return period * (np.floor(s) * 0.5 + f * f * 0.5)

    return (cum(x + t / 2) - cum(x - t / 2)) / t


def _damp(unit_m: float, fld: _TexelField) -> float | np.ndarray:
    """How much of a per-unit variation survives averaging over a texel: 1 / sqrt(units per texel). Per texel
    when the texel sizes are arrays (etl/textures/texturing.py renders many charts of one page in one pass)."""
    return np.minimum(1.0, unit_m / fld.t)


def _noise(fld: _TexelField, cu: float, cv: float, seed: int) -> np.ndarray:
    """Smooth value noise with cells cu x cv metres, mean 0, within +-0.5, damped for cells below a texel."""
    cu, cv = fld.period(cu, 0), fld.period(cv, 1)
    x, y = fld.u / cu, fld.v / cv
    ix, iy = np.floor(x), np.floor(y)
    fx, fy = x - ix, y - iy
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    ix0, ix1 = fld.wrap(ix, cu, 0), fld.wrap(ix + 1, cu, 0)
    iy0, iy1 = fld.wrap(iy, cv, 1), fld.wrap(iy + 1, cv, 1)
    # _hash of the four corners, sharing each coordinate's conversion and product (same values)
    with np.errstate(over="ignore"):
        x0, x1 = _u32(ix0) * _HX, _u32(ix1) * _HX
        y0, y1 = _u32(iy0) * _HY ^ np.uint32(seed & 0xFFFFFFFF), _u32(iy1) * _HY ^ np.uint32(seed & 0xFFFFFFFF)
        top = _mix(x0 ^ y0) * (1 - fx) + _mix(x1 ^ y0) * fx
        bot = _mix(x0 ^ y1) * (1 - fx) + _mix(x1 ^ y1) * fx
    return (top * (1 - fy) + bot * fy - 0.5) * _damp(math.sqrt(cu * cv), fld)


def _bond(
    fld: _TexelField, pu: float, pv: float, ju: float, jv: float, seed: int, shift: float = 0.5
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Running bond of units pu x pv (bricks, stones, tiles) with joints ju, jv, every other row shifted by
    ``shift`` units: (joint coverage (H, W), per-unit variation (H, W) in +-0.5 damped, pu, pv) as used."""
    pv = fld.period(pv, 1, group=2)  # shifted rows repeat every two rows
    pu = fld.period(pu, 0)
    row = np.floor(fld.v / pv)
    off = np.mod(row, 2) * shift * pu  # (H, 1)
    ch = _stripes(fld.v, fld.tv, pv, jv) if jv > 0 else np.zeros_like(fld.v)
    cv = _stripes(fld.u + off, fld.tu, pu, ju) if ju > 0 else np.zeros(fld.shape)
    joint = 1 - (1 - ch) * (1 - cv)
    col = fld.wrap(np.floor((fld.u + off) / pu), pu, 0)
    var = (_hash(col, fld.wrap(row, pv, 1), seed) - 0.5) * _damp(math.sqrt(pu * pv), fld)
    return np.broadcast_to(joint, fld.shape), var, pu, pv


def _joints(base: np.ndarray, joint: np.ndarray, cover: np.ndarray, mean_cover: float) -> np.ndarray:
    """(H, W, 3) units and joints mixed so the surface's mean stays ``base``: the units take the colour that
    balances the joints' share (clipped when no colour can)."""
    unit = np.clip((base - mean_cover * joint) / max(1e-6, 1 - mean_cover), 0, 1)
    c = np.asarray(cover)[..., None]
    return unit * (1 - c) + joint * c


def _grid_cover(fld: _TexelField, pu: float, pv: float, ju: float, jv: float) -> tuple[np.ndarray, float]:
    pu, pv = fld.period(pu, 0), fld.period(pv, 1)
    ch = _stripes(fld.v, fld.tv, pv, jv) if jv > 0 else np.zeros_like(fld.v)
    cu = _stripes(fld.u, fld.tu, pu, ju) if ju > 0 else np.zeros_like(fld.u)
    return 1 - (1 - ch) * (1 - cu), 1 - (1 - jv / pv) * (1 - ju / pu)


def _wall_pattern(material: str, base: np.ndarray, fld: _TexelField, seed: int) -> np.ndarray:
    """(H, W, 3) linear colours of a wall material; mean about ``base``."""
    mortar = _lin(_MORTAR)
    if material == "brick":  # 215 x 65 mm bricks, 10 mm joints, stretcher bond
        joint, var, pu, pv = _bond(fld, 0.225, 0.075, 0.010, 0.010, seed)
        img = _joints(base, 0.5 * base + 0.5 * mortar, joint, 1 - (1 - 0.010 / pv) * (1 - 0.010 / pu))
        return img * (1 + 0.30 * var + 0.08 * _noise(fld, 0.03, 0.03, seed + 1))[..., None]
    if material == "stone":  # ashlar 600 x 300 mm
        joint, var, pu, pv = _bond(fld, 0.60, 0.30, 0.015, 0.015, seed)
        img = _joints(base, 0.6 * base + 0.4 * mortar, joint, 1 - (1 - 0.015 / pv) * (1 - 0.015 / pu))
        return img * (1 + 0.30 * var + 0.10 * _noise(fld, 0.06, 0.06, seed + 1))[..., None]
    if material == "concrete":  # precast panels 3.0 x 1.5 m
        cover, mean = _grid_cover(fld, 3.0, 1.5, 0.02, 0.02)
        img = _joints(base, 0.55 * base, cover, mean)
        return img * (1 + 0.14 * _noise(fld, 0.45, 0.45, seed) + 0.08 * _noise(fld, 0.04, 0.04, seed + 1))[..., None]
    if material == "glass":  # curtain wall: 1.5 m mullion grid, panes lighter towards their top
        cover, mean = _grid_cover(fld, 1.5, 1.5, 0.06, 0.06)
        frame = _lin(_FRAME_DARK)
        pane = np.clip((base - mean * frame) / (1 - mean), 0, 1)  # balances the frames, as in _joints
        sky = 1 + 0.6 * (_saw(fld.v, fld.tv, fld.period(1.5, 1)) - 0.5)  # (H, 1), mean 1
        return pane * (sky * (1 - cover))[..., None] + frame * cover[..., None]
    if material == "wood":  # horizontal boards 150 mm, 8 mm gaps, grain along the boards
        pv = fld.period(0.15, 1)
        gap = np.broadcast_to(_stripes(fld.v, fld.tv, pv, 0.008), fld.shape)
        img = _joints(base, 0.45 * base, gap, 0.008 / pv)
        board = (_hash(fld.wrap(np.floor(fld.v / pv), pv, 1), 0, seed) - 0.5) * _damp(pv, fld)
        return img * (1 + 0.3 * board + 0.2 * _noise(fld, 0.6, 0.012, seed + 1))[..., None]
    if material == "metal":  # cladding: standing seams every 0.6 m, panel joints every 3 m
        pu = fld.period(0.6, 0)
        seam = np.broadcast_to(_stripes(fld.u, fld.tu, pu, 0.03), fld.shape)
        img = _joints(base, np.clip(1.35 * base, 0, 1), seam, 0.03 / pu)
        shade = (
            1
            + 0.2 * (_saw(fld.u, fld.tu, pu) - 0.5)
            - 0.3 * (_stripes(fld.v, fld.tv, fld.period(3.0, 1), 0.01) - 0.01 / fld.period(3.0, 1))
        )
        return img * shade[..., None]
    # plaster, default: render with a slight cloudiness
    big, fine = (0.10, 0.08) if material == "plaster" else (0.06, 0.05)
    return base * (1 + big * _noise(fld, 0.9, 0.9, seed) + fine * _noise(fld, 0.07, 0.07, seed + 1))[..., None]


def _roof_pattern(material: str, base: np.ndarray, fld: _TexelField, seed: int) -> np.ndarray:
    """(H, W, 3) linear colours of a roof material (u along the eaves, v up the slope); mean about ``base``."""
    if material in ("roof_tiles", "slate"):
        pu, pv, ju, shade_amp, amp = (
            (0.22, 0.32, 0.012, 0.35, 0.35) if material == "roof_tiles" else (0.28, 0.18, 0.006, 0.2, 0.3)
        )
        joint, var, pu, pv = _bond(fld, pu, pv, ju, 0.0, seed)
        img = _joints(base, 0.4 * base, joint, ju / pu)
        # each row darkens towards its top, where the row above overlaps it and casts its shadow
        shade = 1 - shade_amp * (_saw(fld.v, fld.tv, pv) - 0.5)
        return img * (shade * (1 + amp * var))[..., None]
    if material == "metal":  # standing seams down the slope every 0.5 m
        pu = fld.period(0.5, 0)
        seam = np.broadcast_to(_stripes(fld.u, fld.tu, pu, 0.03), fld.shape)
        img = _joints(base, np.clip(1.4 * base, 0, 1), seam, 0.03 / pu)
        return img * (1 + 0.1 * (_saw(fld.u, fld.tu, pu) - 0.5) + 0.04 * _noise(fld, 0.8, 0.8, seed))[..., None]
    if material == "concrete":
        cover, mean = _grid_cover(fld, 2.0, 2.0, 0.02, 0.02)
        img = _joints(base, 0.6 * base, cover, mean)
        return img * (1 + 0.14 * _noise(fld, 0.5, 0.5, seed) + 0.08 * _noise(fld, 0.04, 0.04, seed + 1))[..., None]
    if material == "gravel":
        return base * (1 + 0.5 * _noise(fld, 0.025, 0.025, seed) + 0.12 * _noise(fld, 0.3, 0.3, seed + 1))[..., None]
    if material == "grass":
        return base * (1 + 0.4 * _noise(fld, 0.04, 0.04, seed) + 0.3 * _noise(fld, 0.6, 0.6, seed + 1))[..., None]
    # default: roofing felt in 1 m strips up the slope
    pv = fld.period(1.0, 1)
    lap = np.broadcast_to(_stripes(fld.v, fld.tv, pv, 0.012), fld.shape)
    img = _joints(base, np.clip(1.3 * base, 0, 1), lap, 0.012 / pv)
    return img * (1 + 0.1 * _noise(fld, 0.4, 0.4, seed) + 0.08 * _noise(fld, 0.03, 0.03, seed + 1))[..., None]


def _size(w_m: float, h_m: float, texels_per_metre: float | None, size: tuple[int, int] | None) -> tuple[int, int]:
    if size is not None:
        return int(size[0]), int(size[1])
    if texels_per_metre is None or texels_per_metre <= 0:
        raise ValueError("give texels_per_metre > 0 or an explicit size")
    return texels(w_m, texels_per_metre), texels(h_m, texels_per_metre)


def material_texture(
    colour: str | RGB | None,
    material: str | None,
    width_m: float,
    height_m: float,
    texels_per_metre: float | None = None,
    size: tuple[int, int] | None = None,
    origin: tuple[float, float] = (0.0, 0.0),
    kind: str = "wall",
    tile: bool = False,
    seed: int = 0,
) -> np.ndarray:
    """(h, w, 3) uint8: the bare material of a wall or roof over [origin, origin + (width_m, height_m)] metres.
    ``tile``: every period snapped to divide the extent, so the image repeats seamlessly."""
    if kind not in ("wall", "roof"):
        raise ValueError("kind is wall or roof")
    return linear_to_srgb(
        _material(kind, colour, material, width_m, height_m, texels_per_metre, size, origin, tile, seed)[2]
    )


def _material(
    kind: str,
    colour: str | RGB | None,
    material: str | None,
    width_m: float,
    height_m: float,
    texels_per_metre: float | None,
    size: tuple[int, int] | None,
    origin: tuple[float, float],
    tile: bool,
    seed: int,
) -> tuple[str, _Field, np.ndarray]:
    """(pattern, texel field, (h, w, 3) linear colours) of the bare material: what the texture functions share."""
    mat, rgb = material_and_colour(kind, material, colour)
    w, h = _size(width_m, height_m, texels_per_metre, size)
    fld = _Field(origin[0], origin[1], width_m, height_m, w, h, tile)
    pattern = _wall_pattern if kind == "wall" else _roof_pattern
    return mat, fld, pattern(mat, _lin(rgb), fld, _seed(kind, mat, rgb, seed))


def roof_texture(
    colour_rgb: str | RGB | None,
    material: str | None,
    width_m: float,
    height_m: float,
    texels_per_metre: float | None = None,
    size: tuple[int, int] | None = None,
    origin: tuple[float, float] = (0.0, 0.0),
    seed: int = 0,
) -> np.ndarray:
    """(h, w, 3) uint8 roof texture of a chart width_m along the eaves x height_m up the slope (metric, so
    tiles have one size on every roof); roof:material and roof:colour tags accepted raw."""
    return material_texture(colour_rgb, material, width_m, height_m, texels_per_metre, size, origin, "roof", seed=seed)


# --- openings ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Openings:
    """Window/door rectangles in wall coordinates: s along the wall from a, z above the wall's z_bottom."""

    wall: np.ndarray  # (k,) int64 row of the wall arrays the opening is on, ascending
    s0: np.ndarray  # (k,) float64 m
    s1: np.ndarray
    z0: np.ndarray
    z1: np.ndarray
    kind: np.ndarray  # (k,) uint8 SEM_WINDOW or SEM_DOOR

    def of(self, wall: int) -> Openings:
        lo, hi = np.searchsorted(self.wall, [wall, wall + 1])
        return Openings(*(x[lo:hi] for x in (self.wall, self.s0, self.s1, self.z0, self.z1, self.kind)))

    def __len__(self) -> int:
        return len(self.wall)

    @classmethod
    def none(cls) -> Openings:
        """No openings (a blank wall)."""
        e = np.zeros(0)
        return cls(np.zeros(0, np.int64), e, e, e, e, np.zeros(0, np.uint8))


def wall_openings(
    a: ArrayLike,
    b: ArrayLike,
    owner: ArrayLike,
    z_bottom: ArrayLike,
    z_top: ArrayLike,
    levels: ArrayLike,
    ground: ArrayLike,
    exterior: ArrayLike,
    params: FacadeParams = FacadeParams(),  # noqa: B008 -- frozen
) -> Openings:
    """The LOD3 openings of walls a->b (same arrays as etl.geom.facade.facades), per wall.

    facade.py's layout is reused, not re-implemented: its door rule picks each building's door wall, then
    facades() runs with every wall as its own "building" (door allowed only on the chosen wall) so each
    panel can be traced to its wall; windows, storeys and the door clash rule are per wall, so the result
    is the same set of rectangles facades() gives for the real buildings (tests/unit/test_textures_procedural.py)."""
    p = replace(params, style="panel")
    a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 2)
    n = len(a)
    owner = np.asarray(owner, dtype=np.int64)
    zb = np.broadcast_to(np.asarray(z_bottom, dtype=np.float64), (n,))
    zt = np.broadcast_to(np.asarray(z_top, dtype=np.float64), (n,))
    lv = np.broadcast_to(np.asarray(levels, dtype=np.float64), (n,))
    ground = np.broadcast_to(np.asarray(ground, dtype=bool), (n,))
    exterior = np.broadcast_to(np.asarray(exterior, dtype=bool), (n,))
    length = np.hypot(*(b - a).T)
    door = np.zeros(n, dtype=bool)
    door[door_walls(length, zt - zb, owner, ground, exterior, p)] = True
    f = facades(a, b, np.arange(n), zb, zt, lv, door, exterior, n_buildings=n, params=p)
    quad = f.triangles.reshape(-1, 2, 3, 3)
    wall = f.owner[::2]
    c_lo, c_hi = quad[:, 0, 0], quad[:, 0, 2]  # panel corners (s0, z0) and (s1, z1)
    d = (b - a) / np.where(length > 0, length, 1.0)[:, None]
    s0 = ((c_lo[:, :2] - a[wall]) * d[wall]).sum(axis=1)
    s1 = ((c_hi[:, :2] - a[wall]) * d[wall]).sum(axis=1)
    return Openings(
        wall=wall.astype(np.int64),
        s0=s0,
        s1=s1,
        z0=c_lo[:, 2] - zb[wall],
        z1=c_hi[:, 2] - zb[wall],
        kind=f.semantics[::2].astype(np.uint8),
    )


def _cover(x: np.ndarray, t: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(k, N) float32: exact fraction of each texel [x - t/2, x + t/2] inside each interval [lo, hi]
    (float32: the products below are BLAS-bound, and 8-bit output needs no more)."""
    a = np.maximum(x[None, :] - t / 2, lo[:, None])
    b = np.minimum(x[None, :] + t / 2, hi[:, None])
    return (np.clip(b - a, 0.0, None) / t).astype(np.float32)


def _paint_openings(img: np.ndarray, fld: _Field, op: Openings, material: str) -> np.ndarray:
    """Windows (frame, glass with a mullion and a transom) and doors (frame, leaf) over the wall.

    Every feature is a separable rectangle, and openings sit on a grid (a storey's windows share their z
    interval, a column's their s interval, the door adds one of each), so each feature of all openings at once
    is cover_z.T @ (grid @ cover_s): (H, rows) @ (rows, W) products, not one image pass per opening."""
    if len(op) == 0:
        return img
    u, v = fld.u[0], fld.v[:, 0]
    zs, zi = np.unique(np.column_stack([op.z0, op.z1]), axis=0, return_inverse=True)
    ss, si = np.unique(np.column_stack([op.s0, op.s1]), axis=0, return_inverse=True)
    zi, si = zi.reshape(-1), si.reshape(-1)
    win = np.zeros((len(zs), len(ss)), np.float32)
    door = np.zeros_like(win)
    is_win = op.kind == SEM_WINDOW
    win[zi[is_win], si[is_win]] = 1
    door[zi[op.kind == SEM_DOOR], si[op.kind == SEM_DOOR]] = 1
    z0, z1 = zs[:, 0], zs[:, 1]
    s0, s1 = ss[:, 0], ss[:, 1]
    fz = np.minimum(FRAME_WIDTH, 0.25 * (z1 - z0))
    fs = np.minimum(FRAME_WIDTH, 0.25 * (s1 - s0))
    cv_o, cv_i = _cover(v, fld.tv, z0, z1), _cover(v, fld.tv, z0 + fz, z1 - fz)  # (rows, H)
    cu_o, cu_i = _cover(u, fld.tu, s0, s1), _cover(u, fld.tu, s0 + fs, s1 - fs)  # (columns, W)
    mid = (s0 + s1) / 2
    cu_m = _cover(u, fld.tu, mid - BAR_WIDTH / 2, mid + BAR_WIDTH / 2)
    zt = z0 + 0.7 * (z1 - z0)
    cv_t = _cover(v, fld.tv, zt - BAR_WIDTH / 2, zt + BAR_WIDTH / 2)

    def grid(cv: np.ndarray, which: np.ndarray, cu: np.ndarray) -> np.ndarray:
        return cv.T @ (which @ cu)

    outer = grid(cv_o, win + door, cu_o)
    inner_w = grid(cv_i, win, cu_i)
    inner_d = grid(cv_i, door, cu_i)
    bars = grid(cv_i, win, cu_m) + grid(cv_t, win, cu_i) - grid(cv_t, win, cu_m)
    glass = np.clip(inner_w - bars, 0, 1)
    frame = np.clip(outer - glass - inner_d, 0, 1)
    # glass lighter towards the top of each window: the mean height fraction of the glass in the texel
    g = np.clip((v[None, :] - z0[:, None]) / (z1 - z0)[:, None], 0, 1).astype(np.float32)
    grad = grid(cv_i * g, win, cu_i) / np.maximum(inner_w, 1e-9)
    low, high = _lin(_GLASS_LOW), _lin(_GLASS_HIGH)
    frame_c = _lin(_FRAME_DARK if material in _DARK_FRAMES else _FRAME_LIGHT)
    out = img * np.clip(1 - outer, 0, 1)[..., None]
    out += frame_c * frame[..., None]
    out += (low + (high - low) * grad[..., None]) * glass[..., None]
    out += _lin(_DOOR) * inner_d[..., None]
    return out


def facade_texture(
    colour_rgb: str | RGB | None,
    material: str | None,
    levels: float | None,
    length: float,
    height: float,
    texels_per_metre: float | None = None,
    size: tuple[int, int] | None = None,
    openings: Openings | None = None,
    params: FacadeParams = FacadeParams(),  # noqa: B008 -- frozen
    seed: int = 0,
) -> np.ndarray:
    """(h, w, 3) uint8 texture of a whole wall, length x height metres (u from the wall start a, v up from its
    bottom, row 0 at the top), at ``texels_per_metre`` or an exact ``size`` (width, height) texels.

    Openings are ``openings`` (this wall's, from ``wall_openings(...).of(i)``) or, when None, those facade.py
    lays out on a free-standing wall of this length with ``levels`` storeys (no door). building:material and
    building:colour are accepted raw."""
    mat, fld, img = _material(
        "wall", colour_rgb, material, length, height, texels_per_metre, size, (0.0, 0.0), False, seed
    )
    if openings is None:
        lv = np.nan if levels is None else float(levels)
        openings = wall_openings([[0.0, 0.0]], [[length, 0.0]], [0], 0.0, height, lv, False, True, params)
    return linear_to_srgb(_paint_openings(img, fld, openings, mat))


def facade_tile(
    colour_rgb: str | RGB | None,
    material: str | None,
    bay_width: float,
    storey_height: float,
    texels_per_metre: float,
    params: FacadeParams = FacadeParams(),  # noqa: B008 -- frozen
    seed: int = 0,
) -> np.ndarray:
    """(h, w, 3) uint8 tileable texture of one window bay x one storey: the window where facade.py puts it in
    a bay of that width and a storey of that height (horizontally centred, sill_height up, lowered to fit),
    on the material with its periods snapped to divide the tile. Repeated with u' = (u - margin) / bay_width
    and v' = v / storey_height it reproduces facade.py's windows on a wall whose pitch is bay_width."""
    mat, fld, img = _material(
        "wall", colour_rgb, material, bay_width, storey_height, texels_per_metre, None, (0.0, 0.0), True, seed
    )
    # facade.py on a one-bay wall (bay plus both margins, one storey) says where the window goes
    m = params.margin
    op = wall_openings([[0.0, 0.0]], [[bay_width + 2 * m, 0.0]], [0], 0.0, storey_height, 1.0, False, True, params)
    op = Openings(op.wall, op.s0 - m, op.s1 - m, op.z0, op.z1, op.kind)
    return linear_to_srgb(_paint_openings(img, fld, op, mat))


# --- UVs -----------------------------------------------------------------------------------------------------


def wall_uvs(points: np.ndarray, a: np.ndarray, b: np.ndarray, z_bottom: np.ndarray) -> np.ndarray:
    """(n, 2) float64 metric UVs of wall points (n, 3): u metres along a->b from a, v metres above z_bottom
    (a, b, z_bottom per point, i.e. of the wall each point belongs to). Matches wall_openings' s and z."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 2)
    d = b - a
    d = d / np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-12)[:, None]
    return np.column_stack([((p[:, :2] - a) * d).sum(axis=1), p[:, 2] - np.asarray(z_bottom, dtype=np.float64)])


def plane_frame(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(du, dv) unit vectors per normal: du horizontal in the plane (along a wall a->b when the normal is the
    wall's outward one; +x for horizontal planes), dv = n x du, up the plane (north for a flat roof)."""
    n = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    du = np.column_stack([-n[:, 1], n[:, 0], np.zeros(len(n))])  # z x n
    norm = np.hypot(du[:, 0], du[:, 1])
    flat = norm < 1e-9
    du = np.where(flat[:, None], [1.0, 0.0, 0.0], du / np.where(flat, 1.0, norm)[:, None])
    return du, np.cross(n, du)


def plane_keys(tri: np.ndarray, group: np.ndarray, shift: float = 0.0) -> np.ndarray:
    """(m, 5) int64 (group, unit normal x 1e3, plane offset x 1e2) of triangles (m, 3, 3), rounded: the key
    planar_charts groups triangles by. ``shift`` moves the offset that many metres against the normal (a LOD3
    panel's wall lies FacadeParams.depth behind it: etl/textures/texturing.py looks the wall up that way)."""
    cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = cr / np.maximum(np.linalg.norm(cr, axis=1), 1e-300)[:, None]
    off = (n * tri[:, 0]).sum(axis=1) - shift
    return np.column_stack([group, np.round(n * 1e3), np.round(off * 1e2)]).astype(np.int64)


@dataclass(frozen=True)
class PlanarCharts:
    """Planar faces grouped into charts (same group, same plane). uv: metres in the chart's frame relative to
    its lower-left corner ``origin`` (so 0..size), u horizontal, v up the plane."""

    chart: np.ndarray  # (m,) int64 chart per triangle
    uv: np.ndarray  # (m, 3, 2) float64 metres
    origin: np.ndarray  # (c, 2) float64 metric position of each chart's corner in its plane frame
    size: np.ndarray  # (c, 2) float64 metres (width along u, height along v)
    normal: np.ndarray  # (c, 3) unit normal per chart
    group: np.ndarray  # (c,) the group of each chart
    du: np.ndarray  # (c, 3) unit vector of the chart's u axis
    dv: np.ndarray  # (c, 3) unit vector of its v axis (normal x du)
    first: np.ndarray  # (c,) int64 the chart's first triangle


def planar_charts(
    triangles: np.ndarray, group: np.ndarray | None = None, align: dict[int, np.ndarray] | None = None
) -> PlanarCharts:
    """Charts for planar surfaces (walls, roof faces, caps): triangles (m, 3, 3) with the same ``group`` (e.g.
    building id) whose planes agree (normal to 1e-3, offset to 1 cm) share a chart. An extruded wall's chart
    has u from a and v from its bottom, i.e. the frame of wall_uvs and wall_openings; a chart's size is what
    texture_size takes. Coplanar but separate faces of one group share a chart spanning both, so group walls
    by wall (not by building) when their openings are to be painted: those are in each wall's own frame.
    ``align``: group -> horizontal unit vector that the u axis of the group's horizontal charts follows
    instead of +x (e.g. a building's longest wall, so a rotated flat roof does not waste half its chart)."""
    tri = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
    m = len(tri)
    grp = np.zeros(m, dtype=np.int64) if group is None else np.asarray(group, dtype=np.int64)
    _, first, chart = np.unique(plane_keys(tri, grp), axis=0, return_index=True, return_inverse=True)
    chart = chart.reshape(-1)
    c = len(first)
    cr = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nsum = np.zeros((c, 3))
    np.add.at(nsum, chart, cr)  # area-weighted: one frame per chart, identical for all its triangles
    nrm = nsum / np.maximum(np.linalg.norm(nsum, axis=1), 1e-300)[:, None]
    du, dv = plane_frame(nrm)
    if align:
        turn = np.flatnonzero((np.abs(nrm[:, 2]) > 0.999) & np.isin(grp[first], list(align)))
        if len(turn):
            du[turn] = np.array([align[int(g)] for g in grp[first][turn]])
            dv[turn] = np.cross(nrm[turn], du[turn])
    uv = np.stack([(tri * du[chart][:, None, :]).sum(-1), (tri * dv[chart][:, None, :]).sum(-1)], axis=-1)
    lo = np.full((c, 2), np.inf)
    hi = np.full((c, 2), -np.inf)
    np.minimum.at(lo, chart, uv.min(axis=1))
    np.maximum.at(hi, chart, uv.max(axis=1))
    return PlanarCharts(
        chart=chart,
        uv=uv - lo[chart][:, None, :],
        origin=lo,
        size=hi - lo,
        normal=nrm,
        group=grp[first],
        du=du,
        dv=dv,
        first=first.astype(np.int64),
    )


@dataclass(frozen=True)
class XatlasCharts:
    """xatlas charts of a curved surface, laid out on one metric sheet: render a texture of ``size_m`` metres
    over the sheet (e.g. roof_texture at the tile's density) and map ``local`` into its atlas rectangle."""

    vertex: np.ndarray  # (n',) int64 input vertex of each output vertex (xatlas splits along seams)
    faces: np.ndarray  # (m, 3) int64 output vertex indices, same face order as the input
    local: np.ndarray  # (n', 2) float64 position on the sheet in [0, 1] (x right, y down = image rows)
    uv_m: np.ndarray  # (n', 2) float64 the same in metres
    chart: np.ndarray  # (m,) int64 chart per face
    size_m: tuple[float, float]  # sheet width, height in metres


def chart_uvs(vertices: np.ndarray, faces: np.ndarray, texels_per_metre: float = 8.0, padding: int = 2) -> XatlasCharts:
    """Charts for non-planar surfaces (domes, onions, roofs with many small faces) by xatlas, in metric units:
    xatlas lays the charts out at ``texels_per_metre`` with ``padding`` texels between them; pass the density
    of the finest tile level that will show the surface, so that gutter stays >= 1 texel there."""
    import xatlas

    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    centre = v.mean(axis=0) if len(v) else np.zeros(3)  # float32 inside xatlas: keep coordinates small
    po = xatlas.PackOptions()
    po.texels_per_unit = float(texels_per_metre)
    po.padding = int(padding)
    po.resolution = 0  # one sheet, as large as the charts need; the atlas packer bounds the pages
    po.bilinear = True

    def read(atlas: xatlas.Atlas) -> tuple:
        if atlas.atlas_count != 1:
            raise RuntimeError(f"xatlas made {atlas.atlas_count} sheets, expected 1")
        return (*atlas.get_mesh(0), atlas.get_mesh_vertex_assignment(0)[1], atlas.width, atlas.height)

    vmap, idx, uv, vchart, w, h = xatlas_run.generate(
        lambda atlas: atlas.add_mesh(
            np.ascontiguousarray((v - centre).astype(np.float32)), np.ascontiguousarray(f.astype(np.uint32))
        ),
        read,
        chart_options=xatlas.ChartOptions(),
        pack_options=po,
    )
    local = uv.astype(np.float64)
    return XatlasCharts(
        vertex=vmap.astype(np.int64),
        faces=idx.astype(np.int64),
        local=local,
        uv_m=local * np.array([w, h]) / texels_per_metre,
        chart=vchart[idx[:, 0]].astype(np.int64),
        size_m=(w / texels_per_metre, h / texels_per_metre),
    )
