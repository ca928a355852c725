"""The sweep on Dask workers (jaxnav.study.parallel): the dataset is bit-identical to the
in-process one on 2 workers, when a worker is killed mid-sweep, when a sweep interrupted on 2
workers is resumed on 1, through ``jaxnav sweep --scheduler``, and (``-m full``) on 3 workers
(oversubscribed on 2 cores) and on a separately started ``dask scheduler`` + ``dask worker``.

One 2-worker cluster serves the CI tests: a worker keeps its group's compiled programs and full
runs between sweeps of the same study, so only the first sweep on it pays for them."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import tomllib

import numpy as np
import pytest
import xarray as xr

from jaxnav import cli
from jaxnav.study import config, parallel, sweep
from jaxnav.study.factory import SimFactory

pytestmark = [pytest.mark.heavy, pytest.mark.slow]  # worker processes

STUDY = """
[study]
name = "parallel"
modes = ["sf_ppp", "float_ppp"]
systems = ["riss"]
durations_s = [20]
satellites_kept = [0, 2]
realizations = 2
recovery_s = 10
chunk_size = 2

[placement]
kind = "grid"
convergence_s = 120
spacing_s = 40

[scenario]
duration_s = 240
"""


def _cfg():
    return config.from_dict(tomllib.loads(STUDY), modes=SimFactory.modes,
                            systems=SimFactory.systems)


def _run(out, **kw):
    cfg = _cfg()
    return sweep.run_sweep(cfg, SimFactory(cfg.scenario_dict), out, progress=False, **kw)


def _same(a, b, attrs=True):
    assert set(a.data_vars) == set(b.data_vars) and set(a.coords) == set(b.coords)
    for k in [*a.data_vars, *a.coords]:
        np.testing.assert_array_equal(a[k].values, b[k].values, err_msg=k)  # NaN == NaN here
    if attrs:
        assert a.attrs == b.attrs


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The in-process sweep (workers = 1): 2 groups x 6 chunks of 2 scenarios."""
    r = _run(tmp_path_factory.mktemp("ref") / "out")
    assert r.stats["chunks_computed"] == 12
    return r.dataset


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=None,
                      env=parallel._worker_env(), silence_logs=40) as cluster, \
            Client(cluster) as c:
        yield c


def _wait_for_workers(c, n, timeout=120):
    deadline = time.monotonic() + timeout
    while len(c.scheduler_info()["workers"]) < n:
        assert time.monotonic() < deadline, f"fewer than {n} Dask workers after {timeout} s"
        time.sleep(0.5)


def test_two_workers_give_the_same_dataset(reference, client, tmp_path):
    r = _run(tmp_path / "out", client=client)
    assert r.stats["n_workers"] == 2 and r.stats["chunks_computed"] == 12
    _same(r.dataset, reference)


def test_a_worker_killed_mid_sweep_changes_nothing(reference, client, tmp_path):
    _wait_for_workers(client, 2)
    pids = client.run(os.getpid)  # {worker address: pid}
    killed = []

    def kill_one(g, j):  # after the first chunk persists, SIGKILL a worker (its chunks move)
        if not killed:
            victim = sorted(pids.values())[0]
            os.kill(victim, signal.SIGKILL)
            killed.append(victim)

    r = _run(tmp_path / "out", client=client, on_chunk=kill_one)
    assert killed and r.stats["chunks_computed"] == 12
    _same(r.dataset, reference)


def test_interrupted_on_two_workers_resumes_on_one(reference, tmp_path):
    """Two workers of the sweep's own LocalCluster (``workers=2``, started while the study is
    checked), interrupted after three chunks; the cluster closes and one worker finishes."""
    out = tmp_path / "out"

    class Stop(Exception):
        pass

    def stop_after_three(g, j, seen=[]):  # noqa: B006  (a counter across calls)
        seen.append((g, j))
        if len(seen) == 3:
            raise Stop

    with pytest.raises(Stop):
        _run(out, workers=2, on_chunk=stop_after_three)
    n_kept = len(list((out / "chunks").glob("*.npz")))
    assert 3 <= n_kept < 12
    r = _run(out, workers=1, resume=True)
    assert r.stats["chunks_reused"] == n_kept and r.stats["chunks_computed"] == 12 - n_kept
    _same(r.dataset, reference)


def _cli_sweep(tmp_path, *flags):
    study = tmp_path / "study.toml"
    study.write_text(STUDY)
    assert cli.main(["sweep", str(study), "--out", str(tmp_path / "out"), *flags]) == 0
    with xr.open_dataset(tmp_path / "out" / "results.nc") as ds:
        return ds.load()


def test_cli_scheduler_option(reference, client, tmp_path):
    _same(_cli_sweep(tmp_path, "--scheduler", client.scheduler.address), reference, attrs=False)


def test_cli_unreachable_scheduler_is_a_clear_error(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cli, "SCHEDULER_TIMEOUT_S", 1)  # the answer is the same, only sooner
    study = tmp_path / "study.toml"
    study.write_text(STUDY)
    port = _free_port()  # nothing listens there
    assert cli.main(["sweep", str(study), "--out", str(tmp_path / "out"),
                     "--scheduler", f"tcp://127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--scheduler" in err[0]
    assert not (tmp_path / "out").exists()


@pytest.mark.full
@pytest.mark.parametrize("n", [3, 4])  # 4 on 2 cores: oversubscribed, still the same numbers
def test_cli_local_workers(reference, tmp_path, n):
    _same(_cli_sweep(tmp_path, "--workers", str(n)), reference, attrs=False)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.full
def test_cli_on_a_separately_started_scheduler_and_worker(reference, tmp_path):
    """`dask scheduler` and `dask worker` as a user starts them, then `jaxnav sweep --scheduler`."""
    from distributed import Client

    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = os.environ | parallel._worker_env()
    procs = [subprocess.Popen(
        [sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
         "--port", str(port), "--dashboard-address", ":0"], env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "distributed.cli.dask_worker", addr, "--nworkers", "1",
             "--nthreads", "1", "--no-dashboard"], env=env, cwd=tmp_path,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        with Client(addr, timeout="60s") as c:
            _wait_for_workers(c, 1)
        ds = _cli_sweep(tmp_path, "--scheduler", addr)
    finally:
        for p in procs[::-1]:
            p.terminate()
            p.wait(timeout=30)
    _same(ds, reference, attrs=False)
