"""Configuration defaults (SPEC §2), unit conversions and validation."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from thrsim.cli.output import format_validation_error
from thrsim.config import (
    BoneMaterial,
    BonePatchConfig,
    JohnsonCookDamage,
    JohnsonCookHardening,
    LabelConfig,
    Orientation,
    ReamerConfig,
    ReamingCaseConfig,
    SweepConfig,
    ThrsimConfig,
)


def test_spec_defaults():
    config = ThrsimConfig()
    bone = config.bone
    assert (bone.inner_radius_mm, bone.element_size_mm, bone.min_element_size_mm) == (22.0, 0.45, 0.045)
    assert bone.side == "right" and bone.support_side_faces
    assert bone.inner_radius == pytest.approx(0.022)
    assert bone.outer_radius == pytest.approx((22.0 + bone.thickness_mm) * 1e-3)
    assert bone.half_angle == pytest.approx(math.radians(bone.half_angle_deg))

    material = config.material
    assert (material.density_kg_m3, material.youngs_modulus_pa, material.poisson_ratio) == (1700.0, 17e9, 0.35)
    assert material.shear_modulus_pa == pytest.approx(17e9 / 2.7)
    hardening = config.hardening
    assert (hardening.a_pa, hardening.b_pa, hardening.n, hardening.c) == (50e6, 101e6, 0.08, 0.03)
    assert hardening.reference_strain_rate_s == 1e-3
    damage = config.damage
    assert (damage.d1, damage.d2, damage.d3, damage.d4) == (-0.09, 0.08, 0.006, 0.0)
    assert JohnsonCookDamage.TABLE_8_U_F_M == 5e-4 and JohnsonCookDamage.TEXT_U_F_M == 1e-4

    reamer = config.reamer
    assert (reamer.head_diameter_mm, reamer.tooth_count, reamer.omega_rad_s) == (45.0, 56, 136.0)
    assert reamer.head_radius == pytest.approx(0.0225)
    assert (reamer.density_kg_m3, reamer.youngs_modulus_pa, reamer.poisson_ratio) == (7800.0, 200e9, 0.3)
    assert (config.contact.friction, config.contact.damping_ratio) == (0.3, 0.2)

    sweep = config.sweep
    assert sweep.inclinations_deg == (0.0, 15.0, 30.0, 45.0)
    assert sweep.anteversions_deg == tuple(float(a) for a in range(0, 181, 15))
    assert sweep.frames == 120 and sweep.frame_dt_s == pytest.approx(1 / 60)
    labels = config.labels
    assert (labels.mu, labels.tau, labels.von_mises_scale_pa, labels.removed_threshold) == (0.38, 0.42, 1e7, 0.3)
    assert ReamingCaseConfig(inclination_deg=0, anteversion_deg=0).force_n == 230.0
    assert config.igtl.port == 18944


def test_jc_damage_initiation_strain_is_negative_for_every_triaxiality():
    d = JohnsonCookDamage()
    for eta in (-3.0, -1 / 3, 0.0, 1 / 3, 2 / 3, 3.0):
        assert d.d1 + d.d2 * math.exp(d.d3 * eta) < 0


@pytest.mark.parametrize(
    ("inclination", "anteversion", "axis"),
    [(0, 0, (0, 0, -1)), (90, 0, (1, 0, 0)), (90, 90, (0, 1, 0)), (45, 180, (-math.sqrt(0.5), 0, -math.sqrt(0.5)))],
)
def test_reamer_axis(inclination, anteversion, axis):
    d = Orientation(inclination_deg=inclination, anteversion_deg=anteversion).reamer_axis
    assert d == pytest.approx(axis, abs=1e-12)
    assert math.fsum(c * c for c in d) == pytest.approx(1.0)


@pytest.mark.parametrize(
    ("model", "values"),
    [
        (BonePatchConfig, {"element_size_mm": -0.45}),
        (BonePatchConfig, {"element_size_mm": 0}),
        (BonePatchConfig, {"thickness_mm": -1}),
        (BonePatchConfig, {"inner_radius_mm": 0}),
        (BonePatchConfig, {"half_angle_deg": 90}),
        (BonePatchConfig, {"side": "middle"}),
        (BonePatchConfig, {"min_element_size_mm": 1.0, "element_size_mm": 0.5}),
        (BonePatchConfig, {"element_size_mm": 20.0}),
        (BonePatchConfig, {"colour": "white"}),
        (Orientation, {"inclination_deg": -1, "anteversion_deg": 0}),
        (Orientation, {"inclination_deg": 91, "anteversion_deg": 0}),
        (Orientation, {"inclination_deg": 10, "anteversion_deg": 361}),
        (ReamingCaseConfig, {"inclination_deg": 120, "anteversion_deg": 0}),
        (ReamingCaseConfig, {"inclination_deg": 15, "anteversion_deg": 0, "force_n": -5}),
        (SweepConfig, {"inclinations_deg": (0, 95)}),
        (SweepConfig, {"anteversions_deg": (-15,)}),
        (ReamerConfig, {"tooth_count": 0}),
        (ReamerConfig, {"tooth_first_polar_deg": 50, "tooth_last_polar_deg": 40}),
        (ReamerConfig, {"wall_thickness_mm": 30}),
        (BoneMaterial, {"poisson_ratio": 0.5}),
        (JohnsonCookHardening, {"a_pa": -1}),
        (JohnsonCookDamage, {"displacement_at_failure_m": 0}),
        (LabelConfig, {"removed_threshold": 1.5}),
    ],
)
def test_invalid_values_are_refused(model, values):
    with pytest.raises(ValidationError) as error:
        model(**values)
    line = format_validation_error(error.value)
    assert "\n" not in line and line.startswith("invalid configuration: ")


def test_configs_are_frozen():
    bone = BonePatchConfig()
    with pytest.raises(ValidationError):
        bone.element_size_mm = 1.0  # type: ignore[misc]
    assert BonePatchConfig(side="left").side == "left"
    assert BonePatchConfig(element_size_mm=1.0).model_copy(update={"side": "left"}).side == "left"


def test_validation_message_names_the_field():
    with pytest.raises(ValidationError) as error:
        BonePatchConfig(element_size_mm=-1, side="up")
    line = format_validation_error(error.value)
    assert "element_size_mm" in line and "side" in line
