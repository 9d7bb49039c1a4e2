"""Virtual captive tests against independent references.

References: MuJoCo's ellipsoid fluid model written out here from its documentation (fluid.rst)
for a single ellipsoid whose forces are known in closed form; the added mass set on it; the
analytic linear model's derivatives and its closed-form force per geom (the torpedo); the
completed plant's own accelerations.
"""

import math

import mujoco
import numpy as np
import pytest

from testbed.errors import InputError
from testbed.simulation.analytic import analytic_model, geom_terms
from testbed.captive.rig import OSCILLATIONS, SWEEPS, Oscillation, Sweep, captive_tests, pmm_coefficients
from testbed.simulation.plant import Plant
from testbed.simulation.vehicle import (
    FIN_JOINTS,
    FLIP,
    added_mass,
    buoyancy_centre,
    constants,
    fluid_geoms,
    load_model,
    quaternion_matrix,
    semi_axes,
)
from testbed.captive.wrench import hydrodynamic_wrench

T6 = np.kron(np.eye(2), FLIP)  # MuJoCo's body axes (FLU) <-> FRD, for (lin, ang)

# The ellipsoid: semi-axes, fluidcoef (blunt, slender, angular, Kutta, Magnus), the added mass set
# on it (kg, kg m²), its centre and attitude in the body (off the origin and turned, so the
# moments carry the transport), the fluid's density and viscosity.
R_AXES = np.array([0.6, 0.25, 0.12])
COEF = (0.5, 0.25, 1.5, 1.0, 0.8)
ADDED = np.array([14.0, 95.0, 160.0, 2.5, 11.0, 7.0])
CENTRE = np.array([0.1, -0.03, 0.05])
EULER = (0.2, -0.1, 0.3)
RHO, BETA = 1000.0, 0.3


def ellipsoid_model() -> mujoco.MjModel:
    xml = f"""<mujoco><option density="{RHO}" viscosity="{BETA}" gravity="0 0 0"/>
      <worldbody><body><freejoint/><inertial pos="0 0 0" mass="50" diaginertia="1 2 3"/>
        <geom type="ellipsoid" size="{" ".join(map(str, R_AXES))}" pos="{" ".join(map(str, CENTRE))}"
              euler="{" ".join(map(str, EULER))}" fluidshape="ellipsoid"
              fluidcoef="{" ".join(map(str, COEF))}"/>
      </body></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    m.geom_fluid[0, 6:12] = ADDED / RHO  # MuJoCo keeps the virtual masses per unit density
    return m


def fluid_rst_force(v, w, v_dot, w_dot, Q):
    """The ellipsoid model of MuJoCo's fluid.rst on the ellipsoid at body velocity (v, ω) and
    acceleration (v̇, ω̇) (its origin, FLU), with the added-mass inertia −m_A ∘ v̇, −I_A ∘ ω̇ that the
    completed plant applies; returns (force, moment about the origin), FLU."""
    p, r = CENTRE, R_AXES
    blunt, slender, angular, kutta, magnus = COEF
    vg, wg = Q.T @ (v + np.cross(w, p)), Q.T @ w  # the ellipsoid's velocity in its own axes
    ag, bg = Q.T @ (v_dot + np.cross(w_dot, p)), Q.T @ w_dot
    mA, IA = ADDED[:3], ADDED[3:]
    V = 4 / 3 * math.pi * r.prod()
    speed = np.linalg.norm(vg)
    rjk = np.array([r[1] * r[2], r[2] * r[0], r[0] * r[1]])
    # projected area (the lemma) and the normal of the section that projects to it
    A_proj = math.pi * math.sqrt(np.sum(rjk**4 * vg**2) / np.sum(rjk**2 * vg**2))
    n = rjk / r * vg
    n /= np.linalg.norm(n)
    r_max, r_min = r.max(), r.min()
    r_mid = r.sum() - r_max - r_min
    A_max = math.pi * r_max * r_mid
    # angular drag: I_D,i = 8π/15 r_i max(r_j, r_k)⁴; the torque −ρ |ω ∘ c| ω, c the bracket
    I_D = np.array([8 * math.pi / 15 * r[i] * max(r[(i + 1) % 3], r[(i + 2) % 3]) ** 4 for i in range(3)])
    c = angular * I_D + slender * (I_D.max() - I_D)
    r_D = r.sum() / 3
    f = (
        -mA * ag
        + np.cross(mA * vg, wg)  # added mass
        - RHO * (blunt * A_proj + slender * (A_max - A_proj)) * speed * vg  # drag
        + magnus * RHO * V * np.cross(wg, vg)  # Magnus
        + kutta * RHO * A_proj * (vg @ n / speed) * np.cross(np.cross(n, vg), vg)  # Kutta
        - 6 * math.pi * r_D * BETA * vg  # Stokes
    )
    g = (
        -IA * bg
        + np.cross(mA * vg, vg)
        + np.cross(IA * wg, wg)  # added mass (Munk)
        - RHO * np.linalg.norm(wg * c) * wg  # angular drag
        - 8 * math.pi * r_D**3 * BETA * wg  # Stokes
    )
    return Q @ f, Q @ g + np.cross(p, Q @ f)


def test_ellipsoid_sweeps_match_the_closed_form():
    model = ellipsoid_model()
    Q = quaternion_matrix(model.geom_quat[0])
    speeds = (4.0, 7.0)
    tests = (
        Sweep(name="drift", vary=("v",), extent=(3.0,), points=(9,), speeds=speeds),
        Sweep(name="incidence", vary=("w",), extent=(3.0,), points=(9,), speeds=speeds),
        Sweep(name="roll_rate", vary=("p",), extent=(4.0,), points=(9,), speeds=speeds),
        Sweep(name="drift_yaw", vary=("v", "r"), extent=(2.0, 3.0), points=(5, 7), speeds=speeds),
        Sweep(name="incidence_pitch", vary=("w", "q"), extent=(2.0, 3.0), points=(5, 7), speeds=speeds),
        Oscillation(name="pure_sway", variable="v", amplitude=1.5, period=2.0, samples=16, speeds=speeds),
        Oscillation(name="pure_pitch", variable="q", amplitude=2.0, period=1.5, samples=16, speeds=speeds),
    )
    runs = captive_tests(model, tests)
    assert [(r.test, r.speed) for r in runs] == [(t.name, s) for t in tests for s in speeds]
    for run in runs:
        assert run.nu.shape == run.nu_dot.shape == run.wrench.shape == (len(run.nu), 6)
        assert (run.nu[:, 0] == run.speed).all() and not run.fins.any()
        for nu, nu_dot, wrench in zip(run.nu, run.nu_dot, run.wrench):
            f, g = fluid_rst_force(FLIP @ nu[:3], FLIP @ nu[3:], FLIP @ nu_dot[:3], FLIP @ nu_dot[3:], Q)
            expected = np.concatenate([FLIP @ f, FLIP @ g])
            assert np.allclose(wrench, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max()), run.test
    # not vacuous: every term is felt, the acceleration's part too
    pmm = next(r for r in runs if r.test == "pure_sway")
    assert np.abs(pmm.nu_dot).max() > 4 and np.abs(pmm.wrench[:, 1]).max() > 100


def test_pmm_recovers_the_added_mass_set():
    """The quadrature parts of pure sway, heave, roll, pitch and yaw are −M_A's columns, M_A the
    added mass set on the ellipsoid carried to the body's origin (written out here)."""
    model = ellipsoid_model()
    Q, p = quaternion_matrix(model.geom_quat[0]), CENTRE
    # M_A about the origin: the kinetic energy ½ (X ν)ᵀ diag(m_A, I_A) (X ν), X the ellipsoid's
    # velocity (its axes) from the origin's, v_g = Qᵀ (v + ω × p), ω_g = Qᵀ ω.
    X = np.block(
        [
            [Q.T, -Q.T @ np.array([[0, -p[2], p[1]], [p[2], 0, -p[0]], [-p[1], p[0], 0]])],
            [np.zeros((3, 3)), Q.T],
        ]
    )
    M_A = T6 @ X.T @ np.diag(ADDED) @ X @ T6
    assert np.abs(M_A - np.diag(np.diag(M_A))).max() > 1  # turned and off the origin: coupled
    tests = [
        Oscillation(name=f"pure_{x}", variable=x, amplitude=a, period=3.0, speeds=(5.0,))
        for x, a in (("v", 1.0), ("w", 1.0), ("p", 2.0), ("q", 1.5), ("r", 1.5))
    ]
    for test, run in zip(tests, captive_tests(model, tests)):
        k = "uvwpqr".index(test.variable)
        found = pmm_coefficients(test, run)
        quadrature = np.array([found[f"{row}_{test.variable}dot"] for row in "XYZKMN"])
        assert np.allclose(quadrature, -M_A[:, k], rtol=1e-9, atol=1e-9 * np.abs(M_A).max()), test.name


def torpedo_slope(run, x, column):
    """∂F/∂x at x = 0 from a sweep's grid, by the five-point central difference."""
    i = int(np.argmin(np.abs(x)))
    h = x[i + 1] - x[i]
    F = run.wrench[:, column]
    return (8 * (F[i + 1] - F[i - 1]) - (F[i + 2] - F[i - 2])) / (12 * h)


def test_torpedo_sweeps_slopes_are_the_analytic_derivatives():
    """The default drift and fin sweeps' slopes at 0, at every speed, within 1 % of the analytic
    linear model's Y_v, N_v and control derivatives."""
    model = load_model()
    wanted = {"drift", "rudder", "elevator", "differential"}
    runs = captive_tests(model, [t for t in SWEEPS if t.name in wanted])
    assert {r.test for r in runs} == wanted
    for run in runs:
        c = analytic_model(model, run.speed).coefficients
        v, dr, de = run.nu[:, 1], run.fins[:, 0], run.fins[:, 1]
        checks = {
            "drift": [(v, 1, c["Y_v"]), (v, 5, c["N_v"])],
            "rudder": [(dr, 1, c["Y_dr"]), (dr, 5, c["N_dr"]), (dr, 3, c["K_dr"])],
            "elevator": [(de, 2, c["Z_de"]), (de, 4, c["M_de"])],
            # δer = +δ, δel = −δ: K_der δer − K_del δel
            "differential": [(de, 3, c["K_der"] + c["K_del"])],
        }[run.test]
        for x, column, reference in checks:
            slope = torpedo_slope(run, x, column)
            assert slope == pytest.approx(reference, rel=0.01, abs=1e-6 * abs(c["Y_dr"])), (run.test, column)
    # the sweeps reach beyond the linear regime: Y(v) at 3 m/s is 3.6 % off the slope's line
    drift = next(r for r in runs if r.test == "drift" and r.speed == 20.0)
    Y_v = analytic_model(model, 20.0).coefficients["Y_v"]
    assert abs(drift.wrench[-1, 1] / (3.0 * Y_v) - 1) > 0.02


def test_torpedo_pmm_gives_the_added_mass_and_the_damping():
    """Small-amplitude PMM on the torpedo: quadrature parts are −M_A (the vehicle's added mass at
    fins 0), in-phase parts the analytic model's damping derivatives within 0.1 % (the angular
    drag κ|ω|ω, not smooth at 0, adds (8/3π) κ a to the in-phase part: 0.04 % of M_q here)."""
    model = load_model()
    c = analytic_model(model, 20.0).coefficients
    M_A = added_mass(model)
    tests = [
        Oscillation(name=f"pure_{x}", variable=x, amplitude=a, speeds=(20.0,))
        for x, a in (("v", 0.02), ("w", 0.02), ("p", 0.005), ("q", 0.005), ("r", 0.005))
    ]
    damping = {
        "v": ("Y_v", "K_v", "N_v"),
        "w": ("Z_w", "M_w"),
        "p": ("Y_p", "K_p", "N_p"),
        "q": ("Z_q", "M_q"),
        "r": ("Y_r", "K_r", "N_r"),
    }
    for test, run in zip(tests, captive_tests(model, tests)):
        found = pmm_coefficients(test, run)
        k = "uvwpqr".index(test.variable)
        quadrature = np.array([found[f"{row}_{test.variable}dot"] for row in "XYZKMN"])
        assert np.allclose(quadrature, -M_A[:, k], rtol=1e-9, atol=1e-9 * np.abs(M_A).max()), test.name
        for name in damping[test.variable]:
            assert found[name] == pytest.approx(c[name], rel=1e-3), name


def test_torpedo_fluid_force_is_the_sum_over_its_geoms():
    """At ω = 0 (drift and rudder, incidence and elevators), the wrench is Σ_g X_gᵀ φ_g(X_g ν) over
    hull and fin geoms at their deflected poses, φ_g the analytic model's closed-form force."""
    model = load_model()
    tests = [t for t in SWEEPS if t.name in ("drift_rudder", "incidence_elevator")]
    runs = captive_tests(model, tests)
    d = mujoco.MjData(model)
    hull = model.body("hull").id
    qadr = [model.jnt_qposadr[model.joint(f).id] for f in FIN_JOINTS]
    for run in runs:
        for nu, fins, wrench in zip(run.nu, run.fins, run.wrench):
            d.qpos[qadr] = fins
            mujoco.mj_kinematics(model, d)
            Rh, ph = d.xmat[hull].reshape(3, 3), d.xpos[hull]
            total = np.zeros(6)
            for g in fluid_geoms(model):
                Q = Rh.T @ d.geom_xmat[g].reshape(3, 3)  # hull from geom
                p = Rh.T @ (d.geom_xpos[g] - ph)
                v_g = Q.T @ (FLIP @ nu[:3])  # ω = 0: every point moves with v
                phi = sum(
                    t[0]
                    for t in geom_terms(
                        semi_axes(model, g),
                        model.geom_fluid[g, 1:6],
                        model.geom_fluid[g, 6:12],
                        model.opt.density,
                        model.opt.viscosity,
                        v_g,
                    ).values()
                )
                F = Q @ phi[:3]
                total += np.concatenate([F, Q @ phi[3:] + np.cross(p, F)])
            expected = T6 @ total
            assert np.allclose(wrench, expected, rtol=1e-10, atol=1e-10 * np.abs(expected).max())
    assert max(np.abs(r.fins).max() for r in runs) == pytest.approx(0.4)


def test_the_plant_obeys_its_equations_with_the_captive_wrench():
    """M_RB ν̇ + C_RB(ν) ν = τ_H(ν, δ, ν̇) + restoring + thrust, ν̇ the completed plant's own
    accelerations at a set state (tilted, turning, fins deflected)."""
    plant = Plant()
    plant.reset(20.0)
    m = plant.model
    qadr, vadr = m.jnt_qposadr[m.joint("hull").id], m.jnt_dofadr[m.joint("hull").id]
    qpos, qvel = plant.data.qpos.copy(), np.zeros(m.nv)
    quat = np.array([0.9, 0.1, -0.2, 0.3]) / np.linalg.norm([0.9, 0.1, -0.2, 0.3])
    qpos[qadr + 3 : qadr + 7] = quat
    fins = np.array([0.1, -0.2, 0.3])
    qpos[[m.jnt_qposadr[m.joint(f).id] for f in FIN_JOINTS]] = fins
    nu = np.array([18.0, 1.5, -1.0, 0.7, -0.4, 0.9])
    R = quaternion_matrix(quat)  # world from hull, MuJoCo's axes
    qvel[vadr : vadr + 3] = R @ FLIP @ nu[:3]
    qvel[vadr + 3 : vadr + 6] = FLIP @ nu[3:]
    plant.set_state(qpos, qvel)
    nu_dot = plant.body_accelerations()
    tau = hydrodynamic_wrench(plant, nu, fins, nu_dot)
    # the rigid body of hull and fins at these fin angles (MuJoCo's composite inertia, upright)
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    d.qpos[qadr + 3 : qadr + 7] = (1.0, 0.0, 0.0, 0.0)
    mujoco.mj_kinematics(m, d)
    mujoco.mj_comPos(m, d)
    mujoco.mj_makeM(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    M_RB = T6 @ M[vadr : vadr + 6, vadr : vadr + 6] @ T6
    h = M_RB @ nu  # momentum: C_RB(ν) ν = (ω × h_lin, ω × h_ang + v × h_lin)
    C = np.concatenate([np.cross(nu[3:], h[:3]), np.cross(nu[3:], h[3:]) + np.cross(nu[:3], h[:3])])
    vehicle, r_B = constants(m, 20.0), buoyancy_centre(m)
    down = (FLIP @ R @ FLIP).T @ np.array([0.0, 0.0, 1.0])  # NED down in body axes
    restoring = np.concatenate(
        [(vehicle.weight - vehicle.buoyancy) * down, np.cross(r_B, -vehicle.buoyancy * down)]
    )
    thrust = np.array([plant.thrust, 0, 0, 0, 0, 0])
    left = M_RB @ nu_dot + C
    assert np.allclose(left, tau + restoring + thrust, rtol=0, atol=1e-8 * np.abs(left).max())
    assert np.abs(tau).max() > 1e3 and np.abs(nu_dot).max() > 1  # a real state, far from trim


def test_a_sweep_follows_its_lines():
    """`follow` offsets a variable by a ratio times its leader: the grid about a line."""
    sweep = Sweep(
        name="turn",
        vary=("r", "v", "delta_r"),
        extent=(0.5, 0.2, 0.02),
        points=(3, 3, 2),
        speeds=(20.0,),
        follow=(("v", "r", -1.4), ("delta_r", "r", -0.04)),
    )
    nu, nu_dot, fins = sweep.states(20.0)
    plain = Sweep(name="plain", vary=sweep.vary, extent=sweep.extent, points=sweep.points, speeds=(20.0,))
    nu0, _, fins0 = plain.states(20.0)
    assert np.array_equal(nu[:, 5], nu0[:, 5]) and not nu_dot.any()
    assert nu[:, 1] == pytest.approx(nu0[:, 1] - 1.4 * nu0[:, 5], abs=1e-15)
    assert fins[:, 0] == pytest.approx(fins0[:, 0] - 0.04 * nu0[:, 5], abs=1e-15)
    for follow, match in (
        ((("w", "r", 1.0),), "follow"),
        ((("v", "v", 1.0),), "follow"),
        ((("v", "r", math.nan),), "follow"),
        ((("v", "r", 1.0), ("r", "delta_r", 1.0)), "leader"),
    ):
        with pytest.raises(InputError, match=match) as e:
            Sweep(name="bad", vary=("r", "v", "delta_r"), extent=(1, 1, 1), points=(3, 3, 3), follow=follow)
        assert "\n" not in str(e.value)


def test_bad_input_is_one_line():
    model = load_model()
    ellipsoid = ellipsoid_model()
    cases = [
        lambda: hydrodynamic_wrench(model, [20.0, 0, 0]),
        lambda: hydrodynamic_wrench(model, [20.0, 0, 0, 0, 0, math.nan]),
        lambda: hydrodynamic_wrench(model, np.zeros((3, 6)), np.zeros((2, 3))),
        lambda: hydrodynamic_wrench(ellipsoid, [5.0, 0, 0, 0, 0, 0], [0.1, 0, 0]),
        lambda: hydrodynamic_wrench("torpedo.xml", [5.0, 0, 0, 0, 0, 0]),
        lambda: Sweep(name="x", vary=("beta",), extent=(1.0,), points=(5,)),
        lambda: Sweep(name="x", vary=("v",), extent=(1.0, 2.0), points=(5,)),
        lambda: Sweep(name="x", vary=("v",), extent=(1.0,), points=(0,)),
        lambda: Sweep(name="x", vary=("v",), extent=(1.0,), points=(5,), speeds=(-1.0,)),
        lambda: Oscillation(name="x", variable="delta_r", amplitude=0.1),
        lambda: Oscillation(name="x", variable="v", amplitude=0.0),
        lambda: Oscillation(name="x", variable="v", amplitude=1.0, samples=2),
        lambda: captive_tests(model, [SWEEPS[0], SWEEPS[0]]),
        lambda: pmm_coefficients(OSCILLATIONS[0], captive_tests(model, [SWEEPS[0]])[0]),
    ]
    for case in cases:
        with pytest.raises(InputError) as info:
            case()
        assert "\n" not in str(info.value)
