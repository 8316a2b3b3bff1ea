"""frl: federated reinforcement learning for autonomous driving at unsignalized intersections."""

__version__ = "0.1.0"
