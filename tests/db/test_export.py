"""Stage export: valid glb (Khronos glTF-Validator, 0 errors), a tileset that passes the 3D Tiles checks and
parses in 3d-tiles-tools, per-feature metadata, and buildings at their real place on the globe."""

import json
import subprocess
from dataclasses import replace

import numpy as np
import psycopg
import pytest

from core.geodesy import Y_UP_TO_Z_UP
from core.settings import Settings
from core.tiles3d import content_uris, expand
from exporter.checks import check_tileset, compressed_metadata_views
from exporter.export import LEAF_POSITION_ERROR_M, export_tileset
from exporter.gltf import feature_vertices as glb_vertices
from exporter.gltf import property_table, read_glb
from exporter.stream import StreamOptions
from tests.conftest import REPO, node_bin, run_etl, validate_glb

# Helsinki is the real city of make test; Munich and London (the extract tier) add parts and materials.
CITIES = [
    "fixtures",
    "helsinki",
    pytest.param("munich", marks=pytest.mark.extracts),
    pytest.param("london", marks=pytest.mark.extracts),
]


@pytest.mark.parametrize("name", CITIES)
def test_khronos_validator_zero_errors(city, name) -> None:
    c = city(name)
    report = validate_glb(c.tiles)
    assert report["files"] == len(list(c.tiles.rglob("*.glb"))) > 0
    assert report["errors"] == 0 and report["warnings"] == 0, report["reports"][:3]


@pytest.mark.parametrize("name", CITIES)
def test_tileset_passes_the_3d_tiles_checks(city, name) -> None:
    assert check_tileset(city(name).tiles / "tileset.json") == []


@pytest.mark.parametrize("name", CITIES)
def test_3d_tiles_tools_parses_the_tileset(city, conn_of, name) -> None:
    c = city(name)
    out = parse_with_3d_tiles_tools(c.tiles)
    n_tiles = conn_of(c.url).execute("SELECT count(*) FROM tiles.tile").fetchone()[0]
    assert out["tiles"] == n_tiles
    assert out["contentTypes"] == {"CONTENT_TYPE_GLB": n_tiles} and out["unresolved"] == []  # REPLACE: all have content
    # the default is implicit: 3d-tiles-tools reads every subtree and each tile's real region and error from them
    assert out["implicit"] and out["subtrees"] == len(list(c.tiles.rglob("*.subtree"))) >= 1
    assert_final_tiles(conn_of(c.url), out["final"])


def assert_final_tiles(conn, final: dict) -> None:
    """3d-tiles-tools' tiles (after the subtree metadata) have tiles.tile's regions and geometric errors."""
    rows = conn.execute("SELECT content_uri, region, geometric_error FROM tiles.tile").fetchall()
    want = {u: (g, r) for u, r, g in rows if u in final}
    assert len(want) == len(final)
    for uri, (error, region) in final.items():
        assert error == pytest.approx(want[uri][0], abs=1e-9) and region == pytest.approx(want[uri][1], abs=1e-12)


def parse_with_3d_tiles_tools(tiles) -> dict:
    proc = subprocess.run(
        [node_bin(), str(REPO / "tests/js/parse_tileset.mjs"), str(tiles / "tileset.json")],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("name", ["fixtures", "helsinki"])
def test_a_client_ignoring_subtree_metadata_computes_volumes_that_hold_the_content(city, conn_of, name) -> None:
    """The implicit root is the quadtree's root region and its error covers every level's: expanded without the
    subtrees' metadata (as 3DTilesRendererJS and loaders.gl do), every tile's computed volume holds its content
    but for half-extents at its edges, and no computed error is below the measured one; with it, exact."""
    from exporter.volumes import measure

    c = city(name)
    conn = conn_of(c.url)
    ts = json.loads((c.tiles / "tileset.json").read_text())
    root = conn.execute("SELECT west, south, east, north FROM api.quadtree_root()").fetchone()
    assert ts["root"]["boundingVolume"]["region"][:4] == list(root)
    m = measure(conn, ts)
    assert m["buildings"]["beyond_half_extent"] == 0 and m["blocks"]["beyond_half_extent"] == 0
    assert m["error_shortfalls"] == 0 and m["root_error"] >= m["measured_root_error"]  # 0: a root leaf
    read = lambda u: (c.tiles / u).read_bytes()  # noqa: E731
    blind, exact = expand(ts, read, metadata=False), expand(ts, read)
    tiles = {tuple(t["implicit"]): t for t in _walk(blind["root"])}
    for t in _walk(exact["root"]):
        b = tiles[tuple(t["implicit"])]
        assert b["geometricError"] >= t["geometricError"]
        r, v = t["boundingVolume"]["region"], b["boundingVolume"]["region"]
        assert v[4] <= r[4] and r[5] <= v[5]  # heights: the root's
    assert len(tiles) == conn.execute("SELECT count(*) FROM tiles.tile").fetchone()[0]


def _walk(t: dict):
    yield t
    for ch in t.get("children", []):
        yield from _walk(ch)


@pytest.mark.parametrize("name", ["fixtures", "roofs", "helsinki"])
def test_the_default_stream_leaves_every_property_table_view_plain(city, name) -> None:
    """The CesiumGS 3d-tiles-validator (not on npm) reads property tables without a meshopt decoder: no view a
    table reads is compressed in the default stream, while its geometry is."""
    glbs = sorted(city(name).tiles.rglob("*.glb"))
    assert glbs
    compressed_geometry = 0
    for path in glbs:
        gltf, _ = read_glb(path.read_bytes())
        assert compressed_metadata_views(gltf) == [], path
        compressed_geometry += "KHR_meshopt_compression" in gltf.get("extensionsRequired", [])
    assert compressed_geometry == len(glbs)


def test_tables_meshopt_compresses_the_property_tables_and_passes_the_checks(city, tmp_path) -> None:
    c = city("fixtures")
    out = tmp_path / "ts"
    run_etl(c.url, "export", "--out", str(out), "--tables", "meshopt")
    assert check_tileset(out / "tileset.json") == []
    glbs = sorted(out.rglob("*.glb"))
    assert sum(bool(compressed_metadata_views(read_glb(p.read_bytes())[0])) for p in glbs) >= len(glbs) // 2
    for path in glbs:  # the same tables, read through the decoder
        default = c.tiles / path.relative_to(out)
        assert property_table(*read_glb(path.read_bytes())) == property_table(*read_glb(default.read_bytes()))


def test_implicit_and_explicit_tilings_share_every_glb(city, conn_of, tmp_path) -> None:
    """--tiling explicit writes every tile into tileset.json and no subtrees; the glbs are the same bytes as the
    implicit export's (one root transform, node matrices), and both tilesets stand for the same tree (Helsinki:
    a tree of a few levels)."""
    c = city("helsinki")
    out = tmp_path / "explicit"
    counts = export_tileset(c.url, out, Settings.from_env(), stream=StreamOptions(tiling="explicit"))
    assert counts["subtrees"] == 0 and not list(out.rglob("*.subtree"))
    implicit = tmp_path / "implicit"
    export_tileset(c.url, implicit, Settings.from_env(), stream=StreamOptions(tiling="implicit"))
    glbs = sorted(p.relative_to(out) for p in out.rglob("*.glb"))
    assert glbs and glbs == sorted(p.relative_to(implicit) for p in implicit.rglob("*.glb"))
    assert all((out / g).read_bytes() == (implicit / g).read_bytes() for g in glbs)
    assert check_tileset(out / "tileset.json") == [] and check_tileset(implicit / "tileset.json") == []
    ts = json.loads((out / "tileset.json").read_text())
    # compact glbs leave the property descriptions to tileset.json's schema (beside implicit tiling's tile class)
    its = json.loads((implicit / "tileset.json").read_text())
    assert set(its["schema"]["classes"]) == {"tile", "building"} and set(ts["schema"]["classes"]) == {"building"}
    assert all(s["description"] for s in ts["schema"]["classes"]["building"]["properties"].values())
    stack, n = [ts["root"]], 0
    while stack:
        t = stack.pop()
        n += 1
        assert "transform" not in t or t is ts["root"]
        stack.extend(t.get("children", []))
    assert "implicitTiling" not in ts["root"]
    assert n == conn_of(c.url).execute("SELECT count(*) FROM tiles.tile").fetchone()[0]
    a, b = parse_with_3d_tiles_tools(out), parse_with_3d_tiles_tools(implicit)
    assert not a["implicit"] and b["implicit"] and a["tiles"] == b["tiles"] and a["final"] == b["final"]
    explicit_tree = expand(ts, lambda u: b"")
    implicit_tree = expand(json.loads((implicit / "tileset.json").read_text()), lambda u: (implicit / u).read_bytes())
    assert content_uris(explicit_tree) == content_uris(implicit_tree)
    # a one-LOD tileset: content at the leaves only (contentAvailability apart from tileAvailability), ADD
    lod = tmp_path / "lod2"
    export_tileset(c.url, lod, Settings.from_env(), lod=2)
    got = parse_with_3d_tiles_tools(lod)
    leaves = conn_of(c.url).execute("SELECT count(*) FILTER (WHERE is_leaf), count(*) FROM tiles.tile").fetchone()
    assert (got["contents"], got["tiles"]) == tuple(leaves) and got["implicit"] and leaves[0] < leaves[1]
    assert json.loads((lod / "tileset.json").read_text())["root"]["refine"] == "ADD"
    assert check_tileset(lod / "tileset.json") == []
    assert_final_tiles(conn_of(c.url), got["final"])


def tile_of(conn, building_id: int):
    return conn.execute(
        """SELECT t.content_uri FROM tiles.building_tile bt JOIN tiles.tile t USING (level, x, y)
           WHERE bt.building_id = %s""",
        (building_id,),
    ).fetchone()[0]


def tile_world(tiles_dir, uri: str) -> np.ndarray:
    """The 4×4 matrix from a glb's node frame to ECEF, as a client composes it: the tileset root's transform (the
    only one) and glTF y-up to 3D Tiles z-up. The nodes' own matrices (the tile's frame in the root's, composed
    with the quantization) are applied per mesh by exporter.gltf.feature_vertices."""
    root = np.array(json.loads((tiles_dir / "tileset.json").read_text())["root"]["transform"]).reshape(4, 4).T
    y_to_z = np.eye(4)
    y_to_z[:3, :3] = Y_UP_TO_Z_UP
    return root @ y_to_z


@pytest.fixture(scope="module")
def lod2(city, tmp_path_factory):
    """The fixtures city exported at LOD2 alone: every vertex a footprint corner at the bottom or the top. Through
    the exporter's function, not the stage, so the shared city database gets no pipeline_run row."""
    c = city("fixtures")
    out = tmp_path_factory.mktemp("lod2") / "ts"
    export_tileset(c.url, out, Settings.from_env(), lod=2)
    return c.url, out


def feature_vertices(tiles_dir, uri: str, osm_id: int):
    gltf, binary = read_glb((tiles_dir / uri).read_bytes())
    table = property_table(gltf, binary)
    fid = table["osm_id"].index(osm_id)
    pos, fids = glb_vertices(gltf, binary)  # metres in the root's frame (node matrices applied), every mesh
    return pos[fids == fid], {k: v[fid] for k, v in table.items()}


def assert_placed(conn, tiles_dir, base: float = 0.0) -> float:
    """Exported vertices -> node matrix -> (y-up to z-up) -> root transform = ECEF; PostGIS ST_Transform(...,
    4978) of the same corners must agree to the centimetre. Returns the largest distance found (m)."""
    worst = 0.0
    for osm_id, bottom, top in ((10001, 0.0, 12.0), (11001, 0.0, 12.0), (13003, 5.0, 20.0)):
        uri = tile_of(conn, osm_id)
        verts, props = feature_vertices(tiles_dir, uri, osm_id)
        m = tile_world(tiles_dir, uri)
        ecef = (np.c_[verts, np.ones(len(verts))] @ m.T)[:, :3]
        truth = np.array(
            conn.execute(
                """SELECT ST_X(p), ST_Y(p), ST_Z(p) FROM (
                   SELECT ST_Transform(ST_Translate(ST_Force3D((ST_DumpPoints(geom_local)).geom), 0, 0, z), 4978) p
                   FROM osm.building, unnest(ARRAY[%s, %s]::float8[]) z WHERE osm_id = %s) q""",
                (base + bottom, base + top, osm_id),
            ).fetchall()
        )
        assert len(truth) >= 8
        # every exported vertex is a true corner (bottom or top), and every true corner is exported
        d = np.linalg.norm(ecef[:, None, :] - truth[None, :, :], axis=2)
        worst = max(worst, d.min(axis=1).max(), d.min(axis=0).max())
        assert props["osm_id"] == osm_id
    assert worst < 0.01
    return worst


def test_building_sits_at_its_place_on_the_globe(lod2, conn_of) -> None:
    url, tiles = lod2
    assert_placed(conn_of(url), tiles)


def test_base_height_lifts_content_and_regions_alike(city, new_db, conn_of, tmp_path) -> None:
    url = new_db("export_base")
    env = {"CITYLOD_BASE_HEIGHT_M": "100"}
    run_etl(url, "ingest", "--osm", str(city("fixtures").osm))
    run_etl(url, "lod")
    run_etl(url, "tiles", env=env)
    run_etl(url, "generalize", env=env)
    run_etl(url, "export", "--out", str(tmp_path / "ts"), "--lod", "2", env=env)
    conn = conn_of(url)
    assert_placed(conn, tmp_path / "ts", base=100.0)
    lo, hi = conn.execute("SELECT min(region[5]), max(region[6]) FROM tiles.tile").fetchone()
    assert lo == 100.0 and hi > 100.0
    assert check_tileset(tmp_path / "ts" / "tileset.json") == []


def test_feature_metadata(city, conn_of) -> None:
    c = city("fixtures")
    conn = conn_of(c.url)
    _, sq = feature_vertices(c.tiles, tile_of(conn, 10001), 10001)
    assert (
        sq["name"],
        sq["osm_type"],
        sq["kind"],
        sq["height"],
        sq["min_height"],
        sq["lod"],
        sq["gen_level"],
        sq["n_members"],
        sq["error_m"],
    ) == ("Square 100", "way", "building", 12.0, 0.0, 3, 4, 1, 0.0)  # a leaf
    _, part = feature_vertices(c.tiles, tile_of(conn, 13003), 13003)
    assert (part["kind"], part["building_osm_id"], part["building_osm_type"], part["min_height"], part["height"]) == (
        "part",
        13001,
        "way",
        5.0,
        20.0,
    )
    assert part["name"] == "Parts 130"  # a part without a name shows its building's
    _, court = feature_vertices(c.tiles, tile_of(conn, -1201), 1201)
    assert (court["osm_type"], court["building"]) == ("relation", "apartments")


def test_landmark_exaggeration_metadata(city, conn_of) -> None:
    """Every feature carries what a client needs to exaggerate landmarks per frame: the landmark's intervals and
    footprint circle in the glTF's frame, and a covered neighbour's gap and direction; the glbs stay valid."""
    c = city("helsinki")
    conn = conn_of(c.url)
    want = {
        r[0]: r[1:]
        for r in conn.execute(
            """SELECT lo.osm_id, l.scale_distances_m[1], l.scale_factors[1],
                  l.scale_factors[cardinality(l.scale_factors)], l.radius_m
           FROM lm.building l JOIN osm.building lo ON lo.id = l.building_id WHERE l.is_landmark"""
        )
    }
    gaps = {
        r[0]: (r[1], r[2])
        for r in conn.execute(
            """SELECT b.osm_id, lo.osm_id, x.gap_m FROM lm.building l JOIN osm.building b ON b.id = l.building_id
           CROSS JOIN LATERAL lm.exaggeration_role(l.building_id) x JOIN osm.building lo ON lo.id = x.landmark_id
           WHERE x.role = 2"""
        )
    }
    seen = {1: 0, 2: 0}
    for path in sorted(c.tiles.rglob("*.glb")):
        gltf, binary = read_glb(path.read_bytes())
        t = property_table(gltf, binary, fill_no_data=True)  # compact omits all-noData lm_landmark_osm_id
        # the landmark metadata is in the mesh's frame (compact geometry: before the node's translation), over
        # every mesh (a wide compact tile has one per chunk) and primitive
        pos, fid = glb_vertices(gltf, binary, frame="mesh")
        for i, role in enumerate(t["lm_role"]):
            if role == 0:
                assert t["lm_landmark_osm_id"][i] == 0 and t["lm_scale_step"][i] == 0
                continue
            seen[int(role)] += 1
            lmk = int(t["lm_landmark_osm_id"][i])
            frm, step, top, radius = want[lmk]
            got = (t["lm_scale_from_m"][i], t["lm_scale_step"][i], t["lm_max_scale"][i], t["lm_radius_m"][i])
            assert got == pytest.approx((frm, step, top, radius), rel=1e-5)
            centre = np.array([t["lm_centre_x"][i], t["lm_centre_y"][i], t["lm_centre_z"][i]])
            mine = pos[fid == i]
            if role == 1:  # a landmark's own vertices lie in its footprint circle around the centre, above ground
                assert t["building_osm_id"][i] == lmk
                horiz = np.hypot(mine[:, 0] - centre[0], mine[:, 2] - centre[2])
                assert horiz.max() <= radius + 0.5 and mine[:, 1].min() >= centre[1] - 0.5
            else:  # a neighbour lies on its side of the landmark, at its gap
                osm = int(t["building_osm_id"][i])
                assert gaps[osm][0] == lmk and t["lm_gap_m"][i] == pytest.approx(gaps[osm][1], abs=1e-3)
                d = np.array([t["lm_dir_x"][i], t["lm_dir_y"][i], t["lm_dir_z"][i]])
                assert np.linalg.norm(d) == pytest.approx(1, abs=1e-5) and d[1] == 0
                assert ((mine - centre) @ d).mean() > 0
    assert seen[1] >= len(want) and seen[2] > 0, seen
    report = validate_glb(c.tiles)
    assert report["errors"] == 0 and report["warnings"] == 0, report["reports"][:3]


def test_triangle_counts_and_run_record(city, conn_of) -> None:
    c = city("helsinki")
    conn = conn_of(c.url)
    total = 0
    for p in c.tiles.rglob("*.glb"):
        gltf, _ = read_glb(p.read_bytes())
        # every mesh (a wide compact tile has one per chunk of features) and primitive
        total += sum(
            gltf["accessors"][prim["indices"]]["count"] // 3 for m in gltf["meshes"] for prim in m["primitives"]
        )
        assert gltf["asset"]["copyright"].startswith("© OpenStreetMap contributors")
    stored, features = conn.execute(
        "SELECT sum(content_triangles)::bigint, sum(content_features)::bigint FROM tiles.tile"
    ).fetchone()
    assert 0.99 * stored <= total <= stored  # only zero-area triangles are dropped
    counts = conn.execute("SELECT counts FROM meta.pipeline_run WHERE stage = 'export' AND status = 'ok'").fetchone()[0]
    assert counts["triangles"] == total and counts["features"] == features
    ts = json.loads((c.tiles / "tileset.json").read_text())
    assert ts["asset"]["version"] == "1.1" and ts["extras"]["copyright"].startswith("©")


def test_export_never_deletes_a_foreign_directory(city, new_db, tmp_path) -> None:
    url = new_db("export_foreign")  # its own database: the shared city databases are read-only
    for stage in (("ingest", "--osm", str(city("fixtures").osm)), ("lod",), ("tiles",), ("generalize",)):
        run_etl(url, *stage)
    victim = tmp_path / "notes"
    victim.mkdir()
    (victim / "thesis.tex").write_text("precious")
    proc = run_etl(url, "export", "--out", str(victim), check=False)
    assert proc.returncode != 0 and "refusing to overwrite" in proc.stderr
    assert (victim / "thesis.tex").read_text() == "precious"
    # a tileset citylod wrote, and a crashed export's leftovers, are replaced
    out = tmp_path / "ts"
    run_etl(url, "export", "--out", str(out))
    (tmp_path / "ts.partial").mkdir()
    (tmp_path / "ts.partial" / ".citylod-partial").touch()
    run_etl(url, "export", "--out", str(out))
    assert (out / "tileset.json").exists() and not (tmp_path / "ts.partial").exists()


def test_stale_tiles_are_refused(city, new_db, tmp_path) -> None:
    url = new_db("export_stale")
    run_etl(url, "ingest", "--osm", str(city("fixtures").osm))
    run_etl(url, "lod")
    run_etl(url, "tiles")
    proc = run_etl(url, "export", "--out", str(tmp_path / "ts"), check=False)
    assert proc.returncode != 0 and "run the generalize stage" in proc.stderr
    run_etl(url, "generalize")
    with psycopg.connect(url, autocommit=True) as conn:  # a mesh gone behind the tiles' back
        conn.execute("DELETE FROM lod.building_mesh WHERE building_id = 10001 AND lod = 3")
    proc = run_etl(url, "export", "--out", str(tmp_path / "ts"), check=False)
    assert proc.returncode != 0 and "tiles are stale" in proc.stderr
    run_etl(url, "lod")  # a new lod run empties the tiles
    proc = run_etl(url, "export", "--out", str(tmp_path / "ts"), check=False)
    assert proc.returncode != 0 and "run the tiles stage" in proc.stderr
    run_etl(url, "tiles")
    run_etl(url, "generalize")
    run_etl(url, "export", "--out", str(tmp_path / "ts"))


def test_placement_against_the_osm_file_itself(lod2, conn_of) -> None:
    """Independent of PostGIS/PROJ: exported vertices, through the node matrix, the root transform and our own
    ECEF->geodetic, must land on the fixture's node coordinates (as written in the .osm file) at the tagged
    heights."""
    import math
    import xml.etree.ElementTree as ET

    from core.geodesy import ecef_to_geodetic
    from tests.conftest import FIXTURES

    root = ET.parse(FIXTURES / "100_square.osm").getroot()
    nodes = np.array([(float(n.get("lon")), float(n.get("lat"))) for n in root.iter("node")])
    url, tiles = lod2
    uri = tile_of(conn_of(url), 10001)
    verts, _ = feature_vertices(tiles, uri, 10001)
    m = tile_world(tiles, uri)
    ecef = (np.c_[verts, np.ones(len(verts))] @ m.T)[:, :3]
    lon, lat, h = ecef_to_geodetic(ecef).T
    lonlat = np.degrees(np.c_[lon, lat])
    # in metres (1e-8 degrees is about a millimetre here): within the compact geometry's bound at leaves, 1 cm
    # (KHR_mesh_quantization, exporter/gltf.py), plus a millimetre
    metres = np.radians(lonlat[:, None, :] - nodes[None, :, :]) * 6_371_000.0
    metres[..., 0] *= np.cos(np.radians(nodes[None, :, 1]))
    assert np.linalg.norm(metres, axis=2).min(axis=1).max() < LEAF_POSITION_ERROR_M + 1e-3  # horizontal
    tol = LEAF_POSITION_ERROR_M + 1e-3
    assert np.all(np.minimum(np.abs(h), np.abs(h - 12.0)) < tol)
    assert math.isclose(h.max(), 12.0, abs_tol=tol) and math.isclose(h.min(), 0.0, abs_tol=tol)


def _tree_bytes(root) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_the_same_files_from_one_process_or_dask_workers_and_a_hung_tile_keeps_the_old_tileset(city, tmp_path) -> None:
    """Tiles written in the export's own process or as Dask tasks on 2 workers are the same bytes (Helsinki:
    textured, compact); a tile past its time limit stops the export with that tile named and leaves the
    tileset in place untouched."""
    c = city("helsinki")
    one, two = tmp_path / "one", tmp_path / "two"
    export_tileset(c.url, one, replace(Settings.from_env(), export_workers=1))
    export_tileset(c.url, two, replace(Settings.from_env(), export_workers=2))
    files = _tree_bytes(one)
    assert len([f for f in files if f.endswith(".glb")]) >= 5 and files == _tree_bytes(two)
    with pytest.raises(RuntimeError, match=r"tile \d+/\d+/\d+ was not written: its worker ran .* time limit"):
        export_tileset(c.url, two, replace(Settings.from_env(), export_workers=2, export_tile_timeout_s=0.001))
    assert _tree_bytes(two) == files


def test_an_export_swaps_its_tileset_in_whole_and_exports_into_one_directory_take_turns(
    city, tmp_path, monkeypatch
) -> None:
    import fcntl
    import os
    import shutil
    import sys
    import time

    from exporter import export as E

    c = city("fixtures")
    out = tmp_path / "ts"
    export_tileset(c.url, out, Settings.from_env())
    first = (out / "tileset.json").read_bytes()
    # while the old tileset is deleted, the new one is already whole at the directory's name
    seen = []
    real = shutil.rmtree

    def rmtree(path, *a, **k):
        seen.append((path, (out / "tileset.json").exists(), (out / E.PARTIAL_MARKER).exists()))
        return real(path, *a, **k)

    monkeypatch.setattr(E.shutil, "rmtree", rmtree)
    export_tileset(c.url, out, Settings.from_env(), lod=2)
    monkeypatch.setattr(E.shutil, "rmtree", real)
    assert seen and all(p != out and present and not partial for p, present, partial in seen), seen
    assert (out / "tileset.json").read_bytes() != first and not out.with_name("ts.partial").exists()
    assert check_tileset(out / "tileset.json") == []
    # another export holds the directory: this one waits for it, then writes
    with open(out.with_name(".ts.lock"), "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        proc = subprocess.Popen(
            [sys.executable, "-m", "etl", "export", "--out", str(out)],
            cwd=REPO,
            text=True,
            env={**os.environ, "DATABASE_URL": c.url},
            stderr=subprocess.PIPE,
            stdout=subprocess.PIPE,
        )
        time.sleep(8)
        assert proc.poll() is None and (out / "tileset.json").read_bytes() != first
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0 and "waiting for the export already writing" in err
    assert (out / "tileset.json").read_bytes() == first
