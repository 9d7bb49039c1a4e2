"""What a fit means: identifiability (`identifiability`: Fisher information, Cramér-Rao bounds,
drift groups, the screen, the comparison with the analytic model), validation metrics
(`validation`) and experiment design (`design`).
"""

__all__: list[str] = []
