"""The simulated world: the pybullet engine wrapper (:mod:`graspsim.sim.bullet`, the only
module that imports pybullet), objects and object sets, scenes and their layouts, the camera,
hands and gripper, grasp poses and their execution, and a trial scene's observation.

Nothing is imported here, so ``graspsim.sim.camera`` and the other numpy-only modules load
without pybullet."""
