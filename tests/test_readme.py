"""The README's Python example runs as written, and its fit lands where its Cramér-Rao bounds say."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"
# The z of a coefficient within which its estimate must lie: for an efficient, unbiased fit each
# error is N(0, σ²) with σ the Cramér-Rao bound, so 4 σ is exceeded with probability 6e-5 per
# coefficient, under 0.2 % for the twenty the screen may free.
SIGMAS = 4.0
# The linear model's own bias on Scenario II, which no noise level removes: the fit to the
# plant's noise-free data is within 1 % of the analytic model, 3 % in the roll row
# (tests/simulation/test_plant_data.py, test_noise_free_fit_is_the_analytic_model).
BIAS = 0.01
ROLL_ROW_BIAS = 0.03


def test_the_python_example_runs_and_its_fit_agrees_with_the_analytic_model(tmp_path, monkeypatch, capsys):
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## From Python") :]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    names = {"__name__": "readme"}
    exec(compile(code, "README.md", "exec"), names)
    printed = capsys.readouterr().out
    assert (tmp_path / "runs" / "api-demo" / "manifest.json").is_file()
    estimate, analytic, bounds = names["estimate"], names["analytic"], names["bounds"]
    assert estimate.converged, estimate.status.message
    assert estimate.status.message in printed
    # The bounds are the example's own: Fisher information at the analytic values.
    assert tuple(bounds.free) == tuple(estimate.free) and len(estimate.free) >= 10
    want = np.array([analytic.coefficients[n] for n in estimate.free])
    bias = np.array([ROLL_ROW_BIAS if n.startswith("K_") else BIAS for n in estimate.free])
    error = np.abs(estimate.values - want)
    far = [
        (n, v, a, s)
        for n, v, a, s, e, b in zip(estimate.free, estimate.values, want, bounds.crlb_std, error, bias)
        if e > SIGMAS * s + b * abs(a)
    ]
    assert far == [], far
    for n in estimate.free:  # the comparison with the analytic model is printed
        assert re.search(rf"^{n}\s", printed, re.M), n
