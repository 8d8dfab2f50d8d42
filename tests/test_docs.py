"""The docs a newcomer reads: README.md short, its voro3d commands valid, benchmarks/README.md generated."""
import importlib.util
import re
import shlex
from pathlib import Path

import pytest

from voro3d.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MAX_README_LINES = 220


def _summary():
    spec = importlib.util.spec_from_file_location("benchmarks_summary", ROOT / "benchmarks" / "summary.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def code_blocks(text: str) -> list[str]:
    """The contents of the fenced code blocks of a markdown text."""
    return re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.M | re.S)


def shell_commands(text: str) -> list[list[str]]:
    """Every command line in the code blocks, as word lists, in order.

    A line may chain commands with `` && `` or `` ; ``; a ``#`` starts a comment; quotes are the shell's.
    """
    commands = []
    for block in code_blocks(text):
        for line in block.splitlines():
            command = []
            for word in shlex.split(line, comments=True) + ["&&"]:
                if word in ("&&", "||", ";"):
                    if command:
                        commands.append(command)
                    command = []
                else:
                    command.append(word)
    return commands


def voro3d_commands(text: str) -> list[list[str]]:
    """Every ``voro3d ...`` command in the code blocks, as argument lists (after ``voro3d``)."""
    return [words[1:] for words in shell_commands(text) if words[0] == "voro3d"]


def check_commands(text: str) -> list[str]:
    """The ``voro3d`` command lines of ``text`` that ``build_parser()`` refuses, run in order in the
    current folder: output paths are checked as they parse, so a ``mkdir -p`` before them is made."""
    parser = build_parser()
    refused = []
    for words in shell_commands(text):
        if words[:2] == ["mkdir", "-p"]:
            for folder in words[2:]:
                Path(folder).mkdir(parents=True, exist_ok=True)
        if words[0] != "voro3d":
            continue
        try:
            parser.parse_args(words[1:])
        except SystemExit as exit_:
            if exit_.code != 0 or words[1:] not in (["--help"], ["--version"]):
                refused.append(shlex.join(words))
    return refused


def test_readme_is_short():
    lines = README.read_text().splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md is {len(lines)} lines, at most {MAX_README_LINES}"


def test_readme_commands_parse(tmp_path, monkeypatch, capsys):
    text = README.read_text()
    assert len(voro3d_commands(text)) >= 8  # the first ten minutes show the commands a newcomer runs
    monkeypatch.chdir(tmp_path)
    refused = check_commands(text)
    capsys.readouterr()
    assert not refused, f"README commands that do not parse: {refused}"


def test_a_bad_command_fails(tmp_path, monkeypatch, capsys):
    """The check above can fail: a wrong flag, a wrong suffix, a missing argument, a missing folder."""
    monkeypatch.chdir(tmp_path)
    bad = ["voro3d reconstruct cloud.ply -o mesh.ply --grids 32", "voro3d fit a.ply -o out.xyz", "voro3d eval a.ply",
           "voro3d example knot -o nowhere/knot.ply"]
    assert check_commands("```bash\n" + "\n".join(bad) + "\nmkdir -p here && voro3d example knot -o here/k.ply\n```\n") == bad
    capsys.readouterr()


def test_commands_are_found_in_code_blocks_only():
    text = "voro3d fit not-in-a-block\n```bash\nls && voro3d example sphere -o s.ply  # a comment\n```\n"
    assert voro3d_commands(text) == [["example", "sphere", "-o", "s.ply"]]


def test_readme_names_no_missing_example_files():
    """The examples run on what ships: no scan.ply or bunny.off a newcomer does not have."""
    text = README.read_text()
    for name in ("scan.ply", "bunny.off", "part.obj"):
        assert name not in text


def test_benchmarks_readme_is_up_to_date():
    summary = _summary()
    expected = summary.generate()
    actual = (ROOT / "benchmarks" / "README.md").read_text()
    assert actual == expected, "benchmarks/README.md is out of date: run python benchmarks/summary.py (make docs)"


def test_benchmarks_readme_has_every_results_file():
    summary = _summary()
    text = summary.generate()
    for path in sorted((ROOT / "benchmarks" / "results").glob("*.md")):
        assert f"(results/{path.name})" in text
    assert "| 32 | 38 | voromesh | 0.841 |" in text  # a summary table, copied as the benchmark wrote it


def test_summary_keeps_short_tables_and_drops_long_ones(tmp_path, monkeypatch):
    summary = _summary()
    rows = "\n".join(f"| s{i} | {i} |" for i in range(summary.MAX_ROWS + 1))
    (tmp_path / "demo.md").write_text(
        "# A demo (2026)\n\nWhat it is.\n\n| a | b |\n|---|---|\n| 1 | 2 |\n\n## Per shape\n\n| shape | x |\n|---|---|\n"
        + rows + "\n")
    (tmp_path / "demo.json").write_text("{}")
    monkeypatch.setattr(summary, "RESULTS", tmp_path)
    section = summary.summarise(tmp_path / "demo.md")
    assert section.startswith("## demo: A demo (2026)")
    assert "| 1 | 2 |" in section and "| s0 | 0 |" not in section
    assert "[demo.json](results/demo.json)" in section and "1 longer table" in section


def test_results_name_no_path_of_the_machine_that_ran_them():
    """Results files name inputs relative to the repository (or by name), never as /work/..., /tmp/..., /root/..."""
    results = Path(__file__).resolve().parents[1] / "benchmarks" / "results"
    machine_path = re.compile(r'"(/work|/tmp|/root|/home)/')
    offending = [path.name for path in sorted(results.glob("*.json")) if machine_path.search(path.read_text())]
    assert not offending, offending
