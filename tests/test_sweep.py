"""rig sweep and the executor seam: a real Dask scheduler and two worker processes on the
loopback interface, SIGKILL of a worker mid-sweep, resume, Sobol indices (Ishigami's
analytic values; an action parameter that cannot matter)."""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import cloudpickle
import h5py
import numpy as np
import pytest

from rig.analysis import sweep as sw
from rig.analysis.executor import DaskExecutor, LocalExecutor, executor_for, run_all

distributed = pytest.importorskip("distributed")

# the workers are fresh processes: ship this module's blow functions by value
cloudpickle.register_pickle_by_value(sys.modules[__name__])

REPO = Path(__file__).resolve().parents[1]
ISHIGAMI_S1 = (0.3139, 0.4424, 0.0)   # a = 7, b = 0.1
ISHIGAMI_ST = (0.5576, 0.4424, 0.2437)


@pytest.fixture(scope="module")
def cluster():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=":0", worker_dashboard_address=None) as lc, \
            Client(lc) as client:
        yield lc, client


def counted_ishigami(shared, x):
    """Ishigami that appends one line per evaluation to shared['log'] (and may dawdle)."""
    with open(shared["log"], "a") as f:
        f.write(f"{os.getpid()} {x[0]!r} {x[1]!r} {x[2]!r}\n")
    if shared.get("sleep"):
        time.sleep(shared["sleep"])
    return sw.ishigami((7.0, 0.1), x)


def counted_study(log: Path, sleep: float = 0.0) -> sw.Study:
    return sw.Study(counted_ishigami, [sw.Metric("y", "1", "Ishigami")],
                    {"log": str(log), "sleep": sleep}, {"function": "ishigami"})


def evaluations(log: Path) -> int:
    return len(log.read_text().splitlines()) if log.exists() else 0


def test_ishigami_sobol_indices_match_the_analytic_values(tmp_path):
    out = tmp_path / "ish.h5"
    res = sw.run_sweep(sw.ishigami_study(), sw.ishigami_axes(), "sobol", 2048, out,
                       LocalExecutor(1))
    assert res.rows == 2048 * 5 and res.computed == res.rows
    s = sw.sensitivity(out)
    for j in range(3):
        assert s.S1[0, j] == pytest.approx(ISHIGAMI_S1[j], abs=max(0.03, 1.5 * s.S1_conf[0, j]))
        assert s.ST[0, j] == pytest.approx(ISHIGAMI_ST[j], abs=max(0.03, 1.5 * s.ST_conf[0, j]))
    # and it reads the table, not a constant: with b = 0, x3 leaves the function
    out0 = tmp_path / "ish0.h5"
    sw.run_sweep(sw.ishigami_study(b=0.0), sw.ishigami_axes(), "sobol", 1024, out0,
                 LocalExecutor(1))
    s0 = sw.sensitivity(out0)
    assert s0.ST[0, 2] == 0.0 and s0.S1[0, 2] == 0.0


def test_executor_maps_each_item_once_locally_and_on_the_cluster(cluster):
    _, client = cluster
    items = list(range(40))
    with LocalExecutor(2) as lx:
        local = run_all(lx, _square_plus, items, shared=3)
    with DaskExecutor(client=client) as ex:
        seen = [i for i, _ in ex.map(_square_plus, items, shared=3)]
        remote = run_all(ex, _square_plus, items, shared=3)
    assert sorted(seen) == items
    assert local == remote == [i * i + 3 for i in items]


def _square_plus(shared, x):
    return x * x + shared


def _pid_plus(shared, x):
    return os.getpid(), x + shared[0]


def test_local_executor_forks_once_per_shared_object():
    """Maps with the same shared object (a fit's Jacobian columns) reuse the forked
    workers; another shared object gets fresh workers that see it."""
    s1, s2 = [10], [20]
    with LocalExecutor(2) as ex:
        a = run_all(ex, _pid_plus, range(6), shared=s1)
        b = run_all(ex, _pid_plus, range(6), shared=s1)
        c = run_all(ex, _pid_plus, range(6), shared=s2)
    pa, pb, pc = ({p for p, _ in r} for r in (a, b, c))
    assert [v for _, v in a] == [v for _, v in b] == [10 + i for i in range(6)]
    assert [v for _, v in c] == [20 + i for i in range(6)]
    # the same two forked workers for a and b (a worker may take no task of a map on a
    # busy machine: b's may be the one a's did not see, so not b <= a), fresh ones for c
    assert os.getpid() not in pa | pb and len(pa | pb) <= 2 and not (pc & (pa | pb))


def test_dask_sweep_equals_local_processes(cluster, tmp_path):
    _, client = cluster
    axes = sw.ishigami_axes()
    a, b = tmp_path / "local.h5", tmp_path / "dask.h5"
    with LocalExecutor(2) as lx:
        sw.run_sweep(sw.ishigami_study(), axes, "sobol", 64, a, lx)
    with DaskExecutor(client=client) as ex:
        sw.run_sweep(sw.ishigami_study(), axes, "sobol", 64, b, ex)
    c = tmp_path / "dask-batched.h5"
    with DaskExecutor(client=client) as ex:
        res = sw.run_sweep(sw.ishigami_study(), axes, "sobol", 64, c, ex, batch=7)
    assert res.computed == 64 * 5
    ta, tb, tc = sw.load_table(a), sw.load_table(b), sw.load_table(c)
    assert set(ta) == set(tb) == set(tc)
    for k in ta:
        np.testing.assert_array_equal(ta[k], tb[k])
        np.testing.assert_array_equal(ta[k], tc[k])
    assert tb["done"].all()


def test_worker_killed_mid_sweep_loses_no_result(cluster, tmp_path):
    lc, client = cluster
    log = tmp_path / "evals.log"
    out = tmp_path / "killed.h5"
    axes = sw.ishigami_axes()
    pids = list(client.run(os.getpid).values())
    assert len(pids) == 2
    arrived: list[int] = []
    killed: list[int] = []

    def progress(done: int, total: int, eta: float) -> None:
        arrived.append(done)
        if done == 20 and not killed:  # tasks are running on both workers now
            os.kill(pids[0], signal.SIGKILL)
            killed.append(pids[0])

    with DaskExecutor(client=client, retries=3) as ex:
        res = sw.run_sweep(counted_study(log, sleep=0.02), axes, "sobol", 32, out, ex,
                           progress=progress)
    assert killed
    rows = 32 * 5
    assert res.computed == rows and arrived == list(range(1, rows + 1))
    t = sw.load_table(out)
    assert t["done"].all()
    X = np.column_stack([t["x1"], t["x2"], t["x3"]])
    expect = np.array([sw.ishigami(None, x)[0] for x in X])
    np.testing.assert_array_equal(t["y"], expect)
    # the dead worker's tasks ran again elsewhere: at least every row, some perhaps twice
    assert evaluations(log) >= rows
    client.wait_for_workers(2, timeout=60)  # the nanny restarts it for the next tests


def test_resumed_sweep_recomputes_nothing_it_has(tmp_path):
    log = tmp_path / "evals.log"
    out = tmp_path / "resume.h5"
    axes = sw.ishigami_axes()

    class Stop(Exception):
        pass

    def stop_at_25(done: int, total: int, eta: float) -> None:
        assert math.isfinite(eta) and eta >= 0
        if done == 25:
            raise Stop

    with pytest.raises(Stop):
        sw.run_sweep(counted_study(log), axes, "sobol", 16, out, LocalExecutor(1),
                     progress=stop_at_25)
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "interrupted"
        assert int(f["table/done"][:].sum()) == 25
    assert evaluations(log) == 25
    with pytest.raises(ValueError, match="exists"):
        sw.run_sweep(counted_study(log), axes, "sobol", 16, out, LocalExecutor(1))
    with pytest.raises(ValueError, match="different sweep"):
        sw.run_sweep(counted_study(log), axes, "sobol", 32, out, LocalExecutor(1), resume=True)
    with LocalExecutor(2) as lx:
        res = sw.run_sweep(counted_study(log), axes, "sobol", 16, out, lx, resume=True)
    assert (res.reused, res.computed) == (25, 16 * 5 - 25)
    assert evaluations(log) == 16 * 5
    res = sw.run_sweep(counted_study(log), axes, "sobol", 16, out, LocalExecutor(1),
                       resume=True)
    assert res.computed == 0 and evaluations(log) == 16 * 5
    fresh = tmp_path / "fresh.h5"
    sw.run_sweep(sw.ishigami_study(), axes, "sobol", 16, fresh, LocalExecutor(1))
    np.testing.assert_array_equal(sw.load_table(out)["y"], sw.load_table(fresh)["y"])


def test_designs():
    axes = [sw.Axis.parse("a=0:1"), sw.Axis.parse("b=-2:2")]
    g = sw.make_design("grid", axes, 3)
    assert g.shape == (9, 2) and sorted(set(g[:, 1])) == [-2.0, 0.0, 2.0]
    lhs = sw.make_design("lhs", axes, 10)
    # one sample in each tenth of each axis
    assert sorted(np.floor(lhs[:, 0] * 10).astype(int)) == list(range(10))
    assert sw.make_design("sobol", axes, 8).shape == (8 * 4, 2)
    for bad in ("a", "a=1:0", "a=x:1", "=0:1"):
        with pytest.raises(ValueError, match="param"):
            sw.Axis.parse(bad)
    with pytest.raises(ValueError, match="power of 2"):
        sw.make_design("sobol", axes, 12)
    with pytest.raises(ValueError, match="design"):
        sw.make_design("random", axes, 8)


@pytest.mark.slow
def test_executor_for_reads_the_environment(monkeypatch):
    monkeypatch.delenv("RIG_SCHEDULER", raising=False)
    ex = executor_for(jobs=2)
    assert isinstance(ex, LocalExecutor) and ex.workers == 2
    monkeypatch.setenv("RIG_SCHEDULER", "tcp://127.0.0.1:9")  # nothing listens on port 9
    with pytest.raises(ValueError, match="scheduler: cannot reach tcp://127.0.0.1:9"):
        executor_for(jobs=2)


# ---- the action ---------------------------------------------------------------------------
PROFILE = REPO / "profiles" / "forte.yaml"


def _rig(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rig", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=900)


def _doc_commands() -> list[list[str]]:
    """The worked example's commands in docs/sweep.md (lines starting `rig sweep`)."""
    text = (REPO / "docs" / "sweep.md").read_text()
    block = text.split("<!-- worked-sweep -->")[1]
    cmds = []
    for line in block.splitlines():
        line = line.strip()
        if line.startswith("rig sweep"):
            cmds.append(line.split()[1:])
    return cmds


@pytest.mark.slow
def test_worked_sweep_from_the_docs_locally_and_on_the_cluster(cluster, tmp_path):
    """The docs' worked sweep runs as shown, on local processes and through --scheduler;
    both give the same table; hammer_shank_beam.density (the rigid model has no flexible
    shank, so nothing reads it) gets Sobol indices of exactly zero."""
    lc, _ = cluster
    cmds = _doc_commands()
    assert len(cmds) == 2 and "--scheduler" not in cmds[0]
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles" / "forte.yaml").write_bytes(PROFILE.read_bytes())
    r = _rig(*cmds[0], cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert re.search(r"sweep: \d+/\d+ blows, ETA \d+ s", r.stderr)
    out = tmp_path / "sweep.h5"
    assert "wrote sweep.h5" in r.stdout and (tmp_path / "sweep.html").exists()
    # the cluster run: the second command's scheduler address is the test cluster's
    second = [lc.scheduler_address if a == "tcp://lab1:8786" else a for a in cmds[1]]
    r2 = _rig(*second, cwd=tmp_path)
    assert r2.returncode == 0, r2.stderr
    a, b = sw.load_table(out), sw.load_table(tmp_path / "sweep-cluster.h5")
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert a["done"].all()
    assert np.all(np.isfinite(a["strike_s"])) and np.all(a["hammer_speed_m_s"] > 1.0)
    # the dummy axis: changing the density changes no metric at all (an independent check)
    params = ["contacts.12.D", "springs.jack_torque", "hammer_shank_beam.density"]
    with h5py.File(out, "r") as f:
        assert list(f.attrs["params"]) == params
        g = f["sensitivity"]
        S1, ST = g["S1"][:], g["ST"][:]
        S1c, STc = g["S1_conf"][:], g["ST_conf"][:]
        metrics = list(f.attrs["metrics"])
        assert f["table/strike_s"].attrs["units"] == "s"
    j = params.index("hammer_shank_beam.density")
    for i, m in enumerate(metrics):
        if m == "shank_strain_peak":
            assert np.all(np.isnan(ST[i]))  # no strain channel in the rigid model
            continue
        assert S1[i, j] == 0.0 and ST[i, j] == 0.0 and S1c[i, j] == 0.0 and STc[i, j] == 0.0
    # the string felt's damping moves the string contact time
    i = metrics.index("string_contact_s")
    assert ST[i, params.index("contacts.12.D")] > 0.05
    assert "hammer_shank_beam.density" in r.stdout


def test_the_density_axis_is_truly_inert(tmp_path):
    """Independent of SALib: two blows at the density's ends give identical metrics."""
    from rig.inputs import profiles
    from rig.model.action import ActionModel

    model = ActionModel()
    axes = [sw.Axis.parse("hammer_shank_beam.density=300:900")]
    study = sw.action_study(model, profiles.load(PROFILE), axes, duration=0.09)
    lo = study.fn(study.shared, np.array([300.0]))
    hi = study.fn(study.shared, np.array([900.0]))
    assert np.all(np.isfinite(lo[:-1]))
    np.testing.assert_array_equal(lo, hi)


@pytest.mark.slow
def test_sweep_cli_refuses_bad_input_and_existing_out(tmp_path):
    out = tmp_path / "s.h5"
    out.write_bytes(b"precious")
    base = ["sweep", "--profile", str(PROFILE), "--param", "contacts.12.D=0.5:1.0",
            "--out", str(out), "--samples", "2", "--jobs", "1"]
    r = _rig(*base, cwd=tmp_path)
    assert r.returncode == 2 and "out:" in r.stderr and "--force" in r.stderr
    assert out.read_bytes() == b"precious"
    r = _rig(*base[:-4], "--samples", "3", "--out", str(tmp_path / "n.h5"), cwd=tmp_path)
    assert r.returncode == 2 and "power of 2" in r.stderr
    assert not (tmp_path / "n.h5").exists()
    r = _rig("sweep", "--profile", str(PROFILE), "--param", "contacts.99.D=0:1", "--out",
             str(tmp_path / "m.h5"), "--samples", "2", cwd=tmp_path)
    assert r.returncode == 2 and "contacts.99.D" in r.stderr
    assert not (tmp_path / "m.h5").exists()


@pytest.mark.slow
def test_interrupted_cli_sweep_keeps_its_blows_and_resumes(tmp_path):
    """Ctrl-C (SIGINT) mid-sweep: exit 130, the file readable and marked interrupted with
    every finished blow; --resume computes only the rest and the table is complete."""
    out = tmp_path / "int.h5"
    args = [sys.executable, "-m", "rig", "sweep", "--profile", str(PROFILE), "--param",
            "contacts.12.D=0.4:1.2", "--param", "springs.jack_torque=0.0035:0.005",
            "--design", "lhs", "--samples", "400", "--duration", "0.09", "--jobs", "1",
            "--out", str(out)]
    proc = subprocess.Popen(args, cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        line = ""
        while "sweep:" not in line:  # blows are being written
            line = proc.stderr.readline()
            assert line or proc.poll() is None, "the sweep ended before it could be stopped"
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, stderr
    assert "--resume" in stderr
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "interrupted"
        kept = int(f["table/done"][:].sum())
        assert np.all(np.isfinite(f["table/strike_s"][:][f["table/done"][:] == 1]))
    assert 0 < kept < 400
    r = _rig(*args[3:], "--resume", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert f"400 blows: {400 - kept} computed, {kept} already in" in r.stdout
    with h5py.File(out, "r") as f:
        assert f.attrs["status"] == "complete" and f["table/done"][:].all()


@pytest.mark.slow
def test_diagnose_and_fit_on_the_cluster_equal_local_processes(cluster, tmp_path):
    # issue 17: the same executor seam runs diagnose's candidate fits and fit's Jacobian
    # columns on a real 2-worker cluster; the results are those of local processes (the
    # worker-lost retry is the seam's, tested on the sweep above)
    from typer.testing import CliRunner

    from rig.analysis import diagnose as dg
    from rig.analysis import fit as ft
    from rig.analysis import measurement as ms
    from rig.analysis import synth
    from rig.cli import app
    from rig.inputs import profiles
    from rig.model.action import ActionModel

    lc, client = cluster
    run = tmp_path / "run.h5"
    truth = ActionModel(effects=[{"compliant_string": {"stiffness": 2e4}}])
    synth.synth(truth, [profiles.load(PROFILE)], run, seed=5, duration=0.08, trials=2)
    meas = ms.load(run)
    kw = {"duration": 0.08, "candidates": ["compliant_string", "load_cell_filter",
                                           "felt_hysteresis"], "max_effects": 2}
    with LocalExecutor(2) as lx:
        a = dg.diagnose(ActionModel(), meas, executor=lx, **kw)
    with DaskExecutor(client=client) as dx:
        b = dg.diagnose(ActionModel(), meas, executor=dx, **kw)
    assert a.chosen_names == b.chosen_names == ["compliant_string"], a.report_lines()
    assert a.final is not None and b.final is not None
    for k, v in a.final.values.items():
        assert b.final.values[k] == pytest.approx(v, rel=1e-12)
        assert b.final.sigma[k] == pytest.approx(a.final.sigma[k], rel=1e-9)
    assert [c.removal for c in a.candidates] == pytest.approx([c.removal for c in
                                                               b.candidates], rel=1e-12)

    data = ft.Data.build(meas, duration=0.08)
    model = ActionModel(effects=["compliant_string"])
    specs = ["compliant_string.stiffness", "contacts.12.D"]
    with LocalExecutor(2) as lx:
        fa = ft.fit(model, data, specs, executor=lx, max_nfev=3)
    with DaskExecutor(client=client) as dx:
        fb = ft.fit(model, data, specs, executor=dx, max_nfev=3)
    assert fa.nfev == fb.nfev
    for k, v in fa.values.items():
        assert fb.values[k] == pytest.approx(v, rel=1e-12)
        assert fb.sigma[k] == pytest.approx(fa.sigma[k], rel=1e-12)

    # the commands take the cluster's address
    r = CliRunner().invoke(app, ["diagnose", str(run), "--candidate", "compliant_string",
                                 "--duration", "0.08", "--scheduler", lc.scheduler_address])
    assert r.exit_code == 0, r.output
    assert "missing effect: compliant_string" in r.output
    r = CliRunner().invoke(app, ["fit", str(run), "--param", "compliant_string.stiffness",
                                 "--model", str(_string_model(tmp_path)), "--duration", "0.08",
                                 "--max-nfev", "3", "--scheduler", lc.scheduler_address])
    assert r.exit_code == 0, r.output
    assert "compliant_string.stiffness = " in r.output


def _string_model(tmp: Path) -> Path:
    path = tmp / "string.yaml"
    path.write_text("effects:\n  - compliant_string\n")
    return path
