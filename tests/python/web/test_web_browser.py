"""``fap web`` in a real browser (headless Chromium through selenium): the page against a
sim's bus polled by the C exec async master. Live frames and the node table fill in and
agree with the engine; a fault switched from the page shows as timeouts and stops when
switched off; a capture loads, its slider moves the window, the pcap download opens in
tshark, the self-contained HTML export works offline. Each flow saves a screenshot; the console must stay free of errors. Skips without
chromium / chromedriver / selenium unless CI is set."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest
from web_helpers import NODES, SITE, WAIT_S, Poller, get, get_json, need_tool, node_rows, wait_until

pytest.importorskip("aiohttp")
try:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select
except ImportError:  # pragma: no cover - the test extra has it
    if os.environ.get("CI"):
        raise
    pytest.skip("selenium not installed", allow_module_level=True)

from fap_py.web import CaptureSource, SimSource, WebServer

#: the suite's limit (pyproject.toml): the longest flow took 26 s on a loaded 2-core
#: machine with a whole CI run beside it (16 s in CI alone), a fifth of it
pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    chromium = need_tool("chromium")
    driver_path = need_tool("chromedriver")
    downloads = tmp_path_factory.mktemp("downloads")
    opts = webdriver.ChromeOptions()
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
              "--window-size=1400,1000", "--disable-extensions", "--no-first-run"):
        opts.add_argument(a)
    opts.binary_location = chromium
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    opts.add_experimental_option("prefs", {"download.default_directory": str(downloads),
                                           "download.prompt_for_download": False})
    d = webdriver.Chrome(options=opts, service=Service(driver_path))
    d.set_page_load_timeout(WAIT_S)
    d.execute_cdp_cmd("Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)})
    d.downloads = downloads
    try:
        yield d
    finally:
        d.quit()


def severe(driver) -> list:
    return [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def cell(driver, node: int, name: str) -> str:
    """A node table cell's text, read at once (the table is redrawn ten times a second)."""
    return driver.execute_script(
        f"const c = document.querySelector('#nodes tr[data-node=\"{node}\"] td.{name}');"
        "return c ? c.textContent : '';")


def column(driver, index: int) -> set:
    """The texts of one column of the frames table."""
    return set(driver.execute_script(
        f"return Array.from(document.querySelectorAll('#frames tbody tr'), r => r.cells[{index}].textContent);"))


def wait_page(cond, what: str):
    return wait_until(cond, WAIT_S, what)


@pytest.fixture()
def sim_page(browser):
    src = SimSource(SITE)
    with WebServer(src, port=0) as srv:
        srv.start()
        poller = Poller(src.describe()["master_port"])
        try:
            browser.get(srv.url)
            yield browser, srv, src, poller
        finally:
            poller.close()
            browser.get("about:blank")       # the page's stream ends before the server


def test_live_frames_and_node_table_match_the_engine(sim_page, tmp_path):
    d, srv, src, poller = sim_page
    wait_page(lambda: len(d.find_elements(By.CSS_SELECTOR, "#frames tbody tr")) > 20, "frame rows")
    wait_page(lambda: all(cell(d, n, "requests") not in ("", "0") for n in NODES), "node rows")
    assert "live" in d.find_element(By.ID, "status").text
    poller.pause()
    stats = poller.master.stats
    sim_nodes = {n["address"]: n for n in src.sim.status()["buses"][0]["nodes"]}

    def agrees() -> bool:
        reqs = [int(cell(d, n, "requests") or 0) for n in NODES]
        reps = [int(cell(d, n, "replies") or 0) for n in NODES]
        return sum(reqs) == stats.transactions and sum(reps) == stats.replies
    try:
        wait_page(agrees, "the page's counters == the master's")
    except AssertionError:
        raise AssertionError(f"{stats} {[cell(d, n, 'requests') for n in NODES]} "
                             f"{[cell(d, n, 'replies') for n in NODES]} {node_rows(srv.url)} "
                             f"{d.get_log('browser')}") from None
    for n in NODES:
        assert int(cell(d, n, "requests")) == sim_nodes[n]["requests"]
        assert int(cell(d, n, "timeouts")) == 0 and cell(d, n, "p50") != "-"
    # paused, a frame clicked: its bytes; then a node filter
    d.find_element(By.ID, "pause").click()
    wait_page(lambda: d.find_element(By.ID, "status").text == "paused", "paused")
    d.find_element(By.CSS_SELECTOR, "#frames tbody tr:last-child").click()
    wait_page(lambda: d.find_element(By.ID, "detail").text.startswith("0000  "), "the frame's bytes")
    d.find_element(By.ID, "pause").click()
    d.find_element(By.ID, "f-node").send_keys("5")
    wait_page(lambda: column(d, 4) == {"5"}, "node filter")
    assert d.find_element(By.ID, "dropped").text == "dropped 0"
    d.save_screenshot(str(tmp_path / "live.png"))
    assert severe(d) == []


def test_fault_switched_from_the_page_shows_as_timeouts_and_stops(sim_page, tmp_path):
    d, srv, src, poller = sim_page
    row = '#fault-nodes tr[data-node="5"]'
    wait_page(lambda: d.find_elements(By.CSS_SELECTOR, row + " button"), "the fault switches")
    Select(d.find_element(By.CSS_SELECTOR, row + " select")).select_by_visible_text("no_reply")
    d.find_element(By.CSS_SELECTOR, row + " button").click()
    wait_page(lambda: int(cell(d, 5, "timeouts") or 0) >= 3, "timeouts of node 5 on the page")
    assert src.sim.faults_list()[0]["kind"] == "no_reply"
    d.save_screenshot(str(tmp_path / "fault-on.png"))
    wait_page(lambda: d.find_element(By.CSS_SELECTOR, row + " button").text == "switch off", "the off switch")
    d.find_element(By.CSS_SELECTOR, row + " button").click()
    wait_page(lambda: src.sim.faults_list() == [], "the fault removed")
    poller.pause()
    before = poller.errors[5]
    try:
        wait_page(lambda: int(cell(d, 5, "timeouts")) == before, "the page's timeouts == the master's failures")
    except AssertionError:
        sim5 = [n for n in src.sim.status()["buses"][0]["nodes"] if n["address"] == 5]
        raise AssertionError(f"page: {[cell(d, 5, k) for k in ('requests', 'replies', 'timeouts')]} "
                             f"master: errors {poller.errors} {poller.master.stats} sim: {sim5} "
                             f"api: {node_rows(srv.url).get('5')}") from None
    replies, rounds = int(cell(d, 5, "replies")), poller.rounds
    poller.resume()
    wait_until(lambda: poller.rounds >= rounds + 5)
    poller.pause()
    wait_page(lambda: int(cell(d, 5, "replies")) >= replies + 5, "replies again")
    assert int(cell(d, 5, "timeouts")) == before == poller.errors[5]
    assert cell(d, 5, "state").startswith("active")
    d.save_screenshot(str(tmp_path / "fault-off.png"))
    assert severe(d) == []


def test_capture_loads_slider_moves_pcap_opens_in_tshark(browser, tmp_path):
    d = browser
    src = SimSource(SITE)
    with WebServer(src, port=0) as srv:
        srv.start()
        poller = Poller(src.describe()["master_port"], nodes=(1, 5))
        try:
            wait_until(lambda: poller.rounds >= 30)
            poller.pause()
            n = poller.master.stats.tx_frames + poller.master.stats.rx_frames
            rounds = poller.rounds
        finally:
            poller.close()
        wait_until(lambda: get_json(srv.url + "api/stats")["totals"]["frames"] >= n)
        cap = tmp_path / "bus.cap"
        cap.write_bytes(open(src.capture, "rb").read())
    with WebServer(CaptureSource(str(cap)), port=0) as cs:
        cs.start()
        d.get(cs.url)
        wait_page(lambda: d.find_element(By.ID, "status").text == "ended", "the capture read")
        wait_page(lambda: d.find_element(By.ID, "shown").text.startswith(f"{n} of {n} frames"), "every frame")
        assert d.find_element(By.ID, "slider-row").is_displayed()
        full = int(cell(d, 1, "requests"))
        assert full == rounds
        slider = d.find_element(By.ID, "slider")
        d.execute_script("arguments[0].value = 500; arguments[0].dispatchEvent(new Event('input'));", slider)
        wait_page(lambda: slider.get_attribute("data-loaded") == "500", "the window's table")
        half = int(cell(d, 1, "requests"))
        assert 0 < half < full
        shown = int(d.find_element(By.ID, "shown").text.split()[0])
        assert 0 < shown < n
        d.save_screenshot(str(tmp_path / "capture.png"))
        for f in d.downloads.iterdir():
            f.unlink()
        d.find_element(By.ID, "dl-pcap").click()
        pcap = d.downloads / "fap-web.pcap"
        wait_page(lambda: pcap.exists() and pcap.stat().st_size > 24, "the pcap download")
        assert severe(d) == []
        export = tmp_path / "export.html"
        export.write_bytes(get(cs.url + "api/export.html")[1])
        d.get("about:blank")
    # the self-contained export, offline (file://, the server gone): frames, table, slider
    d.get(export.as_uri())
    wait_page(lambda: d.find_element(By.ID, "shown").text.startswith(f"{n} of {n} frames"), "the export's frames")
    assert int(cell(d, 1, "requests")) == rounds and d.find_element(By.ID, "status").text == "export"
    slider = d.find_element(By.ID, "slider")
    d.execute_script("arguments[0].value = 500; arguments[0].dispatchEvent(new Event('input'));", slider)
    wait_page(lambda: 0 < int(cell(d, 1, "requests")) < rounds, "the export's slider")
    d.save_screenshot(str(tmp_path / "export.png"))
    assert severe(d) == []
    d.get("about:blank")
    tshark = need_tool("tshark")
    lua = tmp_path / "lua"
    subprocess.run([sys.executable, "-m", "fap_py", "monitor", "--dissectors", str(lua)], check=True,
                   capture_output=True, timeout=30)
    out = subprocess.run([tshark, "-X", f"lua_script:{lua / 'fap_monitor.lua'}", "-r", str(pcap),
                          "-T", "fields", "-e", "execasync.node"], capture_output=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert len(out.stdout.split()) == shown and set(out.stdout.decode().split()) == {"1", "5"}


def test_daemon_page_shows_its_clients_and_the_tapped_frames(browser, tmp_path):
    """A bus `fap serve` owns: the frames the daemon moves fill the table (its tap), and the
    clients table names a client with its weight and transactions."""
    from pathlib import Path

    from fap_py import execasync
    from fap_py.rs485 import RS485, RS485Mode
    from fap_py.vbus import VirtualBus
    from fap_py.web import DaemonSource

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "serve"))
    from serve_helpers import start_daemon

    d = browser
    with VirtualBus(ports=2, baud=115200) as bus, \
            execasync.Slave(bus.paths[1], node=5, handler=lambda r: r.data,
                            rs485=RS485(mode=RS485Mode.NONE)) as slave:
        slave.start()
        served = start_daemon(str(tmp_path), bus.paths[0])
        try:
            with WebServer(DaemonSource(served.url), port=0) as srv, \
                    execasync.Master(served.url + "?name=hmi&weight=3") as m:
                srv.start()
                d.get(srv.url)
                wait_page(lambda: d.find_element(By.ID, "clients").is_displayed(), "the clients section")
                for i in range(10):
                    m.transact(5, bytes([i]))
                wait_page(lambda: int(cell(d, 5, "replies") or 0) >= 10, "the tapped replies of node 5")
                rows = lambda: d.execute_script(   # noqa: E731
                    "return Array.from(document.querySelectorAll('#client-table tbody tr'),"
                    " r => Array.from(r.cells, c => c.textContent));")
                wait_page(lambda: any(r[0] == "hmi" and r[5] == "10" for r in rows()), "the hmi client row")
                hmi = [r for r in rows() if r[0] == "hmi"][0]
                assert hmi[2] == "3" and hmi[7] == "0"
                assert d.find_element(By.ID, "source").text.startswith("daemon fapd://")
                d.save_screenshot(str(tmp_path / "daemon.png"))
                assert severe(d) == []
                d.get("about:blank")
        finally:
            served.stop()
