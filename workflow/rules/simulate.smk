# Simulation study (thesis Chapter 5): closed-loop tracking without / with the disturbance model /
# with the oracle, and the stability analysis of a_b-input models (eq. 5.15).  Config: conf/sim/.
#
# Sources that need other stages are off in conf/sim/thesis.yaml until wired here:
#   learned model (issue 4):   add its directory to `input` and to `overrides`, e.g.
#       "sim.sources.learned.enabled=true", "sim.sources.learned.vehicle=crazyflie21_brushless",
#       "sim.sources.learned.plant.force.path=<dir>", "sim.sources.learned.estimates.learned.path=<dir>",
#       (stability) "sim.stability.models.learned.enabled=true", "sim.stability.models.learned.path=<dir>"
#   extended vehicle (issue 5): "sim.sources.extended_vehicle.enabled=true",
#       "sim.sources.extended_vehicle.vehicle=<extended_vehicle.yaml>",
#       "sim.sources.extended_vehicle.estimates.extended.path=<extended_vehicle.yaml>"
SIM_CONFIG = "thesis"
SIM_OVERRIDES = []


rule simulate:
    input:
        sim=f"conf/sim/{SIM_CONFIG}.yaml",
        vehicle="conf/vehicle/asctec_hummingbird.yaml",
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
        overrides=[f"sim={SIM_CONFIG}", *SIM_OVERRIDES],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/simulate.py"


rule stability:
    input:
        sim=f"conf/sim/{SIM_CONFIG}.yaml",
        vehicle="conf/vehicle/asctec_hummingbird.yaml",
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
        overrides=[f"sim={SIM_CONFIG}", *SIM_OVERRIDES],
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/stability.py"
