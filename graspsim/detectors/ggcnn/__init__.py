"""GG-CNN (Morrison, Corke and Leitner, RSS 2018) and GR-ConvNet (Kumra, Joshi and Sahin,
IROS 2020) as peer detectors in the harness: two networks, one implementation of the rest.

* :mod:`graspsim.detectors.ggcnn.maps` (numpy only): label maps from rectangles, rectangles from
  maps,
  the depth and colour preprocessing and the crop.
* :mod:`graspsim.detectors.ggcnn.model`: GG-CNN, the registry of networks
  (:data:`~graspsim.detectors.ggcnn.model.NETWORKS`) and their files (PyTorch, the ``cnn`` extra);
  :mod:`graspsim.detectors.ggcnn.grconvnet`: GR-ConvNet.
* :mod:`graspsim.detectors.ggcnn.train`: training either network (resumable, reproducible).
* :mod:`graspsim.detectors.ggcnn.detector`:
  :class:`~graspsim.detectors.ggcnn.detector.GGCNNDetector` (any saved
  network), :class:`~graspsim.detectors.ggcnn.detector.GRConvNetDetector`.
* :mod:`graspsim.eval.offline.ggcnn`: the offline benchmark on DLSR's folds.

Nothing here imports torch at import time; asking for a network without it raises a one-line
``ValueError`` saying how to install it (``pip install -e .[cnn]``).
"""
