"""Stage export: tiles in PostGIS -> a 3D Tiles 1.1 tileset directory.

Streams tile by tile (a few worker threads, each with its own connection): for each leaf,
api.buildings_for_tile(level, x, y, lod) gives the features with their meshes at the chosen LOD, lifted by the
base height and transformed to ECEF by PostGIS (ST_Transform to EPSG:4978, z = height above the ellipsoid);
content.py turns them into glTF arrays in the tile's local frame and gltf.py writes the glb with EXT_mesh_features +
EXT_structural_metadata. The tileset is written into ``<out>.partial`` and swapped in at the end, so a failed
export never leaves a half-written tileset behind.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from psycopg.rows import dict_row

from etl.db import connect
from etl.geom.wkb import decode_triangles
from etl.progress import Progress, summary
from etl.settings import Settings

from .content import DEFAULT_ROOF, DEFAULT_WALL, SEM_UNKNOWN, hex_rgba, tile_arrays
from .gltf import Primitive, Property, write_glb
from .tileset import TileRecord, build_tileset, region_centre

_FEATURES = """
SELECT f.osm_type, f.osm_id, f.kind, f.building_osm_type, f.building_osm_id, f.name, f.building, f.height,
       f.min_height, f.levels, f.roof_shape, f.building_colour, f.roof_colour, f.building_material,
       f.roof_material, f.lod, f.semantics, ST_AsBinary(ST_Transform(ST_Translate(f.geom, 0, 0, %s), 4978)) AS ecef_wkb
FROM api.buildings_for_tile(%s, %s, %s, %s) f
"""

OSM_TYPE = {"W": "way", "R": "relation"}

#: The property table: (column of _FEATURES, component type or None for STRING, description, required, noData)
PROPERTIES: list[tuple[str, str | None, str, bool, object]] = [
    ("osm_id", "INT64", "OSM id of the way or relation", True, None),
    ("osm_type", None, "way or relation", True, None),
    ("kind", None, "building (outline) or part (building:part)", True, None),
    ("building_osm_id", "INT64", "OSM id of the building outline this belongs to", True, None),
    ("building_osm_type", None, "way or relation (of building_osm_id)", True, None),
    ("name", None, "name=* (the building's when a part has none)", False, None),
    ("building", None, "building=* value", False, None),
    ("height", "FLOAT32", "top above ground (m)", True, None),
    ("min_height", "FLOAT32", "bottom above ground (m)", True, None),
    ("levels", "FLOAT32", "building:levels", False, -1.0),
    ("roof_shape", None, "roof shape drawn (roof:shape; flat when untagged or unknown)", False, None),
    ("building_colour", None, "building:colour (#rrggbb)", False, None),
    ("roof_colour", None, "roof:colour (#rrggbb)", False, None),
    ("building_material", None, "building:material", False, None),
    ("roof_material", None, "roof:material", False, None),
    ("lod", "UINT8", "level of detail of the mesh", True, None),
]


def build_tile_glb(rows: list[dict], region: tuple[float, ...]) -> tuple[bytes, int]:
    """glb bytes and triangle count for the feature rows (dicts with the columns of _FEATURES) of one tile."""
    tris = [decode_triangles(r["ecef_wkb"]) for r in rows]
    counts = np.array([len(t) for t in tris])
    triangles = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
    feature = np.repeat(np.arange(len(rows)), counts)
    wall = np.array([hex_rgba(r["building_colour"], DEFAULT_WALL) for r in rows], dtype=np.uint8).reshape(-1, 4)
    roof = np.array([hex_rgba(r["roof_colour"], DEFAULT_ROOF) for r in rows], dtype=np.uint8).reshape(-1, 4)
    lon, lat = region_centre(region)
    # a row without semantics falls back to colouring by orientation, alone, not the whole tile
    sem = np.concatenate([np.zeros(0, np.uint8)] + [
        np.full(len(t), SEM_UNKNOWN, np.uint8) if r["semantics"] is None
        else np.frombuffer(bytes(r["semantics"]), dtype=np.uint8) for r, t in zip(rows, tris, strict=True)])
    if len(sem) != len(triangles):
        raise RuntimeError("lod.building_mesh.semantics does not have one byte per triangle")
    arr = tile_arrays(triangles, feature, wall, roof, lon, lat, semantics=sem)
    props = []
    for name, ctype, doc, required, no_data in PROPERTIES:
        values = [r[name] for r in rows]
        if name in ("osm_type", "building_osm_type"):
            values = [OSM_TYPE[v] for v in values]
        props.append(Property(name, values, ctype, doc, no_data=no_data, required=required))
    prim = Primitive(
        positions=arr.positions, normals=arr.normals, colors=arr.colors, feature_ids=arr.feature_ids,
        indices=arr.indices, properties=props, feature_count=len(rows),
    )
    return write_glb(prim, "building", "An OSM building or building:part"), len(arr.indices) // 3


def _export_leaves(url: str, leaves: list[TileRecord], out: Path, base_height: float, workers: int,
                   progress: Progress, lod: int) -> tuple[int, int, int]:
    """Write every leaf's glb; tiles are independent, so ``workers`` threads each with their own connection
    share them (the SQL runs in separate server backends and numpy releases the GIL while it sorts)."""
    local = threading.local()
    lock = threading.Lock()
    conns: list = []

    def one(rec: TileRecord) -> tuple[int, int, int]:
        if not hasattr(local, "conn"):
            local.conn = connect(url)
            with lock:
                conns.append(local.conn)
        with local.conn.cursor(row_factory=dict_row) as cur:
            rows = cur.execute(_FEATURES, (base_height, rec.level, rec.x, rec.y, lod)).fetchall()
        glb, tri = build_tile_glb(rows, rec.region)
        assert rec.content_uri is not None
        path = out / rec.content_uri
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(glb)
        return len(rows), tri, len(glb)

    n_features = n_triangles = n_bytes = 0
    try:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            for f, t, b in pool.map(one, leaves):
                n_features, n_triangles, n_bytes = n_features + f, n_triangles + t, n_bytes + b
                progress.update(f)
    finally:
        for c in conns:
            c.close()
    return n_features, n_triangles, n_bytes


PARTIAL_MARKER = ".citylod-partial"  # marks an export in progress (or one that crashed): ours to delete


class OutputDirectoryError(RuntimeError):
    pass


def replaceable(path: Path) -> bool:
    """True when ``path`` may be deleted and rewritten: missing, an empty directory, or a tileset citylod
    wrote (its tileset.json names citylod as the generator). Anything else is the user's and is kept."""
    if not path.exists():
        return True
    if not path.is_dir():
        return False
    if not any(path.iterdir()) or (path / PARTIAL_MARKER).exists():
        return True
    try:
        asset = json.loads((path / "tileset.json").read_text()).get("asset", {})
    except (OSError, ValueError):
        return False
    return isinstance(asset, dict) and str(asset.get("generator", "")).startswith("citylod")


def export_tileset(url: str, out: Path, settings: Settings, lod: int) -> dict[str, object]:
    """Write the tileset with every building at level of detail ``lod`` (1 block, 2 roofs, 3 facades)."""
    if lod not in (1, 2, 3):
        raise ValueError(f"--lod must be 1, 2 or 3, not {lod}")
    t0 = time.perf_counter()
    partial = out.with_name(out.name + ".partial")
    for p in (out, partial):
        if not replaceable(p):
            raise OutputDirectoryError(
                f"refusing to overwrite {p}: it is not empty and holds no tileset written by citylod; "
                "choose a new or empty directory")
    with connect(url) as conn:
        records = [
            TileRecord(level=r[0], x=r[1], y=r[2], is_leaf=r[3], region=tuple(r[6]), geometric_error=r[7],
                       content_uri=r[8], n_features=r[4])
            for r in conn.execute(
                "SELECT level, x, y, is_leaf, n_features, n_triangles, region, geometric_error, content_uri"
                " FROM api.tile_tree()"
            )
        ]
        if not records:
            raise RuntimeError("no tiles: run the tiles stage first (make tiles)")
        dataset = conn.execute("SELECT source_sha256 FROM meta.dataset").fetchone()
        meshes = conn.execute("SELECT count(*) FROM lod.building_mesh WHERE lod = %s", (lod,)).fetchone()
    leaves = [r for r in records if r.is_leaf]
    in_tiles = sum(r.n_features for r in leaves)
    if meshes is None or in_tiles != meshes[0]:
        raise RuntimeError(
            f"the tiles are stale: they hold {in_tiles} features but lod.building_mesh has "
            f"{meshes[0] if meshes else 0} LOD{lod} meshes; run the lod and tiles stages again (make lod tiles)")
    if partial.exists():
        shutil.rmtree(partial)
    partial.mkdir(parents=True)
    (partial / PARTIAL_MARKER).touch()
    progress = Progress("export", "buildings", total=in_tiles)
    n_features, n_triangles, n_bytes = _export_leaves(
        url, leaves, partial, settings.base_height_m, min(4, os.cpu_count() or 1), progress, lod)
    if n_features != in_tiles:
        raise RuntimeError(f"export lost features: {in_tiles} in the tiles, {n_features} written")
    tileset = build_tileset(records, tileset_version=(dataset[0][:16] if dataset and dataset[0] else ""))
    js = json.dumps(tileset, indent=1).encode()
    (partial / "tileset.json").write_bytes(js)
    n_bytes += len(js)
    (partial / PARTIAL_MARKER).unlink()
    if out.exists():
        shutil.rmtree(out)
    partial.rename(out)
    seconds = time.perf_counter() - t0
    summary(
        "export",
        f"{n_features:,} features in {len(leaves):,} glb tiles, {n_triangles:,} triangles, "
        f"{n_bytes / 1e6:.2f} MB ({n_bytes / max(n_features, 1):,.0f} bytes/feature) -> {out}",
        seconds,
        n_features,
    )
    print(f"  tileset: {out / 'tileset.json'}", file=sys.stderr)
    return {"lod": lod, "features": n_features, "tiles": len(records), "glb": len(leaves), "triangles": n_triangles,
            "bytes": n_bytes, "bytes_per_feature": round(n_bytes / max(n_features, 1), 1),
            "seconds": round(seconds, 3), "out": str(out)}
