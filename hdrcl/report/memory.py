"""Memory hygiene of the quality report (it runs between merges in one process)."""
from __future__ import annotations


def release_free_memory() -> None:
    """Hand the C heap's free pages back to the system (glibc ``malloc_trim``; nothing
    elsewhere). The report runs after a merge has freed its strips and before the next
    set's: without it, what the merge freed stays resident beside what the report
    allocates (on other threads' heaps too), and the report would raise the peak."""
    global _TRIM
    if _TRIM is None:
        try:
            import ctypes
            import ctypes.util

            _TRIM = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _TRIM = False
    if _TRIM:
        _TRIM(0)


_TRIM = None
