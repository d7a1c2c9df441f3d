"""Fixtures shared by the tests of ccdcore (the app's are in tests/app/conftest.py)."""
from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def client():
    """A real Dask cluster for the tests of ccdcore.distributed.client: a ``LocalCluster`` of 2 worker
    processes with one thread each (as ``--workers 2`` starts), one per test module."""
    import distributed

    with distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                  dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as c:
        yield c
