//! d3il-sandbox (placeholder; owned by its issue).
