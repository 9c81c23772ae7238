-- 0002: pipeline bookkeeping.
CREATE TABLE meta.pipeline_run (
    run_id       bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    stage        text        NOT NULL,
    status       text        NOT NULL CHECK (status IN ('running', 'ok', 'failed')),
    started_at   timestamptz NOT NULL DEFAULT now(),
    finished_at  timestamptz,
    duration_s   double precision,
    params       jsonb       NOT NULL DEFAULT '{}',
    input_file   text,
    input_sha256 text,
    counts       jsonb       NOT NULL DEFAULT '{}',
    git_commit   text,
    host         text,
    error        text
);
CREATE INDEX pipeline_run_stage_idx ON meta.pipeline_run (stage, started_at DESC);
COMMENT ON TABLE meta.pipeline_run IS 'One row per run of a pipeline stage (python -m etl <stage>), written when it starts and updated when it ends.';
COMMENT ON COLUMN meta.pipeline_run.stage IS 'ingest, lod, tiles, export, ...';
COMMENT ON COLUMN meta.pipeline_run.status IS 'running while the stage works; ok or failed when it ended (a crashed process leaves running).';
COMMENT ON COLUMN meta.pipeline_run.duration_s IS 'Wall-clock seconds.';
COMMENT ON COLUMN meta.pipeline_run.params IS 'Every setting the stage used (etl/settings.py plus command-line options).';
COMMENT ON COLUMN meta.pipeline_run.input_file IS 'Input file, for stages that read one (ingest: the OSM extract).';
COMMENT ON COLUMN meta.pipeline_run.input_sha256 IS 'sha256 of input_file.';
COMMENT ON COLUMN meta.pipeline_run.counts IS 'Stage counts, e.g. ingest {"in": n, "loaded": n, "rejected": n}; in = out + rejected always holds.';
COMMENT ON COLUMN meta.pipeline_run.git_commit IS 'Commit of the citylod code that ran (with -dirty when the tree had changes).';
COMMENT ON COLUMN meta.pipeline_run.error IS 'Error message of a failed run.';

CREATE TABLE meta.dataset (
    singleton     boolean PRIMARY KEY DEFAULT true CHECK (singleton),
    source_file   text,
    source_sha256 text,
    srid          integer NOT NULL,
    srid_name     text    NOT NULL,
    bbox          geometry(Polygon, 4326),
    loaded_at     timestamptz NOT NULL DEFAULT now()
);
COMMENT ON TABLE meta.dataset IS 'The dataset currently loaded (one row): its source and the metric working CRS every *_local geometry uses.';
COMMENT ON COLUMN meta.dataset.srid IS 'Working CRS: the UTM zone (WGS84, EPSG:326xx north / 327xx south) of the centre of the data; UPS (32661/32761) beyond 84°N/80°S.';
COMMENT ON COLUMN meta.dataset.srid_name IS 'Human-readable name of the working CRS, e.g. WGS 84 / UTM zone 35N.';
COMMENT ON COLUMN meta.dataset.bbox IS 'Extent of the loaded footprints (EPSG:4326).';

CREATE TABLE meta.diagnostic (
    diagnostic_id bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    stage         text   NOT NULL,
    osm_type      char(1) NOT NULL CHECK (osm_type IN ('N', 'W', 'R')),
    osm_id        bigint NOT NULL,
    code          text   NOT NULL,
    detail        text,
    created_at    timestamptz NOT NULL DEFAULT now()
);
CREATE INDEX diagnostic_object_idx ON meta.diagnostic (osm_type, osm_id);
CREATE INDEX diagnostic_code_idx ON meta.diagnostic (stage, code);
COMMENT ON TABLE meta.diagnostic IS 'Per-building findings that did not drop the building: refused tag values, repaired geometry, outlines hidden by parts. Dropped buildings are in osm.reject.';
COMMENT ON COLUMN meta.diagnostic.stage IS 'Stage that found it.';
COMMENT ON COLUMN meta.diagnostic.osm_type IS 'W = way, R = relation.';
COMMENT ON COLUMN meta.diagnostic.code IS 'Stable code: invalid_tag, geometry_repaired, outline_hidden_by_parts, ...';
COMMENT ON COLUMN meta.diagnostic.detail IS 'Human-readable explanation (the tag and value, the GEOS reason, ...).';
COMMENT ON COLUMN meta.pipeline_run.run_id IS 'Run number, increasing.';
COMMENT ON COLUMN meta.pipeline_run.started_at IS 'When the stage started (UTC).';
COMMENT ON COLUMN meta.pipeline_run.finished_at IS 'When the stage ended (UTC); NULL while running.';
COMMENT ON COLUMN meta.pipeline_run.host IS 'Machine that ran the stage.';
COMMENT ON COLUMN meta.dataset.singleton IS 'Always true: the table holds one row.';
COMMENT ON COLUMN meta.dataset.source_file IS 'OSM file the ingest stage read.';
COMMENT ON COLUMN meta.dataset.source_sha256 IS 'sha256 of source_file.';
COMMENT ON COLUMN meta.dataset.loaded_at IS 'When the ingest stage loaded it (UTC).';
COMMENT ON COLUMN meta.diagnostic.diagnostic_id IS 'Row number.';
COMMENT ON COLUMN meta.diagnostic.osm_id IS 'OSM id of the way or relation.';
COMMENT ON COLUMN meta.diagnostic.created_at IS 'When the stage recorded it (UTC).';
