//! The group hierarchy: grouping rounds with relaxing thresholds, level by level.
