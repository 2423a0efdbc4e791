"""Every number ``thrsim fem`` takes, on its command line or in its --config file, refuses NaN,
infinities and absurd magnitudes in one line, exit 2, before any case starts and with nothing
written (issue 27, items 5 and 6). The flags are walked from the command's signature and the
settings from the case configuration's fields, so a new one is covered without touching this file."""

from __future__ import annotations

import inspect
import json
import re
import typing

import pytest
from pydantic import BaseModel
from test_cli_errors import assert_one_line_error
from test_cli_usage_errors import _bare

from thrsim.cli.fem_cmd import fem
from thrsim.config import ReamingCaseConfig

AIM = ("--inclination", "15", "--anteversion", "30")


@pytest.fixture(autouse=True)
def no_case_runs(monkeypatch):
    """A value that slipped through would start the solver: fail at once instead of simulating."""
    import thrsim.data.ground_truth

    def refuse(*args, **kwargs):
        raise AssertionError("a case started: the value was not refused")

    monkeypatch.setattr(thrsim.data.ground_truth, "run_case", refuse)


def _numeric_flags() -> list[str]:
    hints = typing.get_type_hints(fem)
    return [p.default.param_decls[0] for name, p in inspect.signature(fem).parameters.items() if _bare(hints[name]) in (int, float)]


FLAGS = _numeric_flags()
#: values no flag of fem may take: not numbers, or beyond any reamer, bone or machine
NEVER = ("nan", "inf", "1e300", "-1e300")
#: flags whose meaning makes a vanishing value as absurd as a huge one
NOT_VANISHING = ("--effective-mass", "--cutting-energy", "--element-size", "--failure-displacement", "--target-dt", "--reamer-diameter")


def test_the_walk_finds_fems_numeric_flags():
    assert {"--frames", "--force", "--effective-mass", "--axial-damping", "--contact-factor", "--cutting-energy", "--threads"} <= set(FLAGS)


@pytest.mark.parametrize(
    ("flag", "value"),
    [(f, v) for f in FLAGS for v in NEVER] + [(f, "1e-300") for f in NOT_VANISHING],
)
def test_a_flag_of_fem_refuses_a_value_no_case_can_have(thrsim_inprocess, tmp_path, flag, value):
    aim = (
        {"--cup-inclination": "40", "--cup-anteversion": "15"} if flag.startswith("--cup-") else dict(zip(AIM[::2], AIM[1::2], strict=True))
    )
    args = [part for pair in {**aim, flag: value}.items() for part in pair]  # the flag under test takes the bad value
    assert_one_line_error(thrsim_inprocess("fem", *args, "--out", "c.h5", cwd=tmp_path))
    assert list(tmp_path.iterdir()) == []


def _number_fields(model: type[BaseModel], prefix: str = ""):
    """Dotted name and type of every int or float setting of ``model`` and its nested models."""
    for name, field in model.model_fields.items():
        kind = _bare(field.annotation)
        if isinstance(kind, type) and issubclass(kind, BaseModel):
            yield from _number_fields(kind, f"{prefix}{name}.")
        elif kind in (int, float):
            yield f"{prefix}{name}", kind


#: the Johnson–Cook constants keep any finite value: the verification switches hardening and damage
#: off with yield stresses and fracture strains no test reaches (thrsim.verification.base)
UNBOUNDED = re.compile(r"(^|\.)(hardening\.\w+|damage\.d\d)$")


#: the aim is given by flags, which override the file's
AIMED = ("inclination_deg", "anteversion_deg")


def _bounded_fields():
    return [name for name, _ in _number_fields(ReamingCaseConfig) if not UNBOUNDED.search(name) and name not in AIMED]


def test_the_walk_finds_the_settings_behind_the_flags():
    fields = set(_bounded_fields())
    assert {"hold.effective_mass_kg", "hold.axial_damping_n_s_m", "contact.friction", "contact.penalty_factor", "force_n"} <= fields
    assert {"reamer.omega_rad_s", "solver.threads", "damage.displacement_at_failure_m", "socket.coarse_element_size_mm"} <= fields


def _nested(dotted: str, value) -> dict:
    tree: dict = {}
    *parents, leaf = dotted.split(".")
    node = tree
    for key in parents:
        node = node.setdefault(key, {})
    node[leaf] = value
    return tree


@pytest.mark.parametrize("dotted", _bounded_fields())
@pytest.mark.parametrize("value", [1e300, -1e300])
def test_a_setting_refuses_an_absurd_magnitude(thrsim_inprocess, tmp_path, dotted, value):
    """1e300 N of push, kg of reamer, threads or mm of anything: refused by the setting's bounds,
    the line naming the setting."""
    kind = dict(_number_fields(ReamingCaseConfig))[dotted]
    (tmp_path / "case.json").write_text(json.dumps(_nested(dotted, kind(value))))
    assert_one_line_error(thrsim_inprocess("fem", *AIM, "--config", "case.json", "--out", "c.h5", cwd=tmp_path), dotted.split(".")[-1])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case.json"]
