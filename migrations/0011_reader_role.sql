-- 0011: citylod_reader, the read-only role `python -m etl serve --db` connects as.
-- Roles belong to the cluster, not to one database: the role is created only when it does not exist yet, and a
-- concurrent migrate of another database of the same cluster (the test harness migrates one template per
-- session) creating it at the same moment is not an error either. Grants and default privileges are per
-- database and are (re)applied here. NOINHERIT: the role gets nothing through membership in other roles.
-- The migrating user needs CREATEROLE (or superuser) on its cluster for the CREATE ROLE.
DO $$
BEGIN
    IF NOT EXISTS (SELECT 1 FROM pg_catalog.pg_roles WHERE rolname = 'citylod_reader') THEN
        CREATE ROLE citylod_reader LOGIN NOINHERIT NOSUPERUSER NOCREATEDB NOCREATEROLE NOREPLICATION;
        -- shared catalog: commented only by the migrate that created it (two at once would collide)
        COMMENT ON ROLE citylod_reader IS
            'citylod read-only role: python -m etl serve --db streams tiles as this role (SELECT on the stage schemas, EXECUTE on functions, nothing else).';
    END IF;
EXCEPTION
    WHEN duplicate_object OR unique_violation THEN
        NULL;  -- another database's migrate created it between our check and our CREATE
END
$$;

-- Read access to every schema the tileset is built from (lm and tex too: api functions will read them when
-- their stages land). Functions keep PostgreSQL's default EXECUTE for PUBLIC; sql/ is reloaded by migrate,
-- so its functions and views are new objects after every reload and get the default privileges below.
GRANT USAGE ON SCHEMA meta, osm, lod, gen, lm, tex, tiles, api TO citylod_reader;
GRANT SELECT ON ALL TABLES IN SCHEMA meta, osm, lod, gen, lm, tex, tiles, api TO citylod_reader;
-- Tables and views created later by the role that runs migrate and the stages (the one running this file).
ALTER DEFAULT PRIVILEGES IN SCHEMA meta, osm, lod, gen, lm, tex, tiles, api
    GRANT SELECT ON TABLES TO citylod_reader;
