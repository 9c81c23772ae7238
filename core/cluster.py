"""The embedded PostgreSQL cluster under ``var/pg`` (or whatever ``DATABASE_URL`` points at).

PostgreSQL refuses to run as root, so when we are root the cluster belongs to the ``postgres`` system user
(created by the Debian package) and every server command runs through ``runuser``. It listens only on a unix
socket in ``var/pg/sock`` (no TCP), so two checkouts never clash over a port and no other machine, nor another
local user (the directory is 0700), can reach it; authentication is ``trust`` on that socket. Tools that
want a TCP address (none of ours do) can use DATABASE_URL to point at a server of their own.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from core.settings import REPO, Settings

PG_VERSION = "15"
PGBIN = Path(f"/usr/lib/postgresql/{PG_VERSION}/bin")
SUPERUSER = "citylod"


class ClusterError(RuntimeError):
    pass


@dataclass(frozen=True)
class Cluster:
    root: Path
    port: int

    @property
    def data(self) -> Path:
        return self.root / "data"

    @property
    def sock(self) -> Path:
        return self.root / "sock"

    @property
    def log(self) -> Path:
        return self.root / "server.log"

    def url(self, dbname: str) -> str:
        return f"postgresql://{SUPERUSER}@/{dbname}?host={self.sock}&port={self.port}"


def _owner() -> str | None:
    """System user that runs the server, or None to run as ourselves (non-root developers)."""
    return "postgres" if os.geteuid() == 0 else None


def _as_owner(cmd: list[str]) -> list[str]:
    owner = _owner()
    return ["runuser", "-u", owner, "--", *cmd] if owner else cmd


def _owner_can_reach(path: Path) -> bool:
    owner = _owner()
    if owner is None:
        return True
    probe = path
    while not probe.exists():
        probe = probe.parent
    return subprocess.run(["runuser", "-u", owner, "--", "test", "-x", str(probe)]).returncode == 0


def locate(settings: Settings | None = None) -> Cluster:
    """Cluster directory: ``var/pg`` under the repo, unless the server's user cannot reach it (a clone under
    /root, say) or the socket path would exceed the 107-byte limit; then a per-repo directory in /var/tmp."""
    settings = settings or Settings.from_env()
    root = REPO / "var" / "pg"
    sock_path = root / "sock" / f".s.PGSQL.{settings.pg_port}"
    if not _owner_can_reach(REPO) or len(str(sock_path)) > 100:
        digest = hashlib.sha1(str(REPO).encode()).hexdigest()[:10]
        root = Path("/var/tmp") / f"citylod-pg-{digest}"
    return Cluster(root=root, port=settings.pg_port)


def database_url(dbname: str | None = None, settings: Settings | None = None) -> str:
    """DATABASE_URL when set, else the URL of the local cluster (which need not be running yet)."""
    settings = settings or Settings.from_env()
    env = os.environ.get("DATABASE_URL")
    if env:
        if dbname is None:
            return env
        from psycopg.conninfo import conninfo_to_dict, make_conninfo

        return make_conninfo("", **{**conninfo_to_dict(env), "dbname": dbname})
    return locate(settings).url(dbname or settings.pg_database)


def is_running(cluster: Cluster) -> bool:
    if not (cluster.data / "PG_VERSION").exists():
        return False
    r = subprocess.run(
        _as_owner([str(PGBIN / "pg_ctl"), "-D", str(cluster.data), "status"]),
        capture_output=True,
        text=True,
    )
    return r.returncode == 0


def _check_binaries() -> None:
    if not (PGBIN / "initdb").exists():
        raise ClusterError(
            f"PostgreSQL {PG_VERSION} is not installed ({PGBIN}/initdb missing). "
            "Run `make setup` (installs postgresql-15-postgis-3) or set DATABASE_URL."
        )


def start(settings: Settings | None = None, quiet: bool = False) -> Cluster:
    """Initialise (first time) and start the local cluster; create the city database. Idempotent."""
    settings = settings or Settings.from_env()
    cluster = locate(settings)
    _check_binaries()
    owner = _owner()
    if not (cluster.data / "PG_VERSION").exists():
        cluster.sock.mkdir(parents=True, exist_ok=True)
        cluster.sock.chmod(0o700)
        if owner:
            shutil.chown(cluster.root, owner, owner)
            shutil.chown(cluster.sock, owner, owner)
        subprocess.run(
            _as_owner(
                [
                    str(PGBIN / "initdb"),
                    "-D",
                    str(cluster.data),
                    "-A",
                    "trust",
                    "-U",
                    SUPERUSER,
                    "--no-sync",
                    "-E",
                    "UTF8",
                    "--locale=C.UTF-8",
                ]
            ),
            check=True,
            stdout=subprocess.DEVNULL,
        )
        conf = cluster.data / "postgresql.auto.conf"
        extra = (
            f"listen_addresses = ''\nport = {cluster.port}\n"
            f"unix_socket_directories = '{cluster.sock}'\n"
            # A throwaway development cluster: durability is traded for load speed (osm2pgsql's advice too).
            "fsync = off\nsynchronous_commit = off\nfull_page_writes = off\n"
            "shared_buffers = '512MB'\nwork_mem = '64MB'\nmaintenance_work_mem = '512MB'\n"
            "max_wal_size = '4GB'\ncheckpoint_timeout = '30min'\n"
            # no replicas: COPY into a table truncated in the same transaction then skips WAL entirely
            "wal_level = minimal\nmax_wal_senders = 0\n"
            "max_parallel_workers_per_gather = 2\n"
            # JIT compile time outweighs its gain on the pipeline's short statements.
            "jit = off\n"
        )
        if owner:
            subprocess.run(_as_owner(["sh", "-c", f"cat >> '{conf}'"]), input=extra.encode(), check=True)
        else:
            with conf.open("a") as fh:
                fh.write(extra)
    if not is_running(cluster):
        r = subprocess.run(
            _as_owner(
                [
                    str(PGBIN / "pg_ctl"),
                    "-D",
                    str(cluster.data),
                    "-l",
                    str(cluster.log),
                    "-w",
                    "-t",
                    "60",
                    "start",
                ]
            ),
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        if r.returncode != 0:
            tail = cluster.log.read_text(errors="replace").splitlines()[-5:] if cluster.log.exists() else []
            raise ClusterError(
                f"PostgreSQL did not start (pg_ctl: {r.stderr.strip()}); last lines of {cluster.log}:\n  "
                + "\n  ".join(tail)
            )
    _ensure_database(cluster, settings.pg_database)
    if not quiet:
        print(f"PostgreSQL {PG_VERSION} running: {cluster.url(settings.pg_database)}", file=sys.stderr)
    return cluster


def _ensure_database(cluster: Cluster, dbname: str) -> None:
    import psycopg
    from psycopg import sql

    deadline = time.monotonic() + 30
    while True:
        try:
            conn = psycopg.connect(cluster.url("postgres"), autocommit=True)
            break
        except psycopg.OperationalError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)
    with conn:
        exists = conn.execute("SELECT 1 FROM pg_database WHERE datname = %s", (dbname,)).fetchone()
        if not exists:
            conn.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(dbname)))


def stop(settings: Settings | None = None) -> None:
    cluster = locate(settings)
    if is_running(cluster):
        subprocess.run(
            _as_owner([str(PGBIN / "pg_ctl"), "-D", str(cluster.data), "-m", "fast", "-w", "stop"]),
            check=True,
            stdout=subprocess.DEVNULL,
        )
        print("PostgreSQL stopped", file=sys.stderr)
    else:
        print("PostgreSQL was not running", file=sys.stderr)


def ensure(settings: Settings | None = None) -> str:
    """URL of a reachable database: DATABASE_URL as given, or the local cluster (started on demand)."""
    settings = settings or Settings.from_env()
    if os.environ.get("DATABASE_URL"):
        return os.environ["DATABASE_URL"]
    start(settings, quiet=True)
    return locate(settings).url(settings.pg_database)


__all__ = ["Cluster", "ClusterError", "database_url", "ensure", "locate", "start", "stop"]
