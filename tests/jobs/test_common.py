"""`identify --perturb-spread S`: every free start × exp(S·N(0, 1)), the log-normal errors of an
a-priori model, seeded (`jobs.spread`)."""

import json

import numpy as np
from scipy import stats

from testbed.cli import main
from testbed.data import write_config, write_csv
from studies import remus as examples
from testbed.jobs.common import spread


def test_the_starts_are_log_normal_around_the_config_with_the_spread_asked():
    """Over 200 seeds each free start's log-ratio to the config's value is N(0, S²) by
    Kolmogorov-Smirnov; signs kept, a fixed coefficient untouched, a seed repeats its draw."""
    config = examples.prior_config()
    S = 0.3
    ratios = np.array(
        [
            [spread(config, S, seed).coefficients[n] / config.coefficients[n] for n in config.free]
            for seed in range(200)
        ]
    )
    assert np.all(ratios > 0)
    assert stats.kstest(np.log(ratios).ravel() / S, "norm").pvalue > 0.01
    fixed = [n for n in config.coefficients if n not in config.free]
    moved = spread(config, S, 7)
    assert fixed and all(moved.coefficients[n] == config.coefficients[n] for n in fixed)
    assert moved.coefficients == spread(config, S, 7).coefficients != spread(config, S, 8).coefficients
    assert "perturb-spread=0.3" in moved.source


def test_the_command_fits_from_the_spread_start(tmp_path, capsys):
    """With no iteration (`--start config --max-iter 0`) the estimate is the start drawn; with the
    default options the fit from it lands within 4 σ of the model that flew."""
    paths = []
    for e in examples.experiments(3, duration=30.0):
        paths.append(tmp_path / f"{e.name}.csv")
        write_csv(paths[-1], e.t, e.y, e.inputs)
    config = tmp_path / "model.toml"
    write_config(config, examples.example_config())
    args = [*map(str, paths), "--config", str(config), "--perturb-spread", "0.3", "--seed", "5", "--free-all"]
    main(["identify", *args, "--start", "config", "--max-iter", "0", "--out", str(tmp_path / "start.json")])
    start = json.loads((tmp_path / "start.json").read_text())["coefficients"]
    drawn = spread(examples.example_config(), 0.3, 5)
    assert {n: c["value"] for n, c in start.items()} == {n: drawn.coefficients[n] for n in drawn.free}
    assert main(["identify", *args, "--out", str(tmp_path / "fit.json")]) == 0, capsys.readouterr().err
    truth = examples.EXAMPLE_COEFFICIENTS
    for n, c in json.loads((tmp_path / "fit.json").read_text())["coefficients"].items():
        assert abs(c["value"] - truth[n]) <= 4 * c["std"], n
