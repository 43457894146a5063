"""Old path of :mod:`graspsim.detectors.ggcnn.detector`: the entry point ``ggcnn`` of installs
made before the move (``graspsim.ggcnn.detector:plugin``) and code that imports the detectors
from here keep working. Import from :mod:`graspsim.detectors.ggcnn.detector`."""

from graspsim.detectors.ggcnn.detector import GGCNNDetector, GRConvNetDetector, plugin

__all__ = ["GGCNNDetector", "GRConvNetDetector", "plugin"]
