"""Migrations are applied once with checksums, changed ones are refused, sql/ reloads in full, and every
table, view and column is documented."""

import shutil

import psycopg
import pytest

from etl.migrate import MIGRATIONS, MigrationError, discover, migrate, reload_sql


def test_template_has_every_migration(new_db, conn_of) -> None:
    conn = conn_of(new_db("migrate_applied"))
    rows = conn.execute("SELECT version, name, checksum FROM meta.schema_migrations ORDER BY version").fetchall()
    assert [(v, n, c) for v, n, c in rows] == [(m.version, m.name, m.checksum) for m in discover()]


def test_migrate_is_idempotent_and_refuses_changed_files(new_db, tmp_path) -> None:
    url = new_db("migrate_refuse")
    with psycopg.connect(url) as conn:
        assert migrate(conn, quiet=True) == []  # nothing pending
        copy = tmp_path / "migrations"
        shutil.copytree(MIGRATIONS, copy)
        target = sorted(copy.glob("0003_*.sql"))[0]
        target.write_text(target.read_text() + "\n-- an edit after the fact\n")
        with pytest.raises(MigrationError, match=r"0003_.*changed after it was applied"):
            migrate(conn, directory=copy, quiet=True)
        target.unlink()
        with pytest.raises(MigrationError, match="no longer exists"):
            migrate(conn, directory=copy, quiet=True)


def test_new_migration_is_applied_once(new_db, tmp_path) -> None:
    url = new_db("migrate_new")
    copy = tmp_path / "migrations"
    shutil.copytree(MIGRATIONS, copy)
    (copy / "9999_probe.sql").write_text("CREATE TABLE meta.probe (x int);")
    with psycopg.connect(url) as conn:
        assert migrate(conn, directory=copy, quiet=True) == ["9999_probe.sql"]
        assert migrate(conn, directory=copy, quiet=True) == []
        assert conn.execute("SELECT to_regclass('meta.probe') IS NOT NULL").fetchone()[0]


def test_reload_drops_stale_routines(new_db) -> None:
    url = new_db("migrate_reload")
    with psycopg.connect(url) as conn:
        conn.execute("CREATE FUNCTION api.stale() RETURNS int LANGUAGE sql AS 'SELECT 1'")
        conn.commit()
        n = reload_sql(conn, quiet=True)
        assert n >= 5
        assert conn.execute("SELECT to_regproc('api.stale')").fetchone()[0] is None
        assert conn.execute("SELECT to_regproc('api.buildings_for_tile')").fetchone()[0] is not None


def test_reload_rejects_misnamed_file(new_db, tmp_path) -> None:
    url = new_db("migrate_misnamed")
    (tmp_path / "api").mkdir()
    (tmp_path / "api" / "wrong_name.sql").write_text(
        "CREATE OR REPLACE FUNCTION api.other() RETURNS int LANGUAGE sql AS 'SELECT 1';"
    )
    with psycopg.connect(url) as conn, pytest.raises(MigrationError, match="must define api.wrong_name"):
        reload_sql(conn, directory=tmp_path, quiet=True)


#: Every table, partitioned table, view and materialized view without a comment, and every column of one without
#: its own: in any schema but the system's (so one a later migration creates counts too), extensions' objects
#: (PostGIS' spatial_ref_sys, geometry_columns) aside.
_UNCOMMENTED = """
WITH rel AS (
    SELECT c.oid, n.nspname || '.' || c.relname AS name
    FROM pg_class c JOIN pg_namespace n ON n.oid = c.relnamespace
    WHERE c.relkind IN ('r', 'p', 'v', 'm') AND n.nspname !~ '^(pg_|information_schema$)'
      AND NOT EXISTS (SELECT 1 FROM pg_depend d
                      WHERE d.classid = 'pg_class'::regclass AND d.objid = c.oid AND d.deptype = 'e'))
SELECT r.name FROM rel r WHERE obj_description(r.oid, 'pg_class') IS NULL
UNION ALL
SELECT r.name || '.' || a.attname FROM rel r
JOIN pg_attribute a ON a.attrelid = r.oid AND a.attnum > 0 AND NOT a.attisdropped
WHERE col_description(r.oid, a.attnum) IS NULL
ORDER BY 1
"""


def test_every_table_and_column_is_commented(new_db, conn_of) -> None:
    """README: every table, view and column has a COMMENT ON (a view's are in its sql/ file, reloaded with it),
    and the check finds one that has none, in a schema of its own too."""
    conn = conn_of(new_db("migrate_comments"))
    missing = [r[0] for r in conn.execute(_UNCOMMENTED).fetchall()]
    assert not missing, (
        f"{len(missing)} tables, views or columns have no COMMENT ON (a table's go in a new "
        "migration, a view's in its sql/ file): " + ", ".join(missing)
    )
    conn.execute(
        "CREATE SCHEMA probe; CREATE TABLE probe.t (x int, y int); COMMENT ON COLUMN probe.t.x IS 'x.'; "
        "CREATE VIEW osm.v AS SELECT 1 AS one; COMMENT ON VIEW osm.v IS 'v.'"
    )
    assert {r[0] for r in conn.execute(_UNCOMMENTED).fetchall()} == {"osm.v.one", "probe.t", "probe.t.y"}


def test_api_functions_are_stable_parallel_safe_and_documented(new_db, conn_of) -> None:
    conn = conn_of(new_db("migrate_api"))
    rows = conn.execute(
        """SELECT p.proname, p.provolatile, p.proparallel, obj_description(p.oid, 'pg_proc')
           FROM pg_proc p JOIN pg_namespace n ON n.oid = p.pronamespace WHERE n.nspname = 'api'"""
    ).fetchall()
    assert {r[0] for r in rows} >= {"buildings_for_tile", "tile_tree"}
    for name, volatile, parallel, comment in rows:
        assert (volatile, parallel) == ("s", "s"), name
        assert comment and "Example" in comment, name
