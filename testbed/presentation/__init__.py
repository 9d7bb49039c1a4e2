"""How results are shown: Rerun recordings of fits (`report`), the experiment design's files
(`design_report`), the captive tests' figures and recording (`captive_sweeps`,
`captive_figures`, `captive_recording`, `captive_report`), the campaign's figures and
report.html (`figures`), and a fit's HTML report (`fit_figures`, `fit_report`).
"""

__all__: list[str] = []
