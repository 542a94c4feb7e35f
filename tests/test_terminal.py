"""The command line on a real terminal: ``dsc-fmu run`` and ``dsc-fmu sweep`` run in a pseudo-terminal of
their own (its controlling terminal, so that Ctrl-C typed there interrupts them as it does a user's), and
what they write is read as a terminal shows it: one progress line rewritten in place with carriage
returns, cleared before anything else is written. The watch behind ``run`` writes to a real terminal
and a real pipe too: nothing in the pipe, nothing with ``quiet``."""

import fcntl
import json
import os
import re
import signal
import struct
import subprocess
import sys
import termios

import pytest

from dsc_fmu.cosim.progress import ProgressLine, TerminalWatch

NARROW = 40  # columns: the sweep's line is cut
CTRL_C = b"\x03"
RUN = re.compile(r"paper: t = (\d+\.\d{3})/300 s, (\d+) steps, (\S+) s/s, (.+) left")
SWEEP = ["sweep", "figure_eight", "--stop-time", "6", "--step-sizes", "0.001,0.002,0.004", "--couplings", "hold",
         "--orders", "gauss-seidel", "--tolerances", "", "--jobs", "1", "--no-refine"]


def in_terminal(arguments: list[str], cwd, columns: int, interrupt_when) -> tuple[str, int]:
    """``python -m dsc_fmu ARGUMENTS`` in a new pseudo-terminal ``columns`` wide (0: one that does not
    say its size, as ``script`` makes when run from a pipe), its standard streams and controlling
    terminal, read until it exits; Ctrl-C is typed once when ``interrupt_when(output)`` (the bytes so
    far) is true. Returns what it wrote (the terminal writes "\\r\\n" for "\\n") and its exit status."""
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24 if columns else 0, columns, 0, 0))
    pid = os.fork()
    if pid == 0:  # the child: a session whose controlling terminal is the slave side
        try:
            os.close(master)
            os.chdir(cwd)
            os.login_tty(slave)
            signal.signal(signal.SIGINT, signal.SIG_DFL)
            os.execv(sys.executable, [sys.executable, "-m", "dsc_fmu", *arguments])
        finally:
            os._exit(127)
    os.close(slave)
    output = read_until_closed(master, interrupt_when)
    _, status = os.waitpid(pid, 0)
    return output.decode(), os.waitstatus_to_exitcode(status)


def read_until_closed(reader: int, interrupt_when=None) -> bytes:
    """All that comes from ``reader`` (a pipe's or a pseudo-terminal's reading side) until every writer
    has closed it, typing Ctrl-C into it once ``interrupt_when(output)`` (the bytes so far) is true;
    ``reader`` is closed."""
    output = b""
    while True:
        try:
            chunk = os.read(reader, 4096)
        except OSError:  # EIO: a terminal no process holds any more
            break
        if not chunk:
            break
        output += chunk
        if interrupt_when is not None and interrupt_when(output):
            os.write(reader, CTRL_C)
            interrupt_when = None
    os.close(reader)
    return output


def screen(output: str) -> list[str]:
    """The lines a terminal shows after ``output``: a carriage return goes back to the line's start,
    and what follows overwrites it."""
    lines, line, column = [], [], 0
    for char in output:
        if char == "\n":
            lines.append("".join(line).rstrip())
            line, column = [], 0
        elif char == "\r":
            column = 0
        else:
            line[column:column + 1] = [char]
            column += 1
    return lines + ["".join(line).rstrip()]


def drawn(output: str, label: str) -> list[str]:
    """The progress lines drawn in ``output``: each starts after a carriage return with ``label`` (the
    terminal's echo of Ctrl-C, "^C", left out)."""
    return [part.rstrip().removesuffix("^C") for part in output.split("\r") if part.startswith(label)]


@pytest.mark.slow
def test_a_run_shows_one_line_in_place_and_stops_at_ctrl_c(tmp_path, fmu_paths):
    """``dsc-fmu run`` of the paper's scenario for 300 s with h = 1e-4 s (minutes) on a terminal that
    does not say its size (as ``script`` makes when run from a pipe), Ctrl-C typed once the forecast
    and a progress line after it have come: from a second in, lines of the simulated time, the steps
    (t/h), the speed and the time left, within 80 columns; the forecast on a line of its own; exit 130
    and nothing of the progress line left on the screen."""
    out = tmp_path / "out"

    def forecast_then_progress(output: bytes) -> bool:
        before, forecast, after = output.partition(b"at this pace")
        return bool(forecast) and b"\rpaper: t = " in after

    command = ["run", "paper", "--stop-time", "300", "--step-size", "1e-4", "--no-plots", "--out", str(out),
               "--fmu-dir", str(fmu_paths["MobileRobot"].parent)]
    output, status = in_terminal(command, tmp_path, 0, forecast_then_progress)
    assert status == 130, output
    lines = drawn(output, "paper: t = ")
    before_forecast = drawn(output.partition("at this pace")[0], "paper: t = ")
    assert before_forecast and len(lines) > len(before_forecast), output
    shown = [RUN.fullmatch(line) for line in lines]
    assert all(shown) and all(len(line) <= ProgressLine.COLUMNS - ProgressLine.ROOM for line in lines), lines
    times = [float(match[1]) for match in shown]
    assert times == sorted(set(times)) and 0 < times[0]
    assert [int(match[2]) for match in shown] == [round(time / 1e-4) for time in times]
    stopped = json.loads((out / "summary.json").read_text())["settings"]["stopped_at"]
    assert times[-1] <= stopped < 300
    shows = screen(output)
    assert shows[0].startswith("dsc-fmu: at this pace the run takes about 3,000,000 steps and "), shows
    assert shows[1].startswith(f"stopped at t = {stopped:g} s of 300 s (interrupted)"), shows
    assert not any("paper: t = " in line for line in shows), shows


@pytest.mark.parametrize(("stream", "quiet"), [("terminal", False), ("terminal", True), ("pipe", False)])
def test_the_watch_draws_on_a_terminal_unless_quiet_and_never_in_a_pipe(monkeypatch, stream, quiet):
    """A ``TerminalWatch`` writing to a real pseudo-terminal or pipe, its line due at once: on the
    terminal one line after a carriage return, cleared when the watch ends; quiet or in a pipe, nothing."""
    monkeypatch.setattr(TerminalWatch, "SHOW_AFTER", 0.0)
    reader, writer = os.openpty() if stream == "terminal" else os.pipe()
    with open(writer, "w") as file, TerminalWatch(30.0, "paper", quiet=quiet, stream=file) as watch:
        watch(0.5, 5000)
    written = read_until_closed(reader).decode()
    if quiet or stream == "pipe":
        assert written == ""
    else:
        line = written.split("\r")[1]
        assert line.startswith("paper: t = 0.500/30 s, 5000 steps")
        assert written == f"\r{line}\r{' ' * (len(line) + ProgressLine.ROOM - 1)}\r"


@pytest.mark.slow
def test_a_sweep_counts_its_runs_in_place_and_keeps_them_at_ctrl_c(tmp_path, fmu_paths):
    """``dsc-fmu sweep`` of three runs on a narrow terminal: the line counts the finished runs from 0,
    cut to the width; Ctrl-C once it shows one or two done stops it (exit 130) with the line and the
    echoed "^C" cleared before the message. Run again with standard error to a pipe, it takes what
    finished from its cache and runs the rest with no progress line: nothing on standard error."""
    command = [*SWEEP, "--out", str(tmp_path / "out"), "--fmu-dir", str(fmu_paths["MobileRobot"].parent)]
    output, status = in_terminal(command, tmp_path, NARROW, lambda output: b"/3 runs, " in output)  # 1 or 2 done
    assert status == 130, output
    lines = drawn(output, "sweep figure_eight: ")
    assert lines[0] == "sweep figure_eight: 0/3 runs" and re.match(r"sweep figure_eight: [12]/3 runs, \d", lines[-1])
    assert max(len(line) for line in lines) == NARROW - ProgressLine.ROOM, lines  # cut: room for the "^C"
    assert [line for line in screen(output) if line] == ["dsc-fmu: interrupted; finished runs are kept in the cache"]

    done = subprocess.run([sys.executable, "-m", "dsc_fmu", *command], cwd=tmp_path, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert re.match(r"sweep of figure_eight: 3 runs, .*\n  runs: 3 \([12] from the cache, [12] run now\)", done.stdout)


@pytest.mark.slow
def test_a_quiet_sweep_draws_no_line_on_a_terminal(tmp_path, fmu_paths):
    """``dsc-fmu sweep --quiet`` of one run on a terminal: its summary, and no progress line."""
    command = [*SWEEP[:5], "0.004", *SWEEP[6:], "--quiet", "--out", str(tmp_path / "out"),
               "--fmu-dir", str(fmu_paths["MobileRobot"].parent)]
    output, status = in_terminal(command, tmp_path, NARROW, lambda output: False)
    assert status == 0, output
    assert drawn(output, "sweep figure_eight") == [] and "\r\r" not in output
    assert screen(output)[0].startswith("sweep of figure_eight: 1 runs"), output
