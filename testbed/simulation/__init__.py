"""The simulation, in the order a run is made: sensor noise (`measurements`), the MJCF vehicle
(`vehicle`), its completed plant (`plant`) and analytic linear model (`analytic`), the water's
force on the vehicle held in a prescribed motion (`wrench`), autopilots and input signals
(`autopilot`, `signals`), virtual captive tests (`captive`), scenarios (`scenario`), Rerun
recordings of runs (`recording`) and run directories (`runs`). The built-in scenarios
(`scenarios/*.toml`) are package data; the bundled torpedo is the project's
`assets/mjcf/torpedo.xml`, shipped as `testbed/vehicles/` (`vehicle.vehicles`).
"""

__all__: list[str] = []
