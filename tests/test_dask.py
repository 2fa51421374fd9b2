"""Scale-out: a campaign on a Dask cluster (LocalCluster on loopback) equals the local run."""

import pytest

from quad_drake.campaigns import DaskRunner, run_campaign, table
from quad_drake.campaigns.output import rows
from quad_drake.config.errors import ConfigError
from quad_drake.running import catalog

distributed = pytest.importorskip("distributed")
dask = pytest.importorskip("dask")


def test_dask_campaign_equals_the_local_campaign():
    scenario = catalog.load("10_mag_update", None, ["end_time=1"])
    local = run_campaign(scenario, 3, seed=20, progress=False)
    with distributed.LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=False,
        protocol="tcp",
        host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        runner = DaskRunner(cluster.scheduler_address)
        remote = run_campaign(scenario, 3, runner=runner, seed=20, progress=False)
    assert remote.runner == f"dask {cluster.scheduler_address}"
    assert [r.seed for r in remote.records] == [20, 21, 22]
    assert table(remote) == table(local)
    assert rows(remote) == rows(local)


def test_dask_runs_fleet_batches_like_the_local_fleet():
    """Fleet batches on Dask send their slim records and tallies; table, rows and the
    consistency means equal the in-process fleet campaign's to the last bit."""
    scenario = catalog.load("11_gps_update", None, ["end_time=1"])
    local = run_campaign(scenario, 4, seed=30, progress=False, fleet_batch=2)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
    ) as cluster:
        remote = run_campaign(
            scenario, 4, runner=DaskRunner(cluster.scheduler_address), seed=30, progress=False, fleet_batch=2
        )
    assert remote.runner.startswith("fleet (batch 2) on dask ")
    assert table(remote) == table(local) and rows(remote) == rows(local)
    assert [c["statistic"] for c in remote.consistency] == ["NEES", "NIS gps", "NIS mag"]
    for a, b in zip(remote.consistency, local.consistency, strict=True):
        assert a["mean"].tobytes() == b["mean"].tobytes()


def test_an_unreachable_scheduler_is_a_config_error():
    scenario = catalog.load("10_mag_update", None, ["end_time=1"])
    with (
        dask.config.set({"distributed.comm.timeouts.connect": "2s"}),
        pytest.raises(ConfigError, match="tcp://127.0.0.1:9: cannot connect"),
    ):
        run_campaign(scenario, 1, runner=DaskRunner("tcp://127.0.0.1:9"), progress=False)
