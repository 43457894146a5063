"""The Kinect-like RGB-D camera: geometry (:mod:`~graspsim.sim.camera.geometry`: intrinsics,
poses, projection), the depth sensor's noise (:mod:`~graspsim.sim.camera.noise`), the scene's
randomised appearance (:mod:`~graspsim.sim.camera.appearance`: lights, table colour and texture)
and the rendering camera (:mod:`~graspsim.sim.camera.render`).

The public names of the four modules are importable from here
(``graspsim.sim.camera.Camera``, ``graspsim.sim.camera.CameraIntrinsics``).
"""

from .appearance import (
    LightRanges,
    Lights,
    random_lights,
    random_table_rgba,
    random_table_texture,
    table_texture_image,
)
from .geometry import (
    CameraIntrinsics,
    backproject,
    depth_from_zbuffer,
    look_down_pose,
    project,
    view_matrix,
)
from .noise import (
    MATERIALS,
    DepthNoise,
    apply_depth_noise,
    axial_sigma,
    incidence_angle,
    lateral_sigma,
    projector_shadow,
)
from .render import Camera, RGBDFrame, depth_figure

__all__ = [
    "CameraIntrinsics",
    "DepthNoise",
    "Lights",
    "LightRanges",
    "RGBDFrame",
    "Camera",
    "look_down_pose",
    "random_lights",
    "random_table_rgba",
    "random_table_texture",
    "depth_from_zbuffer",
    "backproject",
    "project",
    "depth_figure",
    "apply_depth_noise",
    "projector_shadow",
    "axial_sigma",
    "lateral_sigma",
    "incidence_angle",
    "view_matrix",
    "table_texture_image",
    "MATERIALS",
]
