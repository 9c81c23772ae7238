"""Procedural textures: deterministic pixels, the tagged colour as the mean, windows exactly where facade.py puts
the LOD3 openings, metric patterns and UVs, seamless tiles, xatlas charts for curved surfaces."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import shapely
import trimesh
from scipy import ndimage

from core.semantics import SEM_DOOR, SEM_WALL, SEM_WINDOW
from etl.geom.extrude import extrude
from etl.geom.facade import FacadeParams, facades
from etl.textures import procedural as T
from etl.textures.atlas import srgb_to_linear
from tests.unit.test_geom_facade import COURT, ELL, OFF, RECT, P, walls

REPO = Path(__file__).resolve().parents[2]


def facade_rects(w: dict[str, np.ndarray], n: int) -> list[tuple]:
    """facades() on the real buildings, each panel traced back to its wall by geometry (the test's own way)."""
    f = facades(**w, n_buildings=n, params=FacadeParams(style="panel"))
    quad = f.triangles.reshape(-1, 2, 3, 3)
    d = w["b"] - w["a"]
    length = np.hypot(d[:, 0], d[:, 1])
    d = d / length[:, None]
    nrm = np.column_stack([d[:, 1], -d[:, 0]])
    out = []
    for q, kind, own in zip(quad, f.semantics[::2], f.owner[::2], strict=True):
        lo, hi = q[0, 0], q[0, 2]
        rel = lo[:2] - w["a"]
        s, off = (rel * d).sum(axis=1), (rel * nrm).sum(axis=1)
        (wall,) = np.flatnonzero(
            (np.abs(off - P.depth) < 1e-6) & (s > -1e-6) & (s < length + 1e-6) & (w["owner"] == own)
        )
        s1 = ((hi[:2] - w["a"][wall]) * d[wall]).sum()
        out.append((int(wall), round(s[wall], 6), round(s1, 6), round(lo[2], 6), round(hi[2], 6), int(kind)))
    return sorted(out)


def opening_rects(op: T.Openings) -> list[tuple]:
    return sorted(
        (int(w), round(a, 6), round(b, 6), round(c, 6), round(d, 6), int(k))
        for w, a, b, c, d, k in zip(op.wall, op.s0, op.s1, op.z0, op.z1, op.kind, strict=True)
    )


@pytest.mark.parametrize("polys", [[RECT], [ELL], [COURT], [RECT, ELL]], ids=["rect", "L", "courtyard", "two"])
def test_wall_openings_are_facade_py_openings(polys: list[shapely.Polygon]) -> None:
    parts = [walls(p, owner=i, levels=3 + i) for i, p in enumerate(polys)]
    w = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    op = T.wall_openings(**w)
    assert (np.diff(op.wall) >= 0).all()
    assert opening_rects(op) == facade_rects(w, len(polys))
    assert (op.kind == SEM_DOOR).sum() == len(polys)


def opening_boxes(img: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Texel boxes (x0, y0, x1, y1) of the windows/doors drawn on a brick wall: blue glass, white frames."""
    r, g, b = (img[..., i].astype(int) for i in range(3))
    mask = (b > r + 10) | ((r > 215) & (g > 215) & (b > 210))
    lab, n = ndimage.label(mask)
    sl = ndimage.find_objects(lab)
    return sorted((s[1].start, s[0].start, s[1].stop, s[0].stop) for s in sl)


def test_texture_windows_fall_on_the_lod3_openings() -> None:
    w = walls(RECT)
    op = T.wall_openings(**w)
    rho = 30.0  # 10 m x 9 m wall -> 300 x 270 texels; facade.py's edges land on texel edges here
    for i in range(4):
        length = float(np.hypot(*(w["b"][i] - w["a"][i])))
        img = T.facade_texture("#a0522d", "brick", 3, length, 9.0, texels_per_metre=rho, openings=op.of(i))
        assert img.shape == (270, round(length * rho), 3)
        mine = op.of(i)
        want = sorted(
            (round(s0 * rho), round((9 - z1) * rho), round(s1 * rho), round((9 - z0) * rho))
            for s0, s1, z0, z1 in zip(mine.s0, mine.s1, mine.z0, mine.z1, strict=True)
        )
        got = opening_boxes(img)
        assert len(got) == len(want) == len(mine) > 0
        np.testing.assert_allclose(np.array(got), np.array(want), atol=1)
    # the south wall (door wall): door centred at the bottom, 2 windows beside it on the ground storey
    south = op.of(0)
    assert (south.kind == SEM_DOOR).sum() == 1 and (south.kind == SEM_WINDOW).sum() == 8


def test_tile_repeats_into_the_wall_layout() -> None:
    # north wall of RECT: 10 m, 3 storeys, no door: 3 bays of pitch (10 - 2 * 0.4) / 3 = 3.0667 m
    w = walls(RECT)
    op = T.wall_openings(**w).of(2)
    assert (op.kind == SEM_WINDOW).all() and len(op) == 9
    pitch = (10 - 2 * P.margin) / 3
    rho = 30.0
    tile = T.facade_tile("#a0522d", "brick", pitch, 3.0, rho)
    assert tile.shape == (90, 92, 3)
    ((x0, y0, x1, y1),) = opening_boxes(tile)
    # the tile's window, shifted by the margin, is facade.py's first window of the first storey
    first = np.argmin(op.s0 + 100 * op.z0)
    assert (x0 + P.margin * rho, x1 + P.margin * rho) == pytest.approx((op.s0[first] * rho, op.s1[first] * rho), abs=1)
    assert (y0, y1) == pytest.approx(((3 - op.z1[first]) * rho, (3 - op.z0[first]) * rho), abs=1)
    # u' = (u - margin) / pitch, v' = v / storey repeats it over every bay and storey of the wall
    wall = T.facade_texture("#a0522d", "brick", 3, 10.0, 9.0, texels_per_metre=rho, openings=op)
    reps = np.tile(tile, (3, 3, 1))
    m = round(P.margin * rho)
    got = {(a + m, b, c + m, d) for a, b, c, d in opening_boxes(reps)}
    assert len(got) == 9 and got == set(opening_boxes(wall))


def test_deterministic_and_driven_by_the_inputs() -> None:
    a = T.facade_texture("#a0522d", "brick", 3, 12.0, 9.0, texels_per_metre=16, seed=5)
    assert (
        a.dtype == np.uint8
        and a.tobytes() == T.facade_texture("#a0522d", "brick", 3, 12.0, 9.0, texels_per_metre=16, seed=5).tobytes()
    )
    assert not np.array_equal(a, T.facade_texture("#4682b4", "brick", 3, 12.0, 9.0, texels_per_metre=16, seed=5))
    assert not np.array_equal(a, T.facade_texture("#a0522d", "brick", 3, 12.0, 9.0, texels_per_metre=16, seed=6))
    assert not np.array_equal(a, T.facade_texture("#a0522d", "stone", 3, 12.0, 9.0, texels_per_metre=16, seed=5))
    # building:levels sets the rows (a 12 m wall: 3 columns), as in facade.py
    assert len(T.wall_openings([[0, 0]], [[12, 0]], [0], 0, 12, 4, False, True)) == 12
    assert len(T.wall_openings([[0, 0]], [[12, 0]], [0], 0, 12, 3, False, True)) == 9
    assert not np.array_equal(
        T.facade_texture(None, "brick", 4, 12.0, 12.0, texels_per_metre=8),
        T.facade_texture(None, "brick", 3, 12.0, 12.0, texels_per_metre=8),
    )
    r = T.roof_texture("#708090", "slate", 8.0, 5.0, texels_per_metre=20, seed=1)
    assert r.tobytes() == T.roof_texture("#708090", "slate", 8.0, 5.0, texels_per_metre=20, seed=1).tobytes()


def test_same_pixels_in_another_process() -> None:
    # no salted hash() or unseeded randomness anywhere: a fresh interpreter with another hash seed agrees
    code = (
        "import hashlib; from etl.textures import procedural as T; "
        "print(hashlib.sha256(T.facade_texture('#a0522d', 'brick', 3, 12.0, 9.0, texels_per_metre=16).tobytes()"
        " + T.roof_texture(None, 'roof_tiles', 6.0, 4.0, texels_per_metre=16).tobytes()).hexdigest())"
    )
    env = dict(os.environ, PYTHONHASHSEED="12345")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, check=True)
    import hashlib

    here = hashlib.sha256(
        T.facade_texture("#a0522d", "brick", 3, 12.0, 9.0, texels_per_metre=16).tobytes()
        + T.roof_texture(None, "roof_tiles", 6.0, 4.0, texels_per_metre=16).tobytes()
    ).hexdigest()
    assert out.stdout.strip() == here


def test_tags_pick_material_and_colour() -> None:
    assert T.wall_material("Brick") == "brick" and T.wall_material("timber_framing") == "wood"
    assert T.wall_material("reinforced_concrete") == "concrete" and T.wall_material("unobtainium") == "default"
    assert T.wall_material(None) == "default"
    assert T.roof_material("tiles") == "roof_tiles" and T.roof_material("metal_sheet") == "metal"
    assert T.roof_material("plants") == "grass" and T.roof_material(None) == "default"
    assert T.parse_rgb("red", (1, 2, 3)) == (255, 0, 0) and T.parse_rgb("#0f0", (1, 2, 3)) == (0, 255, 0)
    assert T.parse_rgb("not a colour", (1, 2, 3)) == (1, 2, 3) and T.parse_rgb(None, (1, 2, 3)) == (1, 2, 3)


@pytest.mark.parametrize(
    "kind,material", [("wall", m) for m in T.WALL_MATERIALS] + [("roof", m) for m in T.ROOF_MATERIALS]
)
def test_tagged_colour_is_the_mean_colour(kind: str, material: str) -> None:
    colour = (150, 110, 90)
    img = T.material_texture(colour, material, 12.0, 9.0, texels_per_metre=24, kind=kind, seed=3)
    mean = srgb_to_linear(img).reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(mean, srgb_to_linear(np.array(colour)), rtol=0.03, atol=0.002)
    # untagged: the material's own colour
    own = (T.WALL_COLOURS if kind == "wall" else T.ROOF_COLOURS)[material]
    img = T.material_texture(None, material, 12.0, 9.0, texels_per_metre=24, kind=kind, seed=3)
    np.testing.assert_allclose(
        srgb_to_linear(img).reshape(-1, 3).mean(axis=0), srgb_to_linear(np.array(own)), rtol=0.03, atol=0.002
    )


def test_patterns_are_metric_and_filtered() -> None:
    # a 10 m and a 20 m wall at the same density: the first 10 m are the same texels (same bricks, same places)
    ten = T.facade_texture(None, "brick", None, 10.0, 6.0, texels_per_metre=32, openings=T.Openings.none())
    twenty = T.facade_texture(None, "brick", None, 20.0, 6.0, texels_per_metre=32, openings=T.Openings.none())
    assert ten.shape == (192, 320, 3) and twenty.shape == (192, 640, 3)
    np.testing.assert_array_equal(twenty[:, :320], ten)
    # stripes are box-filtered exactly: a coarse texel is the mean of the fine texels it covers
    x_fine = (np.arange(800) + 0.5) * 0.01
    x_coarse = (np.arange(100) + 0.5) * 0.08
    fine = T._stripes(x_fine, 0.01, 0.075, 0.01)
    np.testing.assert_allclose(T._stripes(x_coarse, 0.08, 0.075, 0.01), fine.reshape(100, 8).mean(axis=1), atol=1e-9)
    # a coarse wall keeps the fine wall's mean colour (nothing aliases into a brighter or darker wall)
    hi = T.facade_texture(None, "brick", 3, 10.0, 9.0, texels_per_metre=40)
    lo = T.facade_texture(None, "brick", 3, 10.0, 9.0, texels_per_metre=4)
    np.testing.assert_allclose(srgb_to_linear(lo).mean(axis=(0, 1)), srgb_to_linear(hi).mean(axis=(0, 1)), rtol=0.05)


@pytest.mark.parametrize("material", ["brick", "stone", "wood", "concrete", "plaster"])
def test_tiles_are_seamless(material: str) -> None:
    span = (3.2, 2.9)
    a = T.material_texture(None, material, *span, texels_per_metre=40, tile=True)
    b = T.material_texture(None, material, *span, texels_per_metre=40, tile=True, origin=(span[0], 0.0))
    c = T.material_texture(None, material, *span, texels_per_metre=40, tile=True, origin=(0.0, span[1]))
    assert np.abs(a.astype(int) - b).max() <= 1 and np.abs(a.astype(int) - c).max() <= 1


def test_metric_wall_uvs() -> None:
    # quads of a 10 m and a 20 m wall, both 9 m high from z = 2
    for length in (10.0, 20.0):
        a, b = OFF, OFF + np.array([length * 0.6, length * 0.8])  # not axis-aligned
        pts = np.array([[*a, 2.0], [*b, 2.0], [*b, 11.0], [*a, 11.0]])
        uv = T.wall_uvs(pts, np.tile(a, (4, 1)), np.tile(b, (4, 1)), np.full(4, 2.0))
        np.testing.assert_allclose(uv, [[0, 0], [length, 0], [length, 9], [0, 9]], atol=1e-6)
    # the same from extruded meshes, by planar charts: wall charts of 10 x 9 and 20 x 9 m, u from a, v from z0
    ext = extrude(
        np.array([shapely.box(*OFF, *(OFF + [10, 6])), shapely.box(*(OFF + 30), *(OFF + [50, 36]))]),
        np.zeros(2),
        np.full(2, 9.0),
    )
    owner = np.repeat(np.arange(2), ext.counts)
    wall = ext.semantics == SEM_WALL
    ch = T.planar_charts(ext.triangles[wall], owner[wall])
    assert sorted(map(tuple, np.round(ch.size, 9).tolist())) == [
        (6, 9),
        (6, 9),
        (6, 9),
        (6, 9),
        (10, 9),
        (10, 9),
        (20, 9),
        (20, 9),
    ]
    assert ch.uv.min() == pytest.approx(0) and (ch.uv[..., 1].max(axis=1) <= 9 + 1e-9).all()
    # u runs along a -> b: on the south wall (y = const, a -> b = +x) u grows with x
    south = np.flatnonzero(np.all(np.abs(ext.triangles[wall][:, :, 1] - OFF[1]) < 1e-9, axis=1))
    tri = ext.triangles[wall][south]
    np.testing.assert_allclose(ch.uv[south][..., 0], tri[..., 0] - OFF[0], atol=1e-6)
    np.testing.assert_allclose(ch.uv[south][..., 1], tri[..., 2], atol=1e-9)


def test_roof_charts_follow_the_slope() -> None:
    # gabled roof 10 m along the ridge, 8 m across, ridge 3 m up: two 10 x 5 m faces (slope length 5)
    p = {
        k: np.array(v, float)
        for k, v in dict(a=[0, 0, 0], b=[10, 0, 0], c=[10, 8, 0], d=[0, 8, 0], r0=[0, 4, 3], r1=[10, 4, 3]).items()
    }
    tris = np.array(
        [[p["a"], p["b"], p["r1"]], [p["a"], p["r1"], p["r0"]], [p["c"], p["d"], p["r0"]], [p["c"], p["r0"], p["r1"]]]
    )
    ch = T.planar_charts(tris)
    assert ch.chart.tolist() in ([0, 0, 1, 1], [1, 1, 0, 0])
    np.testing.assert_allclose(ch.size, [[10, 5], [10, 5]], atol=1e-9)
    # v goes up the slope: the eaves are at v = 0, the ridge at v = 5, on both faces
    for k in (0, 2):
        eave = tris[k][:, 2] == 0
        np.testing.assert_allclose(ch.uv[k][eave, 1], 0, atol=1e-9)
        np.testing.assert_allclose(ch.uv[k][~eave, 1], 5, atol=1e-9)


def test_xatlas_charts_for_a_dome() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=6.0)
    keep = sphere.triangles_center[:, 2] > 0
    dome = trimesh.Trimesh(sphere.vertices + [*OFF, 20.0], sphere.faces[keep], process=False)
    ch = T.chart_uvs(dome.vertices, dome.faces, texels_per_metre=8.0)
    assert len(ch.faces) == len(dome.faces) and ch.chart.max() >= 1
    np.testing.assert_allclose(dome.vertices[ch.vertex[ch.faces]], dome.vertices[dome.faces])  # same faces, order
    assert (ch.local >= 0).all() and (ch.local <= 1).all()
    # metric: the charts' total area in metres^2 is the dome's surface area (xatlas charts are near-isometric)
    t = ch.uv_m[ch.faces]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    assert uv_area == pytest.approx(dome.area, rel=0.1)
    assert ch.size_m[0] * ch.size_m[1] >= uv_area
    again = T.chart_uvs(dome.vertices, dome.faces, texels_per_metre=8.0)
    np.testing.assert_array_equal(again.local, ch.local)
