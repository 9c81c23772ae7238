"""Stage lod (LOD1): every building and part extruded into a closed solid in lod.building_mesh.

Streams osm.building through a server-side cursor in batches; heights are resolved for a whole batch with
numpy (etl/heights.py), the batch is extruded at once (etl/geom/extrude.py) and COPYed as POLYHEDRALSURFACE Z
EWKB (etl/geom/wkb.py). Outlines whose parts cover them (settings.outline_part_coverage, the S3DB outline rule) are not
extruded: their parts are, and the outline gets an ``outline_hidden_by_parts`` diagnostic. When parts cover
less, only what they leave uncovered is extruded (lod.outline_remainder), so outline and parts never overlap.
An outline that is itself tagged building:part=* is a part too (S3DB) and is always drawn whole.
in = meshes + outlines hidden by parts + rejects (osm.reject, stage lod), checked at the end.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import psycopg
import shapely

from .. import heights as heights_mod
from ..db import connect
from ..geom.extrude import extrude
from ..geom.wkb import encode_triangles_batch
from ..progress import Progress, summary
from ..settings import Settings

BATCH = 2000

# Outlines with parts (and not parts themselves): hidden when the parts cover enough of them, otherwise
# drawn as what the parts leave uncovered (lod.outline_remainder), which is NULL when that is only slivers.
_SELECT = """
WITH src AS (
    SELECT b.*, (b.kind = 'building' AND b.part IS NULL AND b.n_parts > 0) AS has_parts FROM osm.building b
)
SELECT b.id, b.osm_type, b.osm_id, b.building, b.height, b.min_height, b.levels, b.min_level,
       b.roof_levels, b.roof_height,
       ST_AsBinary(CASE WHEN b.has_parts THEN lod.outline_remainder(b.id) ELSE b.geom_local END),
       b.has_parts, b.part_coverage
FROM src b
WHERE NOT (b.has_parts AND coalesce(b.part_coverage, 0) >= %(coverage)s)
ORDER BY b.id
"""
_HIDDEN = """
INSERT INTO meta.diagnostic (stage, osm_type, osm_id, code, detail)
SELECT 'lod', osm_type, osm_id, 'outline_hidden_by_parts',
       format('%%s parts cover %%s%%%% of the outline (threshold %%s%%%%)', n_parts,
              round(100 * coalesce(part_coverage, 0))::int, round(100 * %(c)s::numeric))
FROM osm.building
WHERE kind = 'building' AND part IS NULL AND n_parts > 0 AND coalesce(part_coverage, 0) >= %(c)s
"""


@dataclass
class Batch:
    meshes: list[tuple] = field(default_factory=list)
    rejects: list[tuple] = field(default_factory=list)  # (osm_type, osm_id, reason, detail)
    diagnostics: list[tuple] = field(default_factory=list)  # (osm_type, osm_id, code, detail)
    hidden: int = 0


def build_batch(rows: list[tuple], settings: Settings, srid: int) -> Batch:
    """Meshes, rejects and diagnostics for a batch of rows of _SELECT. Pure apart from its inputs."""
    out = Batch()
    drawn = []
    for r in rows:
        if r[10] is None:  # an outline whose parts leave only slivers: drawn by its parts
            out.hidden += 1
            out.diagnostics.append((r[1], r[2], "outline_hidden_by_parts",
                                    "the parts leave only slivers (< 1 m²) of the outline uncovered"))
            continue
        if r[11]:
            out.diagnostics.append((r[1], r[2], "outline_reduced_by_parts",
                                    f"parts cover {100 * (r[12] or 0):.0f}% of the outline; the rest is drawn"))
        drawn.append(r)
    if not drawn:
        return out
    cols = list(zip(*drawn, strict=True))
    osm_types, osm_ids = cols[1], cols[2]
    ids = np.asarray(cols[0], dtype=np.int64)
    hs = heights_mod.resolve(cols[4], cols[5], cols[6], cols[7], cols[8], cols[9], cols[3], settings)
    geoms = shapely.from_wkb(list(cols[10]))
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
    wkbs = encode_triangles_batch(ex.triangles, ex.offsets, srid)
    n_tri = ex.counts
    out.meshes = [
        (int(ids[k]), 1, wkbs[j].hex(), int(n_tri[j]), float(hs.bottom[k]), float(hs.top[k]), str(hs.source[k]),
         float(ex.volume[j]))
        for j, k in enumerate(sel.tolist())
        if ex.ok[j]
    ]
    return out


def run(conn: psycopg.Connection, url: str, settings: Settings) -> dict[str, object]:
    t0 = time.perf_counter()
    srid_row = conn.execute("SELECT meta.working_srid()").fetchone()
    if not srid_row or srid_row[0] is None:
        raise RuntimeError("no dataset loaded: run the ingest stage first (make ingest)")
    srid = int(srid_row[0])
    coverage = settings.outline_part_coverage
    counts = {"meshes": 0, "rejected": 0, "triangles": 0}
    progress = Progress("lod", "buildings")
    # One connection streams the input, this one writes: all output lands in a single transaction.
    with connect(url) as reader, conn.transaction(), conn.cursor() as cur:
        cur.execute("DELETE FROM lod.building_mesh WHERE lod = 1")
        # the tile tree was built from the old meshes; keeping it would let export drop or miss buildings
        cur.execute("TRUNCATE tiles.building_tile, tiles.tile, tiles.grid")
        cur.execute("DELETE FROM osm.reject WHERE stage = 'lod'")
        cur.execute("DELETE FROM meta.diagnostic WHERE stage = 'lod'")
        total = cur.execute("SELECT count(*) FROM osm.building").fetchone()[0]  # type: ignore[index]
        cur.execute(_HIDDEN, {"c": coverage})
        hidden = cur.rowcount
        progress.total = total - hidden
        with reader.cursor(name="lod_input") as src:
            src.itersize = BATCH
            src.execute(_SELECT, {"coverage": coverage})
            cur.execute("CREATE TEMP TABLE _lod_reject (osm_type char(1), osm_id bigint, reason text, detail text)"
                        " ON COMMIT DROP")
            while rows := src.fetchmany(BATCH):
                b = build_batch(rows, settings, srid)
                with cur.copy(
                    "COPY lod.building_mesh (building_id, lod, geom, n_triangles, min_height, height,"
                    " height_source, volume_m3) FROM STDIN"
                ) as copy:
                    for m in b.meshes:
                        copy.write_row(m)
                if b.rejects:
                    with cur.copy("COPY _lod_reject (osm_type, osm_id, reason, detail) FROM STDIN") as copy:
                        for r in b.rejects:
                            copy.write_row(r)
                if b.diagnostics:
                    with cur.copy("COPY meta.diagnostic (stage, osm_type, osm_id, code, detail) FROM STDIN") as copy:
                        for d in b.diagnostics:
                            copy.write_row(("lod", *d))
                counts["meshes"] += len(b.meshes)
                counts["rejected"] += len(b.rejects)
                counts["triangles"] += sum(m[3] for m in b.meshes)
                hidden += b.hidden
                progress.update(len(rows))
            # rejects keep the building's tags and footprint, so nothing is lost
            cur.execute(
                """INSERT INTO osm.reject (osm_type, osm_id, stage, reason, detail, tags, geom)
                   SELECT r.osm_type, r.osm_id, 'lod', r.reason, r.detail, b.tags, b.geom
                   FROM _lod_reject r JOIN osm.building b ON b.osm_type = r.osm_type AND b.osm_id = r.osm_id"""
            )
        cur.execute("ANALYZE lod.building_mesh")
    if counts["meshes"] + counts["rejected"] + hidden != total:
        raise RuntimeError(
            f"lod lost buildings: {total} in, {counts['meshes']} meshes + {hidden} hidden"
            f" + {counts['rejected']} rejected"
        )
    seconds = time.perf_counter() - t0
    result: dict[str, object] = {
        "in": total, **counts, "hidden_by_parts": hidden, "seconds": round(seconds, 3),
        "triangles_per_building": round(counts["triangles"] / max(counts["meshes"], 1), 1),
    }
    summary(
        "lod",
        f"in {total:,} = {counts['meshes']:,} LOD1 solids + {hidden:,} outlines drawn by their parts "
        f"+ rejected {counts['rejected']:,} | {counts['triangles']:,} triangles",
        seconds,
        total,
    )
    return result
