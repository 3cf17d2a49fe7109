"""The ``cantrack`` command line: sub-command table, error reporting, ``simulate`` outputs."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from controller import __version__, cli
from controller.errors import CantrackError

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

GOOD = """\
engage: 0.02
duration_s: 0.3
tracker:
  sample_time_s: 0.002
  planner: softmc
robot:
  position: [-20.0, 10.0, 0.0]
master:
  segments:
    - duration_s: 0.3
      velocity: 300
"""

BAD = {
    # name: (scenario text, csv text or None, file that is named, line, key)
    "unknown_key": (GOOD.replace("  planner: softmc", "  planer: softmc"), None,
                    "s.yaml", 5, "tracker.planer"),
    "wrong_type": (GOOD.replace("      velocity: 300", "      velocity: fast"), None,
                   "s.yaml", 11, "master.segments[0].velocity"),
    "bad_range": (GOOD.replace("  sample_time_s: 0.002", "  sample_time_s: 0.0"), None,
                  "s.yaml", 4, "tracker.sample_time_s"),
    "bad_csv_row": (GOOD.replace("  segments:\n    - duration_s: 0.3\n      velocity: 300\n",
                                 "  csv: m.csv\n").replace("duration_s: 0.3\n", ""),
                    "time_s,x,y,z\n0,0,0,0\n0.002,0.6,0,0\n0.004,1.2,0,zero\n",
                    "m.csv", 4, "z"),
    "yaml_syntax": (GOOD.replace("  position: [-20.0, 10.0, 0.0]", "  position: [-20.0, 10.0"),
                    None, "s.yaml", 8, "position"),
}


def run_cli(*args, cwd=None, exe=None):
    cmd = [exe] if exe else [sys.executable, "-m", "controller.cli"]
    return subprocess.run(cmd + [str(a) for a in args], capture_output=True, text=True,
                          cwd=cwd, timeout=60)


def _bad_files(tmp_path, name):
    text, csv_text, named, line, key = BAD[name]
    (tmp_path / "s.yaml").write_text(text)
    if csv_text is not None:
        (tmp_path / "m.csv").write_text(csv_text)
    return tmp_path / "s.yaml", tmp_path / named, line, key


def _assert_one_line_error(proc, named: Path, line: int, key: str):
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr
    assert "Traceback" not in err
    assert err.count("\n") == 1 and err.startswith("cantrack: error: "), err
    assert f"{named}:{line}, key '{key}': " in err, err
    assert proc.stdout == ""


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_scenario_one_line_error_exit_2(tmp_path, name):
    scenario, named, line, key = _bad_files(tmp_path, name)
    proc = run_cli("simulate", scenario, "-o", tmp_path / "out.csv")
    _assert_one_line_error(proc, named, line, key)
    assert not (tmp_path / "out.csv").exists()


def _console_script() -> str | None:
    here = Path(sys.executable).with_name("cantrack")
    if here.is_file():
        return str(here)
    return shutil.which("cantrack")


def test_console_script(tmp_path):
    exe = _console_script()
    if exe is None:
        pytest.skip("the cantrack console script is not installed")
    scenario, named, line, key = _bad_files(tmp_path, "unknown_key")
    proc = run_cli("simulate", scenario, exe=exe)
    _assert_one_line_error(proc, named, line, key)
    proc = run_cli("--version", exe=exe)
    assert proc.returncode == 0 and proc.stdout.strip() == f"cantrack {__version__}"


def test_simulate_example_subprocess_writes_trace_in_cwd(tmp_path):
    proc = run_cli("simulate", EXAMPLES / "linear_absolute.yaml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    trace = tmp_path / "linear_absolute_trace.csv"
    assert trace.is_file()
    assert len(trace.read_text().splitlines()) == 1750 + 2
    assert "time to sync" in proc.stdout and f"Trace      {trace}" in proc.stdout


def test_missing_file_is_one_line(tmp_path):
    proc = run_cli("simulate", tmp_path / "nowhere.yaml")
    assert proc.returncode == 2
    assert proc.stderr == f"cantrack: error: {tmp_path / 'nowhere.yaml'}: " \
                          "No such file or directory\n"


# -- in-process -----------------------------------------------------------------------------
def test_plot_writes_a_png(tmp_path, capsys):
    out = tmp_path / "run.csv"
    png = tmp_path / "plots.png"
    assert cli.main(["simulate", str(EXAMPLES / "relative_mode.yaml"), "-o", str(out),
                     "--plot", str(png)]) == 0
    data = png.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(data) > 50_000
    # width and height from the IHDR chunk
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert w >= 1000 and h >= 800
    assert f"Plot       {png}" in capsys.readouterr().out


def test_plot_default_name_next_to_the_trace_and_quiet(tmp_path, capsys):
    out = tmp_path / "q.csv"
    (tmp_path / "s.yaml").write_text(GOOD)
    assert cli.main(["simulate", str(tmp_path / "s.yaml"), "-o", str(out), "--plot",
                     "--quiet"]) == 0
    assert out.is_file() and (tmp_path / "q.png").read_bytes()[:4] == b"\x89PNG"
    assert capsys.readouterr().out == ""


def test_help_lists_the_commands(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for name, (target, help_) in cli.COMMANDS.items():
        assert name in out and help_ in out
        assert ":" in target


def test_unknown_command_and_bad_arguments_exit_2(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["simluate"])
    assert info.value.code == 2
    with pytest.raises(SystemExit) as info:
        cli.main(["simulate"])  # missing SCENARIO
    assert info.value.code == 2
    assert "cantrack simulate" in capsys.readouterr().err


def test_commands_are_imported_lazily(monkeypatch):
    calls = []

    def fake(argv, prog):
        calls.append((list(argv), prog))
        return 3

    monkeypatch.setitem(cli.COMMANDS, "fake", ("nowhere.module:main", "a test command"))
    monkeypatch.setattr(cli, "_load", lambda target: fake)
    assert cli.main(["fake", "a", "--flag", "-h"]) == 3
    assert calls == [(["a", "--flag", "-h"], "cantrack fake")]


@pytest.mark.parametrize("exc,code,stderr", [
    (KeyboardInterrupt(), 130, ""),
    (CantrackError("something is wrong"), 2, "cantrack: error: something is wrong\n"),
    (PermissionError(13, "Permission denied", "/x.csv"), 2,
     "cantrack: error: /x.csv: Permission denied\n"),
])
def test_error_handling(monkeypatch, capsys, exc, code, stderr):
    def boom(argv, prog):
        raise exc

    monkeypatch.setattr(cli, "_load", lambda target: boom)
    assert cli.main(["simulate", "x.yaml"]) == code
    assert capsys.readouterr().err == stderr
    with pytest.raises(type(exc)):
        cli.main(["--debug", "simulate", "x.yaml"])


def test_verbose_logging(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text(GOOD)
    env_out = tmp_path / "o.csv"
    proc = run_cli("-v", "simulate", tmp_path / "s.yaml", "-o", env_out, "-q")
    assert proc.returncode == 0 and proc.stdout == ""
    assert "INFO" in proc.stderr and "trace written" in proc.stderr
    assert os.path.getsize(env_out) > 0


def test_bare_cantrack_lists_the_commands(capsys):
    from controller.cli import COMMANDS, main

    assert main([]) == 2
    err = capsys.readouterr().err
    assert "commands:" in err and all(name in err for name in COMMANDS)
