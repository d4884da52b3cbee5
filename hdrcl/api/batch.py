"""A whole shoot: scan a folder into bracket sets, plan and run the batch
(:func:`run_batch`, :func:`describe_batch`), manifests, the sample shoot and the demo."""
from __future__ import annotations

from hdrcl.shoot.batch.claims import Cancelled
from hdrcl.shoot.demo import run_demo
from hdrcl.shoot.batch.jobs import BatchOptions
from hdrcl.shoot.batch.manifest import save_manifest
from hdrcl.shoot.batch.plan import check_manifest, load_source, parse_sets
from hdrcl.shoot.batch.run import describe_batch, run_batch
from hdrcl.shoot.sample import write_sample_shoot
from hdrcl.shoot.scan import descends, format_explain, format_table, left_below

__all__ = ["BatchOptions", "Cancelled", "check_manifest", "descends", "describe_batch", "format_explain",
           "format_table", "left_below", "load_source", "parse_sets", "run_batch", "run_demo", "save_manifest",
           "write_sample_shoot"]
