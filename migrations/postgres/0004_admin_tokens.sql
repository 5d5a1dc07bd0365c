-- As migrations/sqlite/0004_admin_tokens.sql.
ALTER TABLE api_tokens ADD COLUMN is_admin BOOLEAN NOT NULL DEFAULT FALSE;
