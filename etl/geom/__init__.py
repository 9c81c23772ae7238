"""Pure geometry: arrays in, arrays/bytes out, no database (unit-tested in tests/unit)."""
