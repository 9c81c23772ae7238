"""``python -m etl config`` (Settings.describe): every setting as the CITYLOD_* variable that overrides it, with
whether the environment set it; the lines, read back as an environment, give the same settings."""

from __future__ import annotations

import dataclasses
import shlex

from core.settings import Settings


def test_config_names_every_override_and_reads_back() -> None:
    env = {"CITYLOD_LEVEL_HEIGHT_M": "3.5", "CITYLOD_TEX_PAGE_SIZE": "256"}
    s = Settings.from_env(env)
    lines = s.describe(env)
    assert len(lines) == len(dataclasses.fields(Settings))
    by_key = {line.split("=", 1)[0]: line for line in lines}
    assert by_key["CITYLOD_LEVEL_HEIGHT_M"].endswith("# set in the environment")
    assert by_key["CITYLOD_MIN_AREA_M2"].endswith("# default")
    assert by_key["# CITYLOD_DEFAULT_LEVELS_BY_TYPE"].endswith("# not settable from the environment")
    back = {}
    for line in lines:
        if line.startswith("#"):
            continue
        key, rest = line.split("=", 1)
        back[key] = shlex.split(rest, comments=True)[0]
    assert Settings.from_env(back) == s
