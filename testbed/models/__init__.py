"""The models: the equations of motion the data are fitted with, in layer order.

- `linear`: the paper's linear model `Mt ẋ = At x + Bt δ + St`, its coefficients, states,
  offsets, output biases, current, mounting and delay, and its exact discretisation;
- `cholesky`: small positive definite systems solved inside compiled kernels;
- `sensors`: the measurement model, each sensor's outputs from the state and its inverse;
- `log_mounting`: a velocity log's mounting read through the linear model's outputs;
- `component_kernels`, `components`: the fluid forces of a vehicle's components (hull, fin
  blades) per unit coefficient with exact derivatives, compiled;
- `regressors`, `mechanics`: the nonlinear model's named hydrodynamic terms and its exact
  Kirchhoff, restoring and kinematic parts;
- `nonlinear_kernels`, `nonlinear`: the nonlinear model's state derivative, Jacobians and RK4
  flight (compiled), the model itself and its linearisation;
- `nonlinear_flight`: the nonlinear model flown open loop from recorded fin angles, and its
  sensitivities in the same pass.
"""

__all__: list[str] = []
