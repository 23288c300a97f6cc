"""The fast paths of ``--method dnn``: the inference network and input (same results as the
training forward), and a start-up that does only what the call uses."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from evmotion.cli import COMMANDS, _command_of, build_parser, main  # noqa: E402
from evmotion.events import EventArray  # noqa: E402
from evmotion.methods.dnn.data import sim_window  # noqa: E402
from evmotion.methods.dnn.infer import estimate_flow_dnn, predict_displacement  # noqa: E402
from evmotion.methods.dnn.model import load_inference_net, load_model  # noqa: E402
from evmotion.methods.dnn.network import EVFlowNet, InferenceNet  # noqa: E402
from evmotion.methods.dnn.voxel import (  # noqa: E402
    network_input,
    normalize_voxel,
    pad_to_multiple,
    voxel_grid,
)


def _random_net(width: float, seed: int, norm: str = "batch",
                symmetric: bool = True) -> EVFlowNet:
    torch.manual_seed(seed)
    net = EVFlowNet(width=width, norm=norm, symmetric=symmetric)
    with torch.no_grad():
        for p in net.parameters():  # every weight and bias matters, heads included
            p.normal_(0.0, 0.3)
        for m in net.modules():  # batch norm's running statistics, folded at inference
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.normal_(0.0, 0.5)
                m.running_var.uniform_(0.2, 3.0)
    return net.eval()


@pytest.mark.parametrize(("width", "shape", "batch", "norm", "symmetric"),
                         [(0.0625, (32, 48), 1, "batch", True),
                          (0.125, (48, 80), 2, "batch", True),
                          (0.125, (48, 80), 1, "none", False),
                          (0.125, (48, 80), 1, "batch", False),
                          (0.25, (64, 32), 1, "batch", True)])
def test_inference_net_equals_the_training_forward(width, shape, batch, norm, symmetric):
    net = _random_net(width, seed=int(width * 100), norm=norm, symmetric=symmetric)
    x = torch.randn(batch, 5, *shape)
    with torch.inference_mode():
        ref = net(x)[-1]
        got = InferenceNet(net)(x)
    assert got.shape == ref.shape == (batch, 2, *shape)
    assert ref.abs().max() > 1.0  # a non-trivial flow
    torch.testing.assert_close(got, ref, rtol=1e-4, atol=1e-4 * float(ref.abs().max()))


@pytest.mark.parametrize("train_mode", [False, True])
def test_symmetric_network_is_equivariant_to_the_diagonal_mirror(train_mode):
    net = _random_net(0.0625, seed=3).train(train_mode)
    x = torch.randn(2, 5, 32, 48)
    with torch.no_grad():
        direct, mirrored = net(x), net(x.transpose(-1, -2))
    for a, b in zip(direct, mirrored, strict=True):
        assert a.abs().max() > 0.1
        # mirroring the input swaps the axes: (u, v)(x^T) = (v, u)(x)^T, at every scale
        torch.testing.assert_close(b, a.flip(1).transpose(-1, -2), rtol=1e-5, atol=1e-5)
    plain = _random_net(0.0625, seed=3, symmetric=False).eval()
    with torch.no_grad():
        a, b = plain(x)[-1], plain(x.transpose(-1, -2))[-1]
    assert not torch.allclose(b, a.flip(1).transpose(-1, -2), atol=1e-3)


def test_inference_net_of_the_shipped_checkpoint():
    net = load_model()
    x = torch.randn(1, 5, 272, 352)
    with torch.inference_mode():
        ref = net(x)[-1]
        got = load_inference_net()(x)
    torch.testing.assert_close(got, ref, rtol=1e-5, atol=1e-4)
    assert load_inference_net() is load_inference_net()  # cached


def _window(shape, n, seed, subpixel=False):
    rng = np.random.default_rng(seed)
    h, w = shape
    x = rng.uniform(0, w - 1, n) if subpixel else rng.integers(0, w, n)
    y = rng.uniform(0, h - 1, n) if subpixel else rng.integers(0, h, n)
    return EventArray(x=x, y=y, t=np.sort(rng.integers(0, 30_000, n)),
                      p=rng.integers(0, 2, n), sensor_size=shape)


@pytest.mark.parametrize(("shape", "n_bins", "subpixel"), [((260, 346), 5, False),
                                                           ((17, 33), 3, True),
                                                           ((32, 48), 2, False)])
def test_network_input_equals_voxel_normalize_pad(shape, n_bins, subpixel):
    ev = _window(shape, 5000, seed=n_bins, subpixel=subpixel)
    ref = pad_to_multiple(normalize_voxel(voxel_grid(ev, n_bins))).transpose(1, 2, 0)
    got = network_input(ev, n_bins)
    assert got.shape == ref.shape and got.dtype == np.float32
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-7)


def test_network_input_of_a_window_that_cancels_out():
    # an ON and an OFF event at the same pixel and time: every cell is zero, no scale
    ev = EventArray(x=np.array([3, 3]), y=np.array([2, 2]), t=np.array([5, 5]),
                    p=np.array([1, 0]), sensor_size=(4, 6))
    assert not network_input(ev).any()


def test_predict_displacement_equals_the_training_path():
    win = sim_window(7, scene="rotation", texture="dots", sensor_size=(70, 90),
                     window_events=5000)
    ev = win.events
    net = load_model()
    vox = torch.from_numpy(pad_to_multiple(normalize_voxel(voxel_grid(ev))))
    with torch.inference_mode():
        ref = net(vox[None])[-1][0, :, :70, :90].permute(1, 2, 0).numpy()
    got = predict_displacement(ev)
    assert got.shape == (70, 90, 2) and got.flags.c_contiguous
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-4)


def test_cli_dnn_computes_iwes_only_for_pictures_and_json(tmp_path, capsys, monkeypatch):
    import evmotion.methods.dnn.problem as loss_mod
    from evmotion.io import write_events

    win = sim_window(11, scene="translation", texture="shapes", sensor_size=(50, 70),
                     window_events=3000)
    rec = tmp_path / "win.h5"
    write_events(rec, win.events)
    real = loss_mod.window_problem
    calls = []

    def spy(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(loss_mod, "window_problem", spy)
    assert main(["flow", str(rec), "--method", "dnn", "--out", str(tmp_path / "x.flo")]) == 0
    assert calls == []  # a flow file holds no IWE or focus: none computed
    capsys.readouterr()
    assert main(["flow", str(rec), "--method", "dnn", "--out", str(tmp_path / "y.flo"),
                 "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["windows"][0]
    assert calls and np.isfinite(row["focus"]) and row["focus"] > 0
    # the library's default still carries them
    assert set(estimate_flow_dnn(win.events).iwes) == {"t1", "tmid", "tN", "identity"}


@pytest.mark.parametrize("argv", [["flow", "x.h5", "--method", "dnn", "--out", "x.flo"],
                                  ["info", "x.h5", "--json"],
                                  ["simulate", "zoom", "--out", "s.h5", "--seed", "3"]])
def test_a_command_parses_alike_with_only_its_own_parser(argv):
    assert _command_of(argv) == (argv[0],)
    one = vars(build_parser(_command_of(argv)).parse_args(argv))
    every = vars(build_parser().parse_args(argv))
    assert one == every


@pytest.mark.parametrize("argv", [[], ["--version"], ["nosuch", "x"], ["-h"]])
def test_no_or_unknown_command_gets_every_command(argv):
    assert _command_of(argv) == COMMANDS


def test_multicm_imports_no_optimizer_until_it_optimizes():
    # scipy.optimize costs ~0.3 s of start-up; --method dnn uses multicm's result type only
    code = ("import sys, evmotion.methods.multicm, evmotion.methods.dnn.infer; "
            "print('scipy.optimize' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "False"
