"""The command line: help texts, `info`, `paper`, and the README's Quick start staying true."""

from __future__ import annotations

import re

import pytest
from conftest import REPO

from gagen.app.cli import main, parser


@pytest.mark.parametrize("command", ["build", "info", "simulate", "inverse", "paper", "bench"])
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
    text = (REPO / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert len(blocks) >= 2
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "README.md", "exec"), namespace)  # noqa: S102 (our own README)
    assert (tmp_path / "run.csv").exists()
    assert namespace["tau"].shape == (501, 3)
