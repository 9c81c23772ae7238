"""Reading a 3D Tiles tileset.json: what the stage graph (is an export still on disk?), the database server
(which tile addresses exist), the checks and the tests share. Pure: files come through ``read`` (a relative
URI -> its bytes).

An implicit tileset (3D Tiles 1.1 ``implicitTiling``, QUADTREE) is expanded into the explicit tree it stands
for (``expand``): its subtree files are read from the root down, each available tile becomes a tile with the
content URI its template gives where content is available, and the bounding region and geometric error its
tile metadata gives (semantics TILE_BOUNDING_REGION, TILE_GEOMETRIC_ERROR), else the uniform subdivision of
the root region and the root error halved per level.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

Read = Callable[[str], bytes]

_DTYPES = {"FLOAT32": "<f4", "FLOAT64": "<f8"}


class SubtreeError(ValueError):
    """A subtree file that does not follow the 3D Tiles 1.1 subtree format."""


@dataclass(frozen=True)
class Subtree:
    json: dict[str, Any]
    binary: bytes

    def view(self, index: int) -> bytes:
        views = self.json.get("bufferViews", [])
        if not isinstance(index, int) or not 0 <= index < len(views):
            raise SubtreeError(f"bufferView {index} does not exist")
        v = views[index]
        if v.get("buffer", 0) != 0 or "uri" in self.json["buffers"][0]:
            raise SubtreeError("only the internal buffer (the binary chunk) is supported")
        start, n = v.get("byteOffset", 0), v.get("byteLength", 0)
        if start % 8:
            raise SubtreeError(f"bufferView {index} is not 8-byte aligned")
        if start + n > len(self.binary):
            raise SubtreeError(f"bufferView {index} lies outside the binary chunk")
        return self.binary[start : start + n]

    def bits(self, availability: dict[str, Any], n: int, what: str) -> np.ndarray:
        """An availability as n booleans."""
        if "constant" in availability:
            if availability["constant"] not in (0, 1):
                raise SubtreeError(f"{what}: constant must be 0 or 1")
            out = np.full(n, bool(availability["constant"]))
        elif "bitstream" in availability:
            data = self.view(availability["bitstream"])
            if len(data) * 8 < n:
                raise SubtreeError(f"{what}: bitstream of {len(data)} bytes for {n} bits")
            out = np.unpackbits(np.frombuffer(data, np.uint8), bitorder="little")[:n].astype(bool)
        else:
            raise SubtreeError(f"{what}: neither constant nor bitstream")
        if "availableCount" in availability and availability["availableCount"] != int(out.sum()):
            raise SubtreeError(f"{what}: availableCount {availability['availableCount']} != {int(out.sum())} set")
        return out


def read_subtree(data: bytes) -> Subtree:
    """A binary .subtree file (header, JSON chunk, binary chunk)."""
    if len(data) < 24:
        raise SubtreeError("too short for a subtree header")
    magic, version, jlen, blen = struct.unpack_from("<4sIQQ", data)
    if magic != b"subt" or version != 1:
        raise SubtreeError("not a version 1 subtree file (magic 'subt')")
    if 24 + jlen + blen != len(data):
        raise SubtreeError(f"header says {24 + jlen + blen} bytes, the file has {len(data)}")
    if jlen % 8 or blen % 8:
        raise SubtreeError("JSON and binary chunks must be padded to 8 bytes")
    try:
        js = json.loads(data[24 : 24 + jlen])
    except ValueError as e:
        raise SubtreeError(f"JSON chunk does not parse: {e}") from None
    binary = data[24 + jlen :]
    if js.get("buffers") and js["buffers"][0].get("byteLength", 0) > len(binary):
        raise SubtreeError("buffer 0 is longer than the binary chunk")
    return Subtree(js, binary)


def _morton_xy(index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.zeros_like(index)
    y = np.zeros_like(index)
    for b in range(31):
        x |= ((index >> (2 * b)) & 1) << b
        y |= ((index >> (2 * b + 1)) & 1) << b
    return x, y


def _template(uri: str, level: int, x: int, y: int) -> str:
    return uri.replace("{level}", str(level)).replace("{x}", str(x)).replace("{y}", str(y))


def _semantic_columns(tileset: dict[str, Any], sub: Subtree, count: int) -> dict[str, np.ndarray]:
    """TILE_BOUNDING_REGION (count, 6) and TILE_GEOMETRIC_ERROR (count,) of the subtree's tile metadata."""
    if "tileMetadata" not in sub.json:
        return {}
    tables = sub.json.get("propertyTables", [])
    index = sub.json["tileMetadata"]
    if not isinstance(index, int) or not 0 <= index < len(tables):
        raise SubtreeError(f"tileMetadata {index} is not a property table")
    table = tables[index]
    cls = tileset.get("schema", {}).get("classes", {}).get(table.get("class"))
    if cls is None:
        raise SubtreeError(f"property table class {table.get('class')!r} is not in the tileset's schema")
    if table.get("count") != count:
        raise SubtreeError(f"tile property table count {table.get('count')} != {count} available tiles")
    out = {}
    for name, spec in cls.get("properties", {}).items():
        sem = spec.get("semantic")
        width = {"TILE_BOUNDING_REGION": 6, "TILE_GEOMETRIC_ERROR": 1}.get(sem)
        if width is None or name not in table.get("properties", {}):
            continue
        dtype = _DTYPES.get(spec.get("componentType", ""))
        if dtype is None or spec.get("type") != "SCALAR" or (width > 1 and spec.get("count") != width):
            raise SubtreeError(f"{sem} must be FLOAT32/FLOAT64 SCALAR{f'[{width}]' if width > 1 else ''}")
        if "offset" in spec or "scale" in spec or "offset" in table["properties"][name]:
            raise SubtreeError(f"{name}: offset/scale not supported by this reader")
        raw = sub.view(table["properties"][name]["values"])
        need = count * width * np.dtype(dtype).itemsize
        if len(raw) < need:
            raise SubtreeError(f"{name}: {len(raw)} bytes for {count} tiles (needs {need})")
        vals = np.frombuffer(raw, dtype, count=count * width).astype(np.float64)
        out[sem] = vals.reshape(count, width) if width > 1 else vals
    return out


def _implicit_tiling(imp: dict[str, Any]) -> tuple[int, int, str]:
    """(subtreeLevels, availableLevels, subtree URI template) of a QUADTREE implicitTiling; SubtreeError else."""
    if imp.get("subdivisionScheme") != "QUADTREE":
        raise SubtreeError(f"subdivisionScheme {imp.get('subdivisionScheme')!r}: only QUADTREE is read here")
    levels, available = imp.get("subtreeLevels"), imp.get("availableLevels")
    if not isinstance(levels, int) or levels < 1 or not isinstance(available, int) or available < 1:
        raise SubtreeError("implicitTiling needs subtreeLevels and availableLevels >= 1")
    sub_uri = imp.get("subtrees", {}).get("uri")
    if not isinstance(sub_uri, str):
        raise SubtreeError("implicitTiling.subtrees.uri missing")
    return levels, available, sub_uri


def uniform_region(root_region: list[float], key: tuple[int, int, int]) -> list[float]:
    """Tile ``key``'s (level, x, y) part of the root region by uniform subdivision, the root's heights: the
    volume a client that ignores subtree metadata gives the tile."""
    rw, rs, re_, rn, rlo, rhi = root_region
    n = 1 << key[0]
    return [
        rw + (re_ - rw) * key[1] / n,
        rs + (rn - rs) * key[2] / n,
        rw + (re_ - rw) * (key[1] + 1) / n,
        rs + (rn - rs) * (key[2] + 1) / n,
        rlo,
        rhi,
    ]


def _link_children(tiles: dict[tuple[int, int, int], dict[str, Any]]) -> None:
    """Every available tile below the root into its parent's children (in (level, x, y) order); SubtreeError
    when the root or some tile's parent is not available."""
    if (0, 0, 0) not in tiles:
        raise SubtreeError("the root subtree does not make the root tile available")
    for lv, x, y in sorted(tiles):
        if lv == 0:
            continue
        parent = tiles.get((lv - 1, x >> 1, y >> 1))
        if parent is None:
            raise SubtreeError(f"tile {lv}/{x}/{y} is available but its parent is not")
        parent.setdefault("children", []).append(tiles[(lv, x, y)])


def expand(tileset: dict[str, Any], read: Read, metadata: bool = True) -> dict[str, Any]:
    """The explicit tileset an implicit one stands for (a deep copy; an explicit tileset comes back as is).
    Each expanded tile has boundingVolume, geometricError, content (where available), children, and
    ``implicit``: [level, x, y]. ``metadata=False`` ignores the subtrees' TILE_BOUNDING_REGION and
    TILE_GEOMETRIC_ERROR, as some clients do (the uniform subdivision of the root, its error halved per level).
    Raises SubtreeError (a ValueError) for a malformed subtree, OSError when ``read`` cannot read one."""
    root = tileset.get("root", {})
    if "implicitTiling" not in root:
        return tileset
    levels, available, sub_uri = _implicit_tiling(root["implicitTiling"])
    content_uri = root.get("content", {}).get("uri")
    rw, rs, re_, rn, rlo, rhi = root["boundingVolume"]["region"]
    root_region = [rw, rs, re_, rn, rlo, rhi]
    root_error = float(root["geometricError"])
    n_bits = ((1 << (2 * levels)) - 1) // 3
    tiles: dict[tuple[int, int, int], dict[str, Any]] = {}

    def load(lv: int, sx: int, sy: int) -> None:
        sub = read_subtree(read(_template(sub_uri, lv, sx, sy)))
        avail = sub.bits(sub.json.get("tileAvailability", {}), n_bits, "tileAvailability")
        contents = sub.json.get("contentAvailability", [])
        has = sub.bits(contents[0], n_bits, "contentAvailability") if contents else np.zeros(n_bits, bool)
        if np.any(has & ~avail):
            raise SubtreeError(f"subtree {lv}/{sx}/{sy}: content available on a tile that is not")
        child = sub.bits(sub.json.get("childSubtreeAvailability", {}), 1 << (2 * levels), "childSubtreeAvailability")
        bit = np.flatnonzero(avail)
        local = np.searchsorted(np.array([((1 << (2 * k)) - 1) // 3 for k in range(1, levels + 1)]), bit, side="right")
        mx, my = _morton_xy(bit - (((1 << (2 * local)) - 1) // 3))
        meta = _semantic_columns(tileset, sub, len(bit))
        for i, (k, x, y) in enumerate(zip(local.tolist(), mx.tolist(), my.tolist(), strict=True)):
            key = (lv + k, (sx << k) + x, (sy << k) + y)
            if key[0] >= available:
                raise SubtreeError(f"tile {key} is below availableLevels {available}")
            n = 1 << key[0]
            region = (
                meta["TILE_BOUNDING_REGION"][i].tolist()
                if metadata and "TILE_BOUNDING_REGION" in meta
                else uniform_region(root_region, key)
            )
            error = (
                float(meta["TILE_GEOMETRIC_ERROR"][i])
                if metadata and "TILE_GEOMETRIC_ERROR" in meta
                else root_error / n
            )
            t: dict[str, Any] = {"boundingVolume": {"region": region}, "geometricError": error, "implicit": list(key)}
            if has[bit[i]] and content_uri:
                t["content"] = {"uri": _template(content_uri, *key)}
            tiles[key] = t
        for c in np.flatnonzero(child).tolist():
            cx, cy = _morton_xy(np.array([c]))
            load(lv + levels, (sx << levels) + int(cx[0]), (sy << levels) + int(cy[0]))

    load(0, 0, 0)
    _link_children(tiles)
    out = {k: v for k, v in tileset.items() if k != "root"}
    top = tiles[(0, 0, 0)]
    for k in ("refine", "transform"):
        if k in root:
            top[k] = root[k]
    out["root"] = top
    return out


def content_uris(tileset: dict[str, Any], read: Read | None = None) -> list[str]:
    """Every content URI the tileset references (``content`` and 1.1's ``contents``), sorted. An implicit
    tileset needs ``read`` to expand it (ValueError without)."""
    if "implicitTiling" in tileset.get("root", {}):
        if read is None:
            raise ValueError("an implicit tileset: its content is listed in subtree files, pass read")
        tileset = expand(tileset, read)
    out: list[str] = []
    stack = [tileset.get("root", {})]
    while stack:
        tile = stack.pop()
        for c in [tile.get("content"), *tile.get("contents", [])]:
            if isinstance(c, dict) and "uri" in c:
                out.append(c["uri"])
        stack.extend(tile.get("children", []))
    return sorted(out)


def tileset_files(tileset: dict[str, Any], read: Read | None = None) -> list[str]:
    """Every file the tileset needs besides tileset.json: content, and for an implicit tileset its subtrees."""
    seen: list[str] = []
    if read is not None:
        inner = read

        def read(uri: str) -> bytes:  # noqa: F811 - records what expand reads
            seen.append(uri)
            return inner(uri)

    return sorted(set(content_uris(tileset, read)) | set(seen))
