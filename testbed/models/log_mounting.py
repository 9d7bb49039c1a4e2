"""A velocity log's mounting in the linear model's outputs: a DVL (or an antenna whose velocity is
given in body axes) away from the CG, its axes turned from the body's.

It reads the velocity over the ground of its point, in its own axes (`models.sensors`' map of a
body-frame velocity sensor):

    y = Mᵀ (v + ω × r + c_b) − U e_x,   M = Rz(m_dvl_z) Ry(m_dvl_y),   r = (r_dvl_x, r_dvl_y, r_dvl_z)

v the velocity through the water at the CG (absolute u), ω the body rates, c_b the current in
body axes, the u reading reported as its perturbation from the trim speed U (as the linear
model's u). The turn about x is left out: it mixes v and w, both small at trim, and a log's roll
misalignment shows only where its sideslip or heave does. For a given mounting the reading is
linear in the state, `y = C (v; ω) + Mᵀ (U e_x + c_b) − U e_x` with `C = Mᵀ [I  −[r]×]`, so the
output-error fit simulates the states as before and reads them through C; its mounting
parameters are fitted like the outputs' biases, with exact derivatives (`mounting_derivatives`).
"""

from __future__ import annotations

import numpy as np

from testbed.models.linear import MOUNTING
from testbed.models.sensors import rotation

__all__ = [
    "MOUNTING",
    "body_current",
    "body_current_derivatives",
    "current_along",
    "mounting_derivatives",
    "matrix",
    "matrix_derivatives",
    "read",
    "read_derivatives",
    "read_matrix",
    "reading",
    "second_derivatives",
    "turned",
    "turned_derivatives",
]

_EY = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])  # [e_y]×
_EZ = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # [e_z]×


def _skew(r: np.ndarray) -> np.ndarray:
    """[r]×, the matrix of r × ·."""
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]], dtype=r.dtype)


def turned(mounting: np.ndarray) -> np.ndarray:
    """M = Rz(m_dvl_z) Ry(m_dvl_y) (3, 3): the log's axes in the body's, `mounting` as `MOUNTING`."""
    return rotation(0.0, mounting[0], mounting[1])


def matrix(mounting: np.ndarray) -> np.ndarray:
    """C = Mᵀ [I  −[r]×] (3, 6): the reading's derivative w.r.t. (u, v, w, p, q, r)."""
    Mt = turned(mounting).T
    return np.hstack([Mt, -Mt @ _skew(np.asarray(mounting[2:]))])


def reading(mounting: np.ndarray, velocity: np.ndarray, rates: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Mᵀ (v + ω × r + c_b) (N, 3) for the absolute body velocities `velocity`, the `rates` and the
    current in body axes `current` (each (N, 3))."""
    q = velocity + np.cross(rates, np.asarray(mounting[2:])) + current
    return q @ turned(mounting)  # row k: (Mᵀ q_k)ᵀ = q_kᵀ M


def mounting_derivatives(
    mounting: np.ndarray, velocity: np.ndarray, rates: np.ndarray, current: np.ndarray
) -> np.ndarray:
    """∂y/∂(m_dvl_y, m_dvl_z, r_dvl_x, r_dvl_y, r_dvl_z) (5, N, 3) of `reading`:
    ∂M/∂m_y = M [e_y]×, ∂M/∂m_z = [e_z]× M, and ∂(ω × r)/∂r_i = ω × e_i."""
    M, first = turned(mounting), _turns(mounting)[0]
    q = velocity + np.cross(rates, np.asarray(mounting[2:])) + current
    out = [q @ first[0], q @ first[1]]
    for e in np.eye(3):
        out.append(np.cross(rates, e) @ M)
    return np.stack(out)


def _turns(mounting: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """∂M/∂(m_dvl_y, m_dvl_z) (2, 3, 3) and the second derivatives (2, 2, 3, 3):
    ∂M/∂m_y = M [e_y]×, ∂M/∂m_z = [e_z]× M, ∂²M/∂m_y² = M [e_y]×², ∂²M/∂m_z² = [e_z]×² M,
    ∂²M/∂m_y∂m_z = [e_z]× M [e_y]×."""
    M = turned(mounting)
    first = np.stack([M @ _EY, _EZ @ M])
    cross = _EZ @ M @ _EY
    second = np.stack([np.stack([M @ _EY @ _EY, cross]), np.stack([cross, _EZ @ _EZ @ M])])
    return first, second


def matrix_derivatives(mounting: np.ndarray) -> np.ndarray:
    """∂C/∂(m_dvl_y, m_dvl_z, r_dvl_x, r_dvl_y, r_dvl_z) (5, 3, 6) of `matrix`:
    (∂M/∂m)ᵀ [I  −[r]×] for a turn, −Mᵀ [e_i]× on the rates for a position."""
    first, _ = _turns(mounting)
    arm = np.hstack([np.eye(3), -_skew(np.asarray(mounting[2:], float))])
    out = np.zeros((5, 3, 6))
    out[:2] = np.einsum("aji,jk->aik", first, arm)
    for i, e in enumerate(np.eye(3)):
        out[2 + i, :, 3:] = -turned(mounting).T @ _skew(e)
    return out


def second_derivatives(
    mounting: np.ndarray, velocity: np.ndarray, rates: np.ndarray, current: np.ndarray
) -> np.ndarray:
    """∂²y/∂g_i∂g_j (5, 5, N, 3) of `reading`, g = (m_dvl_y, m_dvl_z, r_dvl_x, r_dvl_y, r_dvl_z):
    q ∂²M for two turns, (ω × e_i) ∂M for a turn and a position, 0 for two positions."""
    first, second = _turns(mounting)
    q = velocity + np.cross(rates, np.asarray(mounting[2:], float)) + current
    out = np.zeros((5, 5) + q.shape)
    for a in range(2):
        for b in range(2):
            out[a, b] = q @ second[a, b]
        for i, e in enumerate(np.eye(3)):
            out[a, 2 + i] = out[2 + i, a] = np.cross(rates, e) @ first[a]
    return out


def turned_derivatives(mounting: np.ndarray) -> np.ndarray:
    """∂M/∂(m_dvl_y, m_dvl_z) (2, 3, 3)."""
    return _turns(mounting)[0]


def read_matrix(mounting: np.ndarray, columns) -> np.ndarray:
    """∂y/∂x (len(columns), 10) of the states `columns` (indices into the 10 states) as read:
    u, v, w through the log (`matrix` on u, v, w, p, q, r), the others the states'."""
    C = np.eye(10, dtype=np.result_type(mounting, float))
    C[:3, :6] = matrix(mounting)
    return C[np.asarray(columns)]


def read_derivatives(mounting: np.ndarray, dx: np.ndarray, columns) -> np.ndarray:
    """The derivatives (N, len(columns), q) of the states `columns` as read (`read`), from the
    states' own `dx` (N, 10, q): `read_matrix` times them, or their rows where the log is at the
    CG and aligned."""
    if not np.any(mounting):
        return dx[:, np.asarray(columns)]
    return np.einsum("cs,nsq->ncq", read_matrix(mounting, columns), dx)


def read(mounting: np.ndarray, states: np.ndarray, columns, current: np.ndarray | None = None) -> np.ndarray:
    """The states `columns` of `states` (N, 10; absolute u, the motion through the water) as
    read: u, v, w by the log mounted as `mounting` (`reading`) over the ground, the `current` in
    body axes (N, 3; `body_current`) added (None: no current), the others as they are."""
    columns = np.asarray(columns)
    y = states[:, columns]
    if not np.any(mounting) and current is None:
        return y
    velocity = columns < 3
    current = np.zeros((len(states), 3)) if current is None else current
    y = y.astype(np.result_type(y, mounting, current))
    y[:, velocity] = reading(mounting, states[:, :3], states[:, 3:6], current)[:, columns[velocity]]
    return y


def body_current(current: np.ndarray, psi: np.ndarray) -> np.ndarray:
    """The current (c_N, c_E) in body axes along the heading ψ (N,), (N, 3):
    (c_N cos ψ + c_E sin ψ, c_E cos ψ − c_N sin ψ, 0) (the roll and pitch left out, as the
    linear model's outputs leave them)."""
    c_n, c_e = current
    cos, sin = np.cos(psi), np.sin(psi)
    zero = np.zeros(len(psi), dtype=np.result_type(current, psi))
    return np.column_stack([c_n * cos + c_e * sin, c_e * cos - c_n * sin, zero])


def current_along(current: np.ndarray, heading: np.ndarray | None, n: int) -> np.ndarray | None:
    """`body_current` over a record's `n` samples along its measured `heading` (ψ 0 where it has
    none), None where the current is 0: `read` then reads no current."""
    if not np.any(current):
        return None
    return body_current(current, np.zeros(n) if heading is None else heading)


def body_current_derivatives(psi: np.ndarray) -> np.ndarray:
    """∂/∂(c_N, c_E) (2, N, 3) of `body_current`: (cos ψ, −sin ψ, 0) and (sin ψ, cos ψ, 0)."""
    cos, sin, zero = np.cos(psi), np.sin(psi), np.zeros(len(psi))
    return np.stack([np.column_stack([cos, -sin, zero]), np.column_stack([sin, cos, zero])])
