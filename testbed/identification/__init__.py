"""The numerical core of identification, for the linear model and the nonlinear one: the
output-error problem (`problem`), the recursions over the samples (`scan`, compiled in
`kernels`), the linear model's states and exact sensitivities (`recursions`), the likelihood
(`likelihood`), the nonlinear model's flight and exact sensitivities
(`nonlinear_sensitivities`), the Fisher information and Cramér-Rao bounds (`bounds`), the
models' predictions and synthetic data (`prediction`, `nonlinear_prediction`), the nonlinear
model's one-sample transition for the filters (`nonlinear_transition`), the cost with the
initial states concentrated out (`concentrated`), the model with process noise and its Kalman
filter (`innovations`), the nonlinear model's output-error likelihood
(`nonlinear_output_error`), and the likelihood as an optimiser sees it whatever the model
(`objective`), for the linear model (`linear_objective`) and the nonlinear one
(`nonlinear_objective`). The estimators themselves are `testbed.estimators`.
"""

__all__: list[str] = []
