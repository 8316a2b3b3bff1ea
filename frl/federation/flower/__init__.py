"""The Flower backend (``federation.backend=flower``; ``pip install frl[flower]``).

- :mod:`~frl.federation.flower.codec`: what crosses the wire, without pickle.
- :mod:`~frl.federation.flower.vehicle`: the long-lived vehicle process behind a ClientApp.
- :mod:`~frl.federation.flower.apps`: the ClientApp (relay) and the deployment ServerApp.
- :mod:`~frl.federation.flower.pool`: the vehicles as a ``ClientPool`` over a Flower Grid.
- :mod:`~frl.federation.flower.runtime`: the simulation and deployment runtimes.
- :mod:`~frl.federation.flower.node`: ``python -m frl.federation.flower.node``, a vehicle host.

Importing this package does not import Flower; its modules that need it do.
"""
