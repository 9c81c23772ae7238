-- api.tile_tree() -> every tile of the quadtree, parents before children
-- The hierarchy the exporter turns into tileset.json: bounding region (radians, metres above the ellipsoid),
-- measured geometric error, content URI, the band of its content (gen_level: 4 LOD3 ... 0 blocks) and how
-- much content it has.
-- Example: SELECT level, gen_level, count(*), sum(content_features), max(geometric_error)
--          FROM api.tile_tree() GROUP BY 1, 2 ORDER BY 1;
CREATE OR REPLACE FUNCTION api.tile_tree()
RETURNS TABLE (
    level             smallint,
    x                 integer,
    y                 integer,
    is_leaf           boolean,
    n_features        integer,
    n_triangles       bigint,
    region            double precision[],
    geometric_error   double precision,
    content_uri       text,
    content_features  integer,
    content_triangles bigint,
    gen_level         smallint,
    height            smallint
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    SELECT t.level, t.x, t.y, t.is_leaf, t.n_features, t.n_triangles, t.region, t.geometric_error, t.content_uri,
           t.content_features, t.content_triangles, t.gen_level, t.height
    FROM tiles.tile t
    ORDER BY t.level, t.x, t.y
$$;
COMMENT ON FUNCTION api.tile_tree() IS
    'The tile quadtree, parents first: region, measured geometric error, content URI, content band (gen_level) and size. Example: SELECT * FROM api.tile_tree() WHERE level = 0;';
