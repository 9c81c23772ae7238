"""LOD2/LOD3 in the database: the roof gallery fixture (200_roofs.osm) and the real extracts."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from core.semantics import SEM_GROUND, SEM_ROOF, SEM_WALL
from core.wkb import decode_triangles
from etl.lod import roofs
from exporter.checks import check_tileset
from exporter.content import WINDOW_RGBA, srgb_to_linear16
from exporter.gltf import accessor_array, property_table, read_glb
from tests.conftest import run_etl, validate_glb


@pytest.fixture()
def gallery(city, conn_of):
    return conn_of(city("roofs").url)


def rows(conn, lod: int) -> dict[str, tuple]:
    return {
        r[0]: r[1:]
        for r in conn.execute(
            """SELECT b.tags->>'ref', m.roof_shape, m.roof_engine, m.roof_height, m.height, m.min_height,
                  ST_AsBinary(m.geom), m.semantics, m.watertight, m.winding_consistent, m.volume_m3, m.n_windows,
                  m.n_doors, m.n_triangles
           FROM lod.building_mesh m JOIN osm.building b ON b.id = m.building_id WHERE m.lod = %s""",
            (lod,),
        )
    }


def test_every_catalogue_shape_is_drawn_closed(gallery) -> None:
    lod2 = rows(gallery, 2)
    drawn = {v[0] for v in lod2.values()}
    assert drawn == roofs.SHAPES  # every roof:shape of the catalogue, nothing else
    for ref, (shape, _engine, rh, top, bottom, blob, sem, wt, wc, vol, *_rest) in lod2.items():
        tris = decode_triangles(blob)
        m = trimesh.Trimesh((tris - tris[0, 0]).reshape(-1, 3), np.arange(len(tris) * 3).reshape(-1, 3))
        assert m.is_watertight and m.is_winding_consistent and wt and wc, ref  # trimesh and the stage agree
        assert m.volume == pytest.approx(vol, rel=1e-6) and vol > 0, ref
        assert len(sem) == len(tris), ref
        assert tris[:, :, 2].max() == pytest.approx(top, abs=1e-6), ref  # the ridge is the tagged height
        if shape != "flat" and not ref.startswith("roof_part"):
            if "angle" not in ref and "levels0" not in ref:
                assert rh == pytest.approx(4.0), ref  # roof:height
            roof = tris[np.frombuffer(sem, np.uint8) == SEM_ROOF]
            eave = top - rh
            assert roof[:, :, 2].min() >= eave - 1e-6, ref  # no roof face below the eaves
            walls = tris[np.frombuffer(sem, np.uint8) == SEM_WALL]
            assert walls[:, :, 2].min() == pytest.approx(bottom, abs=1e-6), ref


def test_tag_variants(gallery) -> None:
    lod2 = rows(gallery, 2)
    assert lod2["fallback_key/rect"][0] == "hipped"  # building:roof:shape
    assert lod2["many/rect"][0] == "flat"
    assert lod2["gabled_across/rect"][1] == "field" and lod2["gabled/rect"][1] == "skeleton"
    # roof:angle=45 on a ~10 m wide rectangle: the roof is half the width high
    assert lod2["hipped_angle45/rect"][2] == pytest.approx(5.0, abs=0.05)
    # building:part=roof with min_height 4: no walls down to the ground
    part = lod2["roof_part/rect"]
    tris = decode_triangles(part[5])
    assert tris[:, :, 2].min() >= 4.0 - 1e-6 and part[4] == 4.0
    assert set(np.frombuffer(part[6], np.uint8)) <= {SEM_GROUND, SEM_ROOF}
    codes = dict(
        gallery.execute(
            """SELECT b.tags->>'ref', string_agg(d.code, ',' ORDER BY d.code) FROM meta.building_diagnostic d
           JOIN osm.building b ON b.id = d.building_id GROUP BY 1"""
        ).fetchall()
    )
    assert codes["many/rect"] == "unknown_roof_shape"
    assert codes["gabled_levels0/rect"] == "pitched_roof_zero_levels"
    assert codes["hipped_feet/rect"] == "unit_converted"
    # the end-wall node does not stop the gable: the same solid as the plain rectangle's, no fallback
    assert "gabled_end_node/rect" not in codes
    assert lod2["gabled_end_node/rect"][9] == pytest.approx(lod2["gabled/rect"][9], rel=5e-3)
    assert lod2["gabled_north/L"][1] == "skeleton"


def test_lod3_adds_windows_and_doors(gallery) -> None:
    lod2, lod3 = rows(gallery, 2), rows(gallery, 3)
    assert lod3 and lod3.keys() == lod2.keys()
    for ref, r3 in lod3.items():
        sem3 = np.frombuffer(r3[6], np.uint8)
        assert len(sem3) == r3[12]
        n_win, n_door = r3[10], r3[11]
        if ref.startswith("roof_part"):
            assert n_win == n_door == 0  # a roof without walls has no facade
            continue
        assert n_door == 1, ref  # on the ground, on its longest wall
        assert n_win > 0 or ref == "hipped_angle45/rect", ref
        # LOD3 = the LOD2 solid plus the openings, each triangle tagged
        assert r3[12] - lod2[ref][12] == 2 * (n_win + n_door), ref  # panels: two triangles per opening
        assert (sem3 == 3).sum() == 2 * n_win and (sem3 == 4).sum() == 2 * n_door, ref


@pytest.mark.parametrize(
    ("name", "min_pitched", "shapes"),
    [  # pitched: Helsinki 23, London 54, Munich 387
        ("helsinki", 20, {"flat", "gabled", "hipped", "pyramidal", "dome", "round", "gambrel"}),
        pytest.param(
            "munich",
            50,
            {"flat", "gabled", "hipped", "pyramidal", "dome", "skillion", "onion", "gambrel"},
            marks=pytest.mark.extracts,
        ),
        pytest.param(
            "london",
            50,
            {"flat", "gabled", "hipped", "pyramidal", "dome", "mansard", "gambrel"},
            marks=pytest.mark.extracts,
        ),
    ],
    ids=["helsinki", "munich", "london"],
)
def test_real_extract_lod2_watertight(city, conn_of, name, min_pitched, shapes) -> None:
    conn = conn_of(city(name).url)
    total, closed, pitched = conn.execute(
        """SELECT count(*), count(*) FILTER (WHERE watertight AND winding_consistent AND volume_m3 > 0),
                  count(*) FILTER (WHERE roof_shape <> 'flat') FROM lod.building_mesh WHERE lod = 2"""
    ).fetchone()
    assert pitched > min_pitched  # real roofs were built, not all flattened
    drawn = {r[0] for r in conn.execute("SELECT DISTINCT roof_shape FROM lod.building_mesh WHERE lod = 2")}
    assert shapes <= drawn  # the city's tagged shapes, each drawn as itself
    assert closed / total >= 0.995
    # roofs that could not be built are drawn flat (and closed): they must stay rare among pitched ones
    fallbacks = conn.execute(
        "SELECT count(*) FROM meta.diagnostic WHERE stage = 'lod' AND code = 'roof_fallback'"
        " AND detail LIKE '%drawn flat'"
    ).fetchone()[0]
    assert fallbacks <= 0.01 * pitched
    # every one that is not closed is in the diagnostics with its reason
    assert (
        total - closed
        == conn.execute(
            "SELECT count(*) FROM meta.diagnostic WHERE stage = 'lod' AND code = 'not_watertight'"
        ).fetchone()[0]
    )


@pytest.mark.parametrize("lod", [1, 2, 3])
def test_export_lod_option(city, conn_of, tmp_path, lod) -> None:
    c = city("roofs")
    out = tmp_path / f"lod{lod}"
    run_etl(c.url, "export", "--out", str(out), "--lod", str(lod))
    report = validate_glb(out)
    assert report["errors"] == 0 and report["warnings"] == 0, report["reports"][:3]
    assert check_tileset(out / "tileset.json") == []
    stored = (
        conn_of(c.url).execute("SELECT sum(n_triangles) FROM lod.building_mesh WHERE lod = %s", (lod,)).fetchone()[0]
    )
    written = 0
    colours: set[tuple[int, ...]] = set()
    for p in out.rglob("*.glb"):
        gltf, binary = read_glb(p.read_bytes())
        prim = gltf["meshes"][0]["primitives"][0]
        written += gltf["accessors"][prim["indices"]]["count"] // 3
        colours |= {tuple(x) for x in accessor_array(gltf, binary, prim["attributes"]["COLOR_0"]).tolist()}
        assert set(property_table(gltf, binary)["lod"]) == {lod}
    assert written == stored  # every triangle of that LOD, none of another
    window = tuple(srgb_to_linear16(WINDOW_RGBA[None])[0].tolist())
    assert (window in colours) == (lod == 3)  # window triangles are coloured from their semantic
