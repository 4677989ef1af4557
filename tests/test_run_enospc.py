"""A full disk and killed writers lose nothing that was flushed (issue 37): the run file's
journal (rig.loop.journal), ENOSPC injected at random writes of a 3-trial simulated run, SIGKILL
of every process of a run, and a real tmpfs that fills at once."""

from __future__ import annotations

import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from typer.testing import CliRunner

from rig.cli import app
from rig.errors import InputError
from rig.inputs import config
from rig.loop import journal
from rig.recordings import runfile
from rig.sim_backend.rig_process import DRIVE_LOG_ENV, read_drive_log

SHORT = "name: p\nsegments:\n  - {hold: 0.05}\n  - {ramp: 0.2, to: 10}\n  - {ramp: 0.2, to: 0}\n"
# (a drive answer timeout of 5 s: on a loaded machine the simulated drive's thread answered
# the enable's status query later than the default 0.5 s, and the run never started)
RIG = {"name": "enospc", "backend": "sim",
       "drive": {"port": "sim", "poll_period_s": 0.01, "timeout_s": 5.0},
       "sim": {"realtime": True, "effects": []}, "loop": {"rest_s": 0.05},
       "channels": {"strain_gauge": {"enabled": False}}, "acquisition": {"buffer_s": 10.0}}
FULL = re.compile(r"at sample (\d+); the (\d+) samples flushed before it are kept")


def _samples(run: runfile.Run) -> np.ndarray:
    parts = [t.channels["sample"] for t in run.trials if "sample" in t.channels]
    return np.concatenate(parts) if parts else np.zeros(0)


# ---- the journal itself (fast) ----
def _small_journal(tmp: Path) -> Path:
    run = tmp / "r.h5"
    jw = journal.JournalWriter.create(run)
    jw.begin(run, "measured", {"format": "rig-run", "format_version": 1, "kind": "measured",
                               "status": "running", "n_trials": np.int64(0)},
             {"profile": {"name": "p"}, "note": "text"})
    jw.trial(0, {"t0": 0.1})
    for i in range(3):
        t = np.arange(i * 10, i * 10 + 10) / 2000
        jw.append(0, "channels", {"time": t, "sample": np.arange(i * 10, i * 10 + 10.0),
                                  "pair": np.ones((10, 2))},
                  {"time": "s", "sample": "1", "pair": "N"}, {"time": "the time"})
    jw.close()
    return run


def test_the_journal_rebuilds_the_run_file(tmp_path: Path) -> None:
    run = _small_journal(tmp_path)
    rec = journal.recover(run)
    assert rec.samples == 30 and rec.status == journal.DIED and not rec.torn
    r = runfile.read(run)
    assert r.status == journal.DIED and r.metadata["profile"] == {"name": "p"}
    assert r.metadata["note"] == "text"
    tr = r.trials[0]
    assert np.array_equal(tr.channels["sample"], np.arange(30.0))
    assert tr.units["time"] == "s" and tr.channels["pair"].shape == (30, 2)
    assert tr.attrs["t0"] == 0.1 and tr.attrs["status"] == journal.DIED
    assert not journal.journal_path(run).exists()


def test_a_journal_being_written_is_not_recovered(tmp_path: Path) -> None:
    run = _small_journal(tmp_path)
    live = journal.JournalWriter.append_to(run)  # a run still writing it (holds its lock)
    try:
        with pytest.raises(InputError, match="a run is still writing it"):
            journal.recover(run)
        with pytest.raises(InputError, match="a run is still writing it"):
            journal.JournalWriter.append_to(run)
    finally:
        live.close()
    assert journal.recover(run).samples == 30  # its writer gone: recovered


@pytest.mark.parametrize("cut", [1, 7, 19, 40, 101])
def test_a_record_cut_short_is_dropped_and_every_whole_one_kept(tmp_path: Path,
                                                                cut: int) -> None:
    run = _small_journal(tmp_path)
    jpath = journal.journal_path(run)
    whole = journal.scan(jpath)
    data = jpath.read_bytes()
    jpath.write_bytes(data[:len(data) - cut])  # the last write reached the disk in part
    sc = journal.scan(jpath)
    assert sc.torn and len(sc.records) == len(whole.records) - 1
    # a damaged byte inside the last record: its checksum fails, the records before stay
    damaged = bytearray(data)
    damaged[-3] ^= 0xFF
    jpath.write_bytes(bytes(damaged))
    assert len(journal.scan(jpath).records) == len(whole.records) - 1
    jpath.write_bytes(data[:len(data) - cut])
    # the run's process adds its records after the cut: they are kept
    jw = journal.JournalWriter.append_to(run)
    jw.close_record("aborted: disk full (test)")
    jw.close()
    rec = journal.recover(run)
    assert rec.samples == 20 and rec.status == "aborted: disk full (test)"
    assert np.array_equal(runfile.read(run).trials[0].channels["sample"], np.arange(20.0))


def test_rig_recover_says_one_line_and_refuses_bad_input(tmp_path: Path) -> None:
    runner = CliRunner()
    run = _small_journal(tmp_path)
    run.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)  # a run file left unreadable
    info = runner.invoke(app, ["info", str(run)])
    assert info.exit_code == 2 and f"`rig recover {run}` rebuilds it" in info.output
    res = runner.invoke(app, ["recover", str(run)])
    assert res.exit_code == 0, res.output
    assert res.output.strip() == (f"recovered {run}: 1 trials, 30 samples, status "
                                  f"{journal.DIED}")
    again = runner.invoke(app, ["recover", str(run)])  # the journal is gone
    assert again.exit_code == 2 and "no journal" in again.output
    assert len(again.output.strip().splitlines()) == 1
    folder = runner.invoke(app, ["recover", str(tmp_path)])
    assert folder.exit_code == 2 and "is a folder" in folder.output
    (tmp_path / "x.h5.journal").write_bytes(b"not a journal at all")
    bad = runner.invoke(app, ["recover", str(tmp_path / "x.h5")])
    assert bad.exit_code == 2 and "not a rig run-file journal" in bad.output
    mine = tmp_path / "mine.h5"
    mine.write_bytes(b"keep")
    (tmp_path / "b").mkdir()
    run2 = _small_journal(tmp_path / "b")
    kept = runner.invoke(app, ["recover", str(run2), "--out", str(mine)])
    assert kept.exit_code == 2 and "--force" in kept.output and mine.read_bytes() == b"keep"


def test_the_final_status_survives_a_disk_with_no_byte_left(tmpfs) -> None:
    """A disk that fills at once can leave no room to append the run's final status to its
    journal (CI, once: the recovered file said "the run's writer died" instead of "disk
    full"): the status goes into the reserve written beside the journal at its start, and
    the recovery takes it from there. Both files go once the run file is rebuilt."""
    small = tmpfs("size=1m")
    run = small / "run.h5"
    jw = journal.JournalWriter.create(run)
    assert journal.end_path(run).stat().st_size == journal.END_RESERVE_BYTES
    jw.begin(run, "measured", {}, {})
    data = {"time": np.arange(100) / 2000.0, "sample": np.arange(100.0)}
    jw.append(0, "channels", data, {"time": "s", "sample": "1"}, {})
    jw.sync()
    # another program takes every byte left
    with open(small / "filler", "wb", buffering=0) as f, pytest.raises(OSError):
        while True:
            f.write(b"\0" * 4096)
    with pytest.raises(OSError):  # the journal cannot take another page
        for _ in range(64):
            jw.append(0, "channels", data, {"time": "s", "sample": "1"}, {})
    assert jw.broken is not None
    status = "aborted: disk full at sample 100; the 100 samples flushed before it are kept"
    jw.close_record(status)  # no OSError: the reserve took it
    jw.close()
    (small / "filler").unlink()
    rec = journal.recover(run)
    assert rec.status == status and runfile.read(run).status == status
    assert not journal.journal_path(run).exists() and not journal.end_path(run).exists()


def test_a_status_neither_file_takes_is_an_os_error(tmp_path: Path) -> None:
    run = tmp_path / "run.h5"
    jw = journal.JournalWriter.create(run)
    jw.broken = OSError(28, "No space left on device")
    journal.end_path(run).unlink()  # (no reserve: say so)
    with pytest.raises(OSError):
        jw.close_record("aborted: disk full")
    jw.close()


# ---- ENOSPC through the writer's seam at random moments of a 3-trial run ----
def _cfg(tmp: Path) -> config.RigConfig:
    return config.from_mapping({**RIG, "data_folder": str(tmp)})


def _drive_safe(log_path: Path) -> None:
    """The simulated motor's last demand 0 V, and the drive disabled -- or never enabled
    (a run that failed before it enabled the drive: no EN command on the serial line)."""
    log = read_drive_log(str(log_path))
    volts = [e for e in log if "volts" in e]
    states = [e for e in log if "enabled" in e and "volts" not in e]
    assert volts and volts[-1]["volts"] == 0.0, log[-5:]
    enabled = any(e.get("command") == "EN" for e in log)
    assert not enabled or states[-1]["enabled"] is False, log[-5:]


@pytest.mark.slow
def test_enospc_at_20_random_writes_of_a_3_trial_run(tmp_path: Path, monkeypatch) -> None:
    from rig.services import run as svc

    cfg = _cfg(tmp_path)
    rate = cfg.rates.acquisition_hz
    # a flush every flush_period_s or flush_period_s of samples, whichever first; plus one
    # read (0.02 s; up to 0.47 s seen when the 2 test cores were shared by 4 agents' tests:
    # the acquisition process starved, the samples waiting in the card buffer)
    lost_max = (cfg.acquisition.flush_period_s + 0.5) * rate
    prof = tmp_path / "p.yaml"
    prof.write_text(SHORT)
    rng = random.Random(37)
    # ~75 writes go through the acquisition's seam in this run (journal records, HDF5
    # appends and flushes), 2 through the run's (adding the events found)
    moments = [("acquisition", rng.randint(1, 75)) for _ in range(17)]
    moments += [("run", 1), ("run", 2), ("acquisition", 2)]
    worst = 0.0
    lost: list[float] = []
    for who, n in moments:
        out = tmp_path / f"{who}-{n}.h5"
        log = tmp_path / f"{who}-{n}.log"
        monkeypatch.setenv(journal.FAULT_ENV, f"{who}:{n}")
        monkeypatch.setenv(DRIVE_LOG_ENV, str(log))
        if out.exists():
            continue  # (the same moment drawn twice)
        rep = svc.run(prof, cfg, trials=3, out=out)
        _drive_safe(log)
        if rep.complete:  # the chosen write came after the run's last one
            assert who == "acquisition" and n > 60, (who, n)
            continue
        assert rep.status.startswith("aborted: disk full") and "\n" not in rep.status, rep.status
        if journal.journal_path(out).exists():  # (only when the disk stays full)
            journal.recover(out)
        run = runfile.read(out)  # the file, readable
        assert run.status == rep.status
        s = _samples(run)
        assert s.size == 0 or (s[0] == 0 and np.all(np.diff(s) == 1)), (who, n)
        m = FULL.search(rep.status)
        if who == "run":  # the run had ended: every sample kept
            assert s.size >= 3 * run.trials[0].channels["sample"].size > 3000
            assert [t.attrs["status"] for t in run.trials] == ["complete"] * 3
            continue
        assert m, rep.status
        at, kept = int(m[1]), int(m[2])
        assert s.size == kept, (who, n, s.size, kept)  # every flushed sample ...
        worst = max(worst, (at - kept) / rate)
        lost.append((at - kept) / rate)
        assert at - kept <= lost_max, (who, n, at, kept)  # ... and at most a flush's worth lost
        for tr in run.trials:  # the loop's records: continuous too (but for missed ticks)
            tick = tr.commands.get("tick", np.zeros(0))
            missed = tr.commands.get("missed", np.zeros(0))
            gaps = np.flatnonzero(np.diff(tick) != 1 + missed[1:])
            assert not gaps.size, (who, n, tick[gaps[:3]], tick[gaps[:3] + 1], rep.status)
    print(f"ENOSPC at {len(moments)} moments: at most {worst:.3f} s of samples not flushed "
          f"(median {np.median(lost):.3f} s)")


# ---- SIGKILL of every process of a run; a real tmpfs filled at once (subprocesses) ----
def _start(tmp: Path, out: Path, trials: int = 3) -> subprocess.Popen[str]:
    (tmp / "rig.yaml").write_text(yaml.safe_dump({**RIG, "data_folder": str(tmp)}))
    (tmp / "p.yaml").write_text(SHORT)
    env = {**os.environ, DRIVE_LOG_ENV: str(tmp / "drive.log")}
    return subprocess.Popen([sys.executable, "-m", "rig", "run", str(tmp / "p.yaml"), "--rig",
                             str(tmp / "rig.yaml"), "--trials", str(trials), "-o", str(out)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)


def _group_shm(pgid: int) -> set[str]:
    names: set[str] = set()
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if os.getpgid(int(d.name)) != pgid:
                continue
            maps = (d / "maps").read_text()
        except (OSError, ProcessLookupError):
            continue
        names |= {ln.split()[-1] for ln in maps.splitlines() if "/dev/shm/" in ln}
    return names


def _wait_running(tmp: Path, proc: subprocess.Popen[str], timeout: float = 240.0) -> None:
    end = time.monotonic() + timeout
    log = tmp / "drive.log"
    while time.monotonic() < end:
        assert proc.poll() is None, proc.communicate()
        if log.exists() and any(e.get("volts", 0) > 0.2 for e in read_drive_log(str(log))):
            return
        time.sleep(0.02)
    raise AssertionError("the run never pushed")


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="reads /proc (Linux)")
def test_sigkill_of_every_process_keeps_every_flushed_sample(tmp_path: Path) -> None:
    rng = random.Random(3737)
    for i in range(3):
        tmp = tmp_path / f"k{i}"
        tmp.mkdir()
        out = tmp / "run.h5"
        proc = _start(tmp, out)
        _wait_running(tmp, proc)
        time.sleep(rng.uniform(0.0, 1.5))
        shm = _group_shm(proc.pid)
        os.killpg(proc.pid, signal.SIGKILL)  # the run, the plant, the acquisition, at once
        proc.communicate(timeout=30)
        time.sleep(0.2)
        for n in shm:  # (nobody is left to remove the simulator's shared blocks)
            Path(n.removesuffix(" (deleted)")).unlink(missing_ok=True)
        in_h5 = 0
        try:
            with h5py.File(out, "r") as f:  # what the HDF5 file itself kept, if readable
                in_h5 = sum(int(f[g]["channels/sample"].shape[0]) for g in f
                            if g.startswith("trial_") and "channels/sample" in f[g])
        except (OSError, KeyError):
            pass
        res = subprocess.run([sys.executable, "-m", "rig", "recover", str(out)],
                             capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stderr
        run = runfile.read(out)
        s = _samples(run)
        assert run.status == journal.DIED
        assert s.size >= in_h5 and s.size > 0 and s[0] == 0 and np.all(np.diff(s) == 1)
        print(f"SIGKILL {i}: {s.size} samples recovered (the HDF5 file held {in_h5})")


@pytest.fixture
def tiny_fs(tmpfs) -> Path:
    """A 6 MB tmpfs mounted for the test (root only)."""
    return tmpfs("size=6m")


def test_a_tmpfs_filled_at_once_mid_run(tmp_path: Path, tiny_fs: Path) -> None:
    out = tiny_fs / "run.h5"
    proc = _start(tmp_path, out, trials=3)
    _wait_running(tmp_path, proc)
    time.sleep(0.3)
    filler = tiny_fs / "filler"
    with open(filler, "wb") as f:  # another program takes every byte left, at once
        try:
            while True:
                f.write(b"\0" * 65536)
        except OSError:
            pass
    out_text, err_text = proc.communicate(timeout=60)
    assert proc.returncode == 1, (out_text, err_text)
    assert err_text.strip().splitlines() == [err_text.strip().splitlines()[-1]], err_text
    assert err_text.strip().startswith("ABORTED: disk full"), err_text
    assert "rig recover" in err_text and "Traceback" not in out_text + err_text
    print(err_text.strip())
    _drive_safe(tmp_path / "drive.log")
    filler.unlink()  # space freed: the run file is rebuilt from its journal
    res = subprocess.run([sys.executable, "-m", "rig", "recover", str(out)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    run = runfile.read(out)
    s = _samples(run)
    assert run.status.startswith("aborted: disk full"), run.status
    # every sample flushed before the fill is kept (how many were flushed by then depends
    # on the machine's load: the fill comes 0.3 s after the loop started)
    flushed = int(FULL.search(err_text).group(2))
    assert s.size >= flushed > 0 and s[0] == 0 and np.all(np.diff(s) == 1), (s.size, flushed)
    print(f"tmpfs filled at once: {s.size} samples recovered; {run.status}")


_ECHO_SCRIPT = r"""
import sys, h5py, numpy as np
from rig.loop import journal
if sys.argv[2] == "quiet":
    journal.DiskFullEchoes().install()
f = h5py.File(sys.argv[1], "w", libver="latest")
f.create_dataset("x", shape=(0,), maxshape=(None,), chunks=(4096,), dtype="f8")
try:
    for i in range(10000):
        d = f["x"]
        d.resize((d.shape[0] + 4096,))
        d[-4096:] = np.random.default_rng(i).random(4096)
        f.flush()
        g = f.create_group(f"g{i}")
        g.attrs["a"] = np.arange(100)
        del g, d
except Exception as exc:
    print("disk full" if journal.is_disk_full(exc) else repr(exc))
class Other:
    def __del__(self):
        raise ValueError("not the disk")
Other()
"""


@pytest.mark.interpreter
@pytest.mark.parametrize("mode", ["loud", "quiet"])
def test_hdf5_frees_after_a_full_disk_do_not_reach_stderr(tmp_path: Path, tmpfs,
                                                         mode: str) -> None:
    """After ENOSPC h5py's objects fail again as they are freed (an "Exception ignored"
    traceback each, seen on stderr of `rig run` when a tmpfs filled at once): the
    acquisition counts them instead (rig.loop.journal.DiskFullEchoes); other errors still print."""
    small = tmpfs("size=2m")
    script = tmp_path / "echo.py"
    script.write_text(_ECHO_SCRIPT)
    res = subprocess.run([sys.executable, str(script), str(small / "a.h5"), mode],
                         capture_output=True, text=True, timeout=120)
    assert res.stdout.strip() == "disk full", (res.stdout, res.stderr)
    assert "ValueError: not the disk" in res.stderr
    echoes = res.stderr.count("errno = 28")
    if mode == "loud":  # the echoes exist (else the quiet case would prove nothing)
        assert echoes >= 1, res.stderr
    else:
        assert echoes == 0, res.stderr
