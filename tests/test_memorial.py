"""The paper's own data: leave-one-out reciprocity on the Memorial Church set.

Merge all frames but one, render the missing one at its own exposure, RMSE in 8-bit
levels over pixels the real frame holds in 10..245; median over the 14 interior frames.
OpenCV's CalibrateDebevec + MergeDebevec scores 5.4 here.
"""
import numpy as np
import pytest

from hdrcl.report.quality import leave_one_out_all


@pytest.mark.slow
def test_leave_one_out_gaussian_weights(memorial_bracket, cl_device):
    rows = leave_one_out_all(memorial_bracket, weight="gaussian")
    assert len(rows) == 14
    assert np.median([r.rmse for r in rows]) <= 4.5


@pytest.mark.slow
def test_leave_one_out_paper_hat_weights(memorial_bracket, cl_device):
    rows = leave_one_out_all(memorial_bracket, weight="hat")
    # The paper's hat weights beat OpenCV (5.4) but not the 4.5 target on this film set:
    # the long exposures depart from reciprocity; see the README.
    assert np.median([r.rmse for r in rows]) <= 5.1
