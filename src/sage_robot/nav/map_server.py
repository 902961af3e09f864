"""The ``map_server`` node: publishes ``/map`` (latched) and answers the place services.

- ``/map``: the navigation map (``nav.map`` or the shipped building), once, latched.
- ``PLACES`` (any request) → :class:`PlaceList` of every named place.
- Event ``places_changed`` on ``EVENTS`` (the web admin rewrote the waypoints file): the
  places are read again.
- ``WHERE_AM_I`` (any request) → :class:`WhereAmI`: the latest ``/amcl_pose``, the nearest
  place and whether localization is healthy.
"""

from __future__ import annotations

import math
from typing import Any

from sage_robot.core import topics
from sage_robot.core.msgs import Event, OccupancyGrid, Pose2D, PoseWithCovariance
from sage_robot.core.msgs.nav import LocalizationHealth, PlaceInfo, PlaceList, WhereAmI
from sage_robot.core.node import Node
from sage_robot.nav.mapdata import MapData, load_for, places_after


def place_list(data: MapData) -> PlaceList:
    return PlaceList(tuple(PlaceInfo(p.name, p.pose, p.description, p.aliases) for p in data.places))


class MapServerNode(Node):
    name = "map_server"

    async def setup(self) -> None:
        self.data = load_for(self.settings)
        self._pose: PoseWithCovariance | None = None
        self._health: LocalizationHealth | None = None
        self.bus.declare(topics.MAP, OccupancyGrid, latched=True)
        g = self.data.grid
        self.bus.publish(topics.MAP, OccupancyGrid(self.clock.now(), "map", g.resolution, g.origin, g.data))
        self.subscribe(topics.AMCL_POSE, PoseWithCovariance, self._on_pose)
        self.subscribe(topics.LOC_HEALTH, LocalizationHealth, self._on_health)
        self.subscribe(topics.EVENTS, Event, self._on_event, maxsize=50)
        self.bus.serve(topics.PLACES, self._places)
        self.bus.serve(topics.WHERE_AM_I, self._where)

    def _on_pose(self, msg: PoseWithCovariance) -> None:
        self._pose = msg

    def _on_health(self, msg: LocalizationHealth) -> None:
        self._health = msg

    def _on_event(self, event: Event) -> None:
        self.data = places_after(event, self.data, self.log)

    async def _places(self, _request: Any) -> PlaceList:
        return place_list(self.data)

    async def _where(self, _request: Any) -> WhereAmI:
        pose = self._pose.pose if self._pose else Pose2D(math.nan, math.nan, math.nan)
        localized = self._pose is not None and not (self._health is not None and self._health.lost)
        if self._pose is None or len(self.data.places) == 0:
            return WhereAmI(pose, "", math.nan, localized)
        place, dist = self.data.places.nearest(pose.x, pose.y)
        return WhereAmI(pose, place.name, dist, localized)

    async def teardown(self) -> None:
        for name in (topics.PLACES, topics.WHERE_AM_I):
            self.bus.unserve(name)

    def stats(self) -> dict[str, Any]:
        return {"places": len(self.data.places), "cells": int(self.data.grid.data.size)}
