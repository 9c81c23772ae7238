"""``python -m benchmarks.footprint_proxy``: a fast stand-in for the CesiumJS fidelity measure of straight-down views.

For cameras looking straight down over the data (the view bench's overview camera, and the same at 2/3 and 1/3 of
its height above the ground), the features ``api.lod_for_view`` selects at SSE 16 (it agrees with what CesiumJS
draws) are rasterised as footprints at the camera's pixel size (pixel centres inside a footprint, the rule a GPU
applies) and compared with every building's footprint rasterised the same way: the IoU of the two masks, the
drawn / full-detail pixel ratio, and the triangles of the drawn tiles against all LOD3 triangles (the overview
target is ≤ 1/20). Footprints stand for the solids seen from above (walls and perspective ignored: buildings are
tens of metres tall, the cameras kilometres up): blocks their gen.block.footprint, LOD1 buildings their simplified
gen.footprint, LOD2/LOD3 features their mapped outline. Prints one JSON object per camera.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from typing import Any

import numpy as np
import psycopg
import shapely

from benchmarks.view_bench import overview_camera, view_triangles
from core.camera import Camera

_FEATURES = """
SELECT ST_AsBinary(CASE v.feature_kind WHEN 'block' THEN k.footprint
                                       ELSE CASE WHEN v.lod = 1 THEN f.geom ELSE b.geom_local END END)
FROM api.lod_for_view(ST_SetSRID(ST_MakePoint(%s, %s, %s), 4326), %s, %s, %s, %s, 16, %s) v
LEFT JOIN gen.block k ON v.feature_kind = 'block' AND k.block_id = v.feature_id
LEFT JOIN gen.footprint f ON v.feature_kind <> 'block' AND v.lod = 1 AND f.building_id = v.feature_id
LEFT JOIN osm.building b ON v.feature_kind <> 'block' AND b.id = v.feature_id
"""


def mask(geoms: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Pixel centres (x, y) inside any of ``geoms``."""
    tree = shapely.STRtree(geoms)
    pts = shapely.points(x, y)
    hit, _ = tree.query(pts, predicate="intersects")
    out = np.zeros(len(pts), bool)
    out[hit] = True
    return out


def measure(conn: psycopg.Connection, cam: Camera, ground: float) -> dict[str, Any]:
    """IoU and pixel ratio of the drawn footprints against all footprints, for a straight-down ``cam``."""
    srid = conn.execute("SELECT meta.working_srid()").fetchone()[0]  # type: ignore[index]
    cx, cy = conn.execute("SELECT ST_X(p), ST_Y(p) FROM ST_Transform(ST_SetSRID(ST_MakePoint(%s, %s), 4326), %s) p",
                          (cam.lon, cam.lat, srid)).fetchone()  # type: ignore[misc]
    half_h = (cam.height - ground) * math.tan(math.radians(cam.fov) / 2)
    px = 2 * half_h / cam.viewport_height
    w = round(cam.viewport_height * cam.aspect)
    xs = cx + (np.arange(w) + 0.5 - w / 2) * px
    ys = cy + (np.arange(cam.viewport_height) + 0.5 - cam.viewport_height / 2) * px
    gx, gy = (a.ravel() for a in np.meshgrid(xs, ys))
    drawn = shapely.from_wkb([r[0] for r in conn.execute(
        _FEATURES, (cam.lon, cam.lat, cam.height, cam.heading, cam.pitch, cam.fov, cam.viewport_height,
                    cam.aspect)).fetchall() if r[0] is not None])
    full = shapely.from_wkb([r[0] for r in conn.execute(
        "SELECT ST_AsBinary(b.geom_local) FROM osm.building b WHERE b.id IN "
        "(SELECT building_id FROM tiles.building_tile)").fetchall()])
    a, b = mask(drawn, gx, gy), mask(full, gx, gy)
    tri = view_triangles(conn, cam)
    return {"height_m": round(cam.height - ground), "pixel_m": round(px, 2),
            "iou": round(float((a & b).sum() / max((a | b).sum(), 1)), 3),
            "drawn_ratio": round(float(a.sum() / max(b.sum(), 1)), 3),
            "tiles": tri["tiles"], "features": tri["features"], "triangles": tri["triangles"],
            "bands": sorted({int(g) for (g,) in conn.execute(
                "SELECT DISTINCT t.gen_level FROM api.lod_for_view(ST_SetSRID(ST_MakePoint(%s, %s, %s), 4326), %s,"
                " %s, %s, %s, 16, %s) v JOIN tiles.tile t USING (level, x, y)",
                (cam.lon, cam.lat, cam.height, cam.heading, cam.pitch, cam.fov, cam.viewport_height,
                 cam.aspect)).fetchall()})}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--url", default=os.environ.get("DATABASE_URL"))
    args = ap.parse_args(argv)
    with psycopg.connect(args.url, autocommit=True) as conn:
        over = overview_camera(conn)
        ground = float(conn.execute("SELECT region[5] FROM tiles.tile WHERE level = 0").fetchone()[0])  # type: ignore[index]
        lod3 = int(conn.execute("SELECT sum(n_triangles) FROM lod.building_mesh WHERE lod = 3").fetchone()[0])  # type: ignore[index]
        for name, f in (("overview", 1.0), ("2/3", 2 / 3), ("1/3", 1 / 3)):
            cam = Camera(over.lon, over.lat, ground + (over.height - ground) * f, 0.0, -90.0)
            t0 = time.perf_counter()
            out = measure(conn, cam, ground)
            out = {"camera": name, **out, "lod3_triangles": lod3,
                   "fewer": round(lod3 / max(out["triangles"], 1), 1), "seconds": round(time.perf_counter() - t0, 1)}
            print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
