"""The bundled samples are exactly what samples/generate.py makes."""

import sys
from pathlib import Path

SAMPLES = Path(__file__).resolve().parents[1] / "samples"
sys.path.insert(0, str(SAMPLES))
from generate import generate  # noqa: E402


def test_committed_samples_are_generated(tmp_path):
    for path in generate(tmp_path):
        assert (SAMPLES / path.name).read_bytes() == path.read_bytes(), f"samples/{path.name} is stale; run python samples/generate.py"
