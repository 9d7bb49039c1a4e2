"""The numerical core of identification: the linear model's output-error likelihood, its
sensitivities and Cramér-Rao bounds (`outputerror`, with its compiled recursions in `kernels`),
and the example vehicle's exactly simulated experiments (`examples`). The estimators themselves
are `testbed.estimators`.
"""

__all__: list[str] = []
