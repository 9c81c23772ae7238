"""Reading a 3D Tiles tileset.json: what the stage graph (is an export still on disk?), the database server
(which tile addresses exist) and the tests share. Pure."""

from __future__ import annotations

from typing import Any


def content_uris(tileset: dict[str, Any]) -> list[str]:
    """Every content URI the tileset references (``content`` and 1.1's ``contents``), sorted."""
    out: list[str] = []
    stack = [tileset.get("root", {})]
    while stack:
        tile = stack.pop()
        for c in [tile.get("content"), *tile.get("contents", [])]:
            if isinstance(c, dict) and "uri" in c:
                out.append(c["uri"])
        stack.extend(tile.get("children", []))
    return sorted(out)
