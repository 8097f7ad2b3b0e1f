"""``python -m qr.simulate ARGS`` = ``qr simulate ARGS``; the stage itself is :mod:`qr.stages.simulate`."""

if __name__ == "__main__":
    from qr.cli import run_as

    run_as("simulate")
