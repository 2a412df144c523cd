"""vkunroll (Python): read_events on jAER AEDAT 2.0, AEDAT 3.1 and Prophesee EVT 2.1 files that this
test writes with struct/numpy from the format descriptions (docs/events.md), independently of the
C++ test encoders; a real recording re-encoded as AEDAT 3.1 reads back equal."""
import os
import struct

import numpy as np
import pytest

import vkunroll

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
REAL = os.path.join(ROOT, "tests", "data", "real")

# (t us, x, y, p) in the top-left image convention of a 346x260 DAVIS346
EVENTS = [(10, 0, 0, 1), (12, 345, 259, -1), (12, 100, 7, 1), (70, 5, 200, -1), (5000, 33, 34, 1)]
W, H = 346, 260


def check(path, fmt, events=EVENTS, size=(W, H), **kw):
    ev, info = vkunroll.read_events(path, return_info=True, **kw)
    assert vkunroll.detect_event_format(path) == fmt
    assert info["format"] == fmt
    assert info["sensor_size"] == size
    assert [(int(e["t"]), int(e["x"]), int(e["y"]), int(e["p"])) for e in ev] == list(events)
    return info


def test_aedat2_davis_flips_and_skipped_records(tmp_path):
    path = str(tmp_path / "rec.aedat")
    with open(path, "wb") as f:
        f.write(b"#!AER-DAT2.0\r\n# AEChip: eu.seebetter.ini.chips.davis.Davis346B\r\n# End Of ASCII Header\r\n")
        for t, x, y, p in EVENTS:
            # jAER: x stored as W-1-x, (0, 0) at the lower left; polarity at bit 11
            f.write(struct.pack(">II", ((H - 1 - y) << 22) | ((W - 1 - x) << 12) | ((p > 0) << 11), t))
        f.write(struct.pack(">II", 0x80000000 | 17, 6000))   # APS reset read sample
        f.write(struct.pack(">II", 0x80000C00, 6001))        # IMU word
        f.write(struct.pack(">II", 0x00000400, 6002))        # special (external input)
    info = check(path, "aedat2")
    assert info["ignored"] == {"APS ADC samples (frame pixels, not read)": 1,
                               "IMU sample words (7 per IMU6 sample)": 1, "special events (external input)": 1}


def test_aedat3_polarity_packets(tmp_path):
    path = str(tmp_path / "rec3.aedat")
    big = [(t + (3 << 31), x, y, p) for t, x, y, p in EVENTS]  # overflow counter 3
    with open(path, "wb") as f:
        f.write(b"#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 1: DAVIS346B\r\n#!END-HEADER\r\n")
        f.write(struct.pack("<hhiiiiii", 1, 1, 8, 4, 3, len(big) + 1, len(big) + 1, len(big)))
        for t, x, y, p in big:
            f.write(struct.pack("<Ii", (x << 17) | (y << 2) | ((p > 0) << 1) | 1, t & 0x7FFFFFFF))
        f.write(struct.pack("<Ii", 0, 5000))                 # an invalidated event
        f.write(struct.pack("<hhiiiiii", 3, 1, 36, 4, 3, 1, 1, 1) + bytes(36))  # one IMU6 event
    info = check(path, "aedat3", big)
    assert info["ignored"] == {"invalid polarity events (valid bit 0)": 1, "IMU6 events": 1}


@pytest.mark.parametrize("legacy", [False, True])
def test_evt21_words_both_byte_orders(tmp_path, legacy):
    path = str(tmp_path / f"rec21_{legacy}.raw")
    header = "% evt 2.1\n% format EVT21;" + ("endianness=legacy;" if legacy else "") + f"height={H};width={W}\n% end\n"

    def word(hi, lo):
        return struct.pack("<II", hi, lo) if legacy else struct.pack("<Q", (hi << 32) | lo)
    with open(path, "wb") as f:
        f.write(header.encode())
        high = -1
        for t, x, y, p in EVENTS:
            if t >> 6 != high:
                high = t >> 6
                f.write(word((0x8 << 28) | high, 0))
            f.write(word(((p > 0) << 28) | ((t & 63) << 22) | ((x & ~31) << 11) | y, 1 << (x & 31)))
    check(path, "evt21")


def test_real_recording_as_aedat3(tmp_path):
    src = os.path.join(REAL, "sample.aedat4")
    ev = vkunroll.read_events(src)
    path = str(tmp_path / "real.aedat")
    data = np.zeros(len(ev), dtype=[("d", "<u4"), ("t", "<i4")])
    data["d"] = (ev["x"].astype(np.uint32) << 17) | (ev["y"].astype(np.uint32) << 2) | ((ev["p"] > 0) << 1) | 1
    with open(path, "wb") as f:
        f.write(b"#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 0: DVXplorer Lite\r\n#!END-HEADER\r\n")
        overflow = ev["t"] >> 31
        for o in np.unique(overflow):  # one packet per overflow value
            sel = overflow == o
            data["t"][sel] = ev["t"][sel] & 0x7FFFFFFF
            f.write(struct.pack("<hhiiiiii", 1, 0, 8, 4, int(o), int(sel.sum()), int(sel.sum()), int(sel.sum())))
            f.write(data[sel].tobytes())
    back, info = vkunroll.read_events(path, return_info=True)
    assert info["sensor_size"] == (320, 240)
    for k in "txyp":
        np.testing.assert_array_equal(back[k], ev[k])
