"""DLSR: dictionary learning and sparse representation for planar grasp detection.

Trottier, Giguère and Chaib-draa, "Dictionary Learning for Robotic Grasp Recognition and
Detection" (2016). This package holds the method, the data formats and the metrics; it never
imports pybullet.
"""

from .rectangles import GraspRectangle

__all__ = ["GraspRectangle"]
__version__ = "0.1.0"
