"""testbed: simulate a submerged body in MuJoCo and identify its manoeuvring coefficients.

Data flows vehicle -> plant -> scenario -> measurements -> model -> estimators -> analysis -> report.
"""

__version__ = "0.1.0"
