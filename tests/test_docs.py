"""The docs site builds with warnings as errors; every generated block of README.md and docs/ is what its committed
result file renders; ``plm-highway docs render`` rewrites stale blocks and ``--check`` finds them; CI runs the
README's Quick start and test commands as the README writes them."""

from __future__ import annotations

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from plm_highway import cli
from plm_highway.publish.blocks import BLOCK, render_all
from plm_highway.publish.renderers import POPULATION, RENDERERS, TABLE3, population_headline

ROOT = Path(__file__).resolve().parents[1]


def _readme_commands():
    spec = importlib.util.spec_from_file_location("readme_commands", ROOT / ".ci" / "readme_commands.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.commands


@pytest.mark.skipif(importlib.util.find_spec("sphinx") is None or importlib.util.find_spec("myst_parser") is None,
                    reason="sphinx or myst-parser is not installed (pip install -e '.[docs]'): the docs build is not checked")
def test_the_docs_build_with_warnings_as_errors(tmp_path):
    done = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html", str(ROOT / "docs"),
                           str(tmp_path / "html")], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    for page in ("index", "evaluation", "calibration", "ekf", "performance", "api"):
        assert (tmp_path / "html" / f"{page}.html").is_file()
    # the API page documents modules, not just headings
    assert "plm_highway.latency.LatencyWrapper" in (tmp_path / "html" / "api.html").read_text(encoding="utf-8")


def test_every_generated_block_matches_its_committed_result():
    result = render_all(ROOT, RENDERERS, check=True)
    assert result.stale == [], f"stale blocks (run 'plm-highway docs render'): {result.stale}"
    # only a result not committed yet may leave a block unrendered, and only the population study's
    assert {relative for _, relative in result.missing} <= {POPULATION}


def test_the_readme_results_box_is_the_population_headline():
    blocks = {m["name"]: m["body"] for m in BLOCK.finditer((ROOT / "README.md").read_text(encoding="utf-8"))}
    assert "population-headline" in blocks
    if not (ROOT / POPULATION).is_file():
        pytest.skip(f"{POPULATION} is not committed yet: the README's results box is a placeholder")
    assert blocks["population-headline"] == population_headline(ROOT).rstrip("\n") + "\n"
    assert len([line for line in blocks["population-headline"].splitlines() if line.strip("> ")]) >= 3


def _temp_project(tmp_path: Path, body: str, name: str = "estimation-table3") -> Path:
    (tmp_path / "docs").mkdir()
    (tmp_path / TABLE3).parent.mkdir(parents=True)
    shutil.copy(ROOT / TABLE3, tmp_path / TABLE3)
    (tmp_path / "README.md").write_text("# x\n", encoding="utf-8")
    (tmp_path / "docs" / "page.md").write_text(f"before\n<!-- render: {name} -->\n{body}<!-- /render -->\nafter\n",
                                               encoding="utf-8")
    return tmp_path


def test_docs_render_check_finds_a_stale_block_and_render_rewrites_it(tmp_path, capsys):
    project = _temp_project(tmp_path, "| an old table |\n")
    page = project / "docs" / "page.md"
    before = page.read_bytes()
    assert cli.main(["docs", "render", "--check", "--root", str(project)]) == 1
    assert "stale: docs/page.md block 'estimation-table3'" in capsys.readouterr().out
    assert page.read_bytes() == before  # --check writes nothing

    assert cli.main(["docs", "render", "--root", str(project)]) == 0
    text = page.read_text(encoding="utf-8")
    assert text.startswith("before\n") and text.endswith("<!-- /render -->\nafter\n")
    table = text.split("-->\n", 1)[1].split("<!-- /render -->")[0]
    assert table.startswith("| scenario | state |") and len(table.splitlines()) == 2 + 12  # 4 scenarios x 3 states
    assert "| an old table |" not in table
    # the committed file's own number: scenario 1's delay-compensated d RMSE, clean / realistic / the paper's
    assert "| 1. 1 m sine weave, straight road, 60 km/h | d [m] |" in table and "| 0.017 / **0.099** / 0.055 |" in table
    capsys.readouterr()
    assert cli.main(["docs", "render", "--check", "--root", str(project)]) == 0
    assert "every block matches" in capsys.readouterr().out


def test_docs_render_refuses_an_unknown_block_naming_it(tmp_path, capsys):
    project = _temp_project(tmp_path, "x\n", name="no-such-table")
    before = (project / "docs" / "page.md").read_bytes()
    assert cli.main(["docs", "render", "--root", str(project)]) == 2
    err = capsys.readouterr().err
    assert "docs/page.md" in err and "no-such-table" in err and "Traceback" not in err
    assert (project / "docs" / "page.md").read_bytes() == before


def test_docs_render_leaves_a_block_whose_result_is_not_committed_and_says_so(tmp_path, capsys):
    project = _temp_project(tmp_path, "placeholder\n", name="population-headline")
    assert cli.main(["docs", "render", "--check", "--root", str(project)]) == 0
    assert f"{POPULATION} is not committed" in capsys.readouterr().err
    assert "placeholder\n" in (project / "docs" / "page.md").read_text(encoding="utf-8")


def test_ci_runs_the_readme_quick_start_then_its_test_commands_verbatim():
    commands = _readme_commands()
    quick, tests = commands("Quick start"), commands("Tests")
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert quick[0] == "pip install torch==2.13.0"
    assert "plm-highway demo zigzag --latency 0.25 --out runs/quickstart/zigzag.png --overwrite" in quick
    assert tests[-1] == "python -m pytest"
    for command in quick + tests:  # each one is a line of the README as written
        assert re.search(rf"^{re.escape(command)}$", readme, re.MULTILINE)
    run = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert run.index('run_section "Quick start"') < run.index('run_section "Tests"')
    assert "readme_commands.py" in run
    # every plm-highway command of the Quick start parses with the real command line (no stale option)
    for command in quick:
        if command.startswith("plm-highway "):
            argv = command.split()[1:]
            cli.build_parser(argv).parse_args(argv)


def test_the_quick_start_writes_only_under_the_ignored_runs_folder():
    # a clean checkout stays clean (git status) after the Quick start: every output it names is under runs/
    import shlex

    outputs = []
    for command in _readme_commands()("Quick start"):
        words = shlex.split(command)
        if words[0] != "plm-highway":
            continue
        argv = words[1:]
        args = cli.build_parser(argv).parse_args(argv)
        outputs += [value for name in ("out", "json") if (value := getattr(args, name, None))]
    assert len(outputs) == 2 and all(Path(output).parts[0] == "runs" for output in outputs), outputs
    assert "/runs/" in (ROOT / ".gitignore").read_text(encoding="utf-8").splitlines()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert "plm-highway demo zigzag --latency 0.25 --out figures/zigzag.png --overwrite" in readme  # the committed one


def test_the_readme_says_what_its_commands_need_and_skip():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    lessons = readme[readme.index("## Lessons"):readme.index("## Commands")]
    assert "PLM_FAST=1 jupyter lab lessons/" in lessons
    tests = readme[readme.index("## Tests"):]
    assert "Chromium and chromedriver" in tests and "../shared/real" in tests
    quick = readme[readme.index("## Quick start"):readme.index("## Lessons")]
    assert "--index-url https://download.pytorch.org/whl/cpu" in quick
    assert "one shipped BM/PLM-Net pair under the simulator's ideal conditions" in " ".join(quick.split())
    assert "<!-- render: quickstart-shipped-pair -->" in quick


def test_the_hero_figure_is_one_the_kit_wrote():
    # made by the documented demo command with --overwrite, which the kit allows only for a figure it wrote itself
    from PIL import Image

    with Image.open(ROOT / "figures" / "zigzag.png") as image:
        assert image.info.get("Software") == "plm-highway"


def test_the_readme_quotes_the_measured_suite_time():
    """The suite's time in the README is the last measurement kept in figures/suite-time.json, idle and loaded."""
    import json

    runs = json.loads((ROOT / "figures" / "suite-time.json").read_text(encoding="utf-8"))["runs"]
    idle = [run for run in runs if run["load"] == "idle"][-1]
    loaded = [run for run in runs if run["load"] != "idle"][-1]
    for run in runs:
        assert run["command"] == "python -m pytest" and run["cores"] == 2 and run["wall_s"] > 0
        assert run["cpu_s"] is None or run["wall_s"] < run["cpu_s"] <= 2 * run["wall_s"]  # 2 cores
    tests = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split("## Tests")[1].split())
    assert f"took {round(idle['wall_s'] / 60)} minutes on 2 otherwise idle cores" in tests
    assert f"{round(loaded['wall_s'] / 60)} minutes with {loaded['load']}" in tests
