-- 0026: only superusers create or change large objects. PostgreSQL grants EXECUTE on the
-- large-object functions to PUBLIC, so the read-only role citylod_reader (0011) could store data with
-- lo_from_bytea although it may write no table. citylod uses no large objects.
-- Revoking needs the functions' owner (a superuser): elsewhere the migration warns and goes on.
DO $$
DECLARE
    f regprocedure;
BEGIN
    FOR f IN SELECT p.oid::regprocedure FROM pg_proc p
             WHERE p.pronamespace = 'pg_catalog'::regnamespace
               AND p.proname IN ('lo_creat', 'lo_create', 'lo_from_bytea', 'lo_put', 'lowrite', 'lo_unlink',
                                 'lo_truncate', 'lo_truncate64', 'lo_import', 'lo_export', 'lo_open') LOOP
        EXECUTE format('REVOKE EXECUTE ON FUNCTION %s FROM PUBLIC', f);
    END LOOP;
EXCEPTION
    WHEN insufficient_privilege THEN
        RAISE WARNING 'not the owner of the large-object functions: citylod_reader can still create large objects '
                      'in this database (a superuser can run migrations/0026_no_large_objects.sql)';
END
$$;
