"""The seed-001 and seed-002 reproduction scripts run end to end in their --quick form.

Each script runs in this process through its ``main(argv)`` (``conftest.run_quick_experiment``)
and writes report.md (with the seed-vs-jaxnav comparison table) and PNG figures into a temporary
directory, so that the scripts cannot rot silently; each test also checks the study's
qualitative claim that the quick form is large enough to support, read from the report.
"""

from __future__ import annotations

import math


def _table_rows(text: str, after: str) -> dict[str, list[str]]:
    """The first Markdown table after the line starting with ``after``: {first cell: cells}."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(after))
    rows, seen = {}, False
    for line in lines[start + 1:]:
        if line.startswith("|"):
            seen = True
            cells = [c.strip() for c in line.strip("|").split("|")]
            rows[cells[0]] = cells[1:]
        elif seen:
            break
    return rows


def _check_report(text, out, must_contain):
    assert "| quantity | seed | jaxnav | ratio |" in text  # common.comparison_table header
    assert "--quick" in text
    for s in must_contain:
        assert s in text, f"{s!r} missing from the report"
    pngs = sorted(out.glob("*.png"))
    assert len(pngs) >= 3, pngs
    assert all(p.stat().st_size > 5000 for p in pngs)  # a real figure, not an empty canvas


def test_seed001_quick(run_quick_experiment, tmp_path, goldens):
    text = run_quick_experiment("seed001_ic_ppp_ins", tmp_path)
    goldens.check("seed001_quick", goldens.numbers_in(tmp_path) | goldens.table_numbers(text))
    _check_report(text, tmp_path, ["Table 2", "Table 3", "Table 5", "GIM"])
    # S001 Table 5: through frequent partial outages (3 satellites kept) the INS-aided IC-PPP
    # keeps the position better than IC-PPP alone. The quick form's 90-s window comes before
    # float-PPP convergence, where the horizontal components of both are dominated by the same
    # unconverged ambiguities, so the claim is checked on the 3D RMS (the seed: 79 % / 67 %
    # better in E / D; quick run measured 3D 106 vs 123 cm).
    rows = _table_rows(text, "## Frequent partial outages")
    rms_3d = {k: math.hypot(*map(float, rows[k][:3])) for k in ("IC-PPP/INS15", "IC-PPP alone")}
    print(f"\n3D RMS through partial outages [cm]: {rms_3d}")
    assert rms_3d["IC-PPP/INS15"] < rms_3d["IC-PPP alone"]


def test_seed002_quick(run_quick_experiment, tmp_path, goldens):
    text = run_quick_experiment("seed002_df_ppp_riss", tmp_path)
    goldens.check("seed002_quick", goldens.numbers_in(tmp_path) | goldens.table_numbers(text))
    _check_report(text, tmp_path, ["Table 5.2", "Table 5.1", "< 1.5 m", "Table 4"])
    # S002 Tables 5.1-5.2: through overpasses PPP alone loses its solution, while DF-PPP/RISS
    # bridges them with a smaller maximum 2D error than PPP alone (quick run measured 113 vs
    # 191 cm and 136 vs 186 cm).
    for traj in ("### trajectory 3", "### trajectory 2"):
        rows = _table_rows(text, traj)
        riss, alone = rows["IF-PPP/RISS9"], rows["IF-PPP alone"]
        print(f"\n{traj[4:]}: MAX 2D RISS9 {riss[1]} cm, PPP alone {alone[1]} cm; PPP alone "
              f"without a solution {alone[4]}")
        assert alone[4] != "0 s", traj
        assert float(riss[1]) < float(alone[1]), traj
