"""The benchmark report: the README section it rewrites, its rows, its exit status."""

from __future__ import annotations

import pytest

from dtalign.benchmarking import timing

REPORT = {
    "created": "2026-11-22 07:00:00 UTC",
    "machine": {"cpu_count": 2, "python": "3.11.7", "numpy": "2.4.6", "numba": "0.68.1"},
    "settings": {"mode": "full", "repeats": 15},
    "rows": [
        {"name": "coarse_30", "kind": "speed", "reference_s": 0.046, "dtalign_s": 1.4e-4,
         "ratio": 328.6, "target": 300.0, "passed": True, "results_agree": True,
         "peak_reference_bytes": 10_000, "peak_dtalign_bytes": 90_000},
        {"name": "batch_64_fits", "kind": "batch", "reference_s": 0.012, "dtalign_s": 0.0066,
         "ratio": 1.83, "target": 1.8, "passed": True, "results_agree": True,
         "control_ratio": 1.93},
        {"name": "import_dtalign", "kind": "startup", "dtalign_s": 0.0015, "target_s": 0.5,
         "passed": True},
    ],
}


def test_readme_table_replaces_only_its_section():
    text = f"# title\n\nbefore\n{timing.README_START}\nold table\n{timing.README_END}\nafter\n"
    out = timing.replace_readme_table(text, REPORT)
    assert out.startswith(f"# title\n\nbefore\n{timing.README_START}\nMeasured 2026-11-22")
    assert out.endswith(f"{timing.README_END}\nafter\n")
    assert "old table" not in out
    lines = out.splitlines()
    assert "| workload | reference | dtalign | ratio | target | status |" in lines[lines.index(
        timing.README_START) + 3]
    assert "| coarse_30 | 46.00 ms | 140.0 us | 328.6x | >= 300x | pass |" in out
    assert "| batch_64_fits | 12.00 ms | 6.60 ms | 1.83x | >= 1.8x | pass (control 1.93x) |" in out
    # rewriting again gives the same text: the markers survive
    assert timing.replace_readme_table(out, REPORT) == out


def test_batch_row_shows_every_control():
    row = {**REPORT["rows"][1], "fp_control_ratio": 1.31, "loop_control_ratio": 1.15,
           "ratio": 1.5, "passed": False}
    out = timing.replace_readme_table(
        f"{timing.README_START}\n{timing.README_END}\n", {**REPORT, "rows": [row]})
    assert ("| 1.50x | >= 1.8x | FAIL (control 1.93x, FP throughput 1.31x, "
            "compiled loop alone 1.15x) |") in out


def test_fp_control_unit_is_deterministic_work():
    from dtalign.benchmarking import fpload

    # 32 chains of x -> x * (1 + 1e-7) + 1e-9 from 1.0: the same sum every call
    x = 1.0
    for _ in range(1000):
        x = x * 1.0000001 + 1e-9
    assert fpload.fp_throughput(1000) == pytest.approx(fpload.LANES * x, rel=1e-14)
    assert fpload.unit() == fpload.unit()


@pytest.mark.parametrize("text", ["no markers", f"{timing.README_END}\n{timing.README_START}"])
def test_readme_table_needs_its_markers(text):
    with pytest.raises(ValueError, match="bench-table"):
        timing.replace_readme_table(text, REPORT)


def test_bench_exits_1_when_a_row_fails(monkeypatch, capsys):
    import dtalign.benchmarking as bench

    rows = [{"name": "x", "passed": True}, {"name": "y", "passed": False}]
    monkeypatch.setattr(bench, "run", lambda *a, **k: {
        "rows": rows, "total_s": 1.0, "warmup_s": 0.0, "other_load_cores": 0.0,
        "all_passed": False})
    monkeypatch.setattr(bench, "format_table", lambda rows: "| table |")
    assert bench.main(["--quick"]) == 1
    assert "1 row(s) FAIL: exit status 1" in capsys.readouterr().err
    assert bench.main(["--quick", "--allow-fail"]) == 0
    rows[1]["passed"] = True
    assert bench.main(["--quick"]) == 0
