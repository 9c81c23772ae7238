"""What another 3D Tiles client covers against CesiumJS, for tests/e2e/test_three_client.py and
tests/e2e/test_loadersgl_tileset.py: the buildings the drawn tiles' features cover (blocks expanded to their members,
from the database), which of them only one client covers and whether that is explained (the frustum's edge, or the
other client drawing the place at another level), and a tileset whose root region is moved so that the implicit
subdivision no longer yields the quadtree's cells (what such a client must be seen to fail on).
"""

from __future__ import annotations

import copy
import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import psycopg

from core.camera import Camera
from core.geodesy import region_box
from core.settings import Settings
from core.tiles3d import expand

#: A building's box closer than this to a frustum plane (metres) is on the edge: the two clients test tile volumes
#: that differ (3DTilesRendererJS and loaders.gl an oriented box around the region
#: they compute, CesiumJS the subtree's region).
EDGE_M = 3.0


def tree(tiles: Path) -> dict[str, dict[str, Any]]:
    """Every tile of the (expanded) tileset by content uri, as a client that reads the subtree metadata has it."""
    tileset = json.loads((tiles / "tileset.json").read_text())
    out: dict[str, dict[str, Any]] = {}
    stack = [expand(tileset, lambda u: (tiles / u).read_bytes())["root"]]
    while stack:
        t = stack.pop()
        if "content" in t:
            out[t["content"]["uri"]] = t
        stack.extend(t.get("children", []))
    return out


def cesium_cameras(drawn: dict[str, Any]) -> list[dict[str, Any]]:
    """The cameras as CesiumJS held them, with its vertical field of view and drawing buffer."""
    out = []
    for name, v in drawn["by_name"].items():
        c = v["camera"]
        out.append(
            {
                "name": name,
                **{k: c[k] for k in ("lon", "lat", "height", "heading", "pitch")},
                "fovyDeg": v["fovyDeg"],
                "widthPx": v["drawingBufferWidth"],
                "heightPx": v["drawingBufferHeight"],
            }
        )
    return out


COVERED = """
    SELECT DISTINCT coalesce(o.parent_id, o.id), format('content/%%s/%%s/%%s.glb', t.level, t.x, t.y)
    FROM unnest(%s::int[], %s::int[], %s::int[]) AS t(level, x, y)
    CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f
    LEFT JOIN gen.block k ON f.feature_kind = 'block' AND k.block_id = f.building_id
    CROSS JOIN LATERAL unnest(coalesce(k.members, ARRAY[f.building_id])) AS u(id)
    JOIN osm.building o ON o.id = u.id
"""
BOXES = """
    SELECT bt.group_id, ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e), h
    FROM (SELECT bt.group_id, ST_Extent(m.envelope_4326) AS e, max(m.height) AS h
          FROM tiles.building_tile bt JOIN lod.building_mesh m ON m.building_id = bt.building_id
          WHERE bt.group_id = ANY(%s) GROUP BY 1) bt
"""


def covered(conn: psycopg.Connection, uris: list[str]) -> dict[int, set[str]]:
    """Building (outline) -> the drawn tiles whose features cover it."""
    keys = [tuple(int(v) for v in u.removesuffix(".glb").split("/")[1:]) for u in uris]
    out: dict[int, set[str]] = {}
    for b, uri in conn.execute(COVERED, ([k[0] for k in keys], [k[1] for k in keys], [k[2] for k in keys])):
        out.setdefault(b, set()).add(uri)
    return out


def related(a: str, b: str) -> bool:
    """One tile is the other's ancestor or descendant."""
    (la, xa, ya), (lb, xb, yb) = (tuple(int(v) for v in u.removesuffix(".glb").split("/")[1:]) for u in (a, b))
    if la > lb:
        (la, xa, ya), (lb, xb, yb) = (lb, xb, yb), (la, xa, ya)
    return la < lb and xb >> (lb - la) == xa and yb >> (lb - la) == ya


def coverage_report(conn: psycopg.Connection, view: dict[str, Any], tiles: list[str], client: str) -> dict[str, Any]:
    """The buildings CesiumJS (``view``, the lod_views driver's) and ``client`` (drawing the content uris ``tiles``)
    cover from one camera, and those covered by one only that
    neither lie on the frustum's edge (their box within EDGE_M of a plane, or outside) nor are drawn by the other
    client at another level (in an ancestor or descendant of the tile that covers them)."""
    cam = Camera(
        view["camera"]["lon"],
        view["camera"]["lat"],
        view["camera"]["height"],
        view["camera"]["heading"],
        view["camera"]["pitch"],
        fov=view["fovyDeg"],
        viewport_height=int(view["drawingBufferHeight"]),
        aspect=view["aspect"],
    )
    by = {
        "cesium": covered(conn, [t["uri"] for t in view["tiles"]]),
        client: covered(conn, tiles),
    }
    drawn = {"cesium": [t["uri"] for t in view["tiles"]], client: tiles}
    only = {k: set(by[k]) - set(by[o]) for k, o in (("cesium", client), (client, "cesium"))}
    diff = sorted(only["cesium"] | only[client])
    boxes = {}
    if diff:
        base = Settings.from_env().base_height_m
        rows = conn.execute(BOXES, (diff,)).fetchall()
        regions = np.array([[math.radians(v) for v in r[1:5]] + [base, base + float(r[5])] for r in rows])
        for r, box in zip(rows, region_box(regions, pad=0.0), strict=True):
            boxes[r[0]] = box
    pos, planes = cam.position(), cam.planes()
    unexplained = []
    for k, o in (("cesium", client), (client, "cesium")):
        for b in sorted(only[k]):
            box = boxes[b]
            c = box[:3] - pos
            inside = planes @ c - np.abs(planes @ box[3:].reshape(3, 3).T).sum(axis=1)
            if inside.min() < EDGE_M:
                continue  # on the frustum's edge or outside
            if any(related(a, d) for a in by[k][b] for d in drawn[o]):
                continue  # the other client draws that place at another level
            unexplained.append(f"building {b}: only {k} ({sorted(by[k][b])})")
    both = set(by["cesium"]) & set(by[client])
    return {
        "cesium": len(by["cesium"]),
        client: len(by[client]),
        "both": len(both),
        "only_cesium": len(only["cesium"]),
        f"only_{client}": len(only[client]),
        "unexplained": unexplained,
    }


def moved_root(tiles: Path, dest: Path) -> Path:
    """A copy of the tileset whose root region is the root tile's own (from the subtree metadata): the implicit
    subdivision of that region no longer yields the quadtree's cells."""
    shutil.copytree(tiles, dest)
    tileset = json.loads((tiles / "tileset.json").read_text())
    root = tree(tiles)["content/0/0/0.glb"]
    doctored = copy.deepcopy(tileset)
    assert doctored["root"]["boundingVolume"]["region"] != root["boundingVolume"]["region"]
    doctored["root"]["boundingVolume"]["region"] = root["boundingVolume"]["region"]
    (dest / "tileset.json").write_text(json.dumps(doctored))
    return dest
