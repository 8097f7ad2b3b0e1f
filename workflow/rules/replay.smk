# Replay (docs/spec/replay.md, docs/replay.md): each set whose flights name their controller and trajectory
# (conf/data/: `controller`, `flown`, `trajectory_files`) replays its held-out flights (the rollout's repeat split:
# every third) under that controller with every model the workflow writes for the set: the nominal file and the
# held-out rollout's extended, refined and hybrid models (rule evaluate_held_out) and the rollout-trained
# residuals (rule learn_residual; the carry-to set's carried network too).  From the raw logs: their motor
# commands give the setpoints' start time, start point and the controller's mass.


from qr.replay.sets import overrides_of, replayed_flights

TRAJECTORY_FILES = {k: str(v) if Path(str(v)).is_absolute() else os.path.normpath(DATA_ROOT / str(v))
                    for k, v in (DATA.get("trajectory_files") or {}).items()}  # relative to the data root
REPLAY_SETS = [s for s in SETS if (SETS[s].get("controller") or {}).get("name")
               and replayed_flights(SETS[s], TRAJECTORY_FILES)]


rule replay:
    input:
        logs=lambda wc: [raw_log(wc.set, f)
                         for f in replayed_flights(SETS[wc.set], TRAJECTORY_FILES)],
        evaluation=lambda wc: rules.evaluate_held_out.output.evaluation.format(set=wc.set),
        residual=lambda wc: rules.learn_residual.output[0].format(set=wc.set),
        carried=lambda wc: f"results/learn/carried/{wc.set}" if wc.set == RESIDUAL_CARRY else [],
        trajectory=lambda wc: list(TRAJECTORY_FILES.values()),
    output:
        directory("results/replay/{set}"),
    log:
        "results/logs/replay/{set}.log",
    benchmark:
        "results/benchmarks/replay/{set}.tsv"
    params:
        controller=lambda wc: SETS[wc.set]["controller"]["name"],
        overrides=lambda wc: overrides_of(SETS[wc.set], replayed_flights(SETS[wc.set], TRAJECTORY_FILES),
                                          TRAJECTORY_FILES),
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/replay.py"


rule replay_summary:
    input:
        sets=expand(rules.replay.output[0], set=REPLAY_SETS),
    output:
        table="results/tables/replay.csv",
    log:
        "results/logs/replay/summary.log",
    benchmark:
        "results/benchmarks/replay/summary.tsv"
    params:
        names=REPLAY_SETS,
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/replay_summary.py"
