-- 0028: following OSM change files. meta.osm_change records what a full rebuild needs to reproduce the
-- database: the base file (meta.dataset keeps its name) and every change file applied on top of it, in order,
-- with its sha256. osm.building_change lists what the last update changed in osm.building, for the stages
-- below it to re-derive only that.
CREATE TABLE meta.osm_change (
    seq          integer PRIMARY KEY CHECK (seq >= 1),
    path         text NOT NULL,
    sha256       text NOT NULL,
    base_file    text NOT NULL,
    base_sha256  text NOT NULL,
    state_sha256 text NOT NULL,
    run_id       bigint REFERENCES meta.pipeline_run (run_id) ON DELETE SET NULL,
    applied_at   timestamptz NOT NULL DEFAULT now(),
    counts       jsonb NOT NULL DEFAULT '{}'
);
COMMENT ON TABLE meta.osm_change IS 'The OSM change files (.osc, .osc.gz) applied to the ingested base file, in order: base + changes 1..n is what a full rebuild reads to give this database. Emptied by a full ingest.';
COMMENT ON COLUMN meta.osm_change.seq IS 'Order of application: 1 for the first change file applied after the base file was ingested.';
COMMENT ON COLUMN meta.osm_change.path IS 'The change file as it was given (absolute path).';
COMMENT ON COLUMN meta.osm_change.base_file IS 'The OSM file the full ingest read, which the changes apply to.';
COMMENT ON COLUMN meta.osm_change.base_sha256 IS 'sha256 of the base file.';
COMMENT ON COLUMN meta.osm_change.run_id IS 'The ingest run (meta.pipeline_run) that applied it.';
COMMENT ON COLUMN meta.osm_change.applied_at IS 'When it was applied.';
COMMENT ON COLUMN meta.osm_change.sha256 IS 'sha256 of the change file as applied (a file whose bytes changed since is refused when the state is rebuilt).';
COMMENT ON COLUMN meta.osm_change.state_sha256 IS 'sha256 naming the OSM state after this change: of the base''s sha256 and every change''s up to this one.';
COMMENT ON COLUMN meta.osm_change.counts IS 'Objects in the change file by action and type (nodes, ways, relations created, modified, deleted) and the buildings it added, modified and deleted.';

CREATE TABLE osm.building_change (
    id     bigint PRIMARY KEY,
    change text NOT NULL CHECK (change IN ('added', 'modified', 'deleted'))
);
COMMENT ON COLUMN osm.building_change.id IS 'osm.building id (of the row deleted, for a deleted building).';
COMMENT ON COLUMN osm.building_change.change IS 'added, modified or deleted.';
COMMENT ON TABLE osm.building_change IS 'What the last update changed in osm.building (by id): the rows added, modified (anything ingest derives differs: tags, geometry, part links) and deleted. Empty after a full ingest.';
