"""Configuration: unit conversions, consistent derived constants, settings files and validation."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from thrsim.cli.output import format_validation_error
from thrsim.config import (
    BoneMaterial,
    BonePatchConfig,
    IgtlConfig,
    JohnsonCookDamage,
    JohnsonCookHardening,
    LabelConfig,
    Orientation,
    ReamerConfig,
    ReamingCaseConfig,
    SweepConfig,
    load_case_config,
)
from thrsim.errors import ThrsimInputError


def test_millimetres_and_degrees_become_si_once():
    bone = BonePatchConfig(inner_radius_mm=20.0, thickness_mm=3.0, half_angle_deg=30.0, element_size_mm=0.9)
    assert (bone.inner_radius, bone.outer_radius, bone.half_angle) == pytest.approx((0.020, 0.023, math.radians(30.0)))
    assert ReamerConfig(head_diameter_mm=50.0).head_radius == pytest.approx(0.025)
    assert ReamingCaseConfig(inclination_deg=0, anteversion_deg=0, frame_rate_hz=30.0).frame_dt_s == pytest.approx(1 / 30)
    assert SweepConfig(frame_rate_hz=120.0).frame_dt_s == pytest.approx(1 / 120)


@pytest.mark.parametrize(("youngs", "nu", "rho"), [(17e9, 0.35, 1700.0), (200e9, 0.3, 7800.0), (1e6, 0.0, 1000.0)])
def test_elastic_constants_agree_with_each_other(youngs, nu, rho):
    material = BoneMaterial(youngs_modulus_pa=youngs, poisson_ratio=nu, density_kg_m3=rho)
    shear, lame, bulk = material.shear_modulus_pa, material.lame_lambda_pa, material.bulk_modulus_pa
    assert lame + 2 * shear / 3 == pytest.approx(bulk)  # K = λ + 2G/3
    assert shear * (3 * lame + 2 * shear) / (lame + shear) == pytest.approx(youngs)  # E from (λ, G)
    assert material.dilatational_wave_speed_m_s == pytest.approx(math.sqrt((bulk + 4 * shear / 3) / rho))


def test_a_case_takes_partial_settings_from_a_file_and_flags_override_them(tmp_path):
    settings = tmp_path / "case.json"
    settings.write_text('{"bone": {"half_angle_deg": 30, "element_size_mm": 0.9}, "inclination_deg": 15, "anteversion_deg": 30}')
    case = load_case_config(str(settings), {"bone.element_size_mm": 1.2, "force_n": None, "frames": 5})
    assert (case.bone.half_angle_deg, case.bone.element_size_mm, case.frames) == (30.0, 1.2, 5)
    assert case.force_n == ReamingCaseConfig(inclination_deg=15, anteversion_deg=30).force_n  # None: not given
    assert case.bone.thickness_mm == BonePatchConfig().thickness_mm  # untouched fields keep their defaults
    for text, message in (("[1, 2]", "must be a JSON object"), ("{oops", "not valid JSON")):
        settings.write_text(text)
        with pytest.raises(ThrsimInputError, match=message):
            load_case_config(str(settings), {})
    with pytest.raises(ThrsimInputError, match="no such configuration file"):
        load_case_config(str(tmp_path / "missing.json"), {})


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
        (IgtlConfig, {"known_devices": ("x" * 21,)}),
        (IgtlConfig, {"known_devices": ("Werkzeug\u00e9",)}),
        (IgtlConfig, {"idle_timeout_s": 0}),
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
