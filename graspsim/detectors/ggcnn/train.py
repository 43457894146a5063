"""Training the networks of this package, one loop for both: GG-CNN (the paper's recipe: sum of
four MSE losses, Adam, lr 1e-3, batch 8, random rotation and zoom) and GR-ConvNet (its authors':
sum of four smooth-L1 losses, Adam, lr 1e-3, batch 8, quarter-turn rotations and zoom;
:mod:`graspsim.detectors.ggcnn.grconvnet`), counted in sample-steps, resumable from checkpoints,
reproducible. The network is a parameter (:data:`graspsim.detectors.ggcnn.model.NETWORKS`).

Same data, seed, options and device give the same weights: the weights are initialised from
``torch.manual_seed(seed)`` (inside :func:`torch.random.fork_rng`, so the caller's torch
generator is untouched), every batch and augmentation is drawn from
``numpy.random.default_rng([seed, batch])`` and GR-ConvNet's dropout masks from a torch
generator seeded from ``(seed, batch)`` (so a resumed run draws what an uninterrupted one
would), and deterministic algorithms run on a fixed number of threads.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time

import cv2
import numpy as np
from tqdm.auto import tqdm

from dlsr.memory import reused_heap
from dlsr.records import read_json, write_text_atomic
from dlsr.rectangles import normalize_angle, rects_to_array
from graspsim.data.samples import load_samples

from .detector import crop_input
from .grconvnet import CHANNELS, DROPOUT
from .maps import grasp_maps
from .model import (
    FILTERS,
    FORMAT,
    model_paths,
    network_of,
    require_torch,
    save_model,
    snapshot_path,
    timed_path,
)

log = logging.getLogger(__name__)

__all__ = ["prepare_samples", "augment", "train_network", "train_ggcnn", "train_grconvnet",
           "trainer", "train_from_folder"]


def prepare_samples(samples, crop: int = 300, input_size: int = 300,
                    crop_method: str = "object", inputs: str = "depth",
                    title: str = "GG-CNN"):
    """Network inputs (channels first) and positive rectangles (input pixels) of labelled
    images.

    The crop is chosen from the observation alone
    (:func:`graspsim.detectors.ggcnn.detector.crop_input`),
    as at test time. Images without positives or without any valid depth (or, for RGB-D, without
    a colour image of the depth's size) are skipped with a logged line naming them.

    Parameters
    ----------
    samples : sequence of dlsr.datasets.GraspSample
    crop, input_size : int
        Crop side (image pixels) and network input side.
    crop_method : {"object", "centre"}
    inputs : {"depth", "rgbd"}
        Depth alone, or depth then R, G, B (:func:`graspsim.detectors.ggcnn.detector.crop_input`).
    title : str
        The network's name in messages.

    Returns
    -------
    X : ndarray of shape (n, C, input_size, input_size), float32
        ``C`` 1 (depth) or 4 (RGB-D).
    rects : list of ndarray of shape (m_i, 5)
        Positives in input pixels.
    ids : list of str

    Raises
    ------
    ValueError
        When no image is left (none has positives, or none has valid depth).
    """
    X, R, ids = [], [], []
    for s in samples:
        if not s.positives:
            log.info("%s training: skipped %s (no positive rectangle)", title, s.image_id)
            continue
        if inputs == "rgbd" and getattr(s, "rgb", None) is None:
            log.info("%s training: skipped %s (no colour image)", title, s.image_id)
            continue
        try:
            x, (row0, col0, scale) = crop_input(s.depth, s.depth_valid, crop, input_size,
                                                crop_method,
                                                s.rgb if inputs == "rgbd" else None)
        except ValueError as exc:
            log.info("%s training: skipped %s (%s)", title, s.image_id, exc)
            continue
        r = rects_to_array(s.positives).copy()
        r[:, 0] = (r[:, 0] - col0) * scale
        r[:, 1] = (r[:, 1] - row0) * scale
        r[:, 3:] *= scale
        X.append(x[None] if x.ndim == 2 else x)
        R.append(r)
        ids.append(str(s.image_id))
    if not X:
        raise ValueError(f"no image to train {title} on: none of the {len(samples)} images "
                         "has both a positive rectangle and valid depth")
    return np.stack(X), R, ids


def augment(x, rects, rng, rotate=True, zoom=(1.0, 2.0), keep=None):
    """One random rotation (about the centre) and zoom of an input and its rectangles.

    Parameters
    ----------
    x : ndarray of shape (S, S) or (C, S, S), float32
    rects : ndarray of shape (m, 5)
    rng : numpy.random.Generator
    rotate : bool or "quarter"
        True: any angle (GG-CNN); ``"quarter"``: 0, 90, 180 or 270 degrees (GR-ConvNet).
    zoom : (float, float) or None
        Range of the magnification (1: none; 2 shows the central half), drawn uniformly.
    keep : (float, float) or None
        Instead of ``zoom``: range of the central fraction kept, drawn uniformly
        (GR-ConvNet's ``(0.5, 1)``; the magnification is its inverse).

    Returns
    -------
    x2 : ndarray of the shape of ``x``, float32
    rects2 : ndarray of shape (m, 5)
        Rectangles moved with the image (angles stay counter-clockwise as displayed).
    """
    S = x.shape[-1]
    if rotate == "quarter":
        angle = 90.0 * int(rng.integers(4))
    elif rotate is True:
        angle = rng.uniform(-180.0, 180.0)
    elif rotate is False:
        angle = 0.0
    else:
        raise ValueError(f"rotate must be True, False or 'quarter', got {rotate!r}")
    if keep is not None:
        z = 1.0 / rng.uniform(*keep)
    else:
        z = rng.uniform(*zoom) if zoom is not None else 1.0
    c = (S - 1) / 2.0
    M = cv2.getRotationMatrix2D((c, c), angle, z)  # counter-clockwise as displayed

    def warp(img):
        return cv2.warpAffine(img, M, (S, S), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)

    x2 = warp(x) if x.ndim == 2 else np.stack([warp(ch) for ch in x])
    r = np.array(rects, dtype=np.float64).reshape(-1, 5)
    xy = np.c_[r[:, :2], np.ones(len(r))] @ M.T
    out = np.c_[xy, normalize_angle(r[:, 2] + np.deg2rad(angle)), r[:, 3] * z, r[:, 4] * z]
    return x2.astype(np.float32), out


def _fingerprint(ids, rects) -> str:
    h = hashlib.sha256()
    for i, r in zip(ids, rects, strict=True):
        h.update(i.encode())
        h.update(np.round(r, 3).tobytes())
    return h.hexdigest()[:16]


def _batch(X, R, rng, batch_size, input_size, do_augment, spec):
    idx = rng.integers(len(X), size=batch_size)
    xs, ys = [], []
    for i in idx:
        x, r = (augment(X[i], R[i], rng, spec.rotate, spec.zoom, spec.keep) if do_augment
                else (X[i], R[i]))
        xs.append(x)
        ys.append(grasp_maps(r, (input_size, input_size), spec.width_scale(input_size),
                             clip_width=spec.width == "half"))
    return np.stack(xs), np.stack(ys)


def train_ggcnn(samples, out, steps: int = 20_000, seed: int = 0, device: str = "cpu",
                batch_size: int = 8, lr: float = 1e-3, crop: int = 300, input_size: int = 300,
                crop_method: str = "object", filters=FILTERS, do_augment: bool = True,
                checkpoint_every: int = 1000, snapshots=(), snapshot_seconds=(),
                threads: int = 2, progress: bool = True) -> dict:
    """Train GG-CNN on labelled images and save it as ``out`` (``.pt`` + ``.json``).

    :func:`train_network` with GG-CNN's defaults (300 px input, the paper's filters).

    Parameters
    ----------
    samples, out, steps, seed, device, batch_size, lr, crop, input_size, crop_method, \
do_augment, checkpoint_every, snapshots, snapshot_seconds, threads, progress :
        As :func:`train_network`.
    filters : sequence of 6 int
        Layer widths (:data:`graspsim.detectors.ggcnn.model.FILTERS`).

    Returns
    -------
    dict
        The model's JSON record.
    """
    return train_network(samples, out, FORMAT, {"filters": [int(f) for f in filters]},
                         steps=steps, seed=seed, device=device, batch_size=batch_size, lr=lr,
                         crop=crop, input_size=input_size, crop_method=crop_method,
                         do_augment=do_augment, checkpoint_every=checkpoint_every,
                         snapshots=snapshots, snapshot_seconds=snapshot_seconds,
                         threads=threads, progress=progress)


def train_grconvnet(samples, out, steps: int = 20_000, seed: int = 0, device: str = "cpu",
                    batch_size: int = 8, lr: float = 1e-3, crop: int = 224,
                    input_size: int = 224, crop_method: str = "object",
                    channels: int = CHANNELS, dropout: float = DROPOUT,
                    do_augment: bool = True, checkpoint_every: int = 1000, snapshots=(),
                    snapshot_seconds=(), threads: int = 2, progress: bool = True) -> dict:
    """Train GR-ConvNet on labelled RGB-D images and save it as ``out`` (``.pt`` + ``.json``).

    :func:`train_network` with GR-ConvNet's defaults (224 px crop and input, ``k = 32``,
    dropout 0.1 before the heads; :mod:`graspsim.detectors.ggcnn.grconvnet`).

    Parameters
    ----------
    samples, out, steps, seed, device, batch_size, lr, crop, input_size, crop_method, \
do_augment, checkpoint_every, snapshots, snapshot_seconds, threads, progress :
        As :func:`train_network` (``input_size`` a multiple of 4).
    channels : int
        ``k``, the filters of the first layer (32 in the paper; 16 the authors' small model,
        about half the cost per sample-step on 2 CPU cores: ``scripts/bench_grconvnet.py``).
    dropout : float
        Dropout probability before each head while training (0: none).

    Returns
    -------
    dict
        The model's JSON record.
    """
    return train_network(samples, out, "grconvnet",
                         {"channels": int(channels), "dropout": float(dropout)},
                         steps=steps, seed=seed, device=device, batch_size=batch_size, lr=lr,
                         crop=crop, input_size=input_size, crop_method=crop_method,
                         do_augment=do_augment, checkpoint_every=checkpoint_every,
                         snapshots=snapshots, snapshot_seconds=snapshot_seconds,
                         threads=threads, progress=progress)


def train_network(samples, out, network: str, arch: dict, steps: int = 20_000, seed: int = 0,
                  device: str = "cpu", batch_size: int = 8, lr: float = 1e-3, crop: int = 300,
                  input_size: int = 300, crop_method: str = "object", do_augment: bool = True,
                  checkpoint_every: int = 1000, snapshots=(), snapshot_seconds=(),
                  threads: int = 2, progress: bool = True) -> dict:
    """Train one of this package's networks on labelled images and save it as ``out``
    (``.pt`` + ``.json``).

    Parameters
    ----------
    samples : sequence of dlsr.datasets.GraspSample
        Training images; every positive rectangle is a label (:func:`grasp_maps`).
    out : str or Path
        ``MODEL``; the checkpoint is ``MODEL.ckpt.pt`` (+ ``.ckpt.json``) and a rerun with the
        same data and options resumes from it.
    network : str
        A key of :data:`graspsim.detectors.ggcnn.model.NETWORKS` (``"ggcnn"``, ``"grconvnet"``): the
        network, its input, loss, augmentation and width encoding.
    arch : dict
        Its architecture fields (:attr:`graspsim.detectors.ggcnn.model.Network.arch`), saved in the
        record: ``{"filters": [...]}`` for GG-CNN, ``{"channels": k, "dropout": p}`` for
        GR-ConvNet.
    steps : int
        Sample-steps (images seen, in whole batches), whatever the dataset size.
    seed : int
    device : str
        ``"cpu"`` or ``"cuda"``.
    batch_size, lr : int, float
        Adam's batch and learning rate (8 and 1e-3 as both papers).
    crop, input_size : int
        Crop side in image pixels and network input side (a multiple of the network's
        :attr:`~graspsim.detectors.ggcnn.model.Network.multiple`: 12 for GG-CNN, 4 for GR-ConvNet).
    crop_method : {"object", "centre"}
    do_augment : bool
        Random rotation and zoom of every training image (the network's kind).
    checkpoint_every : int
        Sample-steps between checkpoints.
    snapshots : sequence of int
        Sample-steps at which the model is also saved as ``MODEL_stepN`` (for choosing the
        budget on validation scenes), at the end of the first batch that reaches ``N`` (its
        record's ``training.sample_steps``, which exceeds ``N`` when the batch size does not
        divide it).
    snapshot_seconds : sequence of float
        Training seconds at which the model is also saved, as ``MODEL_timeTs`` (``T`` rounded
        to whole seconds; its record's ``training.snapshot_seconds`` is ``T``), at the end of
        the first batch that reaches them: another detector's training time, for a comparison
        at equal training wall time. A time already passed when a run resumes, or never
        reached, gives no file.
    threads : int
        torch threads during training.
    progress : bool
        A progress bar with the loss.

    Returns
    -------
    dict
        The model's JSON record (``training``: sample-steps, seconds, the loss curve as
        ``[sample-steps, mean loss since the previous checkpoint]`` pairs, ...).
    """
    spec = network_of(network)
    torch = require_torch()

    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    if input_size < spec.multiple or input_size % spec.multiple:
        raise ValueError(f"input_size must be a positive multiple of {spec.multiple}, got "
                         f"{input_size}")
    if set(arch) != set(spec.arch):
        raise ValueError(f"{spec.title}'s architecture fields are {', '.join(spec.arch)}, "
                         f"got {', '.join(arch) or 'none'}")
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError("device 'cuda' asked for, but torch sees no CUDA device")
    X, R, ids = prepare_samples(samples, crop, input_size, crop_method, spec.inputs,
                                spec.title)
    n_batches = -(-int(steps) // batch_size)
    # GG-CNN's options are those its committed checkpoints were written with (they resume)
    options = {"seed": int(seed), "device": device, "batch_size": int(batch_size),
               "lr": float(lr), "crop": int(crop), "input_size": int(input_size),
               "crop_method": crop_method,
               **({} if spec.name == FORMAT else {"network": spec.name}), **arch,
               "augment": bool(do_augment), "data": _fingerprint(ids, R), "n_images": len(X)}
    loss_fn = (torch.nn.functional.mse_loss if spec.loss == "mse"
               else torch.nn.functional.smooth_l1_loss)
    pt, js = model_paths(out)
    ck_pt = pt.with_name(pt.stem + ".ckpt.pt")
    ck_js = pt.with_name(pt.stem + ".ckpt.json")
    pt.parent.mkdir(parents=True, exist_ok=True)
    det_before = torch.are_deterministic_algorithms_enabled()
    threads_before = torch.get_num_threads()
    torch.use_deterministic_algorithms(True)
    torch.set_num_threads(int(threads))
    # every batch allocates and frees ~100 MB of activations in blocks above glibc's mmap
    # threshold: kept on the heap, a sample-step costs 110-120 ms instead of 245 ms on 2 cores
    # (42 % of the CPU time was page faults; scripts/bench_ggcnn.py, dlsr.memory)
    try:
        with reused_heap():
            with torch.random.fork_rng(devices=[] if device == "cpu" else None):
                torch.manual_seed(int(seed))
                net = spec.build(arch).to(device)
            # NHWC activations: oneDNN's convolutions run 1.07 to 1.33 times faster per
            # sample-step on this machine's 2 cores (scripts/bench_grconvnet.py), the same
            # products summed in another order
            net = net.to(memory_format=torch.channels_last)
            opt = torch.optim.Adam(net.parameters(), lr=lr)
            done, seconds, losses = 0, 0.0, []
            if ck_js.is_file() and ck_pt.is_file():
                info = read_json(ck_js, f"{spec.title} checkpoint")
                if info.get("options") == options and info.get("batches", 0) <= n_batches:
                    state = torch.load(ck_pt, map_location=device, weights_only=True)
                    net.load_state_dict(state["model"])
                    opt.load_state_dict(state["optim"])
                    done, seconds = int(info["batches"]), float(info["seconds"])
                    losses = list(info.get("losses", []))
                    log.info("%s: resumed from %s at %d sample-steps", spec.title, ck_pt,
                             done * batch_size)
                else:
                    log.info("%s: checkpoint %s is of other data or options: starting afresh",
                             spec.title, ck_pt)
            snaps: dict = {}  # batch -> the sample-steps asked for that it is the first to reach
            for s in sorted({int(s) for s in snapshots if 0 < s <= steps}):
                snaps.setdefault(-(-s // batch_size), []).append(s)
            timed = sorted(float(t) for t in snapshot_seconds if float(t) > seconds)

            def checkpoint(b):
                tmp = ck_pt.with_name(ck_pt.name + ".tmp")
                torch.save({"model": net.state_dict(), "optim": opt.state_dict()}, tmp)
                tmp.replace(ck_pt)
                write_text_atomic(ck_js, json.dumps({"options": options, "batches": b,
                                                     "seconds": seconds, "losses": losses}))

            def record(b):
                return {"crop": int(crop), "input_size": int(input_size),
                        "crop_method": crop_method, **arch,
                        "sigma": 2.0, "width_scale": spec.width_scale(input_size),
                        "training": {**options, "sample_steps": b * batch_size,
                                     "seconds": round(seconds, 2),
                                     "loss": losses[-1][1] if losses else None,
                                     "memory_format": "channels_last",
                                     "torch": torch.__version__}}

            net.train()
            every = max(1, int(checkpoint_every) // batch_size)
            bar = tqdm(total=n_batches * batch_size, initial=done * batch_size, desc=spec.title,
                       unit="sample", disable=not progress)
            running, window = None, []
            for b in range(done, n_batches):
                t0 = time.perf_counter()
                rng = np.random.default_rng([int(seed), b])
                xb, yb = _batch(X, R, rng, batch_size, input_size, do_augment, spec)
                xt = torch.from_numpy(xb).to(device).contiguous(
                    memory_format=torch.channels_last)
                yt = torch.from_numpy(yb).to(device)
                # dropout's masks from a generator of (seed, batch) alone, not the caller's
                with torch.random.fork_rng(devices=[] if device == "cpu" else None):
                    torch.manual_seed(int(np.random.SeedSequence([int(seed), b, 1])
                                          .generate_state(1)[0]))
                    pred = net(xt)
                    loss = sum(loss_fn(pred[:, k], yt[:, k]) for k in range(4))
                    opt.zero_grad()
                    loss.backward()
                opt.step()
                window.append(float(loss.detach()))
                running = float(np.mean(window[-every:]))
                seconds += time.perf_counter() - t0
                if (b + 1) % every == 0 or b + 1 == n_batches:
                    losses.append([(b + 1) * batch_size, round(float(np.mean(window)), 6)])
                    window = []
                    checkpoint(b + 1)
                while timed and seconds >= timed[0]:
                    target = timed.pop(0)
                    rec = record(b + 1)
                    rec["training"]["snapshot_seconds"] = round(target, 2)
                    save_model(net, timed_path(pt, target), rec, spec.name)
                for s in snaps.get(b + 1, ()):  # named by the sample-steps asked for
                    save_model(net, snapshot_path(pt, s), record(b + 1), spec.name)
                bar.set_postfix(loss=f"{running:.4f}")
                bar.update(batch_size)
            bar.close()
            meta = record(n_batches)
            meta["training"]["loss_curve"] = losses
            net.eval()
            save_model(net, out, meta, spec.name)
    finally:
        torch.use_deterministic_algorithms(det_before)
        torch.set_num_threads(threads_before)
    return read_json(js, f"{spec.title} model")


def train_from_folder(data, format: str, out, scale=None, mapping=None,
                      network: str = FORMAT, **options) -> dict:
    """:func:`train_ggcnn` (or :func:`train_grconvnet`, ``network="grconvnet"``) on a dataset
    folder: a ``graspsim dataset`` folder or a Cornell copy (``format="cornell"``), or a
    Jacquard copy (``"jacquard"``), read by :func:`graspsim.data.samples.load_samples`
    (the
    readers DLSR uses)."""
    samples = load_samples(data, format, scale, mapping)
    return trainer(network)(samples, out, **options)


def trainer(network: str):
    """The training function of a network with its defaults: :func:`train_ggcnn` for
    ``"ggcnn"``, :func:`train_grconvnet` for ``"grconvnet"``."""
    return {FORMAT: train_ggcnn, "grconvnet": train_grconvnet}[network_of(network).name]
