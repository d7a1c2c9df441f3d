"""The edges of the Dask cluster paths (ccdcore.distributed.client): a local cluster listens on
127.0.0.1 only and has no dashboard unless asked; an absurd ``--workers`` and an address that is
no Dask scheduler fail in one line, within a bounded time; a small file declaring a huge image
is refused from its header before any band is decoded."""
from __future__ import annotations

import socketserver
import threading
import time
from pathlib import Path
from typing import Iterator

import pytest

from ccdcore.distributed import band_tasks as dask_bands
from ccdcore.distributed import client as ccd_dist
from ccdcore.cli.command import main
from ccdcore.errors import CcdError, ImageReadError
from imagefiles import bomb_tiff





# ------------------------------------------------------------------------ the local cluster --
def _listening_hosts(client) -> list[str]:
    """The hosts of every socket listening in this process (the scheduler, its HTTP server,
    the nannies) and in its child processes (the workers and their HTTP servers)."""
    import psutil
    me = psutil.Process()
    hosts = []
    for proc in [me, *me.children(recursive=True)]:
        try:
            conns = proc.net_connections(kind="inet")
        except psutil.Error:
            continue
        hosts += [c.laddr.ip for c in conns if c.status == psutil.CONN_LISTEN]
    for addr in [client.scheduler.address, *client.scheduler_info()["workers"]]:
        hosts.append(addr.split("://")[1].rsplit(":", 1)[0])
    return hosts


def _http_status(client, path: str) -> int:
    """The HTTP status of ``path`` on the scheduler's HTTP server."""
    import urllib.error
    import urllib.request

    server = client.cluster.scheduler.services["dashboard"]
    try:
        with urllib.request.urlopen(f"http://{server.address}:{server.port}{path}",
                                    timeout=5) as answer:
            return answer.status
    except urllib.error.HTTPError as err:
        return err.code


def test_local_cluster_listens_on_loopback_without_a_dashboard(monkeypatch):
    monkeypatch.delenv(ccd_dist.DASHBOARD_ENV, raising=False)
    with ccd_dist.get_client(workers=1) as client:
        hosts = _listening_hosts(client)
        # Dask's scheduler always serves /health; the dashboard's pages are not there
        assert _http_status(client, "/health") == 200
        assert _http_status(client, "/status") == 404
        assert client.cluster.scheduler.services["dashboard"].port != 8787
        info = client.scheduler_info()
        assert len(info["workers"]) == 1
    assert hosts and set(hosts) == {"127.0.0.1"}, hosts


def test_the_dashboard_when_asked_is_on_loopback(monkeypatch):
    monkeypatch.setenv(ccd_dist.DASHBOARD_ENV, "0")              # a free port on 127.0.0.1
    with ccd_dist.get_client(workers=1) as client:
        assert client.dashboard_link.startswith("http://127.0.0.1:")
        assert _http_status(client, "/status") == 200
        hosts = _listening_hosts(client)
    assert set(hosts) == {"127.0.0.1"}, hosts
    monkeypatch.setenv(ccd_dist.DASHBOARD_ENV, "here")
    with pytest.raises(CcdError, match=ccd_dist.DASHBOARD_ENV):
        with ccd_dist.get_client(workers=1):
            pass


def test_absurd_workers_is_one_line(capsys):
    healey = Path(__file__).resolve().parents[1] / "assets" / "healey94"
    start = time.monotonic()
    assert main(["ptc", str(healey), "--workers", "99999999999999999999"]) == 2
    err = capsys.readouterr().err
    assert time.monotonic() - start < 10
    assert err.count("\n") == 1 and "--workers" in err
    assert f"limit of {ccd_dist.max_workers()}" in err
    with pytest.raises(CcdError, match="limit"):
        with ccd_dist.get_client(workers=ccd_dist.max_workers() + 1):
            pass
    assert ccd_dist.max_workers() <= ccd_dist.MAX_WORKERS


# ---------------------------------------------------------------- not a Dask scheduler ---
class _Silent(socketserver.BaseRequestHandler):
    """Accepts and never answers (holds the connection until the test ends)."""

    def handle(self) -> None:
        self.server.stop.wait(30)


class _Http400(socketserver.BaseRequestHandler):
    """Answers anything with an HTTP 400 and closes."""

    def handle(self) -> None:
        self.request.settimeout(2)
        try:
            self.request.recv(4096)
        except OSError:
            pass
        self.request.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n"
                             b"Connection: close\r\n\r\n")


@pytest.fixture(params=[_Silent, _Http400], ids=["silent", "http400"])
def not_a_scheduler(request) -> Iterator[str]:
    server = socketserver.ThreadingTCPServer(("127.0.0.1", 0), request.param)
    server.daemon_threads = True
    server.stop = threading.Event()
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{server.server_address[1]}"
    finally:
        server.stop.set()
        server.shutdown()
        server.server_close()


def test_an_address_that_is_no_scheduler_fails_in_bounded_time(not_a_scheduler, monkeypatch,
                                                              capsys):
    monkeypatch.setattr(ccd_dist, "CONNECT_TIMEOUT", 2)
    start = time.monotonic()
    with pytest.raises(CcdError) as info:
        with ccd_dist.get_client(not_a_scheduler):
            pass
    elapsed = time.monotonic() - start
    message = str(info.value)
    assert elapsed < 5, elapsed
    assert message.startswith(f"{not_a_scheduler}: ") and "\n" not in message
    assert "Dask scheduler" in message
    healey = Path(__file__).resolve().parents[1] / "assets" / "healey94"
    start = time.monotonic()
    assert main(["ptc", str(healey), "--scheduler", not_a_scheduler]) == 2
    assert time.monotonic() - start < 6
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and not_a_scheduler in err


# ------------------------------------------------------------------- the pixel limit ---
def _bomb_session(root: Path) -> Path:
    """A photon-transfer session whose every frame is a small TIFF declaring 40000 x 40000."""
    bomb = bomb_tiff(root / "bomb.tif", 40000, 40000)
    lines = ["schema = 1", "", "[camera]", 'name = "bomb"', "bits = 8", 'layout = "mono"',
             "black_level = 0.0", ""]
    names = [("dark", f"dark/d{i}.tif", 0.01, None) for i in range(2)]
    names += [("ptc", f"ptc/l{lv}_{i}.tif", 0.01 * (lv + 1), lv) for lv in range(3)
              for i in range(2)]
    for role, rel, exposure, level in names:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).hardlink_to(bomb)
        lines += ["[[frames]]", f'path = "{rel}"', f'role = "{role}"', f"exposure = {exposure}"]
        lines += [] if level is None else [f"level = {level}"]
        lines += [""]
    bomb.unlink()
    (root / "session.toml").write_text("\n".join(lines))
    return root


def test_ptc_on_a_cluster_refuses_a_bomb_from_its_header(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("CCDCORE_MAX_PIXELS", raising=False)
    session = _bomb_session(tmp_path / "bomb")
    start = time.monotonic()
    assert main(["ptc", str(session), "--workers", "1"]) == 2
    elapsed = time.monotonic() - start
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "40000x40000" in err and "over the limit" in err and "CCDCORE_MAX_PIXELS" in err
    assert elapsed < 60, elapsed                  # (a cluster's start; was minutes of decoding)
    # (the session's own checks refuse it first, from the headers; the cluster functions'
    # own refusal, for frames given as paths, is pinned by the next test)


def test_cluster_readers_refuse_a_bomb_before_submitting(tmp_path, monkeypatch):
    monkeypatch.delenv("CCDCORE_MAX_PIXELS", raising=False)
    bombs = [bomb_tiff(tmp_path / f"b{i}.tif", 40000, 40000) for i in range(2)]

    class NoClient:
        def submit(self, *args, **kwargs):
            raise AssertionError("a task was submitted")

    with pytest.raises(ImageReadError, match="over the limit") as info:   # hdr: check_bracket
        ccd_dist.check_bracket(bombs)
    assert str(info.value).startswith(str(bombs[0])) and "\n" not in str(info.value)
    shape = (40000, 40000)
    for call in (lambda: ccd_dist.band_moments(NoClient(), bombs, shape=shape),
                 lambda: ccd_dist.pair_sums(NoClient(), {1: [tuple(bombs)]}, shapes={1: shape},
                                            roi=None, full=None),
                 lambda: ccd_dist.frame_sums(NoClient(), bombs, shape=shape, roi=None),
                 lambda: ccd_dist.band_merge(NoClient(), bombs, None, layout="mono",
                                             bloom_radius=0, shape=shape)):
        with pytest.raises(ImageReadError, match="over the limit"):
            call()
    # a worker checks each file's header too (a frame larger than the first one declared)
    with pytest.raises(ImageReadError, match="40000x40000"):
        dask_bands.read_band(ccd_dist.Frame(str(bombs[1]), "b1.tif"), 0, 0, 10, 10)
    monkeypatch.setenv("CCDCORE_MAX_PIXELS", str(40000 * 40000))
    ccd_dist.check_pixels(bombs[0], shape)        # the same override as the streamed reader



class _ClosingFails:
    """A stand-in for Dask's LocalCluster and Client whose close fails, as a cluster's does
    after Ctrl+C has already stopped its worker processes."""

    def __init__(self, *args, **kwargs):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        raise AssertionError("the cluster's workers are gone")


def test_ctrl_c_with_a_local_cluster_stays_an_interrupt(monkeypatch):
    """Ctrl+C while a local cluster runs reaches the command as KeyboardInterrupt (exit 130,
    no traceback), not as the error of closing a cluster whose workers it also stopped; any
    other failure while closing is still raised."""
    import distributed

    monkeypatch.setattr(distributed, "LocalCluster", _ClosingFails)
    monkeypatch.setattr(distributed, "Client", _ClosingFails)
    with pytest.raises(KeyboardInterrupt):
        with ccd_dist.get_client(None, 1):
            raise KeyboardInterrupt
    with pytest.raises(AssertionError):
        with ccd_dist.get_client(None, 1):
            pass
