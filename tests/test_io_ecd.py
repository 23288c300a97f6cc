"""ECD text events: numba parser vs a plain reference, real windows, round trip, errors."""

from __future__ import annotations

import warnings
from decimal import ROUND_HALF_EVEN, Decimal

import numpy as np
import pytest

from evmotion.errors import EvmotionWarning, FormatError
from evmotion.events import EventArray
from evmotion.io import ecd, read_events

SCENES = ["boxes_rotation", "boxes_translation", "dynamic_rotation", "dynamic_translation",
          "poster_rotation", "poster_translation", "shapes_rotation", "shapes_translation"]


def reference_parse(text: str):
    """Plain-Python reference: decimal seconds to µs, rounded half-even on exact decimals."""
    x, y, t, p = [], [], [], []
    for line in text.splitlines():
        parts = line.split()
        if not parts:
            continue
        us = (Decimal(parts[0]) * 1_000_000).quantize(Decimal(1), rounding=ROUND_HALF_EVEN)
        t.append(int(us))
        x.append(int(parts[1]))
        y.append(int(parts[2]))
        p.append(int(parts[3]))
    return (np.array(v, np.int64) for v in (x, y, t, p))


def test_parser_matches_reference_on_real_window(shared_data):
    path = shared_data / "ecd_rotation_windows" / "boxes_rotation" / "events.txt"
    got = ecd.parse_text(path.read_bytes())
    for g, r in zip(got, reference_parse(path.read_text()), strict=True):
        np.testing.assert_array_equal(g, r)


def test_parser_formats_and_rounding():
    text = b"1 2 3 1\n0.5 4 5 0\r\n  2.0000015\t6\t7\t1\n\n3.123456789,8,9,0"
    x, y, t, p = ecd.parse_text(text)
    assert t.tolist() == [1_000_000, 500_000, 2_000_002, 3_123_457]
    assert x.tolist() == [2, 4, 6, 8] and y.tolist() == [3, 5, 7, 9] and p.tolist() == [1, 0, 1, 0]


@pytest.mark.parametrize("scene", SCENES)
def test_real_30k_windows(shared_data, scene):
    ev = ecd.read(shared_data / "ecd_30k_windows" / scene)
    assert len(ev) == 30_000
    assert ev.sensor_size == (180, 240)
    assert ev.x.dtype == np.uint16 and ev.t.dtype == np.int64
    assert np.all(np.diff(ev.t) >= 0)


def test_streaming_across_blocks_matches_whole(shared_data):
    folder = shared_data / "ecd_30k_windows" / "poster_rotation"
    whole = ecd.read(folder)
    small = ecd.read(folder, block_bytes=1000)  # lines cut across many block edges
    chunks = list(ecd.iter_chunks(folder, 7000, block_bytes=4096))
    assert [len(c) for c in chunks] == [7000] * 4 + [2000]
    for k in "xytp":
        np.testing.assert_array_equal(getattr(small, k), getattr(whole, k))
        np.testing.assert_array_equal(np.concatenate([getattr(c, k) for c in chunks]),
                                      getattr(whole, k))


def test_time_range_and_sensor_override(shared_data):
    folder = shared_data / "ecd_30k_windows" / "boxes_rotation"
    whole = ecd.read(folder)
    t0, t1 = int(whole.t[1000]), int(whole.t[20000])
    part = ecd.read(folder, t0=t0, t1=t1)
    assert len(part) == len(whole.slice_time(t0, t1))
    big = ecd.read(folder, sensor_size=(200, 300))
    assert big.sensor_size == (200, 300) and big.meta["sensor_size_from"] == "given"


def test_round_trip_bit_equal(tmp_path):
    rng = np.random.default_rng(1)
    n = 5000
    ev = EventArray(x=rng.integers(0, 240, n), y=rng.integers(0, 180, n),
                    t=np.sort(rng.integers(0, 10**10, n)), p=rng.integers(0, 2, n),
                    sensor_size=(180, 240))
    ecd.write(tmp_path / "events.txt", ev)
    back = ecd.read(tmp_path / "events.txt")
    for k in "xytp":
        np.testing.assert_array_equal(getattr(back, k), getattr(ev, k))


def test_calibration(shared_data):
    cal = ecd.read_calibration(shared_data / "ecd_rotation_windows" / "boxes_rotation")
    assert cal["fx"] == pytest.approx(199.092366542)
    assert cal["dist"] == pytest.approx([-0.368436311798, 0.150947243557, -0.000296130534385,
                                         -0.000759431726241, 0.0])
    assert cal["K"][0][2] == pytest.approx(132.192071378)


def test_folder_extras(tmp_path):
    (tmp_path / "events.txt").write_text("0.1 1 2 1\n0.2 3 4 0\n")
    (tmp_path / "imu.txt").write_text("0.1 0 0 9.8 0.1 0.2 0.3\n0.2 0 0 9.8 0.1 0.2 0.3\n")
    (tmp_path / "groundtruth.txt").write_text("0.1 1 2 3 0 0 0 1\n")
    imu = ecd.read_imu(tmp_path)
    assert imu["t"].tolist() == [100_000, 200_000] and imu["gyro"][0].tolist() == [0.1, 0.2, 0.3]
    assert ecd.read_groundtruth(tmp_path)["quaternion"].tolist() == [[0, 0, 0, 1]]
    d = ecd.describe(tmp_path)
    assert d["imu"] == 2 and d["groundtruth"] == 1


@pytest.mark.parametrize("text, match", [
    ("0.1 1 2 1\n0.2 3 4\n", r"line 2 has 3 column\(s\)"),
    ("0.1 1 2 1\n0.2 3 4 1 5\n", r"line 2 has 5 column"),
    ("0.1 1 2 1\n0.1 1 2 1\n0.2 a 4 1\n", "line 3 is not"),
    ("0.2 1 2 1\n0.1 3 4 1\n", "not sorted"),
    ("0.1 1 2 7\n", "polarity p=7"),
])
def test_bad_input_errors_name_file_and_line(tmp_path, text, match):
    path = tmp_path / "events.txt"
    path.write_text(text)
    with pytest.raises(FormatError, match=match) as info:
        ecd.read(path)
    assert "events.txt" in str(info.value)


def test_truncated_last_line(tmp_path):
    path = tmp_path / "events.txt"
    path.write_text("0.1 1 2 1\n0.2 3")
    with pytest.raises(FormatError, match="line 2 has 2 column"):
        ecd.read(path)


def test_folder_attaches_calibration(shared_data):
    ev = ecd.read(shared_data / "ecd_30k_windows" / "poster_translation")
    assert ev.meta["calibration"]["fx"] == pytest.approx(199.092366542)
    chunk = next(ecd.iter_chunks(shared_data / "ecd_30k_windows" / "poster_translation", 10))
    assert "calibration" in chunk.meta


def test_formatter_matches_plain_python_reference():
    rng = np.random.default_rng(5)
    n = 2000
    t = np.sort(np.concatenate([[0, 999_999, 1_000_000], rng.integers(0, 10**11, n)]))
    x = rng.integers(0, 16384, t.size)
    y = rng.integers(0, 16384, t.size)
    p = rng.integers(0, 2, t.size)
    x[:3] = [0, 16383, 10]
    ev = EventArray(x=x, y=y, t=t, p=p, sensor_size=(16384, 16384))
    ref = "".join(f"{a // 1_000_000}.{a % 1_000_000:06d} {b} {c} {d}\n"
                  for a, b, c, d in zip(t.tolist(), x.tolist(), y.tolist(), p.tolist(),
                                        strict=True))
    assert ecd.format_text(ev) == ref.encode()


def test_microsecond_text(tmp_path):
    (tmp_path / "us.txt").write_text("1000 1 2 1\n2500 3 4 0\n")
    ev = ecd.read(tmp_path / "us.txt", time_unit="us")
    assert ev.t.tolist() == [1000, 2500]
    assert [c.t.tolist() for c in ecd.iter_chunks(tmp_path / "us.txt", 1, time_unit="us")] == \
        [[1000], [2500]]


def test_other_tools_text_variants(tmp_path):
    """Comment lines and a byte-order mark at the top of events.txt; images.txt with a
    header, a BOM, commas, a path with spaces, Windows separators and an exposure column;
    the sensor size from a JPEG frame (it used to fall back to 240x180 for any non-PNG)."""
    cv2 = pytest.importorskip("cv2")
    d = tmp_path / "rec"
    (d / "my images").mkdir(parents=True)
    (d / "events.txt").write_bytes(b"\xef\xbb\xbf# t x y p\n% exported by a tool\n"
                                   b"0.1 1 2 1\n0.2 3 4 0\n")
    ev = ecd.read(d / "events.txt", sensor_size=(10, 10))
    assert ev.t.tolist() == [100_000, 200_000] and ev.x.tolist() == [1, 3]
    from evmotion.io import read_events

    assert read_events(d / "events.txt").t.tolist() == [100_000, 200_000]  # detected
    (d / "events.txt").write_text("# t x y p\n0.1 1 2 1\n0.2 a 4 0\n")
    with pytest.raises(FormatError, match="line 3 is not"):
        ecd.read(d / "events.txt", sensor_size=(10, 10))
    (d / "events.txt").write_text("0.1 1 2 1\n0.2 3 4 0\n")
    img = np.zeros((30, 50), np.uint8)
    for name in ("a.jpg", "b.jpg", "c.jpg"):
        cv2.imwrite(str(d / "my images" / name), img)
    (d / "images.txt").write_bytes(b"\xef\xbb\xbf# timestamp filename\n"
                                   b"0.0,my images/a.jpg\n"
                                   b"0.1 my images\\b.jpg 0.004\n"
                                   b"0.2 my images/c.jpg\n")
    lst = ecd.read_image_list(d)
    assert lst["t"].tolist() == [0, 100_000, 200_000]
    assert lst["files"] == ["my images/a.jpg", "my images/b.jpg", "my images/c.jpg"]
    assert ecd.read(d).sensor_size == (30, 50)
    assert ecd.describe(d)["sensor_size_from"] == "images"
    (d / "images.txt").write_text("0.0 nothere.png 7\n")
    with pytest.raises(FormatError, match="line 1: expected 't file'.*no file"):
        ecd.read_image_list(d)


def test_a_sensor_size_from_header_or_largest_coordinate(tmp_path):
    """Text written for another sensor (346x260) could not be read back (events outside
    the ECD's 240x180): write() states the size in a comment line; a file stating none
    takes the largest coordinates, with a warning; a given size still refuses events
    outside it."""
    import warnings

    from evmotion.errors import EvmotionWarning

    ev = EventArray(x=[1, 345], y=[2, 10], t=[100, 200], p=[1, 0], sensor_size=(260, 346))
    ecd.write(tmp_path / "a.txt", ev)
    assert (tmp_path / "a.txt").read_text().startswith("# evmotion ECD text")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        back = ecd.read(tmp_path / "a.txt")
    assert back.sensor_size == (260, 346) and back.x.tolist() == [1, 345]
    assert ecd.describe(tmp_path / "a.txt")["sensor_size_from"] == "header"
    ecd.write(tmp_path / "b.txt", ev, header=False)
    with pytest.warns(EvmotionWarning, match="taken as 346x180 px"):
        assert ecd.read(tmp_path / "b.txt").sensor_size == (180, 346)
    with pytest.raises(FormatError, match="x=345.*outside the sensor"):
        ecd.read(tmp_path / "b.txt", sensor_size=(260, 300))
    small = EventArray(x=[1], y=[2], t=[100], p=[1], sensor_size=(180, 240))
    ecd.write(tmp_path / "c.txt", small)
    assert not (tmp_path / "c.txt").read_text().startswith("#")  # the ECD's own: pure


def test_whole_number_times_are_microseconds_or_as_given(tmp_path):
    """Text whose times are whole numbers (other tools' us exports) was read as seconds:
    durations 1e6 too long, epoch-us times overflowed int64; they are read as us with a
    warning, or in the unit given."""
    from evmotion.errors import EvmotionWarning

    text = "".join(f"{1_700_000_000_000_000 + 10 * i} {i % 7} {i % 5} {i % 2}\n"
                   for i in range(50))
    (tmp_path / "e.txt").write_text(text)
    with pytest.warns(EvmotionWarning, match="whole number: read as microseconds"):
        ev = ecd.read(tmp_path / "e.txt", sensor_size=(5, 7))
    assert ev.t[0] == 1_700_000_000_000_000 and ev.t[-1] - ev.t[0] == 490
    assert ecd.read(tmp_path / "e.txt", sensor_size=(5, 7), time_unit="ns").t[-1] == \
        1_700_000_000_000 + 0  # 490 ns round to 0 us
    (tmp_path / "s.txt").write_text("0 1 2 1\n0.5 1 2 0\n")
    assert ecd.read(tmp_path / "s.txt", sensor_size=(5, 7)).t.tolist() == [0, 500_000]
    # decimals in a unit given are that unit (they were refused, with advice to read them
    # as seconds, 1e6 off for these)
    assert ecd.read(tmp_path / "s.txt", sensor_size=(5, 7), time_unit="ms").t.tolist() == \
        [0, 500]
    with pytest.raises(Exception, match="time_unit must be one of"):
        ecd.read(tmp_path / "s.txt", time_unit="min")


@pytest.mark.parametrize("text, size, t, x, p", [
    # a header of column names, comma separated, decimal seconds
    ("t,x,y,p\n0.001,1,2,1\n0.002,3,4,0\n", (180, 240), [1000, 2000], [1, 3], [1, 0]),
    # Metavision's CSV order x,y,p,t with whole microseconds
    ("x,y,p,t\n1,2,1,1000\n3,4,0,2500\n", (180, 240), [1000, 2500], [1, 3], [1, 0]),
    # rpg / E2VID text: a first line 'W H', then t x y p
    ("346 260\n0.001 345 2 1\n0.002 3 259 0\n", (260, 346), [1000, 2000], [345, 3], [1, 0]),
    # names other tools use, polarity -1/1
    ("timestamp x y polarity\n1000 1 2 1\n2000 3 4 -1\n", (180, 240), [1000, 2000], [1, 3],
     [1, 0]),
])
def test_other_tools_text_layouts(tmp_path, text, size, t, x, p):
    """A header line of column names (any order) or a 'W H' size line was 'format not
    recognised'."""
    import warnings

    from evmotion.io import iter_events, read_events

    path = tmp_path / "ev.csv"
    path.write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # whole-number times: read as us, said so
        ev = read_events(path)
        streamed = list(iter_events(path, 1))
    assert ev.sensor_size == size and ev.t.tolist() == t and ev.x.tolist() == x
    assert ev.p.tolist() == p
    assert [c.t[0] for c in streamed] == t and streamed[0].sensor_size == size


def test_streaming_text_beyond_240x180_matches_reading_it(tmp_path):
    """info / convert (streaming) refused text that flow (reading whole) took at its
    largest coordinates; both take it now, and no coordinate makes an absurd sensor."""
    from evmotion.errors import EvmotionWarning
    from evmotion.io import iter_events, read_events

    (tmp_path / "b.txt").write_text("0.001 539 2 1\n0.002 3 379 0\n")
    with pytest.warns(EvmotionWarning, match="taken as 540x380"):
        assert next(iter_events(tmp_path / "b.txt", 10)).sensor_size == (380, 540)
    with pytest.warns(EvmotionWarning, match="taken as 540x380"):
        assert read_events(tmp_path / "b.txt").sensor_size == (380, 540)
    (tmp_path / "c.txt").write_text("0.001 100000000 2 1\n")
    with pytest.raises(FormatError, match="outside any sensor"):
        read_events(tmp_path / "c.txt")


@pytest.mark.parametrize("order", ["x y p t", "x y t p", "p t x y"])
def test_other_column_orders_are_named_in_the_error(tmp_path, order):
    """A Metavision CSV (x,y,p,t) without a header said 'event 0 has polarity
    p=1002738'; the error now names the order the columns look like and how to state it,
    and a header line naming them reads the file."""
    from evmotion.io import iter_events, read_events

    rng = np.random.default_rng(0)
    n = 50
    cols = {"t": np.sort(rng.integers(1_000_000, 2_000_000, n)), "x": rng.integers(0, 240, n),
            "y": rng.integers(0, 180, n), "p": rng.integers(0, 2, n)}
    names = order.split()
    path = tmp_path / "e.csv"
    np.savetxt(path, np.column_stack([cols[k] for k in names]), fmt="%d", delimiter=",")
    for read in (read_events, lambda f: next(iter_events(f, 20))):
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            with pytest.raises(FormatError,
                               match=f"look like '{order}'.*naming them \\({','.join(names)}"):
                read(path)
        # the refusal alone: warnings about the times and sizes of misread columns had
        # come first (a Metavision CSV: three lines about one misreading)
        assert not said, [str(w.message) for w in said]
    path.write_text(",".join(names) + "\n" + path.read_text())
    with pytest.warns(EvmotionWarning, match="microseconds"):
        ev = read_events(path)
    np.testing.assert_array_equal(ev.x, cols["x"])
    np.testing.assert_array_equal(ev.t, cols["t"])


@pytest.mark.parametrize("name, unit, scale", [("t_ns", "ns", 1000), ("timestamp_us", "us", 1),
                                               ("t[s]", "s", 1e-6), ("t(ms)", "ms", 1e-3)])
def test_a_unit_in_the_time_columns_name_is_the_unit(tmp_path, name, unit, scale):
    from evmotion.io import read_events

    t_us = np.array([1_650_000_003_000_000, 1_650_000_003_016_000])
    t = t_us * 1000 if unit == "ns" else t_us // round(1 / scale) if unit == "ms" else \
        t_us * scale
    text = "\n".join(f"{v if unit != 's' else format(v, '.6f')},{x},2,1"
                     for v, x in zip(t, (5, 6), strict=True))
    path = tmp_path / "e.csv"
    path.write_text(f"{name},x,y,p\n{text}\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the unit is stated: no guess to warn about
        ev = read_events(path)
    np.testing.assert_array_equal(ev.t, t_us)


def test_whole_nanoseconds_since_the_epoch_and_wider_tables(tmp_path):
    """Text times of whole ns since the epoch read as µs put the recording in the year
    55,000; a table of six columns or with the time in the third was 'format not
    recognised'."""
    from evmotion.io import read_events

    (tmp_path / "ns.txt").write_text("1650000003000000000 5 2 1\n1650000003000016000 6 2 0\n")
    with pytest.warns(EvmotionWarning, match="read as nanoseconds since the epoch"):
        assert read_events(tmp_path / "ns.txt").t.tolist() == [1_650_000_003_000_000,
                                                               1_650_000_003_000_016]
    (tmp_path / "six.txt").write_text("0.001 5 2 1 0 0.5\n")
    with pytest.raises(FormatError, match="line 1 has 6 column.*keep those four"):
        read_events(tmp_path / "six.txt")
    (tmp_path / "xytp.txt").write_text("5 2 0.001000 1\n6 2 0.002000 0\n")
    # the error alone: no warning before it that the (first column's) times are whole
    # microseconds (probe: "as µs the first 2964 events span -53 µs")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FormatError, match="column 3 holds decimals.*'x y t p'"):
            read_events(tmp_path / "xytp.txt")


def test_metavision_csv_geometry_comment_gives_the_sensor(tmp_path):
    # Metavision's CSV export opens with '%geometry:W,H'; the size came from the largest
    # coordinates instead, with a warning
    from evmotion.io import read_events

    (tmp_path / "mv.csv").write_text("%geometry:346,260\nx,y,p,t\n5,2,1,1000\n6,3,0,1016\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # whole-number times: read as µs, said so
        ev = read_events(tmp_path / "mv.csv")
    assert ev.sensor_size == (260, 346) and ev.t.tolist() == [1000, 1016]
    assert ev.meta["sensor_size_from"] != "largest coordinate (the file states no sensor size)"


def test_column_names_in_the_last_comment_line_give_the_order(tmp_path):
    """'# x y p t' above the events: the refusal asked for a line naming the columns,
    which the file had (probe AS)."""
    from evmotion.io import read_events

    (tmp_path / "e.txt").write_text("# my lab's export\n# x y p t_us\n5 2 1 1000\n"
                                    "6 3 0 1016\n")
    ev = read_events(tmp_path / "e.txt", sensor_size=(8, 8))
    assert ev.t.tolist() == [1000, 1016] and ev.x.tolist() == [5, 6]
    assert ev.p.tolist() == [1, 0]


@pytest.mark.parametrize("header", ["# t x y p trigger", "t,x,y,p,trigger", "x y ch0 t p"])
def test_columns_the_header_names_beside_t_x_y_p_are_read_past(tmp_path, header):
    """formats.rst: a header names the columns in any order; a fifth named column (a
    trigger, a decimal gain) was refused ("line 2 has 5 column(s), expected 4", probe BC)."""
    names = header.lstrip("# ").replace(",", " ").split()
    rows = [{"t": "0.001017", "x": "5", "y": "2", "p": "1", "trigger": "0", "ch0": "0.75"},
            {"t": "0.001046", "x": "6", "y": "3", "p": "0", "trigger": "1", "ch0": "1.5"}]
    sep = "," if "," in header else " "
    (tmp_path / "e.txt").write_text(header + "\n" + "".join(
        sep.join(r[n] for n in names) + "\n" for r in rows))
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)  # the decimals are not the times
        ev = read_events(tmp_path / "e.txt", sensor_size=(8, 8))
    assert ev.t.tolist() == [1017, 1046] and ev.x.tolist() == [5, 6]
    assert ev.y.tolist() == [2, 3] and ev.p.tolist() == [1, 0]
    (tmp_path / "e.txt").write_text(header + "\n" + "0.001017 5 2 1\n")
    with pytest.raises(FormatError, match=f"not {len(names)} numbers a line"):
        read_events(tmp_path / "e.txt", sensor_size=(8, 8))


def test_whole_number_times_on_millisecond_steps_are_questioned(tmp_path):
    # relative ns of a µs sensor: all multiples of 1000; the warning says so, and a µs
    # file's does not
    from evmotion.errors import EvmotionWarning

    for step, said in ((3_000_000, True), (3_001, False)):
        (tmp_path / "e.txt").write_text("".join(f"{step * i} {i % 7} {i % 5} {i % 2}\n"
                                                for i in range(200)))
        with pytest.warns(EvmotionWarning, match="whole number") as rec:
            ecd.read(tmp_path / "e.txt", sensor_size=(5, 7))
        assert any("multiples of 1000" in str(w.message) for w in rec) == said


def test_ns_of_a_short_recording_and_whole_milliseconds_are_questioned(tmp_path):
    # 0.47 ms of relative ns (all multiples of 1000) passed unsaid; whole milliseconds
    # (thousands of events a step) read as µs are a readout no sensor makes
    from evmotion.errors import EvmotionWarning

    for step, per_t, said in ((1000, 1, "nanoseconds?"), (1, 2000, "milliseconds?"),
                              (1, 2, None)):
        n = 3000
        (tmp_path / "e.txt").write_text("".join(f"{step * (i // per_t)} {i % 7} {i % 5} "
                                                f"{i % 2}\n" for i in range(n)))
        with pytest.warns(EvmotionWarning, match="whole number") as rec:
            ecd.read(tmp_path / "e.txt", sensor_size=(5, 7))
        text = " ".join(str(w.message) for w in rec)
        for hint in ("nanoseconds?", "milliseconds?"):
            assert (hint in text) == (hint == said), text


SIZE = (200, 200)


@pytest.mark.parametrize(("scale", "fmt", "said"), [
    (1e-3, "{:.6f}", "milliseconds (or microseconds)? If so, read with --time-unit ms"),
    (1e3, "{:.0f}", "nanoseconds? If so, read with --time-unit ns"),  # ns off whole µs
    (1e-6, "{:.6f}", None),  # ECD's seconds at 120 kev/s
])
def test_a_sniffed_unit_at_a_rate_no_camera_makes_is_questioned(tmp_path, scale, fmt, said):
    """Decimal milliseconds read as seconds and nanoseconds not on whole µs read as µs
    made recordings 1000x long, said only as the generic whole-number note (probe AS)."""
    from evmotion.errors import EvmotionWarning

    n = 15_000
    # (events over a 200 x 200 sensor: 120 kev/s on 35 pixels would be 3400 events/s a
    # pixel, which no sensor averages; read 1000x long, the rate is judged on the pixels
    # that fired)
    t_us = np.arange(n) * 8.333 + 17.0  # 120 kev/s: as ms read as s, 125 s at 120 ev/s
    (tmp_path / "e.txt").write_text("".join(f"{fmt.format(v * scale)} {i % 200} "
                                            f"{i // 200 % 200} {i % 2}\n"
                                            for i, v in enumerate(t_us)))
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        ev = ecd.read(tmp_path / "e.txt", sensor_size=SIZE)
        chunks = list(ecd.iter_chunks(tmp_path / "e.txt", 14_000, sensor_size=SIZE))
    text = [str(w.message) for w in rec if issubclass(w.category, EvmotionWarning)]
    assert sum(said in m for m in text) == 2 if said else not any("?" in m for m in text)
    assert sum(len(c) for c in chunks) == len(ev) == n
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        if said:
            unit = said.split("--time-unit ")[1]
            ev = ecd.read(tmp_path / "e.txt", sensor_size=SIZE, time_unit=unit)
            assert ev.duration_us == pytest.approx(125_000, rel=0.01)


def test_decimal_milliseconds_named_in_the_header(tmp_path):
    # 't_ms' with decimals was refused, its advice ("give time_unit 's'") 1000x wrong
    f = tmp_path / "lab.tsv"
    f.write_text("t_ms\tx\ty\tp\n49006.624\t1\t2\t0\n49006.6245\t3\t4\t1\n"
                 "49012.158\t5\t2\t1\n")
    ev = ecd.read(f, sensor_size=(5, 7))
    assert ev.t.tolist() == [49_006_624, 49_006_624, 49_012_158]
    assert ev.x.tolist() == [1, 3, 5]


def test_whole_pixels_written_as_decimals_are_read(tmp_path):
    # other tools write float columns ("146.0"): whole values are pixels and polarities
    f = tmp_path / "floats.txt"
    f.write_text("0.001 146.0 166.0 1\n0.002 10.00 12.0 0.0\n0.003 11 12 1\n")
    ev = read_events(f, sensor_size=(200, 200))
    assert ev.x.tolist() == [146, 10, 11] and ev.y.tolist() == [166, 12, 12]
    assert ev.p.tolist() == [1, 0, 1] and ev.t.tolist() == [1000, 2000, 3000]


def test_numpy_savetxt_scientific_notation_is_read(tmp_path):
    # np.savetxt writes every column as %.18e by default: 1.418999999999999906e-03 s
    t = np.array([1419e-6, 2500e-6, 0.0123456, 3.5])
    table = np.column_stack([t, [98, 3, 0, 239], [42, 4, 179, 0], [1, 0, 1, 0]])
    f = tmp_path / "events.txt"
    np.savetxt(f, table)
    ev = read_events(f, sensor_size=(180, 240))
    assert ev.t.tolist() == [1419, 2500, 12346, 3_500_000]
    assert ev.x.tolist() == [98, 3, 0, 239] and ev.y.tolist() == [42, 4, 179, 0]
    assert ev.p.tolist() == [1, 0, 1, 0]
    # a pixel that is no whole number is still refused, on one line
    f.write_text("1.4e-03 9.5e+00 4 1\n")
    with pytest.raises(FormatError, match=r"events.txt: line 1") as exc:
        read_events(f, sensor_size=(180, 240))
    assert "\n" not in str(exc.value)


def test_a_fractional_pixel_is_named(tmp_path):
    f = tmp_path / "half.txt"
    f.write_text("0.001 14 16 1\n0.002 146.5 166.0 1\n")
    with pytest.raises(FormatError, match=r"half.txt: line 2: x = 146.5 is not a whole "
                                          r"number.*\.npy / \.h5 with float x, y") as exc:
        read_events(f, sensor_size=(200, 200))
    assert "\n" not in str(exc.value)


def test_a_negative_time_is_named_as_such(tmp_path):
    # it was "line 1 is not 't[s] x y p' numbers", which the line plainly is
    from evmotion.errors import FormatError

    f = tmp_path / "neg.txt"
    f.write_text("0.5 1 2 1\n-10.993376 1 2 0\n")
    with pytest.raises(FormatError, match=r"line 2: t = -10.993376 is negative.*offset"):
        ecd.read(f, sensor_size=(5, 7))


def test_images_txt_that_is_no_regular_file_or_names_a_huge_path(tmp_path):
    # probe AO: images.txt linked to /dev/zero was read by `info` until memory ran out;
    # a 300-character name in it was an OSError traceback (ENAMETOOLONG), echoed whole
    import os

    from evmotion.io import describe
    from evmotion.io.bosinput import load_bos_input

    (tmp_path / "events.txt").write_text("0.0 1 1 1\n0.001 2 2 0\n")
    os.symlink("/dev/zero", tmp_path / "images.txt")
    with pytest.raises(FormatError, match="images.txt: not a regular file"):
        describe(tmp_path)
    (tmp_path / "images.txt").unlink()
    (tmp_path / "images.txt").write_text(f"0.0 {'a' * 300}.png\n0.1 {'b' * 300}.png\n")
    with pytest.raises(FormatError, match=r"lists a missing frame file 'a{60}\.\.\.a{36}\.png'"
                       ) as exc:
        load_bos_input(tmp_path)
    assert len(str(exc.value)) < 400


@pytest.mark.parametrize("first", ["9300000000000", "9300000000000.5",
                                   "9223372036854775807"])
def test_a_time_past_int64_microseconds_is_named_not_wrapped(first):
    # probe AQ: 9300000000000 s wrapped to -9.1e18 us, and the file was read
    data = f"{first} 67 89 0\n0.5 1 2 1\n".encode()
    with pytest.raises(FormatError, match=rf"line 1: t = {first} s is beyond \+-2\^62 us"):
        ecd.parse_text(data, "e.txt")
    x, y, t, p = ecd.parse_text(b"4611686018427.387903 1 2 1\n", "e.txt")
    assert t.tolist() == [4_611_686_018_427_387_903]


@pytest.mark.parametrize(("unit", "said", "whole", "read"), [
    ("ns", r"nanoseconds: the times are in seconds\?", "1000.0 1 2 1\n3000.0 1 2 0\n", [1, 3]),
    ("us", r"microseconds, and the times span under 1 ms", "1000.4 1 2 1\n3000.6 1 2 0\n",
     [1000, 3001])])
def test_decimal_seconds_read_as_ns_or_us_are_refused(tmp_path, unit, said, whole, read):
    """Probe BD: --time-unit ns on decimal seconds put every event on 0 us, and the
    command then said "30000 events spanning 0 us"; probe BJ: so did --time-unit us ("all
    at one time (0 us)"). Whole ns and decimal µs still read."""
    (tmp_path / "s.txt").write_text("0.001017 1 2 1\n0.001046 1 2 0\n")
    with pytest.raises(FormatError, match=r"0.001017 is not a whole number of " + said):
        ecd.read(tmp_path / "s.txt", sensor_size=(5, 7), time_unit=unit)
    (tmp_path / "n.txt").write_text(whole)
    assert ecd.read(tmp_path / "n.txt", sensor_size=(5, 7), time_unit=unit).t.tolist() == read


@pytest.mark.parametrize("block_bytes", [4096, 1 << 30])  # many blocks; the whole at once
def test_chunks_say_how_far_into_the_file_they_are(tmp_path, block_bytes):
    """Text states no event count: the share of the file read gives convert's progress
    bar its total (it showed a count with no total, rate or ETA)."""
    from _helpers import assert_chunks_track_the_file, random_events

    out = tmp_path / "events.txt"
    ecd.write(out, random_events(40_000, (180, 240), 2_000_000))
    assert_chunks_track_the_file(ecd, out, 40_000, block_bytes)


def test_other_labs_text_variants(tmp_path):
    """Probe BL: a '#' comment among the events was 'not t[s] x y p numbers' (the docs
    allow comments); pandas' to_csv with its index (a first column named '') had '5
    column(s), expected 4'; a True / False polarity was 'format not recognised'."""
    from evmotion.io import read_events

    lines = [f"{0.001 + k * 1e-5:.6f} {k} {k + 1} {k % 2}" for k in range(6)]
    (tmp_path / "mid.txt").write_text("\n".join(lines[:3] + ["# a note", "  # indented"]
                                                + lines[3:]) + "\n")
    ev = read_events(tmp_path / "mid.txt")
    assert ev.x.tolist() == list(range(6)) and ev.t[-1] == 1050
    (tmp_path / "pandas.csv").write_text(",t,x,y,p\n" + "".join(
        f"{k},{line.replace(' ', ',')}\n" for k, line in enumerate(lines)))
    ev = read_events(tmp_path / "pandas.csv")
    assert ev.x.tolist() == list(range(6)) and ev.y.tolist() == list(range(1, 7))
    (tmp_path / "bool.csv").write_text("t,x,y,p\n0.001,1,2,True\n0.002,3,4,False\n")
    with pytest.raises(FormatError, match="True / False.*1 and 0"):
        read_events(tmp_path / "bool.csv")


def test_a_garbage_calib_txt_leaves_the_events_readable(tmp_path):
    # probe BL: "calib.txt must hold numbers" stopped the folder's events being read
    from evmotion.errors import EvmotionWarning

    (tmp_path / "events.txt").write_text("0.000500 3 4 1\n0.001000 5 6 0\n")
    (tmp_path / "calib.txt").write_text("garbage\n")
    with pytest.warns(EvmotionWarning, match=r"calib\.txt must hold numbers.*not used"):
        ev = ecd.read(tmp_path)
    assert ev.t.tolist() == [500, 1000] and "calibration" not in ev.meta


def test_a_companion_table_of_other_columns_is_not_counted_as_samples(tmp_path):
    # probe BL: info counted an 8-column imu.txt as 2 IMU samples; convert then dropped
    # them as unreadable
    (tmp_path / "events.txt").write_text("0.000500 3 4 1\n0.001000 5 6 0\n")
    (tmp_path / "imu.txt").write_text("0.01 0 0 9.8 0.1 0 0 5\n0.02 0 0 9.8 0.1 0 0 5\n")
    d = ecd.describe(tmp_path)
    assert d["imu"] == 0 and d["imu_error"] == "imu.txt has 8 columns, expected 7"
    (tmp_path / "imu.txt").write_text("0.01 0 0 9.8 0.1 0 0\n0.02 0 0 9.8 0.1 0 0\n")
    d = ecd.describe(tmp_path)
    assert d["imu"] == 2 and "imu_error" not in d


@pytest.mark.parametrize("line", ["0.000200 1e30 4 1", "0.000200 5 4 1e30"])
def test_a_huge_number_in_scientific_notation_is_one_line(tmp_path, line):
    """1e30 in a pixel or polarity column was cast to int64 with numpy's RuntimeWarning
    on stderr, then said as a negative coordinate (probe CG)."""
    from evmotion.io import read_events

    path = tmp_path / "e.txt"
    path.write_text(f"0.000100 3 4 1\n{line}\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(FormatError, match=f"line 2 is not .*'{line}'"):
            read_events(path)
