"""The attacker's pure core: its attacks, stepped through simulation time; no bus, no clock.

`hear(payload, t)` hands what the station heard to every attack (the replay
keeps it); `step(t0, t1)` gives every frame due in [t0, t1), in time order
(ties in the order the attacks were configured, so a run repeats). The process
shell (attacker.app) feeds it at each tick and publishes what it returns.
"""
from __future__ import annotations

from collections import Counter
from typing import Any

from attacker.attacks import ATTACKS, Attack, Context, Frame


class AttackerCore:
    def __init__(self, attacks: list[Attack]):
        self.attacks = attacks
        self.sent: Counter = Counter()  # by attack label
        self.heard = 0

    @classmethod
    def build(cls, specs: list[tuple[str, str, Any]], ctx: Context) -> "AttackerCore":
        """From (label, kind, params) triples (attacker.config.AttackSpec)."""
        return cls([ATTACKS[kind](label, params, ctx) for label, kind, params in specs])

    def hear(self, payload: bytes, t_arrival: float) -> None:
        self.heard += 1
        for attack in self.attacks:
            attack.hear(payload, t_arrival)

    def step(self, t0: float, t1: float) -> list[Frame]:
        frames = []
        for i, attack in enumerate(self.attacks):
            frames.extend((f.t, i, k, f) for k, f in enumerate(attack.frames(t0, t1)))
        frames.sort(key=lambda item: item[:3])
        out = [f for *_, f in frames]
        self.sent.update(f.attack for f in out)
        return out

    def summary(self) -> list[dict[str, Any]]:
        return [a.summary() for a in self.attacks]
