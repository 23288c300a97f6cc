"""Reading dense flow back from any container of :mod:`evmotion.io.flowout`, with its
windows' times and validity masks (:func:`read_flow`), and describing it
(:func:`describe_flow`, for ``evmotion info``).

Examples
--------
>>> from evmotion.io.flowout import open_flow_output
>>> with open_flow_output("flow_{:05d}.flo", (4, 5), {"method": "x"}) as out:
...     for i in range(3):
...         out.append(np.full((4, 5, 2), 10.0 * i, np.float32), i * 10_000, (i + 1) * 10_000)
>>> seq = read_flow("flow_{:05d}.flo")
>>> seq.flow.shape, seq.t0[:2].tolist()
((3, 4, 5, 2), [0, 10000])
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.io.eventflow import EVENT_FLOW_FORMAT, describe_event_flow
from evmotion.io.flowfiles import (
    FLOW_FORMAT,
    FlowSequence,
    check_flow_arrays,
    extra_specs,
    read_dsec_flow_png,
    read_dsec_gt_flow,
    read_flo,
    read_flow_h5,
    read_mvsec_gt_flow,
    window_times_ok,
)
from evmotion.io.flowout import (
    CONTAINERS,
    PER_WINDOW,
    SIDECAR_FORMAT,
    is_pattern,
    json_value,
    sidecar_path,
    window_path,
)
from evmotion.io.guard import guarded, open_h5, open_npz
from evmotion.io.h5attrs import read_attrs
from evmotion.io.h5filters import is_hdf5

__all__ = ["SCHLIEREN_GT_FORMAT", "describe_flow", "read_displacement", "read_flow",
           "read_flow_paired", "undated_flow_files"]

#: The ``schlieren_format`` attribute of the schlieren simulator's ground truth
#: (:func:`evmotion.sim.schlieren.write_schlieren`), a flow file that holds q and the
#: displacement too.
SCHLIEREN_GT_FORMAT = "evmotion-schlieren-gt"


def _read_sidecar(path: Path) -> dict | None:
    side = sidecar_path(path)
    if not side.exists():
        return None
    try:
        doc = json.loads(side.read_text())
    except (OSError, ValueError) as exc:
        raise FormatError(side, f"cannot read the flow sidecar: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != SIDECAR_FORMAT:
        raise FormatError(side, f"not an evmotion flow sidecar (format "
                          f"{doc.get('format') if isinstance(doc, dict) else None!r})")
    for key in ("t0_us", "t1_us"):
        if not isinstance(doc.get(key), int):
            raise FormatError(side, f"field '{key}' is {doc.get(key)!r}, expected an integer "
                              "in µs")
    if doc["t1_us"] < doc["t0_us"]:
        raise FormatError(side, f"t1_us {doc['t1_us']} is before t0_us {doc['t0_us']}")
    return doc


def _read_one_window(path: Path, t0_us: int | None, t1_us: int | None) -> FlowSequence:
    kind = CONTAINERS[path.suffix.lower()]
    if not path.is_file():
        raise FormatError(path, "no such file")
    side = _read_sidecar(path)
    if side is not None:
        if t0_us is not None or t1_us is not None:
            raise ParameterError(f"{path}: carries its window's times in "
                                 f"{sidecar_path(path).name}; give no interval")
        t0_us, t1_us = side["t0_us"], side["t1_us"]
    elif t0_us is None or t1_us is None or t1_us <= t0_us:
        raise ParameterError(f"{path}: no {sidecar_path(path).name} beside it, so no time "
                             "interval; give t0_us and t1_us (t1_us > t0_us)")
    disp, valid = read_displacement(path)
    if not window_times_ok(t0_us, t1_us, valid):
        raise FormatError(path, f"its window [{t0_us}, {t1_us}) us has no duration but "
                          "valid pixels")
    # a window of no duration (events all at one time, skipped) holds no flow at all
    flow = (disp / np.float32((t1_us - t0_us) * 1e-6) if t1_us > t0_us
            else np.full_like(disp, np.nan))
    attrs = dict(side.get("attrs", {})) if side else {}
    attrs.update(container="middlebury-flo" if kind == "flo" else "dsec-png",
                 units="px/s", stored_units="px")
    return FlowSequence(flow=flow[None], t0=np.array([t0_us], np.int64),
                        t1=np.array([t1_us], np.int64), valid=valid[None], attrs=attrs)


def read_displacement(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """One ``.flo`` or DSEC ``.png`` flow file as stored, without times.

    Returns
    -------
    disp : (H, W, 2) float32
        Displacement in px over the file's window (NaN where it holds none).
    valid : (H, W) bool
        The pixels that hold a displacement.

    Examples
    --------
    >>> from evmotion.io.flowfiles import write_flo
    >>> write_flo("one.flo", np.full((4, 5, 2), 1.5, np.float32))
    >>> disp, valid = read_displacement("one.flo")
    >>> disp.shape, float(disp[0, 0, 0]), bool(valid.all())
    ((4, 5, 2), 1.5, True)
    """
    path = Path(path)
    if path.suffix.lower() == ".flo":
        disp = read_flo(path)
        return disp, np.isfinite(disp).all(axis=2)
    return read_dsec_flow_png(path)


def undated_flow_files(path: str | os.PathLike) -> list[Path]:
    """The flow files at ``path`` that carry no window times (another tool's output).

    Parameters
    ----------
    path : path-like
        A ``.flo`` or DSEC-style ``.png`` (16-bit RGB) file without its JSON sidecar, or a
        folder of such files (one kind, none with a sidecar).

    Returns
    -------
    list of Path
        The files, in the order of the numbers in their names; empty for anything else
        (a dated flow output, a folder of frames, a recording).

    Examples
    --------
    >>> import os
    >>> from evmotion.io.flowfiles import write_flo
    >>> os.makedirs("pred", exist_ok=True)
    >>> for i in (2, 10):
    ...     write_flo(f"pred/{i}.flo", np.zeros((4, 5, 2), np.float32))
    >>> [f.name for f in undated_flow_files("pred")]
    ['2.flo', '10.flo']
    """
    p = Path(path)
    if p.is_dir():
        if is_dsec_flow_folder(p):
            return []
        try:
            files = _folder_files(p)
        except FormatError:
            return []
    elif p.is_file() and p.suffix.lower() in (".flo", ".png") and not is_pattern(p):
        files = [p]
    else:
        return []
    if any(sidecar_path(f).exists() for f in files):
        return []
    if files[0].suffix.lower() == ".png" and not _is_dsec_png(files[0]):
        return []  # images (a frames folder), not flow
    return files


def read_flow_paired(path: str | os.PathLike, reference: FlowSequence,
                     reference_names: list[str] | None = None) -> tuple[FlowSequence, str]:
    """Per-window ``.flo`` / ``.png`` files that carry no times of their own (other tools'
    output: RAFT, E-RAFT), given the windows of a ``reference`` (ground truth).

    Parameters
    ----------
    path : path-like
        A folder of ``.flo`` or ``.png`` files (one kind), or a pattern such as
        ``pred_{:06d}.png``.
    reference : FlowSequence
        Its windows' times go to the files: by file name where ``reference_names`` (the
        reference's own file names, e.g. a DSEC flow folder's PNGs) holds every file's
        name, else in order where there are as many files as windows.
    reference_names : list of str, optional
        One name per reference window.

    Returns
    -------
    (FlowSequence, str)
        The flow in px/s (each file's displacement over its window's duration) with the
        windows' times, and how the files were paired, for the user to read.

    Examples
    --------
    >>> from evmotion.io.flowfiles import write_flo
    >>> Path("eraft_pred").mkdir()
    >>> for i in range(2):  # displacements in px, as RAFT / E-RAFT write them
    ...     write_flo(f"eraft_pred/{i:06d}.flo", np.full((4, 5, 2), i + 1.0, np.float32))
    >>> ref = FlowSequence(np.zeros((2, 4, 5, 2), np.float32), np.array([0, 100_000]),
    ...                    np.array([100_000, 200_000]))  # e.g. read_dsec_gt_flow("flow/")
    >>> seq, how = read_flow_paired("eraft_pred/", ref)
    >>> seq.t0.tolist(), seq.flow[:, 0, 0, 0].tolist()
    ([0, 100000], [10.0, 20.0])
    """
    p = Path(path)
    if is_pattern(p):
        files = _pattern_files(p)
    elif p.is_dir():
        files = _folder_files(p)
    else:
        raise FormatError(p, "no such folder" if not p.exists() else
                          "expected a folder or a pattern of per-window .flo / .png files")
    if CONTAINERS.get(files[0].suffix.lower()) not in PER_WINDOW:
        raise FormatError(files[0], "not a per-window flow file (.flo or .png)")
    n_ref = len(reference.t0)
    index = {Path(n).stem: k for k, n in enumerate(reference_names or [])}
    if index and all(f.stem in index for f in files):
        at = [index[f.stem] for f in files]
        how = f"{len(files)} files paired by name with the ground truth's {n_ref} windows"
    elif len(files) == n_ref:
        at = list(range(n_ref))
        how = f"{len(files)} files paired in name order with the ground truth's windows"
    else:
        raise FormatError(p, f"{len(files)} flow files carry no times (no .json sidecars) "
                          f"and the ground truth has {n_ref} windows"
                          + (" whose file names they do not all share" if index else "")
                          + ": cannot tell which window each file is; give one sidecar per "
                          "file (t0_us, t1_us) or as many files as windows")
    seqs = [_read_one_window(f, int(reference.t0[k]), int(reference.t1[k]))
            if _read_sidecar(f) is None else _read_one_window(f, None, None)
            for f, k in zip(files, at, strict=True)]
    seq = _concatenated(seqs, p)
    seq.attrs["source"] = str(p)
    return seq, how


def _concatenated(seqs: list[FlowSequence], where: Path) -> FlowSequence:
    """One sequence of per-window files' windows, in order."""
    shapes = {s.flow.shape[1:3] for s in seqs}
    if len(shapes) != 1:
        raise FormatError(where, f"the files have different sizes: {sorted(shapes)}")
    return FlowSequence(flow=np.concatenate([s.flow for s in seqs]),
                        t0=np.concatenate([s.t0 for s in seqs]),
                        t1=np.concatenate([s.t1 for s in seqs]),
                        valid=np.concatenate([s.valid for s in seqs]),
                        attrs=dict(seqs[0].attrs))


def _folder_files(folder: Path) -> list[Path]:
    """A folder's per-window ``.flo`` or ``.png`` files (one kind), in the order of the
    numbers in their names."""
    kinds = {f.suffix.lower() for f in folder.iterdir() if f.suffix.lower() in (".flo", ".png")}
    if len(kinds) != 1:
        raise FormatError(folder, f"expected a folder of .flo or of .png flow files, found "
                          f"{'both' if kinds else 'neither'}")
    # 0.flo ... 11.flo sorted as text put 10 and 11 after 1, and paired them with the
    # ground truth's windows 2 and 3 (probe BI)
    return sorted((f for f in folder.iterdir() if f.suffix.lower() in kinds),
                  key=_natural_key)


def _is_flow_folder(folder: Path) -> bool:
    """Whether a folder holds evmotion's per-window flow files: ``.flo`` or ``.png``
    (one kind), each with its JSON sidecar."""
    try:
        files = _folder_files(folder)
    except FormatError:
        return False
    return all(_read_sidecar(f) is not None for f in files)


def _natural_key(path: Path) -> tuple:
    """A file name as its text and numbers, numbers compared as numbers.

    Examples
    --------
    >>> [p.name for p in sorted(map(Path, ["10.flo", "2.flo", "1.flo"]), key=_natural_key)]
    ['1.flo', '2.flo', '10.flo']
    """
    return tuple(int(part) if part.isdigit() else part
                 for part in re.split(r"(\d+)", path.name))


def _pattern_files(path: Path) -> list[Path]:
    files = []
    while (p := window_path(path, len(files))).exists():
        files.append(p)
    if not files:
        raise FormatError(path, f"no file of this pattern (looked for {window_path(path, 0)})")
    # a missing file in the middle would silently end the sequence there
    m = re.fullmatch(r"(.*)\{[^{}]*\}(.*)", path.name)
    if m and path.parent.is_dir():
        number = re.compile(re.escape(m.group(1)) + r"(\d+)" + re.escape(m.group(2)))
        later = sorted(int(k.group(1)) for q in path.parent.iterdir()
                       if (k := number.fullmatch(q.name)) and int(k.group(1)) > len(files))
        if later:
            raise FormatError(path, f"{window_path(path, len(files)).name} is missing but "
                              f"{window_path(path, later[0]).name} exists: a gap in the "
                              f"sequence after {len(files)} files")
    return files


def _read_npz(path: Path) -> FlowSequence:
    with open_npz(path) as z:
        names = set(z.files)
        if "format" in names and str(z["format"]) == FLOW_FORMAT:
            for key in ("flow", "t0", "t1", "valid", "units"):
                if key not in names:
                    raise FormatError(path, f"evmotion flow .npz lacks array '{key}'")
            flow, t0, t1 = z["flow"], z["t0"], z["t1"]
            valid = z["valid"].astype(bool)
            check_flow_arrays(path, flow, t0, t1, valid, z["units"])
            t0, t1, n = t0.astype(np.int64), t1.astype(np.int64), t1.shape[0]
            try:
                attrs = json.loads(str(z["attrs"])) if "attrs" in names else {}
            except ValueError as exc:
                raise FormatError(path, f"array 'attrs' is not JSON: {exc}") from None
            attrs.update(format=FLOW_FORMAT, units=str(z["units"]), container="npz")
            extras = {}
            if "extras" in names:
                try:
                    specs = json.loads(str(z["extras"]))
                except ValueError as exc:
                    raise FormatError(path, f"array 'extras' is not JSON: {exc}") from None
                for name in specs:
                    if name not in names or z[name].shape[:1] != (n,):
                        raise FormatError(path, f"extra '{name}' is missing or does not "
                                          f"hold {n} windows")
                    extras[name] = z[name]
                attrs["extras_units"] = {k: v.get("units", "") for k, v in specs.items()}
            return FlowSequence(flow=flow.astype(np.float32), t0=t0, t1=t1, valid=valid,
                                attrs=attrs, extras=extras)
        if {"timestamps", "x_flow_dist"} <= names:
            return read_mvsec_gt_flow(path)
        if {"t", "x", "y", "vx", "vy"} <= names:
            raise FormatError(path, "per-event flow (t, x, y, vx, vy per event), not dense "
                              "windows: read it with numpy.load")
    raise FormatError(path, f"not an evmotion flow .npz (arrays: {', '.join(sorted(names))})")


@guarded('flow file')
def read_flow(path: str | os.PathLike, *, t0_us: int | None = None,
              t1_us: int | None = None) -> FlowSequence:
    """Read dense flow back from any container, with its windows' times and masks.

    Parameters
    ----------
    path : path-like
        ``.h5`` (evmotion flow, BOS or simulator ground truth), ``.npz`` (evmotion flow or
        MVSEC ground truth), ``.flo``, DSEC ``.png``, a per-window pattern
        (``flow_{:05d}.flo``: the files numbered from 0, in order), or a folder of
        per-window files with their JSON sidecars (in the order of the numbers in their
        names).
    t0_us, t1_us : int, optional
        The interval of a single ``.flo`` / ``.png`` that has no JSON sidecar.

    Returns
    -------
    FlowSequence
        ``flow`` (N, H, W, 2) float32 in **px/s** whatever the container stores
        (``.flo``/``.png`` displacements are divided by their window's duration), ``t0``,
        ``t1`` (N,) µs, ``valid`` (N, H, W) bool, and ``extras`` (name -> (N, ...)
        array) the method stored beside the flow in ``.h5`` / ``.npz`` (BOS: ``q``, ``p``,
        ``window/<number>``), their units in ``attrs["extras_units"]``.

    Examples
    --------
    >>> from evmotion.io.flowout import open_flow_output
    >>> flow = np.ones((4, 5, 2), np.float32)
    >>> flow[0] = np.nan  # no flow on the first row
    >>> with open_flow_output("flow_{:05d}.flo", (4, 5), {"method": "x"}) as out:
    ...     out.append(flow, t0=0, t1=10_000)
    ...     out.append(flow, t0=10_000, t1=20_000)
    >>> seq = read_flow("flow_{:05d}.flo")
    >>> seq.t0[:2].tolist(), float(seq.valid.mean())
    ([0, 10000], 0.75)
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if is_dsec_flow_folder(p):
        return read_dsec_gt_flow(p)
    if p.is_dir():
        # evmotion's per-window files moved or copied into a folder of their own (they
        # were refused as 'not a flow file', probe BK); each carries its times
        files = _folder_files(p)
        bare = [f.name for f in files if _read_sidecar(f) is None]
        if bare:
            raise FormatError(p, f"{bare[0]} has no {bare[0]}.json sidecar with its window's "
                              "times: give the windows another way (evmotion eval --gt "
                              "pairs such files with the ground truth's windows)")
        return _concatenated([_read_one_window(f, None, None) for f in files], p)
    if suffix == ".npy":
        raise FormatError(p, "a bare .npy holds no times, units or validity mask; evmotion "
                          "writes .npz (flow, t0, t1, valid, units)")
    kind = CONTAINERS.get(suffix)
    if kind is None:
        raise FormatError(p, "not a flow file: expected .h5, .npz, .flo or .png (DSEC)")
    if is_pattern(p):
        if kind not in PER_WINDOW:
            raise ParameterError(f"{p}: a {suffix} file holds every window; no pattern")
        return _concatenated([_read_one_window(f, None, None) for f in _pattern_files(p)],
                             p)
    if kind in PER_WINDOW:
        return _read_one_window(p, t0_us, t1_us)
    if t0_us is not None or t1_us is not None:
        raise ParameterError(f"{p}: a {suffix} flow file carries its windows' times; give no "
                             "interval")
    if kind == "npz":
        if not p.is_file():
            raise FormatError(p, "no such file")
        seq = _read_npz(p)
    else:
        seq = read_flow_h5(p)
    if not len(seq):
        raise FormatError(p, "holds no flow window (a run interrupted before its first?)")
    if seq.valid is None:
        seq = FlowSequence(flow=seq.flow, t0=seq.t0, t1=seq.t1,
                           valid=np.isfinite(seq.flow).all(axis=3), attrs=seq.attrs,
                           extras=seq.extras)
    return seq


@guarded('flow file', 'describe')
def describe_flow(path: str | os.PathLike) -> dict | None:
    """What a flow output holds (``evmotion info``), or None if ``path`` is not one.

    Returns
    -------
    dict or None
        ``format``, ``container``, ``sensor_size`` (H, W), ``windows``, ``t_first_us``,
        ``t_last_us``, ``duration_s``, ``units`` (as stored), ``grid``, ``method``,
        ``valid_fraction`` (over all windows) and ``files`` for a pattern; per-event
        ``.npz`` files give ``events`` instead of windows.

    Examples
    --------
    >>> from evmotion.io.flowout import open_flow_output
    >>> with open_flow_output("flow.h5", (4, 5), {"method": "x"}) as out:
    ...     out.append(np.zeros((4, 5, 2), np.float32), t0=0, t1=10_000)
    ...     out.append(np.zeros((4, 5, 2), np.float32), t0=10_000, t1=20_000)
    >>> d = describe_flow("flow.h5")
    >>> d["windows"], d["sensor_size"], d["method"]
    (2, [4, 5], 'x')
    """
    p = Path(path)
    if is_dsec_flow_folder(p):  # DSEC's ground truth: PNGs and their timestamps
        seq = read_dsec_gt_flow(p)
        out = {"path": str(p), "format": "dsec-gt-flow", "container": "png folder"}
        out.update(_summary(seq.flow.shape[1:3], seq.t0, seq.t1, seq.valid, seq.attrs))
        out["units"] = "px (displacement over each window)"
        return out
    if p.is_dir():
        # evmotion's per-window files, or another tool's without sidecars (no times)
        undated = undated_flow_files(p)
        if not undated and not _is_flow_folder(p):
            return None
        seq = (_concatenated([_read_undated(f) for f in undated], p) if undated
               else read_flow(p))
        flo = (undated[0].suffix.lower() == ".flo" if undated
               else seq.attrs["container"] == "middlebury-flo")
        out = {"path": str(p), "format": "middlebury-flo" if flo else "dsec-flow-png",
               "container": "folder", "files": len(seq)}
        out.update(_summary(seq.flow.shape[1:3], seq.t0, seq.t1, seq.valid, seq.attrs))
        if undated:
            out["windows"] = len(seq)  # one per file, whose times are not stored
        out["units"] = "px (displacement over each window)"
        return out
    kind = CONTAINERS.get(p.suffix.lower())
    if kind is None:
        return None
    if is_pattern(p):
        if kind not in PER_WINDOW or not window_path(p, 0).exists():
            return None
    elif not p.is_file():
        return None
    if kind == "h5":
        return _describe_h5(p)
    if kind == "npz":
        return _describe_npz(p)
    if not is_pattern(p) and _read_sidecar(p) is None:
        if kind == "png" and not _is_dsec_png(p):
            return None
    dated = is_pattern(p) or _read_sidecar(p) is not None
    seq = read_flow(p) if dated else _read_undated(p)
    out = {"path": str(p), "format": "middlebury-flo" if kind == "flo" else "dsec-flow-png",
           "container": kind}
    if is_pattern(p):
        out["files"] = len(seq)
    out.update(_summary(seq.flow.shape[1:3], seq.t0, seq.t1, seq.valid, seq.attrs))
    if not dated:
        out["windows"] = 1  # one window, whose times are not stored
    out["units"] = "px (displacement over each window)"
    return out


def _read_undated(p: Path) -> FlowSequence:
    """A .flo / .png without a sidecar: no times (shown as such)."""
    disp, valid = read_displacement(p)
    return FlowSequence(flow=disp[None], t0=np.zeros(0, np.int64), t1=np.zeros(0, np.int64),
                        valid=valid[None], attrs={})


def _is_dsec_png(p: Path) -> bool:
    import png

    try:
        _, _, _, info = png.Reader(filename=str(p)).read()
    except (png.Error, OSError, ValueError):
        return False
    return info.get("bitdepth") == 16 and info.get("planes", 1) >= 3


def _summary(size, t0, t1, valid_fraction_or_mask, attrs) -> dict:
    out: dict = {"sensor_size": [int(size[0]), int(size[1])], "windows": int(len(t0))}
    if len(t0):
        out.update(t_first_us=int(t0[0]), t_last_us=int(t1[-1]),
                   duration_s=(int(t1[-1]) - int(t0[0])) * 1e-6)
    else:
        out["times"] = "none stored (no JSON sidecar)"
    vf = valid_fraction_or_mask
    if isinstance(vf, np.ndarray):
        vf = float(vf.mean()) if vf.size else None
    out["valid_fraction"] = vf
    for key in ("grid", "method", "source"):
        if key in attrs:
            out[key] = json_value(attrs[key])
    if attrs.get("extras_units"):
        out["extras"] = {k: u or "-" for k, u in attrs["extras_units"].items()}
    return out


def _describe_h5(p: Path) -> dict | None:
    if not is_hdf5(p):
        return None
    try:
        # open_h5 registers the Blosc filters of the flow and masks read below
        f = open_h5(p)
    except FormatError:
        return None
    with f:
        raw = read_attrs(p, f)
        attrs = {k: json_value(v) for k, v in raw.items()}
        fmt = attrs.get("format")
        if fmt == EVENT_FLOW_FORMAT:
            f.close()
            return describe_event_flow(p)
        if fmt != FLOW_FORMAT or "t1" not in f:
            return None
        n = int(f["t1"].shape[0])
        t0, t1 = f["t0"][:n], f["t1"][:n]
        # no masks: every pixel counts, as eval and read_flow take it ("valid_fraction:
        # None" read as unknown, probe BA)
        vf = 1.0 if n else None
        if "valid" in f and n:
            vf = float(sum(int(np.count_nonzero(f["valid"][i])) for i in range(n))
                       / (n * f["valid"].shape[1] * f["valid"].shape[2]))
        specs = extra_specs(f, p, raw)
        if specs:
            attrs["extras_units"] = {k: s.units for k, s in specs.items()}
        out = {"path": str(p), "format": FLOW_FORMAT, "container": "h5"}
        out.update(_summary(f["flow"].shape[1:3], t0, t1, vf, attrs))
        out["units"] = str(attrs.get("units", "px/s"))
        out["valid_masks"] = "valid" in f
        if attrs.get("schlieren_format") == SCHLIEREN_GT_FORMAT:
            # the simulator's ground truth holds more than its flow (probe BA: unsaid)
            out["content"] = ("the schlieren simulator's ground truth: per frame interval "
                              "the exact flow, q and displacement")
            out["datasets"] = sorted(k for k in f if k not in ("flow", "t0", "t1"))
        return out


def _describe_npz(p: Path) -> dict | None:
    try:
        z = open_npz(p)
    except FormatError:
        return None
    with z:
        names = set(z.files)
        if "meta" in names and {"t", "valid"} <= names:
            z.close()
            return describe_event_flow(p)
        if {"t", "x", "y", "vx", "vy"} <= names:
            t = z["t"]
            out = {"path": str(p), "format": "per-event-flow", "container": "npz",
                   "events": int(t.size), "units": "px/s",
                   "fields": sorted(names)}
            if t.size:
                out.update(t_first_us=int(t[0]), t_last_us=int(t[-1]),
                           duration_s=(int(t[-1]) - int(t[0])) * 1e-6)
            if "valid" in names:
                out["valid_fraction"] = float(z["valid"].mean()) if t.size else None
            return out
        mvsec_gt = {"timestamps", "x_flow_dist", "y_flow_dist"} <= names
        if not mvsec_gt and ("format" not in names or str(z["format"]) != FLOW_FORMAT):
            return None
    if mvsec_gt:  # a ground truth's flow: described as such, not as events
        seq = read_mvsec_gt_flow(p)
        out = {"path": str(p), "format": "mvsec-gt-flow", "container": "npz"}
        out.update(_summary(seq.flow.shape[1:3], seq.t0, seq.t1, seq.valid, seq.attrs))
        out["units"] = "px (displacement between consecutive timestamps)"
        return out
    seq = _read_npz(p)
    out = {"path": str(p), "format": FLOW_FORMAT, "container": "npz"}
    out.update(_summary(seq.flow.shape[1:3], seq.t0, seq.t1, seq.valid, seq.attrs))
    out["units"] = seq.attrs["units"]
    out["valid_masks"] = True
    return out


def is_dsec_flow_folder(p: Path) -> bool:
    """A DSEC optical-flow folder: ``forward/`` PNGs with ``forward_timestamps.txt``, or
    the sequence folder holding ``flow/``."""
    if not p.is_dir():
        return False
    where = [p, p / "flow"] + ([p.parent] if p.name == "forward" else [])
    return any((d / "forward_timestamps.txt").is_file() for d in where)
