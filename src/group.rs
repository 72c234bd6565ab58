//! One grouping round: greedy merging of adjacent groups by the evaluation function.
