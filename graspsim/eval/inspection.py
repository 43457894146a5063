"""Replay a trial folder's rectangles and record what the object and the pads do in each phase.

For harness diagnoses (why a thin object slips, what a collision hits): trial ``i``'s scene is
rebuilt (:func:`graspsim.sim.observe.observe_scene`), its recorded rectangle executed with the
current harness and the folder's execution parameters, and at the end of each phase (pregrasp,
approach, close, lift, hold) the record has, in the gripper frame (x closing, z approach, TCP at
0, fingertips at +10 mm, palm at -40 mm): the object's roll about its own x axis and tilt since
the start (degrees), its height (m), its centre (mm), the opening between the pads (mm), and per
pad (0, 1) the contact points with the object (mm) and their summed normal force (N); at the
approach, every contact of the gripper (``palm`` or ``finger0/1``, with ``object`` or
``table``). ``scripts/inspect_grasps.py`` prints one JSON line per trial.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dlsr.records import read_json, read_jsonl
from dlsr.rectangles import GraspRectangle

from ..labels.graspability import resolve_objects
from ..sim.bullet import Simulation
from ..sim.execution import execute_grasp, harness_grasps
from ..sim.observe import observe_scene
from ..sim.scene import build_scene
from .trials import campaign_execution_params

__all__ = ["inspect_trial", "inspect_folder"]


def _mm(v) -> list[float]:
    return [round(1000.0 * float(x), 1) for x in v]


def inspect_trial(sim, specs, seed: int, index: int, n_objects: int, rect, params) -> dict:
    """Execute one recorded rectangle in its rebuilt scene and record each phase.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    specs : list of ObjectSpec
        The campaign's objects.
    seed, index : int
        The trial (its scene: :func:`graspsim.sim.observe.observe_scene`).
    n_objects : int
        Objects per scene of the campaign.
    rect : sequence of 5 float
        The recorded rectangle ``[x, y, theta, w, h]``.
    params : ExecutionParams

    Returns
    -------
    dict
        ``index``, ``reason`` (the outcome now), ``opening_m``, ``lift_height_m`` and
        ``phases``: per phase (see the module docstring) ``object``, ``roll_deg``,
        ``tilt_deg``, ``height_m``, ``centre_mm``, ``opening_mm``, ``pads`` and, at the
        approach, ``contacts``.
    """
    scene, _, frame, _ = observe_scene(sim, specs, seed, index, n_objects)
    grasp = harness_grasps([GraspRectangle(*rect)], frame, scene.table_z, params)[0]
    bodies = build_scene(sim, scene)
    c = sim.client
    q0 = [Rotation.from_quat(c.getBasePositionAndOrientation(b)[1]) for b in bodies.objects]
    phases = {}

    def record(phase):
        gripper = c.getBodyUniqueId(c.getNumBodies() - 1)  # loaded last
        g_pos, g_q = c.getBasePositionAndOrientation(gripper)
        to_grip = Rotation.from_quat(g_q).inv()
        # the object nearest the TCP
        k = int(np.argmin([np.linalg.norm(np.subtract(c.getBasePositionAndOrientation(b)[0],
                                                      g_pos)) for b in bodies.objects]))
        body = bodies.objects[k]
        pos, q = c.getBasePositionAndOrientation(body)
        rv = (q0[k].inv() * Rotation.from_quat(q)).as_rotvec()
        pads = {}
        for j in (0, 1):
            cps = c.getContactPoints(bodyA=gripper, bodyB=body, linkIndexA=j)
            pads[j] = {"points_mm": [_mm(to_grip.apply(np.subtract(cp[5], g_pos))) for cp in cps],
                       "force_N": round(sum(cp[9] for cp in cps), 2)}
        out = {"object": scene.objects[k].spec.name,
               "roll_deg": round(float(np.degrees(rv[0])), 1),
               "tilt_deg": round(float(np.degrees(np.linalg.norm(rv[1:]))), 1),
               "height_m": round(float(pos[2]), 4),
               "centre_mm": _mm(to_grip.apply(np.subtract(pos, g_pos))),
               "opening_mm": round(1000.0 * sum(c.getJointState(gripper, j)[0] for j in (0, 1)),
                                   2),
               "pads": pads}
        if phase == "approach":
            out["contacts"] = [
                {"link": "palm" if cp[3] == -1 else f"finger{cp[3]}",
                 "with": "object" if cp[2] in bodies.objects else "table",
                 "at_mm": _mm(to_grip.apply(np.subtract(cp[5], g_pos)))}
                for cp in c.getContactPoints(bodyA=gripper)]
        phases[phase] = out

    res = execute_grasp(sim, scene, bodies, grasp, params, record)
    return {"index": index, "reason": res.reason, "opening_m": round(grasp.opening, 4),
            "lift_height_m": round(res.lift_height, 4), "phases": phases}


def inspect_folder(folder, objects=None, tip_clearance: float | None = None,
                   sim: Simulation | None = None) -> Iterator[dict]:
    """:func:`inspect_trial` of every executed trial of a trial folder, in index order.

    Parameters
    ----------
    folder : str or Path
        A :func:`graspsim.eval.trials.run_trials` folder (``config.json``, ``trials.jsonl``).
    objects : collection of str or None
        Only the trials whose scene holds one of these objects.
    tip_clearance : float or None
        Replaces the folder's execution parameter (metres).
    sim : Simulation or None
        The simulator (default: a new one).

    Yields
    ------
    dict
        :func:`inspect_trial`'s record with the folder's ``recorded_reason``.

    Raises
    ------
    FileNotFoundError
        When ``folder`` holds no ``config.json``.
    """
    folder = Path(folder)
    cfg_path = folder / "config.json"
    if not cfg_path.exists():
        raise FileNotFoundError(f"{cfg_path}: not found (not a trial folder)")
    cfg = read_json(cfg_path, "trials configuration")
    records = {int(r["index"]): r for r in read_jsonl(folder / "trials.jsonl")}
    keep = None if objects is None else set(objects)
    params = campaign_execution_params(folder)
    if tip_clearance is not None:
        params = dataclasses.replace(params, tip_clearance=tip_clearance)
    sim = Simulation() if sim is None else sim
    recorded = cfg["objects"]  # an object-set text, or the names of objects given in Python
    specs = resolve_objects(",".join(recorded) if isinstance(recorded, list) else recorded)
    for i, rec in sorted(records.items()):
        if rec["rectangle"] is None or (keep is not None and not keep.intersection(rec["object"])):
            continue
        row = inspect_trial(sim, specs, cfg["seed"], i, cfg["config"]["n_objects"],
                            rec["rectangle"], params)
        row["recorded_reason"] = rec["reason"]
        yield row
