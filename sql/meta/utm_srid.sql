-- meta.utm_srid(lon, lat) -> integer
-- The metric working CRS for data centred at (lon, lat): the WGS 84 / UTM zone (EPSG:326zz north,
-- 327zz south), or UPS (EPSG:32661 / 32761) beyond 84°N / 80°S where UTM is not defined.
-- Example: SELECT meta.utm_srid(24.94, 60.17);  -- 32635 (Helsinki, UTM 35N)
CREATE OR REPLACE FUNCTION meta.utm_srid(lon double precision, lat double precision)
RETURNS integer
LANGUAGE sql IMMUTABLE PARALLEL SAFE STRICT
AS $$
    SELECT CASE
        WHEN lat > 84 THEN 32661
        WHEN lat < -80 THEN 32761
        ELSE (CASE WHEN lat >= 0 THEN 32600 ELSE 32700 END)
             + least(60, greatest(1, floor((lon + 180) / 6)::integer + 1))
    END
$$;
COMMENT ON FUNCTION meta.utm_srid(double precision, double precision) IS
    'EPSG code of the UTM zone (UPS near the poles) containing lon/lat: the working CRS rule of ingest.';
