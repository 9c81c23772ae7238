"""Where the shared test extracts are: ../shared/data/osm beside the clone, or CITYLOD_SHARED_DATA/osm."""

from __future__ import annotations

import os
from pathlib import Path

from core.settings import REPO

SHARED_OSM = Path(os.environ.get("CITYLOD_SHARED_DATA", REPO.parent / "shared" / "data")) / "osm"
