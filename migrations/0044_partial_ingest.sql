-- 0044: osm.finish_ingest gains p_changed_ways (sql/osm/finish_ingest.sql): an update stages only the candidates
-- its change files touched and decides their rows alone, instead of staging and comparing every building of the
-- city again (most of an update's ingest). The procedure of four arguments goes, so that the reload of sql/
-- leaves one procedure of that name (two would make a call of four arguments ambiguous).
DROP PROCEDURE IF EXISTS osm.finish_ingest(double precision, text, text, boolean);
