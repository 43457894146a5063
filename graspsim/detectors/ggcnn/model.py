"""The networks of this package and their files (``MODEL.pt`` weights + ``MODEL.json``).

PyTorch is imported only inside functions (:func:`require_torch`), so the rest of the toolkit
works without it. Two networks map an image crop to the same four maps (quality, cos 2 phi,
sin 2 phi, width) and share everything else (labels, training, files, read-out); each is a
:class:`Network` of :data:`NETWORKS`, named by the ``format`` field of ``MODEL.json``:

* ``"ggcnn"``, GG-CNN (Morrison, Corke and Leitner, RSS 2018): depth only, three strided
  convolutions (9x9/3, 5x5/2, 3x3/2 with 32, 16, 8 filters), three transposed convolutions back
  (3x3/2, 5x5/2, 9x9/3 with 8, 16, 32 filters), ReLU on the hidden layers and four linear 2x2
  heads: 62,420 parameters. The input side must be a multiple of 12 (300 in the paper).
* ``"grconvnet"``, GR-ConvNet (Kumra, Joshi and Sahin, IROS 2020): depth and RGB,
  :mod:`graspsim.detectors.ggcnn.grconvnet`.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from dlsr.records import read_json, write_text_atomic

from .backend import INSTALL_HINT, require_torch
from .grconvnet import build_grconvnet
from .maps import WIDTH_SCALE

__all__ = [
    "INSTALL_HINT",
    "FILTERS",
    "FORMAT",
    "Network",
    "NETWORKS",
    "network_of",
    "require_torch",
    "build_network",
    "n_parameters",
    "model_paths",
    "snapshot_path",
    "timed_path",
    "budget_path",
    "is_ggcnn_model",
    "save_model",
    "load_model",
]

#: Filters of the three convolutions and the three transposed convolutions (the paper's).
FILTERS = (32, 16, 8, 8, 16, 32)
#: The ``format`` field of ``MODEL.json``.
FORMAT = "ggcnn"
FORMAT_VERSION = 1


def build_network(filters=FILTERS):
    """A freshly initialised GG-CNN (``torch.nn.Module``) mapping (B, 1, S, S) depth to
    (B, 4, S, S) maps (Q, cos 2 phi, sin 2 phi, width), S a multiple of 12.

    Parameters
    ----------
    filters : sequence of 6 int
        Filters of the six hidden layers (:data:`FILTERS`; smaller ones for tests).

    Returns
    -------
    torch.nn.Module
        Initialised from torch's global generator: seed it (``torch.manual_seed``) first.
    """
    torch = require_torch()
    nn = torch.nn
    f = [int(v) for v in filters]
    if len(f) != 6 or min(f) < 1:
        raise ValueError(f"filters must be 6 positive counts, got {filters!r}")

    class GGCNN(nn.Module):
        def __init__(self):
            super().__init__()
            self.body = nn.Sequential(
                nn.Conv2d(1, f[0], 9, stride=3, padding=3), nn.ReLU(),
                nn.Conv2d(f[0], f[1], 5, stride=2, padding=2), nn.ReLU(),
                nn.Conv2d(f[1], f[2], 3, stride=2, padding=1), nn.ReLU(),
                nn.ConvTranspose2d(f[2], f[3], 3, stride=2, padding=1, output_padding=1),
                nn.ReLU(),
                nn.ConvTranspose2d(f[3], f[4], 5, stride=2, padding=2, output_padding=1),
                nn.ReLU(),
                nn.ConvTranspose2d(f[4], f[5], 9, stride=3, padding=3, output_padding=1),
                nn.ReLU(),
            )
            # four heads of one 2x2 filter each, linear output (S + 1 -> S)
            self.heads = nn.ModuleList(nn.Conv2d(f[5], 1, 2) for _ in range(4))

        def forward(self, x):
            h = self.body(x)
            return torch.cat([head(h) for head in self.heads], dim=1)

    return GGCNN()


def n_parameters(net) -> int:
    """Trainable parameters of a network."""
    return int(sum(p.numel() for p in net.parameters() if p.requires_grad))


@dataclass(frozen=True)
class Network:
    """One network of this package: how it is built, fed and trained.

    Attributes
    ----------
    name : str
        The ``format`` field of its ``MODEL.json`` (``"ggcnn"``, ``"grconvnet"``).
    title : str
        Its name in messages (``"GG-CNN"``).
    inputs : {"depth", "rgbd"}
        Depth alone (one channel), or depth then R, G, B (four).
    arch : tuple of str
        The ``MODEL.json`` fields that build it (:meth:`build`).
    multiple : int
        The input side must be a multiple of this.
    loss : {"mse", "smooth_l1"}
        Loss of each of the four maps; the training loss is their sum.
    rotate : bool or "quarter"
        Training augmentation: any rotation, or a multiple of 90 degrees.
    zoom : (float, float) or None
        Magnification range of the augmentation, drawn uniformly...
    keep : (float, float) or None
        ... or as ``1 / f`` with ``f``, the kept central fraction, drawn uniformly.
    width : {"fixed", "half"}
        Width maps hold the opening over 150 px (GG-CNN), or clipped to half the input side and
        divided by it (GR-ConvNet).
    """

    name: str
    title: str
    inputs: str
    arch: tuple
    multiple: int
    loss: str
    rotate: object
    zoom: tuple | None
    keep: tuple | None
    width: str

    @property
    def in_channels(self) -> int:
        """Input channels (1 or 4)."""
        return 1 if self.inputs == "depth" else 4

    def width_scale(self, input_size: int) -> float:
        """Pixels of opening that make a width value of 1 at this input side."""
        return WIDTH_SCALE if self.width == "fixed" else float(input_size) / 2

    def build(self, arch: dict):
        """A freshly initialised network of the ``arch`` fields (a ``MODEL.json`` record)."""
        if self.name == FORMAT:
            return build_network(arch["filters"])
        return build_grconvnet(int(arch["channels"]), float(arch["dropout"]),
                               self.in_channels)

    def describe(self, arch: dict) -> str:
        """The network and its architecture fields, for messages."""
        return f"{self.title} with " + ", ".join(f"{k} {arch.get(k)}" for k in self.arch)


#: The networks by ``format`` name.
NETWORKS = {
    FORMAT: Network(FORMAT, "GG-CNN", "depth", ("filters",), 12, "mse", True, (1.0, 2.0),
                    None, "fixed"),
    "grconvnet": Network("grconvnet", "GR-ConvNet", "rgbd", ("channels", "dropout"), 4,
                         "smooth_l1", "quarter", None, (0.5, 1.0), "half"),
}


def network_of(name) -> Network:
    """The :class:`Network` named ``name`` (a key of :data:`NETWORKS`).

    Raises
    ------
    ValueError
        For an unknown name, listing the known ones.
    """
    if name not in NETWORKS:
        raise ValueError(f"unknown network {name!r}: one of {', '.join(NETWORKS)}")
    return NETWORKS[name]


def model_paths(path) -> tuple[Path, Path]:
    """``(MODEL.pt, MODEL.json)`` of ``path`` given with or without either suffix."""
    p = Path(path)
    if p.suffix in (".pt", ".json"):
        p = p.with_suffix("")
    return p.with_name(p.name + ".pt"), p.with_name(p.name + ".json")


def snapshot_path(path, budget: int) -> Path:
    """The model a training run to ``path`` saves on its way, at ``budget`` sample-steps:
    ``MODEL_stepN`` (without suffix, as :func:`model_paths` takes it), named by the budget
    asked for whatever the batch that reached it (:func:`graspsim.detectors.ggcnn.train.
    train_network`'s ``snapshots``)."""
    p = model_paths(path)[0].with_suffix("")
    return p.with_name(f"{p.name}_step{int(budget)}")


def timed_path(path, seconds: float) -> Path:
    """The model a training run to ``path`` saves on its way after ``seconds`` of training:
    ``MODEL_timeTs``, ``T`` the seconds rounded to whole ones (without suffix, as
    :func:`model_paths` takes it; :func:`graspsim.detectors.ggcnn.train.train_network`'s
    ``snapshot_seconds``)."""
    p = model_paths(path)[0].with_suffix("")
    return p.with_name(f"{p.name}_time{round(seconds)}s")


def budget_path(path, budget: int, final: int) -> Path:
    """The model of ``budget`` sample-steps in a training run to ``path`` of ``final``
    sample-steps: ``path`` itself at the final budget, else its snapshot
    (:func:`snapshot_path`)."""
    return Path(path) if int(budget) == int(final) else snapshot_path(path, budget)


def is_ggcnn_model(path) -> bool:
    """Whether ``path`` names a saved model of this package's networks (its JSON's
    ``format`` is a key of :data:`NETWORKS`: GG-CNN or GR-ConvNet); reads no weights and needs
    no torch."""
    _, js = model_paths(path)
    if not js.is_file():
        return False
    try:
        with js.open() as fh:
            head = json.load(fh)
    except (OSError, ValueError):
        return False
    return isinstance(head, dict) and head.get("format") in NETWORKS


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def save_model(net, path, meta: dict, network: str = FORMAT) -> tuple[Path, Path]:
    """Write the weights (a state dict, ``MODEL.pt``) and ``MODEL.json`` (``meta`` plus the
    format, the architecture and the sha256 of the weights file). No pickled objects.

    Parameters
    ----------
    net : torch.nn.Module
        From :meth:`Network.build` (:func:`build_network` for GG-CNN).
    path : str or Path
        ``MODEL`` (suffixes optional).
    meta : dict
        JSON-serialisable: the network's architecture fields (:attr:`Network.arch`),
        ``input_size`` and the read-out options are required by :func:`load_model`; training
        information may be added.
    network : str
        A key of :data:`NETWORKS`, written as the ``format`` field.

    Returns
    -------
    (Path, Path)
        The two files written.
    """
    torch = require_torch()
    pt, js = model_paths(path)
    pt.parent.mkdir(parents=True, exist_ok=True)
    tmp = pt.with_name(pt.name + ".tmp")
    state = {k: v.detach().cpu().contiguous() for k, v in net.state_dict().items()}
    torch.save(state, tmp)
    tmp.replace(pt)
    record = {"format": network_of(network).name, "version": FORMAT_VERSION, **meta,
              "weights": pt.name, "sha256": _sha256(pt)}
    write_text_atomic(js, json.dumps(record, indent=2))
    return pt, js


def load_model(path, device: str = "cpu"):
    """A saved model (GG-CNN or GR-ConvNet, by its ``format``): the network (eval mode, on
    ``device``) and its JSON record.

    Raises
    ------
    FileNotFoundError
        When a file is missing.
    ValueError
        One line naming the file: not a model of these networks, weights not matching the
        recorded sha256 (truncated or replaced), or weights that do not fit the architecture
        (another network's, or another size's).
    """
    pt, js = model_paths(path)
    if not js.is_file():
        raise FileNotFoundError(f"GG-CNN model file not found: {js}")
    meta = read_json(js, "GG-CNN model")
    if not isinstance(meta, dict) or meta.get("format") not in NETWORKS:
        raise ValueError(f"{js}: not a GG-CNN model (no \"format\": \"{FORMAT}\")"
                         if not isinstance(meta, dict) or "format" not in meta else
                         f"{js}: not a model of {', '.join(NETWORKS)} (\"format\": "
                         f"{meta['format']!r})")
    spec = NETWORKS[meta["format"]]
    if meta.get("version") != FORMAT_VERSION:
        raise ValueError(f"{js}: {spec.title} model version {meta.get('version')!r}, this "
                         f"toolkit reads {FORMAT_VERSION}")
    for key in (*spec.arch, "input_size", "sha256"):
        if key not in meta:
            raise ValueError(f"{js}: {spec.title} model record has no {key!r}")
    if not pt.is_file():
        raise FileNotFoundError(f"{spec.title} weights file not found: {pt}")
    if _sha256(pt) != meta["sha256"]:
        raise ValueError(f"{pt}: the weights do not match the sha256 recorded in {js.name} "
                         "(truncated or replaced file)")
    torch = require_torch()
    try:
        state = torch.load(pt, map_location=device, weights_only=True)
    except Exception as exc:  # a foreign or corrupt file: one line
        msg = " ".join(str(exc).split())[:200]
        raise ValueError(f"{pt}: not a readable weights file ({type(exc).__name__}: "
                         f"{msg})") from None
    try:
        net = spec.build(meta)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{js}: bad {spec.title} architecture ({exc})") from None
    try:
        if not isinstance(state, dict):
            raise TypeError(f"a {type(state).__name__}, not a state dict")
        net.load_state_dict(state)
    except Exception as exc:
        msg = " ".join(str(exc).split())[:200]
        what = (f"GG-CNN with filters {meta['filters']}" if spec.name == FORMAT
                else spec.describe(meta))
        raise ValueError(f"{pt}: the weights do not fit {what} ({msg})") from None
    net.to(device).eval()
    return net, meta
