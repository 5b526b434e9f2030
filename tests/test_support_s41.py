"""Queries on a joint of more than a turn (probe s41 AF): the network input is taken modulo a turn, so a
query beyond the folded trained range lies in a gap of the data on the circle, not "outside the joint
range the networks were trained on" (17 test poses in a 2.5° gap of a ±248° joint were said so)."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np

from hykin.hybrid.errors import OutOfRangeWarning
from hykin.hybrid.support import circular_joints, warn_outside


def _messages(**kw) -> list[str]:
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        warn_outside(**kw)
    return [str(x.message) for x in w if issubclass(x.category, OutOfRangeWarning)]


def test_circular_joints_are_those_wrapped_with_limits_beyond_a_turn():
    robot = SimpleNamespace(dof=3, lower=np.radians([-170, -400, -350]), upper=np.radians([170, 400, 350]))
    got = circular_joints(robot, np.array([0.1, 0.2, np.nan]))
    assert got.tolist() == [False, True, False]  # joint 3 spans 700° but is not wrapped


def test_a_gap_on_a_circular_joint_is_named_so_with_the_data_coverage():
    ex = np.zeros((5, 3))
    ex[:2, 1] = 0.01  # joint 2 (circular): 2 queries
    ex[4, 0] = 0.02  # joint 1 (ranged): 1 query
    sup = SimpleNamespace(lower=np.radians([-100, -27.5, -90]), upper=np.radians([100, 330.0, 90]))
    (msg,) = _messages(ex=ex, gap=np.zeros(5), fading=True, circular=np.array([False, True, False]), sup=sup)
    assert msg.startswith("3 of 5 queries are outside the joint range the networks were trained on (q1: 1); or "
                          "in a gap of the training data on a joint of more than a turn (q2: 2, data on 357.5° of its 360°)")
    (old,) = _messages(ex=ex, gap=np.zeros(5), fading=True)  # without the joints' kind: as before
    assert "(q1: 1, q2: 2)" in old and "gap" not in old
