"""What a request path may name, decided before any file is opened or the database is asked.

A URL path is percent-decoded strictly (UTF-8, from the raw bytes the client sent), then either joined under a
root directory (``safe_join``: no '..', NUL or backslash, no symlink leading out of the root) or, under
``/tiles/`` in DB mode, classified as tileset.json or a canonical tile address (``tile_address``). Anything
malformed raises BadPath, answered with 400; a well-formed name of nothing is None, answered with 404.
"""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote_to_bytes


class BadPath(ValueError):
    """The request path is malformed or tries to leave its root (answered with 400)."""


def decode(raw_path: bytes) -> str:
    """The path as the client meant it: percent-decoded, then UTF-8. BadPath for bytes that are not UTF-8, so
    ``%ff`` is a 400 rather than a replacement character that names some other file."""
    try:
        return unquote_to_bytes(raw_path).decode("utf-8")
    except UnicodeDecodeError as e:
        raise BadPath(repr(raw_path)) from e


def safe_join(root: Path, rel: str) -> Path | None:
    """The file ``rel`` (decoded, '/'-separated) under ``root``, or None when there is no such regular file.
    Raises BadPath for '..', NUL and the like, so a traversal attempt is a 400, not a probe."""
    if "\x00" in rel or "\\" in rel:
        raise BadPath(rel)
    parts = [p for p in rel.split("/") if p not in ("", ".")]
    if any(p == ".." for p in parts):
        raise BadPath(rel)
    root = root.resolve()
    try:
        target = root.joinpath(*parts).resolve()
        # resolve() follows symlinks: this refuses a link that points outside the root as well.
        if not target.is_relative_to(root) or not target.is_file():
            return None
    except (OSError, RuntimeError):  # permissions, symlink loops, over-long names
        return None
    return target


TILESET = "tileset.json"
#: The quadtree never goes deeper than this (settings.tile_max_level is 16); deeper addresses are 404s.
MAX_TILE_LEVEL = 30
_INT = r"(0|[1-9][0-9]{0,9})"  # canonical: no sign, no leading zeros, at most 10 digits
_CONTENT_RE = re.compile(rf"content/{_INT}/{_INT}/{_INT}\.glb")
_SUBTREE_RE = re.compile(rf"subtrees/{_INT}/{_INT}/{_INT}\.subtree")


def tile_address(rel: str) -> str | None:
    """Classify what follows ``/tiles/`` (decoded): ``tileset.json``, a canonical ``content/L/X/Y.glb`` or
    ``subtrees/L/X/Y.subtree`` (implicit tiling); None for an address that cannot exist (404). Raises BadPath
    (400) for anything malformed: '..', NUL, backslashes, a tile path that is not three non-negative decimal
    integers."""
    if "\x00" in rel or "\\" in rel or ".." in rel.split("/"):
        raise BadPath(rel)
    if rel == TILESET:
        return rel
    if rel.startswith("content/"):
        m = _CONTENT_RE.fullmatch(rel)
    elif rel.startswith("subtrees/"):
        m = _SUBTREE_RE.fullmatch(rel)
    else:
        return None
    if m is None:
        raise BadPath(rel)
    level, x, y = (int(g) for g in m.groups())
    if level > MAX_TILE_LEVEL or x >= 1 << level or y >= 1 << level:
        return None
    return rel
