"""Height resolution rules (etl/lod/heights.py) with the documented defaults."""

import numpy as np

from core.settings import Settings
from etl.lod.heights import resolve

S = Settings()


def r(**kw):  # one building
    cols = dict(
        height=[None],
        min_height=[None],
        levels=[None],
        min_level=[None],
        roof_levels=[None],
        roof_height=[None],
        building_type=["yes"],
    )
    cols.update({k: [v] for k, v in kw.items()})
    return resolve(settings=S, **cols)


def test_height_tag_wins() -> None:
    h = r(height=17.0, levels=10.0)
    assert (h.top[0], h.bottom[0], h.source[0]) == (17.0, 0.0, "height")


def test_levels_and_roof() -> None:
    h = r(levels=4.0)
    assert (h.top[0], h.source[0]) == (12.0, "levels")
    assert r(levels=2.0, roof_levels=1.0).top[0] == 9.0
    assert r(levels=2.0, roof_height=2.5).top[0] == 8.5


def test_defaults_by_type_and_global() -> None:
    assert (r(building_type="garage").top[0], r(building_type="garage").source[0]) == (3.0, "type_default")
    assert (r().top[0], r().source[0]) == (9.0, "default")
    assert r(building_type=None).source[0] == "default"


def test_bottom_from_min_height_or_min_level() -> None:
    assert r(height=20.0, min_height=5.0).bottom[0] == 5.0
    assert r(levels=6.0, min_level=2.0).bottom[0] == 6.0


def test_contradictions() -> None:
    bad = r(height=10.0, min_height=20.0)
    assert bad.invalid[0] and not bad.raised[0]
    floating = r(min_level=5.0)  # only a min level: the defaulted top is lifted above the bottom
    assert floating.raised[0] and not floating.invalid[0]
    assert floating.top[0] == 18.0 and floating.bottom[0] == 15.0


def test_vectorised() -> None:
    h = resolve(
        [10.0, None, None],
        [None, None, 3.0],
        [None, 5.0, None],
        [None] * 3,
        [None] * 3,
        [None] * 3,
        ["yes", "yes", "shed"],
        S,
    )
    assert np.allclose(h.top, [10.0, 15.0, 6.0])  # shed: 1 level = 3 m, lifted above min_height 3 -> 6
    assert list(h.source) == ["height", "levels", "type_default"]
