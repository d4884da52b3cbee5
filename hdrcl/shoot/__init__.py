"""Whole shoots: grouping frames into bracket sets (scan, manifests), batch merging
(plan, idempotent state, pooled responses, running, executors, report.json), the
generated sample shoot and the demo.
"""
