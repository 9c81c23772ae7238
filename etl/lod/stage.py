"""Stage lod: every building and part as LOD1 (block), LOD2 (roof:shape roof) and LOD3 (LOD2 + windows and
doors) solids in lod.building_mesh, one row per building and LOD.

Streams osm.building through a server-side cursor in batches; heights are resolved for a whole batch with
numpy (etl/lod/heights.py). LOD1 and the flat LOD2 roofs (most buildings) are extruded for the whole batch at
once (etl/geom/extrude.py); pitched roofs are built per footprint from the straight skeleton SFCGAL computes
in the same query (lod.straight_skeleton, etl/lod/roofs.py); LOD3 adds windows and doors for the whole batch
(etl/geom/facade.py). Every LOD2 solid is measured (closed, consistently wound, volume > 0,
etl/geom/check.py) and failures are recorded. Meshes are COPYed as POLYHEDRALSURFACE Z EWKB with one
surface-semantic byte per triangle. The batches are built as Dask tasks (core/workers.py; settings.lod_workers),
a few in flight, while one thread COPYs the built ones in input order; a batch whose worker hangs or dies on
every attempt becomes rejects (lod_hung / lod_crashed), never a stopped run.

Outlines whose parts cover them (settings.outline_part_coverage, the S3DB outline rule) are not drawn: their
parts are, and the outline gets an ``outline_hidden_by_parts`` diagnostic. When parts cover less, only what
they leave uncovered is drawn (lod.outline_remainder, diagnostic ``outline_reduced_by_parts``), so outline
and parts never overlap. An outline that is itself tagged building:part=* is a part too (S3DB) and is
always drawn whole. building:part=roof / building=roof is a roof without walls: a slab of ROOF_SLAB_M under
the roof. in = buildings drawn + outlines hidden by parts + rejects (osm.reject, stage lod), checked at the end.
"""

from __future__ import annotations

import collections
import os
import queue
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import psycopg
import shapely
from psycopg.rows import dict_row

from core.changes import Changes
from core.db import analyze, connect, working_srid
from core.progress import Balance, Progress, summary
from core.semantics import N_SEMANTICS, SEM_ROOF, SEM_WALL
from core.settings import Settings
from core.stage import Context, Result
from core.wkb import encode_triangles_batch
from core.workers import Lost, imap_isolated, worker_count
from etl.geom.check import closure
from etl.geom.extrude import extrude
from etl.geom.facade import FacadeParams, facades
from etl.lod import heights as heights_mod
from etl.lod import roofs

ROOF_SLAB_M = 0.3  # thickness of a roof drawn without walls (building:part=roof)
LODS = (1, 2, 3)
_SKELETON_VALUES = sorted(roofs.NEEDS_SKELETON | {k for k, v in roofs.ALIASES.items() if v in roofs.NEEDS_SKELETON})

# The input is lod.building_input (sql/lod/building_input.sql: outlines hidden by their parts left out, an
# outline with parts drawn as what they leave uncovered, the roof footprint and straight skeleton where the roof
# shape needs them), an inlined SQL function streamed by a server-side cursor and read by column name. Hidden
# outlines get their diagnostics from lod.diagnose_hidden_outlines, rejects go to osm.reject through
# lod.store_rejects.
COLUMNS = (
    "building_id", "lod", "geom", "n_triangles", "min_height", "height", "height_source", "volume_m3",
    "semantics", "roof_shape", "roof_height", "roof_engine", "ground_area_m2", "wall_area_m2", "roof_area_m2",
    "opening_area_m2", "n_windows", "n_doors", "watertight", "winding_consistent",
)
# binary COPY: no hex encoding and half the bytes; EWKB goes to geometry_recv as it is
COPY_TYPES = (
    "int8", "int2", "bytea", "int4", "float4", "float4", "text", "float8", "bytea", "text", "float4", "text",
    "float8", "float8", "float8", "float8", "int4", "int4", "bool", "bool",
)


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
        return self.triangles[self.offsets[k]:self.offsets[k + 1]], self.semantics[self.offsets[k]:self.offsets[k + 1]]


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
        tri[offsets[j]:offsets[j + 1]], sem[offsets[j]:offsets[j + 1]] = t, s_
    return Meshes(tri, sem, offsets)


def _subset(m: Meshes, keys: np.ndarray) -> Meshes:
    """The meshes of buildings ``keys``, in that order."""
    parts = [m.of(int(j)) for j in keys]
    counts = [len(t) for t, _ in parts]
    return Meshes(np.concatenate([t for t, _ in parts]), np.concatenate([s_ for _, s_ in parts]),
                  np.concatenate([[0], np.cumsum(counts)]).astype(np.int64))


def _pitched_solid(geom: shapely.Geometry, arcs_wkb: bytes | None, shape: str, bottom: float, top: float,
                   roof_tagged: float | None, included: bool, angle: float | None, direction: float | None,
                   orientation: str | None, roof_only: bool
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
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]), h_used, top2, engine,
            note)


def _hidden(out: Batch, r: dict[str, Any]) -> None:
    out.hidden += 1
    out.diagnostics.append((r["osm_type"], r["osm_id"], "outline_hidden_by_parts",
                            "the parts leave only slivers (< 1 m²) of the outline uncovered"))


def build_batch(rows: list[dict[str, Any]], settings: Settings, srid: int) -> Batch:
    """Mesh rows, rejects and diagnostics for a batch of rows of lod.building_input (dicts by column name).
    Pure apart from its inputs."""
    out = Batch()
    drawn = []
    for r in rows:
        if r["footprint"] is None:  # an outline whose parts leave only slivers: drawn by its parts
            _hidden(out, r)
            continue
        if r["has_parts"]:
            out.diagnostics.append((r["osm_type"], r["osm_id"], "outline_reduced_by_parts",
                                    f"parts cover {100 * (r['part_coverage'] or 0):.0f}% of the outline; "
                                    "the rest is drawn"))
        drawn.append(r)
    if not drawn:
        return out
    t0 = time.perf_counter()
    cols = {k: [r[k] for r in drawn] for k in drawn[0]}  # column name -> values, in batch order
    osm_types, osm_ids = cols["osm_type"], cols["osm_id"]
    ids = np.asarray(cols["id"], dtype=np.int64)
    hs = heights_mod.resolve(cols["height"], cols["min_height"], cols["levels"], cols["min_level"],
                             cols["roof_levels"], cols["roof_height"], cols["building"], settings)
    geoms = shapely.from_wkb(cols["footprint"])
    out.rejects += [
        (osm_types[k], osm_ids[k], "min_height_ge_height", f"height {hs.top[k]:g} m <= bottom {hs.bottom[k]:g} m")
        for k in np.flatnonzero(hs.invalid)
    ]
    out.diagnostics += [
        (osm_types[k], osm_ids[k], "top_raised_above_min",
         f"no height tagged and the default top lay below the bottom {hs.bottom[k]:g} m; top set to {hs.top[k]:g} m")
        for k in np.flatnonzero(hs.raised)
    ]
    sel = np.flatnonzero(~hs.invalid)
    ex = extrude(geoms[sel], hs.bottom[sel], hs.top[sel])
    out.rejects += [
        (osm_types[sel[j]], osm_ids[sel[j]], "triangulation_failed",
         "the cap triangulation does not cover the footprint")
        for j in np.flatnonzero(~ex.ok)
    ]
    good = np.flatnonzero(ex.ok)
    k_of = sel[good]  # row index of each drawn building
    n = len(good)
    out.drawn = n
    # ex.offsets of failed footprints are empty ranges, so the ok ones' ranges are contiguous
    lod1 = Meshes(ex.triangles, ex.semantics, np.concatenate([ex.offsets[good], [ex.offsets[-1]]]))
    out.seconds["lod1"] += time.perf_counter() - t0

    # --- LOD2 ----------------------------------------------------------------------------------------------
    t0 = time.perf_counter()
    lh = settings.level_height_m
    bottom, top = hs.bottom[k_of], hs.top[k_of]
    top2 = top.copy()
    roof_h = np.zeros(n)
    shape_used = np.array(["flat"] * n, dtype=object)
    engine = np.array(["flat"] * n, dtype=object)
    own: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # LOD2 differing from LOD1 (pitched, roof-only)
    # building:part=roof / building=roof: a roof without walls
    roof_only = np.array([(cols["part"][k] or "").lower() == "roof" or (cols["building"][k] or "").lower() == "roof"
                          for k in k_of.tolist()], dtype=bool)
    slabs = []  # flat roofs without walls: extruded together after the loop
    for j, k in enumerate(k_of.tolist()):
        raw = cols["roof_shape"][k]
        shape, known = roofs.canonical_shape(raw)
        ot, oi = osm_types[k], osm_ids[k]
        if not known:
            out.diagnostics.append((ot, oi, "unknown_roof_shape",
                                    f"roof:shape={raw} is not in the catalogue; drawn flat"))
        if shape == "flat":
            if roof_only[j]:
                slabs.append(j)
            continue
        rh, rl, angle = cols["roof_height"][k], cols["roof_levels"][k], cols["roof_angle"][k]
        # roof:height, else roof:angle (roof_surface), else roof:levels, else the shape's default pitch
        from_levels = rh is None and angle is None and rl is not None and rl > 0
        roof_tagged = float(rh) if rh is not None else (float(rl) * lh if from_levels else None)
        if shape != "flat" and rh is None and rl is not None and rl == 0:
            out.diagnostics.append((ot, oi, "pitched_roof_zero_levels",
                                    f"roof:levels=0 on a {shape} roof; the default pitch is used"))
        # heights.resolve put roof:height / roof:levels into the top already when the top came from levels
        included = hs.source[k] == "height" or rh is not None or (rl is not None and rl > 0)
        if roof_tagged is not None and roof_tagged > top[j] - bottom[j]:
            out.diagnostics.append((ot, oi, "roof_height_clamped",
                                    f"roof height {roof_tagged:g} m exceeds the building's {top[j] - bottom[j]:g} m"))
        try:
            direction = cols["roof_direction"][k]
            roof_wkb = cols["roof_footprint"][k]
            roof_geom = geoms[k] if roof_wkb is None else shapely.from_wkb(roof_wkb)
            tri, sem, h, t2, eng, note = _pitched_solid(
                roof_geom, cols["skeleton"][k], shape, float(bottom[j]), float(top[j]), roof_tagged, included,
                None if angle is None else float(angle), None if direction is None else float(direction),
                cols["roof_orientation"][k], bool(roof_only[j]))
            own[j] = (tri, sem)
            roof_h[j], top2[j], shape_used[j], engine[j] = h, t2, shape, eng
            out.pitched += 1
            if note:
                out.diagnostics.append((ot, oi, "roof_fallback", f"{shape}: {note}"))
        except (roofs.RoofError, ValueError, KeyError, shapely.errors.GEOSException) as e:
            code = e.code if isinstance(e, roofs.RoofError) else type(e).__name__
            out.diagnostics.append((ot, oi, "roof_fallback", f"{shape} roof failed ({code}: {e}); drawn flat"))
    if slabs:
        js = np.asarray(slabs)
        es = extrude(geoms[k_of[js]], np.maximum(bottom[js], top[js] - ROOF_SLAB_M), top[js])
        for i, j in enumerate(slabs):  # a slab's rim is roof, not wall
            own[j] = (es.of(i), np.where(es.semantics[es.offsets[i]:es.offsets[i + 1]] == SEM_WALL, SEM_ROOF,
                                         es.semantics[es.offsets[i]:es.offsets[i + 1]]).astype(np.uint8))
    lod2 = _replace(lod1, own, n)
    cl = closure(lod2.triangles, lod2.offsets)
    bad = np.flatnonzero(~cl.ok)
    out.not_closed += len(bad)
    for j in bad.tolist():
        k = int(k_of[j])
        reasons = []
        if cl.open_edges[j]:
            reasons.append(f"{cl.open_edges[j]} open edges")
        if cl.nonmanifold_edges[j]:
            reasons.append(f"{cl.nonmanifold_edges[j]} edges shared by 3+ triangles")
        if not cl.winding_consistent[j]:
            reasons.append("inconsistent winding")
        if cl.volume[j] <= 0:
            reasons.append(f"volume {cl.volume[j]:.3g} m³")
        # confirm with trimesh itself (failures are rare, so its per-mesh cost does not matter here; imported
        # only then, as its import costs ~0.2 s)
        import trimesh

        t, _ = lod2.of(j)
        tm = trimesh.Trimesh((t - t[0, 0]).reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3)) if len(t) else None
        verdict = ("trimesh: empty" if tm is None else
                   f"trimesh: is_watertight={tm.is_watertight}, is_winding_consistent={tm.is_winding_consistent}, "
                   f"volume={tm.volume:.3g}")
        out.diagnostics.append((osm_types[k], osm_ids[k], "not_watertight",
                                f"LOD2 {shape_used[j]} ({engine[j]}): " + ", ".join(reasons) + f"; {verdict}"))
    out.seconds["lod2"] += time.perf_counter() - t0

    # --- LOD3: LOD2 plus windows and doors ----------------------------------------------------------------
    t0 = time.perf_counter()
    # the walls LOD1 stood on, renumbered from footprints of the batch to drawn buildings
    j_of_sel = np.full(len(sel), -1)
    j_of_sel[good] = np.arange(n)
    w = ex.walls
    w_owner = j_of_sel[w.owner]
    keep = w_owner >= 0
    keep[keep] &= ~roof_only[w_owner[keep]]
    w_owner = w_owner[keep]
    eave = top2 - roof_h
    # NaN: untagged
    storeys = (heights_mod.floats(cols["levels"]) - np.nan_to_num(heights_mod.floats(cols["min_level"])))[k_of]
    params = FacadeParams(level_height=lh, style=settings.lod3_openings)
    fac = facades(w.a[keep], w.b[keep], w_owner, bottom[w_owner], eave[w_owner], storeys[w_owner],
                  (bottom < 0.5)[w_owner], w.exterior[keep], n, params)
    f_counts = np.bincount(fac.owner, minlength=n)
    f_off = np.concatenate([[0], np.cumsum(f_counts)])
    # each building's LOD2 triangles, then its openings: placed by index arithmetic, no sort
    counts2 = np.diff(lod2.offsets)
    off3 = lod2.offsets + f_off
    own2 = np.repeat(np.arange(n), counts2)
    dest2 = off3[own2] + (np.arange(len(own2)) - lod2.offsets[own2])
    destf = off3[fac.owner] + counts2[fac.owner] + (np.arange(len(fac.owner)) - f_off[fac.owner])
    tri3 = np.empty((len(dest2) + len(destf), 3, 3))
    sem3 = np.empty(len(tri3), dtype=np.uint8)
    tri3[dest2], sem3[dest2] = lod2.triangles, lod2.semantics
    tri3[destf], sem3[destf] = fac.triangles, fac.semantics
    lod3 = Meshes(tri3, sem3, off3)
    out.seconds["lod3"] += time.perf_counter() - t0

    # --- rows ------------------------------------------------------------------------------------------------
    t0 = time.perf_counter()
    # LOD3 = LOD2 + openings: their areas add up
    area2 = _areas(lod2, n)
    area_by_lod = {1: _areas(lod1, n), 2: area2, 3: area2 + _areas(Meshes(fac.triangles, fac.semantics, f_off), n)}
    # LOD1 is LOD2 wherever the roof is flat: measured and encoded once; only the other buildings apart
    keys = np.fromiter(own, dtype=np.int64, count=len(own))
    cl1_wt, cl1_wc = cl.watertight.copy(), cl.winding_consistent.copy()
    if len(keys):
        sub1 = _subset(lod1, keys)
        c1 = closure(sub1.triangles, sub1.offsets)
        cl1_wt[keys], cl1_wc[keys] = c1.watertight, c1.winding_consistent
    if settings.lod3_openings == "box":  # every opening a closed box: LOD3 is measured like LOD2
        cl3 = closure(lod3.triangles, lod3.offsets)
        vol3, cl3_wt, cl3_wc = cl3.volume, cl3.watertight.tolist(), cl3.winding_consistent.tolist()
    else:  # open panels: not a closed solid, so not measured (NULL); they enclose no volume
        vol3, cl3_wt, cl3_wc = cl.volume, [None] * n, [None] * n
    wkb1 = encode_triangles_batch(lod1.triangles, lod1.offsets, srid)
    wkb2 = list(wkb1)
    if len(keys):
        sub2 = _subset(lod2, keys)
        for j, b in zip(keys.tolist(), encode_triangles_batch(sub2.triangles, sub2.offsets, srid), strict=True):
            wkb2[j] = b
    flat = np.array(["flat"] * n, dtype=object)
    for lod, m, wkbs, vol, tops, rh_, shp, eng, wt, wc in (
        (1, lod1, wkb1, ex.volume[good], top, np.zeros(n), flat, flat, cl1_wt.tolist(), cl1_wc.tolist()),
        (2, lod2, wkb2, cl.volume, top2, roof_h, shape_used, engine, cl.watertight.tolist(),
         cl.winding_consistent.tolist()),
        (3, lod3, encode_triangles_batch(lod3.triangles, lod3.offsets, srid), vol3, top2, roof_h, shape_used, engine,
         cl3_wt, cl3_wc),
    ):
        ar = area_by_lod[lod]
        counts = np.diff(m.offsets)
        nwin = fac.n_windows if lod == 3 else np.zeros(n, int)
        ndoor = fac.n_doors if lod == 3 else np.zeros(n, int)
        out.triangles[lod] += int(counts.sum())
        sem_bytes = m.semantics.tobytes()
        offs = m.offsets.tolist()
        out.meshes += zip(
            ids[k_of].tolist(), [lod] * n, wkbs, counts.tolist(), bottom.tolist(), tops.tolist(),
            hs.source[k_of].tolist(), np.asarray(vol, dtype=np.float64).tolist(),
            [sem_bytes[offs[j]:offs[j + 1]] for j in range(n)], [str(x) for x in shp], rh_.tolist(),
            [str(x) for x in eng], ar[:, 0].tolist(), ar[:, 1].tolist(), ar[:, 2].tolist(),
            (ar[:, 3] + ar[:, 4]).tolist(), np.asarray(nwin).tolist(), np.asarray(ndoor).tolist(),
            list(wt), list(wc), strict=True,
        )
    out.seconds["encode"] += time.perf_counter() - t0
    return out


def _build(item: tuple[list[dict[str, Any]], Settings, int]) -> Batch:
    return build_batch(*item)


def _lost_batch(rows: list[dict[str, Any]], lost: Lost) -> Batch:
    """A batch whose worker hung or died on it: its buildings become rejects with the reason, so none is lost
    (the outlines without a footprint are drawn by their parts, as build_batch would say)."""
    out = Batch()
    for r in rows:
        if r["footprint"] is None:
            _hidden(out, r)
        else:
            out.rejects.append((r["osm_type"], r["osm_id"], f"lod_{lost.reason}",
                                f"its batch of {len(rows)} buildings: {lost.detail}"))
    return out


def _built(src: psycopg.Cursor, settings: Settings, srid: int,
           failure: list[BaseException]) -> Iterator[tuple[list[dict[str, Any]], Batch]]:
    """(rows, their Batch) for every batch of the input, in input order: built here with one worker, else as
    Dask tasks (core/workers.py) with a few batches in flight, so the city is never held whole."""
    batches = iter(lambda: [] if failure else src.fetchmany(settings.lod_batch_size), [])
    # the database COPYs the meshes while they are built: it keeps a core (on 2 cores the stage's own process
    # and the COPY thread were faster than 2 Dask workers: 15 s against 21 s on Liechtenstein x6, measured)
    workers = worker_count(settings.lod_workers, min(4, max(1, (os.cpu_count() or 1) - 1)))
    if workers <= 1:
        for rows in batches:
            yield rows, build_batch(rows, settings, srid)
        return
    flight: collections.deque[list[dict[str, Any]]] = collections.deque()

    def items() -> Iterator[tuple[list[dict[str, Any]], Settings, int]]:
        for rows in batches:
            flight.append(rows)
            yield rows, settings, srid

    for out in imap_isolated(_build, items(), workers, settings.lod_batch_timeout_s, window=2 * workers):
        rows = flight.popleft()
        yield rows, (_lost_batch(rows, out) if isinstance(out, Lost) else out)


def run(ctx: Context) -> Result:
    """Draw every building; in an update that knows what changed since the last run, only the buildings it
    changed, with their outlines and parts (lod.affected_buildings), keeping every other building's meshes."""
    conn, url, settings = ctx.conn, ctx.url, ctx.settings
    changed = ctx.update and ctx.changed is not None
    t0 = time.perf_counter()
    srid = working_srid(conn)
    coverage = settings.outline_part_coverage
    counts = {"buildings": 0, "meshes": 0, "rejected": 0, "pitched_roofs": 0, "lod2_not_closed": 0,
              "triangles_lod1": 0, "triangles_lod2": 0, "triangles_lod3": 0}
    seconds = {"lod1": 0.0, "lod2": 0.0, "lod3": 0.0, "encode": 0.0, "copy": 0.0}
    progress = Progress("lod", "buildings")
    # One connection streams the input, this one writes: all output lands in a single transaction.
    with connect(url) as reader, conn.transaction(), conn.cursor() as cur:
        # TRUNCATE when the table holds nothing but this stage's LODs: with wal_level=minimal (the local
        # cluster) PostgreSQL then writes the COPY without WAL, ~300 MB less on a 20k-building city
        only: list[int] | None = None
        if changed:
            assert ctx.changed is not None
            only = [i for (i,) in cur.execute("SELECT id FROM lod.affected_buildings(%s)",
                                              (sorted(set(ctx.changed.buildings)),))]
            keys = [("W" if i > 0 else "R", abs(i)) for i in only]  # osm2pgsql ids: way id, or minus the relation's
            cur.execute("DELETE FROM lod.building_mesh WHERE building_id = ANY(%s) AND lod = ANY(%s)",
                        (only, list(LODS)))
            for table in ("osm.reject", "meta.diagnostic"):
                cur.execute(f"DELETE FROM {table} WHERE stage = 'lod' AND (osm_type, osm_id) IN "  # noqa: S608
                            "(SELECT * FROM unnest(%s::text[], %s::bigint[]))",
                            ([k[0] for k in keys], [k[1] for k in keys]))
        else:
            others = cur.execute("SELECT EXISTS (SELECT 1 FROM lod.building_mesh WHERE lod <> ALL(%s))",
                                 (list(LODS),)).fetchone()[0]  # type: ignore[index]
            if others:
                cur.execute("DELETE FROM lod.building_mesh WHERE lod = ANY(%s)", (list(LODS),))
            else:
                cur.execute("TRUNCATE lod.building_mesh")
            # the tile tree and its generalized content were built from the old meshes; keeping them would let
            # export drop or miss buildings
            cur.execute("TRUNCATE gen.block, gen.building_mesh, gen.footprint, tiles.building_tile, "
                        "tiles.tile_content, tex.page, tex.feature_uv, tex.failure, tiles.tile, tiles.grid "
                        "RESTART IDENTITY")
            cur.execute("DELETE FROM osm.reject WHERE stage = 'lod'")
            cur.execute("DELETE FROM meta.diagnostic WHERE stage = 'lod'")
        total = cur.execute("SELECT count(*) FROM osm.building WHERE %s::bigint[] IS NULL OR id = ANY(%s)",
                            (only, only)).fetchone()[0]  # type: ignore[index]
        hidden = cur.execute("CALL lod.diagnose_hidden_outlines(%s, NULL, %s)",
                             (coverage, only)).fetchone()[0]  # type: ignore[index]
        progress.total = total - hidden
        with reader.cursor(name="lod_input", row_factory=dict_row) as src:
            src.itersize = settings.lod_batch_size
            src.execute("SELECT * FROM lod.building_input(%s, %s, %s)", (coverage, _SKELETON_VALUES, only))
            # The database parses and indexes a batch (COPY) while Python builds the next: two cores busy.
            pending: queue.Queue[Batch | None] = queue.Queue(maxsize=2)
            failure: list[BaseException] = []

            def write() -> None:
                try:
                    while (b := pending.get()) is not None:
                        tc = time.perf_counter()
                        with cur.copy(f"COPY lod.building_mesh ({', '.join(COLUMNS)}) FROM STDIN (FORMAT BINARY)"
                                      ) as copy:
                            copy.set_types(list(COPY_TYPES))
                            for m in b.meshes:
                                copy.write_row(m)
                        if b.rejects:  # few: with their tags and footprint, so nothing is lost
                            cur.execute("CALL lod.store_rejects(%s, %s, %s, %s)",
                                        [list(c) for c in zip(*b.rejects, strict=True)])
                        if b.diagnostics:
                            with cur.copy("COPY meta.diagnostic (stage, osm_type, osm_id, code, detail) FROM STDIN"
                                          ) as copy:
                                for d in b.diagnostics:
                                    copy.write_row(("lod", *d))
                        seconds["copy"] += time.perf_counter() - tc
                except BaseException as e:  # noqa: BLE001 - handed to the main thread
                    failure.append(e)
                    while pending.get() is not None:  # drain so the producer never blocks
                        pass

            writer = threading.Thread(target=write, name="lod-copy")
            writer.start()
            try:
                for rows, b in _built(src, settings, srid, failure):
                    for key, v in b.seconds.items():
                        seconds[key] += v
                    counts["buildings"] += b.drawn
                    counts["meshes"] += len(b.meshes)
                    counts["rejected"] += len(b.rejects)
                    counts["pitched_roofs"] += b.pitched
                    counts["lod2_not_closed"] += b.not_closed
                    for lod in LODS:
                        counts[f"triangles_lod{lod}"] += b.triangles[lod]
                    hidden += b.hidden
                    pending.put(b)
                    progress.update(len(rows))
            finally:
                pending.put(None)
                writer.join()
            if failure:
                raise failure[0]
        analyze(cur, "lod.building_mesh", counts["meshes"] if changed else None)
    balance = Balance("buildings and parts", total,
                      {"drawn": counts["buildings"], "outlines drawn by their parts": hidden}, counts["rejected"])
    wall = time.perf_counter() - t0
    nb = max(counts["buildings"], 1)
    result: dict[str, object] = {
        **counts, **balance.counts(), "hidden_by_parts": hidden, "seconds": round(wall, 3),
        "changed_only": changed,
        "seconds_by_step": {k: round(v, 3) for k, v in seconds.items()},
        **{f"triangles_per_building_lod{lod}": round(counts[f"triangles_lod{lod}"] / nb, 1) for lod in LODS},
        "lod2_closed_pct": round(100.0 * (1 - counts["lod2_not_closed"] / nb), 3),
    }
    summary(
        "lod", balance,
        f"{counts['pitched_roofs']:,} pitched roofs, LOD2 closed {result['lod2_closed_pct']}% | triangles LOD1 "
        f"{counts['triangles_lod1']:,}, LOD2 {counts['triangles_lod2']:,}, LOD3 {counts['triangles_lod3']:,}",
        wall, total,
    )
    # an update: only the buildings ingest recorded (and their kin, reached through their group)
    return Result(result, Changes() if changed else None)
