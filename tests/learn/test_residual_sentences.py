"""The sentences of ``qr learn residual``'s report and log, each generated from the numbers it states
(small hand-made cases; the real run is tests/learn/test_learn_residual.py)."""

from qr.residual_training.sentences import change_sentence, kept_sentence, split_sentence

Q = ("p", "v", "R", "w")


def _val(vehicle, hybrid):
    return {"vehicle": dict(zip(Q, vehicle)), "hybrid": dict(zip(Q, hybrid))}


def test_each_change_is_stated_with_its_numbers():
    s = change_sentence(50, _val([1.0, 0.5, 0.8, 0.3], [0.9, 0.5, 0.88, None]))
    assert s == ("At h = 50 the residual lowers the validation error of p (1 -> 0.9 x rate_frozen, -10 %); "
                 "it raises that of R (0.8 -> 0.88 x rate_frozen, +10 %); it leaves v equal to the vehicle's to the "
                 "last bit; it has no validation error of w.")


def test_equal_errors_are_said_equal_never_raised():
    s = change_sentence(10, _val([1.0, 0.5, 0.8, 0.3], [1.0, 0.5, 0.8, 0.3]))
    assert s == "At h = 10 the residual leaves the validation error of p, v, R and w equal to the vehicle's to the last bit."


def test_lowered_everywhere():
    s = change_sentence(50, _val([1.0, 1.0, 1.0, 2.0], [0.5, 0.25, 0.75, 1.0]))
    assert s == ("At h = 50 the residual lowers the validation error of p (1 -> 0.5 x rate_frozen, -50 %), "
                 "v (1 -> 0.25 x rate_frozen, -75 %), R (1 -> 0.75 x rate_frozen, -25 %) and "
                 "w (2 -> 1 x rate_frozen, -50 %).")


def test_the_split_names_the_flights_by_their_paths():
    by_flight = {"by": "flight", "training": ["run1/flight.csv", "run2/flight.csv"],
                 "validation": ["run3/flight.csv"]}
    assert split_sentence(by_flight) == ("3 flights given: 2 train (run1/flight.csv and run2/flight.csv), 1 validates "
                                         "(run3/flight.csv: early stopping, never trained on)")
    by_time = {"by": "time", "training": ["a/flight.csv"], "validation": ["a/flight.csv"], "validation_from_s": 32.0}
    assert split_sentence(by_time) == ("1 flight given, a/flight.csv: its windows ending before t = 32.00 s train, "
                                       "those from t = 32.00 s on validate (early stopping; never trained on)")


def test_what_is_kept_when_no_epoch_improves():
    assert kept_sentence(1.8441, [21.17, 3.2], False) == (
        "no epoch improved the validation loss (1.844 at the start, 3.2 at best over 2 epoch(s)): the weights at the "
        "start are kept, a network of zero output (the hybrid flies as the vehicle without a residual)")
    assert kept_sentence(0.5, [0.5], True).endswith("the vehicle's own residual, unchanged by this training")
