"""Pictures of one grasp trial: the observation with the rectangle, then pre-grasp, approach,
close, lift and hold seen from the side; as a PNG strip or a GIF."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .execution import harness_grasps, run_grasp

__all__ = ["side_camera_pose", "trial_frames", "save_strip", "save_gif"]


def side_camera_pose(target, view_dir, distance: float = 0.4, elevation: float = 0.35):
    """``T_world_cam`` (OpenCV frame) looking at ``target`` horizontally along ``view_dir``,
    raised by ``elevation`` radians."""
    target = np.asarray(target, float)
    d = np.asarray(view_dir, float).copy()
    d[2] = 0.0
    d /= np.linalg.norm(d)
    f = np.cos(elevation) * d + np.array([0.0, 0.0, -np.sin(elevation)])
    eye = target - distance * f
    up = np.array([0.0, 0.0, 1.0])
    y = -(up - (up @ f) * f)
    y /= np.linalg.norm(y)
    x = np.cross(y, f)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, f, eye
    return T


def _label(img, text):
    img = img.copy()
    cv2.rectangle(img, (0, 0), (img.shape[1], 22), (255, 255, 255), -1)
    cv2.putText(img, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (20, 20, 20), 1, cv2.LINE_AA)
    return img


def trial_frames(sim, scene, frame, rect, size=(320, 240)):
    """Execute ``rect`` in ``scene`` and return labelled pictures of the phases.

    Parameters
    ----------
    sim : graspsim.sim.Simulation
    scene : graspsim.scene.Scene
    frame : RGBDFrame
        The observation the rectangle lives in.
    rect : GraspRectangle
    size : (int, int)
        Width and height of each picture.

    Returns
    -------
    frames : list of ndarray of shape (h, w, 3), uint8
        Observation with the rectangle (jaws in red), then one picture per phase.
    result : GraspResult
    """
    from .camera import Camera, CameraIntrinsics

    W, H = size
    obs = frame.rgb.copy()
    c = rect.corners().astype(np.int32)
    cv2.polylines(obs, [c], True, (0, 120, 255), 2, cv2.LINE_AA)
    for a, b in ((0, 3), (1, 2)):  # the jaw edges, across the closing direction
        cv2.line(obs, tuple(int(v) for v in c[a]), tuple(int(v) for v in c[b]), (230, 0, 0), 3,
                 cv2.LINE_AA)
    x0, y0 = int(np.clip(rect.x - 160, 0, obs.shape[1] - 320)), int(
        np.clip(rect.y - 120, 0, obs.shape[0] - 240))
    crop = obs[y0:y0 + 240, x0:x0 + 320]
    frames = [_label(cv2.resize(crop, (W, H), interpolation=cv2.INTER_AREA), "observation")]
    g = harness_grasps([rect], frame, scene.table_z)[0]
    if g.failure is not None:
        return frames, run_grasp(sim, scene, g)
    target = g.position + np.array([0.0, 0.0, 0.09])
    T_side = side_camera_pose(target, g.T_world_grasp[:3, 1], distance=0.5, elevation=0.3)
    cam = Camera(sim.client, CameraIntrinsics(width=W, height=H, fx=0.9 * W, fy=0.9 * W))

    phases = []

    def record(phase):
        rgb, _, _ = cam.render_clean(T_side)
        phases.append(phase)
        return rgb

    result = run_grasp(sim, scene, g, record=record)
    names = {"hold": "hold 1 s"}
    for i, (rgb, phase) in enumerate(zip(result.frames, phases, strict=True)):
        text = names.get(phase, phase)
        if i == len(phases) - 1:
            text += " - success" if result.success else f" - failure: {result.reason}"
        frames.append(_label(rgb, text))
    return frames, result


def save_strip(frames, path) -> Path:
    """Frames side by side in one PNG (separated by white bars)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    bar = np.full((frames[0].shape[0], 4, 3), 255, np.uint8)
    row = [frames[0]]
    for f in frames[1:]:
        row += [bar, f]
    cv2.imwrite(str(path), np.concatenate(row, axis=1)[..., ::-1])
    return path


def save_gif(frames, path, seconds_per_frame: float = 0.8) -> Path:
    """Frames as a looping GIF."""
    import imageio.v3 as iio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), duration=int(seconds_per_frame * 1000), loop=0)
    return path
