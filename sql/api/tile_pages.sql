-- api.tile_pages(level, x, y, format) -> the texture atlas pages of tile (level, x, y) in format webp or ktx2
-- The encoded images (tex.page, made by the textures stage) the exporter puts into the tile's glb, one
-- material each, by page number; none when the tile was not textured. A page the KTX2 encoder refused has a
-- NULL bytes in ktx2 (its features are drawn with vertex colours there: tex.failure ktx2_encode_failed). md5:
-- the md5 of bytes, stored with the page (migrations/0042), for fingerprints (api.export_digest).
-- Example: SELECT page_no, mime, length(bytes) FROM api.tile_pages(0, 0, 0, 'ktx2');
CREATE OR REPLACE FUNCTION api.tile_pages(level integer, x integer, y integer, format text DEFAULT 'webp')
RETURNS TABLE (
    page_no smallint,
    mime    text,
    bytes   bytea,
    md5     text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT p.page_no,
           CASE WHEN $4 = 'ktx2' THEN 'image/ktx2' ELSE p.mime END,
           CASE WHEN $4 = 'ktx2' THEN p.ktx2 ELSE p.bytes END,
           CASE WHEN $4 = 'ktx2' THEN p.ktx2_md5 ELSE p.bytes_md5 END
    FROM tex.page p
    WHERE p.level = $1 AND p.x = $2 AND p.y = $3 AND $4 IN ('webp', 'ktx2')
    ORDER BY p.page_no
$$;
COMMENT ON FUNCTION api.tile_pages(integer, integer, integer, text) IS
    'Atlas pages (number, media type, encoded image, its md5) of tile (level, x, y) in format webp (EXT_texture_webp) or ktx2 (KHR_texture_basisu; bytes NULL where the encoder refused the page), as the exporter embeds them. Example: SELECT page_no, mime FROM api.tile_pages(0, 0, 0, ''ktx2'');';
