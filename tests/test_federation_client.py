"""A vehicle in-process, and a FedAvg round across vehicles in worker processes.

The privacy test records every message that leaves a vehicle's process during training
and a FedAvg round, and checks that the only tensors in them are model parameters.
"""

import numpy as np
import pytest
import torch
from train_helpers import tiny_spec

from frl.agents import is_target_key
from frl.federation import ProcessClientPool, VehicleClient, fedavg
from frl.federation.client import LocalUpdate, drive_rounds
from frl.federation.frames import decode_frame, encode_frame
from frl.federation.vehicle_host import PARAMETERS_PREFIX

# One xdist worker runs this module: its tests share one vehicle (a module fixture).
pytestmark = pytest.mark.xdist_group("client")


@pytest.fixture(scope="module")
def client():
    vehicle = VehicleClient(tiny_spec(0, "left"))
    yield vehicle
    vehicle.close()


def test_local_training_reports_steps_episodes_and_parameters(client):
    update = client.train(70)

    assert update.client == "client0_left"
    assert update.num_steps == 70 and update.total_steps == 70
    assert update.step_rewards.dtype == np.float32 and update.step_rewards.shape == (70,)
    assert update.episodes, "30-step episodes: at least two end in 70 steps"
    assert all(e.task == "left" and 1 <= e.steps <= 30 for e in update.episodes)
    assert np.isfinite(update.losses["critic_loss"][-1])  # learning started at step 20
    assert np.isnan(update.losses["critic_loss"][0])
    assert set(update.parameters) == set(client.agent.federated_keys)
    # The reported returns are the sums of the step rewards of each episode.
    first = update.episodes[0]
    assert first.episode_return == pytest.approx(float(update.step_rewards[: first.steps].sum()))
    # Diagnostics: the actions driven and proposed, speeds, critic bias.
    executed, policy = update.actions["executed"], update.actions["policy"]
    assert executed.shape == policy.shape == (70,)
    assert np.all(np.abs(executed) <= 1.0)
    assert np.isnan(policy[:20]).all() and np.isfinite(policy[20:]).all()  # warm-up: uniform
    for episode in update.episodes:
        assert 0 <= episode.stopped_steps <= episode.steps
        assert 0 <= episode.mean_speed <= 20.2
        assert (episode.critic_bias is None) == episode.timeout


def test_upload_options(client):
    without_targets = client.train(5, include_targets=False).parameters
    assert without_targets and not any(is_target_key(k) for k in without_targets)
    assert client.train(5, upload=False).parameters is None


def test_set_parameters_with_and_without_target_resync(client):
    state = client.get_parameters()
    online = {k: torch.full_like(v, 0.5) for k, v in state.items() if not is_target_key(k)}

    client.set_parameters(online)
    after = client.get_parameters()
    assert all(torch.equal(after[k], online[k]) for k in online)
    assert all(torch.equal(after[k], state[k]) for k in state if is_target_key(k))

    client.set_parameters(online, sync_targets=True)
    after = client.get_parameters()
    assert all(torch.all(after[k] == 0.5) for k in after)
    with pytest.raises(ValueError, match=r"unexpected parameter 'optimizer\.x'"):
        client.set_parameters({**online, "optimizer.x": torch.zeros(1)})
    with pytest.raises(ValueError, match="lacks"):
        client.set_parameters({})


def test_save_and_load_restore_the_agent(client, tmp_path):
    client.save(tmp_path)
    before = client.get_parameters()
    steps = client.agent.num_env_steps
    client.train(10)
    client.load(tmp_path)
    assert client.agent.num_env_steps == steps
    after = client.get_parameters()
    assert all(torch.equal(before[k], after[k]) for k in before)
    client.train(3)  # resumes on a fresh simulation


def test_evaluate_uses_the_deterministic_policy(client):
    records = client.evaluate("right", [1, 3])
    again = client.evaluate("right", [1, 3])
    assert [r.task for r in records] == ["right", "right"]
    assert records == again  # same seeds, no exploration: identical episodes


# ------------------------------------------------------------ worker processes
_ALLOWED_TYPES = (str, int, float, bool, type(None), np.floating, np.integer, np.bool_)


def _audit(payload, federated_keys, path="message"):
    """Every array must be a model parameter or a 1-D per-step scalar series."""
    if isinstance(payload, bytes):  # a reply frame: JSON header and arrays
        header, arrays = decode_frame(payload)
        for key, array in arrays.items():
            if key.startswith(PARAMETERS_PREFIX):
                assert key[len(PARAMETERS_PREFIX) :] in federated_keys, f"{path}: {key}"
            else:
                assert array.ndim == 1, f"{path}: {key}: only per-step scalar series may leave"
                assert array.dtype == np.float32, f"{path}: {key}"
        _audit(header, federated_keys, path)
    elif isinstance(payload, dict):
        for key, value in payload.items():
            assert isinstance(key, str)
            lowered = key.lower()
            assert not any(w in lowered for w in ("optim", "buffer", "noise", "obs")), key
            _audit(value, federated_keys, f"{path}.{key}")
    elif isinstance(payload, (list, tuple)):
        for i, value in enumerate(payload):
            _audit(value, federated_keys, f"{path}[{i}]")
    else:
        assert isinstance(payload, _ALLOWED_TYPES), f"{path}: {type(payload).__name__}"


def _without_parameters(frame: bytes) -> int:
    """Bytes of a reply frame once its model parameters are taken out."""
    header, arrays = decode_frame(frame)
    rest = {k: v for k, v in arrays.items() if not k.startswith(PARAMETERS_PREFIX)}
    return len(encode_frame(header, rest))


def test_a_fedavg_round_leaves_every_client_with_the_mean_and_only_parameters_leave():
    specs = [tiny_spec(0, "left"), tiny_spec(1, "right")]
    messages = []
    with ProcessClientPool(specs, num_threads=1, on_message=lambda *m: messages.append(m)) as pool:
        updates = pool.train(60, upload=True, include_targets=True, on_progress=lambda *_: None)
        uploads = [u.parameters for u in updates]
        first_layer = "actor.layers.0.weight"
        assert not torch.equal(uploads[0][first_layer], uploads[1][first_layer])
        global_model = fedavg(uploads)
        pool.set_parameters(global_model, sync_targets=False)
        held = pool.get_parameters()
        # Next round: clients continue from the global model.
        pool.train(20, upload=False, include_targets=True)

    for state in held:
        assert set(state) == set(global_model)
        for key, tensor in global_model.items():
            assert torch.equal(state[key], tensor), key
    key = "critic.layers.0.weight"
    torch.testing.assert_close(global_model[key], (uploads[0][key] + uploads[1][key]) / 2)

    kinds = {kind for _, kind, _ in messages}
    assert kinds == {"ready", "progress", "ok"}
    federated_keys = set(global_model)
    for client, kind, payload in messages:
        _audit(payload, federated_keys, f"{client}:{kind}")
    # Byte budget: besides parameters, a round's messages carry only small scalars. A
    # worker answers with one frame per vehicle it hosts (here one).
    others = [
        _without_parameters(frame)
        for _, kind, p in messages
        if kind == "ok" and p
        for frame in p
        if frame is not None
    ]
    assert max(others) < 10_000


def _round(name: str, steps: int, seen: list):
    """A round of ``steps`` steps whose observations are (name, step); it records the
    policy action and the losses it is given."""
    for step in range(steps):
        action = yield (name, step)
        losses = yield None
        seen.append((name, step, action, losses))
    return LocalUpdate(name, steps, steps, np.zeros(steps, np.float32), [])


def test_rounds_in_lockstep_act_together_then_learn_together():
    seen: list = []
    asked: list = []

    def act(observations):
        asked.append(list(observations))
        return [f"action {name} {step}" for name, step in observations]

    results = drive_rounds(
        [_round("a", 3, seen), _round("b", 3, seen)],
        update=lambda: [{"loss": 1.0}, {"loss": 2.0}],
        act=act,
    )
    assert [r.client for r in results] == ["a", "b"]
    assert asked == [[("a", s), ("b", s)] for s in range(3)]  # one call per step, all at once
    assert seen[:2] == [
        ("a", 0, "action a 0", {"loss": 1.0}),
        ("b", 0, "action b 0", {"loss": 2.0}),
    ]
    # Without a shared forward pass each vehicle computes its own (None given).
    seen.clear()
    drive_rounds([_round("a", 2, seen)], update=lambda: [{}])
    assert seen == [("a", 0, None, {}), ("a", 1, None, {})]
