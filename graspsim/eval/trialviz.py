"""Pictures of one grasp trial: the observation with the rectangle, then pre-grasp, approach,
close, lift and hold seen from the side; as a PNG strip or a GIF. And the hands side by side
at one scale (:func:`hands_picture`)."""

from __future__ import annotations

from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np

from ..sim.bullet import Simulation
from ..sim.camera import Camera, CameraIntrinsics
from ..sim.execution import harness_grasps, run_grasp
from ..sim.gripper import Gripper, hand_params
from ..sim.hands import HAND_NAMES, hand_geometry

__all__ = ["side_camera_pose", "trial_frames", "save_strip", "save_gif", "hands_picture"]


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
    sim : graspsim.sim.bullet.Simulation
    scene : graspsim.sim.scene.Scene
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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), duration=int(seconds_per_frame * 1000), loop=0)
    return path


def _ortho(half_w: float, half_h: float, near: float, far: float) -> list[float]:
    """An OpenGL orthographic projection, column-major as pybullet takes it."""
    M = np.array([[1 / half_w, 0, 0, 0], [0, 1 / half_h, 0, 0],
                  [0, 0, -2 / (far - near), -(far + near) / (far - near)], [0, 0, 0, 1.0]])
    return M.T.ravel().tolist()


def hands_picture(hands=None, spacing: float = 0.26, px_per_mm: float = 1.5,
                  height: float = 0.30) -> np.ndarray:
    """The hands open to their largest opening, side by side at one scale above a ruler.

    Each hand hangs with its fingers down (its approach pointing at the floor), its closing
    direction along the image's rows, seen from the side with an orthographic camera
    (pybullet's TinyRenderer), so one millimetre is ``px_per_mm`` pixels everywhere in the
    picture. Under the fingertips lies a ruler of 1 cm ticks (alternately dark and light,
    taller every 5 and 10 cm); each hand is named with its stroke.

    Parameters
    ----------
    hands : sequence of str or None
        Names of :data:`graspsim.sim.hands.HAND_NAMES` (default: all of them).
    spacing : float
        Metres between the hands' TCPs.
    px_per_mm : float
        The picture's scale.
    height : float
        Metres of the scene shown, from below the ruler up.

    Returns
    -------
    ndarray of shape (H, W, 3), uint8
        RGB.
    """
    hands = list(HAND_NAMES if hands is None else hands)
    width = spacing * len(hands)
    tcp_z = 0.24
    sim = Simulation()
    c = sim.client
    try:
        for i, hand in enumerate(hands):
            T = np.eye(4)
            T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # approach down, closing along world x
            T[:3, 3] = [(i + 0.5) * spacing - width / 2, 0.0, tcp_z]
            geo = hand_geometry(hand)
            Gripper(sim, T, opening=geo.max_opening, params=hand_params(hand))
        ruler_z = tcp_z - 0.01 - 0.025  # 2.5 cm below the fingertips
        n_ticks = int(round(width * 100))
        for k in range(n_ticks):
            tall = 0.012 if k % 10 == 0 else 0.008 if k % 5 == 0 else 0.004
            shade = 0.1 if k % 2 == 0 else 0.85
            vis = c.createVisualShape(c.GEOM_BOX, halfExtents=[0.005, 0.004, tall / 2],
                                      rgbaColor=[shade, shade, shade, 1.0])
            c.createMultiBody(0, -1, vis, [k * 0.01 + 0.005 - width / 2, 0.0,
                                           ruler_z + tall / 2])
        W = int(round(width * 1000 * px_per_mm))
        H = int(round(height * 1000 * px_per_mm))
        top = ruler_z - 0.02 + height
        view = c.computeViewMatrix([0.0, -1.0, (ruler_z - 0.02 + top) / 2],
                                   [0.0, 0.0, (ruler_z - 0.02 + top) / 2], [0.0, 0.0, 1.0])
        _, _, rgba, _, _ = c.getCameraImage(
            W, H, viewMatrix=view, projectionMatrix=_ortho(width / 2, height / 2, 0.5, 1.5),
            renderer=c.ER_TINY_RENDERER, lightDirection=[-0.4, -1.0, 0.8], shadow=0,
            lightAmbientCoeff=0.55, lightDiffuseCoeff=0.5, lightSpecularCoeff=0.05)
    finally:
        sim.close()
    img = np.ascontiguousarray(np.reshape(rgba, (H, W, 4))[:, :, :3], dtype=np.uint8)
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.45 * px_per_mm
    for i, hand in enumerate(hands):
        stroke = f"stroke {hand_geometry(hand).max_opening * 1000:.0f} mm"
        cx = int(round((i + 0.5) * spacing * 1000 * px_per_mm))
        for row, text in enumerate((hand, stroke)):
            (tw, _), _ = cv2.getTextSize(text, font, scale, 1)
            cv2.putText(img, text, (cx - tw // 2, int(22 * px_per_mm * (row + 1))), font, scale,
                        (20, 20, 20), 1, cv2.LINE_AA)
    ruler_px = int(round((top - ruler_z + 0.012) * 1000 * px_per_mm)) + int(14 * px_per_mm)
    for k in range(0, n_ticks + 1, 10):
        x = int(round(k * 10 * px_per_mm))
        cv2.putText(img, f"{k} cm", (max(x - 10, 2), min(ruler_px, H - 4)), font, scale * 0.8,
                    (20, 20, 20), 1, cv2.LINE_AA)
    return img
