"""``neuralbrdf view``: the explorer's direction grids and values against independent computations,
its server, the command line's start, stop and refusals, and the page in headless Chromium driven
as a person drives it (a slider dragged with the mouse, a state given in the URL)."""

from __future__ import annotations

import base64
import io
import json
import re
import signal
import socket
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from browser import CHROMIUM, Browser
from onnx_fixtures import SpectralLambert, export_module, write_ggx_glossy, write_inplane_spectral, write_lambert

import neuralbrdf as nb
from neuralbrdf import geometry
from neuralbrdf.cli.main import main as cli
from neuralbrdf.data.colorimetry import spectral_to_linear_srgb
from neuralbrdf.data.table import write_table
from neuralbrdf.errors import InputError
from neuralbrdf.kinds import contract_metadata
from neuralbrdf.sources import virtual_truth
from neuralbrdf.explorer import grids
from neuralbrdf.explorer.launch import open_scene
from neuralbrdf.explorer.models import LUMINANCE, ViewedModel
from neuralbrdf.explorer.server import Viewer
from neuralbrdf.explorer.views import State, depends, sphere_radiance

needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (installed by .ci/run)")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """An RGB glossy model (kind nlb), a spectral MLP, a spectral truth (kind reference) and the
    virtual gold's noiseless samples on DS3 as a measurement table."""
    folder = tmp_path_factory.mktemp("view")
    truth_metadata = contract_metadata("reference", "fixture", "tests/test_view.py", wavelength_range_nm=(400.0, 700.0))
    write_table(virtual_truth("gold", "DS3"), folder / "measured.csv")
    return SimpleNamespace(
        folder=folder,
        glossy=write_ggx_glossy(folder / "glossy.onnx"),
        spectral=write_inplane_spectral(folder / "spectral.onnx"),
        truth=export_module(SpectralLambert(0.3, 0.4), folder / "truth.onnx", truth_metadata, spectral=True),
        table=folder / "measured.csv",
    )


@pytest.fixture(scope="module")
def scene(files):
    from neuralbrdf.data.table import read_table

    return open_scene([files.glossy, files.spectral], files.truth, read_table(files.table), "measured.csv")


# --------------------------------------------------------------------------- grids and values


def test_grids_follow_the_direction_conventions():
    theta_r, wi, wo = grids.plane_slice(30.0, 0.0)  # the plane of incidence: the report's signed angles
    ref_i, ref_o = geometry.inplane_to_vectors(np.full_like(theta_r, 30.0), theta_r)
    np.testing.assert_allclose(wi, ref_i, atol=1e-12)
    np.testing.assert_allclose(wo, ref_o, atol=1e-12)
    _, _, wo_90 = grids.plane_slice(30.0, 90.0)  # a plane turned by 90°: wo in the y-z plane
    np.testing.assert_allclose(wo_90[:, 0], 0.0, atol=1e-12)

    disk = grids.hemisphere_disk(30.0, size=16)
    axis = grids.disk_coordinates(16)
    x, y = np.meshgrid(axis, axis)
    theta, phi = geometry.vector_to_spherical(disk.wo)
    np.testing.assert_allclose(theta, np.hypot(x, y)[disk.inside], atol=1e-9)  # distance from the centre = θo
    np.testing.assert_allclose(np.cos(np.radians(phi)) * theta, x[disk.inside], atol=1e-9)

    cells, image = grids.half_diff_image(90.0, size=12)
    theta_h, _, theta_d, phi_d = geometry.half_diff_angles(image.wi, image.wo)
    assert image.inside.all()  # φd = 90°: every pair above the horizon
    h, d = np.meshgrid(cells, cells)
    np.testing.assert_allclose(theta_h, h.ravel(), atol=1e-8)
    np.testing.assert_allclose(theta_d, d.ravel(), atol=1e-8)
    np.testing.assert_allclose(phi_d, 90.0, atol=1e-8)


def test_lit_sphere_pairs_are_the_light_and_view_in_each_normals_frame():
    axis, image = grids.lit_sphere(40.0, 135.0, size=24)
    x, y = np.meshgrid(axis, axis)
    normal = np.stack([x[image.inside], y[image.inside], np.sqrt(1 - x[image.inside] ** 2 - y[image.inside] ** 2)], 1)
    light = geometry.spherical_to_vector(np.array(40.0), np.array(135.0))
    np.testing.assert_allclose(image.wi[:, 2], normal @ light, atol=1e-12)  # cos θi = n·l
    np.testing.assert_allclose(image.wo[:, 2], normal[:, 2], atol=1e-12)  # cos θo = n·v, v = +z
    np.testing.assert_allclose(np.sum(image.wi * image.wo, 1), light[2], atol=1e-12)  # l·v kept: a rotation
    np.testing.assert_allclose(np.linalg.norm(image.wi, axis=1), 1.0, atol=1e-12)


def test_a_lambertian_sphere_shows_its_albedo_times_the_cosine_and_the_exposure(tmp_path):
    albedo = np.array([0.8, 0.5, 0.2])
    model = ViewedModel.load(write_lambert(tmp_path / "lambert.onnx", tuple(albedo)), "lambert.onnx")
    axis, image = grids.lit_sphere(30.0, 60.0, size=20)
    x, y = np.meshgrid(axis, axis)
    normal = np.stack([x[image.inside], y[image.inside], np.sqrt(1 - x[image.inside] ** 2 - y[image.inside] ** 2)], 1)
    cosine = np.clip(normal @ geometry.spherical_to_vector(np.array(30.0), np.array(60.0)), 0, None)
    shaded = sphere_radiance(model, image, exposure_ev=1.5)
    np.testing.assert_allclose(shaded, albedo * 2**1.5 * cosine[:, None], rtol=1e-5, atol=1e-6)


def test_a_spectral_models_colour_is_the_colorimetric_integral_of_its_spectrum(files):
    """The few-wavelength rule against the 31-band CIE integral of the model's spectra, per direction
    (dim directions included), and the luminance row against colour-science's sRGB matrix."""
    model = ViewedModel.load(files.spectral, "spectral.onnx")
    assert model.rule.size < 31
    image = grids.hemisphere_disk(40.0, size=24)
    grid = np.arange(400.0, 701.0, 10.0)
    full = spectral_to_linear_srgb(nb.load(files.spectral)(np.repeat(image.wi, 31, 0), np.repeat(image.wo, 31, 0),
                                                           np.tile(grid, len(image.wi))).reshape(-1, 31), grid)
    rgb = model.linear_srgb(image.wi, image.wo)
    scale = np.linalg.norm(full, axis=1)
    assert np.max(np.linalg.norm(rgb - np.clip(full, 0, None), axis=1) / scale) < 2e-2
    np.testing.assert_allclose(LUMINANCE, [0.2126, 0.7152, 0.0722], atol=1e-4)  # IEC 61966-2-1's Y row
    np.testing.assert_allclose(model.channel(image.wi, image.wo, "Y", 550.0), rgb @ LUMINANCE)


def test_views_show_every_file_that_has_the_quantity_and_the_measured_samples_on_the_slice(scene, files):
    assert scene.defaults.channel == "Y"  # an RGB model among them: luminance first
    state = scene.defaults.updated({"theta_i": "30", "wavelength": "600", "channel": "wavelength"})
    at_wavelength = scene.view("inplane", state)
    assert [c["label"] for c in at_wavelength["curves"]] == ["spectral.onnx", "truth.onnx"]
    assert at_wavelength["missing"] == ["glossy.onnx"]  # an RGB model has no value at one wavelength
    theta_r = np.array(at_wavelength["x"])
    wi, wo = geometry.inplane_to_vectors(np.full_like(theta_r, 30.0), theta_r)
    np.testing.assert_allclose(at_wavelength["curves"][0]["y"], nb.load(files.spectral)(wi, wo, 600.0), rtol=1e-4)
    measured = virtual_truth("gold", "DS3")  # DS3 at θi = ±30°: 2 × 12 samples, drawn at θi = 30°
    theta_i, _ = measured.inplane_angles()
    assert len(at_wavelength["measured"]["x"]) == np.sum(np.abs(theta_i) == 30.0)
    at_600 = measured.values[:, list(measured.wavelengths).index(600.0)][np.abs(theta_i) == 30.0]
    assert sorted(at_wavelength["measured"]["y"]) == pytest.approx(sorted(at_600), rel=1e-4)
    luminance = scene.view("inplane", state.updated({"channel": "Y"}))
    assert len(luminance["curves"]) == 3 and not luminance["missing"]
    assert scene.view("inplane", state.updated({"plane_phi": "90"}))["measured"] is None  # off the measured plane


def test_a_model_against_itself_differs_by_nothing_and_a_different_one_by_something(files):
    same = open_scene([files.truth], files.truth)
    other = open_scene([files.spectral], files.truth)
    for scene_, zero in ((same, True), (other, False)):
        halfdiff = scene_.view("halfdiff", scene_.defaults)
        ratio = np.frombuffer(base64.b64decode(halfdiff["diffs"][0]["z"]["bdata"]), np.float32)
        sphere = scene_.view("sphere", scene_.defaults)
        assert (np.nanmax(np.abs(ratio)) == 0) == zero
        assert (sphere["diffs"][0]["mean"] == 0) == zero


def test_state_is_checked_and_unchanged_views_are_not_sent_again(scene):
    with pytest.raises(InputError, match="theta_i.*0 to 89"):
        scene.defaults.updated({"theta_i": "95"})
    with pytest.raises(InputError, match="channel.*wavelength, Y, R, G, B"):
        scene.defaults.updated({"channel": "X"})
    with pytest.raises(InputError, match="unknown view"):
        scene.view("nothing", scene.defaults)
    first = scene.view("halfdiff", scene.defaults)
    assert scene.view("halfdiff", scene.defaults.updated({"theta_i": "50"}), known=first["key"]) == {
        "key": first["key"], "unchanged": True}  # the θh–θd image does not depend on θi
    luminance = scene.defaults.updated({"channel": "Y"})
    assert "wavelength" not in depends("inplane", luminance) and "wavelength" in depends("inplane", State(channel="wavelength"))
    assert depends("hemisphere", luminance.updated({"hemisphere": "colour"})) == ("theta_i", "hemisphere")


# --------------------------------------------------------------------------- server


def _get(url: str) -> tuple[int, bytes]:
    try:
        with urllib.request.urlopen(url, timeout=30) as answer:
            return answer.status, answer.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


def test_server_serves_the_page_plotly_and_views_and_refuses_bad_queries(scene):
    with Viewer(scene) as viewer:
        assert viewer.address[0] == "127.0.0.1" and viewer.url.startswith("http://127.0.0.1:")
        status, page = _get(viewer.url)
        assert status == 200 and b'src="plotly.min.js"' in page and b"http" not in page.split(b"<body>")[0]
        status, plotly = _get(viewer.url + "plotly.min.js")
        assert status == 200 and plotly.startswith(b"/**\n* plotly.js") and len(plotly) > 1_000_000
        status, body = _get(viewer.url + "api/views?views=inplane,spectrum&theta_i=45")
        views = json.loads(body)["views"]
        assert status == 200 and set(views) == {"inplane", "spectrum"} and views["spectrum"]["pair"]["theta_i"] == 45
        status, body = _get(viewer.url + "api/views?views=inplane&wavelength=2000")
        assert status == 400 and "wavelength" in json.loads(body)["error"]
        assert _get(viewer.url + "etc/passwd")[0] == 404
        port = viewer.address[1]
    with pytest.raises(OSError):  # stopped: the socket is closed
        socket.create_connection(("127.0.0.1", port), timeout=2)


def _status_with_host(port: int, host: str | None, path: str = "/api/scene") -> tuple[int, bytes]:
    """GET ``path`` from 127.0.0.1:``port`` over a real socket with the ``Host`` header ``host``
    (none when ``None``), as a page on a rebinding domain sends it."""
    import http.client

    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    try:
        connection.putrequest("GET", path, skip_host=True)
        if host is not None:
            connection.putheader("Host", host)
        connection.endheaders()
        answer = connection.getresponse()
        return answer.status, answer.read()
    finally:
        connection.close()


def test_command_answers_only_requests_addressed_to_its_own_host_and_port(files):
    """DNS rebinding: a page on another site reaching 127.0.0.1 under its own name is refused."""
    process, url = _start([str(files.glossy)])
    try:
        port = int(url.rsplit(":", 1)[1].strip("/"))
        for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"LOCALHOST:{port}", f"[::1]:{port}"):
            assert _status_with_host(port, host)[0] == 200, host
        for host in (f"attacker.example:{port}", "attacker.example", f"127.0.0.1:{port + 1}", f"localhost.evil:{port}",
                     None, ""):
            status, body = _status_with_host(port, host)
            assert status == 403 and "answers requests to its own address" in json.loads(body)["error"], host
            assert b"glossy" not in body
    finally:
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=30)
    assert process.returncode == 0 and err == "", err


def test_a_burst_of_connections_waits_in_the_backlog_and_is_answered(scene):
    """200 connections at once complete while nothing accepts them (a backlog of 5 dropped most),
    then 200 parallel requests are all answered."""
    from concurrent.futures import ThreadPoolExecutor

    viewer = Viewer(scene)
    port = viewer.address[1]
    waiting = []
    try:
        for _ in range(200):
            waiting.append(socket.create_connection(("127.0.0.1", port), timeout=3))
    finally:
        for connection in waiting:
            connection.close()
        viewer.stop()
    assert len(waiting) == 200
    with Viewer(scene) as viewer, ThreadPoolExecutor(200) as pool:
        statuses = list(pool.map(lambda _: _get(viewer.url + "api/views?views=inplane&theta_i=30")[0], range(200)))
    assert statuses == [200] * 200


def test_ctrl_c_while_a_request_thread_starts_stops_the_server(scene, monkeypatch):
    """A Ctrl-C that lands while a worker thread is being started (its request may already be
    served) must reach serve_forever, not be lost in the bookkeeping of the worker slots."""
    import threading

    from neuralbrdf.explorer import server

    started = threading.Thread.start

    def start_then_interrupted(thread):
        started(thread)
        thread.join()
        raise KeyboardInterrupt

    viewer = Viewer(scene)
    try:
        connection = socket.create_connection(viewer.address, timeout=30)
        connection.sendall(f"GET /api/scene HTTP/1.0\r\nHost: 127.0.0.1:{viewer.address[1]}\r\n\r\n".encode())
        monkeypatch.setattr(threading.Thread, "start", start_then_interrupted)
        with pytest.raises(KeyboardInterrupt):
            viewer._server.handle_request()
        monkeypatch.undo()
        assert connection.recv(12).startswith(b"HTTP/1.0 200")
        connection.close()
        # every slot is free again, none freed twice
        assert all(viewer._server._workers.acquire(blocking=False) for _ in range(server.MAX_WORKERS))
        assert not viewer._server._workers.acquire(blocking=False)
    finally:
        viewer.stop()


def test_silent_connections_hold_a_bounded_number_of_threads_and_are_closed(scene, monkeypatch):
    """1 000 half-open connections held 1 000 threads for ever: now at most MAX_WORKERS threads
    serve at once and a connection silent for the socket timeout is closed."""
    import threading
    import time

    from neuralbrdf.explorer import server

    monkeypatch.setattr(server._Handler, "timeout", 0.5)
    before = threading.active_count()
    silent = []
    with Viewer(scene) as viewer:
        port = viewer.address[1]
        try:
            for _ in range(100):
                silent.append(socket.create_connection(("127.0.0.1", port), timeout=30))
            time.sleep(0.3)
            most = threading.active_count()
            for connection in silent:  # each is closed by the server: recv sees the end
                assert connection.recv(1) == b""
            most = max(most, threading.active_count())
            assert most <= before + 1 + server.MAX_WORKERS, most
            assert _get(viewer.url + "api/scene")[0] == 200
        finally:
            for connection in silent:
                connection.close()


# --------------------------------------------------------------------------- command line


@pytest.mark.parametrize("case", ["missing", "damaged", "truth of another kind", "port in use", "reference alone",
                                  "bad table"])
def test_bad_input_is_one_line_and_exit_2_before_serving(files, tmp_path, capsys, case):
    damaged = tmp_path / "damaged.onnx"
    damaged.write_bytes(files.spectral.read_bytes()[:-200])
    table = tmp_path / "table.csv"
    table.write_text("theta_i,phi_i,theta_o,phi_o,R,G,B\n30,0,30,180,0.1,0.2,nan\n")
    args = {"missing": [str(tmp_path / "nothing.onnx")],
            "damaged": [str(damaged)],
            "truth of another kind": [str(files.spectral), "--truth", str(files.glossy)],
            "reference alone": [str(files.spectral), "--reference", str(files.table)],
            "bad table": [str(files.spectral), "--table", str(table)]}
    expected = {"missing": "nothing.onnx: no such ONNX model file", "damaged": "damaged.onnx: not an ONNX model",
                "truth of another kind": "glossy.onnx: is a model of kind 'nlb'; a truth must be kind 'reference'",
                "port in use": "cannot listen on 127.0.0.1 port", "reference alone": "--reference goes with",
                "bad table": "table.csv, line 2"}
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        args["port in use"] = [str(files.spectral), "--port", str(taken.getsockname()[1])]
        assert cli(["view", *args[case]]) == 2
    out, err = capsys.readouterr()
    assert "serving" not in out
    assert len(err.strip().splitlines()) == 1 and expected[case] in err, err


def test_a_unit_slip_in_the_table_names_the_views_own_option(files, tmp_path, capsys):
    """The refusal said "read it with trust_units=True", which neuralbrdf view did not take."""
    import dataclasses

    from neuralbrdf.data.table import read_table

    gold = read_table(files.table)
    radians = tmp_path / "radians.csv"
    write_table(dataclasses.replace(gold, **{name: np.radians(getattr(gold, name)) for name in
                                             ("theta_i", "phi_i", "theta_o", "phi_o")}), radians)
    assert cli(["view", str(files.spectral), "--table", str(radians)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(radians) in err[0] and "--trust-units" in err[0] and "trust_units=True" not in err[0]
    with pytest.raises(InputError, match=r"nb\.read\(TABLE, trust_units=True\)"):
        nb.view(files.spectral, table=radians)
    assert nb.read(radians, trust_units=True).samples.n_rows == gold.n_rows   # what view --trust-units reads


def _listening_address(port: int) -> str | None:
    """The local IPv4 address a socket listens on at ``port`` (from /proc/net/tcp), else ``None``."""
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, _, state = line.split()[1:4]
        address, local_port = local.split(":")
        if int(local_port, 16) == port and state == "0A":  # LISTEN
            return socket.inet_ntoa(bytes.fromhex(address)[::-1])
    return None


def _start(args: list[str]) -> tuple[subprocess.Popen, str]:
    """``neuralbrdf view ARGS --port 0`` in a subprocess; it and its address (from its first line)."""
    # SIGINT as a terminal gives it, also where this test was started in the background (a shell
    # starts background jobs with SIGINT ignored, and Python then installs no handler for it)
    process = subprocess.Popen([sys.executable, "-m", "neuralbrdf", "view", *args, "--port", "0"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    first = process.stdout.readline()
    found = re.fullmatch(r"serving (http://127\.0\.0\.1:(\d+)/)\n", first)
    if not found:
        process.kill()
        raise AssertionError(f"first line {first!r}; stderr: {process.communicate()[1][-2000:]}")
    return process, found.group(1)


def test_command_serves_on_loopback_only_and_stops_cleanly_on_sigint(files):
    process, url = _start([str(files.glossy)])
    try:
        port = int(url.rsplit(":", 1)[1].strip("/"))
        assert _listening_address(port) == "127.0.0.1"  # bound to loopback, not 0.0.0.0
        assert _get(url + "api/scene")[0] == 200
    finally:
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=30)
    assert process.returncode == 0 and out.rstrip().endswith("stopped") and err == "", err
    assert _listening_address(port) is None


# --------------------------------------------------------------------------- the page in a browser


def _picture(path: Path) -> np.ndarray:
    from matplotlib import image

    return image.imread(io.BytesIO(path.read_bytes()))[..., :3]


def _settled(browser: Browser) -> None:
    """Wait until no update is under way and no view on screen is stale."""
    browser.wait_for("document.body?.dataset.busy === '0' && document.body.dataset.updates !== undefined")


def _shot(browser: Browser, view: str, path: Path) -> np.ndarray:
    browser.screenshot(path, f"#view-{view}")
    browser.wait_for(f"!document.body.dataset.stale.split(',').includes('{view}') && document.body.dataset.busy === '0'")
    return _picture(browser.screenshot(path, f"#view-{view}"))


@needs_chromium
def test_page_draws_and_a_dragged_slider_redraws_the_slice(files, tmp_path):
    process, url = _start([str(files.spectral), "--truth", str(files.truth), "--table", str(files.table)])
    try:
        with Browser(tmp_path / "profile") as browser:
            browser.open(url)
            browser.wait_for("document.body?.dataset.ready === '1'", timeout=120)
            # the views on screen are drawn, those below wait until scrolled to
            assert browser.evaluate("document.getElementById('plot-inplane').classList.contains('js-plotly-plot')")
            assert "sphere" in browser.evaluate("document.body.dataset.stale")
            before = _shot(browser, "inplane", tmp_path / "before.png")
            assert before.std() > 0.05  # axes, curves and text, not a blank box
            reached = browser.drag_slider("#control-theta_i", 60)
            assert reached > 45
            _settled(browser)
            after = _shot(browser, "inplane", tmp_path / "after.png")
            assert np.abs(after - before).mean() > 0.002  # the curves moved with θi
            assert f"theta_i={reached:g}" in browser.evaluate("location.search")
            timings = browser.evaluate("window.viewerTimings")
            assert any(t["cause"] == "theta_i" and "inplane" in t["views"] for t in timings), timings
            assert not browser.problems(), browser.problems()
    finally:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=30)


@needs_chromium
def test_a_click_anywhere_on_the_slice_chart_picks_its_outgoing_angle(files, tmp_path):
    """The page says "click the chart", but only a click on a curve picked: a click in the empty top
    of the chart, far from every curve, now picks the angle under it as well."""
    process, url = _start([str(files.spectral), "--truth", str(files.truth)])
    try:
        with Browser(tmp_path / "profile") as browser:
            browser.open(url)
            browser.wait_for("document.body?.dataset.ready === '1'", timeout=120)
            _settled(browser)
            x, y = browser.evaluate(
                "(() => { const gd = document.getElementById('plot-inplane'); const box = gd.getBoundingClientRect();"
                " const size = gd._fullLayout._size; return [box.left + size.l + gd._fullLayout.xaxis.d2p(-55),"
                " box.top + size.t + 4]; })()")
            for kind in ("mouseMoved", "mousePressed", "mouseReleased"):
                browser.call("Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": "left",
                                                          "buttons": 0 if kind == "mouseReleased" else 1,
                                                          "clickCount": 1})
            picked = browser.wait_for("new URLSearchParams(location.search).get('pick_theta')", timeout=30)
            assert abs(float(picked) - 55) <= 1, picked
            assert not browser.problems(), browser.problems()
    finally:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=30)


@needs_chromium
def test_rgb_files_only_draw_no_empty_spectrum_axes_and_metadata_keys_stay_whole(files, tmp_path):
    """With RGB files only the spectrum chart drew empty axes of −1…6 nm, and the file table's
    metadata keys wrapped letter by letter."""
    from onnx_fixtures import Lambert, rgb_metadata

    # a long unbroken metadata value (a provenance path) squeezes the key column
    metadata = {**rgb_metadata("nlb"), "neuralbrdf.provenance": "/runs/" + "a_long_folder_name/" * 40 + "best.ckpt"}
    model = export_module(Lambert((0.5, 0.4, 0.3)), tmp_path / "long.onnx", metadata, spectral=False)
    process, url = _start([str(model)])
    try:
        with Browser(tmp_path / "profile", width=900) as browser:
            browser.open(url)
            browser.wait_for("document.body?.dataset.ready === '1'", timeout=120)
            browser.evaluate("document.getElementById('view-spectrum').scrollIntoView()")
            browser.wait_for("document.getElementById('plot-spectrum')._fullLayout !== undefined && "
                             "!document.body.dataset.stale.split(',').includes('spectrum')", timeout=60)
            layout = browser.evaluate("(() => { const l = document.getElementById('plot-spectrum')._fullLayout; "
                                      "return [l.xaxis.visible, l.yaxis.visible, l.title.text]; })()")
            assert layout == [False, False, "no spectral file: colours only"], layout
            lines = browser.evaluate(  # the line boxes of each key's text
                "(() => { const d = document.querySelector('table.files details'); d.open = true;"
                " return [...d.querySelectorAll('table tr')].slice(1).map((r) => { const range = document.createRange();"
                " range.selectNodeContents(r.cells[0]); return [r.cells[0].textContent, range.getClientRects().length]; });"
                " })()")
            assert lines and all(count == 1 for _, count in lines), lines
            assert not browser.problems(), browser.problems()
    finally:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=30)


@needs_chromium
@pytest.mark.slow
def test_every_view_draws_changes_with_its_controls_and_reads_its_state_from_the_url(files, tmp_path):
    """Each view's screenshot is not blank and changes when one of its controls is dragged; a page
    opened on a URL state shows that state."""
    process, url = _start([str(files.glossy), str(files.spectral), "--truth", str(files.truth),
                           "--table", str(files.table)])
    drags = {"hemisphere": ("theta_i", 70), "lobe": ("theta_i", 10), "halfdiff": ("phi_d", 20),
             "sphere": ("light_theta", 80), "spectrum": ("pick_theta", 60), "inplane": ("plane_phi", 90)}
    try:
        with Browser(tmp_path / "profile") as browser:
            browser.open(url + "?channel=Y&hemisphere=colour&exposure=1")
            browser.wait_for("document.body?.dataset.ready === '1'", timeout=120)
            assert browser.evaluate("[+document.getElementById('control-exposure').value, "
                                    "document.getElementById('control-channel').value]") == [1, "Y"]
            for view, (control, value) in drags.items():
                before = _shot(browser, view, tmp_path / f"{view}_before.png")
                assert before.std() > 0.05, view
                browser.drag_slider(f"#control-{control}", value)
                _settled(browser)
                after = _shot(browser, view, tmp_path / f"{view}_after.png")
                assert np.abs(after - before).mean() > 0.002, view
            assert not browser.problems(), browser.problems()
    finally:
        process.send_signal(signal.SIGINT)
        process.communicate(timeout=30)


def test_python_api_serves_in_the_background_until_stopped(files):
    viewer = nb.view(files.spectral, truth=files.truth, table=files.table)
    try:
        assert viewer.url.startswith("http://127.0.0.1:") and _get(viewer.url + "api/scene")[0] == 200
        described = json.loads(_get(viewer.url + "api/scene")[1])
        assert [s["kind"] for s in described["sources"]] == ["spectral_mlp", "reference"]
        assert described["measured"]["rows"] == 57
    finally:
        viewer.stop()
