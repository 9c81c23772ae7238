-- osm.extent_kept(p_ways)
-- Whether a partial update (ingest reading again only the ways p_ways a change file touched, and every
-- relation) keeps the working CRS, which the centre of the footprints' extent chose, and the extent: true when
-- every footprint the change touched whose box moved (the box ST_Extent takes of it, as the full ingest's
-- extent is made of them), before (a staged or changed way's row, every relation's, their rejects') and after
-- it (a staged geometry in osm.building_import), lies strictly inside the extent meta.dataset records, and
-- none of those before was repaired (a repaired footprint's box need not be its ring's). Else the update
-- stages every candidate (etl/ingest/stage.py).
-- Example: SELECT osm.extent_kept(ARRAY[4711]::bigint[]);
CREATE OR REPLACE FUNCTION osm.extent_kept(p_ways bigint[])
RETURNS boolean
LANGUAGE sql STABLE
AS $$
    WITH box AS (SELECT ST_XMin(bbox) AS x0, ST_YMin(bbox) AS y0, ST_XMax(bbox) AS x1, ST_YMax(bbox) AS y1
                 FROM meta.dataset WHERE bbox IS NOT NULL),
    new AS (SELECT i.osm_type, i.osm_id, ST_XMin(e.b) AS x0, ST_YMin(e.b) AS y0, ST_XMax(e.b) AS x1, ST_YMax(e.b) AS y1
            FROM osm.building_import i CROSS JOIN LATERAL (SELECT ST_Extent(x.g) AS b FROM (SELECT i.geom) x(g)) e
            WHERE i.geom IS NOT NULL),
    old AS (SELECT o.osm_type, o.osm_id, o.repaired, ST_XMin(e.b) AS x0, ST_YMin(e.b) AS y0, ST_XMax(e.b) AS x1,
                   ST_YMax(e.b) AS y1
            FROM (SELECT osm_type, osm_id, geom, repaired FROM osm.building
                  UNION ALL SELECT osm_type, osm_id, geom, false FROM osm.reject WHERE stage = 'ingest') o
            CROSS JOIN LATERAL (SELECT ST_Extent(x.g) AS b FROM (SELECT o.geom) x(g)) e
            WHERE o.geom IS NOT NULL AND (o.osm_type = 'R' OR (o.osm_type = 'W' AND o.osm_id = ANY(p_ways))
                                          OR (o.osm_type, o.osm_id) IN (SELECT osm_type, osm_id FROM new))),
    same AS (SELECT n.osm_type, n.osm_id FROM new n JOIN old o USING (osm_type, osm_id, x0, y0, x1, y1)
             WHERE NOT o.repaired),
    moved AS (SELECT x0, y0, x1, y1, false AS repaired FROM new WHERE (osm_type, osm_id) NOT IN (SELECT * FROM same)
              UNION ALL
              SELECT x0, y0, x1, y1, repaired FROM old WHERE (osm_type, osm_id) NOT IN (SELECT * FROM same))
    SELECT EXISTS (SELECT 1 FROM box)
       AND NOT EXISTS (SELECT 1 FROM moved m, box
                       WHERE m.repaired OR NOT (m.x0 > box.x0 AND m.x1 < box.x1 AND m.y0 > box.y0 AND m.y1 < box.y1))
$$;
COMMENT ON FUNCTION osm.extent_kept(bigint[]) IS
    'Whether the footprints a partial update staged (osm.building_import) or changed (the ways p_ways, every relation) that moved lie strictly inside the extent meta.dataset records, none repaired: then the working CRS and extent stay.';
