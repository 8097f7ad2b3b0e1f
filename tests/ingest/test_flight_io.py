import numpy as np
import pandas as pd

from conftest import VEHICLES, run_cli
from conftest import small_flight as _flight
from qr.flight import QUATERNION, REQUIRED, read_flight, write_flight


def test_csv_and_parquet_round_trip(tmp_path, hummingbird):
    df = _flight()
    for name in ("f.csv", "f.parquet"):
        write_flight(df, tmp_path / name)
        back = read_flight(tmp_path / name, hummingbird)
        pd.testing.assert_frame_equal(back[REQUIRED], df[REQUIRED], rtol=1e-8)


def test_messy_but_legal_input_is_repaired(tmp_path, hummingbird, capsys):
    df = _flight()
    df.loc[50:80, QUATERNION] *= -1  # sign flips
    df.loc[120, "px"] = np.nan  # a mocap dropout
    df.loc[130, "u3"] = np.nan  # a rotor-speed dropout
    df["temperature"] = 21.0  # an extra column
    path = tmp_path / "messy.csv"
    df.to_csv(path, index=False)
    status, out, err = run_cli(["ingest", path, "--vehicle", VEHICLES / "asctec_hummingbird.yaml",
                                "--out", tmp_path / "clean.csv"], capsys)
    assert status == 0, err
    clean = pd.read_csv(tmp_path / "clean.csv")
    q = clean[QUATERNION].to_numpy()
    assert (np.sum(q[1:] * q[:-1], axis=1) > 0.99).all()  # continuous sign
    assert np.isnan(clean.loc[120, "px"]) and np.isnan(clean.loc[130, "u3"])  # gaps kept
    assert list(clean.columns[-1:]) == ["temperature"]
    assert len(clean) == len(df)


def test_quaternions_are_renormalised(tmp_path, hummingbird):
    df = _flight()
    df[QUATERNION] *= 1.01
    write_flight(df, tmp_path / "f.csv")
    back = read_flight(tmp_path / "f.csv", hummingbird)
    np.testing.assert_allclose(np.linalg.norm(back[QUATERNION].to_numpy(), axis=1), 1.0, atol=1e-12)
