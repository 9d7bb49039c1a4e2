"""The analytic linear model against its independent checks.

References: central differences of the completed plant's own dynamics, of MuJoCo's
own fluid forces on a single ellipsoid, and Tuckerman's closed-form added mass.
"""

import functools
import tomllib

import mujoco
import numpy as np
import pytest
from scipy.integrate import quad

from testbed.analysis.structural import structural
from testbed.cli import main
from testbed.data import ModelConfig, parse_config, read_config
from testbed.errors import InputError
from testbed.models.linear import IX, PARAMETERS, STATES, continuous, structure, theta_vector
from testbed.simulation import analytic
from testbed.simulation.plant import Plant
from testbed.simulation.vehicle import added_mass, default_mjcf, load_model

SPEEDS = (20.0, 12.0)


@functools.cache
def models(speed):
    model = load_model()
    return analytic.analytic_model(model, speed), analytic.numerical_model(model, speed)


def close(actual, reference, rel=0.02, atol=1e-6):
    """Entry-wise: within `rel` of the reference, or `atol` where the entry is near zero."""
    return np.abs(actual - reference) <= np.maximum(rel * np.abs(reference), atol)


@pytest.mark.parametrize("speed", SPEEDS)
def test_analytic_matches_numerical_linearization(speed):
    lin, (A, B) = models(speed)
    assert close(lin.A_full, A).all(), np.argwhere(~close(lin.A_full, A))
    assert close(lin.B_full, B).all(), np.argwhere(~close(lin.B_full, B))
    # not a vacuous pass: the model is far from zero, and the plant ignores heading and depth
    assert np.abs(A[:6, :6]).max() > 10 and np.abs(B).max() > 100
    assert np.abs(A[:, [IX["psi"], IX["z"]]]).max() < 1e-9
    plant = Plant(model=load_model())
    plant.reset(speed)
    assert lin.thrust == pytest.approx(plant.thrust, rel=1e-9)  # the same trim


@pytest.mark.parametrize("speed", SPEEDS)
def test_spec_projection_reproduces_full_model(speed):
    lin, _ = models(speed)
    s = structure(lin.vehicle)
    theta = theta_vector(lin.coefficients)
    places = {  # where the linear model's table has an entry (a coefficient or a known constant)
        "Mt": (s.dMt != 0).any(0) | (s.Mt0 != 0),
        "At": (s.dAt != 0).any(0) | (s.At0 != 0),
        "Bt": (s.dBt != 0).any(0),
        "St": s.St0 != 0,
    }
    for name, spec, full in (
        ("Mt", lin.Mt, lin.Mt_full),
        ("At", lin.At, lin.At_full),
        ("Bt", lin.Bt, lin.Bt_full),
        ("St", lin.St, lin.St_full),
    ):
        scale = lin.thrust if name == "St" else np.abs(full).max()  # St: trim forces, N
        where = places[name]
        assert np.allclose(spec[where], full[where], rtol=1e-12, atol=1e-10 * scale), name
        outside = {t.name for t in lin.outside if t.matrix == name}
        big = np.abs(full - spec) > 1e-9 * scale
        assert len(outside) >= big.sum(), name  # every visible difference is reported
    # On the linear model's own entries of A and B, what it misses is small (≤ 2 %, or 0.1 % of
    # the row's largest entry where the entry itself is small).
    A, B, _ = continuous(s, theta)
    for spec, full in ((A, lin.A_full), (B, lin.B_full)):
        tol = np.maximum(0.02 * np.abs(full), 1e-3 * np.abs(full).max(1, keepdims=True))
        assert (np.abs(spec - full) <= tol)[spec != 0].all()
    # The fins' axial added mass below the CG is the largest term the linear model lacks; it is small.
    worst = lin.outside[0]
    assert worst.name in ("X_qdot", "M_udot") and worst.relative < 1e-3


def test_geom_jacobian_matches_mujoco():
    """geom_terms against MuJoCo's own fluid force on one ellipsoid, at a generic velocity."""
    r, coef, rho, beta = (0.4, 0.15, 0.07), (0.5, 0.25, 1.5, 1.0, 0.8), 1000.0, 0.3
    xml = f"""<mujoco><option density="{rho}" viscosity="{beta}" gravity="0 0 0"/>
      <worldbody><body><freejoint/><inertial pos="0 0 0" mass="1" diaginertia="1 1 1"/>
        <geom type="ellipsoid" size="{r[0]} {r[1]} {r[2]}" fluidshape="ellipsoid"
              fluidcoef="{" ".join(map(str, coef))}"/>
      </body></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)

    def wrench(nu):
        d.qvel[:] = nu
        mujoco.mj_forward(m, d)
        return d.qfrc_passive.copy()  # identity pose: (force, torque) in the geom's axes

    v = np.array([3.0, -1.2, 0.7])
    terms = analytic.geom_terms(r, coef, m.geom_fluid[0, 6:12], rho, beta, v)
    phi = sum(t[0] for t in terms.values())
    J = sum(t[1] for t in terms.values())
    nu0 = np.concatenate([v, np.zeros(3)])
    assert np.allclose(phi, wrench(nu0), rtol=1e-12, atol=1e-12)
    h = np.array([1e-5] * 3 + [1e-8] * 3)  # angular drag is κ|ω|ω: the ω step must be tiny
    J_fd = np.column_stack([(wrench(nu0 + e) - wrench(nu0 - e)) / (2 * e.sum()) for e in np.diag(h)])
    assert np.allclose(J, J_fd, rtol=1e-6, atol=1e-6 * np.abs(J).max())


def test_kutta_lift_along_the_chord_closed_form():
    """At v = U e_x + δv: f_K ≈ C_K ρ π r_y r_z U (0, (1 − r_x²/r_y²) δv_y, (1 − r_x²/r_z²) δv_z)."""
    r, U, rho, C_K = np.array([0.10, 0.11, 0.05]), 17.0, 1025.0, 0.9
    J = analytic.geom_terms(r, (0, 0, 0, C_K, 0), np.zeros(6), rho, 0.0, [U, 0, 0])["lift"][1]
    k = C_K * rho * np.pi * r[1] * r[2] * U
    expected = np.diag([0.0, k * (1 - r[0] ** 2 / r[1] ** 2), k * (1 - r[0] ** 2 / r[2] ** 2)])
    assert np.allclose(J[:3, :3], expected, rtol=1e-12, atol=1e-9)
    assert not J[:, 3:].any() and not J[3:].any()


def test_ellipsoid_added_mass_is_tuckermans():
    r, rho = np.array([0.5, 0.2, 0.1]), 1025.0
    xml = f"""<mujoco><option density="{rho}"/><worldbody><body name="hull"><freejoint/>
      <geom type="ellipsoid" size="{r[0]} {r[1]} {r[2]}" fluidshape="ellipsoid"/>
      </body></worldbody></mujoco>"""
    m = mujoco.MjModel.from_xml_string(xml)

    def kappa(i):
        j, k = (i + 1) % 3, (i + 2) % 3

        def f(lam):
            return np.prod(r) / np.sqrt((r[i] ** 2 + lam) ** 3 * (r[j] ** 2 + lam) * (r[k] ** 2 + lam))

        return quad(f, 0, np.inf, epsabs=0, epsrel=1e-12, limit=200)[0]

    kap = np.array([kappa(i) for i in range(3)])
    V = 4 / 3 * np.pi * np.prod(r)
    mA = rho * V * kap / (2 - kap)
    IA = np.empty(3)
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        a, b = r[j] ** 2 - r[k] ** 2, r[j] ** 2 + r[k] ** 2
        IA[i] = rho * V / 5 * a**2 * (kap[k] - kap[j]) / (2 * a + b * (kap[j] - kap[k]))
    assert np.allclose(rho * m.geom_fluid[0, 6:12], np.concatenate([mA, IA]), rtol=1e-6)
    # and the vehicle's 6×6 (body axes: y, z flip sign, a diagonal keeps its values)
    assert np.allclose(added_mass(m), np.diag(np.concatenate([mA, IA])), rtol=1e-6, atol=1e-9)


def test_open_loop_stable_at_cruise():
    lin, _ = models(20.0)
    for states in (("v", "r"), ("w", "q", "theta")):
        i = [IX[n] for n in states]
        eig = np.linalg.eigvals(lin.A_full[np.ix_(i, i)])
        print(states, eig)
        assert (eig.real < 0).all(), (states, eig)


def test_default_free_list_is_identifiable():
    lin, _ = models(20.0)
    config, _ = analytic.analytic_config(None, 20.0)
    s = structure(lin.vehicle)
    assert structural(s, theta_vector(lin.coefficients), config.free, STATES).null_directions == 0
    assert not any(n.endswith("dot") for n in config.free)


def test_cli_truth_round_trip(capsys, tmp_path):
    lin, _ = models(20.0)
    assert main(["analytic", "--speed", "20"]) == 0
    text = capsys.readouterr().out
    config = parse_config(tomllib.loads(text))
    assert config.coefficients == ModelConfig(lin.vehicle, lin.coefficients).coefficients  # offsets 0
    assert config.vehicle == lin.vehicle
    assert set(config.coefficients) == set(PARAMETERS) and config.free == analytic.FREE
    assert "outside the linear model: " in text and "X_qdot" in text  # terms outside it are in the comments
    out = tmp_path / "model.toml"
    assert main(["analytic", "--speed", "20", "--mjcf", str(default_mjcf()), "--out", str(out)]) == 0
    assert read_config(out).coefficients == ModelConfig(lin.vehicle, lin.coefficients).coefficients


def _one_line_error(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    return err


def test_cli_truth_bad_input(capsys, tmp_path):
    assert "--speed" in _one_line_error(["analytic", "--speed", "0"], capsys)
    assert "speed" in _one_line_error(["analytic", "--speed", "inf"], capsys)
    assert "--speed 1e-300" in _one_line_error(["analytic", "--speed", "1e-300"], capsys)
    assert "--speed 1e+300" in _one_line_error(
        ["analytic", "--speed", "1e300"], capsys
    )  # named as given, not as NaN
    for speed in (0.0, -1.0, float("inf"), float("nan"), 1e-300, 451.0, 1e300):
        with pytest.raises(InputError, match=r"speed=.*; expected a trim speed of 0\.001 to 450 m/s"):
            analytic.analytic_config(None, speed)
        with pytest.raises(InputError, match="expected a trim speed"):
            analytic.analytic_model(load_model(), speed)
    with pytest.raises(InputError, match="speed"):
        analytic.numerical_model(load_model(), -1.0)
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body>")
    assert "bad.xml" in _one_line_error(["analytic", "--mjcf", str(bad)], capsys)
    finless = tmp_path / "finless.xml"
    finless.write_text("""<mujoco><option density="1000"/><worldbody><body name="hull">
      <freejoint name="hull"/><geom type="ellipsoid" size="1 0.2 0.2" fluidshape="ellipsoid"/>
      </body></worldbody><actuator><motor name="thruster" joint="hull" gear="1 0 0 0 0 0"/>
      </actuator></mujoco>""")
    assert "rudder" in _one_line_error(["analytic", "--mjcf", str(finless)], capsys)
    assert "missing.xml" in _one_line_error(["analytic", "--mjcf", str(tmp_path / "missing.xml")], capsys)
