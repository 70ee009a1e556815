"""Grasp densities for your own object, learned by trial and error on a simulated Panda.

    MUJOCO_GL=egl python examples/grasp_own_object.py [trials_per_cycle]

The object is an MJCF file in robosuite's object format: its geoms inside
``<body name="object">`` (``group="0"``: robosuite keeps only those); the sites
``bottom_site``, ``top_site`` and ``horizontal_radius_site`` of robosuite's own objects are
optional. Here a block with a knob on top; write yours the same way.
"""

import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")  # render offscreen, on the CPU

import torch

from vistask.envs.grasp_runners import VectorGraspTrials
from vistask.grasp import GraspLearner, demonstration_density, scripted_teacher_grasps

KNOB_BLOCK = """<mujoco model="knob_block">
  <worldbody>
    <body>
      <body name="object">
        <geom name="block" type="box" size="0.03 0.02 0.02" rgba="0.2 0.6 0.3 1" density="300"
              friction="1 0.3 0.1" condim="4" group="0"/>
        <geom name="knob" type="cylinder" size="0.012 0.015" pos="0 0 0.035"
              rgba="0.8 0.2 0.2 1" density="300" friction="1 0.3 0.1" condim="4" group="0"/>
      </body>
      <site rgba="0 0 0 0" size="0.005" pos="0 0 -0.02" name="bottom_site"/>
      <site rgba="0 0 0 0" size="0.005" pos="0 0 0.05" name="top_site"/>
      <site rgba="0 0 0 0" size="0.005" pos="0.03 0.02 0" name="horizontal_radius_site"/>
    </body>
  </worldbody>
</mujoco>
"""

if __name__ == "__main__":
    trials = int(sys.argv[1]) if len(sys.argv) > 1 else 40
    path = Path(tempfile.mkdtemp()) / "knob_block.xml"
    path.write_text(KNOB_BLOCK)
    # One simulator in this process; the object at random yaw, alone, acted on at its true pose.
    runner = VectorGraspTrials(str(path), num_envs=1, n_distractors=0, tip_probability=0.0)
    generator = torch.Generator().manual_seed(0)
    # The first proposal: a scripted teacher's grasps from the object's bounding box, with noise.
    bounds = torch.as_tensor(runner.object_bounds, dtype=torch.float32)
    hypothesis = demonstration_density(scripted_teacher_grasps(bounds), generator=generator)
    learner = GraspLearner(hypothesis, runner.workspace)
    for cycle in range(2):
        seeds = range(cycle * trials, (cycle + 1) * trials)
        stats = learner.run_cycle(runner, trials, seeds, generator)
        print(f"cycle {cycle}: {stats.successes}/{stats.trials} grasps lifted the object")
    runner.close()
    learner.save("knob_block_grasps.pt")  # GraspLearner.load(...) goes on from here
    print(f"learned density: {len(learner.empirical)} particles")
