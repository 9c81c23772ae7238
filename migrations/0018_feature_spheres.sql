-- 0018: a bounding sphere per tile feature, so api.lod_for_view can drop the features of a drawn tile that lie
-- outside the view frustum (a coarse tile kilometres wide is often mostly outside it); and the omission error of
-- every block, for the selection by tile error.
ALTER TABLE tiles.tile_content
    ADD COLUMN cx double precision,
    ADD COLUMN cy double precision,
    ADD COLUMN cz double precision,
    ADD COLUMN radius real;
COMMENT ON COLUMN tiles.tile_content.cx IS 'Centre of the feature''s bounding sphere, ECEF (EPSG:4978) metres: the centre of its 3D bounding box in the working CRS, lifted by the base height (tiles.feature_sphere). NULL in rows written before migration 0018 until generalize runs again.';
COMMENT ON COLUMN tiles.tile_content.cy IS 'See cx.';
COMMENT ON COLUMN tiles.tile_content.cz IS 'See cx.';
COMMENT ON COLUMN tiles.tile_content.radius IS 'Radius (m) of the feature''s bounding sphere (half the diagonal of its 3D bounding box, with a margin for the working CRS''s scale error); see cx.';

-- the omission error of every block, kept for the selection by tile error (tiles.omit_within_error)
ALTER TABLE gen.block ADD COLUMN collapse_m real;
COMMENT ON COLUMN gen.block.collapse_m IS 'Error (m) of omitting the block: sqrt(radius² + height²) of its members'' bounding circle and highest roof, the farthest any point of them lies from the circle''s centre at ground level. A block is omitted when it is within its band''s tolerance or within its tile''s geometric error (tiles.omit_within_error). NULL in rows written before migration 0018.';
COMMENT ON COLUMN gen.block.omitted IS 'Selection: the block is not drawn by its tile, either because it is too small for its band (collapse_m <= gen.tolerance(gen_level)) or because the omission, with its members'' own errors, is within its tile''s geometric error (tiles.omit_within_error); its members are drawn again in the finer tiles below. Kept for the coarser bands, which merge it with its neighbours, and for its error. error_m and total_error_m of an omitted block are those of the omission.';
