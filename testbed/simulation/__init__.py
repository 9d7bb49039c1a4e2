"""The simulation, in the order a run is made: sensor noise (`measurements`), the MJCF vehicle
(`vehicle`), its completed plant (`plant`, its compiled step `plant_step`; the linear model
flown as a plant, `linear_plant`),
the plant set at a model state (`states`), the analytic linear model (`analytic`), autopilots
and input signals (`autopilot`, `signals`), the truth's named sensors (`sensing`), a trial's
imperfections (`trial`), a scenario's a-priori model (`prior`), an imperfect trial's flight
(`imperfect`), scenario files (`scenario`) and their flight (`flight`), Rerun recordings of
runs (`recording`) and run directories (`runs`). The built-in scenarios (`scenarios/*.toml`)
are package data; the bundled torpedo is the project's `assets/mjcf/torpedo.xml`, shipped as
`testbed/vehicles/` (`vehicle.vehicles`). Virtual captive tests are `testbed.captive`.
"""

__all__: list[str] = []
