"""A scaling row (2 workers against 1) is judged against its target and its own control.

Synthetic (ratio, control) figures, nothing timed: a healthy row passes by
its target, a row on a machine whose control could not scale passes
control-bound, and a row that stays at 1x while its control scaled (work
serialised on a lock) fails; so does one below the floor whatever the control.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from dtalign.benchmarking import scaling, timing
from dtalign.benchmarking.scaling import CONTROL_FRACTION, FLOOR, expected_ratio, judge


def test_a_row_at_its_target_passes_whatever_its_control():
    for control in (None, 0.5, 1.0, 1.9):
        verdict = judge(1.85, 1.8, control)
        assert verdict.passed and verdict.rule == "target" and verdict.required == 1.8


def test_a_row_the_machine_held_back_passes_control_bound():
    # another process held the second core: the control itself scaled 1.05x
    verdict = judge(0.95, 1.8, 1.05)
    assert verdict.passed and verdict.rule == "control-bound"
    assert verdict.required == pytest.approx(max(FLOOR, CONTROL_FRACTION * 1.05))
    # a control that scaled most of the way: the row needs that fraction of it
    assert judge(1.35, 1.8, 1.6).passed
    assert judge(1.25, 1.8, 1.6).rule == "below control"


def test_a_serialised_batch_fails_when_its_control_scaled():
    # a lock: two workers no faster than one, while the control scaled 1.6x
    verdict = judge(1.0, 1.8, 1.6)
    assert not verdict.passed and verdict.rule == "below control"
    assert verdict.required == pytest.approx(CONTROL_FRACTION * 1.6)
    assert not judge(1.02, 1.5, 1.9).passed
    # the bound never asks more than the target
    assert judge(1.49, 1.5, 1.99).required == 1.5


def test_below_the_floor_fails_whatever_the_control():
    verdict = judge(FLOOR - 0.05, 1.8, 0.5)
    assert not verdict.passed and verdict.rule == "below floor" and verdict.required == FLOOR
    assert judge(FLOOR + 0.05, 1.8, 0.5).rule == "control-bound"


def test_a_row_mostly_under_the_gil_is_held_to_its_parallel_share():
    # 64 fits, a quarter of one worker's time GIL-free: 2 workers cannot get far past 1x
    assert expected_ratio(2.0, 0.25) == pytest.approx(1 / 0.875)
    assert expected_ratio(1.5, 1.0) == pytest.approx(1.5)
    own = scaling.CONTROLS["batch_64_fits"]
    assert judge(0.93, 1.5, 1.53, 0.25, own.fraction).rule == "control-bound"
    verdict = judge(0.75, 1.5, 1.9, 0.25, own.fraction)
    assert not verdict.passed and verdict.rule == "below control"
    assert verdict.required == pytest.approx(own.fraction / (0.75 + 0.25 / 1.9))
    # the same figures against a row whose work all runs on both workers fail
    assert not judge(0.93, 1.5, 1.53).passed


def test_without_a_control_only_the_target_passes():
    assert judge(1.0, 1.8, None) == scaling.Verdict(False, "below target", 1.8)


BATCH = {"name": "batch_images", "kind": "batch", "reference_s": 0.3, "dtalign_s": 0.3,
         "ratio": 1.0, "target": 1.8, "results_agree": True, "control_ratio": 1.02,
         "fp_control_ratio": 0.9, "loop_control_ratio": 1.1, "judged_by": "control_ratio"}


def _row(ratio: float, control: float) -> dict:
    """A batch_images row as measure_batch writes it, judged against its SHA-256 control."""
    verdict = judge(ratio, 1.8, control)
    return {**BATCH, "ratio": ratio, "control_ratio": control, "passed": verdict.passed,
            "rule": verdict.rule, "required_ratio": verdict.required}


def test_each_scaling_row_has_its_own_control():
    assert set(scaling.CONTROLS) == {"batch_64_fits", "batch_images", "archive_32_frames"}
    for own in scaling.CONTROLS.values():
        assert own.key in {"control_ratio", "fp_control_ratio"}
        # serialised work (1x) of share 1 beside a control at 1.5x is below the bound
        assert 1.0 < own.fraction * 1.5 and own.fraction <= 1.0


def test_the_table_says_which_rule_a_row_passed_or_failed_by():
    status = timing._cells(_row(1.0, 1.05))[5]
    assert status == ("pass, control-bound (SHA-256 control): needs 0.84x (control 1.05x, "
                      "FP throughput 0.90x, compiled loop alone 1.10x)")
    fp = {**_row(0.9, 1.6), "judged_by": "fp_control_ratio"}
    assert timing._cells(fp)[5].startswith("FAIL, below control (FP throughput): needs 1.28x (")
    assert timing._cells(_row(1.9, 1.6))[5].startswith("pass (control 1.60x")


@pytest.fixture(scope="module")
def bench_check():
    path = Path(__file__).resolve().parents[1] / ".ci" / "bench_check.py"
    spec = importlib.util.spec_from_file_location("_bench_check_under_test", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_ci_fails_the_scaling_rows_the_run_failed(bench_check):
    failures = bench_check.check([_row(1.0, 1.05), _row(1.0, 1.6)])
    assert [f.name for f in failures] == ["batch_images"]
    assert failures[0].message == ("batch_images: ratio 1.00x below control: needs 1.28x "
                                   "(target 1.8x, control_ratio 1.60x)")
    assert bench_check.missed_targets([_row(1.0, 1.05)]) == [
        "batch_images 1.00x < target 1.8x (control-bound)"]


def test_the_campaign_row_is_judged_against_its_sha256_control():
    from types import SimpleNamespace

    from dtalign.benchmarking.archive import _Pairs, _rows

    def campaign(cluster_s: float) -> dict:
        pairs = _Pairs(t_serial=[1.0], t_cluster=[cluster_s], t_single=[0.9], cpu_serial=[1.0],
                       cpu_cluster=[1.1], cpu_single=[1.2], store_s=[0.01],
                       c_serial=[1.0], c_cluster=[0.625], f_serial=[1.0], f_cluster=[0.9])
        pairs.summary = SimpleNamespace(items_per_task=4)
        return _rows(pairs, 32, 2.0, 0.5, 1.0, 0.0)[0]

    # its SHA-256 control scaled 1.6x: 1.3x is 0.8 of it, 1.0x is serialised work
    row = campaign(1 / 1.3)
    assert row["passed"] and row["rule"] == "control-bound" and row["judged_by"] == "control_ratio"
    assert row["required_ratio"] == pytest.approx(1.28)
    assert campaign(1.0)["rule"] == "below control"
