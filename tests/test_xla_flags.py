"""The XLA flags ``import jaxnav`` adds: the older fusion emitters only when asked for and only
on the jaxlib where they were measured, never over a user's own setting.

Each case imports jaxnav in a fresh interpreter (XLA reads XLA_FLAGS once per process) and
reads back the environment it leaves.
"""

import os
import subprocess
import sys
from importlib import metadata

import pytest

import jaxnav

PROBE = "import os, jaxnav; print(os.environ['XLA_FLAGS'])"


def _flags_after_import(**env) -> str:
    clean = {k: v for k, v in os.environ.items()
             if k not in ("XLA_FLAGS", "JAXNAV_XLA_FUSION_EMITTERS")}
    out = subprocess.run([sys.executable, "-c", PROBE], env={**clean, **env},
                         capture_output=True, text=True, check=True)
    return out.stdout.strip()


def test_xla_default_emitters_unless_asked():
    assert _flags_after_import() == "--xla_cpu_multi_thread_eigen=false"


def test_older_emitters_on_request_only_on_the_measured_jaxlib():
    flags = _flags_after_import(JAXNAV_XLA_FUSION_EMITTERS="0")
    measured = jaxnav._jaxlib_minor() == (0, 10)
    assert (jaxnav.OLDER_EMITTERS_FLAG in flags) is measured, (metadata.version("jaxlib"), flags)


def test_a_users_own_flag_wins():
    assert _flags_after_import(XLA_FLAGS="--xla_cpu_use_fusion_emitters=true",
                               JAXNAV_XLA_FUSION_EMITTERS="0") == (
        "--xla_cpu_use_fusion_emitters=true --xla_cpu_multi_thread_eigen=false")


def test_the_suite_runs_with_the_older_emitters():
    """conftest.py asks for them; on jaxlib 0.10 this process was started with them."""
    assert os.environ["JAXNAV_XLA_FUSION_EMITTERS"] == "0"
    if jaxnav._jaxlib_minor() == (0, 10):
        assert jaxnav.OLDER_EMITTERS_FLAG in os.environ["XLA_FLAGS"]


@pytest.mark.parametrize("version, expected", [("0.10.2", (0, 10)), ("0.12.0.1", (0, 12)),
                                               ("1.0", (1, 0)), ("dev", None)])
def test_jaxlib_minor_parses_release_strings(monkeypatch, version, expected):
    monkeypatch.setattr(metadata, "version", lambda name: version)
    assert jaxnav._jaxlib_minor() == expected
