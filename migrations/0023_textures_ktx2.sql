-- 0023: every atlas page also as KTX2 (Basis Universal ETC1S, full mip chain) next to its WebP, so an export
-- picks either (--textures ktx2|webp) without running the textures stage again; pages are powers of two a side.
ALTER TABLE tex.page
    ADD COLUMN ktx2         bytea,
    ADD COLUMN ktx2_n_bytes integer CHECK (ktx2_n_bytes > 0),
    ADD COLUMN ktx2_levels  smallint CHECK (ktx2_levels > 0),
    ADD CONSTRAINT page_ktx2_complete CHECK ((ktx2 IS NULL) = (ktx2_n_bytes IS NULL)
                                             AND (ktx2 IS NULL) = (ktx2_levels IS NULL));
ALTER TABLE tex.page ALTER COLUMN ktx2 SET STORAGE EXTERNAL;
COMMENT ON COLUMN tex.page.ktx2 IS 'The page as KTX2: Basis Universal ETC1S (BasisLZ), sRGB, no alpha, every mip level down to 1x1 (basisu -ktx2 -mipmap, etl/textures/ktx2.py), for KHR_texture_basisu. NULL when the encoder refused the page: its features are in tex.failure (ktx2_encode_failed) and KTX2 exports draw them with vertex colours.';
COMMENT ON COLUMN tex.page.ktx2_n_bytes IS 'Length of ktx2.';
COMMENT ON COLUMN tex.page.ktx2_levels IS 'Mip levels in ktx2: log2(max(width, height)) + 1.';
COMMENT ON COLUMN tex.page.format IS 'Image format of bytes: webp (the KTX2 encoding is in ktx2).';
COMMENT ON COLUMN tex.page.width IS 'Page width in texels: a power of two (KTX2 mip chains halve it exactly), at most tex_page_size; the smallest that holds the page''s charts.';
COMMENT ON COLUMN tex.page.height IS 'Page height in texels: a power of two, at most tex_page_size.';
COMMENT ON TABLE tex.failure IS 'Tile features the textures stage could not texture (they keep their vertex colours; nothing is dropped), and, with reason ktx2_encode_failed, textured features one of whose pages the KTX2 encoder refused (textured in WebP exports, vertex colours in KTX2 exports). For every run: features in the tiles = rows of tex.feature_uv + rows here whose reason is not ktx2_encode_failed.';
COMMENT ON COLUMN tex.failure.reason IS 'Stable code: texturing_failed (the feature fails alone), tile_texturing_failed (the tile failed without it too), texturing_hung, texturing_crashed (its unit was lost), ktx2_encode_failed (a page of it has no KTX2: basisu failed, timed out or wrote no KTX2).';
