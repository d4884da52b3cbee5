"""Where the OpenCL kernel sources live.

In an installed wheel they ship inside the package (``hdrcl/kernels/``, placed there
by the build's force-include); in a source checkout they are the repository's
top-level ``kernels/`` folder.
"""
from __future__ import annotations

from pathlib import Path

from hdrcl.errors import HdrclError


def kernel_dir() -> Path:
    """Folder holding ``fusion.cl`` and ``exposure.cl``.

    ``HDRCL_KERNEL_DIR`` overrides the search (for kernel development).
    """
    from hdrcl.env import text

    env = text("HDRCL_KERNEL_DIR")
    here = Path(__file__).resolve().parent.parent  # the hdrcl package
    for cand in ([Path(env)] if env else []) + [here / "kernels", here.parent / "kernels"]:
        if (cand / "fusion.cl").is_file():
            return cand
    raise HdrclError(
        f"OpenCL kernel sources not found (looked in {here / 'kernels'} and {here.parent / 'kernels'}); "
        "the installation is incomplete: reinstall hdrcl"
    )


def kernel_source(name: str) -> str:
    """Text of ``kernels/<name>.cl``."""
    return (kernel_dir() / f"{name}.cl").read_text()
