""":ref:`contract-gates`: ``DTFitGateConfig``, ``DTFitGateVerdict``, ``evaluate_dt_fit_gates``."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

import dtalign

pytestmark = pytest.mark.filterwarnings("error")

FIELDS = ["lm_unconverged_confidence_cap", "spurious_max_polarity_rejection_fraction",
          "spurious_unconverged_polarity_rejection_fraction",
          "spurious_min_coarse_peak_fraction"]
SHIPPED = (0.84, 0.35, 0.10, 0.05)


def _lm(converged=True, rejected=0):
    return dtalign.LMRefineResult(
        offset_vu=(0.0, 0.0), rotation_rad=0.0, covariance=np.zeros((2, 2)),
        residuals_px=np.zeros(4), weights=np.ones(4), rms_px=0.0, raw_rms_px=0.0,
        iterations=3, converged=converged, inlier_count=4, degenerate=False,
        polarity_rejected_count=rejected)


def _gate(lm_result, cfg=None, *, coarse=0.9, total=100, use_polarity=True):
    cfg = dtalign.DTFitGateConfig(*SHIPPED) if cfg is None else cfg
    v = dtalign.evaluate_dt_fit_gates(lm_result, cfg, coarse_peak_fraction=coarse,
                                      total_vertex_count=total, use_polarity=use_polarity)
    assert isinstance(v, dtalign.DTFitGateVerdict)
    assert isinstance(v.spurious_reasons, tuple)
    return v


# ---------------------------------------------------------------- DTFitGateConfig

def test_config_shipped_values():
    cfg = dtalign.DTFitGateConfig(*SHIPPED)
    assert tuple(getattr(cfg, f) for f in FIELDS) == SHIPPED
    assert cfg == dtalign.DTFitGateConfig(**dict(zip(FIELDS, SHIPPED, strict=True)))


def test_config_requires_all_four():
    with pytest.raises(TypeError):
        dtalign.DTFitGateConfig(0.84, 0.35, 0.10)


@pytest.mark.parametrize("value", [0.0, 1.0, 0, 1, np.float64(0.5), np.float32(0.25), "0.5",
                                   True])
def test_config_stores_what_was_given(value):
    for index in range(4):
        values = list(SHIPPED)
        values[index] = value
        cfg = dtalign.DTFitGateConfig(*values)
        stored = getattr(cfg, FIELDS[index])
        assert stored is value or (stored == value and type(stored) is type(value))


@pytest.mark.parametrize("index", range(4))
@pytest.mark.parametrize("value", [1.0000000000000002, -5e-324, math.nan, math.inf, 7,
                                   np.float64(-0.5), "2"], ids=repr)
def test_config_invalid_field(index, value):
    values = list(SHIPPED)
    values[index] = value
    text = f"DTFitGateConfig.{FIELDS[index]} must be in [0, 1]; got {float(value)!r}"
    with pytest.raises(ValueError, match=re.escape(text)):
        dtalign.DTFitGateConfig(*values)


def test_config_first_invalid_field_wins():
    for first in range(4):
        values = [5.0] * 4
        for i in range(first):
            values[i] = 0.5
        text = f"DTFitGateConfig.{FIELDS[first]} must be in [0, 1]; got 5.0"
        with pytest.raises(ValueError, match=re.escape(text)):
            dtalign.DTFitGateConfig(*values)


# ---------------------------------------------------------------- from_tuning

class _Recording(dict):
    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.reads = []

    def __getitem__(self, key):
        self.reads.append(key)
        return super().__getitem__(key)


def test_from_tuning_reads_in_field_order_and_converts():
    tuning = _Recording({FIELDS[3]: "0.05", FIELDS[1]: 0.35, FIELDS[0]: np.float32(0.5),
                         FIELDS[2]: 0, "unrelated_key": "not a number", "gain": 99})
    cfg = dtalign.DTFitGateConfig.from_tuning(tuning)
    assert isinstance(cfg, dtalign.DTFitGateConfig)
    got = [getattr(cfg, f) for f in FIELDS]
    assert got == [float(np.float32(0.5)), 0.35, 0.0, 0.05]
    assert all(type(x) is float for x in got)
    assert [k for k in tuning.reads if k in FIELDS][:4] == FIELDS
    assert "unrelated_key" not in tuning.reads and "gain" not in tuning.reads


def test_from_tuning_shipped():
    cfg = dtalign.DTFitGateConfig.from_tuning(dict(zip(FIELDS, SHIPPED, strict=True)))
    assert cfg == dtalign.DTFitGateConfig(*SHIPPED)


@pytest.mark.parametrize("missing", [[0], [1], [2], [3], [1, 3], [2, 3], [0, 1, 2, 3]])
def test_from_tuning_first_missing_key(missing):
    tuning = {f: v for i, (f, v) in enumerate(zip(FIELDS, SHIPPED, strict=True))
              if i not in missing}
    tuning["extra"] = 1.0
    with pytest.raises(KeyError) as exc:
        dtalign.DTFitGateConfig.from_tuning(tuning)
    assert exc.value.args == (FIELDS[missing[0]],)


def test_from_tuning_missing_before_invalid():
    # keys are read in field order: a missing second key is met before an invalid third
    tuning = {FIELDS[0]: 0.84, FIELDS[2]: 5.0, FIELDS[3]: 0.05}
    with pytest.raises(KeyError) as exc:
        dtalign.DTFitGateConfig.from_tuning(tuning)
    assert exc.value.args == (FIELDS[1],)


# ---------------------------------------------------------------- evaluate_dt_fit_gates

def test_clean_converged_fit():
    v = _gate(_lm(converged=True, rejected=0))
    assert v.spurious_reasons == ()
    assert v.spurious is False
    assert v.confidence_cap is None
    assert v.polarity_rejection_fraction == 0.0
    assert v.coarse_peak_fraction == 0.9
    assert v.lm_converged is True


def test_all_reasons_in_order():
    v = _gate(_lm(converged=False, rejected=50), coarse=0.01)
    assert v.spurious_reasons == ("polarity_rejection_fraction",
                                  "lm_unconverged_with_polarity_rejection",
                                  "coarse_peak_fraction")
    assert v.spurious is True
    assert v.confidence_cap == 0.84
    assert v.polarity_rejection_fraction == 0.5
    assert v.lm_converged is False


def test_max_rejection_threshold_is_inclusive():
    # 35 / 100 == 0.35 exactly as floats
    assert 35 / 100 == 0.35
    v = _gate(_lm(converged=True, rejected=35))
    assert v.spurious_reasons == ("polarity_rejection_fraction",)
    assert v.polarity_rejection_fraction == 0.35
    v = _gate(_lm(converged=True, rejected=34))
    assert v.spurious_reasons == ()


def test_unconverged_threshold_is_inclusive():
    assert 10 / 100 == 0.10
    v = _gate(_lm(converged=False, rejected=10))
    assert v.spurious_reasons == ("lm_unconverged_with_polarity_rejection",)
    assert v.confidence_cap == 0.84
    v = _gate(_lm(converged=False, rejected=9))
    assert v.spurious_reasons == ()
    assert v.confidence_cap == 0.84
    assert v.spurious is False
    # converged: the combined gate does not fire
    v = _gate(_lm(converged=True, rejected=20))
    assert v.spurious_reasons == ()
    assert v.confidence_cap is None


def test_coarse_threshold_is_strict_and_nan_never_fires():
    assert _gate(_lm(), coarse=0.05).spurious_reasons == ()
    assert _gate(_lm(), coarse=0.04999999).spurious_reasons == ("coarse_peak_fraction",)
    v = _gate(_lm(), coarse=math.nan)
    assert v.spurious_reasons == ()
    assert math.isnan(v.coarse_peak_fraction)
    assert _gate(_lm(), coarse=-math.inf).spurious_reasons == ("coarse_peak_fraction",)


def test_coarse_gate_regardless_of_polarity():
    v = _gate(_lm(converged=False, rejected=90), coarse=0.0, use_polarity=False)
    assert v.spurious_reasons == ("coarse_peak_fraction",)
    assert v.polarity_rejection_fraction == 0.0
    assert v.confidence_cap == 0.84


def test_no_polarity_fraction_is_zero():
    v = _gate(_lm(converged=True, rejected=100), use_polarity=False)
    assert v.polarity_rejection_fraction == 0.0
    assert v.spurious_reasons == ()


def test_zero_total_vertices():
    v = _gate(_lm(converged=False, rejected=3), total=0)
    assert v.polarity_rejection_fraction == 0.0
    assert v.spurious_reasons == ()
    assert v.confidence_cap == 0.84


def test_fraction_is_the_quotient():
    v = _gate(_lm(converged=True, rejected=1), total=3)
    assert v.polarity_rejection_fraction == 1 / 3
    assert isinstance(v.polarity_rejection_fraction, float)


def test_recorded_types():
    v = _gate(_lm(converged=np.True_, rejected=0), coarse=1)
    assert v.coarse_peak_fraction == 1.0 and type(v.coarse_peak_fraction) is float
    assert v.lm_converged is True
    v = _gate(_lm(converged=np.False_, rejected=0), coarse=np.float32(0.5))
    assert v.lm_converged is False
    assert type(v.coarse_peak_fraction) is float and v.coarse_peak_fraction == 0.5


def test_confidence_cap_is_the_configured_value():
    cfg = dtalign.DTFitGateConfig(0.5, 1.0, 1.0, 0.0)
    v = _gate(_lm(converged=False, rejected=100), cfg)
    # frac 1.0 >= 1.0: both polarity gates fire; coarse 0.9 < 0.0 does not
    assert v.spurious_reasons == ("polarity_rejection_fraction",
                                  "lm_unconverged_with_polarity_rejection")
    assert v.confidence_cap == 0.5


def test_thresholds_as_stored_ints():
    cfg = dtalign.DTFitGateConfig(1, 1, 0, 0)
    v = _gate(_lm(converged=False, rejected=0), cfg, coarse=0.0)
    # frac 0.0 < 1; frac 0.0 >= 0 (unconverged); coarse 0.0 < 0 is False
    assert v.spurious_reasons == ("lm_unconverged_with_polarity_rejection",)
    assert v.confidence_cap == 1


def test_verdict_frozen():
    import dataclasses

    v = _gate(_lm())
    with pytest.raises(dataclasses.FrozenInstanceError):
        v.spurious_reasons = ("x",)
