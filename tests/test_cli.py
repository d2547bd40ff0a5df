"""The command line: help texts, `info`, `paper`, and the README's Quick start staying true."""

from __future__ import annotations

import argparse
import importlib.util
import logging
import os
import re
import shutil
import subprocess
import sys

import pytest
from conftest import REPO

from gagen.app.cli import COMMANDS, _flat, main, parser
from gagen.diagnostics import showing_progress


@pytest.mark.parametrize("command", ["build", "info", "simulate", "inverse", "paper", "bench",
                                     "view", "export"])
def test_every_command_explains_itself(command, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "usage: python -m gagen " + command in text
    assert len(text) > 200


def test_info_lists_coordinates_and_parameters(capsys):
    assert main(["info", "rrr"]) == 0
    out = capsys.readouterr().out
    assert "coordinates  3: q1, q2, q3" in out and "m3" in out and "40" in out


def test_info_lists_every_method_of_the_api(capsys):
    from gagen.runtime.dynamics import Dynamics

    assert main(["info", "rrr"]) == 0
    out = capsys.readouterr().out
    listed = [line.split()[0].split("(")[0] for line in out.split("methods", 1)[1].splitlines()
              if "(" in line.split()[0]]
    documented = [name for name, f in vars(Dynamics).items()
                  if callable(f) and not name.startswith("_") and name != "parameter_vector"]
    assert sorted(listed) == sorted(documented)
    assert "linearize(q, qd, tau) *" in out and "(6, 6), (6, 3)" in out


def test_build_with_derivatives_builds_and_reports_both_modules(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["build", "chain:2", "--out", str(out), "--derivatives"]) == 0
    shown = capsys.readouterr()
    assert "building the derivatives of 'chain2'" in shown.err
    reports = [line for line in shown.out.splitlines() if "operations before CSE" in line]
    assert len(reports) == 2 and "the derivatives of chain2: 2 coordinates" in reports[1]
    assert any(out.glob("chain2.h")) and any((out / "derivatives").glob("*_derivatives.h"))
    assert len(list(out.glob("gagen_*.so"))) == len(list((out / "derivatives").glob("*.so"))) == 1


def test_unknown_model_is_a_clean_error(capsys):
    assert main(["info", "no-such-robot.txt"]) == 2
    assert "not a built-in model" in capsys.readouterr().err


def test_paper_reproduces_the_three_figures(tmp_path, cache_dir, capsys):
    assert main(["paper", "--out", str(tmp_path), "--cache-dir", str(cache_dir)]) == 0
    names = {p.name for p in tmp_path.iterdir()}
    assert {"simulate.csv", "inverse.csv", "fig2_positions.png", "fig3_arm.png",
            "fig4_inverse.png"} <= names
    out = capsys.readouterr().out
    final = re.search(r"final q1, q2, q3: (\S+), (\S+), (\S+) deg", out)
    assert final and [float(v.rstrip(",")) for v in final.groups()] == [-60.0, -60.0, -30.0]
    peak = re.search(r"T12x \+(\S+) \.\. \+(\S+) N m", out)
    assert peak and 300 <= float(peak.group(2)) <= 400


def quick_start_commands() -> list[str]:
    text = (REPO / "README.md").read_text()
    section = text.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```(?:sh|bash|console)?\n(.*?)\n```", section, flags=re.DOTALL)


def test_readme_quick_start_has_two_commands_and_ci_runs_the_second():
    commands = quick_start_commands()
    assert len(commands) == 2, commands
    assert all("\n" not in c for c in commands)
    assert commands[1] in (REPO / ".ci" / "run").read_text()
    assert "python -m gagen paper" in commands[0]


def test_parser_builds():
    assert parser().prog == "python -m gagen"


def test_readme_python_examples_run(cache_dir, monkeypatch, tmp_path):
    """The API tour in the README is code that works."""
    monkeypatch.chdir(tmp_path)
    # the floating-base tour loads a URDF from the current folder
    shutil.copy(REPO / "tests" / "data" / "urdf" / "anymal_c.urdf", tmp_path)
    text = (REPO / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert len(blocks) >= 2
    if importlib.util.find_spec("viser") is None:  # the viewer is an optional extra
        blocks = [b for b in blocks if "to_html" not in b]
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)  # noqa: S102 (our own README)
    assert (tmp_path / "run.csv").exists()
    assert namespace["tau"].shape == (501, 3)


# ------------------------------------------------------------ registry and arguments


def test_one_registry_names_every_command_of_the_parser():
    sub = next(a for a in parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert list(sub.choices) == list(COMMANDS)
    assert all(callable(command.run) for command in COMMANDS.values())


def test_app_modules_do_not_import_the_command_line():
    """paper.py and runs.py are jobs the command line calls, never the other way round."""
    for name in ("paper.py", "runs.py", "figures.py"):
        text = (REPO / "src" / "gagen" / "app" / name).read_text()
        assert "from .cli" not in text and "gagen.app.cli" not in text, name


@pytest.mark.parametrize("argv, expected", [
    (["--target", "-60", "-60", "-30"], [-60.0, -60.0, -30.0]),
    (["--target=-60,-60,-30"], [-60.0, -60.0, -30.0]),  # the older comma form
    (["--target", "-1.5"], [-1.5]),
    (["--target", ".5", "-.25", "7"], [0.5, -0.25, 7.0]),
])
def test_lists_are_numbers_after_their_option_negative_ones_included(argv, expected):
    args = parser().parse_args(["simulate", "rrr", *argv, "--kp", "500", "300", "200"])
    assert args.model == "rrr"
    assert _flat(args.target) == expected
    assert _flat(args.kp) == [500.0, 300.0, 200.0] and args.kd is None


@pytest.mark.parametrize("bad", [["--qf", "-60", "x"], ["--qf", "nan"], ["--qf"],
                                 ["--qf", "1,,inf"]])
def test_a_list_with_something_else_than_finite_numbers_is_a_usage_error(bad, capsys):
    with pytest.raises(SystemExit) as exit_:
        parser().parse_args(["inverse", "rrr", *bad])
    assert exit_.value.code == 2
    assert "--qf" in capsys.readouterr().err


def test_quiet_is_accepted_before_and_after_the_command():
    assert parser().parse_args(["-q", "info"]).quiet
    assert parser().parse_args(["info", "--quiet"]).quiet
    assert not parser().parse_args(["info"]).quiet


# ------------------------------------------------------------------- diagnostics


def test_progress_goes_to_stderr_unless_quiet(tmp_path, cache_dir, capsys):
    argv = ["inverse", "rrr", "--points", "5", "--out", str(tmp_path), "--cache-dir",
            str(cache_dir)]
    assert main(argv) == 0
    shown = capsys.readouterr()
    assert "gagen: loading 'rrr'" in shown.err and "gagen: plotting..." in shown.err
    assert "loading" not in shown.out and "peak T12x" in shown.out
    assert main([*argv, "--quiet"]) == 0
    quiet = capsys.readouterr()
    assert quiet.err == "" and "peak T12x" in quiet.out


def _progress(verbose: bool):
    from gagen.building.builder import BuildReport, Progress

    return Progress(BuildReport("m", "m_mod", REPO), verbose)


def test_library_progress_is_logged_and_quiet_by_default(capsys, caplog):
    with caplog.at_level(logging.INFO, logger="gagen"):
        _progress(False).stage("derive", 1.25, "3 coordinates")
    assert capsys.readouterr().err == ""
    [record] = caplog.records
    assert record.name == "gagen.building.builder" and record.levelno == logging.INFO
    assert record.getMessage() == "derive       1.25 s  3 coordinates"


def test_verbose_shows_progress_once_and_the_command_line_decides(capsys):
    _progress(True).say("compiling")
    assert capsys.readouterr().err == "gagen: compiling\n"
    with showing_progress():  # the command line's handler: verbose adds no second line
        _progress(True).say("compiling")
    assert capsys.readouterr().err == "gagen: compiling\n"
    with showing_progress(level=logging.WARNING):  # --quiet wins over verbose
        _progress(True).say("compiling")
    assert capsys.readouterr().err == ""
    assert not logging.getLogger("gagen").handlers  # nothing left attached


def test_figures_leave_matplotlib_s_backend_alone(tmp_path):
    code = (
        "import matplotlib, numpy as np\n"
        "matplotlib.use('pdf')\n"
        "from gagen.app.figures import fig2_positions\n"
        "import sys\n"
        f"fig2_positions(np.linspace(0, 1, 5), np.zeros((5, 2)), path={str(tmp_path)!r} + '/f.png')\n"
        "assert matplotlib.get_backend() == 'pdf', matplotlib.get_backend()\n"
        "assert 'matplotlib.pyplot' not in sys.modules\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, "MPLBACKEND": ""}, check=False)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
