"""``python -m benchmarks.report_textures``: the textures stage's atlases measured on a textured database
(issue 6): utilization, pages and bytes per level, draw calls per tile, atlases against one texture per
building at a near and an overview camera, and xatlas' packer against the shelf packer on the real charts.

Everything is read from tex.page, tex.feature_uv, tex.failure and tiles.tile (the database is only read):

* **Per band and per quadtree level**: tiles, atlas pages, texture bytes (the encoded pages), utilization
  (chart texels / page texels over all pages, i.e. texel-weighted; also the mean and the worst page), texels
  per metre, and draw calls per tile. *Draw calls* are what the exporter writes (exporter/export.py
  ``build_tile_glb``): one glTF primitive (= one draw call) with one material per atlas page that some
  triangle of the tile uses, plus the vertex-coloured primitive when a feature of the tile has no UVs
  (tex.failure); a tile without texture rows is the single vertex-coloured primitive.
* **One texture per building** (the baseline): every textured feature of a tile (building, part or block:
  api.buildings_for_tile's rows) gets its own material and texture, so it is drawn with its own call(s); the
  vertex-coloured primitive stays as it is. Its texture holds the feature's own charts at the same resolution,
  taken from the atlas: the charts its triangles' UVs fall in (a chart = a content box of tex.page.rects) and,
  for its flat-coloured triangles (all three corners on one palette texel), a palette of just the texels they
  use. Those are laid out by the same packer with the tile's gutters and page size (atlas.layout; a feature
  needing more than one page costs one draw call per page), composed from the decoded atlas pages (gutters
  included, free texels the mean colour as the stage does) and **encoded for real** as WebP with the stage's
  quality and effort, one image per feature. Above ``--max-encode`` features in a view a seeded sample is
  encoded and the others are estimated from their page texels × the sample's bytes per page texel (the report
  says how many were encoded). The decoded atlas texels are already WebP-compressed once, which slightly
  favours the baseline.
* **Views**: the tiles api.lod_for_view selects (``cull_features => false``: a client loads and draws whole
  tiles; 60°, 1080 px, 16:9, max SSE 16) for benchmarks/view_bench.py's *near* camera (``street_camera``: 80 m
  up, 150 m south of the median building of the densest leaf tile, 20° down) and *overview* camera
  (``overview_camera``: straight down, the root region filling the view). Draw calls and texture bytes of
  those tiles, atlases against one texture per
  building. Target: at least 10× fewer draw calls at the overview.
* **Packers**: for the ``--packer-tiles`` tiles with the most charts (0 = every textured tile), the chart
  sizes the stage packed (tex.page.rects, in page order; charts the stage shrank to fit a page are taken at
  their shrunk size) laid out again by atlas.layout with ``packer='shelf'`` and ``packer='xatlas'`` with the
  tile's gutter and tex_page_size: pages, utilization (chart texels / cropped page texels) and the packer's
  own time (Layout.seconds). Every chart is checked to be placed once, unshrunk, inside its page and apart
  from the others.

Writes ``textures.md``, ``textures.json`` and ``textures.png`` into ``--out``. benchmarks/bench.py calls
``measure`` and ``section_lines`` for the Textures section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import psycopg

from benchmarks import view_bench as vb
from benchmarks.common import db_name, machine, machine_section, markdown_table, pass_mark
from core import cluster
from core.settings import REPO, Settings
from etl.textures import atlas as A
from etl.textures.stage import WEBP_METHOD

DEFAULT_OUT = Path("build/reports")
PACKER_TILES = 20
MAX_ENCODE = 5000
SEED = 6
UTIL_TARGET = 0.80
DRAW_TARGET = 10.0
PALETTE_WIDTH = 16  # texturing.Params.palette_width: the stage's palette rows

_TILES = """
SELECT level, x, y, gen_level, is_leaf, geometric_error, content_features FROM tiles.tile
WHERE content_features > 0 ORDER BY level, x, y
"""
_PAGES = """
SELECT level, x, y, page_no, width, height, n_bytes, utilization, texels_per_metre, view_distance_m, n_charts,
       n_scaled, padding, rects
FROM tex.page ORDER BY level, x, y, page_no
"""
_UV_PAGES = "SELECT level, x, y, page FROM tex.feature_uv"
_FAILED = "SELECT level, x, y, count(*) FROM tex.failure GROUP BY 1, 2, 3"
_TILE_PAGES = """
SELECT page_no, format, width, height, padding, rects, bytes FROM tex.page
WHERE level = %s AND x = %s AND y = %s ORDER BY page_no
"""
_TILE_UVS = """
SELECT feature_kind, feature_id, n_triangles, page, uv FROM tex.feature_uv
WHERE level = %s AND x = %s AND y = %s ORDER BY feature_kind, feature_id
"""


def log(msg: str) -> None:
    print(f"[report-textures {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def band_name(g: int) -> str:
    """The generalization band of a gen_level (the names of BENCHMARKS.md's generalize bands)."""
    names = {0: "blocks 10 m", 1: "blocks 5 m", 2: "LOD1", 3: "LOD2", 4: "LOD3, leaves"}
    return names.get(g, f"blocks {10 * 2**-g:g} m" if g < 0 else "?")


# --- per tile --------------------------------------------------------------------------------------------------


@dataclass
class TileStats:
    level: int
    x: int
    y: int
    gen_level: int
    is_leaf: bool
    geometric_error: float
    features: int  # api.buildings_for_tile rows (tiles.tile.content_features)
    textured: int = 0  # features with UVs (tex.feature_uv)
    failed: int = 0  # tex.failure rows
    page_dims: list[tuple[int, int]] = field(default_factory=list)
    page_bytes: list[int] = field(default_factory=list)
    page_util: list[float] = field(default_factory=list)
    used_pages: set[int] = field(default_factory=set)  # pages some triangle uses (the exporter drops the others)
    chart_sizes: list[np.ndarray] = field(default_factory=list)  # per page, (w, h) of its charts (tex.page.rects)
    padding: int = 0  # the gutter (tex.page.padding of its first page)
    charts: int = 0
    scaled: int = 0
    content_texels: int = 0
    texels_per_metre: float | None = None
    view_distance_m: float | None = None

    @property
    def key(self) -> tuple[int, int, int]:
        return self.level, self.x, self.y

    @property
    def pages(self) -> int:
        return len(self.page_dims)

    @property
    def page_texels(self) -> int:
        return sum(w * h for w, h in self.page_dims)

    @property
    def bytes(self) -> int:
        return sum(self.page_bytes)

    @property
    def used_bytes(self) -> int:
        return sum(self.page_bytes[p] for p in self.used_pages)

    @property
    def used_page_texels(self) -> int:
        return sum(self.page_dims[p][0] * self.page_dims[p][1] for p in self.used_pages)

    @property
    def plain(self) -> int:
        """1 when the tile has a vertex-coloured primitive: a feature without UVs, or no textures at all."""
        return int(self.features - self.textured > 0)

    @property
    def draw_calls(self) -> int:
        """glTF primitives of the exported tile: one per used atlas page, plus the vertex-coloured one."""
        return len(self.used_pages) + self.plain

    @property
    def per_building_draw_calls(self) -> int:
        """One texture per building, one page each (a lower bound: the views count the extra pages)."""
        return self.textured + self.plain

    def as_dict(self) -> dict[str, Any]:
        return {
            "level": self.level,
            "x": self.x,
            "y": self.y,
            "gen_level": self.gen_level,
            "features": self.features,
            "textured": self.textured,
            "failed": self.failed,
            "pages": self.pages,
            "used_pages": len(self.used_pages),
            "bytes": self.bytes,
            "page_texels": self.page_texels,
            "content_texels": self.content_texels,
            "charts": self.charts,
            "utilization": round(self.content_texels / self.page_texels, 4) if self.page_texels else None,
            "texels_per_metre": self.texels_per_metre,
            "draw_calls": self.draw_calls,
            "per_building_draw_calls": self.per_building_draw_calls,
        }


def read_tiles(conn: psycopg.Connection) -> dict[tuple[int, int, int], TileStats]:
    tiles = {
        (int(r[0]), int(r[1]), int(r[2])): TileStats(
            int(r[0]), int(r[1]), int(r[2]), int(r[3]), bool(r[4]), float(r[5] or 0.0), int(r[6])
        )
        for r in conn.execute(_TILES).fetchall()
    }
    if not tiles:
        raise SystemExit("tiles.tile has no content: run the tiles and generalize stages first")
    for level, x, y, _p, w, h, nb, util, rho, dist, n, scaled, pad, rects in conn.execute(_PAGES):
        t = tiles[(level, x, y)]
        if not t.page_dims:
            t.padding = int(pad)
        t.page_dims.append((int(w), int(h)))
        t.page_bytes.append(int(nb))
        t.page_util.append(float(util))
        r = np.frombuffer(bytes(rects), "<i4").reshape(-1, 4)
        t.content_texels += int((r[:, 2].astype(np.int64) * r[:, 3]).sum())
        t.chart_sizes.append(r[:, 2:])
        t.charts += int(n)
        t.scaled += int(scaled)
        t.texels_per_metre, t.view_distance_m = float(rho), float(dist)
    with conn.cursor() as cur:
        cur.execute(_UV_PAGES)
        for level, x, y, page in cur:
            t = tiles[(level, x, y)]
            t.textured += 1
            t.used_pages.update(np.unique(np.frombuffer(bytes(page), "<i2")).tolist())
    for level, x, y, n in conn.execute(_FAILED):
        tiles[(level, x, y)].failed = int(n)
    if not any(t.pages for t in tiles.values()):
        raise SystemExit("tex.page is empty: run the textures stage first (make textures)")
    return tiles


def summarize(tiles: Iterable[TileStats]) -> dict[str, Any]:
    """Pages, bytes, utilization and draw calls of a group of tiles (all of them, or those with pages)."""
    ts = list(tiles)
    tex = [t for t in ts if t.pages]
    utils = [u for t in tex for u in t.page_util]
    page_texels = sum(t.page_texels for t in tex)
    content = sum(t.content_texels for t in tex)
    rho = [t.texels_per_metre for t in tex if t.texels_per_metre is not None]
    dist = [t.view_distance_m for t in tex if t.view_distance_m is not None]
    dc = [t.draw_calls for t in ts]
    return {
        "tiles": len(ts),
        "textured_tiles": len(tex),
        "features": sum(t.features for t in ts),
        "textured_features": sum(t.textured for t in ts),
        "failed_features": sum(t.failed for t in ts),
        "pages": sum(t.pages for t in tex),
        "bytes": sum(t.bytes for t in tex),
        "page_texels": page_texels,
        "content_texels": content,
        "charts": sum(t.charts for t in tex),
        "scaled": sum(t.scaled for t in tex),
        "utilization": round(content / page_texels, 4) if page_texels else None,
        "mean_page_utilization": round(float(np.mean(utils)), 4) if utils else None,
        "min_page_utilization": round(float(np.min(utils)), 4) if utils else None,
        "texels_per_metre": [round(min(rho), 3), round(max(rho), 3)] if rho else None,
        "view_distance_m": [round(min(dist), 1), round(max(dist), 1)] if dist else None,
        "pages_per_tile": round(sum(t.pages for t in tex) / len(tex), 2) if tex else 0.0,
        "bytes_per_tile": round(sum(t.bytes for t in tex) / len(tex)) if tex else 0,
        "draw_calls": sum(dc),
        "draw_calls_per_tile": round(float(np.mean(dc)), 2) if dc else 0.0,
        "max_draw_calls_per_tile": max(dc, default=0),
        "per_building_draw_calls_per_tile": round(float(np.mean([t.per_building_draw_calls for t in ts])), 1)
        if ts
        else 0.0,
    }


def grouped(tiles: dict[tuple[int, int, int], TileStats], by: str) -> list[dict[str, Any]]:
    groups: dict[int, list[TileStats]] = {}
    for t in tiles.values():
        groups.setdefault(getattr(t, by), []).append(t)
    out = []
    for g, ts in sorted(groups.items()):
        row = {by: g, **summarize(ts)}
        if by == "gen_level":
            row["band"] = band_name(g)
        else:
            row["bands"] = sorted({t.gen_level for t in ts})
        out.append(row)
    return out


# --- one texture per building ------------------------------------------------------------------------------------


@dataclass
class FeatureTexture:
    """A feature's own texture in the baseline: its charts (and palette texels) laid out alone."""

    kind: str
    fid: int
    charts: np.ndarray  # global chart ids of the tile (into TileCharts.rects)
    palette: np.ndarray  # (k, 3) int64 (page, tx, ty) palette texels its flat triangles use
    sizes: np.ndarray  # (c, 2) the chart sizes laid out (palette last when there is one)
    layout: A.Layout
    bytes: int | None = None  # encoded (None: not encoded)

    @property
    def content_texels(self) -> int:
        return int((self.sizes[:, 0] * self.sizes[:, 1]).sum())

    @property
    def page_texels(self) -> int:
        return int((self.layout.page_dims[:, 0] * self.layout.page_dims[:, 1]).sum())


class TileCharts:
    """The charts of one textured tile, which of them each feature uses, and each feature's own texture."""

    def __init__(self, conn: psycopg.Connection, key: tuple[int, int, int], page_size: int):
        self.key = key
        self.page_size = page_size
        pages = conn.execute(_TILE_PAGES, key).fetchall()
        self.formats = [str(p[1]) for p in pages]
        self.dims = np.array([(p[2], p[3]) for p in pages], np.int64).reshape(-1, 2)
        self.padding = int(pages[0][4]) if pages else 0
        self.data = [bytes(p[6]) for p in pages]
        rects = [np.frombuffer(bytes(p[5]), "<i4").reshape(-1, 4).astype(np.int64) for p in pages]
        self.rects = np.concatenate(rects) if rects else np.zeros((0, 4), np.int64)  # x, y, w, h
        self.rect_page = np.repeat(np.arange(len(rects)), [len(r) for r in rects])
        # per page: the global chart id of every content texel, -1 elsewhere
        self.labels = []
        base = 0
        for (w, h), r in zip(self.dims.tolist(), rects, strict=True):
            lab = np.full((h, w), -1, np.int32)
            for i, (x, y, cw, ch) in enumerate(r.tolist()):
                lab[y : y + ch, x : x + cw] = base + i
            self.labels.append(lab)
            base += len(r)
        self.unassigned = 0  # triangles found in no chart (0 unless the UVs and rects disagree)
        self.features: list[FeatureTexture] = []
        for kind, fid, n, page, uv in conn.execute(_TILE_UVS, key).fetchall():
            pg = np.frombuffer(bytes(page), "<i2").astype(np.int64)
            corner = np.frombuffer(bytes(uv), "<f4").reshape(int(n), 3, 2).astype(np.float64)
            self.features.append(self._feature(str(kind), int(fid), pg, corner))
        self._pixels: list[np.ndarray] | None = None

    def _lookup(self, page: np.ndarray, px: np.ndarray) -> np.ndarray:
        """Chart id at texel coordinates px (n, 2) on ``page`` (n,), -1 where there is none."""
        out = np.full(len(page), -1, np.int64)
        for p in np.unique(page).tolist():
            on = page == p
            w, h = self.dims[p]
            ix = np.clip(np.floor(px[on, 0]).astype(np.int64), 0, w - 1)
            iy = np.clip(np.floor(px[on, 1]).astype(np.int64), 0, h - 1)
            out[on] = self.labels[p][iy, ix]
        return out

    def _feature(self, kind: str, fid: int, page: np.ndarray, corner: np.ndarray) -> FeatureTexture:
        dims = self.dims[page].astype(np.float64)  # (m, 2)
        px = corner * dims[:, None, :]
        flat = np.all(corner[:, 1] == corner[:, 0], axis=1) & np.all(corner[:, 2] == corner[:, 0], axis=1)
        # a triangle's chart: the one under its UV centroid (half a texel back for one on a right/bottom edge)
        c = px[~flat].mean(axis=1)
        pg = page[~flat]
        chart = self._lookup(pg, c)
        for d in ((-0.5, 0.0), (0.0, -0.5), (-0.5, -0.5)):
            miss = chart < 0
            if not miss.any():
                break
            chart[miss] = self._lookup(pg[miss], c[miss] + np.array(d))
        self.unassigned += int((chart < 0).sum())
        charts = np.unique(chart[chart >= 0])
        # flat triangles: the palette texel their corners sit on, unless it is inside a chart taken whole
        tex = np.floor(px[flat, 0]).astype(np.int64)
        fp = page[flat]
        in_chart = np.isin(self._lookup(fp, tex + 0.5), charts)
        palette = np.unique(np.column_stack([fp[~in_chart], tex[~in_chart]]), axis=0).reshape(-1, 3)
        sizes = self.rects[charts, 2:].reshape(-1, 2)
        if len(palette):
            pw = min(len(palette), PALETTE_WIDTH)
            sizes = np.vstack([sizes, [[pw, -(-len(palette) // pw)]]])
        lay = A.layout(sizes, self.page_size, "shelf", self.padding)
        return FeatureTexture(kind, fid, charts, palette, sizes, lay)

    def pixels(self) -> list[np.ndarray]:
        if self._pixels is None:
            self._pixels = [A.decode_image(d, f)[:, :, :3] for d, f in zip(self.data, self.formats, strict=True)]
        return self._pixels

    def encode(self, f: FeatureTexture, quality: int, method: int = WEBP_METHOD) -> int:
        """Compose the feature's own pages from the atlas (charts with their gutters, the palette texels with
        edge gutters, the mean colour elsewhere), encode each as WebP; total bytes (also stored in f.bytes)."""
        src = self.pixels()
        lay, pad = f.layout, self.padding
        pages = [np.zeros((int(h), int(w), 3), np.uint8) for w, h in lay.page_dims]
        used = [np.zeros((int(h), int(w)), bool) for w, h in lay.page_dims]
        for i, c in enumerate(f.charts.tolist()):
            x, y, w, h = self.rects[c].tolist()
            img = src[int(self.rect_page[c])][y - pad : y + h + pad, x - pad : x + w + pad]
            x0, y0 = int(lay.x[i]) - pad, int(lay.y[i]) - pad
            pages[lay.page[i]][y0 : y0 + h + 2 * pad, x0 : x0 + w + 2 * pad] = img
            used[lay.page[i]][y0 : y0 + h + 2 * pad, x0 : x0 + w + 2 * pad] = True
        if len(f.palette):
            i = len(f.charts)
            w, h = (int(v) for v in f.sizes[i])
            cols = np.array([src[p][ty, tx] for p, tx, ty in f.palette.tolist()], np.uint8)
            img = cols[np.minimum(np.arange(w * h), len(cols) - 1)].reshape(h, w, 3)
            img = np.pad(img, ((pad, pad), (pad, pad), (0, 0)), mode="edge")
            x0, y0 = int(lay.x[i]) - pad, int(lay.y[i]) - pad
            pages[lay.page[i]][y0 : y0 + h + 2 * pad, x0 : x0 + w + 2 * pad] = img
            used[lay.page[i]][y0 : y0 + h + 2 * pad, x0 : x0 + w + 2 * pad] = True
        n = 0
        for pg, u in zip(pages, used, strict=True):
            if not u.all():
                pg[~u] = np.round(pg[u].reshape(-1, 3).mean(axis=0)).astype(np.uint8)
            n += len(A.encode_image(pg, "webp", quality, method=method)[0])
        f.bytes = n
        return n


# --- views -------------------------------------------------------------------------------------------------------


def view_tiles(conn: psycopg.Connection, cam: Any, max_sse: float) -> list[tuple[int, int, int]]:
    rows = conn.execute(
        f"SELECT DISTINCT level, x, y FROM ({vb._VIEW_TILES}) q ORDER BY 1, 2, 3", vb._params(cam, max_sse)
    ).fetchall()
    return [(int(r[0]), int(r[1]), int(r[2])) for r in rows]


def measure_view(
    conn: psycopg.Connection,
    name: str,
    cam: Any,
    tiles: dict[tuple[int, int, int], TileStats],
    charts: dict[tuple[int, int, int], TileCharts],
    settings: Settings,
    max_encode: int,
    seed: int,
    max_sse: float,
) -> dict[str, Any]:
    """Draw calls and texture bytes of the tiles a camera loads: atlases against one texture per building."""
    t0 = time.perf_counter()
    keys = [k for k in view_tiles(conn, cam, max_sse) if k in tiles]
    for k in keys:
        if k not in charts and tiles[k].pages:
            charts[k] = TileCharts(conn, k, settings.tex_page_size)
    feats = [(k, f) for k in keys if k in charts for f in charts[k].features]
    todo = [i for i, (_, f) in enumerate(feats) if f.bytes is None]
    if len(todo) > max_encode:
        todo = sorted(random.Random(f"{seed}:{name}").sample(todo, max_encode))
    for i in todo:
        k, f = feats[i]
        charts[k].encode(f, settings.tex_quality)
    done = [f for _, f in feats if f.bytes is not None]
    enc_bytes = sum(f.bytes or 0 for f in done)
    enc_texels = sum(f.page_texels for f in done)
    per_texel = enc_bytes / enc_texels if enc_texels else 0.0
    pb_bytes = sum(f.bytes if f.bytes is not None else f.page_texels * per_texel for _, f in feats)
    ts = [tiles[k] for k in keys]
    pb_texels = sum(f.page_texels for _, f in feats)
    pb_content = sum(f.content_texels for _, f in feats)
    atlas_dc = sum(t.draw_calls for t in ts)
    pb_dc = sum(f.layout.n_pages for _, f in feats) + sum(t.plain for t in ts)
    atlas_bytes = sum(t.used_bytes for t in ts)
    return {
        "camera": vb._cam_dict(cam),
        "tiles": len(keys),
        "bands": sorted({t.gen_level for t in ts}),
        "features": sum(t.features for t in ts),
        "textured_features": len(feats),
        "atlas": {
            "draw_calls": atlas_dc,
            "pages": sum(len(t.used_pages) for t in ts),
            "bytes": atlas_bytes,
            "page_texels": sum(t.used_page_texels for t in ts),
        },
        "per_building": {
            "draw_calls": pb_dc,
            "textures": sum(f.layout.n_pages for _, f in feats),
            "bytes": round(pb_bytes),
            "page_texels": pb_texels,
            "content_texels": pb_content,
            "utilization": round(pb_content / pb_texels, 4) if pb_texels else None,
            "encoded": len(done),
            "estimated": len(feats) - len(done),
            "bytes_per_page_texel": round(per_texel, 4),
        },
        "draw_call_ratio": round(pb_dc / atlas_dc, 2) if atlas_dc else None,
        "bytes_ratio": round(pb_bytes / atlas_bytes, 3) if atlas_bytes else None,
        "unassigned_triangles": sum(charts[k].unassigned for k in keys if k in charts),
        "seconds": round(time.perf_counter() - t0, 2),
    }


# --- packers -------------------------------------------------------------------------------------------------------


def _check_layout(lay: A.Layout, sizes: np.ndarray, page_size: int) -> bool:
    """Every chart placed once, unshrunk, inside its page, and no two slots (gutters included) overlapping."""
    if len(lay.page) != len(sizes) or lay.scaled.any() or not np.array_equal(np.column_stack([lay.w, lay.h]), sizes):
        return False
    p = lay.padding
    x0, y0, x1, y1 = lay.x - p, lay.y - p, lay.x + lay.w + p, lay.y + lay.h + p
    dims = lay.page_dims[lay.page]
    if (
        (x0 < 0).any()
        or (y0 < 0).any()
        or (x1 > dims[:, 0]).any()
        or (y1 > dims[:, 1]).any()
        or (lay.page_dims > page_size).any()
    ):
        return False
    for pg in range(lay.n_pages):
        cover = np.zeros((int(lay.page_dims[pg, 1]), int(lay.page_dims[pg, 0])), np.int32)
        for a, b, c, d in zip(*(v[lay.page == pg].tolist() for v in (x0, y0, x1, y1)), strict=True):
            cover[b:d, a:c] += 1
        if cover.max(initial=0) > 1:
            return False
    return True


def compare_packers(
    tiles: dict[tuple[int, int, int], TileStats],
    page_size: int,
    n_tiles: int = PACKER_TILES,
    stage_packer: str = "shelf",
) -> dict[str, Any]:
    """Shelf against xatlas on the chart sizes of the tiles with the most charts (n_tiles = 0: every tile)."""
    chosen = sorted((t for t in tiles.values() if t.pages), key=lambda t: (-t.charts, t.key))
    if n_tiles > 0:
        chosen = chosen[:n_tiles]
    rows = []
    totals = {p: {"pages": 0, "page_texels": 0, "content_texels": 0, "seconds": 0.0, "ok": True} for p in A.PACKERS}
    for t in chosen:
        sizes = np.concatenate(t.chart_sizes).astype(np.int64)
        pad = t.padding
        row: dict[str, Any] = {
            "level": t.level,
            "x": t.x,
            "y": t.y,
            "gen_level": t.gen_level,
            "charts": len(sizes),
            "padding": pad,
            "stored": {"pages": t.pages, "utilization": round(t.content_texels / t.page_texels, 4)},
        }
        for packer in A.PACKERS:
            lay = A.layout(sizes, page_size, packer, pad, pot=True)  # the stage's pages: powers of two a side
            area = int((lay.page_dims[:, 0] * lay.page_dims[:, 1]).sum())
            ok = _check_layout(lay, sizes, page_size)
            row[packer] = {
                "pages": lay.n_pages,
                "page_texels": area,
                "utilization": round(lay.total_utilization, 4),
                "min_page_utilization": round(float(lay.utilization.min()), 4),
                "seconds": round(lay.seconds, 4),
                "placed_ok": ok,
            }
            tot = totals[packer]
            tot["pages"] += lay.n_pages
            tot["page_texels"] += area
            tot["content_texels"] += int((sizes[:, 0] * sizes[:, 1]).sum())
            tot["seconds"] += lay.seconds
            tot["ok"] = tot["ok"] and ok
        rows.append(row)
    by_band = []
    for g in sorted({r["gen_level"] for r in rows}):
        rs = [r for r in rows if r["gen_level"] == g]
        band: dict[str, Any] = {
            "gen_level": g,
            "band": band_name(g),
            "tiles": len(rs),
            "charts": sum(r["charts"] for r in rs),
        }
        for packer in A.PACKERS:
            content = sum(r[packer]["utilization"] * r[packer]["page_texels"] for r in rs)
            area = sum(r[packer]["page_texels"] for r in rs)
            band[packer] = {
                "pages": sum(r[packer]["pages"] for r in rs),
                "utilization": round(content / area, 4) if area else None,
                "seconds": round(sum(r[packer]["seconds"] for r in rs), 3),
            }
        by_band.append(band)
    for tot in totals.values():
        tot["utilization"] = round(tot["content_texels"] / tot["page_texels"], 4) if tot["page_texels"] else None
        tot["seconds"] = round(tot["seconds"], 3)
    return {
        "tiles": len(chosen),
        "of_tiles": sum(1 for t in tiles.values() if t.pages),
        "charts": sum(r["charts"] for r in rows),
        "page_size": page_size,
        "totals": totals,
        "xatlas_better": sum(r["xatlas"]["utilization"] > r["shelf"]["utilization"] for r in rows),
        # the stage's own packer on these sizes gives its pages back: they are the sizes it packed
        "stage_packer": stage_packer,
        "stage_reproduced": all(
            r[stage_packer]["pages"] == r["stored"]["pages"]
            and abs(r[stage_packer]["utilization"] - r["stored"]["utilization"]) < 1e-3
            for r in rows
        ),
        "by_band": by_band,
        "rows": rows,
    }


# --- the measurement -------------------------------------------------------------------------------------------


def measure(
    url: str,
    packer_tiles: int = PACKER_TILES,
    max_encode: int = MAX_ENCODE,
    seed: int = SEED,
    settings: Settings | None = None,
) -> dict[str, Any]:
    """Every figure of the report (no files): the dict textures.json holds, minus machine and command."""
    settings = settings or Settings.from_env()
    t0 = time.perf_counter()
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("SET default_transaction_read_only = on")
        tiles = read_tiles(conn)
        total = summarize(tiles.values())
        log(
            f"{total['textured_tiles']} textured tiles of {total['tiles']}, {total['pages']} pages, "
            f"{total['bytes'] / 1e6:.1f} MB, utilization {100 * (total['utilization'] or 0):.1f} %"
        )
        charts: dict[tuple[int, int, int], TileCharts] = {}
        views = {}
        for name, cam in (("near", vb.street_camera(conn)), ("overview", vb.overview_camera(conn))):
            views[name] = measure_view(conn, name, cam, tiles, charts, settings, max_encode, seed, vb.MAX_SSE)
            v = views[name]
            log(
                f"{name}: {v['tiles']} tiles, {v['textured_features']} textured features: draw calls "
                f"{v['atlas']['draw_calls']} vs {v['per_building']['draw_calls']} ({v['draw_call_ratio']}x), "
                f"bytes {v['atlas']['bytes']:,} vs {v['per_building']['bytes']:,} ({v['seconds']} s)"
            )
        t1 = time.perf_counter()
        packers = compare_packers(tiles, settings.tex_page_size, packer_tiles, settings.tex_packer)
        pt = packers["totals"]
        log(
            f"packers on {packers['tiles']} tiles ({packers['charts']:,} charts): shelf "
            f"{100 * (pt['shelf']['utilization'] or 0):.1f} % in {pt['shelf']['seconds']} s, xatlas "
            f"{100 * (pt['xatlas']['utilization'] or 0):.1f} % in {pt['xatlas']['seconds']} s "
            f"({time.perf_counter() - t1:.1f} s)"
        )
    over = views["overview"]
    return {
        "database": db_name(url),
        "settings": {
            "page_size": settings.tex_page_size,
            "max_texels_per_metre": settings.tex_max_texels_per_metre,
            "padding_max": settings.tex_padding,
            "quality": settings.tex_quality,
            "webp_method": WEBP_METHOD,
            "packer": settings.tex_packer,
            "max_sse": vb.MAX_SSE,
        },
        "parameters": {"packer_tiles": packer_tiles, "max_encode": max_encode, "seed": seed},
        "totals": total,
        "utilization_target": UTIL_TARGET,
        "utilization_pass": (total["utilization"] or 0) >= UTIL_TARGET,
        "bands": grouped(tiles, "gen_level"),
        "levels": grouped(tiles, "level"),
        "views": views,
        "draw_call_target": DRAW_TARGET,
        "draw_call_pass": (over["draw_call_ratio"] or 0) >= DRAW_TARGET,
        "packers": packers,
        "tiles": [t.as_dict() for t in sorted(tiles.values(), key=lambda t: t.key)],
        "seconds": round(time.perf_counter() - t0, 1),
    }


# --- markdown ----------------------------------------------------------------------------------------------------


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.1f} %"


def _mb(n: float) -> str:
    return f"{n / 1e6:.2f}" if n >= 1e5 else f"{n / 1e6:.3f}"


def _rho(r: list[float] | None) -> str:
    if not r:
        return "–"
    return f"{r[0]:.2f}" if r[0] == r[1] else f"{r[0]:.2f}–{r[1]:.2f}"


def _group_rows(groups: list[dict[str, Any]], by: str) -> list[list[object]]:
    rows = []
    for g in groups:
        label = (
            f"{g['gen_level']} ({g['band']})"
            if by == "gen_level"
            else f"{g['level']} (bands {', '.join(str(b) for b in g['bands'])})"
        )
        rows.append(
            [
                label,
                f"{g['textured_tiles']}/{g['tiles']}",
                f"{g['pages']:,}",
                _mb(g["bytes"]),
                _pct(g["utilization"]),
                _pct(g["mean_page_utilization"]),
                _pct(g["min_page_utilization"]),
                _rho(g["texels_per_metre"]),
                f"{g['pages_per_tile']:.1f}",
                f"{g['draw_calls_per_tile']:.1f} (max {g['max_draw_calls_per_tile']})",
                f"{g['per_building_draw_calls_per_tile']:,.0f}",
            ]
        )
    return rows


GROUP_HEADER = [
    "",
    "textured tiles",
    "pages",
    "MB",
    "utilization",
    "mean page",
    "worst page",
    "texels/m",
    "pages/tile",
    "draw calls/tile",
    "one texture per building: draw calls/tile",
]


def section_lines(r: dict[str, Any], h: str = "##") -> list[str]:
    """The report's tables as markdown (``h`` the heading level of its sections): BENCHMARKS.md's Textures
    section is these lines for the benchmark extract."""
    t = r["totals"]
    v = r["views"]
    pk = r["packers"]
    lines = [
        f"{h} Atlases per band",
        "",
        f"{t['textured_tiles']} of {t['tiles']} tiles textured, {t['textured_features']:,} features "
        f"({t['failed_features']:,} failed), {t['pages']:,} pages of at most {r['settings']['page_size']} texels, "
        f"{t['bytes'] / 1e6:.1f} MB of WebP; utilization {_pct(t['utilization'])} of the page texels hold chart "
        f"texels (target ≥ {100 * r['utilization_target']:.0f} %: {pass_mark(r['utilization_pass'])}). "
        "*utilization*: chart texels / page texels over the group's pages (texel-weighted); *mean page*, "
        "*worst page*: of the pages' own utilizations. *draw calls/tile*: glTF primitives the exporter writes "
        "(one per atlas page used, plus the vertex-coloured one where a feature has no UVs); one texture per "
        "building: the tile's textured features + that primitive.",
        "",
        *markdown_table(["band (gen_level)", *GROUP_HEADER[1:]], _group_rows(r["bands"], "gen_level"), "lrrrrrrrrrr"),
        "",
        f"{h} Atlases per quadtree level",
        "",
        *markdown_table(["level", *GROUP_HEADER[1:]], _group_rows(r["levels"], "level"), "lrrrrrrrrrr"),
        "",
        f"{h} Atlases against one texture per building",
        "",
        "Draw calls and texture bytes of the tiles a client loads for a camera (api.lod_for_view, "
        "`cull_features => false`, 60°, 1080 px, 16:9, max SSE "
        f"{r['settings']['max_sse']:g}). *One texture per building*: each textured feature's own charts, at the "
        "same resolution and gutters, packed alone and encoded as its own WebP (for real, from the decoded atlas "
        "texels; *encoded* says how many), each its own material and draw call (one per page), plus the "
        "vertex-coloured primitive where there is one.",
        "",
    ]
    rows = []
    for name, label in (("near", "near (street camera)"), ("overview", "overview")):
        x = v[name]
        a, b = x["atlas"], x["per_building"]
        rows.append(
            [
                f"{label}: {x['camera']['height']:,.0f} m, pitch {x['camera']['pitch']:.0f}°",
                f"{x['tiles']} (bands {', '.join(str(g) for g in x['bands'])})",
                f"{x['textured_features']:,}",
                f"{a['draw_calls']:,}",
                f"{b['draw_calls']:,}",
                f"**{x['draw_call_ratio']}×**",
                _mb(a["bytes"]),
                _mb(b["bytes"]),
                f"{x['bytes_ratio']}×",
                f"{a['page_texels'] / 1e6:.2f} / {b['page_texels'] / 1e6:.2f} ({_pct(b['utilization'])})",
                f"{b['encoded']:,} of {x['textured_features']:,}",
            ]
        )
    over = v["overview"]
    lines += [
        *markdown_table(
            [
                "camera",
                "tiles",
                "textured features",
                "draw calls: atlases",
                "one texture per building",
                "fewer",
                "MB: atlases",
                "one per building",
                "more",
                "M page texels: atlases / per building (its utilization)",
                "encoded",
            ],
            rows,
            "lrrrrrrrrrr",
        ),
        "",
        f"Overview: {over['draw_call_ratio']}× fewer draw calls with atlases (target ≥ "
        f"{r['draw_call_target']:g}×: {pass_mark(r['draw_call_pass'])}).",
        "",
        f"{h} Shelf packer against xatlas on real tiles",
        "",
        f"The chart sizes the stage packed (tex.page.rects) of the {pk['tiles']} tiles with the most charts "
        f"(of {pk['of_tiles']} textured; {pk['charts']:,} charts), laid out again by atlas.layout with each "
        f"packer, the tile's gutter and {pk['page_size']}-texel pages; time = the packer alone. Every chart "
        "placed once, unshrunk, inside its page, no slots overlapping: "
        f"shelf {'yes' if pk['totals']['shelf']['ok'] else '**no**'}, xatlas "
        f"{'yes' if pk['totals']['xatlas']['ok'] else '**no**'}. The stage's packer ({pk['stage_packer']}) "
        f"gives the stored pages back: {'yes' if pk['stage_reproduced'] else '**no**'}.",
        "",
    ]
    prow = []
    for p in A.PACKERS:
        tt = pk["totals"][p]
        prow.append(
            [
                p,
                f"{tt['pages']:,}",
                _pct(tt["utilization"]),
                f"{tt['seconds']:.2f}",
                f"{1e3 * tt['seconds'] / max(pk['charts'], 1):.3f}",
            ]
        )
    lines += [
        *markdown_table(["packer", "pages", "utilization", "seconds", "ms/chart"], prow, "lrrrr"),
        "",
        f"xatlas reaches a higher utilization on {pk['xatlas_better']} of {pk['tiles']} tiles. By band:",
        "",
    ]
    brow = [
        [
            f"{b['gen_level']} ({b['band']})",
            str(b["tiles"]),
            f"{b['charts']:,}",
            f"{b['shelf']['pages']} / {b['xatlas']['pages']}",
            f"{_pct(b['shelf']['utilization'])} / {_pct(b['xatlas']['utilization'])}",
            f"{b['shelf']['seconds']:.2f} / {b['xatlas']['seconds']:.2f}",
        ]
        for b in pk["by_band"]
    ]
    lines += [
        *markdown_table(
            ["band", "tiles", "charts", "pages shelf / xatlas", "utilization shelf / xatlas", "seconds shelf / xatlas"],
            brow,
            "lrrrrr",
        ),
        "",
    ]
    rows = [
        [
            f"{x['level']}/{x['x']}/{x['y']} (band {x['gen_level']})",
            f"{x['charts']:,}",
            str(x["padding"]),
            f"{x['shelf']['pages']} / {x['xatlas']['pages']}",
            f"{_pct(x['shelf']['utilization'])} / {_pct(x['xatlas']['utilization'])}",
            f"{x['shelf']['seconds']:.3f} / {x['xatlas']['seconds']:.3f}",
        ]
        for x in pk["rows"][:10]
    ]
    lines += [
        f"The {min(10, len(pk['rows']))} tiles with the most charts:",
        "",
        *markdown_table(
            [
                "tile",
                "charts",
                "gutter",
                "pages shelf / xatlas",
                "utilization shelf / xatlas",
                "seconds shelf / xatlas",
            ],
            rows,
            "lrrrrr",
        ),
    ]
    return lines


def render_markdown(report: dict[str, Any]) -> str:
    lines = [
        "# Texture atlases",
        "",
        f"Generated by `{report['command']}` on `{report['database']}` in "
        f"{report['seconds']:.0f} s; the database is only read. benchmarks/report_textures.py explains every "
        "figure.",
        "",
    ]
    lines += section_lines(report)
    lines += [
        "",
        "## How the baseline's bytes were computed",
        "",
        "Each textured feature's texture is built for real: the charts its triangles' UVs fall in (tex.page."
        "rects) and a small palette of the flat-colour texels it uses are laid out alone by the shelf packer "
        "(the tile's gutter, page size), filled from the decoded atlas pages and encoded with the stage's "
        f"WebP settings (quality {report['settings']['quality']}, method {report['settings']['webp_method']}). "
        f"Above {report['parameters']['max_encode']:,} features per view a seeded sample is encoded and the "
        "rest estimated at the sample's bytes per page texel. Re-encoding already WebP-decoded texels "
        "compresses a little better than fresh ones would, so the baseline's bytes are if anything low.",
        "",
    ]
    lines += machine_section(report["machine"])
    lines += ["", "![utilization per band, draw calls and bytes per view, shelf vs xatlas](textures.png)", ""]
    return "\n".join(lines)


# --- plot ---------------------------------------------------------------------------------------------------------


def plot(report: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(14, 9.5), layout="constrained")
    bands = [b for b in report["bands"] if b["pages"]]
    xs = np.arange(len(bands))
    a = ax[0, 0]
    a.bar(xs, [100 * b["utilization"] for b in bands], color="tab:blue", label="texel-weighted")
    a.plot(xs, [100 * b["min_page_utilization"] for b in bands], "v", color="tab:red", label="worst page")
    a.axhline(100 * report["utilization_target"], color="grey", ls="--", lw=1, label="target")
    for i, b in enumerate(bands):
        a.annotate(f"{b['pages']} p\n{_mb(b['bytes'])} MB", (i, 2), ha="center", fontsize=8, color="white")
    a.set(
        xticks=xs,
        xticklabels=[f"{b['gen_level']}\n{b['band'].replace(' ', chr(10), 1)}" for b in bands],
        ylim=(0, 112),
        ylabel="utilization (%)",
        title="Atlas utilization per band (pages, MB)",
    )
    a.legend(loc="upper center", fontsize=8, ncol=3)
    names = ["near", "overview"]
    views = [report["views"][n] for n in names]
    for a, key, title, scale in (
        (ax[0, 1], "draw_calls", "Draw calls per view", 1.0),
        (ax[1, 0], "bytes", "Texture MB per view", 1e-6),
    ):
        w = 0.38
        at = [v["atlas"][key] * scale for v in views]
        pb = [v["per_building"][key] * scale for v in views]
        a.bar(np.arange(2) - w / 2, at, w, label="atlases", color="tab:green")
        a.bar(np.arange(2) + w / 2, pb, w, label="one texture per building", color="tab:orange")
        for i, v in enumerate(views):
            ratio = v["draw_call_ratio"] if key == "draw_calls" else v["bytes_ratio"]
            a.annotate(f"{ratio}×", (i, max(at[i], pb[i])), ha="center", va="bottom", fontsize=9)
        a.set(
            xticks=[0, 1],
            xticklabels=[
                f"{n}\n({v['tiles']} tile{'s' if v['tiles'] != 1 else ''})" for n, v in zip(names, views, strict=True)
            ],
            title=title,
            yscale="log",
        )
        a.legend(fontsize=8)
    a = ax[1, 1]
    rows = report["packers"]["rows"]
    su = [100 * r["shelf"]["utilization"] for r in rows]
    xu = [100 * r["xatlas"]["utilization"] for r in rows]
    sz = [8 + 40 * r["charts"] / max(x["charts"] for x in rows) for r in rows] if rows else []
    a.scatter(su, xu, s=sz, alpha=0.7)
    lo = min(su + xu, default=50) - 2
    a.plot([lo, 100], [lo, 100], color="grey", lw=0.8, ls="--")
    tt = report["packers"]["totals"]
    a.set(
        xlabel=f"shelf utilization (%), {tt['shelf']['seconds']:.2f} s in all",
        ylabel=f"xatlas utilization (%), {tt['xatlas']['seconds']:.2f} s in all",
        title=f"Packers on {len(rows)} real tiles (dot size: charts)",
        xlim=(lo, 100),
        ylim=(lo, 100),
    )
    for a in ax.flat:
        a.grid(True, alpha=0.3)
    fig.suptitle(f"citylod texture atlases ({report['database']})", fontsize=14)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --- main -------------------------------------------------------------------------------------------------------


def run(
    url: str,
    out: Path,
    packer_tiles: int = PACKER_TILES,
    max_encode: int = MAX_ENCODE,
    seed: int = SEED,
    command: str = "",
) -> dict[str, Any]:
    out.mkdir(parents=True, exist_ok=True)
    report = {
        "command": command or "python -m benchmarks.report_textures",
        **measure(url, packer_tiles, max_encode, seed),
    }
    report["machine"] = machine(url, osm2pgsql=False)
    (out / "textures.json").write_text(json.dumps(report, indent=1, ensure_ascii=False) + "\n")
    (out / "textures.md").write_text(render_markdown(report))
    plot(report, out / "textures.png")
    log(f"wrote {out}/textures.md, .json, .png in {report['seconds']:.1f} s")
    return report


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.report_textures", description=__doc__.split("\n\n")[0])
    p.add_argument("--db", help="database URL (default: DATABASE_URL, else the local cluster's city database)")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default: {DEFAULT_OUT})")
    p.add_argument(
        "--packer-tiles",
        type=int,
        default=PACKER_TILES,
        help=f"tiles (most charts first) to pack with shelf and xatlas; 0 = all (default {PACKER_TILES})",
    )
    p.add_argument(
        "--max-encode",
        type=int,
        default=MAX_ENCODE,
        help=f"per view, features whose own texture is encoded for real; the rest estimated (default {MAX_ENCODE})",
    )
    p.add_argument("--seed", type=int, default=SEED, help=f"seed of the encoded sample (default {SEED})")
    args = p.parse_args(argv)
    if args.packer_tiles < 0 or args.max_encode < 1:
        p.error("--packer-tiles must be >= 0 and --max-encode >= 1")
    url = args.db or cluster.ensure()
    out: Path = REPO / args.out  # an absolute --out stays as it is
    command = f"python -m benchmarks.report_textures --out {args.out}"
    if args.packer_tiles != PACKER_TILES:
        command += f" --packer-tiles {args.packer_tiles}"
    if args.max_encode != MAX_ENCODE:
        command += f" --max-encode {args.max_encode}"
    if args.db:
        command += f" --db {db_name(url)}"
    run(url, out, args.packer_tiles, args.max_encode, args.seed, command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
