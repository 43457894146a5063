"""Grasp detectors: the protocol every detector follows (:mod:`graspsim.detectors.base`), the
baselines, the gripper-aware wrapper, loading by name, plug-in or saved model
(:mod:`graspsim.detectors.loading`), the DLSR detector's options, and the CNN peers
(:mod:`graspsim.detectors.ggcnn`).

The public names of :mod:`~graspsim.detectors.base`, :mod:`~graspsim.detectors.baselines`,
:mod:`~graspsim.detectors.gripper_aware` and :mod:`~graspsim.detectors.loading` are importable
from here, as they were from the module ``graspsim.detectors`` before the package existed
(``graspsim.detectors.GraspDetector``,
``graspsim.detectors.load_detector``). The plug-in entry-point group keeps its name,
``graspsim.detectors``.
"""

from .base import GraspDetector, check_detections
from .baselines import MaskPCADetector, OracleDetector, RandomDetector, object_mask_from_depth
from .gripper_aware import GripperAwareDetector, executable, gripper_aware
from .loading import (
    AWARE_SUFFIX,
    DETECTORS,
    ENTRY_POINT_GROUP,
    PluginDetector,
    check_detector,
    check_detector_options,
    detector_label,
    load_detector,
    parse_detector_options,
    plugin_names,
)

__all__ = [
    "GraspDetector",
    "check_detections",
    "PluginDetector",
    "ENTRY_POINT_GROUP",
    "AWARE_SUFFIX",
    "RandomDetector",
    "MaskPCADetector",
    "OracleDetector",
    "GripperAwareDetector",
    "executable",
    "gripper_aware",
    "DETECTORS",
    "load_detector",
    "check_detector",
    "check_detector_options",
    "detector_label",
    "parse_detector_options",
    "plugin_names",
    "object_mask_from_depth",
]
