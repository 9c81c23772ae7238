-- tiles.build_quadtree(lod, max_features, max_triangles, max_level, base_height)
-- Builds the tile quadtree, budgeted on the meshes of LOD `lod`, set-based, one statement per level:
--   * features are grouped by building (an outline with its parts) and placed by the centre of the
--     outline's bounding box, so a building and its parts always share a tile;
--   * the level-0 cell (tiles.grid) is a region in longitude and latitude around every mesh, square on the
--     ground at its centre, and a level-L cell is that region halved L times (tiles.cell_region), as implicit
--     tiling subdivides its root: so a client that computes tile volumes from the root alone gets our cells,
--     and content overhangs its cell by at most the half-extent of a building that straddles an edge;
--   * a cell becomes a leaf when it holds at most max_features meshes and max_triangles triangles, holds a
--     single building, or is at max_level; otherwise its groups move on to the four cells of the next level;
--   * tiles.tile gets every cell with a content URI, its height above its deepest leaf and the generalization
--     level of its content (gen.level_for_height), its 3D Tiles bounding region (extent of the meshes of
--     every LOD below it, from their stored envelopes, heights above the ellipsoid from base_height) and geometric
--     error 0 for leaves; inner tiles get theirs from the generalize stage (tiles.finish_hierarchy), which
--     measures it;
--   * tiles.building_tile gets each mesh's leaf, its outline (group) and the anchor point that placed it.
-- Both tables are changed in place, never emptied: tiles that vanished are deleted (with what hangs off them),
-- tiles whose cell, counts or mesh region changed are updated (the columns the generalize stage owns, geometric
-- error, content counts, region and box, stay as they were until it runs), new ones inserted; building_tile
-- rows likewise. So in an update the blocks and textures of the other tiles stay readable, as they were, until
-- their stages replace them (readers see the old rows, never none).
-- Example: CALL tiles.build_quadtree(3, 500, 100000, 16, 0);
CREATE OR REPLACE PROCEDURE tiles.build_quadtree(
    lod integer,
    max_features integer,
    max_triangles integer,
    max_level integer,
    base_height double precision
)
LANGUAGE plpgsql
AS $$
DECLARE
    v_srid integer := meta.working_srid();
    v_ox double precision;
    v_oy double precision;
    v_size double precision;
    v_west double precision;
    v_south double precision;
    v_dlon double precision;
    v_dlat double precision;
    v_level integer := 0;
BEGIN
    IF v_srid IS NULL THEN
        RAISE EXCEPTION 'no dataset loaded (meta.dataset is empty): run the ingest stage first';
    END IF;
    DELETE FROM tiles.grid;

    CREATE TEMP TABLE _grp ON COMMIT DROP AS
    SELECT g.group_id, ST_X(c.pt) AS ax, ST_Y(c.pt) AS ay, radians(ST_X(c.geo)) AS lon, radians(ST_Y(c.geo)) AS lat,
           g.n_features, g.n_triangles, NULL::integer AS lvl, NULL::integer AS tx, NULL::integer AS ty
    FROM (
        SELECT coalesce(b.parent_id, b.id) AS group_id, count(*) AS n_features, sum(m.n_triangles) AS n_triangles
        FROM lod.building_mesh m JOIN osm.building b ON b.id = m.building_id
        WHERE m.lod = build_quadtree.lod
        GROUP BY 1
    ) g
    JOIN osm.building o ON o.id = g.group_id
    CROSS JOIN LATERAL (SELECT ST_Centroid(ST_Envelope(o.geom_local)) AS pt) p
    CROSS JOIN LATERAL (SELECT p.pt, ST_Transform(p.pt, 4326) AS geo) c;

    ANALYZE _grp;  -- temporary tables get no statistics from autovacuum: without them every join below is a guess

    IF NOT EXISTS (SELECT 1 FROM _grp) THEN
        -- nothing to tile: say whether the lod stage is missing or drew nothing (every building rejected)
        IF EXISTS (SELECT 1 FROM meta.pipeline_run r WHERE r.stage = 'lod' AND r.status = 'ok'
                   AND r.run_id > coalesce((SELECT max(i.run_id) FROM meta.pipeline_run i
                                            WHERE i.stage = 'ingest' AND i.status = 'ok'), 0)) THEN
            RAISE EXCEPTION 'no LOD% meshes to tile: the lod stage drew no building (% buildings in osm.building, '
                            '% rejected in osm.reject: see their reasons there)', lod,
                            (SELECT count(*) FROM osm.building), (SELECT count(*) FROM osm.reject);
        END IF;
        RAISE EXCEPTION 'no LOD% meshes: run the lod stage first', lod;
    END IF;

    -- The root region: the extent of every mesh of every LOD (their stored envelopes), widened to a square on
    -- the ground at its centre latitude (WGS84 radii of curvature), so that halving it keeps cells near square.
    WITH e AS (
        SELECT ST_Extent(m.envelope_4326)::box2d AS ext
        FROM _grp g
        JOIN osm.building b ON coalesce(b.parent_id, b.id) = g.group_id
        JOIN lod.building_mesh m ON m.building_id = b.id
    ), c AS (
        SELECT radians((ST_XMin(ext) + ST_XMax(ext)) / 2) AS lon, radians((ST_YMin(ext) + ST_YMax(ext)) / 2) AS lat,
               radians(ST_XMax(ext) - ST_XMin(ext)) AS dlon, radians(ST_YMax(ext) - ST_YMin(ext)) AS dlat
        FROM e
    ), r AS (
        -- metres per radian east (N cos lat) and north (M) at the centre
        SELECT c.*, 6378137.0 * cos(c.lat) / sqrt(1 - 0.00669437999014 * sin(c.lat) ^ 2) AS me,
               6378137.0 * (1 - 0.00669437999014) / (1 - 0.00669437999014 * sin(c.lat) ^ 2) ^ 1.5 AS mn
        FROM c
    )
    SELECT greatest(dlon * me, dlat * mn, 1.0) * (1 + 1e-6), lon, lat, me, mn
    INTO v_size, v_west, v_south, v_dlon, v_dlat
    FROM r;
    -- (v_west, v_south hold the centre and v_dlon, v_dlat the metres per radian until here)
    v_dlon := v_size / v_dlon;
    v_dlat := v_size / v_dlat;
    v_west := v_west - v_dlon / 2;
    v_south := v_south - v_dlat / 2;
    SELECT ST_X(o), ST_Y(o) INTO v_ox, v_oy
    FROM ST_Transform(ST_SetSRID(ST_MakePoint(degrees(v_west), degrees(v_south)), 4326), v_srid) o;
    INSERT INTO tiles.grid (srid, origin_x, origin_y, size, west, south, east, north, max_features, max_triangles,
                            max_level)
    VALUES (v_srid, v_ox, v_oy, v_size, v_west, v_south, v_west + v_dlon, v_south + v_dlat, max_features,
            max_triangles, max_level);

    CREATE TEMP TABLE _cell (level integer, x integer, y integer, nf bigint, nt bigint, is_leaf boolean)
        ON COMMIT DROP;
    LOOP
        INSERT INTO _cell (level, x, y, nf, nt, is_leaf)
        SELECT v_level, cx, cy, sum(n_features), sum(n_triangles),
               (sum(n_features) <= max_features AND sum(n_triangles) <= max_triangles)
               OR count(*) = 1 OR v_level >= max_level
        FROM (
            SELECT least(floor((lon - v_west) / v_dlon * 2 ^ v_level), 2 ^ v_level - 1)::integer AS cx,
                   least(floor((lat - v_south) / v_dlat * 2 ^ v_level), 2 ^ v_level - 1)::integer AS cy,
                   n_features, n_triangles
            FROM _grp WHERE lvl IS NULL
        ) s
        GROUP BY cx, cy;

        UPDATE _grp g SET lvl = c.level, tx = c.x, ty = c.y
        FROM _cell c
        WHERE g.lvl IS NULL AND c.level = v_level AND c.is_leaf
          AND c.x = least(floor((g.lon - v_west) / v_dlon * 2 ^ v_level), 2 ^ v_level - 1)::integer
          AND c.y = least(floor((g.lat - v_south) / v_dlat * 2 ^ v_level), 2 ^ v_level - 1)::integer;

        EXIT WHEN NOT EXISTS (SELECT 1 FROM _grp WHERE lvl IS NULL);
        v_level := v_level + 1;
    END LOOP;

    ANALYZE _grp;
    ANALYZE _cell;

    -- The tiles as this run makes them: leaves, region of their meshes at every LOD (each mesh's working-CRS
    -- box, reprojected).
    CREATE TEMP TABLE _tile ON COMMIT DROP AS
    SELECT c.level::smallint AS level, c.x, c.y, true AS is_leaf, c.nf::integer AS n_features, c.nt AS n_triangles,
           tiles.cell_envelope(c.level, c.x, c.y) AS cell,
           ARRAY[radians(ST_XMin(e.ext)), radians(ST_YMin(e.ext)), radians(ST_XMax(e.ext)), radians(ST_YMax(e.ext)),
                 base_height + e.zmin, base_height + e.zmax] AS region,
           format('content/%s/%s/%s.glb', c.level, c.x, c.y) AS content_uri,
           0::smallint AS height, 4::smallint AS gen_level
    FROM _cell c
    JOIN (
        -- bounds of every LOD's mesh: roofs add height, onion domes and LOD3 openings stand out of the walls;
        -- from each mesh's stored envelope (migrations/0045), not from the meshes themselves
        SELECT g.lvl, g.tx, g.ty, ST_Extent(m.envelope_4326)::box2d AS ext,
               min(m.min_height) AS zmin, max(m.height) AS zmax
        FROM _grp g
        JOIN osm.building b ON coalesce(b.parent_id, b.id) = g.group_id
        JOIN lod.building_mesh m ON m.building_id = b.id
        GROUP BY g.lvl, g.tx, g.ty
    ) e ON e.lvl = c.level AND e.tx = c.x AND e.ty = c.y
    WHERE c.is_leaf;

    -- Inner tiles: union of the leaves below them (each leaf expanded to all its ancestors).
    INSERT INTO _tile
    SELECT a.level, a.x, a.y, false, sum(l.n_features), sum(l.n_triangles),
           tiles.cell_envelope(a.level, a.x, a.y),
           ARRAY[min(l.region[1]), min(l.region[2]), max(l.region[3]), max(l.region[4]),
                 min(l.region[5]), max(l.region[6])],
           format('content/%s/%s/%s.glb', a.level, a.x, a.y),
           max(l.level - a.level), NULL
    FROM _tile l
    CROSS JOIN LATERAL (
        SELECT k AS level, l.x >> (l.level - k) AS x, l.y >> (l.level - k) AS y
        FROM generate_series(0, l.level - 1) k
    ) a
    WHERE l.is_leaf
    GROUP BY a.level, a.x, a.y;

    UPDATE _tile SET gen_level = gen.level_for_height(height, (SELECT r.height FROM _tile r WHERE r.level = 0),
                                                      v_size / 2 ^ level);
    ANALYZE _tile;

    -- into tiles.tile: the vanished go (their blocks, textures and content with them), the changed are updated
    DELETE FROM tiles.tile t WHERE NOT EXISTS (SELECT 1 FROM _tile n WHERE (n.level, n.x, n.y) = (t.level, t.x, t.y));
    UPDATE tiles.tile t
    SET is_leaf = n.is_leaf, n_features = n.n_features, n_triangles = n.n_triangles, cell = n.cell,
        mesh_region = n.region, content_uri = n.content_uri, height = n.height, gen_level = n.gen_level
    FROM _tile n
    WHERE (n.level, n.x, n.y) = (t.level, t.x, t.y)
      AND (t.is_leaf, t.n_features, t.n_triangles, t.cell, t.mesh_region, t.content_uri, t.height, t.gen_level)
          IS DISTINCT FROM (n.is_leaf, n.n_features, n.n_triangles, n.cell, n.region, n.content_uri, n.height,
                            n.gen_level);
    INSERT INTO tiles.tile (level, x, y, is_leaf, n_features, n_triangles, cell, region, mesh_region,
                            geometric_error, content_uri, height, gen_level)
    SELECT n.level, n.x, n.y, n.is_leaf, n.n_features, n.n_triangles, n.cell, n.region, n.region,
           CASE WHEN n.is_leaf THEN 0.0 END, n.content_uri, n.height, n.gen_level
    FROM _tile n
    WHERE NOT EXISTS (SELECT 1 FROM tiles.tile t WHERE (t.level, t.x, t.y) = (n.level, n.x, n.y))
    ORDER BY n.level, n.x, n.y;

    CREATE TEMP TABLE _placed ON COMMIT DROP AS
    SELECT m.building_id, g.lvl::smallint AS level, g.tx AS x, g.ty AS y, g.group_id,
           ST_SetSRID(ST_MakePoint(g.ax, g.ay), v_srid) AS anchor
    FROM lod.building_mesh m
    JOIN osm.building b ON b.id = m.building_id
    JOIN _grp g ON g.group_id = coalesce(b.parent_id, b.id)
    WHERE m.lod = build_quadtree.lod;
    ALTER TABLE _placed ADD PRIMARY KEY (building_id);
    DELETE FROM tiles.building_tile o
    WHERE NOT EXISTS (SELECT 1 FROM _placed n
                      WHERE n.building_id = o.building_id
                        AND (n.level, n.x, n.y, n.group_id, n.anchor) = (o.level, o.x, o.y, o.group_id, o.anchor));
    INSERT INTO tiles.building_tile (building_id, level, x, y, group_id, anchor)
    SELECT n.building_id, n.level, n.x, n.y, n.group_id, n.anchor
    FROM _placed n
    WHERE NOT EXISTS (SELECT 1 FROM tiles.building_tile o WHERE o.building_id = n.building_id)
    ORDER BY n.building_id;

    -- for the generalize stage's first statements, before autovacuum sees the committed tables
    ANALYZE tiles.tile;
    ANALYZE tiles.building_tile;
END
$$;
COMMENT ON PROCEDURE tiles.build_quadtree(integer, integer, integer, integer, double precision) IS
    'Fills tiles.grid, tiles.tile and tiles.building_tile: a quadtree over the meshes of one LOD split by a feature/triangle budget.';
