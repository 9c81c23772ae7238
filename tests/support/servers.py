"""A citylod server for a client to load, and its base URL: ``spawned`` runs a serve command in a child process
(as a user does), ``threaded`` runs an application on a thread of this process (for a test that inspects the
server's cache and pool). Used by the tests and benchmarks/serve_bench.py; the server never imports it."""

from __future__ import annotations

import contextlib
import os
import queue
import subprocess
import sys
import tempfile
import threading
from collections.abc import Iterator, Mapping
from typing import IO, Any

from core.settings import REPO
from exporter.serve.run import ANNOUNCE, listen, url_of, uvicorn_server


@contextlib.contextmanager
def spawned(
    args: list[str], env: Mapping[str, str] | None = None, timeout: float = 30.0
) -> Iterator[tuple[str, subprocess.Popen, IO[str]]]:
    """Run ``python -m <args>`` (a serve command, usually with ``--port 0``) and yield (its base URL, the
    process, its stderr as a file); terminated after. The announcement is read on a thread, so a server that
    hangs before announcing raises RuntimeError with its stderr instead of hanging the caller."""
    with tempfile.TemporaryFile(mode="w+") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", *args],
            cwd=REPO,
            env=dict(env or os.environ),
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
        )
        try:
            lines: queue.Queue[str] = queue.Queue()
            out = proc.stdout
            assert out is not None
            threading.Thread(target=lambda: lines.put(out.readline()), daemon=True).start()
            try:
                line = lines.get(timeout=timeout)
            except queue.Empty:
                line = ""
            if not line.startswith(ANNOUNCE):
                err.seek(0)
                raise RuntimeError(f"python -m {' '.join(args)} did not announce its URL (got {line!r}):\n{err.read()}")
            yield line[len(ANNOUNCE) :].strip(), proc, err
        finally:
            if proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            if proc.stdout:
                proc.stdout.close()


@contextlib.contextmanager
def threaded(app: Any, host: str = "127.0.0.1") -> Iterator[str]:
    """Serve the ASGI ``app`` on a free port from a thread of this process; yields the base URL; stopped after
    (open connections closed, requests in flight finished)."""
    sock = listen(host, 0)
    server = uvicorn_server(app)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        yield url_of(sock)
    finally:
        server.should_exit = True
        thread.join(15)
        sock.close()
