"""Apply migrations/ (state) and reload sql/ (logic).

Migrations are numbered, forward-only files; each is applied once in its own transaction and recorded with
its sha256 in meta.schema_migrations. An applied migration whose file changed is refused. After migrating,
every function, procedure and view in our schemas is dropped and sql/ is loaded again in one transaction, so
the database always holds exactly the logic on disk (Nominatim's rule: functions are always re-imported). The
reload records each file's sha256 in meta.sql_object; ``migrate --if-stale`` (make) skips it when no migration
was applied and sql/ on disk is what the database holds.
"""

from __future__ import annotations

import hashlib
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import psycopg
from psycopg import sql

from core.settings import REPO

MIGRATIONS = REPO / "migrations"
SQL_DIR = REPO / "sql"
#: Schemas whose routines and views come from sql/, in load order (the pipeline order).
SCHEMAS = ("meta", "osm", "lod", "gen", "lm", "tex", "tiles", "api")
_MIGRATION_NAME = re.compile(r"^(\d{4})_([a-z0-9_]+)\.sql$")
_ADVISORY_LOCK = 727_100_001  # serialises concurrent migrate runs


class MigrationError(RuntimeError):
    pass


@dataclass(frozen=True)
class Migration:
    version: int
    name: str
    path: Path

    @property
    def checksum(self) -> str:
        return hashlib.sha256(self.path.read_bytes()).hexdigest()


def exists(conn: psycopg.Connection, relation: str) -> bool:
    """Whether the table or view ``relation`` ("schema.name") exists: a database older than its migration
    has none."""
    row = conn.execute("SELECT to_regclass(%s) IS NOT NULL", (relation,)).fetchone()
    return bool(row and row[0])


def discover(directory: Path = MIGRATIONS) -> list[Migration]:
    out: list[Migration] = []
    for p in sorted(directory.glob("*.sql")):
        m = _MIGRATION_NAME.match(p.name)
        if not m:
            raise MigrationError(f"{p.name}: migration files are named NNNN_snake_case.sql")
        out.append(Migration(int(m.group(1)), m.group(2), p))
    versions = [m.version for m in out]
    if len(set(versions)) != len(versions):
        raise MigrationError(f"duplicate migration numbers in {directory}")
    return out


def _bootstrap(conn: psycopg.Connection) -> None:
    conn.execute("CREATE SCHEMA IF NOT EXISTS meta")
    conn.execute(
        """CREATE TABLE IF NOT EXISTS meta.schema_migrations (
               version    integer PRIMARY KEY,
               name       text NOT NULL,
               checksum   text NOT NULL,
               applied_at timestamptz NOT NULL DEFAULT now())"""
    )
    for target, text in (
        (
            "TABLE meta.schema_migrations",
            "Migrations applied to this database (python -m etl migrate), with the sha256 of each file.",
        ),
        ("COLUMN meta.schema_migrations.version", "Number of the migration file (NNNN_name.sql)."),
        ("COLUMN meta.schema_migrations.name", "Name part of the migration file."),
        (
            "COLUMN meta.schema_migrations.checksum",
            "sha256 of the file when it was applied; a changed file is refused.",
        ),
        ("COLUMN meta.schema_migrations.applied_at", "When it was applied (UTC)."),
    ):
        conn.execute(sql.SQL("COMMENT ON {} IS {}").format(sql.SQL(target), sql.Literal(text)))


def migrate(conn: psycopg.Connection, directory: Path = MIGRATIONS, quiet: bool = False) -> list[str]:
    """Apply pending migrations; refuse changed or vanished ones. Returns the names applied."""
    migrations = discover(directory)
    applied_names: list[str] = []
    with conn.transaction():
        conn.execute("SELECT pg_advisory_xact_lock(%s)", (_ADVISORY_LOCK,))
        _bootstrap(conn)
        done = {v: (n, c) for v, n, c in conn.execute("SELECT version, name, checksum FROM meta.schema_migrations")}
    on_disk = {m.version for m in migrations}
    for version, (name, _) in sorted(done.items()):
        if version not in on_disk:
            raise MigrationError(
                f"migration {version:04d}_{name}.sql is recorded as applied but no longer exists in "
                f"{directory}; migrations are forward-only and must never be deleted"
            )
    for m in migrations:
        if m.version in done:
            _, checksum = done[m.version]
            if checksum != m.checksum:
                raise MigrationError(
                    f"migration {m.path.name} was changed after it was applied to this database "
                    f"(checksum {checksum[:12]}… recorded, {m.checksum[:12]}… on disk). Migrations are "
                    "forward-only: revert the edit and put the change in a new numbered migration."
                )
            continue
        with conn.transaction():
            conn.execute("SELECT pg_advisory_xact_lock(%s)", (_ADVISORY_LOCK,))
            conn.execute(m.path.read_text())
            conn.execute(
                "INSERT INTO meta.schema_migrations (version, name, checksum) VALUES (%s, %s, %s)",
                (m.version, m.name, m.checksum),
            )
        applied_names.append(m.path.name)
        if not quiet:
            print(f"  applied {m.path.name}", file=sys.stderr)
    return applied_names


@dataclass(frozen=True)
class SqlObject:
    schema: str
    name: str
    path: Path

    @property
    def key(self) -> str:
        """Its meta.sql_object.path: sql/<schema>/<object>.sql, whichever directory it was loaded from."""
        return f"sql/{self.schema}/{self.path.name}"


def discover_sql(directory: Path = SQL_DIR) -> list[SqlObject]:
    """sql/<schema>/<object>.sql, in pipeline order of the schemas, then by name."""
    objs: list[SqlObject] = []
    for sub in sorted(p for p in directory.iterdir() if p.is_dir()):
        if sub.name not in SCHEMAS:
            raise MigrationError(f"sql/{sub.name}: not a citylod schema ({', '.join(SCHEMAS)})")
    for schema in SCHEMAS:
        for p in sorted((directory / schema).glob("*.sql")) if (directory / schema).is_dir() else []:
            objs.append(SqlObject(schema, p.stem, p))
    return objs


_DROP_ROUTINES = """
SELECT n.nspname, p.proname, pg_get_function_identity_arguments(p.oid), p.prokind
FROM pg_proc p JOIN pg_namespace n ON n.oid = p.pronamespace
WHERE n.nspname = ANY(%s)
  AND NOT EXISTS (SELECT 1 FROM pg_depend d WHERE d.objid = p.oid AND d.deptype = 'e')
"""
_DROP_VIEWS = """
SELECT n.nspname, c.relname, c.relkind FROM pg_class c JOIN pg_namespace n ON n.oid = c.relnamespace
WHERE n.nspname = ANY(%s) AND c.relkind IN ('v', 'm')
  AND NOT EXISTS (SELECT 1 FROM pg_depend d WHERE d.objid = c.oid AND d.deptype = 'e')
"""


def reload_sql(conn: psycopg.Connection, directory: Path = SQL_DIR, quiet: bool = False) -> int:
    """Drop every routine and view in our schemas and load sql/ again, atomically. Returns objects loaded."""
    objs = discover_sql(directory)
    schemas = list(SCHEMAS)
    with conn.transaction():
        conn.execute("SELECT pg_advisory_xact_lock(%s)", (_ADVISORY_LOCK,))
        for nsp, rel, kind in conn.execute(_DROP_VIEWS, (schemas,)).fetchall():
            view = sql.SQL("MATERIALIZED VIEW" if kind == "m" else "VIEW")
            conn.execute(
                sql.SQL("DROP {} IF EXISTS {}.{} CASCADE").format(view, sql.Identifier(nsp), sql.Identifier(rel))
            )
        for nsp, name, args, kind in conn.execute(_DROP_ROUTINES, (schemas,)).fetchall():
            what = {"p": "PROCEDURE", "a": "AGGREGATE"}.get(kind, "FUNCTION")
            conn.execute(
                sql.SQL("DROP {} IF EXISTS {}.{}({})").format(
                    sql.SQL(what), sql.Identifier(nsp), sql.Identifier(name), sql.SQL(args)
                )
            )
        # Bodies reference objects defined in later files; they are checked when first called and by the tests.
        conn.execute("SET LOCAL check_function_bodies = off")
        for obj in objs:
            try:
                conn.execute(obj.path.read_text())
            except psycopg.Error as e:
                raise MigrationError(f"{_show(obj.path)}: {e}") from e
            found = conn.execute(
                """SELECT (SELECT count(*) FROM pg_proc p JOIN pg_namespace n ON n.oid = p.pronamespace
                           WHERE n.nspname = %(s)s AND p.proname = %(n)s)
                        + (SELECT count(*) FROM pg_class c JOIN pg_namespace n ON n.oid = c.relnamespace
                           WHERE n.nspname = %(s)s AND c.relname = %(n)s AND c.relkind IN ('v', 'm'))""",
                {"s": obj.schema, "n": obj.name},
            ).fetchone()
            if not found or not found[0]:
                raise MigrationError(
                    f"{_show(obj.path)} must define {obj.schema}.{obj.name} (one object per file, named after the file)"
                )
        if exists(conn, "meta.sql_object"):
            conn.execute("DELETE FROM meta.sql_object")
            with conn.cursor() as cur:
                cur.executemany(
                    "INSERT INTO meta.sql_object (path, sha256) VALUES (%s, %s)", list(on_disk_sql(objs).items())
                )
    if not quiet:
        print(f"  loaded {len(objs)} objects from sql/", file=sys.stderr)
    return len(objs)


def on_disk_sql(objs: list[SqlObject]) -> dict[str, str]:
    """meta.sql_object's rows for ``objs``: path -> sha256."""
    return {o.key: hashlib.sha256(o.path.read_bytes()).hexdigest() for o in objs}


def loaded_sql(conn: psycopg.Connection) -> dict[str, str]:
    """What the last reload recorded (empty before migration 0021)."""
    if not exists(conn, "meta.sql_object"):
        return {}
    return dict(conn.execute("SELECT path, sha256 FROM meta.sql_object").fetchall())


def sql_current(conn: psycopg.Connection, directory: Path = SQL_DIR) -> bool:
    """True when the database holds exactly the sql/ files on disk, as the last reload recorded them."""
    loaded = loaded_sql(conn)
    return bool(loaded) and loaded == on_disk_sql(discover_sql(directory))


def _show(p: Path) -> str:
    return str(p.relative_to(REPO)) if p.is_relative_to(REPO) else str(p)


def migrate_and_reload(conn: psycopg.Connection, quiet: bool = False) -> tuple[list[str], int]:
    applied = migrate(conn, quiet=quiet)
    n = reload_sql(conn, quiet=quiet)
    return applied, n
