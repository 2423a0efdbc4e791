"""α labels (eq. 47), angle lists, the sweep plan (γ = 0 merging, force axis) and the split."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from thrsim.config import LabelConfig
from thrsim.data.labels import alpha, removed
from thrsim.data.sweep import (
    DEFAULT_SPLIT,
    SplitRule,
    coverage_order,
    format_list,
    parse_list,
    plan_sweep,
)
from thrsim.errors import ThrsimInputError


def test_alpha_values():
    # intact, unstressed: 1 − τ = 0.58; σ_M ≥ 1e7/μ: the stress term vanishes → 1 − PEEQ
    a = alpha([0.0, 0.0, 0.1, 2.0, 0.0], [0.0, 1e8, 1e8, 0.0, 5e6], [1, 1, 1, 1, 0])
    assert a.dtype == np.float32
    np.testing.assert_allclose(a, [0.58, 1.0, 0.9, 0.0, 0.0], atol=1e-6)
    mid = alpha([0.05], [1e7])[0]  # 1 − (0.05 + 0.42·(1 − 0.38))
    assert mid == pytest.approx(1 - (0.05 + 0.42 * 0.62), abs=1e-6)
    assert removed(a).tolist() == [False, False, False, True, True]
    custom = LabelConfig(mu=0.0, tau=0.0)
    assert alpha([0.2], [0.0], config=custom)[0] == pytest.approx(0.8)


def test_crushed_bone_that_stays_is_not_removed():
    """A crushable foam's plastic strain is compaction: its damage counts as material lost instead."""
    peeq, vm, status = [[0.6, 0.6, 0.6]], [[5e6, 5e6, 5e6]], [[1, 1, 0]]
    damage = [[0.0, 0.9, 0.0]]
    compacting = np.array([True, True, True])
    a = alpha(peeq, vm, status, damage=damage, compacting=compacting)
    assert removed(a).tolist() == [[False, True, True]]  # crushed and kept / fractured / deleted
    np.testing.assert_allclose(a[0, 0], 1 - 0.42 * (1 - 0.38 * 0.5), atol=1e-6)  # as intact bone at that stress
    assert removed(alpha(peeq, vm, status)).all()  # eq. 47 as written reads the compaction as lost
    assert removed(alpha(peeq, vm, status, LabelConfig(crushed_bone_is_lost=True), damage=damage, compacting=compacting)).all()
    with pytest.raises(ThrsimInputError, match="damage"):
        alpha(peeq, vm, status, compacting=compacting)


def test_the_socket_s_cancellous_bone_compacts_unless_written_before_it_could():
    from thrsim.data.labels import compacting_elements
    from thrsim.geometry.mesh import TetMesh

    mesh = TetMesh(
        np.eye(4, 3), np.array([[0, 1, 2, 3], [0, 1, 2, 3]]), material=np.array([0, 1]), material_names=("cortical", "cancellous")
    )
    assert compacting_elements({}, mesh).tolist() == [False, True]
    old = {"cancellous": {"specific_cutting_energy_j_m3": 1e8}}  # a solver before 0.5.2 wrote no compaction
    assert compacting_elements(old, mesh).tolist() == [False, False]
    assert compacting_elements({"cancellous": {"compaction": None}}, mesh).tolist() == [False, False]


@settings(max_examples=60, deadline=None)
@given(st.floats(0, 10), st.floats(0, 1e9), st.integers(0, 1))
def test_alpha_bounded_and_zero_when_removed(peeq, vm, status):
    a = alpha([peeq], [vm], [status])[0]
    assert 0.0 <= a <= 1.0
    if status == 0:
        assert a == 0.0


def test_parse_list():
    assert parse_list("0:180:15", "x") == tuple(float(v) for v in range(0, 181, 15))
    assert parse_list("0:30:15,45, 15", "x") == (0.0, 15.0, 30.0, 45.0)
    assert parse_list("0:1:0.1", "x")[-1] == 1.0 and len(parse_list("0:1:0.1", "x")) == 11
    assert parse_list("none", "x", allow_empty=True) == ()
    for bad in ("", "a,b", "0:10", "0:10:0", "10:0:5", "1,,2", "nan"):
        with pytest.raises(ThrsimInputError):
            parse_list(bad, "--inclinations")


def test_default_plan():
    plan = plan_sweep()
    main = [c for c in plan.cases if c.force_n == 230.0]
    assert len(main) == 1 + 3 * 13  # γ = 0 is one physical case
    for force in (150.0, 310.0):
        extra = [c for c in plan.cases if c.force_n == force]
        assert len(extra) == 1 + 3 * 3
        assert {c.anteversion_deg for c in extra} == {0.0, 90.0, 180.0}
    assert len(plan.cases) == 60 == len({c.case_id for c in plan.cases})
    zero = [c for c in plan.cases if c.inclination_deg == 0.0 and c.force_n == 230.0]
    assert len(zero) == 1 and zero[0].anteversion_deg == 0.0 and len(zero[0].aliases) == 13
    assert any("one physical case" in n for n in plan.notes)
    assert all(c.frames == 120 for c in plan.cases)


def test_plan_refuses_bad_input():
    with pytest.raises(ThrsimInputError, match="no cases"):
        plan_sweep((), (0.0,))
    with pytest.raises(ThrsimInputError, match="inclinations must lie in"):
        plan_sweep((95.0,), (0.0,))
    with pytest.raises(ThrsimInputError, match="anteversions must lie in"):
        plan_sweep((10.0,), (-15.0,))
    with pytest.raises(ThrsimInputError, match="positive"):
        plan_sweep((10.0,), (0.0,), force_n=-1.0)
    with pytest.raises(ThrsimInputError, match="frames"):
        plan_sweep((10.0,), (0.0,), frames=0)


def test_extra_axes_and_case_config():
    plan = plan_sweep((15.0,), (0.0, 90.0), frames=3, extra_forces_n=(), element_sizes_mm=(0.9, 1.2))
    assert len(plan.cases) == 4
    spec = [c for c in plan.cases if c.element_size_mm == 1.2][0]
    config = spec.case_config({"frames": 99})
    assert config.bone.element_size_mm == 1.2 and config.frames == 3 and config.inclination_deg == 15.0
    assert "_h1.2mm" in spec.case_id


def test_split_is_by_orientation_and_deterministic():
    plan = plan_sweep()
    splits = {}
    for c in plan.cases:
        s = DEFAULT_SPLIT.split(c.inclination_deg, c.anteversion_deg)
        assert splits.setdefault(c.orientation, s) == s  # every force of an orientation shares it
    train = {o for o, s in splits.items() if s == "train"}
    test = {o for o, s in splits.items() if s == "test"}
    val = {o for o, s in splits.items() if s == "validation"}
    assert not (train & test) and not (train & val)
    assert {o[1] for o in test} == {45.0, 135.0} and {o[0] for o in test} == {15.0, 30.0, 45.0}
    assert {o[1] for o in val} == {90.0}
    assert (0.0, 0.0) in train
    assert (len(train), len(val), len(test)) == (31, 3, 6)
    rule = SplitRule(test_anteversions_deg=(0.0,), zero_inclination_split="test")
    assert rule.split(0.0, 0.0) == "test" and rule.split(30.0, 45.0) == "train"


def test_coverage_order_reaches_every_inclination_and_force_early():
    from thrsim.data.sweep import coverage_order, plan_sweep

    plan = plan_sweep()
    ordered = coverage_order(plan.cases)
    assert sorted(c.case_id for c in ordered) == sorted(c.case_id for c in plan.cases)
    first = ordered[:15]
    assert {c.inclination_deg for c in first} == {0.0, 15.0, 30.0, 45.0}
    assert {c.force_n for c in first} == {150.0, 230.0, 310.0}
    assert len({c.anteversion_deg for c in first}) >= 3


def test_sweep_defaults_are_defined_once_in_the_configuration():
    """thrsim dataset's options, plan_sweep's arguments and SweepConfig agree, because the first
    two are derived from the third."""
    import inspect

    from thrsim.cli import dataset_cmd
    from thrsim.config import SocketSweepConfig, SweepConfig

    config = SweepConfig()
    options = {
        name: p.default.default for name, p in inspect.signature(dataset_cmd.dataset).parameters.items() if hasattr(p.default, "default")
    }
    assert parse_list(options["inclinations"], "") == config.inclinations_deg
    assert parse_list(options["anteversions"], "") == config.anteversions_deg
    assert parse_list(options["forces"], "") == config.forces_n
    assert parse_list(options["extra_forces"], "", allow_empty=True) == config.extra_forces_n
    assert parse_list(options["extra_force_anteversions"], "", allow_empty=True) == config.extra_force_anteversions_deg
    # --frames defaults per bone, both from the configuration, and its help says both
    assert options["frames"] is None
    help_text = inspect.signature(dataset_cmd.dataset).parameters["frames"].default.help
    assert f"{config.frames} on the patch" in help_text and f"{SocketSweepConfig().frames} on the socket" in help_text
    defaults = {name: p.default for name, p in inspect.signature(plan_sweep).parameters.items()}
    assert (defaults["inclinations"], defaults["anteversions"], defaults["frames"]) == (
        config.inclinations_deg,
        config.anteversions_deg,
        config.frames,
    )
    assert (defaults["force_n"], defaults["extra_forces_n"], defaults["extra_force_anteversions"]) == (
        config.forces_n, config.extra_forces_n, config.extra_force_anteversions_deg,
    )  # fmt: skip


@pytest.mark.parametrize(
    "values", [(0.0, 15.0, 30.0, 45.0), tuple(float(a) for a in range(0, 181, 15)), (150.0, 310.0), (0.5, 1.25, 2.0, 2.75, 3.5), ()]
)
def test_format_list_is_the_inverse_of_parse_list(values):
    assert parse_list(format_list(values), "", allow_empty=True) == values


def test_coverage_order_starts_with_the_plans_own_main_force():
    plan = plan_sweep(
        (15.0, 30.0), (0.0, 90.0, 180.0), frames=2, force_n=(200.0,), extra_forces_n=(120.0,), extra_force_anteversions=(90.0,)
    )
    ordered = coverage_order(plan.cases, plan.main_forces_n)
    assert plan.main_forces_n == (200.0,)
    assert ordered[0].force_n == 200.0 and sorted(c.case_id for c in ordered) == sorted(c.case_id for c in plan.cases)
    extra_positions = [i for i, c in enumerate(ordered) if c.force_n == 120.0]
    assert extra_positions[0] > 0 and extra_positions[-1] < len(ordered) - 1  # interleaved, not bunched at an end
