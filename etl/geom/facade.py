"""LOD3 facade detail: windows and doors as geometry, for a whole batch of buildings at once.

Pure numpy over arrays of wall segments (one row per footprint ring edge); no per-building or per-window
Python loop. Walls are oriented with the building interior on the left of a->b (exterior rings
counter-clockwise, holes clockwise), so a wall's outward normal is the right-hand normal (dy, -dx) / L.

Rules:
  * storeys: ``levels`` per wall, or (z_top - z_bottom) / level_height when it is missing, rounded half up, at least 1
    when the wall is at least one window high; storey k spans z_bottom + k*h .. z_bottom + (k+1)*h with
    h = (z_top - z_bottom) / levels. A storey lower than sill_height + window_height + 0.1 gets no windows.
  * windows: on every wall and storey, count = floor((L - 2*margin) / window_spacing), at least 1 when
    L - 2*margin >= window_width, else none; centres evenly spread at margin + (i + 0.5) * (L - 2*margin) / count.
    The bottom sits sill_height above the storey floor, lowered if needed so the top stays 0.05 below the
    storey top.
  * doors: one per building standing on the ground, centred on its longest exterior wall that can hold one
    (L >= door_width + 2*margin, wall height >= door_height + 0.3), from z_bottom up door_height. Streets are
    not in the database, so the longest exterior wall stands in for the street-facing one. Hole (courtyard)
    walls get windows but never a door. Windows whose box would intersect the door box are dropped.

Style ``box`` (FacadeParams.style): every opening is a closed box (12 triangles, counter-clockwise seen from
outside) whose back face lies 1 cm inside the wall plane (embedded, so it does not z-fight with the wall)
and whose front face stands ``depth`` outside it. Boxes rather than recessed openings: each one is a closed
shell, so every LOD3 component stays watertight without boolean operations on the wall mesh. Style
``panel`` keeps only each box's front face (2 triangles instead of 12) for when LOD3 size matters more than
closed openings; it is the pipeline's default (settings.lod3_openings says what boxes cost).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.semantics import SEM_DOOR, SEM_WINDOW

EMBED = 0.01  # how far a box's back face sits behind the wall plane
_EPS = 1e-9  # keeps exact fits (e.g. a storey exactly as high as required) on the accepting side

# Unit cube, corner i at (x, y, z) = (i & 1, i >> 1 & 1, i >> 2 & 1) in a right-handed frame; each triangle
# counter-clockwise seen from outside.
_CUBE = np.array(
    [
        [0, 2, 3], [0, 3, 1],  # z = 0
        [4, 5, 7], [4, 7, 6],  # z = 1
        [0, 1, 5], [0, 5, 4],  # y = 0
        [2, 6, 7], [2, 7, 3],  # y = 1
        [0, 4, 6], [0, 6, 2],  # x = 0
        [1, 3, 7], [1, 7, 5],  # x = 1
    ],
    dtype=np.int64,
)  # fmt: skip
_BIT_X = np.arange(8) & 1
_BIT_Y = (np.arange(8) >> 1) & 1
_BIT_Z = (np.arange(8) >> 2) & 1


@dataclass(frozen=True)
class FacadeParams:
    level_height: float = 3.0  # m per storey when levels are not given
    window_width: float = 1.2
    window_height: float = 1.5
    sill_height: float = 0.9  # above each storey's floor
    window_spacing: float = 3.0  # target centre-to-centre distance along a wall
    door_width: float = 1.1
    door_height: float = 2.2
    depth: float = 0.12  # how far a window/door frame box stands out of the wall
    margin: float = 0.4  # minimum wall left free at each wall end
    style: str = "box"  # box: a closed 12-triangle box per opening; panel: only its 2-triangle front face


@dataclass(frozen=True)
class Facades:
    triangles: np.ndarray  # (m, 3, 3) float64, CCW seen from outside
    semantics: np.ndarray  # (m,) uint8: SEM_WINDOW or SEM_DOOR
    owner: np.ndarray  # (m,) int64 building index (0..n-1), sorted ascending (stable)
    n_windows: np.ndarray  # (n,) int64 per building
    n_doors: np.ndarray  # (n,) int64 per building


def door_walls(
    length: np.ndarray, height: np.ndarray, owner: np.ndarray, ground: np.ndarray, exterior: np.ndarray, p: FacadeParams
) -> np.ndarray:
    """Indices of the walls that get a door: per building, the first longest eligible wall."""
    ok = exterior & ground & (length + _EPS >= p.door_width + 2 * p.margin) & (height + _EPS >= p.door_height + 0.3)
    cand = np.flatnonzero(ok)
    if cand.size == 0:
        return cand
    order = np.lexsort((cand, -length[cand], owner[cand]))  # by owner, longest first, then first wall
    cand = cand[order]
    _, first = np.unique(owner[cand], return_index=True)
    return cand[first]


def _boxes(
    a: np.ndarray,
    u: np.ndarray,
    nrm: np.ndarray,
    wall: np.ndarray,
    s0: np.ndarray,
    s1: np.ndarray,
    z0: np.ndarray,
    z1: np.ndarray,
    depth: float,
) -> np.ndarray:
    """(k, 12, 3, 3) closed boxes: s along the wall from a, z vertical, from EMBED inside to depth outside."""
    # (n, u, z) is right-handed (n x u = +z), so the cube's x maps to the normal and y to the wall direction,
    # which keeps the template's winding.
    d = np.where(_BIT_X == 1, depth, -EMBED)  # (8,)
    s = np.where(_BIT_Y == 1, s1[:, None], s0[:, None])  # (k, 8)
    corners = np.empty((len(wall), 8, 3))
    corners[:, :, :2] = (
        a[wall][:, None, :] + d[None, :, None] * nrm[wall][:, None, :] + s[:, :, None] * u[wall][:, None, :]
    )
    corners[:, :, 2] = np.where(_BIT_Z == 1, z1[:, None], z0[:, None])
    return np.take(corners, _CUBE, axis=1)  # far faster than corners[:, _CUBE], which comes out strided


def _panels(
    a: np.ndarray,
    u: np.ndarray,
    nrm: np.ndarray,
    wall: np.ndarray,
    s0: np.ndarray,
    s1: np.ndarray,
    z0: np.ndarray,
    z1: np.ndarray,
    depth: float,
) -> np.ndarray:
    """(k, 2, 3, 3): the front faces of _boxes without building the boxes (same corners, same winding)."""
    base = a[wall] + depth * nrm[wall]  # (k, 2)
    p0 = base + s0[:, None] * u[wall]
    p1 = base + s1[:, None] * u[wall]
    c = np.empty((len(wall), 4, 3))  # corners 1 (s0, z0), 3 (s1, z0), 7 (s1, z1), 5 (s0, z1) of the cube
    c[:, 0, :2], c[:, 0, 2] = p0, z0
    c[:, 1, :2], c[:, 1, 2] = p1, z0
    c[:, 2, :2], c[:, 2, 2] = p1, z1
    c[:, 3, :2], c[:, 3, 2] = p0, z1
    return np.take(c, np.array([[0, 1, 2], [0, 2, 3]]), axis=1)


@dataclass(frozen=True)
class _Walls:
    """The walls a->b (one row per wall) as arrays, with their length, direction, outward normal and height."""

    a: np.ndarray  # (w, 2)
    owner: np.ndarray  # (w,) int64
    zb: np.ndarray  # (w,) bottom
    levels: np.ndarray  # (w,) storeys when given (NaN or <= 0: not)
    ground: np.ndarray  # (w,) bool: the building stands on the ground
    exterior: np.ndarray  # (w,) bool
    length: np.ndarray
    u: np.ndarray  # (w, 2) unit direction a->b
    nrm: np.ndarray  # (w, 2) outward normal
    height: np.ndarray


@dataclass(frozen=True)
class _Openings:
    """Windows or doors: the wall of each, its centre along the wall from a, its bottom and top."""

    wall: np.ndarray
    mid: np.ndarray
    z0: np.ndarray
    z1: np.ndarray


def facades(
    a: np.ndarray,
    b: np.ndarray,
    owner: np.ndarray,
    z_bottom: np.ndarray,
    z_top: np.ndarray,
    levels: np.ndarray,
    ground: np.ndarray,
    exterior: np.ndarray,
    n_buildings: int,
    params: FacadeParams = FacadeParams(),  # noqa: B008 -- frozen, so a shared default is safe
) -> Facades:
    """Window and door boxes for the walls a->b (one row per wall) of n_buildings buildings."""
    p = params
    w = _walls(a, b, owner, z_bottom, z_top, levels, ground, exterior, n_buildings)
    windows = _windows(w, p)
    door_wall = door_walls(w.length, w.height, w.owner, w.ground, w.exterior, p)
    dz0 = w.zb[door_wall]
    doors = _Openings(door_wall, w.length[door_wall] / 2, dz0, dz0 + p.door_height)
    windows = _clear_of_doors(w, windows, doors, p)

    # Windows then doors, reordered per box (not per triangle) so the output comes out sorted by owner.
    win_wall = windows.wall
    wall = np.concatenate([win_wall, door_wall])
    mid = np.concatenate([windows.mid, doors.mid])
    half = np.concatenate([np.full(win_wall.size, p.window_width / 2), np.full(door_wall.size, p.door_width / 2)])
    z0 = np.concatenate([windows.z0, doors.z0])
    z1 = np.concatenate([windows.z1, doors.z1])
    sem = np.concatenate([np.full(win_wall.size, SEM_WINDOW, np.uint8), np.full(door_wall.size, SEM_DOOR, np.uint8)])
    box_owner = w.owner[wall]
    order = np.argsort(box_owner, kind="stable")
    wall, mid, half, z0, z1, sem, box_owner = (x[order] for x in (wall, mid, half, z0, z1, sem, box_owner))

    if p.style not in ("box", "panel"):
        raise ValueError(f"unknown opening style {p.style!r} (box or panel)")
    if p.style == "panel":  # the box's front face alone (cube triangles 10 and 11), `depth` proud of the wall
        tris = _panels(w.a, w.u, w.nrm, wall, mid - half, mid + half, z0, z1, p.depth).reshape(-1, 3, 3)
        per = 2
    else:
        tris = _boxes(w.a, w.u, w.nrm, wall, mid - half, mid + half, z0, z1, p.depth).reshape(-1, 3, 3)
        per = 12
    return Facades(
        triangles=tris,
        semantics=np.repeat(sem, per),
        owner=np.repeat(box_owner, per),
        n_windows=np.bincount(w.owner[win_wall], minlength=n_buildings).astype(np.int64),
        n_doors=np.bincount(w.owner[door_wall], minlength=n_buildings).astype(np.int64),
    )


def _walls(
    a: np.ndarray,
    b: np.ndarray,
    owner: np.ndarray,
    z_bottom: np.ndarray,
    z_top: np.ndarray,
    levels: np.ndarray,
    ground: np.ndarray,
    exterior: np.ndarray,
    n_buildings: int,
) -> _Walls:
    """The per-wall arrays of ``facades`` checked (one row per wall, owners in range) and measured."""
    a = np.asarray(a, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(b, dtype=np.float64).reshape(-1, 2)
    owner = np.asarray(owner, dtype=np.int64)
    zb = np.asarray(z_bottom, dtype=np.float64)
    zt = np.asarray(z_top, dtype=np.float64)
    levels = np.asarray(levels, dtype=np.float64)
    ground = np.asarray(ground, dtype=bool)
    exterior = np.asarray(exterior, dtype=bool)
    if any(len(x) != len(a) for x in (b, owner, zb, zt, levels, ground, exterior)):
        raise ValueError("every per-wall array needs one row per wall")
    if owner.size and (owner.min() < 0 or owner.max() >= n_buildings):
        raise ValueError("owner must lie in 0..n_buildings-1")

    delta = b - a
    length = np.hypot(delta[:, 0], delta[:, 1])
    u = delta / np.where(length > 0, length, 1.0)[:, None]
    nrm = np.column_stack([u[:, 1], -u[:, 0]])  # right-hand normal = outward
    height = zt - zb
    return _Walls(a, owner, zb, levels, ground, exterior, length, u, nrm, height)


def _storeys(w: _Walls, p: FacadeParams) -> tuple[np.ndarray, np.ndarray]:
    """(storeys with windows, storey height) per wall; no storeys where a storey is too low for a window."""
    # Storeys: all storeys of a wall are equally high, so "tall enough for a window" is per wall.
    height, levels = w.height, w.levels
    with np.errstate(invalid="ignore", divide="ignore"):
        given = np.isfinite(levels) & (levels > 0)
        lv = np.floor(np.where(given, levels, height / p.level_height) + 0.5)
        tall = height + _EPS >= p.window_height
        lv = np.where(tall, np.maximum(lv, 1.0), 0.0)
        h = np.where(lv > 0, height / lv, 0.0)
    storey_ok = (lv > 0) & (h + _EPS >= p.sill_height + p.window_height + 0.1)
    lv = np.where(storey_ok, lv, 0).astype(np.int64)  # cast only after absurd level counts were zeroed
    return lv, h


def _columns(w: _Walls, p: FacadeParams) -> tuple[np.ndarray, np.ndarray]:
    """(windows per storey, their centre-to-centre distance) per wall."""
    usable = w.length - 2 * p.margin
    with np.errstate(invalid="ignore"):
        count = np.floor(usable / p.window_spacing + _EPS)
        count = np.where(usable + _EPS >= p.window_width, np.maximum(count, 1.0), 0.0).astype(np.int64)
    pitch = np.where(count > 0, usable / np.maximum(count, 1), 0.0)
    return count, pitch


def _windows(w: _Walls, p: FacadeParams) -> _Openings:
    """Every window of every wall and storey, wall by wall, storey by storey, column by column."""
    lv, h = _storeys(w, p)
    count, pitch = _columns(w, p)
    # Enumerate windows without a loop: window j of wall w is column j % count, storey j // count.
    per_wall = count * lv
    win_wall = np.repeat(np.arange(len(w.a)), per_wall)
    j = np.arange(win_wall.size) - np.repeat(np.cumsum(per_wall) - per_wall, per_wall)
    col = j % np.maximum(count[win_wall], 1)
    storey = j // np.maximum(count[win_wall], 1)
    centre = p.margin + (col + 0.5) * pitch[win_wall]
    hw = h[win_wall]
    wz0 = w.zb[win_wall] + storey * hw + np.minimum(p.sill_height, hw - 0.05 - p.window_height)
    wz1 = wz0 + p.window_height
    return _Openings(win_wall, centre, wz0, wz1)


def _clear_of_doors(w: _Walls, windows: _Openings, doors: _Openings, p: FacadeParams) -> _Openings:
    """The windows whose box would not intersect the door's: on another wall, beside it or above it."""
    win_wall, centre, wz0, wz1 = windows.wall, windows.mid, windows.z0, windows.z1
    has_door = np.zeros(len(w.a), dtype=bool)
    has_door[doors.wall] = True
    mid_of = np.zeros(len(w.a))
    mid_of[doors.wall] = doors.mid
    on_door_wall = has_door[win_wall]
    clash = (
        on_door_wall
        & (np.abs(centre - mid_of[win_wall]) < (p.window_width + p.door_width) / 2)
        & (wz0 < w.zb[win_wall] + p.door_height)
        & (wz1 > w.zb[win_wall])
    )
    keep = ~clash
    return _Openings(win_wall[keep], centre[keep], wz0[keep], wz1[keep])
