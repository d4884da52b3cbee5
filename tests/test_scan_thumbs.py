"""Issue 33: the scan's thumbnails are read on every core (a small thread pool), with the
same thumbnails, damaged frames and grouping as reading them one by one."""
from __future__ import annotations

import os
import threading

import numpy as np

from hdrcl.shoot.grouping import scene
from hdrcl.shoot.scan import scan_directory

try:
    import shootgen
except ImportError:  # tests/ made a package
    from tests import shootgen


def _shoot(tmp_path):
    folder = tmp_path / "card"
    folder.mkdir()
    shootgen.make_shoot(str(folder), seed=3)
    return str(folder)


def _manifest_text(m):
    return m.to_dict()


def test_scan_reads_thumbnails_on_two_threads_at_once(tmp_path, monkeypatch):
    """Two thumbnails are read at the same time (each waits for the other at a barrier:
    read one by one, the first would wait alone and the barrier break)."""
    folder = _shoot(tmp_path)
    monkeypatch.setattr(scene.os, "cpu_count", lambda: 2)
    barrier = threading.Barrier(2, timeout=30)
    real = scene.read_thumb
    met, names = [], set()

    def meeting(info):
        names.add(threading.current_thread().name)
        if not met:
            met.append(barrier.wait())  # the first two reads meet here
        return real(info)

    monkeypatch.setattr(scene, "read_thumb", meeting)
    scan_directory(folder)
    assert len(met) >= 1 and not barrier.broken
    assert len(names) == 2 and all(n.startswith("hdrcl-thumb") for n in names)


def test_thumbnails_and_grouping_are_those_of_reading_one_by_one(tmp_path, monkeypatch):
    folder = _shoot(tmp_path)
    from hdrcl.io.frames import read_info

    infos = []
    for n in sorted(os.listdir(folder)):
        try:
            infos.append(read_info(os.path.join(folder, n)))
        except Exception:
            pass
    one, many = scene.SceneCache(), scene.SceneCache()
    for info in infos:
        one.thumb(info)
    many.read_all(infos, workers=3)
    for info in infos:
        a, b = one.thumb(info), many.thumb(info)
        assert (a is None) == (b is None)
        if a is not None:
            assert np.array_equal(a.lum, b.lum) and a.exposure == b.exposure
    assert list(one.damaged.items()) == list(many.damaged.items())
    together = scan_directory(folder)
    monkeypatch.setattr(scene.os, "cpu_count", lambda: 1)
    alone = scan_directory(folder)
    assert _manifest_text(together) == _manifest_text(alone)
