"""RLVC against Stable-Baselines3's PPO on the same pixels, at equal interactions.

    python examples/compare_sb3.py [total_timesteps]

``scripts/compare_baselines.py`` does this over seeds, budgets and methods, with rliable's
statistics; this is the same comparison for one seed, in a few lines.
"""

import sys

import gymnasium as gym
from stable_baselines3 import PPO
from stable_baselines3.common.evaluation import evaluate_policy

import vistask.envs  # noqa: F401  (registers the vistask/... envs)
from vistask.agents import RLVCAgent

if __name__ == "__main__":
    steps = int(sys.argv[1]) if len(sys.argv) > 1 else 40_000
    env = gym.make("vistask/VisualMaze-v0")  # 64x64 RGB percepts, 4 moves
    rlvc = RLVCAgent(env, seed=0).learn(total_timesteps=steps)
    ppo = PPO("CnnPolicy", env, n_steps=512, seed=0).learn(total_timesteps=steps)
    for name, model in (("RLVC", rlvc), ("PPO", ppo)):
        # evaluate_policy calls predict on batches of observations: RLVCAgent takes them too.
        mean, std = evaluate_policy(model, env, n_eval_episodes=20)
        print(f"{name}: mean return {mean:.1f} +- {std:.1f} after {steps} interactions")
