"""The ``qr`` command.  Every user mistake ends in one line on stderr and exit status 2."""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

from . import __version__
from .errors import EXIT_BAD_INPUT, QrInputError, QrInputWarning, error_line

EXAMPLES = """\
commands:
  ingest     raw log -> canonical flight CSV/Parquet (validated)
  synth      synthetic flight with hidden effects (flight.csv, vehicle.yaml, truth.json)
  summary    per-flight table of ingested flights
  diagnose   name what the nominal model gets wrong, extend it, measure the gain
  evaluate   score vehicle models by multi-step open-loop rollout (the field's yardstick)
  replay     fly vehicle models under the vehicle's own controller along the flight's setpoints, against the log
  export     a vehicle for RotorPy, PX4 + Gazebo Sim or MuJoCo, with mapping.md
  filter     Kalman filters / smoother (Hydra overrides)
  learn      train and test residual models, -m for a sweep (Hydra overrides)
  learn residual  a residual wrench trained through the rollout (docs/spec/hybrid.md)
  simulate   closed-loop study and stability analysis (Hydra overrides)

examples:
  qr ingest ../shared/data/imrclab-crazyflie/brushless_flights/data/eckart00 \\
      --vehicle conf/vehicle/crazyflie21_brushless.yaml --out flight.csv
  qr synth --vehicle conf/vehicle/asctec_hummingbird.yaml --duration 60 --rate 100 --seed 1 \\
      --effect linear_drag:kx=0.3,ky=0.3,kz=0.1 --effect cg_offset:rx=0.01,ry=0 --out synth1
  qr diagnose synth1/flight.csv --vehicle synth1/vehicle.yaml --out diag1
  qr evaluate synth1/flight.csv --vehicle synth1/vehicle.yaml --vehicle diag1/extended_vehicle.yaml --out eval1
  qr replay ../shared/data/imrclab-crazyflie/brushless_flights/data/eckart00 --vehicle crazyflie21_brushless \
      --controller lee --out rep1 replay.trajectory=../shared/data/crazyswarm2-figure8/figure8.csv
  qr summary results/ingest/brushless/*.parquet --vehicle conf/vehicle/crazyflie21_brushless.yaml \\
      --out summary.csv
  qr export diag1/extended_vehicle.yaml --to rotorpy --out sim_rotorpy

stages with Hydra configs (conf/; KEY=VALUE overrides, --help each, -m for a sweep):
  qr filter     Kalman filters / smoother: canonical flight -> state table + NIS report
      qr filter filter=auto filter.flight=flight.csv filter.vehicle=vehicle.yaml filter.out=states.parquet
  qr learn      train and test one residual model (ANN, linear, GPR); -m: a sweep, one MLflow parent run
      qr learn -m sweep=table_4_2 hydra/launcher=joblib2      (hydra/launcher=slurm: on SLURM)
  qr learn residual  a body wrench trained through the rollout on top of a vehicle (conf/learn/residual.yaml)
      qr learn residual a.csv b.csv c.csv --vehicle diag/extended_vehicle.yaml --out res learn.width=16
      qr learn residual a.csv b.csv c.csv --vehicle v.yaml --out sweep -m learn.width=16,32
  qr simulate   closed-loop tracking study and stability analysis (thesis Chapter 5)
      qr simulate simulate.task=stability
  (python -m qr.<stage> ARGS = qr <stage> ARGS for ingest, filter, learn, diagnose, simulate, evaluate, export;
   python -m qr.train = qr learn)

the whole workflow (Snakefile; docs/workflow.md):
  snakemake --cores 2                                          every stage, resumable after a kill
  snakemake --cores 2 --configfile conf/workflow_ci.yaml       the reduced run (tests, CI)
  snakemake --profile profiles/slurm                           on SLURM (profiles/local-cluster: local test)
  make mlflow-ui                                               browse the runs at http://127.0.0.1:5000
"""


def _format_warning(message, category, filename, lineno, line=None):
    if issubclass(category, QrInputWarning):
        return f"qr: warning: {message}\n"
    return f"{filename}:{lineno}: {category.__name__}: {message}\n"


class _Parser(argparse.ArgumentParser):
    """argparse's parser, its usage errors in qr's one line (the problem, the fix, exit status 2) instead of
    the usage block above argparse's message (the spec's "one line on standard error").  Subcommands
    inherit it (``add_subparsers`` makes parsers of the parent's class)."""

    def error(self, message: str):
        self.exit(EXIT_BAD_INPUT, error_line(QrInputError(None, message, f"see '{self.prog} --help'"), self.prog) + "\n")


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="qr", description="Learn what a quadrotor's physics model gets wrong from measured flight logs.",
                epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"qr {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    for add in (_add_ingest, _add_synth, _add_summary, _add_flight_commands, _add_export):
        add(sub)
    for name, (_, help) in HYDRA_STAGES.items():  # listed here, parsed by Hydra (_parse)
        sub.add_parser(name, help=help, add_help=False)
    p.commands = sub.choices  # name -> subparser (for _parse)
    return p


def _add_ingest(sub) -> None:
    """``qr ingest``: a raw log to a canonical flight."""
    s = sub.add_parser("ingest", help="raw log -> canonical flight", formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="examples:\n  qr ingest LOG --vehicle conf/vehicle/crazyflie21_brushless.yaml "
                              "--out flight.csv\n  qr ingest px4_export.csv --vehicle my_px4.yaml --frame ned-frd "
                              "--out flight.csv")
    s.add_argument("src", help="raw log: canonical CSV/Parquet, Crazyflie uSD binary, PX4 ULog, ROS 1 bag or ROS 2 bag folder")
    s.add_argument("--vehicle", required=True, help="vehicle YAML (flight-log.md)")
    s.add_argument("--out", required=True, help="output flight (.csv or .parquet); never an existing file")
    s.add_argument("--force", action="store_true", help="replace an existing --out file")
    s.add_argument("--format", default="auto", choices=["auto", "csv", "parquet", "cf-usd", "ulog", "rosbag"])
    s.add_argument("--topic", action="append", metavar="KIND=/NAME",
                   help="ROS bags: the topic of a kind (pose, rotors, imu) where the bag has several")
    s.add_argument("--align", action="store_true",
                   help="move the gyro and the rotor stream by their time offsets to the motion capture (always "
                        "estimated and printed; the rotor offset includes the motors' response)")
    s.add_argument("--skip-check", action="append", default=[], metavar="CHECK",
                   help="a convention check to skip, where you know the log is right (repeatable): thrust_axis, "
                        "gyro, rotor_layout (docs/cli.md)")
    s.add_argument("--frame", default="enu-flu", choices=["enu-flu", "ned-frd"],
                   help="the frames a CSV/Parquet log (or ROS bag) is written in: enu-flu (the spec's: ENU world, "
                        "FLU body; default) or ned-frd (PX4's CSV exports: NED world, FRD body), converted to "
                        "enu-flu: position, velocity vx..vz if present, attitude, gyro and accelerometer "
                        "(docs/ingest.md). A PX4 ULog is converted without it")


def _add_synth(sub) -> None:
    """``qr synth``: a synthetic flight with hidden effects."""
    s = sub.add_parser("synth", help="synthetic flight with hidden effects",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="example:\n  qr synth --vehicle conf/vehicle/asctec_hummingbird.yaml --duration 60 "
                              "--rate 100 --seed 1 --effect linear_drag:kx=0.3,ky=0.3,kz=0.1 --out DIR\n"
                              "effects: see docs/spec/diagnosis.md (qr.effects.CATALOG)")
    s.add_argument("--vehicle", required=True, help="NOMINAL vehicle YAML (an extended one adds its effects)")
    s.add_argument("--duration", type=float, help="s (default 60; --controller lee: the trajectory's length + 2.5 s)")
    s.add_argument("--rate", type=float, default=100.0, help="log rate in Hz (default 100)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--effect", action="append", default=[], metavar="NAME:P=V,...",
                   help="hidden effect in the TRUE plant, every parameter given (repeatable)")
    s.add_argument("--out", required=True, help=OUT_DIR_HELP)
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.add_argument("--noise-free", action="store_true", help="log the true states without noise or dropouts")
    s.add_argument("--position-noise", type=float, help="mocap position std, m (default 0.0005)")
    s.add_argument("--attitude-noise", type=float, help="mocap attitude std, rad (default 0.003)")
    s.add_argument("--rotor-noise", type=float, help="rotor speed std as a fraction of hover speed (default 0.005)")
    s.add_argument("--dropout", type=float, help="fraction of mocap samples blank (default 0.005)")
    s.add_argument("--low-passes", action="store_true", help="dip towards the floor every 12 s (ground effect)")
    s.add_argument("--yaw-rate", type=float, default=0.0, help="constant yaw spin, rad/s")
    s.add_argument("--v-max", type=float, default=2.5, help="peak horizontal speed, m/s")
    s.add_argument("--tilt-max", type=float, default=25.0, help="peak tilt, degrees")
    s.add_argument("--controller", default="lqr", choices=["lqr", "lee"],
                   help="lqr: the thesis's LQR + PD along a random trajectory (default); lee: the Crazyflie firmware's "
                        "Lee controller along --trajectory (qr replay rebuilds the flight)")
    s.add_argument("--trajectory", metavar="PIECES.csv",
                   help="--controller lee: a crazyswarm trajectory CSV (e.g. figure8.csv), flown from (0, 0, 1) m")
    s.add_argument("--timescale", type=float, default=1.0, help="--controller lee: the trajectory's time scale")


def _add_summary(sub) -> None:
    """``qr summary``: a table of ingested flights."""
    s = sub.add_parser("summary", help="table of ingested flights", formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="example:\n  qr summary results/ingest/brushless/*.parquet "
                              "--vehicle conf/vehicle/crazyflie21_brushless.yaml --out summary.csv\n"
                              "writes summary.csv and its Markdown twin summary.md")
    s.add_argument("flights", nargs="+")
    s.add_argument("--vehicle", required=True)
    s.add_argument("--out", required=True,
                   help="CSV (a Markdown twin is written beside it); never an existing file")
    s.add_argument("--force", action="store_true", help="replace existing --out files")


def _add_flight_commands(sub) -> None:
    """The commands that read flights and a vehicle file: diagnose, evaluate, replay."""
    _flights_command(sub, "diagnose", "name what the nominal model gets wrong (docs/spec/diagnosis.md)",
                     "examples:\n  qr diagnose flight.csv --vehicle vehicle.yaml --out diag\n"
                     "  qr diagnose a.csv b.csv --vehicle v.yaml --out diag diagnose.horizon_s=0.5 filter=auto\n"
                     "writes OUTDIR/diagnosis.json, report.md, figures/, extended_vehicle.yaml",
                     vehicle=dict(help="vehicle YAML (nominal, or an extended one to build on)"))
    _flights_command(sub, "evaluate", "multi-step rollout of vehicle models (docs/spec/evaluate.md)",
                     "examples:\n  qr evaluate flight.csv --vehicle v.yaml --vehicle diag/extended_vehicle.yaml "
                     "--out ev\n  qr evaluate a.csv b.csv --vehicle v.yaml --out ev evaluate.horizon=100\n"
                     "writes OUTDIR/evaluation.json, report.md, figures/rollout_mae.png",
                     vehicle=dict(action="append", help="vehicle YAML to score (repeatable; the first one also "
                                                        "filters and is the references' nominal)"))
    s = _flights_command(sub, "replay", "fly vehicle models in closed loop under the vehicle's own controller "
                         "along the flight's setpoints, against the log (docs/spec/replay.md)",
                         "examples:\n  qr replay LOG --vehicle v.yaml --vehicle diag/extended_vehicle.yaml --controller lee "
                         "--out rep replay.trajectory=figure8.csv replay.timescale=0.8\n"
                         "  qr replay synth1/flight.csv --vehicle synth1/vehicle.yaml --controller lee --out rep\n"
                         "writes OUTDIR/replay.json, report.md, figures/; settings: conf/replay/default.yaml, "
                         "conf/controller/lee.yaml (controller.KR=[...])",
                         vehicle=dict(action="append", help="vehicle YAML to fly (repeatable; the first one reads "
                                                            "raw logs)"),
                         what="raw log(s) (Crazyflie uSD: their motor commands give the setpoints' start) or canonical "
                              "flight(s)")
    s.add_argument("--controller", required=True, metavar="lee|rotorpy_se3|MODULE:CLASS",
                   help="the controller the vehicle flew: lee (the Crazyflie firmware's), rotorpy_se3, or your class "
                        "(qr.replay.controller.Controller)")


def _add_export(sub) -> None:
    """``qr export``: a vehicle for a simulator."""
    s = sub.add_parser("export", help="a vehicle for RotorPy, PX4 + Gazebo Sim or MuJoCo (docs/spec/export.md)",
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EXPORT_EPILOG)
    s.add_argument("vehicle", metavar="VEHICLE.yaml", help="vehicle YAML: nominal, extended or hybrid (as qr "
                   "diagnose and qr learn residual write them), or a shipped vehicle's name")
    s.add_argument("--to", required=True, metavar="rotorpy|px4-gz|mujoco", help="the simulator")
    s.add_argument("--out", required=True, help=OUT_DIR_HELP)
    s.add_argument("--force", action="store_true", help=FORCE_HELP)


# qr <stage> [HYDRA ARGS]: the stage's own Hydra entry point (overrides, -m sweeps, --help, --cfg job)
HYDRA_STAGES = {"filter": ("qr.stages.filter", "Kalman filters / smoother on one flight (Hydra overrides)"),
                "learn": ("qr.stages.learn", "train and test residual models; -m: a sweep (Hydra overrides)"),
                "simulate": ("qr.stages.simulate", "closed-loop study and stability analysis (Hydra overrides)")}


def _residual_parser() -> argparse.ArgumentParser:
    s = _Parser(prog="qr learn residual", formatter_class=argparse.RawDescriptionHelpFormatter,
                description="A body force and torque trained through the multi-step rollout "
                            "(docs/spec/hybrid.md), on top of a vehicle file.",
                epilog="examples:\n  qr learn residual a.csv b.csv c.csv --vehicle diag/extended_vehicle.yaml "
                       "--out res\n  qr learn residual a.csv b.csv c.csv --vehicle v.yaml --out sweep -m "
                       "learn.width=16,32 learn.horizon=25,50\nwrites OUTDIR/hybrid_vehicle.yaml, "
                       "residual.npz, training.json, report.md, figures/ (a sweep: OUTDIR/job<N>/, "
                       "sweep.csv); settings: conf/learn/residual.yaml (src/qr/residual_fit.py)")
    s.add_argument("flights", nargs="+", metavar="FLIGHT.csv [KEY=VALUE ...]",
                   help="the training flights (a part is kept for validation), and optional Hydra overrides "
                        "(learn.*, evaluate.*, filter=...), before or after the options")
    s.add_argument("--vehicle", required=True, help="vehicle YAML (nominal or extended, as qr diagnose writes it)")
    s.add_argument("--out", required=True, help=OUT_DIR_HELP)
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    s.add_argument("-m", "--multirun", action="store_true", help="a sweep over comma-separated values (Hydra)")
    return s


def _cmd_learn_residual(a) -> None:
    flights, overrides = _flights_and_overrides(a, "learn residual")
    if a.multirun:
        from .stages.learn_residual_sets import sweep

        sweep(flights, a.vehicle, a.out, overrides, force=a.force)
    else:
        from .stages.learn_residual import run_residual

        run_residual(flights, a.vehicle, a.out, overrides, force=a.force)


def _cmd_hydra_stage(a) -> None:
    import importlib

    module = importlib.import_module(HYDRA_STAGES[a.command][0])
    argv, sys.argv = sys.argv, [f"qr {a.command}", *a.rest]
    try:
        module.main()
    finally:
        sys.argv = argv


def _flights_command(sub, name: str, help: str, epilog: str, vehicle: dict,
                     what: str = "canonical flight(s)") -> argparse.ArgumentParser:
    """A stage command on flights: ``FLIGHT.csv ... [KEY=VALUE ...] --vehicle V --out DIR [--force]``."""
    s = sub.add_parser(name, help=help, formatter_class=argparse.RawDescriptionHelpFormatter, epilog=epilog)
    s.add_argument("flights", nargs="+", metavar="FLIGHT.csv [KEY=VALUE ...]",
                   help=f"{what}, and optional Hydra overrides (conf/{name}/default.yaml), "
                        "before or after the options")
    s.add_argument("--vehicle", required=True, **vehicle)
    s.add_argument("--out", required=True, help=OUT_DIR_HELP)
    s.add_argument("--force", action="store_true", help=FORCE_HELP)
    return s


EXPORT_EPILOG = """\
writes OUTDIR/mapping.md (every parameter and named effect: the simulator's key, its value in the
simulator's units, exact / approximate (with the condition) / impossible (with its size)) and:
  --to rotorpy   OUTDIR/<name>_params.py: quad_params for rotorpy.vehicles.multirotor.Multirotor, and
                 QrMultirotor, a subclass adding the terms RotorPy has no key for (exact: qr's plant)
  --to px4-gz    OUTDIR/<name>/model.config, model.sdf (Gazebo Sim, one MulticopterMotorModel per rotor),
                 OUTDIR/<name>.params (PX4: CA_ROTOR*_PX/PY/KM, SIM_GZ_EC_MIN/MAX; QGroundControl format)
  --to mujoco    OUTDIR/<name>.xml: MJCF body (mass, inertia, CG), thrust and yaw-moment actuators per rotor
                 (ctrl = rotor speed squared, (rad/s)^2)
a hybrid (qr learn residual): rotorpy also writes <name>_residual.npz (QrMultirotor evaluates the network in
NumPy); mujoco writes <name>_learned_wrench.py (a control callback applying it) and the .npz; px4-gz lists
it as impossible with its RMS force and torque over the training flights

examples:
  qr export diag/extended_vehicle.yaml --to rotorpy --out sim_rotorpy
  qr export conf/vehicle/crazyflie21_brushless.yaml --to px4-gz --out sim_gz
  qr export crazyflie21_brushless --to mujoco --out sim_mujoco
units, conventions and their derivations: docs/export.md"""

OUT_DIR_HELP = ("output folder: new, empty, or a previous qr output (only the files qr wrote there are "
                "replaced)")
FORCE_HELP = "write into a non-empty folder that qr did not write, beside its files (none of them is replaced)"


def _cmd_ingest(a):
    from .stages.ingest import ingest_file

    from .ingest.rosbag import parse_topics

    df = ingest_file(a.src, a.vehicle, a.out, a.format, force=a.force, topics=parse_topics(a.topic), align=a.align,
                     skip_checks=a.skip_check, frame=a.frame)
    print(f"{a.out}: {len(df)} samples, {df['t'].iloc[-1] - df['t'].iloc[0]:.2f} s")
    for kind, o in df.attrs["time_offsets"].items():
        when = "late" if o["offset_s"] >= 0 else "early"
        halves = " and ".join(f"{1000 * h:+.1f}" if h is not None else "none" for h in o["halves"])
        act = ("moved" if a.align else "--align would move it") if o["confident"] else \
            "not determined: the log's halves disagree, leave it" + (" (not moved)" if a.align else "")
        print(f"  {kind} stamped {1000 * abs(o['offset_s']):.1f} ms {when} against the motion capture ({o['against']}: "
              f"correlation {o['correlation']:.2f}; its halves alone: {halves} ms): {act}")


def _check_synth_arguments(a):
    """Every number of ``qr synth`` in its range, before anything is simulated."""
    from .allowed import allowed
    from .sim.synth import NoiseConfig

    noise = NoiseConfig()
    ranges = {  # option: (allowed values, default)
        "duration": (allowed(gt=0, le=3600), 60.0),  # s; an hour at 100 Hz is 360 000 rows
        "timescale": (allowed(gt=0, le=100), 1.0),
        "rate": (allowed(gt=0, le=10000), 100.0),  # Hz
        "position_noise": (allowed(ge=0), noise.position_std),
        "attitude_noise": (allowed(ge=0), noise.attitude_std),
        "rotor_noise": (allowed(ge=0), noise.rotor_std),
        # the first and last rows are never blanked, so 1 could never be reached
        "dropout": (allowed(ge=0, lt=1), noise.dropout),
        "v_max": (allowed(ge=0), 2.5),
        "tilt_max": (allowed(ge=0, le=60), 25.0),  # degrees; the nominal controller's reach
        "yaw_rate": (allowed(), 0.0),
        "seed": (allowed("integer", ge=0), 0),
    }
    for name, (rule, default) in ranges.items():
        val = getattr(a, name)
        if val is not None:
            rule.check(f"--{name.replace('_', '-')}", val, default)


def _cmd_synth(a):
    from dataclasses import replace

    from .effects import parse_effect_spec
    from .sim.synth import NoiseConfig, SynthConfig, write_synth
    from .sim.trajectory import TrajectoryConfig
    from .vehicle import load_vehicle

    _check_synth_arguments(a)
    vehicle = load_vehicle(a.vehicle)
    effects = [parse_effect_spec(e, vehicle) for e in a.effect]
    noise = NoiseConfig()
    for field, val in (("position_std", a.position_noise), ("attitude_std", a.attitude_noise),
                       ("rotor_std", a.rotor_noise), ("dropout", a.dropout)):
        if val is not None:
            noise = replace(noise, **{field: val})
    traj = TrajectoryConfig(v_max=a.v_max, tilt_max_deg=a.tilt_max, yaw_rate=a.yaw_rate, low_passes=a.low_passes)
    duration, setpoints = a.duration if a.duration is not None else 60.0, None
    if a.controller == "lee":
        from .replay.synth import duration_of, setpoints_record

        if not a.trajectory:
            raise QrInputError(None, "--controller lee flies a trajectory and none is given",
                               "add --trajectory PIECES.csv (a crazyswarm trajectory, e.g. figure8.csv)")
        setpoints = setpoints_record(a.trajectory, a.timescale, (0.0, 0.0, 1.0), vehicle)
        duration = a.duration if a.duration is not None else duration_of(setpoints)
    elif a.trajectory:
        raise QrInputError(a.trajectory, "--trajectory is flown by --controller lee only", "add --controller lee")
    cfg = SynthConfig(duration=duration, rate=a.rate, seed=a.seed, noise=noise, noise_free=a.noise_free,
                      trajectory=traj, controller=a.controller, setpoints=setpoints)
    meta = write_synth(a.out, vehicle, effects, cfg, force=a.force, inputs=[a.vehicle, a.trajectory])
    names = ", ".join(e["name"] for e in meta["effects"]) or "none"
    print(f"{a.out}: {meta['samples']} samples at {a.rate:g} Hz, hidden effects: {names}")


def _cmd_summary(a):
    from .stages.ingest import summarise_files

    summarise_files(a.flights, a.vehicle, a.out, force=a.force)


def _flights_and_overrides(a, command: str) -> tuple[list[str], list[str]]:
    """The positional arguments of ``qr diagnose`` / ``qr evaluate``: flights, then KEY=VALUE overrides."""
    flights = [f for f in a.flights if "=" not in f or Path(f).exists()]
    if not flights:
        raise QrInputError(None, "no flight given", f"qr {command} FLIGHT.csv --vehicle V.yaml --out OUTDIR")
    return flights, [f for f in a.flights if f not in flights]


def _cmd_diagnose(a):
    from .stages.diagnose import run_diagnosis

    flights, overrides = _flights_and_overrides(a, "diagnose")
    run_diagnosis(flights, a.vehicle, a.out, overrides, force=a.force)


def _cmd_evaluate(a):
    from .stages.evaluate import run_evaluation

    flights, overrides = _flights_and_overrides(a, "evaluate")
    run_evaluation(flights, a.vehicle, a.out, overrides, force=a.force)


def _cmd_replay(a):
    from .stages.replay import run_replay

    flights, overrides = _flights_and_overrides(a, "replay")
    run_replay(flights, a.vehicle, a.controller, a.out, overrides, force=a.force)


def _cmd_export(a):
    from .stages.export import run_export

    for p in run_export(a.vehicle, a.to, a.out, force=a.force):
        print(p)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    sys.stderr.write(_format_warning(message, category, filename, lineno))


def main(argv: list[str] | None = None) -> int:
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        warnings.showwarning = _show_warning
        return _main(argv)


def _parse(parser: argparse.ArgumentParser, argv) -> argparse.Namespace:
    """The documented ``qr diagnose FLIGHT... --vehicle V --out D [KEY=VALUE ...]``: overrides may follow
    the options (argparse's intermixed parsing, which only a parser without subcommands offers)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:2] == ["learn", "residual"]:
        args = _residual_parser().parse_intermixed_args(argv[2:], argparse.Namespace(command="learn residual"))
        return args
    if argv and argv[0] in HYDRA_STAGES:
        return argparse.Namespace(command=argv[0], rest=argv[1:])
    args, rest = parser.parse_known_args(argv)
    if args.command in ("diagnose", "evaluate", "replay"):
        rest = argv[argv.index(args.command) + 1:]
        args = parser.commands[args.command].parse_intermixed_args(rest, argparse.Namespace(command=args.command))
    elif rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    return args


def _main(argv):
    from .procs import Terminated, interrupt_in, sigterm_raises

    parser = _parser()
    args = _parse(parser, argv)
    if args.command is None:
        parser.print_help()
        return 0
    # SIGTERM (kill, a cancelled job) ends the command like Ctrl-C: its temporaries are removed
    with sigterm_raises():
        try:
            {"ingest": _cmd_ingest, "synth": _cmd_synth, "summary": _cmd_summary, "diagnose": _cmd_diagnose,
             "evaluate": _cmd_evaluate, "replay": _cmd_replay, "export": _cmd_export, "learn residual": _cmd_learn_residual,
             **dict.fromkeys(HYDRA_STAGES, _cmd_hydra_stage)}[args.command](args)
        except QrInputError as e:
            print(error_line(e), file=sys.stderr)
            return EXIT_BAD_INPUT
        except (KeyboardInterrupt, SystemError) as e:
            stop = interrupt_in(e)  # a SystemError may carry one (a compiled function was running)
            if stop is None:
                raise
            if isinstance(stop, Terminated):
                print("qr: terminated; nothing half-written was left", file=sys.stderr)
                return 128 + 15
            print("qr: interrupted; nothing half-written was left", file=sys.stderr)
            return 130
    return 0


def run_as(command: str) -> None:
    """``python -m qr.<stage> ARGS``: exit with ``qr <stage> ARGS``'s status."""
    _exit([command, *sys.argv[1:]])


def entry() -> None:
    """The ``qr`` program (the console script): :func:`main` on the command line, then exit."""
    _exit(sys.argv[1:])


def _exit(argv: list[str]) -> None:
    """Exit with ``qr ARGV``'s status.  After one of qr's own commands (not a Hydra stage: a sweep closes
    its parent run at exit) the process ends at once: its files are written and renamed, its MLflow runs
    closed, its figure children reaped, and freeing the ~2000 modules it imported (pandas, scipy,
    numba, matplotlib) would cost ~0.5 s of CPU, a fifth of a short diagnosis."""
    status = main(argv)
    if argv and argv[0] in HYDRA_STAGES:
        sys.exit(status)
    import logging

    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


if __name__ == "__main__":
    entry()
