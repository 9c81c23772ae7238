"""Tileset checks against the 3D Tiles 1.1 specification (the CesiumGS validator is not installable here).

``check_tileset(path)`` returns a list of problems (empty = passes). It checks what the specification
requires of tileset.json and tiles, plus the rules a client silently depends on:
  * asset.version "1.0"/"1.1"; top-level geometricError and root present; extensionsRequired ⊆ extensionsUsed;
  * every tile: exactly one bounding volume of box (12 numbers), region (6, radians in range, south <= north,
    minimum height <= maximum) or sphere (4, radius >= 0); geometricError a number >= 0 and not larger than
    its parent's (the top-level value counts as the root's parent); refine present on the root and one of
    ADD/REPLACE wherever present; transform 16 finite numbers; children a non-empty array; content with a
    uri (or contents, 1.1) that resolves to an existing file, and glb content that is a GLB 2.0 container;
  * child bounding volumes inside their parent's (regions compared directly; boxes and spheres compared by
    their ECEF corners after the accumulated transforms), with a small tolerance;
  * the top-level geometricError is sized to the tileset's extent (at least half the root volume's
    diagonal): CesiumJS skips the whole tileset, without an error, when it is too small;
  * in every glb content, EXT_mesh_features and EXT_structural_metadata (``check_glb``), which the Khronos
    glTF-Validator does not check ("unsupported extension");
  * an implicit tileset (``implicitTiling``): subdivisionScheme, subtreeLevels, availableLevels, the subtree
    and content URI templates; every subtree file it reaches parses (header, 8-byte padding and alignment,
    bufferViews inside the binary chunk, bitstreams long enough, availableCount right, content only on
    available tiles, every available tile's parent available, the tile property table's class in the
    tileset's schema and one row per available tile); then the tree it stands for (core/tiles3d.expand, with
    each tile's TILE_BOUNDING_REGION and TILE_GEOMETRIC_ERROR) is checked like an explicit one.
Pure Python + numpy; no database.
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeGuard
from urllib.parse import unquote, urlparse

import numpy as np

from core.geodesy import geodetic_to_ecef
from core.tiles3d import expand
from exporter.gltf import SCALAR_DTYPES, accessor_array, read_glb
from exporter.gltf import view_bytes as _view_bytes

TOLERANCE_RAD = 1e-9
TOLERANCE_M = 1e-3
ROOT_ERROR_FRACTION = 0.5


def _is_number(v: object) -> TypeGuard[float]:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def _numbers(v: object, n: int) -> bool:
    return isinstance(v, list) and len(v) == n and all(_is_number(x) for x in v)


def _matrix(transform: list[float] | None) -> np.ndarray:
    return np.eye(4) if transform is None else np.array(transform, dtype=float).reshape(4, 4).T


def volume_corners(bv: dict[str, Any], world: np.ndarray) -> np.ndarray:
    """ECEF points spanning a bounding volume (corners; for regions also edge midpoints)."""
    if "region" in bv:
        w, s, e, n, lo, hi = bv["region"]
        lons = np.array([w, (w + e) / 2, e])
        lats = np.array([s, (s + n) / 2, n])
        g = np.array(np.meshgrid(lons, lats, [lo, hi])).reshape(3, -1)
        return geodetic_to_ecef(g[0], g[1], g[2])
    if "box" in bv:
        b = np.array(bv["box"], dtype=float)
        c, axes = b[:3], b[3:].reshape(3, 3)
        signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
        local = c + signs @ axes
    else:
        c, r = np.array(bv["sphere"][:3], dtype=float), float(bv["sphere"][3])
        signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
        local = c + r * signs
    return (np.c_[local, np.ones(len(local))] @ world.T)[:, :3]


def _inside(child: dict[str, Any], parent: dict[str, Any], cw: np.ndarray, pw: np.ndarray) -> bool:
    if "region" in child and "region" in parent:
        c, p = child["region"], parent["region"]
        t = TOLERANCE_RAD
        return (
            c[0] >= p[0] - t
            and c[1] >= p[1] - t
            and c[2] <= p[2] + t
            and c[3] <= p[3] + t
            and c[4] >= p[4] - TOLERANCE_M
            and c[5] <= p[5] + TOLERANCE_M
        )
    # Conservative for mixed kinds: the child's ECEF corners must lie in the parent's ECEF box.
    pts = volume_corners(child, cw)
    ppts = volume_corners(parent, pw)
    lo, hi = ppts.min(axis=0) - TOLERANCE_M, ppts.max(axis=0) + TOLERANCE_M
    return bool(np.all(pts >= lo) and np.all(pts <= hi))


def _check_bv(bv: object, where: str, problems: list[str]) -> bool:
    if not isinstance(bv, dict):
        problems.append(f"{where}: boundingVolume missing or not an object")
        return False
    kinds = [k for k in ("box", "region", "sphere") if k in bv]
    if len(kinds) != 1:
        problems.append(f"{where}: boundingVolume needs exactly one of box/region/sphere, has {kinds or 'none'}")
        return False
    k = kinds[0]
    v = bv[k]
    if k == "box" and not _numbers(v, 12):
        problems.append(f"{where}: box must be 12 numbers")
        return False
    if k == "sphere" and (not _numbers(v, 4) or v[3] < 0):
        problems.append(f"{where}: sphere must be 4 numbers with radius >= 0")
        return False
    if k == "region":
        if not _numbers(v, 6):
            problems.append(f"{where}: region must be 6 numbers")
            return False
        w, s, e, n, lo, hi = v
        if not (-math.pi <= w <= math.pi and -math.pi <= e <= math.pi):
            problems.append(f"{where}: region west/east outside [-pi, pi]")
        if not (-math.pi / 2 <= s <= n <= math.pi / 2):
            problems.append(f"{where}: region needs -pi/2 <= south <= north <= pi/2")
        if lo > hi:
            problems.append(f"{where}: region minimum height {lo} > maximum height {hi}")
        if w > e:
            problems.append(f"{where}: region crosses the antimeridian (west > east), unsupported by these checks")
    return True


def _check_implicit(root: dict[str, Any], problems: list[str]) -> dict[str, Any] | None:
    """The root's implicitTiling, or None (with the problems) when it cannot be expanded."""
    imp = root["implicitTiling"]
    before = len(problems)
    if not isinstance(imp, dict):
        problems.append("root: implicitTiling must be an object")
        return None
    if imp.get("subdivisionScheme") not in ("QUADTREE", "OCTREE"):
        problems.append("root: implicitTiling.subdivisionScheme must be QUADTREE or OCTREE")
    elif imp["subdivisionScheme"] == "OCTREE":
        problems.append("root: implicitTiling OCTREE is not checked here (citylod writes QUADTREE)")
    for k in ("subtreeLevels", "availableLevels"):
        if not isinstance(imp.get(k), int) or isinstance(imp.get(k), bool) or imp[k] < 1:
            problems.append(f"root: implicitTiling.{k} must be an integer >= 1")
    templates = [("implicitTiling.subtrees.uri", (imp.get("subtrees") or {}).get("uri"))]
    if "content" in root:
        templates.append(("content.uri", root["content"].get("uri")))
    for where, uri in templates:
        if not isinstance(uri, str) or not all(v in uri for v in ("{level}", "{x}", "{y}")):
            problems.append(f"root: {where} must be a template with {{level}}, {{x}} and {{y}}")
    if "children" in root:
        problems.append("root: an implicit root tile must not have children")
    if "region" not in (root.get("boundingVolume") or {}) and "box" not in (root.get("boundingVolume") or {}):
        problems.append("root: an implicit root needs a region or box bounding volume")
    return None if len(problems) > before else imp


def _check_glb(path: Path, where: str, problems: list[str]) -> None:
    problems.extend(f"{where}: {path.name}: {p}" for p in check_glb(path.read_bytes()))


def check_glb(data: bytes) -> list[str]:
    """Problems in a GLB's container and in its EXT_mesh_features / EXT_structural_metadata (feature ids in
    range and all used, property tables consistent with their class, buffer views inside the buffer and
    8-byte aligned, string offsets increasing and inside their buffer). Empty list = passes."""
    try:
        gltf, binary = read_glb(data)
    except (ValueError, struct.error) as e:
        return [str(e)]
    overflow = _buffer_overflow(gltf, binary)
    if overflow is not None:
        return [overflow]
    return [*_check_views(gltf), *_check_metadata(gltf, binary), *_check_features(gltf, binary)]


def _buffer_overflow(gltf: dict[str, Any], binary: bytes) -> str | None:
    """The problem when buffer 0 declares more bytes than the BIN chunk holds (nothing else can be read)."""
    buffers = gltf.get("buffers", [])
    if buffers and buffers[0].get("byteLength", 0) > len(binary):
        return f"buffer 0 declares {buffers[0].get('byteLength')} bytes, the BIN chunk holds {len(binary)}"
    return None


def _check_views(gltf: dict[str, Any]) -> list[str]:
    """Every bufferView inside its buffer."""
    problems: list[str] = []
    buffers = gltf.get("buffers", [])
    for i, v in enumerate(gltf.get("bufferViews", [])):
        buf = buffers[v.get("buffer", 0)] if v.get("buffer", 0) < len(buffers) else None
        if buf is None or v.get("byteOffset", 0) + v.get("byteLength", 0) > buf.get("byteLength", 0):
            problems.append(f"bufferView {i} lies outside its buffer")
    return problems


def _property_tables(gltf: dict[str, Any]) -> list[dict[str, Any]]:
    meta = gltf.get("extensions", {}).get("EXT_structural_metadata")
    return meta.get("propertyTables", []) if meta else []


def _check_metadata(gltf: dict[str, Any], binary: bytes) -> list[str]:
    """EXT_structural_metadata: declared in extensionsUsed, each property table consistent with its class."""
    problems: list[str] = []
    used = set(gltf.get("extensionsUsed", []))
    meta = gltf.get("extensions", {}).get("EXT_structural_metadata")
    tables = _property_tables(gltf)
    classes = meta.get("schema", {}).get("classes", {}) if meta else {}
    if meta and "EXT_structural_metadata" not in used:
        problems.append("EXT_structural_metadata is used but not in extensionsUsed")
    for t_index, table in enumerate(tables):
        problems.extend(_check_property_table(gltf, binary, t_index, table, classes))
    return problems


def _check_property_table(
    gltf: dict[str, Any], binary: bytes, t_index: int, table: dict[str, Any], classes: dict[Any, Any]
) -> list[str]:
    """Property table ``t_index``: its class exists, required properties present (and without noData), every
    column a property of the class with valid buffer views."""
    cls = classes.get(table.get("class"))
    if cls is None:
        return [f"propertyTables[{t_index}]: class {table.get('class')!r} not in the schema"]
    problems: list[str] = []
    count = table.get("count", 0)
    props = cls.get("properties", {})
    for name, spec in props.items():
        if spec.get("required") and name not in table.get("properties", {}):
            problems.append(f"propertyTables[{t_index}]: required property {name} missing")
        if spec.get("required") and "noData" in spec:
            problems.append(f"class property {name}: required properties cannot have noData")
    for name, col in table.get("properties", {}).items():
        spec = props.get(name)
        where = f"propertyTables[{t_index}].{name}"
        if spec is None:
            problems.append(f"{where}: not a property of class {table.get('class')}")
            continue
        problems.extend(_check_column(gltf, binary, where, col, spec, count))
    return problems


def _check_column(
    gltf: dict[str, Any], binary: bytes, where: str, col: dict[str, Any], spec: dict[str, Any], count: int
) -> list[str]:
    """One property-table column: its views exist, values 8-byte aligned, STRING offsets or SCALAR values
    covering ``count`` rows."""
    views = gltf.get("bufferViews", [])
    for key in ("values", "stringOffsets", "arrayOffsets"):
        if key in col and (not isinstance(col[key], int) or not 0 <= col[key] < len(views)):
            return [f"{where}: {key} is not a bufferView"]
    problems: list[str] = []
    values = views[col["values"]]
    if values.get("byteOffset", 0) % 8:
        problems.append(f"{where}: values bufferView is not 8-byte aligned")
    if spec.get("type") == "STRING":
        problems.extend(_check_string_offsets(gltf, binary, where, col, count))
    elif spec.get("type") == "SCALAR":
        comp = spec.get("componentType", "")
        need = count * (np.dtype(SCALAR_DTYPES[comp]).itemsize if comp in SCALAR_DTYPES else 0)
        if values["byteLength"] < need:
            problems.append(f"{where}: values need {need} bytes, bufferView has fewer")
    return problems


def _check_string_offsets(
    gltf: dict[str, Any], binary: bytes, where: str, col: dict[str, Any], count: int
) -> list[str]:
    """A STRING column's offsets: ``count`` + 1 of them, from 0, increasing, inside the values view."""
    if "stringOffsets" not in col:
        return [f"{where}: STRING property without stringOffsets"]
    dtype = SCALAR_DTYPES[col.get("stringOffsetType", "UINT32")]
    # meshopt-compressed views decoded (compact geometry)
    offs = np.frombuffer(_view_bytes(gltf, binary, col["stringOffsets"]), dtype=dtype)
    if len(offs) < count + 1:
        return [f"{where}: {len(offs)} string offsets for {count} values"]
    if (
        offs[0] != 0
        or np.any(np.diff(offs[: count + 1].astype(np.int64)) < 0)
        or offs[count] > gltf["bufferViews"][col["values"]]["byteLength"]
    ):
        return [f"{where}: string offsets must start at 0, increase and stay in the buffer"]
    return []


def _check_features(gltf: dict[str, Any], binary: bytes) -> list[str]:
    """EXT_mesh_features over all primitives: a textured tile spreads its features over one primitive per atlas
    page, so each primitive's featureCount is the number of distinct ids it holds, and together they must draw
    every row of the property table."""
    problems: list[str] = []
    used = set(gltf.get("extensionsUsed", []))
    tables = _property_tables(gltf)
    drawn: dict[int, list[np.ndarray]] = {}
    for m_index, mesh in enumerate(gltf.get("meshes", [])):
        for p_index, prim in enumerate(mesh.get("primitives", [])):
            feats = prim.get("extensions", {}).get("EXT_mesh_features")
            if not feats:
                continue
            where = f"meshes[{m_index}].primitives[{p_index}]"
            if "EXT_mesh_features" not in used:
                problems.append(f"{where}: EXT_mesh_features is used but not in extensionsUsed")
            for f in feats.get("featureIds", []):
                problems.extend(_check_feature_ids(gltf, binary, where, prim, f, tables, drawn))
    for table, parts in drawn.items():
        count = tables[table].get("count", 0)
        missing = count - len(np.unique(np.concatenate(parts)))
        if missing:
            problems.append(f"propertyTables[{table}]: {missing} of {count} features have no vertex")
    return problems


def _check_feature_ids(
    gltf: dict[str, Any],
    binary: bytes,
    where: str,
    prim: dict[str, Any],
    f: dict[str, Any],
    tables: list[dict[str, Any]],
    drawn: dict[int, list[np.ndarray]],
) -> list[str]:
    """One featureIds entry of primitive ``prim``: featureCount, its property table, and the _FEATURE_ID_
    attribute's values (integers in range, featureCount distinct ones); the distinct ids go into ``drawn``
    under their table."""
    n = f.get("featureCount", 0)
    if not isinstance(n, int) or n < 1:
        return [f"{where}: featureCount must be a positive integer"]
    problems: list[str] = []
    limit = n
    table = f.get("propertyTable")
    if table is not None:
        if not isinstance(table, int) or not 0 <= table < len(tables):
            return [f"{where}: propertyTable {table} does not exist"]
        limit = tables[table].get("count", 0)
        if n > limit:
            problems.append(f"{where}: featureCount {n} exceeds the property table count {limit}")
    if "attribute" not in f:
        return problems
    acc_i = prim.get("attributes", {}).get(f"_FEATURE_ID_{f['attribute']}")
    if acc_i is None:
        return [*problems, f"{where}: no _FEATURE_ID_{f['attribute']} attribute"]
    acc = gltf["accessors"][acc_i]
    if acc.get("type") != "SCALAR" or acc.get("normalized"):
        return [*problems, f"{where}: feature ids must be a SCALAR, non-normalized accessor"]
    ids = accessor_array(gltf, binary, acc_i)
    if np.any(ids != np.round(ids)) or np.any(ids < 0) or np.any(ids >= limit):
        return [*problems, f"{where}: feature ids must be integers in [0, {limit})"]
    distinct = np.unique(ids)
    if len(distinct) != n:
        problems.append(f"{where}: featureCount {n} != {len(distinct)} distinct feature ids")
    if table is not None:
        drawn.setdefault(table, []).append(distinct)
    return problems


def check_tileset(path: Path) -> list[str]:
    try:
        ts = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        return [f"{path}: cannot read tileset JSON: {e}"]
    base = path.parent
    problems, top_error = _check_top_level(ts)
    root = ts.get("root")
    if not isinstance(root, dict):
        problems.append("root tile missing")
        return problems
    if root.get("refine") not in ("ADD", "REPLACE"):
        problems.append("root: refine is required on the root tile and must be ADD or REPLACE")
    if "implicitTiling" in root:
        expanded = _expand_implicit(ts, root, base, problems)
        if expanded is None:
            return problems
        ts = expanded
        root = ts["root"]
    _TileWalk(base, problems).tile(root, "root", top_error, None, np.eye(4), np.eye(4))
    problems.extend(_check_root_error(ts, root))
    return problems


def _check_top_level(ts: dict[str, Any]) -> tuple[list[str], float]:
    """(problems, the top-level geometricError: infinity when it is not a number >= 0) of the asset, the
    top-level geometricError and the extension lists."""
    problems: list[str] = []
    asset = ts.get("asset")
    if not isinstance(asset, dict) or asset.get("version") not in ("1.0", "1.1"):
        problems.append("asset.version must be '1.0' or '1.1'")
    top_error = ts.get("geometricError")
    if not _is_number(top_error) or top_error < 0:
        problems.append("top-level geometricError must be a number >= 0")
        top_error = math.inf
    used = set(ts.get("extensionsUsed", []))
    required = set(ts.get("extensionsRequired", []))
    if not required <= used:
        problems.append(f"extensionsRequired {sorted(required - used)} not in extensionsUsed")
    return problems, top_error


def _expand_implicit(
    ts: dict[str, Any], root: dict[str, Any], base: Path, problems: list[str]
) -> dict[str, Any] | None:
    """The explicit tileset an implicit one stands for, or None (with the problems) when it cannot be expanded."""
    if _check_implicit(root, problems) is None:
        return None
    try:
        return expand(ts, lambda uri: (base / unquote(uri)).read_bytes())
    except (OSError, ValueError) as e:
        problems.append(f"root: implicit tiling: {e}")
        return None


def _check_root_error(ts: dict[str, Any], root: dict[str, Any]) -> list[str]:
    """The top-level geometricError against the root volume's diagonal (CesiumJS loads nothing when too small)."""
    if isinstance(root.get("boundingVolume"), dict) and _is_number(ts.get("geometricError")):
        pts = volume_corners(root["boundingVolume"], _matrix(root.get("transform")))
        diagonal = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
        if ts["geometricError"] < ROOT_ERROR_FRACTION * diagonal:
            return [
                f"top-level geometricError {ts['geometricError']:g} is too small for a tileset "
                f"{diagonal:.0f} m across (needs >= {ROOT_ERROR_FRACTION * diagonal:.0f}): CesiumJS would load nothing"
            ]
    return []


@dataclass
class _TileWalk:
    """The checks of every tile of an explicit tree, depth first, into ``problems``; content uris relative to
    ``base``, each seen once."""

    base: Path
    problems: list[str]
    uris: set[str] = field(default_factory=set)

    def tile(
        self,
        tile: dict[str, Any],
        where: str,
        parent_error: float,
        parent_bv: dict[str, Any] | None,
        parent_world: np.ndarray,
        world: np.ndarray,
    ) -> None:
        problems = self.problems
        if "transform" in tile:
            if not _numbers(tile["transform"], 16):
                problems.append(f"{where}: transform must be 16 numbers")
            else:
                world = world @ _matrix(tile["transform"])
        raw_bv = tile.get("boundingVolume")
        bv = raw_bv if _check_bv(raw_bv, where, problems) else None
        ge = self._error(tile, where, parent_error)
        if "refine" in tile and tile["refine"] not in ("ADD", "REPLACE"):
            problems.append(f"{where}: refine must be ADD or REPLACE, not {tile['refine']!r}")
        if bv is not None and parent_bv is not None and not _inside(bv, parent_bv, world, parent_world):
            problems.append(f"{where}: bounding volume not inside its parent's")
        contents = ([tile["content"]] if "content" in tile else []) + list(tile.get("contents", []))
        for c in contents:
            self._content(c, where, bv, world)
        if "children" in tile:
            kids = tile["children"]
            if not isinstance(kids, list) or not kids:
                problems.append(f"{where}: children must be a non-empty array")
                return
            for i, k in enumerate(kids):
                if not isinstance(k, dict):
                    problems.append(f"{where}.children[{i}]: not an object")
                    continue
                self.tile(k, f"{where}.children[{i}]", ge, bv, world, world)

    def _error(self, tile: dict[str, Any], where: str, parent_error: float) -> float:
        """The tile's geometricError (its parent's when invalid), not larger than its parent's."""
        ge = tile.get("geometricError")
        if not _is_number(ge) or ge < 0:
            self.problems.append(f"{where}: geometricError must be a number >= 0")
            return parent_error
        if ge > parent_error + 1e-9:
            self.problems.append(f"{where}: geometricError {ge} exceeds its parent's {parent_error}")
        return ge

    def _content(self, c: object, where: str, bv: dict[str, Any] | None, world: np.ndarray) -> None:
        """One content: a relative uri to an existing file, used once, a valid glb, inside the tile's volume."""
        problems = self.problems
        uri = c.get("uri") if isinstance(c, dict) else None
        if not isinstance(c, dict) or not isinstance(uri, str) or not uri:
            problems.append(f"{where}: content needs a uri")
            return
        parsed = urlparse(uri)
        if parsed.scheme or parsed.netloc:
            problems.append(f"{where}: content uri {uri} is not relative (cannot be checked offline)")
            return
        target = (self.base / unquote(parsed.path)).resolve()
        if not target.is_file():
            problems.append(f"{where}: content uri {uri} does not resolve to a file")
            return
        if uri in self.uris:
            problems.append(f"{where}: content uri {uri} used twice")
        self.uris.add(uri)
        if target.suffix == ".glb":
            _check_glb(target, where, problems)
        if (
            "boundingVolume" in c
            and _check_bv(c["boundingVolume"], where + ".content", problems)
            and bv is not None
            and not _inside(c["boundingVolume"], bv, world, world)
        ):
            problems.append(f"{where}: content bounding volume not inside the tile's")


def compressed_metadata_views(gltf: dict[str, Any]) -> list[int]:
    """The bufferViews EXT_structural_metadata's property tables read (values, arrayOffsets, stringOffsets) that
    are meshopt-compressed: what a metadata reader without a meshopt decoder (the CesiumGS 3d-tiles-validator)
    misreads as the table. The default stream has none (exporter/stream.py ``tables``)."""
    views = gltf.get("bufferViews", [])
    read = {
        col[key]
        for table in _property_tables(gltf)
        for col in table.get("properties", {}).values()
        for key in ("values", "arrayOffsets", "stringOffsets")
        if key in col
    }
    meshopt = ("KHR_meshopt_compression", "EXT_meshopt_compression")
    return sorted(i for i in read if i < len(views) and any(e in views[i].get("extensions", {}) for e in meshopt))
