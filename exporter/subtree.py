"""Subtree files of a 3D Tiles 1.1 implicit quadtree. Pure: tile keys and arrays in, bytes out.

A subtree covers ``subtree_levels`` levels below its root tile (level, x, y). Its binary file (magic ``subt``)
holds a JSON chunk and a binary chunk with:
  * tileAvailability, contentAvailability and childSubtreeAvailability: bitstreams over the tiles in
    Morton order, level by level (bit i is byte i >> 3, bit i & 7), or ``{"constant": 0|1}`` when all bits
    agree;
  * the tile metadata property table (``tileMetadata``): one row per available tile, in bit order, of the
    class ``tile`` of ``tileset.TILE_SCHEMA`` (each tile's real bounding region and geometric error, with the metadata
    semantics TILE_BOUNDING_REGION and TILE_GEOMETRIC_ERROR: the quadtree is cut in the working CRS and its
    regions are the extents of the meshes, not the uniform subdivision of the root region).
Every bufferView starts on an 8-byte boundary; the JSON chunk is padded with spaces, the binary with zeros.
"""

from __future__ import annotations

import json
import struct

import numpy as np

MAGIC = b"subt"
VERSION = 1


def level_offset(level: int | np.ndarray) -> int | np.ndarray:
    """Bits before ``level`` in a quadtree subtree's availability: (4^level - 1) / 3."""
    return (
        ((1 << (2 * np.asarray(level, np.int64))) - 1) // 3
        if isinstance(level, np.ndarray)
        else ((1 << (2 * level)) - 1) // 3
    )


def morton(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Quadtree Morton index: the bits of x and y interleaved, x in the lower bit of each pair."""
    x, y = np.asarray(x, np.int64), np.asarray(y, np.int64)
    out = np.zeros(np.broadcast(x, y).shape, np.int64)
    top = int(max(x.max(initial=0), y.max(initial=0)))
    for b in range(top.bit_length()):
        out |= ((x >> b) & 1) << (2 * b) | ((y >> b) & 1) << (2 * b + 1)
    return out


def subtree_roots(keys: np.ndarray, subtree_levels: int) -> np.ndarray:
    """(n, 3) the root (level, x, y) of the subtree each tile key (n, 3: level, x, y) lies in."""
    lv = keys[:, 0]
    root_lv = lv - lv % subtree_levels
    shift = lv - root_lv
    return np.stack([root_lv, keys[:, 1] >> shift, keys[:, 2] >> shift], axis=1)


def subtree_sizes(keys: np.ndarray, subtree_levels: int, row_bytes: int) -> tuple[np.ndarray, np.ndarray]:
    """(roots (m, 3), bytes (m,)) of the subtree files ``keys`` (n, 3: level, x, y) make with ``subtree_levels``,
    estimated: ~500 bytes of header and JSON, the availability bitstreams that are not
    constant (content shares the tiles' when equal) and ``row_bytes`` of metadata per tile."""
    roots = subtree_roots(keys, subtree_levels)
    uniq, count = np.unique(roots, axis=0, return_counts=True)
    n_bits = level_offset(subtree_levels)
    tile_bits = np.where(count == n_bits, 0, -(-n_bits // 64) * 8)
    # the subtrees just below each one: roots at level + subtree_levels under it
    deep = uniq[uniq[:, 0] >= subtree_levels]
    up = np.c_[deep[:, 0] - subtree_levels, deep[:, 1] >> subtree_levels, deep[:, 2] >> subtree_levels]
    parent, n_child = np.unique(up, axis=0, return_counts=True)
    children = np.zeros(len(uniq), np.int64)
    if len(parent):
        pos = {tuple(k): i for i, k in enumerate(uniq.tolist())}
        children[[pos[tuple(k)] for k in parent.tolist()]] = n_child
    n_child_bits = 1 << (2 * subtree_levels)
    child_bits = np.where((children == 0) | (children == n_child_bits), 0, -(-n_child_bits // 64) * 8)
    return uniq, 500 + tile_bits + child_bits + count * row_bytes


def choose_subtree_levels(
    keys: np.ndarray, row_bytes: int, single_budget: int = 2 << 20, root_budget: int = 65_536, file_cost: int = 4_096
) -> int:
    """subtreeLevels for a tree (keys (n, 3): level, x, y).

    One subtree for the whole tree when it fits in ``single_budget`` bytes (the ~1M bench city's is 500 kB):
    a client builds the placeholder of a child subtree, before loading it, from the uniform subdivision of
    the root region and the root error halved per level (CesiumJS Implicit3DTileContent
    makePlaceholderChildSubtree), and our tiles are not that subdivision, so a placeholder can be culled while
    the tiles below it are in view. Deeper trees: the fewest bytes plus ``file_cost`` per file (a request
    costs about as much as that many bytes), among the levels (2 to 10) whose root subtree, a client's first
    fetch, stays within ``root_budget`` bytes."""
    levels = int(keys[:, 0].max()) + 1
    if subtree_sizes(keys, levels, row_bytes)[1].sum() <= single_budget:
        return levels
    best, best_cost = 2, float("inf")
    for s in range(2, 11):
        roots, size = subtree_sizes(keys, s, row_bytes)
        root = size[np.flatnonzero(np.all(roots == 0, axis=1))].sum()
        cost = size.sum() + len(size) * file_cost
        if root <= root_budget and cost < best_cost:
            best, best_cost = s, cost
    return best


def _bitstream(bits: np.ndarray) -> dict[str, int] | bytes:
    """{"constant": 0|1} when every bit agrees, else the packed bytes (little-endian bit order)."""
    if bits.all():
        return {"constant": 1}
    if not bits.any():
        return {"constant": 0}
    return np.packbits(bits, bitorder="little").tobytes()


def write_subtree(
    root: tuple[int, int, int],
    subtree_levels: int,
    tiles: np.ndarray,
    content: np.ndarray,
    child_roots: np.ndarray,
    columns: list[tuple[str, np.ndarray]],
) -> bytes:
    """The .subtree file of the subtree at ``root``: ``tiles`` (n, 3) the available tiles in it (global level,
    x, y), ``content`` (n,) bool which of them have content, ``child_roots`` (m, 3) the available child
    subtrees' roots (level root + subtree_levels), ``columns`` the tile metadata (name, (n, ...) array, one row
    per tile in the order of ``tiles``)."""
    r_lv, r_x, r_y = root
    local = tiles[:, 0] - r_lv
    if len(tiles) == 0 or local.min() < 0 or local.max() >= subtree_levels:
        raise ValueError(f"subtree {root}: tiles outside its {subtree_levels} levels")
    lx, ly = tiles[:, 1] - (r_x << local), tiles[:, 2] - (r_y << local)
    if np.any(lx < 0) or np.any(ly < 0) or np.any(lx >= (1 << local)) or np.any(ly >= (1 << local)):
        raise ValueError(f"subtree {root}: a tile lies outside it")
    bit = level_offset(local) + morton(lx, ly)
    order = np.argsort(bit, kind="stable")
    n_bits = level_offset(subtree_levels)
    tile_bits = np.zeros(n_bits, bool)
    tile_bits[bit] = True
    if tile_bits.sum() != len(tiles):
        raise ValueError(f"subtree {root}: a tile is listed twice")
    content_bits = np.zeros(n_bits, bool)
    content_bits[bit[content]] = True
    child_bits = np.zeros(1 << (2 * subtree_levels), bool)
    if len(child_roots):
        if np.any(child_roots[:, 0] != r_lv + subtree_levels):
            raise ValueError(f"subtree {root}: child subtrees must start {subtree_levels} levels below")
        child_bits[morton(child_roots[:, 1] - (r_x << subtree_levels), child_roots[:, 2] - (r_y << subtree_levels))] = (
            True
        )

    binary = bytearray()
    views: list[dict[str, int]] = []

    def view(data: bytes) -> int:
        binary.extend(b"\0" * ((-len(binary)) % 8))
        views.append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(data)})
        binary.extend(data)
        return len(views) - 1

    def availability(bits: np.ndarray, same_as: tuple[np.ndarray, dict] | None = None) -> dict[str, int]:
        packed = _bitstream(bits)
        if isinstance(packed, dict):
            return {**packed, "availableCount": int(bits.sum())}
        if same_as is not None and np.array_equal(bits, same_as[0]) and "bitstream" in same_as[1]:
            return {"bitstream": same_as[1]["bitstream"], "availableCount": int(bits.sum())}
        return {"bitstream": view(packed), "availableCount": int(bits.sum())}

    tile_av = availability(tile_bits)
    doc: dict[str, object] = {
        "tileAvailability": tile_av,
        "contentAvailability": [availability(content_bits, (tile_bits, tile_av))],
        "childSubtreeAvailability": availability(child_bits),
    }
    if columns:
        props = {}
        for name, values in columns:
            if len(values) != len(tiles):
                raise ValueError(f"tile metadata {name}: {len(values)} rows for {len(tiles)} tiles")
            props[name] = {"values": view(np.ascontiguousarray(values[order]).tobytes())}
        doc["propertyTables"] = [{"class": "tile", "count": len(tiles), "properties": props}]
        doc["tileMetadata"] = 0
    binary.extend(b"\0" * ((-len(binary)) % 8))
    if binary:
        doc["buffers"] = [{"byteLength": len(binary)}]
        doc["bufferViews"] = views
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * ((-len(js)) % 8)
    return struct.pack("<4sIQQ", MAGIC, VERSION, len(js), len(binary)) + js + bytes(binary)
