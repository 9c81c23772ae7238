"""Atlas packers compared: xatlas' chart packer against a simple shelf packer on utilization, pages and time.

The request set is what one tile of the textures stage asks for: N buildings with seeded random footprints
(rectangles w x d) and storey counts, one texture per wall (4) and per roof, each sized by the thesis'
resolution rule for the distance the tile is viewed from (``--distances``, one tile level each). Only the
layout is timed (no pixels are drawn); ``--draw`` also renders the procedural textures, packs them and
encodes the pages, to show what a whole tile costs.

    .venv/bin/python -m benchmarks.atlas_compare                 # table on stdout
    .venv/bin/python -m benchmarks.atlas_compare --json out.json --buildings 400 --draw
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from etl.textures import atlas as A


@dataclass
class Row:
    distance_m: float
    texels_per_metre: float
    packer: str
    requests: int
    content_texels: int
    pages: int
    page_texels: int
    utilization: float  # content / page texels over all pages
    min_page_utilization: float  # the worst page (usually the last, partly filled one)
    scaled: int  # requests shrunk to fit a page
    seconds: float  # layout only
    draw_seconds: float | None = None  # render + pack + encode (--draw)
    page_bytes: int | None = None  # encoded pages (--draw)


def requests(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(chart sizes in metres (5 n, 2), building of each chart): 4 walls and a flat roof per building."""
    rng = np.random.default_rng(seed)
    w = rng.uniform(6, 40, n)
    d = rng.uniform(6, 25, n)
    storeys = rng.choice(np.arange(1, 13), n, p=np.r_[[0.1, 0.2, 0.2, 0.15, 0.1, 0.08, 0.06], [0.022] * 5])
    h = storeys * 3.0
    metres = np.concatenate(
        [
            np.column_stack([w, h]),
            np.column_stack([d, h]),
            np.column_stack([w, h]),
            np.column_stack([d, h]),
            np.column_stack([w, d]),
        ]
    )
    return metres, np.tile(np.arange(n), 5)


def run(
    n: int,
    distances: list[float],
    page_size: int,
    padding: int,
    seed: int,
    fov_deg: float,
    screen_px: int,
    brute_force: bool,
    draw: bool,
    fmt: str,
) -> list[Row]:
    metres, owner = requests(n, seed)
    rows = []
    packers = ["shelf", "xatlas"] + (["xatlas-brute"] if brute_force else [])
    for dist in distances:
        rho = A.texels_per_metre(dist, math.radians(fov_deg), screen_px)
        sizes = A.texels(metres, rho)
        for name in packers:
            packer = name.split("-")[0]
            lay = A.layout(
                sizes, page_size=page_size, packer=packer, padding=padding, brute_force=name.endswith("brute")
            )
            area = lay.page_dims[:, 0] * lay.page_dims[:, 1]
            row = Row(
                distance_m=dist,
                texels_per_metre=round(rho, 3),
                packer=name,
                requests=len(sizes),
                content_texels=int((lay.w * lay.h).sum()),
                pages=lay.n_pages,
                page_texels=int(area.sum()),
                utilization=round(lay.total_utilization, 4),
                min_page_utilization=round(float(lay.utilization.min()), 4),
                scaled=int(lay.scaled.sum()),
                seconds=round(lay.seconds, 4),
            )
            if draw:
                row.draw_seconds, row.page_bytes = _draw(metres, owner, sizes, page_size, packer, padding, fmt, seed)
            rows.append(row)
    return rows


def _draw(
    metres: np.ndarray,
    owner: np.ndarray,
    sizes: np.ndarray,
    page_size: int,
    packer: str,
    padding: int,
    fmt: str,
    seed: int,
) -> tuple[float, int]:
    from etl.textures import procedural as T

    rng = np.random.default_rng(seed + 1)
    n = int(owner.max()) + 1
    wall_mat = rng.choice(T.WALL_MATERIALS, n)
    roof_mat = rng.choice(T.ROOF_MATERIALS, n)
    t0 = time.perf_counter()

    def wall(wm: float, hm: float, b: int) -> Callable[[int, int], np.ndarray]:
        return lambda w, h: T.facade_texture(None, wall_mat[b], hm / 3.0, wm, hm, size=(w, h), seed=b)

    def roof(wm: float, hm: float, b: int) -> Callable[[int, int], np.ndarray]:
        return lambda w, h: T.roof_texture(None, roof_mat[b], wm, hm, size=(w, h), seed=b)

    reqs = []
    for i, ((wm, hm), (w, h)) in enumerate(zip(metres, sizes, strict=True)):
        gen = (wall if i < 4 * n else roof)(float(wm), float(hm), int(owner[i]))
        reqs.append(A.TextureRequest(size=(int(w), int(h)), generator=gen, key=i))
    at = A.pack(reqs, page_size=page_size, packer=packer, padding=padding)
    nbytes = sum(len(A.encode_image(p, fmt)[0]) for p in at.pages)
    return round(time.perf_counter() - t0, 3), nbytes


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--buildings", type=int, default=200, help="buildings in the tile (default 200)")
    ap.add_argument(
        "--distances",
        type=float,
        nargs="+",
        default=[100.0, 200.0, 400.0, 800.0, 1600.0],
        help="view distances in metres, one tile level each",
    )
    ap.add_argument("--page-size", type=int, default=A.PAGE_SIZE)
    ap.add_argument("--padding", type=int, default=2)
    ap.add_argument("--fov", type=float, default=60.0, help="vertical field of view in degrees")
    ap.add_argument("--screen", type=int, default=1080, help="screen height in pixels")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--brute-force", action="store_true", help="also run xatlas with bruteForce (slow)")
    ap.add_argument("--draw", action="store_true", help="also render, pack and encode the textures")
    ap.add_argument("--format", default="webp", help="page format for --draw (webp, png, jpeg)")
    ap.add_argument("--json", help="write the rows to this file as JSON")
    args = ap.parse_args(argv)
    rows = run(
        args.buildings,
        args.distances,
        args.page_size,
        args.padding,
        args.seed,
        args.fov,
        args.screen,
        args.brute_force,
        args.draw,
        args.format,
    )
    head = (
        f"{'dist m':>7} {'tex/m':>6} {'packer':<13} {'charts':>6} {'pages':>5} {'util':>6} {'worst':>6} "
        f"{'scaled':>6} {'layout s':>9}"
    )
    if args.draw:
        head += f" {'draw s':>7} {'bytes':>9}"
    print(
        f"{args.buildings} buildings, page {args.page_size}, padding {args.padding}, fov {args.fov:g}°, "
        f"{args.screen} px"
    )
    print(head)
    for r in rows:
        line = (
            f"{r.distance_m:7.0f} {r.texels_per_metre:6.2f} {r.packer:<13} {r.requests:6d} {r.pages:5d} "
            f"{r.utilization:6.1%} {r.min_page_utilization:6.1%} {r.scaled:6d} {r.seconds:9.3f}"
        )
        if args.draw:
            line += f" {r.draw_seconds:7.2f} {r.page_bytes:9d}"
        print(line)
    if args.json:
        with open(args.json, "w") as f:
            json.dump([asdict(r) for r in rows], f, indent=1)


if __name__ == "__main__":
    main()
