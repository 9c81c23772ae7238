"""S3DB tag parsing: every accepted spelling gives the right value; every refused one a stable reason."""

import pytest

from etl.geom.tags import (
    ParseError,
    building_kind,
    parse_angle,
    parse_building_tags,
    parse_colour,
    parse_count,
    parse_direction,
    parse_length,
    parse_orientation,
)


@pytest.mark.parametrize(
    ("raw", "metres"),
    [
        ("12", 12.0),
        ("12 m", 12.0),
        ("12m", 12.0),
        ("12,5", 12.5),
        ("12.5", 12.5),
        (" 7 ", 7.0),
        ("40'", 12.192),
        ("40 ft", 12.192),
        ("40 feet", 12.192),
        ("12'6\"", 3.81),
        ("120 cm", 1.2),
        ("12 metres", 12.0),
        ("0", 0.0),
        ("1e2", 100.0),
    ],
)
def test_length_units(raw: str, metres: float) -> None:
    assert parse_length(raw) == pytest.approx(metres, abs=1e-9)


@pytest.mark.parametrize(
    ("raw", "code"),
    [
        ("-3", "negative"),
        ("abc", "not_a_length"),
        ("1e9", "out_of_range"),
        ("12;15", "not_a_length"),
        ("", "not_a_length"),
        ("12 storeys", "not_a_length"),
        ("1001", "out_of_range"),
        ("nan", "not_a_length"),
    ],
)
def test_length_refused(raw: str, code: str) -> None:
    with pytest.raises(ParseError) as e:
        parse_length(raw)
    assert e.value.code == code


def test_counts_angles_directions() -> None:
    assert parse_count("4") == 4.0
    assert parse_count("2.5") == 2.5
    with pytest.raises(ParseError):
        parse_count("three")
    with pytest.raises(ParseError):
        parse_count("-1")
    assert parse_angle("30") == 30.0
    assert parse_angle("45°") == 45.0
    with pytest.raises(ParseError):
        parse_angle("95")
    assert parse_direction("N") == 0.0
    assert parse_direction("nne") == 22.5
    assert parse_direction("SW") == 225.0
    assert parse_direction("NNW") == 337.5
    assert parse_direction("90") == 90.0
    assert parse_direction("-90") == 270.0
    assert parse_direction("450") == 90.0
    with pytest.raises(ParseError):
        parse_direction("up")
    assert parse_orientation("Across") == "across"
    with pytest.raises(ParseError):
        parse_orientation("diagonal")


def test_colours() -> None:
    assert parse_colour("red") == "#ff0000"
    assert parse_colour("Light Grey") == "#d3d3d3"
    assert parse_colour("#ABC") == "#aabbcc"
    assert parse_colour("a0b1c2") == "#a0b1c2"
    with pytest.raises(ParseError):
        parse_colour("#12345")


def test_kind() -> None:
    assert building_kind({"building": "yes"}) == "building"
    assert building_kind({"building:part": "yes"}) == "part"
    assert building_kind({"building": "no"}) is None
    assert building_kind({"building": "no", "building:part": "roof"}) == "part"
    assert building_kind({"highway": "residential"}) is None


def test_parse_building_tags_collects_issues_and_fallbacks() -> None:
    t = parse_building_tags(
        {
            "building": "house",
            "height": "abc",
            "min_height": "2 m",
            "building:levels": "3",
            "building:roof:shape": "Gabled",
            "roof:direction": "NNE",
            "building:colour": "brown",
            "roof:colour": "nonsense",
            "building:material": "Brick",
            "name": "Villa",
        }
    )
    assert t is not None
    assert (t.kind, t.building, t.name) == ("building", "house", "Villa")
    assert t.height is None and t.min_height == 2.0 and t.levels == 3.0
    assert t.roof_shape == "gabled"  # building:roof:shape is the fallback key
    assert t.roof_direction == 22.5
    assert t.building_colour == "#a52a2a" and t.roof_colour is None
    assert t.building_material == "brick"
    assert {(i.key, i.code) for i in t.issues} == {("height", "not_a_length"), ("roof:colour", "not_a_colour")}
    assert parse_building_tags({"amenity": "cafe"}) is None
    outline = parse_building_tags({"building": "yes", "building:part": "no"})
    assert outline is not None and outline.part is None
    both = parse_building_tags({"building": "yes", "building:part": "yes"})
    assert both is not None and (both.kind, both.part) == ("building", "yes")
