-- api.tile_uvs(level, x, y) -> per textured feature of tile (level, x, y): its triangles' pages and corner UVs
-- tex.feature_uv as the exporter reads it: page is one little-endian int16 per triangle (-1: vertex colours),
-- uv six little-endian float32 per triangle (u, v of its three corners), in the triangle order of the
-- feature's mesh in api.buildings_for_tile. Features without a row keep their vertex colours. md5: the md5 of
-- page || uv, stored with the row (migrations/0042), for fingerprints (api.export_digest).
-- Example: SELECT feature_kind, count(*), sum(n_triangles) FROM api.tile_uvs(0, 0, 0) GROUP BY 1;
CREATE OR REPLACE FUNCTION api.tile_uvs(level integer, x integer, y integer)
RETURNS TABLE (
    feature_kind text,
    feature_id   bigint,
    n_triangles  integer,
    page         bytea,
    uv           bytea,
    md5          text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT u.feature_kind, u.feature_id, u.n_triangles, u.page, u.uv, u.uv_md5 FROM tex.feature_uv u
    WHERE u.level = $1 AND u.x = $2 AND u.y = $3
$$;
COMMENT ON FUNCTION api.tile_uvs(integer, integer, integer) IS
    'Per textured feature of tile (level, x, y): triangle count, per-triangle atlas pages (int16) and corner UVs (float32) and their md5, as the exporter reads them. Example: SELECT count(*) FROM api.tile_uvs(0, 0, 0);';
