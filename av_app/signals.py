"""Signals: stop at a red signal group of the ego's approach, from SPaT and MAP.

Filled in below once the typed MAP codec (bridges.j2735.map) is available; until
a MAP and a SPaT have been received, no signal constrains the plan.
"""
from __future__ import annotations

from av_app.config import AvConfig


class SignalState:
    def __init__(self, cfg: AvConfig, origin):
        self.cfg, self.origin = cfg, origin
        self.spat = None
        self.map_message = None

    def take_spat(self, spat, t: float) -> None:
        self.spat = (t, spat)

    def take_map(self, message, t: float) -> None:
        self.map_message = (t, message)

    def stops(self, t, state, route, planner) -> list:
        return []
