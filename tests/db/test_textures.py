"""Stage textures on a real city (the Helsinki demo extract): bounded pages, a UV for every corner of every textured
feature inside its chart, utilization as stored, coarser tiles with fewer texels per metre, the same bytes on
a second run, features in = textured + failed; and the export: glTF-Validator 0 errors, one material per
atlas page (not per building), the DB server's bytes the file's, windows where the LOD3 panels are."""

from __future__ import annotations

import contextlib
import hashlib
import http.client
import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np
import psycopg
import pytest

from core.semantics import SEM_WALL, SEM_WINDOW
from core.settings import Settings
from core.wkb import decode_triangles
from etl.textures import atlas as A
from exporter.checks import check_tileset
from exporter.gltf import read_glb
from exporter.serve.app import make_app
from exporter.serve.reader import reader_url
from exporter.serve.source import DbTileSource
from tests.conftest import REPO, helsinki, run_etl, validate_glb
from tests.support.servers import threaded
from tests.unit.test_textures_ktx2 import IDENTIFIER, assert_ktx2_report, read_ktx2

S = Settings()


@pytest.fixture(scope="module")
def textured(new_db: Callable[[str], str], tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path, dict]:
    """Helsinki through every stage, textures included, exported: (url, tileset dir, the textures run's counts)."""
    url = new_db("textures")
    run_etl(url, "ingest", "--osm", str(helsinki()))
    for stage in ("lod", "landmarks", "tiles", "generalize", "textures"):
        run_etl(url, stage)
    out = tmp_path_factory.mktemp("textures") / "helsinki"
    run_etl(url, "export", "--out", str(out))
    with psycopg.connect(url) as conn:
        counts = conn.execute(
            "SELECT counts FROM meta.pipeline_run WHERE stage = 'textures' AND status = 'ok' "
            "ORDER BY run_id DESC LIMIT 1"
        ).fetchone()[0]
    return url, out, counts


@pytest.fixture(scope="module")
def webp_export(textured: tuple[str, Path, dict], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The same database exported with --textures webp (the default export above is KTX2)."""
    out = tmp_path_factory.mktemp("textures-webp") / "helsinki"
    run_etl(textured[0], "export", "--out", str(out), "--textures", "webp")
    return out


def pages(conn: psycopg.Connection) -> list[tuple]:
    return conn.execute("""SELECT level, x, y, page_no, width, height, utilization, rects, n_charts, padding,
                                  texels_per_metre FROM tex.page ORDER BY 1, 2, 3, 4""").fetchall()


def test_pages_are_bounded_and_their_utilization_is_what_they_hold(textured, conn_of) -> None:
    url, _, counts = textured
    conn = conn_of(url)
    rows = pages(conn)
    assert rows and all(0 < w <= S.tex_page_size and 0 < h <= S.tex_page_size for _, _, _, _, w, h, *_ in rows)
    content = total = 0
    for level, x, y, p, w, h, util, rects, n, pad, _ in rows:
        r = np.frombuffer(rects, "<i4").reshape(-1, 4)
        assert len(r) == n > 0
        # chart boxes (with their gutters) inside the page and apart from each other
        x0, y0, x1, y1 = r[:, 0] - pad, r[:, 1] - pad, r[:, 0] + r[:, 2] + pad, r[:, 1] + r[:, 3] + pad
        assert (x0 >= 0).all() and (y0 >= 0).all() and (x1 <= w).all() and (y1 <= h).all(), (level, x, y, p)
        cover = np.zeros((h, w), np.int32)
        for a, b, c, d in zip(x0, y0, x1, y1, strict=True):
            cover[b:d, a:c] += 1
        assert cover.max() == 1, (level, x, y, p)
        assert util == pytest.approx((r[:, 2] * r[:, 3]).sum() / (w * h), rel=1e-6)
        content += int((r[:, 2] * r[:, 3]).sum())
        total += w * h
    # the target, measured: >= 80 % of the atlas texels hold chart texels
    assert content / total >= 0.8
    assert counts["utilization"] == pytest.approx(content / total, abs=1e-4)


def test_every_textured_feature_has_a_uv_in_its_chart_for_every_corner(textured, conn_of) -> None:
    url, _, counts = textured
    conn = conn_of(url)
    feats = {
        (r[0], r[1], r[2], r[3], r[4]): r[5]
        for r in conn.execute(
            """SELECT t.level, t.x, t.y, f.feature_kind, f.building_id, f.n_triangles
           FROM tiles.tile t CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f"""
        )
    }
    uvs = conn.execute("""SELECT level, x, y, feature_kind, feature_id, n_triangles, page, uv FROM tex.feature_uv
                          ORDER BY 1, 2, 3, 4, 5""").fetchall()
    failed = conn.execute("SELECT count(*) FROM tex.failure").fetchone()[0]
    # count in = count out + rejects
    assert len(feats) == len(uvs) + failed == counts["features"] == counts["textured"] + counts["failed"]
    dims = {
        (r[0], r[1], r[2], r[3]): (r[4], r[5], np.frombuffer(r[7], "<i4").reshape(-1, 4), r[9]) for r in pages(conn)
    }
    for level, x, y, kind, fid, n, page, uv in uvs:
        assert feats[(level, x, y, kind, fid)] == n  # the mesh the exporter writes has n triangles
        pg = np.frombuffer(page, "<i2")
        corner = np.frombuffer(uv, "<f4").reshape(n, 3, 2)
        assert len(pg) == n and (pg >= 0).all()
        assert (corner >= 0).all() and (corner <= 1).all()
        for p in np.unique(pg).tolist():
            w, h, rects, _ = dims[(level, x, y, p)]
            px = corner[pg == p] * [w, h]
            lo, hi = px.min(axis=1), px.max(axis=1)
            inside = (
                (lo[:, None, :] >= rects[None, :, :2] - 1e-3)
                & (hi[:, None, :] <= rects[None, :, :2] + rects[None, :, 2:] + 1e-3)
            ).all(axis=2)
            assert inside.any(axis=1).all(), (level, x, y, kind, fid)  # every triangle inside one chart


def test_coarser_tiles_get_fewer_texels_per_metre(textured, conn_of) -> None:
    conn = conn_of(textured[0])
    rho = {
        (r[0], r[1], r[2]): (r[3], r[4], r[5])
        for r in conn.execute(
            """SELECT DISTINCT t.level, t.x, t.y, p.texels_per_metre, t.geometric_error, p.view_distance_m
           FROM tex.page p JOIN tiles.tile t USING (level, x, y)"""
        )
    }
    for (level, x, y), (r, err, d) in rho.items():
        # the thesis' rule at the distance the tile is first drawn from, capped
        want = (
            min(S.tex_max_texels_per_metre, S.tex_max_sse / (err * S.tex_px_per_texel))
            if err > 0
            else S.tex_max_texels_per_metre
        )
        assert r == pytest.approx(want, rel=1e-5)
        assert float(A.texels_per_metre(d, np.radians(S.tex_fov_deg), S.tex_screen_height)) == pytest.approx(r, 1e-5)
        parent = rho.get((level - 1, x // 2, y // 2))
        if parent is not None:
            assert parent[0] <= r + 1e-6
    leaves = [v[0] for v in rho.values() if v[1] == 0]
    root = rho[min(rho)]
    assert root[0] < min(leaves) / 4  # the root's blocks at a fraction of the leaves' resolution


def _digest(conn: psycopg.Connection) -> tuple[str, str]:
    a = hashlib.sha256()
    for row in conn.execute("SELECT level, x, y, page_no, bytes, ktx2 FROM tex.page ORDER BY 1, 2, 3, 4"):
        a.update(repr(row[:4]).encode() + bytes(row[4]) + bytes(row[5] or b""))
    b = hashlib.sha256()
    for row in conn.execute(
        "SELECT level, x, y, feature_kind, feature_id, page, uv FROM tex.feature_uv ORDER BY 1, 2, 3, 4, 5"
    ):
        b.update(repr(row[:5]).encode() + bytes(row[5]) + bytes(row[6]))
    return a.hexdigest(), b.hexdigest()


def _tiles_digest(url: str, out: Path) -> str:
    run_etl(url, "export", "--out", str(out))
    h = hashlib.sha256()
    for f in sorted(out.rglob("*")):
        if f.is_file():
            h.update(f.relative_to(out).as_posix().encode() + f.read_bytes())
    return h.hexdigest()


@contextlib.contextmanager
def dask_cluster(extra_workers: int = 1):
    """A LocalCluster of 2 workers in this process plus ``extra_workers`` `dask worker` processes started
    separately, as a user would add a machine: (scheduler address, the extra workers' Popen objects)."""
    from distributed import Client, LocalCluster

    with (
        LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster,
        Client(cluster) as client,
    ):
        extra = [
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "distributed.cli.dask_worker",
                    cluster.scheduler_address,
                    "--nthreads",
                    "1",
                    "--no-dashboard",
                    "--name",
                    f"extra-{i}",
                ],
                cwd=REPO,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            for i in range(extra_workers)
        ]
        try:
            client.wait_for_workers(2 + extra_workers, timeout=60)
            yield cluster.scheduler_address, extra
        finally:
            for proc in extra:
                proc.kill()
                proc.wait(30)


def test_the_same_bytes_with_1_and_2_workers_and_an_extra_dask_worker(textured, conn_of, tmp_path) -> None:
    """Units are Dask tasks: one in-process worker, a LocalCluster of 2, and an existing cluster (2 local workers
    plus a `dask worker` started separately) give the same pages, UVs and tiles."""
    url = textured[0]
    conn = conn_of(url)
    before = _digest(conn)
    tiles = _tiles_digest(url, tmp_path / "first")
    run_etl(url, "textures", env={"CITYLOD_TEX_WORKERS": "1"})
    assert _digest(conn) == before
    run_etl(url, "textures", env={"CITYLOD_TEX_WORKERS": "2"})
    assert _digest(conn) == before
    with dask_cluster() as (address, _):
        proc = run_etl(url, "textures", env={"CITYLOD_DASK_SCHEDULER": address, "CITYLOD_TEX_WORKERS": "2"})
        assert "textures: in" in proc.stdout
    assert _digest(conn) == before
    assert _tiles_digest(url, tmp_path / "again") == tiles


def test_a_worker_killed_mid_run_loses_nothing(textured, conn_of) -> None:
    """The extra `dask worker` is killed while the stage runs: its task runs again on another worker, so the
    pages are the same bytes and no feature goes to tex.failure."""
    url = textured[0]
    conn = conn_of(url)
    before = _digest(conn)
    failed_before = conn.execute("SELECT count(*) FROM tex.failure").fetchone()[0]
    with dask_cluster() as (address, extra):
        env = {**os.environ, "DATABASE_URL": url, "CITYLOD_DASK_SCHEDULER": address, "CITYLOD_TEX_WORKERS": "2"}
        stage = subprocess.Popen(
            [sys.executable, "-m", "etl", "textures"],
            cwd=REPO,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        # the extra worker dies while it runs a unit of the stage
        from distributed import Client

        busy = False
        with Client(address) as client:
            addr = next(a for a, w in client.scheduler_info()["workers"].items() if w.get("name") == "extra-0")
            deadline = time.monotonic() + 300
            while not busy and time.monotonic() < deadline and stage.poll() is None:
                busy = any(str(k).startswith("citylod-") for k in client.processing().get(addr, ()))
                time.sleep(0.02)
            extra[0].kill()
        out, err = stage.communicate(timeout=900)
        assert busy, "the extra worker never ran a unit"
    assert stage.returncode == 0, err
    assert _digest(conn) == before
    assert conn.execute("SELECT count(*) FROM tex.failure").fetchone()[0] == failed_before
    run = conn.execute(
        "SELECT counts FROM meta.pipeline_run WHERE stage = 'textures' AND status = 'ok' ORDER BY run_id DESC LIMIT 1"
    ).fetchone()[0]
    assert run["units_lost"] == 0


def test_every_page_is_stored_as_webp_and_as_ktx2_with_its_mip_chain(textured, conn_of) -> None:
    conn = conn_of(textured[0])
    rows = conn.execute("SELECT width, height, format, bytes, ktx2, ktx2_n_bytes, ktx2_levels FROM tex.page").fetchall()
    assert rows
    for w, h, fmt, webp, k2, n, levels in rows:
        assert w & (w - 1) == 0 and h & (h - 1) == 0  # powers of two a side
        assert fmt == "webp" and A.decode_image(bytes(webp), "webp").shape[:2] == (h, w)
        k = read_ktx2(bytes(k2))
        assert len(k2) == n and (k["width"], k["height"]) == (w, h)
        assert k["levels"] == levels == max(w, h).bit_length()  # every level down to 1 x 1
        assert k["scheme"] == 1 and k["color_model"] == 163 and k["transfer"] == 2  # ETC1S BasisLZ, sRGB
    counts = textured[2]
    assert counts["ktx2_pages"] == counts["pages"] == len(rows) and counts["ktx2_failed"] == 0
    assert counts["ktx2_bytes"] == sum(r[5] for r in rows)


@pytest.mark.parametrize("fmt", ["ktx2", "webp"])
def test_export_validates_with_one_material_per_page(fmt, textured, webp_export, conn_of) -> None:
    url, out, _ = textured
    out = out if fmt == "ktx2" else webp_export
    conn = conn_of(url)
    report = validate_glb(out)
    if fmt == "ktx2":
        assert_ktx2_report(report)
    else:
        assert report["errors"] == 0 and report["warnings"] == 0, report["reports"][:3]
    assert check_tileset(out / "tileset.json") == []
    ext, mime = {"ktx2": ("KHR_texture_basisu", "image/ktx2"), "webp": ("EXT_texture_webp", "image/webp")}[fmt]
    n_pages = dict(
        ((r[0], r[1], r[2]), r[3]) for r in conn.execute("SELECT level, x, y, count(*) FROM tex.page GROUP BY 1, 2, 3")
    )
    features = textured_tiles = 0
    for glb in sorted(out.rglob("*.glb")):
        level, x, y = (int(p) for p in glb.relative_to(out / "content").with_suffix("").parts)
        gltf, _ = read_glb(glb.read_bytes())
        prims = [p for m in gltf["meshes"] for p in m["primitives"]]
        with_texture = [p for p in prims if "TEXCOORD_0" in p["attributes"]]
        materials = {p["material"] for p in with_texture}
        assert len(materials) == len(gltf.get("images", [])) <= n_pages.get((level, x, y), 0)
        if with_texture:
            textured_tiles += 1
            materials = {p["material"] for p in with_texture}
            assert len(materials) == len(gltf["images"])  # one material per page, never per building
            # compact geometry's (texcoords in quarter texels, scaled back per material)
            geometry = {"KHR_mesh_quantization", "KHR_meshopt_compression", "KHR_texture_transform"}
            assert set(gltf["extensionsRequired"]) - geometry == {ext}
            assert all(im["mimeType"] == mime for im in gltf["images"])
            assert all(set(t["extensions"]) == {ext} for t in gltf["textures"])
            if fmt == "ktx2":
                _, binary = read_glb(glb.read_bytes())
                for im in gltf["images"]:
                    view = gltf["bufferViews"][im["bufferView"]]
                    assert binary[view["byteOffset"] : view["byteOffset"] + 12] == IDENTIFIER
        features += gltf["extensions"]["EXT_structural_metadata"]["propertyTables"][0]["count"]
        assert len({p["material"] for p in prims}) == len(gltf["materials"]) <= n_pages.get((level, x, y), 0) + 1
    assert textured_tiles == len(n_pages)
    assert features > 10 * sum(n_pages.values())  # materials (draw calls) per tile << buildings per tile


def test_window_panels_show_the_painted_windows(textured, conn_of) -> None:
    """The UV order matches the exporter's triangle order: each LOD3 window panel's UV centre samples dark
    glass on its page, each wall triangle its (lighter) wall."""
    url = textured[0]
    conn = conn_of(url)
    level, x, y = conn.execute(
        "SELECT level, x, y FROM tiles.tile WHERE is_leaf ORDER BY content_features DESC LIMIT 1"
    ).fetchone()
    imgs = {
        r[0]: A.decode_image(bytes(r[1]), "webp")
        for r in conn.execute("SELECT page_no, bytes FROM tex.page WHERE (level, x, y) = (%s, %s, %s)", (level, x, y))
    }
    uv = {
        (r[0], r[1]): (np.frombuffer(r[2], "<i2"), np.frombuffer(r[3], "<f4").reshape(-1, 3, 2))
        for r in conn.execute(
            "SELECT feature_kind, feature_id, page, uv FROM tex.feature_uv WHERE (level, x, y) = (%s, %s, %s)",
            (level, x, y),
        )
    }
    glass, wall = [], []
    for kind, bid, sem, wkb in conn.execute(
        "SELECT feature_kind, building_id, semantics, ST_AsBinary(geom) FROM api.buildings_for_tile(%s, %s, %s)",
        (level, x, y),
    ):
        s = np.frombuffer(sem, np.uint8)
        assert len(s) == len(decode_triangles(wkb))
        pg, corner = uv[(kind, bid)]
        for i in np.flatnonzero((s == SEM_WINDOW) | (s == SEM_WALL))[::7]:
            img = imgs[int(pg[i])]
            h, w = img.shape[:2]
            c = corner[i].mean(axis=0)
            rgb = img[min(int(c[1] * h), h - 1), min(int(c[0] * w), w - 1)].astype(float)
            (glass if s[i] == SEM_WINDOW else wall).append(rgb.mean())
    assert len(glass) > 50 and np.median(glass) < np.median(wall) - 40


def test_the_db_server_serves_the_textured_files(textured) -> None:
    url, out, _ = textured
    source = DbTileSource(reader_url(url, environ={}), base_height=S.base_height_m)
    try:
        with threaded(make_app(source=source)) as base:
            u = urlsplit(base)
            c = http.client.HTTPConnection(u.hostname, u.port, timeout=60)
            for glb in sorted(out.rglob("*.glb")):
                c.request("GET", "/tiles/" + glb.relative_to(out).as_posix())
                r = c.getresponse()
                body = r.read()
                assert r.status == 200 and body == glb.read_bytes(), glb
            c.close()
    finally:
        source.close()


def test_units_past_their_time_limit_are_recorded_as_failed_not_lost(textured, conn_of) -> None:
    url, _, counts = textured
    conn = conn_of(url)
    # a limit every unit exceeds: each worker's watchdog ends it mid-unit (as it would a hang in native code)
    proc = run_etl(url, "textures", env={"CITYLOD_TEX_UNIT_TIMEOUT_S": "0.001", "CITYLOD_TEX_WORKERS": "2"})
    assert "Timeout (" in proc.stderr and "most recent call first" in proc.stderr  # the workers' stacks
    run = conn.execute(
        "SELECT counts FROM meta.pipeline_run WHERE stage = 'textures' AND status = 'ok' ORDER BY run_id DESC LIMIT 1"
    ).fetchone()[0]
    assert run["units_lost"] == run["units"] > 0 and run["workers"] == 2
    assert run["textured"] == 0 and run["failed"] == run["features"] == counts["features"]
    assert conn.execute("SELECT count(*) FROM tex.page").fetchone()[0] == 0
    reasons = conn.execute(
        "SELECT reason, count(*), count(DISTINCT (level, x, y, feature_kind, feature_id)), "
        "bool_and(detail LIKE '%time limit%') FROM tex.failure GROUP BY 1"
    ).fetchall()
    assert reasons == [("texturing_hung", counts["features"], counts["features"], True)]
    # every feature of every tile is there, as api.buildings_for_tile lists them
    missing = conn.execute("""
        SELECT count(*) FROM tiles.tile t, api.buildings_for_tile(t.level, t.x, t.y) f
        WHERE NOT EXISTS (SELECT 1 FROM tex.failure x WHERE (x.level, x.x, x.y, x.feature_kind, x.feature_id)
                                                            = (t.level, t.x, t.y, f.feature_kind, f.building_id))
    """).fetchone()[0]
    assert missing == 0
    run_etl(url, "textures")  # back to the module's textured state
    assert conn.execute("SELECT count(*) FROM tex.failure").fetchone()[0] == counts["failed"]


def test_pages_the_ktx2_encoder_refuses_stay_webp_and_their_features_get_vertex_colours(
    textured, conn_of, tmp_path
) -> None:
    """An encoder that fails on every page: the stage still ends well, every page keeps its WebP, every textured
    feature is in tex.failure as ktx2_encode_failed (in = textured + textured in WebP only + rejected), a KTX2
    export draws them with vertex colours and validates, a WebP export is textured as before."""
    url, _, counts = textured
    conn = conn_of(url)
    fake = tmp_path / "basisu"
    fake.write_text("#!/bin/sh\necho 'ERROR: refused' >&2\nexit 1\n")
    fake.chmod(0o755)
    try:
        run_etl(url, "textures", env={"CITYLOD_BASISU": str(fake)})
        run = conn.execute(
            "SELECT counts FROM meta.pipeline_run WHERE stage = 'textures' AND status = 'ok' "
            "ORDER BY run_id DESC LIMIT 1"
        ).fetchone()[0]
        n = counts["textured"]
        assert n > 0 and run["ktx2_failed"] == n and run["ktx2_pages"] == 0 and run["pages"] == counts["pages"]
        assert (run["textured"], run["failed"]) == (counts["textured"], counts["failed"])
        assert run["out_by_kind"] == {"textured": 0, "textured in WebP only": n}
        assert run["in"] == run["out"] + run["rejected"] == counts["features"]
        reasons = dict(
            (r[0], r[1:])
            for r in conn.execute(
                "SELECT reason, count(*), bool_and(detail LIKE '%basisu exit 1%') FROM tex.failure GROUP BY 1"
            )
        )
        assert reasons.pop("ktx2_encode_failed") == (n, True)
        assert sum(r[0] for r in reasons.values()) == counts["failed"]
        assert (
            conn.execute("SELECT count(*) FROM tex.page WHERE ktx2 IS NULL AND bytes IS NOT NULL").fetchone()[0]
            == counts["pages"]
        )
        ktx2, webp = tmp_path / "ktx2", tmp_path / "webp"
        run_etl(url, "export", "--out", str(ktx2), "--textures", "ktx2")
        run_etl(url, "export", "--out", str(webp), "--textures", "webp")
        report = validate_glb(ktx2)
        assert report["errors"] == 0 and report["warnings"] == 0, report["reports"][:3]
        assert not any("images" in read_glb(g.read_bytes())[0] for g in ktx2.rglob("*.glb"))  # vertex colours
        assert sum("images" in read_glb(g.read_bytes())[0] for g in webp.rglob("*.glb")) == len(
            {(r[0], r[1], r[2]) for r in pages(conn)}
        )
    finally:
        run_etl(url, "textures")  # back to the module's textured state
    assert conn.execute("SELECT count(*) FROM tex.page WHERE ktx2 IS NULL").fetchone()[0] == 0


def test_generalizing_again_makes_the_textures_stale(textured, tmp_path) -> None:
    url = textured[0]
    # a later generalize run: export refuses the old textures until the textures stage runs again
    run_etl(url, "generalize")
    proc = run_etl(url, "export", "--out", str(tmp_path / "stale"), check=False)
    assert proc.returncode != 0 and "textures are stale" in proc.stderr
    run_etl(url, "textures")
    run_etl(url, "export", "--out", str(tmp_path / "fresh"))
