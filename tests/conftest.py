"""Shared test fixtures."""

import pytest


@pytest.fixture(autouse=True)
def keep_torch_threads():
    """A training config sets torch's thread count for its process (``num_threads``); every test
    gets back the count it started with."""
    import torch

    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)
