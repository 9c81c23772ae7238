"""The textures stage's worker side: one unit of work (a LOD2 tile and its leaves, or a tile alone) textured and
encoded, in a worker process with its own connection (etl/textures/stage.py writes what comes back).

Per tile: its resolution (``resolution``: texels per metre and view distance) and gutter (``padding_for``), the
rows of tex.tile_features turned into arrays and styles, etl/textures/texturing.py's charts, pages and UVs, and
every page encoded twice (WebP by OpenImageIO here, KTX2 by basisu processes meanwhile). A feature that fails
alone is listed in the tile's failures and the tile textured without it; a unit whose worker hangs or dies comes
back as a ``Lost`` (core/workers.py), and ``_lost`` lists its features.
"""

from __future__ import annotations

import atexit
import math
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Any, LiteralString

import numpy as np
import psycopg
from psycopg.rows import dict_row

from core.camera import distance_for_pixels
from core.db import connect
from core.semantics import SEM_DOOR, SEM_WINDOW
from core.settings import Settings
from core.wkb import decode_triangles
from core.workers import Lost, imap_isolated
from etl.textures import atlas as A
from etl.textures import ktx2 as K
from etl.textures import texturing as X

FORMAT = "webp"
WEBP_METHOD = 2  # libwebp effort: 4 is 2.4x slower for 3 % fewer bytes on these pages (measured)
# KTX2 settings (core.settings tex_ktx2_*), measured on 16 Liechtenstein pages of 512 x 512, level 0 of the ETC1
# transcode against the page (WebP q90 for scale: 363 kB, PSNR 39.6 dB, mean abs diff 1.49 of 255): basisu -q 64
# 208 kB, 35.2 dB, 2.43; -q 128 257 kB, 35.2 dB, 2.42; -q 32 180 kB, 34.8 dB, 2.49; -comp_level 0 6 % more bytes
# for ~10 % less time. The error is ETC1S's block format, not its codebook size: -q above 64 buys bytes only.
# Encoding costs ~0.35 s a 512 x 512 page (basisu, one thread): on Liechtenstein (636 pages, 2 workers on a
# shared machine under load 6-7) the stage took 411 s with it against 97 s without, for 13.0 MB of KTX2
# pages against 39.0 MB of WebP.
BLOCK_KEY = 1 << 62  # style keys of blocks (gen.block ids) apart from osm.building ids

# A tile's features from tex.tile_features (the same meshes in the same triangle order as the exporter's; sql/tex/),
# rows by column name.
_FEATURES = "SELECT * FROM tex.tile_features(%s, %s, %s)"
_FEATURE_IDS = "SELECT feature_kind, building_id, osm_type, osm_id FROM tex.tile_features(%s, %s, %s)"  # no meshes


@dataclass(frozen=True)
class Tile:
    """A tile to texture, as tex.tiles_to_texture gives it (``features``: its features, as counted there)."""

    level: int
    x: int
    y: int
    gen_level: int
    geometric_error: float
    is_leaf: bool
    features: int


Key = tuple[int, int, int]
#: A unit of work: its tiles, the fingerprints of their last textures (in an update; else None) and this run's.
Unit = tuple[list[Tile], dict[Key, str] | None, dict[Key, str]]


@dataclass
class TileResult:
    """What a worker made of a tile: its tex.page, tex.feature_uv and tex.failure rows, counts and times."""

    tile: Tile
    rho: float
    distance: float
    padding: int
    pages: list[tuple] = field(default_factory=list)
    uvs: list[tuple] = field(default_factory=list)
    failures: list[tuple] = field(default_factory=list)
    features: int = 0
    ktx2_failed: int = 0  # features among ``failures`` textured, but on a page without KTX2
    stats: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    encode_seconds: float = 0.0
    fingerprint: str | None = None  # of everything read for the tile (tex.tile_input)
    kept: bool = False  # the tile's input had not changed: its rows in tex.* stay as they are
    redrawn: bool = False  # kept, but drawn again for its unit's chart cache (its unit's LOD2 tile changed)


def resolution(geometric_error: float, settings: Settings) -> tuple[float, float]:
    """(texels per metre, view distance m) of a tile: the thesis' rule at the nearest distance the tile is
    drawn from, capped by tex_max_texels_per_metre; the distance is where that resolution is exactly right."""
    fov = math.radians(settings.tex_fov_deg)
    cap = settings.tex_max_texels_per_metre
    rho = cap
    if geometric_error > 0:
        d = distance_for_pixels(geometric_error, settings.tex_max_sse, fov, settings.tex_screen_height)
        rho = min(cap, float(A.texels_per_metre(d, fov, settings.tex_screen_height, settings.tex_px_per_texel)))
    # where rho texels per metre are exactly rho * px_per_texel pixels per metre (a float for a float length)
    distance = float(distance_for_pixels(1.0, rho * settings.tex_px_per_texel, fov, settings.tex_screen_height))
    return rho, distance


def padding_for(rho: float, settings: Settings) -> int:
    """Gutter texels at rho texels/m: about half a metre of texels, at most tex_padding. A 2-texel gutter
    around charts a few texels wide would cost more texels than they hold (utilization below 60 % at 1 texel/m
    against 98 % without, on Liechtenstein); without gutters the charts' edge texels are centred on their
    edges (texturing._insets), so full-resolution sampling never reads a neighbour."""
    return max(0, min(settings.tex_padding, int(rho // 2)))


def units(tiles: list[Tile]) -> list[list[Tile]]:
    """Units of work: each LOD2-band tile with the leaves below it (leaves first, so they fill the chart cache
    it reads), every other tile alone. Deterministic order."""
    lod2: dict[Key, list[Tile]] = {(t.level, t.x, t.y): [] for t in tiles if t.gen_level == 3}
    alone: list[list[Tile]] = []
    for t in tiles:
        if t.gen_level == 4:
            for up in range(1, t.level + 1):
                key = (t.level - up, t.x >> up, t.y >> up)
                if key in lod2:
                    lod2[key].append(t)
                    break
            else:
                alone.append([t])
        elif t.gen_level != 3:
            alone.append([t])
    by_key = {(t.level, t.x, t.y): t for t in tiles}
    out = [leaves + [by_key[k]] for k, leaves in lod2.items()] + alone
    # biggest units first, so the last worker does not start a long one at the end
    return sorted(out, key=lambda u: -sum(t.features for t in u))


#: A row of tex.tile_features, by column name.
Feature = dict[str, Any]


def _style(r: Feature) -> X.Style:
    """The look of a feature from its tags; blocks keyed apart from buildings (BLOCK_KEY)."""
    bid = int(r["building_id"])
    key = BLOCK_KEY + bid if r["feature_kind"] == "block" else bid
    return X.Style.from_tags(
        key,
        r["building_material"],
        r["building_colour"],
        r["roof_material"],
        r["roof_colour"],
        r["levels"],
        generic_openings=r["gen_level"] <= 2,
    )


def _arrays(rows: list[Feature]) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[int]]:
    """(triangles, feature of each, semantics of each, triangles per feature) of the rows' meshes."""
    tris, sems, counts = [], [], []
    for r in rows:
        t = decode_triangles(r["mesh"])
        s = (
            np.full(len(t), X.SEM_UNKNOWN, np.uint8)
            if r["semantics"] is None
            else np.frombuffer(bytes(r["semantics"]), np.uint8)
        )
        if len(s) != len(t):
            raise ValueError(f"{len(s)} semantics bytes for {len(t)} triangles")
        tris.append(t)
        sems.append(s)
        counts.append(len(t))
    feat = np.repeat(np.arange(len(rows)), counts)
    return (
        np.concatenate(tris) if tris else np.zeros((0, 3, 3)),
        feat,
        np.concatenate(sems) if sems else np.zeros(0, np.uint8),
        counts,
    )


def _texture(
    rows: list[Feature], conn: psycopg.Connection, rho: float, params: X.Params, cache: X.ChartCache | None, store: bool
) -> tuple[X.TileTexture, list[int]]:
    """texturing.texture_tile of the rows, with the LOD3 openings of their LOD2 buildings the cache lacks; and
    the triangles per row."""
    tri, feat, sem, counts = _arrays(rows)
    styles = [_style(r) for r in rows]
    # LOD2 features whose leaves were not textured in this unit: their openings from the LOD3 meshes
    lod2 = [r["gen_level"] == 3 and r["feature_kind"] != "block" for r in rows]
    need = sorted(
        {
            int(r["building_id"])
            for r, s, is2 in zip(rows, styles, lod2, strict=True)
            if is2 and (cache is None or s.key not in cache.buildings)
        }
    )
    extra: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    if need:
        index = {int(r["building_id"]): i for i, (r, is2) in enumerate(zip(rows, lod2, strict=True)) if is2}
        ot, of, os_ = [], [], []
        for bid, s3, g3 in conn.execute(
            "SELECT building_id, semantics, mesh FROM tex.opening_meshes(%s)", (need,)
        ).fetchall():
            t3 = decode_triangles(g3)
            s = np.frombuffer(bytes(s3), np.uint8) if s3 is not None else np.zeros(0, np.uint8)
            if len(s) != len(t3):
                continue  # no usable semantics: the wall stays without openings
            keep = (s == SEM_WINDOW) | (s == SEM_DOOR)
            ot.append(t3[keep])
            of.append(np.full(int(keep.sum()), index[int(bid)]))
            os_.append(s[keep])
        if ot:
            extra = (np.concatenate(ot), np.concatenate(of), np.concatenate(os_))
    tt = X.texture_tile(tri, feat, sem, styles, rho, params, extra, cache, store)
    return tt, counts


def _failure(key: Key, row: Feature, reason: str, detail: str) -> tuple:
    """A tex.failure row (stage._FAIL_COLUMNS) of the feature ``row`` (of tex.tile_features)."""
    return (
        *key,
        row["feature_kind"],
        int(row["building_id"]),
        row["osm_type"],
        int(row["osm_id"]),
        reason,
        detail[:2000],
    )


def _features(conn: psycopg.Connection, tile: Tile, query: LiteralString) -> list[Feature]:
    """The rows of ``query`` (_FEATURES or _FEATURE_IDS) for ``tile``."""
    with conn.cursor(row_factory=dict_row) as cur:
        return cur.execute(query, (tile.level, tile.x, tile.y)).fetchall()


def _texture_isolating(
    rows: list[Feature],
    conn: psycopg.Connection,
    rho: float,
    params: X.Params,
    cache: X.ChartCache | None,
    store: bool,
    res: TileResult,
) -> tuple[X.TileTexture | None, list[int], list[int]]:
    """(texture, triangles per textured row, the rows textured) of the tile; when it fails, of the tile without
    the features that fail alone (_texture_without_failing)."""
    try:
        tt, counts = _texture(rows, conn, rho, params, cache, store)
    except Exception:  # noqa: BLE001 -- one broken building never stops the run: find it below
        return _texture_without_failing(rows, conn, rho, params, cache, store, res)
    return tt, counts, list(range(len(rows)))


def _texture_without_failing(
    rows: list[Feature],
    conn: psycopg.Connection,
    rho: float,
    params: X.Params,
    cache: X.ChartCache | None,
    store: bool,
    res: TileResult,
) -> tuple[X.TileTexture | None, list[int], list[int]]:
    """The tile textured again without the features that fail on their own (texturing is pure and per tile, so
    this is exact and rare), those listed in ``res.failures``; if even that fails, every feature is."""
    key = (res.tile.level, res.tile.x, res.tile.y)
    bad = []
    for i, r in enumerate(rows):
        try:
            _texture([r], conn, rho, params, None, False)
        except Exception as e:  # noqa: BLE001
            bad.append(i)
            res.failures.append(_failure(key, r, "texturing_failed", f"{type(e).__name__}: {e}"))
    good = sorted(set(range(len(rows))) - set(bad))
    try:
        tt, counts = _texture([rows[i] for i in good], conn, rho, params, cache, store)
    except Exception as e:  # noqa: BLE001
        detail = "".join(traceback.format_exception_only(type(e), e)).strip()
        res.failures += [_failure(key, rows[i], "tile_texturing_failed", detail) for i in good]
        return None, [], []
    return tt, counts, good


def _encode_pages(res: TileResult, tt: X.TileTexture, settings: Settings, jobs: int) -> dict[int, str]:
    """Every page as WebP and KTX2 into ``res.pages`` (tex.page rows); the pages the KTX2 encoder refused, with
    why (they stay WebP only)."""
    key = (res.tile.level, res.tile.x, res.tile.y)
    rects = [tt.page_rects(p) for p in range(tt.layout.n_pages)]
    util = tt.layout.utilization
    refused: dict[int, str] = {}
    # basisu's processes encode the KTX2 while this one writes the WebP (the bytes do not depend on ``jobs``)
    t1 = time.perf_counter()
    pending = K.start_many(
        list(tt.pages), settings.tex_ktx2_quality, settings.tex_ktx2_comp_level, settings.tex_ktx2_timeout_s, jobs
    )
    try:
        webp = [A.encode_image(img, FORMAT, settings.tex_quality, method=WEBP_METHOD) for img in tt.pages]
    except BaseException:
        pending.cancel()
        raise
    ktx2 = pending.result()
    res.encode_seconds += time.perf_counter() - t1
    for p, img in enumerate(tt.pages):
        data, mime = webp[p]
        got = ktx2[p]
        k2: bytes | None
        if isinstance(got, K.EncodeError):  # this page stays WebP only; its features get vertex colours in KTX2
            k2, refused[p] = None, str(got)
        else:
            k2 = got
        h, w = img.shape[:2]
        res.pages.append(
            (
                *key,
                p,
                FORMAT,
                mime,
                w,
                h,
                len(data),
                data,
                float(util[p]),
                res.rho,
                res.distance,
                len(rects[p]),
                int(tt.layout.scaled[tt.layout.page == p].sum()),
                res.padding,
                rects[p].astype("<i4").tobytes(),
                k2,
                len(k2) if k2 else None,
                max(w, h).bit_length() if k2 else None,
            )
        )
    return refused


def _add_uvs(
    res: TileResult, tt: X.TileTexture, rows: list[Feature], good: list[int], counts: list[int], refused: dict[int, str]
) -> None:
    """The tex.feature_uv row of every textured feature into ``res.uvs``; a feature on a page without KTX2 also
    into ``res.failures`` (ktx2_encode_failed)."""
    key = (res.tile.level, res.tile.x, res.tile.y)
    off = np.concatenate([[0], np.cumsum(counts)])
    refused_pages = np.array(sorted(refused), np.int64)
    for j, i in enumerate(good):
        r = rows[i]
        sl = slice(off[j], off[j + 1])
        res.uvs.append(
            (
                *key,
                r["feature_kind"],
                int(r["building_id"]),
                int(counts[j]),
                tt.tri_page[sl].astype("<i2").tobytes(),
                tt.tri_uv[sl].astype("<f4").tobytes(),
            )
        )
        hit = np.intersect1d(tt.tri_page[sl], refused_pages) if len(refused_pages) else refused_pages
        if len(hit):
            first = int(hit[0])
            res.failures.append(_failure(key, r, K.EncodeError.reason, f"page {first}: {refused[first]}"))
            res.ktx2_failed += 1


def _one_tile(
    tile: Tile,
    conn: psycopg.Connection,
    settings: Settings,
    cache: X.ChartCache | None,
    store: bool,
    rows: list[Feature] | None = None,
    encode: bool = True,
    jobs: int = 1,
) -> TileResult:
    """Texture ``tile``. ``encode`` False: only draw it, for the charts it adds to ``cache`` (its pages are
    kept from the last run, so neither encoded nor returned). ``jobs``: basisu processes for its pages (the
    cores this unit has to itself)."""
    t0 = time.perf_counter()
    rho, distance = resolution(tile.geometric_error, settings)
    pad = padding_for(rho, settings)
    res = TileResult(tile, rho, distance, pad)
    params = X.Params(
        page_size=settings.tex_page_size,
        padding=pad,
        packer=settings.tex_packer,
        min_chart_texels=settings.tex_min_chart_texels,
        xatlas_min_planes=settings.tex_xatlas_min_planes,
    )
    rows = _features(conn, tile, _FEATURES) if rows is None else rows
    res.features = len(rows)
    tt, counts, good = _texture_isolating(rows, conn, rho, params, cache, store, res)
    if tt is not None and encode:
        refused = _encode_pages(res, tt, settings, jobs)
        _add_uvs(res, tt, rows, good, counts, refused)
        res.stats = tt.stats
    res.seconds = time.perf_counter() - t0
    return res


def _kept_result(t: Tile, fingerprint: str, features: int, settings: Settings) -> TileResult:
    """A tile of a unit whose input did not change (``features``: as tex.input_digests counted them): its rows
    stay as the last run wrote them."""
    rho, distance = resolution(t.geometric_error, settings)
    return TileResult(
        t, rho, distance, padding_for(rho, settings), features=features, fingerprint=fingerprint, kept=True
    )


_WORKER: dict[str, Any] = {}


def _init_worker(url: str, settings: Settings, jobs: int = 1) -> None:
    """A worker's connection, settings and basisu processes per tile, for _do_unit."""
    _WORKER["conn"] = connect(url, autocommit=True)  # reads only: no transaction left open between tiles
    _WORKER["settings"] = settings
    _WORKER["jobs"] = jobs
    atexit.register(_WORKER["conn"].close)


def _do_unit(item: Unit) -> list[TileResult]:
    """Texture a unit in order (leaves first): a LOD2 tile and its leaves share one chart cache. In an update
    (the unit changed: run() keeps a unit whose fingerprints are all the last ones without sending it here) every
    tile is textured again but the leaves whose input is unchanged: those are only drawn, for the charts the
    unit's LOD2 tile reads, and their rows kept (encoding is most of a tile's time)."""
    unit, kept, prints = item
    conn, settings = _WORKER["conn"], _WORKER["settings"]
    shared = any(t.gen_level == 3 for t in unit)
    cache = X.ChartCache() if shared else None
    results = []
    for t in unit:
        f = prints[(t.level, t.x, t.y)]
        store = shared and t.gen_level == 4
        # a leaf as it was is drawn again for the charts the LOD2 tile reads from the cache, not encoded: its
        # pages are the kept ones (a leaf reads no chart of another leaf: a building is in one leaf)
        same = store and kept is not None and kept.get((t.level, t.x, t.y)) == f
        res = _one_tile(t, conn, settings, cache, store=store, encode=not same, jobs=_WORKER["jobs"])
        if same:
            res = replace(_kept_result(t, f, res.features, settings), seconds=res.seconds, redrawn=True)
        res.fingerprint = f
        results.append(res)
    return results


def _map_units(work: list[Unit], url: str, settings: Settings, workers: int) -> Iterator[list[TileResult] | Lost]:
    """Results of every unit, in order; a unit whose worker hung or died comes back as a Lost. Worker
    processes, not threads: most of the time is numpy on arrays of a few thousand elements and Python between
    them, which threads serialise on the GIL (2 threads were no faster than 1, measured); each process reads
    its tiles through its own connection. One per unit at a time (core/workers.py), so a building that hangs or
    crashes xatlas or OpenImageIO loses its unit's textures, never the run."""
    if workers <= 1:
        _init_worker(url, settings)
        try:
            yield from (_do_unit(u) for u in work)
        finally:
            _WORKER.pop("conn").close()
        return
    # fewer units than workers (an update of a few buildings): the cores no unit takes encode their pages
    jobs = max(1, workers // len(work))
    yield from imap_isolated(
        _do_unit, work, min(workers, len(work)), settings.tex_unit_timeout_s, _init_worker, (url, settings, jobs)
    )


def _lost(conn: psycopg.Connection, unit: list[Tile], lost: Lost, settings: Settings) -> list[TileResult]:
    """A lost unit's features, every one in tex.failure (they keep their vertex colours)."""
    out = []
    for t in unit:
        rho, distance = resolution(t.geometric_error, settings)
        res = TileResult(t, rho, distance, padding_for(rho, settings))
        rows = _features(conn, t, _FEATURE_IDS)
        res.features = len(rows)
        detail = f"the unit of tile {t.level}/{t.x}/{t.y}: {lost.detail}"
        res.failures = [_failure((t.level, t.x, t.y), r, f"texturing_{lost.reason}", detail) for r in rows]
        out.append(res)
    return out
