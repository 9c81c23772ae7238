"""Stage lod (LOD1): every building and part extruded into a closed solid in lod.building_mesh.

Streams osm.building through a server-side cursor in batches; heights are resolved for a whole batch with
numpy (etl/heights.py), the batch is extruded at once (etl/geom/extrude.py) and COPYed as POLYHEDRALSURFACE Z
EWKB (etl/geom/wkb.py). Outlines whose parts cover them (settings.outline_part_coverage, the S3DB outline rule) are not
extruded: their parts are, and the outline gets an ``outline_hidden_by_parts`` diagnostic. An outline that
is itself tagged building:part=* is a part too (S3DB) and is always drawn.
in = meshes + outlines hidden by parts + rejects (osm.reject, stage lod), checked at the end.
"""

from __future__ import annotations

import time

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

_SELECT = """
SELECT b.id, b.osm_type, b.osm_id, b.building, b.height, b.min_height, b.levels, b.min_level,
       b.roof_levels, b.roof_height, ST_AsBinary(b.geom_local)
FROM osm.building b
WHERE NOT (b.kind = 'building' AND b.part IS NULL AND b.n_parts > 0
           AND coalesce(b.part_coverage, 0) >= %(coverage)s)
ORDER BY b.id
"""


def build_batch(
    rows: list[tuple], settings: Settings, srid: int
) -> tuple[list[tuple], list[tuple], list[tuple]]:
    """Meshes, rejects and diagnostics for a batch of osm.building rows. Pure apart from its inputs."""
    cols = list(zip(*rows, strict=True))
    osm_types, osm_ids = cols[1], cols[2]
    ids = np.asarray(cols[0], dtype=np.int64)
    hs = heights_mod.resolve(cols[4], cols[5], cols[6], cols[7], cols[8], cols[9], cols[3], settings)
    geoms = shapely.from_wkb(list(cols[10]))
    rejects: list[tuple] = [
        (osm_types[k], osm_ids[k], "lod", "min_height_ge_height",
         f"height {hs.top[k]:g} m <= bottom {hs.bottom[k]:g} m")
        for k in np.flatnonzero(hs.invalid)
    ]
    diags: list[tuple] = [
        (osm_types[k], osm_ids[k], "top_raised_above_min",
         f"no height tagged and the default top lay below the bottom {hs.bottom[k]:g} m; top set to {hs.top[k]:g} m")
        for k in np.flatnonzero(hs.raised)
    ]
    sel = np.flatnonzero(~hs.invalid)
    ex = extrude(geoms[sel], hs.bottom[sel], hs.top[sel])
    for j in np.flatnonzero(~ex.ok):
        k = sel[j]
        rejects.append((osm_types[k], osm_ids[k], "lod", "triangulation_failed",
                        "the cap triangulation does not cover the footprint"))
    wkbs = encode_triangles_batch(ex.triangles, ex.offsets, srid)
    n_tri = ex.counts
    meshes = [
        (int(ids[k]), 1, wkbs[j].hex(), int(n_tri[j]), float(hs.bottom[k]), float(hs.top[k]), str(hs.source[k]),
         float(ex.volume[j]))
        for j, k in enumerate(sel.tolist())
        if ex.ok[j]
    ]
    return meshes, rejects, diags


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
        cur.execute("DELETE FROM osm.reject WHERE stage = 'lod'")
        cur.execute("DELETE FROM meta.diagnostic WHERE stage = 'lod'")
        total = cur.execute("SELECT count(*) FROM osm.building").fetchone()[0]  # type: ignore[index]
        cur.execute(
            """INSERT INTO meta.diagnostic (stage, osm_type, osm_id, code, detail)
               SELECT 'lod', osm_type, osm_id, 'outline_hidden_by_parts',
                      format('%%s parts cover %%s%%%% of the outline (threshold %%s%%%%)', n_parts,
                             round(100 * coalesce(part_coverage, 0))::int, round(100 * %(c)s::numeric))
               FROM osm.building
               WHERE kind = 'building' AND part IS NULL AND n_parts > 0
                 AND coalesce(part_coverage, 0) >= %(c)s""",
            {"c": coverage},
        )
        hidden = cur.rowcount
        progress.total = total - hidden
        with reader.cursor(name="lod_input") as src:
            src.itersize = BATCH
            src.execute(_SELECT, {"coverage": coverage})
            while rows := src.fetchmany(BATCH):
                meshes, rejects, diags = build_batch(rows, settings, srid)
                with cur.copy(
                    "COPY lod.building_mesh (building_id, lod, geom, n_triangles, min_height, height,"
                    " height_source, volume_m3) FROM STDIN"
                ) as copy:
                    for m in meshes:
                        copy.write_row(m)
                if rejects:
                    cur.executemany(
                        "INSERT INTO osm.reject (osm_type, osm_id, stage, reason, detail, tags, geom)"
                        " SELECT %s, %s, %s, %s, %s, b.tags, b.geom FROM osm.building b"
                        " WHERE b.osm_type = %s AND b.osm_id = %s",
                        [(*r, r[0], r[1]) for r in rejects],
                    )
                if diags:
                    cur.executemany(
                        "INSERT INTO meta.diagnostic (stage, osm_type, osm_id, code, detail)"
                        " VALUES ('lod', %s, %s, %s, %s)",
                        diags,
                    )
                counts["meshes"] += len(meshes)
                counts["rejected"] += len(rejects)
                counts["triangles"] += sum(m[3] for m in meshes)
                progress.update(len(rows))
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
