"""Progress lines of the recorded-data commands (apps.Stages): one line per long step with its
elapsed seconds, nothing with --quiet, and a stage that fails says so before the error."""

from __future__ import annotations

import re
import time

import pytest

from jaxnav.apps import Stages


def test_a_stage_prints_its_name_and_elapsed_seconds(capsys):
    stage = Stages()
    with stage("reading x.obs"):
        time.sleep(0.2)
    out = capsys.readouterr().out
    m = re.fullmatch(r"  reading x\.obs \.\.\. (\d+\.\d) s\n", out)
    assert m, out
    assert float(m.group(1)) >= 0.2 - 0.05  # the printed time is the step's (rounded to 0.1 s)


def test_quiet_prints_nothing_and_a_failed_stage_says_so(capsys):
    with Stages(quiet=True)("reading x.obs"):
        pass
    assert capsys.readouterr().out == ""
    with pytest.raises(ValueError, match="bad"), Stages()("preparing"):
        raise ValueError("bad")
    assert capsys.readouterr().out == "  preparing ... failed\n"
