"""The models: the equations of motion the data are fitted with.

- `linear`: the paper's linear model `Mt ẋ = At x + Bt δ + St`, its coefficients and states.
"""

__all__: list[str] = []
