"""``python -m qr.evaluate ARGS`` = ``qr evaluate ARGS``; the stage itself is :mod:`qr.stages.evaluate`."""

if __name__ == "__main__":
    from qr.cli import run_as

    run_as("evaluate")
