"""RLVC on your own Gymnasium image env: a corridor of views cut from a photograph.

python examples/rlvc_own_env.py [total_timesteps]
"""

import sys

import gymnasium as gym
import numpy as np
from skimage import data

from vistask.agents import RLVCAgent


class PhotoCorridor(gym.Env):
    """Walk left or right along a photograph; reward 1 at the right end. The agent sees only
    a 48x48 view around its position, never the position itself."""

    def __init__(self, cells: int = 12, view: int = 48) -> None:
        self.photo, self.cells, self.view = data.astronaut(), cells, view
        self.observation_space = gym.spaces.Box(0, 255, (view, view, 3), np.uint8)
        self.action_space = gym.spaces.Discrete(2)  # 0: left, 1: right

    def _obs(self) -> np.ndarray:
        x = 20 + self.position * (self.photo.shape[1] - self.view - 40) // (self.cells - 1)
        return self.photo[200 : 200 + self.view, x : x + self.view].copy()

    def reset(self, *, seed=None, options=None):
        """Start at a random cell left of the right end."""
        super().reset(seed=seed)
        self.position = int(self.np_random.integers(self.cells - 1))
        return self._obs(), {"position": self.position}

    def step(self, action):
        """Move one cell; the episode ends at the right end with reward 1."""
        self.position = int(np.clip(self.position + (1 if action == 1 else -1), 0, self.cells - 1))
        done = self.position == self.cells - 1
        return self._obs(), float(done), done, False, {"position": self.position}


if __name__ == "__main__":
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 8_000
    env = gym.wrappers.TimeLimit(PhotoCorridor(), max_episode_steps=30)
    agent = RLVCAgent(env, gamma=0.9, seed=0).learn(total_timesteps=steps, progress_bar=True)
    print(f"{agent.rlvc.n_classes} visual classes")
    obs, info = env.reset(seed=1)
    terminated = truncated = False
    steps_taken = 0
    while not (terminated or truncated):
        action, _ = agent.predict(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        steps_taken += 1
    print(f"reached the right end: {terminated} in {steps_taken} steps")
    agent.save("rlvc_corridor.pt")
    agent = RLVCAgent.load("rlvc_corridor.pt", env=env)
