"""Beyond the catalog: does a learned model still find structure in what the named effects leave?

A non-leaking learned model (``qr.models``; inputs never include ``a_b`` or
``alpha``, from which the residual is computed) is fit to the training part of
the remaining residual and judged on the held-out part.  Structure remains when
it cuts the held-out weighted loss by more than ``remainder_min_gain``; each
input group alone then says what the remainder is correlated with.
"""

from __future__ import annotations

import numpy as np

from ..parallel import thread_map
from .core import extended_prediction, weights


def remainder(res: dict, vehicle, cfg) -> dict:
    try:
        from ..datasets import features
        from ..models import fit
    except ImportError:
        return {"evaluated": False, "statement": "Not evaluated: the learning stage (qr.models) is not installed."}
    # cross-fitted data: features from one half-sample filter, labels from the other (no shared noise)
    prep = res["fitprep"]
    named, theta = res["named"], res["theta"]
    tr, te = np.flatnonzero(prep.train), np.flatnonzero(prep.test)
    s_tr, s_te = prep.s.take(tr), prep.s.take(te)
    r_tr = prep.y[tr] - extended_prediction(prep, vehicle, named, theta, tr, res.get("force_only", ()))
    r_te = prep.y[te] - extended_prediction(prep, vehicle, named, theta, te, res.get("force_only", ()))
    w_te = weights(prep.sd)[te]
    l0 = float(np.nanmean(w_te * r_te**2))

    def gain(inputs):
        X_tr, X_te = features(s_tr, inputs), features(s_te, inputs)
        ok = np.isfinite(X_tr).all(1) & np.isfinite(r_tr).all(1)
        model = fit("linear", X_tr[ok], r_tr[ok], {})
        return 1 - float(np.nanmean(w_te * (r_te - model.predict(X_te)) ** 2)) / l0

    groups = list(cfg.remainder_inputs)
    g_all, *alone = thread_map(gain, [groups] + [[g] for g in groups])  # independent fits, side by side
    per_group = dict(zip(groups, alone))
    top = max(per_group, key=per_group.get)
    remains = g_all > cfg.remainder_min_gain
    statement = (f"Unexplained residual: a linear model on {', '.join(cfg.remainder_inputs)} removes "
                 f"{100 * g_all:.1f} % of the remaining held-out residual variance; it is most correlated with "
                 f"`{top}` ({100 * per_group[top]:.1f} % alone)." if remains else
                 f"No structure left: a linear model on {', '.join(cfg.remainder_inputs)} removes only "
                 f"{100 * g_all:.1f} % of the remaining held-out residual variance (threshold "
                 f"{100 * cfg.remainder_min_gain:.0f} %).")
    return {"evaluated": True, "structure_remains": bool(remains), "held_out_gain": round(g_all, 4),
            "by_input_group": {k: round(v, 4) for k, v in per_group.items()},
            "correlated_with": top if remains else None, "statement": statement}
