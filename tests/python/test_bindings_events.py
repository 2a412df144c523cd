"""vkunroll (Python): real recordings read into numpy equal `vkunroll events`; write_events /
read_events round trips, also in tonic's, expelliarmus' and Metavision's dtypes (built here by
hand from their documented layouts, since those packages are not installed); RowTiming."""
import fractions
import os
import re
import subprocess

import numpy as np
import pytest

import vkunroll

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
REAL = os.path.join(ROOT, "tests", "data", "real")  # its README: sources, licenses
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))

# The other libraries' layouts, written out from their documentation (not taken from vkunroll):
# tonic.io.events_struct, expelliarmus' read() arrays, Metavision SDK's EventCD.
TONIC = np.dtype([("x", np.int16), ("y", np.int16), ("t", np.int64), ("p", bool)])
EXPELLIARMUS = np.dtype([("t", "<i8"), ("x", "<i2"), ("y", "<i2"), ("p", "u1")])
METAVISION = np.dtype({"names": ["x", "y", "p", "t"], "formats": ["<u2", "<u2", "<i2", "<i8"],
                       "offsets": [0, 2, 4, 8], "itemsize": 16})


def real(name):
    return os.path.join(REAL, name)


def cli_events(path, *args):
    """`vkunroll events` printout as a dict of its lines."""
    out = subprocess.run([CLI, "events", path, *args], check=True, capture_output=True, text=True).stdout
    return {m.group(1): m.group(2) for m in re.finditer(r"^(\w+)\s+(.*)$", out, re.M)}


@pytest.mark.parametrize("name,count,size", [("evt3_sample.raw", 219596, (1280, 720)),
                                             ("sample.aedat4", 111954, (320, 240))])
def test_real_recording_equals_cli(name, count, size):
    path = real(name)
    ev, info = vkunroll.read_events(path, return_info=True)
    assert ev.dtype == vkunroll.EVENT_DTYPE
    assert len(ev) == count  # the count a correct decoder yields (tests/data/real/README.md)
    assert info["sensor_size"] == size
    cli = cli_events(path)
    assert int(cli["events"]) == len(ev)
    assert cli["sensor"].startswith(f"{size[0]}x{size[1]}")
    first, last = re.match(r"(-?\d+) \.\. (-?\d+) us", cli["time"]).groups()
    assert (int(first), int(last)) == (int(ev["t"][0]), int(ev["t"][-1]))
    on, off = (int(v) for v in re.match(r"(\d+) on \(\+1\), (\d+) off", cli["polarity"]).groups())
    assert (on, off) == (int((ev["p"] == 1).sum()), int((ev["p"] == -1).sum()))
    assert set(np.unique(ev["p"])) == {-1, 1}
    assert (np.diff(ev["t"]) >= 0).all()
    assert int(ev["x"].max()) < size[0] and int(ev["y"].max()) < size[1]
    # A window: the same events as the CLI's --window-us, and exactly the slice of the whole stream.
    t0, t1 = int(ev["t"][len(ev) // 3]), int(ev["t"][2 * len(ev) // 3])
    win = vkunroll.read_events(path, t_start=t0, t_end=t1)
    assert int(cli_events(path, "--window-us", f"{t0}:{t1}")["events"]) == len(win)
    np.testing.assert_array_equal(win, ev[(ev["t"] >= t0) & (ev["t"] < t1)])


def test_written_file_reads_back_and_equals_cli(tmp_path):
    ev = vkunroll.read_events(real("sample.aedat4"))
    for ext in (".h5", ".txt"):
        out = tmp_path / f"events{ext}"
        vkunroll.write_events(out, ev, sensor_size=(320, 240))
        back, info = vkunroll.read_events(out, return_info=True)
        np.testing.assert_array_equal(back, ev)
        assert info["sensor_size"] == (320, 240)
        assert int(cli_events(str(out))["events"]) == len(ev)


@pytest.mark.parametrize("dtype,off", [(TONIC, False), (EXPELLIARMUS, 0), (METAVISION, 0)])
def test_foreign_dtypes_round_trip(tmp_path, dtype, off):
    ev = vkunroll.read_events(real("evt3_sample.raw"))[:5000]
    # Our names for their layouts are theirs.
    assert dtype in (vkunroll.TONIC_DTYPE, vkunroll.EXPELLIARMUS_DTYPE, vkunroll.METAVISION_DTYPE)
    theirs = np.zeros(len(ev), dtype=dtype)
    for k in "txy":
        theirs[k] = ev[k]
    theirs["p"] = np.where(ev["p"] > 0, True if off is False else 1, off)
    # Read straight into their dtype: the same array as theirs.
    got = vkunroll.read_events(real("evt3_sample.raw"), dtype=dtype)[:5000]
    assert got.dtype == dtype
    np.testing.assert_array_equal(got, theirs)
    # Their array in, files out, theirs back.
    path = tmp_path / "theirs.h5"
    vkunroll.write_events(path, theirs, sensor_size=(1280, 720))
    np.testing.assert_array_equal(vkunroll.read_events(path, dtype=dtype), theirs)
    np.testing.assert_array_equal(vkunroll.read_events(path), ev)
    np.testing.assert_array_equal(vkunroll.convert_events(theirs), ev)
    np.testing.assert_array_equal(vkunroll.convert_events(ev, dtype), theirs)


def test_polarity_encodings_and_field_order():
    t = np.arange(6, dtype=np.int64)
    want = np.array([1, -1, 1, -1, 1, -1], np.int8)
    for p in (want, want > 0, (want > 0).astype(np.uint8), (want > 0).astype(np.float32)):
        d = np.dtype([("p", p.dtype), ("y", np.int32), ("t", np.uint32), ("x", np.int64)])  # any order, any ints
        a = np.zeros(6, d)
        a["p"], a["t"], a["x"], a["y"] = p, t, t + 1, t + 2
        ev = vkunroll.convert_events(a)
        np.testing.assert_array_equal(ev["p"], want)
        np.testing.assert_array_equal(ev["x"], t + 1)
    assert vkunroll.convert_events(ev, vkunroll.EXPELLIARMUS_DTYPE)["p"].tolist() == [1, 0, 1, 0, 1, 0]


def test_event_input_errors_are_value_errors_naming_the_field():
    a = np.zeros(3, [("t", "f8"), ("x", "i4"), ("y", "i4"), ("p", "i1")])
    a["t"] = [0, 0.5, 1]
    with pytest.raises(ValueError, match=r"t\[1\] = 0.5 is not an integer number of microseconds"):
        vkunroll.convert_events(a)
    a["t"] = [0, 1, 2]
    a["x"] = [0, -3, 1]
    with pytest.raises(ValueError, match=r"x\[1\] = -3 is outside 0..65535"):
        vkunroll.convert_events(a)
    with pytest.raises(ValueError, match="no field 'p'"):
        vkunroll.convert_events(np.zeros(2, [("t", "i8"), ("x", "u2"), ("y", "u2")]))
    with pytest.raises(ValueError, match="does not fit dtype int16"):
        vkunroll.convert_events(np.array([(0, 40000, 0, 1)], vkunroll.EVENT_DTYPE), vkunroll.TONIC_DTYPE)


def test_row_timing_is_exact():
    tm = vkunroll.RowTiming(260, 1000, "73000/259", 3000.5, "bottom-up")
    assert tm.height == 260 and tm.readout == "bottom-up"
    assert tm.line_delay_us == fractions.Fraction(73000, 259)
    assert tm.exposure_us == fractions.Fraction(6001, 2)
    # Bottom-up: the last sensor row is read first.
    assert tm.start_us(259) == 1000 and tm.start_us(0) == 1000 + 259 * fractions.Fraction(73000, 259)
    assert tm.last_end_us == 1000 + 73000 + fractions.Fraction(6001, 2)
    t_mid = tm.target_time(fractions.Fraction(1, 3))
    assert tm.tau_of(t_mid) == fractions.Fraction(1, 3)
    assert tm.target_time(0.1) == 1000 + fractions.Fraction(1, 10) * (tm.last_end_us - 1000)
    np.testing.assert_allclose(tm.start_times_us()[::-1][:3], [1000, 1000 + 73000 / 259, 1000 + 2 * 73000 / 259])
    import pickle
    assert pickle.loads(pickle.dumps(tm)) == tm
    with pytest.raises(ValueError, match="exposure"):
        vkunroll.RowTiming(10, 0, 1, 0)
    with pytest.raises(ValueError, match="bottom-up"):
        vkunroll.RowTiming(10, 0, 1, 1, "sideways")
