"""The README's command-line tour, end to end on a small simulated recording."""

import json

import numpy as np
import pytest

from evmotion.cli import main


def test_simulate_then_egomotion_uses_stored_intrinsics(tmp_path, capsys):
    rec = tmp_path / "sim.h5"
    assert main(["simulate", "rotation", "--duration", "0.03", "--out", str(rec)]) == 0
    capsys.readouterr()
    out = tmp_path / "ego"
    assert main(["egomotion", str(rec), "--warp", "rotation", "--window-events", "20000",
                 "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    first = summary["windows"][0]
    assert first["units"] == {"wx": "rad/s", "wy": "rad/s", "wz": "rad/s"}
    est = np.array([first["params"][k] for k in ("wx", "wy", "wz")])
    # the rotation scene's default angular velocity (see evmotion.sim.scenes)
    np.testing.assert_allclose(est, [0.5, -0.7, 1.2], atol=0.1)
    assert first["omega"] == list(est) and first["omega_units"] == "rad/s"
    assert (out / "params.csv").is_file() and any(out.glob("*.png"))


@pytest.mark.slow
def test_demo_writes_pictures_and_report(tmp_path, monkeypatch):
    from evmotion import demo

    monkeypatch.setattr(demo, "_zoom", lambda out, rep, seed: {})
    assert demo.main(["--out", str(tmp_path)]) == 0
    assert (tmp_path / "report.html").is_file()
    pngs = {p.name for p in tmp_path.glob("*.png")}
    assert {"rotation_iwe.png", "object_flow.png", "triplet_flow.png", "bos_flow.png",
            "bos_q.png"} <= pngs
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["rotation"]["omega_rms_error"] < 0.03  # (0.017; 0.050 at start)
    # BOS, scale-aware term: direction and magnitude of the simulated plume's flow
    bos = summary["bos"][0]
    assert bos["data term"] == "scale" and bos["AE rad"] < 0.3
    assert 0.7 < bos["median |v|/|v_true|"] < 1.3
