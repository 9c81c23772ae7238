-- lm.building_measures(religious_types, tower_types) -> one row per drawn building, in id order
-- What the landmarks stage scores: every drawn building (an outline with its parts, or a lone part) with
-- its point on surface (the node of the Delaunay triangulation) and the radius of the circle around it that
-- covers the outline, the outline's area, perimeter, oriented-envelope area and vertex count (shape), the
-- height of its tallest LOD2 mesh and the volume of them all, and its semantic tags: a flag holds when the
-- outline or any of its parts has it.
--   religious_types  building / building:part values of religious buildings (etl/landmarks/stage.py RELIGIOUS)
--   tower_types      building / man_made values of towers (TOWERS)
-- Streamed by a server-side cursor: inlined into the caller's query (LANGUAGE sql, STABLE, not STRICT).
-- Example: SELECT building_id, height, volume, worship FROM lm.building_measures(ARRAY['church'], ARRAY['tower'])
--          ORDER BY height DESC LIMIT 5;
CREATE OR REPLACE FUNCTION lm.building_measures(religious_types text[], tower_types text[])
RETURNS TABLE (
    building_id   bigint,
    x             double precision,
    y             double precision,
    area          double precision,
    perimeter     double precision,
    envelope_area double precision,
    n_points      integer,
    height        real,
    volume        double precision,
    worship       boolean,
    religious     boolean,
    tower         boolean,
    historic      boolean,
    wikidata      boolean,
    tourism       boolean,
    named         boolean,
    radius        double precision
)
LANGUAGE sql STABLE PARALLEL SAFE
AS $$
    WITH f AS (
        SELECT coalesce(o.parent_id, o.id) AS gid,
               bool_or(o.tags->>'amenity' = 'place_of_worship') AS worship,
               bool_or(o.building = ANY($1) OR o.tags->>'building:part' = ANY($1)) AS religious,
               bool_or(o.building = ANY($2) OR o.tags->>'man_made' = ANY($2) OR o.tags ? 'tower:type') AS tower,
               bool_or(o.tags ? 'historic' OR o.tags ? 'heritage') AS historic,
               bool_or(o.tags ? 'wikidata' OR o.tags ? 'wikipedia') AS wikidata,
               bool_or(o.tags ? 'tourism') AS tourism,
               bool_or(o.name IS NOT NULL) AS named
        FROM osm.building o GROUP BY 1
    ), g AS (
        SELECT coalesce(o.parent_id, o.id) AS gid, max(m.height) AS height,
               sum(m.volume_m3 ORDER BY m.building_id) AS volume  -- in id order: the same bits after an update
        FROM lod.building_mesh m JOIN osm.building o ON o.id = m.building_id
        WHERE m.lod = 2 GROUP BY 1
    )
    SELECT b.id, ST_X(c.p), ST_Y(c.p), ST_Area(b.geom_local), ST_Perimeter(b.geom_local),
           ST_Area(ST_OrientedEnvelope(b.geom_local)), ST_NPoints(b.geom_local), g.height, g.volume,
           f.worship, f.religious, f.tower, f.historic, f.wikidata, f.tourism, f.named,
           ST_MaxDistance(c.p, b.geom_local)
    FROM osm.building b
    JOIN g ON g.gid = b.id
    JOIN f ON f.gid = b.id
    -- OFFSET 0: computed once, not substituted into each of its three uses (0.35 s against 0.21 s on Liechtenstein)
    CROSS JOIN LATERAL (SELECT ST_PointOnSurface(b.geom_local) AS p OFFSET 0) c
    ORDER BY b.id
$$;
COMMENT ON FUNCTION lm.building_measures(text[], text[]) IS
    'Per drawn building (outline with its parts): point on surface, covering radius, footprint area, perimeter, oriented-envelope area, vertex count, LOD2 height and volume, semantic tag flags; id order. Example: SELECT * FROM lm.building_measures(ARRAY[''church''], ARRAY[''tower'']) LIMIT 5;';
