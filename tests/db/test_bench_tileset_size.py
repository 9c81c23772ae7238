"""benchmarks/tileset_size.py: the sizes it computes from the tile records are those of the files export writes."""

from benchmarks.tileset_size import measure


def test_tileset_size_benchmark_measures_what_export_writes(city) -> None:
    """benchmarks/tileset_size.py (tile records -> bytes, no glb) gives the sizes of the files the export wrote."""
    c = city("helsinki")
    got = measure(c.url)
    subtrees = list(c.tiles.rglob("*.subtree"))
    assert got["implicit_tileset_json_bytes"] == (c.tiles / "tileset.json").stat().st_size
    assert (got["subtrees"], got["subtree_bytes"]) == (len(subtrees), sum(p.stat().st_size for p in subtrees))
    assert got["subtree_tiles"] == got["tiles"] and got["explicit_tileset_json_bytes"] > 0
