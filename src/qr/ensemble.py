"""A residual ensemble for ``qr learn residual``'s band (``learn.members``; :mod:`qr.bands`).

Each member is the trained hybrid's residual fine-tuned on the training flights resampled by flight (member
k draws with ``numpy.random.default_rng([seed, k])``, shuffles with seed ``seed + 1 + k``), in
``learn.member_jobs`` processes; the same bytes serially or in parallel.  What the members measure, and the
files (``members/``, ``hybrid_vehicle.bands.json``): docs/evaluate.md "Bands: how far to trust a rollout".
"""

from __future__ import annotations

import math
import os
import pickle
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from . import residual as rs
from .atomic import atomic_path, write_json
from .errors import QrInputError

if TYPE_CHECKING:
    from .bands import Scale

MEMBERS_DIR = "members"
BANDS_FILE = "hybrid_vehicle.bands.json"
START = ("warm: each member fine-tuned from the trained network on its resample of the flights (a bootstrap "
         "fine-tune; the spread around the network, its width set by the validation scale)")


@dataclass(frozen=True)
class Member:
    residual: rs.Residual
    seed: int
    flights: Mapping[str, int]  # flight -> times drawn
    best_epoch: int
    epochs_run: int = 0


def resample(flights: list[str], seed: int, k: int) -> dict:
    """Member ``k``'s draw: ``len(flights)`` flights with replacement, as {flight: times drawn} (in the given
    order, only the drawn ones)."""
    rng = np.random.default_rng([seed, k])
    c = Counter(flights[i] for i in rng.integers(0, len(flights), len(flights)))
    return {f: c[f] for f in flights if c[f]}


def member_pieces(parts: list, draw: dict) -> list:
    """The pieces (:class:`qr.residual_fit.Piece`) member training sees: each piece of a drawn flight with its
    training starts, once per draw (the copies without validation starts); every piece keeps its validation
    starts once."""
    out = []
    for pc in parts:
        n = draw.get(pc.flight, 0)
        out.append(replace(pc, train=pc.train if n else pc.train[:0]))
        out += [replace(pc, val=pc.val[:0]) for _ in range(max(n - 1, 0))]
    return out


PARALLEL_FROM_S = 30.0  # learn.member_jobs=0 trains members serially when they would take less (a process
#                         costs a few seconds to start: torch and qr imported again)


def jobs(setting: int, members: int, estimate_s: float = math.inf, cores: int | None = None) -> int:
    """Processes for ``members`` members: ``learn.member_jobs``; 0: the fewest processes that keep min(2, cores)
    cores busy to the end, or 1 when the members' serial time (``estimate_s``) is under :data:`PARALLEL_FROM_S`.
    Members are dealt to the processes in turn, so the last round holds ``members % n`` of them: fewer than
    the cores leaves a core idle at the end (5 members in 2 processes: the fifth alone, 3 member-times; in 3
    processes sharing 2 cores: 2.5).  The members' bytes do not depend on it."""
    c = min(2, cores or os.cpu_count() or 1)
    if setting:
        return max(1, min(setting, members))
    if estimate_s < PARALLEL_FROM_S or c == 1 or members <= 1:
        return 1
    return next(n for n in range(min(c, members), members + 1) if members % n == 0 or members % n >= c)


THREADS_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


def worker(inputs: str, folder: str, ks: str) -> None:
    """A member process (:func:`train_members` starts it with one thread each): the members ``ks``
    (comma-separated, 0-based) from the pickled ``inputs``, each written to ``folder/member<k>.pickle``."""
    work = pickle.loads(Path(inputs).read_bytes())
    for k in map(int, ks.split(",")):
        with atomic_path(Path(folder) / f"member{k}.pickle") as tmp:  # appears whole or not at all
            tmp.write_bytes(pickle.dumps(_member(k, work), protocol=pickle.HIGHEST_PROTOCOL))


def _member(k: int, w: dict):
    """Member ``k`` (0-based) from the inputs ``w``: a :class:`Member`, or the error's parts."""
    import torch  # (heavy: the member processes and the trainer only)

    from .residual_fit import train

    draw = resample(w["training"], w["seed"], k)
    try:
        with torch.random.fork_rng(devices=[]):  # building the network draws its discarded initial weights
            t = train(w["cfg"], w["start"], member_pieces(w["parts"], draw), w["seed"] + 1 + k, keep_start=False)
    except QrInputError as e:  # its own arguments: the exception does not pickle back as it is
        return ("error", e.path, e.problem, e.fix)
    return Member(t.net.to_residual(), w["seed"] + 1 + k, draw, t.best_epoch, len(t.epochs))


def train_members(cfg, start, parts: list, training: list[str], seed: int, members: int,
                  log=lambda m: None, epoch_s: float = math.inf) -> tuple[list[Member], int]:
    """``members`` residuals fine-tuned from ``start`` (the vehicle with the trained residual), each on the
    ``training`` flights resampled by flight (see the module doc), and the processes that trained them
    (:func:`jobs`; ``epoch_s``: the network's seconds per epoch, for the estimate)."""
    n = jobs(cfg.member_jobs, members, epoch_s * cfg.member_epochs * members)
    payload = pickle.dumps({"cfg": replace(cfg, epochs=cfg.member_epochs), "start": start, "parts": parts,
                            "training": training, "seed": seed}, protocol=pickle.HIGHEST_PROTOCOL)
    log(f"ensemble: {members} members fine-tuned from the trained network (at most {cfg.member_epochs} "
        f"epoch(s) each) in {n} process(es)")
    if n == 1:
        work = pickle.loads(payload)  # the inputs exactly as a worker sees them
        return [_done(_member(k, work), k, members, training, log) for k in range(members)], n
    # fresh interpreters (not multiprocessing: a spawned worker re-runs an unguarded main script, as Snakemake's
    # `script:` is), one thread each; the inputs and results go through files
    src = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, **dict.fromkeys(THREADS_ENV, "1"),
           "PYTHONPATH": os.pathsep.join([src, *filter(None, [os.environ.get("PYTHONPATH")])])}
    code = "import sys; from qr.ensemble import worker; worker(*sys.argv[1:])"
    with tempfile.TemporaryDirectory(prefix="qr-members-") as d:
        folder = Path(d)
        with atomic_path(folder / "inputs.pickle") as tmp:
            tmp.write_bytes(payload)
        procs, errs = [], []
        try:
            for j in range(n):
                errs.append(tempfile.TemporaryFile())
                procs.append(subprocess.Popen(
                    [sys.executable, "-c", code, str(folder / "inputs.pickle"), d,
                     ",".join(map(str, range(j, members, n)))], env=env, stdout=subprocess.DEVNULL, stderr=errs[j]))
            out = []
            for k in range(members):
                done, proc = folder / f"member{k}.pickle", procs[k % n]
                while not done.exists():
                    if proc.poll() is not None and not done.exists():
                        errs[k % n].seek(0)
                        tail = errs[k % n].read().decode(errors="replace").strip().splitlines()[-3:]
                        raise RuntimeError(f"the process training ensemble member {k + 1} ended ({proc.returncode}) "
                                           f"without it: {' | '.join(tail)}")
                    time.sleep(0.2)
                out.append(_done(pickle.loads(done.read_bytes()), k, members, training, log))
            return out, n
        finally:
            for proc in procs:
                if proc.poll() is None:
                    proc.kill()
                proc.wait()
            for err in errs:
                err.close()


def _done(r, k: int, members: int, training: list[str], log) -> Member:
    if isinstance(r, tuple):
        raise QrInputError(r[1], f"ensemble member {k + 1}: {r[2]}", r[3])
    log(f"ensemble member {k + 1} of {members}: {sum(r.flights.values())} flights drawn ({len(r.flights)} distinct "
        f"of {len(training)}), best epoch {r.best_epoch} of {r.epochs_run}")
    return r


def calibrated(physical, centre, members: list[Member], parts: list,
               H: int) -> tuple[Scale | None, Scale | None, str]:
    """The band's scales per quantity of its 90 % and 50 % levels on the validation windows
    (:func:`qr.bands.calibrate_levels`) and where."""
    from . import bands
    from .sim.plant import true_params

    val = [pc.windows.scored_at(pc.val) for pc in parts if len(pc.val)]
    if len(members) < 2 or not val:
        return None, None, ""
    rows = [true_params(centre, list(centre.effects))]
    for m in members:
        v = physical.with_changes()
        v.residual = m.residual
        rows.append(true_params(v, list(v.effects)))
    sp = bands.spread(val, np.array(rows), H)
    return (*bands.calibrate_levels(sp),
            f"the {len(val)} validation piece(s) of qr learn residual ({len(sp.err)} windows)")


def write(tmp, members: list[Member], scale, scale50, where: str, note: str, horizon: int) -> None:
    """``members/`` and ``hybrid_vehicle.bands.json`` into the folder ``tmp`` (being written atomically)."""
    from .bands import SCHEMA

    (tmp / MEMBERS_DIR).mkdir()
    docs = []
    for k, m in enumerate(members, 1):
        name = f"{MEMBERS_DIR}/member{k}.npz"
        rs.save_weights(m.residual, tmp / name)
        docs.append({"residual": rs.block(m.residual, name, f"{note}; ensemble member {k}"), "seed": m.seed,
                     "flights": m.flights, "best_epoch": m.best_epoch, "epochs_run": m.epochs_run})
    write_json(tmp / BANDS_FILE, {"schema": SCHEMA, "kind": "ensemble", "vehicle": "hybrid_vehicle.yaml",
                                  "members": docs, "scale": scale, "scale50": scale50, "horizon": horizon,
                                  "calibrated_on": where,
                                  "start": START,
                                  "resampling": "by flight: each member draws as many training flights as there "
                                                "are, with replacement; a flight drawn twice counts twice"})
