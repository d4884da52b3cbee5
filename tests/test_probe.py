"""Reduced looks at photographs (hdrcl.io.probe): a JPEG without a thumbnail is decoded
at a DCT-scaled size when Pillow or OpenCV can, else whole in its own sample type; the
scene comparison sees the same picture either way."""
from __future__ import annotations

import builtins

import numpy as np
import pytest

from hdrcl.io import probe
from hdrcl.io.ldr import write_photo


@pytest.fixture
def jpeg(tmp_path):
    y, x = np.mgrid[0:480, 0:640]
    img = np.stack([x * 255 / 639, y * 255 / 479, (x + y) * 255 / 1118], axis=2).astype(np.uint8)
    path = tmp_path / "big.jpg"
    write_photo(str(path), img, {"ExposureTime": 0.01})
    return str(path), img


def _without(monkeypatch, *names):
    real = builtins.__import__

    def imp(name, *args, **kw):
        if name.split(".")[0] in names:
            raise ImportError(name)
        return real(name, *args, **kw)

    monkeypatch.setattr(builtins, "__import__", imp)


def test_a_large_jpeg_is_decoded_reduced_and_grey(jpeg):
    pytest.importorskip("PIL")
    path, img = jpeg
    a = probe.reduced_pixels(path)
    assert a.dtype == np.uint8 and a.ndim == 2
    assert a.shape[1] <= 640 // 4 and a.shape[1] >= 64 and a.shape[0] >= 24  # 1/8 scale: 80 x 60
    grey = img.astype(float) @ [0.299, 0.587, 0.114]
    assert abs(a.mean() - grey.mean()) < 3.0


def test_without_a_reduced_decoder_the_full_decode_keeps_the_files_sample_type(jpeg, monkeypatch):
    path, img = jpeg
    _without(monkeypatch, "PIL", "cv2")
    a = probe.reduced_pixels(path)
    assert a.dtype == np.uint8 and a.shape == img.shape  # not converted to float (7x the decode time)
    assert abs(a.astype(float).mean() - img.mean()) < 3.0
