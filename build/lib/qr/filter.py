"""``python -m qr.filter ARGS`` = ``qr filter ARGS``; the stage itself is :mod:`qr.stages.filter`."""

if __name__ == "__main__":
    from qr.cli import run_as

    run_as("filter")
