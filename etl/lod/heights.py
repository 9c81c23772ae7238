"""Bottom and top of a building's volume from its S3DB tags, with documented defaults. Pure numpy.

top (height above ground of the roof top):
  1. ``height`` when tagged                                                         -> source "height"
  2. ``building:levels`` × level height + roof (``roof:height``, else ``roof:levels`` × level height)
                                                                                   -> source "levels"
  3. the default number of levels for the building type (garage 1, house 2, ...)    -> source "type_default"
  4. ``default_levels`` (3) × level height                                          -> source "default"
  (3 and 4 also add the tagged roof height / roof levels.)
bottom: ``min_height``, else ``building:min_level`` × level height, else 0.

When the top was not tagged (3, 4) but lies at or below the bottom (a floating part with only
building:min_level), the top becomes bottom + one level and the building gets a diagnostic. When an explicit
height does not exceed the bottom, the building is rejected (min_height_ge_height): the tags contradict.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import SupportsFloat

import numpy as np

from core.settings import Settings

SOURCES = np.array(["height", "levels", "type_default", "default"])


@dataclass(frozen=True)
class Heights:
    bottom: np.ndarray  # float64
    top: np.ndarray  # float64
    source: np.ndarray  # str, one of SOURCES
    raised: np.ndarray  # bool: defaulted top lifted above a tagged bottom
    invalid: np.ndarray  # bool: explicit height <= bottom


def floats(a: Iterable[SupportsFloat | None]) -> np.ndarray:
    """None -> NaN float array."""
    return np.array([np.nan if v is None else float(v) for v in a], dtype=np.float64)


def resolve(
    height: Iterable[SupportsFloat | None],
    min_height: Iterable[SupportsFloat | None],
    levels: Iterable[SupportsFloat | None],
    min_level: Iterable[SupportsFloat | None],
    roof_levels: Iterable[SupportsFloat | None],
    roof_height: Iterable[SupportsFloat | None],
    building_type: Iterable[object],
    settings: Settings,
) -> Heights:
    """Vectorised over buildings; every argument is a sequence (None = untagged)."""
    h, mh, lv, ml, rl, rh = (floats(a) for a in (height, min_height, levels, min_level, roof_levels, roof_height))
    lh = settings.level_height_m
    types = list(building_type)
    type_levels = np.array(
        [np.nan if t is None else settings.default_levels_by_type.get(str(t).lower(), np.nan) for t in types]
    )
    roof = np.where(~np.isnan(rh), rh, np.where(~np.isnan(rl), rl * lh, 0.0))

    source = np.full(len(h), "default", dtype=object)
    top = settings.default_levels * lh + roof
    has_type = ~np.isnan(type_levels)
    top = np.where(has_type, type_levels * lh + roof, top)
    source[has_type] = "type_default"
    has_levels = ~np.isnan(lv)
    top = np.where(has_levels, lv * lh + roof, top)
    source[has_levels] = "levels"
    has_height = ~np.isnan(h)
    top = np.where(has_height, h, top)
    source[has_height] = "height"

    bottom = np.where(~np.isnan(mh), mh, np.where(~np.isnan(ml), ml * lh, 0.0))
    invalid = has_height & (top <= bottom)
    raised = ~has_height & (top <= bottom)
    top = np.where(raised, bottom + lh, top)
    return Heights(bottom=bottom, top=top, source=source.astype(str), raised=raised, invalid=invalid)
