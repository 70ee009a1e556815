"""Agents of vistask (installed as ``vistask.agents``): RLVC and RLJC on images, tabular
Q-learning."""

from vistask.agents.rljc_agent import RLJCAgent
from vistask.agents.rlvc_agent import Compaction, RLVCAgent
from vistask.agents.tabular import TabularQAgent

__all__ = ["Compaction", "RLJCAgent", "RLVCAgent", "TabularQAgent"]
