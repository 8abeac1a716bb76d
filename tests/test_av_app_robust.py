"""The AV app keeps driving on inputs a run that falls behind real time produces (found running the case
study in realtime at RTF 1 on a 2-core machine: the app crashed twice)."""
from __future__ import annotations

import math

import numpy as np

from av_app.config import build
from av_app.ego import EgoFilter
from av_app.route import Route


def test_a_station_hint_off_the_route_searches_the_whole_route():
    route = Route([[1.75, -120.0], [1.75, -1.75], [120.0, -1.75]], 6.0)
    s_far, lateral_far = route.project(1.75, -50.0, s_hint=route.s[-1] + 500.0)  # was: argmin of nothing
    s_ok, lateral_ok = route.project(1.75, -50.0)
    assert s_far == s_ok and lateral_far == lateral_ok and abs(s_ok - 70.0) < 0.5
    assert route.project(1.75, -50.0, s_hint=math.nan)[0] == s_ok


def test_an_ego_filter_whose_covariance_broke_starts_again_from_the_next_fix():
    ego = EgoFilter(build({"security": {"allow_unsecured": True}}).ego)
    assert ego.gnss(0.0, 1.75, -50.0, math.pi / 2, 8.3)
    ego.ukf.P = np.full((5, 5), np.nan)  # what out-of-order inputs left behind (LinAlgError on update)
    assert ego.gnss(0.1, 1.75, -49.2, math.pi / 2, 8.3)
    assert ego.resets == 1
    st = ego.state()
    assert (st.x, st.y, st.v) == (1.75, -49.2, 8.3) and math.isfinite(st.pos_std)
    ego.ukf.P = np.full((5, 5), np.nan)
    assert not ego.status(0.15, 8.3, 0.0)  # a status cannot restart it: it waits for the next fix
    assert ego.resets == 2 and ego.state() is None
    assert ego.gnss(0.2, 1.75, -48.4, math.pi / 2, 8.3) and ego.state().y == -48.4
