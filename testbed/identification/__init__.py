"""The numerical core of identification, for the linear model: the output-error problem
(`problem`), the recursions over the samples (`scan`, compiled in `kernels`), the model's states
and exact sensitivities (`recursions`), the likelihood (`likelihood`), the Fisher information and
Cramér-Rao bounds (`bounds`), the model's predictions and synthetic data (`prediction`), and the
example vehicle's exactly simulated experiments (`examples`). The estimators themselves are
`testbed.estimators`.
"""

__all__: list[str] = []
