"""Copying unchanged tiles: an export of a published tileset builds only the glbs whose input changed.

A tile's glb is a function of what api.export_digest fingerprints (its features, their landmark metadata, its
atlas pages and UVs), of the exporter's code, settings and options, and of the tile's record in the tree. The
export records the sha256 of all that per glb (pub.file.input_digest) when it publishes; the next export of the
same tileset computes it again for every tile its stages' runs reached since (core/changes.py; about half the cost
of reading the features; the others keep the published key, live_keys) and copies the glb of every tile whose key
is the same: from the export directory when the file there has the published bytes,
else from pub.blob. So an update that moves a few buildings writes the few tiles they are in and their
ancestors, and the other glbs keep their bytes (and their ETags).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import psycopg

from core.changes import reach, since
from core.db import connect, shares, thread_map
from core.fingerprint import run_seed
from exporter.gltf import read_glb
from exporter.stream import StreamOptions
from exporter.tileset import TileRecord

#: a share of the tiles in one statement: planned once, where a call per tile was planned per call (Liechtenstein,
#: 133 tiles: 1.7 s with 2 connections against 2.2 s a call per tile)
_DIGESTS = ("SELECT t.level, t.x, t.y, d.digest, d.n_features FROM unnest(%s::int[], %s::int[], %s::int[]) "
            "AS t(level, x, y) CROSS JOIN LATERAL api.export_digest(t.level, t.x, t.y, %s, %s) d")


@dataclass(frozen=True)
class TileKey:
    key: str         # sha256 hex: the recipe, the tile's record, api.export_digest
    n_features: int  # the features api.export_features gives the tile


def recipe(code: str, lod: int | None, stream: StreamOptions, root_region: tuple[float, ...]) -> str:
    """What every tile's key starts from: ``code`` (the export's Python and SQL and the settings they read, as
    the command line has etl/staleness.py record them), the options, and the root region (every glb is placed in its
    frame)."""
    return run_seed(code, lod, stream.as_dict(), list(root_region))


def tile_key(seed: str, rec: TileRecord, digest: str) -> str:
    return hashlib.sha256(json.dumps([seed, dataclasses.astuple(rec), digest], default=str).encode()).hexdigest()


def tile_keys(url: str, tiles: list[TileRecord], seed: str, lod: int | None,
              stream: StreamOptions) -> dict[str, TileKey]:
    """Every tile's key by content URI; the digests are read by threads with a connection each (the SQL runs in
    separate backends), each over a share of the tiles in one statement."""
    textures = stream.textures if lod is None else None
    threads = min(4, os.cpu_count() or 1)
    by_place = {(r.level, r.x, r.y): r for r in tiles}

    def one(conn: psycopg.Connection, share: list[TileRecord]) -> list[tuple]:
        return conn.execute(_DIGESTS, ([r.level for r in share], [r.x for r in share], [r.y for r in share], lod,
                                       textures)).fetchall()

    keys: dict[str, TileKey] = {}
    largest_first = sorted(tiles, key=lambda r: -(r.content_features or 0))
    with thread_map(url, one, shares(largest_first, threads), threads) as got:
        for part in got:
            for level, x, y, digest, n in part:
                rec = by_place[(level, x, y)]
                assert rec.content_uri is not None
                keys[rec.content_uri] = TileKey(tile_key(seed, rec, digest), int(n))
    return keys


def published_inputs(conn: psycopg.Connection, name: str) -> dict[str, tuple[str, bytes]]:
    """The live generation of tileset ``name``: path -> (input digest, sha256) of every file that has one."""
    return {p: (d, bytes(s)) for p, d, s in conn.execute(
        "SELECT f.path, f.input_digest, f.sha256 FROM pub.file f WHERE f.input_digest IS NOT NULL AND f.generation = "
        "(SELECT max(generation) FROM pub.generation WHERE tileset = %s)", (name,))}


def live_keys(conn: psycopg.Connection, name: str, seed: str, tiles: list[TileRecord],
              published: dict[str, tuple[str, bytes]], lod: int | None) -> dict[str, TileKey]:
    """The keys of the tiles whose input is, without reading it, the one the live generation of ``name`` was
    built from: made with the same recipe (``seed``, recorded in its options), and reached by no run of the
    stages since the export that published it (core/changes.py): their features, pages and record are as they were.
    Empty when that is not known (another recipe, a run since that recorded no change set)."""
    live = conn.execute("SELECT run_id, options->>'recipe' FROM pub.generation WHERE tileset = %s "
                        "ORDER BY generation DESC LIMIT 1", (name,)).fetchone()
    if live is None or live[0] is None or live[1] != seed:
        return {}
    changed = since(conn, "export", int(live[0]))
    if changed is None:
        return {}
    reached = reach(conn, changed)
    return {r.content_uri: TileKey(published[r.content_uri][0], r.n_features if lod else r.content_features or 0)
            for r in tiles
            if r.content_uri is not None and r.content_uri in published and (r.level, r.x, r.y) not in reached}


def unchanged(keys: dict[str, TileKey], published: dict[str, tuple[str, bytes]]) -> dict[str, bytes]:
    """path -> sha256 of the published glb, for every tile whose key is the published one."""
    return {p: published[p][1] for p, k in keys.items() if p in published and published[p][0] == k.key}


def glb_triangles(glb: bytes) -> int:
    """Triangles of a glb's meshes (index accessor counts / 3), as the export counts the ones it builds."""
    gltf, _ = read_glb(glb)
    acc = gltf.get("accessors", [])
    return sum(acc[p["indices"]]["count"] // 3  # type: ignore[index]
               for m in gltf.get("meshes", []) for p in m["primitives"])  # type: ignore[union-attr, attr-defined]


def copy_unchanged(url: str, reuse: dict[str, bytes], old: Path, new: Path) -> tuple[int, int]:
    """Put every reused glb under ``new``: hard-linked (else copied) from ``old`` where that file holds the
    published bytes, the others read from pub.blob. Returns (triangles, bytes)."""
    from_blob: dict[bytes, list[str]] = {}
    triangles = n_bytes = 0
    for path, sha in sorted(reuse.items()):
        src, dst = old / path, new / path
        dst.parent.mkdir(parents=True, exist_ok=True)
        try:
            data: bytes | None = src.read_bytes()
        except OSError:
            data = None
        if data is not None and hashlib.sha256(data).digest() == sha:
            try:
                os.link(src, dst)
            except OSError:
                dst.write_bytes(data)
            triangles, n_bytes = triangles + glb_triangles(data), n_bytes + len(data)
        else:
            from_blob.setdefault(sha, []).append(path)
    if from_blob:
        with connect(url) as conn:
            for sha, body in conn.execute("SELECT sha256, body FROM pub.blob WHERE sha256 = ANY(%s)",
                                          (list(from_blob),)):
                for path in from_blob.pop(bytes(sha)):
                    (new / path).write_bytes(body)
                    triangles, n_bytes = triangles + glb_triangles(body), n_bytes + len(body)
    if from_blob:  # only if other exports published this tileset twice meanwhile, dropping the generation
        raise RuntimeError(f"published glbs missing from pub.blob: {sorted(p for v in from_blob.values() for p in v)}")
    return triangles, n_bytes
