# Simulation study (thesis Chapter 5): closed-loop tracking without / with the disturbance model /
# with the oracle, and the stability analysis of a_b-input models (eq. 5.15).  Config: conf/simulate/.
#
# Besides the thesis's sources, the tracking study flies the two the other stages produce: the
# best non-leaking learned force model (rule learn_best; the Crazyflie it was trained on) and the
# extended vehicle of the no-payload diagnosis (rule diagnose_set), both switched on here.
SIM_CONFIG = "thesis"
SIM_OVERRIDES = list(config.get("simulate", {}).get("overrides", []))  # conf/workflow.yaml, key `simulate`


rule simulate:
    input:
        sim=f"conf/simulate/{SIM_CONFIG}.yaml",
        vehicle=shipped_vehicle("asctec_hummingbird"),
        learned=rules.learn_best.output.force,
        diagnosis=expand(rules.diagnose_set.output[0], set=MODEL_SET)[0],
    output:
        table="results/simulation/tracking.csv",
        markdown="results/simulation/tracking.md",
        tracking=report("results/figures/sim_tracking.png", caption="../report/sim_tracking.rst",
                        category="Simulation"),
        euler=report("results/figures/sim_euler.png", caption="../report/sim_euler.rst", category="Simulation"),
        rmse=report("results/figures/sim_rmse.png", caption="../report/sim_rmse.rst", category="Simulation"),
    log:
        "results/logs/simulation/simulate.log",
    benchmark:
        "results/benchmarks/simulation/simulate.tsv"
    params:
        overrides=lambda wc, input: [f"simulate={SIM_CONFIG}", *SIM_OVERRIDES, *stage_sources(wc, input)],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/simulate.py"


rule stability:
    input:
        sim=f"conf/simulate/{SIM_CONFIG}.yaml",
        vehicle=shipped_vehicle("asctec_hummingbird"),
    output:
        table="results/simulation/stability.csv",
        markdown="results/simulation/stability.md",
        eigenvalues=report("results/figures/stability_eigenvalues.png", caption="../report/stability_eigenvalues.rst",
                           category="Simulation"),
        divergence=report("results/figures/stability_divergence.png", caption="../report/stability_divergence.rst",
                          category="Simulation"),
    log:
        "results/logs/simulation/stability.log",
    benchmark:
        "results/benchmarks/simulation/stability.tsv"
    params:
        overrides=[f"simulate={SIM_CONFIG}", *SIM_OVERRIDES],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/stability.py"
