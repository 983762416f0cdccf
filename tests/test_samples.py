"""The bundled samples are exactly what samples/generate.py makes."""

from pathlib import Path

SAMPLES = Path(__file__).resolve().parents[1] / "samples"
from generate import generate


def test_committed_samples_are_generated(tmp_path):
    for path in generate(tmp_path):
        assert (SAMPLES / path.name).read_bytes() == path.read_bytes(), f"samples/{path.name} is stale; run python samples/generate.py"
