"""ROS 1 bags (docs/rosbags.md): bags written here by Debian's python3-rosbag, the messages
serialized by hand from the .msg layouts (numpy), read back by vkunroll's own bag reader from the CLI
and from Python. The real EVT 3.0 recording goes into a bag twice, as dvs_msgs/EventArray and as
event_camera_msgs/EventPacket (evt3), and must read back with its exact events."""
import json
import os
import re
import subprocess

import numpy as np
import pytest

rosbag = pytest.importorskip("rosbag")  # Debian's python3-rosbag (bootstrap.sh test mode)
import genpy  # noqa: E402
import genpy.dynamic  # noqa: E402

import vkunroll  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
REAL = os.path.join(ROOT, "tests", "data", "real", "evt3_sample.raw")
CLI = os.environ.get("VKUNROLL_CLI", os.path.join(ROOT, "build", "vkunroll"))

SEP = "\n" + "=" * 80 + "\n"
HEADER_DEF = "uint32 seq\ntime stamp\nstring frame_id\n"
EVENT_DEF = "uint16 x\nuint16 y\ntime ts\nbool polarity\n"
ARRAY_DEF = "Header header\nuint32 height\nuint32 width\nEvent[] events\n"
PACKET_DEF = ("Header header\nuint32 height\nuint32 width\nuint64 seq\nuint64 time_base\nstring encoding\n"
              "bool is_bigendian\nuint8[] events\n")


def msg_class(type_name, main, deps):
    text = main + "".join(SEP + "MSG: " + name + "\n" + d for name, d in deps)
    return genpy.dynamic.generate_dynamic(type_name, text)[type_name]


DVS = msg_class("dvs_msgs/EventArray", ARRAY_DEF, [("std_msgs/Header", HEADER_DEF), ("dvs_msgs/Event", EVENT_DEF)])
PROPHESEE = msg_class("prophesee_event_msgs/EventArray", ARRAY_DEF,
                      [("std_msgs/Header", HEADER_DEF), ("prophesee_event_msgs/Event", EVENT_DEF)])
PACKET = msg_class("event_camera_msgs/EventPacket", PACKET_DEF, [("std_msgs/Header", HEADER_DEF)])
EVENT13 = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"), ("p", "u1")])


def header_bytes(seq, t_us):
    return np.array([seq, t_us // 1000000, t_us % 1000000 * 1000, 0], "<u4").tobytes()  # frame_id ""


def array_message(seq, ev, width, height):
    """A dvs_msgs/prophesee_event_msgs EventArray, serialized: the .msg fields in order, little-endian."""
    a = np.empty(len(ev), EVENT13)
    a["x"], a["y"] = ev["x"], ev["y"]
    a["sec"], a["nsec"] = ev["t"] // 1000000, ev["t"] % 1000000 * 1000
    a["p"] = ev["p"] > 0
    t0 = int(ev["t"][0]) if len(ev) else 0
    return header_bytes(seq, t0) + np.array([height, width, len(ev)], "<u4").tobytes() + a.tobytes()


def packet_message(seq, t_us, payload, encoding, width, height, time_base=0):
    enc = encoding.encode()
    return (header_bytes(seq, t_us) + np.array([height, width], "<u4").tobytes() +
            np.array([seq, time_base], "<u8").tobytes() + np.array([len(enc)], "<u4").tobytes() + enc +
            b"\x00" + np.array([len(payload)], "<u4").tobytes() + payload)


def write_raw(bag, topic, cls, data, t_us, md5=None):
    stamp = genpy.Time(int(t_us // 1000000), int(t_us % 1000000 * 1000))
    bag.write(topic, (cls._type, data, md5 or cls._md5sum, cls), stamp, raw=True)


def real_events():
    return vkunroll.read_events(REAL, return_info=True)


def raw_evt3_words():
    """The recording's EVT 3.0 bytes after its '%' header (what a Prophesee driver puts in EventPackets)."""
    data = open(REAL, "rb").read()
    at = 0
    while data[at:at + 1] == b"%":
        end = data.index(b"\n", at) + 1
        line, at = data[at:end], end
        if line.strip() == b"% end":
            break
    return data[at:]


def write_real_bag(path, ev, compression="none", per_message=2000, words_per_packet=3001):
    """Both topics: the decoded events as dvs_msgs/EventArray, the raw words as EventPackets (a packet
    boundary falls anywhere between words: the decoder's state carries over, as in a driver's stream)."""
    words = raw_evt3_words()
    with rosbag.Bag(path, "w", compression=compression) as bag:
        for k, i in enumerate(range(0, len(ev), per_message)):
            part = ev[i:i + per_message]
            write_raw(bag, "/dvs/events", DVS, array_message(k, part, 1280, 720), int(part["t"][-1]))
        step = 2 * words_per_packet
        for k, i in enumerate(range(0, len(words), step)):
            write_raw(bag, "/event_camera/events", PACKET,
                      packet_message(k, 0, words[i:i + step], "evt3", 1280, 720), int(ev["t"][0]) + k)


def cli(path, *args, check=True):
    r = subprocess.run([CLI, "events", path, *args], capture_output=True, text=True)
    if check:
        assert r.returncode == 0, r.stderr
    return r


def cli_fields(out):
    return {m.group(1): m.group(2) for m in re.finditer(r"^(\w+)\s+(.*)$", out, re.M)}


def same_events(a, b):
    assert len(a) == len(b)
    for f in ("t", "x", "y", "p"):
        assert np.array_equal(a[f], b[f]), f


@pytest.mark.parametrize("compression", ["none", "bz2", "lz4"])
def test_real_recording_in_both_message_types_reads_back_exactly(tmp_path, compression):
    ev, info = real_events()
    assert len(ev) == 219596 and info["sensor_size"] == (1280, 720)
    path = str(tmp_path / f"real_{compression}.bag")
    write_real_bag(path, ev, compression)
    assert vkunroll.detect_event_format(path) == "bag"
    for topic in ("/dvs/events", "/event_camera/events"):
        got, ginfo = vkunroll.read_events(path, topic=topic, return_info=True)
        same_events(got, ev)
        assert ginfo["sensor_size"] == (1280, 720) and ginfo["format"] == "bag"
        assert ginfo["dropped"] == 0
        out = cli_fields(cli(path, "--events-topic", topic).stdout)
        assert int(out["events"]) == len(ev)
        first, last = re.match(r"(-?\d+) \.\. (-?\d+) us", out["time"]).groups()
        assert (int(first), int(last)) == (int(ev["t"][0]), int(ev["t"][-1]))
        on, off = (int(v) for v in re.match(r"(\d+) on \(\+1\), (\d+) off", out["polarity"]).groups())
        assert (on, off) == (int((ev["p"] == 1).sum()), int((ev["p"] == -1).sum()))
        assert out["sensor"].startswith("1280x720")
    # A window is the slice of the whole stream, from Python and the CLI.
    t0, t1 = int(ev["t"][len(ev) // 3]), int(ev["t"][2 * len(ev) // 3])
    win = vkunroll.read_events(path, t_start=t0, t_end=t1, topic="/event_camera/events")
    same_events(win, ev[(ev["t"] >= t0) & (ev["t"] < t1)])
    out = cli_fields(cli(path, "--events-topic", "/dvs/events", "--window-us", f"{t0}:{t1}").stdout)
    assert int(out["events"]) == len(win)


def test_two_event_topics_without_a_choice_is_an_error_naming_both(tmp_path):
    path = str(tmp_path / "two.bag")
    ev = np.zeros(3, vkunroll.EVENT_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["p"] = [10, 20, 30], [1, 2, 3], [4, 5, 6], [1, -1, 1]
    with rosbag.Bag(path, "w") as bag:
        write_raw(bag, "/a/events", DVS, array_message(0, ev, 8, 8), 30)
        write_raw(bag, "/b/events", PROPHESEE, array_message(0, ev, 8, 8), 30)
    with pytest.raises(ValueError, match=r"several event topics \(/a/events, /b/events\); choose one with topic "):
        vkunroll.read_events(path)
    r = cli(path, check=False)
    assert r.returncode != 0 and "/a/events, /b/events" in r.stderr and path in r.stderr
    same_events(vkunroll.read_events(path, topic="/b/events"), ev)  # prophesee_event_msgs too
    with pytest.raises(ValueError, match=r"no topic '/c' .*/a/events \(dvs_msgs/EventArray\)"):
        vkunroll.read_events(path, topic="/c")


def test_unknown_md5_and_unknown_type_are_named_errors(tmp_path):
    path = str(tmp_path / "md5.bag")
    ev = np.zeros(2, vkunroll.EVENT_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["p"] = [10, 20], [1, 2], [3, 4], [1, -1]
    wrong = "0123456789abcdef0123456789abcdef"
    with rosbag.Bag(path, "w") as bag:
        write_raw(bag, "/dvs/events", DVS, array_message(0, ev, 8, 8), 20, md5=wrong)
        write_raw(bag, "/other", PACKET, packet_message(0, 0, b"", "mono", 8, 8), 20, md5="*")
    with pytest.raises(ValueError) as e:
        vkunroll.read_events(path, topic="/dvs/events")
    msg = str(e.value)
    assert path in msg and "/dvs/events" in msg and "dvs_msgs/EventArray" in msg and wrong in msg
    assert "5e8beee5a6c107e504c2e78903c224b8" in msg
    r = cli(path, "--events-topic", "/dvs/events", check=False)
    assert r.returncode != 0 and wrong in r.stderr


def test_truncated_bag_is_named_and_what_precedes_the_cut_still_reads(tmp_path):
    """A bag cut short (a recorder killed, a partial copy): no index; the complete messages before
    the cut read under on_bad=drop, the cut is one counted record; under error it is named."""
    ev = np.zeros(6000, vkunroll.EVENT_DTYPE)
    ev["t"] = np.arange(6000) * 7 + 1000
    ev["x"], ev["y"], ev["p"] = np.arange(6000) % 640, np.arange(6000) % 480, np.where(np.arange(6000) % 3, 1, -1)
    path = str(tmp_path / "whole.bag")
    messages = []
    with rosbag.Bag(path, "w", chunk_threshold=20000) as bag:
        for k, i in enumerate(range(0, len(ev), 500)):
            data = array_message(k, ev[i:i + 500], 640, 480)
            messages.append(data)
            write_raw(bag, "/dvs/events", DVS, data, int(ev["t"][i + 499]))
    whole = open(path, "rb").read()
    cut = int(len(whole) * 0.55)
    cut_path = str(tmp_path / "cut.bag")
    open(cut_path, "wb").write(whole[:cut])
    # The events of the messages that lie whole before the cut (uncompressed chunks: found by their bytes).
    complete = 0
    for k, data in enumerate(messages):
        at = whole.find(data)
        assert at > 0
        if at + len(data) <= cut:
            complete += 500
    assert 0 < complete < len(ev)
    with pytest.raises(ValueError) as e:
        vkunroll.read_events(cut_path)
    assert cut_path in str(e.value) and "cut short" in str(e.value)
    got, info = vkunroll.read_events(cut_path, on_bad="drop", return_info=True)
    same_events(got, ev[:complete])
    assert info["dropped_unknown_word"] == 1
    assert any("no usable index" in n for n in info["notes"])
    r = cli(cut_path, check=False)
    assert r.returncode != 0 and "cut short" in r.stderr
    out = cli_fields(cli(cut_path, "--on-bad", "drop").stdout)
    assert int(out["events"]) == complete


def test_mono_packets_and_packet_time_base(tmp_path):
    """event_camera_msgs mono: 64-bit words (32-bit ns offset to time_base, x 16 bits, y 15, p top bit)."""
    path = str(tmp_path / "mono.bag")
    n = 50
    dt_ns = np.arange(n, dtype=np.uint64) * 3000 + 999
    x, y, p = np.arange(n, dtype=np.uint64) % 300, np.arange(n, dtype=np.uint64) % 200, np.arange(n) % 2
    words = dt_ns | (x << np.uint64(32)) | (y << np.uint64(48)) | (p.astype(np.uint64) << np.uint64(63))
    base_ns = 1_700_000_000_123_456_000
    with rosbag.Bag(path, "w", compression="lz4") as bag:
        write_raw(bag, "/ec/events", PACKET, packet_message(0, 0, words.astype("<u8").tobytes(), "mono", 346, 260,
                                                            time_base=base_ns), 1)
        write_raw(bag, "/ec/events", PACKET, packet_message(1, 0, b"\x00" * 6, "trigger", 346, 260), 2)
    with pytest.raises(ValueError, match="encoding 'trigger' is not decoded"):
        vkunroll.read_events(path)
    got, info = vkunroll.read_events(path, on_bad="drop", return_info=True)
    assert info["sensor_size"] == (346, 260) and info["dropped_unknown_word"] == 1
    assert np.array_equal(got["t"], ((base_ns + dt_ns) // 1000).astype(np.int64))
    assert np.array_equal(got["x"], x) and np.array_equal(got["y"], y)
    assert np.array_equal(got["p"], np.where(p == 1, 1, -1))


IMAGE_DEF = "Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n"
IMAGE = msg_class("sensor_msgs/Image", IMAGE_DEF, [("std_msgs/Header", HEADER_DEF)])


def image_message(seq, t_us, pixels, encoding):
    h, w = pixels.shape[:2]
    enc = encoding.encode()
    data = np.ascontiguousarray(pixels).tobytes()
    return (header_bytes(seq, t_us) + np.array([h, w, len(enc)], "<u4").tobytes() + enc + b"\x00" +
            np.array([len(data) // h, len(data)], "<u4").tobytes() + data)


CAMINFO_DEF = ("Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] D\nfloat64[9] K\n"
               "float64[9] R\nfloat64[12] P\nuint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n")
ROI_DEF = "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n"
CAMINFO = msg_class("sensor_msgs/CameraInfo", CAMINFO_DEF, [("std_msgs/Header", HEADER_DEF), ("sensor_msgs/RegionOfInterest", ROI_DEF)])


def camera_info_message(t_us, w, h, d, k):
    model = b"plumb_bob"
    p = list(k[:3]) + [0.0] + list(k[3:6]) + [0.0] + list(k[6:]) + [0.0]
    return (header_bytes(0, t_us) + np.array([h, w, len(model)], "<u4").tobytes() + model +
            np.array([len(d)], "<u4").tobytes() + np.array(list(d) + list(k) + [1, 0, 0, 0, 1, 0, 0, 0, 1] + p, "<f8").tobytes() +
            np.array([0, 0, 0, 0, 0, 0], "<u4").tobytes() + b"\x00")


def test_bag_sequence_records_the_frames_camera_info(tmp_path):
    """sensor_msgs/CameraInfo in the frames' namespace lands in meta.json's source.camera_info, as
    written; one of another size than the images is a named error."""
    assert CAMINFO._md5sum == "c9a58c1b0b154e0e6da7578cb991d214"
    w, h = 20, 16
    ev = np.zeros(50, vkunroll.EVENT_DTYPE)
    ev["t"] = 1000 + np.arange(50) * 100
    d, k = [-0.3, 0.1, 0.001, -0.002, 0.0], [200.5, 0, 10.25, 0, 201.0, 8.5, 0, 0, 1]
    for size, ok in (((w, h), True), ((w * 2, h), False)):
        path = str(tmp_path / f"cam{ok}.bag")
        with rosbag.Bag(path, "w") as bag:
            write_raw(bag, "/dvs/events", DVS, array_message(0, ev, w, h), 6000)
            write_raw(bag, "/dvs/camera_info", CAMINFO, camera_info_message(1000, *size, d, k), 1000)
            for i in range(2):
                img = np.full((h, w), 40 * i, np.uint8)
                write_raw(bag, "/dvs/image_raw", IMAGE, image_message(i, 1000 + 2000 * i, img, "mono8"), 1000 + 2000 * i)
        out = tmp_path / f"seq{ok}"
        r = subprocess.run([CLI, "bag-sequence", path, str(out), "--line-delay-us", "10", "--exposure-us", "100"],
                           capture_output=True, text=True)
        if not ok:
            assert r.returncode != 0 and "camera info of topic /dvs/camera_info is for 40x16" in r.stderr, r.stderr
            continue
        assert r.returncode == 0, r.stderr
        assert "camera info  /dvs/camera_info" in r.stdout
        ci = json.loads((out / "meta.json").read_text())["source"]["camera_info"]
        assert ci["topic"] == "/dvs/camera_info" and ci["distortion_model"] == "plumb_bob"
        assert (ci["width"], ci["height"]) == (w, h) and ci["D"] == d and ci["K"] == k and ci["P"][0] == 200.5
        assert vkunroll.Sequence.open(out).width == w  # the schema accepts source.camera_info (source is free-form)


def test_bag_sequence_from_a_davis_like_bag(tmp_path):
    """`vkunroll bag-sequence`: frames of an image topic -> rs/*.png + meta.json naming the bag for the
    events; the folder opens as a sequence whose frames and events are the bag's."""
    from PIL import Image
    w, h, n = 40, 30, 3
    rng = np.random.default_rng(5)
    ev = np.zeros(4000, vkunroll.EVENT_DTYPE)
    ev["t"] = 1_700_000_000_000_000 + np.arange(4000) * 25
    ev["x"], ev["y"] = rng.integers(0, w, 4000), rng.integers(0, h, 4000)
    ev["p"] = np.where(rng.integers(0, 2, 4000) == 1, 1, -1)
    frames = [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]
    t0s = [int(ev["t"][0]) + 20000 * k + 5000 for k in range(n)]
    path = str(tmp_path / "davis.bag")
    with rosbag.Bag(path, "w", compression="lz4") as bag:
        for k in range(0, 4000, 400):
            write_raw(bag, "/dvs/events", DVS, array_message(k // 400, ev[k:k + 400], w, h), int(ev["t"][k + 399]))
            # A second event topic: meta.json's events_topic must pick /dvs/events when the sequence opens.
            write_raw(bag, "/other/events", PROPHESEE, array_message(k // 400, ev[k:k + 2], w, h), int(ev["t"][k + 399]))
        for k in range(n):
            write_raw(bag, "/dvs/image_raw", IMAGE, image_message(k, t0s[k], frames[k], "rgb8"), t0s[k])
    out = tmp_path / "seq"
    r = subprocess.run([CLI, "bag-sequence", path, str(out), "--line-delay-us", "73000/259", "--exposure-us", "3000",
                        "--events-topic", "/dvs/events"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "3 from /dvs/image_raw (rgb8, 40x30)" in r.stdout
    for k in range(n):
        assert np.array_equal(np.asarray(Image.open(out / "rs" / f"{k:06d}.png").convert("RGB")), frames[k])
    meta = json.loads((out / "meta.json").read_text())
    assert meta["events_topic"] == "/dvs/events" and meta["line_delay_us"] == "73000/259"
    seq = vkunroll.Sequence.open(out)
    assert len(seq) == n and (seq.width, seq.height) == (w, h)
    assert [int(seq.timing(k).t0_us) for k in range(n)] == t0s
    t0, t1 = t0s[1], t0s[2]
    same_events(seq.events(t0, t1), ev[(ev["t"] >= t0) & (ev["t"] < t1)])
    other = vkunroll.Sequence.open(out, events_topic="/other/events")  # the option wins over meta.json
    assert len(other.events(None, None)) == 20
    # An image encoding that is not read is named.
    path2 = str(tmp_path / "bayer.bag")
    with rosbag.Bag(path2, "w") as bag:
        write_raw(bag, "/dvs/events", DVS, array_message(0, ev[:10], w, h), int(ev["t"][9]))
        write_raw(bag, "/cam/image", IMAGE, image_message(0, t0s[0], frames[0][:, :, 0], "bayer_rggb8"), t0s[0])
    r = subprocess.run([CLI, "bag-sequence", path2, str(tmp_path / "s2"), "--line-delay-us", "10", "--exposure-us", "100"],
                       capture_output=True, text=True)
    assert r.returncode != 0 and "image encoding 'bayer_rggb8' is not read" in r.stderr
