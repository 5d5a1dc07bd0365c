-- Issue 17: `/admin` is behind an admin token (`d3il token create --admin`).
ALTER TABLE api_tokens ADD COLUMN is_admin INTEGER NOT NULL DEFAULT 0;
