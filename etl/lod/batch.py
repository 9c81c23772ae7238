"""The meshes of one batch of lod.building_input rows (a Dask task's work; etl/lod/stage.py streams the input
and COPYs what comes out): LOD1 blocks, LOD2 roofs, LOD3 openings, and their rows of lod.building_mesh with
the batch's rejects and diagnostics. Pure: rows in, a Batch out.

The steps, in order (each timed into Batch.seconds): the rows to draw (``_drawn_rows``), their heights and
LOD1 blocks (``_lod1``), the roofs of LOD2 (``_roofs``: pitched solids and slabs, then measured,
``_not_closed``), the openings of LOD3 (``_openings``, ``_with_openings``), the rows (``_rows``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely

from core.semantics import N_SEMANTICS, SEM_ROOF, SEM_WALL
from core.settings import Settings
from core.wkb import encode_triangles_batch
from etl.geom.check import Closure, closure
from etl.geom.extrude import Extrusion, extrude
from etl.geom.facade import FacadeParams, Facades, facades
from etl.lod import heights as heights_mod
from etl.lod import roofs

ROOF_SLAB_M = 0.3  # thickness of a roof drawn without walls (building:part=roof)


@dataclass
class Batch:
    meshes: list[tuple] = field(default_factory=list)  # rows in COLUMNS order
    rejects: list[tuple] = field(default_factory=list)  # (osm_type, osm_id, reason, detail)
    diagnostics: list[tuple] = field(default_factory=list)  # (osm_type, osm_id, code, detail)
    hidden: int = 0
    drawn: int = 0
    pitched: int = 0
    triangles: dict[int, int] = field(default_factory=lambda: {1: 0, 2: 0, 3: 0})
    not_closed: int = 0
    seconds: dict[str, float] = field(default_factory=lambda: {"lod1": 0.0, "lod2": 0.0, "lod3": 0.0, "encode": 0.0})


@dataclass
class Meshes:
    """Triangles of a set of buildings, grouped: building k owns triangles[offsets[k]:offsets[k+1]]."""

    triangles: np.ndarray
    semantics: np.ndarray
    offsets: np.ndarray

    def of(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        return self.triangles[self.offsets[k] : self.offsets[k + 1]], self.semantics[
            self.offsets[k] : self.offsets[k + 1]
        ]


def _areas(m: Meshes, n: int) -> np.ndarray:
    """(n, N_SEMANTICS) area per building and surface type."""
    t = m.triangles
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    owner = np.repeat(np.arange(n), np.diff(m.offsets))
    out = np.zeros((n, N_SEMANTICS))
    np.add.at(out, (owner, m.semantics.astype(np.int64)), area)
    return out


def _replace(base: Meshes, own: dict[int, tuple[np.ndarray, np.ndarray]], n: int) -> Meshes:
    """``base`` with the meshes of the buildings in ``own`` replaced."""
    if not own:
        return base
    counts = np.diff(base.offsets)
    new_counts = counts.copy()
    keys = np.fromiter(own, dtype=np.int64, count=len(own))
    new_counts[keys] = [len(own[int(j)][0]) for j in keys]
    offsets = np.concatenate([[0], np.cumsum(new_counts)]).astype(np.int64)
    tri = np.empty((int(offsets[-1]), 3, 3))
    sem = np.empty(len(tri), dtype=np.uint8)
    keep = np.ones(n, dtype=bool)
    keep[keys] = False
    owner = np.repeat(np.arange(n), counts)
    kept = keep[owner]
    dest = offsets[owner[kept]] + (np.flatnonzero(kept) - base.offsets[owner[kept]])
    tri[dest], sem[dest] = base.triangles[kept], base.semantics[kept]
    for j in keys.tolist():
        t, s_ = own[j]
        tri[offsets[j] : offsets[j + 1]], sem[offsets[j] : offsets[j + 1]] = t, s_
    return Meshes(tri, sem, offsets)


def _subset(m: Meshes, keys: np.ndarray) -> Meshes:
    """The meshes of buildings ``keys``, in that order."""
    parts = [m.of(int(j)) for j in keys]
    counts = [len(t) for t, _ in parts]
    return Meshes(
        np.concatenate([t for t, _ in parts]),
        np.concatenate([s_ for _, s_ in parts]),
        np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
    )


def _pitched_solid(
    geom: shapely.Geometry,
    arcs_wkb: bytes | None,
    shape: str,
    bottom: float,
    top: float,
    roof_tagged: float | None,
    included: bool,
    angle: float | None,
    direction: float | None,
    orientation: str | None,
    roof_only: bool,
) -> tuple[np.ndarray, np.ndarray, float, float, str, str | None]:
    """LOD2 solid of one footprint: (triangles, semantics, roof height, top, engine, fallback note)."""
    polys = list(shapely.get_parts(geom))
    arcs_all = None
    if arcs_wkb is not None:
        lines = shapely.get_parts(shapely.from_wkb(arcs_wkb))
        arcs_all = shapely.get_coordinates(lines).reshape(-1, 2, 2)
    parts, h_used, engine, note = [], 0.0, "flat", None
    for poly in polys:
        origin = np.asarray(poly.exterior.coords[0])
        local = shapely.transform(poly, lambda c, o=origin: c - o)
        arcs = None
        if arcs_all is not None and len(polys) > 1:
            mid = arcs_all.mean(axis=1)
            arcs = arcs_all[shapely.intersects_xy(poly, mid[:, 0], mid[:, 1])] - origin
        elif arcs_all is not None:
            arcs = arcs_all - origin
        # a default pitch takes at most half of a tagged height; a tagged roof may take all of it
        max_h = (top - bottom) if included else 3.0 * (top - bottom)
        if included and roof_tagged is None and angle is None:
            max_h = 0.5 * (top - bottom)
        surf, h = roofs.roof_surface(local, shape, arcs, roof_tagged, angle, direction, orientation, max_h)
        eave = top - h if included else top
        z_bottom = max(bottom, eave - ROOF_SLAB_M) if roof_only else bottom
        tri, sem = roofs.solid(surf, eave, min(z_bottom, eave), SEM_ROOF if roof_only else SEM_WALL)
        tri = tri + np.array([origin[0], origin[1], 0.0])
        parts.append((tri, sem))
        h_used, engine, note = max(h_used, h), surf.engine, surf.fallback or note
    top2 = top if included else top + h_used
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]), h_used, top2, engine, note)


def hidden_outline(out: Batch, r: dict[str, Any]) -> None:
    """Row ``r``, an outline without a footprint of its own, is drawn by its parts: counted and diagnosed."""
    out.hidden += 1
    out.diagnostics.append(
        (
            r["osm_type"],
            r["osm_id"],
            "outline_hidden_by_parts",
            "the parts leave only slivers (< 1 m²) of the outline uncovered",
        )
    )


@dataclass(frozen=True)
class _Lod1:
    """The drawn rows of a batch as columns, their heights and LOD1 blocks: what the later steps read."""

    cols: dict[str, list[Any]]  # column name -> values, in batch order
    osm_types: list[Any]
    osm_ids: list[Any]
    ids: np.ndarray
    hs: heights_mod.Heights
    geoms: np.ndarray  # footprint per row
    sel: np.ndarray  # row index of each footprint extruded (its heights valid)
    ex: Extrusion  # the blocks of the footprints sel
    good: np.ndarray  # index into sel of each drawn building
    k_of: np.ndarray  # row index of each drawn building
    n: int  # drawn buildings
    lod1: Meshes


@dataclass
class _Roofs:
    """Per drawn building, its LOD2 roof as the roof step leaves it (LOD1's flat block where ``own`` has none)."""

    bottom: np.ndarray
    top: np.ndarray
    top2: np.ndarray  # the top of the LOD2 solid (a roof on top of an untagged height raises it)
    roof_h: np.ndarray
    shape_used: np.ndarray  # object: str
    engine: np.ndarray  # object: str
    roof_only: np.ndarray  # bool: building:part=roof / building=roof, a roof without walls
    own: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # LOD2 differing from LOD1
    slabs: list[int] = field(default_factory=list)  # flat roofs without walls: extruded together after the loop


@dataclass(frozen=True)
class _Lod23:
    """The LOD2 meshes and their measure, the openings with their offsets per building, the LOD3 meshes."""

    lod2: Meshes
    cl: Closure
    fac: Facades
    f_off: np.ndarray
    lod3: Meshes


@dataclass(frozen=True)
class _LodRows:
    """What the rows of one LOD hold beyond the buildings' ids, bottoms and height sources."""

    lod: int
    mesh: Meshes
    wkbs: list[bytes]
    volume: np.ndarray
    tops: np.ndarray
    roof_h: np.ndarray
    shapes: np.ndarray
    engines: np.ndarray
    watertight: list[Any]
    winding_consistent: list[Any]
    n_windows: np.ndarray
    n_doors: np.ndarray


def build_batch(rows: list[dict[str, Any]], settings: Settings, srid: int) -> Batch:
    """Mesh rows, rejects and diagnostics for a batch of rows of lod.building_input (dicts by column name).
    Pure apart from its inputs."""
    out = Batch()
    drawn = _drawn_rows(rows, out)
    if not drawn:
        return out
    t0 = time.perf_counter()
    d = _lod1(drawn, settings, out)
    out.seconds["lod1"] += time.perf_counter() - t0

    t0 = time.perf_counter()
    r = _roofs(d, settings, out)
    lod2 = _replace(d.lod1, r.own, d.n)
    cl = closure(lod2.triangles, lod2.offsets)
    _not_closed(out, d, r, lod2, cl)
    out.seconds["lod2"] += time.perf_counter() - t0

    # LOD3: LOD2 plus windows and doors
    t0 = time.perf_counter()
    fac = _openings(d, r, settings)
    lod3, f_off = _with_openings(lod2, fac, d.n)
    out.seconds["lod3"] += time.perf_counter() - t0

    t0 = time.perf_counter()
    _rows(out, d, r, _Lod23(lod2, cl, fac, f_off, lod3), settings, srid)
    out.seconds["encode"] += time.perf_counter() - t0
    return out


def _drawn_rows(rows: list[dict[str, Any]], out: Batch) -> list[dict[str, Any]]:
    """The rows with a footprint to draw; an outline without one is drawn by its parts (a diagnostic), one whose
    parts leave some of it uncovered is drawn as that rest (a diagnostic too)."""
    drawn = []
    for r in rows:
        if r["footprint"] is None:  # an outline whose parts leave only slivers: drawn by its parts
            hidden_outline(out, r)
            continue
        if r["has_parts"]:
            out.diagnostics.append(
                (
                    r["osm_type"],
                    r["osm_id"],
                    "outline_reduced_by_parts",
                    f"parts cover {100 * (r['part_coverage'] or 0):.0f}% of the outline; the rest is drawn",
                )
            )
        drawn.append(r)
    return drawn


def _lod1(drawn: list[dict[str, Any]], settings: Settings, out: Batch) -> _Lod1:
    """The rows' heights and their LOD1 blocks; contradicting heights and failed cap triangulations are rejects."""
    cols = {k: [r[k] for r in drawn] for k in drawn[0]}  # column name -> values, in batch order
    osm_types, osm_ids = cols["osm_type"], cols["osm_id"]
    ids = np.asarray(cols["id"], dtype=np.int64)
    hs = heights_mod.resolve(
        cols["height"],
        cols["min_height"],
        cols["levels"],
        cols["min_level"],
        cols["roof_levels"],
        cols["roof_height"],
        cols["building"],
        settings,
    )
    geoms = shapely.from_wkb(cols["footprint"])
    out.rejects += [
        (osm_types[k], osm_ids[k], "min_height_ge_height", f"height {hs.top[k]:g} m <= bottom {hs.bottom[k]:g} m")
        for k in np.flatnonzero(hs.invalid)
    ]
    out.diagnostics += [
        (
            osm_types[k],
            osm_ids[k],
            "top_raised_above_min",
            f"no height tagged and the default top lay below the bottom {hs.bottom[k]:g} m; top set to {hs.top[k]:g} m",
        )
        for k in np.flatnonzero(hs.raised)
    ]
    sel = np.flatnonzero(~hs.invalid)
    ex = extrude(geoms[sel], hs.bottom[sel], hs.top[sel])
    out.rejects += [
        (
            osm_types[sel[j]],
            osm_ids[sel[j]],
            "triangulation_failed",
            "the cap triangulation does not cover the footprint",
        )
        for j in np.flatnonzero(~ex.ok)
    ]
    good = np.flatnonzero(ex.ok)
    k_of = sel[good]  # row index of each drawn building
    n = len(good)
    out.drawn = n
    # ex.offsets of failed footprints are empty ranges, so the ok ones' ranges are contiguous
    lod1 = Meshes(ex.triangles, ex.semantics, np.concatenate([ex.offsets[good], [ex.offsets[-1]]]))
    return _Lod1(cols, osm_types, osm_ids, ids, hs, geoms, sel, ex, good, k_of, n, lod1)


def _roofs(d: _Lod1, settings: Settings, out: Batch) -> _Roofs:
    """The LOD2 roof of every drawn building: its roof:shape's solid, or a slab where a flat roof has no walls."""
    n, cols = d.n, d.cols
    bottom, top = d.hs.bottom[d.k_of], d.hs.top[d.k_of]
    # building:part=roof / building=roof: a roof without walls
    roof_only = np.array(
        [
            (cols["part"][k] or "").lower() == "roof" or (cols["building"][k] or "").lower() == "roof"
            for k in d.k_of.tolist()
        ],
        dtype=bool,
    )
    r = _Roofs(
        bottom=bottom,
        top=top,
        top2=top.copy(),
        roof_h=np.zeros(n),
        shape_used=np.array(["flat"] * n, dtype=object),
        engine=np.array(["flat"] * n, dtype=object),
        roof_only=roof_only,
    )
    for j, k in enumerate(d.k_of.tolist()):
        _roof(d, r, j, k, settings.level_height_m, out)
    _slabs(d, r)
    return r


def _roof(d: _Lod1, r: _Roofs, j: int, k: int, lh: float, out: Batch) -> None:
    """Drawn building j (row k): its roof:shape read (unknown ones drawn flat), its roof height from the tags,
    and unless flat its pitched solid; flat roofs without walls are left to ``_slabs``."""
    raw = d.cols["roof_shape"][k]
    shape, known = roofs.canonical_shape(raw)
    ot, oi = d.osm_types[k], d.osm_ids[k]
    if not known:
        out.diagnostics.append((ot, oi, "unknown_roof_shape", f"roof:shape={raw} is not in the catalogue; drawn flat"))
    if shape == "flat":
        if r.roof_only[j]:
            r.slabs.append(j)
        return
    rh, rl, angle = d.cols["roof_height"][k], d.cols["roof_levels"][k], d.cols["roof_angle"][k]
    # roof:height, else roof:angle (roof_surface), else roof:levels, else the shape's default pitch
    from_levels = rh is None and angle is None and rl is not None and rl > 0
    roof_tagged = float(rh) if rh is not None else (float(rl) * lh if from_levels else None)
    if shape != "flat" and rh is None and rl is not None and rl == 0:
        out.diagnostics.append(
            (ot, oi, "pitched_roof_zero_levels", f"roof:levels=0 on a {shape} roof; the default pitch is used")
        )
    # heights.resolve put roof:height / roof:levels into the top already when the top came from levels
    included = d.hs.source[k] == "height" or rh is not None or (rl is not None and rl > 0)
    if roof_tagged is not None and roof_tagged > r.top[j] - r.bottom[j]:
        out.diagnostics.append(
            (
                ot,
                oi,
                "roof_height_clamped",
                f"roof height {roof_tagged:g} m exceeds the building's {r.top[j] - r.bottom[j]:g} m",
            )
        )
    _pitched(d, r, j, k, shape, roof_tagged, included, angle, out)


def _pitched(
    d: _Lod1,
    r: _Roofs,
    j: int,
    k: int,
    shape: str,
    roof_tagged: float | None,
    included: bool,
    angle: float | None,
    out: Batch,
) -> None:
    """Drawn building j's (row k's) pitched LOD2 solid into ``r``; when it cannot be built the building keeps its
    flat block and gets a roof_fallback diagnostic."""
    ot, oi = d.osm_types[k], d.osm_ids[k]
    try:
        direction = d.cols["roof_direction"][k]
        roof_wkb = d.cols["roof_footprint"][k]
        roof_geom = d.geoms[k] if roof_wkb is None else shapely.from_wkb(roof_wkb)
        tri, sem, h, t2, eng, note = _pitched_solid(
            roof_geom,
            d.cols["skeleton"][k],
            shape,
            float(r.bottom[j]),
            float(r.top[j]),
            roof_tagged,
            included,
            None if angle is None else float(angle),
            None if direction is None else float(direction),
            d.cols["roof_orientation"][k],
            bool(r.roof_only[j]),
        )
        r.own[j] = (tri, sem)
        r.roof_h[j], r.top2[j], r.shape_used[j], r.engine[j] = h, t2, shape, eng
        out.pitched += 1
        if note:
            out.diagnostics.append((ot, oi, "roof_fallback", f"{shape}: {note}"))
    except (roofs.RoofError, ValueError, KeyError, shapely.errors.GEOSException) as e:
        code = e.code if isinstance(e, roofs.RoofError) else type(e).__name__
        out.diagnostics.append((ot, oi, "roof_fallback", f"{shape} roof failed ({code}: {e}); drawn flat"))


def _slabs(d: _Lod1, r: _Roofs) -> None:
    """The flat roofs without walls (``r.slabs``), extruded together: a slab of ROOF_SLAB_M whose rim is roof."""
    if not r.slabs:
        return
    js = np.asarray(r.slabs)
    es = extrude(d.geoms[d.k_of[js]], np.maximum(r.bottom[js], r.top[js] - ROOF_SLAB_M), r.top[js])
    for i, j in enumerate(r.slabs):  # a slab's rim is roof, not wall
        r.own[j] = (
            es.of(i),
            np.where(
                es.semantics[es.offsets[i] : es.offsets[i + 1]] == SEM_WALL,
                SEM_ROOF,
                es.semantics[es.offsets[i] : es.offsets[i + 1]],
            ).astype(np.uint8),
        )


def _not_closed(out: Batch, d: _Lod1, r: _Roofs, lod2: Meshes, cl: Closure) -> None:
    """A not_watertight diagnostic for every LOD2 solid the closure measure fails, with trimesh's verdict."""
    bad = np.flatnonzero(~cl.ok)
    out.not_closed += len(bad)
    for j in bad.tolist():
        k = int(d.k_of[j])
        reasons = _closure_reasons(cl, j)
        t, _ = lod2.of(j)
        verdict = _trimesh_verdict(t)
        out.diagnostics.append(
            (
                d.osm_types[k],
                d.osm_ids[k],
                "not_watertight",
                f"LOD2 {r.shape_used[j]} ({r.engine[j]}): " + ", ".join(reasons) + f"; {verdict}",
            )
        )


def _closure_reasons(cl: Closure, j: int) -> list[str]:
    """Why solid j is not closed, in words."""
    reasons = []
    if cl.open_edges[j]:
        reasons.append(f"{cl.open_edges[j]} open edges")
    if cl.nonmanifold_edges[j]:
        reasons.append(f"{cl.nonmanifold_edges[j]} edges shared by 3+ triangles")
    if not cl.winding_consistent[j]:
        reasons.append("inconsistent winding")
    if cl.volume[j] <= 0:
        reasons.append(f"volume {cl.volume[j]:.3g} m³")
    return reasons


def _trimesh_verdict(t: np.ndarray) -> str:
    """trimesh's own measure of the triangles ``t``, to confirm a failed closure."""
    # failures are rare, so its per-mesh cost does not matter here; imported only then, as its import costs ~0.2 s
    import trimesh

    tm = trimesh.Trimesh((t - t[0, 0]).reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3)) if len(t) else None
    return (
        "trimesh: empty"
        if tm is None
        else f"trimesh: is_watertight={tm.is_watertight}, is_winding_consistent={tm.is_winding_consistent}, "
        f"volume={tm.volume:.3g}"
    )


def _openings(d: _Lod1, r: _Roofs, settings: Settings) -> Facades:
    """Windows and doors on the walls LOD1 stood on (none on a roof without walls), up to each building's eaves."""
    n = d.n
    # the walls LOD1 stood on, renumbered from footprints of the batch to drawn buildings
    j_of_sel = np.full(len(d.sel), -1)
    j_of_sel[d.good] = np.arange(n)
    w = d.ex.walls
    w_owner = j_of_sel[w.owner]
    keep = w_owner >= 0
    keep[keep] &= ~r.roof_only[w_owner[keep]]
    w_owner = w_owner[keep]
    eave = r.top2 - r.roof_h
    # NaN: untagged
    storeys = (heights_mod.floats(d.cols["levels"]) - np.nan_to_num(heights_mod.floats(d.cols["min_level"])))[d.k_of]
    params = FacadeParams(level_height=settings.level_height_m, style=settings.lod3_openings)
    return facades(
        w.a[keep],
        w.b[keep],
        w_owner,
        r.bottom[w_owner],
        eave[w_owner],
        storeys[w_owner],
        (r.bottom < 0.5)[w_owner],
        w.exterior[keep],
        n,
        params,
    )


def _with_openings(lod2: Meshes, fac: Facades, n: int) -> tuple[Meshes, np.ndarray]:
    """LOD3 (each building's LOD2 triangles, then its openings: placed by index arithmetic, no sort) and the
    openings' offsets per building."""
    f_counts = np.bincount(fac.owner, minlength=n)
    f_off = np.concatenate([[0], np.cumsum(f_counts)])
    counts2 = np.diff(lod2.offsets)
    off3 = lod2.offsets + f_off
    own2 = np.repeat(np.arange(n), counts2)
    dest2 = off3[own2] + (np.arange(len(own2)) - lod2.offsets[own2])
    destf = off3[fac.owner] + counts2[fac.owner] + (np.arange(len(fac.owner)) - f_off[fac.owner])
    tri3 = np.empty((len(dest2) + len(destf), 3, 3))
    sem3 = np.empty(len(tri3), dtype=np.uint8)
    tri3[dest2], sem3[dest2] = lod2.triangles, lod2.semantics
    tri3[destf], sem3[destf] = fac.triangles, fac.semantics
    return Meshes(tri3, sem3, off3), f_off


def _rows(out: Batch, d: _Lod1, r: _Roofs, m: _Lod23, settings: Settings, srid: int) -> None:
    """The rows of lod.building_mesh of every drawn building and LOD: measured, encoded, their areas summed."""
    n, lod1 = d.n, d.lod1
    # LOD3 = LOD2 + openings: their areas add up
    area2 = _areas(m.lod2, n)
    area_by_lod = {
        1: _areas(lod1, n),
        2: area2,
        3: area2 + _areas(Meshes(m.fac.triangles, m.fac.semantics, m.f_off), n),
    }
    # LOD1 is LOD2 wherever the roof is flat: measured and encoded once; only the other buildings apart
    keys = np.fromiter(r.own, dtype=np.int64, count=len(r.own))
    cl1_wt, cl1_wc = _lod1_closure(lod1, keys, m.cl)
    if settings.lod3_openings == "box":  # every opening a closed box: LOD3 is measured like LOD2
        cl3 = closure(m.lod3.triangles, m.lod3.offsets)
        vol3, cl3_wt, cl3_wc = cl3.volume, cl3.watertight.tolist(), cl3.winding_consistent.tolist()
    else:  # open panels: not a closed solid, so not measured (NULL); they enclose no volume
        vol3, cl3_wt, cl3_wc = m.cl.volume, [None] * n, [None] * n
    wkb1 = encode_triangles_batch(lod1.triangles, lod1.offsets, srid)
    wkb2 = _lod2_wkb(wkb1, m.lod2, keys, srid)
    flat = np.array(["flat"] * n, dtype=object)
    no_openings = np.zeros(n, int)
    for lr in (
        _LodRows(
            1,
            lod1,
            wkb1,
            d.ex.volume[d.good],
            r.top,
            np.zeros(n),
            flat,
            flat,
            cl1_wt.tolist(),
            cl1_wc.tolist(),
            no_openings,
            no_openings,
        ),
        _LodRows(
            2,
            m.lod2,
            wkb2,
            m.cl.volume,
            r.top2,
            r.roof_h,
            r.shape_used,
            r.engine,
            m.cl.watertight.tolist(),
            m.cl.winding_consistent.tolist(),
            no_openings,
            no_openings,
        ),
        _LodRows(
            3,
            m.lod3,
            encode_triangles_batch(m.lod3.triangles, m.lod3.offsets, srid),
            vol3,
            r.top2,
            r.roof_h,
            r.shape_used,
            r.engine,
            cl3_wt,
            cl3_wc,
            m.fac.n_windows,
            m.fac.n_doors,
        ),
    ):
        _append_rows(out, d, r, lr, area_by_lod[lr.lod])


def _lod1_closure(lod1: Meshes, keys: np.ndarray, cl: Closure) -> tuple[np.ndarray, np.ndarray]:
    """(watertight, winding consistent) of the LOD1 blocks: LOD2's, measured again only where LOD2 differs."""
    cl1_wt, cl1_wc = cl.watertight.copy(), cl.winding_consistent.copy()
    if len(keys):
        sub1 = _subset(lod1, keys)
        c1 = closure(sub1.triangles, sub1.offsets)
        cl1_wt[keys], cl1_wc[keys] = c1.watertight, c1.winding_consistent
    return cl1_wt, cl1_wc


def _lod2_wkb(wkb1: list[bytes], lod2: Meshes, keys: np.ndarray, srid: int) -> list[bytes]:
    """The LOD2 meshes as EWKB: LOD1's, encoded again only for the buildings ``keys`` whose LOD2 differs."""
    wkb2 = list(wkb1)
    if len(keys):
        sub2 = _subset(lod2, keys)
        for j, b in zip(keys.tolist(), encode_triangles_batch(sub2.triangles, sub2.offsets, srid), strict=True):
            wkb2[j] = b
    return wkb2


def _append_rows(out: Batch, d: _Lod1, r: _Roofs, lr: _LodRows, ar: np.ndarray) -> None:
    """The rows (in COLUMNS order) of one LOD of the drawn buildings into ``out``; ``ar`` their areas by surface."""
    n, m = d.n, lr.mesh
    counts = np.diff(m.offsets)
    out.triangles[lr.lod] += int(counts.sum())
    sem_bytes = m.semantics.tobytes()
    offs = m.offsets.tolist()
    out.meshes += zip(
        d.ids[d.k_of].tolist(),
        [lr.lod] * n,
        lr.wkbs,
        counts.tolist(),
        r.bottom.tolist(),
        lr.tops.tolist(),
        d.hs.source[d.k_of].tolist(),
        np.asarray(lr.volume, dtype=np.float64).tolist(),
        [sem_bytes[offs[j] : offs[j + 1]] for j in range(n)],
        [str(x) for x in lr.shapes],
        lr.roof_h.tolist(),
        [str(x) for x in lr.engines],
        ar[:, 0].tolist(),
        ar[:, 1].tolist(),
        ar[:, 2].tolist(),
        (ar[:, 3] + ar[:, 4]).tolist(),
        np.asarray(lr.n_windows).tolist(),
        np.asarray(lr.n_doors).tolist(),
        list(lr.watertight),
        list(lr.winding_consistent),
        strict=True,
    )
