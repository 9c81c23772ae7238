"""Simple 3D Buildings tag parsing: raw OSM strings to typed values, with a reason for every value refused.

Pure functions, no database. The ingest stage stores the typed values in columns of ``osm.building`` and every
refused value as a row of ``meta.diagnostic`` (code ``invalid_tag``); the raw tags stay in ``tags`` jsonb.

Units (S3DB says metres; mappers write all of these): ``12``, ``12 m``, ``12m``, ``12.5``, ``12,5`` (decimal
comma), ``40'``, ``40 ft``, ``40 feet``, ``12'6"`` (feet and inches), ``120 cm``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TypeVar

FOOT = 0.3048
INCH = 0.0254
_T = TypeVar("_T")

_NUM = r"[+-]?(?:\d+(?:[.,]\d*)?|[.,]\d+)(?:[eE][+-]?\d+)?"
_LENGTH = re.compile(rf"^({_NUM})\s*(m|meters?|metres?|ft|feet|foot|'|cm|km)?$", re.IGNORECASE)
_FEET_INCHES = re.compile(r"^(\d+(?:\.\d+)?)\s*(?:'|ft)\s*(\d+(?:\.\d+)?)\s*(?:\"|''|in)$", re.IGNORECASE)
_UNIT_FACTOR = {
    None: 1.0,
    "m": 1.0,
    "meter": 1.0,
    "meters": 1.0,
    "metre": 1.0,
    "metres": 1.0,
    "ft": FOOT,
    "feet": FOOT,
    "foot": FOOT,
    "'": FOOT,
    "cm": 0.01,
    "km": 1000.0,
}
_NUMBER = re.compile(rf"^({_NUM})$")
_ANGLE = re.compile(rf"^({_NUM})\s*(°|deg|degrees?)?$", re.IGNORECASE)

#: 16-point compass rose (roof:direction may be given as letters).
CARDINAL = {
    name: i * 22.5
    for i, name in enumerate(
        ["N", "NNE", "NE", "ENE", "E", "ESE", "SE", "SSE", "S", "SSW", "SW", "WSW", "W", "WNW", "NW", "NNW"]
    )
}

#: Colour names mappers use on building:colour / roof:colour (CSS names plus common OSM spellings).
NAMED_COLOURS = {
    "black": "#000000",
    "white": "#ffffff",
    "grey": "#808080",
    "gray": "#808080",
    "lightgrey": "#d3d3d3",
    "lightgray": "#d3d3d3",
    "darkgrey": "#a9a9a9",
    "darkgray": "#a9a9a9",
    "dimgray": "#696969",
    "dimgrey": "#696969",
    "silver": "#c0c0c0",
    "gainsboro": "#dcdcdc",
    "red": "#ff0000",
    "darkred": "#8b0000",
    "maroon": "#800000",
    "brown": "#a52a2a",
    "sienna": "#a0522d",
    "saddlebrown": "#8b4513",
    "chocolate": "#d2691e",
    "peru": "#cd853f",
    "tan": "#d2b48c",
    "burlywood": "#deb887",
    "wheat": "#f5deb3",
    "beige": "#f5f5dc",
    "ivory": "#fffff0",
    "linen": "#faf0e6",
    "cream": "#fffdd0",
    "orange": "#ffa500",
    "darkorange": "#ff8c00",
    "coral": "#ff7f50",
    "salmon": "#fa8072",
    "pink": "#ffc0cb",
    "yellow": "#ffff00",
    "gold": "#ffd700",
    "khaki": "#f0e68c",
    "olive": "#808000",
    "green": "#008000",
    "darkgreen": "#006400",
    "lime": "#00ff00",
    "lightgreen": "#90ee90",
    "teal": "#008080",
    "cyan": "#00ffff",
    "aqua": "#00ffff",
    "blue": "#0000ff",
    "navy": "#000080",
    "darkblue": "#00008b",
    "lightblue": "#add8e6",
    "skyblue": "#87ceeb",
    "steelblue": "#4682b4",
    "purple": "#800080",
    "violet": "#ee82ee",
    "magenta": "#ff00ff",
    "fuchsia": "#ff00ff",
    "terracotta": "#e2725b",
    "sandybrown": "#f4a460",
    "lightyellow": "#ffffe0",
    "whitesmoke": "#f5f5f5",
    "snow": "#fffafa",
    "slategray": "#708090",
    "slategrey": "#708090",
    "darkslategray": "#2f4f4f",
    "darkslategrey": "#2f4f4f",
}
_HEX = re.compile(r"^#?([0-9a-f]{6}|[0-9a-f]{3})$", re.IGNORECASE)


@dataclass(frozen=True)
class TagIssue:
    """A tag value that could not be used. ``code`` is stable (analysts filter on it)."""

    key: str
    value: str
    code: str  # not_a_length | negative | ... (value refused) | unit_converted (value kept, converted)
    detail: str

    def as_dict(self) -> dict[str, str]:
        return {"key": self.key, "value": self.value, "code": self.code, "detail": self.detail}


class ParseError(ValueError):
    def __init__(self, code: str, detail: str):
        super().__init__(detail)
        self.code = code
        self.detail = detail


def _to_float(text: str) -> float:
    return float(text.replace(",", "."))


def parse_length(value: str, max_value: float = 1000.0) -> float:
    """Metres from an OSM length. Raises ParseError(code, detail) when the value is unusable."""
    return parse_length_unit(value, max_value)[0]


def parse_length_unit(value: str, max_value: float = 1000.0) -> tuple[float, bool]:
    """(metres, True when the value was in another unit than metres: feet, inches, cm, km)."""
    s = value.strip()
    m = _FEET_INCHES.match(s)
    converted = bool(m)
    if m:
        metres = float(m.group(1)) * FOOT + float(m.group(2)) * INCH
    else:
        m = _LENGTH.match(s)
        if not m:
            raise ParseError("not_a_length", f"{value!r} is not a length (expected e.g. 12, 12 m, 12,5, 40 ft)")
        unit = m.group(2).lower() if m.group(2) else None
        metres = _to_float(m.group(1)) * _UNIT_FACTOR[unit]
        converted = _UNIT_FACTOR[unit] != 1.0
    if not math.isfinite(metres):
        raise ParseError("not_a_length", f"{value!r} is not a finite length")
    if metres < 0:
        raise ParseError("negative", f"{value!r} is negative")
    if metres > max_value:
        raise ParseError("out_of_range", f"{value!r} = {metres:g} m exceeds {max_value:g} m")
    return metres, converted


def parse_count(value: str, max_value: float = 200.0) -> float:
    """Level counts (building:levels, roof:levels, building:min_level). Fractions (2.5) are kept."""
    s = value.strip()
    m = _NUMBER.match(s)
    if not m:
        raise ParseError("not_a_number", f"{value!r} is not a number of levels")
    n = _to_float(m.group(1))
    if not math.isfinite(n):
        raise ParseError("not_a_number", f"{value!r} is not finite")
    if n < 0:
        raise ParseError("negative", f"{value!r} is negative")
    if n > max_value:
        raise ParseError("out_of_range", f"{value!r} exceeds {max_value:g} levels")
    return n


def parse_angle(value: str) -> float:
    """roof:angle in degrees, 0–90."""
    m = _ANGLE.match(value.strip())
    if not m:
        raise ParseError("not_an_angle", f"{value!r} is not an angle in degrees")
    a = _to_float(m.group(1))
    if not (0.0 <= a <= 90.0):
        raise ParseError("out_of_range", f"{value!r} is outside 0–90°")
    return a


def parse_direction(value: str) -> float:
    """roof:direction: degrees clockwise from north (any real, normalised to [0, 360)) or N, NNE, … NNW."""
    s = value.strip()
    card = CARDINAL.get(s.upper())
    if card is not None:
        return card
    m = _ANGLE.match(s)
    if not m:
        raise ParseError("not_a_direction", f"{value!r} is neither degrees nor a compass point (N, NNE, …)")
    d = _to_float(m.group(1))
    if not math.isfinite(d):
        raise ParseError("not_a_direction", f"{value!r} is not finite")
    return d % 360.0


def parse_orientation(value: str) -> str:
    s = value.strip().lower()
    if s not in ("along", "across"):
        raise ParseError("not_an_orientation", f"{value!r} is not along/across")
    return s


def parse_colour(value: str) -> str:
    """Colour as lower-case ``#rrggbb`` from hex (with or without #, 3 or 6 digits) or a colour name."""
    s = value.strip().lower()
    named = NAMED_COLOURS.get(s.replace(" ", "").replace("_", ""))
    if named:
        return named
    m = _HEX.match(s)
    if not m:
        raise ParseError("not_a_colour", f"{value!r} is neither #rrggbb nor a known colour name")
    h = m.group(1)
    if len(h) == 3:
        h = "".join(c * 2 for c in h)
    return "#" + h


def _text(value: str | None) -> str | None:
    if value is None:
        return None
    v = value.strip()
    return v or None


@dataclass
class BuildingTags:
    """Typed S3DB values of one building or building:part. None = not tagged or refused (see issues)."""

    kind: str  # "building" or "part"
    building: str | None = None
    part: str | None = None
    name: str | None = None
    height: float | None = None
    min_height: float | None = None
    levels: float | None = None
    min_level: float | None = None
    roof_levels: float | None = None
    roof_height: float | None = None
    roof_angle: float | None = None
    roof_shape: str | None = None
    roof_direction: float | None = None
    roof_orientation: str | None = None
    building_colour: str | None = None
    roof_colour: str | None = None
    building_material: str | None = None
    roof_material: str | None = None
    issues: list[TagIssue] = field(default_factory=list)


def building_kind(tags: Mapping[str, str]) -> str | None:
    """'building', 'part' or None (not a building). ``building=no`` / ``building:part=no`` do not count.
    A way with both keys is an outline that is also drawn as a part; it is stored as a building."""
    b = tags.get("building")
    if b is not None and b.strip().lower() != "no":
        return "building"
    p = tags.get("building:part")
    if p is not None and p.strip().lower() != "no":
        return "part"
    return None


def parse_building_tags(
    tags: Mapping[str, str], max_height: float = 1000.0, max_levels: float = 200.0
) -> BuildingTags | None:
    kind = building_kind(tags)
    if kind is None:
        return None
    part = _text(tags.get("building:part"))
    # building:part=no on an outline says "not a part": keep the column NULL so the outline rule ignores it
    out = BuildingTags(
        kind=kind, building=_text(tags.get("building")), part=None if part and part.lower() == "no" else part
    )
    out.name = _text(tags.get("name"))

    def take(key: str, fn: Callable[..., _T], *args: object) -> _T | None:
        """``fn`` of the tag's value (None when untagged or blank); a value it refuses becomes an issue."""
        raw = tags.get(key)
        if raw is None or not raw.strip():
            return None
        try:
            return fn(raw, *args)
        except ParseError as e:
            out.issues.append(TagIssue(key, raw, e.code, e.detail))
            return None

    def length(key: str) -> float | None:
        v = take(key, parse_length_unit, max_height)
        if v is None:
            return None
        if v[1]:  # kept, but analysts want to see odd units
            raw = tags[key].strip()
            out.issues.append(TagIssue(key, raw, "unit_converted", f"{raw!r} read as {v[0]:g} m"))
        return v[0]

    out.height = length("height")
    out.min_height = length("min_height")
    out.levels = take("building:levels", parse_count, max_levels)
    out.min_level = take("building:min_level", parse_count, max_levels)
    out.roof_levels = take("roof:levels", parse_count, max_levels)
    out.roof_height = length("roof:height")
    out.roof_angle = take("roof:angle", parse_angle)
    out.roof_direction = take("roof:direction", parse_direction)
    out.roof_orientation = take("roof:orientation", parse_orientation)
    out.building_colour = take("building:colour", parse_colour)
    out.roof_colour = take("roof:colour", parse_colour)
    shape = _text(tags.get("roof:shape")) or _text(tags.get("building:roof:shape"))
    out.roof_shape = shape.lower() if shape else None
    mat = _text(tags.get("building:material"))
    out.building_material = mat.lower() if mat else None
    rmat = _text(tags.get("roof:material"))
    out.roof_material = rmat.lower() if rmat else None
    return out
