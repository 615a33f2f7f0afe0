"""``goniofrost serve``'s page in a real headless Chromium (Playwright), on the small simulated rig:
the controls of a page opened with the token (pause, resume and stop a capture, reorder and remove
pending entries; the token never in the address bar nor a cookie), and the read-only page of a
viewer without it."""
from __future__ import annotations

import pytest

from test_monitor_browser import CHROMIUM, browser, expect, page  # noqa: F401 - the fixtures
from test_serve import Server, entry, plan  # noqa: F401 - the fixture

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(), reason=f"needs headless Chromium at {CHROMIUM} "
                                "(Debian's chromium package; .ci/run installs it)")
WAIT_MS = 60_000  # a capture's calibration can take seconds on a loaded 2-core host


@pytest.fixture
def server(plan, tmp_path):  # noqa: F811
    rig, plan_file = plan
    root = tmp_path / "root"
    root.mkdir()
    (root / plan_file.name).write_text(plan_file.read_text())
    served = Server(rig, root, speedup=5)  # a slower clock: the stop comes before the capture ends
    yield served
    served.close()


def test_the_page_controls_a_capture_with_the_token_and_only_reads_without_it(server, plan, page, browser):  # noqa: F811
    """A viewer without the token sees the state and no control; with it, a refused move shows the
    server's words, a frame is taken, and pause, resume and stop of a capture show on the page."""
    rig, plan_file = plan
    viewer, errors = browser.new_context().new_page(), []
    viewer.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        viewer.goto(server.url + "/")
        expect(viewer.locator("#state")).to_have_text("idle")
        expect(viewer.locator("#read-only")).to_be_visible()
        expect(viewer.locator("#pos-camera_arm")).to_have_text("90.00°")
        expect(viewer.locator("#axis-table tbody tr").first).to_contain_text("8° to 172°")
        for control in ("#pause", "#resume", "#stop", "#add-form", "#camera", "#move-camera_arm", "#lamp-on"):
            expect(viewer.locator(control)).to_be_hidden()
        assert viewer.evaluate("() => sessionStorage.length") == 0 and errors == []
    finally:
        viewer.context.close()

    sent = []
    page.on("request", lambda r: sent.append((r.method, r.url, r.headers.get("authorization"))))
    page.goto(f"{server.url}/?token={server.token}")
    expect(page.locator("#state")).to_have_text("idle")
    assert page.url == f"{server.url}/"  # the token left the address bar (and the history)
    page.fill("#operator", "ada")
    page.fill("#target-camera_arm", "200")
    page.click("#move-camera_arm")
    error = page.locator("#move-error")
    expect(error).to_contain_text("camera_arm: target 200 deg is outside its limits [8, 172] deg")
    assert error.get_attribute("data-field") == "targets.camera_arm"
    assert server.status()["pose"]["camera_arm"] == 90.0 and server.get("/api/actions").json() == []
    page.click("#take-frame")  # the lamp is off: a dark frame, its levels printed
    expect(page.locator("#camera-caption")).to_contain_text("auto levels: black")
    assert page.eval_on_selector("#camera-img", "img => img.naturalWidth") == 120
    caught_up(page, server)  # the frame's own running and idle are behind us: the next running is the capture's

    page.fill("#add-form [name=plan]", plan_file.name)
    page.fill("#add-form [name=sample_id]", "red-1")
    page.click("#add")
    expect(page.locator("#state")).to_have_text("running", timeout=WAIT_MS)
    page.click("#pause")
    expect(page.locator("#state")).to_have_text("paused", timeout=WAIT_MS)
    expect(page.locator("#reason")).to_contain_text("paused at plan sample")
    page.click("#resume")
    expect(page.locator("#state")).to_have_text("running", timeout=WAIT_MS)
    page.click("#stop")
    expect(page.locator("#state")).to_have_text("idle", timeout=WAIT_MS)
    expect(page.locator("#held")).to_be_visible()
    row = page.locator("#queue-table tbody tr")
    expect(row.locator(".entry-state")).to_have_text("stopped")
    expect(row).to_contain_text("interrupted by a stop request from ada at 127.0.0.1")
    actions = [(a["who"], a["action"]) for a in server.get("/api/actions").json()]
    assert actions == [("ada", "camera"), ("ada", "queue_add"), ("ada", "pause"), ("ada", "resume"), ("ada", "stop")]
    posts = [(url.removeprefix(server.url), auth) for method, url, auth in sent if method != "GET"]
    assert [url for url, _ in posts] == ["/api/move", "/api/camera", "/api/queue", "/api/pause", "/api/resume",
                                         "/api/stop"]
    assert {auth for _, auth in posts} == {f"Bearer {server.token}"}
    assert all(server.token not in url for _, url, _ in sent[1:]) and page.context.cookies() == []

    for sample in ("b-1", "b-2"):  # the queue is held after the stop: both wait
        assert server.post("/api/queue", entry(plan_file, sample_id=sample)).status_code == 201
    pending = page.locator("#queue-table tbody tr[data-state=pending]")
    expect(pending).to_have_count(2)
    first = pending.first.get_attribute("data-id")
    pending.first.locator("[data-action=down]").click()
    expect(pending.last).to_have_attribute("data-id", first)
    pending.last.locator("[data-action=remove]").click()
    expect(pending).to_have_count(1)
    assert [e["sample_id"] for e in server.get("/api/queue").json()] == ["red-1", "b-2"]


def caught_up(page, server) -> None:
    """Wait until the instrument is idle and the page has had every record published until then."""
    server.wait(lambda: server.status()["state"] == "idle", "an idle instrument")
    page.wait_for_function("n => window.goniofrostServe.lastSeq + 1 >= n", arg=server.status()["events"])
    expect(page.locator("#state")).to_have_text("idle")
