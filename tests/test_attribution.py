"""The out-of-sample evidence: folds of whole speeds, the pass rule, paired differences."""

import math

import numpy as np

from bayesdamper.diagnosis.attribution import MAX_FOLDS, LovoScore, paired, velocity_folds
from bayesdamper.diagnosis.loop import lovo_passes


def test_folds_are_whole_speeds_dealt_round_robin():
    v = [0.5e-3, -0.5e-3, 1e-3, 1e-3, 1.5e-3, 2e-3, 2.5e-3, 3e-3, 3.5e-3, 4e-3]
    folds = velocity_folds(v)
    assert len(folds) == MAX_FOLDS
    assert sorted(np.concatenate(folds).tolist()) == list(range(len(v)))
    for f in folds:  # a speed (either direction) never split over folds
        speeds = {round(abs(v[i]), 9) for i in f}
        assert all(round(abs(v[j]), 9) not in speeds for g in folds if g is not f for j in g)
    assert len(velocity_folds([1e-3, 2e-3, 1e-3])) == 2


def test_pass_rule_every_fold_and_se_with_enough_folds():
    # three folds: every fold better suffices (2 df: no usable normal se), one worse fails
    assert lovo_passes(LovoScore(550.0, 268.0, (10.0, 240.0, 300.0)))
    assert not lovo_passes(LovoScore(530.0, 268.0, (-10.0, 240.0, 300.0)))
    # six folds: also > 2 se
    assert lovo_passes(LovoScore(573.0, 150.0, (194.0, 51.0, 70.0, 77.0, 36.0, 145.0)))
    assert not lovo_passes(LovoScore(60.0, 40.0, (1.0, 1.0, 1.0, 1.0, 1.0, 55.0)))


def test_paired_difference_and_its_se():
    a = LovoScore(6.0, 1.0, (1.0, 2.0, 3.0))
    b = LovoScore(3.0, 1.0, (0.0, 1.0, 2.0))
    p = paired(a, b)
    assert p["gain"] == 3.0 and p["se"] == 0.0
    c = LovoScore(3.0, 1.0, (2.0, 0.0, 1.0))
    q = paired(a, c)
    assert math.isclose(q["se"], math.sqrt(3 * np.var([-1.0, 2.0, 2.0], ddof=1)))
