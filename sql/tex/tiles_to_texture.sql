-- tex.tiles_to_texture() -> every tile with content, in key order: what the textures stage textures
-- With its band (gen_level) and measured geometric error (NULL until the generalize stage ran), which set
-- its texture resolution, and its number of features.
-- Example: SELECT gen_level, count(*), sum(features) FROM tex.tiles_to_texture() GROUP BY 1;
CREATE OR REPLACE FUNCTION tex.tiles_to_texture()
RETURNS TABLE (
    level           smallint,
    x               integer,
    y               integer,
    gen_level       smallint,
    geometric_error double precision,
    is_leaf         boolean,
    features        integer
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT t.level, t.x, t.y, t.gen_level, t.geometric_error, t.is_leaf, t.content_features
    FROM tiles.tile t WHERE t.content_features > 0
    ORDER BY t.level, t.x, t.y
$$;
COMMENT ON FUNCTION tex.tiles_to_texture() IS
    'Tiles with content (level, x, y, band, geometric error, is_leaf, features), in key order: the textures stage''s input. Example: SELECT count(*) FROM tex.tiles_to_texture();';
