"""``python -m qr.train ARGS`` = ``qr learn ARGS`` (the thesis-era name); the stage is :mod:`qr.stages.learn`."""

if __name__ == "__main__":
    from qr.cli import run_as

    run_as("learn")
