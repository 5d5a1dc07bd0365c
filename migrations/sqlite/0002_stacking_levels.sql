-- Stacking-1/2/3 each with its own success rate, behaviour entropy and
-- conditional entropy (JSON of d3il_protocol::StackingLevel x 3, with bootstrap
-- intervals). NULL for other tasks and for Stacking results stored before this
-- column existed (those only have the three success rates in stacking_json).
ALTER TABLE results ADD COLUMN stacking_levels_json TEXT;
