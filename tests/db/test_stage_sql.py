"""The stages' SQL lives in sql/ as functions and procedures. The set-returning functions the stages and the
exporter read are inlined into the caller's query, so they plan as the query itself and a server-side cursor
streams them (a set-returning function that is not inlined runs to completion into a tuplestore before its
first row: a whole city in memory instead of a batch); the feature row of a tile is one type for
api.buildings_for_tile and tiles.lod2_features, and api.buildings_for_tile keeps the columns analysts use."""

from collections.abc import Iterator

import psycopg
import pytest

#: Every set-returning function a stage or the exporter reads, called as they call it.
READ = {
    "gen.footprint_input": "SELECT * FROM gen.footprint_input(0.1, 2000)",
    "gen.group_lod2_meshes": "SELECT * FROM gen.group_lod2_meshes(ARRAY[1, 2]::bigint[])",
    "gen.decimation_input": "SELECT * FROM gen.decimation_input(64, 2000)",
    "gen.block_clusters": "SELECT * FROM gen.block_clusters(NULL, NULL, NULL, '', NULL)",
    "gen.coarse_block_clusters": "SELECT * FROM gen.coarse_block_clusters(-1, 2, NULL, NULL, '', NULL)",
    "gen.coarse_bands": "SELECT * FROM gen.coarse_bands(NULL)",
    "lod.building_input": "SELECT * FROM lod.building_input(0.9, ARRAY['hipped'])",
    "lm.building_measures": "SELECT * FROM lm.building_measures(ARRAY['church'], ARRAY['tower'])",
    "tex.tiles_to_texture": "SELECT * FROM tex.tiles_to_texture()",
    "tex.tile_features": "SELECT * FROM tex.tile_features(1, 0, 1)",
    "tex.opening_meshes": "SELECT * FROM tex.opening_meshes(ARRAY[1, 2]::bigint[])",
    "tiles.band_summary": "SELECT * FROM tiles.band_summary()",
    "tiles.lod2_features": "SELECT * FROM tiles.lod2_features(1, 0, 1)",
    "api.export_features": "SELECT * FROM api.export_features(1, 0, 1, NULL, 0)",
    "api.tile_pages": "SELECT * FROM api.tile_pages(1, 0, 1)",
    "api.tile_uvs": "SELECT * FROM api.tile_uvs(1, 0, 1)",
}

#: api.buildings_for_tile's output columns: analysts' queries and the exporter read them by name.
FEATURE_COLUMNS = [
    ("feature_kind", "text"),
    ("building_id", "bigint"),
    ("osm_type", "text"),
    ("osm_id", "bigint"),
    ("kind", "text"),
    ("building_osm_type", "text"),
    ("building_osm_id", "bigint"),
    ("name", "text"),
    ("building", "text"),
    ("height", "real"),
    ("min_height", "real"),
    ("levels", "real"),
    ("roof_shape", "text"),
    ("building_colour", "text"),
    ("roof_colour", "text"),
    ("building_material", "text"),
    ("roof_material", "text"),
    ("lod", "smallint"),
    ("gen_level", "smallint"),
    ("n_members", "integer"),
    ("error_m", "real"),
    ("n_triangles", "integer"),
    ("roof_height", "real"),
    ("semantics", "bytea"),
    ("geom", "geometry"),
    ("mesh_md5", "text"),
]


@pytest.fixture(scope="module")
def conn(new_db) -> Iterator[psycopg.Connection]:
    with psycopg.connect(new_db("stage_sql"), autocommit=True) as c:
        yield c


def _nodes(plan: dict) -> Iterator[dict]:
    yield plan
    for p in plan.get("Plans", []):
        yield from _nodes(p)


@pytest.mark.parametrize("name", sorted(READ))
def test_read_functions_are_inlined(conn, name) -> None:
    schema, func = name.split(".")
    assert conn.execute("SELECT to_regproc(%s)", (name,)).fetchone()[0] is not None
    plan = conn.execute(f"EXPLAIN (VERBOSE, FORMAT JSON) {READ[name]}").fetchone()[0][0]["Plan"]  # type: ignore[index]
    scans = [(n.get("Schema"), n.get("Function Name")) for n in _nodes(plan) if n["Node Type"] == "Function Scan"]
    assert (schema, func) not in scans, f"{name} is run as a function (materialized), not inlined: {scans}"


#: Queries over every tile or batch that read one of READ per tile or batch, and the function they must inline: WITH
#: ORDINALITY on it, for instance, keeps it a Function Scan, which then makes every mesh's WKB that the digests never
#: read (tex.input_digests took 1.12 s against 0.76 s over every tile of the benchmark extract).
CALLERS = {
    "tex.input_digests": ("SELECT * FROM tex.input_digests(ARRAY[1], ARRAY[0], ARRAY[1])", "tex.tile_features"),
    "gen.footprint_unit_digests": ("SELECT * FROM gen.footprint_unit_digests(0.1, 2000)", "gen.group_lod2_meshes"),
}


@pytest.mark.parametrize("name", sorted(CALLERS))
def test_callers_over_the_city_inline_what_they_read(conn, name) -> None:
    query, inner = CALLERS[name]
    plan = conn.execute(f"EXPLAIN (VERBOSE, FORMAT JSON) {query}").fetchone()[0][0]["Plan"]  # type: ignore[index]
    scans = {f"{n.get('Schema')}.{n.get('Function Name')}" for n in _nodes(plan) if n["Node Type"] == "Function Scan"}
    assert name not in scans and inner not in scans, f"{name} runs {inner} as a function, not inlined: {scans}"


def _columns(conn: psycopg.Connection, query: str) -> list[tuple[str, str]]:
    cur = conn.execute(f"{query} LIMIT 0")
    assert cur.description is not None
    types = dict(
        conn.execute(
            "SELECT oid::int, format_type(oid, NULL) FROM pg_type WHERE oid = ANY(%s)",
            ([d.type_code for d in cur.description],),
        ).fetchall()
    )
    return [(d.name, types[d.type_code]) for d in cur.description]


def test_the_feature_row_is_one_type_with_the_public_columns(conn) -> None:
    assert _columns(conn, "SELECT * FROM api.buildings_for_tile(0, 0, 0)") == FEATURE_COLUMNS
    # the LOD2 band's rows are UNIONed into api.buildings_for_tile: the same columns, from the same type
    assert _columns(conn, "SELECT * FROM tiles.lod2_features(0, 0, 0)") == FEATURE_COLUMNS
    rettypes = conn.execute(
        """SELECT DISTINCT prorettype::regtype::text FROM pg_proc
           WHERE oid IN ('api.buildings_for_tile'::regproc, 'tiles.lod2_features'::regproc)"""
    ).fetchall()
    assert rettypes == [("api.feature",)]
    args = conn.execute("SELECT pg_get_function_arguments('api.buildings_for_tile'::regproc)").fetchone()[0]
    assert args == "level integer, x integer, y integer, single_lod integer DEFAULT NULL::integer"
    # what the exporter writes starts with the feature's properties
    export = _columns(conn, "SELECT * FROM api.export_features(0, 0, 0)")
    assert export[:22] == [c for c in FEATURE_COLUMNS if c[0] not in ("n_triangles", "roof_height", "geom", "mesh_md5")]


def test_set_boxes_refuses_arrays_that_do_not_match(conn) -> None:
    with pytest.raises(psycopg.errors.RaiseException, match="need 12 box values"):
        conn.execute("CALL tiles.set_boxes(ARRAY[0]::smallint[], ARRAY[0], ARRAY[0], ARRAY[1, 2, 3]::float8[])")
