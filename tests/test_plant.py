"""The completed plant against closed forms: added-mass inertia, Kirchhoff energy, hydrostatics."""

import mujoco
import numpy as np
import pytest
import scipy.linalg

from testbed.errors import InputError
from testbed.plant import Plant
from testbed.vehicle import FINS, added_mass, constants, load_model, rigid_body_mass

WRENCH = np.array([300.0, -120.0, 80.0, 6.0, -25.0, 40.0])  # N, N m; SPEC body axes at the CG


def _plant(complete=True, **opt):
    model = load_model()
    for key, value in opt.items():
        setattr(model.opt, key, value)
    return Plant(model=model, complete=complete)


@pytest.mark.parametrize("attitude", [(0.0, 0.0, 0.0), (0.3, -0.2, 1.1)])
def test_force_step_gives_inverse_of_rigid_plus_added_mass(attitude):
    """From rest, a known wrench gives (M_RB + M_A)⁻¹F; plain MuJoCo gives M_RB⁻¹F, i.e. F/m."""
    model = load_model()
    M_RB, M_A = rigid_body_mass(model), added_mass(model)
    assert M_A[1, 1] > 0.9 * M_RB[1, 1]  # the torpedo case: added mass comparable to body mass
    for complete, M in ((True, M_RB + M_A), (False, M_RB)):
        plant = Plant(model=model, complete=complete)
        plant.reset(speed=0.0, heading=attitude[2])
        q = plant.data.qpos.copy()
        quat = np.empty(4)
        # roll and pitch about the body axes (MuJoCo hull axes x forward, y port, z up)
        mujoco.mju_euler2Quat(quat, np.array([attitude[0], -attitude[1], 0.0]), "xyz")
        mujoco.mju_mulQuat(q[3:7], q[3:7].copy(), quat)
        plant.set_state(q, np.zeros(model.nv))
        plant.wrench[:] = WRENCH
        expected = np.linalg.solve(M, WRENCH)
        got = plant.body_accelerations()
        # at rest the rest is hydrostatics (a moment when tilted; plain MuJoCo: weight alone)
        plant.wrench[:] = 0.0
        baseline = plant.body_accelerations()
        if complete and not any(attitude[:2]):
            assert np.abs(baseline).max() < 1e-9  # neutrally buoyant, CB above CG
        np.testing.assert_allclose(got - baseline, expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())
    assert np.isclose(np.linalg.solve(M_RB, WRENCH)[0], WRENCH[0] / constants(model, 1.0).mass)


def test_force_step_through_mujoco_step():
    """The same holds in MuJoCo's own step (qacc), fins locked by making them very heavy."""
    model = load_model()
    model.dof_armature[[model.joint(f).dofadr[0] for f in FINS]] = 1e12
    plant = Plant(model=model)
    plant.reset(speed=0.0)
    plant.wrench[:] = WRENCH
    plant.step(n=1)
    d = plant.data
    R = d.xmat[plant.hull].reshape(3, 3)
    flip = np.diag([1.0, -1.0, -1.0])
    acc = np.concatenate([flip @ R.T @ d.qacc[:3], flip @ d.qacc[3:6]])
    expected = np.linalg.solve(rigid_body_mass(model) + added_mass(model), WRENCH)
    np.testing.assert_allclose(acc, expected, rtol=1e-6)


def _inviscid(complete):
    """Fluid coefficients, viscosity and gravity zero; fins free (no servo, no stops), added mass
    kept; RK4 so that integration error (MuJoCo's Euler is first order) does not mask physics."""
    model = load_model()
    model.opt.gravity[:] = 0.0
    model.opt.viscosity = 0.0
    model.geom_fluid[:, 1:6] = 0.0  # drag, lift and Magnus coefficients (added mass stays)
    model.actuator_gainprm[:] = 0.0
    model.actuator_biasprm[:] = 0.0
    model.jnt_range[:] = [-1e6, 1e6]
    model.opt.timestep = 0.001
    plant = Plant(model=model, complete=complete, rk4=True)
    plant.reset(speed=0.0)
    qvel = np.zeros(model.nv)
    qvel[:6] = [2.0, -1.0, 0.5, 1.5, -0.8, 1.2]  # tumbling
    plant.set_state(plant.data.qpos.copy(), qvel)
    return plant


def test_inviscid_coast_conserves_kirchhoff_energy():
    """Potential flow: ½νᵀ(M_RB + M_A)ν is conserved by the completed plant, not by plain MuJoCo."""
    drift = {}
    for complete in (True, False):
        plant = _inviscid(complete)
        e0 = plant.kinetic_energy()
        energies = []
        for _ in range(10):
            plant.step(n=1000)  # 10 s in all
            energies.append(plant.kinetic_energy())
        drift[complete] = np.abs(np.array(energies) / e0 - 1).max()
    assert drift[True] < 1e-6, drift
    assert drift[False] > 1e-3, drift


def test_neutral_body_at_rest_stays_at_rest():
    plant = Plant()
    plant.reset(speed=0.0)
    x0 = plant.state()
    plant.step(n=int(60 / plant.timestep))
    np.testing.assert_allclose(plant.state(), x0, atol=1e-6)


def _period(signal, dt):
    """Mean period from upward zero crossings (linear interpolation)."""
    s = signal - signal.mean()
    i = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))
    t = (i + s[i] / (s[i] - s[i + 1])) * dt
    return np.diff(t).mean()


@pytest.mark.parametrize("axis", ["phi", "theta"])
def test_roll_and_pitch_periods_match_hydrostatics(axis):
    """CB above CG: small oscillations at ω² eigenvalues of K x = ω² (M_RB + M_A) x."""
    model = load_model()
    model.geom_fluid[:, 1:6] = 0.0  # undamped, to read the period cleanly
    v = constants(model, 1.0)
    K = np.zeros((6, 6))
    K[3, 3] = K[4, 4] = -v.zB * v.buoyancy
    w2 = scipy.linalg.eigvals(K, rigid_body_mass(model) + added_mass(model)).real
    w2 = np.sort(w2[np.isfinite(w2) & (w2 > 1e-9)])
    expected = 2 * np.pi / np.sqrt(w2[1] if axis == "phi" else w2[0])  # roll is the fast one
    plant = Plant(model=model)
    plant.reset(speed=0.0)
    q = plant.data.qpos.copy()
    quat = np.empty(4)
    angle = 0.02
    mujoco.mju_euler2Quat(quat, np.array([angle, 0, 0] if axis == "phi" else [0, -angle, 0]), "xyz")
    mujoco.mju_mulQuat(q[3:7], q[3:7].copy(), quat)
    plant.set_state(q, np.zeros(model.nv))
    n = int(4 * expected / plant.timestep)
    k = 6 if axis == "phi" else 7
    trace = []
    for _ in range(n):
        plant.step()
        trace.append(plant.state()[k])
    assert abs(_period(np.array(trace), plant.timestep) / expected - 1) < 0.02


def test_stable_for_600_s_with_fins_working():
    """600 s at the MJCF's timestep, fins swept, added mass ~ body mass in sway and heave."""
    plant = Plant()
    plant.reset()
    t = 0.0
    while t < 600.0:
        cmd = 0.15 * np.sign(np.sin([0.7 * t, 0.5 * t + 1.0, 0.5 * t + 1.3]))
        plant.step(cmd, n=25)
        t += 25 * plant.timestep
    x = plant.state()
    assert np.all(np.isfinite(x)) and 5.0 < x[0] < 25.0


def test_stable_for_600_s_when_added_mass_exceeds_body_mass():
    """A variant with the hull made light: sway added mass 2.9× the body's; still stable."""
    model = load_model()
    hull = model.body("hull").id
    model.body_mass[hull] *= 0.3
    model.body_inertia[hull] *= 0.3
    model.opt.gravity[:] = 0.0  # no longer neutral; keep it from surfacing
    M_RB, M_A = rigid_body_mass(model), added_mass(model)
    assert M_A[1, 1] > 2 * M_RB[1, 1] and M_A[2, 2] > 2 * M_RB[2, 2]
    plant = Plant(model=model)
    plant.reset()
    t = 0.0
    while t < 600.0:
        plant.step(0.2 * np.sign(np.sin([0.9 * t, 0.6 * t, 0.4 * t])), n=25)
        t += 25 * plant.timestep
    assert np.all(np.isfinite(plant.state()))


def test_bad_mjcf_is_one_line_input_error(tmp_path):
    with pytest.raises(InputError, match="no such MJCF"):
        load_model(tmp_path / "missing.xml")
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body name='hull'>")
    with pytest.raises(InputError, match="not a valid MJCF") as e:
        load_model(bad)
    assert "\n" not in str(e.value)
    finless = tmp_path / "finless.xml"
    finless.write_text("""<mujoco><option density="1025"/><worldbody><body name="hull">
        <freejoint name="hull"/><geom type="ellipsoid" size="1 0.1 0.1" fluidshape="ellipsoid"/>
        </body></worldbody></mujoco>""")
    with pytest.raises(InputError, match="rudder"):
        load_model(finless)
    with pytest.raises(InputError, match="speed"):
        constants(load_model(), 0.0)
