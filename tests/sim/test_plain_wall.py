"""The textureless wall beside a poster (sim scene "plain-wall", SGBM on the rendered stereo pair):
the wall's segments are not "good" and wrong; the textured poster's still are good
(docs/decisions/matcher-confidence.md)."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.stress import figures
from evaluation.textureless_wall import run_textureless_wall
from measure.confidence import LOW_CONFIDENCE_REASON


@pytest.fixture(scope="module")
def records():
    return run_textureless_wall((7,), (2.0, 3.5))


def test_wall_segments_are_not_confidently_wrong(records):
    wall = [r for r in records if r.case.group == "wall" and r.disparity == "sgbm"]
    assert len(wall) >= 16
    f = figures(wall)
    assert f["good_and_A_below_90"] <= 0.05, f
    answered = [r for r in wall if np.isfinite(r.robust_m)]
    assert sum(LOW_CONFIDENCE_REASON in r.reasons for r in answered) >= 0.9 * len(answered)


def test_the_poster_beside_it_stays_good(records):
    poster = figures([r for r in records if r.case.group == "poster" and r.disparity == "sgbm"])
    assert poster["good"] >= 0.75 and poster["median_A"] >= 98.0, poster


def test_without_confidence_the_answers_are_the_same(records):
    # The confidence changes the verdict and the sigma, never the answer.
    by = {}
    for r in records:
        by.setdefault((r.case.p1_px, r.case.p2_px), {})[r.disparity] = r.robust_m
    assert all(v["sgbm"] == v["sgbm-no-confidence"] or not np.isfinite(v["sgbm"]) for v in by.values())
