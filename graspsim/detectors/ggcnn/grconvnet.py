"""GR-ConvNet, the generative residual grasp network, as a second network of this package.

Kumra, Joshi and Sahin, "Antipodal Robotic Grasping using Generative Residual Convolutional
Neural Network", IROS 2020 (arXiv:1909.04810); v2: "GR-ConvNet v2: A Real-Time Multi-Grasp
Detection Network for Robotic Grasping", Sensors 22(16), 6208, 2022 (references below). The
figures below are facts read from the paper and from its authors' code, skumra/robotic-grasping
(``inference/models/grconvnet3.py``, ``inference/models/grasp_model.py``,
``utils/data/grasp_data.py``, ``utils/data/cornell_data.py``, ``utils/data/jacquard_data.py``,
``utils/dataset_processing/image.py``, ``inference/post_process.py``, ``train_network.py``;
the version the project's fetch tool stored); the code here is this project's.

Network (``grconvnet3``, the paper's and v2's), ``k`` filters (``channel_size``, 32; 16 also
shipped by the authors):

* input: 4 channels, the depth image then R, G, B (``grasp_data.py``), ``S x S`` with S a
  multiple of 4 (224 in the paper);
* three convolutions down, each followed by batch normalisation and ReLU: 9x9 stride 1 pad 4
  (k filters), 4x4 stride 2 pad 1 (2k), 4x4 stride 2 pad 1 (4k): ``S/4`` at 4k channels;
* five residual blocks at 4k channels: 3x3 convolution, batch norm, ReLU, 3x3 convolution,
  batch norm, plus the block's input (no ReLU after the sum);
* three transposed convolutions up: 4x4 stride 2 pad 1 output-pad 1 (2k) and 4x4 stride 2
  pad 2 output-pad 1 (k), each with batch norm and ReLU, then 9x9 stride 1 pad 4 (k), linear:
  ``S + 1`` pixels;
* four heads, one 2x2 convolution of one output channel each (``S + 1 -> S``): quality,
  cos 2 theta, sin 2 theta, width, each after its own dropout when dropout is on (v2's
  option; the authors' training default ``--use-dropout 1 --dropout-prob 0.1``, their
  Jacquard models were trained without);
* convolution weights initialised Xavier-uniform (gain 1), the rest as PyTorch does.

At k = 32 with 4 input channels this is 1,900,900 trainable parameters (the authors'
``trained-models/cornell-randsplit-rgbd-grconvnet3-drop1-ch32/arch.txt`` lists 1,900,900;
about 1.9 million); at k = 16, 479,156;
:func:`grconvnet_parameter_count` counts them from the layer list above, a test checks it
against the network.

Input normalisation (``image.py``): depth minus its mean, clipped to [-1, 1] (GG-CNN's, with
the same inpainting here, :func:`graspsim.detectors.ggcnn.maps.prepare_depth`); RGB divided by 255
and
minus its mean over the whole crop (:func:`graspsim.detectors.ggcnn.maps.prepare_rgb`).

Labels (``grasp_data.py``, ``grasp.py``): as GG-CNN's, the centre third of every positive
rectangle along its opening; width encoded as the opening clipped to ``S / 2`` pixels and
divided by ``S / 2`` (112 px at 224). The authors' post-processing multiplies the width map by
150 instead, which does not invert their encoding; here the same ``S / 2`` is used both ways.

Training (``train_network.py``, ``grasp_model.py``, ``grasp_data.py``): the sum of the four
smooth-L1 losses, Adam at PyTorch's default learning rate (1e-3), batch 8, 50 epochs of 1,000
batches (400k sample-steps); augmentation by a random rotation among 0, 90, 180 and 270
degrees and a random zoom that keeps the central fraction ``U(0.5, 1)`` of the crop (a
magnification of 1 to 2). Cornell's crop is 224 px centred on the labelled rectangles, which
leaks the answer at test time; here the crop is centred on the object found from depth, as
GG-CNN's (:func:`graspsim.detectors.ggcnn.maps.crop_box`). Read-out (``post_process.py``): quality
and
angle Gaussian-filtered with sigma 2; here the cos and sin maps are filtered instead of the
angle (:func:`graspsim.detectors.ggcnn.maps.decode_maps`, shared with GG-CNN).

Reported accuracy by the rectangle metric: 97.7 % on Cornell and 94.6 % on Jacquard, at 20 ms
per image on a GPU (the IROS paper's abstract); v2 reports 98.8 % and 95.1 % (its abstract).

References:

* S. Kumra, S. Joshi and F. Sahin, "Antipodal Robotic Grasping using Generative Residual
  Convolutional Neural Network", IROS 2020, pp. 9626-9633, doi:10.1109/IROS45743.2020.9340777.
* S. Kumra, S. Joshi and F. Sahin, "GR-ConvNet v2: A Real-Time Multi-Grasp Detection Network
  for Robotic Grasping", Sensors 22(16):6208, 2022, doi:10.3390/s22166208.
* The authors' code: https://github.com/skumra/robotic-grasping (BSD-3-Clause licence).
"""

from __future__ import annotations

from .backend import require_torch

__all__ = ["CHANNELS", "DROPOUT", "INPUT_CHANNELS", "build_grconvnet",
           "grconvnet_parameter_count"]

#: The paper's number of filters ``k`` of the first layer.
CHANNELS = 32
#: Dropout before each head in the authors' training default (v2's option).
DROPOUT = 0.1
#: Depth, R, G, B.
INPUT_CHANNELS = 4
N_RESIDUAL = 5


def grconvnet_parameter_count(k: int = CHANNELS, in_channels: int = INPUT_CHANNELS) -> int:
    """Trainable parameters of GR-ConvNet with ``k`` filters, counted from its layer list.

    A convolution of ``a`` to ``b`` channels with an ``n x n`` kernel has ``a b n^2 + b``
    parameters; a batch normalisation of ``b`` channels ``2 b``.

    Parameters
    ----------
    k : int
        Filters of the first layer.
    in_channels : int
        Input channels (4: depth and RGB).

    Returns
    -------
    int
    """
    def conv(a, b, n):
        return a * b * n * n + b

    def bn(b):
        return 2 * b

    down = (conv(in_channels, k, 9) + bn(k) + conv(k, 2 * k, 4) + bn(2 * k)
            + conv(2 * k, 4 * k, 4) + bn(4 * k))
    residual = N_RESIDUAL * 2 * (conv(4 * k, 4 * k, 3) + bn(4 * k))
    up = conv(4 * k, 2 * k, 4) + bn(2 * k) + conv(2 * k, k, 4) + bn(k) + conv(k, k, 9)
    heads = 4 * conv(k, 1, 2)
    return down + residual + up + heads


def build_grconvnet(channels: int = CHANNELS, dropout: float = DROPOUT,
                    in_channels: int = INPUT_CHANNELS):
    """A freshly initialised GR-ConvNet (``torch.nn.Module``) mapping (B, C, S, S) input to
    (B, 4, S, S) maps (Q, cos 2 theta, sin 2 theta, width), S a multiple of 4.

    Parameters
    ----------
    channels : int
        ``k``, the filters of the first layer (32 in the paper, 16 the authors' small model).
    dropout : float
        Dropout probability before each head during training, in [0, 1) (0: none).
    in_channels : int
        Input channels (4: depth, R, G, B).

    Returns
    -------
    torch.nn.Module
        Initialised from torch's global generator: seed it (``torch.manual_seed``) first.
    """
    torch = require_torch()
    nn = torch.nn
    k = int(channels)
    if k < 1:
        raise ValueError(f"channels must be a positive count, got {channels!r}")
    p = float(dropout)
    if not 0.0 <= p < 1.0:
        raise ValueError(f"dropout must be in [0, 1), got {dropout!r}")

    def conv_bn_relu(conv, b):
        return nn.Sequential(conv, nn.BatchNorm2d(b), nn.ReLU())

    class Residual(nn.Module):
        def __init__(self, c):
            super().__init__()
            self.body = nn.Sequential(nn.Conv2d(c, c, 3, padding=1), nn.BatchNorm2d(c),
                                      nn.ReLU(), nn.Conv2d(c, c, 3, padding=1),
                                      nn.BatchNorm2d(c))

        def forward(self, x):
            return x + self.body(x)

    class GRConvNet(nn.Module):
        def __init__(self):
            super().__init__()
            self.down = nn.Sequential(
                conv_bn_relu(nn.Conv2d(in_channels, k, 9, stride=1, padding=4), k),
                conv_bn_relu(nn.Conv2d(k, 2 * k, 4, stride=2, padding=1), 2 * k),
                conv_bn_relu(nn.Conv2d(2 * k, 4 * k, 4, stride=2, padding=1), 4 * k))
            self.residual = nn.Sequential(*(Residual(4 * k) for _ in range(N_RESIDUAL)))
            self.up = nn.Sequential(
                conv_bn_relu(nn.ConvTranspose2d(4 * k, 2 * k, 4, stride=2, padding=1,
                                                output_padding=1), 2 * k),
                conv_bn_relu(nn.ConvTranspose2d(2 * k, k, 4, stride=2, padding=2,
                                                output_padding=1), k),
                nn.ConvTranspose2d(k, k, 9, stride=1, padding=4))
            self.drop = nn.ModuleList(nn.Dropout(p) for _ in range(4))
            self.heads = nn.ModuleList(nn.Conv2d(k, 1, 2) for _ in range(4))
            for m in self.modules():
                if isinstance(m, nn.Conv2d | nn.ConvTranspose2d):
                    nn.init.xavier_uniform_(m.weight, gain=1.0)

        def forward(self, x):
            h = self.up(self.residual(self.down(x)))
            return torch.cat([head(drop(h)) for drop, head in zip(self.drop, self.heads,
                                                                  strict=True)], dim=1)

    return GRConvNet()
