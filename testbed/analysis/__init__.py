"""What a fit means, in layer order: validation metrics (`validation`), the linear model's
structural identifiability (`structural`), an estimate against the analytic model
(`comparison`), the compatibility check's kinematics (`kinematics`), the profile likelihood
(`profile`), identifiability from data (`identifiability`), the screen of a candidate list
(`screening`), the linear regime (`regime`), the nonlinear model's identifiability and screen
(`nonlinear_identifiability`), the data's kinematic compatibility before any fit
(`compatibility_checks`, `compatibility_records`, `compatibility_fit`, `compatibility`) and its
corrections applied (`corrections`), experiment design (`design_model`, `design_signals`,
`design`), simultaneous drift in
practice (`drift`), and the manoeuvre metrics (`instants`, `track`, `turning`, `zigzag`,
`manoeuvres`).
"""

__all__: list[str] = []
