"""GG-CNN (Morrison, Corke and Leitner, RSS 2018) and GR-ConvNet (Kumra, Joshi and Sahin,
IROS 2020) as peer detectors in the harness: two networks, one implementation of the rest.

* :mod:`graspsim.ggcnn.maps` (numpy only): label maps from rectangles, rectangles from maps,
  the depth and colour preprocessing and the crop.
* :mod:`graspsim.ggcnn.model`: GG-CNN, the registry of networks
  (:data:`~graspsim.ggcnn.model.NETWORKS`) and their files (PyTorch, the ``cnn`` extra);
  :mod:`graspsim.ggcnn.grconvnet`: GR-ConvNet.
* :mod:`graspsim.ggcnn.train`: training either network (resumable, reproducible).
* :mod:`graspsim.ggcnn.detector`: :class:`~graspsim.ggcnn.detector.GGCNNDetector` (any saved
  network), :class:`~graspsim.ggcnn.detector.GRConvNetDetector`.
* :mod:`graspsim.ggcnn.evaluate`: the offline benchmark on DLSR's folds.

Nothing here imports torch at import time; asking for a network without it raises a one-line
``ValueError`` saying how to install it (``pip install -e .[cnn]``).
"""
