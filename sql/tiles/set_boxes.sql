-- tiles.set_boxes(levels, xs, ys, boxes)
-- Stores each tile's oriented bounding box in ECEF (tiles.tile.box: centre, then the east, north and up
-- half-axis vectors, 12 values), which the generalize stage computes from the tiles' regions in Python
-- (core.geodesy.region_box) and api.lod_for_view measures distances and culls against. Tile i is
-- (levels[i], xs[i], ys[i]) and its box boxes[12 (i - 1) + 1 : 12 i] (one flat array: a few values per tile).
-- A tile whose box is already that one is not written.
-- Example: CALL tiles.set_boxes(ARRAY[0]::smallint[], ARRAY[0], ARRAY[0],
--                               ARRAY[4e6, 7e5, 5e6, 1e3, 0, 0, 0, 1e3, 0, 0, 0, 1e2]);
CREATE OR REPLACE PROCEDURE tiles.set_boxes(levels smallint[], xs integer[], ys integer[],
                                            boxes double precision[])
LANGUAGE plpgsql
AS $$
BEGIN
    IF cardinality(boxes) <> 12 * cardinality(levels) OR cardinality(xs) <> cardinality(levels)
       OR cardinality(ys) <> cardinality(levels) THEN
        RAISE EXCEPTION 'tiles.set_boxes: % tiles (% x, % y) need % box values, got %', cardinality(levels),
            cardinality(xs), cardinality(ys), 12 * cardinality(levels), cardinality(boxes);
    END IF;
    UPDATE tiles.tile t SET box = b.box
    FROM (
        -- the flat array regrouped by 12 in one pass (slicing it per tile would copy it per tile), each group's
        -- tile read from the key arrays by its position (a join on the position was planned as a nested loop
        -- over every group per tile: 1.4 s for 851 tiles)
        SELECT levels[v.i] AS level, xs[v.i] AS x, ys[v.i] AS y, v.box
        FROM (SELECT (o - 1) / 12 + 1 AS i, array_agg(e ORDER BY o) AS box
              FROM unnest(boxes) WITH ORDINALITY u(e, o) GROUP BY 1) v
    ) b
    -- only the boxes that changed are written: an update whose region changed for a few tiles rewrites those
    -- rows alone, not every tile of the city
    WHERE (t.level, t.x, t.y) = (b.level, b.x, b.y) AND t.box IS DISTINCT FROM b.box;
END
$$;
COMMENT ON PROCEDURE tiles.set_boxes(smallint[], integer[], integer[], double precision[]) IS
    'Sets tiles.tile.box of tiles (levels[i], xs[i], ys[i]) to boxes[12 (i - 1) + 1 : 12 i] (ECEF centre and half-axes). Run by the generalize stage.';
