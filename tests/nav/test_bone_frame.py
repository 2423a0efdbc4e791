"""The bone frame's γ/θ and the clinical cup angles: one aim, converted as the trainer places the bone."""

from __future__ import annotations

import pytest

from thrsim.app.controls import parse_reaming_control
from thrsim.app.reaming import ReamingTrainer
from thrsim.config import SafeZone
from thrsim.nav.bone_frame import bone_angles_from_cup, cup_angles_from_bone


def test_the_safe_zones_centre_is_the_socket_axis():
    zone = SafeZone()
    assert bone_angles_from_cup(zone.inclination_deg, zone.anteversion_deg) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert cup_angles_from_bone(0.0, 0.0) == pytest.approx((zone.inclination_deg, zone.anteversion_deg))


@pytest.mark.parametrize("cup", [(45.0, 20.0), (30.0, 5.0), (60.0, 30.0), (40.0, -10.0), (25.0, 25.0)])
def test_cup_angles_and_bone_angles_convert_both_ways(cup):
    gamma, theta = bone_angles_from_cup(*cup)
    assert 0.0 <= gamma <= 90.0 and 0.0 <= theta < 360.0
    assert cup_angles_from_bone(gamma, theta) == pytest.approx(cup)


def test_the_documented_worked_example():
    assert bone_angles_from_cup(45.0, 20.0) == pytest.approx((6.9, 330.1), abs=0.05)
    assert cup_angles_from_bone(15.0, 30.0) == pytest.approx((54.9, 11.2), abs=0.05)


def test_an_aim_into_the_pelvis_has_no_clinical_angles():
    assert cup_angles_from_bone(90.0, 180.0) is None


@pytest.mark.parametrize("side", ["right", "left"])
def test_the_trainer_measures_the_same_gamma_and_theta(side):
    trainer = ReamingTrainer(side=side)  # no simulator: the aim is still measured
    trainer.apply_control(parse_reaming_control({"type": "reamer", "inclination_deg": 45, "anteversion_deg": 20}), 0.0)
    reaming = trainer.step(1 / 60)["reaming"]
    assert (reaming["gamma_deg"], reaming["theta_deg"]) == pytest.approx(bone_angles_from_cup(45.0, 20.0), abs=1e-6)
