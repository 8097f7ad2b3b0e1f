"""The refinement alone on a per-rotor thrust error: nothing named, the file's model as its start (issue 33, part 2).

    .venv/bin/python benchmarks/refine_rotor_alone.py                 # Crazyflie, rotor 2 at 0.97, seed 1
    .venv/bin/python benchmarks/refine_rotor_alone.py --seed 3 --d2 -0.02

``tests/diagnose/test_refine_generalizes.py`` runs the same flights through ``qr diagnose``, which names the
imbalance by equation error and refines from there.  This script calls :func:`qr.diagnose.refine.refine` with no
effect named (as ``tests/diagnose/test_refine_rotors.py`` does for the Hummingbird) on a 20 s random trajectory
and prints what it admits, wants, holds as unconstrained and writes, then the written, the true and the file's
model scored at h = 50 on the crazyswarm figure-8 (Lee controller) as ratios to ``rate_frozen`` (p / v / R / ω).
Measured (seed 1, under load): admitted motor_imbalance and cg_offset (held-out loss −37 %), the first fit's
loss 10531 → 39.5, but the written model is the file's (the per-rotor/CG directions unconstrained around the
one-step model): figure-8 6.11 / 6.66 / 7.53 / 8.29, the file's 6.12 / 6.67 / 7.53 / 8.29, the true plant's
0.70 / 0.66 / 0.61 / 0.57.
"""

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("QR_TRACKING", "off")

ROOT = Path(__file__).resolve().parents[1]
FIGURE8 = Path(os.environ.get("QR_DATA", ROOT.parent / "shared" / "data" / "imrclab-crazyflie")).parent / \
    "crazyswarm2-figure8" / "figure8.csv"
H = 50


def main():
    from qr.config import compose, to_dict
    from qr.diagnose.refine import RefineSettings, balance_rows, diagnosis_windows, refine
    from qr.effects import parse_effect_spec
    from qr.flight import read_flight
    from qr.replay.synth import duration_of, setpoints_record
    from qr.rollout import MODEL, RATE_FROZEN, EvaluateConfig, at, pool, score_plant, summary, windows
    from qr.sim.plant import true_params
    from qr.sim.synth import SynthConfig, write_synth
    from qr.pieces import rollout_pieces
    from qr.vehicle import load_vehicle

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--d2", type=float, default=-0.03)
    ap.add_argument("--duration", type=float, default=20.0)
    a = ap.parse_args()
    v = load_vehicle(ROOT / "conf" / "vehicle" / "crazyflie21_brushless.yaml")
    eff = [parse_effect_spec(f"motor_imbalance:d1=0,d2={a.d2},d3=0,d4=0")]
    filt = to_dict(compose(["filter=auto"]))["filter"]
    pieces = lambda p: rollout_pieces([p], [read_flight(p)], v, EvaluateConfig(horizon=H), filt)[0]  # noqa: E731
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_synth(tmp / "train", v, eff, SynthConfig(duration=a.duration, rate=100, seed=a.seed))
        rec = setpoints_record(FIGURE8, 1.0, (0, 0, 1), v)
        write_synth(tmp / "fig8", v, eff, SynthConfig(duration=duration_of(rec), rate=100, seed=a.seed + 1,
                                                      controller="lee", setpoints=rec))
        st, ms, _ = zip(*pieces(tmp / "train" / "flight.csv"))
        t = st[0]["t"].to_numpy()
        cut = t[0] + 0.7 * (t[-1] - t[0])
        split = [{"train": [t[0], cut], "test": [cut + 0.5, t[-1]]}]
        owner = [0] * len(st)
        train, test, noise = diagnosis_windows(list(st), list(ms), owner, split, H, 2, 0.5)
        t0 = time.perf_counter()
        r = refine(train, test, v, [], RefineSettings(horizon=H), noise, 0,
                   balance=balance_rows(list(st), owner, split, 0.5))
        print(f"refinement: {time.perf_counter() - t0:.1f} s; {r.stopped}")
        for term, (before, after, ok) in r.admission.items():
            print(f"  admission {term}: held-out loss {before:.4g} -> {after:.4g} ({'admitted' if ok else 'not'})")
        for p in r.parameters:
            if p.refined:
                print(f"  {p.label:24s} one-step {p.one_step:+.4g}  wants {p.rollout:+.4g} ± {p.rollout_se or float('nan'):.2g}"
                      f"  written {p.written:+.4g}")
        for d in r.unconstrained:
            print(f"  unconstrained (s.e. {d.stderr if d.stderr is None else round(float(d.stderr), 2)} of the ranges): "
                  + ", ".join(f"{lab} {x:+.2f}" for lab, x in d.loadings))
        written = v.with_changes(effects=r.effects([]), **r.properties())
        truth = v.with_changes(effects=eff)
        plants = {"rate_frozen": (true_params(v, residual=False), RATE_FROZEN), "file": (true_params(v), MODEL),
                  "true": (true_params(truth, truth.effects), MODEL),
                  "written": (true_params(written, written.effects), MODEL)}
        parts = [{k: score_plant(windows(s, m, H, 2, keep), H, P, mode) for k, (P, mode) in plants.items()}
                 for s, m, keep in pieces(tmp / "fig8" / "flight.csv")]
        b = {k: summary(*x) for k, x in pool(parts).items()}
        for k in ("file", "true", "written"):
            print(f"figure-8, {k:8s} model: " + " / ".join(f"{at(b[k], H, q) / at(b['rate_frozen'], H, q):.2f}"
                                                        for q in "pvRw") + " x rate_frozen (p / v / R / w)")


if __name__ == "__main__":
    main()
