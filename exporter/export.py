"""Stage export: tiles in PostGIS -> a 3D Tiles 1.1 tileset directory.

Streams tile by tile (threads, or Dask tasks: each with its own connection; core/workers.py): for each tile,
api.buildings_for_tile(level, x, y) gives the features of its band (blocks at the root down to LOD3 at the
leaves; REPLACE refinement), or with ``lod`` every building of each leaf at that one LOD (ADD), lifted by the
base height and transformed to ECEF by PostGIS (ST_Transform to EPSG:4978, z = height above the ellipsoid);
content.py turns them into glTF arrays in the tile's local frame and gltf.py writes the glb with EXT_mesh_features +
EXT_structural_metadata. Where the textures stage made atlas pages for a tile (tex.page, tex.feature_uv; the
hierarchy only, not ``lod`` tilesets), its features are drawn with one material per page (TEXCOORD_0, WebP);
a tile without texture rows is written exactly as before. The tileset is written into ``<out>.partial`` and
swapped in at the end in one step (swap_in), so a failed export never leaves a half-written tileset behind and a
reader of ``<out>`` never meets a tileset.json naming files not there; exports into one directory take turns.
An export that publishes copies the glb of every tile whose input is the one its tileset's live generation was
built from (exporter/reuse.py) and builds the others.
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import errno
import fcntl
import hashlib
import json
import os
import shutil
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TypedDict

import numpy as np
import psycopg
import shapely
from psycopg.rows import dict_row

from core.db import connect, thread_map
from core.geodesy import Z_UP_TO_Y_UP, enu_rotation, geodetic_to_ecef
from core.progress import Balance, Progress, summary
from core.settings import Settings
from core.stage import Context, Result
from core.wkb import decode_triangles
from exporter.content import DEFAULT_ROOF, DEFAULT_WALL, SEM_UNKNOWN, ContentArrays, hex_rgba, tile_arrays
from exporter.gltf import Image, Primitive, Property, class_schema, plan_quantization, read_glb, write_glb
from exporter.meshopt import CompressionError
from exporter.publish import check_name, publish
from exporter.reuse import Glbs, copy_unchanged, plan_glbs, recipe
from exporter.stream import COMPACT, StreamOptions
from exporter.tileset import TileRecord, build, node_matrix, region_centre

TILESET_JSON = "tileset.json"

# A tile's features as the glb holds them (api.export_features: api.buildings_for_tile's rows with ECEF meshes and
# the landmark metadata), its atlas pages and UVs (api.tile_pages, api.tile_uvs); rows read by column name.
_FEATURES = "SELECT * FROM api.export_features(%(level)s, %(x)s, %(y)s, %(lod)s, %(base)s)"
_PAGES = "SELECT page_no, mime, bytes FROM api.tile_pages(%s, %s, %s, %s)"
_UVS = "SELECT feature_kind, feature_id, n_triangles, page, uv FROM api.tile_uvs(%s, %s, %s)"

OSM_TYPE = {"W": "way", "R": "relation", "B": "block"}

#: The property table: (column of api.export_features, component type or None for STRING, description, required, noData)
PROPERTIES: list[tuple[str, str | None, str, bool, object]] = [
    ("osm_id", "INT64", "OSM id of the way or relation (gen.block.block_id for a block)", True, None),
    ("osm_type", None, "way, relation or block", True, None),
    ("kind", None, "building (outline), part (building:part) or block (buildings merged)", True, None),
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
    ("lod", "UINT8", "level of detail of the mesh: 0 block, 1 simplified block, 2 roofs, 3 facades", True, None),
    (
        "gen_level",
        "INT8",
        "generalization level (gen.tolerance): 1 and below blocks (10 m at 0, 20 m at -1, ...), "
        "2 simplified, 3 LOD2, 4 LOD3",
        True,
        None,
    ),
    ("n_members", "UINT32", "buildings merged into this feature (1 unless a block)", True, None),
    ("error_m", "FLOAT32", "bound on the distance to the full-detail model (m)", True, None),
    # the level, not the city-wide rank: one edit shifts the rank of every building below it, and so every tile
    (
        "lm_level",
        "UINT8",
        "landmark level of the building (lm.building.level): the Delaunay voting rounds it won, "
        "0 for most; the higher, the farther away it stands out (absent on blocks)",
        False,
        255,
    ),
    # landmark exaggeration (api.landmark_scale / api.landmark_exaggeration, done by the client per frame)
    (
        "lm_role",
        "UINT8",
        "landmark exaggeration: 1 a landmark, 2 a building its scaled footprint would cover, 0 neither",
        True,
        None,
    ),
    ("lm_landmark_osm_id", "INT64", "the landmark (itself for role 1, the one that pushes it for role 2)", False, 0),
    (
        "lm_scale_from_m",
        "FLOAT32",
        "the landmark's intervals: from camera distance lm_scale_from_m * "
        "lm_scale_step^i on, scale min(lm_scale_step^(i+1), lm_max_scale); 1 before the first (0 unless role > 0)",
        True,
        None,
    ),
    ("lm_scale_step", "FLOAT32", "see lm_scale_from_m (0 unless role > 0)", True, None),
    ("lm_max_scale", "FLOAT32", "see lm_scale_from_m (1 unless role > 0)", True, None),
    (
        "lm_centre_x",
        "FLOAT32",
        "the landmark's footprint centre at ground level in this glTF's frame (y up)",
        True,
        None,
    ),
    ("lm_centre_y", "FLOAT32", "see lm_centre_x", True, None),
    ("lm_centre_z", "FLOAT32", "see lm_centre_x", True, None),
    ("lm_radius_m", "FLOAT32", "radius of the landmark's footprint circle (m)", True, None),
    (
        "lm_gap_m",
        "FLOAT32",
        "role 2: gap between this building's footprint circle and the landmark's at scale 1 "
        "(m, negative when they overlap); at scale s it moves max(0, (s - 1) * lm_radius_m - max(gap, 0)) away "
        "along lm_dir",
        True,
        None,
    ),
    (
        "lm_dir_x",
        "FLOAT32",
        "role 2: horizontal unit vector from the landmark's centre to this building's, in this glTF's frame",
        True,
        None,
    ),
    ("lm_dir_y", "FLOAT32", "see lm_dir_x (0: horizontal)", True, None),
    ("lm_dir_z", "FLOAT32", "see lm_dir_x", True, None),
]

#: compact geometry: the frame of the landmark metadata said precisely (plain glbs keep the words above)
COMPACT_DOCS = {
    "lm_centre_x": "the landmark's footprint centre at ground level in this glTF's mesh frame (m, y up): the "
    "frame of POSITION times its node's scale, before the node's translation (the quantization origin)",
    "lm_dir_x": "role 2: horizontal unit vector from the landmark's centre to this building's, in this glTF's "
    "mesh frame (see lm_centre_x)",
}


#: the glbs' property-table class (name, description)
BUILDING_CLASS = ("building", "An OSM building or building:part")


def building_schema_class(compact: bool = True) -> dict[str, object]:
    """The glbs' building class with its descriptions, for tileset.json's schema: compact glbs carry the class
    without them (a few kB in every glb)."""
    props = [
        Property(name, (), ctype, COMPACT_DOCS.get(name, doc) if compact else doc, no_data=no_data, required=required)
        for name, ctype, doc, required, no_data in PROPERTIES
    ]
    return class_schema(props, *BUILDING_CLASS)


@dataclass(frozen=True)
class TileTextures:
    """A tile's atlas pages and, per feature (feature_kind, building_id), its triangles' pages and corner UVs."""

    images: list[Image]
    uvs: dict[tuple[str, int], tuple[np.ndarray, np.ndarray]]  # (m,) int16 page, (m, 3, 2) float32 uv


def load_textures(
    conn: psycopg.Connection, level: int, x: int, y: int, fmt: str = COMPACT.textures
) -> TileTextures | None:
    """The tile's textures (tex.page in ``fmt``, ktx2 or webp, and tex.feature_uv), None when the textures stage
    has not textured it. A feature with a triangle on a page that has no KTX2 (the encoder refused it: tex.failure
    ktx2_encode_failed) is drawn with vertex colours in a ktx2 export: its UVs are left out."""
    with conn.cursor(row_factory=dict_row) as cur:
        pages = cur.execute(_PAGES, (level, x, y, fmt)).fetchall()
        if not pages:
            return None
        if [p["page_no"] for p in pages] != list(range(len(pages))):
            raise RuntimeError(f"tex.page of tile {level}/{x}/{y} is not numbered 0..{len(pages) - 1}")
        missing = np.array([p["page_no"] for p in pages if p["bytes"] is None], np.int16)
        uvs = {}
        for u in cur.execute(_UVS, (level, x, y)):
            page = np.frombuffer(bytes(u["page"]), "<i2").copy()
            if len(missing) and np.isin(page, missing).any():
                continue
            uvs[(u["feature_kind"], int(u["feature_id"]))] = (
                page,
                np.frombuffer(bytes(u["uv"]), "<f4").reshape(u["n_triangles"], 3, 2),
            )
    # a page without bytes is used by no UV left, so build_tile_glb never embeds it
    return TileTextures([Image(bytes(p["bytes"] or b""), p["mime"]) for p in pages], uvs)


def _split(arr: ContentArrays, n_pages: int) -> tuple[ContentArrays, list[tuple[int, ContentArrays]]]:
    """The vertex-coloured part and one part per atlas page (a triangle's corners share their page)."""
    assert arr.pages is not None and arr.uvs is not None  # tile_arrays gives both or neither
    pages, uvs = arr.pages, arr.uvs
    tri_page = pages[arr.indices[0::3]] if len(arr.indices) else np.zeros(0, np.int16)

    def part(p: int) -> ContentArrays:
        keep_v = pages == p
        new = np.cumsum(keep_v) - 1
        tris = arr.indices.reshape(-1, 3)[tri_page == p]
        return replace(
            arr,
            positions=arr.positions[keep_v],
            normals=arr.normals[keep_v],
            colors=arr.colors[keep_v],
            feature_ids=arr.feature_ids[keep_v],
            indices=new[tris].reshape(-1).astype(np.uint32),
            uvs=uvs[keep_v],
            pages=pages[keep_v],
        )

    return part(-1), [(p, part(p)) for p in range(n_pages) if np.any(tri_page == p)]


def build_tile_glb(
    rows: list[dict],
    region: tuple[float, ...],
    textures: TileTextures | None = None,
    stream: StreamOptions = COMPACT,
    rec: TileRecord | None = None,
    node_matrix: list[float] | None = None,
) -> tuple[bytes, int]:
    """glb bytes and triangle count for the feature rows (dicts with the columns of api.export_features) of one tile;
    with ``textures``, the features that have UVs are drawn with their atlas pages; ``node_matrix`` places the
    tile's frame in the root's (tileset.node_matrix). ``stream.geometry`` compact: quantized
    (``position_error_m(rec)``) meshopt-compressed geometry; a tile meshoptimizer refuses is written plain with a
    warning."""
    rows_in = rows
    tris = [decode_triangles(r["ecef_wkb"]) for r in rows]
    counts = np.array([len(t) for t in tris])
    triangles = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
    feature = np.repeat(np.arange(len(rows)), counts)
    wall = np.array([hex_rgba(r["building_colour"], DEFAULT_WALL) for r in rows], dtype=np.uint8).reshape(-1, 4)
    roof = np.array([hex_rgba(r["roof_colour"], DEFAULT_ROOF) for r in rows], dtype=np.uint8).reshape(-1, 4)
    lon, lat = region_centre(region)
    sem = _semantics(rows, tris, len(triangles))
    tri_page, tri_uv = _triangle_uvs(rows, counts, len(triangles), textures) if textures is not None else (None, None)
    arr = tile_arrays(triangles, feature, wall, roof, lon, lat, semantics=sem, tri_page=tri_page, tri_uv=tri_uv)
    plain = arr
    parts: list[tuple[int, ContentArrays]] = []
    if textures is not None and arr.pages is not None and np.any(arr.pages >= 0):
        plain, parts = _split(arr, len(textures.images))
    compact = stream.compact
    q = plan_quantization([plain, *(a for _, a in parts)], position_error_m(rec)) if compact else None
    # the landmark metadata is in the mesh's frame, the one a custom shader sees: less the quantization origin
    origin = np.broadcast_to(np.asarray(q.origin), (len(rows), 3)) if q is not None else None
    rows = [{**r, **x} for r, x in zip(rows, _landmark_frame(rows, lon, lat, origin), strict=True)]
    prim = Primitive(
        positions=plain.positions,
        normals=plain.normals,
        colors=plain.colors,
        feature_ids=plain.feature_ids,
        indices=plain.indices,
        properties=_properties(rows, compact),
        feature_count=len(rows),
    )
    # only the pages some triangle uses, renumbered (a page whose triangles were all degenerate goes)
    textured = [
        Primitive(
            positions=a.positions,
            normals=a.normals,
            colors=a.colors,
            feature_ids=a.feature_ids,
            indices=a.indices,
            uvs=a.uvs,
            image=k,
        )
        for k, (_, a) in enumerate(parts)
    ]
    images = [textures.images[p] for p, _ in parts] if textures is not None else []
    if compact:
        try:
            return write_glb(
                prim,
                *BUILDING_CLASS,
                textured=textured,
                images=images,
                node_matrix=node_matrix,
                compact=True,
                quantization=q,
                meshopt_extension=stream.meshopt_extension,
                compress_tables=stream.tables == "meshopt",
            ), len(arr.indices) // 3
        except CompressionError as e:
            # recorded: the export counts tiles whose glb is not compact (geometry_fallback) and says why
            print(f"  warning: tile {_tile_name(rec)} written plain: {e}", file=sys.stderr)
            # the landmark metadata back in the tile's frame, as plain tiles have it
            return build_tile_glb(rows_in, region, textures, replace(stream, geometry="plain"), rec, node_matrix)
    glb = write_glb(prim, *BUILDING_CLASS, textured=textured, images=images, node_matrix=node_matrix)
    return glb, len(arr.indices) // 3


def _semantics(rows: list[dict], tris: list[np.ndarray], n_triangles: int) -> np.ndarray:
    """One semantic byte per triangle of the rows' meshes."""
    # a row without semantics falls back to colouring by orientation, alone, not the whole tile
    sem = np.concatenate(
        [np.zeros(0, np.uint8)]
        + [
            np.full(len(t), SEM_UNKNOWN, np.uint8)
            if r["semantics"] is None
            else np.frombuffer(bytes(r["semantics"]), dtype=np.uint8)
            for r, t in zip(rows, tris, strict=True)
        ]
    )
    if len(sem) != n_triangles:
        raise RuntimeError("lod.building_mesh.semantics does not have one byte per triangle")
    return sem


def _triangle_uvs(
    rows: list[dict], counts: np.ndarray, n_triangles: int, textures: TileTextures
) -> tuple[np.ndarray, np.ndarray]:
    """(atlas page per triangle, -1 for vertex colours; UVs per triangle corner) of the rows' meshes."""
    tri_page = np.full(n_triangles, -1, np.int16)
    tri_uv = np.zeros((n_triangles, 3, 2), np.float32)
    off = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    for i, r in enumerate(rows):
        got = textures.uvs.get((r["feature_kind"], int(r["building_id"])))
        if got is None:
            continue  # not textured (tex.failure): vertex colours
        if len(got[0]) != counts[i]:
            raise RuntimeError(
                f"the textures are stale: {r['feature_kind']} {r['building_id']} has {counts[i]} triangles, "
                f"its UVs {len(got[0])}; run the textures stage again (make textures)"
            )
        tri_page[off[i] : off[i + 1]] = got[0]
        tri_uv[off[i] : off[i + 1]] = got[1]
    if tri_page.max(initial=-1) >= len(textures.images):
        raise RuntimeError("tex.feature_uv refers to a page the tile does not have")
    return tri_page, tri_uv


def _properties(rows: list[dict], compact: bool) -> list[Property]:
    """The property-table columns of the rows (compact glbs with the short descriptions)."""
    props = []
    for name, ctype, doc, required, no_data in PROPERTIES:
        doc = COMPACT_DOCS.get(name, doc) if compact else doc
        values = [r[name] for r in rows]
        if name in ("osm_type", "building_osm_type"):
            values = [OSM_TYPE[v] for v in values]
        props.append(Property(name, values, ctype, doc, no_data=no_data, required=required))
    return props


def _tile_name(rec: TileRecord | None) -> str:
    return "?" if rec is None else f"{rec.level}/{rec.x}/{rec.y}"


#: the largest position error of compact geometry (KHR_mesh_quantization) at a leaf (m)
LEAF_POSITION_ERROR_M = 0.01
#: inner tiles: this share of the tile's geometric error, when larger (far below a pixel where they are drawn)
INNER_POSITION_ERROR_SHARE = 0.01


def position_error_m(rec: TileRecord | None) -> float:
    """The quantization bound of a tile's positions: 1 cm at leaves (and without a record), max(1 cm, 1 % of the
    geometric error) for inner tiles, which CesiumJS draws only while that error is below its pixel threshold."""
    if rec is None or rec.is_leaf or rec.geometric_error is None:
        return LEAF_POSITION_ERROR_M
    return max(LEAF_POSITION_ERROR_M, INNER_POSITION_ERROR_SHARE * float(rec.geometric_error))


def is_compact(glb: bytes) -> bool:
    """True when a glb's geometry is compact (KHR_mesh_quantization required: every compact glb has BYTE normals)."""
    gltf, _ = read_glb(glb)
    return "KHR_mesh_quantization" in gltf.get("extensionsRequired", [])


def _landmark_frame(
    rows: list[dict], lon: float, lat: float, origin: np.ndarray | None = None
) -> list[dict[str, float]]:
    """lm_centre_* and lm_dir_* of each row in the mesh's frame: tile_arrays' (ENU at (lon, lat), y up) less the
    quantization ``origin`` (features, 3) in compact geometry (which its node's matrix adds back)."""
    out = [
        dict.fromkeys(("lm_centre_x", "lm_centre_y", "lm_centre_z", "lm_dir_x", "lm_dir_y", "lm_dir_z"), 0.0)
        for _ in rows
    ]
    idx = [i for i, r in enumerate(rows) if r.get("lm_centre_wkb") is not None]
    if not idx:
        return out
    ecef0 = geodetic_to_ecef(lon, lat, 0.0)
    shift = np.zeros(3) if origin is None else np.asarray(origin, np.float64)[idx]
    to_gl = enu_rotation(lon, lat) @ Z_UP_TO_Y_UP.T

    def local(key: str) -> np.ndarray:
        pts = shapely.get_coordinates(shapely.from_wkb([bytes(rows[i][key]) for i in idx]), include_z=True)
        return (pts - ecef0) @ to_gl - shift

    centre, own = local("lm_centre_wkb"), local("lm_own_wkb")
    d = own - centre
    d[:, 1] = 0.0  # horizontal: y is up in the glTF frame
    norm = np.linalg.norm(d, axis=1)
    d = np.where(norm[:, None] > 1e-9, d / np.where(norm > 1e-9, norm, 1.0)[:, None], [1.0, 0.0, 0.0])
    for k, i in enumerate(idx):
        out[i].update(lm_centre_x=float(centre[k, 0]), lm_centre_y=float(centre[k, 1]), lm_centre_z=float(centre[k, 2]))
        if rows[i]["lm_role"] == 2:
            out[i].update(lm_dir_x=float(d[k, 0]), lm_dir_y=0.0, lm_dir_z=float(d[k, 2]))
    return out


def load_records(conn: psycopg.Connection) -> list[TileRecord]:
    """The tile tree (api.tile_tree), parents first."""
    with conn.cursor(row_factory=dict_row) as cur:
        return [
            TileRecord(
                level=r["level"],
                x=r["x"],
                y=r["y"],
                is_leaf=r["is_leaf"],
                region=tuple(r["region"]),
                geometric_error=r["geometric_error"],
                content_uri=r["content_uri"],
                n_features=r["n_features"],
                content_features=r["content_features"],
            )
            for r in cur.execute(
                "SELECT level, x, y, is_leaf, n_features, region, geometric_error, content_uri, content_features"
                " FROM api.tile_tree()"
            )
        ]


def tileset_files(
    conn: psycopg.Connection, records: list[TileRecord], lod: int | None, stream: StreamOptions = COMPACT
) -> dict[str, bytes]:
    """tileset.json and, implicit, its subtree files, by URI, as written to disk and served (same bytes either
    way)."""
    dataset = conn.execute("SELECT source_sha256 FROM meta.dataset").fetchone()
    version = dataset[0][:16] if dataset and dataset[0] else ""
    root = conn.execute("SELECT west, south, east, north FROM api.quadtree_root()").fetchone()
    ts, files = build(
        records,
        tileset_version=version,
        single_lod=lod is not None,
        tiling=stream.tiling,
        root_volume=(root[0], root[1], root[2], root[3]) if root and root[0] is not None else None,
    )
    if stream.compact:
        # the glbs' class with the descriptions they leave out (3D Tiles 1.1 schema; the glbs keep their own
        # EXT_structural_metadata schema, which is what clients read a picked feature's values with)
        schema = ts.get("schema") or {"id": "citylod"}
        ts["schema"] = {
            **schema,
            "classes": {
                **schema.get("classes", {}),
                BUILDING_CLASS[0]: building_schema_class(),
            },
        }
    # compact JSON: an implicit tileset.json is a few kB either way, an explicit one is the size of the tree
    return {TILESET_JSON: json.dumps(ts, separators=(",", ":")).encode(), **files}


def tileset_bytes(
    conn: psycopg.Connection, records: list[TileRecord], lod: int | None, stream: StreamOptions = COMPACT
) -> bytes:
    """tileset.json as written to disk and served (same bytes either way)."""
    return tileset_files(conn, records, lod, stream)[TILESET_JSON]


def tile_glb(
    conn: psycopg.Connection,
    rec: TileRecord,
    base_height: float,
    lod: int | None,
    stream: StreamOptions = COMPACT,
    root_region: tuple[float, ...] | None = None,
) -> tuple[bytes, int, int]:
    """(glb bytes, features, triangles) of one tile's content, placed in the frame of the tileset's root
    (``root_region``: the root tile's; without it the glb stays in its own tile's frame, no node matrix);
    textured when the textures stage made pages for it (the generalized hierarchy only: ``lod`` tilesets hold
    other meshes than the stage textured)."""
    with conn.cursor(row_factory=dict_row) as cur:
        rows = cur.execute(
            _FEATURES, {"base": base_height, "level": rec.level, "x": rec.x, "y": rec.y, "lod": lod}
        ).fetchall()
    textures = load_textures(conn, rec.level, rec.x, rec.y, stream.textures) if lod is None else None
    matrix = node_matrix(rec.region, root_region) if root_region is not None else None
    glb, tri = build_tile_glb(rows, rec.region, textures, stream, rec, matrix)
    return glb, len(rows), tri


class _WorkerState(TypedDict, total=False):
    """A Dask worker's connection and tile_glb's other arguments, set by _init_worker."""

    conn: psycopg.Connection
    args: tuple[float, int | None, StreamOptions, tuple[float, ...]]


_WORKER: _WorkerState = {}


def _init_worker(
    url: str, base_height: float, lod: int | None, stream: StreamOptions, root_region: tuple[float, ...]
) -> None:
    _WORKER.update({"conn": connect(url, autocommit=True), "args": (base_height, lod, stream, root_region)})
    atexit.register(_WORKER["conn"].close)


def _tile_task(rec: TileRecord) -> tuple[bytes, int, int]:
    """One tile's glb as a Dask task, read through the worker's own connection (a module-level function, as
    core/workers.py needs); the bytes come back, so a worker on another machine writes nothing here."""
    return tile_glb(_WORKER["conn"], rec, *_WORKER["args"])


def _export_tiles(
    url: str,
    tiles: list[TileRecord],
    out: Path,
    base_height: float,
    settings: Settings,
    progress: Progress,
    lod: int | None,
    stream: StreamOptions,
    root_region: tuple[float, ...],
) -> tuple[int, int, int, int]:
    """Write every tile's glb. Tiles are independent: by default threads of this process share them; with
    ``export_workers`` of 2 or more, or a Dask cluster named (CITYLOD_DASK_SCHEDULER), each is a Dask task
    (core/workers.py) reading through its worker's own connection, and this process writes the bytes as they
    come back. A tile whose worker hung or died on every attempt stops the export with the tile named; the
    tileset in place is kept (the tiles are written into the partial directory). Returns (features,
    triangles, bytes, compact tiles meshoptimizer refused, written plain)."""
    from core.workers import SCHEDULER_ENV, Lost, imap_isolated, worker_count

    args = (base_height, lod, stream, root_region)
    with contextlib.ExitStack() as stack:
        if settings.export_workers == 0 and not os.environ.get(SCHEDULER_ENV):
            # the local default: threads of this process, each with its own connection. On 2 cores they are at
            # least as fast as 2 Dask workers, whose results travel back through the scheduler: Liechtenstein
            # 10.2 s (make bench, threads) against 15.9 s (make bench, Dask); its 6x 51.8 s against 53.9 s (the
            # same database, one after the other)
            results: Iterator[tuple[bytes, int, int] | Lost] = stack.enter_context(
                thread_map(url, lambda conn, rec: tile_glb(conn, rec, *args), tiles, min(4, os.cpu_count() or 1))
            )
        else:
            workers = worker_count(settings.export_workers, 2)
            if workers <= 1:
                conn = stack.enter_context(connect(url))
                results = (tile_glb(conn, rec, *args) for rec in tiles)
            else:
                results = imap_isolated(
                    _tile_task,
                    tiles,
                    min(workers, len(tiles)),
                    settings.export_tile_timeout_s,
                    _init_worker,
                    (url, *args),
                    window=4 * workers,
                )
        n_features = n_triangles = n_bytes = n_fallback = 0
        for rec, res in zip(tiles, results, strict=True):
            if isinstance(res, Lost):
                raise RuntimeError(
                    f"tile {rec.level}/{rec.x}/{rec.y} was not written: {res.detail}; the tileset in place is kept"
                )
            glb, f, t = res
            assert rec.content_uri is not None
            path = out / rec.content_uri
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(glb)
            n_features, n_triangles, n_bytes = n_features + f, n_triangles + t, n_bytes + len(glb)
            n_fallback += int(stream.compact and not is_compact(glb))
            progress.update(f)
    return n_features, n_triangles, n_bytes, n_fallback


def _textures_stale(conn: psycopg.Connection) -> object:
    """api.textures_stale(): the tiles were generalized again after the textures stage ran."""
    row = conn.execute("SELECT api.textures_stale()").fetchone()
    assert row is not None  # a function call: one row
    return row[0]


def _content_features(r: TileRecord, lod: int | None) -> int:
    """The features of a tile's glb: its own at one LOD, its generalized content's otherwise."""
    n = r.n_features if lod else r.content_features
    assert n is not None  # check_current refuses tiles without measured content
    return n


def check_current(conn: psycopg.Connection, records: list[TileRecord], lod: int | None) -> None:
    """Refuse tiles that no longer match the meshes (lod/tiles re-run) or that generalize has not finished."""
    if not records:
        raise RuntimeError("no tiles: run the tiles stage first (make tiles)")
    meshes = conn.execute("SELECT count(*) FROM lod.building_mesh WHERE lod = %s", (lod or 3,)).fetchone()
    in_tiles = sum(r.n_features for r in records if r.is_leaf)
    if meshes is None or in_tiles != meshes[0]:
        raise RuntimeError(
            f"the tiles are stale: they hold {in_tiles} features but lod.building_mesh has "
            f"{meshes[0] if meshes else 0} LOD{lod or 3} meshes; run the lod, tiles and generalize stages again "
            "(make lod tiles generalize)"
        )
    if any(r.geometric_error is None or r.content_features is None for r in records):
        raise RuntimeError("the tiles have no measured geometric errors: run the generalize stage (make generalize)")
    # textures are made from the generalized content: a later lod, tiles or generalize run may have changed it
    if lod is None and _textures_stale(conn):
        raise RuntimeError(
            "the textures are stale: the tiles were generalized again after the textures stage "
            "ran; run it again (make textures)"
        )


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


_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


def exchange(a: Path, b: Path) -> bool:
    """Swap two existing paths in one step (Linux renameat2 RENAME_EXCHANGE): a reader sees either, never
    neither. False where the system or the file system cannot (the caller then replaces in two steps)."""
    fn = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    if fn is None:
        return False
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EPERM, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), f"{a} <-> {b}")


def swap_in(partial: Path, out: Path) -> None:
    """``partial`` becomes ``out`` in one step, so a server or client reading ``out`` always finds one whole
    tileset; the old one is then deleted under the partial name (marked ours first, should that be cut short)."""
    if out.exists() and exchange(partial, out):
        (partial / PARTIAL_MARKER).touch()
        shutil.rmtree(partial)
        return
    if out.exists():
        shutil.rmtree(out)
    partial.rename(out)


@contextlib.contextmanager
def _directory_lock(out: Path) -> Iterator[None]:
    """One export at a time into ``out``: a second one waits for the first instead of failing or mixing."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_name(f".{out.name}.lock"), "w") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print(f"  export: waiting for the export already writing {out}", file=sys.stderr, flush=True)
            fcntl.flock(fh, fcntl.LOCK_EX)
        yield  # the lock goes with the file's closing


@dataclass(frozen=True)
class Options:
    """What an export writes: the directory, the generalized hierarchy or one ``lod``, the stream's encoding,
    and the name it publishes the tileset under in the database (None: the directory only)."""

    out: Path
    lod: int | None = None
    stream: StreamOptions = COMPACT
    publish_as: str | None = None


def run(ctx: Context) -> Result:
    """The export stage (core/stage.py): ``ctx.options`` says what to write. An update's export fingerprints
    only the tiles the runs since the live generation reached (exporter/reuse.py)."""
    o: Options = ctx.options
    counts = export_tileset(
        ctx.url,
        o.out,
        ctx.settings,
        lod=o.lod,
        stream=o.stream,
        publish_as=o.publish_as,
        run_id=ctx.run_id,
        code=ctx.code,
        reached=ctx.update,
    )
    return Result(counts, output=tileset_output(o.out))


def tileset_output(out: Path) -> dict[str, object]:
    """What export records of the directory it wrote (etl/staleness.py compares it)."""
    return {"tileset_sha256": hashlib.sha256((out / TILESET_JSON).read_bytes()).hexdigest()}


def export_tileset(
    url: str,
    out: Path,
    settings: Settings,
    lod: int | None = None,
    stream: StreamOptions = COMPACT,
    publish_as: str | None = None,
    run_id: int | None = None,
    code: str = "",
    reached: bool = False,
) -> dict[str, object]:
    """Write the tileset: the generalized hierarchy (blocks far away, LOD3 at the leaves), or with ``lod``
    every building at that one level of detail (1 block, 2 roofs, 3 facades). Exports into one directory are
    serialized, and each swaps its tileset in whole (swap_in). With ``publish_as`` the same files become the
    next generation of that tileset in the database (exporter/publish.py), before the directory's swap; with
    ``code`` too (the export's code and settings as etl/staleness.py records them), the tiles whose input is the one
    the live generation was built from are copied from it (exporter/reuse.py); with ``reached`` (an update's
    export) only the tiles its stages' runs reached since that generation are fingerprinted (core/changes.py)."""
    if lod not in (None, 1, 2, 3):
        raise ValueError(f"--lod must be 1, 2 or 3, not {lod}")
    if publish_as is not None:
        check_name(publish_as)
    with _directory_lock(out):
        return _export_tileset(url, out, settings, lod, stream, publish_as, run_id, code, reached)


def _check_replaceable(out: Path, partial: Path) -> None:
    """OutputDirectoryError unless the output and partial directories are empty or hold a citylod tileset."""
    for p in (out, partial):
        if not replaceable(p):
            raise OutputDirectoryError(
                f"refusing to overwrite {p}: it is not empty and holds no tileset written by citylod; "
                "choose a new or empty directory"
            )


def _start_partial(partial: Path) -> None:
    """A new, empty partial directory, marked as such until the export completes it."""
    if partial.exists():
        shutil.rmtree(partial)
    partial.mkdir(parents=True)
    (partial / PARTIAL_MARKER).touch()


def _write_files(partial: Path, files: dict[str, bytes]) -> int:
    """Write tileset.json and the subtrees under ``partial``; their bytes."""
    for uri, data in files.items():
        (partial / uri).parent.mkdir(parents=True, exist_ok=True)
        (partial / uri).write_bytes(data)
    return sum(len(d) for d in files.values())


def _export_tileset(
    url: str,
    out: Path,
    settings: Settings,
    lod: int | None,
    stream: StreamOptions,
    publish_as: str | None,
    run_id: int | None,
    code: str,
    reached: bool,
) -> dict[str, object]:
    t0 = time.perf_counter()
    partial = out.with_name(out.name + ".partial")
    _check_replaceable(out, partial)
    with connect(url) as conn:
        records = load_records(conn)
        check_current(conn, records, lod)
        files = tileset_files(conn, records, lod, stream)
    root_region = next(r.region for r in records if r.level == 0)
    tiles = [r for r in records if r.is_leaf or lod is None]
    expected = sum(_content_features(r, lod) for r in tiles)
    # a published tileset: the tiles whose input is what its live generation was built from are copied
    seed = recipe(code, lod, stream, root_region)
    glbs = plan_glbs(url, publish_as, seed, tiles, lod, stream, reached) if publish_as is not None and code else Glbs()
    same = glbs.copy
    _start_partial(partial)
    progress = Progress("export", "features", total=expected)
    n_features, n_triangles, n_bytes, n_fallback = _export_tiles(
        url,
        [r for r in tiles if r.content_uri not in same],
        partial,
        settings.base_height_m,
        settings,
        progress,
        lod,
        stream,
        root_region,
    )
    features_built = n_features
    if same:
        t, b = copy_unchanged(url, same, out, partial)
        n_features += sum(glbs.n_features[p] for p in same)  # as api.export_features counts them now
        n_triangles, n_bytes = n_triangles + t, n_bytes + b
    # every feature of the exported tiles is in a glb (counted as written); before the tileset replaces the old
    balance = Balance("features", int(expected), {"written": int(n_features)})
    n_bytes += _write_files(partial, files)
    (partial / PARTIAL_MARKER).unlink()
    published: dict[str, str | int] = {}
    if publish_as is not None:
        options: dict[str, object] = {"lod": lod, **stream.as_dict(), "recipe": seed}
        pub = publish(url, publish_as, partial, options, run_id, settings.publish_keep, glbs.keys)
        published = {"published_as": publish_as, **pub.as_dict()}
    swap_in(partial, out)
    seconds = time.perf_counter() - t0
    buildings = sum(r.n_features for r in records if r.is_leaf)
    summary(
        "export",
        balance,
        f"{len(tiles):,} glb tiles{f' ({len(same):,} unchanged: copied)' if same else ''}, "
        f"{len(files) - 1:,} subtrees, {n_triangles:,} triangles, "
        f"{n_bytes / 1e6:.2f} MB ({n_bytes / max(buildings, 1):,.0f} bytes/building) -> {out}",
        seconds,
        buildings,
    )
    print(f"  tileset: {out / 'tileset.json'}", file=sys.stderr)
    if published:
        print(
            f"  published: {publish_as} generation {published['published_generation']} "
            f"({published['published_new_files']:,} new files, "
            f"{int(published['published_new_bytes']) / 1e6:.2f} MB new)",
            file=sys.stderr,
        )
    return {
        **balance.counts(),
        "lod": lod or "all",
        **stream.as_dict(),
        "buildings": buildings,
        "features": n_features,
        "tiles": len(records),
        "glb": len(tiles),
        "subtrees": len(files) - 1,
        "tileset_json_bytes": len(files[TILESET_JSON]),
        "geometry_fallback": n_fallback,
        "glb_copied": len(same),
        "glb_built": len(tiles) - len(same),
        "glb_fingerprinted": glbs.fingerprinted,
        # what building those glbs handled: an update's share of the export's work
        "features_built": features_built,
        "triangles": n_triangles,
        "bytes": n_bytes,
        "bytes_per_building": round(n_bytes / max(buildings, 1), 1),
        "seconds": round(seconds, 3),
        "directory": str(out),
        **published,
    }
