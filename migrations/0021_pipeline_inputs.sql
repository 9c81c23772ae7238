-- 0021: what make's DAG compares (python -m etl <stage> --if-stale, etl/dag.py): the inputs each stage run
-- recorded, what export wrote, and which sql/ files the database holds.
ALTER TABLE meta.pipeline_run ADD COLUMN inputs jsonb, ADD COLUMN output jsonb;
COMMENT ON COLUMN meta.pipeline_run.inputs IS 'What the output depends on, compared by --if-stale (etl/dag.py): upstream (last successful run id of every stage it reads, directly or not), settings (the values of the settings its code names), code (sha256 of its Python modules, of the sql/ objects it calls as loaded in meta.sql_object, and of the migrations applied), file (ingest: path, sha256), options (export: out, lod). NULL for runs before migration 0021.';
COMMENT ON COLUMN meta.pipeline_run.output IS 'What the run wrote outside the database (export: {"tileset_sha256": ...} of the tileset.json it wrote), checked by --if-stale; NULL otherwise.';

CREATE TABLE meta.sql_object (
    path      text PRIMARY KEY,
    sha256    text NOT NULL,
    loaded_at timestamptz NOT NULL DEFAULT now()
);
COMMENT ON TABLE meta.sql_object IS 'The sql/ files the last reload (python -m etl migrate) loaded: migrate --if-stale reloads only when sql/ on disk differs, and a stage run records the sha256 of the objects it calls from here (what the database runs).';
COMMENT ON COLUMN meta.sql_object.path IS 'sql/<schema>/<object>.sql';
COMMENT ON COLUMN meta.sql_object.sha256 IS 'sha256 of the file as loaded.';
COMMENT ON COLUMN meta.sql_object.loaded_at IS 'When it was loaded (UTC).';
