"""Virtual captive tests of an MJCF body and the nonlinear model fitted to them, in the order the
work flows: the water's force and moment on the body held in a prescribed motion (`wrench`),
the MJCF's fluid geoms as components and their terms (`fluid_components`), the rig's static
sweeps and oscillatory tests with their in-phase and quadrature parts (`rig`), the nonlinear
model fitted to the measurements with the fit of every force surface (`fit`), the captive
reference over a manoeuvre's region (`reference`: slopes at trim, then the rest) and its
nonlinear model config (`config`, `testbed captive`).
"""

__all__: list[str] = []
