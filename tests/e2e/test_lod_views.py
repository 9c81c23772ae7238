"""Levels of detail in a real 3D Tiles client: the deep multi-LOD Helsinki tileset (40 features per leaf, so every
band exists, as tests/db/test_generalize.py builds it), served by ``python -m exporter serve`` and drawn by
CesiumJS in headless Chromium (tests/e2e/lod_views_e2e.mjs) with the plain traversal (maximumScreenSpaceError 16;
no dynamic or foveated screen-space error, no skipLevelOfDetail).

* A far camera (the whole centre from 6 km up) draws only coarse tiles: no leaf, features of LOD 0 and 1.
* A near camera (30 m above the street) draws leaves and their LOD3 features.
* REPLACE refinement: no tile is ever drawn together with one of its ancestors.
* What CesiumJS draws agrees with api.lod_for_view for the same camera, given CesiumJS's own viewport height,
  vertical field of view and aspect ratio (see test_cesium_agrees_with_lod_for_view for what "agrees" means).
* The page stays offline and clean: no console error, no failed request, no host but the local server.

Screenshots: build/screenshots/lod_far.png and lod_near.png. A missing Chromium or Node.js fails these tests.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import psycopg
import pytest

from core.camera import Camera
from core.geodesy import box_distance, region_box
from core.tiles3d import expand
from tests.e2e.conftest import MAX_SSE, SCREENSHOT

pytestmark = pytest.mark.e2e

#: Share of the tiles (|both| / |either|) CesiumJS and api.lod_for_view must agree on per camera. Measured with
#: CesiumJS 1.145: far 4/4, mid 15/15, near 16/16, street 17/20 (the disagreements are explained below).
MIN_AGREEMENT = 0.8
#: A refinement decision within this fraction of MAX_SSE may go either way: CesiumJS measures the distance to a
#: region as the larger of its own region and oriented-box distances, api.lod_for_view to the east-north-up box
#: around the region (geodesy.region_box), and near a tile the two differ by a few per cent (measured up to 4.5 %).
SSE_TOLERANCE = 0.25
#: A frustum test within this many metres of a plane may go either way: region_box pads the box by 1 m on each
#: of its three axes (up to √3 m along a plane's normal), CesiumJS culls the tight oriented box of the region.
EDGE_M = 3.0

CONTENT = re.compile(r"content/(\d+)/(\d+)/(\d+)\.glb$")


# --- the tile tree and the two traversals ----------------------------------------------------------------------


@dataclass(eq=False)
class Node:
    uri: str
    key: tuple[int, int, int]
    geometric_error: float
    box: np.ndarray
    parent: Node | None = None
    children: list[Node] = field(default_factory=list)

    def path(self) -> list[Node]:
        """This tile and its ancestors."""
        out, n = [], self
        while n is not None:
            out.append(n)
            n = n.parent
        return out


def tile_tree(tileset: dict[str, Any]) -> tuple[Node, dict[str, Node]]:
    flat: list[dict[str, Any]] = []

    def walk(t: dict[str, Any]) -> None:
        flat.append(t)
        for k in t.get("children", []):
            walk(k)

    walk(tileset["root"])
    boxes = region_box(np.array([t["boundingVolume"]["region"] for t in flat]))
    nodes: dict[int, Node] = {}
    by_uri: dict[str, Node] = {}
    for t, box in zip(flat, boxes, strict=True):
        uri = t["content"]["uri"]
        m = CONTENT.search(uri)
        assert m, uri
        n = Node(uri, (int(m[1]), int(m[2]), int(m[3])), float(t["geometricError"]), box)
        nodes[id(t)] = n
        by_uri[uri] = n
    for t in flat:
        for k in t.get("children", []):
            nodes[id(k)].parent = nodes[id(t)]
            nodes[id(t)].children.append(nodes[id(k)])
    return nodes[id(tileset["root"])], by_uri


@dataclass
class Judged:
    """Every tile's screen-space error and frustum slack (metres; >= 0: in the frustum) for one camera, with the
    numbers api.lod_for_view uses (the box of geodesy.region_box, five planes through the camera)."""

    sse: dict[Node, float]
    slack: dict[Node, float]

    @classmethod
    def of(cls, nodes: list[Node], cam: Camera) -> Judged:
        pos, planes = cam.position(), cam.planes()
        sse, slack = {}, {}
        for n in nodes:
            c = n.box[:3] - pos
            s = planes @ c + np.abs(planes @ n.box[3:].reshape(3, 3).T).sum(axis=1)
            slack[n] = float(s.min())
            sse[n] = cam.sse(n.geometric_error, box_distance(n.box, pos))
        return cls(sse, slack)

    def seen(self, n: Node) -> bool:
        return self.slack[n] >= 0

    def plain(self, root: Node) -> set[Node]:
        """The 3D Tiles traversal api.lod_for_view implements: a tile in the frustum is drawn unless its error
        exceeds MAX_SSE, and then its children in the frustum replace it."""
        out: set[Node] = set()

        def visit(n: Node) -> None:
            if not self.seen(n):
                return
            if n.children and self.sse[n] > MAX_SSE:
                for k in n.children:
                    visit(k)
            else:
                out.add(n)

        visit(root)
        return out

    def cesium(self, root: Node, cull_with_children: bool = True) -> set[Node]:
        """The same with the two rules CesiumJS 1.145 adds (Cesium3DTilesetTraversal.updateTileVisibility with
        cullWithChildrenBounds, on by default; Cesium3DTilesetBaseTraversal.updateAndPushChildren): a REPLACE tile
        none of whose children's volumes is in the frustum is culled, and a tile refines only into children that
        are visible by that rule, otherwise it is drawn itself, whatever its error. The first rule only for tiles
        of tileset.json (``cull_with_children``): CesiumJS decides whether it applies
        (Cesium3DTileOptimizations.checkChildrenWithinParent) when it loads tileset.json, never for the tiles it
        makes from an implicit tileset's subtrees."""

        def visible(n: Node) -> bool:
            return self.seen(n) and (not cull_with_children or not n.children or any(self.seen(k) for k in n.children))

        out: set[Node] = set()

        def visit(n: Node) -> None:
            if not visible(n):
                return
            kids = [k for k in n.children if visible(k)]
            if kids and self.sse[n] > MAX_SSE:
                for k in kids:
                    visit(k)
            else:
                out.add(n)

        visit(root)
        return out

    def borderline(self, n: Node) -> list[str]:
        """Why CesiumJS may legitimately decide otherwise about ``n``: a refinement decision on its path within
        SSE_TOLERANCE of MAX_SSE, or a frustum test on its path or their children within EDGE_M of a plane."""
        why: dict[str, None] = {}  # ordered, without repeats
        for p in n.path():
            if p.children and abs(self.sse[p] / MAX_SSE - 1) <= SSE_TOLERANCE:
                why[f"{p.uri} sse {self.sse[p]:.2f}"] = None
            for q in (p, *p.children):
                if abs(self.slack[q]) <= EDGE_M:
                    why[f"{q.uri} frustum slack {self.slack[q]:.2f} m"] = None
        return list(why)


def camera_of(view: dict[str, Any]) -> Camera:
    """The camera as CesiumJS held it (read back from the page), with its drawing buffer and frustum."""
    c = view["camera"]
    assert view["pixelRatio"] == 1, view["pixelRatio"]  # else CesiumJS divides its errors by it
    return Camera(
        c["lon"],
        c["lat"],
        c["height"],
        c["heading"],
        c["pitch"],
        fov=view["fovyDeg"],
        viewport_height=int(view["drawingBufferHeight"]),
        aspect=view["aspect"],
    )


def lod_for_view(conn: psycopg.Connection, cam: Camera) -> dict[str, tuple[float, set[int]]]:
    """api.lod_for_view for ``cam``: content uri -> (the tile's screen-space error, the LODs of its features)."""
    rows = conn.execute(
        """SELECT format('content/%%s/%%s/%%s.glb', level, x, y), screen_space_error, array_agg(DISTINCT lod)
           FROM api.lod_for_view(ST_SetSRID(ST_MakePoint(%s, %s, %s), 4326), %s, %s, %s, %s, %s, %s,
                                 cull_features => false)  -- CesiumJS draws whole tiles
           GROUP BY 1, 2""",
        (cam.lon, cam.lat, cam.height, cam.heading, cam.pitch, cam.fov, cam.viewport_height, MAX_SSE, cam.aspect),
    ).fetchall()
    out = {uri: (sse, set(lods)) for uri, sse, lods in rows}
    assert len(out) == len(rows)  # one error per tile
    return out


def lods_in_db(conn: psycopg.Connection, tile: dict[str, Any]) -> dict[str, int]:
    return {
        str(lod): n
        for lod, n in conn.execute(
            "SELECT lod, count(*) FROM api.buildings_for_tile(%s, %s, %s) GROUP BY lod",
            (tile["level"], tile["x"], tile["y"]),
        ).fetchall()
    }


def is_ancestor(a: tuple[int, int, int], b: tuple[int, int, int]) -> bool:
    (la, xa, ya), (lb, xb, yb) = a, b
    return la < lb and xb >> (lb - la) == xa and yb >> (lb - la) == ya


# --- the tests -------------------------------------------------------------------------------------------------


def test_every_view_settles_and_the_page_stays_clean(drawn: dict[str, Any]) -> None:
    context = drawn["context"]
    assert drawn["tileset"] == {
        "maximumScreenSpaceError": MAX_SSE,
        "dynamicScreenSpaceError": False,
        "foveatedScreenSpaceError": False,
        "skipLevelOfDetail": False,
    }, context
    for name, v in drawn["by_name"].items():
        assert v["settled"]["loaded"] and v["tilesLoaded"], f"{name}: tiles still loading\n{context}"
        assert v["stable"], f"{name}: the drawn tiles changed from frame to frame: {v['frames']}\n{context}"
        assert v["tiles"] and all(t["level"] is not None for t in v["tiles"]), f"{name}\n{context}"
        assert v["maximumScreenSpaceError"] == v["memoryAdjustedScreenSpaceError"] == MAX_SSE, context
    assert drawn["hosts"] == [drawn["host"]], f"requests left the local server: {drawn['hosts']}"
    assert drawn["consoleErrors"] == [], context
    assert drawn["failedRequests"] == [], context
    for path in SCREENSHOT.values():
        assert path.exists() and path.stat().st_size > 10_000, path


def test_features_are_those_of_the_tile(drawn: dict[str, Any], deep: tuple[str, Path], conn_of: Callable) -> None:
    """The `lod` of every feature CesiumJS exposes in a drawn tile, counted, is api.buildings_for_tile's; a tile is
    a leaf in CesiumJS's tree exactly when it is one in tiles.tile."""
    conn = conn_of(deep[0])
    for name, v in drawn["by_name"].items():
        for t in v["tiles"]:
            assert t["lods"] == lods_in_db(conn, t), (name, t["uri"])
            leaf = conn.execute(
                "SELECT is_leaf FROM tiles.tile WHERE (level, x, y) = (%s, %s, %s)", (t["level"], t["x"], t["y"])
            ).fetchone()[0]
            assert t["leaf"] == leaf, (name, t["uri"])


def test_far_view_draws_only_coarse_tiles(drawn: dict[str, Any], deep: tuple[str, Path], conn_of: Callable) -> None:
    far = drawn["by_name"]["far"]
    conn = conn_of(deep[0])
    # the camera still fits the tileset (if not, the tree changed and needs another camera, not another client)
    want = lod_for_view(conn, camera_of(far))
    assert want and set().union(*(lods for _, lods in want.values())) <= {0, 1}, want

    tiles = far["tiles"]
    assert len(tiles) >= 2, f"the far camera should refine the root: {[t['uri'] for t in tiles]}"
    assert not [t["uri"] for t in tiles if t["leaf"] or t["geometricError"] == 0]
    lods = {int(lod) for t in tiles for lod in t["lods"]}
    assert lods and lods <= {0, 1}, lods
    bands = {
        g
        for (g,) in conn.execute(
            """SELECT gen_level FROM tiles.tile
           WHERE (level, x, y) IN (SELECT * FROM unnest(%s::int[], %s::int[], %s::int[]))""",
            ([t["level"] for t in tiles], [t["x"] for t in tiles], [t["y"] for t in tiles]),
        )
    }
    assert bands <= {0, 1, 2}, bands  # blocks and simplified solids, never the LOD2 or LOD3 bands


def test_near_view_reaches_lod3(drawn: dict[str, Any]) -> None:
    tiles = drawn["by_name"]["near"]["tiles"]
    leaves = [t for t in tiles if t["leaf"]]
    assert leaves, [t["uri"] for t in tiles]
    assert all(set(t["lods"]) == {"3"} for t in leaves), leaves
    assert sum(t["lods"].get("3", 0) for t in tiles) > 0
    # and farther away in the same picture, coarser tiles stand in for whole quarters
    assert {int(lod) for t in tiles for lod in t["lods"]} > {3}


def test_replace_never_draws_two_versions(drawn: dict[str, Any]) -> None:
    for name, v in drawn["by_name"].items():
        assert v["nestedPairs"] == [], name  # from CesiumJS's own tile tree
        keys = [(t["level"], t["x"], t["y"]) for t in v["tiles"]]
        assert len(set(keys)) == len(keys), name
        nested = [(a, b) for a in keys for b in keys if is_ancestor(a, b)]
        assert nested == [], (name, nested)


def test_cesium_agrees_with_lod_for_view(drawn: dict[str, Any], deep: tuple[str, Path], conn_of: Callable) -> None:
    """CesiumJS and api.lod_for_view, same camera, same viewport height, vertical fov and aspect.

    They agree on most tiles, not all, for two measured reasons:
    * CesiumJS adds two rules to the plain traversal (see Judged.cesium): it culls a tile none of whose children's
      volumes is in view (cullWithChildrenBounds), and it draws a tile over the error bound when none of its
      children is visible (in the street view, CesiumJS draws tile 2/2/0 where api.lod_for_view draws its child
      3/4/1). Neither ever draws two versions of a building; api.lod_for_view follows the specification.
    * Decisions on a knife edge: an error within SSE_TOLERANCE of MAX_SSE (CesiumJS measures distance to the region
      differently from our box; on Munich's old town a tile was at 16.5 for us, 15.75 for CesiumJS) or a frustum
      test within EDGE_M of a plane (our box is padded by 1 m; in the street view leaf 4/9/4 is 0.96 m inside one).
    So the test asserts that they agree on a clear majority of tiles and that CesiumJS draws exactly what the
    plain traversal plus its two rules predicts, up to knife-edge decisions; and that api.lod_for_view is, to the
    last digit, the plain traversal computed here (so the prediction uses api.lod_for_view's own numbers).
    """
    conn = conn_of(deep[0])
    # the export is implicit: the tree its subtrees stand for
    tileset = json.loads((deep[1] / "tileset.json").read_text())
    implicit = "implicitTiling" in tileset["root"]
    root, by_uri = tile_tree(expand(tileset, lambda u: (deep[1] / u).read_bytes()))
    nodes = list(by_uri.values())
    report = []
    for name, v in drawn["by_name"].items():
        cam = camera_of(v)
        judged = Judged.of(nodes, cam)
        sql = lod_for_view(conn, cam)
        plain = judged.plain(root)
        assert {n.uri for n in plain} == set(sql), name
        for n in plain:
            assert sql[n.uri][0] == pytest.approx(judged.sse[n], rel=1e-6, abs=1e-9), (name, n.uri)

        cesium = {by_uri[t["uri"]] for t in v["tiles"]}
        predicted = judged.cesium(root, cull_with_children=not implicit)
        agreement = len(cesium & plain) / len(cesium | plain)
        # CesiumJS's own error for the tiles it draws (a private field, for the tolerance above): within it
        ratios = [
            t["sse"] / judged.sse[by_uri[t["uri"]]]
            for t in v["tiles"]
            if isinstance(t.get("sse"), (int, float)) and t["geometricError"] > 0
        ]
        unexplained = {n.uri: judged.borderline(n) for n in cesium ^ predicted}
        by_rules = len((cesium ^ plain) - (cesium ^ predicted))
        report.append(
            f"{name}: CesiumJS {len(cesium)} tiles, lod_for_view {len(plain)}, both {len(cesium & plain)} "
            f"({agreement:.0%}); only CesiumJS {sorted(n.uri for n in cesium - plain)}, only lod_for_view "
            f"{sorted(n.uri for n in plain - cesium)}; {by_rules} explained by CesiumJS's rules, knife edges "
            f"{unexplained}; CesiumJS / our error {min(ratios, default=1):.3f}..{max(ratios, default=1):.3f}"
        )
        assert agreement >= MIN_AGREEMENT, report[-1]
        assert all(unexplained.values()), report[-1]
        assert all(abs(r - 1) <= SSE_TOLERANCE for r in ratios), report[-1]
    print("\n" + "\n".join(report))
