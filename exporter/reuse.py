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
import os
from dataclasses import dataclass, field
from pathlib import Path

import psycopg

from core.changes import reach, since
from core.db import connect, shares, thread_map
from core.fingerprint import run_seed
from core.reuse import plan
from exporter.gltf import read_glb
from exporter.stream import StreamOptions
from exporter.tileset import TileRecord

#: a share of the tiles in one statement: planned once, where a call per tile was planned per call (Liechtenstein,
#: 133 tiles: 1.7 s with 2 connections against 2.2 s a call per tile)
_DIGESTS = (
    "SELECT t.level, t.x, t.y, d.digest, d.n_features FROM unnest(%s::int[], %s::int[], %s::int[]) "
    "AS t(level, x, y) CROSS JOIN LATERAL api.export_digest(t.level, t.x, t.y, %s, %s) d"
)


def recipe(code: str, lod: int | None, stream: StreamOptions, root_region: tuple[float, ...]) -> str:
    """What every tile's key starts from: ``code`` (the export's Python and SQL and the settings they read, as
    its run records them), the options, and the root region (every glb is placed in its frame)."""
    return run_seed(code, lod, stream.as_dict(), list(root_region))


@dataclass
class Glbs:
    """Which glbs an export copies from the live generation of its tileset, and every tile's key."""

    #: content URI -> the tile's key this run (pub.file.input_digest)
    keys: dict[str, str] = field(default_factory=dict)
    #: content URI -> sha256 of the published glb to copy: its key is the published one
    copy: dict[str, bytes] = field(default_factory=dict)
    #: content URI -> the features api.export_features gives the tile now
    n_features: dict[str, int] = field(default_factory=dict)
    #: the tiles whose api.export_digest was read
    fingerprinted: int = 0


def _digests(
    url: str, tiles: list[TileRecord], lod: int | None, stream: StreamOptions
) -> dict[tuple[int, int, int], tuple[str, int]]:
    """api.export_digest of every tile (digest, features), read by threads with a connection each (the SQL runs
    in separate backends), each over a share of the tiles in one statement."""
    textures = stream.textures if lod is None else None
    threads = min(4, os.cpu_count() or 1)

    def one(conn: psycopg.Connection, share: list[TileRecord]) -> list[tuple]:
        return conn.execute(
            _DIGESTS, ([r.level for r in share], [r.x for r in share], [r.y for r in share], lod, textures)
        ).fetchall()

    largest_first = sorted(tiles, key=lambda r: -(r.content_features or 0))
    with thread_map(url, one, shares(largest_first, threads), threads) as got:
        return {(lv, x, y): (d, int(n)) for part in got for lv, x, y, d, n in part}


def published_inputs(conn: psycopg.Connection, name: str) -> dict[str, tuple[str, bytes]]:
    """The live generation of tileset ``name``: path -> (input digest, sha256) of every file that has one."""
    return {
        p: (d, bytes(s))
        for p, d, s in conn.execute(
            "SELECT f.path, f.input_digest, f.sha256 FROM pub.file f WHERE f.input_digest IS NOT NULL"
            " AND f.generation = (SELECT max(generation) FROM pub.generation WHERE tileset = %s)",
            (name,),
        )
    }


def _reached(conn: psycopg.Connection, name: str, seed: str, tiles: list[TileRecord]) -> set[str] | None:
    """The content URIs of the tiles some run reached since the export that published the live generation of
    ``name`` (core/changes.py); the others' features, pages and record are as they were. None when that is not
    known (no such generation, another recipe, a run since that recorded no change set)."""
    live = conn.execute(
        "SELECT run_id, options->>'recipe' FROM pub.generation WHERE tileset = %s ORDER BY generation DESC LIMIT 1",
        (name,),
    ).fetchone()
    if live is None or live[0] is None or live[1] != seed:
        return None
    changed = since(conn, "export", int(live[0]))
    if changed is None:
        return None
    at = reach(conn, changed)
    return {r.content_uri for r in tiles if r.content_uri is not None and (r.level, r.x, r.y) in at}


def plan_glbs(
    url: str, name: str, seed: str, tiles: list[TileRecord], lod: int | None, stream: StreamOptions, reached: bool
) -> Glbs:
    """Which glbs of ``tiles`` to copy from the live generation of tileset ``name`` (core/reuse.py): a tile's
    key is made of ``seed``, its record in the tree and api.export_digest. With ``reached`` (an update's
    export) only the tiles some run reached since that generation are fingerprinted; the others keep its key."""
    out = Glbs()
    by_uri = {r.content_uri: r for r in tiles if r.content_uri is not None}
    with connect(url) as conn:
        published = published_inputs(conn, name)
        at = _reached(conn, name, seed, tiles) if reached else None

    def parts(uris: list[str]) -> dict[str, tuple[object, ...]]:
        got = _digests(url, [by_uri[u] for u in uris], lod, stream)
        out.n_features.update({u: got[(r.level, r.x, r.y)][1] for u, r in ((u, by_uri[u]) for u in uris)})
        return {u: (dataclasses.astuple(r), got[(r.level, r.x, r.y)][0]) for u, r in ((u, by_uri[u]) for u in uris)}

    p = plan(list(by_uri), seed, {u: d for u, (d, _) in published.items()}, parts, reached=at)
    for u in by_uri.keys() - set(p.read):  # as api.export_features counts them
        r = by_uri[u]
        out.n_features[u] = r.n_features if lod else r.content_features or 0
    out.keys, out.fingerprinted = p.prints, len(p.read)
    out.copy = {u: published[u][1] for u in p.keep}
    return out


def glb_triangles(glb: bytes) -> int:
    """Triangles of a glb's meshes (index accessor counts / 3), as the export counts the ones it builds."""
    gltf, _ = read_glb(glb)
    acc = gltf.get("accessors", [])
    return sum(acc[p["indices"]]["count"] // 3 for m in gltf.get("meshes", []) for p in m["primitives"])


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
            for sha, body in conn.execute(
                "SELECT sha256, body FROM pub.blob WHERE sha256 = ANY(%s)", (list(from_blob),)
            ):
                for path in from_blob.pop(bytes(sha)):
                    (new / path).write_bytes(body)
                    triangles, n_bytes = triangles + glb_triangles(body), n_bytes + len(body)
    if from_blob:  # only if other exports published this tileset twice meanwhile, dropping the generation
        raise RuntimeError(f"published glbs missing from pub.blob: {sorted(p for v in from_blob.values() for p in v)}")
    return triangles, n_bytes
