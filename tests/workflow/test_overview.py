"""The report's overview page (qr.report.overview): built from the workflow's tables, figures inlined with
their captions, nothing missing silently and nothing half-written."""

import base64
import re

import matplotlib

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
    pd.DataFrame([{"set": "brushless", "model": "hybrid", "R / rate_frozen": 0.7802}]).to_csv(roll, index=False)
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
    # the answer first: the named effects come before any table
    assert text.index("linear_drag(kx=0.0125") < text.index("<table")
    assert "blade_flapping(k=0.000688)" in text and "nothing named" in text
    assert "<caption>Table 4.2: ANN architectures learning f_a</caption>" in text  # the table's own title
    assert "0.7802" in text and "0.0098" in text
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
