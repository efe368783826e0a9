import pytest

from yowo_sim.capture import generate
from yowo_sim.presets import get_preset


@pytest.fixture(scope="session")
def tiny_bag(tmp_path_factory):
    """One `tiny` capture shared by the bag-level tests (about 10 s to render)."""
    path = tmp_path_factory.mktemp("sim") / "tiny_s3"
    summary = generate(get_preset("tiny"), 3, path)
    return path, summary
