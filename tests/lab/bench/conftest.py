"""The camera bench's tests open the Aravis fakes: the acquisition tests' fixtures (tests/acquisition/conftest.py)."""

from tests.acquisition.conftest import aravis, gv_fake  # noqa: F401  (fixtures, registered by name)
