"""GG-CNN (Morrison, Corke and Leitner, RSS 2018) as a peer detector in the harness.

* :mod:`graspsim.ggcnn.maps` (numpy only): label maps from rectangles, rectangles from maps,
  the depth preprocessing and the crop.
* :mod:`graspsim.ggcnn.model`: the network and its files (PyTorch, the ``cnn`` extra).
* :mod:`graspsim.ggcnn.train`: training (resumable, reproducible).
* :mod:`graspsim.ggcnn.detector`: :class:`~graspsim.ggcnn.detector.GGCNNDetector`.
* :mod:`graspsim.ggcnn.evaluate`: the offline benchmark on DLSR's folds.

Nothing here imports torch at import time; asking for GG-CNN without it raises a one-line
``ValueError`` saying how to install it (``pip install -e .[cnn]``).
"""
