"""Texturing a tile (etl/textures/texturing.py): every triangle corner lands in its chart on a bounded page, LOD3
window panels land on the windows painted into their wall, the batched page renderer draws what
textures.facade_texture draws, a LOD2 tile reuses its leaves' charts, small charts become flat colours."""

import math
import zlib

import numpy as np
import pytest
import shapely
import trimesh

from core.semantics import SEM_DOOR, SEM_ROOF, SEM_WALL, SEM_WINDOW
from etl.geom.extrude import extrude
from etl.geom.facade import FacadeParams, facades
from etl.textures import atlas as A
from etl.textures import procedural as T
from etl.textures import texturing as X

OFF = np.array([385_000.0, 6_672_000.0])  # UTM-sized coordinates
BOXES = [(0, 0, 12, 8, 9.0, 3.0), (20, 0, 38, 10, 6.0, 2.0), (0, 20, 8, 50, 15.0, 5.0)]  # x0 y0 x1 y1 top levels
# a building key whose pattern shift is 0 (texturing shifts each building's pattern by a multiple of 9 m)
UNSHIFTED = next(k for k in range(10_000) if zlib.crc32(str(k).encode()) % 97 == 0)


def city(boxes=BOXES, lod: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Extruded boxes (LOD2 = LOD1 here) plus facade.py's window/door panels (LOD3), as lod.py builds them."""
    polys = np.array([shapely.box(*(OFF + [x0, y0]), *(OFF + [x1, y1])) for x0, y0, x1, y1, _, _ in boxes])
    top = np.array([b[4] for b in boxes])
    ex = extrude(polys, np.zeros(len(boxes)), top)
    own = np.repeat(np.arange(len(boxes)), ex.counts)
    tri, feat, sem = ex.triangles, own, ex.semantics
    if lod == 3:
        w = ex.walls
        f = facades(
            w.a,
            w.b,
            w.owner,
            np.zeros(len(w.a)),
            top[w.owner],
            np.array([b[5] for b in boxes])[w.owner],
            np.ones(len(w.a), bool),
            w.exterior,
            len(boxes),
            FacadeParams(style="panel"),
        )
        tri = np.concatenate([tri, f.triangles])
        feat = np.concatenate([feat, f.owner])
        sem = np.concatenate([sem, f.semantics])
    return tri, feat, sem


def styles(boxes=BOXES, material: str = "brick", generic: bool = False) -> list[X.Style]:
    return [
        X.Style.from_tags(UNSHIFTED + i, material, "#a0522d", "roof_tiles", "#80302a", b[5], generic)
        for i, b in enumerate(boxes)
    ]


def texel(tt: X.TileTexture, page: int, uv: np.ndarray) -> np.ndarray:
    img = tt.pages[page]
    h, w = img.shape[:2]
    return img[min(int(uv[1] * h), h - 1), min(int(uv[0] * w), w - 1)].astype(int)


@pytest.mark.parametrize("padding", [2, 1, 0])
def test_every_corner_lands_in_its_chart_on_a_bounded_page(padding: int) -> None:
    tri, feat, sem = city()
    tt = X.texture_tile(tri, feat, sem, styles(), 4.0, X.Params(page_size=128, padding=padding))
    assert tt.layout.n_pages >= 3  # 37k texels of charts: several 128 x 128 pages, strips cut to fit
    assert all(p.shape[0] <= 128 and p.shape[1] <= 128 for p in tt.pages) and tt.stats["scaled"] == 0
    # every side a power of two (the KTX2 pages' full mip chains), the page's pixels exactly that size
    assert all(s & (s - 1) == 0 for p in tt.pages for s in p.shape[:2])
    assert [p.shape[1::-1] for p in tt.pages] == [tuple(d) for d in tt.layout.page_dims.tolist()]
    assert (tt.tri_page >= 0).all() and tt.tri_page.max() < len(tt.pages)
    dims = tt.layout.page_dims[tt.tri_page].astype(float)
    px = tt.tri_uv * dims[:, None, :]  # texel coordinates of every corner
    for p in range(len(tt.pages)):
        rects = tt.page_rects(p)
        on = tt.tri_page == p
        lo, hi = px[on].min(axis=1), px[on].max(axis=1)
        inside = (
            (lo[:, None, :] >= rects[None, :, :2] - 1e-3)
            & (hi[:, None, :] <= rects[None, :, :2] + rects[None, :, 2:] + 1e-3)
        ).all(axis=2)
        assert inside.any(axis=1).all()  # each triangle lies in one chart's box
        # utilization is the charts' share of the page
        h, w = tt.pages[p].shape[:2]
        assert tt.layout.utilization[p] == pytest.approx((rects[:, 2] * rects[:, 3]).sum() / (w * h))
    if padding == 0:
        # no gutters: the edge texels are centred on the charts' edges
        frac = (px[..., 0] - np.floor(px[..., 0]))[tt.tri_page >= 0]
        assert np.isclose(frac, 0.5).any()


def test_window_panels_land_on_the_painted_windows() -> None:
    tri, feat, sem = city()
    tt = X.texture_tile(tri, feat, sem, styles(), 8.0)
    win = np.flatnonzero(sem == SEM_WINDOW)
    wall = np.flatnonzero(sem == SEM_WALL)
    assert tt.stats["panels_mapped"] == int(((sem == SEM_WINDOW) | (sem == SEM_DOOR)).sum())
    # the centre of each window's glass: dark blue-grey, not the red brick around it
    glass = np.array([texel(tt, tt.tri_page[i], tt.tri_uv[i].mean(axis=0)) for i in win[::2]])
    brick = np.array([texel(tt, tt.tri_page[i], tt.tri_uv[i].mean(axis=0)) for i in wall])
    assert np.median(glass[:, 2] - glass[:, 0]) > 10  # blue above red
    assert np.median(brick[:, 0] - brick[:, 2]) > 40  # red above blue
    # a panel's UVs lie inside its wall's texture: its corners map like the wall's points behind it
    assert (tt.tri_page[win] >= 0).all()


def test_batched_renderer_draws_what_facade_texture_draws() -> None:
    length, height, rho = 14.0, 9.0, 10.0  # chart edges on texel edges
    a, b = np.array([[0.0, 0.0]]), np.array([[length, 0.0]])
    op = T.wall_openings(a, b, [0], 0.0, height, 3.0, True, True)
    want = T.facade_texture("#a0522d", "brick", 3, length, height, texels_per_metre=rho, openings=op)
    s = X.Style.from_tags(UNSHIFTED, "brick", "#a0522d", None, None, 3.0)
    ops = np.column_stack([op.s0, op.s1, op.z0, op.z1, op.kind])
    lay = A.layout([[int(length * rho), int(height * rho)]], 512, "shelf", 2)
    req = X._requests(
        np.array([X.KIND_WALL], np.int8),
        np.array([0]),
        np.array([[length, height]]),
        [ops],
        X._insets(lay, np.array([X.KIND_WALL])),
        [s],
    )
    page = X._render_page(lay, 0, req, np.zeros((0, 3), np.uint8), {})
    got = page[2 : 2 + want.shape[0], 2 : 2 + want.shape[1]]
    assert np.abs(got.astype(int) - want).max() <= 1
    assert (page[0, 2 : 2 + want.shape[1]] == page[2, 2 : 2 + want.shape[1]]).all()  # gutter repeats the edge


def test_deterministic() -> None:
    tri, feat, sem = city()
    a = X.texture_tile(tri, feat, sem, styles(), 4.0)
    b = X.texture_tile(tri, feat, sem, styles(), 4.0)
    assert [p.tobytes() for p in a.pages] == [p.tobytes() for p in b.pages]
    assert a.tri_uv.tobytes() == b.tri_uv.tobytes() and a.tri_page.tobytes() == b.tri_page.tobytes()


def test_lod2_tile_copies_its_leaves_charts_with_their_windows() -> None:
    tri3, feat3, sem3 = city(lod=3)
    tri2, feat2, sem2 = city(lod=2)
    cache = X.ChartCache()
    leaf = X.texture_tile(tri3, feat3, sem3, styles(), 4.0, cache=cache, store=True)
    lod2 = X.texture_tile(tri2, feat2, sem2, styles(), 4.0, cache=cache)
    charts = lod2.stats["charts"] - 1  # all but the palette (ground caps)
    assert lod2.stats["copied"] == charts and lod2.stats["rendered_texels"] < lod2.stats["content_texels"] * 0.01
    assert [p.tobytes() for p in lod2.pages] == [p.tobytes() for p in leaf.pages]
    # without the cache, the LOD3 panels passed as openings give the same walls
    panels = (sem3 == SEM_WINDOW) | (sem3 == SEM_DOOR)
    alone = X.texture_tile(
        tri2, feat2, sem2, styles(), 4.0, opening_triangles=(tri3[panels], feat3[panels], sem3[panels])
    )
    assert [p.tobytes() for p in alone.pages] == [p.tobytes() for p in leaf.pages]
    # a coarser parent downsamples the cached charts (OpenImageIO) instead of rendering them
    coarse = X.texture_tile(tri2, feat2, sem2, styles(), 2.0, X.Params(padding=1), cache=cache)
    assert coarse.stats["resized"] == charts


def test_generic_windows_for_simplified_solids_and_blocks() -> None:
    tri, feat, sem = city(lod=2)
    plain = X.texture_tile(tri, feat, sem, styles(), 4.0)
    gen = X.texture_tile(tri, feat, sem, styles(generic=True), 4.0)
    assert plain.stats["openings"] == 0 and gen.stats["openings"] > 20
    # storeys from building:levels, windows from the wall length: facade.py's layout on every wall
    walls = extrude(
        np.array([shapely.box(*(OFF + [x0, y0]), *(OFF + [x1, y1])) for x0, y0, x1, y1, _, _ in BOXES]),
        np.zeros(3),
        np.array([b[4] for b in BOXES]),
    ).walls
    length = np.hypot(*(walls.b - walls.a).T)
    want = T.wall_openings(
        np.zeros((len(length), 2)),
        np.column_stack([length, np.zeros(len(length))]),
        np.arange(len(length)),
        0.0,
        np.array([b[4] for b in BOXES])[walls.owner],
        np.array([b[5] for b in BOXES], float)[walls.owner],
        False,
        True,
    )
    assert gen.stats["openings"] == len(want)


def test_small_charts_become_flat_colours() -> None:
    tri, feat, sem = city([(0, 0, 1.5, 1.5, 1.5, 1.0)], lod=2)
    tt = X.texture_tile(tri, feat, sem, styles([(0, 0, 1.5, 1.5, 1.5, 1.0)]), 1.0)
    assert tt.stats["flat"] >= 2 and tt.stats["charts"] == 1 and tt.chart_kind.tolist() == [X.KIND_PALETTE]
    wall = np.flatnonzero(sem == SEM_WALL)[0]
    # every corner of a flat triangle samples one texel centre of the palette, in the tagged colour
    assert np.ptp(tt.tri_uv[wall], axis=0).max() == 0
    assert tuple(texel(tt, 0, tt.tri_uv[wall, 0])) == (0xA0, 0x52, 0x2D)


def test_curved_roofs_get_an_xatlas_sheet() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=6.0)
    keep = sphere.triangles_center[:, 2] > 0
    dome = sphere.vertices[sphere.faces[keep]] + [*OFF, 10.0]
    tri = dome
    tt = X.texture_tile(tri, np.zeros(len(tri), np.int64), np.full(len(tri), SEM_ROOF, np.uint8), styles()[:1], 8.0)
    assert tt.stats["sheets"] == 1 and (tt.tri_page >= 0).all()
    # xatlas charts are near-isometric: UV areas in texels ~ surface area x rho^2
    px = tt.tri_uv * tt.layout.page_dims[tt.tri_page][:, None, :]
    e1, e2 = px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    assert uv_area == pytest.approx(area * 64, rel=0.15)


def test_bad_input_is_refused() -> None:
    tri, feat, sem = city(lod=2)
    tri[0, 0, 0] = math.nan
    with pytest.raises(ValueError, match="non-finite"):
        X.texture_tile(tri, feat, sem, styles(), 4.0)
    with pytest.raises(ValueError, match="rho"):
        X.texture_tile(*city(lod=2), styles(), 0.0)
