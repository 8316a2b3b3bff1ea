"""The Flower backend's wire formats (no Flower needed): specs, updates and local frames."""

import io

import numpy as np
import pytest
import torch
from train_helpers import tiny_spec

from frl.episodes import EpisodeRecord
from frl.federation.client import LocalUpdate
from frl.federation.codec import (
    spec_from_json,
    spec_to_json,
    update_from_parts,
    update_to_parts,
)
from frl.federation.frames import decode_frame, encode_frame


def test_a_client_spec_survives_json():
    spec = tiny_spec(2, "right", seed=7)

    assert spec_from_json(spec_to_json(spec)) == spec


def test_a_local_update_survives_its_parts():
    update = LocalUpdate(
        client="client1_straight",
        num_steps=3,
        total_steps=83,
        step_rewards=np.array([0.1, -0.2, 0.3], np.float32),
        episodes=[EpisodeRecord("straight", 1.5, False, True, False, 40, 82, 4.2, 3, -0.75)],
        losses={"critic_loss": np.array([np.nan, 0.5, 0.25], np.float32)},
        actions={"executed": np.array([1.0, -0.5, 0.2], np.float32)},
        parameters={"actor.layers.0.weight": torch.arange(6.0).reshape(2, 3)},
        cpu_time_s=0.75,
    )

    parameters, series, summary = update_to_parts(update)
    back = update_from_parts(parameters, series, summary)

    assert back.client == update.client and back.num_steps == 3 and back.total_steps == 83
    assert back.episodes == update.episodes and back.cpu_time_s == 0.75
    np.testing.assert_array_equal(back.step_rewards, update.step_rewards)
    np.testing.assert_array_equal(back.losses["critic_loss"], update.losses["critic_loss"])
    np.testing.assert_array_equal(back.actions["executed"], update.actions["executed"])
    assert torch.equal(back.parameters["actor.layers.0.weight"], torch.arange(6.0).reshape(2, 3))


def test_a_frame_carries_json_and_arrays_without_pickle():
    arrays = {"param/a.weight": np.ones((2, 2), np.float32), "series/step_rewards": np.zeros(3)}

    header, back = decode_frame(encode_frame({"op": "train", "num_steps": 3}, arrays))

    assert header == {"op": "train", "num_steps": 3}
    assert set(back) == set(arrays)
    np.testing.assert_array_equal(back["param/a.weight"], arrays["param/a.weight"])
    with pytest.raises(ValueError):  # object arrays would need pickle: refused on both ends
        encode_frame({}, {"x": np.array([{"a": 1}], dtype=object)})
    pickled = io.BytesIO()
    np.savez(pickled, x=np.array([{"a": 1}], dtype=object))
    frame = encode_frame({"op": "x"}) + pickled.getvalue()
    with pytest.raises(ValueError, match="pickle"):
        decode_frame(frame)


def test_a_frame_is_read_in_place_not_from_a_copy_of_its_tail():
    import tracemalloc

    weights = np.arange(2_000_000, dtype=np.float32)  # 8 MB, a model upload's size
    frame = encode_frame({"op": "train"}, {"param/w": weights})

    tracemalloc.start()
    try:
        _, back = decode_frame(frame)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()

    np.testing.assert_array_equal(back["param/w"], weights)
    # The decoded array itself, and no copy of the 8 MB archive beside it.
    assert peak < 1.5 * weights.nbytes, peak


def test_decoded_parameters_become_tensors_without_a_copy_only_when_asked():
    from frl.federation.codec import arrays_to_tensors

    decoded = {"w": np.ones(4, np.float32)}
    frozen = np.ones(4, np.float32)
    frozen.flags.writeable = False

    shared = arrays_to_tensors(decoded, copy=False)["w"]
    copied = arrays_to_tensors(decoded)["w"]
    still_copied = arrays_to_tensors({"w": frozen}, copy=False)["w"]

    assert shared.data_ptr() == decoded["w"].ctypes.data
    assert copied.data_ptr() != decoded["w"].ctypes.data
    assert still_copied.data_ptr() != frozen.ctypes.data
    assert torch.equal(shared, copied) and torch.equal(still_copied, copied)
