"""The Flower backend (``federation.backend=flower``; ``pip install frl[flower]``).

- :mod:`~frl.flower.codec`: what crosses the wire, without pickle.
- :mod:`~frl.flower.vehicle`: the long-lived vehicle process behind a ClientApp.
- :mod:`~frl.flower.apps`: the ClientApp (relay) and the deployment ServerApp.
- :mod:`~frl.flower.pool`: the vehicles as a ``ClientPool`` over a Flower Grid.
- :mod:`~frl.flower.runtime`: the simulation and deployment runtimes.
- :mod:`~frl.flower.node`: ``python -m frl.flower.node``, a vehicle host.

Importing this package does not import Flower; its modules that need it do.
"""
