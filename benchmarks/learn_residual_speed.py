"""How long ``qr learn residual`` takes on 15 flights of 60 s at 100 Hz (issue 33, part 5: goal ≤ 5 min on
2 cores for the network, ≤ 10 min with the band's ensemble), and where the time goes.

    .venv/bin/python benchmarks/learn_residual_speed.py                    # flights cached in $TMPDIR
    .venv/bin/python benchmarks/learn_residual_speed.py --members          # the defaults: with the ensemble
    .venv/bin/python benchmarks/learn_residual_speed.py --dir /tmp/lrs --flights 15 --profile

1. The flights (made once, kept in ``--dir``; ``qr synth``, one subprocess each): a Crazyflie 2.1
   (``conf/vehicle/crazyflie21_brushless.yaml``) with linear drag and a CG offset hidden — a force
   growing with the body velocity and a torque growing with the thrust, both inside what the
   residual's inputs (v_b, ω, g_b, u²) can express — along the LQR controller's random trajectories,
   varied by seed, peak speed (1–2.5 m/s), peak tilt (10–25°), a constant yaw spin on some and dips
   towards the floor on others.  The vehicle given is ``qr synth``'s nominal ``vehicle.yaml`` (the
   command's documented input: a nominal or extended vehicle file), so the residual has the hidden
   effects to learn.
2. ``qr learn residual`` with its defaults but ``learn.members=0`` (the network alone; ``--members``: the
   defaults, the ensemble of ``learn.members`` included, its seconds printed beside the network's), timed
   from a fresh subprocess (a cold shell: Python
   start-up, imports, numba's cached kernels loaded, filtering every flight, training, the compiled
   validation table, the files and the MLflow run): the wall clock a user sees.  Then the breakdown
   from its ``training.json``: filtering the flights, the training (per epoch: seconds, and the
   shares of rollout forward, backward + Adam step, gathering batches, validation), the rest
   (start-up, the compiled validation table, writing, MLflow).
3. ``--profile``: the same training in this process under cProfile (the 25 most expensive functions
   by own time), for looking into the training loop.

The machine is shared (2 cores): say the load (``os.getloadavg`` is printed) beside any figure quoted.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_SCRIPT = Path(sys.executable).parent / "qr"  # the command a user types, beside this interpreter
QR = [str(_SCRIPT)] if _SCRIPT.exists() else [sys.executable, "-m", "qr.cli"]
VEHICLE = ROOT / "conf" / "vehicle" / "crazyflie21_brushless.yaml"
EFFECTS = ["linear_drag:kx=0.01,ky=0.01,kz=0.005", "cg_offset:rx=0.002,ry=-0.001"]
V_MAX = (1.0, 1.75, 2.5)
TILT_MAX = (10.0, 18.0, 25.0)


def flight_args(k: int) -> list[str]:
    """``qr synth``'s options of flight k (0-based): seed, speed, tilt, yaw spin, floor dips varied."""
    args = ["--seed", str(k + 1), "--v-max", str(V_MAX[k % 3]), "--tilt-max", str(TILT_MAX[(k // 3) % 3])]
    if k % 4 == 1:
        args += ["--yaw-rate", "0.5"]
    if k % 5 == 2:
        args += ["--low-passes"]
    return args


def make_flights(folder: Path, n: int, duration: float, rate: float) -> tuple[list[Path], Path]:
    """The flights' CSVs and the nominal vehicle file, synthesised once (a folder that holds them is reused)."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(n):
        out = folder / f"flight{k + 1:02d}"
        spec = " ".join(["--duration", f"{duration:g}", "--rate", f"{rate:g}", *flight_args(k), *EFFECTS])
        stamp = out / "bench_args.txt"
        if not (stamp.exists() and stamp.read_text() == spec and (out / "flight.csv").exists()):
            t0 = time.perf_counter()
            cmd = [*QR, "synth", "--vehicle", str(VEHICLE), "--duration", f"{duration:g}", "--rate", f"{rate:g}",
                   *flight_args(k), *[a for e in EFFECTS for a in ("--effect", e)], "--out", str(out), "--force"]
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
            stamp.write_text(spec)
            print(f"  synthesised {out.name} ({' '.join(flight_args(k))}): {time.perf_counter() - t0:.1f} s", flush=True)
        paths.append(out / "flight.csv")
    return paths, folder / "flight01" / "vehicle.yaml"


def cold_run(flights: list[Path], vehicle: Path, out: Path, overrides: list[str]) -> tuple[float, list]:
    """``qr learn residual`` in a fresh interpreter with the defaults (plus ``overrides``): its wall clock,
    and its log lines with the second each arrived (kept in ``<dir>/learn.log``)."""
    cmd = [*QR, "learn", "residual", *map(str, flights), "--vehicle", str(vehicle), "--out", str(out), "--force",
           *overrides]
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMP_", "OPENBLAS_", "MKL_"))}
    env["PYTHONUNBUFFERED"] = "1"
    lines = []
    t0 = time.perf_counter()
    with subprocess.Popen(cmd, cwd=out.parent, env=env, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                          text=True) as proc:
        for line in proc.stderr:
            lines.append((time.perf_counter() - t0, line.rstrip()))
    wall = time.perf_counter() - t0
    (out.parent / "learn.log").write_text("".join(f"{t:8.1f} s  {m}\n" for t, m in lines))
    if proc.returncode:
        raise SystemExit(f"qr learn residual failed ({proc.returncode}): see {out.parent / 'learn.log'}")
    return wall, lines


def phases(lines: list, wall: float) -> None:
    """Start-up, filtering, training and the end (validation table, files, MLflow) from the log's times."""
    def first(word):
        return next((t for t, m in lines if word in m), None)

    est, windows, last_epoch, wrote = first("estimates of"), first("validation windows of"), None, first("wrote ")
    epochs = [t for t, m in lines if "qr learn residual: epoch " in m]
    last_epoch = epochs[-1] if epochs else None
    if None in (est, windows, last_epoch, wrote):
        return
    ens = first("ensemble:")
    members = [t for t, m in lines if "ensemble member " in m]
    tail = (f"validation table {ens - last_epoch:.1f} s; ensemble {members[-1] - ens:.1f} s; files and MLflow "
            f"{wrote - members[-1]:.1f} s" if ens and members else f"validation table, files and MLflow {wrote - last_epoch:.1f} s")
    print(f"  from the log: start-up and imports {est:.1f} s; filtering and windows {windows - est:.1f} s; "
          f"training {last_epoch - windows:.1f} s; {tail}; exit {wall - wrote:.1f} s")


def breakdown(doc: dict, wall: float) -> None:
    ep = doc["loss_per_epoch"]
    est, train = doc["wall_s"]["estimates"], doc["wall_s"]["training"]
    print(f"windows: {doc['windows']['training']} training, {doc['windows']['validation']} validation "
          f"(every {doc['windows']['stride']}th start), H = {doc['horizon']}; epochs run {len(ep)} "
          f"(best {doc['epochs']['best']}; {doc['epochs']['stopped']})")
    print(f"  filtering the flights     {est:7.1f} s")
    print(f"  training                  {train:7.1f} s  ({train / max(len(ep), 1):.1f} s per epoch incl. the start)")
    ens = doc.get("ensemble")
    if ens:
        print(f"  the ensemble              {ens['wall_s']:7.1f} s  ({ens['members']} members, at most "
              f"{ens['member_epochs']} epoch(s) each, epochs run {ens['epochs_run']}, in {ens['jobs']} process(es); "
              f"{ens['wall_s'] / max(train, 1e-9):.2f} x the network's training)")
    rest = wall - est - train - (ens["wall_s"] if ens else 0.0)
    print(f"  the rest                  {rest:7.1f} s  (start-up, imports, validation table, files, MLflow)")
    parts = [k for k in ("forward_s", "backward_s", "gather_s", "validation_s") if k in ep[0]]
    print("per epoch (s): " + "  ".join(f"{e['epoch']}: {e['seconds']:.1f}" for e in ep))
    if parts:
        tot = {k: sum(e[k] for e in ep) for k in parts}
        secs = sum(e["seconds"] for e in ep)
        print("where the epochs' time goes: " + ", ".join(f"{k[:-2]} {v:.1f} s ({100 * v / secs:.0f} %)"
                                                          for k, v in tot.items()))
    print("validation ratio to rate_frozen at H (vehicle -> hybrid): " + ", ".join(
        f"{q} {doc['validation']['ratio_to_rate_frozen_at_H']['vehicle'][q]:.3f} -> "
        f"{doc['validation']['ratio_to_rate_frozen_at_H']['hybrid'][q]:.3f}" for q in ("p", "v", "R", "w")))


def profile(flights: list[Path], vehicle: Path, out: Path, overrides: list[str]) -> None:
    import cProfile
    import pstats

    os.environ.setdefault("QR_TRACKING", "off")
    from qr.stages.learn_residual import run_residual

    pr = cProfile.Profile()
    pr.enable()
    run_residual(flights, vehicle, out, overrides, force=True, track=False, log=lambda m: None)
    pr.disable()
    pstats.Stats(pr).sort_stats("tottime").print_stats(25)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()) / "qr-learn-residual-speed",
                    help="where the flights are made once and kept (default: $TMPDIR/qr-learn-residual-speed)")
    ap.add_argument("--flights", type=int, default=15)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--profile", action="store_true", help="also run the training under cProfile, in process")
    ap.add_argument("--no-cold", action="store_true", help="skip the timed cold run (with --profile)")
    ap.add_argument("--members", action="store_true",
                    help="time the defaults, the band's ensemble included (else learn.members=0: the network alone)")
    ap.add_argument("overrides", nargs="*", help="qr learn residual overrides (default: none, the defaults)")
    a = ap.parse_args()
    if not a.members:
        a.overrides = ["learn.members=0", *a.overrides]
    print(f"flights: {a.flights} x {a.duration:g} s at {a.rate:g} Hz in {a.dir}", flush=True)
    flights, vehicle = make_flights(a.dir, a.flights, a.duration, a.rate)
    out = a.dir / "learned"
    if not a.no_cold:
        if out.exists():
            shutil.rmtree(out)
        load0 = os.getloadavg()[0]
        wall, lines = cold_run(flights, vehicle, out, a.overrides)
        load1 = os.getloadavg()[0]
        print(f"\nqr learn residual, {a.flights} flights, defaults{' + ' + ' '.join(a.overrides) if a.overrides else ''}, "
              f"cold shell: {wall:.1f} s wall ({wall / 60:.1f} min; goal <= {10 if a.members else 5} min on 2 cores); "
              f"load average {load0:.1f} before, {load1:.1f} after")
        breakdown(json.loads((out / "training.json").read_text()), wall)
        phases(lines, wall)
    if a.profile:
        profile(flights, vehicle, a.dir / "profiled", a.overrides)


if __name__ == "__main__":
    main()
