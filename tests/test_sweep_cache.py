"""A sweep cache that can be trusted: damaged entries are recomputed, lost workers retried, stale work
folders removed, and the sweep's options and folder checked up front, each in one line of ``dsc-fmu sweep``."""

import csv
import hashlib
import io
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import psutil
import pytest

from dsc_fmu.cli import main
from dsc_fmu.scenario import load_scenario
from dsc_fmu.study import cache as sweep_cache
from dsc_fmu.study.cache import CacheEntryError, SweepCache, load_reference, load_trajectory
from dsc_fmu.study.cases import Case, Runner, SweepError
from dsc_fmu.study.execute import LOST_TWICE, execute

SCENARIO = "figure_eight"  # no linearised prediction: the sweeps of these tests stay short
WARNING = "dsc-fmu: warning: "


@pytest.fixture(scope="module")
def fmu_dir(fmu_paths):
    return next(iter(fmu_paths.values())).parent


def sweep(out, fmu_dir, steps="0.005,0.01,0.02", stop_time="1", jobs="1"):
    """``dsc-fmu sweep`` of the figure eight with one order, the hold, no error-controlled runs and no
    refinement; the exit status."""
    return main(["sweep", SCENARIO, "--stop-time", stop_time, "--step-sizes", steps, "--orders", "gauss-seidel",
                 "--couplings", "hold", "--tolerances", "", "--no-refine", "--jobs", jobs, "--out", str(out),
                 "--fmu-dir", str(fmu_dir)])


def records(out):
    """The verified rows of the sweep folder ``out`` by key, and its reference keys."""
    cache = SweepCache(out)
    rows = {path.stem: cache.row(path.stem) for path in sorted(cache.runs.glob("*.json"))}
    return rows, sorted(path.stem for path in cache.references.glob("*.json"))


def without_wall_time(row):
    return json.dumps({k: v for k, v in row.items() if k != "wall_time_s"})


def csv_rows(out):
    return list(csv.DictReader(io.StringIO((out / "sweep.csv").read_text())))


@pytest.fixture(scope="module")
def cached(fmu_dir, tmp_path_factory):
    """A sweep folder with a complete cache (three runs, one reference): copy it, never change it."""
    out = tmp_path_factory.mktemp("cached") / "sweep"
    assert sweep(out, fmu_dir) == 0
    return out


@pytest.fixture
def copied(cached, tmp_path):
    out = tmp_path / "sweep"
    shutil.copytree(cached, out)
    return out


# --- damaged entries -------------------------------------------------------------------------------------------


def _first(out, folder, suffix):
    return sorted((out / "cache" / folder).glob(f"*{suffix}"))[0]


def _empty_row(out):
    path = _first(out, "runs", ".json")
    path.write_text("[]")
    return path


def _edited_deviation(out):
    path = _first(out, "runs", ".json")
    record = json.loads(path.read_text())
    record["row"]["max_position_deviation_m"] = 17.94
    path.write_text(json.dumps(record, indent=1))
    return path


def _truncated(folder):
    def damage(out):
        path = _first(out, folder, ".npz")
        path.write_bytes(path.read_bytes()[:300])
        return path
    return damage


def _garbage_trajectory(out):
    path = _first(out, "runs", ".npz")
    path.write_bytes(np.random.default_rng(1).bytes(2000))
    return path


DAMAGE = {
    "row-holds-an-empty-list": (_empty_row, "not an entry record (an older cache layout, or edited)"),
    "hand-edited-deviation": (_edited_deviation, "does not match its checksum (edited or damaged)"),
    "truncated-trajectory": (_truncated("runs"), "does not match the SHA-256 in its record (damaged or replaced)"),
    "garbage-trajectory": (_garbage_trajectory, "does not match the SHA-256 in its record (damaged or replaced)"),
    "truncated-reference": (_truncated("references"),
                            "does not match the SHA-256 in its record (damaged or replaced)"),
}


@pytest.mark.parametrize("damage", DAMAGE)
def test_a_damaged_entry_is_recomputed_with_one_warning(cached, copied, fmu_dir, capsys, damage):
    original, references = records(cached)
    damaged, reason = DAMAGE[damage]
    path = damaged(copied)
    assert sweep(copied, fmu_dir) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"{WARNING}1 cache entry did not verify and was recomputed: {path}: {reason}"]
    runs = "3 from the cache, 0 run now" if "reference" in damage else "2 from the cache, 1 run now"
    assert f"  runs: 3 ({runs})\n" in captured.out
    rows, again = records(copied)  # every entry verifies again, the damaged one recomputed
    assert again == references and sorted(rows) == sorted(original)
    for key, row in rows.items():
        assert without_wall_time(row) == without_wall_time(original[key])
        assert load_trajectory(copied, key).tobytes() == load_trajectory(cached, key).tobytes()
    assert load_reference(copied, references[0]).tobytes() == load_reference(cached, references[0]).tobytes()
    untouched = [p for p in (copied / "cache").rglob("*") if p.is_file() and p.stem != path.stem]
    assert len(untouched) == 2 * (len(original) + len(references)) - 2
    assert all(p.read_bytes() == (cached / p.relative_to(copied)).read_bytes() for p in untouched)
    assert "17.94" not in (copied / "sweep.csv").read_text()


def test_a_cached_sweep_says_how_many_runs_came_from_the_cache(copied, fmu_dir, capsys):
    assert sweep(copied, fmu_dir) == 0
    captured = capsys.readouterr()
    assert "  runs: 3 (3 from the cache, 0 run now)\n" in captured.out and captured.err == ""


def test_the_loaders_raise_one_line_for_a_damaged_entry(cached, copied):
    rows, [reference] = records(cached)
    key = next(iter(rows))
    (copied / "cache" / "runs" / f"{key}.npz").write_bytes(b"PK\x03\x04 not a zip")
    (copied / "cache" / "references" / f"{reference}.npz").write_bytes(b"")
    with pytest.raises(CacheEntryError, match=rf"{key}\.npz: does not match the SHA-256") as info:
        load_trajectory(copied, key)
    assert "\n" not in str(info.value)
    with pytest.raises(CacheEntryError, match=rf"{reference}\.npz: does not match the SHA-256"):
        load_reference(copied, reference)
    with pytest.raises(CacheEntryError, match=r"missing: no run of this key is cached"):
        load_trajectory(copied, "0" * 64)
    assert load_reference(copied, "0" * 64) is None
    (copied / "cache" / "runs" / f"{key}.json").write_text(json.dumps(rows[key]))  # the layout before records
    with pytest.raises(CacheEntryError, match="not an entry record"):
        SweepCache(copied).row(key)


@pytest.mark.parametrize(("arrays", "reason"), [
    ({"time": np.array([0.0, 1.0], dtype=object)}, r"not a readable \.npz file \(ValueError\)"),
    (np.zeros(3), r"not a readable \.npz file \(TypeError\)"),  # an .npy file
    ({"time": np.zeros(2)}, "holds the columns time; expected time, x, y"),
    ({name: np.zeros(3 if name == "u2" else 2) for name in sweep_cache.TRAJECTORY},
     "not 1-D float arrays of one length"),
])
def test_a_trajectory_that_matches_its_record_must_still_hold_the_columns(copied, arrays, reason):
    """A record whose checksums agree with its .npz is not enough: no pickles, the expected columns."""
    key = next(iter(records(copied)[0]))
    data = io.BytesIO()
    if isinstance(arrays, dict):
        np.savez(data, **arrays)
    else:
        np.save(data, arrays)
    path = copied / "cache" / "runs" / f"{key}.json"
    record = json.loads(path.read_text())
    del record["checksum"]
    record["trajectory_sha256"] = hashlib.sha256(data.getvalue()).hexdigest()
    record["checksum"] = sweep_cache._checksum(record)
    path.write_text(json.dumps(record))
    path.with_suffix(".npz").write_bytes(data.getvalue())
    with pytest.raises(CacheEntryError, match=reason):
        SweepCache(copied).row(key)


# --- lost worker processes ----------------------------------------------------------------------------------------


class Killer(threading.Thread):
    """Watches ``out/.work/sweep-*/<pid>`` (a pool worker's folder) and SIGKILLs the worker, a child
    of this process: the first one seen, or with ``every`` each one until ``stop()``."""

    def __init__(self, out, every=False):
        super().__init__(daemon=True)
        self.out, self.every, self.seen, self.killed, self.done = out, every, set(), [], threading.Event()

    def run(self):
        while not self.done.is_set():
            for folder in self.out.glob(".work/sweep-*/*"):
                if not folder.name.isdigit() or int(folder.name) in self.seen:
                    continue
                pid = int(folder.name)
                self.seen.add(pid)
                try:
                    if psutil.Process(pid).ppid() != os.getpid():
                        continue
                    os.kill(pid, signal.SIGKILL)
                except (psutil.NoSuchProcess, ProcessLookupError):
                    continue
                self.killed.append(pid)
                if not self.every:
                    return
            time.sleep(0.005)

    def stop(self):
        self.done.set()
        self.join()


LONG_RUNS = "2e-4,2.5e-4,4e-4,5e-4"  # four runs of about a second on the 1 s figure eight


def test_a_killed_worker_costs_a_retry_not_the_sweep(tmp_path, fmu_dir, capsys):
    out = tmp_path / "sweep"
    killer = Killer(out)
    killer.start()
    status = sweep(out, fmu_dir, LONG_RUNS, "1", "2")
    killer.stop()
    captured = capsys.readouterr()
    assert status == 0 and len(killer.killed) == 1
    [line] = captured.err.splitlines()
    assert re.fullmatch(rf"{WARNING}a worker process was lost \(killed or crashed\); \d computations? in flight "
                        r"retried on a new pool", line), line
    assert "  runs: 4 (0 from the cache, 4 run now)\n" in captured.out
    assert [row["diverged_reason"] for row in csv_rows(out)] == [""] * 4
    assert len(records(out)[0]) == 4 and not (out / ".work").exists()


def test_runs_whose_worker_is_lost_twice_are_rows_with_the_reason_and_not_cached(tmp_path, fmu_dir, capsys):
    """Every worker killed as soon as it starts: each run is lost twice. The sweep writes everything
    (the lost runs as rows with their reason), then fails with exit status 1; nothing of them is cached,
    so the next sweep tries them again."""
    out = tmp_path / "sweep"
    killer = Killer(out, every=True)
    killer.start()
    status = sweep(out, fmu_dir, "2e-4,4e-4", "1", "2")
    killer.stop()
    captured = capsys.readouterr()
    assert status == 1 and len(killer.killed) >= 2  # one death breaks the whole pool: at least one per round
    warning, error = captured.err.splitlines()
    assert re.fullmatch(rf"{WARNING}a worker process was lost \(killed or crashed\) \d+ times; \d+ computations in "
                        r"flight retried on a new pool; 2 runs did not finish: rows with the reason, not cached",
                        warning), warning
    assert error == ("dsc-fmu: error: 2 of 2 runs did not finish (their worker process was lost, killed or crashed): "
                     f"their rows carry the reason and are not cached; everything else is written to {out}; "
                     "run the sweep again to retry them")
    assert [(row["diverged_reason"], row["diverged"], row["stable"]) for row in csv_rows(out)] == \
        [(LOST_TWICE, "True", "False")] * 2
    rows, references = records(out)
    assert rows == {} and len(references) == 1  # the reference solution was computed here after all
    assert (out / "report.md").is_file() and not (out / ".work").exists()


# --- stale work folders, the checks up front -----------------------------------------------------------------------


def _dead_pid():
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    with pytest.raises(ProcessLookupError):
        os.kill(process.pid, 0)
    return process.pid


def test_work_folders_of_killed_sweeps_are_removed_those_of_live_ones_kept(tmp_path, fmu_paths):
    stale, live = tmp_path / ".work" / f"sweep-{_dead_pid()}-x", tmp_path / ".work" / f"sweep-{os.getpid()}-y"
    for folder in (stale / "12345", live):
        folder.mkdir(parents=True)
        (folder / "DSCController.fmu").write_bytes(b"left behind")
    scenario = load_scenario(SCENARIO).with_simulation(stop_time=0.1)
    done = execute(scenario, [Case(0.01)], tmp_path, fmu_paths, Runner(jobs=1, progress=False))
    assert done.ran == 1 and not stale.exists() and (live / "DSCController.fmu").is_file()
    shutil.rmtree(live)
    execute(scenario, [Case(0.01)], tmp_path, fmu_paths, Runner(jobs=1, progress=False))  # all cached: still cleaned
    assert not (tmp_path / ".work").exists()


def _closed_port():
    """A local TCP port bound but not listening: connections to it are refused."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    return sock, sock.getsockname()[1]


@pytest.mark.parametrize("address", ["tcp://127.0.0.1:notaport", "closed", "tcp://127.0.0.1:99999", "inproc://x"])
def test_a_bad_scheduler_is_one_line_at_once(tmp_path, fmu_dir, address):
    """No stall and no traceback: the address is checked, and a closed port found, before a Dask client exists."""
    sock, port = _closed_port()
    refused = address == "closed"
    with sock:
        address = f"tcp://127.0.0.1:{port}" if refused else address
        process = subprocess.run(
            [sys.executable, "-m", "dsc_fmu", "sweep", "--scheduler", address, "--stop-time", "1", "--step-sizes",
             "0.01", "--out", str(tmp_path / "out"), "--fmu-dir", str(fmu_dir)],
            capture_output=True, text=True, timeout=30)
    [line] = process.stderr.splitlines()
    assert process.returncode == 1 and process.stdout == ""
    if refused:
        assert line == f"dsc-fmu: error: cannot reach the Dask scheduler at {address} within 10 s: Connection refused"
    else:
        assert line.startswith(f"dsc-fmu: error: Dask scheduler address {address!r} is not allowed: ")
        assert line.endswith("; allowed: tcp://HOST:PORT or tls://HOST:PORT with PORT a whole number in 1..65535")
    assert not (tmp_path / "out").exists()


def test_a_server_that_is_not_a_dask_scheduler_is_one_line_after_the_timeout():
    """What accepts the connection but never answers as a scheduler: a Dask client of it would wait forever."""
    from dsc_fmu.study.cluster import connect

    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        with pytest.raises(SweepError, match=rf"^cannot reach the Dask scheduler at {address} within 1 s: "
                                             "no Dask scheduler answered there$"):
            connect(address, 1)


def test_a_step_larger_than_the_stop_time_is_refused(tmp_path, fmu_dir, capsys):
    assert sweep(tmp_path / "out", fmu_dir, "100,3") == 1
    assert capsys.readouterr().err.splitlines() == [
        "dsc-fmu: error: step size 100 s is not allowed: larger than the stop time 1 s; allowed: 0 < h <= stop time"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("where", ["a-file", "under-a-file"])
def test_an_out_that_cannot_be_a_folder_is_named_as_given(tmp_path, fmu_dir, capsys, where):
    (tmp_path / "taken").write_text("not a folder")
    out = tmp_path / "taken" if where == "a-file" else tmp_path / "taken" / "sweep"
    assert sweep(out, fmu_dir) == 1
    [line] = capsys.readouterr().err.splitlines()
    why = "it is not a folder" if where == "a-file" else f"{tmp_path / 'taken'} is not a folder"
    assert line == (f"dsc-fmu: error: {out}: cannot use as the sweep folder: {why}; "
                    "allowed: a writable folder, or a path where one can be created")
    assert ".work" not in line
