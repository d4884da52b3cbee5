"""Batch merging of a shoot: the run, each set's merge, pooled responses, jobs, claims, state, plan and manifest."""
