"""The CNN grasp detectors of the harness: a saved model's maps read as ranked rectangles.

:class:`GGCNNDetector` reads any saved network of this package (GG-CNN or GR-ConvNet, by the
model's ``format``; :class:`GRConvNetDetector` insists on GR-ConvNet) and follows the
:class:`graspsim.detectors.GraspDetector` protocol, so it runs wherever a detector does
(``graspsim trials --detector MODEL``, ``graspsim run`` baselines,
:func:`graspsim.detectors.gripper_aware`).
"""

from __future__ import annotations

import os
import time

import cv2
import numpy as np

from .maps import WIDTH_SCALE, crop_box, decode_maps, prepare_depth, prepare_rgb
from .model import FORMAT, load_model, network_of, require_torch

__all__ = ["GGCNNDetector", "GRConvNetDetector", "crop_input", "network_input", "plugin",
           "MODEL_ENV"]

#: Environment variable naming the model the ``ggcnn`` plug-in name loads.
MODEL_ENV = "GRASPSIM_GGCNN_MODEL"


def crop_input(depth, valid, crop: int, input_size: int, method: str = "object", rgb=None):
    """The network's input of one depth (or RGB-D) image and where it came from.

    Parameters
    ----------
    depth : ndarray of shape (H, W)
        Metres, 0 where missing.
    valid : ndarray of shape (H, W) or None
    crop : int
        Side of the square crop, pixels of the image
        (:func:`graspsim.detectors.ggcnn.maps.crop_box`).
    input_size : int
        Side of the network's input; the crop is resized to it.
    method : {"object", "centre"}
        Where the crop is centred (from the observation alone).
    rgb : ndarray of shape (H, W, 3), uint8, or None
        The colour image registered with ``depth``: GR-ConvNet's input also holds it.

    Returns
    -------
    x : ndarray of shape (input_size, input_size), or (4, input_size, input_size) with ``rgb``
        Preprocessed depth (:func:`graspsim.detectors.ggcnn.maps.prepare_depth`), float32; with
        ``rgb``
        followed by R, G, B (:func:`graspsim.detectors.ggcnn.maps.prepare_rgb`).
    box : (row0, col0, scale)
        Crop corner in the image and ``input_size / side``: an input pixel ``(c, r)`` is the
        image pixel ``(col0 + c / scale, row0 + r / scale)``.
    """
    depth = np.asarray(depth, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"depth must be a 2-D image (H, W), got shape {depth.shape}")
    if valid is not None and np.shape(valid) != depth.shape:
        raise ValueError(f"depth_valid has shape {np.shape(valid)}, depth {depth.shape}")
    row0, col0, side = crop_box(depth, valid, crop, method)
    d = depth[row0:row0 + side, col0:col0 + side]
    v = None if valid is None else np.asarray(valid, dtype=bool)[row0:row0 + side,
                                                                 col0:col0 + side]
    x = prepare_depth(d, v)
    interpolation = cv2.INTER_AREA if side > input_size else cv2.INTER_LINEAR
    if side != input_size:
        x = cv2.resize(x, (input_size, input_size), interpolation=interpolation)
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape[:2] != depth.shape:
            raise ValueError(f"rgb has shape {rgb.shape}, depth {depth.shape}")
        c = prepare_rgb(rgb[row0:row0 + side, col0:col0 + side])
        if side != input_size:
            c = np.stack([cv2.resize(ch, (input_size, input_size), interpolation=interpolation)
                          for ch in c])
        x = np.concatenate([x[None], c])
    return x.astype(np.float32), (row0, col0, input_size / side)


def network_input(obs, meta: dict):
    """The input of a saved model's network (``MODEL.json``'s record ``meta``) of one
    observation, channels first, and the crop it covers.

    Parameters
    ----------
    obs : dict
        ``depth``, optionally ``depth_valid``, and ``rgb`` for a network that reads colour.
    meta : dict
        The model's record (:func:`graspsim.detectors.ggcnn.model.load_model`).

    Returns
    -------
    x : ndarray of shape (C, S, S), float32
    box : (row0, col0, scale)
        As :func:`crop_input`.
    """
    spec = network_of(meta.get("format", FORMAT))
    rgb = None
    if spec.inputs == "rgbd":
        rgb = obs.get("rgb")
        if rgb is None:
            raise ValueError(f"{spec.title} needs the colour image: the observation has no "
                             "'rgb'")
    x, box = crop_input(obs["depth"], obs.get("depth_valid"), int(meta["crop"]),
                        int(meta["input_size"]), meta.get("crop_method", "object"), rgb)
    return (x[None] if x.ndim == 2 else x), box


class GGCNNDetector:
    """GG-CNN (Morrison et al., RSS 2018) trained by
    :func:`graspsim.detectors.ggcnn.train.train_ggcnn`,
    or any saved network of this package (GR-ConvNet: :class:`GRConvNetDetector`).

    Each call crops the depth image (and the colour image, for GR-ConvNet) around the object
    found from depth (or the centre), preprocesses it, runs the network and returns the
    ``top_k`` highest peaks of the filtered quality map as rectangles (opening from the width
    map, jaw size half the opening), with the filtered quality as scores.

    Parameters
    ----------
    model : str or Path
        ``MODEL`` of ``MODEL.pt`` + ``MODEL.json``.
    device : str
        ``"cpu"`` or ``"cuda"``.
    top_k : int
        Rectangles returned at most (several, so a gripper-aware filter can choose).
    sigma : float or None
        Gaussian filter of the maps, pixels of the input (None: the model's, default 2).
    min_distance : int
        Peaks this many input pixels apart at least.
    threads : int or None
        torch threads for inference (None: leave torch's setting).
    """

    requires_labels = False

    def __init__(self, model, device: str = "cpu", top_k: int = 5, sigma: float | None = None,
                 min_distance: int = 10, threads: int | None = None):
        self.model = model
        self.device = device
        self.top_k = top_k
        self.sigma = sigma
        self.min_distance = min_distance
        self.threads = threads

    def _loaded(self):
        if getattr(self, "net_", None) is None:
            self.net_, self.meta_ = load_model(self.model, self.device)
        return self.net_, self.meta_

    def maps(self, obs):
        """The network's maps of one observation and the crop they cover.

        Returns
        -------
        maps : ndarray of shape (4, S, S), float32
            Q, cos 2 phi, sin 2 phi, width (input pixels).
        box : (row0, col0, scale)
            As :func:`crop_input`.
        """
        torch = require_torch()
        net, meta = self._loaded()
        x, box = network_input(obs, meta)
        if self.threads is not None:
            torch.set_num_threads(int(self.threads))
        with torch.no_grad():
            t = torch.from_numpy(x)[None].to(self.device)
            out = net(t)[0].cpu().numpy()
        return out, box

    def predict(self, obs):
        """Rectangles (``(n, 5)``, image pixels) best first and their filtered quality."""
        t0 = time.perf_counter()
        out, (row0, col0, scale) = self.maps(obs)
        sigma = self.sigma if self.sigma is not None else self.meta_.get("sigma", 2.0)
        rects, scores = decode_maps(out, n=self.top_k, sigma=sigma,
                                    width_scale=self.meta_.get("width_scale", WIDTH_SCALE),
                                    min_distance=self.min_distance)
        rects[:, 0] = col0 + rects[:, 0] / scale
        rects[:, 1] = row0 + rects[:, 1] / scale
        rects[:, 3:] /= scale
        self.last_seconds_ = time.perf_counter() - t0
        return rects, scores

    def __getstate__(self):  # the network is loaded again in a worker, not pickled
        return {k: v for k, v in self.__dict__.items() if k not in ("net_", "meta_")}

    def __repr__(self):
        return (f"{type(self).__name__}({str(self.model)!r}, device={self.device!r}, "
                f"top_k={self.top_k})")


class GRConvNetDetector(GGCNNDetector):
    """GR-ConvNet (Kumra et al., IROS 2020) trained by
    :func:`graspsim.detectors.ggcnn.train.train_grconvnet`: :class:`GGCNNDetector` on depth and
    colour
    (the observation needs ``rgb``), refusing a model of another network.

    Parameters
    ----------
    model, device, top_k, sigma, min_distance, threads :
        As :class:`GGCNNDetector`.
    """

    def _loaded(self):
        if getattr(self, "net_", None) is None:
            net, meta = load_model(self.model, self.device)
            if meta.get("format") != "grconvnet":
                raise ValueError(f"{self.model}: a {network_of(meta['format']).title} model, "
                                 "not GR-ConvNet")
            self.net_, self.meta_ = net, meta
        return self.net_, self.meta_


def plugin() -> GGCNNDetector:
    """The ``ggcnn`` entry point (group ``graspsim.detectors``): the model named by the
    environment variable :data:`MODEL_ENV` (a saved model's path works directly too)."""
    path = os.environ.get(MODEL_ENV)
    if not path:
        raise ValueError(f"the ggcnn detector needs a trained model: pass its path "
                         f"(--detector MODEL, from `graspsim train ggcnn`) or set {MODEL_ENV}")
    det = GGCNNDetector(path)
    det._loaded()  # names a missing or broken file now
    return det
