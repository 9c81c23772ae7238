"""Update: OSM change files applied to the database, and the stages run again on what they changed."""
