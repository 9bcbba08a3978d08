"""The daemon's parts, each built alone from tiny inputs: no vehicle, no UDP, no flight (tests/runtime/test_daemon.py
flies them together). A fake link answers the status and odometry a test sets; a fake clock stands in for
``time.monotonic`` where a part measures how long something lasted."""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from edge_explorer.mapping.observed import ObservedMaps
from edge_explorer.plan.follow import FreeSpace
from edge_explorer.plan.registry import build_planner
from edge_explorer.plan.waypoint import path_home
from edge_explorer.runtime.daemon import (
    DaemonConfig,
    DecisionPipeline,
    FlightMaps,
    FlightPhases,
    FlightState,
    InputCheck,
    InputWatchdog,
    RunRecord,
    SetpointFeeder,
    StageTimings,
)
from edge_explorer.runtime.daemon import decisions as decisions_module
from edge_explorer.runtime.daemon import phases as phases_module
from edge_explorer.runtime.depth_sources import DepthFrame
from edge_explorer.runtime.mavlink_link import LinkError, LinkStatus, Pose
from edge_explorer.vehicle.camera import DepthIntrinsics
from edge_explorer.vehicle.dynamics import Action, load_action_table
from edge_explorer.world.grid import FREE, UNKNOWN, GridSpec

CONFIG = DaemonConfig(max_hold_s=5.0, home_hover_s=2.0, return_home=False)
HEALTHY = LinkStatus(True, False, False, True, "OFFBOARD", 0.1, 0.01, 0, 0, 0, 0, 0)


class FakeLink:
    """What the parts ask of a :class:`~edge_explorer.runtime.mavlink_link.MavlinkLink`, answered from fields."""

    def __init__(self, pose: Pose | None = None, status: LinkStatus = HEALTHY) -> None:
        self.config = SimpleNamespace(link_lost_after_s=1.5)
        self.status_now = status
        self.pose = pose
        self.holds = 0
        self.offboard_starts = 0

    def status(self) -> LinkStatus:
        return self.status_now

    def latest_pose(self) -> Pose | None:
        return self.pose

    def pose_at(self, stamp_s: float) -> Pose | None:
        return None if self.pose is None else replace(self.pose, stamp_s=stamp_s)

    def hold(self) -> None:
        if self.pose is None:
            raise LinkError("no odometry yet")
        self.holds += 1

    def start_offboard(self, warmup_s: float, timeout_s: float = 5.0) -> None:
        self.offboard_starts += 1

    def set_target(self, x: float, y: float, z: float, yaw: float) -> None:
        pass


class FakeClock:
    """``time.monotonic`` at ``now`` (the rest of the ``time`` module as it is): a module's ``time`` for the length
    of a test."""

    def __init__(self, now: float = 100.0) -> None:
        self.now = now

    def monotonic(self) -> float:
        return self.now

    def __getattr__(self, name: str) -> object:
        return getattr(time, name)


@pytest.fixture
def clock(monkeypatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(phases_module, "time", fake)
    monkeypatch.setattr(decisions_module, "time", fake)
    return fake


def _record(coverage_goal: float = 0.95) -> RunRecord:
    return RunRecord(coverage_goal, StageTimings())


def _watchdog(link: FakeLink, config: DaemonConfig = CONFIG) -> tuple[InputWatchdog, FlightState, RunRecord]:
    state, record = FlightState(), _record()
    maps = FlightMaps(config.fusion)
    watchdog = InputWatchdog(config, link, 1.0, StageTimings(), maps, state, record)  # type: ignore[arg-type]
    return watchdog, state, record


def _phases(link: FakeLink, config: DaemonConfig = CONFIG) -> tuple[FlightPhases, FlightState, RunRecord]:
    state, record = FlightState(), _record()
    feeder = SetpointFeeder(link, config.setpoint_rate_hz, StageTimings())  # type: ignore[arg-type]  # not started
    phases = FlightPhases(config, link, load_action_table(), feeder, state, FlightMaps(config.fusion), record)  # type: ignore[arg-type]
    return phases, state, record


# ---- the input watchdog ------------------------------------------------------------------------------------------


def test_the_watchdog_holds_on_stale_or_missing_odometry():
    link = FakeLink(Pose(10.0, 1.0, 1.0, 1.2, 0.0))
    watchdog, _, _ = _watchdog(link)
    assert watchdog.check(10.0).hold_reason is None
    link.status_now = replace(HEALTHY, odometry_age_s=0.5)  # older than odometry_max_age_s (0.3 s)
    assert watchdog.check(10.5).hold_reason == "odometry stale (none for more than 0.3 s)"
    link.status_now = replace(HEALTHY, odometry_age_s=None)
    assert watchdog.check(10.6).hold_reason == "odometry stale (none for more than 0.3 s)"
    link.status_now, link.pose = HEALTHY, None
    assert watchdog.check(10.7).hold_reason == "odometry stale (none for more than 0.3 s)"


def test_the_watchdog_reports_a_pose_jump_and_holds_while_it_settles():
    link = FakeLink(Pose(10.0, 1.0, 1.0, 1.2, 0.0))
    watchdog, _, _ = _watchdog(link)
    assert watchdog.check(50.0) == InputCheck(None)
    link.pose = Pose(10.1, 1.1, 1.0, 1.2, 0.0)  # 0.1 m in 0.1 s: flown, not a jump
    assert watchdog.check(50.1).jump_xy_m is None
    link.pose = Pose(10.2, 4.1, 2.0, 1.2, 0.0)  # 3.2 m in 0.1 s: a VIO reset
    check = watchdog.check(50.2)
    assert check.hold_reason == "settling after an odometry jump"
    assert check.jump_xy_m == pytest.approx((3.0, 1.0))
    assert watchdog.check(50.9) == InputCheck("settling after an odometry jump")  # jump_settle_s = 1 s, no new jump
    assert watchdog.check(51.3).hold_reason is None and watchdog.last_pose == link.pose


def test_the_watchdog_tells_a_link_loss_from_a_pilot_taking_over():
    link = FakeLink(Pose(10.0, 1.0, 1.0, 1.2, 0.0), replace(HEALTHY, connected=False))
    watchdog, state, _ = _watchdog(link)
    assert watchdog.check(1.0).hold_reason == "MAVLink link lost (no autopilot heartbeat for 1.5 s)"
    assert watchdog.link_lost_in_control
    loiter = replace(HEALTHY, mode="AUTO.LOITER")
    link.status_now = loiter  # the autopilot's offboard-loss failsafe during the loss: take control back
    assert watchdog.check(2.0).hold_reason == "autopilot in AUTO.LOITER after the link loss: re-engaging OFFBOARD"
    assert state.stop_reason is None
    link.status_now = HEALTHY
    assert watchdog.check(3.0).hold_reason is None and not watchdog.link_lost_in_control
    link.status_now = loiter  # now with the link healthy all along: a pilot
    reason = watchdog.check(4.0).hold_reason
    assert reason == state.stop_reason == "pilot took over (autopilot left OFFBOARD for AUTO.LOITER)"


def test_the_watchdog_drops_bad_frames_and_counts_them_per_reason():
    k = DepthIntrinsics.d435()
    link = FakeLink(Pose(10.0, 1.0, 1.0, 1.2, 0.0))
    watchdog, _, record = _watchdog(link)
    nan = np.full(k.shape, 2.0, np.float32)
    nan[3, 4] = np.nan
    watchdog.ingest(DepthFrame(nan, 10.0, k))
    watchdog.ingest(DepthFrame(np.zeros(k.shape, np.float32), 10.1, k))
    watchdog.ingest(DepthFrame(np.zeros(k.shape, np.float32), 10.2, k))
    watchdog.ingest(DepthFrame(np.full(k.shape, 2.0, np.float32)[:-1], 10.3, k))
    link.pose = None  # a good frame without odometry at its time
    watchdog.ingest(DepthFrame(np.full(k.shape, 2.0, np.float32), 10.4, k))
    assert record.frames_fused == 0
    assert record.frames_dropped == {
        "NaN or inf depth": 1,
        "no returns (all zero)": 2,
        "wrong shape": 1,
        "no odometry at the frame's time": 1,
    }


def test_the_watchdog_fuses_a_good_frame_and_stamps_the_flown_footprint():
    k = DepthIntrinsics.d435()
    link = FakeLink(Pose(10.0, 2.0, 1.5, CONFIG.flight_height_m, 0.0))  # at band height: the footprint counts
    watchdog, _, record = _watchdog(link)
    watchdog.maps.start(2.0, 1.5, CONFIG.band)
    watchdog.ingest(DepthFrame(np.full(k.shape, 1.5, np.float32), 10.0, k))
    assert record.frames_fused == 1 and record.frames_dropped == {}
    flown, grid = watchdog.maps.flown, watchdog.maps.flown_grid
    assert flown is not None and grid is not None and flown[grid.cell_of(2.0, 1.5)] == 1
    assert int(flown.sum()) < 60  # a 0.2 m disc of 0.05 m cells, nothing more
    watchdog.ingest(DepthFrame(np.full(k.shape, 1.5, np.float32), 10.0, k))  # the same stamp again
    assert record.frames_dropped == {"timestamp not after the last frame": 1}


def test_the_watchdog_says_the_daemon_is_blind_without_a_fused_frame():
    watchdog, _, _ = _watchdog(FakeLink())
    watchdog.frames_due_from(20.0)
    assert watchdog.blind(20.9) is None
    assert watchdog.blind(21.1) == "no usable depth frame for more than 1.0 s"


# ---- the run record ----------------------------------------------------------------------------------------------


def test_the_run_record_sums_decisions_frames_holds_path_and_stages():
    record = _record()
    record.start(100.0)
    record.frame_fused()
    record.frame_fused()
    record.frame_dropped("NaN or inf depth")
    record.hold_began(103.0, "odometry stale")
    record.hold_ended(1.5)
    for source in ("frontier", "frontier", "hover"):
        record.decision(source)
    maps = ObservedMaps.empty(GridSpec((0.0, 0.0), 0.05, (40, 40)))
    record.record_progress(101.0, Pose(101.0, 0.0, 0.0, 1.0, 0.0), maps, None, "takeoff")  # climbing: no path
    record.record_progress(102.0, Pose(102.0, 3.0, 4.0, 1.0, 0.0), maps, None, "takeoff")
    record.record_progress(103.0, Pose(103.0, 6.0, 8.0, 1.0, 0.0), maps, None, "exploring")
    record.record_progress(104.0, Pose(104.0, 6.0, 9.0, 1.0, 0.0), maps, None, "returning")
    for seconds in (0.010, 0.030):
        record.timings.add("decision", seconds)
    report = record.report(
        10.0, 2.0, ending="time limit", planner="frontier", predictor=False, exploration_s=5.0, returned_home=False
    )
    assert (report.decisions, report.waypoint_sources) == (3, {"frontier": 2, "hover": 1})
    assert (report.frames_fused, report.frames_dropped) == (2, {"NaN or inf depth": 1})
    assert report.holds == [{"t_s": 3.0, "reason": "odometry stale", "duration_s": 1.5}]
    assert report.path_length_m == pytest.approx(6.0) and len(report.path_xy_m) == 4
    assert [t for t, *_ in report.timeline] == [1.0, 2.0, 3.0, 4.0] and report.coverage is None
    assert report.stages["decision"].count == 2 and report.stages["decision"].mean_ms == pytest.approx(20.0)
    assert set(report.stages) == {"decision", "coverage"}  # the maps' unverified area is measured without a plan
    assert report.stages["coverage"].count == 4  # (issue #56)
    progress = record.progress(105.0, "returning", None)
    assert (progress.elapsed_s, progress.decisions, progress.path_length_m) == (5.0, 3, pytest.approx(6.0))
    assert progress.decision_p95_ms == pytest.approx(29.0)


# ---- the flight phases -------------------------------------------------------------------------------------------


def test_the_phases_enter_and_leave_a_hold(clock):
    link = FakeLink(Pose(10.0, 1.0, 1.0, 1.2, 0.0))
    phases, state, record = _phases(link)
    record.start(90.0)
    phases.enter_hold("odometry stale (none for more than 0.3 s)")
    assert link.holds == 1 and phases.hold_reason.startswith("odometry stale") and phases.feeder.end_s is None
    clock.now = 101.0
    phases.enter_hold("odometry stale (none for more than 0.3 s)")
    phases.enter_hold("no usable depth frame for more than 1.0 s")  # still the same hold, for another reason
    assert link.holds == 1 and phases.hold_reason == "no usable depth frame for more than 1.0 s"
    clock.now = 102.5
    phases.leave_hold()
    assert phases.hold_reason is None and state.stop_reason is None
    assert record.holds == [{"t_s": 10.0, "reason": "odometry stale (none for more than 0.3 s)", "duration_s": 2.5}]


def test_a_hold_that_lasts_ends_the_flight_and_a_link_loss_re_engages(clock):
    link = FakeLink(Pose(10.0, 1.0, 1.0, 1.2, 0.0))
    phases, state, _ = _phases(link)
    reason = "autopilot in AUTO.LOITER after the link loss: re-engaging OFFBOARD"
    phases.enter_hold(reason, link_lost_in_control=True)
    assert link.offboard_starts == 1 and state.stop_reason is None
    clock.now += 5.5  # max_hold_s = 5
    phases.enter_hold(reason, link_lost_in_control=True)
    assert state.stop_reason == f"held position for more than 5 s ({reason})"
    ardupilot, ardupilot_state, _ = _phases(link, replace(CONFIG, autopilot="ardupilot"))
    ardupilot.enter_hold(reason.replace("OFFBOARD", "GUIDED"), link_lost_in_control=True)
    assert ardupilot_state.stop_reason == "autopilot left GUIDED during the link loss (its failsafe acted)"
    assert link.offboard_starts == 2


def test_the_phases_climb_explore_end_and_hover_home(clock):
    link = FakeLink(Pose(10.0, 1.0, 1.0, 0.5, 0.0))
    phases, state, _ = _phases(link)
    phases.climb()  # 0.5 m → 1.7 m at 0.5 m/s: 2.4 s
    assert phases.feeder.end_s == pytest.approx(100.0 + (CONFIG.flight_height_m - 0.5) / CONFIG.takeoff_speed_mps)
    at_height = replace(link.pose, z_m=CONFIG.flight_height_m)
    phases.check_takeoff_done(at_height, "frontier")
    assert state.phase == "takeoff"  # the climb's segment has not ended yet
    clock.now = 102.5
    phases.check_takeoff_done(replace(at_height, z_m=0.9), "frontier")
    assert state.phase == "takeoff"  # not at height
    phases.check_takeoff_done(at_height, "frontier")
    assert state.phase == "exploring"
    clock.now = 110.0
    phases.check_end_of_exploration(110.0, 0.5)
    assert state.phase == "exploring" and phases.exploration_s() == pytest.approx(7.5)
    phases.check_end_of_exploration(110.0, 0.96)
    assert (state.phase, state.ending) == ("home", "coverage goal")  # return_home is off: hover where it is
    assert not phases.decision_due(111.0) and state.phase == "home"
    assert not phases.decision_due(112.0) and state.phase == "done"  # home_hover_s = 2


def test_without_a_coverage_the_time_limit_ends_exploration_and_the_vehicle_returns(clock):
    phases, state, _ = _phases(
        FakeLink(Pose(10.0, 1.0, 1.0, 1.5, 0.0)), replace(CONFIG, return_home=True, time_limit_s=30.0)
    )
    phases.climb()
    clock.now += 5.0
    phases.check_takeoff_done(Pose(10.0, 1.0, 1.0, CONFIG.flight_height_m, 0.0), "frontier")
    phases.check_end_of_exploration(clock.now + 29.0, None)
    assert state.phase == "exploring"
    phases.check_end_of_exploration(clock.now + 30.0, None)
    assert (state.phase, state.ending) == ("returning", "time limit")


def test_the_flight_budget_keeps_the_way_home_in_reserve(clock):
    config = replace(CONFIG, return_home=True, time_limit_s=100.0)
    phases, state, _ = _phases(FakeLink(Pose(10.0, 1.0, 1.0, 1.5, 0.0)), config)
    phases.climb()
    clock.now += 5.0
    phases.check_takeoff_done(Pose(10.0, 1.0, 1.0, config.flight_height_m, 0.0), "frontier")
    state.home_xy = (1.0, 1.0)  # where take_off() puts it
    # 10 m from home: 10 m × detour 2 at 0.5 m/s + 2 s hover + 10 s margin = 52 s kept for the way home
    assert phases.home_reserve_s((11.0, 1.0)) == pytest.approx(52.0)
    phases.check_end_of_exploration(clock.now + 47.0, None, None, (11.0, 1.0))
    assert state.phase == "exploring"
    phases.check_end_of_exploration(clock.now + 48.0, None, None, (11.0, 1.0))
    assert (state.phase, state.ending) == ("returning", "time limit")


def test_the_reserve_follows_the_measured_path_home_round_a_wall(clock):
    # home lies behind a wall with one gap at its far end: the way home is ~3 × the straight line, and the reserve,
    # once the path home is measured, keeps that way (× home_path_slack), not the straight line × home_detour_factor
    from edge_explorer.mapping.observed import coarsen_codes

    high = np.full((200, 200), FREE, dtype=np.int8)  # 10 m × 10 m, all seen free
    high[:180, 100:102] = 1  # a wall across x = 5 m from y = 0 to 9 m (OCCUPIED = 1): the gap is at the top
    grid = GridSpec((0.0, 0.0), 0.05, high.shape)
    maps = ObservedMaps(grid, grid.coarsened(4), high, coarsen_codes(high, 4))
    config = replace(CONFIG, return_home=True, time_limit_s=300.0, return_time_limit_s=30.0)
    phases, state, _ = _phases(FakeLink(Pose(10.0, 7.0, 1.0, 1.7, 0.0)), config)
    state.phase, state.home_xy = "exploring", (3.0, 1.0)
    cruise, fixed_s = 0.5, config.home_hover_s + config.home_reserve_margin_s
    straight = np.hypot(4.0, 0.0)
    assert phases.home_reserve_s((7.0, 1.0)) == pytest.approx(straight * 2.0 / cruise + fixed_s)  # not measured yet
    phases.measure_way_home(maps, (7.0, 1.0), clock.now)
    path_m = (phases.home_reserve_s((7.0, 1.0)) - fixed_s) * cruise / config.home_path_slack
    assert 2 * np.hypot(2.0, 8.5) <= path_m <= 2 * np.hypot(2.0, 8.5) + 3.0  # up round the wall's end and down
    # 1 m further on, before the next measurement: the path plus the straight line flown since
    assert phases.home_reserve_s((7.0, 2.0)) == pytest.approx(
        (path_m + 1.0) * config.home_path_slack / cruise + fixed_s
    )
    phases.measure_way_home(maps, (7.0, 2.0), clock.now + 1.0)  # too soon: the last measurement stays
    assert phases.home_reserve_s((7.0, 1.0)) == pytest.approx(path_m * config.home_path_slack / cruise + fixed_s)
    # the return gets twice the reserve to fly home where that is longer than return_time_limit_s
    phases.finish_exploring("time limit")
    reserve_s = phases.home_reserve_s((7.0, 1.0))
    assert phases.home_action(maps, (7.0, 1.0, 0.0), int(Action.HOVER)) is not None
    clock.now += 1.5 * reserve_s  # past return_time_limit_s (30 s), within twice the reserve: still on its way
    assert reserve_s * 1.5 > config.return_time_limit_s
    assert phases.home_action(maps, (7.0, 1.0, 0.0), int(Action.HOVER)) is not None and state.phase == "returning"
    clock.now += reserve_s
    assert phases.home_action(maps, (7.0, 1.0, 0.0), int(Action.HOVER)) is None
    assert (state.phase, state.reached_home) == ("home", False)


def test_the_return_plans_its_path_home_every_few_seconds_not_every_step(clock, monkeypatch):
    # the whole-map plan costs ~0.2 s on a 271 m floor: a step home follows the last path on a window around the
    # vehicle, and the path is planned again after home_path_every_s, after a decision's waypoint is out
    # (replan_home), not inside the step's own action
    from edge_explorer.mapping.observed import coarsen_codes

    high = np.full((200, 400), FREE, dtype=np.int8)  # 20 m × 10 m, all seen free
    grid = GridSpec((0.0, 0.0), 0.05, high.shape)
    maps = ObservedMaps(grid, grid.coarsened(4), high, coarsen_codes(high, 4))
    plans = []
    monkeypatch.setattr(phases_module, "path_home", lambda *a, **k: plans.append(a[1]) or path_home(*a, **k))
    config = replace(CONFIG, return_home=True)
    phases, state, _ = _phases(FakeLink(Pose(10.0, 18.0, 5.0, 1.7, np.pi)), config)
    state.phase, state.home_xy = "exploring", (2.0, 5.0)
    phases.finish_exploring("time limit")
    for _ in range(3):  # facing home along a free corridor: forward, on the first plan
        assert phases.home_action(maps, (18.0, 5.0, np.pi), int(Action.FORWARD)) == Action.FORWARD
        phases.replan_home(maps, (18.0, 5.0, np.pi), clock.now)  # not due yet
        clock.now += 1.0
    assert len(plans) == 1
    clock.now += config.home_path_every_s
    assert phases.home_action(maps, (18.0, 5.0, np.pi), int(Action.FORWARD)) == Action.FORWARD
    assert len(plans) == 1  # the step follows the old path (it still leads home) …
    phases.replan_home(maps, (17.5, 5.0, np.pi), clock.now)
    assert len(plans) == 2 and plans[-1] == (17.5, 5.0)  # … and the plan comes after its waypoint, from its start
    phases.replan_home(maps, (17.0, 5.0, np.pi), clock.now + 1.0)
    assert len(plans) == 2


# ---- the decision pipeline ---------------------------------------------------------------------------------------


class FailingPlanner:
    """A goal planner whose model fails: what a learned goal policy's planner does when its policy raises."""

    def act(self, *args, **kwargs):
        raise RuntimeError("the model answered NaN")

    def reset(self) -> None:
        pass


def _pipeline(config: DaemonConfig = CONFIG, policy=None) -> DecisionPipeline:
    link = FakeLink(Pose(10.0, 1.0, 1.0, 1.5, 0.0))
    phases, _, record = _phases(link, config)
    timings = record.timings  # one run, one set of stage timings
    return DecisionPipeline(
        config,
        link,
        load_action_table(),
        timings,
        phases.feeder,
        phases.maps,
        phases,
        record,
        policy,  # type: ignore[arg-type]
    )


def _open_room() -> tuple[ObservedMaps, tuple[float, float, float]]:
    """A 4 m × 3 m room seen free in a 6 m × 5 m unknown map, the vehicle in it facing east."""
    maps = ObservedMaps.empty(GridSpec((0.0, 0.0), 0.05, (100, 120)))
    maps.apply_patch(20, 20, np.full((60, 80), FREE, dtype=np.int8))
    return maps, (2.0, 2.5, 0.0)


def test_a_failing_goal_policy_hands_over_to_the_frontier_planner(caplog):
    pipeline = _pipeline(policy=object())  # a policy is loaded; its planner fails
    assert pipeline.planner_name == "drl"
    pipeline.planner = FailingPlanner()
    maps, pose = _open_room()
    with caplog.at_level(logging.ERROR, logger="edge_explorer.runtime.daemon"):
        action = pipeline.planner_action(maps, pose, int(Action.HOVER), None)
    assert pipeline.policy is None and pipeline.planner_name == "frontier"
    assert type(pipeline.planner) is type(build_planner("frontier"))
    assert action is not None and action != Action.HOVER  # the frontier planner flies towards the room's rim
    assert any("the goal policy failed (RuntimeError: the model answered NaN)" in m for m in caplog.messages)


def test_a_frontier_planner_that_fails_is_no_policy_to_hand_over_from():
    pipeline = _pipeline()
    pipeline.planner = FailingPlanner()
    with pytest.raises(RuntimeError, match="answered NaN"):
        pipeline.planner_action(*_open_room(), int(Action.HOVER), None)


def test_after_a_hold_the_next_step_starts_at_rest():
    pipeline = _pipeline()
    pipeline._previous_action = int(Action.FORWARD)
    pipeline.restart_at_rest()
    assert pipeline.previous_action == Action.HOVER


def test_decisions_explore_until_the_time_limit_then_hold(clock):
    """The whole pipeline alone, on a map that saw nothing yet: the frontier planner's waypoint while exploring;
    at the time limit exploration ends and, return_home off, the waypoint is a hold. Every decision is recorded."""
    pipeline = _pipeline()
    phases, maps, record = pipeline.phases, pipeline.maps, pipeline.record
    maps.start(1.0, 1.0, CONFIG.band)
    phases.climb()
    clock.now += 5.0
    phases.check_takeoff_done(replace(pipeline.link.pose, z_m=CONFIG.flight_height_m), pipeline.planner_name)
    assert phases.phase == "exploring"
    pipeline.decide(clock.now, time.thread_time())
    assert phases.phase == "exploring" and (record.decisions, record.sources) == (1, {"frontier": 1})
    assert pipeline.view is not None and pipeline.view.thresholded is None
    assert pipeline.view.high.shape == (320, 320)  # the first box: 16 m around the take-off point
    assert {"project", "planner", "waypoint_trajectory", "decision", "decision_cpu"} <= set(record.timings.stats())
    clock.now += CONFIG.time_limit_s
    pipeline.decide(clock.now, time.thread_time())
    assert (phases.phase, phases.state.ending) == ("home", "time limit")
    assert record.sources == {"frontier": 1, "hold": 1} and len(record.path) == 2
    assert pipeline.previous_action == Action.HOVER and pipeline.feeder.end_s is not None


# ---- the map stop rule without a plan (issue #56) ----------------------------------------------------------------


def test_without_a_plan_the_map_stop_rule_ends_exploration(clock):
    phases, state, _ = _phases(FakeLink(Pose(10.0, 1.0, 1.0, 1.5, 0.0)), replace(CONFIG, stop_threshold_m2=3.0))
    phases.climb()
    clock.now += 5.0
    phases.check_takeoff_done(Pose(10.0, 1.0, 1.0, CONFIG.flight_height_m, 0.0), "frontier")
    phases.check_end_of_exploration(clock.now, None, 12.0)  # 12 m² unverified: go on
    phases.check_end_of_exploration(clock.now, 0.5, 1.0)  # with a plan the coverage goal decides, not the map
    assert state.phase == "exploring"
    phases.check_end_of_exploration(clock.now, None, 2.5)
    assert (state.phase, state.ending) == ("home", "map says verified")
    with pytest.raises(ValueError, match="stop_threshold_m2"):
        replace(CONFIG, stop_threshold_m2=-1.0)


def test_the_record_measures_the_unverified_area_without_a_plan():
    record = _record()
    maps = ObservedMaps.empty(GridSpec((0.0, 0.0), 0.05, (80, 80)))
    record.record_progress(100.0, Pose(100.0, 1.0, 1.0, 1.0, 0.0), maps, None, "exploring")
    assert record.unverified_m2 == float("inf")  # nothing seen: nothing verified
    maps.high[8:72, 8:72] = 1  # a closed room, seen whole: walls …
    maps.high[12:68, 12:68] = FREE  # … around free space
    maps.low[:] = 0
    maps.low[2:18, 2:18] = 1
    maps.low[3:17, 3:17] = FREE
    record.record_progress(101.0, Pose(101.0, 1.0, 1.0, 1.0, 0.0), maps, None, "exploring")
    assert record.unverified_m2 == 0.0 and record.coverage is None
    report = record.report(
        1.0,
        0.1,
        ending="map says verified",
        planner="frontier",
        predictor=False,
        exploration_s=1.0,
        returned_home=False,
    )
    assert report.unverified_m2 == 0.0 and report.verified_m2 == pytest.approx(16 * 16 * 0.04)
    assert report.unverified == {"unknown_reachable_m2": 0.0, "expected_wrong_m2": 0.0, "predicted_m2": 0.0}


def test_the_daemons_maps_are_not_sized_from_the_plan():
    """The daemon takes no map box (a plan only scores coverage): its maps start around the take-off point, the
    same whatever the building, and grow when the vehicle flies past them."""
    import inspect

    from edge_explorer.runtime.daemon import Daemon

    assert "region" not in inspect.signature(Daemon).parameters
    maps = FlightMaps(CONFIG.fusion)
    maps.start(30.03, -4.1, CONFIG.band)
    assert maps.region is not None and maps.flown_grid is not None
    assert maps.region.size_xyz_m[:2] == pytest.approx((16.0, 16.0))
    assert maps.flown_grid.origin_xy == pytest.approx((22.0, -12.2))  # take-off on the 0.20 m lattice, − 8 m
    assert maps.voxels is not None
    maps.voxels.ensure_covers(60.0, -4.1)  # a frame from 30 m further on
    assert maps.region.size_xyz_m[0] >= 30.0 + 2 * maps.voxels.reach_m
    maps.mark_flown(60.0, -4.1, 0.2)
    high, grid, _, _ = maps.project(CONFIG.band)
    assert high[grid.cell_of(60.0, -4.1)] == FREE


def test_the_safety_check_on_the_window_around_the_vehicle_answers_as_on_the_whole_map():
    """The decision pipeline checks waypoints on a square of the maps around the vehicle (their cost must not grow
    with maps that grow with the flight): every motion it judges, it judges as the whole map would."""
    from edge_explorer.mapping.observed import coarsen_codes
    from edge_explorer.plan.follow import FreeSpace
    from edge_explorer.plan.waypoint import WaypointPlanner
    from edge_explorer.plan.window import crop_maps, place_window
    from edge_explorer.world.grid import OCCUPIED, UNKNOWN

    rng = np.random.default_rng(0)
    high = np.full((600, 600), FREE, dtype=np.int8)  # 30 m × 30 m: walls, pillars and unseen patches
    for _ in range(120):
        r, c, h, w = rng.integers(0, 600, 2).tolist() + rng.integers(1, 30, 2).tolist()
        high[r : r + h, c : c + w] = OCCUPIED if rng.random() < 0.6 else UNKNOWN
    grid = GridSpec((-3.0, 2.0), 0.05, high.shape)
    maps = ObservedMaps(grid, grid.coarsened(4), high, coarsen_codes(high, 4))
    table = load_action_table()
    whole = WaypointPlanner(table, FreeSpace.from_codes(high, grid), CONFIG.follow.safe_distance_m)
    judged = 0
    for x, y in rng.uniform((-2.5, 2.5), (26.5, 31.5), (40, 2)):
        near = crop_maps(maps, place_window(maps.low_grid, (x, y), decisions_module._SAFETY_WINDOW_M))
        cropped = WaypointPlanner(table, FreeSpace.from_codes(near.high, near.high_grid), whole.safe_distance_m)
        for yaw in (0.0, 2.0, 4.0):
            start = (x + 0.3, y - 0.3, yaw)  # the step starts at the reference, off the odometry position
            for previous in Action:
                for action in Action:
                    safe = whole.is_safe((x, y), start, previous, action)
                    assert cropped.is_safe((x, y), start, previous, action) == safe
                    judged += safe
    assert judged > 100  # safe and unsafe motions both judged


def test_the_return_counts_as_home_only_when_it_ends_at_home(clock):
    # a return that ends where the observed map leads no nearer home, or by its time limit, is no return home
    from edge_explorer.mapping.observed import coarsen_codes

    high = np.full((200, 200), FREE, dtype=np.int8)  # 10 m × 10 m, all seen free
    high[:, 100:102] = 1  # a wall across it (OCCUPIED = 1): home lies behind it
    grid = GridSpec((0.0, 0.0), 0.05, high.shape)
    maps = ObservedMaps(grid, grid.coarsened(4), high, coarsen_codes(high, 4))
    # at home; at the wall's near side, the nearest the map leads to a home behind it
    for xy, home, reached in (((2.0, 5.0), (2.0, 5.0), True), ((4.55, 4.95), (8.0, 5.0), False)):
        phases, state, _ = _phases(FakeLink(Pose(10.0, *xy, 1.7, 0.0)), replace(CONFIG, return_home=True))
        state.phase, state.home_xy = "exploring", home
        phases.finish_exploring("time limit")
        assert phases.home_action(maps, (*xy, 0.0), int(Action.HOVER)) is None  # nowhere nearer to go
        assert (state.phase, state.reached_home) == ("home", reached)


def test_the_return_arrives_within_a_step_of_home(clock):
    # 0.3 m from home, facing away, in open space: the follower would turn in place for ever (its goal tolerance is
    # 0.25 m and a forward step ~0.5 m; session 45's 271 m flight did so until its return time ran out)
    from edge_explorer.mapping.observed import coarsen_codes

    high = np.full((200, 200), FREE, dtype=np.int8)  # 10 m × 10 m, all seen free
    grid = GridSpec((0.0, 0.0), 0.05, high.shape)
    maps = ObservedMaps(grid, grid.coarsened(4), high, coarsen_codes(high, 4))
    for yaw in (0.0, np.pi / 2, np.pi, -np.pi / 2):
        phases, state, _ = _phases(FakeLink(Pose(10.0, 5.3, 5.0, 1.7, yaw)), replace(CONFIG, return_home=True))
        state.phase, state.home_xy = "exploring", (5.0, 5.0)
        phases.finish_exploring("time limit")
        assert phases.home_action(maps, (5.3, 5.0, yaw), int(Action.HOVER)) is None
        assert (state.phase, state.reached_home) == ("home", True)


def test_the_goal_policy_scores_on_its_own_daemon_thread_and_its_failures_reach_the_planner():
    """TimedScores.submit: the same scores as a call, timed as stage "policy", on a daemon thread (the program's
    exit joins every other thread); a model that raises raises where the planner waits for the scores."""
    import threading

    from edge_explorer.plan.goal_policy import ConcurrentGoalPolicy
    from edge_explorer.runtime.daemon.report import StageTimings

    seen = []

    def scores(observation):  # noqa: ANN001, ANN202 - PolicyRuntime.scores
        seen.append(threading.current_thread())
        if observation["fail"]:
            raise RuntimeError("model failed")
        return np.full((59, 59), 2.0, dtype=np.float32)

    timings = StageTimings()
    policy = decisions_module.TimedScores(SimpleNamespace(scores=scores), timings)
    assert isinstance(policy, ConcurrentGoalPolicy)
    np.testing.assert_array_equal(policy.submit({"fail": False}).result(timeout=5), policy({"fail": False}))
    assert seen[0].daemon and seen[0] is not threading.main_thread() and seen[1] is threading.main_thread()
    assert len(timings.samples_ms("policy")) == 2
    with pytest.raises(RuntimeError, match="model failed"):
        policy.submit({"fail": True}).result(timeout=5)


def test_the_way_home_is_planned_on_the_known_part_of_growing_maps(clock, monkeypatch):
    # a whole floor's maps hold unknown slack ahead of the flight: the way home is planned on the known cells (its
    # transient was the daemon's peak memory), and it is the path the whole map gives
    from edge_explorer.mapping.observed import coarsen_codes

    high = np.full((400, 800), UNKNOWN, dtype=np.int8)  # 40 m × 20 m of maps, a 20 m × 8 m part known
    high[100:260, 200:600] = FREE
    high[100:230, 380:382] = 1  # a wall with a gap at its top end (OCCUPIED = 1)
    grid = GridSpec((-3.0, 2.0), 0.05, high.shape)
    maps = ObservedMaps(grid, grid.coarsened(4), high, coarsen_codes(high, 4))
    sizes = []
    measured = FreeSpace.from_codes
    monkeypatch.setattr(
        phases_module.FreeSpace, "from_codes", lambda codes, g, *a: sizes.append(codes.size) or measured(codes, g, *a)
    )
    phases, state, _ = _phases(FakeLink(Pose(10.0, 14.0, 9.0, 1.7, 0.0)), replace(CONFIG, return_home=True))
    state.home_xy = (22.0, 8.0)  # beyond the wall
    path = phases._path_home(maps, (14.0, 9.0))
    whole = path_home(FreeSpace.from_codes(high, grid), (14.0, 9.0), (22.0, 8.0), CONFIG.follow.safe_distance_m)
    assert sizes[0] <= (160 + 2 * 40 + 3) * (400 + 2 * 40 + 3) < high.size / 2
    assert path.shape == whole.shape and np.allclose(path, whole, atol=1e-9)
    assert path[:, 1].max() > 2.0 + 230 * 0.05  # round the wall's top end
