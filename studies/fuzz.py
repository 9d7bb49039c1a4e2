"""Bad input tried against the command line as a user's files and arguments would be, tallied.

A corpus of about seven hundred cases over a workspace of valid inputs (two small measurement
CSVs simulated from the linear model, a model config, a run directory with truth files): the
CSVs broken in every way `CSV_MUTATIONS` knows, the config's every vehicle constant, some
coefficients and its noise_std given impossible values, the manifest's every broken form, every flag given bad
values, every kind of output target (a folder, a file in the way, an input, standard output, a
missing folder), the cases of the bad-input issue one by one, `input_cases`: scenario
files, estimates, names and `reproduce`, and `time_cases`: bad time and gaps as loggers write
them, and priors a fit or a flight cannot take for granted. Each case runs `testbed` on a
fresh copy of the workspace; the tally counts:

- errors: exit status 2 with exactly one stderr line naming a file, flag or value;
- crashes: any other failure: a traceback, a status other than 0, 1 or 2, a second stderr line
  (a numpy warning is made an error here, so it counts), an unnamed one-line error, or one
  that blames a flag the command line did not give (a value read from a file, named as a flag);
- partial outputs: anything written on failure, an input changed, or a user's file replaced
  without --force, whatever the status.

    python studies/fuzz.py              # in this process (fd-level output captured)
    python studies/fuzz.py --subprocess # each case a real `python -m testbed` (slower)

The property-based tests (tests/test_properties.py) use the same workspace, snapshots and
mutations with generated values.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import hashlib
import io
import json
import math
import os
import random
import re
import shutil
import stat
import subprocess
import sys
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from testbed.data import ModelConfig, config_text, csv_text
from studies.remus import NOISE, EXAMPLE_COEFFICIENTS, VEHICLE, inputs
from testbed.identification.prediction import synthetic
from testbed.models.linear import COEFFICIENTS, INPUTS, STATES, Vehicle

FREE = ("Y_v", "Y_r", "N_v", "N_r", "Z_w", "M_q")  # observed from both experiments of the workspace

# -- the workspace -------------------------------------------------------------------------------


def workspace(root: Path) -> Path:
    """Valid inputs in `root`: data/h.csv and data/v.csv (2 s at 20 Hz, noisy), cfg.toml (FREE,
    30 % off the example's coefficients), run/ (a run directory: the two CSVs, their noise-free .truth.csv,
    model.toml at the example's coefficients and manifest.json), keep.txt (a user's file),
    link.txt (a symbolic link to it) and an empty out/."""
    rng = np.random.default_rng(7)
    example = ModelConfig(VEHICLE, dict(EXAMPLE_COEFFICIENTS), FREE, "example")
    for folder in ("data", "run", "out"):
        (root / folder).mkdir(parents=True, exist_ok=True)
    for name, (t, u) in inputs(duration=2.0, dt=0.05).items():
        clean = synthetic(example, t, u, name=name)
        noisy = synthetic(example, t, u, NOISE, rng=rng, name=name)
        text = csv_text(t, noisy.y, u)
        (root / "data" / f"{name[0]}.csv").write_text(text)
        (root / "run" / f"{name}.csv").write_text(text)
        (root / "run" / f"{name}.truth.csv").write_text(csv_text(t, clean.y, u))
    prior = example.with_coefficients(
        {n: EXAMPLE_COEFFICIENTS[n] * (1.3 if k % 2 else 0.7) for k, n in enumerate(FREE)}
    )
    (root / "cfg.toml").write_text(config_text(prior))
    (root / "run" / "model.toml").write_text(config_text(example))
    manifest = {"scenario": "fuzz", "experiments": ["horizontal", "vertical"]}
    (root / "run" / "manifest.json").write_text(json.dumps(manifest))
    (root / "keep.txt").write_text("a user's file\n")
    (root / "link.txt").symlink_to("keep.txt")
    return root


def snapshot(root: Path) -> dict[str, str]:
    """Every path below `root` (hidden ones too) → its kind and, for a file, its SHA-256."""
    out = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = Path(folder) / name
            rel = str(path.relative_to(root))
            st = os.lstat(path)
            if stat.S_ISLNK(st.st_mode):
                out[rel] = f"link:{os.readlink(path)}"
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = "dir"
            elif stat.S_ISREG(st.st_mode):
                out[rel] = hashlib.sha256(path.read_bytes()).hexdigest()
            else:
                out[rel] = f"node:{st.st_mode:o}"
    return out


# -- mutations -----------------------------------------------------------------------------------

CELLS = [
    "",
    "nan",
    "inf",
    "-inf",
    "1e300",
    "-1e7",
    "abc",
    "1,5",
    '"',
    "  ",
    "1e-400",
    "0x1p3",
    "１",
    "1_0",
    "\x00",
    "9" * 400,
    "1e308",
    "--1",
    "True",
    "1.0.0",
    "-1.7e308",
    "1.7e308",
]


def _rows(data: bytes) -> list[list[str]]:
    return list(csv.reader(io.StringIO(data.decode("utf-8-sig"))))


def _text(rows: list[list[str]]) -> bytes:
    return ("\n".join(",".join(r) for r in rows) + "\n").encode()


def _at(rows, where: int) -> tuple[int, int]:
    """A data row and a column of `rows` picked by `where`."""
    return 1 + where % max(len(rows) - 1, 1), (where // 7) % len(rows[0])


def _set_cell(rows, where):
    r, c = _at(rows, where)
    rows[r][c] = CELLS[where % len(CELLS)]
    return rows


def _drop_column(rows, where):
    c = where % len(rows[0])
    return [row[:c] + row[c + 1 :] for row in rows]


def _drop_states(rows, where):
    keep = [c for c, name in enumerate(rows[0]) if name not in STATES]
    return [[row[c] for c in keep] for row in rows]


def _duplicate_column(rows, where):
    c = where % len(rows[0])
    rows[0][(c + 1) % len(rows[0])] = rows[0][c]
    return rows


def _cut_row(rows, where):
    r = _at(rows, where)[0]
    rows[r] = rows[r][:-1]
    return rows


def _extend_row(rows, where):
    rows[_at(rows, where)[0]].append("0")
    return rows


def _few_rows(rows, where):
    return rows[: 1 + where % 3]


def _time_jump(rows, where):
    r = _at(rows, where)[0]
    rows[r][0] = repr(float(rows[r][0]) + 0.5 * (float(rows[2][0]) - float(rows[1][0])))
    return rows


def _scale(factor, every_state=False):
    def mutate(rows, where):
        columns = (
            [c for c, n in enumerate(rows[0]) if n in STATES]
            if every_state
            else [1 + where % (len(rows[0]) - 1)]
        )
        for row in rows[1:]:
            for c in columns:
                row[c] = repr(float(row[c]) * factor)
        return rows

    return mutate


def _time_scale(factor):
    def mutate(rows, where):
        c = rows[0].index("t")
        for row in rows[1:]:
            row[c] = repr(float(row[c]) * factor)
        return rows

    return mutate


def _missing(fraction, columns=STATES):
    """Empty a `fraction` of the cells of the named columns, picked by `where`."""

    def mutate(rows, where):
        rng = random.Random(where)
        for c, name in enumerate(rows[0]):
            if name in columns:
                for row in rows[1:]:
                    if rng.random() < fraction:
                        row[c] = rng.choice(("", "nan", "NaN", " "))
        return rows

    return mutate


def _empty_column(rows, where):
    states = [c for c, n in enumerate(rows[0]) if n in STATES]
    c = states[where % len(states)]
    for row in rows[1:]:
        row[c] = ""
    return rows


def _jittered_time(rows, where):
    rng = random.Random(where)
    dt = float(rows[2][0]) - float(rows[1][0])
    for row in rows[1:]:
        row[0] = repr(float(row[0]) + rng.uniform(-0.45, 0.45) * dt)
    return rows


def _repeated_time(rows, where):
    for r in range(2 + where % 3, len(rows), 3):
        rows[r][0] = rows[r - 1][0]
    return rows


def _long_cell(rows, where):
    r, c = _at(rows, where)
    rows[r][c] = "1" * 200_000
    return rows


def _insert_line(line):
    def mutate(rows, where):
        rows.insert(1 + where % len(rows), line)
        return rows

    return mutate


def _bytes_at(blob: bytes):
    def mutate(data: bytes, where: int) -> bytes:
        k = where % (len(data) + 1)
        return data[:k] + blob + data[k:]

    return mutate


# name → (rows, where) → rows, or (bytes, where) → bytes (names ending in "bytes")
CSV_MUTATIONS: dict[str, Callable] = {
    "cell": _set_cell,
    "drop column": _drop_column,
    "drop states": _drop_states,
    "duplicate column": _duplicate_column,
    "short row": _cut_row,
    "long row": _extend_row,
    "few rows": _few_rows,
    "time jump": _time_jump,
    "time reversed": lambda rows, where: rows[:1] + rows[1:][::-1],
    "time constant": lambda rows, where: [rows[0]] + [["1"] + r[1:] for r in rows[1:]],
    "time in ms": _time_scale(1000),
    "time x4000": _time_scale(4000),
    "header only": lambda rows, where: rows[:1],
    "no header": lambda rows, where: rows[1:],
    "scaled 1e300": _scale(1e300),
    "states scaled 1e300": _scale(1e300, every_state=True),
    "scaled 1e8": _scale(1e8),
    "scaled 1e-300": _scale(1e-300),
    "long cell": _long_cell,
    "missing states": _missing(0.3),
    "mostly missing": _missing(0.97),
    "missing fins": _missing(0.3, ("delta_r", "delta_er", "delta_el")),
    "empty column": _empty_column,
    "jittered time": _jittered_time,
    "repeated time": _repeated_time,
    "units row": lambda rows, where: [rows[0], ["s"] * len(rows[0])] + rows[1:],
    "comment line": _insert_line(["# a comment"]),
    "blank lines": _insert_line([]),
    "index column": lambda rows, where: [[""] + rows[0]] + [[str(k)] + r for k, r in enumerate(rows[1:])],
    "padded cells": lambda rows, where: [[f"  {c} " for c in r] for r in rows],
    "quoted cells": lambda rows, where: [[f'"{c}"' for c in r] for r in rows],
    "empty bytes": lambda data, where: b"",
    "semicolons bytes": lambda data, where: data.replace(b",", b";"),
    "utf-16 bytes": lambda data, where: data.decode().encode("utf-16"),
    "bom bytes": lambda data, where: b"\xef\xbb\xbf" + data,
    "crlf bytes": lambda data, where: data.replace(b"\n", b"\r\n"),
    "latin-1 bytes": _bytes_at(b"\xe9t\xe9"),
    "nul bytes": _bytes_at(b"\x00\x00"),
    "junk bytes": _bytes_at(b"\xff\xfe\x80,\n\r"),
    "truncated bytes": lambda data, where: data[: where % (len(data) + 1)],
}


NAN_SPELLINGS = ("nan", "-nan", "+NaN", "NAN", "nan(ind)", "-nan(ind)", "NaN(0x7ff8)")


def _decreasing_once(rows, where):
    r = min(_at(rows, where)[0], len(rows) - 2)  # a stamp swapped with the next row's
    rows[r][0], rows[r + 1][0] = rows[r + 1][0], rows[r][0]
    return rows


def _duplicated_rows(rows, where):
    every = 2 + where % 4
    out = rows[:1]
    for k, row in enumerate(rows[1:]):
        out += [row, list(row)] if k % every == 0 else [row]
    return out


def _gap(seconds, isolated=False):
    """Every stamp from a row on moved `seconds` later; `isolated`: a gap before and after every
    sixth row, each a segment of one row."""

    def mutate(rows, where):
        shift, first = 0.0, _at(rows, where)[0]
        for k, row in enumerate(rows[1:], start=1):
            if (k % 6 in (0, 1) and k > 1) if isolated else k == first:
                shift += seconds
            row[0] = repr(float(row[0]) + shift)
        return rows

    return mutate


def _nan_channels(rows, where):
    """Every cell of a third of the state columns a NaN, spelled as loggers write it."""
    states = [c for c, n in enumerate(rows[0]) if n in STATES]
    for c in states[where % 3 :: 3]:
        for k, row in enumerate(rows[1:]):
            row[c] = NAN_SPELLINGS[(k + where) % len(NAN_SPELLINGS)]
    return rows


def _nan_spellings(rows, where):
    """A fifth of the state and fin cells after the first row NaNs, spelled as loggers write it."""
    rng = random.Random(where)
    for c, name in enumerate(rows[0]):
        if name in STATES + INPUTS:
            for row in rows[2:]:
                if rng.random() < 0.2:
                    row[c] = rng.choice(NAN_SPELLINGS)
    return rows


def _stale(columns):
    """The named state columns (None: every state) repeating the row before in every other row."""

    def mutate(rows, where):
        cs = [c for c, n in enumerate(rows[0]) if n in (columns or STATES)]
        for k in range(2 + where % 2, len(rows), 2):
            for c in cs:
                rows[k][c] = rows[k - 1][c]
        return rows

    return mutate


# Bad time and gaps, as loggers write them: name → (rows, where) → rows
TIME_MUTATIONS: dict[str, Callable] = {
    "decreasing stamp": _decreasing_once,
    "repeated stamps": _repeated_time,
    "duplicated rows": _duplicated_rows,
    "huge gap": _gap(1e6),
    "gap of 1e300 s": _gap(1e300),
    "single-row segments": _gap(10.0, isolated=True),
    "all-NaN channels": _nan_channels,
    "NaN spellings": _nan_spellings,
    "stale DVL": _stale(("u", "v", "w")),
    "stale rows": _stale(None),
}


def apply_csv_mutation(data: bytes, name: str, where: int) -> bytes:
    """`data` (a valid measurement CSV) broken by the mutation `name` at position `where`."""
    mutate = CSV_MUTATIONS.get(name) or TIME_MUTATIONS[name]
    try:
        return mutate(data, where) if name.endswith("bytes") else _text(mutate(_rows(data), where))
    except (IndexError, ValueError, ZeroDivisionError, UnicodeDecodeError, csv.Error):  # too broken for it
        return data


TOML_BAD_VALUES = [
    "x",
    True,
    [],
    {},
    float("nan"),
    float("inf"),
    -float("inf"),
    1e300,
    -1.0,
    0,
    10**30,
    10**400,
    [1, 2],
    {"a": 1},
    -0.0,
    1e-300,
    "1.5",
]


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string
    if isinstance(v, list):
        return "[" + ", ".join(map(_toml_value, v)) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_text(doc: dict) -> str:
    """TOML text of `doc`: top-level tables as [sections], everything else as key = value."""
    lines = [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for table, body in doc.items():
        if isinstance(body, dict):
            lines += [f"[{json.dumps(table)}]"] + [
                f"{json.dumps(k)} = {_toml_value(v)}" for k, v in body.items()
            ]
    return "\n".join(lines) + "\n"


# -- the corpus ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One command line over a fresh workspace: `files` are written into it first, as pairs of a
    relative path and its bytes, or a workspace CSV and the mutations that break it: (source,
    ((mutation, where), ...))."""

    label: str
    argv: tuple[str, ...]
    files: tuple = ()


def _config_doc(root: Path) -> dict:
    import tomllib

    return tomllib.loads((root / "cfg.toml").read_text())


def corpus(root: Path) -> list[Case]:
    """The cases, over the workspace at `root` (read for the config to break)."""
    fit = ("--max-iter", "2")
    cases = []
    for name in CSV_MUTATIONS:
        for where in (0, 1, 7, 23):
            files = (("bad.csv", ("data/h.csv", ((name, where),))),)
            cases.append(
                Case(
                    f"csv {name} @{where}",
                    ("identify", "bad.csv", "--config", "cfg.toml", "--out", "out/e.json", *fit),
                    files,
                )
            )
        files = (("bad.csv", ("data/v.csv", ((name, 3),))),)
        cases.append(
            Case(
                f"csv {name} (analyze)",
                ("analyze", "bad.csv", "--config", "cfg.toml", "--out", "out/a.json"),
                files,
            )
        )
        cases.append(
            Case(
                f"csv {name} (mekf)",
                (
                    "identify",
                    "bad.csv",
                    "data/h.csv",
                    "--config",
                    "cfg.toml",
                    "--method",
                    "mekf",
                    "--out",
                    "out/e.json",
                ),
                files,
            )
        )
    doc = _config_doc(root)
    bad = [float("nan"), -1.0, 0, "x", 1e300, True, 10**400]
    for key in Vehicle.names():
        for value in bad:
            broken = json.loads(json.dumps(doc))
            broken["vehicle"][key] = value
            cases.append(
                Case(
                    f"config vehicle {key}={value!r:.12}",
                    ("identify", "data", "--config", "bad.toml", "--out", "out/e.json", *fit),
                    (("bad.toml", toml_text(broken).encode()),),
                )
            )
    for key in ("X_udot", "N_rdot", "Y_v", "Nope", "N_0", "b_r", "c_N", "input_delay", "b_", "N_0[h]"):
        for value in bad + [doc["vehicle"]["Iz"]]:
            broken = json.loads(json.dumps(doc))
            broken["coefficients"][key] = value
            cases.append(
                Case(
                    f"config {key}={value!r:.12}",
                    ("analyze", "data", "--config", "bad.toml"),
                    (("bad.toml", toml_text(broken).encode()),),
                )
            )
    for label, free in (
        ("unknown", ["Y_v", "Nope"]),
        ("twice", ["Y_v", "Y_v"]),
        ("not a list", "Y_v"),
        ("numbers", [1, 2]),
        ("empty", []),
        ("all", list(doc["coefficients"])),
    ):
        broken = json.loads(json.dumps(doc)) | {"identify": {"free": free}}
        argv = ("identify", "data", "--config", "bad.toml", "--out", "out/e.json", *fit)
        cases.append(Case(f"config free {label}", argv, (("bad.toml", toml_text(broken).encode()),)))
    for label, free, per_record in (
        ("not in free", ["Y_v"], ["N_r"]),
        ("twice", ["Y_v", "N_0"], ["N_0", "N_0"]),
        ("not a list", ["N_0"], "N_0"),
        ("numbers", ["N_0"], [1]),
        ("a table", ["N_0"], {"N_0": 1}),
        ("offsets and biases", ["Y_v", "N_0", "b_r", "c_N", "input_delay"], ["N_0", "b_r"]),
    ):
        broken = json.loads(json.dumps(doc)) | {"identify": {"free": free, "per_record": per_record}}
        for method in ("ml-gn", "mekf", "ml-fem", "equation-error"):
            argv = ("identify", "data", "--config", "bad.toml", "--method", method, "--out", "out/e.json")
            argv += fit if method.startswith("ml-") else ()
            cases.append(
                Case(
                    f"config per_record {label} ({method})", argv, (("bad.toml", toml_text(broken).encode()),)
                )
            )
    for label, sensors in (
        ("not a table", 1.0),
        ("sensor not a table", {"dvl": 1.0}),
        ("no outputs", {"dvl": {"position": [0.1, 0.0, 0.0]}}),
        ("unknown output", {"dvl": {"outputs": ["yaw"]}}),
        ("specific force", {"imu": {"outputs": ["ax", "ay", "az"]}}),
        ("rate", {"dvl": {"outputs": ["u", "v", "w"], "rate": 10.0}}),
        ("position short", {"dvl": {"outputs": ["u", "v", "w"], "position": [0.1]}}),
        ("position text", {"dvl": {"outputs": ["u", "v", "w"], "position": ["a", 0, 0]}}),
        ("frame", {"dvl": {"outputs": ["u", "v", "w"], "frame": "ned"}}),
        ("earth part", {"dvl": {"outputs": ["u", "v"], "frame": "earth"}}),
        ("misalignment large", {"dvl": {"outputs": ["u", "v", "w"], "misalignment": [1.0, 0, 0]}}),
        ("delay negative", {"dvl": {"outputs": ["u", "v", "w"], "delay": -0.1}}),
        ("delay huge", {"dvl": {"outputs": ["u", "v", "w"], "delay": 1e300}}),
        ("bias other", {"dvl": {"outputs": ["u"], "bias": {"w": 0.1}}}),
        ("scale -1", {"dvl": {"outputs": ["u"], "scale": {"u": -1.0}}}),
        ("twice", {"a": {"outputs": ["u"]}, "b": {"outputs": ["u"]}}),
        ("name", {".hidden": {"outputs": ["u"]}}),
        ("good", {"dvl": {"outputs": ["u", "v", "w"], "position": [0.2, 0.0, 0.1], "delay": 0.04}}),
    ):
        broken = json.loads(json.dumps(doc)) | {"sensors": sensors}
        for method in ("ml-gn", "mekf"):
            argv = ("identify", "data", "--config", "bad.toml", "--method", method, "--out", "out/e.json")
            argv += fit if method == "ml-gn" else ()
            cases.append(
                Case(f"config sensors {label} ({method})", argv, (("bad.toml", toml_text(broken).encode()),))
            )
    for label, noise in (
        ("not a table", 0.01),
        ("unknown state", {"yaw": 0.01}),
        ("zero", {"r": 0}),
        ("negative", {"r": -1.0}),
        ("huge", {"r": 1e300}),
        ("tiny", {"r": 1e-300}),
        ("text", {"r": "0.01"}),
        ("table", {"r": {"a": 1}}),
        ("given", {"r": 0.002, "psi": 0.01}),
    ):
        broken = json.loads(json.dumps(doc))
        broken.setdefault("identify", {})["noise_std"] = noise
        for method in ("ml-gn", "mekf"):
            argv = ("identify", "data", "--config", "bad.toml", "--method", method, "--out", "out/e.json")
            argv += fit if method == "ml-gn" else ()
            cases.append(
                Case(
                    f"config noise_std {label} ({method})", argv, (("bad.toml", toml_text(broken).encode()),)
                )
            )
    inertia = {k: v for k, v in doc["coefficients"].items() if k.endswith("dot")}
    for label, terms, free in (
        ("good", {"Y_uv": -100.0, "N_v|v|": -12.0}, []),
        ("not a table", 1.0, []),
        ("unknown term", {"Y_q|": 1.0}, []),
        ("no factor", {"Y_": 1.0}, []),
        ("bad row", {"Q_uv": 1.0}, []),
        ("linear name", {"Y_v": 1.0}, []),
        ("nan", {"Y_uv": float("nan")}, []),
        ("huge", {"Y_uv": 1e300}, []),
        ("text", {"Y_uv": "1"}, []),
        ("bool", {"Y_uv": True}, []),
        ("free unknown", {"Y_uv": 1.0}, ["N_uv"]),
        ("free twice", {"Y_uv": 1.0}, ["Y_uv", "Y_uv"]),
        ("free linear", {"Y_uv": 1.0}, ["Y_v"]),
        ("linear coefficient", {"Y_uv": 1.0}, None),
    ):
        broken = json.loads(json.dumps(doc))
        broken["coefficients"] = inertia if free is not None else inertia | {"Y_v": -2.0}
        broken["terms"] = terms
        broken["identify"] = {"free": free or []}
        argv = ("analyze", "data", "--config", "bad.toml")
        cases.append(Case(f"config terms {label}", argv, (("bad.toml", toml_text(broken).encode()),)))
    blade = {
        "axes": [0.1, 0.11, 0.05],
        "centre": [-1.15, 0.0, -0.17],
        "frame": [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],
        "moments": [3.7e-05, 2.8e-05, 1.9e-05],
        "density": 1025.0,
        "added_mass": [0.76, 0.65, 2.77, 0.0029, 0.0021, 4.0e-05],
        "fin": "dr",
        "hinge": [-1.15, 0.0, 0.0],
        "hinge_axis": [0.0, 0.0, 1.0],
    }
    for label, field, value in (
        ("good", None, None),
        ("axes short", "axes", [0.1, 0.11]),
        ("axes negative", "axes", [0.1, -0.11, 0.05]),
        ("axes text", "axes", ["a", 0.11, 0.05]),
        ("centre nan", "centre", [float("nan"), 0.0, 0.0]),
        ("frame not a rotation", "frame", [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 1.0]]),
        ("frame 2 rows", "frame", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
        ("moments negative", "moments", [-1.0, 0.0, 0.0]),
        ("density 0", "density", 0.0),
        ("added mass short", "added_mass", [1.0, 1.0]),
        ("fin unknown", "fin", "dx"),
        ("hinge axis 0", "hinge_axis", [0.0, 0.0, 0.0]),
        ("unknown field", "colour", "red"),
        ("not a table", "", 1.0),
    ):
        component = dict(blade) if field is None else blade | {field: value}
        if field == "":
            component = value
        for terms, name in (
            ({"lift@blade": 1.0, "blunt@blade": 0.04}, "blade"),
            ({"drag@blade": 1.0}, "blade"),
            ({"lift@nope": 1.0}, "blade"),
            ({"lift@blade": 1.0}, ".blade"),
        ):
            if label != "good" and terms != {"lift@blade": 1.0, "blunt@blade": 0.04}:
                continue
            broken = json.loads(json.dumps(doc))
            broken["coefficients"] = inertia
            broken["terms"] = terms
            broken["components"] = {name: component}
            broken["identify"] = {"free": list(terms)}
            which = f"{label}, {', '.join(terms)} on {name}"
            for argv in (
                ("analyze", "data", "--config", "bad.toml"),
                ("identify", "data", "--config", "bad.toml", "--out", "out/e.json", *fit),
            ):
                cases.append(
                    Case(
                        f"config components {which} ({argv[0]})",
                        argv,
                        (("bad.toml", toml_text(broken).encode()),),
                    )
                )
    text = (root / "cfg.toml").read_bytes()
    for label, blob in (
        ("empty", b""),
        ("cut", text[: len(text) // 2]),
        ("binary", b"\xff\xfe\x00\x01"),
        ("no vehicle", text.replace(b"[vehicle]", b"[vehicles]")),
        ("deep", b"a = " + b"[" * 5000),
        ("twice", text + text),
        ("json", b'{"vehicle": {}}'),
    ):
        cases.append(
            Case(f"config text {label}", ("analyze", "data", "--config", "bad.toml"), (("bad.toml", blob),))
        )
    manifests = {
        "not json": b"{",
        "list": b"[]",
        "no experiments": b"{}",
        "deep": b"[" * 100_000,
        "binary": b"\xff\xfe",
        "string": "h",
        "numbers": [1],
        "outside": ["../data/h"],
        "absolute": ["/etc/passwd"],
        "twice": ["horizontal", "horizontal"],
        "missing": ["gone"],
        "empty list": [],
        "nul": ["a\x00b"],
        "truth": ["horizontal.truth"],
    }
    for label, value in manifests.items():
        text = value if isinstance(value, bytes) else json.dumps({"experiments": value}).encode()
        argv = ("identify", "run", "--out", "out/e.json", *fit)
        cases.append(Case(f"manifest {label}", argv, (("run/manifest.json", text),)))
    for label, name, blob in (
        ("broken truth file", "run/horizontal.truth.csv", b"t,u\n"),
        ("broken model.toml", "run/model.toml", b"[vehicle\n"),
        ("truth file of 1e300", "run/vertical.truth.csv", ("run/vertical.truth.csv", (("scaled 1e300", 2),))),
    ):
        cases.append(Case(f"run {label}", ("identify", "run", "--out", "out/e.json", *fit), ((name, blob),)))
    flags = {
        "identify": {
            "--method": ["nope", ""],
            "--max-iter": ["-1", "x", "1e3", ""],
            "--start": ["nope", ""],
            "--perturb": ["0", "-1", "nan", "inf", "1e400", "x"],
            "--seed": ["-1", "x", "1.5", str(2**70)],
            "--rrd": ["out", "-", "out/no/f.rrd", "keep.txt/f.rrd", "data/h.csv", "keep.txt"],
            "--noise-std": ["r=-1", "yaw=1", "r", "", ",", "r=nan", "r=1e-300", "r=1,r=2", "r=0.002"],
        },
        "analytic": {
            "--speed": ["0", "-1", "nan", "inf", "1e-6", "x", "1e300"],
            "--mjcf": ["data", "missing.xml", "cfg.toml", "/dev/null"],
        },
        "simulate": {
            "--duration": ["0.001", "0.02", "0", "-1", "nan", "1e300", "x"],
            "--seed": ["-1", "x"],
            "--speed": ["0", "1e-6", "nan", "x"],
            "--scenario": ["nope", ""],
            "--mjcf": ["data", "missing.xml", "cfg.toml"],
        },
    }
    base = {
        "identify": ("identify", "run", "--out", "out/e.json", *fit),
        "analytic": ("analytic", "--out", "out/m.toml"),
        "simulate": ("simulate", "--quiet", "--scenario", "I", "--duration", "0.06", "--out", "out/run"),
    }
    for command, options in flags.items():
        for flag, values in options.items():
            for value in values:
                argv = [a for a in base[command]]
                if flag in argv:
                    argv[argv.index(flag) + 1] = value
                else:
                    argv += [flag, value]
                cases.append(Case(f"{command} {flag} {value[:12]!r}", tuple(argv)))
    argv = base["identify"] + ("--method", "mekf", "--start", "config")
    cases.append(Case("identify --start config --method mekf", argv))
    targets = [
        "out",
        "out/no/e.json",
        "keep.txt/e.json",
        "data/h.csv",
        "cfg.toml",
        "run/model.toml",
        "-",
        "keep.txt",
        "null",
        "out/e.json",
    ]
    for target in targets:
        for argv in (
            ("identify", "run", *fit),
            ("identify", "run", "--method", "mekf"),
            ("analyze", "run"),
            ("analytic",),
        ):
            cases.append(Case(f"{argv[0]} {' '.join(argv[2:4])} --out {target}", (*argv, "--out", target)))
    cases.append(Case("analytic --out link.txt", ("analytic", "--out", "link.txt")))
    cases.append(Case("analytic --out keep.txt --force", ("analytic", "--out", "keep.txt", "--force")))
    # through a link, --force replaces the file it names (the link stays)
    cases.append(Case("analytic --out link.txt --force", ("analytic", "--out", "link.txt", "--force")))
    for target in ("out", "keep.txt", "keep.txt/run", "-", "data", "run", "out/new/run"):
        for force in ((), ("--force",)):
            cases.append(
                Case(f"simulate --out {target} {' '.join(force)}", (*base["simulate"][:-1], target, *force))
            )
    issue = [
        (
            "1e300 cell, mekf",
            ("identify", "bad.csv", "--config", "cfg.toml", "--method", "mekf"),
            (("bad.csv", ("data/h.csv", (("cell", 4 * len(CELLS) + 4),))),),
        ),
        (
            "every state x1e300",
            ("identify", "bad.csv", "--config", "cfg.toml"),
            (("bad.csv", ("data/h.csv", (("states scaled 1e300", 0),))),),
        ),
        ("perturb with seed -1", ("identify", "run", "--perturb", "0.2", "--seed", "-1"), ()),
        (
            "only u, lateral free",
            ("identify", "u.csv", "--config", "cfg.toml", "--out", "out/e.json"),
            "u.csv",
        ),
        ("only u, lateral free (analyze)", ("analyze", "u.csv", "--config", "cfg.toml"), "u.csv"),
        (
            "1e300 cell, analyze",
            ("analyze", "bad.csv", "--config", "cfg.toml"),
            (("bad.csv", ("data/h.csv", (("cell", 4 * len(CELLS) + 4),))),),
        ),
        ("N_rdot = Iz, mekf", ("identify", "data", "--config", "iz.toml", "--method", "mekf"), "iz.toml"),
        (
            "dt 200 s",
            ("identify", "bad.csv", "--config", "cfg.toml", "--start", "config"),
            (("bad.csv", ("data/h.csv", (("time x4000", 0),))),),
        ),
    ]
    for label, argv, files in issue:
        if files == "iz.toml":
            broken = json.loads(json.dumps(doc))
            broken["coefficients"]["N_rdot"] = broken["vehicle"]["Iz"]
            files = (("iz.toml", toml_text(broken).encode()),)
        if files == "u.csv":
            rows = _rows((root / "data" / "h.csv").read_bytes())
            keep = [0, 1] + [rows[0].index(n) for n in INPUTS]
            files = (("u.csv", _text([[r[c] for c in keep] for r in rows])),)
        cases.append(Case(f"issue: {label}", argv, files))
    return cases + input_cases(root)


def time_cases(root: Path) -> list[Case]:
    """Bad time and gaps (`TIME_MUTATIONS`) through the commands that read data, and priors a fit
    or a flight cannot take for granted: a course-unstable linear model (N_r positive and large),
    coefficients at the largest magnitude a config may hold (1e15), for the linear and the
    nonlinear model, and a nonlinear term whose product overflows."""
    fit = ("--max-iter", "2")
    commands = {
        "ml-gn": ("identify", "bad.csv", "--config", "cfg.toml", "--out", "out/e.json", *fit),
        "mekf": ("identify", "bad.csv", "--config", "cfg.toml", "--method", "mekf", "--out", "out/e.json"),
        "analyze": ("analyze", "bad.csv", "--config", "cfg.toml", "--out", "out/a.json"),
        "validate": ("validate", "bad.csv", "--config", "cfg.toml", "--out", "out/v.json"),
    }
    cases = []
    for name in TIME_MUTATIONS:
        for where, (label, argv) in enumerate(commands.items()):
            files = (("bad.csv", ("data/h.csv", ((name, where),))),)
            cases.append(Case(f"time: {name} ({label})", argv, files))
    doc = _config_doc(root)
    inertia = {k: v for k, v in doc["coefficients"].items() if k.endswith("dot")}
    priors = {}
    unstable = json.loads(json.dumps(doc))
    unstable["coefficients"]["N_r"] = 50 * abs(doc["coefficients"]["N_r"])
    priors["unstable linear prior (N_r > 0)"] = unstable
    huge = json.loads(json.dumps(doc))
    for k, n in enumerate(FREE):
        huge["coefficients"][n] = (-1) ** k * 1e15
    priors["linear prior at 1e15"] = huge
    for label, terms in (
        ("nonlinear prior at 1e15", {"Y_uv": 1e15, "N_uv": -1e15, "Y_ur": 1e15, "N_ur": -1e15}),
        ("nonlinear term of 3000 factors", {"Y_uv": -100.0, "N_" + "u" * 3000: 0.0}),
    ):
        nonlinear = json.loads(json.dumps(doc))
        nonlinear["coefficients"] = inertia
        nonlinear["terms"] = terms
        nonlinear["identify"] = {"free": list(terms)[:2]}
        priors[label] = nonlinear
    for label, broken in priors.items():
        files = (("bad.toml", toml_text(broken).encode()),)
        for command in (
            ("identify", "data", "--config", "bad.toml", "--out", "out/e.json", *fit),
            ("identify", "data", "--config", "bad.toml", "--method", "mekf", "--out", "out/e.json"),
            ("analyze", "data", "--config", "bad.toml", "--out", "out/a.json"),
            ("validate", "data", "--config", "bad.toml", "--out", "out/v.json"),
        ):
            method = "mekf" if "mekf" in command else command[0]
            cases.append(Case(f"prior: {label} ({method})", command, files))
    return cases


def input_cases(root: Path) -> list[Case]:
    """The bad input of the scenario files, estimates, names and campaigns: deep nesting in every
    reader, names that cannot be file names, values a scenario file gives, a fit with all 35
    coefficients free, and `reproduce` on a user's folder, with absurd seeds or no scheduler."""
    from testbed.simulation.scenario import SCENARIO_DIR

    scenario = (SCENARIO_DIR / "II.toml").read_text().replace("duration = 60.0", "duration = 0.5")

    def edited(**changes) -> bytes:
        text = scenario
        for old, new in changes.items():
            text = text.replace(old, new)
        return text.encode()

    deep_toml, deep_json = b"a = " + b"[" * 100_000, b'{"coefficients": ' + b"[" * 100_000
    names = {
        "scenario name ../escaped": {'name = "II"': 'name = "../escaped"'},
        "scenario name ..": {'name = "II"': 'name = ".."'},
        "scenario name with NUL": {'name = "II"': 'name = "a\\u0000b"'},
        "scenario name of 300 bytes": {'name = "II"': f'name = "{"n" * 300}"'},
        "experiment name with NUL": {'name = "horizontal"': 'name = "hor\\u0000izontal"'},
        "experiment name of 300 bytes": {'name = "horizontal"': f'name = "{"h" * 300}"'},
        "experiment name with a backslash": {'name = "horizontal"': 'name = "a\\\\b"'},
        "scenario speed 30 (autopilots unstable)": {"duration = 0.5": "duration = 0.5\nspeed = 30.0"},
        "scenario duration 1e7": {"duration = 0.5": "duration = 10000000.0"},
        "experiment duration 1e7": {'name = "roll"': 'name = "roll"\nduration = 1e7'},
        "scenario speed 1e-6": {"duration = 0.5": "duration = 0.5\nspeed = 1e-6"},
        "scenario feedback 'sensors'": {"duration = 0.5": 'duration = 0.5\nfeedback = "sensors"'},
        "scenario feedback 1": {"duration = 0.5": "duration = 0.5\nfeedback = 1"},
        "scenario feedback a table": {"duration = 0.5": "duration = 0.5\nfeedback = {measured = true}"},
    }
    cases = [
        Case(
            f"input: {label}",
            ("simulate", "--scenario", "s.toml", "--quiet"),
            (("s.toml", edited(**changes)),),
        )
        for label, changes in names.items()
    ]
    cases += [
        Case(
            "input: scenario nested 100 000 deep",
            ("simulate", "--scenario", "s.toml", "--quiet"),
            (("s.toml", deep_toml),),
        ),
        Case(
            "input: estimates nested 100 000 deep (validate)",
            ("validate", "run", "--estimates", "est.json", "--out", "out/v.json"),
            (("est.json", deep_json),),
        ),
        Case(
            "input: estimates nested 100 000 deep (design)",
            ("design", "--from", "est.json", "--out", "out/d.toml"),
            (("est.json", deep_json),),
        ),
        Case(
            "input: --duration on a scenario file",
            ("simulate", "--scenario", "s.toml", "--duration", "1e-6", "--quiet"),
            (("s.toml", edited()),),
        ),
    ]
    every = re.sub(
        r"^free = .*$",
        "free = [" + ", ".join(f'"{n}"' for n in COEFFICIENTS) + "]",
        (root / "run" / "model.toml").read_text(),
        flags=re.M,
    )
    cases.append(
        Case(
            "input: identify --free-all, all 35 free",
            ("identify", "run", "--config", "all.toml", "--free-all", "--out", "out/e.json"),
            (("all.toml", every.encode()),),
        )
    )
    mine = (("mine/results.csv", b"my results\n"), ("mine/notes.txt", b"my notes\n"))
    for label, argv, files in (
        ("a user's folder", ("--quick", "--out", "mine"), mine),
        ("a user's file", ("--quick", "--out", "keep.txt"), ()),
        ("seeds 1e9", ("--seeds", "1000000000", "--out", "out/study"), ()),
        ("seeds 0", ("--seeds", "0", "--out", "out/study"), ()),
        ("a malformed scheduler", ("--scheduler", "not an address", "--out", "out/study"), ()),
        ("no scheduler listening", ("--scheduler", "tcp://127.0.0.1:1", "--out", "out/study"), ()),
    ):
        cases.append(Case(f"input: reproduce, {label}", ("reproduce", *argv), files))
    return cases


# -- running and tallying ------------------------------------------------------------------------


@dataclass(frozen=True)
class Outcome:
    label: str
    code: int
    out: str
    err: str
    kind: str  # ok, error, crash
    partial: str  # what was written on failure or changed among the inputs ("" if nothing)


def prepare(ws: Path, case: Case) -> Path:
    """A fresh copy of the workspace with the case's files written in, and `null`: a character
    device like /dev/null where the system lets us make one (never the real one: an output that
    replaced it would break the machine)."""
    root = Path(tempfile.mkdtemp(prefix="fuzz-"))
    shutil.copytree(ws, root, dirs_exist_ok=True, symlinks=True)
    with contextlib.suppress(OSError):
        os.mknod(root / "null", stat.S_IFCHR | 0o666, os.makedev(1, 3))
    for name, content in case.files:
        if isinstance(content, tuple):
            source, mutations = content
            content = (ws / source).read_bytes()
            for mutation, where in mutations:
                content = apply_csv_mutation(content, mutation, where)
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(content)
    return root


@contextlib.contextmanager
def _captured():
    """Standard output and error at the file-descriptor level (C libraries' prints included):
    yields a dict filled with their text when the block ends."""
    got = {}
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    files = [tempfile.TemporaryFile(), tempfile.TemporaryFile()]
    py = sys.stdout, sys.stderr
    try:
        for fd, f in zip((1, 2), files):
            os.dup2(f.fileno(), fd)
        sys.stdout = io.TextIOWrapper(os.fdopen(os.dup(1), "wb"), write_through=True)
        sys.stderr = io.TextIOWrapper(os.fdopen(os.dup(2), "wb"), write_through=True)
        yield got
    finally:
        for s in (sys.stdout, sys.stderr):
            s.flush()
            s.close()
        sys.stdout, sys.stderr = py
        for fd, old in zip((1, 2), saved):
            os.dup2(old, fd)
            os.close(old)
        for key, f in zip(("out", "err"), files):
            f.seek(0)
            got[key] = f.read().decode(errors="replace")
            f.close()


def run_in_process(argv, cwd: Path) -> tuple[int, str, str]:
    from testbed.cli import main

    here = os.getcwd()
    os.chdir(cwd)
    try:
        with _captured() as got, warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # a numpy warning would be an extra line
            try:
                code = main(list(argv))
            except SystemExit as exc:
                code = exc.code
    finally:
        os.chdir(here)
    return code, got["out"], got["err"]


def run_subprocess(argv, cwd: Path) -> tuple[int, str, str]:
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    done = subprocess.run(
        [sys.executable, "-m", "testbed", *argv],
        cwd=cwd,
        capture_output=True,
        text=True,
        env=env,
        stdin=subprocess.DEVNULL,
        timeout=600,
    )
    return done.returncode, done.stdout, done.stderr


def _is_output(path: str, argv, before: dict) -> bool:
    """Whether `path` is one of the outputs `argv` names (--out, --rrd, the history), the file a
    named symbolic link points to (`before`: the snapshot; a link names its target's file, which
    `--force` replaces), inside one (a run directory) or a folder made for one."""
    targets = [argv[k + 1] for k, a in enumerate(argv[:-1]) if a in ("--out", "--rrd")]
    targets += [str(Path(t).with_suffix(".history.csv")) for t in targets]
    targets += [
        os.path.normpath(os.path.join(os.path.dirname(t), before[t][len("link:") :]))
        for t in targets
        if str(before.get(t, "")).startswith("link:")
    ]
    return any(path == t or path.startswith(t.rstrip("/") + "/") or t.startswith(path + "/") for t in targets)


def _was_file(kind: str | None) -> bool:
    """Whether a `snapshot` entry is a regular file's (its hash)."""
    return kind is not None and kind != "dir" and not kind.startswith(("link:", "node:"))


def judge(argv, code, out, err, before: dict, after: dict) -> tuple[str, str]:
    """(kind, partial) of one run: see the module docstring."""
    changed = sorted(p for p in set(before) | set(after) if before.get(p) != after.get(p))
    failed = code not in (0, 1)
    replaced = "--force" not in argv  # a file that was there is replaced only when asked for
    partial = [
        p
        for p in changed
        if failed or not _is_output(p, argv, before) or (replaced and _was_file(before.get(p)))
    ]
    named = [a for a in argv if a] + [Path(a).name for a in argv if a]
    blamed = re.match(r"testbed \S+: error: (--[\w-]+)", err)  # the flag the error starts with
    if code in (0, 1) and "Traceback" not in err + out:
        kind = "ok"
    elif (
        code == 2
        and err.count("\n") == 1
        and "Traceback" not in err
        and any(a in err for a in named)
        and (blamed is None or blamed.group(1) in argv)
    ):
        kind = "error"
    else:
        kind = "crash"
    return kind, ", ".join(partial)


def run_case(ws: Path, case: Case, runner=run_in_process) -> Outcome:
    root = prepare(ws, case)
    try:
        before = snapshot(root)
        code, out, err = runner(case.argv, root)
        kind, partial = judge(case.argv, code, out, err, before, snapshot(root))
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return Outcome(case.label, code, out, err, kind, partial)


def tally(outcomes: list[Outcome]) -> dict[str, int]:
    return {
        "cases": len(outcomes),
        "ok": sum(o.kind == "ok" for o in outcomes),
        "errors": sum(o.kind == "error" for o in outcomes),
        "crashes": sum(o.kind == "crash" for o in outcomes),
        "partial_outputs": sum(bool(o.partial) for o in outcomes),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--subprocess", action="store_true", help="run each case as `python -m testbed`")
    ap.add_argument("--every", type=int, default=1, help="run every N-th case only")
    ap.add_argument("--verbose", action="store_true", help="print every case's status and stderr")
    args = ap.parse_args(argv)
    runner = run_subprocess if args.subprocess else run_in_process
    with tempfile.TemporaryDirectory() as tmp:
        ws = workspace(Path(tmp))
        cases = (corpus(ws) + time_cases(ws))[:: args.every]
        outcomes = []
        for case in cases:
            o = run_case(ws, case, runner)
            outcomes.append(o)
            if args.verbose or o.kind == "crash" or o.partial:
                last = o.err.strip().splitlines()[-1:] or [""]
                print(
                    f"{o.kind:5} {o.code:3} {o.label}: {last[0][:160]}"
                    + (f" [written/changed: {o.partial}]" if o.partial else "")
                )
    counts = tally(outcomes)
    print(" ".join(f"{k}={v}" for k, v in counts.items()))
    return 0 if counts["crashes"] == 0 and counts["partial_outputs"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
