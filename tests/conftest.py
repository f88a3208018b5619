"""Fixtures shared by several test files."""

import pytest
import torch


@pytest.fixture(scope="module")
def one_thread():
    """The test machine's cores are shared; one thread is fastest for the tiny graphs of the
    inverse and differentiable-MPM tests (use with pytestmark = usefixtures("one_thread"))."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
