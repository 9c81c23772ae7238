-- osm2pgsql flex style for `make bench`: buildings and building:parts only, as the reference loader that
-- citylod's ingest stage is compared against. Written for osm2pgsql 1.8.0 (Debian bookworm); newer
-- releases renamed some of the API (as_area, expire), so keep to what 1.8 documents.
--
--   osm2pgsql -O flex -S benchmarks/osm2pgsql/buildings.lua --create FILE.osm.pbf
--
-- Result: one table public.buildings (osm_type, osm_id, kind, tags, geom), roughly what citylod puts in
-- osm.building before its own repairs and rejects.

-- One table for both kinds. ids type 'any' keeps the OSM object type in its own column (W/R), so way
-- and relation ids never collide and nothing is negated.
local buildings = osm2pgsql.define_table({
    name = 'buildings',
    ids = { type = 'any', type_column = 'osm_type', id_column = 'osm_id' },
    columns = {
        -- 'building' or 'part', the same classification as etl/geom/tags.py building_kind().
        { column = 'kind', type = 'text', not_null = true },
        -- All tags, so the comparison loads the same amount of data per row as citylod does.
        { column = 'tags', type = 'jsonb' },
        -- multipolygon in WGS84: a single polygon from a way is stored as a one-member multipolygon.
        { column = 'geom', type = 'multipolygon', projection = 4326, not_null = true },
    },
})

-- building=* (anything but "no") wins over building:part, as in citylod: a way tagged with both is an
-- outline that is also drawn as a part, stored once as a building.
local function kind_of(tags)
    local b = tags.building
    if b ~= nil and b:lower() ~= 'no' then
        return 'building'
    end
    local p = tags['building:part']
    if p ~= nil and p:lower() ~= 'no' then
        return 'part'
    end
    return nil
end

-- Insert one row unless the geometry could not be built (broken ring, missing nodes); osm2pgsql returns
-- a null geometry then, and skipping it here mirrors citylod's rejects.
local function add(object, kind, geom)
    if geom:is_null() then
        return
    end
    buildings:insert({ kind = kind, tags = object.tags, geom = geom })
end

-- Closed ways are areas; open ways tagged building are tagging errors and are left out.
function osm2pgsql.process_way(object)
    if not object.is_closed then
        return
    end
    local kind = kind_of(object.tags)
    if kind then
        add(object, kind, object:as_polygon())
    end
end

-- Only multipolygon relations are areas. type=building relations only group members (their outline and
-- parts arrive as ways or multipolygons themselves), so they are not loaded as geometry.
function osm2pgsql.process_relation(object)
    if object.tags.type ~= 'multipolygon' then
        return
    end
    local kind = kind_of(object.tags)
    if kind then
        add(object, kind, object:as_multipolygon())
    end
end
