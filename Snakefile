# qr workflow: raw logs -> canonical flights -> ... -> results/.
# Stages live in workflow/rules/*.smk; scripts in workflow/scripts/ only call qr.


include: "workflow/rules/common.smk"
include: "workflow/rules/ingest.smk"


rule all:
    default_target: True
    input:
        rules.summary.output,
