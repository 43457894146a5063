"""Simulation profiles: the camera, table, lighting and depth-noise settings of an observation.

A :class:`SimProfile` groups the settings that decide what a simulated RGB-D image looks like
(not the physics): the camera height range and intrinsics, the table colour, the ranges the
lights are drawn from, and the depth-noise model. ``PROFILES`` names the built-in ones:

* ``"default"``: the simulator's usual Kinect-v1-like set-up (camera 0.6-0.8 m above the
  table, 640x480, f = 550 px, random muted table colours, random lights, Kinect-like depth
  noise and dropout).
* ``"jacquard"``: the setting that the sim -> real study on the Jacquard samples kept
  (``docs/sim_settings.md``): the clean z-buffer depth, without the Kinect model's noise and
  dropout (Jacquard's depth loses about 3 % of an object's pixels, the Kinect model about
  24 %). Everything else is the default's.

Every profile draws the same random values in the same order, so scene ``i`` of seed ``s``
holds the same objects at the same poses under every profile; only how it is seen changes.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields, replace

from .camera import CameraIntrinsics, DepthNoise, LightRanges
from .scene import TABLE_COLOURS

__all__ = ["SimProfile", "PROFILES", "get_profile", "profile_changes"]


@dataclass(frozen=True)
class SimProfile:
    """How the simulated camera sees a scene.

    Attributes
    ----------
    name : str
    camera_height : (float, float)
        Uniform range of the camera height above the table top, metres
        (:func:`graspsim.sim.camera.look_down_pose`).
    intrinsics : graspsim.sim.camera.CameraIntrinsics
        Image size (pixels), focal lengths (pixels), principal point and clipping planes.
    table : {"random", "grey"}
        Table colour (:func:`graspsim.sim.scene.table_colour`).
    lighting : graspsim.sim.camera.LightRanges
        Ranges the lights are drawn from.
    depth_noise : graspsim.sim.camera.DepthNoise
        Depth noise and dropout model (``DepthNoise.off()``: the clean z-buffer depth).
    """

    name: str = "default"
    camera_height: tuple[float, float] = (0.6, 0.8)
    intrinsics: CameraIntrinsics = field(default_factory=CameraIntrinsics)
    table: str = "random"
    lighting: LightRanges = field(default_factory=LightRanges)
    depth_noise: DepthNoise = field(default_factory=DepthNoise)

    def __post_init__(self):
        lo, hi = self.camera_height
        if not (0 < lo <= hi < self.intrinsics.far):
            raise ValueError(f"profile {self.name!r}: camera_height must satisfy 0 < low <= "
                             f"high < far ({self.intrinsics.far} m), got {(lo, hi)}")
        if self.table not in TABLE_COLOURS:
            raise ValueError(f"profile {self.name!r}: unknown table {self.table!r}; use one of "
                             f"{TABLE_COLOURS}")

    def to_dict(self) -> dict:
        """JSON-ready settings (angles in radians, lengths in metres, pixels)."""
        d = asdict(self)
        d["camera_height"] = list(self.camera_height)
        d["lighting"] = {k: (list(v) if isinstance(v, tuple) else v)
                         for k, v in d["lighting"].items()}
        d["depth_noise"] = {k: (list(v) if isinstance(v, tuple) else v)
                            for k, v in d["depth_noise"].items()}
        return d


_DEFAULT = SimProfile()

PROFILES: dict[str, SimProfile] = {
    "default": _DEFAULT,
    # Sim -> real on the Jacquard samples: 67.9 -> 82.1 % (80 scenes, seed 1) and
    # 64.3 -> 89.3 % (seed 2, exact McNemar p = 0.039); docs/sim_settings.md.
    "jacquard": replace(_DEFAULT, name="jacquard", depth_noise=DepthNoise.off()),
}
"""The built-in profiles by name (see the module docstring)."""


def get_profile(profile=None) -> SimProfile:
    """A :class:`SimProfile` from a name in ``PROFILES``, a profile, or None (the default).

    Raises
    ------
    ValueError
        For an unknown name (the message lists the known ones).
    """
    if profile is None:
        return _DEFAULT
    if isinstance(profile, SimProfile):
        return profile
    if isinstance(profile, str) and profile in PROFILES:
        return PROFILES[profile]
    raise ValueError(f"unknown simulation profile {profile!r}; use one of {sorted(PROFILES)}")


def profile_changes(profile, base="default") -> list[str]:
    """Names of the settings in which ``profile`` differs from ``base`` (``name`` left out)."""
    a, b = get_profile(profile), get_profile(base)
    return [f.name for f in fields(SimProfile)
            if f.name != "name" and getattr(a, f.name) != getattr(b, f.name)]
