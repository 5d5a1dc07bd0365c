//! d3il-metrics (placeholder; owned by its issue).
