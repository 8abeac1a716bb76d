"""Signals: stop at a red signal group of the ego's approach, from the RSU's MAP and SPaT.

The MAP (bridges.j2735.map) says which ingress lane the ego is on and where
its stop line is; of that lane's connections, the one whose egress lane the
ego's route takes gives the signal group; the SPaT gives that group's state.
Then:

* red (stop-And-Remain, stop-Then-Proceed, pre-Movement): stop with the front
  bumper `STOP_LINE_GAP` before the stop line;
* yellow (permissive-/protected-clearance): stop if it can be done within
  `decel_comfort`, else go on (the dilemma zone is passed, not braked in);
* green, dark, unavailable, unknown group, no fresh SPaT: no constraint.

Once past its stop line the ego is in the junction and clears it. MAP nodes
are metres from the MAP's reference point; the reference point is placed in
the world with the scenario origin (the RSU uses the origin itself). MAP and
SPaT count from their FUSE time, like every V2X input.
"""
from __future__ import annotations

import math
from typing import Any

from bridges.j2735.map import IntersectionGeometry, MapData

from av_app.config import AvConfig

RED = ("stop-And-Remain", "stop-Then-Proceed", "pre-Movement")
YELLOW = ("permissive-clearance", "protected-clearance")
STOP_LINE_GAP = 0.5  # m between the front bumper and the stop line when stopped


class SignalState:
    def __init__(self, cfg: AvConfig, origin):
        self.cfg, self.origin = cfg, origin
        self._maps: list[tuple[float, list[tuple[IntersectionGeometry, float, float]]]] = []  # (usable, [(g, dx, dy)])
        self._spat: list[tuple[float, Any]] = []  # (usable from, Spat)
        self.states: dict[tuple[int, int], tuple[str, float]] = {}  # (intersection, group) -> (state, time)
        self.geometries: list[tuple[IntersectionGeometry, float, float]] = []
        self.last: dict[str, Any] = {}  # what the last evaluation found (for the plan log)

    def take_map(self, data: MapData, t_usable: float) -> None:
        """A typed MAP, usable from t_usable."""
        placed = []
        for g in data.intersections:
            dx, dy, _ = self.origin.to_local(g.ref_latitude, g.ref_longitude, g.ref_elevation)
            placed.append((g, float(dx), float(dy)))
        self._maps.append((t_usable, placed))

    def take_spat(self, spat, t_usable: float) -> None:
        self._spat.append((t_usable, spat))

    def _advance(self, t: float) -> None:
        while self._maps and self._maps[0][0] <= t + 1e-12:
            self.geometries = self._maps.pop(0)[1]  # the newest MAP replaces the previous one
        keep = []
        for usable, spat in self._spat:
            if usable > t + 1e-12:
                keep.append((usable, spat))
                continue
            for ix in spat.intersections:
                for m in ix.movements:
                    self.states[(ix.intersection_id, m.signal_group)] = (m.state, usable)
        self._spat = keep

    def stops(self, t: float, state, route, planner) -> list:
        """Stop points (planner.Stop) the signals impose on the ego at time t."""
        from av_app.planner import Stop

        self._advance(t)
        self.last = {}
        if not self.cfg.signals.enabled or not self.geometries or state is None:
            return []
        heading = (90.0 - math.degrees(state.yaw)) % 360.0
        out = []
        for g, dx, dy in self.geometries:
            found = g.ingress_lane_at(state.x - dx, state.y - dy, heading)
            if found is None:
                continue
            lane, to_stop = found
            if to_stop < 0 or lane.stop_line is None:
                continue  # past the stop line: in the junction, clear it
            group = self._group(g, lane, dx, dy, route, planner)
            if group is None:
                continue
            got = self.states.get((g.intersection_id, group))
            self.last = {"intersection": g.intersection_id, "lane": lane.lane_id, "group": group,
                         "state": got[0] if got else None}
            if got is None or t - got[1] > self.cfg.signals.max_age_s:
                continue
            phase = got[0]
            if phase not in RED and phase not in YELLOW:
                continue
            sx, sy = lane.stop_line
            s_line, _ = route.project(sx + dx, sy + dy, planner.s)
            v = self.cfg.vehicle
            s_stop = s_line - (v.length - v.rear_overhang) - STOP_LINE_GAP
            if phase in YELLOW:
                dist = s_stop - route.project(state.x, state.y, planner.s)[0]
                if dist <= 0 or state.v * state.v / (2 * dist) > self.cfg.control.decel_comfort:
                    continue  # cannot stop comfortably any more: go on through
            out.append(Stop(s_stop, "red", f"signal group {group}"))
        return out

    @staticmethod
    def _group(g: IntersectionGeometry, lane, dx: float, dy: float, route, planner) -> int | None:
        """The signal group of the connection whose egress lane the route takes."""
        best = None
        for c in lane.connections:
            if c.signal_group is None or c.remote_intersection is not None:
                continue
            try:
                egress = g.lane(c.lane)
            except KeyError:
                continue
            if not egress.nodes:
                continue
            for node in egress.nodes[:2]:
                s, lateral = route.project(node.x + dx, node.y + dy, planner.s, window=80.0)
                if best is None or abs(lateral) < best[0]:
                    best = (abs(lateral), c.signal_group)
        return best[1] if best is not None and best[0] < 2.0 else None
