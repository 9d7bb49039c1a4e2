"""A component model config: its [components.NAME] tables read, checked and written back exactly,
bad tables refused in one line naming the table and key, and the config behind `identify` and
`validate` on a record the component model flew."""

from __future__ import annotations

import json
import os
import tomllib
from dataclasses import replace

import numpy as np
import pytest

from test_bad_input import cli
from testbed.data import (
    Experiment,
    ModelConfig,
    check_config,
    config_text,
    parse_config,
    write_config,
    write_csv,
)
from testbed.errors import InputError
from testbed.models.linear import STATES
from testbed.models.nonlinear import INERTIA
from testbed.models.nonlinear_flight import fly_nonlinear
from testbed.simulation.analytic import analytic, analytic_config
from testbed.captive.fluid_components import component_terms, mjcf_components
from testbed.simulation.measurements import NOISE_STD
from testbed.simulation.vehicle import load_model

FREE = ("lift@rudder_upper", "lift@elevator_right", "blunt@hull")


@pytest.fixture(scope="module")
def config():
    """The torpedo's component model at the MJCF's coefficients, FREE free."""
    mjcf, lin = load_model(), analytic()
    return ModelConfig(
        vehicle=lin.vehicle,
        coefficients={n: lin.coefficients[n] for n in INERTIA},
        free=FREE,
        terms=component_terms(mjcf),
        components=mjcf_components(mjcf),
    )


def read_config_text(text, source="c.toml"):
    return parse_config(tomllib.loads(text), source)


def test_the_tables_round_trip_exactly(config):
    text = config_text(config)
    again = read_config_text(text)
    assert again.components == config.components and dict(again.terms) == dict(config.terms)
    assert config_text(again) == text
    assert "[components.rudder_upper]" in text and 'fin = "dr"' in text


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda t: t.replace("density = 1025.0\n", "", 1), ["[components.hull]", "density missing"]),
        (
            lambda t: t.replace("[components.hull]\n", "[components.hull]\ncolour = 1\n", 1),
            ["unknown key 'colour'"],
        ),
        (
            lambda t: t.replace('fin = "dr"', 'fin = "aileron"', 1),
            ["[components.rudder_upper]", "fin 'aileron'"],
        ),
        (lambda t: t.replace("axes = [", "axes = [0.2, ", 1), ["[components.hull]", "axes must be 3"]),
        (lambda t: t.replace("axes = [", 'axes = ["x", ', 1), ["[components.hull] axes"]),
        (lambda t: t.replace('"blunt@hull"', '"blunt@keel"', 1), ["blunt@keel", "no component 'keel'"]),
        (
            lambda t: t.replace("[components.hull]\n", "[components.hull]\nhinge = [0.0, 0.0, 0.0]\n", 1),
            ["hinge without fin"],
        ),
        (lambda t: t.replace("[components.hull]", '[components."hull\\nx"]', 1), ["letters, digits"]),
    ],
)
def test_bad_tables_are_one_line_errors(config, edit, words):
    text = edit(config_text(config))
    with pytest.raises(InputError) as e:
        read_config_text(text)
    message = str(e.value)
    assert "\n" not in message and message.startswith("c.toml")
    for w in words:
        assert w in message, message


def test_a_component_given_twice_is_refused(config):
    twice = replace(config, components=config.components + config.components[:1])
    with pytest.raises(InputError, match=r"\[components.hull\] given twice"):
        check_config(twice)


def test_components_in_a_linear_config_are_refused():
    linear = config_text(analytic_config()[0])
    with pytest.raises(InputError, match=r"\[components\] in a linear model config"):
        read_config_text(linear + "\n[components.hull]\naxes = [1.0, 1.0, 1.0]\n")


@pytest.fixture(scope="module")
def files(config, tmp_path_factory):
    """A 6 s record the component model flew through 1° rudder and elevator doublets, with the
    sensors' noise; the config that flew it and a start with FREE moved 20 %."""
    model, theta = config.nonlinear()
    t = np.arange(301) * 0.02
    a = np.radians(1.0)
    fins = np.zeros((len(t), 3))
    fins[(t >= 0.5) & (t < 1.0), 0], fins[(t >= 1.0) & (t < 1.5), 0] = a, -a
    fins[(t >= 3.0) & (t < 3.5), 1:], fins[(t >= 3.5) & (t < 4.0), 1:] = a, -a
    x0 = np.array([config.vehicle.speed, 0.1, -0.1, 0.01, 0.02, -0.01, 0.02, -0.01, 0.3, 1.0])
    x = fly_nonlinear(model, theta, t, x0, fins)
    noisy = x + np.random.default_rng(2).normal(size=x.shape) * np.array([NOISE_STD[s] for s in STATES])
    root = tmp_path_factory.mktemp("components")
    write_csv(root / "doublets.csv", t, noisy, fins)
    write_config(root / "truth.toml", config)
    start = config.with_coefficients(
        {n: config.terms[n] * (1.2 if k % 2 else 0.8) for k, n in enumerate(FREE)}
    )
    write_config(root / "start.toml", start)
    return root, Experiment("doublets", t, STATES, noisy, fins)


def test_identify_and_validate_a_component_config_on_the_command_line(config, files, capsys, tmp_path):
    root, _ = files
    out = tmp_path / "e.json"
    code, _, err = cli(
        capsys,
        "identify",
        root / "doublets.csv",
        "--config",
        root / "start.toml",
        "--method",
        "ml-gn",
        "--out",
        out,
    )
    assert code == 0, err
    doc = json.loads(out.read_text())
    for n in FREE:  # the truth within 3 σ from 20 % off
        c = doc["coefficients"][n]
        assert abs(c["value"] - config.terms[n]) <= 3 * c["std"], (n, c, config.terms[n])
    fits = {}
    for which in ("truth", "start"):
        out = tmp_path / f"{which}.json"
        code, _, err = cli(
            capsys, "validate", root / "doublets.csv", "--config", root / f"{which}.toml", "--out", out
        )
        assert code == 0, err
        fits[which] = json.loads(out.read_text())["validation"]["doublets"]
    for s in ("v", "r", "w", "q"):  # the config that flew the record predicts it better than the start
        assert fits["truth"][s]["fit_percent"] > fits["start"][s]["fit_percent"], s


def test_a_bad_component_table_through_the_command_line_writes_nothing(files, capsys, tmp_path):
    root, _ = files
    bad = tmp_path / "bad.toml"
    bad.write_text((root / "truth.toml").read_text().replace('fin = "der"', 'fin = "flap"', 1))
    out = tmp_path / "e.json"
    code, _, err = cli(
        capsys, "identify", root / "doublets.csv", "--config", bad, "--method", "ml-gn", "--out", out
    )
    assert code == 2 and err.count("\n") == 1 and "fin 'flap'" in err and "bad.toml" in err, err
    assert os.listdir(tmp_path) == ["bad.toml"]


def test_a_config_whose_flight_overflows_is_refused_where_it_is_flown_and_a_start_where_it_is_fitted(
    files, capsys, tmp_path
):
    """A hull drag of 1e15 throws the flight out of the floating-point range within a step, where
    the mass matrix with the blades' Munk terms has no inverse: `validate` and `analyze` (after
    the records cut into segments, none short enough) say so in one line naming the config, and
    write nothing; `identify` skips the screen's first step, saying why, and fits from the start
    that flies (equation error), as from any prior."""
    root, _ = files
    huge = tmp_path / "huge.toml"
    huge.write_text(
        "\n".join(
            '"blunt@hull" = 1e15' if line.startswith('"blunt@hull" =') else line
            for line in (root / "truth.toml").read_text().splitlines()
        )
    )
    out = tmp_path / "out.json"
    code, _, err = cli(capsys, "validate", root / "doublets.csv", "--config", huge, "--out", out)
    assert code == 2 and err.count("\n") == 1, err
    assert "huge.toml's model flown" in err and "expected a model whose flight stays bounded" in err, err
    code, _, err = cli(capsys, "analyze", root / "doublets.csv", "--config", huge, "--out", out)
    assert code == 2 and err.count("\n") == 1, err
    assert "huge.toml: the model diverges at these coefficients even on" in err, err
    assert os.listdir(tmp_path) == ["huge.toml"]
    code, _, err = cli(capsys, "identify", root / "doublets.csv", "--config", huge, "--out", out)
    doc = json.loads(out.read_text())
    assert code == 0 and doc["start"] == "equation-error", err
    assert "huge.toml: the model diverges at these coefficients even on" in doc["screen_skipped"]
