//! d3il-policy (placeholder; owned by its issue).
