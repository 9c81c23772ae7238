-- api.tile_tree() -> every tile of the quadtree, parents before children
-- The hierarchy the exporter turns into tileset.json: bounding region (radians, metres above the ellipsoid),
-- geometric error, content URI for leaves.
-- Example: SELECT level, count(*), sum(n_features) FROM api.tile_tree() GROUP BY level ORDER BY level;
CREATE OR REPLACE FUNCTION api.tile_tree()
RETURNS TABLE (
    level           smallint,
    x               integer,
    y               integer,
    is_leaf         boolean,
    n_features      integer,
    n_triangles     bigint,
    region          double precision[],
    geometric_error double precision,
    content_uri     text
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT t.level, t.x, t.y, t.is_leaf, t.n_features, t.n_triangles, t.region, t.geometric_error, t.content_uri
    FROM tiles.tile t
    ORDER BY t.level, t.x, t.y
$$;
COMMENT ON FUNCTION api.tile_tree() IS
    'The tile quadtree, parents first: region, geometric error, content URI. Example: SELECT * FROM api.tile_tree() WHERE level = 0;';
