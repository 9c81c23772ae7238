-- 0027: published tilesets, the generations the database server streams. Each export publishes the files it
-- wrote (tileset.json, subtrees, glbs) as one new generation of a named tileset, in one transaction: a reader
-- sees the old generation whole or the new one whole, never a mix, and never waits on a stage (no stage locks
-- these tables; the stages rebuild osm.* ... tex.* while the server keeps streaming the last generation).
-- Files are stored once by content (pub.blob): a generation that changes a few tiles adds only those bytes,
-- and an unchanged tile keeps its ETag (its sha256) from one generation to the next.
CREATE SCHEMA pub;
COMMENT ON SCHEMA pub IS 'Published tilesets: the generations python -m etl serve --db streams (written by the export stage).';

CREATE TABLE pub.blob (
    sha256 bytea PRIMARY KEY CHECK (length(sha256) = 32),
    body bytea NOT NULL
);
-- glbs are meshopt/KTX2-compressed already: pglz would spend time for nothing, and external storage keeps the
-- row small for the index-only existence checks of the next publish
ALTER TABLE pub.blob ALTER COLUMN body SET STORAGE EXTERNAL;
COMMENT ON TABLE pub.blob IS 'The bytes of published files, stored once by content; a blob no generation names any more is deleted with the generations that named it.';
COMMENT ON COLUMN pub.blob.sha256 IS 'sha256 of body: the file''s identity, and its ETag when served.';
COMMENT ON COLUMN pub.blob.body IS 'The file''s bytes (a glb, a subtree, tileset.json).';

CREATE TABLE pub.generation (
    generation bigint GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
    tileset text NOT NULL CHECK (tileset ~ '^[A-Za-z0-9._-]{1,100}$'),
    run_id bigint REFERENCES meta.pipeline_run (run_id) ON DELETE SET NULL,
    published_at timestamptz NOT NULL DEFAULT clock_timestamp(),
    options jsonb NOT NULL,
    n_files integer NOT NULL,
    n_bytes bigint NOT NULL,
    n_new_files integer NOT NULL,
    n_new_bytes bigint NOT NULL
);
CREATE INDEX generation_tileset_idx ON pub.generation (tileset, generation DESC);
COMMENT ON TABLE pub.generation IS 'One published generation of a named tileset; the live one is the highest generation of its tileset. The export keeps the last publish_keep generations of each tileset.';
COMMENT ON COLUMN pub.generation.generation IS 'Increases with every publish (in commit order); the highest of a tileset is the one served.';
COMMENT ON COLUMN pub.generation.published_at IS 'When the export published it.';
COMMENT ON COLUMN pub.generation.n_files IS 'Files in this generation.';
COMMENT ON COLUMN pub.generation.n_bytes IS 'Their bytes in all (shared blobs counted in every generation naming them).';
COMMENT ON COLUMN pub.generation.tileset IS 'The tileset''s name: the export directory''s name unless export --publish names it (make serve DB=1 serves OUT''s name).';
COMMENT ON COLUMN pub.generation.run_id IS 'The export run (meta.pipeline_run) that published it.';
COMMENT ON COLUMN pub.generation.options IS 'How it was exported: lod (null = the generalized hierarchy), geometry, textures, tiling.';
COMMENT ON COLUMN pub.generation.n_new_files IS 'Files whose bytes no earlier generation still kept had (stored by this one).';
COMMENT ON COLUMN pub.generation.n_new_bytes IS 'Bytes this generation added to pub.blob.';

CREATE TABLE pub.file (
    generation bigint NOT NULL REFERENCES pub.generation ON DELETE CASCADE,
    path text NOT NULL,
    sha256 bytea NOT NULL REFERENCES pub.blob,
    PRIMARY KEY (generation, path)
);
CREATE INDEX file_sha256_idx ON pub.file (sha256);
COMMENT ON COLUMN pub.file.generation IS 'The generation (pub.generation) the file belongs to.';
COMMENT ON COLUMN pub.file.path IS 'Its path under the tileset (the URL under /tiles/).';
COMMENT ON COLUMN pub.file.sha256 IS 'Its bytes (pub.blob).';
COMMENT ON TABLE pub.file IS 'The files of a generation: path (as in the export directory: tileset.json, subtrees/..., content/L/X/Y.glb) -> blob.';

GRANT USAGE ON SCHEMA pub TO citylod_reader;
GRANT SELECT ON ALL TABLES IN SCHEMA pub TO citylod_reader;
ALTER DEFAULT PRIVILEGES IN SCHEMA pub GRANT SELECT ON TABLES TO citylod_reader;
