-- 0039: gen.footprint_input and gen.decimation_input take the buildings to read (ids, NULL for all), so that an
-- update reads only the batches it computes again instead of aggregating every building's meshes and keeping
-- a few (sql/gen/). The two-argument versions go: sql/ creates the new ones, and a call with two arguments
-- would otherwise match both.
DROP FUNCTION IF EXISTS gen.footprint_input(double precision, integer);
DROP FUNCTION IF EXISTS gen.decimation_input(integer, integer);
