"""The visitor scenario end to end on the simulated clock: the words a visitor says reach
the brain (converse), its reply is spoken (/sage/say) and the robot drives to the café
through navigation, the serial bridge and the firmware model."""

from __future__ import annotations

from typing import Any

from sage_robot.app.runtime import make_context, run_launcher, specs_for
from sage_robot.core import topics
from sage_robot.core.config import load_profile
from sage_robot.core.msgs import Event, Text
from sage_robot.sim.node import SCENARIO_RESOURCE, SUMMARY_RESOURCE, WORLD_RESOURCE
from sage_robot.sim.scenario import load_scenario

NODES = ("sim_world", "mcu_sim", "serial_bridge", "map_server", "localization", "navigator", "brain")
CAFE = "GUELLY_DELLY"


async def test_a_visitor_asking_for_the_cafe_is_answered_and_taken_there() -> None:
    scenario = load_scenario("visitor")
    overrides = scenario.settings_overrides()
    overrides["sim"] = {**overrides.get("sim", {}), "speed": None, "camera_hz": 0}
    ctx = make_context(load_profile(None, overrides), simulated=True)
    ctx.resources[SCENARIO_RESOURCE] = scenario
    said: list[Text] = []
    ctx.bus.subscribe(topics.SAY, Text, said.append, maxsize=100)

    async def stop_on_arrival(launcher: Any) -> None:
        def on_event(ev: Event) -> None:
            if ev.kind == "arrived":
                launcher.request_stop()

        ctx.bus.subscribe(topics.EVENTS, Event, on_event, maxsize=1000)

    specs = [s for s in specs_for("sim") if s.name in NODES]
    assert len(specs) == len(NODES)
    # Bounded on the simulated clock by the scenario's duration_s (150 s; arrival ~107 s).
    await run_launcher(ctx, specs, until=scenario.duration_s, after_start=stop_on_arrival)
    summary = ctx.resources[SUMMARY_RESOURCE]
    (talk,) = summary["conversations"]
    assert talk["heard"] == "take me to the cafe please"
    assert talk["status"] == "succeeded"
    replies = talk["replies"]
    assert replies
    assert [t.data for t in said[: len(replies)]] == replies  # spoken in order
    assert "Guelly Delly" in replies[0]
    (arrival,) = summary["arrivals"]
    assert arrival["place"] == CAFE
    assert arrival["at_s"] > talk["sent_s"]
    world = ctx.resources[WORLD_RESOURCE]
    assert world.collisions == 0
