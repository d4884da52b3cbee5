"""The OpenCL devices: whether OpenCL is on, the devices found, the one hdrcl picks and
why the others were passed over (``hdrcl devices``)."""
from __future__ import annotations


def opencl_enabled() -> bool:
    from hdrcl.cl.backend import opencl_enabled as enabled

    return enabled()


def device_report() -> dict:
    """``{"devices": [...], "selected": name, "selected_id": id, "problem": text, "icd": {...}}``:
    every device with ``status`` (selected, failed, ...) and ``reason``."""
    from hdrcl.cl.context import get_context, list_devices, selection_report
    from hdrcl.cl.drivers import prepare_icd_environment

    problem = None
    chosen = None
    try:
        chosen = get_context(None).name
    except Exception as exc:  # reported, not fatal: listing is the point
        problem = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    try:
        rows = list_devices()
    except Exception as exc:
        rows, problem = [], problem or f"listing OpenCL devices failed: {exc}"
    report = selection_report()
    for r in rows:
        r["status"], r["reason"] = report.get(r["id"], ("not tried", ""))
    selected_id = next((r["id"] for r in rows if r["status"] == "selected"), None)
    return {"devices": rows, "selected": chosen, "selected_id": selected_id, "problem": problem,
            "icd": prepare_icd_environment()}
