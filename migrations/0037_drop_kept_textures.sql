-- 0037: the textures stage of an update leaves the rows of the tiles whose input did not change in tex.page,
-- tex.feature_uv and tex.failure, and replaces only the others' (the stages above no longer empty those
-- tables in an update): nothing is copied aside and back any more, which wrote every page twice per update.
DROP TABLE tex.kept_page, tex.kept_feature_uv, tex.kept_failure;
