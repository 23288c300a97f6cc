"""Unsupervised training of EV-FlowNet with multicm's objective (thesis §4.3.7).

Adam (lr 1e-3), learning rate times 0.8 after every epoch, loss :func:`multiscale_loss`
at the four decoder scales. Each epoch draws ``sim_windows`` fresh simulated windows and
uses every recording window once, each randomly cropped to ``crop`` (a multiple of 16;
inference runs on the whole sensor), in an order drawn from ``(seed, epoch)``.

Deterministic: the weights' initialization is seeded (``torch.manual_seed``), torch runs
deterministic algorithms with a fixed thread count, and an epoch's data depends on
``(seed, epoch)`` only. The state (weights, optimizer, scheduler, history) is written
atomically after every epoch, so ``resume=True`` continues after the last finished
epoch and ends with the same weights as an uninterrupted run.

Outputs in ``out_dir``: ``last.pt`` (resumable), ``model.pt`` (weights only, for
inference) and its numpy export ``model.npz`` (inference without torch), ``best.pt`` and
``best.npz`` (the same for the epoch of the lowest validation loss), ``steps.csv``
(loss per step), ``epochs.csv`` (training and validation scores per epoch) and
``loss.png``.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import os
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from evmotion.catalog import MAX_EPOCHS, MAX_LR, MAX_TRAIN_SEED, VAL_SEED_BASE
from evmotion.errors import EvmotionWarning, ParameterError, PoorFitWarning
from evmotion.methods.dnn import MAX_CROP_SIDE, MAX_WIDTH, MIN_CROP_SIDE
from evmotion.methods.dnn.data import (
    TrainWindow,
    crop_window,
    recording_windows,
    sim_window,
    transpose_window,
)
from evmotion.methods.dnn.folder import check_training_folder
from evmotion.methods.dnn.loss import WindowLoss, multiscale_loss, window_problem
from evmotion.methods.dnn.model import (
    check_device,
    damaged_archive,
    load_model,
    save_atomically,
    save_model,
)
from evmotion.methods.dnn.network import NORMS, EVFlowNet, upsample_flows
from evmotion.methods.dnn.voxel import (
    N_BINS,
    PAD_MULTIPLE,
    normalize_voxel,
    pad_to_multiple,
    voxel_grid,
)
from evmotion.utils import atomic_path, atomic_write_text, is_finite_number, progress

__all__ = ["TrainConfig", "batch_input", "best_epoch", "evaluate_windows", "train"]

#: Weight initializations of the convolutions (the flow heads keep theirs, near zero):
#: ``default`` torch's (uniform, biases uniform too), ``kaiming`` He-normal weights for ReLU
#: and zero biases (see :func:`_kaiming_init`).
INITS = ("default", "kaiming")


@dataclass
class TrainConfig:
    """Training settings (see ``evmotion train --help``)."""

    width: float = 0.125
    epochs: int = 10
    batch_size: int = 8
    lr: float = 1e-3
    lr_decay: float = 0.8
    sim_windows: int = 64
    recordings: list[str] = field(default_factory=list)
    val_sim: int = 4
    val_recordings: list[str] = field(default_factory=list)
    window_events: int = 40_000
    crop: tuple[int, int] = (176, 240)
    sim_sensor: tuple[int, int] = (260, 346)
    sim_duration_s: float = 0.05
    transpose: bool = False
    init: str = "default"
    norm: str = "batch"
    symmetric: bool = True
    objective: str = "gradient_magnitude"
    lam: float = 0.0025
    seed: int = 0
    threads: int = 1
    device: str = "cpu"
    max_steps_per_epoch: int | None = None
    init_weights: str | None = None
    read_format: str | None = None
    sensor_size: tuple[int, int] | None = None

    def check(self) -> None:
        counts = {"epochs": 1, "batch_size": 1, "sim_windows": 0, "val_sim": 0,
                  "window_events": 100, "threads": 1, "seed": 0}
        if self.max_steps_per_epoch is not None:
            counts["max_steps_per_epoch"] = 1
        for name, least in counts.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < least:
                raise ParameterError(f"{name} must be an integer >= {least}, got {v!r}")
        for name, v, positive in (("lr", self.lr, True), ("lam", self.lam, False)):
            number = is_finite_number(v)
            if not number or v < 0 or (positive and v == 0):
                raise ParameterError(f"{name} must be a finite number "
                                     f"{'> 0' if positive else '>= 0'}, got {v!r}")
        if self.lr > MAX_LR:
            # Adam steps each weight by about lr: beyond 1 the weights run off (1e30 trained
            # to weights of 1e30, finite, and a checkpoint that answers nothing)
            raise ParameterError(f"lr must be at most {MAX_LR:g}, got {self.lr!r}")
        if self.epochs > MAX_EPOCHS:
            # epoch 100's windows would be the next seed's epoch 0 (probe OPT: 1e30 epochs
            # were taken, an ETA of 1e30 epochs)
            raise ParameterError(f"epochs must be at most {MAX_EPOCHS} (the simulated windows' "
                                 f"seeds are seed * 1e6 + epoch * 1e4 + i), got "
                                 f"{self.epochs!r}")
        if self.seed >= MAX_TRAIN_SEED:
            # the training windows' seeds would reach the validation windows'
            raise ParameterError(f"seed must be below {MAX_TRAIN_SEED} (from {MAX_TRAIN_SEED} the "
                                 "training scenes are the validation scenes), got "
                                 f"{self.seed!r}")
        if isinstance(self.recordings, (str, Path)) or isinstance(self.val_recordings,
                                                                   (str, Path)):
            raise ParameterError("recordings and val_recordings are lists of paths, got "
                                 "a single path")
        if len(self.crop) != 2:
            raise ParameterError(f"crop must be (height, width), got {self.crop!r}")
        if self.sim_windows == 0 and not self.recordings:
            raise ParameterError("no training data: give recordings or sim_windows > 0 "
                                 "(--sim-windows)")
        if any(not MIN_CROP_SIDE <= c <= MAX_CROP_SIDE or c % PAD_MULTIPLE for c in self.crop):
            raise ParameterError(f"crop sides must be multiples of {PAD_MULTIPLE} from "
                                 f"{MIN_CROP_SIDE} to {MAX_CROP_SIDE} px, got "
                                 f"{tuple(self.crop)}")
        if not 0 < self.lr_decay <= 1 or not 0 < self.width <= MAX_WIDTH or self.threads < 1:
            raise ParameterError(f"need 0 < lr_decay <= 1, 0 < width <= {MAX_WIDTH:g}, "
                                 f"threads >= 1; got {self.lr_decay}, {self.width}, "
                                 f"{self.threads}")
        if not 0 < self.sim_duration_s <= 10:
            raise ParameterError(f"sim_duration_s must be in (0, 10] s, got {self.sim_duration_s}")
        if self.norm not in NORMS:
            raise ParameterError(f"norm must be one of {', '.join(NORMS)}, got {self.norm!r}")
        if self.init not in INITS:
            raise ParameterError(f"init must be one of {', '.join(INITS)}, got {self.init!r}")
        if self.sim_windows >= 10_000:
            raise ParameterError(f"sim_windows must be < 10000, got {self.sim_windows}")
        check_device(self.device)


def batch_input(windows: Sequence[TrainWindow], shape: tuple[int, int]) -> torch.Tensor:
    """The network's input for a training batch: the windows' normalized voxel grids,
    zero-padded to the common ``shape`` (B, 5, H, W).

    Examples
    --------
    >>> w = sim_window(3, sensor_size=(30, 40), window_events=1000)
    >>> tuple(batch_input([w, w], (32, 48)).shape)
    (2, 5, 32, 48)
    """
    out = np.zeros((len(windows), N_BINS, *shape), np.float32)
    for i, w in enumerate(windows):
        v = normalize_voxel(voxel_grid(w.events))
        out[i, :, :v.shape[1], :v.shape[2]] = v
    return torch.from_numpy(out)


def _epoch_items(cfg: TrainConfig, epoch: int, rec: list[TrainWindow]) -> list:
    """The epoch's work list, ``("sim", seed)`` or ``("rec", index)``, shuffled."""
    items = [("sim", cfg.seed * 1_000_000 + epoch * 10_000 + i) for i in range(cfg.sim_windows)]
    items += [("rec", j) for j in range(len(rec))]
    order = np.random.default_rng([cfg.seed, epoch, 1]).permutation(len(items))
    return [items[k] for k in order]


def _materialize(cfg, item, rec, epoch, k) -> TrainWindow | None:
    kind, val = item
    rng = np.random.default_rng([cfg.seed, epoch, k, 2])
    # half the windows mirrored about the diagonal (cfg.transpose): see transpose_window
    flip = bool(cfg.transpose and rng.random() < 0.5)
    if kind == "sim":
        # simulated at the crop size directly (half the simulation time of a crop of a
        # 346x260 scene), with the event density of a window_events window at sim_sensor
        area = cfg.crop[0] * cfg.crop[1] / (cfg.sim_sensor[0] * cfg.sim_sensor[1])
        size = tuple(cfg.crop)[::-1] if flip else tuple(cfg.crop)
        win = sim_window(val, sensor_size=size,
                         window_events=max(1000, round(cfg.window_events * area)),
                         duration_s=cfg.sim_duration_s)
    else:
        win = rec[val]
    if flip:
        win = transpose_window(win)
    return crop_window(win, tuple(cfg.crop), rng, min_events=_min_events(cfg))


def evaluate_windows(net: EVFlowNet, windows: Sequence[TrainWindow], *,
                     objective: str = "gradient_magnitude", lam: float = 0.0025) -> list[dict]:
    """Loss, FWL and (with ground truth) AEE of the network on whole windows.

    FWL is ``var(IWE(t_mid)) / var(IWE(zero flow))``; AEE is the mean endpoint error of
    the displacement over the window on the pixels that have events.
    """
    from evmotion.core.tileflow import iwe_forward

    rows = []
    net.eval()
    for w in windows:
        ev = w.events
        h, wd = ev.sensor_size
        prob = window_problem(ev, objective=objective, lam=lam)
        vox = torch.from_numpy(pad_to_multiple(normalize_voxel(voxel_grid(ev)))[None])
        vox = vox.to(next(net.parameters()).device)
        with torch.no_grad():
            flow = net(vox)[-1][0, :, :h, :wd].permute(1, 2, 0).double().cpu().numpy()
        if not np.isfinite(flow).all():
            raise ParameterError(f"the network's flow on {w.name} is not finite: its weights "
                                 "diverged (train again with a lower --lr)")
        val, _ = prob.value_grad(flow.ravel())
        _, _, iwes = prob.focus_grad(flow)
        ident = iwe_forward(prob.x, prob.y, np.zeros((prob.x.size, 2)), np.zeros(prob.x.size),
                            (h, wd))
        row = {"window": w.name, "loss": float(val),
               "FWL": float(np.var(iwes[1]) / max(np.var(ident), 1e-300))}
        if w.gt is not None:
            mask = ident > 0
            e = np.linalg.norm(flow - w.gt, axis=-1)
            ok = mask & np.isfinite(e)
            row["AEE_px"] = float(e[ok].mean())
            row["AEE_zero_px"] = float(np.linalg.norm(w.gt, axis=-1)[ok].mean())
        rows.append(row)
    return rows


def _write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        return
    keys = list(dict.fromkeys(k for r in rows for k in r))
    buf = io.StringIO()
    wr = csv.DictWriter(buf, fieldnames=keys)
    wr.writeheader()
    wr.writerows(rows)
    atomic_write_text(path, buf.getvalue())


def _plot(path: Path, steps: list[dict], epochs: list[dict]) -> None:
    """Write the figure of :func:`_loss_figure` as ``path`` (PNG, atomically)."""
    import matplotlib.pyplot as plt

    fig = _loss_figure(steps, epochs)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)


def _loss_figure(steps: list[dict], epochs: list[dict]):
    """The figure of ``loss.png`` (matplotlib): the training loss, and below it what validation measured, each on an
    axis of its own (probe DA: the validation loss, of the finest scale, shared the
    training loss' axis, a sum over 4 scales, and the AEE against the zero flow's, which
    the "no better than the zero flow" warning is about, was not drawn). The x axis counts
    the steps done: a step's row in ``steps.csv`` (index ``step``) is drawn at ``step +
    1``, where an epoch's row (``step``: the steps done by its end) puts the epoch."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    panels = [_val_panel(epochs, k) for k in ("val_loss", "val_AEE_px")]
    panels = [p for p in panels if p]
    fig, axes = plt.subplots(1 + len(panels), 1, sharex=True, squeeze=False,
                             figsize=(7, 3 + 2 * len(panels)))
    ax = axes[0, 0]
    if steps:
        ax.plot([r["step"] + 1 for r in steps], [r["loss"] for r in steps], lw=0.6,
                alpha=0.6, label="per step")
    if epochs:
        ax.plot([r["step"] for r in epochs], [r["train_loss"] for r in epochs], "o-",
                label="epoch mean")
    ax.set_ylabel("training loss\n(1/f + λ TV, sum of 4 scales)", fontsize=9)
    ax.set_title(f"evmotion train: {len(epochs)} epoch{'s' * (len(epochs) != 1)}, "
                 f"{steps[-1]['step'] + 1 if steps else 0} steps")
    for k, (label, series) in enumerate(panels, start=1):
        axk = axes[k, 0]
        for name, ys, style in series:
            axk.plot([r["step"] for r in epochs], ys, style, label=name)
        axk.set_ylabel(label, fontsize=9)
    for a in axes[:, 0]:
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
        a.xaxis.set_major_locator(MaxNLocator(integer=True))
        a.ticklabel_format(axis="y", useOffset=False)
    axes[-1, 0].set_xlabel("steps done")
    fig.tight_layout()
    return fig


def _val_panel(epochs: list[dict], key: str) -> tuple[str, list] | None:
    """(y label, [(legend, values, style)]) of one validation panel of ``loss.png``, or
    None where no epoch measured ``key``."""
    if not epochs or key not in epochs[0]:
        return None
    if key == "val_loss":
        series = [("validation loss (finest scale, whole frames)",
                   [r["val_loss"] for r in epochs], "s-")]
        return "validation loss", series
    series = [("network", [r["val_AEE_px"] for r in epochs], "s-"),
              ("zero flow", [r.get("val_AEE_zero_px", np.nan) for r in epochs], "k--")]
    return "validation AEE [px]", series


def _kaiming_init(net: EVFlowNet) -> None:
    """He-normal weights (fan-in, ReLU gain) and zero biases for every convolution except
    the flow heads.

    Why: with torch's default initialization a quarter of the deepest encoder and
    coarsest decoder channels are inactive (ReLU output 0) on every training pixel from the
    start (13-17 of 64 and 7-12 of 32 on 4 simulated windows, 3 seeds), and the first
    training steps at lr 1e-3 silence most of the rest (the shipped network: 26 of the 32
    coarsest decoder channels); the surviving features encoded one flow component only
    (vertical gain 0.05). He-normal with zero biases leaves 0-1 channels inactive.
    """
    heads = {id(h) for h in net.heads}
    for m in net.modules():
        if isinstance(m, torch.nn.Conv2d) and id(m) not in heads:
            torch.nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
            torch.nn.init.zeros_(m.bias)


def _diverged(what: str, epoch: int, step: int, opt, out: Path, created: bool) -> None:
    """Stop a diverged training: the checkpoints of the epochs before stay usable; a
    folder this run made and left empty goes (probe BG: an empty folder, and advice to
    resume from an epoch that had never been)."""
    last = out / "last.pt"
    if created and out.is_dir() and not any(out.iterdir()):
        out.rmdir()
    again = (", or --resume from the last good epoch (its last.pt)" if last.is_file()
             else "; nothing was written")
    raise ParameterError(f"training diverged: {what} at epoch {epoch}, step {step} (lr "
                         f"{opt.param_groups[0]['lr']:g}); train again with a lower --lr"
                         f"{again}")


def _epoch_line(row: dict) -> str:
    return " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                    for k, v in row.items())


def _min_events(cfg: TrainConfig) -> int:
    """Events a training crop must keep to be used."""
    return min(1000, cfg.window_events // 10)


def _seed_all(cfg: TrainConfig) -> None:
    if torch.device(cfg.device).type == "cuda":
        # cuBLAS is deterministic only with a fixed workspace, read when it starts
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    torch.manual_seed(cfg.seed)
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(cfg.threads)


def best_epoch(epochs_log: Sequence[dict]) -> int | None:
    """The epoch with the lowest validation loss (the first of equals), None without
    validation.

    Examples
    --------
    >>> best_epoch([{"epoch": 0, "val_loss": 0.9}, {"epoch": 1, "val_loss": 0.8},
    ...             {"epoch": 2, "val_loss": 0.85}])
    1
    """
    scored = [r for r in epochs_log if np.isfinite(r.get("val_loss", np.nan))]
    return min(scored, key=lambda r: r["val_loss"])["epoch"] if scored else None


def _write_outputs(out: Path, net, epoch: int, cfg: TrainConfig, steps_log: list,
                   epochs_log: list) -> None:
    """model.pt, its numpy export model.npz (the network without torch: a one-window
    command on it saves torch's 2 s import), best.pt / best.npz when this epoch has the
    lowest validation loss so far (a later epoch can overfit, and only the last weights
    were kept, probe BG), the CSV logs and the loss curve of the training so far."""
    from evmotion.methods.dnn.network import InferenceNet
    from evmotion.methods.dnn.numpynet import save_export

    names = ["model"] + (["best"] if best_epoch(epochs_log) == epoch else [])
    for name in names:
        save_model(out / f"{name}.pt", net, epoch=epoch, config=asdict(cfg))
        save_export(out / f"{name}.npz", InferenceNet(net))
    _write_csv(out / "steps.csv", steps_log)
    _write_csv(out / "epochs.csv", epochs_log)
    _plot(out / "loss.png", steps_log, epochs_log)


def _setting(key: str, value):
    """A setting as a resumed run compares it: recordings by the files they name (a path
    spelled another way is the same file), tuples as lists."""
    if key in ("recordings", "val_recordings") and value is not None:
        return [str(Path(v).resolve()) for v in value]
    return list(value) if isinstance(value, tuple) else value


def _file_id(path) -> tuple:
    """What tells a recording apart from another at the same path: its resolved path,
    size and content's SHA-1. (Its modification time had refused a resume after a
    ``touch`` or a copy without ``-p`` of the same bytes, probe BG.)"""
    import hashlib

    p = Path(path).resolve()
    try:
        with open(p, "rb") as fh:
            digest = hashlib.file_digest(fh, "sha1").hexdigest()
        size = p.stat().st_size
    except OSError:
        return (str(p), None, None)
    return (str(p), size, digest)


def train(cfg: TrainConfig, out_dir: str | Path, *, resume: bool = False,
          show_progress: bool = False, log: Callable[[str], None] | None = None) -> dict:
    """Train (or resume training) and return the summary of the last epoch (its row of
    ``epochs.csv``) with ``best_epoch`` (:func:`best_epoch`).

    Parameters
    ----------
    cfg : TrainConfig
    out_dir : path
        Folder for checkpoints and logs (created once the data has loaded); one holding a
        training (``last.pt``) is refused unless ``resume``.
    resume : bool
        Continue from ``out_dir/last.pt`` (its configuration must equal ``cfg`` except
        ``epochs``).
    show_progress : bool
        A progress bar with the loss and ETA on stderr.
    log : callable, optional
        Receives one line per epoch.
    """
    cfg.check()
    out = Path(out_dir)
    last = out / "last.pt"
    check_training_folder(out, resume)
    _seed_all(cfg)
    device = torch.device(check_device(cfg.device))
    net = EVFlowNet(width=cfg.width, norm=cfg.norm, symmetric=cfg.symmetric)
    if cfg.init == "kaiming":
        _kaiming_init(net)
    net = net.to(device)
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=cfg.lr_decay)
    steps_log: list[dict] = []
    epochs_log: list[dict] = []
    start = 0
    # (once: hashing a recording reads it whole)
    file_ids = [_file_id(p) for p in cfg.recordings]
    if resume:
        if not last.is_file():
            raise ParameterError(f"--resume: no checkpoint {last}")
        damaged = damaged_archive(last)
        if damaged:
            raise ParameterError(f"--resume: {last} is damaged ({damaged}); delete it to "
                                 "train from the start, or choose another --out")
        try:
            blob = torch.load(last, map_location=device, weights_only=False)
            saved = dict(blob["config"])
            state = [blob[k] for k in ("model", "optimizer", "scheduler", "steps", "epochs",
                                       "epoch")]
        except Exception as exc:  # torch.load raises many types for a damaged file
            raise ParameterError(f"--resume: {last} is not a readable training checkpoint "
                                 f"({type(exc).__name__}); delete it to train from the "
                                 "start, or choose another --out") from None
        mine = asdict(cfg)
        diff = [k for k in mine if k != "epochs"
                and _setting(k, saved.get(k)) != _setting(k, mine[k])]
        if diff:
            raise ParameterError(f"--resume: {last} was trained with other settings: "
                                 + "; ".join(f"{k} {saved.get(k)!r} there, {mine[k]!r} now"
                                             for k in diff))
        changed = [p for p, was, now in zip(cfg.recordings, blob.get("recording_files", []),
                                            file_ids, strict=False) if now != tuple(was)]
        if changed:
            raise ParameterError(f"--resume: {', '.join(map(str, changed))} changed since "
                                 f"{last} began (another file, or rewritten): the resumed "
                                 "run would not be the one interrupted")
        net.load_state_dict(state[0])
        opt.load_state_dict(state[1])
        sched.load_state_dict(state[2])
        steps_log, epochs_log = state[3], state[4]
        start = int(state[5]) + 1
        # an interruption between last.pt and the files after it left those a step behind;
        # they are those of the checkpoint's run (a resume with fewer --epochs, nothing to
        # do, had rewritten model.pt's epochs, probe CK)
        _write_outputs(out, net, start - 1,
                       dataclasses.replace(cfg, epochs=int(saved.get("epochs", cfg.epochs))),
                       steps_log, epochs_log)
    elif cfg.init_weights:
        # fine-tuning: start from a checkpoint's weights (same network), fresh optimizer
        start_net = load_model(cfg.init_weights, str(device))
        theirs = (start_net.width, start_net.norm, start_net.symmetric)
        if theirs != (net.width, net.norm, net.symmetric):
            raise ParameterError(
                f"--init-weights {cfg.init_weights}: its network (width {theirs[0]}, norm "
                f"{theirs[1]}, symmetric {theirs[2]}) differs from this training's (width "
                f"{net.width}, norm {net.norm}, symmetric {net.symmetric})")
        if not all(bool(torch.isfinite(p).all()) for p in start_net.parameters()):
            # (it trained one step on a NaN loss and blamed the learning rate, probe BG)
            raise ParameterError(f"--init-weights {cfg.init_weights}: its weights are not "
                                 "all finite (its training diverged): start from another "
                                 "checkpoint, or without --init-weights")
        net.load_state_dict(start_net.state_dict())
    reading = {"format": cfg.read_format, "sensor_size": cfg.sensor_size}
    rec = recording_windows(cfg.recordings, cfg.window_events, **reading) \
        if cfg.recordings else []
    if cfg.recordings and not rec and cfg.sim_windows == 0:
        raise ParameterError(f"no training window: none of the {len(cfg.recordings)} "
                             f"recording(s) holds a window of --window-events "
                             f"{cfg.window_events} (at least 1000 events, and half of it); "
                             "nothing was written")
    # (simulated before the first step with no word: minutes for a large --val-sim,
    # probe BG)
    val = [sim_window(VAL_SEED_BASE + i, sensor_size=cfg.sim_sensor,
                      window_events=cfg.window_events)
           for i in progress(range(cfg.val_sim), desc="validation windows", unit="win",
                             disable=not show_progress or cfg.val_sim < 2)]
    if cfg.val_recordings:
        trained = {Path(p).resolve() for p in cfg.recordings}
        shared = [str(p) for p in cfg.val_recordings if Path(p).resolve() in trained]
        if shared:
            # (its score was reported as held out, probe BG)
            warnings.warn(EvmotionWarning(
                f"--val {', '.join(shared)}: also trained on, so val_rec_FWL does not "
                "measure held-out data"), stacklevel=2)
        val += recording_windows(cfg.val_recordings, cfg.window_events,
                                 what="validation recording", **reading)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)  # once the data is known to load
    n_items = cfg.sim_windows + len(rec)
    per_epoch = -(-n_items // cfg.batch_size)
    if cfg.max_steps_per_epoch:
        per_epoch = min(per_epoch, cfg.max_steps_per_epoch)
    shape = tuple(int(c) for c in cfg.crop)
    bar = None
    if show_progress:
        from tqdm.auto import tqdm

        # smoothing 0: the rate over the whole run, validation between epochs included
        # (the ETA counted the steps' rate alone, probe BG)
        bar = tqdm(total=cfg.epochs * per_epoch, initial=start * per_epoch, desc="train",
                   unit="step", dynamic_ncols=True, smoothing=0)
    summary: dict = dict(epochs_log[-1]) if epochs_log else {}
    if start >= cfg.epochs and log is not None:
        log(f"already trained {start} of {cfg.epochs} epochs: nothing to do (the last epoch "
            "below)")
        log(_epoch_line(summary))
    # the steps taken: an epoch whose crops keep too few events takes fewer than planned
    done = len(steps_log)
    for epoch in range(start, cfg.epochs):
        t_epoch = time.perf_counter()
        net.train()
        items = _epoch_items(cfg, epoch, rec)
        losses, t_loss = [], 0.0
        k = dropped = 0
        for step in range(per_epoch):
            batch = []
            while len(batch) < cfg.batch_size and k < len(items):
                w = _materialize(cfg, items[k], rec, epoch, k)
                k += 1
                if w is not None:
                    batch.append(w)
                else:
                    dropped += 1
            if not batch:
                break
            probs = [WindowLoss(window_problem(w.events, objective=cfg.objective,
                                               lam=cfg.lam), w.events.sensor_size)
                     for w in batch]
            vox = batch_input(batch, shape).to(device)
            opt.zero_grad()
            flows = upsample_flows(net(vox), shape)
            tl = time.perf_counter()
            loss = multiscale_loss(flows, probs)
            t_loss += time.perf_counter() - tl
            if not torch.isfinite(loss):
                # stop before the step: the checkpoints written so far stay usable
                _diverged(f"the loss is {float(loss.detach())}", epoch, step, opt, out,
                          created)
            loss.backward()
            opt.step()
            if not all(bool(torch.isfinite(p).all()) for p in net.parameters()):
                _diverged("a weight is not finite after the step", epoch, step, opt, out,
                          created)
            losses.append(float(loss.detach()))
            steps_log.append({"epoch": epoch, "step": done, "loss": losses[-1],
                              "lr": opt.param_groups[0]["lr"]})
            done += 1
            if bar is not None:
                bar.set_postfix(epoch=epoch, loss=f"{losses[-1]:.4f}")
                bar.update(1)
        if not steps_log:
            if created:
                out.rmdir()
            raise ParameterError(
                f"no training window kept {_min_events(cfg)} events in a {shape[0]}x"
                f"{shape[1]} crop in epoch {epoch}: the recordings are too short or sparse "
                "for --window-events, or --crop is too small; nothing was written")
        lr = opt.param_groups[0]["lr"]  # this epoch's, before the decay for the next
        with warnings.catch_warnings():
            # an epoch without a step still decays the rate (the schedule is per epoch)
            warnings.filterwarnings("ignore", "Detected call of `lr_scheduler.step",
                                    UserWarning)
            sched.step()
        if not losses:
            warnings.warn(EvmotionWarning(
                f"epoch {epoch}: no training window kept enough events in its "
                f"{shape[0]}x{shape[1]} crop; nothing was trained (a larger --crop or "
                "--window-events)"), stacklevel=2)
        if bar is not None and len(losses) < per_epoch:
            bar.total -= per_epoch - len(losses)  # the bar ends full, at the steps taken
            bar.refresh()
        row = {"epoch": epoch, "step": done, "dropped_crops": dropped, "train_loss":
               float(np.mean(losses)) if losses else float("nan"),
               "lr": lr, "seconds": time.perf_counter() - t_epoch,
               "loss_forward_seconds": t_loss}
        if val:
            scores = evaluate_windows(net, val, objective=cfg.objective, lam=cfg.lam)
            row["val_loss"] = float(np.mean([s["loss"] for s in scores]))
            row["val_FWL"] = float(np.mean([s["FWL"] for s in scores]))
            if len(scores) > cfg.val_sim:  # the user's --val recordings, on their own
                row["val_rec_FWL"] = float(np.mean([s["FWL"] for s in scores[cfg.val_sim:]]))
            aee = [s["AEE_px"] for s in scores if "AEE_px" in s]
            if aee:
                row["val_AEE_px"] = float(np.mean(aee))
                row["val_AEE_zero_px"] = float(np.mean([s["AEE_zero_px"] for s in scores
                                                        if "AEE_zero_px" in s]))
        epochs_log.append(row)
        state = {"model": net.state_dict(), "optimizer": opt.state_dict(),
                 "scheduler": sched.state_dict(), "epoch": epoch, "config": asdict(cfg),
                 "steps": steps_log, "epochs": epochs_log,
                 "recording_files": file_ids}
        save_atomically(state, last)
        _write_outputs(out, net, epoch, cfg, steps_log, epochs_log)
        summary = row
        if log is not None:
            log(_epoch_line(row))
    if bar is not None:
        bar.close()
    _warn_no_better_than_zero(summary)
    return {**summary, "best_epoch": best_epoch(epochs_log)}


def _warn_no_better_than_zero(row: dict) -> None:
    """A PoorFitWarning where the last epoch's flow on the validation windows with ground
    truth is no better than the zero flow (the run announced its best epoch without a word
    at AEE 5.12 px against the zero flow's 5.11, probe CE)."""
    aee, zero = row.get("val_AEE_px"), row.get("val_AEE_zero_px")
    if aee is not None and zero is not None and np.isfinite(aee) and aee >= zero:
        warnings.warn(PoorFitWarning(
            f"the network's flow on the validation windows is no better than the zero flow "
            f"(AEE {aee:.4g} px against {zero:.4g}): it has not learnt their motion; train "
            "longer (more steps or epochs) before using it"), stacklevel=3)
