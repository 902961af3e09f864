"""Every page's layout and accessibility in a real Chromium, on the simulated robot.

At a phone (390x844), a laptop (1280x800) and a small laptop screen (1366x768):
no page scrolls sideways, the teleop E-STOP is fully inside the window (also scrolled to
the bottom, and with the e-stop banner showing, which overlays instead of pushing the page
down). Screenshots of every page at every size land in $SAGE_ARTIFACTS/web/layout (default
/tmp/sage-artifacts/web/layout).

Every control (button, link, field, slider, ...) in Chromium's accessibility tree has a name;
the teleop wheel, pedals, joystick, speed slider and E-STOP by the names they must have.

Accessibility: axe-core (from the npm registry, pinned in scripts/bootstrap.sh, installed
into tests/web/.axe) runs inside each page: no serious or critical violation (WCAG 2.1 AA
contrast, labels, ARIA). Every violation found, of any impact, is written to
``axe-<page>.json`` next to the screenshots.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.browser

WAIT_MS = 30_000
SIZES = {"phone": (390, 844), "laptop": (1280, 800), "small-laptop": (1366, 768)}
AXE_JS = Path(__file__).parent / ".axe" / "node_modules" / "axe-core" / "axe.min.js"
BLOCKING = ("serious", "critical")  # axe impacts that fail the test
# A page is ready once this selector is in it (its first data arrived).
PAGES = {
    "index": ("/", "#nodes tr"),
    "login": ("/login", "#password"),
    "teleop": ("/teleop", "#link.up"),
    "admin": ("/admin", "#nodes tr"),
    "face": ("/face", "#mouth"),
    "talk": ("/talk", "#ptt"),
}
SCROLL_WIDTH = "[document.scrollingElement.scrollWidth, window.innerWidth]"
BOX_IN_VIEW = """(sel) => {
  const r = document.querySelector(sel).getBoundingClientRect();
  return {left: r.left, top: r.top, right: r.right, bottom: r.bottom, w: innerWidth, h: innerHeight};
}"""
SETTLE = "new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(() => done(true))))"


@pytest.fixture(scope="module")
def shots(robot: Any) -> Path:
    path: Path = robot.artifacts / "layout"
    path.mkdir(parents=True, exist_ok=True)
    print(f"\nlayout screenshots and axe reports: {path}")
    return path


@pytest.fixture(scope="module")
def context(browser: Any, robot: Any) -> Iterator[Any]:
    """A browser context with the operator's login (through the login API)."""
    ctx = browser.new_context(viewport={"width": 1280, "height": 800})
    resp = ctx.request.post(f"{robot.url}/api/login", data={"password": robot.password})
    assert resp.ok, resp.text()
    yield ctx
    ctx.close()


def open_page(context: Any, robot: Any, name: str) -> Any:
    path, ready = PAGES[name]
    page = context.new_page()
    page.goto(f"{robot.url}{path}")
    page.wait_for_selector(ready, timeout=WAIT_MS, state="attached")
    return page


def fits(box: dict[str, float]) -> bool:
    return box["left"] >= 0 and box["top"] >= 0 and box["right"] <= box["w"] and box["bottom"] <= box["h"]


@pytest.mark.parametrize("name", list(PAGES))
def test_no_page_scrolls_sideways(context: Any, robot: Any, shots: Path, name: str) -> None:
    page = open_page(context, robot, name)
    try:
        for size, (w, h) in SIZES.items():
            page.set_viewport_size({"width": w, "height": h})
            page.evaluate(SETTLE)
            page.screenshot(path=str(shots / f"{name}-{size}.png"))
            scroll_w, inner_w = page.evaluate(SCROLL_WIDTH)
            assert scroll_w <= inner_w, f"{name} at {w}x{h} is {scroll_w} px wide: it scrolls sideways"
    finally:
        page.close()


def test_estop_always_fully_visible(context: Any, robot: Any) -> None:
    page = open_page(context, robot, "teleop")
    try:
        for w, h in SIZES.values():
            page.set_viewport_size({"width": w, "height": h})
            for where in ("top", "bottom"):
                page.evaluate("window.scrollTo(0, 0)" if where == "top" else
                              "window.scrollTo(0, document.scrollingElement.scrollHeight)")
                page.evaluate(SETTLE)
                box = page.evaluate(BOX_IN_VIEW, "#estop")
                assert fits(box), f"the E-STOP at {w}x{h}, scrolled to the {where}, is not all inside: {box}"
                # what is in the E-STOP's middle is the E-STOP: nothing covers it
                hit = page.evaluate("""(b) => document.elementFromPoint((b.left + b.right) / 2,
                                       (b.top + b.bottom) / 2).id""", box)
                assert hit == "estop", f"the E-STOP at {w}x{h} is covered by #{hit}"
    finally:
        page.close()


def test_estop_banner_overlays_instead_of_pushing_the_page(context: Any, robot: Any, shots: Path) -> None:
    page = open_page(context, robot, "teleop")
    teleop = robot.web_node().teleop
    try:
        page.set_viewport_size({"width": 1366, "height": 768})
        page.evaluate("window.scrollTo(0, 0)")
        top_before = page.evaluate("document.querySelector('main').getBoundingClientRect().top")
        robot.run(teleop.set_estop(True, "layout test"))
        page.wait_for_selector("#estop-banner.show", timeout=WAIT_MS)
        assert page.get_attribute("#estop-banner", "role") == "alert"  # screen readers say it at once
        page.evaluate(SETTLE)
        top_after = page.evaluate("document.querySelector('main').getBoundingClientRect().top")
        assert top_after == top_before, f"the banner pushed the page down {top_after - top_before} px"
        for size, (w, h) in SIZES.items():
            page.set_viewport_size({"width": w, "height": h})
            page.evaluate(SETTLE)
            page.screenshot(path=str(shots / f"teleop-estop-{size}.png"))
            assert fits(page.evaluate(BOX_IN_VIEW, "#estop")), f"the E-STOP at {w}x{h} with the banner"
            assert fits(page.evaluate(BOX_IN_VIEW, "#estop-banner")), f"the banner at {w}x{h}"
            scroll_w, inner_w = page.evaluate(SCROLL_WIDTH)
            assert scroll_w <= inner_w, f"teleop with the banner at {w}x{h} is {scroll_w} px wide"
    finally:
        robot.run(teleop.set_estop(False, "layout test"))
        page.close()


def test_places_show_human_titles(context: Any, robot: Any) -> None:
    """Place buttons read as titles; the code name is in the tooltip (and data-place)."""
    page = open_page(context, robot, "teleop")
    try:
        page.wait_for_selector("#places button", timeout=WAIT_MS)
        buttons = page.evaluate("""[...document.querySelectorAll('#places button')].map(
            (b) => [b.dataset.place, b.textContent, b.title])""")
        for code, text, tip in buttons:
            assert "_" not in text, f"{code} shows its code name: {text!r}"
            assert tip.startswith(code), tip
        names = page.evaluate("""import('/static/js/places.js').then((m) => [
            m.humanName('GUELLY_DELLY'), m.humanName('ECE_LAB_1'), m.humanName('3D_PRINTING_LAB'),
            m.kbPlaceTitle('Guelly Delly café (GUELLY_DELLY)'), m.kbPlaceTitle('Opening hours')])""")
        kb_pair = ["GUELLY_DELLY", "Guelly Delly café"]
        assert names == ["Guelly Delly", "ECE Lab 1", "3D Printing Lab", kb_pair, None]
    finally:
        page.close()
    admin = open_page(context, robot, "admin")  # its places table: titles, code names in tooltips
    try:
        admin.wait_for_selector("#places tr", timeout=WAIT_MS)
        rows = admin.evaluate("""[...document.querySelectorAll('#places tr[data-place]')].map(
            (tr) => [tr.dataset.place, tr.cells[0].textContent, tr.cells[0].title])""")
        assert rows
        for code, text, tip in rows:
            assert "_" not in text, f"{code} shows its code name on /admin: {text!r}"
            assert tip == code, tip
    finally:
        admin.close()


# ---------------------------------------------------------------- accessibility (axe-core)
def axe_violations(page: Any) -> list[dict[str, Any]]:
    page.add_script_tag(path=str(AXE_JS))
    result = page.evaluate("axe.run(document, {resultTypes: ['violations']})")
    return [
        {"id": v["id"], "impact": v["impact"], "help": v["help"],
         "nodes": [{"target": n["target"], "summary": n.get("failureSummary", "")} for n in v["nodes"]]}
        for v in result["violations"]
    ]


@pytest.fixture(scope="module")
def axe() -> Path:
    if not AXE_JS.exists():
        why = (f"axe-core is not installed ({AXE_JS} is missing): run `bash scripts/bootstrap.sh setup`, "
               "which installs the pinned axe-core from the npm registry")
        if os.environ.get("CI"):
            pytest.fail(why)
        pytest.skip(why)
    return AXE_JS


@pytest.mark.parametrize("name", list(PAGES))
def test_no_serious_accessibility_violations(
    context: Any, robot: Any, shots: Path, axe: Path, name: str
) -> None:
    page = open_page(context, robot, name)
    try:
        if name in ("teleop", "admin"):  # the places (titles) have arrived
            page.wait_for_selector("#places button, #places tr", timeout=WAIT_MS)
        page.evaluate(SETTLE)
        found = axe_violations(page)
    finally:
        page.close()
    (shots / f"axe-{name}.json").write_text(json.dumps(found, indent=1))
    blocking = [v for v in found if v["impact"] in BLOCKING]
    assert not blocking, f"{name}: {json.dumps(blocking, indent=1)}"


def test_kb_admin_page_is_styled_with_a_way_back(context: Any, robot: Any, shots: Path, axe: Path) -> None:
    page = context.new_page()
    try:
        resp = page.goto(f"{robot.url}/kb/admin")
        if resp is None or resp.status == 404:
            pytest.skip("the knowledge base's router is not mounted in this robot")
        back = page.locator("header nav a[href='/admin']")
        assert back.count() == 1
        assert page.evaluate("getComputedStyle(document.body).backgroundColor") == "rgb(16, 21, 28)"
        for size, (w, h) in SIZES.items():
            page.set_viewport_size({"width": w, "height": h})
            page.evaluate(SETTLE)
            page.screenshot(path=str(shots / f"kb-admin-{size}.png"))
            scroll_w, inner_w = page.evaluate(SCROLL_WIDTH)
            assert scroll_w <= inner_w, f"/kb/admin at {w}x{h} is {scroll_w} px wide"
        count, unnamed = controls(page)
        assert count > 0
        assert unnamed == [], "/kb/admin: controls without a name"
        found = axe_violations(page)
    finally:
        page.close()
    (shots / "axe-kb-admin.json").write_text(json.dumps(found, indent=1))
    blocking = [v for v in found if v["impact"] in BLOCKING]
    assert not blocking, f"/kb/admin: {json.dumps(blocking, indent=1)}"


# ---------------------------------------------------------------- the teleop map's tools
# Records the page's API calls (path and JSON body), to see what a gesture on the map sent.
FETCH_PROBE = """
(() => {
  const native = window.fetch;
  window.sageCalls = [];
  window.fetch = (path, opts = {}) => {
    window.sageCalls.push({ path: String(path), body: opts.body ? JSON.parse(opts.body) : null });
    return native(path, opts);
  };
})();
"""


def sent(page: Any, path: str) -> list[dict[str, Any]]:
    calls: list[dict[str, Any]] = page.evaluate("window.sageCalls")
    return [c["body"] for c in calls if c["path"] == path]


POLLS = ("/api/slam/progress",)  # the teleop page asks these on a timer, whatever the user does


def commands(page: Any) -> list[dict[str, Any]]:
    """The calls the page made, less its periodic polls."""
    calls: list[dict[str, Any]] = page.evaluate("window.sageCalls")
    return [c for c in calls if c["path"] not in POLLS]


def test_go_here_drag_sets_the_heading_and_never_the_pose(context: Any, robot: Any, shots: Path) -> None:
    import math

    page = context.new_page()
    page.add_init_script(FETCH_PROBE)
    page.goto(f"{robot.url}/teleop")
    try:
        page.wait_for_selector("#map[data-map-version]", timeout=WAIT_MS)
        page.locator("#map").scroll_into_view_if_needed()
        box = page.locator("#map").bounding_box()
        assert box is not None
        x0, y0 = box["x"] + box["width"] * 0.5, box["y"] + box["height"] * 0.5
        page.mouse.move(x0, y0)  # "go here" is the default tool
        page.mouse.down()
        page.mouse.move(x0, y0 - 60, steps=5)  # drag upwards: face +y (90°)
        page.mouse.up()
        page.wait_for_function("window.sageCalls.some((c) => c.path === '/api/goal')", timeout=WAIT_MS)
        goal = sent(page, "/api/goal")[-1]
        assert abs(math.remainder(goal["theta"] - math.pi / 2, 2 * math.pi)) < 0.1, goal
        assert sent(page, "/api/initial_pose") == [], "a drag in 'go here' must not set the pose"
        page.click("#cancel")
        # "set pose": a drag asks first; Cancel sends nothing
        page.check("input[name=tool][value=pose]")
        page.mouse.move(x0, y0)
        page.mouse.down()
        page.mouse.move(x0 + 60, y0, steps=5)
        page.mouse.up()
        page.wait_for_selector("#pose-confirm:not([hidden])", timeout=WAIT_MS)
        page.screenshot(path=str(shots / "teleop-set-pose-confirm.png"))
        page.click("#pose-no")
        assert page.locator("#pose-confirm").is_hidden()
        assert sent(page, "/api/initial_pose") == []
    finally:
        page.close()


def test_place_goal_marker_and_zoom(context: Any, robot: Any, shots: Path) -> None:
    from sage_robot.core import topics
    from sage_robot.core.msgs.nav import NavigateFeedback, NavState

    page = open_page(context, robot, "teleop")
    try:
        page.wait_for_selector("#places button", timeout=WAIT_MS)
        page.wait_for_selector("#map[data-map-version]", timeout=WAIT_MS)
        code = page.get_attribute("#places button", "data-place")
        title = page.text_content("#places button")
        robot.publish(topics.NAV_STATE, NavigateFeedback(NavState.DRIVING, code or "", 12.0, 20.0))
        page.wait_for_function("window.sageMap.placeGoal() !== null", timeout=WAIT_MS)
        marker = page.evaluate("window.sageMap.placeGoal()")
        assert marker["title"] == title
        assert title in (page.text_content("#nav") or "")
        assert page.get_attribute("#nav", "title") == code
        # said to screen readers once (a polite live region), by its title
        assert page.text_content("#announce") == f"navigation: driving → {title}"
        assert page.get_attribute("#announce", "aria-live") == "polite"
        legend = page.eval_on_selector_all(".legend li:not([hidden])",
                                           "(lis) => lis.map((li) => li.textContent)")
        assert legend == ["robot", "path", "goal", "place", "person", "lidar"], legend
        page.locator("#map").scroll_into_view_if_needed()
        page.screenshot(path=str(shots / "teleop-place-goal.png"))
        robot.publish(topics.NAV_STATE, NavigateFeedback(NavState.IDLE))
        page.wait_for_function("window.sageMap.placeGoal() === null", timeout=WAIT_MS)
        # zoom: the buttons, the wheel, back to the whole map
        before = page.evaluate("window.sageMap.view().scale")
        page.click("#zoom-in")
        assert page.evaluate("window.sageMap.view().scale") > before * 1.4
        box = page.locator("#map").bounding_box()
        assert box is not None
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.wheel(0, -100)
        page.wait_for_function(f"window.sageMap.view().scale > {before * 1.6}", timeout=WAIT_MS)
        page.check("#follow")
        page.click("#zoom-fit")
        assert abs(page.evaluate("window.sageMap.view().scale") - before) < 1e-6
        assert not page.is_checked("#follow")
    finally:
        page.close()


# ---------------------------------------------------------------- every control has a name
# Roles a visitor or operator operates; each needs an accessible name (what a screen reader says).
CONTROL_ROLES = frozenset({"button", "checkbox", "combobox", "link", "listbox", "menuitem", "radio",
                           "searchbox", "slider", "spinbutton", "switch", "tab", "textbox"})
# Controls that are not native form elements, by the names the teleop page must give them.
TELEOP_CONTROLS = [("slider", "Steering wheel"), ("button", "Brake pedal"), ("button", "Gas pedal"),
                   ("group", "Touch joystick"), ("slider", "Speed"), ("button", "Emergency stop")]


def controls(page: Any) -> tuple[int, list[str]]:
    """How many controls Chromium's accessibility tree (what screen readers get) has, and those
    of them without a name."""
    cdp = page.context.new_cdp_session(page)
    try:
        found, count = [], 0
        for node in cdp.send("Accessibility.getFullAXTree")["nodes"]:
            role = (node.get("role") or {}).get("value")
            name = str((node.get("name") or {}).get("value") or "").strip()
            if node.get("ignored") or role not in CONTROL_ROLES:
                continue
            count += 1
            if name:
                continue
            described = cdp.send("DOM.describeNode", {"backendNodeId": node["backendDOMNodeId"]})["node"]
            attrs = described.get("attributes", [])
            found.append(f"{role} <{described.get('localName')} {' '.join(attrs)}>")
        return count, found
    finally:
        cdp.detach()


@pytest.mark.parametrize("name", list(PAGES))
def test_every_control_is_labelled(context: Any, robot: Any, name: str) -> None:
    from sage_robot.core import topics
    from sage_robot.core.msgs.nav import NavigateFeedback, NavState

    page = open_page(context, robot, name)
    try:
        if name in ("teleop", "admin"):  # the place buttons have arrived
            page.wait_for_selector("#places button, #places tr", timeout=WAIT_MS)
        if name == "face":  # its controls show while guiding (idle, it has none)
            robot.publish(topics.NAV_STATE, NavigateFeedback(NavState.DRIVING, "HESSE_CENTER", 12.0, 20.0))
            page.wait_for_selector("#guide-stop", state="visible", timeout=WAIT_MS)
        page.evaluate(SETTLE)
        count, unnamed = controls(page)
        assert count > 0, f"{name}: no controls in the accessibility tree"
        assert unnamed == [], f"{name}: controls without a name"
        if name == "teleop":
            for role, label in TELEOP_CONTROLS:
                assert page.get_by_role(role, name=label).count() == 1, f"no {role} named {label!r}"
        if name == "talk":
            assert page.get_by_role("button", name="Hold to talk").get_attribute("aria-pressed") == "false"
    finally:
        if name == "face":
            robot.publish(topics.NAV_STATE, NavigateFeedback(NavState.IDLE))
        page.close()


def test_set_pose_confirmed_moves_the_map_and_follows_the_robot(context: Any, robot: Any) -> None:
    """"Set pose" confirmed sends the pressed point facing the drag (here the robot's own pose,
    so localization is not disturbed); "Move map" drags the view and sends nothing; "Follow
    the robot" keeps it in the middle."""
    import math

    from sage_robot.core import topics
    from sage_robot.core.msgs import PoseWithCovariance

    from ..support.waits import wait_until

    poses: list[PoseWithCovariance] = []
    sub = robot.call(lambda: robot.bus.subscribe(topics.INITIAL_POSE, PoseWithCovariance, poses.append))
    page = context.new_page()
    page.add_init_script(FETCH_PROBE)
    page.goto(f"{robot.url}/teleop")
    try:
        page.wait_for_selector("#map[data-map-version]", timeout=WAIT_MS)
        page.wait_for_function("window.sageMap.layers.pose", timeout=WAIT_MS)
        page.locator("#map").scroll_into_view_if_needed()
        box = page.locator("#map").bounding_box()
        assert box is not None
        pose = page.evaluate("window.sageMap.layers.pose")
        px, py = page.evaluate(f"window.sageMap.toPx({pose['x']}, {pose['y']})")
        ahead = (math.cos(pose["theta"]) * 60, -math.sin(pose["theta"]) * 60)  # screen y points down
        page.check("input[name=tool][value=pose]")
        page.mouse.move(box["x"] + px, box["y"] + py)
        page.mouse.down()
        page.mouse.move(box["x"] + px + ahead[0], box["y"] + py + ahead[1], steps=5)
        page.mouse.up()
        page.wait_for_selector("#pose-confirm:not([hidden])", timeout=WAIT_MS)
        assert poses == [], "nothing is sent before the confirmation"
        page.click("#pose-yes")
        wait_until(lambda: poses, "the confirmed pose on /initialpose", 10.0)
        sent_pose = poses[-1].pose
        scale = page.evaluate("window.sageMap.view().scale")  # px per metre
        assert math.hypot(sent_pose.x - pose["x"], sent_pose.y - pose["y"]) < 2.0 / scale
        assert abs(math.remainder(sent_pose.theta - pose["theta"], 2 * math.pi)) < 0.05
        page.wait_for_function("document.getElementById('goal-msg').textContent.startsWith('pose set')",
                               timeout=WAIT_MS)
        # "Move map": the world point under the middle moves with the drag; nothing is sent
        page.check("input[name=tool][value=pan]")
        page.click("#zoom-in")
        calls = len(commands(page))
        middle = "(() => { const m = window.sageMap, v = m.view(); return m.toWorld(v.w / 2, v.h / 2); })()"
        before = page.evaluate(middle)
        cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
        page.mouse.move(cx, cy)
        page.mouse.down()
        page.mouse.move(cx + 80, cy, steps=5)
        page.mouse.up()
        after = page.evaluate(middle)
        scale = page.evaluate("window.sageMap.view().scale")
        assert abs((before[0] - after[0]) - 80 / scale) < 1.0 / scale, (before, after)
        assert abs(before[1] - after[1]) < 1.0 / scale
        assert len(commands(page)) == calls, "a pan sends nothing"
        # follow: the robot in the middle of the map
        page.check("#follow")
        x, y, w, h = page.evaluate("""(() => { const m = window.sageMap, v = m.view(), p = m.layers.pose;
                                       return [...m.toPx(p.x, p.y, v), v.w, v.h]; })()""")
        assert abs(x - w / 2) < 1, (x, w)
        assert abs(y - h / 2) < 1, (y, h)
    finally:
        robot.call(sub.close)
        page.close()
