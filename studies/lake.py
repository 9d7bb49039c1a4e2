"""The lake trial's acceptance: every method from the course-unstable prior, default `ml-gn`
against a global search, the attitude offsets, and held-out dives.

    python studies/lake.py [--seeds 10] [--out runs/lake] [--fit-dives 12] [--methods M ...] [--jobs N]
    python studies/lake.py --tables runs/lake/study.json     # the tables of a study again (its
                                                             # check run where it has none)

For each seed k the built-in lake trial (docs/scenarios.md, the lake trial) is simulated as a
user does it (`testbed simulate --scenario lake --seed k --out OUT/seed<k>`) and fitted through
the command line from the run's `prior.toml` (the a-priori model, course-unstable at +0.80 1/s,
b_phi, b_theta, b_psi among the candidates), every fit timed (wall clock of the command):

- **every method** (`testbed.METHODS`, the command's default options): its exit status (0, 1
  or 2; never 70) and one-line reason (the estimate's status, or the error's line);
- **default `ml-gn` against `--start global`** on the same data and config: ΔJ, the default
  fit's cost (the estimate JSON's `cost`) less the least of the two; reached when ΔJ ≤ 1;
- **the attitude offsets** of default `ml-gn` against the scenario's AHRS `bias` (read from the
  run's scenario.toml), in the fit's σ (the coloured-residual bound where the JSON gives one,
  else the Cramér-Rao σ): within 3 σ; one the screen fixed is not estimated (its reason);
- **the attitude offsets of `testbed check`** (the depth check's kinematics, pooled over the
  dives: no dynamic model) against the same AHRS bias, in the check's Cramér-Rao σ;
- **held-out dives**: `ml-gn` on the first `--fit-dives` dives, `testbed validate` of that
  estimate and of `prior.toml` as it stands on the others; per fitted channel the median fit %
  over the held-out dives, the fit's against the prior's.

Markdown tables on standard output and in OUT/study.md (a table per seed, then the summary),
the numbers in OUT/study.json.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from itertools import repeat
import json
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

from testbed import METHODS
from testbed.outputs import atomic_write_text
from testbed.errors import InputError

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script, too
from studies.seeds import check_out  # noqa: E402

OFFSETS = {"b_phi": "phi", "b_theta": "theta", "b_psi": "psi"}  # offset → the AHRS output it biases
DELTA_J = 1.0  # default ml-gn reaches the global search's optimum within this much cost
SIGMAS = 3.0  # an offset within this many of its σ of the scenario's
FILES = ("study.md", "study.json")


def command(*args: str) -> tuple[int, str, float]:
    """`testbed ARGS` as a user types it (this checkout's package): exit status, the last line
    of standard error, wall-clock seconds."""
    t0 = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "testbed", *args], capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    last = (run.stderr.strip().splitlines() or [""])[-1]
    return run.returncode, last, seconds


def identify(data: list[Path], config: Path, out: Path, *extra: str) -> dict:
    """`testbed identify DATA --config CONFIG --out OUT EXTRA`: exit status, one-line reason (the
    estimate's status where it wrote one, else the error's line), seconds, and the estimate."""
    code, last, seconds = command(
        "identify", *map(str, data), "--config", str(config), "--out", str(out), "--force", *extra
    )
    estimate = json.loads(out.read_text()) if code in (0, 1) and out.exists() else None
    reason = estimate["status"] if estimate else last.removeprefix("testbed identify: error: ")
    return {"exit": code, "reason": reason, "seconds": seconds, "estimate": estimate}


def validate(data: list[Path], config: Path, out: Path, *extra: str) -> dict:
    """`testbed validate DATA --config CONFIG --out OUT EXTRA`: experiment → state → fit %, or
    the error's line."""
    code, last, _ = command(
        "validate", *map(str, data), "--config", str(config), "--out", str(out), "--force", *extra
    )
    if code != 0:
        return {"error": f"exit {code}: {last}"}
    doc = json.loads(out.read_text())["validation"]
    return {e: {s: m["fit_percent"] for s, m in states.items()} for e, states in doc.items()}


def true_offsets(run: Path) -> dict[str, float]:
    """The attitude offsets the scenario injected: its AHRS's `bias`, by offset name."""
    sensors = tomllib.loads((run / "scenario.toml").read_text())["sensors"]
    bias = {o: v for s in sensors.values() if isinstance(s, dict) for o, v in s.get("bias", {}).items()}
    return {name: float(bias.get(state, 0.0)) for name, state in OFFSETS.items()}


def offsets(estimate: dict, truth: dict[str, float]) -> dict[str, dict]:
    """Each attitude offset of `estimate` against `truth`: value, σ (coloured-residual bound
    where given, else Cramér-Rao), error in σ; or the reason the screen fixed it. Where the
    estimate compares with the run's noise-free record (`comparison`'s `truth_fit`: the same fit
    on the `.truth.csv` files), that offset too (`model`: what the linear model takes for an
    offset in the plant's own motion, such as its trim pitch), and the error from the two
    together in σ."""
    out = {}
    corrected = estimate.get("crlb_corrected_std") or {}
    model = {r["name"]: r.get("truth_fit") for r in estimate.get("comparison", {}).get("rows", [])}
    for name, true in truth.items():
        c = estimate["coefficients"].get(name)
        if c is None:
            why = estimate.get("fixed", {}).get(name, {}).get("reason", "not free")
            out[name] = {"true": true, "estimated": False, "reason": why}
            continue
        sd = corrected.get(name) or c["std"] or np.inf  # null in the JSON: an infinite bound
        o = {
            "true": true,
            "estimated": True,
            "value": c["value"],
            "std": sd,
            "sigmas": (c["value"] - true) / sd if np.isfinite(sd) else None,
        }
        if model.get(name) is not None and np.isfinite(sd):
            o |= {"model": model[name], "sigmas_model": (c["value"] - true - model[name]) / sd}
        out[name] = o
    return out


def check(run: Path, out: Path) -> dict:
    """`testbed check RUN --out OUT`: exit status, seconds and the pooled depth check's attitude
    offsets against the scenario's AHRS bias (value, σ, error in σ; or why the check held it)."""
    code, last, seconds = command("check", str(run), "--out", str(out), "--force")
    row = {"exit": code, "seconds": seconds, "reason": last}
    if code != 0:
        return row
    pooled = json.loads(out.read_text())["pooled"].get("depth", {}).get("parameters", {})
    truth = true_offsets(run)
    row["offsets"] = {}
    for name in ("b_phi", "b_theta"):
        p = pooled.get(name)
        if p is None or not p["identifiable"]:
            row["offsets"][name] = {
                "true": truth[name],
                "estimated": False,
                "reason": (p or {}).get("reason", ""),
            }
            continue
        sd = p["std"] or np.inf
        row["offsets"][name] = {
            "true": truth[name],
            "estimated": True,
            "value": p["value"],
            "std": sd,
            "sigmas": (p["value"] - truth[name]) / sd if np.isfinite(sd) else None,
        }
    return row


def median_fit(validation: dict, channels: list[str]) -> dict[str, float | None]:
    """Per channel, the median fit % over the experiments validated."""
    out = {}
    for c in channels:
        values = [v[c] for v in validation.values() if v.get(c) is not None]
        out[c] = float(np.median(values)) if values else None
    return out


def seed_study(run: Path, methods=tuple(sorted(METHODS)), fit_dives: int = 12) -> dict:
    """The study on one run directory of the lake trial (see the module's docstring)."""
    prior, fits = run / "prior.toml", run / "fits"
    fits.mkdir(exist_ok=True)
    row = {"run": str(run), "methods": {}}
    for m in methods:
        row["methods"][m] = identify([run], prior, fits / f"{m}.json", "--method", m)
        print(
            f"{run.name} {m:15s} exit {row['methods'][m]['exit']} "
            f"{row['methods'][m]['seconds']:6.1f} s  {row['methods'][m]['reason']}",
            file=sys.stderr,
        )
    gn = row["methods"].get("ml-gn") or identify([run], prior, fits / "ml-gn.json")
    search = identify([run], prior, fits / "ml-gn-global.json", "--start", "global")
    row["global"] = search
    if gn["estimate"] and search["estimate"]:
        best = min(gn["estimate"]["cost"], search["estimate"]["cost"])
        row["delta_j"] = gn["estimate"]["cost"] - best
        row["same_free"] = list(gn["estimate"]["coefficients"]) == list(search["estimate"]["coefficients"])
    row["offsets"] = offsets(gn["estimate"], true_offsets(run)) if gn["estimate"] else {}
    row["check"] = check(run, fits / "check.json")
    dives = json.loads((run / "manifest.json").read_text())["experiments"]
    fitted, held = dives[:fit_dives], dives[fit_dives:]
    part = identify([run / f"{d}.csv" for d in fitted], prior, fits / "ml-gn-fit-dives.json")
    row["held_out"] = {
        "fit_dives": fitted,
        "held_dives": held,
        "fit": {k: part[k] for k in part if k != "estimate"},
    }
    if part["estimate"] and held:
        held_csv = [run / f"{d}.csv" for d in held]
        outputs = tomllib.loads(prior.read_text())["identify"]["outputs"]
        mine = validate(
            held_csv, prior, fits / "validate-fit.json", "--estimates", str(fits / "ml-gn-fit-dives.json")
        )
        theirs = validate(held_csv, prior, fits / "validate-prior.json")
        row["held_out"] |= {"fitted": mine, "prior": theirs}
        if "error" not in mine and "error" not in theirs:
            a, b = median_fit(mine, outputs), median_fit(theirs, outputs)
            row["held_out"]["median"] = {c: {"fit": a[c], "prior": b[c]} for c in outputs}
            row["held_out"]["better"] = all(
                a[c] is not None and (b[c] is None or a[c] > b[c]) for c in outputs
            )
    return row


def number(x, fmt: str = ".1f") -> str:
    return "–" if x is None or not np.isfinite(x) else format(x, fmt)


def seed_table(seed: int, row: dict) -> str:
    """One seed as Markdown: every method's outcome, the global search, the offsets, the
    held-out dives."""
    out = [f"### Seed {seed}", "", "| fit | exit | wall s | cost | reason |", "|---|---:|---:|---:|---|"]
    fits = dict(row["methods"]) | {"ml-gn --start global": row["global"]}
    for name, f in fits.items():
        cost = f["estimate"]["cost"] if f["estimate"] else None
        out.append(f"| {name} | {f['exit']} | {f['seconds']:.1f} | {number(cost, '.2f')} | {f['reason']} |")
    same = "" if row.get("same_free", True) else " (the two fits' free sets differ)"
    out += [
        "",
        f"Default `ml-gn` less the global search's best: ΔJ = {number(row.get('delta_j'), '.3f')}{same}.",
        "",
    ]
    out += [
        "| offset | true (AHRS bias) | estimate ± σ | error | the plant's own (noise-free fit); error from both |",
        "|---|---:|---:|---|---|",
    ]
    for name, o in row["offsets"].items():
        if o["estimated"]:
            model = f"{o['model']:+.5f}; {o['sigmas_model']:+.1f} σ" if "model" in o else "–"
            error = "unbounded σ" if o["sigmas"] is None else f"{o['sigmas']:+.1f} σ"
            out.append(
                f"| {name} | {o['true']:.5f} | {o['value']:.5f} ± {o['std']:.2g} | {error} | {model} |"
            )
        else:
            out.append(f"| {name} | {o['true']:.5f} | not estimated | {o['reason']} | |")
    c = row.get("check", {})
    if c.get("offsets"):
        out += ["", f"`testbed check` (exit {c['exit']}, {c['seconds']:.1f} s), the depth check pooled:", ""]
        out += ["| offset | true (AHRS bias) | estimate ± σ | error |", "|---|---:|---:|---|"]
        for name, o in c["offsets"].items():
            if o["estimated"]:
                error = "unbounded σ" if o["sigmas"] is None else f"{o['sigmas']:+.1f} σ"
                out.append(f"| {name} | {o['true']:.5f} | {o['value']:.5f} ± {o['std']:.2g} | {error} |")
            else:
                out.append(f"| {name} | {o['true']:.5f} | held | {o['reason']} |")
    h = row["held_out"]
    out += [
        "",
        f"`ml-gn` on {len(h['fit_dives'])} dives (exit {h['fit']['exit']}, {h['fit']['seconds']:.1f} s), "
        f"validated on {', '.join(h['held_dives'])}: median fit % (fit / prior)",
        "",
    ]
    if "median" in h:
        cells = h["median"]
        out += ["| " + " | ".join(cells) + " | better on every one |", "|" + "---:|" * (len(cells) + 1)]
        out.append(
            "| "
            + " | ".join(f"{number(c['fit'])} / {number(c['prior'])}" for c in cells.values())
            + f" | {'yes' if h['better'] else 'no'} |"
        )
    else:
        out.append(
            f"not validated: {h.get('fitted', {}).get('error') or h.get('prior', {}).get('error') or h['fit']['reason']}"
        )
    return "\n".join(out) + "\n"


def summary(rows: dict[int, dict]) -> str:
    """Over the seeds: each method's exits and median wall time, the goals counted."""
    n = len(rows)
    out = [
        "### Summary",
        "",
        f"Over {n} seeds:",
        "",
        "| fit | exit 0 | exit 1 | exit 2 | other | median wall s |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    names = list(next(iter(rows.values()))["methods"]) + ["ml-gn --start global"]
    for name in names:
        fits = [r["global"] if name == "ml-gn --start global" else r["methods"][name] for r in rows.values()]
        codes = [f["exit"] for f in fits]
        other = sum(c not in (0, 1, 2) for c in codes)
        wall = np.median([f["seconds"] for f in fits])
        out.append(
            f"| {name} | {codes.count(0)} | {codes.count(1)} | {codes.count(2)} | {other} | {wall:.1f} |"
        )
    reached = sum(r.get("delta_j", np.inf) <= DELTA_J for r in rows.values())
    out += ["", "| goal | seeds |", "|---|---:|"]
    out.append(
        f"| every method exits 0, 1 or 2 | {sum(all(f['exit'] in (0, 1, 2) for f in r['methods'].values()) for r in rows.values())} of {n} |"
    )
    out.append(f"| default `ml-gn` within ΔJ {DELTA_J:g} of the global search | {reached} of {n} |")
    for name in OFFSETS:
        mine = [r["offsets"].get(name, {}) for r in rows.values()]
        estimated = sum(o.get("estimated", False) for o in mine)
        within = sum(abs(o.get("sigmas") or np.inf) <= SIGMAS for o in mine)
        model = sum(abs(o.get("sigmas_model") or np.inf) <= SIGMAS for o in mine)
        out.append(f"| {name} estimated (not fixed by the screen) | {estimated} of {n} |")
        out.append(f"| {name} within {SIGMAS:g} σ of the AHRS bias | {within} of {n} |")
        out.append(
            f"| {name} within {SIGMAS:g} σ of the AHRS bias plus the plant's own offset | {model} of {n} |"
        )
    for name in ("b_phi", "b_theta"):
        mine = [r.get("check", {}).get("offsets", {}).get(name, {}) for r in rows.values()]
        within = sum(abs(o.get("sigmas") or np.inf) <= SIGMAS for o in mine)
        out.append(f"| {name} of `testbed check` within {SIGMAS:g} σ of the AHRS bias | {within} of {n} |")
    better = sum(r["held_out"].get("better", False) for r in rows.values())
    out.append(f"| held-out dives better than the prior on every fitted channel | {better} of {n} |")
    return "\n".join(out) + "\n"


def one_seed(seed: int, out: Path, methods, fit_dives: int) -> dict:
    """Seed `seed`'s run simulated as a user does it (into OUT/seed<k>), and its study."""
    run = out / f"seed{seed}"
    code, last, seconds = command(
        "simulate", "--scenario", "lake", "--seed", str(seed), "--out", str(run), "--force"
    )
    if code != 0:
        raise RuntimeError(f"simulate seed {seed}: exit {code}: {last}")
    return seed_study(run, methods, fit_dives) | {"simulate_seconds": seconds}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds 1 to N (default 10)")
    ap.add_argument("--out", type=Path, default=Path("runs/lake"), help="the study's folder")
    ap.add_argument("--fit-dives", type=int, default=12, help="dives fitted before the held-out ones")
    ap.add_argument("--methods", nargs="+", default=sorted(METHODS), choices=sorted(METHODS))
    ap.add_argument("--jobs", type=int, default=1, help="seeds studied at once")
    ap.add_argument(
        "--tables", type=Path, help="only print the tables of this study.json, its offsets read again"
    )
    a = ap.parse_args(argv)
    if a.tables:
        rows = {int(k): r for k, r in json.loads(a.tables.read_text()).items()}
        for r in rows.values():
            gn = r["methods"].get("ml-gn", {}).get("estimate")
            r["offsets"] = offsets(gn, true_offsets(Path(r["run"]))) if gn else {}
            if "check" not in r:
                r["check"] = check(Path(r["run"]), Path(r["run"]) / "fits" / "check.json")
        print("\n".join([seed_table(seed, row) for seed, row in rows.items()] + [summary(rows)]))
        return 0
    try:
        check_out(a.out, a.seeds, FILES)
    except InputError as exc:
        print(f"lake.py: {exc}", file=sys.stderr)
        return 2
    rows = {}
    with ProcessPoolExecutor(a.jobs) as pool:
        done = pool.map(
            one_seed, range(1, a.seeds + 1), repeat(a.out), repeat(a.methods), repeat(a.fit_dives)
        )
        for seed, row in zip(range(1, a.seeds + 1), done):
            rows[seed] = row
            print(seed_table(seed, row), flush=True)
            # the study's own folder, run again in place (`check_out`); each seed as it ends
            text = "\n".join([seed_table(k, r) for k, r in rows.items()] + [summary(rows)])
            atomic_write_text(
                a.out / "study.json", json.dumps(rows, indent=1, default=float) + "\n", force=True
            )
            atomic_write_text(a.out / "study.md", text, force=True)
    print(summary(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
