"""The camera options of the CLI: --calib / --K / --dist checked as they are parsed (one line,
exit code 2), the one distortion rule (undistort when the calibration has distortion,
--no-undistort to opt out) in flow as in egomotion, the 'grid' every output names, and the
intrinsics `info` shows."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from evmotion.cli import main
from evmotion.events import EventArray
from evmotion.io import write_events
from evmotion.io.calibration import read_camera

CALIB = "199.092366542 198.82882 132.192071378 110.712660011 -0.368436311798 " \
        "0.150947243557 -0.000296130534 -0.000759431726 0.0"
K_ARG = "199.092366542,198.82882,132.192071378,110.712660011"
DIST_ARG = "-0.368436311798,0.150947243557,-0.000296130534,-0.000759431726"
MULTICM = ["--method", "multicm", "--scales", "1", "--max-iter", "3"]


@pytest.fixture(scope="module")
def ecd(tmp_path_factory):
    """A small ECD folder (DAVIS240C, 180 x 240): a bright bar moving right, strong barrel
    distortion in calib.txt."""
    d = tmp_path_factory.mktemp("ecd")
    rng = np.random.default_rng(3)
    n = 4000
    t = np.sort(rng.uniform(0, 0.02, n))
    x = np.clip(40 + 4000 * t + rng.normal(0, 0.7, n), 0, 239).round().astype(int)
    y = rng.integers(10, 170, n)
    p = rng.integers(0, 2, n)
    np.savetxt(d / "events.txt", np.column_stack([t, x, y, p]), fmt=["%.9f", "%d", "%d", "%d"])
    (d / "calib.txt").write_text(CALIB + "\n")
    return d


def _events(folder) -> EventArray:
    from evmotion.io import read_events

    return read_events(folder)


def _one_line_exit2(argv, capsys, *needles):
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for n in needles:
        assert n in lines[0], (n, lines[0])


@pytest.mark.parametrize("cmd", [
    ["flow", "REC", "--out", "OUT.h5"],
    ["egomotion", "REC", "--window-events", "1000", "--out", "OUTDIR"],
    ["segment", "REC", "--out", "OUTDIR"],
    ["landscape", "REC", "--range", "-1", "1", "--out", "OUT.png"],
])
@pytest.mark.parametrize("bad, needles", [
    (["--K", "200,200,120"], ["--K", "4 comma-separated numbers", "'200,200,120'"]),
    (["--K", "0,200,120,90"], ["--K", "fx, fy must be in [1, 1e+06] px", "'0,200,120,90'"]),
    (["--K", "200,nan,120,90"], ["--K", "finite", "'200,nan,120,90'"]),
    (["--K", "200,200,120,90", "--dist", "0.1,0.2,0"], ["--dist", "4 or 5", "'0.1,0.2,0'"]),
    (["--K", "200,200,120,90", "--dist", "a,b,c,d"], ["--dist", "'a,b,c,d'"]),
    (["--K", "200,200,120,90", "--calib", "CALIB"], ["--calib", "not allowed with"]),
])
def test_camera_options_are_checked_at_parse_time(ecd, tmp_path, capsys, cmd, bad, needles):
    sub = {"REC": str(ecd), "OUT.h5": str(tmp_path / "f.h5"), "OUTDIR": str(tmp_path / "o"),
           "OUT.png": str(tmp_path / "l.png"), "CALIB": str(ecd / "calib.txt")}
    argv = [sub.get(a, a) for a in cmd + bad]
    _one_line_exit2(argv, capsys, *needles)
    assert not (tmp_path / "f.h5").exists() and not (tmp_path / "o").exists()


def test_dist_without_k_is_refused(ecd, tmp_path, capsys):
    _one_line_exit2(["flow", str(ecd), "--out", str(tmp_path / "f.h5"), "--dist", "0,0,0,0"],
                    capsys, "--dist 0,0,0,0 needs --K")


def test_flow_on_ecd_folder_undistorts_unless_told_not_to(ecd, tmp_path, capsys):
    from evmotion.methods.multicm import estimate_flow

    def run(*extra):
        out = tmp_path / f"f{len(list(tmp_path.iterdir()))}.h5"
        assert main(["flow", str(ecd), "--out", str(out), *MULTICM, "--json", *extra]) == 0
        summary = json.loads(capsys.readouterr().out)
        with h5py.File(out) as f:
            return np.asarray(f["flow"][0]), f.attrs["grid"], summary["grid"]

    ev = _events(ecd)
    cam = read_camera(ecd / "calib.txt")
    expect_und = estimate_flow(cam.undistort_events(ev), n_scales=1, max_iter=3).flow
    expect_raw = estimate_flow(ev, n_scales=1, max_iter=3).flow

    flow, attr, field = run()
    label = "undistorted (K=[199.092, 198.829, 132.192, 110.713])"
    assert attr == field == label
    np.testing.assert_allclose(flow, expect_und, rtol=1e-5, atol=1e-4)

    flow_raw, attr, field = run("--no-undistort")
    assert attr == field == "distorted sensor"
    np.testing.assert_allclose(flow_raw, expect_raw, rtol=1e-5, atol=1e-4)
    assert np.abs(flow - flow_raw).max() > 1.0  # the two grids give different flows

    # --K/--dist with the same numbers as calib.txt: the same flow
    flow_k, attr, _ = run("--K", K_ARG, f"--dist={DIST_ARG}")
    assert attr == label
    np.testing.assert_allclose(flow_k, flow, rtol=1e-5, atol=1e-4)
    # --K alone: no distortion, so the events stay where they are, on K's pinhole grid
    flow_k0, attr, _ = run("--K", K_ARG)
    assert attr == label
    np.testing.assert_allclose(flow_k0, expect_raw, rtol=1e-5, atol=1e-4)


def test_flow_triplet_undistorts_on_the_pixel_lattice(ecd, tmp_path, capsys):
    out = tmp_path / "t.h5"
    assert main(["flow", str(ecd), "--method", "triplet", "--out", str(out), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["grid"].startswith("undistorted (K=[199.092")
    cam = read_camera(ecd / "calib.txt")
    assert s["events"] == len(cam.undistort_events(_events(ecd), integer=True))
    with h5py.File(out) as f:
        assert f.attrs["grid"] == s["grid"]
    assert main(["flow", str(ecd), "--method", "triplet", "--out", str(out), "--json",
                 "--no-undistort"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["grid"] == "distorted sensor" and s["events"] == len(_events(ecd))


def test_egomotion_k_equals_recording_own_calibration(ecd, tmp_path, capsys):
    rows = {}
    for name, extra in (("own", []), ("K", ["--K", K_ARG, f"--dist={DIST_ARG}"]),
                        ("raw", ["--no-undistort"])):
        assert main(["egomotion", str(ecd), "--window-events", "4000", "--max-png", "0",
                     "--out", str(tmp_path / name), "--json", *extra]) == 0
        rows[name] = json.loads(capsys.readouterr().out)
        with h5py.File(tmp_path / name / "params.h5") as f:
            assert f.attrs["grid"] == rows[name]["grid"]
    assert rows["own"]["grid"].startswith("undistorted (K=[199.092")
    assert rows["raw"]["grid"] == "distorted sensor"
    own = rows["own"]["windows"][0]["params"]
    assert rows["K"]["windows"][0]["params"] == own
    assert rows["raw"]["windows"][0]["params"] != own


def test_info_shows_the_recording_intrinsics(ecd, tmp_path, capsys):
    assert main(["info", str(ecd), "--json"]) == 0
    intr = json.loads(capsys.readouterr().out)["intrinsics"]
    assert intr["source"] == str(ecd / "calib.txt") and intr["nominal"] is False
    assert intr["K"] == pytest.approx([199.092366542, 198.82882, 132.192071378, 110.712660011])
    assert intr["dist"][0] == pytest.approx(-0.368436311798)
    assert intr["resolution"] == [180, 240]
    assert main(["info", str(ecd)]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("intrinsics:")]
    assert line == [f"intrinsics:  K=[199.092, 198.829, 132.192, 110.713] dist=[-0.368436, "
                    f"0.150947, -0.000296131, -0.000759432, 0] 240 x 180 px from "
                    f"{ecd / 'calib.txt'}"]
    # converted to .h5, the recording keeps its calibration
    h5 = tmp_path / "rec.h5"
    assert main(["convert", str(ecd / "events.txt"), str(h5)]) == 0
    capsys.readouterr()
    assert main(["info", str(h5), "--json"]) == 0
    intr = json.loads(capsys.readouterr().out)["intrinsics"]
    assert intr["source"] == f"{h5} (calibration attribute)"
    assert intr["K"][0] == pytest.approx(199.092366542)
    # a recording without calibration says so
    plain = tmp_path / "plain.h5"
    ev = _events(ecd)
    write_events(plain, EventArray(ev.x, ev.y, ev.t, ev.p, ev.sensor_size))  # no meta
    assert main(["info", str(plain), "--json"]) == 0
    intr = json.loads(capsys.readouterr().out)["intrinsics"]
    assert intr["source"] is None and "no calibration" in intr["reason"]


@pytest.mark.realdata
def test_real_jaer_info_says_why_no_intrinsics(shared_data, capsys):
    f = shared_data / "formats" / "davis240_translboxes_aedat2.aedat"
    assert main(["info", str(f), "--header-only", "--json"]) == 0
    intr = json.loads(capsys.readouterr().out)["intrinsics"]
    assert intr["source"] is None and "4.5, 8.5, 12 mm" in intr["reason"]


def test_undistortion_that_drops_many_events_says_so(tmp_path, capsys):
    """Undistorting an ECD window left 18 % of its events out without a word."""
    from evmotion.cli import main
    from evmotion.events import EventArray
    from evmotion.io import write_events

    rng = np.random.default_rng(0)
    n = 4000
    ev = EventArray(x=rng.integers(0, 60, n), y=rng.integers(0, 40, n), t=np.arange(n) * 10,
                    p=rng.integers(0, 2, n), sensor_size=(40, 60))
    calib = {"K": [[30.0, 0, 30.0], [0, 30.0, 20.0], [0, 0, 1]],
             "dist": [-0.5, 0.2, 0.0, 0.0, 0.0], "resolution": [40, 60]}
    write_events(tmp_path / "r.h5", ev, calibration=calib)
    assert main(["flow", str(tmp_path / "r.h5"), "--scales", "2", "--out",
                 str(tmp_path / "f.h5")]) == 0
    err = capsys.readouterr().err
    assert "undistortion moved" in err and "outside the image" in err
    assert main(["flow", str(tmp_path / "r.h5"), "--scales", "2", "--no-undistort", "--out",
                 str(tmp_path / "g.h5")]) == 0
    assert "undistortion moved" not in capsys.readouterr().err


def test_undistortion_that_drops_every_event_names_the_calibration(tmp_path, capsys):
    # every event in a corner the lens model maps outside: "the recording holds no
    # events" had followed the warning (probe)
    ev = EventArray(x=np.zeros(500, int), y=np.zeros(500, int), t=np.arange(500) * 10,
                    p=np.ones(500, int), sensor_size=(40, 60))
    calib = {"K": [[30.0, 0, 30.0], [0, 30.0, 20.0], [0, 0, 1]],
             "dist": [-0.5, 0.2, 0.0, 0.0, 0.0], "resolution": [40, 60]}
    write_events(tmp_path / "corner.h5", ev, calibration=calib)
    assert main(["flow", str(tmp_path / "corner.h5"), "--out", str(tmp_path / "f.h5")]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "corner.h5" in lines[0], lines
    assert "undistortion moved all 500 events outside the image" in lines[0]
    assert "--no-undistort" in lines[0]


def test_info_shows_the_simulators_camera_in_its_ground_truth(tmp_path, capsys):
    """``sim_gt.h5`` stores K (the events were made with it); info said "none"."""
    sim = tmp_path / "sim.h5"
    assert main(["simulate", "translation", "--duration", "0.02", "--sensor-size", "60", "80",
                 "--out", str(sim)]) == 0
    capsys.readouterr()
    assert main(["info", str(tmp_path / "sim_gt.h5"), "--json"]) == 0
    intr = json.loads(capsys.readouterr().out)["intrinsics"]
    assert intr["source"] == f"{tmp_path / 'sim_gt.h5'} (its camera K)"
    assert main(["info", str(sim), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["intrinsics"]["K"] == intr["K"]


@pytest.mark.parametrize("k, warned", [("200,200,120,90", False), ("120,90,200,170", False),
                                       ("200,200,300,90", True), ("90,200,-5,90", True)])
def test_k_principal_point_off_the_sensor_is_said(ecd, tmp_path, capsys, k, warned):
    """--K in another order (cx, cy past the 240 x 180 sensor) runs, with one line saying
    the principal point is off the sensor; a plausible one says nothing."""
    assert main(["flow", str(ecd), "--out", str(tmp_path / "f.h5"), *MULTICM, "--K", k]) == 0
    err = capsys.readouterr().err
    assert ("principal point" in err) == warned, err
    if warned:
        assert "240 x 180 px sensor" in err and "FX,FY,CX,CY" in err


@pytest.mark.parametrize("k, warned", [("2,2,120,90", True), ("8,8,120,90", True),
                                       ("50,50,120,90", False)])
def test_k_of_an_implausible_field_of_view_is_said(ecd, tmp_path, capsys, k, warned):
    """--K 2,2,125,86 on 240 x 180 (a 177 degree field of view) ran unsaid (probe)."""
    assert main(["flow", str(ecd), "--out", str(tmp_path / "f.h5"), *MULTICM, "--K", k]) == 0
    err = capsys.readouterr().err
    assert ("degree field of view" in err) == warned, err


def test_k_principal_point_far_off_the_sensor_is_refused(ecd, tmp_path, capsys):
    """Probe AR: --K 199,198,1320,110 was only said, and the estimate came out valid."""
    assert main(["flow", str(ecd), "--out", str(tmp_path / "f.h5"), *MULTICM,
                 "--K", "199,198,1320,110"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "(1320, 110) px lies far outside the 240 x 180" in err
    assert not (tmp_path / "f.h5").exists()


def test_the_summary_line_says_when_the_flow_left_the_sensor_grid(ecd, tmp_path, capsys):
    """A calib.txt beside events.txt undistorts the events, so a .flo (which cannot say
    so) is on another grid than the sensor's: the line the command prints says it (not
    for a pinhole calibration, which moves nothing)."""
    for extra, said in (([], True), (["--no-undistort"], False), (["--K", K_ARG], False)):
        assert main(["flow", str(ecd), "--out", str(tmp_path / "f.flo"), *MULTICM,
                     *extra]) == 0
        out = capsys.readouterr().out
        assert ("on the undistorted pixel grid" in out) == said, out


def test_a_distortion_of_no_lens_is_said(ecd, tmp_path, capsys):
    # --dist=5,0,0,0 (k1 = 5: the corners move 279 % of their distance from the principal
    # point) ran without a word; the ECD's own calibration (19 %) still says nothing
    from evmotion.camera import Camera

    assert Camera(200, 200, 119.5, 89.5, (5.0, 0, 0, 0, 0), (180, 240)).corner_shift() > 2.5
    assert read_camera(ecd / "calib.txt", sensor_size=(180, 240)).corner_shift() < 0.3
    argv = ["egomotion", str(ecd), "--warp", "translation", "--window-events", "2000",
            "--max-windows", "1", "--K", "200,200,119.5,89.5"]
    assert main(argv + ["--dist=5,0,0,0", "--out", str(tmp_path / "a")]) == 0
    assert "move the sensor's corners by 279% of their distance" in capsys.readouterr().err
    assert main(argv + ["--dist=-0.37,0.15,0,0", "--out", str(tmp_path / "b")]) == 0
    assert "sensor's corners" not in capsys.readouterr().err


def test_landscape_says_undistortion_left_out_the_short_windows_events(ecd, tmp_path, capsys):
    """Probe AR: a window short of --window-events because undistortion left events out
    was said to be short because 'the recording (or --t1) ends first'."""
    assert main(["landscape", str(ecd), "--warp", "translation", "--range", "-1", "1",
                 "--steps", "3", "--window-events", "4000", "--out",
                 str(tmp_path / "l.png")]) == 0
    err = capsys.readouterr().err
    assert "undistortion left out the rest" in err and "ends first" not in err, err


def test_info_gives_an_ecd_calibration_the_recordings_sensor(tmp_path, capsys):
    """calib.txt states no sensor size: info reported the ECD's 240 x 180 for a 346 x 260
    recording (probe AW)."""
    d = tmp_path / "rec"
    d.mkdir()
    (d / "events.txt").write_text("# evmotion ECD text: t[s] x y p; sensor height 260 width "
                                  "346\n0.000100 300 200 1\n0.000200 10 5 0\n")
    (d / "calib.txt").write_text("260 260 172.5 129.5 0 0 0 0 0\n")
    assert main(["info", str(d), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["intrinsics"]["resolution"] == [260, 346]
