"""What ``hdrcl merge`` writes beside a radiance map on request, as the command line calls
it (messages name its flags): the quality report (``--report``), its figures as text,
and the pictures for HDR screens (``--deliver``). Imported by the command only when asked."""
from __future__ import annotations

from hdrcl.report.deliver import deliver_beside
from hdrcl.report.merge_report import write_quality_report
from hdrcl.report.pages import format_figures

__all__ = ["deliver_beside", "format_figures", "write_quality_report"]
