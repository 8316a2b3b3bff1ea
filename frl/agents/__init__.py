"""DDPG agent for gymnasium Box spaces: ``from frl.agents import DDPG, DDPGConfig``."""

from frl.agents.checkpoint import CheckpointError
from frl.agents.config import DDPGConfig
from frl.agents.ddpg import DDPG, is_target_key
from frl.agents.functional import discounted_returns, hard_update, soft_update, td_target
from frl.agents.networks import Actor, Critic
from frl.agents.noise import GaussianNoise, OrnsteinUhlenbeckNoise, make_noise
from frl.agents.replay_buffer import Batch, ReplayBuffer
from frl.agents.runtime import configure_cpu_training, retain_freed_memory, set_torch_threads
from frl.agents.sparse_linear import InputLinear, SparseRows

__all__ = [
    "DDPG",
    "Actor",
    "Batch",
    "CheckpointError",
    "Critic",
    "DDPGConfig",
    "GaussianNoise",
    "InputLinear",
    "OrnsteinUhlenbeckNoise",
    "ReplayBuffer",
    "SparseRows",
    "configure_cpu_training",
    "discounted_returns",
    "hard_update",
    "is_target_key",
    "make_noise",
    "retain_freed_memory",
    "set_torch_threads",
    "soft_update",
    "td_target",
]
