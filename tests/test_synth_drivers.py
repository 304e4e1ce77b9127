"""The simulated drivers' car-following (IIDM), on values computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from ngsim_graphs.synth.drivers import idm
from ngsim_graphs.synth.traffic import FLEET_DTYPE


def _driver(v_fps: float) -> np.ndarray:
    fleet = np.zeros(1, FLEET_DTYPE)
    fleet["v"], fleet["a_max"], fleet["b_comf"] = v_fps, 3.0, 6.0
    fleet["headway_s"], fleet["s0"] = 1.5, 6.0
    return fleet


def test_on_a_free_road_a_driver_speeds_up_towards_its_desired_speed() -> None:
    # a * (1 - (v / v0)^4) = 3 * (1 - 1/16)
    acc = idm(_driver(30.0), np.array([0]), np.array([60.0]), np.array([np.inf]), np.array([30.0]))
    assert acc == pytest.approx([2.8125])


def test_close_behind_a_leader_of_its_speed_a_driver_brakes() -> None:
    # desired gap s0 + v * T = 6 + 10 * 1.5 = 21 ft at a gap of 10.5 ft: z = 2, a * (1 - z^2) = -9
    acc = idm(_driver(10.0), np.array([0]), np.array([60.0]), np.array([10.5]), np.array([10.0]))
    assert acc == pytest.approx([-9.0])


def test_above_its_desired_speed_a_driver_brakes_gently() -> None:
    # -b * (1 - (v0 / v)^(4 a / b)) = -6 * (1 - 0.5^2) = -4.5, no leader
    acc = idm(_driver(60.0), np.array([0]), np.array([30.0]), np.array([np.inf]), np.array([60.0]))
    assert acc == pytest.approx([-4.5])
