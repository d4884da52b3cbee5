"""Issue 32 item 8: gaps judged against the exposure (long-exposure noise reduction),
and a compact's hand-shot ladder with irregular gaps kept whole."""
from __future__ import annotations

import os

import numpy as np
import pytest

try:
    import cardgen
except ImportError:  # tests/ made a package
    from tests import cardgen

from hdrcl.shoot.scan import scan_directory

NIGHT = [1.0, 2.0, 0.5] + [cardgen.nominal(0.25 / 2 ** k) for k in range(9)]  # 1/4 .. 1/1000 s


def _names(m):
    return [[os.path.basename(f) for f in s.files] for s in m.sets]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_night_ladder_with_noise_reduction_headers_only(tmp_path, seed):
    """No thumbnail vouches (RAW files, --no-content): the 1 s, 2 s and 0.5 s frames are
    followed by their dark frame and the camera's processing (up to 8 s + 2 t)."""
    rng = np.random.default_rng(seed)
    gaps = [1.0 + 8.8, 2.0 + 9.9, 0.5 + 8.4] + list(rng.uniform(2, 5, len(NIGHT) - 4))
    shots = [cardgen.Shot(cardgen._ladder(NIGHT, gaps=gaps), label="night", brightness=1 / 30),
             cardgen.Shot(cardgen._ladder([1 / 500, 1 / 125, 1 / 30], gaps=[3.0, 3.0], first_gap=300.0))]
    truth = cardgen.write_shots(tmp_path, shots, seed=seed)
    m = scan_directory(tmp_path, content=False)
    assert _names(m) == truth["sets"]
    assert m.unmerged == []


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_night_ladder_gaps_9_to_14_s_with_scene(tmp_path, seed):
    rng = np.random.default_rng(seed)
    gaps = list(rng.uniform(9.5, 14, len(NIGHT) - 1))
    shots = [cardgen.Shot(cardgen._ladder(NIGHT, gaps=gaps), label="night", contrast=2.0, brightness=1 / 30,
                          tone=4.0, drift=0.5, pedestal=12.0, noise=2.0),
             cardgen.Shot(cardgen._ladder([1 / 500, 1 / 125, 1 / 30], gaps=[3.0, 3.0], first_gap=300.0))]
    truth = cardgen.write_shots(tmp_path, shots, seed=seed)
    m = scan_directory(tmp_path)
    assert _names(m) == truth["sets"]
    assert m.unmerged == []


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compact_hand_ladder_of_13_irregular_gaps(tmp_path, seed):
    rng = np.random.default_rng(seed)
    ts = [cardgen.nominal(1 / 2000 * 2 ** (k * 2 / 3)) for k in range(13)]
    shots = [cardgen.Shot(cardgen._ladder(ts, gaps=rng.uniform(2, 40, 12)), camera=dict(cardgen.COMPACT)),
             cardgen.Shot(cardgen._ladder([1 / 500, 1 / 125, 1 / 30], gaps=[3.0, 3.0], first_gap=300.0),
                          camera=dict(cardgen.COMPACT))]
    truth = cardgen.write_shots(tmp_path, shots, seed=seed)
    m = scan_directory(tmp_path)
    assert _names(m) == truth["sets"]
    assert m.unmerged == []
