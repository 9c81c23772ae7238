-- tiles.finish_hierarchy(base_height, levels DEFAULT NULL, xs DEFAULT NULL, ys DEFAULT NULL)
-- Completes the tile hierarchy once the generalize stage has filled gen.*: for every tile, its own content
-- (api.buildings_for_tile, exactly what the exporter writes) gives content_features, content_triangles and
-- content_error_m (the largest error bound of its features and of the blocks it omits) and widens its region to
-- the generalized meshes from mesh_region (the LOD meshes' region the tiles stage measured) (simplified outlines
-- and blocks may reach past the meshes they replace); then, leaves up to the root, each inner tile's geometric
-- error becomes the larger of its content error and its children's geometric errors (so it never grows
-- downwards) and its region the union with its children's. Then the blocks within their tile's error are
-- omitted (tiles.omit_within_error), and what is left is each tile's content in tiles.tile_content (for
-- api.lod_for_view, with each feature's bounding sphere, tiles.feature_sphere). Only the rows that differ are
-- written: an update keeps the rows its change does not reach, where rewriting the table wrote every row of the
-- city (and every omitted block's twice). It refuses a tile whose content does not stand for the buildings
-- below it (blocks, drawn or omitted, through their members): as many features as below it in the LOD2/LOD3
-- bands, as many buildings (outlines with their parts) in the others.
--   levels, xs, ys  the tiles to measure again, with their ancestors (an update: the tiles its change reached,
--                   core/changes.py); the others keep what the last run measured, which their content, the same,
--                   gives again. NULL: every tile.
-- Example: CALL tiles.finish_hierarchy(0);
CREATE OR REPLACE PROCEDURE tiles.finish_hierarchy(base_height double precision, levels integer[] DEFAULT NULL,
                                                   xs integer[] DEFAULT NULL, ys integer[] DEFAULT NULL)
LANGUAGE plpgsql
-- the planner puts a Memoize over api.buildings_for_tile, keyed by tile: every tile is read once, so it only copied
-- every feature's row, mesh included, into its cache (71 MB on the benchmark extract; the statement took 1.19 s
-- against 1.01 s without, median of 5 pairs)
SET enable_memoize = off
AS $$
DECLARE
    v_level integer;
    v_bad text;
    v_omitted bigint;
    v_levels integer[];
    v_xs integer[];
    v_ys integer[];
BEGIN
    -- the tiles measured: those given and every ancestor (a tile's error and region take its children's), or all
    CREATE TEMP TABLE _scope ON COMMIT DROP AS
    SELECT t.level, t.x, t.y FROM tiles.tile t
    WHERE levels IS NULL
       OR (t.level, t.x, t.y) IN (SELECT d.level - k, d.x >> k, d.y >> k
                                  FROM unnest(levels, xs, ys) AS d(level, x, y)
                                  CROSS JOIN LATERAL generate_series(0, d.level) k);
    ALTER TABLE _scope ADD PRIMARY KEY (level, x, y);
    ANALYZE _scope;
    IF levels IS NOT NULL THEN
        SELECT coalesce(array_agg(s.level), '{}'), coalesce(array_agg(s.x), '{}'), coalesce(array_agg(s.y), '{}')
        INTO v_levels, v_xs, v_ys FROM _scope s;
    END IF;

    CREATE TEMP TABLE _feature ON COMMIT DROP AS
    SELECT level, x, y, feature_kind, building_id, osm_type, osm_id, lod, gen_level, n_members, n_triangles, error_m,
           min_height, height, ST_Transform(ST_SetSRID(b::box2d::geometry, srid), 4326)::box2d AS ext,
           tiles.feature_sphere(b, srid, base_height) AS sphere, group_id
    FROM (
        SELECT t.level, t.x, t.y, f.feature_kind, f.building_id, f.osm_type, f.osm_id, f.lod, f.gen_level,
               f.n_members, f.n_triangles, f.error_m, f.min_height, f.height, Box3D(f.geom) AS b,
               ST_SRID(f.geom) AS srid,
               CASE WHEN f.feature_kind <> 'block' THEN coalesce(o.parent_id, o.id) END AS group_id
        FROM _scope t
        CROSS JOIN LATERAL api.buildings_for_tile(t.level, t.x, t.y) f
        LEFT JOIN osm.building o ON o.id = f.building_id
        WHERE f.feature_kind <> 'block'
        UNION ALL
        -- the blocks as made, as api.buildings_for_tile's block branch gives them but for the omissions on tile
        -- error, which are decided below from the errors as made (an update finds the last run's still there)
        SELECT k.level, k.x, k.y, 'block', k.block_id, 'B', k.block_id, 0::smallint, k.gen_level, k.n_members,
               k.n_triangles, k.total_error_m, 0::real, k.height, Box3D(k.geom), ST_SRID(k.geom), NULL
        FROM gen.block_as_made k JOIN tiles.tile t ON (t.level, t.x, t.y) = (k.level, k.x, k.y)
        JOIN _scope sc ON (sc.level, sc.x, sc.y) = (t.level, t.x, t.y)
        WHERE t.gen_level <= 1 AND NOT k.omitted
        -- a fence: each mesh is decompressed once, for its Box3D. Without it the planner pulls the box up into
        -- every reference of the inlined tiles.feature_sphere and decompresses the mesh for each (1.45 s
        -- against 0.86 s for this statement on Liechtenstein)
        OFFSET 0
    ) s;

    CREATE TEMP TABLE _content ON COMMIT DROP AS
    SELECT t.level, t.x, t.y, t.gen_level, coalesce(t.mesh_region, t.region) AS mesh_region,
           coalesce(c.nf, 0) AS nf, coalesce(c.nt, 0) AS nt,
           greatest(coalesce(c.err, 0), coalesce(om.err, 0)) AS err, c.ext, c.zmin, c.zmax,
           coalesce(CASE WHEN t.gen_level >= 3 THEN c.nf ELSE c.groups + coalesce(om.members, 0) END, 0)
               AS represented,
           CASE WHEN t.gen_level >= 3 THEN t.n_features
                ELSE (SELECT count(DISTINCT b.group_id) FROM tiles.building_tiles_below(t.level, t.x, t.y) b)
           END AS expected
    FROM tiles.tile t JOIN _scope USING (level, x, y)
    LEFT JOIN (
        SELECT f.level, f.x, f.y, count(*)::integer AS nf, sum(f.n_triangles)::bigint AS nt,
               max(f.error_m)::double precision AS err, ST_Extent(f.ext)::box2d AS ext,
               min(f.min_height) AS zmin, max(f.height) AS zmax,
               -- buildings: blocks through their members, a landmark drawn at LOD2 once for all its parts
               coalesce(sum(f.n_members) FILTER (WHERE f.feature_kind = 'block'), 0)
                   + count(DISTINCT f.group_id) AS groups
        FROM _feature f GROUP BY 1, 2, 3
    ) c ON (c.level, c.x, c.y) = (t.level, t.x, t.y)
    LEFT JOIN (
        -- blocks the tile omits for its band (selection) stand for their members too, with the omission's error
        SELECT k.level, k.x, k.y, sum(k.n_members)::bigint AS members, max(k.total_error_m)::double precision AS err
        FROM gen.block_as_made k WHERE k.omitted GROUP BY 1, 2, 3
    ) om ON (om.level, om.x, om.y) = (t.level, t.x, t.y);

    SELECT string_agg(format('(%s, %s, %s) band %s draws %s for %s', level, x, y, gen_level, represented, expected),
                      '; ')
    INTO v_bad
    FROM (SELECT * FROM _content WHERE represented <> expected ORDER BY level, x, y LIMIT 5) b;
    IF v_bad IS NOT NULL THEN
        RAISE EXCEPTION 'tiles that do not stand for the buildings below them (run generalize after tiles): %', v_bad;
    END IF;

    UPDATE tiles.tile t
    SET content_features = c.nf, content_triangles = c.nt, content_error_m = CASE WHEN t.is_leaf THEN 0 ELSE c.err END,
        geometric_error = CASE WHEN t.is_leaf THEN 0 ELSE c.err END,
        -- widened from the meshes' region the tiles stage measured, not from the last run's (it may shrink)
        region = ARRAY[least(c.mesh_region[1], radians(ST_XMin(c.ext))),
                       least(c.mesh_region[2], radians(ST_YMin(c.ext))),
                       greatest(c.mesh_region[3], radians(ST_XMax(c.ext))),
                       greatest(c.mesh_region[4], radians(ST_YMax(c.ext))),
                       least(c.mesh_region[5], base_height + c.zmin),
                       greatest(c.mesh_region[6], base_height + c.zmax)]
    FROM _content c
    WHERE c.level = t.level AND c.x = t.x AND c.y = t.y;

    FOR v_level IN SELECT DISTINCT t.level FROM tiles.tile t WHERE NOT t.is_leaf ORDER BY 1 DESC LOOP
        UPDATE tiles.tile p
        SET geometric_error = greatest(p.geometric_error, k.ge),
            region = ARRAY[least(p.region[1], k.w), least(p.region[2], k.s), greatest(p.region[3], k.e),
                           greatest(p.region[4], k.n), least(p.region[5], k.lo), greatest(p.region[6], k.hi)]
        FROM (
            SELECT c.x >> 1 AS px, c.y >> 1 AS py, max(c.geometric_error) AS ge,
                   min(c.region[1]) AS w, min(c.region[2]) AS s, max(c.region[3]) AS e, max(c.region[4]) AS n,
                   min(c.region[5]) AS lo, max(c.region[6]) AS hi
            FROM tiles.tile c WHERE c.level = v_level + 1
            GROUP BY 1, 2
        ) k
        WHERE p.level = v_level AND p.x = k.px AND p.y = k.py
          AND (p.level, p.x, p.y) IN (SELECT * FROM _scope);
    END LOOP;

    CALL tiles.omit_within_error(NULL, v_omitted, v_levels, v_xs, v_ys);

    -- the content rows as the table types them (EXCEPT compares them as stored)
    CREATE TEMP TABLE _row (LIKE tiles.tile_content) ON COMMIT DROP;
    INSERT INTO _row (level, x, y, feature_kind, feature_id, osm_type, osm_id, lod, gen_level, n_members,
                      n_triangles, error_m, cx, cy, cz, radius)
    SELECT f.level, f.x, f.y, f.feature_kind, f.building_id, f.osm_type, f.osm_id, f.lod, f.gen_level, f.n_members,
           f.n_triangles, f.error_m, f.sphere[1], f.sphere[2], f.sphere[3], f.sphere[4]
    FROM _feature f
    WHERE NOT EXISTS (SELECT FROM gen.block k
                      WHERE f.feature_kind = 'block' AND k.block_id = f.building_id AND k.omitted);
    -- not TRUNCATE and rewrite: readers keep the old rows until commit, never wait, and only what differs is
    -- written
    DELETE FROM tiles.tile_content c
    USING (SELECT * FROM tiles.tile_content WHERE (level, x, y) IN (SELECT * FROM _scope) EXCEPT SELECT * FROM _row) d
    WHERE (c.level, c.x, c.y, c.feature_kind, c.feature_id) = (d.level, d.x, d.y, d.feature_kind, d.feature_id);
    INSERT INTO tiles.tile_content
    SELECT * FROM (SELECT * FROM _row
                   EXCEPT SELECT * FROM tiles.tile_content WHERE (level, x, y) IN (SELECT * FROM _scope)) n
    ORDER BY level, x, y, feature_kind, feature_id;  -- a tile's rows together on disk
END
$$;
COMMENT ON PROCEDURE tiles.finish_hierarchy(double precision, integer[], integer[], integer[]) IS
    'Fills content counts, content error, measured geometric error (max of content and children) and regions of every tile (or of the tiles given, levels/xs/ys, and their ancestors) from the generalized content, checks each tile stands for every building below it, omits the blocks within their tile''s error (tiles.omit_within_error) and writes the rows of tiles.tile_content that differ. Run by the generalize stage. Example: CALL tiles.finish_hierarchy(0);';
