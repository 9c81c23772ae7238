"""The pure parts of benchmarks/scale_bench.py (make bench's Scale section): growth exponents and the section."""

import os

import pytest

from benchmarks import scale_bench as sb


def run(copies: int, buildings: int, factor: float, o2p: float | None = 1.0) -> dict:
    stages = {
        st: {
            "s": 2.0 * factor * (3.0 if st == "textures" else 1.0),
            "client_rss_mib": 100.0 * copies,
            "server_rss_mib": 50.0,
        }
        for st in sb.STAGES
    }
    total = sum(s["s"] for s in stages.values())
    return {
        "copies": copies,
        "osm_bytes": 2_700_000 * copies,
        "buildings": buildings,
        "stages": stages,
        "total_s": total,
        "buildings_per_s": buildings / total,
        "db_bytes": 10**8 * copies,
        "tileset_bytes": 4 * 10**7 * copies,
        "osm2pgsql_s": o2p,
    }


def test_exponents_are_one_for_linear_stages_and_two_for_quadratic_ones() -> None:
    a, b = run(1, 1000, 1.0), run(6, 6000, 6.0)
    b["stages"]["ingest"]["s"] = a["stages"]["ingest"]["s"] * 36
    e = sb.exponents([a, b])
    assert len(e) == 1
    assert e[0]["lod"] == pytest.approx(1.0) and e[0]["ingest"] == pytest.approx(2.0)
    assert sb.exponents([a]) == []


def test_section_has_every_stage_the_totals_and_the_osm2pgsql_ratio() -> None:
    a, b = run(1, 1000, 1.0), run(6, 6000, 6.0, o2p=None)
    data = {"extract": "li", "runs": [a, b], "exponents": sb.exponents([a, b])}
    text = "\n".join(sb.section(data))
    assert "## Scale: li and its replicas" in text
    for st in sb.STAGES:
        assert f"| {st} |" in text
    assert "| ×1 | 2.7 | 1,000 |" in text and "| 2.0× |" in text  # ingest 2 s against osm2pgsql's 1 s
    assert "| ×6 | 16.2 | 6,000 |" in text and text.count("| – | – |") == 1  # no osm2pgsql figure at ×6
    assert "Largest stage exponent" in text
    assert sb.section(None) == [] and sb.section({"runs": []}) == []


def test_exponents_use_the_stages_own_seconds_when_recorded() -> None:
    a, b = run(1, 1000, 1.0), run(6, 6000, 6.0)
    for r, own in ((a, 1.0), (b, 36.0)):  # wall time linear, the stage's own seconds quadratic
        r["stages"]["ingest"]["stage_s"] = own
    assert sb.exponents([a, b])[0]["ingest"] == pytest.approx(2.0)


def test_server_memory_counts_only_that_databases_backends() -> None:
    with sb.ServerMemory("a-database-that-does-not-exist-here") as mem:
        pass
    assert mem.peak_kib == 0
    assert os.path.isdir("/proc")
