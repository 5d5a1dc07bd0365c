//! d3il-server (placeholder; owned by its issue).
