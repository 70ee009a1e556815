"""Agents of vistask (installed as ``vistask.agents``): RLVC on images, tabular Q-learning."""

from vistask.agents.rlvc_agent import RLVCAgent
from vistask.agents.tabular import TabularQAgent

__all__ = ["RLVCAgent", "TabularQAgent"]
