-- Issue 51: intervals chosen for their coverage (d3il_metrics::intervals).
-- `results.intervals_json`: how each of the three estimates' intervals was
-- made or why there is none ({"success_rate": {"method": ..} | {"no_interval":
-- {"reason": ..}}, "behaviour_entropy": .., "conditional_entropy": ..}).
-- `intervals_rules` (results, robustness_results): the interval rules a row
-- was computed under (d3il_metrics::recompute::RULES_VERSION); NULL for rows
-- stored before 0.5.0. The server recomputes every row below the current
-- rules from its rollout records when it starts.
ALTER TABLE results ADD COLUMN intervals_json TEXT;
ALTER TABLE results ADD COLUMN intervals_rules BIGINT;
ALTER TABLE robustness_results ADD COLUMN intervals_rules BIGINT;
