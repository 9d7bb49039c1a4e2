"""The completed plant at a model state: set it there and read its accelerations.

A model state x = (u v w p q r φ θ ψ z) (u absolute; body axes FRD, earth axes NED, Euler angles
Rz(ψ) Ry(θ) Rx(φ)) and fin angles δ put the plant's hull at that attitude, depth and velocity,
its fins at δ and at rest relative to the hull; `Plant.body_accelerations` then gives ν̇ there
(the fins held). For linearisation, fits and checks of models against the plant's own dynamics.
"""

from __future__ import annotations

import mujoco
import numpy as np

from testbed.simulation.plant import Plant
from testbed.simulation.vehicle import FIN_JOINTS, FLIP

__all__ = ["earth_from_body", "plant_rates"]


def earth_from_body(phi: float, theta: float, psi: float) -> np.ndarray:
    """NED from FRD body axes: Rz(ψ) Ry(θ) Rx(φ)."""
    c, s = np.cos([phi, theta, psi]), np.sin([phi, theta, psi])
    Rx = np.array([[1, 0, 0], [0, c[0], -s[0]], [0, s[0], c[0]]])
    Ry = np.array([[c[1], 0, s[1]], [0, 1, 0], [-s[1], 0, c[1]]])
    Rz = np.array([[c[2], -s[2], 0], [s[2], c[2], 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def plant_rates(plant: Plant, x, delta, depth: float = 50.0) -> np.ndarray:
    """ν̇ (n, 6): the plant's body accelerations at each state x (n, 10) and fin angles δ (n, 3),
    the hull `depth` + z below the surface at the origin, the fins held (their rates zero). The
    thrust is the plant's own (`Plant.reset` sets it). Leaves the plant at the last sample."""
    m = plant.model
    qadr = m.jnt_qposadr[m.joint("hull").id]
    vadr = m.jnt_dofadr[m.joint("hull").id]
    fins = [m.jnt_qposadr[m.joint(f).id] for f in FIN_JOINTS]
    x, delta = np.atleast_2d(x), np.atleast_2d(delta)
    out = np.empty((len(x), 6))
    quat = np.empty(4)
    for i, (xi, di) in enumerate(zip(x, delta)):
        qpos, qvel = plant.data.qpos.copy(), np.zeros(m.nv)
        R = FLIP @ earth_from_body(*xi[6:9]) @ FLIP  # MuJoCo's world from its hull axes
        mujoco.mju_mat2Quat(quat, R.ravel())
        qpos[qadr : qadr + 3] = (0.0, 0.0, -(depth + xi[9]))
        qpos[qadr + 3 : qadr + 7] = quat
        qpos[fins] = di
        qvel[vadr : vadr + 3] = R @ FLIP @ xi[:3]
        qvel[vadr + 3 : vadr + 6] = FLIP @ xi[3:6]
        plant.set_state(qpos, qvel)
        out[i] = plant.body_accelerations()
    return out
