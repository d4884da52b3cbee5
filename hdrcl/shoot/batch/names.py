"""Names of the files a batch makes for a camera group: its response curve.

One rule: the outputs keep their frames' own stems (``IMG_0001.exr``), and the files named
after a camera follow the outputs' style, words joined by underscores:
``Canon_EOS_R6_ISO_100.response.json``, ``unknown_camera_1600x1200_8_bit.response.json``
(the same slug fills the ``{camera}`` field of ``--name``). Versions before issue 34 joined
them by hyphens (``Canon-EOS-R6-ISO-100.response.json``): such a file, in a
``--response-cache`` folder or beside the outputs, is still read
(:func:`response_to_read`); what a batch writes takes the new name.
"""
from __future__ import annotations

import os
import re

from hdrcl.shoot.batch.jobs import RESPONSE_SUFFIX

__all__ = ["slug", "legacy_slug", "response_path", "response_to_read"]

_RUNS = re.compile(r"[^A-Za-z0-9]+")


def slug(text: str) -> str:
    """``text`` as a file-name stem: every run of other characters than ASCII letters
    and digits becomes one ``_`` (``#`` is dropped); ``camera`` when nothing is left."""
    s = _RUNS.sub("_", text.replace("#", "")).strip("_")
    return s or "camera"


def legacy_slug(text: str) -> str:
    """The hyphenated stem versions before issue 34 gave the same ``text``."""
    s = _RUNS.sub("-", text.replace("#", "")).strip("-")
    return s or "camera"


def response_path(group: str, folder: str) -> str:
    """Where a response group's curve is written: ``<folder>/<slug>.response.json``."""
    return os.path.join(folder, slug(group) + RESPONSE_SUFFIX)


def response_to_read(group: str, folder: str) -> str:
    """The group's curve to read from ``folder``: the file of :func:`response_path` when
    it exists, else the one an older version wrote under the hyphenated name when that
    exists, else :func:`response_path` (absent)."""
    path = response_path(group, folder)
    if os.path.lexists(path):
        return path
    old = os.path.join(folder, legacy_slug(group) + RESPONSE_SUFFIX)
    return old if os.path.isfile(old) else path
