"""Results in a notebook: `Estimate`, `Validation`, `Comparison` and the identifiability result
render as HTML tables and inline SVG figures (`_repr_html_`), the numbers the terminal tables and
the JSON hold, every cell and label escaped."""

from dataclasses import replace
from html.parser import HTMLParser

import pytest

from testbed import identify
from testbed.analysis.validation import validate
from testbed.html_table import html_table
from studies import remus as examples


class Tables(HTMLParser):
    """The text of every cell, per table and row; the captions."""

    def __init__(self, text: str):
        super().__init__()
        self.tables, self.captions, self._cell, self._in = [], [], None, None
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.tables.append([])
        elif tag == "tr":
            self.tables[-1].append([])
        elif tag in ("td", "th", "caption"):
            self._cell, self._in = "", tag

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self.tables[-1][-1].append(self._cell)
        elif tag == "caption":
            self.captions.append(self._cell)
        if tag in ("td", "th", "caption"):
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data


@pytest.fixture(scope="module")
def fitted():
    experiments = examples.experiments(2, duration=30.0)
    return experiments, identify(experiments, examples.prior_config(), "ml-gn")


def test_an_estimate_shows_how_it_ended_its_coefficients_and_noise(fitted):
    _, est = fitted
    t = Tables(est._repr_html_())
    coefficients, noise = t.tables
    assert coefficients[0] == ["coefficient", "estimate", "σ (Cramér-Rao)", "σ (coloured residuals)"]
    assert [r[0] for r in coefficients[1:]] == list(est.free)
    for row, v, s, c in zip(coefficients[1:], est.values, est.std, est.crlb_corrected_std):
        assert (float(row[1]), float(row[2]), float(row[3])) == pytest.approx((v, s, c), rel=1e-2)
    assert t.captions[0].startswith(f"ml-gn: {est.status.message}, {est.iterations} iterations")
    assert {r[0] for r in noise[1:]} == set(est.noise_std)


def test_a_validation_shows_the_terminal_tables_rows_escaped(fitted):
    experiments, est = fitted
    odd = [replace(e, name=f"<b>{e.name} & co</b>") for e in experiments]
    v = validate(odd, examples.prior_config().with_coefficients(est.coefficients))
    text = v._repr_html_()
    assert "<b>" not in text.replace("<tbody>", "") and "&lt;b&gt;horizontal &amp; co&lt;/b&gt;" in text
    rows = Tables(text).tables[0]
    head, body = v.rows()
    assert rows == [list(head), *map(list, body)]
    assert len(body) == sum(len(e.measured) for e in experiments)
    lines = v.table().splitlines()
    assert len(lines) == len(body) + 1 and all(r[2] in line for r, line in zip(body, lines[1:]))


def test_numbers_right_aligned_text_not():
    text = html_table(("a", "b"), [("x", 1.5), ("y", "12.0%")])
    assert '<td style="text-align:right">1.5</td>' in text and "<td>x</td>" in text
    assert '<td style="text-align:right">12.0%</td>' in text


def test_a_comparison_and_an_analysis_show_their_rows(fitted):
    import numpy as np

    from testbed import analyze, compare

    experiments, est = fitted
    c = compare(est, examples.example_config())
    rows = Tables(c._repr_html_()).tables[0]
    assert rows[0][:3] == ["coefficient", "analytic", "identified"] and len(rows) == len(est.free) + 1
    for row, r in zip(rows[1:], c.rows()):
        assert row[0] == r["name"] and float(row[2]) == pytest.approx(r["identified"], rel=1e-3)
    assert [line.split()[0] for line in c.table().splitlines()[1:]] == list(est.free)
    a = analyze(experiments, examples.prior_config().with_coefficients(est.coefficients))
    t = Tables(a._repr_html_())
    bounds = t.tables[0]
    assert [r[0] for r in bounds[1:]] == list(a.free)
    for row, sd in zip(bounds[1:], a.crlb_std):
        assert row[2] == "∞" if not np.isfinite(sd) else float(row[2]) == pytest.approx(sd, rel=1e-2)
    assert t.captions[0] == "identifiability"


SVG = "{http://www.w3.org/2000/svg}"


def _figures(text: str):
    """Each inline `<svg>` of a notebook rendering, parsed (so well formed) as an XML tree."""
    import re
    import xml.etree.ElementTree as ET

    return [ET.fromstring(s) for s in re.findall(r"<svg .*?</svg>", text, re.S)]


def _dots(svg) -> dict[str, tuple[float, float]]:
    """name → (the value in its tooltip, the dot's x) of an `svg_dots` figure."""
    out = {}
    for c in svg.iter(f"{SVG}circle"):
        name, value = c.find(f"{SVG}title").text.rsplit(": ", 1)
        out[name] = (float(value), float(c.get("cx")))
    return out


def _increasing(dots: dict[str, tuple[float, float]]) -> bool:
    """The dots' x grows with their values: the axis is one affine map."""
    pairs = sorted(dots.values())
    return all(b[1] > a[1] for a, b in zip(pairs, pairs[1:]) if b[0] > a[0])


def test_each_result_draws_its_figure_beside_its_table(fitted):
    """The notebook figures are drawn from the result's own numbers: the estimate's relative
    bounds, the validation's fit %, the comparison's errors in σ and the analysis' correlations,
    every dot where its value puts it and every label escaped."""

    from testbed import analyze, compare

    experiments, est = fitted
    (figure,) = _figures(est._repr_html_())
    dots = _dots(figure)
    assert list(dots) == list(est.free) and _increasing(dots)
    for n, v, s in zip(est.free, est.values, est.std):
        assert dots[n][0] == pytest.approx(200 * s / abs(v), rel=5e-4)
    assert "2σ / |estimate| (%)" in "".join(t.text or "" for t in figure.iter(f"{SVG}text"))

    odd = [replace(e, name=f"<b>{e.name}</b>") for e in experiments]
    v = validate(odd, examples.prior_config().with_coefficients(est.coefficients))
    (figure,) = _figures(v._repr_html_())
    dots = _dots(figure)
    for e, channels in v.experiments.items():
        for c, m in channels.items():
            name = f"{e} {c}{'' if m.whiteness.white else ' (coloured)'}"
            assert dots[name][0] == pytest.approx(m.fit_percent, rel=5e-4), name
    assert _increasing(dots) and any(n.startswith("<b>") for n in dots)  # escaped in the text, read back

    c = compare(est, examples.example_config())
    (figure,) = _figures(c._repr_html_())
    dots = _dots(figure)
    for r in c.rows():
        assert dots[r["name"]][0] == pytest.approx(r["error_sigmas"], rel=5e-4, abs=1e-4)
    assert _increasing(dots) and len(list(figure.iter(f"{SVG}rect"))) == 1  # the ±2σ band

    a = analyze(experiments, examples.prior_config().with_coefficients(est.coefficients))
    (figure,) = _figures(a._repr_html_())
    cells = {r.find(f"{SVG}title").text.rsplit(": ", 1)[0]: r for r in figure.iter(f"{SVG}rect")}
    assert len(cells) == len(a.free) ** 2
    for i, p in enumerate(a.free):
        for j, q in enumerate(a.free):
            value = float(cells[f"{p}, {q}"].find(f"{SVG}title").text.rsplit(": ", 1)[1])
            assert value == pytest.approx(a.correlation[i, j], abs=6e-4)
    # +1 full red, −1 full blue: the diagonal, and the colour's side the correlation's sign
    assert all(cells[f"{p}, {p}"].get("fill") == "#c0392b" for p in a.free)
    for i, p in enumerate(a.free):
        for j, q in enumerate(a.free):
            red, blue = (int(cells[f"{p}, {q}"].get("fill")[k : k + 2], 16) for k in (1, 5))
            assert (red >= blue) == (a.correlation[i, j] >= 0) or abs(a.correlation[i, j]) < 0.01, (p, q)
