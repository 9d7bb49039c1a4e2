"""The user documentation (docs/*.md) against the program: every name the program reads or
writes is documented, spelled as the program spells it, and every link resolves.

Each check derives its list from the code (the model's names, the argument parser, the readers'
keys, the writers' JSON), so a name added, renamed or moved in the code without the pages fails
here. Nothing is simulated or fitted.
"""

from __future__ import annotations

import argparse
import ast
import inspect
import json
import re
import textwrap
from dataclasses import MISSING, fields
from pathlib import Path

import numpy as np
import pytest

import testbed

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = ("model.md", "files.md", "cli.md")


def page(name: str) -> str:
    return (DOCS / name).read_text(encoding="utf-8")


def mentions(text: str, name: str) -> bool:
    """`name` occurs in `text` as a whole token (not inside a longer name: X_u is not X_udot)."""
    return re.search(rf"(?<![\w-]){re.escape(name)}(?![\w-])", text) is not None


def missing_tokens(text: str, names) -> list[str]:
    return [n for n in names if not mentions(text, n)]


def missing_code(text: str, names) -> list[str]:
    """The names not written as code in `text`: `name`, or as a TOML table `[name]`, `[[name]]`."""
    return [n for n in names if not any(f"`{form}`" in text for form in (n, f"[{n}]", f"[[{n}]]"))]


def headings(text: str):
    """(line index, level, title) of every Markdown heading, code blocks left out."""
    fenced = False
    for i, line in enumerate(text.splitlines()):
        if line.startswith("```"):
            fenced = not fenced
        m = re.match(r"(#+) (.*)", line)
        if m and not fenced:
            yield i, len(m.group(1)), m.group(2).strip()


def section(text: str, heading: str) -> str:
    """The text under the Markdown heading `heading` (any level) up to the next heading of the
    same or a higher level."""
    lines, marks = text.splitlines(), list(headings(text))
    for k, (i, level, title) in enumerate(marks):
        if title == heading:
            end = next((j for j, lv, _ in marks[k + 1 :] if lv <= level), len(lines))
            return "\n".join(lines[i + 1 : end])
    raise AssertionError(f"heading {heading!r} not found")


def table_rows(text: str) -> list[list[str]]:
    """The cells of every Markdown table row in `text` (separator rows left out); `\\|` is a
    literal bar inside a cell."""
    rows = []
    for line in text.splitlines():
        if line.startswith("|") and not re.match(r"\|[-| :]+\|$", line):
            cells = re.split(r"(?<!\\)\|", line.strip())[1:-1]
            rows.append([c.strip() for c in cells])
    return rows


# -- docs/model.md -------------------------------------------------------------------------------


def test_model_names_in_their_order():
    from testbed.models.linear import COEFFICIENTS, INPUTS, PARAMETERS, STATES

    text = page("model.md")
    assert f"`{' '.join(STATES)}`" in text
    assert f"`{' '.join(INPUTS)}`" in text
    names = re.search(r"```\n(.*?)```", section(text, "The 35 coefficients"), re.S).group(1).split()
    assert names == list(COEFFICIENTS)
    offsets = re.search(r"```\n(.*?)```", section(text, "Constant offsets"), re.S).group(1).split()
    biases = re.search(r"```\n(.*?)```", section(text, "Output biases"), re.S).group(1).split()
    current = re.search(r"```\n(.*?)```", section(text, "A steady current"), re.S).group(1).split()
    mounting = re.search(r"```\n(.*?)```", section(text, "A velocity log's mounting"), re.S).group(1).split()
    delay = re.search(r"```\n(.*?)```", section(text, "The inputs' delay"), re.S).group(1).split()
    assert names + offsets + biases + current + mounting + delay == list(PARAMETERS)
    assert missing_tokens(text, PARAMETERS + STATES + INPUTS) == []


ROWS = {"surge": "u", "sway": "v", "heave": "w", "roll": "p", "pitch": "q", "yaw": "r"}


def test_model_table_places_every_coefficient_in_its_row():
    """Each row of the equations table names, on its left side, the coefficients of that row of
    Mt and, on its right side, those of that row of At and Bt: no more, no fewer."""
    from testbed.models.linear import IX, PARAMETERS, Vehicle, structure

    s = structure(Vehicle(30.0, 1.0, 2.0, 3.0, 290.0, 300.0, 0.01, 0.02, -0.03, 1.5))
    rows = {r[0]: r for r in table_rows(section(page("model.md"), "The equations")) if len(r) == 3}
    assert set(ROWS) | {"kinematics"} <= set(rows)
    for row, state in ROWS.items():
        i = IX[state]
        left = {n for k, n in enumerate(PARAMETERS) if s.dMt[k, i].any()}
        right = {n for k, n in enumerate(PARAMETERS) if s.dAt[k, i].any() or s.dBt[k, i].any() or s.dSt[k, i]}
        assert {n for n in PARAMETERS if mentions(rows[row][1], n)} == left, row
        assert {n for n in PARAMETERS if mentions(rows[row][2], n)} == right, row
    assert not any(mentions(" ".join(rows["kinematics"]), n) for n in PARAMETERS)


def test_model_vehicle_constants():
    from testbed.models.linear import Vehicle

    rows = table_rows(section(page("model.md"), "The equations"))
    keys = {k for r in rows for k in re.findall(r"`(\w+)`", r[1])} if rows else set()
    assert set(Vehicle.names()) <= keys


# -- docs/cli.md ---------------------------------------------------------------------------------


def subcommands() -> dict[str, argparse.ArgumentParser]:
    from testbed.arguments import parser

    (action,) = [a for a in parser()._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(action.choices)


def test_cli_every_command_option_and_choice():
    text = page("cli.md")
    commands = subcommands()
    assert commands
    for name, sub in commands.items():
        body = section(text, f"testbed {name}")
        options = " ".join(r[0] for r in table_rows(body))  # the options tables' first column
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):  # -h, --help: once, for every command
                assert missing_tokens(text, action.option_strings) == []
                continue
            for option in action.option_strings:
                assert mentions(options, option), f"testbed {name}: {option} not in its options table"
            if not action.option_strings:  # a positional: its metavar (DATA, RUN)
                assert mentions(body, action.metavar or action.dest.upper()), f"testbed {name}: {action.dest}"
            for choice in action.choices or ():
                assert mentions(body, str(choice)), f"testbed {name} {action.option_strings}: {choice}"


def test_cli_builtin_scenarios_and_methods():
    from testbed.estimators import METHODS
    from testbed.simulation.scenario import BUILTIN

    text = page("cli.md")
    simulate = section(text, "testbed simulate")
    assert missing_code(simulate, BUILTIN) == []
    documented = {r[0].strip("`") for r in table_rows(section(text, "Methods"))[1:]}
    assert documented == set(METHODS)


def test_cli_exit_statuses():
    from testbed.cli import INTERNAL_ERROR

    statuses = {r[0] for r in table_rows(section(page("cli.md"), "Exit status"))}
    assert {"0", "1", "2", str(INTERNAL_ERROR), "130"} <= statuses


# -- docs/files.md -------------------------------------------------------------------------------


def test_files_measurement_csv_and_config():
    from testbed.data import CSV_COLUMNS
    from testbed.models.linear import Vehicle

    text = page("files.md")
    csv = section(text, "Measurement CSV")
    assert ",".join(CSV_COLUMNS) in csv
    assert missing_code(csv, ("t", "u", "psi", "z") + CSV_COLUMNS[-3:]) == []
    config = section(text, "Model config TOML")
    assert (
        missing_code(
            config,
            Vehicle.names() + ("free", "screen", "outputs", "[vehicle]", "[coefficients]", "[identify]"),
        )
        == []
    )


def _default(f) -> str | None:
    """A field's default as the signal table writes it, or None (no default, or a computed one)."""
    d = f.default
    if d is MISSING or d is None:
        return None
    if isinstance(d, str):
        return f'"{d}"'
    if isinstance(d, tuple):
        return "[" + ", ".join(f"{v:.3g}" for v in d) + "]"
    return f"{d:.3g}"


def test_files_every_signal_with_its_fields_and_defaults():
    from testbed.simulation.signals import SIGNALS

    rows = {r[0]: r for r in table_rows(section(page("files.md"), "Signals"))}
    assert SIGNALS
    for kind, cls in SIGNALS.items():
        row = rows.get(f"`{kind}`")
        assert row is not None, f"signal {kind} not documented"
        for f in fields(cls):
            assert f"`{f.name}`" in row[1], f"signal {kind}: field {f.name}"
            default = _default(f)
            if default is not None:
                assert f"`{f.name}` ({default})" in row[1], f"signal {kind}: {f.name} default {default}"


def accepted_keys(doc: dict) -> tuple[str, ...]:
    """The keys the scenario reader accepts where `doc` has an unknown one, read off its error."""
    from testbed.errors import InputError
    from testbed.simulation.scenario import parse_scenario

    with pytest.raises(InputError, match="unknown key 'unknown'; expected ") as error:
        parse_scenario(doc, "probe")
    return tuple(str(error.value).split("; expected ")[1].split(", "))


def test_files_scenario_keys():
    from testbed.simulation import scenario
    from testbed.simulation.measurements import Sensors

    body = section(page("files.md"), "Scenario file")
    top = accepted_keys({"unknown": 1})  # the keys the reader accepts, as its error lists them
    experiment = accepted_keys({"experiment": [{"name": "e", "unknown": 1}]})
    assert {"name", "duration", "experiment"} <= set(top) and {"name", "rudder"} <= set(experiment)
    sensors = tuple(f.name for f in fields(Sensors)) + ("measured",)
    assert missing_code(body, top + experiment + sensors + tuple(scenario.LOOPS) + scenario.CHANNELS) == []


def _dict_keys(node) -> set[str]:
    """The string keys of the dict literals in an expression (nested ones and comprehension
    values included)."""
    keys = set()
    for n in ast.walk(node):
        if isinstance(n, ast.Dict):
            keys |= {k.value for k in n.keys if isinstance(k, ast.Constant) and isinstance(k.value, str)}
    return keys


def _written_keys(tree, name: str) -> set[str]:
    """Keys given to the dict `name`: `name = {...}`, `name["key"] = ...` (with the dict literals
    of the value), and `f(name={...})`."""
    keys = set()
    for n in ast.walk(tree):
        if isinstance(n, ast.Assign):
            for target in n.targets:
                if isinstance(target, ast.Name) and target.id == name and isinstance(n.value, ast.Dict):
                    keys |= _dict_keys(n.value)
                if (
                    isinstance(target, ast.Subscript)
                    and isinstance(target.value, ast.Name)
                    and target.value.id == name
                    and isinstance(target.slice, ast.Constant)
                ):
                    keys |= {target.slice.value} | _dict_keys(n.value)
        elif isinstance(n, ast.keyword) and n.arg == name and isinstance(n.value, ast.Dict):
            keys |= _dict_keys(n.value)
    return keys


def _package_trees():
    for path in sorted(Path(testbed.__file__).parent.rglob("*.py")):
        yield ast.parse(path.read_text(encoding="utf-8"))


def _function_tree(fn):
    return ast.parse(textwrap.dedent(inspect.getsource(fn)))


def test_files_estimates_json_keys():
    from testbed.estimators import Estimate, FilterEstimate, Status
    from testbed.jobs.identify import identify_data

    text = section(page("files.md"), "Estimates JSON")
    one = dict(
        free=("X_u",),
        values=np.array([1.0]),
        std=np.array([0.1]),
        cost=1.0,
        iterations=1,
        wall_time_s=0.1,
        noise_std={"u": 0.1},
    )
    fitted = Estimate(
        "ml-gn",
        Status.CONVERGED,
        **one,
        start_reason="why",
        crlb_corrected_std=np.array([0.2]),
        initial_states={"e": {"u": 1.0}},
        process_noise_std={"v": {"value": 0.1, "std": 0.01}},
    )
    diverged = FilterEstimate(
        "mekf",
        Status.DIVERGED,
        **one,
        message="why",
        sqrt="qr",
        max_covariance_asymmetry=0.0,
        diverged_sample=1,
        diverged_t=0.1,
        model_error_std={"u": 0.1},
        passes=2,
        last_step_std=0.1,
    )
    keys = set(fitted.json_fields()) | set(diverged.json_fields())
    assert {
        "crlb_corrected_std",
        "initial_states",
        "process_noise_std",
        "start_reason",
        "diverged",
        "sqrt",
    } <= keys
    identify = _written_keys(_function_tree(identify_data), "doc")
    assert {"fixed", "screen", "comparison", "validation"} <= identify
    assert missing_code(text, sorted(keys | identify)) == []
    assert [s.message for s in Status if s is not Status.DIVERGED and s.message not in text] == []


def test_files_comparison_and_validation_keys():
    from testbed.analysis.comparison import Comparison
    from testbed.analysis.validation import ChannelMetrics, whiteness

    one = np.array([1.0])
    comparison = Comparison(("X_u",), one, one * 1.1, one * 0.1, one * 1.05, note="n").to_dict()
    keys = set(comparison) | set(comparison["rows"][0])
    metrics = ChannelMetrics(50.0, whiteness(np.random.default_rng(0).standard_normal(100)), 60.0).to_dict()
    keys |= set(metrics) | set(metrics["whiteness"])
    from testbed.jobs.validate import validate_data

    validate = _written_keys_dumps(validate_data)
    assert {"estimates", "coefficients", "validation"} <= validate
    assert missing_code(page("files.md"), sorted(keys | validate)) == []


def _written_keys_dumps(fn) -> set[str]:
    """The keys of the dict literals a function passes to `json.dumps`."""
    keys = set()
    for n in ast.walk(_function_tree(fn)):
        if isinstance(n, ast.Call) and getattr(n.func, "attr", None) == "dumps" and n.args:
            keys |= _dict_keys(n.args[0])
    return keys


def test_files_identifiability_json_keys():
    from testbed.analysis.identifiability import Identifiability
    from testbed.analysis.structural import Structural

    free = ("X_u",)
    result = Identifiability(
        free,
        np.array([1.0]),
        np.eye(1),
        np.array([0.1]),
        np.eye(1),
        Structural(free, np.zeros((0, 1)), ()),
        (),
        (),
        ("ok",),
    )
    table = table_rows(section(page("files.md"), "Identifiability JSON"))
    documented = {r[0].strip("`") for r in table[1:]}
    assert set(json.loads(result.to_json())) <= documented


def test_files_run_directory_manifest():
    keys = set().union(*(_written_keys(t, "manifest") for t in _package_trees()))
    assert {"scenario", "seed", "mjcf_sha256"} <= keys  # the scan finds the manifest
    body = section(page("files.md"), "Run directory")
    assert missing_code(body, sorted(keys)) == []
    for name in (
        "manifest.json",
        "model.toml",
        "scenario.toml",
        "recording.rrd",
        "<experiment>.csv",
        "<experiment>.truth.csv",
    ):
        assert f"`{name}`" in body


def test_files_reproduce_outputs():
    from testbed.estimators import Status
    from testbed.study.results import COLUMNS, SUMMARY_COLUMNS
    from testbed.study.rules import conclusions

    body = section(page("files.md"), "Reproduce outputs")
    assert ",".join(COLUMNS) in body
    assert ", ".join(SUMMARY_COLUMNS) in body
    rows = {r[0].strip("`") for r in table_rows(body)}
    assert set(COLUMNS) <= rows
    verdicts = conclusions([], {}, {})
    assert [k for k in verdicts if f'`"{k}"`' not in body] == []
    assert missing_tokens(body, sorted({k for v in verdicts.values() for k in v})) == []
    statuses = [s.name.lower().replace("_", " ") for s in Status] + ["failed"]
    assert missing_code(body, statuses) == []


# -- all pages -----------------------------------------------------------------------------------


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of a page's headings (a repeated one gets -1, -2, ...)."""
    seen: dict[str, int] = {}
    out = set()
    for _, _, title in headings(path.read_text(encoding="utf-8")):
        s = slug(title)
        out.add(s if s not in seen else f"{s}-{seen[s]}")
        seen[s] = seen.get(s, 0) + 1
    return out


LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


@pytest.mark.parametrize("source", ["README.md"] + [f"docs/{p.name}" for p in sorted(DOCS.glob("*.md"))])
def test_links_resolve(source):
    path = ROOT / source
    for target in LINK.findall(path.read_text(encoding="utf-8")):
        if re.match(r"[a-z]+:", target):  # http:, https:, mailto:
            continue
        file, _, anchor = target.partition("#")
        resolved = (path.parent / file).resolve() if file else path
        assert resolved.exists(), f"{source}: link {target}: no {resolved}"
        if anchor and resolved.suffix == ".md":
            assert anchor in anchors(resolved), f"{source}: link {target}: no heading #{anchor}"


def test_readme_and_the_index_link_every_page():
    links = set(LINK.findall((ROOT / "README.md").read_text(encoding="utf-8")))
    index = set(LINK.findall(page("README.md")))
    pages = sorted(p.name for p in DOCS.glob("*.md") if p.name != "README.md")
    assert set(PAGES) <= set(pages)
    assert [name for name in pages if f"docs/{name}" not in links] == []
    assert [name for name in pages if name not in index] == []


def test_readme_is_short_and_starts_with_the_two_commands():
    """At most 200 lines; its set-up gives one command that installs and runs the main job and
    one that installs the test extras and runs the tests, as code blocks of one line each."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 200
    blocks = re.findall(r"```bash\n(.*?)```", section(text, "Set-up (Python 3.11 and pip)"), re.S)
    assert [b.strip() for b in blocks] == [
        "pip install -e . && testbed reproduce --quick --out runs/quick",
        "pip install -e '.[test]' && ruff format --check . && python -m pytest -q",
    ]


@pytest.mark.parametrize("name", PAGES + ("README.md",))
def test_pages_name_no_contract_sections_or_modules(name):
    """The pages stand alone: no section numbers of another document, no internal module paths
    (the command line and the file formats are the interface)."""
    text = page(name)
    assert "§" not in text
    assert re.search(r"testbed[./][a-z_]+", text) is None
