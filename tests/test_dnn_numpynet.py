"""The network in numpy (methods/dnn/numpynet.py): the torch network's flow to float32
rounding, the shipped export equal to the shipped checkpoint, and a one-window estimate on
the CPU that never imports torch."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from evmotion.errors import ParameterError  # noqa: E402
from evmotion.methods.dnn import numpynet as N  # noqa: E402
from evmotion.methods.dnn.infer import _resized, load_network  # noqa: E402
from evmotion.methods.dnn.model import load_inference_net, save_model  # noqa: E402
from evmotion.methods.dnn.network import InferenceNet  # noqa: E402
from test_dnn_speed import _random_net  # noqa: E402


@pytest.mark.parametrize(("width", "shape", "batch", "norm", "symmetric"),
                         [(0.0625, (32, 48), 1, "batch", True),
                          (0.125, (48, 80), 2, "batch", True),
                          (0.125, (48, 80), 1, "none", False),
                          (0.25, (64, 32), 2, "batch", False)])
def test_numpy_net_is_the_torch_networks_flow(width, shape, batch, norm, symmetric):
    net = _random_net(width, seed=int(width * 1000) + batch, norm=norm, symmetric=symmetric)
    x = torch.randn(batch, 5, *shape)
    with torch.inference_mode():
        ref = net(x)[-1].numpy()
    got = N.NumpyNet(N._arrays_of(InferenceNet(net)))(x.numpy())
    assert got.shape == ref.shape == (batch, 2, *shape) and got.dtype == np.float32
    assert np.abs(ref).max() > 1.0  # a non-trivial flow
    np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-4 * np.abs(ref).max())


def test_shipped_export_is_the_shipped_checkpoint():
    # the .npz is made from the .pt (export_checkpoint); a retrained .pt without a new
    # export would ship two different networks
    with np.load(N.SHIPPED_EXPORT) as data:
        shipped = {k: data[k] for k in data.files}
    fresh = N._arrays_of(load_inference_net())
    assert sorted(shipped) == sorted(fresh)
    for k, v in fresh.items():
        # (within float32 rounding: the batch norms folded into the weights come out an
        # ulp apart on CPUs whose vector units torch dispatches to differently)
        np.testing.assert_allclose(shipped[k], v, rtol=1e-6, atol=1e-7, err_msg=k)
    x = np.random.default_rng(0).normal(size=(1, 5, 64, 96)).astype(np.float32)
    with torch.inference_mode():
        ref = load_inference_net()(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(N.load_numpy_net()(x), ref, rtol=1e-5, atol=1e-4)


def test_a_torch_checkpoint_and_its_export_give_one_network(tmp_path):
    net = _random_net(0.0625, seed=5)
    save_model(tmp_path / "model.pt", net)
    N.export_checkpoint(tmp_path / "model.pt", tmp_path / "model.npz")
    x = np.random.default_rng(1).normal(size=(1, 5, 32, 48)).astype(np.float32)
    a = load_network(tmp_path / "model.pt", backend="numpy")(x)
    b = load_network(tmp_path / "model.npz")(x)   # an export: numpy, torch loaded or not
    assert isinstance(load_network(tmp_path / "model.npz"), N.NumpyNet)
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("content", [b"not a zip", b"PK\x03\x04truncated", b"x y p t\n1 2 1 3\n"])
def test_an_unreadable_export_is_named(tmp_path, content):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(content)
    with pytest.raises(ParameterError, match="bad.npz: not an evmotion network export"):
        load_network(bad)


@pytest.mark.parametrize(("change", "match"), [
    (lambda a: a.update(dec2_w=a["dec2_w"][:, :-3]), r"dec2_w is \[32, 303\], the network needs \[32, 306\]"),
    # numpy's broadcasting ran these two without a word (probe AX)
    (lambda a: a.update(head3_w=a["head3_w"][:1]), r"head3_w is \[1, 16\], the network needs \[8, 16\]"),
    (lambda a: a.update(enc2_b=a["enc2_b"][:1]), r"enc2_b is \[1\], the network needs \[32\]"),
    (lambda a: a.update(n_bins=np.int64(0)), r"n_bins is .*0.*not a whole number of time bins"),
    (lambda a: a.update(n_bins=np.float64(1e9)), r"n_bins is .*not a whole number of time bins"),
    (lambda a: a.pop("head0_b"), r"no array 'head0_b'"),
])
def test_an_export_whose_arrays_do_not_make_the_network_is_named(tmp_path, change, match):
    with np.load(N.SHIPPED_EXPORT) as data:
        arrays = {k: data[k] for k in data.files}
    change(arrays)
    np.savez(tmp_path / "odd.npz", **arrays)
    with pytest.raises(ParameterError, match="odd.npz: .*" + match):
        load_network(tmp_path / "odd.npz")


def test_a_renamed_torch_checkpoint_is_named(tmp_path):
    bad = tmp_path / "model.npz"
    bad.write_bytes((N.SHIPPED_EXPORT.with_suffix(".pt")).read_bytes())
    with pytest.raises(ParameterError, match="model.npz: not an evmotion network export "
                                             r"\(no array 'n_bins'"):
        load_network(bad)


@pytest.mark.parametrize(("shape", "size"), [((2, 5, 7), (20, 28)), ((3, 4, 4), (32, 32)),
                                             ((1, 6, 9), (13, 17)), ((2, 3, 5), (3, 5))])
def test_resize_is_torchs_bilinear(shape, size):
    a = np.random.default_rng(2).normal(size=shape).astype(np.float32)
    ref = torch.nn.functional.interpolate(torch.from_numpy(a)[None], size=size,
                                          mode="bilinear", align_corners=False)[0].numpy()
    np.testing.assert_allclose(_resized(a, size), ref, rtol=1e-5, atol=1e-5)


def test_a_window_on_the_cpu_imports_no_torch():
    # torch's import was 2.0-2.4 s of the 4-6 s one-window command
    code = ("import sys, numpy as np; from evmotion.events import EventArray; "
            "from evmotion.methods.dnn import estimate_flow_dnn; "
            "rng = np.random.default_rng(0); n = 3000; "
            "ev = EventArray(x=rng.integers(0, 60, n), y=rng.integers(0, 40, n), "
            "t=np.arange(n) * 10, p=rng.integers(0, 2, n), sensor_size=(40, 60)); "
            "import warnings; warnings.simplefilter('ignore'); "
            "r = estimate_flow_dnn(ev); "
            "print(r.flow.shape, sorted(r.iwes)[0], 'torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "(40, 60, 2) identity False"


def test_the_two_backends_give_one_flow():
    from evmotion.methods.dnn.data import sim_window
    from evmotion.methods.dnn.infer import estimate_flow_dnn

    win = sim_window(21, scene="rotation", texture="shapes", sensor_size=(60, 80),
                     window_events=6000).events
    a = estimate_flow_dnn(win, backend="numpy", with_iwes=False)
    b = estimate_flow_dnn(win, backend="torch", with_iwes=False)
    auto = estimate_flow_dnn(win, with_iwes=False)   # torch is loaded in this process
    assert (a.meta["backend"], b.meta["backend"], auto.meta["backend"]) == (
        "numpy", "torch", "torch")
    assert np.abs(b.flow).max() > 1.0
    np.testing.assert_allclose(a.flow, b.flow, rtol=0, atol=1e-3 * np.abs(b.flow).max())
    np.testing.assert_array_equal(auto.flow, b.flow)


@pytest.mark.parametrize(("ckpt", "backend", "device", "match"), [
    (None, "jax", "cpu", "backend must be one of auto, numpy, torch"),
    (None, "numpy", "cuda", "the numpy network runs on the CPU only"),
    (N.SHIPPED_EXPORT, "auto", "cuda", "CPU only, got device 'cuda' for the export"),
    (N.SHIPPED_EXPORT, "torch", "cpu", "an .npz export runs on the numpy backend only")])
def test_a_backend_that_cannot_run_is_refused(ckpt, backend, device, match):
    with pytest.raises(ParameterError, match=match):
        load_network(ckpt, device, backend)
