"""frl without Flower: the core imports and trains; ``backend=flower`` says what to install."""

import subprocess
import sys
import textwrap
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def test_the_core_runs_without_flower_and_backend_flower_names_the_extra(tmp_path):
    script = textwrap.dedent(
        f"""
        import sys
        sys.modules["flwr"] = None  # as if Flower were not installed
        sys.modules["ray"] = None
        sys.path.insert(0, {str(TESTS)!r})

        if __name__ == "__main__":
            import frl.federation, frl.train, frl.flower
            from train_helpers import compose_config
            from frl.train import train
            from frl.train_config import ConfigError, validate

            try:
                validate(compose_config(None, ["federation.backend=flower"]))
            except ConfigError as error:
                assert "pip install 'frl[flower]'" in str(error), error
            else:
                raise AssertionError("backend=flower validated without Flower")
            results = train(compose_config({str(tmp_path / "run")!r},
                ["total_steps=20", "interval=10", "eval_episodes=0", "federation.tasks=[left]"]))
            assert results["rounds"] == 1, results
            assert not any(name.startswith(("flwr.", "ray.")) for name in sys.modules)
            print("core ok")
        """
    )
    path = tmp_path / "no_flower.py"
    path.write_text(script)

    done = subprocess.run([sys.executable, str(path)], capture_output=True, text=True, timeout=300)

    assert done.returncode == 0, done.stderr[-3000:]
    assert "core ok" in done.stdout
