"""Every quality verdict states its cause: the figure, its value and the limit that decided
it, on the set's card (set page and contact sheet) and in the figures' JSON."""
import html
import json

import numpy as np
import pytest

from hdrcl.core import synthetic as s
from hdrcl.core.bracket import load_bracket
from hdrcl.core.merge import merge_bracket
from hdrcl.report.pages import write_contact_sheet, write_set_report
from hdrcl.report.quality import QualityFigures, measure
from hdrcl.report.verdicts import THRESHOLDS, causes, verdicts, verdicts_dict


@pytest.fixture(scope="module")
def figured():
    rad = s.radiance_field(41, 59, decades=3.0, seed=5)
    times = s.stops(4, 2.0, centre=1.0 / float(np.median(rad)))
    br = load_bracket(s.bracket(rad, times, s.Camera(a=1.1, x0=(1.0, 1.2, 0.8)), noise=0.5, seed=3), times)
    res = merge_bracket(br)
    return br, res, measure(br, res.response, res.radiance)


def _copy(fig) -> QualityFigures:
    return QualityFigures.from_dict(fig.to_dict())


def test_a_clean_set_has_no_causes(figured):
    fig = figured[2]
    assert all(v is not None and v.verdict == "pass" for v in verdicts(fig).values())
    assert causes(fig) == [] and verdicts_dict(fig)["verdict"] == "pass" and verdicts_dict(fig)["causes"] == []
    assert verdicts(fig)["Clipped high"].why.startswith("Clipped high 0.00 % ≤ 0.1 %")


def test_fail_states_figure_value_and_limit(figured):
    fig = _copy(figured[2])
    fig.loo_rmse = 12.3
    fig.clipped_high_fraction = 0.047
    fig.clipped_low_fraction = 0.002  # warn only: not a cause of the fail
    why = [c.why for c in causes(fig)]
    assert len(why) == 2
    assert why[0].startswith("Clipped high 4.70 % > 1 %") and "shorter exposure" in why[0]
    assert why[1].startswith("Leave-one-out RMSE 12.30 levels > 10 levels") and "--align" in why[1]
    low = verdicts(fig)["Clipped low"]
    assert low.verdict == "warn" and low.why.startswith("Clipped low 0.20 % > 0.1 %") and "longer" in low.why
    d = json.loads(json.dumps(fig.to_dict(), allow_nan=False))["verdicts"]
    assert d["verdict"] == "fail" and d["causes"] == why
    rows = {r["figure"]: r for r in d["figures"]}
    assert rows["Leave-one-out RMSE"] == {"check": "loo", "figure": "Leave-one-out RMSE", "verdict": "fail",
                                          "value": 12.3, "unit": "levels", "limit": 10.0, "why": why[1]}
    assert QualityFigures.from_dict(fig.to_dict()).to_dict() == fig.to_dict()


def test_warn_names_the_pass_limit():
    t = {t.key: t for t in THRESHOLDS}["coverage"]
    from hdrcl.report.verdicts import verdict

    v = verdict("coverage", "Thin coverage", 20.0)
    assert v.verdict == "warn" and v.limit == t.warn_above
    assert v.why.startswith(f"Thin coverage 20.00 % > {t.warn_above:g} %") and "too far apart" in v.why


def test_causes_on_the_card(figured, tmp_path):
    br, res, fig = figured
    fig = _copy(fig)
    fig.coverage = figured[2].coverage
    fig.loo_rmse = 7.5
    entry = write_set_report(tmp_path, "shaky", fig, res.response, res.radiance, bracket=br)
    page = open(write_contact_sheet(tmp_path, [entry]), encoding="utf-8").read()
    why = html.escape("Leave-one-out RMSE 7.50 levels > 5 levels", quote=True)
    block = page[page.index('<div class="why v-warn" data-verdict="warn">'):]
    assert why in block[:block.index("</div>")]
    badge = page[page.index('<span class="verdict v-warn"'):]
    assert why in badge[:badge.index(">")]  # the badge's title says it too
    assert f'data-verdict="warn" title="{why}' in page  # and the figure's row
    stored = json.loads((tmp_path / entry.files["json"]).read_text())
    assert stored["figures"]["verdicts"]["causes"][0].startswith("Leave-one-out RMSE 7.50 levels > 5 levels")
