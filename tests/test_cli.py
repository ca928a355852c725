"""The command line: config validation before any work, and a tiny end-to-end sweep."""

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from jaxnav import cli

TINY = textwrap.dedent(
    """
    [study]
    name = "tiny"
    modes = ["sf_ppp"]  # the newest mode through the whole sweep (others: demo, test_sweep)
    systems = ["riss"]
    durations_s = [20]
    satellites_kept = [0, "all"]
    realizations = 1
    recovery_s = 10
    chunk_size = 8

    [placement]
    kind = "grid"
    convergence_s = 120
    spacing_s = 40

    [scenario]
    duration_s = 240
    constellations = ["gps"]  # a list in [scenario] (it once reached the factory still frozen)
    """
)


@pytest.mark.parametrize("old, new, words", [
    ('modes = ["sf_ppp"]', 'modes = ["df_cod"]', ["study.modes[0] = 'df_cod'", "sf_code"]),
    # the [scenario] table is the factory's: checked by its schema, also before any work
    ('constellations = ["gps"]', 'constellations = ["gps", "beidu"]',
     ["scenario.constellations[1] = 'beidu'", "'galileo'"]),
    ('constellations = ["gps"]', 'source = "recorded"', ["scenario.source = 'recorded'",
                                                         "'replay'"]),
    # issue 23: studies that hung or asked XLA for tens of GB, refused before any work
    ("realizations = 1", "realizations = 1000000000",
     ["study.realizations = 1000000000", "<= 1,000,000"]),
    ("chunk_size = 8", "chunk_size = 1000000000", ["study.chunk_size = 1000000000", "<= 4,096"]),
    ("duration_s = 240", "duration_s = 1e7",
     ["needs about", "GB are available: lower scenario.duration_s", "--force"]),
    # issue 23: accepted nonsense, now refused with its key
    ('satellites_kept = [0, "all"]', "satellites_kept = [1000]",
     ["study.satellites_kept = 1000", "16 satellite slots"]),
    ("spacing_s = 40", "spacing_s = 40\nmin_spacing_s = 30",
     ["placement.min_spacing_s = 30", "used only by kind 'random' and 'events'"]),
    ('kind = "grid"', 'kind = "random"\ncount = 1000000',
     ["placement.spacing_s = 40", "used only by kind 'grid'"]),
    ('kind = "grid"\nconvergence_s = 120\nspacing_s = 40',
     'kind = "random"\nconvergence_s = 120\ncount = 1000000',
     ["count = 1000000 placements, but only 91 start epochs"]),
    # found when the plan turns seconds into epochs, still before any scenario runs
    ("spacing_s = 40", "spacing_s = 40\n\n[metrics]\npre_s = 0.5",
     ["metrics.pre_s = 0.5", "whole number"]),
])
def test_invalid_config_is_rejected_before_any_work(tmp_path, capsys, old, new, words):
    bad = tmp_path / "bad.toml"
    text = TINY.replace(old, new)
    assert text != TINY  # the typo is really in the file (a no-op replace once ran a sweep)
    bad.write_text(text)
    out = tmp_path / "out"
    assert cli.main(["sweep", str(bad), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bad) in err, err  # one line naming the file
    for w in words:
        assert w in err, err
    assert not out.exists()


@pytest.mark.parametrize("old, new, words", [
    # issue 23's accepted-nonsense and late-traceback studies, refused by --check with their key
    ("duration_s = 240", "duration_s = 240\niono_scale = -1", ["scenario.iono_scale = -1"]),
    ("duration_s = 240", "duration_s = 240\niono_scale = nan", ["scenario.iono_scale = nan"]),
    ("duration_s = 240", "duration_s = 240\niono_scale = 9.99e99",
     ["scenario.iono_scale = 9.99e+99", "<= 20"]),
    ("duration_s = 240", 'duration_s = 240\nimu_grade = "__name__"',
     ["scenario.imu_grade = '__name__'"]),
    ("duration_s = 240", "duration_s = 240\ndrive_seed = -5", ["scenario.drive_seed = -5"]),
    ("duration_s = 240", "duration_s = -240", ["scenario.duration_s = -240"]),
    ("duration_s = 240", "duration_s = inf", ["scenario.duration_s = inf"]),
    ("durations_s = [20]", "durations_s = [nan]", ["study.durations_s[0] = nan"]),
])
def test_check_refuses_what_a_run_would(tmp_path, capsys, old, new, words):
    bad = tmp_path / "bad.toml"
    text = TINY.replace(old, new)
    assert text != TINY
    bad.write_text(text)
    assert cli.main(["sweep", str(bad), "--check"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bad) in err, err
    for w in words:
        assert w in err, err


def test_check_prints_the_study_size_and_writes_nothing(tmp_path, capsys, monkeypatch):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["sweep", str(cfg), "--check"]) == 0
    out = capsys.readouterr().out
    # 1 mode x 1 system; grid starts 120, 160, 200 s each leave the 20-s outage and 10 s of
    # recovery inside 240 s: 3 placements x 2 kept x 1 duration x 1 realisation
    assert "valid; 1 group(s) (sf_ppp x riss) x 6 scenarios = 6 scenarios" in out, out
    assert "memory about" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiny.toml"]
    assert cli.main(["sweep", str(cfg)]) == 2  # a run needs --out
    assert "--out is required" in capsys.readouterr().err


def test_workers_auto_runs_a_small_study_in_process(tmp_path, capsys, monkeypatch):
    """``--workers auto`` (the default outside the suite) keeps a 6-scenario study in one
    process, below parallel.AUTO_MIN_SCENARIOS, and the threshold switches to every core."""
    from jaxnav.study import parallel

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    monkeypatch.setenv("JAXNAV_WORKERS", "auto")
    assert cli.main(["sweep", str(cfg), "--check"]) == 0
    assert "1 worker(s)" in capsys.readouterr().out
    assert parallel.auto_workers(parallel.AUTO_MIN_SCENARIOS - 1) == 1
    assert parallel.auto_workers(parallel.AUTO_MIN_SCENARIOS) == parallel.default_workers()


@pytest.mark.parametrize("flag, env", [(["--workers", "two"], None), ([], "0")])
def test_a_bad_worker_count_is_a_clear_error(tmp_path, capsys, monkeypatch, flag, env):
    if env is not None:
        monkeypatch.setenv("JAXNAV_WORKERS", env)  # it used to raise while building the parser
    with pytest.raises(SystemExit) as e:
        cli.main(["demo", "--out", str(tmp_path / "out"), *flag])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "JAXNAV_WORKERS" in err and "'auto' or a whole number >= 1" in err, err
    assert not (tmp_path / "out").exists()


def test_tiny_sweep_writes_results_tables_and_plots(tmp_path, goldens, capsys):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    out = tmp_path / "out"
    assert cli.main(["sweep", str(cfg), "--out", str(out)]) == 0
    ds = xr.open_dataset(out / "results.nc")
    assert ds.sizes["satellites_kept"] == 2 and ds.sizes["placement"] >= 2
    worst = ds["max_2d_m"].sel(satellites_kept=0).mean()
    best = ds["max_2d_m"].sel(satellites_kept=-1).mean()
    assert float(worst) > float(best)  # a complete outage is worse than none
    # the no-outage reference is selectable by its label, singly or in a list, after a reload
    from jaxnav.study.store import load_results
    back = load_results(out / "results.nc")
    xr.testing.assert_identical(back["max_2d_m"].sel(satellites_kept="all"),
                                ds["max_2d_m"].sel(satellites_kept=-1))
    pair = back["max_2d_m"].sel(satellites_kept=["0", "all"])
    assert list(pair.satellites_kept.values) == [0, -1]
    assert float(back["max_2d_m"].sel(satellites_kept="all").mean()) == float(best)
    with pytest.raises(KeyError, match="allowed are integers and 'all'"):
        back.sel(satellites_kept="none")
    # outage starts also as GPS datetimes: epoch 0 is one interval after the scenario start
    from jaxnav.core.gpstime import gps_seconds_to_datetime64
    from jaxnav.sim.constellation import DEFAULT_T0_GPS_S
    lag = (back.start_s + back.attrs["epoch_dt_s"]).values * 1e9
    want = gps_seconds_to_datetime64(DEFAULT_T0_GPS_S) + lag.astype("timedelta64[ns]")
    np.testing.assert_array_equal(back.start_time.values, want)
    assert "GPS time" in back.start_time.attrs["long_name"]
    assert (out / "table.md").read_text().count("|") > 10
    goldens.check("tiny_sweep", goldens.numbers_in(out))  # refactors keep the numbers
    # An existing result is never silently overwritten: one line, exit 2 (issue 23: it was a
    # traceback), and --resume with --overwrite is refused by the parser.
    capsys.readouterr()
    assert cli.main(["sweep", str(cfg), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "results.nc exists; pass --overwrite" in err, err
    with pytest.raises(SystemExit) as e:
        cli.main(["sweep", str(cfg), "--out", str(out), "--resume", "--overwrite"])
    assert e.value.code == 2 and "pass one" in capsys.readouterr().err


@pytest.mark.heavy
def test_console_script_help():
    """The suite's one subprocess run of the command line: the ``jaxnav`` console script that
    pyproject installs beside this interpreter (``python -m jaxnav.cli`` where it is absent)."""
    script = Path(sys.executable).with_name("jaxnav")
    cmd = [str(script)] if script.is_file() else [sys.executable, "-m", "jaxnav.cli"]
    r = subprocess.run([*cmd, "--help"], capture_output=True, text=True, check=True)
    for command in ("demo", "sweep", "ppp", "lc"):
        assert command in r.stdout


@pytest.mark.parametrize("command", ["ppp", "lc"])
def test_real_data_commands_are_wired(command, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main([command, "--help"])
    assert exc.value.code == 0
    assert f"jaxnav {command}" in capsys.readouterr().out


def _all_parsers():
    """(name, parser) of ``jaxnav`` and each subcommand, delegated ones through their modules."""
    import argparse
    import importlib

    top = cli.build_parser()
    yield "jaxnav", top
    sub = next(a for a in top._actions if isinstance(a, argparse._SubParsersAction))
    for name, parser in sub.choices.items():
        if name in cli.DELEGATED:
            parser = importlib.import_module(f"jaxnav.apps.{name}").build_parser()
        yield name, parser


# The words that give a number its unit in a help text.
UNIT_WORDS = ("[", "second", "degree", " s ", " s)", " s of", "iterations")


def test_every_option_says_what_it_does_its_default_and_its_unit():
    """Each subcommand's --help: a description, a help text on every option, the default of
    every option that has one, and the unit of every numeric option (issue 22)."""
    import argparse

    missing = []
    for name, parser in _all_parsers():
        if not parser.description and name != "jaxnav":
            missing.append(f"{name}: no description")
        for a in parser._actions:
            if isinstance(a, (argparse._HelpAction, argparse._VersionAction,
                              argparse._SubParsersAction)):
                continue
            flag = a.option_strings[0] if a.option_strings else a.dest
            text = (a.help or "").replace("\n", " ")
            if not text:
                missing.append(f"{name} {flag}: no help")
                continue
            default = a.default
            if a.option_strings and default not in (None, False, [], argparse.SUPPRESS) \
                    and not isinstance(a, argparse._StoreConstAction) \
                    and "default" not in text.lower():
                missing.append(f"{name} {flag}: default {default!r} not said")
            if a.type in (float, int) and not any(w in text for w in UNIT_WORDS):
                missing.append(f"{name} {flag}: no unit")
    assert not missing, "\n".join(missing)


def test_list_prints_what_the_registries_hold(capsys):
    from jaxnav.gnss import modes
    from jaxnav.sim import sensors
    from jaxnav.study.factory import SimFactory

    for what, names in (("modes", modes.MODES), ("systems", SimFactory.systems),
                        ("presets", (*sensors.IMU_GRADES, *sensors.ODOMETERS))):
        assert cli.main(["list", what]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert [ln.split()[1 if what == "presets" else 0] for ln in lines] == list(names), what
    from jaxnav.study.factory import DRIVE_STYLES, SCENARIO_SCHEMA

    assert cli.main(["list", "drives"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [ln.split()[0] for ln in lines[:-1]] == list(DRIVE_STYLES)
    assert all(SCENARIO_SCHEMA["drive_style"](name) == name for name in DRIVE_STYLES)
    with pytest.raises(SystemExit) as e:
        cli.main(["list", "grades"])
    assert e.value.code == 2
    with pytest.raises(SystemExit) as e:
        cli.main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("jaxnav 0.")


@pytest.mark.full
def test_demo_table_matches_its_golden(tmp_path, goldens):
    """The main job (README): ``jaxnav demo``'s results and table.md keep their numbers (90 s on
    2 cores, hence ``full``; the tiny sweep above and seed000's quick form check the same path
    in CI)."""
    out = tmp_path / "demo"
    assert cli.main(["demo", "--out", str(out)]) == 0
    goldens.check("demo", goldens.numbers_in(out)
                  | goldens.table_numbers((out / "table.md").read_text(), "table.md"))


@pytest.mark.parametrize("extra, message", [
    (["--freq", "single"], "the C/A code needs the satellites' P1-C1 biases (expected --dcb FILE"),
    (["--freq", "single", "--ionex", "x.i", "--sp3", "x.sp3"],
     "--freq single needs the broadcast group delays (TGD / BGD) (expected --nav)"),
    (["--freq", "single", "--sp3", "x.sp3", "--no-p1c1"],
     "sf_code needs a model ionosphere (expected --nav (Klobuchar) or --ionex)"),
    (["--freq", "dual", "--no-p1c1"], "are for --freq single"),
])
def test_ppp_bad_options_exit_2_before_reading(extra, message, capsys, tmp_path):
    """``jaxnav ppp``: a missing product or P1-C1 choice is one line and exit 2, found before
    any file is read (the observation file here is empty)."""
    from jaxnav.apps import ppp as app

    for name in ("empty.rnx", "empty.nav", "x.i", "x.sp3"):  # present, so argparse accepts them
        (tmp_path / name).write_text("")
    extra = [str(tmp_path / a) if a in ("x.i", "x.sp3") else a for a in extra]
    args = ["--obs", str(tmp_path / "empty.rnx"), "--mode", "static", "--out",
            str(tmp_path / "o.pos"), *extra]
    if "--nav" not in extra and "--sp3" not in extra:
        args += ["--nav", str(tmp_path / "empty.nav")]
    assert app.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and message in err, err


# ---- issue 22: every user error is one line and exit code 2, before any long work --------------
def _one_line_exit_2(capsys, argv, *words):
    """Run ``jaxnav ARGV``: exit code 2 (returned or from argparse), one line on stderr holding
    every word, no traceback."""
    try:
        rc = cli.main(argv)
    except SystemExit as e:
        rc = e.code
    err = capsys.readouterr().err.strip()
    assert rc == 2, (rc, err)
    assert "Traceback" not in err and all(w in err for w in words), err
    assert err.splitlines()[-1].startswith("jaxnav"), err
    return err


@pytest.mark.parametrize("argv, option", [
    (["sweep", "{missing}", "--check"], "argument config"),
    (["ppp", "--obs", "{present}", "--nav", "{missing}", "--mode", "static", "--freq", "dual",
      "--out", "o.pos"], "argument --nav"),
    (["ppp", "--obs", "{missing}", "--mode", "static", "--freq", "dual", "--out", "o.pos"],
     "argument --obs"),
    (["lc", "--imu", "{present}", "--gnss", "{missing}", "--config", "{present}", "--out",
      "o.pos"], "argument --gnss"),
    (["ins", "--config", "{missing}", "--out", "o.pos"], "argument --config"),
    (["tune", "--config", "{present}", "--imu", "{missing}", "--gnss", "{present}",
      "--params", "x", "--out", "o.toml"], "argument --imu"),
])
def test_a_missing_input_file_names_its_option(tmp_path, capsys, argv, option):
    """A missing input file is refused by the argument parser, naming the option, before any
    other input is read (``jaxnav ppp --nav`` was found after 21 s of RINEX reading)."""
    present = tmp_path / "present.txt"
    present.write_text("")
    missing = tmp_path / "missing.toml"
    argv = [a.format(present=present, missing=missing) for a in argv]
    _one_line_exit_2(capsys, argv, option, f"{missing}: no such file")


def test_ctrl_c_during_a_sweep_is_one_line_naming_resume(tmp_path, capsys, monkeypatch):
    """Ctrl-C (KeyboardInterrupt from anywhere inside the run, e.g. compilation) ends the
    command with one line that says how to continue, not a traceback."""
    from jaxnav.study import sweep

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep, "run_sweep", interrupted)
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    _one_line_exit_2(capsys, ["sweep", str(cfg), "--out", str(tmp_path / "o")], "interrupted",
                     "--resume")


@pytest.mark.heavy
def test_ctrl_c_in_a_real_sweep_subprocess(tmp_path):
    """SIGINT sent to a running ``jaxnav sweep`` (while it compiles or runs): exit code 2, one
    line, no traceback; the folder then resumes (``--resume``) to a complete result."""
    import signal
    import time

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY)
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "jaxnav.cli", "sweep", str(cfg), "--out", str(out),
           "--workers", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not out.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)  # the output folder exists once the checks passed and work started
    assert proc.poll() is None, proc.communicate()
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    assert "Traceback" not in err and "interrupted" in err and "--resume" in err, err
    assert len([ln for ln in err.splitlines() if ln.startswith("jaxnav")]) == 1, err
    assert cli.main(["sweep", str(cfg), "--out", str(out), "--resume", "--workers", "1"]) == 0
    assert (out / "results.nc").is_file()


def test_init_writes_a_valid_template_with_every_key_and_its_default(tmp_path, capsys):
    """``jaxnav init``: the template passes ``--check``, names every key of every section
    (those of other placement kinds commented out), and its values are the defaults: the same
    study and simulated drive as a TOML without them."""
    import tomllib

    from jaxnav.study import config as sc
    from jaxnav.study import factory as fc

    path = tmp_path / "study.toml"
    assert cli.main(["init", str(path)]) == 0
    text = path.read_text()
    for section, keys in (("study", sc._STUDY_KEYS), ("placement", sc._PLACEMENT_SCHEMA),
                          ("metrics", sc._METRICS_SCHEMA), ("scenario", fc.SCENARIO_SCHEMA)):
        body = text.split(f"[{section}]", 1)[1].split("\n[", 1)[0]
        for key in keys:
            assert f"\n{key} = " in body or f"\n# {key} = " in body, (section, key)
    capsys.readouterr()
    assert cli.main(["sweep", str(path), "--check"]) == 0
    data = tomllib.loads(text)
    full = sc.from_dict(data)
    bare = sc.from_dict({"study": {k: data["study"][k] for k in ("modes", "systems")}})
    assert full.replace(scenario=()) == bare
    a, b = fc.SimFactory(data["scenario"]), fc.SimFactory({})
    assert a.cfg == b.cfg and (a.ins_grade, a.bssd, a.lc_fix_correlated) == (
        b.ins_grade, b.bssd, b.lc_fix_correlated)
    assert cli.main(["init", str(path)]) == 2  # no silent overwrite
    assert "exists; pass --overwrite" in capsys.readouterr().err


def test_dry_run_prints_the_plan_and_its_estimate(tmp_path, capsys):
    """``--dry-run``: the --check line, then the axes, placements, scenario count and a time
    estimate that is the cost model's sum (study.costs) over the groups; nothing written."""
    from jaxnav.study import config as sc
    from jaxnav.study import costs, sweep
    from jaxnav.study.factory import SimFactory

    cfg_path = tmp_path / "tiny.toml"
    cfg_path.write_text(TINY.replace('modes = ["sf_ppp"]', 'modes = ["sf_ppp", "float_ppp"]'))
    assert cli.main(["sweep", str(cfg_path), "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "placements      : 3 (grid), starts [s] 120, 160, 200" in out
    assert "scenarios       : 6 per group x 2 group(s)" in out
    assert "sf_ppp/riss as float_ppp/riss" in out  # not measured: said so
    assert "many realizations are over-estimated" not in out  # one realization: exact
    cfg = sc.load(cfg_path, modes=SimFactory.modes, systems=SimFactory.systems)
    plan = sweep.make_plan(cfg, SimFactory(cfg.scenario_dict).timeline(cfg))
    c = costs.COSTS[("float_ppp", "riss")]
    want = 2 * (c.compile_s + len(plan.seeds) * (plan.timeline.n_epochs * c.full_epoch_s
                                                  + c.other_per_realization_s)
                + plan.n_per_group * plan.window * c.scenario_epoch_s)
    want += costs.DRIVE_S_PER_S * plan.timeline.n_epochs * plan.timeline.epoch_dt_s
    assert costs.estimate(cfg, plan, 240.0).seconds == pytest.approx(want, rel=1e-12)
    assert f"about {want / 60:.1f} min" in out
    cfg_path.write_text(TINY.replace("realizations = 1", "realizations = 3"))
    assert cli.main(["sweep", str(cfg_path), "--dry-run"]) == 0
    assert "many realizations are over-estimated" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == [cfg_path]
