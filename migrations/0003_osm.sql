-- 0003: ingested OSM buildings, building:parts, type=building relations and rejects.
CREATE TABLE osm.building (
    id                bigint  PRIMARY KEY,
    osm_type          char(1) NOT NULL CHECK (osm_type IN ('W', 'R')),
    osm_id            bigint  NOT NULL,
    kind              text    NOT NULL CHECK (kind IN ('building', 'part')),
    building          text,
    part              text,
    name              text,
    height            real,
    min_height        real,
    levels            real,
    min_level         real,
    roof_levels       real,
    roof_height       real,
    roof_angle        real,
    roof_shape        text,
    roof_direction    real,
    roof_orientation  text,
    building_colour   text,
    roof_colour       text,
    building_material text,
    roof_material     text,
    tags              jsonb   NOT NULL,
    geom              geometry(MultiPolygon, 4326) NOT NULL,
    geom_local        geometry(MultiPolygon) NOT NULL,
    area_m2           double precision NOT NULL,
    repaired          boolean NOT NULL DEFAULT false,
    repair_reason     text,
    parent_id         bigint,
    parent_source     text CHECK (parent_source IN ('relation', 'contains')),
    n_parts           integer NOT NULL DEFAULT 0,
    part_coverage     real,
    UNIQUE (osm_type, osm_id)
);
CREATE INDEX building_geom_idx ON osm.building USING gist (geom);
CREATE INDEX building_geom_local_idx ON osm.building USING gist (geom_local);
CREATE INDEX building_parent_idx ON osm.building (parent_id) WHERE parent_id IS NOT NULL;
COMMENT ON TABLE osm.building IS 'Buildings (building=*) and building parts (building:part=*) from closed ways and multipolygon relations, with the Simple 3D Buildings tags parsed. Refused tag values are NULL here and listed in meta.diagnostic.';
COMMENT ON COLUMN osm.building.id IS 'osm2pgsql convention: the way id, or minus the relation id.';
COMMENT ON COLUMN osm.building.osm_type IS 'W = way, R = multipolygon relation.';
COMMENT ON COLUMN osm.building.osm_id IS 'OSM id of the way or relation.';
COMMENT ON COLUMN osm.building.kind IS 'building (an outline) or part (a building:part).';
COMMENT ON COLUMN osm.building.building IS 'Value of building=* (yes, house, church, ...).';
COMMENT ON COLUMN osm.building.part IS 'Value of building:part=* (yes, roof, ...).';
COMMENT ON COLUMN osm.building.name IS 'name=*.';
COMMENT ON COLUMN osm.building.height IS 'height=* in metres (ground to top of roof); units such as 40 ft and 12,5 converted.';
COMMENT ON COLUMN osm.building.min_height IS 'min_height=* in metres (ground to bottom of this volume).';
COMMENT ON COLUMN osm.building.levels IS 'building:levels=* (storeys above ground, without roof levels).';
COMMENT ON COLUMN osm.building.min_level IS 'building:min_level=* (storeys skipped below this part).';
COMMENT ON COLUMN osm.building.roof_levels IS 'roof:levels=*.';
COMMENT ON COLUMN osm.building.roof_height IS 'roof:height=* in metres.';
COMMENT ON COLUMN osm.building.roof_angle IS 'roof:angle=* in degrees (0-90).';
COMMENT ON COLUMN osm.building.roof_shape IS 'roof:shape=* (fallback building:roof:shape=*), lower case.';
COMMENT ON COLUMN osm.building.roof_direction IS 'roof:direction=* in degrees clockwise from north; compass points (N, NNE, ...) converted.';
COMMENT ON COLUMN osm.building.roof_orientation IS 'roof:orientation=* (along or across).';
COMMENT ON COLUMN osm.building.building_colour IS 'building:colour=* as #rrggbb.';
COMMENT ON COLUMN osm.building.roof_colour IS 'roof:colour=* as #rrggbb.';
COMMENT ON COLUMN osm.building.building_material IS 'building:material=*, lower case.';
COMMENT ON COLUMN osm.building.roof_material IS 'roof:material=*, lower case.';
COMMENT ON COLUMN osm.building.tags IS 'All OSM tags of the object.';
COMMENT ON COLUMN osm.building.geom IS 'Footprint in EPSG:4326 (holes kept).';
COMMENT ON COLUMN osm.building.geom_local IS 'Footprint in the metric working CRS (meta.dataset.srid).';
COMMENT ON COLUMN osm.building.area_m2 IS 'Footprint area in square metres (working CRS).';
COMMENT ON COLUMN osm.building.repaired IS 'True when the OSM geometry was invalid and repaired with ST_MakeValid.';
COMMENT ON COLUMN osm.building.repair_reason IS 'Why the input was invalid (GEOS ST_IsValidReason).';
COMMENT ON COLUMN osm.building.parent_id IS 'For a part: id of the outline building it belongs to.';
COMMENT ON COLUMN osm.building.parent_source IS 'relation: from a type=building relation (roles outline/part); contains: the smallest outline containing the part.';
COMMENT ON COLUMN osm.building.n_parts IS 'For an outline: number of building:parts linked to it.';
COMMENT ON COLUMN osm.building.part_coverage IS 'For an outline with parts: fraction of its area covered by its parts (0-1).';

-- COPY target of the ingest stage; osm.finish_ingest() turns it into osm.building and osm.reject.
CREATE UNLOGGED TABLE osm.building_import (
    osm_type          char(1) NOT NULL,
    osm_id            bigint  NOT NULL,
    kind              text    NOT NULL,
    building          text,
    part              text,
    name              text,
    height            real,
    min_height        real,
    levels            real,
    min_level         real,
    roof_levels       real,
    roof_height       real,
    roof_angle        real,
    roof_shape        text,
    roof_direction    real,
    roof_orientation  text,
    building_colour   text,
    roof_colour       text,
    building_material text,
    roof_material     text,
    tags              jsonb   NOT NULL,
    tag_issues        jsonb,
    geom_kind         char(1) CHECK (geom_kind IN ('L', 'M')),
    geom              geometry,
    reject_reason     text,
    reject_detail     text
);
COMMENT ON TABLE osm.building_import IS 'Staging table the ingest stage COPYs into (emptied after each ingest). geom_kind L = closed way as a linestring, M = assembled multipolygon.';

CREATE TABLE osm.reject (
    reject_id  bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    osm_type   char(1) NOT NULL CHECK (osm_type IN ('N', 'W', 'R')),
    osm_id     bigint  NOT NULL,
    stage      text    NOT NULL,
    reason     text    NOT NULL,
    detail     text,
    tags       jsonb,
    geom       geometry,
    created_at timestamptz NOT NULL DEFAULT now()
);
CREATE INDEX reject_object_idx ON osm.reject (osm_type, osm_id);
CREATE INDEX reject_reason_idx ON osm.reject (stage, reason);
COMMENT ON TABLE osm.reject IS 'Every building or part a stage could not use, with the reason. For every stage: objects in = objects out + rejects.';
COMMENT ON COLUMN osm.reject.reject_id IS 'Row number.';
COMMENT ON COLUMN osm.reject.osm_type IS 'W = way, R = relation.';
COMMENT ON COLUMN osm.reject.osm_id IS 'OSM id of the way or relation.';
COMMENT ON COLUMN osm.reject.created_at IS 'When the stage rejected it (UTC).';
COMMENT ON COLUMN osm.reject.stage IS 'Stage that rejected it (ingest, lod, ...).';
COMMENT ON COLUMN osm.reject.reason IS 'Stable code: unclosed_way, missing_nodes, degenerate_ring, invalid_geometry, too_small, multipolygon_assembly_failed, min_height_ge_height, ...';
COMMENT ON COLUMN osm.reject.detail IS 'Human-readable detail (node ids, GEOS reason, values).';
COMMENT ON COLUMN osm.reject.tags IS 'The OSM tags of the rejected object, so nothing is lost.';
COMMENT ON COLUMN osm.reject.geom IS 'The raw geometry when one could be built (EPSG:4326).';

CREATE TABLE osm.building_relation (
    relation_id bigint PRIMARY KEY,
    name        text,
    tags        jsonb NOT NULL
);
COMMENT ON TABLE osm.building_relation IS 'type=building relations: they group an outline with its building:parts.';
COMMENT ON COLUMN osm.building_relation.relation_id IS 'OSM relation id.';
COMMENT ON COLUMN osm.building_relation.name IS 'name=* of the relation.';
COMMENT ON COLUMN osm.building_relation.tags IS 'All tags of the relation (it may carry building-wide tags).';

CREATE TABLE osm.building_relation_member (
    relation_id bigint  NOT NULL REFERENCES osm.building_relation ON DELETE CASCADE,
    seq         integer NOT NULL,
    member_type char(1) NOT NULL CHECK (member_type IN ('N', 'W', 'R')),
    member_id   bigint  NOT NULL,
    role        text    NOT NULL,
    PRIMARY KEY (relation_id, seq)
);
CREATE INDEX building_relation_member_idx ON osm.building_relation_member (member_type, member_id);
COMMENT ON TABLE osm.building_relation_member IS 'Members of type=building relations; role outline or part.';
COMMENT ON COLUMN osm.building_relation_member.relation_id IS 'The type=building relation.';
COMMENT ON COLUMN osm.building_relation_member.seq IS 'Position of the member in the relation (0-based).';
COMMENT ON COLUMN osm.building_relation_member.member_type IS 'N, W or R.';
COMMENT ON COLUMN osm.building_relation_member.member_id IS 'OSM id of the member; osm.building.osm_id when it is a building or part.';
COMMENT ON COLUMN osm.building_relation_member.role IS 'outline or part (other roles are kept but unused).';
