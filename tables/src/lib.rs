//! d3il-tables (placeholder; owned by its issue).
