"""``python -m qr.learn ARGS`` = ``qr learn ARGS``; the stage itself is :mod:`qr.stages.learn`."""

if __name__ == "__main__":
    from qr.cli import run_as

    run_as("learn")
