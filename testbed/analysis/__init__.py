"""What a fit means: identifiability (`identifiability`: Fisher information, Cramér-Rao bounds,
drift groups, the screen, the comparison with the analytic model), validation metrics
(`validation`), experiment design (`design`), before any fit the data's kinematic
compatibility (`compatibility`: sensor biases, scale factors and delays), and the manoeuvre
metrics of turning circles and zigzags (`manoeuvres`, `turning`, `zigzag`).
"""

__all__: list[str] = []
