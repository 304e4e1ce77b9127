"""The simulated drivers' car-following (IIDM), on values computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from ngsim_graphs.synth.drivers import idm, lane_index, relax
from ngsim_graphs.synth.road import ROADWAYS
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


def test_a_relaxed_driver_keeps_a_shorter_headway() -> None:
    # Headway 1.5 s less 0.5 s relaxed: desired gap 6 + 10 * 1 = 16 ft at a gap of 8 ft: z = 2.
    driver = _driver(10.0)
    driver["relax_s"] = 0.5
    acc = idm(driver, np.array([0]), np.array([60.0]), np.array([8.0]), np.array([10.0]))
    assert acc == pytest.approx([-9.0])


def test_a_lane_change_relaxes_the_mover_and_its_new_follower() -> None:
    # Lane 1: vehicle 0 at 200 ft, vehicle 1 at 100 ft; vehicle 2 at 150 ft moves from lane 2 to
    # lane 1, between them: it and vehicle 1 (its new follower) keep 75 % of their headway.
    fleet = np.zeros(3, FLEET_DTYPE)
    fleet["lane"] = fleet["from_lane"] = [1, 1, 2]
    fleet["y"] = [200.0, 100.0, 150.0]
    fleet["headway_s"] = [1.2, 1.6, 2.0]
    fleet["relax_s"] = [0.0, 0.0, 0.1]
    _, index = lane_index(fleet, ROADWAYS["lankershim"])
    relax(fleet, index, np.array([2]), np.array([1], np.int16))
    assert fleet["relax_s"].tolist() == pytest.approx([0.0, 0.4, 0.5])
    # An earlier, larger relaxation is kept.
    fleet["relax_s"][1] = 0.6
    relax(fleet, index, np.array([2]), np.array([1], np.int16))
    assert fleet["relax_s"][1] == pytest.approx(0.6)
