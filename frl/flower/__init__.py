"""The Flower backend (``federation.backend=flower``; ``pip install frl[flower]``).

- :mod:`~frl.flower.vehicle`: the long-lived vehicle process behind a ClientApp; it
  answers the frames of :mod:`frl.federation.vehicle_host`, as the process backend's workers do.
- :mod:`~frl.flower.messages`: the Flower messages between roadside unit and vehicle.
- :mod:`~frl.flower.client_app`: the ClientApp, a relay to the vehicle process.
- :mod:`~frl.flower.grid_pool`: the vehicles as a ``ClientPool`` over a Flower Grid.
- :mod:`~frl.flower.server_app`: the roadside unit as a ServerApp.
- :mod:`~frl.flower.launch`: starting a run under the simulation or deployment runtime.
- :mod:`~frl.flower.node`: ``python -m frl.flower.node``, a vehicle host.

Importing this package does not import Flower; its modules that need it do.
"""
