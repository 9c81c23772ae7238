-- gen.merge_gap(gen_level) -> metres: the widest gap a block's merge fills
-- A block band merges the buildings closer than this into one block (one feature, one outline with no interior
-- walls, one height: city blocks, terraces, a house and its garage) and fills the gaps between them, while
-- gardens and streets wider than it stay open, because a filled gap is drawn as building wherever the block is
-- drawn (and a block of distant houses would give them all one height, which oblique views show). gen.tolerance(2), the LOD1
-- footprint tolerance (2.5 m), at every block band: measured on Liechtenstein's 17.6k buildings, filling the
-- gaps up to 2 m keeps the drawn footprint's IoU with the buildings' at 0.96, up to 10 m at 0.83 and up to 40 m
-- (the 40 m band's old closing) at 0.37, the filled gardens doubling the drawn area.
-- Example: SELECT g, gen.tolerance(g), gen.merge_gap(g) FROM generate_series(-4, 1) g;
CREATE OR REPLACE FUNCTION gen.merge_gap(gen_level integer)
RETURNS double precision
LANGUAGE sql IMMUTABLE PARALLEL SAFE STRICT
AS $$
    SELECT least(gen.tolerance(gen_level), gen.tolerance(2))
$$;
COMMENT ON FUNCTION gen.merge_gap(integer) IS
    'Widest gap (m) a block of band gen_level fills, and the distance it merges buildings within: least(gen.tolerance(gen_level), gen.tolerance(2)); buildings farther apart are separate blocks. Example: SELECT gen.merge_gap(-2); -- 2.5';
