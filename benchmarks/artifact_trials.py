"""Statistics of the printed-artifact fit (issues 27 and 35; not a speed benchmark): the figures
of docs/artifact.md. Per mode (full: 36 measurements read three times; quick: 12 read once)
and error size (the paper's, and small: 100 um/m, 50 ppm), N random SIMULATED printers on a
220 mm bed: 10 um noise, 0.01 mm rounding, line width 0.40-0.50 mm, shrinkage 0-0.5 %. Prints
how often each value lies within its reported 2 sigma, the sigmas, false alarms, and whether a
1 mm typo (one reading; all repeats of one id) is named by its id alone.

    .venv/bin/python benchmarks/artifact_trials.py [--trials 500] [--mode full|quick]
"""

import argparse

import numpy as np


def main() -> int:
    from octoprint_kincomp.calibration.artifact.program import ArtifactSpec, generate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=500)
    ap.add_argument("--mode", choices=("full", "quick"), action="append")
    args = ap.parse_args()
    for mode in args.mode or ("full", "quick"):
        spec = ArtifactSpec(volume=(0, 220, 0, 220, 0, 250), mode=mode)
        trials(mode, spec.repeats, generate(spec), args.trials)
    return 0


def trials(mode: str, repeats: int, text: str, n: int) -> None:
    """Prints the statistics of ``n`` trials per error size of the program ``text`` read
    ``repeats`` times."""
    from octoprint_kincomp.calibration.artifact.fit import analyse_artifact
    from octoprint_kincomp.calibration.artifact.program import read_measurements, read_program_info
    from octoprint_kincomp.core.params import Params
    from octoprint_kincomp.simulator.artifact import simulate_readings

    meas, info = read_measurements(text), read_program_info(text)

    def named(readings, mid):
        """1 when the typo's id is named alone (left out: the others' findings none); 2 when
        it is named among the readings that could be wrong (all left out: a quick artifact
        cannot tell which), with only what they alone measured said to stay as it was; 0
        else."""
        bad = [
            f
            for f in analyse_artifact(meas, readings, info=info)["findings"]
            if f["severity"] != "info"
        ]
        if [f["evidence"].get("id") for f in bad] == [mid]:
            return 1
        group = [f for f in bad if f["code"] == "artifact.outlier_ambiguous"]
        rest = {f["code"] for f in bad} - {"artifact.outlier_ambiguous", "artifact.not_separable"}
        if len(group) == 1 and mid in group[0]["evidence"]["ids"] and not rest:
            return 2
        return 0

    for size, seed in (("paper", 99), ("small", 98)):
        rng = np.random.default_rng(seed)
        hits, sig = {}, {}
        flagged = 0
        typo_one, typo_all = [0, 0, 0], [0, 0, 0]
        for _ in range(n):
            if size == "paper":
                sq = {
                    "xy": -3638.6 * rng.uniform(0.5, 1.2) * float(rng.choice([-1, 1])),
                    "xz": rng.uniform(-1500, 1500),
                    "yz": rng.uniform(-1500, 1500),
                }
                sc = {a: rng.uniform(-500, 500) for a in "xyz"}
            else:
                sq = {p: 100 * float(rng.choice([-1, 1])) for p in ("xy", "xz", "yz")}
                sc = {
                    "x": 50 * float(rng.choice([-1, 1])),
                    "y": 0.0,
                    "z": -50 * float(rng.choice([-1, 1])),
                }
            truth = Params.from_dict({"squareness_um_per_m": sq, "scale_ppm": sc})
            r = simulate_readings(
                meas,
                truth,
                shrinkage=rng.uniform(0, 0.005),
                line_width_mm=rng.uniform(0.4, 0.5),
                repeats=repeats,
                rng=rng,
            )
            res = analyse_artifact(meas, r, info=info)
            d, u = res["diagnostics"], res["diagnostics"]["uncertainty"]
            want = {("squareness_um_per_m", p): sq[p] for p in sq}
            want.update(
                {
                    ("scale_mismatch_ppm", f"{a}-{b}"): sc[a] - sc[b]
                    for a, b in (("x", "y"), ("x", "z"), ("y", "z"))
                }
            )
            for (key, sub), v in want.items():
                hits.setdefault(sub, []).append(abs(d[key][sub] - v) <= 2 * u[key][sub])
                sig.setdefault(sub, []).append(u[key][sub])
            flagged += any(f["severity"] != "info" for f in res["findings"])
            mid = meas[rng.integers(len(meas))].id
            j = int(rng.integers(repeats))
            one = {a: list(b) for a, b in r.items()}
            one[mid][j] += float(rng.choice([-1, 1]))
            typo_one[named(one, mid)] += 1
            every = {a: list(b) for a, b in r.items()}
            every[mid] = [v + 1.0 for v in every[mid]]
            typo_all[named(every, mid)] += 1
        print(f"## {mode}, {size}: {n} trials")
        for sub in hits:
            print(
                f"{sub}: within 2 sigma {100 * np.mean(hits[sub]):.1f} %, sigma mean "
                f"{np.mean(sig[sub]):.1f}, max {np.max(sig[sub]):.1f}"
            )
        print(
            f"clean trials with a warning/error: {flagged}; one reading +-1 mm named alone: "
            f"{typo_one[1]}/{n}, named among those left out with it: {typo_one[2]}/{n}; all "
            f"repeats of one id +1 mm named alone: {typo_all[1]}/{n}, among those left out "
            f"with it: {typo_all[2]}/{n}"
        )


if __name__ == "__main__":
    raise SystemExit(main())
