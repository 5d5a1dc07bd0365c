-- As migrations/sqlite/0002_stacking_levels.sql.
ALTER TABLE results ADD COLUMN stacking_levels_json TEXT;
