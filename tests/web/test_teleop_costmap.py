"""The teleop map's costmap layer and its touch gestures (issue #21), in a real Chromium against
the simulated robot with the real navigator.

Costmap: the navigator publishes its local costmap on ``/nav/costmap`` (latched, 1 Hz); the
web sends it on ``/ws/live`` as a small PNG; the operator's **Costmap** switch draws it over the
map. The test finds lethal cells (walls) in the costmap the robot published and reads the
canvas's pixels there: magenta with the layer on, never with it off.

Pinch: two touch points through Chrome's input pipeline (CDP ``Input.dispatchTouchEvent`` in a
touch-enabled context: the page sees ``pointerType == "touch"`` pointer events): spreading zooms
in about the fingers' midpoint, moving both pans, and neither sends a goal.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from sage_robot.core import topics
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.nav.costmap_msg import costmap_grid
from sage_robot.web.costmap_view import LETHAL_RGBA, costmap_json

from ..support.waits import wait_until
from .conftest import SimRobot

pytestmark = pytest.mark.browser

WAIT_S = 60.0  # the navigator localizes and sees its first scan (a busy machine takes longer)
WAIT_MS = int(WAIT_S * 1000)
LAPTOP = {"width": 1280, "height": 900}
ZOOM_IN_PRESSES = 6  # × 1.5 each: a 0.05 m cell becomes several pixels wide
CELLS_CHECKED = 60  # lethal cells whose pixels are read
PINCH_SPREAD = 2.0  # the fingers end this many times farther apart than they start
PINCH_STEPS = 8  # touch moves per gesture
CELL_TOLERANCE = 2  # cells: the world point under the fingers may drift this much in a pinch


def magenta(rgba: list[int]) -> bool:
    """The lethal colour (255, 45, 150 at 90 %) over anything the map draws below it: r 233-255,
    g 44-66, b 138-160. Never lidar red, robot yellow, place violet or plan blue, nor a place
    circle's anti-aliased violet edge over a lidar point on a wall (at most r 218 with b >= 128;
    CI once read such a pixel as lethal with a looser test)."""
    r, g, b = rgba[:3]
    return r >= 220 and g <= 90 and b >= 128


@pytest.fixture(scope="module")
def costmaps(robot: SimRobot) -> list[OccupancyGrid]:
    got: list[OccupancyGrid] = []
    robot.call(lambda: robot.bus.subscribe(topics.COSTMAP, OccupancyGrid, got.append))
    wait_until(lambda: got and (got[-1].data >= 100).any(), "a costmap with lethal cells from the navigator",
               WAIT_S)
    return got


@pytest.fixture(scope="module")
def operator(browser: Any, robot: SimRobot) -> Iterator[Any]:
    context = browser.new_context(viewport=LAPTOP, has_touch=True)
    resp = context.request.post(f"{robot.url}/api/login", data={"password": robot.password},
                                    headers={"Origin": robot.url})
    assert resp.ok, resp.text()
    yield context
    context.close()


def open_teleop(operator: Any, robot: SimRobot) -> Any:
    page = operator.new_page()
    page.goto(f"{robot.url}/teleop")
    page.wait_for_selector("#link.up", timeout=WAIT_MS)
    page.wait_for_function("document.getElementById('map').dataset.mapVersion", timeout=WAIT_MS)
    return page


def pixels_at_lethal_cells(page: Any, grid: OccupancyGrid) -> list[list[int]]:
    """The canvas's RGBA at the centres of up to CELLS_CHECKED lethal cells of ``grid``."""
    rows, cols = np.nonzero(grid.data >= 100)
    pick = np.linspace(0, len(rows) - 1, min(CELLS_CHECKED, len(rows))).astype(int)
    res, o = grid.resolution, grid.origin
    points = [[o.x + (cols[i] + 0.5) * res, o.y + (rows[i] + 0.5) * res] for i in pick]
    return page.evaluate(
        """(points) => {
          const canvas = document.getElementById("map");
          const g = canvas.getContext("2d");
          const dpr = window.devicePixelRatio || 1;
          return points.map(([x, y]) => {
            const [px, py] = window.sageMap.toPx(x, y);
            return Array.from(g.getImageData(Math.round(px * dpr), Math.round(py * dpr), 1, 1).data);
          });
        }""",
        points,
    )


def redrawn(page: Any) -> None:
    """Wait for the map's next frame to be drawn."""
    page.evaluate("() => new Promise((done) => requestAnimationFrame(() => requestAnimationFrame(done)))")


def test_costmap_message_is_a_small_png_with_the_lethal_cells(costmaps: list[OccupancyGrid]) -> None:
    grid = costmaps[-1]
    msg = costmap_json(grid)
    assert max(grid.width, grid.height) <= 160
    assert msg["lethal"] == int((grid.data >= 100).sum()) > 0
    assert len(msg["png"]) < 40_000, "a few kilobytes a second per operator page"


def test_costmap_layer_toggles_and_draws_the_obstacles(operator: Any, robot: SimRobot,
                                                       costmaps: list[OccupancyGrid]) -> None:
    page = open_teleop(operator, robot)
    page.wait_for_function("document.getElementById('map').dataset.costmapStamp", timeout=WAIT_MS)
    page.check("#follow")
    for _ in range(ZOOM_IN_PRESSES):
        page.click("#zoom-in")
    redrawn(page)
    assert page.get_attribute("#map", "data-costmap-shown") == "false", "the layer starts hidden"
    off = pixels_at_lethal_cells(page, costmaps[-1])
    assert not any(magenta(p) for p in off), "no costmap colour while the layer is off"
    assert page.locator(".costmap-key").first.is_hidden()

    page.check("#costmap-on")
    page.wait_for_function("document.getElementById('map').dataset.costmapShown === 'true'", timeout=WAIT_MS)
    redrawn(page)
    on = pixels_at_lethal_cells(page, costmaps[-1])
    shown = sum(magenta(p) for p in on)
    page.screenshot(path=str(robot.artifacts / "teleop-costmap.png"))
    # walls are static: the lethal cells of the costmap the page draws are these (a few may be
    # covered by the robot's icon or a place's label)
    assert shown >= 0.8 * len(on), f"{shown} of {len(on)} lethal cells drawn ({LETHAL_RGBA}): {on[:3]}"
    assert page.locator(".costmap-key").first.is_visible()

    page.uncheck("#costmap-on")
    page.wait_for_function("document.getElementById('map').dataset.costmapShown === 'false'", timeout=WAIT_MS)
    redrawn(page)
    assert not any(magenta(p) for p in pixels_at_lethal_cells(page, costmaps[-1]))
    page.close()


def touch(cdp: Any, kind: str, points: list[tuple[float, float]]) -> None:
    cdp.send("Input.dispatchTouchEvent", {
        "type": kind,
        "touchPoints": [{"x": x, "y": y, "id": i} for i, (x, y) in enumerate(points)],
    })


def test_two_finger_pinch_zooms_about_the_fingers_and_pans(operator: Any, robot: SimRobot) -> None:
    page = open_teleop(operator, robot)
    goals: list[str] = []
    page.on("request", lambda r: goals.extend([r.url] if "/api/goal" in r.url else []))
    box = page.locator("#map").bounding_box()
    assert box is not None
    cx, cy = box["x"] + box["width"] * 0.4, box["y"] + box["height"] * 0.6  # off-centre on purpose
    local = [cx - box["x"], cy - box["y"]]
    before = page.evaluate("(p) => ({zoom: sageMap.zoom, world: sageMap.toWorld(p[0], p[1])})", local)
    cdp = page.context.new_cdp_session(page)
    half = 40.0
    touch(cdp, "touchStart", [(cx - half, cy), (cx + half, cy)])
    for i in range(1, PINCH_STEPS + 1):
        d = half * (1 + (PINCH_SPREAD - 1) * i / PINCH_STEPS)
        touch(cdp, "touchMove", [(cx - d, cy), (cx + d, cy)])
    touch(cdp, "touchEnd", [])
    redrawn(page)
    after = page.evaluate("(p) => ({zoom: sageMap.zoom, world: sageMap.toWorld(p[0], p[1])})", local)
    assert after["zoom"] == pytest.approx(before["zoom"] * PINCH_SPREAD, rel=0.05), (before, after)
    res = page.evaluate("sageMap.meta.resolution")
    drift = np.hypot(after["world"][0] - before["world"][0], after["world"][1] - before["world"][1])
    assert drift <= CELL_TOLERANCE * res, f"the point under the fingers moved {drift:.3f} m"

    # both fingers moving together: the map follows them (pan), the zoom stays
    shift = 60.0
    start = page.evaluate("(p) => sageMap.toWorld(p[0], p[1])", local)
    touch(cdp, "touchStart", [(cx - half, cy), (cx + half, cy)])
    for i in range(1, PINCH_STEPS + 1):
        dx = shift * i / PINCH_STEPS
        touch(cdp, "touchMove", [(cx - half + dx, cy), (cx + half + dx, cy)])
    touch(cdp, "touchEnd", [])
    redrawn(page)
    moved = page.evaluate("(p) => ({zoom: sageMap.zoom, world: sageMap.toWorld(p[0] + p[2], p[1])})",
                          [*local, shift])
    assert moved["zoom"] == pytest.approx(after["zoom"], rel=0.01)
    assert np.hypot(moved["world"][0] - start[0], moved["world"][1] - start[1]) <= CELL_TOLERANCE * res
    assert goals == [], "a pinch never sends the robot anywhere"
    page.close()


def test_costmap_values_follow_nav2_and_shrinking_keeps_every_obstacle() -> None:
    from sage_robot.nav import costmap as cmod
    from sage_robot.nav.costmap_msg import occupancy_values, shrink

    costs = np.array([[0, 1, cmod.MAX_NON_OBSTACLE, cmod.INSCRIBED, cmod.LETHAL, cmod.NO_INFORMATION]])
    assert occupancy_values(costs).tolist() == [[0, 1, 98, 99, 100, -1]]
    values = np.full((7, 7), -1, dtype=np.int8)
    values[0, 0], values[6, 6] = 100, 0
    assert shrink(values, 3).tolist() == [[100, -1, -1], [-1, -1, -1], [-1, -1, 0]]

    res_m = 0.05
    static = np.zeros((400, 300), dtype=bool)
    static[200, 150] = True  # one wall cell in a big room
    geom = cmod.GridGeometry(-7.5, -10.0, res_m, static.shape)
    cm = cmod.Costmap(geom, static, np.zeros_like(static), 0.2, 0.5, 3.0)
    grid = costmap_grid(cm, 1.5, max_cells=100)
    with pytest.raises(ValueError, match="max_cells must be at least 1, not 0"):
        costmap_grid(cm, 1.5, max_cells=0)
    assert (grid.width, grid.height) == (75, 100)
    assert grid.resolution == pytest.approx(4 * res_m)
    assert (grid.data == 100).sum() == 1, "the one lethal cell survives the 4x shrink"
    row, col = np.argwhere(grid.data == 100)[0]
    x, y = grid.origin.x + (col + 0.5) * grid.resolution, grid.origin.y + (row + 0.5) * grid.resolution
    wall_x, wall_y = geom.origin_x + 150.5 * res_m, geom.origin_y + 200.5 * res_m
    assert abs(x - wall_x) <= grid.resolution
    assert abs(y - wall_y) <= grid.resolution
