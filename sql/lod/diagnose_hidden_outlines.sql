-- lod.diagnose_hidden_outlines(coverage, INOUT n_hidden, ids) -> outlines hidden by their parts
-- The S3DB outline rule, recorded: an outline (not itself a part) whose building:parts cover at least
-- `coverage` of its area is not drawn by the lod stage (lod.building_input leaves it out; its parts are
-- drawn); each gets an outline_hidden_by_parts diagnostic saying how much its parts cover. Returns how many.
--   coverage  settings.outline_part_coverage (0.9: OSM2World's rule; 0: any part hides the outline)
--   ids       these osm.building ids alone (an update's), or NULL for all
-- Example: CALL lod.diagnose_hidden_outlines(0.9, NULL);
CREATE OR REPLACE PROCEDURE lod.diagnose_hidden_outlines(coverage double precision, INOUT n_hidden bigint DEFAULT NULL,
                                                         ids bigint[] DEFAULT NULL)
LANGUAGE plpgsql
AS $$
BEGIN
    INSERT INTO meta.diagnostic (stage, osm_type, osm_id, code, detail)
    SELECT 'lod', osm_type, osm_id, 'outline_hidden_by_parts',
           format('%s parts cover %s%% of the outline (threshold %s%%)', n_parts,
                  round(100 * coalesce(part_coverage, 0))::int, round(100 * coverage::numeric))
    FROM osm.building
    WHERE kind = 'building' AND part IS NULL AND n_parts > 0 AND coalesce(part_coverage, 0) >= coverage
      AND (ids IS NULL OR id = ANY(ids));
    GET DIAGNOSTICS n_hidden = ROW_COUNT;
END
$$;
COMMENT ON PROCEDURE lod.diagnose_hidden_outlines(double precision, bigint, bigint[]) IS
    'Writes an outline_hidden_by_parts diagnostic (stage lod) for every outline whose parts cover at least coverage of it, and returns how many (n_hidden). Run by the lod stage.';
