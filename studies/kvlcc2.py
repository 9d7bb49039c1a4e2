"""Real data: the KVLCC2 tanker's free-running trials, identified with testbed's sway-yaw model.

    python studies/kvlcc2.py RAW_DIR [--data DIR] [--out DIR] [--convert-only] [--fit NAME]
                             [--records NAME...] [--roll]

RAW_DIR holds one of the two public SIMMAN 2008 sets (as in the repository
martinlarsalbert/System-identification-of-Vessel-Manoeuvring-Models, `data/01_raw/...`):

- MARIN: `MARIN_FREE_KVLCC2_{zz_10,zz_-10,zz_20,zz_-20,tc_35,tc_-35}_m.dat`, full scale, 3 header
  lines, 11 columns: t, x0, y0, φ, ψ, ẋ0, ẏ0, p, r, δ, n (deg, deg/s, m/s, rpm). t is printed to
  three significant digits (a step of 0.135 s repeats stamps beyond 10 s).
- HSVA: `HSVA_CPMC_KVLCC2_Z_*.dat`, model scale 1:45.7, 4 header lines, 12 columns: t, x0, y0,
  ψ, ẋ0, ẏ0, r, φ, δ, n, thrust, torque.

Column meanings were checked on the data: dx0/dt = ẋ0 and dy0/dt = ẏ0 (earth-fixed velocities,
not body ones), dψ/dt = r, dφ/dt = p (MARIN). HSVA's 8th column has no rate to check it
against; its size and its correlation with sway match MARIN's roll angle, so it is read as φ.
The SIMMAN report gives the conventions: origin amidships, ψ positive to starboard, φ
starboard down, δ positive steering to port. A positive δ thus turns the bow to port, as a
positive rudder turns testbed's torpedo (N_dr < 0): δ is kept as it is, in radians.

Conversion (`convert`): uniform time (`uniform_time`), ψ unwrapped, body velocities at the CG, a
uniform grid (1 s full scale, 0.1 s model scale), inputs as interval means (the zero-order
hold); one model config per record (its approach speed as U, a-priori coefficients from Clarke,
Gedling & Hine 1983 and the rudder's lift; `ship_data.yml` beside RAW_DIR or one level up).
The study (`study_record`): every method of METHODS on each record through `testbed identify`,
a scipy reference of the same likelihood, and every fit validated on the other records; Markdown
tables on standard output and in OUT/study.md, the numbers in OUT/study.json.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares, linprog

from testbed.identification import likelihood, recursions
from testbed.identification.problem import Problem, problem
from testbed.data import ModelConfig, read_config, read_csv, write_config, write_csv
from testbed.outputs import atomic_write_text
from testbed.models.linear import COEFFICIENTS, Vehicle
from testbed.analysis.validation import validate

G = 9.81
LAYOUTS = {  # raw columns in file order; angles in deg, rates in deg/s
    "MARIN": ("t", "x0", "y0", "phi", "psi", "dx0", "dy0", "p", "r", "delta", "n"),
    "HSVA": ("t", "x0", "y0", "psi", "dx0", "dy0", "r", "phi", "delta", "n", "thrust", "torque"),
}
SCALE = {"MARIN": 45.7, "HSVA": 1.0}  # the data's scale relative to ship_data.yml (model scale)
RHO = {"MARIN": 1025.0, "HSVA": 1000.0}  # sea water at full scale; the towing tank's fresh water
STEP = {"MARIN": 1.0, "HSVA": 0.1}  # s, the resampled step
# Not in ship_data.yml (model scale, from the SIMMAN 2008 KVLCC2 particulars and HSVA's report):
GM, KG, KXX = 0.125, 0.407, 0.372  # m, m, roll radius of gyration / B (added inertia included)
K_RUDDER = 0.95  # (u_R/U)² (1 + a_H): the rudder's inflow (0.85 U) and hull interaction (a_H 0.31)
ROLL_DAMPING = 0.05  # the roll mode's damping ratio, a-priori (no bilge keels)
SWAY_YAW_FREE = ("Y_v", "Y_r", "N_v", "N_r", "Y_dr", "N_dr")
ROLL_FREE = ("K_v", "K_p", "K_r", "K_dr")


def kind_of(path: Path) -> str:
    for kind in LAYOUTS:
        if path.name.upper().startswith(kind):
            return kind
    raise ValueError(f"{path}: not a MARIN_ or HSVA_ record")


def read_dat(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The raw columns of a .dat file and each stamp's printing resolution (one unit of its last
    digit). Lines that are not all numbers (headers, blank or tab-only lines) are skipped."""
    names = LAYOUTS[kind_of(path)]
    rows, ulp = [], []
    for line in path.read_bytes().decode("latin-1").splitlines():
        fields = line.split()
        try:
            values = [float(f) for f in fields]
        except ValueError:
            continue
        if len(values) == len(names):
            rows.append(values)
            ulp.append(last_digit(fields[0]))
    if len(rows) < 3:
        raise ValueError(f"{path}: fewer than 3 rows of {len(names)} numbers")
    a = np.array(rows)
    return {n: a[:, k] for k, n in enumerate(names)}, np.array(ulp)


def last_digit(token: str) -> float:
    """One unit of the last printed digit of a number: '1.36E-01' → 0.001, '0.050000' → 1e-6."""
    m = re.fullmatch(r"[-+]?\d*(?:\.(\d*))?(?:[eE]([-+]?\d+))?", token)
    decimals = len(m.group(1) or "") if m else 0
    return 10.0 ** (int(m.group(2) or 0) - decimals) if m else 1.0


def uniform_time(t: np.ndarray, ulp: np.ndarray, slack: float = 1.1) -> np.ndarray | None:
    """The uniform times t0 + k Δ nearest the printed stamps in the worst case (a Chebyshev fit,
    each stamp's deviation counted in its half printing unit), if every stamp is within `slack`
    half units of them: the stamps are those of one uniform clock, rounded. Else None (a gap)."""
    k = np.arange(t.size, dtype=float)
    half = 0.5 * ulp
    # variables t0, Δ, e: minimise e subject to |t0 + k Δ − t_k| ≤ e half_k
    A = np.block([[np.c_[np.ones_like(k), k, -half]], [np.c_[-np.ones_like(k), -k, -half]]])
    fit = linprog([0, 0, 1], A_ub=A, b_ub=np.r_[t, -t], bounds=[(None, None)] * 2 + [(0, None)])
    if not fit.success or fit.x[1] <= 0 or fit.x[2] > slack:
        return None
    return fit.x[0] + fit.x[1] * k


def merged(t: np.ndarray, cols: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Rows sharing a stamp merged into their mean, stamps sorted."""
    stamps, which = np.unique(t, return_inverse=True)
    counts = np.bincount(which)
    return stamps, {n: np.bincount(which, weights=c) / counts for n, c in cols.items()}


def interval_mean(t: np.ndarray, y: np.ndarray, grid: np.ndarray, dt: float) -> np.ndarray:
    """The mean of the linear interpolant of y over [grid_k, grid_k + dt) (the last: its value)."""
    area = np.concatenate([[0.0], np.cumsum(np.diff(t) * (y[1:] + y[:-1]) / 2)])

    def integral(tau):
        i = np.clip(np.searchsorted(t, tau, side="right") - 1, 0, t.size - 2)
        return area[i] + (tau - t[i]) * (y[i] + np.interp(tau, t, y)) / 2

    mean = np.interp(grid, t, y)
    inside = grid + dt <= t[-1]
    mean[inside] = (integral(grid[inside] + dt) - integral(grid[inside])) / dt
    return mean


def ship(raw_dir: Path, kind: str) -> dict[str, float]:
    """The ship's particulars at the data's scale (SI): L, B, T, CB, rho, m, volume, x_G, Iz,
    Ix, Iy, GM, KG, A_R, H_R, x_R (midship origin); `ship_data.yml` is at model scale."""
    path = raw_dir / "ship_data.yml"
    path = path if path.exists() else raw_dir.parent / "ship_data.yml"
    data = {}
    for line in path.read_text().splitlines():  # flat `key: number  # comment` lines
        m = re.match(r"^(\w+):\s*([-+0-9.eE]+)\s*(#.*)?$", line)
        if m:
            data[m.group(1)] = float(m.group(2))
    lam, rho = SCALE[kind], RHO[kind]
    s = {"rho": rho, "CB": data["CB"], "GM": GM * lam, "KG": KG * lam}
    s.update({k: data[k] * lam for k in ("L", "B", "T", "x_G", "H_R", "x_r")})
    s["A_R"] = data["A_R"] * lam**2
    s["volume"] = data["volume"] * lam**3
    s["m"] = rho * s["volume"]
    s["Iz"] = data["I_z"] / data["m"] * lam**2 * s["m"] - s["m"] * s["x_G"] ** 2  # about the CG
    s["Ix"] = s["m"] * (KXX * s["B"]) ** 2
    s["Iy"] = s["m"] * (0.25 * s["L"]) ** 2
    return s


def record(path: Path) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, float]]:
    """One raw record converted: the uniform grid, the states (SI, body axes at the CG, absolute u)
    and delta_r (rad, interval means), and the ship's particulars."""
    kind = kind_of(path)
    cols, ulp = read_dat(path)
    s = ship(path.parent, kind)
    cols["psi"] = np.unwrap(np.deg2rad(cols["psi"]))
    t = uniform_time(cols["t"], ulp)
    if t is None:
        t, cols = merged(cols["t"], cols)
    dt = STEP[kind]
    grid = np.arange(t[0], t[-1] + 1e-9, dt)
    at = {n: np.interp(grid, t, c) for n, c in cols.items()}
    psi, r = at["psi"], np.deg2rad(at["r"])
    out = {
        "u": at["dx0"] * np.cos(psi) + at["dy0"] * np.sin(psi),
        "v": -at["dx0"] * np.sin(psi) + at["dy0"] * np.cos(psi) + s["x_G"] * r,
        "r": r,
        "phi": np.deg2rad(at["phi"]),
        "psi": psi,
        "delta_r": interval_mean(t, np.deg2rad(cols["delta"]), grid, dt),
    }
    if "p" in cols:
        out["p"] = np.deg2rad(at["p"])
    return grid - grid[0], out, s


def clarke(s: dict[str, float], U: float) -> dict[str, float]:
    """Sway-yaw derivatives of Clarke, Gedling & Hine (1983), dimensional (½ρL²U, ½ρL³U, ...,
    ½ρL³, ...), moved from the midship origin to the CG: D_G = Tᵀ D_O T, T = [[1, −x_G], [0, 1]]."""
    L, b, t, CB = s["L"], s["B"] / s["L"], s["T"] / s["L"], s["CB"]  # b = B/L, t = T/L
    damping = [
        [1 + 0.40 * CB * b / t, -0.5 + 2.2 * b - 0.080 * b / t],
        [0.5 + 2.4 * t, 0.25 + 0.039 * b / t - 0.56 * b],
    ]
    added = [
        [1 + 0.16 * CB * b / t - 5.1 * b**2, 0.67 * b - 0.0033 * (b / t) ** 2],
        [1.1 * b - 0.041 * b / t, 1 / 12 + 0.017 * CB * b / t - 0.33 * b],
    ]
    # prime → SI: ½ρ L² [[1, L], [L, L²]], times U (damping) or L (added mass), and Clarke's −π (T/L)²
    unit = -math.pi * t**2 * 0.5 * s["rho"] * np.array([[L**2, L**3], [L**3, L**4]])
    damping, added = unit * U * np.array(damping), unit * L * np.array(added)
    shift = np.array([[1.0, -s["x_G"]], [0.0, 1.0]])
    D, M = shift.T @ damping @ shift, shift.T @ added @ shift
    return {
        "Y_v": D[0, 0], "Y_r": D[0, 1], "N_v": D[1, 0], "N_r": D[1, 1],
        "Y_vdot": M[0, 0], "Y_rdot": M[0, 1], "N_vdot": M[1, 0], "N_rdot": M[1, 1],
    }  # fmt: skip


def prior(s: dict[str, float], U: float, roll: bool) -> dict[str, float]:
    """Every a-priori coefficient: Clarke's sway and yaw, the rudder's lift (Fujii's slope
    6.13 Λ/(Λ + 2.25), Λ = H_R²/A_R, on K_RUDDER ½ρU²A_R; N_dr at the rudder's arm from the CG),
    surge from the ITTC-57 friction line (form factor 0.3); with `roll`, the lateral forces'
    heeling arms (hull at T/2 below the waterline, rudder at H_R/2 above the keel) and
    ROLL_DAMPING."""
    c = clarke(s, U)
    aspect = s["H_R"] ** 2 / s["A_R"]
    c["Y_dr"] = K_RUDDER * 0.5 * s["rho"] * U**2 * s["A_R"] * 6.13 * aspect / (aspect + 2.25)
    c["N_dr"] = (s["x_r"] - s["x_G"]) * c["Y_dr"]
    wetted = 1.7 * s["L"] * s["T"] + s["volume"] / s["T"]  # Mumford's wetted surface
    reynolds = U * s["L"] / 1.19e-6
    drag = 1.3 * 0.075 / (math.log10(reynolds) - 2) ** 2 * 0.5 * s["rho"] * wetted * U**2
    c["X_u"], c["X_udot"] = -2 * drag / U, -0.05 * s["m"]
    c["Z_wdot"], c["M_qdot"] = -s["m"], -0.5 * s["Iy"]  # only to give heave and pitch an inertia
    if roll:
        z_hull, z_rudder = s["KG"] - s["T"] / 2, s["KG"] - s["H_R"] / 2
        c["K_v"], c["K_r"], c["K_dr"] = -z_hull * c["Y_v"], -z_hull * c["Y_r"], -z_rudder * c["Y_dr"]
        c["K_p"] = -2 * ROLL_DAMPING * math.sqrt(s["m"] * G * s["GM"] * s["Ix"])
    return c


def model_config(
    s: dict[str, float], U: float, roll: bool, measured=("v", "p", "r", "phi", "psi")
) -> ModelConfig:
    """The record's model config: W = B = m g, the restoring arm zB = −GM (the metacentre above
    the CG stands for the waterplane's restoring), free and fitted as the variant says."""
    W = s["m"] * G
    vehicle = Vehicle(s["m"], s["Ix"], s["Iy"], s["Iz"], W, W, 0.0, 0.0, -s["GM"], U)
    values = prior(s, U, roll)
    coefficients = {n: float(values.get(n, 0.0)) for n in COEFFICIENTS}
    free = SWAY_YAW_FREE + (ROLL_FREE if roll else ())
    outputs = tuple(
        n for n in ("v", "p", "r", "phi", "psi") if n in measured and (roll or n in ("v", "r", "psi"))
    )
    return ModelConfig(vehicle, coefficients, free, outputs=outputs)


def convert(raw_dir: Path, data_dir: Path) -> list[str]:
    """Every record of RAW_DIR as `NAME.csv`, `NAME.toml` (sway-yaw) and `NAME-roll.toml`
    (sway-yaw-roll) in data_dir; returns the names."""
    paths = sorted(p for p in raw_dir.glob("*.dat") if p.name.upper().startswith(tuple(LAYOUTS)))
    if not paths:
        raise ValueError(f"{raw_dir}: no MARIN_*.dat or HSVA_*.dat records")
    data_dir.mkdir(parents=True, exist_ok=True)
    names = []
    for path in paths:
        name = re.sub(r"^(MARIN_FREE_KVLCC2_|HSVA_CPMC_KVLCC2_)|_m$", "", path.stem)
        t, x, s = record(path)
        measured = [n for n in ("u", "v", "p", "r", "phi", "psi") if n in x]
        inputs = np.column_stack([x["delta_r"], np.zeros_like(t), np.zeros_like(t)])
        y = np.column_stack([x[n] for n in measured])  # converted again on every run: replaced
        write_csv(data_dir / f"{name}.csv", t, y, inputs, measured, force=True)
        U = float(np.mean(x["u"][:5]))  # the approach speed
        write_config(data_dir / f"{name}.toml", model_config(s, U, roll=False), force=True)
        write_config(data_dir / f"{name}-roll.toml", model_config(s, U, True, measured), force=True)
        names.append(name)
    return names


# --- the study -------------------------------------------------------------------------------------

# (label, method, extra options); an option the CLI does not accept yet is reported, not fatal
METHODS = (
    ("ml-gn", "ml-gn", ()),
    ("ml-gn config", "ml-gn", ("--start", "config")),
    ("ml-gn global", "ml-gn", ("--start", "global")),
    ("ml-nm", "ml-nm", ()),
    ("mekf", "mekf", ()),
)
FIT = {"MARIN": "zz_10", "HSVA": "Z_10_01"}  # the most linear well-excited zigzag of each set
CHANNELS = ("v", "r", "psi")


def identify_cli(csv: Path, toml: Path, method: str, extra, out: Path) -> dict:
    """`testbed identify` on one record: its estimates JSON, or {"status": why} if it wrote none."""
    out.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "testbed", "identify", str(csv), "--config", str(toml), "--method", method]
    run = subprocess.run(cmd + [*extra, "--out", str(out)], capture_output=True, text=True)
    if run.returncode in (0, 1) and out.exists():
        return json.loads(out.read_text())
    why = (run.stderr.strip().splitlines() or [""])[-1].removeprefix("testbed identify: error: ")
    return {"status": f"no estimate (exit {run.returncode}): {why.split(';')[0]}"}


def concentrated(prob: Problem, theta: np.ndarray, rounds: int = 50) -> tuple[float, np.ndarray]:
    """The negative log-likelihood at the free `theta` with the initial states and the noise at
    their ML values (alternated until the noise settles), and the parameter vector there."""
    R = None
    for _ in range(rounds):
        p = likelihood.initial_states(prob, theta, R)
        R_new = likelihood.noise_variance(prob, recursions.residuals(prob, p))
        if R is not None and np.allclose(R_new, R, rtol=1e-9, atol=0):
            break
        R = R_new
    return likelihood.negative_log_likelihood(prob, recursions.residuals(prob, p)), p


def weighted(prob: Problem, R: np.ndarray):
    """The residuals over the noise σ as a function of p (a diverging model's: large, finite),
    and their Jacobian from testbed's exact output sensitivities."""
    weight = [R[r.channels] ** -0.5 for r in prob.records]

    def fun(q):
        with np.errstate(all="ignore"):
            e = np.concatenate([(e * w).ravel() for e, w in zip(recursions.residuals(prob, q), weight)])
        return np.nan_to_num(e, nan=1e10, posinf=1e10, neginf=-1e10)

    def jac(q):
        rows = []
        for r, S, w in zip(prob.records, recursions.sensitivities(prob, q), weight):
            block = np.zeros((r.y.size, prob.n_params))
            block[:, prob.columns(r)] = -(S * w[None, :, None]).reshape(r.y.size, -1)
            rows.append(block)
        return np.concatenate(rows)

    return fun, jac


def reference(prob: Problem, starts, rounds: int = 20) -> tuple[float, np.ndarray, np.ndarray, str]:
    """The same likelihood minimised by scipy's trust-region reflective least squares on the
    noise-weighted residuals over (θ, x0), the noise re-estimated between rounds until the cost
    settles (< 0.001 per round; else after `rounds`); the best over `starts`: (cost, θ, the
    Cramér-Rao σ of θ from the final Jacobian, "settled" or "round limit")."""
    best = (np.inf, None, None, "")
    for theta in starts:
        p = concentrated(prob, np.asarray(theta, dtype=float))[1]
        cost, status = np.inf, "round limit"
        for _ in range(rounds):
            fun, jac = weighted(prob, likelihood.noise_variance(prob, recursions.residuals(prob, p)))
            fit = least_squares(
                fun, p, jac, method="trf", x_scale="jac", ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=200
            )
            p, last = fit.x, cost
            cost = likelihood.negative_log_likelihood(prob, recursions.residuals(prob, p))
            if abs(last - cost) < 1e-3:
                status = "settled"
                break
        if cost < best[0]:
            norm = np.linalg.norm(fit.jac, axis=0)  # columns scaled to 1: θ and x0 differ by 1e14
            with np.errstate(invalid="ignore"):  # NaN where the information is numerically singular
                std = np.sqrt(np.diag(np.linalg.inv((fit.jac / norm).T @ (fit.jac / norm)))) / norm
            best = (cost, p[: prob.n_free], std[: prob.n_free], status)
    return best


def fit_percent(est: dict, csv: Path, toml: Path) -> list[float]:
    """The fit % of v, r, ψ on a record of the config `toml` with the estimated coefficients."""
    coefficients = {n: c["value"] for n, c in est.get("coefficients", {}).items()}
    v = validate([read_csv(csv)], read_config(toml).with_coefficients(coefficients)).experiments
    return [next(iter(v.values()))[c].fit_percent for c in CHANNELS]


def study_record(data: Path, name: str, others: list[str], out: Path, variant: str) -> list[dict]:
    """Every method on one record, the reference fit, and each fit's validation on `others`."""
    csv, toml = data / f"{name}.csv", data / f"{name}{variant}.toml"
    config = read_config(toml)
    experiments = config.fitted([read_csv(csv)])
    a_priori = {n: {"value": config.coefficients[n], "std": None} for n in config.free}
    rows = [{"record": name, "method": "a priori", "estimate": {"status": "–", "coefficients": a_priori}}]
    for label, method, extra in METHODS:
        est = identify_cli(csv, toml, method, extra, out / f"{name}.{label.replace(' ', '-')}.json")
        rows.append({"record": name, "method": label, "estimate": est})
    gn = rows[1]["estimate"]  # ml-gn from its default start: the free set as the default screen left it
    free = tuple(gn.get("coefficients", config.free))
    for row in rows:  # every fit's ML cost: x0 and the noise at their ML values for its coefficients
        values = {n: c["value"] for n, c in row["estimate"].get("coefficients", {}).items()}
        if values:
            own = problem(experiments, replace(config.with_coefficients(values), free=tuple(values)))
            row["ml_cost"] = concentrated(own, own.start)[0]
    # scipy from the a-priori values, ml-gn's estimate and the best fit of any method
    fits = [r for r in rows if "ml_cost" in r and tuple(r["estimate"]["coefficients"]) == free]
    starts = {r["method"]: [r["estimate"]["coefficients"][n]["value"] for n in free] for r in fits[:2]}
    best = min(fits, key=lambda r: r["ml_cost"])
    starts[best["method"]] = [best["estimate"]["coefficients"][n]["value"] for n in free]
    ref_cost, ref_theta, ref_std, status = reference(
        problem(experiments, replace(config, free=free)), starts.values()
    )
    coefficients = {n: {"value": float(v), "std": float(s)} for n, v, s in zip(free, ref_theta, ref_std)}
    ref = {"status": status, "cost": ref_cost, "coefficients": coefficients}
    rows.append({"record": name, "method": "scipy trf", "estimate": ref, "ml_cost": ref_cost})
    for row in rows:
        est = row["estimate"]
        if "ml_cost" not in row:
            continue
        row["dJ"] = row["ml_cost"] - ref_cost
        if tuple(est["coefficients"]) == free:
            values = [est["coefficients"][n]["value"] for n in free]
            row["dtheta_sigma"] = float(np.max(np.abs(values - ref_theta) / ref_std))
        row["validation"] = {
            o: fit_percent(est, data / f"{o}.csv", data / f"{o}{variant}.toml") for o in others
        }
    return rows


def number(x, fmt: str = ".1f") -> str:
    return "–" if x is None or not np.isfinite(x) else format(x, fmt)


def tables(rows: list[dict], fit: str) -> str:
    """The study as Markdown: every record and method; the chosen record's coefficients and its
    validation on every other record."""
    out = [
        "| record | method | status | cost (its own) | ΔJ (ML cost − scipy's) | iterations | wall s | "
        "max \\|Δθ\\|/σ | fit % v / r / ψ on the others (median) |",
        "|---|---|---|---:|---:|---:|---:|---:|---|",
    ]
    for r in rows:
        e = r["estimate"]
        fits = np.array(list(r.get("validation", {}).values()), dtype=float).reshape(-1, len(CHANNELS))
        median = " / ".join(number(x, ".0f") for x in np.median(fits, axis=0)) if fits.size else "–"
        out.append(
            f"| {r['record']} | {r['method']} | {e['status']} | {number(e.get('cost'))} | "
            f"{number(r.get('dJ'), '.2f')} | {e.get('iterations', '–')} | {number(e.get('wall_time_s'), '.2f')} | "
            f"{number(r.get('dtheta_sigma'), '.2f')} | {median} |"
        )
    out += ["", "Per method over the records: converged; at scipy's optimum (ΔJ < 1); median wall time:", ""]
    out += ["| method | converged | ΔJ < 1 | median wall s |", "|---|---:|---:|---:|"]
    for label, *_ in METHODS:
        mine = [r for r in rows if r["method"] == label]
        done = sum(r["estimate"].get("converged", False) for r in mine)
        best = sum(r.get("dJ", np.inf) < 1 for r in mine)
        wall = np.median([r["estimate"].get("wall_time_s", np.nan) for r in mine])
        out.append(f"| {label} | {done} of {len(mine)} | {best} of {len(mine)} | {number(wall, '.2f')} |")
    chosen = [r for r in rows if r["record"] == fit]
    names = list(chosen[-1]["estimate"]["coefficients"]) if chosen else []
    out += ["", f"Coefficients fitted on {fit} (value ± Cramér-Rao σ, SI):", ""]
    out += ["| method | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for r in chosen:
        c = r["estimate"].get("coefficients", {})
        cells = [f"{c[n]['value']:.3g} ± {number(c[n]['std'], '.2g')}" if n in c else "–" for n in names]
        cells = [c.removesuffix(" ± –") for c in cells]
        out.append(f"| {r['method']} | " + " | ".join(cells) + " |")
    others = list(next((r["validation"] for r in chosen if "validation" in r), {}))
    out += ["", f"Fit % (v / r / ψ) of the model fitted on {fit}, simulated on each other record:", ""]
    out += ["| method | " + " | ".join(others) + " |", "|---|" + "---|" * len(others)]
    for r in chosen:
        if "validation" in r:
            cells = [" / ".join(number(x, ".0f") for x in r["validation"][o]) for o in others]
            out.append(f"| {r['method']} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("raw", type=Path, help="folder of MARIN_*.dat or HSVA_*.dat records")
    ap.add_argument("--data", type=Path, help="where the CSVs and configs go (default OUT/data)")
    ap.add_argument("--out", type=Path, default=Path("runs/kvlcc2"), help="the study's folder")
    ap.add_argument("--convert-only", action="store_true", help="only write the CSVs and configs")
    ap.add_argument("--fit", help="the record shown in detail (default: zz_10, Z_10_01)")
    ap.add_argument("--records", nargs="+", help="fit only these records (default: every one)")
    ap.add_argument("--roll", action="store_true", help="the sway-yaw-roll configs (NAME-roll.toml)")
    a = ap.parse_args(argv)
    data = a.data or a.out / "data"
    names = convert(a.raw, data)
    if a.convert_only:
        print("\n".join(names))
        return 0
    fit = a.fit or FIT[kind_of(next(a.raw.glob("*.dat")))]
    variant = "-roll" if a.roll else ""
    (a.out / "estimates").mkdir(parents=True, exist_ok=True)
    rows = []
    for name in a.records or names:
        print(f"fitting {name} ...", file=sys.stderr)
        rows += study_record(data, name, [o for o in names if o != name], a.out / "estimates", variant)
    # the study's own folder, run again in place
    atomic_write_text(a.out / "study.json", json.dumps(rows, indent=1, default=float) + "\n", force=True)
    text = tables(rows, fit)
    atomic_write_text(a.out / "study.md", text, force=True)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
