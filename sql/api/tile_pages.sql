-- api.tile_pages(level, x, y) -> the texture atlas pages of tile (level, x, y), by page number
-- The encoded images (tex.page, made by the textures stage) the exporter puts into the tile's glb, one
-- material each; none when the tile was not textured.
-- Example: SELECT page_no, mime, length(bytes) FROM api.tile_pages(0, 0, 0);
CREATE OR REPLACE FUNCTION api.tile_pages(level integer, x integer, y integer)
RETURNS TABLE (
    page_no smallint,
    mime    text,
    bytes   bytea
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT p.page_no, p.mime, p.bytes FROM tex.page p WHERE p.level = $1 AND p.x = $2 AND p.y = $3 ORDER BY p.page_no
$$;
COMMENT ON FUNCTION api.tile_pages(integer, integer, integer) IS
    'Atlas pages (number, media type, encoded image) of tile (level, x, y), as the exporter embeds them. Example: SELECT page_no, mime FROM api.tile_pages(0, 0, 0);';
