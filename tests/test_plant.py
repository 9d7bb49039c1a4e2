"""The completed plant against closed forms: added-mass inertia, Kirchhoff energy, hydrostatics."""

import mujoco
import numpy as np
import pytest
import scipy.linalg

from testbed import truth
from testbed.cli import main
from testbed.errors import InputError
from testbed.plant import Plant
from testbed.vehicle import FINS, added_mass, constants, default_mjcf, load_model, rigid_body_mass

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
    """Fluid coefficients, viscosity and gravity zero; fins free (actuation off, no stops), added
    mass kept; RK4 so that integration error (MuJoCo's Euler is first order) does not mask physics."""
    model = load_model()
    model.opt.gravity[:] = 0.0
    model.opt.viscosity = 0.0
    model.geom_fluid[:, 1:6] = 0.0  # drag, lift and Magnus coefficients (added mass stays)
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_ACTUATION
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
    """The hull made light (its centre of mass moved to keep the CG): sway and heave added mass
    2.79× the body's (the bundled torpedo's is 0.93×). 600 s of fin sweeps stay bounded, as
    physics says: the propulsor, set to the trim drag, cannot drive the vehicle faster than trim
    (any manoeuvre adds drag), so surge and the Kirchhoff energy ½νᵀ(M_RB + M_A)ν stay at or
    below their trim values."""
    model = load_model()
    hull = model.body("hull").id
    model.body_mass[hull] *= 0.3
    model.body_inertia[hull] *= 0.3
    model.body_ipos[hull] /= 0.3
    model.opt.gravity[:] = 0.0  # no longer neutral; keep it from surfacing
    M_RB, M_A = rigid_body_mass(model), added_mass(model)
    ratio = np.diag(M_A)[1:3] / np.diag(M_RB)[1:3]
    assert np.allclose(ratio, 2.79, atol=0.01), ratio
    plant = Plant(model=model)
    plant.reset()
    U, trim = plant.state()[0], plant.kinetic_energy()
    surge, energy = [], []
    for k in range(round(600.0 / (25 * plant.timestep))):
        t = 25 * k * plant.timestep
        plant.step(0.2 * np.sign(np.sin([0.9 * t, 0.6 * t, 0.4 * t])), n=25)
        surge.append(plant.state()[0])
        if k % 10 == 0:
            energy.append(plant.kinetic_energy())
    assert 0.5 * U < min(surge) and max(surge) < U * (1 + 1e-3), (min(surge), max(surge))
    assert max(energy) < trim * (1 + 1e-3) and min(energy) > 0.25 * trim, (min(energy), trim)


def test_unstable_simulation_is_one_line_input_error(tmp_path, monkeypatch, capsys):
    """MuJoCo resets an unstable state and goes on (a warning is all it gives): the plant stops
    at that step instead, and so does the command line, with nothing written."""
    monkeypatch.chdir(tmp_path)  # MuJoCo logs its warnings to MUJOCO_LOG.TXT in the working folder
    plant = Plant()
    plant.reset(speed=1e6)
    with pytest.raises(InputError, match=r"unstable at t=0\.004 s \(MuJoCo: Nan, Inf or huge value in QACC") as e:
        plant.step(n=10)
    assert "\n" not in str(e.value)
    # RK4 has no MuJoCo check; at 20 steps per period of the 30 Hz fin servo it diverges
    # (the bundled 4 ms step is the implicit integrator's).
    plant = Plant(timestep=0.05, rk4=True)
    plant.reset()
    with pytest.raises(InputError, match=r"unstable at t=0\.1 s \(velocities non-finite or beyond"):
        plant.step((0.1, 0.0, 0.0), n=100)
    # the highest trim speed the command line takes (MAX_SPEED) is beyond the plant's timestep
    assert main(["simulate", "--scenario", "I", "--speed", "450", "--out", "run", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "simulation unstable at t=" in err, err
    assert not (tmp_path / "run").exists()


def test_timestep_option_leaves_the_callers_model_alone():
    model = load_model()
    plant = Plant(model=model, timestep=0.001)
    assert plant.timestep == 0.001 and model.opt.timestep == 0.004
    with pytest.raises(InputError, match="timestep"):
        Plant(model=model, timestep=float("inf"))


def _variant(tmp_path, name, old, new):
    """The bundled torpedo with one piece of its MJCF text replaced."""
    text = default_mjcf().read_text()
    assert text.count(old) == 1, old
    path = tmp_path / f"{name}.xml"
    path.write_text(text.replace(old, new))
    return path


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
    # Each is rejected by load_model, and alike by the plant and the analytic model on the
    # compiled model (one check for both).
    cases = {
        "motor fin": ('<position name="rudder" joint="rudder"/>', '<motor name="rudder" joint="rudder"/>',
                      "actuator 'rudder' is not a position servo .* expected a <position> actuator"),
        "extra joint": ('<site name="imu" pos="0 0 0"/>',
                        '<site name="imu" pos="0 0 0"/><body name="flap"><joint name="flap"/>'
                        '<geom size="0.01" mass="0.001"/></body>', "5 joints; expected only"),
        "hinge off origin": ('<joint name="rudder" class="fin" axis="0 0 -1"/>',
                             '<joint name="rudder" class="fin" axis="0 0 -1" pos="0.02 0 0"/>',
                             "joint 'rudder' pos=\"0.02 0 0\"; expected 0 0 0"),
        "CG off origin": ('<inertial pos="0.0565274137 0 0.000859924"', '<inertial pos="0.1 0 0"',
                          "not the vehicle's CG"),
        "fluid geom off hinge": ('<geom name="elevator_left" class="blade"/>',
                                 '<geom name="elevator_left" class="blade" pos="0.05 0 0"/>',
                                 "fin 'elevator_left': its fluid geoms' volume centre .* off its hinge axis"),
    }  # fmt: skip
    for name, (old, new, message) in cases.items():
        path = _variant(tmp_path, name.replace(" ", "_"), old, new)
        with pytest.raises(InputError, match=message) as e:
            load_model(path)
        assert str(e.value).startswith(str(path)) and "\n" not in str(e.value), name
        model = mujoco.MjModel.from_xml_path(str(path))
        with pytest.raises(InputError, match=message):
            Plant(model=model)
        with pytest.raises(InputError, match=message):
            truth.analytic_model(model, 20.0)
