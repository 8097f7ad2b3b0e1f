"""The report's overview page (qr.report.overview): built from the workflow's tables, figures inlined with
their captions, nothing missing silently and nothing half-written; its sentences say what its numbers say
(read back here and checked against the table cells), and nothing on it scrolls sideways at 1400 px."""

import base64
import json
import re
import shutil
import subprocess

import matplotlib
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402

from qr.report.overview import write_overview  # noqa: E402
from qr.report.tables import write_table  # noqa: E402


def test_the_overview_page_leads_with_the_named_effects_and_holds_every_table_and_figure(tmp_path):
    diag = tmp_path / "diagnosis_summary.csv"
    pd.DataFrame([{"set": "brushless", "flights": 30, "samples": 19078,
                   "named": "linear_drag(kx=0.0125, ky=0.0126, kz=0.0106); blade_flapping(k=0.000688)",
                   "nominal_force_rmse": "0.0069 / 0.0051 / 0.0176", "replay_nominal_m": 0.4274},
                  {"set": "payload (check)", "flights": 65, "samples": 30864, "named": "none",
                   "nominal_force_rmse": "0.0168 / 0.0252 / 0.0214", "replay_nominal_m": 0.5665}]).to_csv(diag, index=False)
    roll = tmp_path / "rollout.csv"
    pd.DataFrame([{"set": "brushless", "held-out flights": 10, "model": "hybrid", "horizon (s)": 0.5,
                   "R@50": 0.1423, "R / rate_frozen": 0.7802}]).to_csv(roll, index=False)
    thesis = tmp_path / "table_4_2.csv"
    write_table(pd.DataFrame({"Model No.": [0, 1], "RMSE (N)": [0.0172, 0.0098]}), thesis,
                title="Table 4.2: ANN architectures learning f_a")
    fig, ax = plt.subplots(figsize=(2, 1))
    ax.plot([0, 1], [0, 1])
    png = tmp_path / "fig.png"
    fig.savefig(png)
    out = tmp_path / "overview.html"
    write_overview(out, diag, roll, {"table_4_2": thesis},
                   [(png, "Rollout, brushless: MAE against h"), (tmp_path / "absent.png", "never made")])
    text = out.read_text()
    # the answer first, then the named effects in words with their units, before any table
    assert text.index('<p class="answer">On the 30 brushless flights qr names 2 effects') < text.index("<h3>")
    assert text.index("<b>linear drag</b> — air drag proportional to the body velocity: kx = 0.0125 N s/m, "
                      "ky = 0.0126 N s/m, kz = 0.0106 N s/m") < text.index("<table")
    assert "<b>blade flapping</b>" in text and "k = 0.000688 N m s/m" in text
    assert "Nothing named; the table gives no noise floor" in text  # the check set's row has none
    assert "<caption>Table 4.2: ANN architectures learning f_a</caption>" in text  # the table's own title
    assert "<td>0.142 (0.78×)</td>" in text and "0.0098" in text
    imgs = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert len(imgs) == 1 and base64.b64decode(imgs[0]) == png.read_bytes()
    assert "<figcaption>Rollout, brushless: MAE against h</figcaption>" in text and "never made" not in text
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".") or "tmp" in p.name] == []
    # the landing page of Snakemake's report: the same body in a div, its style scoped to the div
    frag = (tmp_path / "overview.fragment.html").read_text()
    body = re.search(r"<body>(.*)</body>", text, re.S).group(1)
    assert re.sub(r"<style>.*?</style>", "", frag, flags=re.S) == f'<div class="qr-overview">{body}</div>'
    rules = re.search(r"<style>(.*?)</style>", frag, re.S).group(1).strip().splitlines()
    assert rules and all(r.startswith(".qr-overview") or ":has(.qr-overview)" in r for r in rules)


def _row(name, named, nominal, noise, extended=None, replay=(0.43, 0.17)):
    f = lambda xs: " / ".join(f"{x:.4f}" for x in xs)  # noqa: E731  (as qr.stages.diagnose_sets.summary writes them)
    return {"set": name, "flights": 30, "samples": 19078, "named": named, "nominal_force_rmse": f(nominal),
            "extended_force_rmse": f(extended or nominal), "noise_force_rmse": f(noise),
            "nominal_torque_rmse": "1.00e-04 / 2.00e-04 / 3.00e-05", "extended_torque_rmse": "9.00e-05 / 1.00e-04 / 3.00e-05",
            "replay_nominal_m": replay[0], "replay_extended_m": replay[1]}


def _spans(sentence):
    """Every ``a–b×`` or ``a×`` range the sentence states, as (a, b)."""
    return [(float(a), float(b or a)) for a, b in re.findall(r"(\d+(?:\.\d+)?)(?:–(\d+(?:\.\d+)?))?×", sentence)]


def _ratios(row, which):
    num = [float(x) for x in row[f"{which}_force_rmse"].split(" / ")]
    den = [float(x) for x in row["noise_force_rmse"].split(" / ")]
    return [a / b for a, b in zip(num, den)]


def test_nothing_named_is_up_to_noise_only_when_the_numbers_say_so():
    """Issue 25: 'nothing named: the nominal model explains these flights up to noise' beside a residual
    6–12 × the noise floor.  Now the sentence is built from the ratio, and says which it is."""
    from qr.report.overview import UP_TO_NOISE, SetResult, set_sentence

    far = _row("payload (check)", "none", nominal=[0.0168, 0.0252, 0.0214], noise=[0.0028, 0.0021, 0.0030])
    near = _row("quiet", "none", nominal=[0.0030, 0.0022, 0.0031], noise=[0.0028, 0.0021, 0.0030])
    for row in (far, near):
        s = set_sentence(SetResult.from_row(row))
        ratios = _ratios(row, "nominal")
        (lo, hi), = _spans(s)
        assert (lo, hi) == pytest.approx((min(ratios), max(ratios)), rel=0.05)  # printed to 2 digits
        if max(ratios) <= UP_TO_NOISE:
            assert "explains these flights up to noise" in s
        else:
            assert "up to noise" not in s and "do not describe these flights" in s
    assert max(_ratios(far, "nominal")) > 6 and "6–12×" in set_sentence(SetResult.from_row(far))


def test_the_answer_and_each_set_sentence_state_the_tables_numbers():
    from qr.report.overview import Rollout, SetResult, answer, set_sentence

    row = _row("brushless", "linear_drag(kx=0.0125, ky=0.0126, kz=0.0106); blade_flapping(k=0.000688)",
               nominal=[0.0069, 0.0051, 0.0176], noise=[0.0025, 0.0024, 0.0031], extended=[0.0031, 0.0029, 0.0052])
    roll = pd.DataFrame([{"set": "brushless", "held-out flights": 10, "model": m, "horizon (s)": 0.5,
                          "p@50": p, "p / rate_frozen": p / 0.1, "v@50": 0.5, "v / rate_frozen": 1.0,
                          "R@50": 0.2, "R / rate_frozen": 1.0, "w@50": 0.8, "w / rate_frozen": 1.0}
                         for m, p in (("hold", 0.3), ("rate_frozen", 0.1), ("nominal", 0.42), ("extended", 0.12))])
    r = SetResult.from_row(row)
    s = answer([r], {"brushless": Rollout.of(roll, "brushless")})
    assert s.startswith("On the 30 brushless flights qr names 2 effects (linear drag, blade flapping)")
    (n_lo, n_hi), (e_lo, e_hi), *rest = _spans(s)
    assert (n_lo, n_hi) == pytest.approx((min(_ratios(row, "nominal")), max(_ratios(row, "nominal"))), rel=0.05)
    assert (e_lo, e_hi) == pytest.approx((min(_ratios(row, "extended")), max(_ratios(row, "extended"))), rel=0.05)
    assert "replay drift from 0.43 m to 0.17 m" in s
    assert "; 0.5 s ahead, the position error is nominal 4.2×, extended 1.2× the physics baseline's." in s
    assert [x for x, _ in rest] == pytest.approx([4.2, 1.2])
    # the set's own sentence: more than twice the up-to-noise ratio left is said to be unexplained
    s = set_sentence(r)
    assert max(_ratios(row, "extended")) <= 3 and "do not explain all of it" not in s
    worse = SetResult.from_row({**row, "extended_force_rmse": "0.0069 / 0.0051 / 0.0170"})
    assert "5.5×" in set_sentence(worse) and "the named effects do not explain all of it" in set_sentence(worse)


def test_the_tables_are_narrow():
    from qr.report.overview import SetResult, gains_table

    table = gains_table([SetResult.from_row(_row("brushless", "none", [0.007] * 3, [0.002] * 3))])
    assert table.shape[1] <= 6 and max(len(str(c)) for c in table.to_numpy().ravel()) <= 40


def _generalization_csv(path):
    rows = [{"set": "brushless", "split": "repeat", "held_out": "every third flight (same trajectories)"},
            {"set": "brushless", "split": "trajectory", "held_out": "time scale 0.5"},
            {"set": "brushless", "split": "trajectory", "held_out": "time scales 1, 0.9, 0.8, 0.7, 0.6, 0.5, each in "
                                                                    "turn (6 folds, pooled)"},
            {"set": "brushless", "split": "speed", "held_out": "time scales 0.6, 0.5 (faster), trained on 1, 0.9, 0.8, 0.7"},
            {"set": "payload", "split": "trajectory", "held_out": "sideways"}]
    pd.DataFrame([{**r, "model": m, "p": 1.2345, "v": 0.98, "R": 1.1, "w": 2.2, "coverage90": float("nan")}
                  for r in rows for m in ("nominal", "physical (refined)", "hybrid (rollout-trained)")]).to_csv(
        path, index=False)


def test_the_overview_says_what_was_held_out_and_shows_the_generalization_table(tmp_path):
    from qr.report.overview import held_out_line

    _generalization_csv(tmp_path / "g.csv")
    g = pd.read_csv(tmp_path / "g.csv")
    line = held_out_line(g)
    # each set's held-out splits, named once, the pooled group standing for its folds; the repeat split said apart
    assert line.startswith("Held out, never trained on — brushless: time scales 1, 0.9, 0.8, 0.7, 0.6, 0.5, each "
                           "in turn (6 folds, pooled); time scales 0.6, 0.5 (faster)")
    assert "time scale 0.5;" not in line and "payload: sideways." in line and "measures interpolation" in line
    pd.DataFrame([_row("brushless", "none", [0.007] * 3, [0.002] * 3)]).to_csv(tmp_path / "d.csv", index=False)
    write_overview(tmp_path / "o.html", tmp_path / "d.csv", generalization_csv=tmp_path / "g.csv")
    text = (tmp_path / "o.html").read_text()
    assert text.index("<h2>Generalisation") < text.index("<caption>Rollout on flights the models were not trained on")
    assert "<th>coverage90</th>" not in text and "no uncertainty bands yet" in text and "<td>1.234</td>" in text


PROBE = """<script>window.addEventListener('load', () => { const w = document.documentElement.clientWidth;
const wide = Array.from(document.querySelectorAll('body *')).filter(e => e.getBoundingClientRect().right > w + 0.5
  || e.scrollWidth > e.clientWidth + 1 && getComputedStyle(e).overflowX !== 'visible').map(e => e.tagName);
document.body.setAttribute('data-probe', JSON.stringify({page: document.documentElement.scrollWidth, w: w, wide: wide}));
});</script>"""


def test_nothing_scrolls_sideways_in_a_1400_px_browser(tmp_path):
    """The page at 1400 px in headless Chromium: no element wider than the window, no table scrolling in its box.
    `make test` installs Chromium where it is missing (Makefile: browser); without it this test fails, never skips."""
    assert shutil.which("chromium"), "no chromium on PATH: run `make browser` (Debian: apt-get install chromium)"
    from qr.report.overview import write_overview

    rows = [_row("brushless", "linear_drag(kx=0.0125, ky=0.0126, kz=0.0106); blade_flapping(k=0.000688); "
                 "body_force_bias(bx=-0.004057, by=0.001259, bz=0.14); wind_force(fx=0.0023, fy=-0.0011, fz=0.0)",
                 [0.0068, 0.0044, 0.0169], [0.0006, 0.0007, 0.0003], [0.0016, 0.0017, 0.0030]),
            _row("payload (check)", "none", [0.0168, 0.0252, 0.0214], [0.0028, 0.0021, 0.0030])]
    pd.DataFrame(rows).to_csv(tmp_path / "d.csv", index=False)
    cols = {f"{q}@50": 0.123456 for q in "pvRw"} | {f"{q} / rate_frozen": 1.23456 for q in "pvRw"}
    pd.DataFrame([{"set": "brushless", "held-out flights": 10, "model": m, "horizon (s)": 0.5, **cols}
                  for m in ("hold", "rate_frozen", "nominal", "extended", "hybrid")]).to_csv(tmp_path / "r.csv", index=False)
    _generalization_csv(tmp_path / "g.csv")
    write_overview(tmp_path / "o.html", tmp_path / "d.csv", tmp_path / "r.csv", generalization_csv=tmp_path / "g.csv")
    assert "Generalisation" in (tmp_path / "o.html").read_text()
    page = tmp_path / "probe.html"
    page.write_text((tmp_path / "o.html").read_text().replace("</body>", PROBE + "</body>"))
    dom = subprocess.run(["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--window-size=1400,900",
                          "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120).stdout
    probe = json.loads(re.search(r'data-probe="([^"]*)"', dom).group(1).replace("&quot;", '"'))
    assert probe["wide"] == [] and probe["page"] <= probe["w"], probe
