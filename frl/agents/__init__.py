"""DDPG agent for gymnasium Box spaces: ``from frl.agents import DDPG, DDPGConfig``."""

from frl.agents.checkpoint import CheckpointError
from frl.agents.config import CriticConfig, DDPGConfig, NoiseConfig, SparseConfig
from frl.agents.ddpg import DDPG
from frl.agents.federated import is_target_key
from frl.agents.functional import discounted_returns, hard_update, soft_update, td_target
from frl.agents.learn import training_step
from frl.agents.networks import Actor, ActorCritic, Critic
from frl.agents.noise import GaussianNoise, OrnsteinUhlenbeckNoise, make_noise
from frl.agents.replay_buffer import Batch, ReplayBuffer
from frl.agents.sparse_linear import InputLinear, SparseRows

__all__ = [
    "DDPG",
    "Actor",
    "ActorCritic",
    "Batch",
    "CheckpointError",
    "Critic",
    "CriticConfig",
    "DDPGConfig",
    "GaussianNoise",
    "InputLinear",
    "NoiseConfig",
    "OrnsteinUhlenbeckNoise",
    "ReplayBuffer",
    "SparseConfig",
    "SparseRows",
    "discounted_returns",
    "hard_update",
    "is_target_key",
    "make_noise",
    "soft_update",
    "td_target",
    "training_step",
]
