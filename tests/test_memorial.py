"""The paper's own data: leave-one-out reciprocity on the Memorial Church set.

Merge all frames but one, render the missing one at its own exposure, RMSE in 8-bit
levels over pixels the real frame holds in 10..245; median over the 14 interior frames.
OpenCV's CalibrateDebevec + MergeDebevec scores 5.4 here.
"""
import numpy as np
import pytest

from hdrcl.core.weights import DEFAULT_WEIGHT
from hdrcl.report.leaveoneout import leave_one_out_all


@pytest.mark.slow
def test_leave_one_out_with_default_settings(memorial_bracket, cl_device):
    """Issue 9: the defaults meet the target (measured 4.32 with gaussian weights)."""
    assert DEFAULT_WEIGHT == "gaussian"
    rows = leave_one_out_all(memorial_bracket)
    assert len(rows) == 14
    assert np.median([r.rmse for r in rows]) <= 4.5


@pytest.mark.slow
def test_leave_one_out_paper_hat_weights(memorial_bracket, cl_device):
    rows = leave_one_out_all(memorial_bracket, weight="hat")
    # The paper's hat weights beat OpenCV (5.4) but not the 4.5 target on this film set
    # (measured 4.97): the long exposures depart from reciprocity; see docs/radiometry.md (Accuracy).
    assert np.median([r.rmse for r in rows]) <= 5.1


@pytest.mark.slow
def test_deghost_leaves_the_static_memorial_alone(memorial_bracket, cl_device):
    """Issue 9: the old detector marked 99.86 % of this static scene (measured now: 0.45 %)."""
    from hdrcl.core.merge import merge_bracket

    res = merge_bracket(memorial_bracket, deghost=True)
    assert res.counts["ghost"] / (512 * 768) <= 0.01
