-- 0046: the comments that the columns of two tables never had. README says every table and column has one; the
-- 26 columns of osm.building_import (0003) and 7 of lm.exaggeration (0040) had none, and the check in
-- tests/db/test_migrate.py skipped the staging table and the lm schema. Comments only: nothing else changes. (The
-- columns of the views gen.block_as_made and meta.building_diagnostic get theirs in their sql/ files: a view is
-- dropped and created again by every reload, and with it any comment a migration gave it.)

-- The ingest's COPY staging table: etl/ingest/stage.py writes one row per candidate, osm.finish_ingest reads them
-- into osm.building and osm.reject (and tag_issues into meta.diagnostic) and empties the table.
COMMENT ON COLUMN osm.building_import.osm_type IS 'W = way, R = relation (the candidates are ways and relations with building=* or building:part=*).';
COMMENT ON COLUMN osm.building_import.osm_id IS 'OSM id of the way or relation; osm.finish_ingest makes osm.building.id of it (the way id, or minus the relation id).';
COMMENT ON COLUMN osm.building_import.kind IS 'building (building=* other than no) or part (building:part=* other than no, and no such building=*), as etl/geom/tags.py building_kind decides.';
COMMENT ON COLUMN osm.building_import.building IS 'Value of building=*, trimmed (NULL when untagged).';
COMMENT ON COLUMN osm.building_import.part IS 'Value of building:part=*, trimmed; NULL when untagged or no.';
COMMENT ON COLUMN osm.building_import.name IS 'name=*, trimmed.';
COMMENT ON COLUMN osm.building_import.height IS 'height=* in metres as parsed by etl/geom/tags.py (40 ft, 12,5 converted); NULL when untagged or refused (the reason in tag_issues).';
COMMENT ON COLUMN osm.building_import.min_height IS 'min_height=* in metres, parsed as height; NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.levels IS 'building:levels=* as a number (fractions kept); NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.min_level IS 'building:min_level=* as a number; NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.roof_levels IS 'roof:levels=* as a number; NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.roof_height IS 'roof:height=* in metres, parsed as height; NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.roof_angle IS 'roof:angle=* in degrees (0-90); NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.roof_shape IS 'roof:shape=* (fallback building:roof:shape=*), lower case; not checked against the catalogue here (the lod stage does).';
COMMENT ON COLUMN osm.building_import.roof_direction IS 'roof:direction=* in degrees clockwise from north, in [0, 360); compass points (N, NNE, ...) converted; NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.roof_orientation IS 'roof:orientation=*: along or across; NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.building_colour IS 'building:colour=* as lower-case #rrggbb (hex or colour name converted); NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.roof_colour IS 'roof:colour=* as lower-case #rrggbb (hex or colour name converted); NULL when untagged or refused (see tag_issues).';
COMMENT ON COLUMN osm.building_import.building_material IS 'building:material=*, lower case.';
COMMENT ON COLUMN osm.building_import.roof_material IS 'roof:material=*, lower case.';
COMMENT ON COLUMN osm.building_import.tags IS 'All OSM tags of the way or relation (a JSON object); copied to osm.building.tags, or osm.reject.tags for a reject.';
COMMENT ON COLUMN osm.building_import.tag_issues IS 'Tag values the parser refused or converted, a JSON array of {key, value, code, detail} (NULL when none); osm.finish_ingest writes each into meta.diagnostic (unit_converted, or invalid_tag for a refused value).';
COMMENT ON COLUMN osm.building_import.geom_kind IS 'L = a closed way''s ring as a linestring (osm.finish_ingest makes it a polygon), M = a multipolygon libosmium assembled (holes kept); NULL for a row rejected already (reject_reason).';
COMMENT ON COLUMN osm.building_import.geom IS 'The raw geometry in EPSG:4326, a LineString (geom_kind L) or MultiPolygon (M), as pyosmium built it; not yet validated or repaired. NULL when reject_reason is set.';
COMMENT ON COLUMN osm.building_import.reject_reason IS 'Set when no geometry could be built in Python: unclosed_way, missing_nodes, degenerate_ring, multipolygon_assembly_failed, unsupported_relation; osm.finish_ingest writes the row into osm.reject (stage ingest) with this reason. NULL for a row to build.';
COMMENT ON COLUMN osm.building_import.reject_detail IS 'Human-readable detail of reject_reason (node counts and ids, the libosmium error, the relation type); osm.reject.detail.';

-- The landmarks' exaggeration per building (lm.exaggeration_role, stored by lm.fill_exaggeration): role,
-- landmark_id and gap_m have their comments from 0040.
COMMENT ON COLUMN lm.exaggeration.building_id IS 'lm.building.building_id (osm.building.id of the outline) of the building this row is about; the row goes with it.';
COMMENT ON COLUMN lm.exaggeration.scale_from_m IS 'The landmark''s first lm.building.scale_distances_m: the camera distance (m) from which it is exaggerated. Interval i (from 0) starts at scale_from_m * scale_step^i with scale min(scale_step^(i+1), max_scale); 1 before the first.';
COMMENT ON COLUMN lm.exaggeration.scale_step IS 'The landmark''s first lm.building.scale_factors: the lm_scale_step setting, or its top scale (max_scale) when that is smaller, as it then has a single interval.';
COMMENT ON COLUMN lm.exaggeration.max_scale IS 'The landmark''s top scale, its last lm.building.scale_factors (lm_max_scale at the top of the hierarchy, less for lower levels).';
COMMENT ON COLUMN lm.exaggeration.landmark_centroid IS 'The landmark''s lm.building.centroid (working CRS): the centre of its footprint circle, from which role 2 buildings are pushed away.';
COMMENT ON COLUMN lm.exaggeration.landmark_radius_m IS 'The landmark''s lm.building.radius_m: radius (m) of its footprint circle at scale 1.';
COMMENT ON COLUMN lm.exaggeration.centroid IS 'This building''s lm.building.centroid (working CRS; landmark_centroid for role 1): with landmark_centroid, the direction a role 2 building moves in.';
