-- osm.finish_ingest(min_area_m2, source_file, source_sha256, p_update, p_changed_ways)
-- Second half of the ingest stage, set-based over the COPY staging table osm.building_import:
--   1. closed ways become polygons (ST_MakePolygon); rings with fewer than 4 points are rejected, and so are
--      footprints crossing the 180th meridian (crosses_antimeridian: they would span the world);
--   2. the working CRS is chosen from the centre of the data (meta.utm_srid) and recorded in meta.dataset;
--   3. invalid polygons are repaired with ST_MakeValid (polygonal part kept, flagged repaired with the GEOS
--      reason); polygons that cannot be repaired, or are smaller than min_area_m2, go to osm.reject;
--   4. the buildings (EPSG:4326 and working-CRS footprints) are assembled in a temporary table, rejects and tag
--      diagnostics are written;
--   5. the spatial indexes of osm.building are built once after a full load, and the table is analyzed;
--   6. parts are linked to their outline: by type=building relation (roles outline/part) first, else by the
--      smallest outline containing the part's point on surface; outlines get n_parts and part_coverage.
--   7. a full ingest (the caller truncated osm.building) loads the new rows; an update (p_update) compares them
--      with osm.building and replaces only the rows that differ (osm.building_change lists them: added,
--      modified, deleted), so that the stages below re-derive those alone.
--   8. a partial update (p_changed_ways not NULL: the caller staged only the candidates a change touched, every
--      relation and the ways p_changed_ways lists or whose nodes moved, and checked that none reaches the edge of
--      the extent, so the working CRS stays) decides the rows of those alone: the staged ones, the changed ways
--      (one no longer a candidate goes) and every relation; their rejects and diagnostics are replaced. The part
--      linking reads, besides them, the unchanged parts and every unchanged outline a part was or may be linked
--      to, so each part gets the outline a full ingest would give it.
-- The caller commits afterwards, so a run is all or nothing.
-- Example: CALL osm.finish_ingest(1.0, 'helsinki.osm.pbf', '<sha256>');
CREATE OR REPLACE PROCEDURE osm.finish_ingest(
    min_area_m2 double precision,
    source_file text,
    source_sha256 text,
    p_update boolean DEFAULT false,
    p_changed_ways bigint[] DEFAULT NULL
)
LANGUAGE plpgsql
AS $$
DECLARE
    v_srid integer;
    v_centre geometry;
    v_indexes text[] := '{}';
    v_index text;
    v_gist record;
    v_partial boolean := p_update AND p_changed_ways IS NOT NULL;
BEGIN
    CREATE TEMP TABLE _cand ON COMMIT DROP AS
    SELECT i.*, x.crosses,
           CASE
               WHEN i.reject_reason IS NOT NULL OR i.geom IS NULL OR x.crosses THEN NULL
               WHEN i.geom_kind = 'L' THEN
                   CASE WHEN ST_NPoints(i.geom) >= 4 AND ST_IsClosed(i.geom)
                        THEN ST_MakePolygon(i.geom) END
               ELSE i.geom
           END AS poly
    FROM osm.building_import i
    -- OSM splits what meets the 180th meridian; a footprint wider than half the world crossed it
    CROSS JOIN LATERAL (SELECT coalesce(ST_XMax(i.geom) - ST_XMin(i.geom) > 180, false) AS crosses) x;

    -- in a partial update, the rows this run decides (osm.building ids: a way's id, a relation's negated)
    CREATE TEMP TABLE _affected ON COMMIT DROP AS
    SELECT CASE WHEN i.osm_type = 'R' THEN -i.osm_id ELSE i.osm_id END AS id, i.osm_type, i.osm_id
    FROM osm.building_import i WHERE v_partial
    UNION SELECT w, 'W', w FROM unnest(p_changed_ways) w WHERE v_partial
    UNION SELECT b.id, b.osm_type, b.osm_id FROM osm.building b WHERE v_partial AND b.osm_type = 'R'
    UNION SELECT -r.osm_id, r.osm_type, r.osm_id FROM osm.reject r
          WHERE v_partial AND r.stage = 'ingest' AND r.osm_type = 'R';
    CREATE UNIQUE INDEX ON _affected (id);
    ANALYZE _affected;
    IF v_partial THEN
        DELETE FROM osm.reject r USING _affected a
        WHERE r.stage = 'ingest' AND r.osm_type = a.osm_type AND r.osm_id = a.osm_id;
        DELETE FROM meta.diagnostic d USING _affected a
        WHERE d.stage = 'ingest' AND d.osm_type = a.osm_type AND d.osm_id = a.osm_id;
        -- the extent, hence the working CRS, is as it was (the caller checked it)
        UPDATE meta.dataset SET source_file = finish_ingest.source_file, source_sha256 = finish_ingest.source_sha256;
        SELECT d.srid INTO v_srid FROM meta.dataset d;
    ELSE
        SELECT ST_Centroid(ST_Extent(poly)::geometry) INTO v_centre FROM _cand WHERE poly IS NOT NULL;
        IF v_centre IS NULL THEN
            v_srid := 4326;  -- nothing loadable; keep a valid row in meta.dataset
        ELSE
            v_srid := meta.utm_srid(ST_X(v_centre), ST_Y(v_centre));
        END IF;

        DELETE FROM meta.dataset;
        INSERT INTO meta.dataset (srid, srid_name, source_file, source_sha256, bbox)
        SELECT v_srid,
               coalesce((SELECT split_part(split_part(srtext, '"', 2), '"', 1) FROM spatial_ref_sys
                         WHERE srid = v_srid), 'EPSG:' || v_srid),
               source_file, source_sha256,
               -- always a polygon: the extent of a single zero-area building is a line or a point as a geometry
               (SELECT ST_MakeEnvelope(ST_XMin(e), ST_YMin(e), ST_XMax(e), ST_YMax(e), 4326)
                FROM (SELECT ST_Extent(poly) AS e FROM _cand WHERE poly IS NOT NULL) x WHERE e IS NOT NULL);
    END IF;

    CREATE TEMP TABLE _fixed ON COMMIT DROP AS
    SELECT s.*, CASE WHEN s.fixed IS NOT NULL AND NOT ST_IsEmpty(s.fixed)
                     THEN ST_Transform(s.fixed, v_srid) END AS fixed_local
    FROM (
        SELECT v.*, CASE WHEN NOT v.valid THEN ST_IsValidReason(v.poly) END AS invalid_reason,
               CASE WHEN v.valid THEN ST_Multi(v.poly)
                    ELSE ST_Multi(ST_CollectionExtract(ST_MakeValid(v.poly), 3)) END AS fixed
        FROM (SELECT c.*, ST_IsValid(c.poly) AS valid FROM _cand c WHERE c.poly IS NOT NULL OFFSET 0) v
        -- the fences (OFFSET 0) make each of valid and fixed computed once per polygon: without them the planner
        -- substitutes the expressions into every use (ST_IsValid five times, ST_MakeValid three; 0.27 s against
        -- 0.09 s for Liechtenstein's footprints)
        OFFSET 0
    ) s;

    -- A footprint valid in degrees can still self-touch after projection; repair again there if needed.
    UPDATE _fixed SET fixed_local = ST_Multi(ST_CollectionExtract(ST_MakeValid(fixed_local), 3)),
                      invalid_reason = coalesce(invalid_reason, 'invalid after projection: '
                                                || ST_IsValidReason(fixed_local)),
                      valid = false
    WHERE fixed_local IS NOT NULL AND NOT ST_IsValid(fixed_local);

    -- The new buildings are assembled in _building first (parts linked, part counts), then either loaded into
    -- the emptied osm.building (a full ingest) or compared with it (an update: only what differs is replaced).
    CREATE TEMP TABLE _building (LIKE osm.building INCLUDING DEFAULTS) ON COMMIT DROP;
    INSERT INTO _building (
        id, osm_type, osm_id, kind, building, part, name, height, min_height, levels, min_level,
        roof_levels, roof_height, roof_angle, roof_shape, roof_direction, roof_orientation,
        building_colour, roof_colour, building_material, roof_material, tags,
        geom, geom_local, area_m2, repaired, repair_reason)
    SELECT CASE WHEN f.osm_type = 'R' THEN -f.osm_id ELSE f.osm_id END,
           f.osm_type, f.osm_id, f.kind, f.building, f.part, f.name, f.height, f.min_height, f.levels,
           f.min_level, f.roof_levels, f.roof_height, f.roof_angle, f.roof_shape, f.roof_direction,
           f.roof_orientation, f.building_colour, f.roof_colour, f.building_material, f.roof_material, f.tags,
           f.fixed, f.fixed_local, ST_Area(f.fixed_local), NOT f.valid, f.invalid_reason
    FROM _fixed f
    WHERE f.fixed_local IS NOT NULL AND NOT ST_IsEmpty(f.fixed_local)
      AND ST_Area(f.fixed_local) >= min_area_m2;
    IF v_partial THEN
        -- the unchanged rows the part linking reads: every part, the outlines of type=building relations, the
        -- outlines parts were linked to and those covering a part's point (their links as a full ingest starts them)
        INSERT INTO _building (
            id, osm_type, osm_id, kind, building, part, name, height, min_height, levels, min_level,
            roof_levels, roof_height, roof_angle, roof_shape, roof_direction, roof_orientation,
            building_colour, roof_colour, building_material, roof_material, tags,
            geom, geom_local, area_m2, repaired, repair_reason)
        SELECT o.id, o.osm_type, o.osm_id, o.kind, o.building, o.part, o.name, o.height, o.min_height, o.levels,
               o.min_level, o.roof_levels, o.roof_height, o.roof_angle, o.roof_shape, o.roof_direction,
               o.roof_orientation, o.building_colour, o.roof_colour, o.building_material, o.roof_material, o.tags,
               o.geom, o.geom_local, o.area_m2, o.repaired, o.repair_reason
        FROM osm.building o
        WHERE o.id IN (
            SELECT p.id FROM osm.building p WHERE p.kind = 'part'
            UNION SELECT p.parent_id FROM osm.building p WHERE p.parent_id IS NOT NULL
            UNION SELECT b.id FROM osm.building b JOIN osm.building_relation_member m
                  ON m.role = 'outline' AND m.member_type = b.osm_type AND m.member_id = b.osm_id
            UNION SELECT c.id
                  FROM (SELECT p.geom_local FROM osm.building p WHERE p.kind = 'part'
                        UNION ALL SELECT p.geom_local FROM _building p WHERE p.kind = 'part') p
                  CROSS JOIN LATERAL (SELECT b.id FROM osm.building b WHERE b.kind = 'building'
                                      AND ST_Covers(b.geom_local, ST_PointOnSurface(p.geom_local))) c)
          AND NOT EXISTS (SELECT 1 FROM _affected a WHERE a.id = o.id);
    END IF;
    CREATE INDEX ON _building USING gist (geom_local);
    CREATE UNIQUE INDEX ON _building (id);
    -- Statistics for the part-linking join below: without them the planner paired every building with every
    -- part (96 M pairs at 107k buildings).
    ANALYZE _building;

    INSERT INTO osm.reject (osm_type, osm_id, stage, reason, detail, tags, geom)
    SELECT c.osm_type, c.osm_id, 'ingest', c.reject_reason, c.reject_detail, c.tags, c.geom
    FROM _cand c WHERE c.reject_reason IS NOT NULL
    UNION ALL
    SELECT c.osm_type, c.osm_id, 'ingest', 'degenerate_ring',
           format('closed way with %s distinct points; a polygon needs at least 3', ST_NPoints(c.geom) - 1),
           c.tags, c.geom
    FROM _cand c WHERE c.reject_reason IS NULL AND c.poly IS NULL AND NOT c.crosses
    UNION ALL
    SELECT c.osm_type, c.osm_id, 'ingest', 'crosses_antimeridian',
           format('its longitudes span %s° to %s°: it crosses the 180th meridian, which OSM data never does '
                  '(split it there)', round(ST_XMin(c.geom)::numeric, 6), round(ST_XMax(c.geom)::numeric, 6)),
           c.tags, c.geom
    FROM _cand c WHERE c.reject_reason IS NULL AND c.crosses
    UNION ALL
    SELECT f.osm_type, f.osm_id, 'ingest', 'invalid_geometry',
           format('%s; ST_MakeValid left no polygon', f.invalid_reason), f.tags, f.poly
    FROM _fixed f WHERE f.fixed_local IS NULL OR ST_IsEmpty(f.fixed_local)
    UNION ALL
    SELECT f.osm_type, f.osm_id, 'ingest', 'too_small',
           format('footprint area %s m² < %s m²', round(ST_Area(f.fixed_local)::numeric, 3), min_area_m2),
           f.tags, f.poly
    FROM _fixed f
    WHERE f.fixed_local IS NOT NULL AND NOT ST_IsEmpty(f.fixed_local) AND ST_Area(f.fixed_local) < min_area_m2;

    INSERT INTO meta.diagnostic (stage, osm_type, osm_id, code, detail)
    SELECT 'ingest', i.osm_type, i.osm_id,
           CASE WHEN e ->> 'code' = 'unit_converted' THEN 'unit_converted' ELSE 'invalid_tag' END,
           format('%s=%s: %s', e ->> 'key', e ->> 'value', e ->> 'detail')
    FROM osm.building_import i CROSS JOIN LATERAL jsonb_array_elements(i.tag_issues) e
    WHERE i.tag_issues IS NOT NULL
    UNION ALL
    SELECT 'ingest', b.osm_type, b.osm_id, 'geometry_repaired', b.repair_reason
    FROM _building b
    -- not the unchanged rows a partial update read for the linking: their diagnostics stay
    WHERE b.repaired AND (NOT v_partial OR EXISTS (SELECT 1 FROM _affected a WHERE a.id = b.id));

    -- Parts named by a type=building relation belong to that relation's outline.
    UPDATE _building p
    SET parent_id = o.id, parent_source = 'relation'
    FROM osm.building_relation_member mp
    JOIN osm.building_relation_member mo ON mo.relation_id = mp.relation_id AND mo.role = 'outline'
    JOIN _building o ON o.osm_type = mo.member_type AND o.osm_id = mo.member_id AND o.kind = 'building'
    WHERE mp.role = 'part' AND p.kind = 'part' AND p.osm_type = mp.member_type AND p.osm_id = mp.member_id;

    -- Other parts belong to the smallest outline that contains them.
    -- Each part probes the spatial index once (a lateral join, materialised first, so the update joins on
    -- the key and never pairs every building with every part).
    CREATE TEMP TABLE _link ON COMMIT DROP AS
    SELECT q.id, l.outline_id
    FROM _building q
    CROSS JOIN LATERAL (
        SELECT o.id AS outline_id FROM _building o
        WHERE o.kind = 'building' AND ST_Covers(o.geom_local, ST_PointOnSurface(q.geom_local))
        ORDER BY o.area_m2, o.id LIMIT 1
    ) l
    WHERE q.kind = 'part' AND q.parent_id IS NULL;

    UPDATE _building p
    SET parent_id = s.outline_id, parent_source = 'contains'
    FROM _link s
    WHERE p.id = s.id;

    UPDATE _building o
    SET n_parts = s.n, part_coverage = s.coverage
    FROM (
        SELECT o2.id, count(*) AS n,
               least(1.0, ST_Area(ST_Intersection(o2.geom_local, ST_Union(p.geom_local)))
                          / nullif(o2.area_m2, 0)) AS coverage
        FROM _building o2 JOIN _building p ON p.parent_id = o2.id
        GROUP BY o2.id, o2.geom_local, o2.area_m2
    ) s
    WHERE o.id = s.id;

    IF NOT p_update THEN
        -- Into the emptied table without its spatial indexes, rebuilt after the load from their own definitions
        -- (migrations/ own them): a bulk GiST build is several times faster than one insertion per row.
        FOR v_gist IN SELECT i.indexrelid::regclass::text AS name, pg_get_indexdef(i.indexrelid) AS def
                      FROM pg_index i JOIN pg_class c ON c.oid = i.indexrelid JOIN pg_am a ON a.oid = c.relam
                      WHERE i.indrelid = 'osm.building'::regclass AND a.amname = 'gist' AND NOT i.indisexclusion LOOP
            v_indexes := v_indexes || v_gist.def;
            EXECUTE 'DROP INDEX ' || v_gist.name;  -- a regclass name from the catalog, already quoted
        END LOOP;
        INSERT INTO osm.building SELECT * FROM _building;
        FOREACH v_index IN ARRAY v_indexes LOOP
            EXECUTE v_index;  -- CREATE INDEX statements as pg_get_indexdef wrote them
        END LOOP;
        TRUNCATE osm.building_change;
    ELSE
        -- An update: the rows that differ in anything ingest derives (landmarks' protected flag aside) are
        -- updated in place, so what the stages below derived from them stays readable until those stages
        -- replace it; deleted buildings go with what was derived from them (ON DELETE CASCADE); the others are
        -- not touched. osm.building_change lists them for the stages below. No TRUNCATE: readers of these
        -- tables see the rows of before until the commit and never wait for it.
        DELETE FROM osm.building_change;
        INSERT INTO osm.building_change (id, change)
        SELECT coalesce(n.id, o.id),
               CASE WHEN o.id IS NULL THEN 'added' WHEN n.id IS NULL THEN 'deleted' ELSE 'modified' END
        FROM _building n
        FULL JOIN (SELECT * FROM osm.building b
                   WHERE NOT v_partial
                      OR b.id IN (SELECT a.id FROM _affected a UNION ALL SELECT k.id FROM _building k)) o
          ON o.id = n.id
        WHERE n.id IS NULL OR o.id IS NULL OR
               (n.osm_type, n.osm_id, n.kind, n.building, n.part, n.name, n.height, n.min_height, n.levels,
                n.min_level, n.roof_levels, n.roof_height, n.roof_angle, n.roof_shape, n.roof_direction,
                n.roof_orientation, n.building_colour, n.roof_colour, n.building_material, n.roof_material, n.tags,
                n.geom, n.geom_local, n.area_m2, n.repaired, n.repair_reason, n.parent_id, n.parent_source,
                n.n_parts, n.part_coverage)
               IS DISTINCT FROM
               (o.osm_type, o.osm_id, o.kind, o.building, o.part, o.name, o.height, o.min_height, o.levels,
                o.min_level, o.roof_levels, o.roof_height, o.roof_angle, o.roof_shape, o.roof_direction,
                o.roof_orientation, o.building_colour, o.roof_colour, o.building_material, o.roof_material, o.tags,
                o.geom, o.geom_local, o.area_m2, o.repaired, o.repair_reason, o.parent_id, o.parent_source,
                o.n_parts, o.part_coverage);
        DELETE FROM osm.building b USING osm.building_change c WHERE b.id = c.id AND c.change = 'deleted';
        UPDATE osm.building b
        SET (osm_type, osm_id, kind, building, part, name, height, min_height, levels, min_level, roof_levels,
             roof_height, roof_angle, roof_shape, roof_direction, roof_orientation, building_colour, roof_colour,
             building_material, roof_material, tags, geom, geom_local, area_m2, repaired, repair_reason, parent_id,
             parent_source, n_parts, part_coverage)
          = (n.osm_type, n.osm_id, n.kind, n.building, n.part, n.name, n.height, n.min_height, n.levels,
             n.min_level, n.roof_levels, n.roof_height, n.roof_angle, n.roof_shape, n.roof_direction,
             n.roof_orientation, n.building_colour, n.roof_colour, n.building_material, n.roof_material, n.tags,
             n.geom, n.geom_local, n.area_m2, n.repaired, n.repair_reason, n.parent_id, n.parent_source,
             n.n_parts, n.part_coverage)
        FROM _building n JOIN osm.building_change c ON c.id = n.id AND c.change = 'modified'
        WHERE b.id = n.id;
        INSERT INTO osm.building
        SELECT n.* FROM _building n JOIN osm.building_change c ON c.id = n.id AND c.change = 'added';
    END IF;
    ANALYZE osm.building;  -- for the stages that read it next (autovacuum sees it only after the commit)
    TRUNCATE osm.building_import;
END
$$;
COMMENT ON PROCEDURE osm.finish_ingest(double precision, text, text, boolean, bigint[]) IS
    'Turns the ingest staging table into osm.building and osm.reject: polygons, working CRS, repair, part linking; in an update only the rows that differ, in a partial one only those of the candidates staged. Example: CALL osm.finish_ingest(1.0, ''helsinki.osm.pbf'', ''<sha256>'');';
