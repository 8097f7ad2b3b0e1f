# Export: the extended model of the chain's first set (the brushless set on the IMRCLab data; else the
# first set) in the simulators people use (qr export: RotorPy, PX4 + Gazebo Sim, MuJoCo), each folder
# with its mapping.md. Marked for the report (category "Exports"), which links every file.

EXPORT_TARGETS = ["rotorpy", "px4-gz", "mujoco"]
EXPORT_SET = DIAG_FIRST if DIAG_FIRST in SETS else list(SETS)[0]


rule export:
    input:
        diagnosis=expand(rules.diagnose_set.output[0], set=EXPORT_SET),
    output:
        # files only (PX4's model folder holds its files a level down): a folder cannot be embedded
        report(directory("results/export/{target}"),
               patterns=["{file}.md", "{file}.py", "{file}.xml", "{file}.params", "{model}/model.{ext}"],
               caption="../report/export.rst",
               category="6. Exports", subcategory="{target}"),
    wildcard_constraints:
        target="|".join(EXPORT_TARGETS),
    log:
        "results/logs/export/{target}.log",
    benchmark:
        "results/benchmarks/export/{target}.tsv"
    conda:
        "../envs/qr.yaml"
    script:
        "../scripts/export.py"
